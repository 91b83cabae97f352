//! Bad input gets a clear error naming the file and the problem, exit code 1, and no panic.
//! Each case starts from a small valid generated scene and breaks one thing.

use fipt_core::scene::{Camera, Image, procedural};
use glam::{DVec3, Vec3};
use std::path::{Path, PathBuf};
use std::process::Command;

const W: usize = 16;
const H: usize = 12;

fn fresh_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("fipt-bad-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn cameras() -> Vec<Camera> {
    [(1.0, 1.2, 1.0), (4.0, 1.5, 3.0)]
        .iter()
        .map(|&(x, y, z)| {
            Camera::look_at_fov(
                DVec3::new(x, y, z),
                DVec3::new(2.5, 1.0, 2.0),
                DVec3::Y,
                1.2,
                W,
                H,
            )
        })
        .collect()
}

fn transforms_json(cams: &[Camera]) -> String {
    let frames: Vec<serde_json::Value> = cams
        .iter()
        .enumerate()
        .map(|(k, c)| {
            serde_json::json!({"file_path": format!("Image/{k:03}_0001"), "transform_matrix": c.to_fipt_c2w()})
        })
        .collect();
    serde_json::json!({"camera_angle_x": 1.2, "frames": frames}).to_string()
}

/// A valid FIPT-synthetic scene: procedural room, 2 train views, constant images, DiffCol.
fn valid_scene(name: &str) -> PathBuf {
    let d = fresh_dir(name);
    let room = procedural::room(Vec3::new(5.0, 2.7, 4.0), 1);
    room.mesh
        .save_obj(&d.join("scene.obj"), "test room")
        .unwrap();
    let cams = cameras();
    std::fs::create_dir_all(d.join("train/Image")).unwrap();
    std::fs::write(d.join("train/transforms.json"), transforms_json(&cams)).unwrap();
    for k in 0..cams.len() {
        let mut img = Image::new(W, H, 3);
        img.data.fill(0.5);
        img.write_exr(&d.join(format!("train/Image/{k:03}_0001.exr")))
            .unwrap();
        img.write_exr(&d.join(format!("train/DiffCol/{k:03}_0001.exr")))
            .unwrap();
    }
    d
}

/// Runs `fipt-train` with `args` and asserts a clean failure (exit 1, no panic) whose message
/// has every `needle`.
fn assert_cli_fails(args: &[&std::ffi::OsStr], needles: &[&str]) {
    let out = Command::new(env!("CARGO_BIN_EXE_fipt-train"))
        .args(args)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "expected exit 1, stderr: {err}");
    assert!(!err.contains("panicked"), "panic: {err}");
    for n in needles {
        assert!(err.contains(n), "stderr lacks '{n}': {err}");
    }
}

/// Runs `fipt-train check` and asserts a clean failure whose message has every `needle`.
fn assert_fails(scene: &Path, needles: &[&str]) {
    assert_cli_fails(
        &["check".as_ref(), "--scene".as_ref(), scene.as_os_str()],
        needles,
    );
    let _ = std::fs::remove_dir_all(scene);
}

#[test]
fn valid_scene_passes() {
    let d = valid_scene("ok");
    let out = Command::new(env!("CARGO_BIN_EXE_fipt-train"))
        .args(["check", "--json", "--scene"])
        .arg(&d)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let r: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(r["views"], 2);
    assert_eq!(r["hit_fraction"], 1.0);
    // No labels in this scene: the doctor says so.
    assert!(r["problems"].to_string().contains("IndexMA"));
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn missing_folder_and_files() {
    let d = fresh_dir("nofolder");
    assert_fails(&d.join("nope"), &["nope", "scene folder not found"]);
    let d = valid_scene("noobj");
    std::fs::remove_file(d.join("scene.obj")).unwrap();
    assert_fails(&d, &["scene.obj", "file not found"]);
    let d = valid_scene("noimages");
    std::fs::remove_dir_all(d.join("train/Image")).unwrap();
    assert_fails(&d, &["Image", "not found"]);
    let d = valid_scene("nomap");
    std::fs::remove_file(d.join("train/DiffCol/001_0001.exr")).unwrap();
    assert_fails(
        &d,
        &["DiffCol", "missing 1 of the 2 frames", "001_0001.exr"],
    );
}

#[test]
fn broken_exr_files() {
    let d = valid_scene("trunc");
    let p = d.join("train/Image/001_0001.exr");
    let bytes = std::fs::read(&p).unwrap();
    std::fs::write(&p, &bytes[..bytes.len() * 2 / 3]).unwrap();
    assert_fails(&d, &["001_0001.exr", "EXR"]);
    let d = valid_scene("notexr");
    std::fs::write(d.join("train/Image/000_0001.exr"), "P6 16 12 255\n").unwrap();
    assert_fails(&d, &["000_0001.exr", "not a readable EXR"]);
    let d = valid_scene("nan");
    let mut img = Image::new(W, H, 3);
    img.data[3 * (2 * W + 5)] = f32::INFINITY;
    img.write_exr(&d.join("train/Image/001_0001.exr")).unwrap();
    assert_fails(&d, &["001_0001.exr", "NaN/Inf", "row 2 col 5"]);
}

#[test]
fn size_and_count_mismatches() {
    let d = valid_scene("size");
    Image::new(W + 1, H, 3)
        .write_exr(&d.join("train/Image/001_0001.exr"))
        .unwrap();
    assert_fails(&d, &["001_0001.exr", "17x12", "16x12"]);
    let d = valid_scene("mapsize");
    Image::new(W, H + 2, 3)
        .write_exr(&d.join("train/DiffCol/000_0001.exr"))
        .unwrap();
    assert_fails(&d, &["DiffCol/000_0001.exr", "16x14"]);
    let d = valid_scene("count");
    std::fs::remove_file(d.join("train/Image/001_0001.exr")).unwrap();
    assert_fails(
        &d,
        &[
            "Image",
            "missing 1 of the 2 frames",
            "transforms.json",
            "001_0001.exr",
        ],
    );
    let d = valid_scene("extra");
    Image::new(W, H, 3)
        .write_exr(&d.join("train/Image/007_0001.exr"))
        .unwrap();
    assert_fails(&d, &["Image", "007_0001.exr", "no frame", "2 frames"]);
}

#[test]
fn malformed_json() {
    let d = valid_scene("json");
    std::fs::write(
        d.join("train/transforms.json"),
        "{\"camera_angle_x\": 1.2, \"frames\": [",
    )
    .unwrap();
    assert_fails(&d, &["transforms.json", "malformed JSON"]);
    let d = valid_scene("jsonkey");
    std::fs::write(d.join("train/transforms.json"), "{\"frames\": []}").unwrap();
    assert_fails(&d, &["transforms.json", "camera_angle_x"]);
    let d = valid_scene("jsonmat");
    let bad = transforms_json(&cameras()).replacen("[[", "[[\"x\",", 1);
    std::fs::write(d.join("train/transforms.json"), bad).unwrap();
    assert_fails(&d, &["transforms.json", "frame 0", "transform_matrix"]);
}

#[test]
fn malformed_meshes() {
    let cases: [(&str, &str, &[&str]); 5] = [
        (
            "objsyntax",
            "v 0 0\nf 1 2 3\n",
            &["scene.obj", "line 1", "3 coordinates"],
        ),
        (
            "objempty",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\n",
            &["scene.obj", "no triangles"],
        ),
        (
            "objdegen",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 2 0 0\nf 1 2 3\nf 1 2 4\n",
            &["scene.obj", "degenerate", "triangle 1"],
        ),
        (
            "objrange",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n",
            &["scene.obj", "line 4", "out of range"],
        ),
        (
            "objindex",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 b 3\n",
            &["scene.obj", "bad face index"],
        ),
    ];
    for (name, text, needles) in cases {
        let d = valid_scene(name);
        std::fs::write(d.join("scene.obj"), text).unwrap();
        assert_fails(&d, needles);
    }
}

#[test]
fn real_and_nerfstudio_layouts() {
    // FIPT real layout with two cameras in cam.txt and the intrinsics `k`.
    let real = |name: &str, k: &str| {
        let d = valid_scene(name);
        std::fs::rename(d.join("train/Image"), d.join("Image")).unwrap();
        std::fs::remove_dir_all(d.join("train")).unwrap();
        let cam = "2\n1 1.2 1\n2.5 1 2\n0 1 0\n4 1.5 3\n2.5 1 2\n0 1 0\n";
        std::fs::write(d.join("cam.txt"), cam).unwrap();
        std::fs::write(d.join("K_list.txt"), k).unwrap();
        d
    };
    // K_list.txt has 1 camera.
    let d = real("real", "1\n10 0 8\n0 10 6\n0 0 1\n");
    assert_fails(&d, &["K_list.txt", "1 intrinsics", "2 cameras"]);
    // A focal length of 0 (rays at infinity).
    let d = real(
        "real-fx",
        "2\n10 0 8\n0 10 6\n0 0 1\n0 0 8\n0 10 6\n0 0 1\n",
    );
    assert_fails(
        &d,
        &[
            "K_list.txt",
            "camera 1",
            "focal lengths",
            "out of their range",
        ],
    );
    // nerfstudio: a frame without focal length.
    let d = valid_scene("ns");
    std::fs::rename(d.join("train/Image"), d.join("images")).unwrap();
    std::fs::remove_dir_all(d.join("train")).unwrap();
    let js = serde_json::json!({"w": W, "h": H, "cx": 8.0, "cy": 6.0, "fl_y": 10.0,
        "frames": [{"file_path": "images/000_0001.exr", "transform_matrix": cameras()[0].to_fipt_c2w()}]});
    std::fs::write(d.join("transforms.json"), js.to_string()).unwrap();
    assert_fails(&d, &["transforms.json", "frame 0", "fl_x"]);
}

/// Values out of range in the files beside the photos, through `check`: the file, the field
/// and the range are named (`tests/inputs.rs` walks every field through its loader).
#[test]
fn values_out_of_range_beside_the_photos() {
    // A roughness of 1.5 in scene_meta.json.
    let d = valid_scene("meta-range");
    let meta = serde_json::json!({"parts": [{"id": 0, "name": "room", "triangles": [0, 1],
        "material": {"base_color": [0.5, 0.5, 0.5], "roughness": 1.5, "metallic": 0.0}}]});
    std::fs::write(d.join("scene_meta.json"), meta.to_string()).unwrap();
    assert_fails(
        &d,
        &[
            "scene_meta.json",
            "parts[0].material.roughness",
            "out of its range [0, 1]",
        ],
    );
    // A part's triangles past the mesh.
    let d = valid_scene("meta-tris");
    let meta = serde_json::json!({"parts": [{"id": 0, "name": "room", "triangles": [0, 100000],
        "material": {"base_color": [0.5, 0.5, 0.5], "roughness": 0.5, "metallic": 0.0}}]});
    std::fs::write(d.join("scene_meta.json"), meta.to_string()).unwrap();
    assert_fails(
        &d,
        &[
            "scene_meta.json",
            "parts[0].triangles",
            "runs past them",
            "scene.obj",
        ],
    );
    // A camera matrix with a zero axis.
    let d = valid_scene("singular");
    let t = d.join("train/transforms.json");
    let mut js: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&t).unwrap()).unwrap();
    for r in 0..3 {
        js["frames"][1]["transform_matrix"][r][1] = serde_json::json!(0.0);
    }
    std::fs::write(&t, js.to_string()).unwrap();
    assert_fails(&d, &["transforms.json", "frame 1", "degenerate axes"]);
}

/// `landscape --cover-planes` without `train.min_coverage` fails before reading the scene,
/// naming the key, and writes nothing.
#[test]
fn cover_planes_without_min_coverage() {
    let d = valid_scene("cover-planes");
    let out_dir = fresh_dir("cover-planes-out");
    // `configs/fast.json` leaves every pixel in (`train.min_coverage` 0; the default's is 0.75).
    let fast = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/fast.json");
    let args = [
        "landscape".as_ref(),
        "--cover-planes".as_ref(),
        "--config".as_ref(),
        fast.as_os_str(),
        "--scene".as_ref(),
        d.as_os_str(),
        "--out".as_ref(),
        out_dir.as_os_str(),
    ];
    assert_cli_fails(&args, &["train.min_coverage"]);
    assert!(!out_dir.join("landscape.json").exists());
    let _ = std::fs::remove_dir_all(&d);
    let _ = std::fs::remove_dir_all(&out_dir);
}
