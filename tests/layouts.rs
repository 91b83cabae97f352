//! The three scene layouts describe the same cameras: fipt-room (FIPT synthetic layout) rewritten
//! as a FIPT real scene (`cam.txt` origin / look-at / up + `K_list.txt`) and as a nerfstudio
//! scene (`transforms.json`, OpenGL c2w columns right, up, back, position) must load into the same
//! pixel-centre rays and the same images.

use fipt_core::scene::dataset::Layout;
use fipt_core::scene::{Camera, Dataset, LoadOptions};
use serde_json::json;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

fn scene_dir() -> PathBuf {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../scenes/fipt-room");
    assert!(p.join("scene.obj").exists(), "missing {}", p.display());
    p
}

fn link(src: &Path, dst: &Path) {
    std::os::unix::fs::symlink(src, dst)
        .unwrap_or_else(|e| panic!("symlink {} -> {}: {e}", dst.display(), src.display()));
}

fn v3(v: glam::DVec3) -> String {
    format!("{:?} {:?} {:?}", v.x, v.y, v.z)
}

/// FIPT real layout: per camera origin, a look-at point 2.5 m ahead and an up vector that is
/// not orthogonal to the view direction (the loader orthogonalises it, as FIPT does).
fn write_real(dir: &Path, scene: &Path, cams: &[&Camera]) {
    std::fs::create_dir_all(dir).unwrap();
    link(&scene.join("scene.obj"), &dir.join("scene.obj"));
    link(&scene.join("train/Image"), &dir.join("Image"));
    let (mut cam, mut k) = (format!("{}\n", cams.len()), format!("{}\n", cams.len()));
    for c in cams {
        let (down, fwd) = (c.rotation.y_axis, c.rotation.z_axis);
        writeln!(cam, "{}", v3(c.origin)).unwrap();
        writeln!(cam, "{}", v3(c.origin + 2.5 * fwd)).unwrap();
        writeln!(cam, "{}", v3(-down + 0.3 * fwd)).unwrap();
        writeln!(k, "{:?} 0 {:?}", c.fx, c.cx).unwrap();
        writeln!(k, "0 {:?} {:?}", c.fy, c.cy).unwrap();
        writeln!(k, "0 0 1").unwrap();
    }
    std::fs::write(dir.join("cam.txt"), cam).unwrap();
    std::fs::write(dir.join("K_list.txt"), k).unwrap();
}

/// nerfstudio layout: shared intrinsics at the top level, c2w = (right, up, back, position);
/// every other file path without its extension `ext` (the loader finds it).
fn write_nerfstudio(dir: &Path, scene: &Path, cams: &[&Camera], ext: &str) {
    std::fs::create_dir_all(dir).unwrap();
    link(&scene.join("scene.obj"), &dir.join("scene.obj"));
    link(&scene.join("train/Image"), &dir.join("images"));
    let c0 = cams[0];
    let frames: Vec<_> = cams
        .iter()
        .enumerate()
        .map(|(k, c)| {
            let m = c.to_opengl_c2w();
            let ext = if k % 2 == 0 { ext } else { "" };
            json!({"file_path": format!("images/{k:03}_0001{ext}"), "transform_matrix": m})
        })
        .collect();
    let t = json!({
        "camera_model": "OPENCV",
        "fl_x": c0.fx, "fl_y": c0.fy, "cx": c0.cx, "cy": c0.cy,
        "w": c0.width, "h": c0.height,
        "frames": frames,
    });
    std::fs::write(
        dir.join("transforms.json"),
        serde_json::to_string_pretty(&t).unwrap(),
    )
    .unwrap();
}

#[test]
fn real_and_nerfstudio_layouts_give_the_synthetic_rays() {
    let scene = scene_dir();
    let opts = LoadOptions {
        maps: vec![],
        val: false,
    };
    let syn = Dataset::load(&scene, &opts).unwrap();
    assert_eq!(syn.layout, Layout::FiptSynthetic);
    let cams: Vec<&Camera> = syn.train.views.iter().map(|v| &v.camera).collect();
    assert_eq!(cams.len(), 48);

    let tmp = std::env::temp_dir().join(format!("fipt-layouts-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&tmp);
    write_real(&tmp.join("real"), &scene, &cams);
    write_nerfstudio(&tmp.join("ns"), &scene, &cams, ".exr");

    for (name, layout) in [("real", Layout::FiptReal), ("ns", Layout::Nerfstudio)] {
        let ds = Dataset::load(&tmp.join(name), &opts).unwrap();
        assert_eq!(ds.layout, layout);
        assert_eq!(ds.mesh.num_triangles(), syn.mesh.num_triangles());
        assert_eq!(
            (ds.train.width, ds.train.height),
            (syn.train.width, syn.train.height)
        );
        assert_eq!(ds.train.views.len(), syn.train.views.len(), "{name}");
        let mut worst = 0f32;
        for (a, b) in syn.train.views.iter().zip(&ds.train.views) {
            assert_eq!(a.index, b.index);
            let (ca, cb) = (&a.camera, &b.camera);
            assert_eq!((cb.width, cb.height), (ca.width, ca.height));
            let o = (ca.origin_f32() - cb.origin_f32()).abs().max_element();
            assert!(o <= 1e-4, "{name}: view {}: origin differs by {o}", a.index);
            for row in 0..ca.height {
                for col in 0..ca.width {
                    let d = (ca.pixel_direction(row, col) - cb.pixel_direction(row, col))
                        .abs()
                        .max_element();
                    worst = worst.max(d);
                    assert!(
                        d <= 1e-4,
                        "{name}: view {} pixel ({row}, {col}): direction differs by {d}",
                        a.index
                    );
                }
            }
            // Same photo (the real loader clamps negative radiance to 0; renders have none).
            assert!(
                a.image
                    .data
                    .iter()
                    .zip(&b.image.data)
                    .all(|(x, y)| x.max(0.0) == *y),
                "{name}: view {}: image differs",
                a.index
            );
        }
        eprintln!("{name}: max direction difference {worst:e}");
    }
    std::fs::remove_dir_all(&tmp).unwrap();
}

/// LDR photos in the real layout (PNG) and the nerfstudio layout (JPEG, file paths with and
/// without the extension) load as the synthetic layout's twins do: the same 8-bit codes.
#[test]
fn ldr_photos_load_in_every_layout() {
    let tmp = std::env::temp_dir().join(format!("fipt-layouts-ldr-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&tmp);
    let opts = LoadOptions {
        maps: vec![],
        val: false,
    };
    for (format, layout_dir, ext) in [
        (fipt_train::ldr::twin::LdrFormat::Png, "real", ""),
        (fipt_train::ldr::twin::LdrFormat::Jpeg, "ns", ".jpg"),
    ] {
        let twin = tmp.join(format!("twin-{layout_dir}"));
        fipt_train::ldr::make_twin(&fipt_train::ldr::TwinJob {
            scene: scene_dir(),
            out: twin.clone(),
            response: fipt_train::ldr::twin::CurveSpec::Srgb,
            exposure: None,
            clip_share: 0.01,
            stops: 0.0,
            give_exposure: false,
            format,
            quality: 90,
            seed: 0,
        })
        .unwrap();
        let syn = Dataset::load(&twin, &opts).unwrap();
        assert!(syn.is_ldr());
        let cams: Vec<&Camera> = syn.train.views.iter().map(|v| &v.camera).collect();
        let dir = tmp.join(layout_dir);
        match layout_dir {
            "real" => write_real(&dir, &twin, &cams),
            _ => write_nerfstudio(&dir, &twin, &cams, ext),
        }
        let ds = Dataset::load(&dir, &opts).unwrap();
        assert!(ds.is_ldr(), "{layout_dir}");
        assert_eq!(ds.train.views.len(), syn.train.views.len());
        for (a, b) in syn.train.views.iter().zip(&ds.train.views) {
            let (fa, fb) = (a.ldr.as_ref().unwrap(), b.ldr.as_ref().unwrap());
            assert_eq!(fa.codes, fb.codes, "{layout_dir}: view {}", a.index);
            assert_eq!(fa.clip_at, fb.clip_at);
            assert_eq!(a.image.data, b.image.data);
        }
    }
    std::fs::remove_dir_all(&tmp).unwrap();
}

/// The `ldr` twin of a nerfstudio scene (file paths with and without the extension): its
/// photos are the synthetic layout's twin's, its transforms.json names them and carries the
/// exposures, and the source's photos are left as they were.
#[test]
fn nerfstudio_scenes_have_ldr_twins() {
    let tmp = std::env::temp_dir().join(format!("fipt-layouts-ns-twin-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&tmp);
    let opts = LoadOptions {
        maps: vec![],
        val: false,
    };
    let scene = scene_dir();
    let hdr = Dataset::load(&scene, &opts).unwrap();
    let cams: Vec<&Camera> = hdr.train.views.iter().map(|v| &v.camera).collect();
    let ns = tmp.join("ns");
    write_nerfstudio(&ns, &scene, &cams, ".exr");
    let job = |scene: PathBuf, out: PathBuf| fipt_train::ldr::TwinJob {
        scene,
        out,
        response: fipt_train::ldr::twin::CurveSpec::Gamma([2.0, 2.2, 2.4]),
        exposure: Some(0.3),
        clip_share: 0.01,
        stops: 1.0,
        give_exposure: true,
        format: fipt_train::ldr::twin::LdrFormat::Png,
        quality: 90,
        seed: 4,
    };
    let truth = fipt_train::ldr::make_twin(&job(ns.clone(), tmp.join("ns-ldr"))).unwrap();
    fipt_train::ldr::make_twin(&job(scene.clone(), tmp.join("syn-ldr"))).unwrap();
    let a = Dataset::load(&tmp.join("ns-ldr"), &opts).unwrap();
    let b = Dataset::load(&tmp.join("syn-ldr"), &opts).unwrap();
    assert!(a.is_ldr());
    assert_eq!(a.train.views.len(), b.train.views.len());
    let base = truth.exposure;
    for ((va, vb), e) in a
        .train
        .views
        .iter()
        .zip(&b.train.views)
        .zip(&truth.splits[0].exposures)
    {
        let (fa, fb) = (va.ldr.as_ref().unwrap(), vb.ldr.as_ref().unwrap());
        assert_eq!(fa.codes, fb.codes, "view {}", va.index);
        let given = fa.exposure.expect("exposure written");
        assert!((given - e / base).abs() < 1e-9, "view {}", va.index);
    }
    // The exposures spread over the stops asked for.
    let ex = &truth.splits[0].exposures;
    let (lo, hi) = ex
        .iter()
        .fold((f64::INFINITY, 0.0f64), |(l, h), &x| (l.min(x), h.max(x)));
    assert!(hi / lo > 1.5 && hi / lo <= 4.0 + 1e-9, "{lo} {hi}");
    // The source still holds its HDR photos and no LDR one.
    assert!(ns.join("images/000_0001.exr").is_file());
    assert!(!ns.join("images/000_0001.png").exists());
    assert!(!scene.join("train/Image/000_0001.png").exists());
    std::fs::remove_dir_all(&tmp).unwrap();
}
