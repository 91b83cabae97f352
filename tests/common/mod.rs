//! Helpers shared by the end-to-end tests (included with `mod common;`; each test uses some).
#![allow(dead_code)]

use std::path::{Path, PathBuf};

/// The reference scene carried in the repository.
pub fn scene_dir() -> PathBuf {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../scenes/fipt-room");
    assert!(p.join("scene.obj").exists(), "missing {}", p.display());
    p
}

/// An empty scratch folder of this test process, named by `tag`.
pub fn tmp_dir(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("fipt-test-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Panics unless the file at `p` is non-empty and reads as what its extension says: JSON, PNG,
/// EXR, or HTML that ends with `</html>`.
pub fn assert_readable(p: &Path) {
    let s = p.display();
    let len = std::fs::metadata(p).unwrap().len();
    assert!(len > 0, "{s}: empty");
    match p.extension().and_then(|e| e.to_str()) {
        Some("json") => {
            serde_json::from_str::<serde_json::Value>(&std::fs::read_to_string(p).unwrap())
                .unwrap_or_else(|e| panic!("{s}: {e}"));
        }
        Some("png") => {
            image::open(p).unwrap_or_else(|e| panic!("{s}: {e}"));
        }
        Some("exr") => {
            fipt_core::scene::Image::read_exr(p).unwrap_or_else(|e| panic!("{s}: {e}"));
        }
        Some("html") => {
            let t = std::fs::read_to_string(p).unwrap();
            assert!(t.trim_end().ends_with("</html>"), "{s}: cut short");
        }
        _ => {}
    }
}

/// A scene folder at `dir` holding the first `views` train views of the reference scene and,
/// with `val`, its val views and relighting set (links to its files).
pub fn small_scene(dir: &Path, views: usize, val: bool) {
    let src = scene_dir();
    let _ = std::fs::remove_dir_all(dir);
    std::fs::create_dir_all(dir.join("train")).unwrap();
    let mut links = vec!["scene.obj", "scene_meta.json", "textures"];
    if val {
        links.extend(["val", "relight.json"]);
    }
    for f in links {
        std::os::unix::fs::symlink(src.join(f), dir.join(f)).unwrap();
    }
    let t: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(src.join("train/transforms.json")).unwrap())
            .unwrap();
    let mut t2 = t.clone();
    t2["frames"] = serde_json::Value::Array(t["frames"].as_array().unwrap()[..views].to_vec());
    std::fs::write(dir.join("train/transforms.json"), t2.to_string()).unwrap();
    for entry in std::fs::read_dir(src.join("train")).unwrap() {
        let folder = entry.unwrap().path();
        if !folder.is_dir() {
            continue;
        }
        let name = folder.file_name().unwrap().to_owned();
        std::fs::create_dir_all(dir.join("train").join(&name)).unwrap();
        let mut files: Vec<PathBuf> = std::fs::read_dir(&folder)
            .unwrap()
            .map(|e| e.unwrap().path())
            .collect();
        files.sort();
        for f in files.iter().take(views) {
            std::os::unix::fs::symlink(
                f,
                dir.join("train").join(&name).join(f.file_name().unwrap()),
            )
            .unwrap();
        }
    }
}

/// `configs/fast.json` with a small model for the small scenes (`small_scene`): fits of
/// `min_steps` steps of 2048 pixels, 8 hash-grid levels of 2^14 entries, an emission network
/// of 3 layers of 64, and a voxel grid of 64 for the bake.
pub fn small_fast_config(min_steps: usize) -> serde_json::Value {
    let fast = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../configs/fast.json");
    let mut c: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(fast).unwrap()).unwrap();
    let t = &mut c["train"];
    t["batch"] = 2048.into();
    t["min_steps"] = min_steps.into();
    t["grid"]["levels"] = 8.into();
    t["grid"]["log2_table"] = 14.into();
    t["emission_depth"] = 3.into();
    t["emission_width"] = 64.into();
    c["bake"]["voxel_res"] = 64.into();
    c
}
