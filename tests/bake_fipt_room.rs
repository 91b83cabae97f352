//! Stage 1 on the Mitsuba reference scene: the factorised render with the ground-truth materials
//! and the baked shadings must reproduce the rendered images.

use fipt_bake::integrators::bake::{BakeConfig, BakeView, bake_views, build_light_field};
use fipt_bake::{Accel, cast_view};
use fipt_core::scene::{Dataset, LoadOptions};
use fipt_train::image_metrics;
use std::path::PathBuf;

fn scene_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../scenes/fipt-room")
}

#[test]
fn gt_render_of_baked_shadings_matches_images() {
    let opts = LoadOptions {
        maps: image_metrics::GT_RENDER_MAPS.to_vec(),
        val: false,
    };
    let ds = Dataset::load(&scene_dir(), &opts).unwrap();
    let accel = Accel::build(&ds.mesh);
    // The bake section of configs/default.json (the reference sample counts and the filter).
    let cfg: BakeConfig = fipt_train::config::Config::load(
        &PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../configs/default.json"),
    )
    .unwrap()
    .bake;
    // L′ from every train view, as the pipeline builds it; the shadings of every third view
    // (16 of 48: the bake is the cost of this test).
    let hits: Vec<_> = ds
        .train
        .views
        .iter()
        .map(|v| cast_view(&accel, &ds.mesh, &v.camera))
        .collect();
    let views: Vec<BakeView> = ds
        .train
        .views
        .iter()
        .zip(&hits)
        .map(|(v, h)| BakeView {
            hits: h,
            image: &v.image.data,
            camera: &v.camera,
        })
        .collect();
    let lf = build_light_field(&views, &ds.mesh, cfg.voxel_res, cfg.fill_rings);
    let picked: Vec<usize> = (0..views.len()).step_by(3).collect();
    let subset: Vec<BakeView> = picked
        .iter()
        .map(|&k| BakeView {
            hits: views[k].hits,
            image: views[k].image,
            camera: views[k].camera,
        })
        .collect();
    let baked = bake_views(&accel, &lf, &subset, &cfg, None, &|_| true).unwrap();
    let scores: Vec<_> = picked
        .iter()
        .zip(&baked.shadings)
        .map(|(&k, s)| image_metrics::gt_render_psnr(&ds.train.views[k], s).unwrap())
        .collect();
    let mean = |f: &dyn Fn(&image_metrics::GtRenderPsnr) -> Option<f64>| {
        let v: Vec<f64> = scores.iter().filter_map(f).collect();
        v.iter().sum::<f64>() / v.len() as f64
    };
    let (all, diff, spec) = (
        mean(&|s| Some(s.all)),
        mean(&|s| s.diffuse),
        mean(&|s| s.specular),
    );
    let worst = scores.iter().map(|s| s.all).fold(f64::INFINITY, f64::min);
    eprintln!(
        "GT render PSNR: all {all:.2} dB, diffuse {diff:.2}, specular {spec:.2}, worst view {worst:.2}"
    );
    // Measured on these 16 views 32.16 / 32.49 dB (one ring of filling, the previous default:
    // 32.06 / 32.38; all 48 views: 31.84 / 32.21). On all 48 views, L′
    // with one mean per voxel (the reference) gave 30.82 / 31.19, with side records but sampling
    // holes left at 0 31.20 / 31.56; the bounds keep the margins they had over those (0.34 /
    // 0.31 dB below the measured figure), so both would fail here.
    assert!(all >= 31.7, "all-pixel PSNR {all:.2}");
    assert!(diff >= 32.05, "diffuse PSNR {diff:.2}");
}
