//! The path tracer against Mitsuba on fipt-room, at a small budget: `render --truth` of two val
//! views at 64 spp, and the relit scene of `relight.json`. An unbiased renderer's image mean
//! matches Mitsuba's to within noise, and its PSNR against the 2048-spp `Image` follows from
//! the noise at 64 spp: Mitsuba itself re-rendered at 512 spp scores 35.0 dB mean, and noise
//! power scales as 1/spp, so 64 spp should score about 35.0 − 10·log10(512/64) = 26.0 dB on
//! average and 32.6 − 9.0 = 23.6 dB on Mitsuba's worst view (the reference's own noise only
//! lowers that slightly); the bounds leave 1.5 dB (mean) and 1 dB (each view) for that.

use fipt_bake::emitters::LightSelection;
use fipt_bake::integrators::path::PathConfig;
use fipt_train::render::{RenderJob, render};
use std::path::PathBuf;

fn scene_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/scenes/fipt-room")
}

fn job(out: &str, relight: bool) -> RenderJob {
    RenderJob {
        scene: scene_dir(),
        out: std::env::temp_dir().join(format!("fipt-render-{}-{out}", std::process::id())),
        split: "val".into(),
        views: vec![0, 5],
        relight: relight.then(|| scene_dir().join("relight.json")),
        selection: LightSelection::Power,
        path: PathConfig {
            spp: 64,
            seed: 1,
            ..Default::default()
        },
        quiet: true,
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
