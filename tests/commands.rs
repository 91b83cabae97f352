//! The `bake` and `eval` commands of the `fipt-train` binary on the reference scene: exit codes,
//! `--json` output, the files they write, the shading cache, and the scorer's cap on maps that
//! equal the ground truth.

use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn scene_dir() -> PathBuf {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../scenes/fipt-room");
    assert!(p.join("scene.obj").exists(), "missing {}", p.display());
    p
}

fn tmp_dir(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("fipt-commands-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn fipt(args: &[&str], paths: &[(&str, &Path)]) -> Output {
    let mut c = Command::new(env!("CARGO_BIN_EXE_fipt-train"));
    c.args(args);
    for (flag, p) in paths {
        c.arg(flag).arg(p);
    }
    c.output().unwrap()
}

fn ok_json(o: &Output, what: &str) -> Value {
    assert!(
        o.status.success(),
        "{what} failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    serde_json::from_slice(&o.stdout)
        .unwrap_or_else(|e| panic!("{what}: stdout is not JSON ({e}): {:?}", o.stdout))
}

fn read_json(p: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap()
}

#[test]
fn bake_writes_outputs_and_reuses_its_cache() {
    let out = tmp_dir("bake");
    let cfg = out.join("small.json");
    let (diffuse, specular) = (8u64, 4u64);
    std::fs::write(
        &cfg,
        serde_json::json!({
            "bake": {
                "voxel_res": 64,
                "samples": {"diffuse": diffuse, "specular": vec![specular; 6]}
            }
        })
        .to_string(),
    )
    .unwrap();
    let scene = scene_dir();
    let bake = || {
        let o = fipt(
            &["bake", "--json"],
            &[("--scene", &scene), ("--out", &out), ("--config", &cfg)],
        );
        ok_json(&o, "bake")
    };

    let r = bake();
    assert_eq!(r["views"], 48);
    assert_eq!(r["from_cache"], false);
    assert_eq!(r["config"]["voxel_res"], 64);
    let rays = r["secondary_rays"].as_u64().expect("secondary_rays");
    // 160×120 pixels per view, one bake ray per sample (GGX samples below the horizon cast none).
    let max_rays = 48 * 160 * 120 * (diffuse + 6 * specular);
    assert!(
        rays > 0 && rays <= max_rays,
        "{rays} rays, at most {max_rays}"
    );
    assert_eq!(
        read_json(&out.join("bake.json")),
        r,
        "bake.json differs from stdout"
    );
    let mut files = vec![
        out.join("cache/shadings.bin"),
        out.join("shading/diffuse/000.exr"),
    ];
    for c in 0..2 {
        for j in 0..6 {
            files.push(out.join(format!("shading/specular/000_{c}_{j}.exr")));
        }
    }
    files.push(out.join("shading/diffuse/047.exr"));
    for f in &files {
        assert!(f.is_file(), "{} missing", f.display());
    }
    // fipt-room has the GT maps, so the factorised render with GT materials is scored.
    let gt = r["gt_render_psnr"].clone();
    let mean = gt["mean_all_db"]
        .as_f64()
        .expect("gt_render_psnr.mean_all_db");
    assert!(mean.is_finite(), "{mean}");
    assert_eq!(gt["per_view"].as_array().map(Vec::len), Some(48));

    let again = bake();
    assert_eq!(again["from_cache"], true);
    assert!(again["secondary_rays"].is_null());
    assert_eq!(
        again["gt_render_psnr"], gt,
        "cached shadings score differently"
    );
    std::fs::remove_dir_all(&out).unwrap();
}

#[test]
fn eval_needs_maps_and_scores_ground_truth_at_the_cap() {
    let scene = scene_dir();
    let out = tmp_dir("eval");
    // No maps: a clear error naming the folder.
    let o = fipt(&["eval", "--json"], &[("--scene", &scene), ("--out", &out)]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "eval without maps succeeded");
    assert!(err.contains("maps/train"), "stderr: {err}");
    assert!(!out.join("eval.json").exists());

    // Predicted maps = the ground truth, in the file names `ViewMaps::read` expects (the GT
    // layout's own names).
    let dst = out.join("maps/train");
    for folder in [
        "DiffCol",
        "Roughness",
        "Metallic",
        "BaseColor",
        "albedo",
        "Emit",
    ] {
        std::fs::create_dir_all(dst.join(folder)).unwrap();
        for k in 0..48 {
            let name = if folder == "albedo" {
                format!("{k:03}.exr")
            } else {
                format!("{k:03}_0001.exr")
            };
            let src = scene.join("train").join(folder).join(&name);
            std::fs::copy(&src, dst.join(folder).join(&name))
                .unwrap_or_else(|e| panic!("{}: {e}", src.display()));
        }
    }
    let o = fipt(&["eval", "--json"], &[("--scene", &scene), ("--out", &out)]);
    let r = ok_json(&o, "eval");
    for k in ["kd_psnr", "albedo_psnr", "roughness_psnr"] {
        let v = r[k].as_f64().unwrap_or_else(|| panic!("{k} missing: {r}"));
        assert!(v >= 99.0, "{k} = {v}");
    }
    let iou = r["emission_iou"].as_f64().expect("emission_iou");
    assert!(iou >= 0.99, "emission_iou {iou}");
    let l2 = r["emission_log_l2"].as_f64().expect("emission_log_l2");
    assert!(l2 <= 1e-9, "emission_log_l2 {l2}");
    assert_eq!(r["per_view"].as_array().map(Vec::len), Some(48));
    assert_eq!(
        read_json(&out.join("eval.json")),
        r,
        "eval.json differs from stdout"
    );
    std::fs::remove_dir_all(&out).unwrap();
}
