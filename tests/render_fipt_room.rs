//! The path tracer against Mitsuba on fipt-room, at a small budget: `render --truth` of two val
//! views at 64 spp, and the relit scene of `relight.json`. An unbiased renderer's image mean
//! matches Mitsuba's to within noise, and its PSNR against the 2048-spp `Image` follows from
//! the noise at 64 spp: Mitsuba itself re-rendered at 512 spp scores 35.0 dB mean, and noise
//! power scales as 1/spp, so 64 spp should score about 35.0 − 10·log10(512/64) = 26.0 dB on
//! average and 32.6 − 9.0 = 23.6 dB on Mitsuba's worst view (the reference's own noise only
//! lowers that slightly); the bounds leave 1.5 dB (mean) and 1 dB (each view) for that.

use fipt_bake::emitters::LightSelection;
use fipt_bake::integrators::path::PathConfig;
use fipt_train::rerender::{RenderJob, render};
use std::path::PathBuf;

fn scene_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../scenes/fipt-room")
}

fn job(out: &str, relight: bool) -> RenderJob {
    RenderJob {
        scene: Some(scene_dir()),
        source: fipt_train::rerender::Source::Truth,
        insert: None,
        cache: false,
        material_cache: false,
        off_reflect: false,
        out: std::env::temp_dir().join(format!("fipt-render-{}-{out}", std::process::id())),
        split: "val".into(),
        views: vec![0, 5],
        cameras: None,
        relight: relight.then(|| scene_dir().join("relight.json")),
        selection: LightSelection::Power,
        path: PathConfig {
            spp: 64,
            seed: 1,
            ..Default::default()
        },
        quiet: true,
        backend: fipt_core::model::BackendKind::Flex,
    }
}

/// 10·log10(512/64).
const SPP_DB: f64 = 9.03;
const MEAN_BOUND_DB: f64 = 35.0 - SPP_DB - 1.5;
const VIEW_BOUND_DB: f64 = 32.6 - SPP_DB - 1.0;
/// Relit: Mitsuba at 512 spp scores 44.2 dB mean against `Relight/`.
const RELIGHT_MEAN_BOUND_DB: f64 = 44.2 - SPP_DB - 1.5;

#[test]
fn truth_renders_agree_with_mitsuba() {
    for (relight, min_ratio_err) in [(false, 0.02), (true, 0.03)] {
        let j = job(if relight { "relight" } else { "image" }, relight);
        let r = render(&j).unwrap();
        eprintln!(
            "relight {relight}: {:?}, {:.2} M paths/s",
            r.views
                .iter()
                .map(|v| (v.view, v.psnr_db.unwrap(), v.mean_ratio.unwrap()))
                .collect::<Vec<_>>(),
            r.paths_per_s / 1e6
        );
        assert_eq!(r.stats.nonfinite, 0);
        for v in &r.views {
            let (p, m) = (v.psnr_db.unwrap(), v.mean_ratio.unwrap());
            assert!(
                (m - 1.0).abs() <= min_ratio_err,
                "view {}: mean ratio {m:.4}",
                v.view
            );
            assert!(
                p >= VIEW_BOUND_DB,
                "view {}: PSNR {p:.2} < {VIEW_BOUND_DB:.2}",
                v.view
            );
        }
        let mean = r.mean_psnr_db.unwrap();
        let bound = if relight {
            RELIGHT_MEAN_BOUND_DB
        } else {
            MEAN_BOUND_DB
        };
        assert!(mean >= bound, "mean PSNR {mean:.2} < {bound:.2}");
        let folder = if relight { "Relight" } else { "Image" };
        assert!(
            j.out
                .join("val")
                .join(folder)
                .join("005_0001.exr")
                .is_file()
        );
        assert!(j.out.join("render.json").is_file());
        let _ = std::fs::remove_dir_all(&j.out);
    }
}

/// A copy of fipt-room (links to its folders and mesh, a copy of `scene_meta.json` and
/// `relight.json`) that a test may break.
fn scene_copy(name: &str) -> PathBuf {
    let src = scene_dir();
    let d = std::env::temp_dir().join(format!("fipt-render-bad-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(d.join("textures")).unwrap();
    for f in ["train", "val", "scene.obj"] {
        std::os::unix::fs::symlink(src.join(f), d.join(f)).unwrap();
    }
    for f in ["scene_meta.json", "relight.json"] {
        std::fs::copy(src.join(f), d.join(f)).unwrap();
    }
    for e in std::fs::read_dir(src.join("textures")).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), d.join("textures").join(e.file_name())).unwrap();
    }
    d
}

/// Runs `render --truth` (1 spp, view 0); expects exit 1, a stderr naming `needle`, and no
/// image in the output folder.
fn assert_render_fails(scene: &std::path::Path, relight: bool, needles: &[&str]) {
    let out = scene.join("out");
    let mut cmd = std::process::Command::new(env!("CARGO_BIN_EXE_fipt-train"));
    cmd.args([
        "render", "--truth", "--spp", "1", "--views", "0", "--json", "--scene",
    ])
    .arg(scene)
    .arg("--out")
    .arg(&out);
    if relight {
        cmd.arg("--relight").arg(scene.join("relight.json"));
    }
    let o = cmd.output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    for n in needles {
        assert!(err.contains(n), "stderr lacks '{n}': {err}");
    }
    assert!(!out.join("val").exists(), "a failed render wrote images");
}

#[test]
fn bad_render_input_is_named() {
    // Malformed relight.json, and one that switches off a part that is not an emitter.
    let d = scene_copy("relight");
    std::fs::write(d.join("relight.json"), "{\"emitters_off\": [").unwrap();
    assert_render_fails(&d, true, &["relight.json", "bad JSON"]);
    std::fs::write(d.join("relight.json"), r#"{"emitters_off": ["floor"]}"#).unwrap();
    assert_render_fails(&d, true, &["relight.json", "floor"]);
    std::fs::write(
        d.join("relight.json"),
        r#"{"emitters_scale": {"lamp": -1}}"#,
    )
    .unwrap();
    assert_render_fails(&d, true, &["relight.json", "lamp"]);
    // A missing texture.
    let d = scene_copy("texture");
    std::fs::remove_file(d.join("textures/floor_planks.exr")).unwrap();
    assert_render_fails(&d, false, &["floor_planks.exr"]);
    // Part ranges that leave triangles uncovered.
    let d = scene_copy("ranges");
    let p = d.join("scene_meta.json");
    let mut meta: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
    meta["parts"][0]["triangles"][1] = serde_json::json!(2);
    std::fs::write(&p, meta.to_string()).unwrap();
    assert_render_fails(&d, false, &["scene_meta.json", "belongs to no part"]);
    for n in ["relight", "texture", "ranges"] {
        let _ = std::fs::remove_dir_all(
            std::env::temp_dir().join(format!("fipt-render-bad-{n}-{}", std::process::id())),
        );
    }
}

/// `--cameras val/transforms.json` renders the very cameras of the val split: the same image
/// bit for bit (same seed and view index), written under `cameras/`, unscored.
#[test]
fn cameras_file_gives_the_split_cameras() {
    let mut a = job("split", false);
    a.views = vec![5];
    a.path.spp = 4;
    let mut b = a.clone();
    b.out = a.out.with_extension("cams");
    b.cameras = Some(scene_dir().join("val/transforms.json"));
    let (ra, rb) = (render(&a).unwrap(), render(&b).unwrap());
    assert!(ra.views[0].psnr_db.is_some() && rb.views[0].psnr_db.is_none());
    let read = |p: PathBuf| fipt_core::scene::Image::read_exr(&p).unwrap().data;
    assert_eq!(
        read(a.out.join("val/Image/005_0001.exr")),
        read(b.out.join("cameras/Image/005_0001.exr"))
    );
    for d in [a.out, b.out] {
        let _ = std::fs::remove_dir_all(d);
    }
}

/// Rescaling every emitter by 2 (`emitters_scale: {"all": 2}`) doubles the image exactly: the
/// same paths (power-weighted light selection is scale-free), twice the radiance.
#[test]
fn rescaled_emitters_scale_the_image() {
    let mut a = job("scale", false);
    a.views = vec![5];
    a.path.spp = 4;
    let mut b = a.clone();
    b.out = a.out.with_extension("x2");
    let file = b.out.with_extension("json");
    std::fs::create_dir_all(&b.out).unwrap();
    std::fs::write(&file, r#"{"emitters_scale": {"all": 2}}"#).unwrap();
    b.relight = Some(file.clone());
    render(&a).unwrap();
    render(&b).unwrap();
    let read = |p: PathBuf| fipt_core::scene::Image::read_exr(&p).unwrap().data;
    let (x, y) = (
        read(a.out.join("val/Image/005_0001.exr")),
        read(b.out.join("val/Relight/005_0001.exr")),
    );
    assert!(x.iter().any(|&v| v > 0.0));
    for (p, q) in x.iter().zip(&y) {
        assert!((2.0 * p - q).abs() <= 1e-5 * q.abs().max(1e-3), "{p} {q}");
    }
    for d in [a.out, b.out] {
        let _ = std::fs::remove_dir_all(d);
    }
    let _ = std::fs::remove_file(file);
}
