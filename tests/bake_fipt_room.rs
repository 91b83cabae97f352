//! Stage 1 on the Mitsuba reference scene: the factorised render with the ground-truth materials
//! and the baked shadings must reproduce the rendered images.

use fipt_bake::Accel;
use fipt_bake::integrators::bake::BakeConfig;
use fipt_core::scene::{Dataset, LoadOptions};
use fipt_train::metrics;
use fipt_train::pipeline::bake;
use std::path::PathBuf;

fn scene_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/scenes/fipt-room")
}

#[test]
fn gt_render_of_baked_shadings_matches_images() {
    let opts = LoadOptions {
        maps: metrics::GT_RENDER_MAPS.to_vec(),
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
    let baked = bake::bake(&accel, &ds.mesh, &ds.train, &cfg, false);
    let scores: Vec<_> = ds
        .train
        .views
        .iter()
        .zip(&baked.shadings)
        .map(|(v, s)| metrics::gt_render_psnr(v, s).unwrap())
        .collect();
    let mean = |f: &dyn Fn(&metrics::GtRenderPsnr) -> Option<f64>| {
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
    // Measured 31.84 / 32.21 dB. L′ with one mean per voxel (the reference) gives 30.82 /
    // 31.19, with side records but sampling holes left at 0 31.20 / 31.56: both fail here.
    assert!(all >= 31.5, "all-pixel PSNR {all:.2}");
    assert!(diff >= 31.9, "diffuse PSNR {diff:.2}");
}
