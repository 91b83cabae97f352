//! `bench refine`: the refinement of a few train views of a finished run, with the voxel
//! material cache and with exact queries of the learned field: the time of each, and (because
//! the cache trades accuracy for that time) the relative difference of the shadings, beside the
//! Monte Carlo noise floor of two exact runs.
//!
//! Owns: that benchmark. Must not touch: the refinement.

use crate::pipeline::pixels::PixelStore;
use anyhow::Result;
use fipt_bake::Accel;
use fipt_core::scene::{Dataset, LoadOptions};
use serde_json::json;
use std::path::Path;
use std::time::Instant;

/// Relative RMS difference ‖a − b‖/‖b‖ and mean ratio Σa/Σb of one shading channel group over
/// the hit pixels of some views.
fn shading_difference(
    a: &[Vec<f32>],
    b: &[Vec<f32>],
    channels: std::ops::Range<usize>,
) -> (f64, f64) {
    use fipt_core::shading::ShadingLayout;
    let (mut d2, mut b2, mut sa, mut sb) = (0f64, 0f64, 0f64, 0f64);
    for (va, vb) in a.iter().zip(b) {
        for p in 0..va.len() / ShadingLayout::DIM {
            let (pa, pb) = (ShadingLayout::pixel(va, p), ShadingLayout::pixel(vb, p));
            for c in channels.clone() {
                let (x, y) = (pa[c] as f64, pb[c] as f64);
                d2 += (x - y) * (x - y);
                b2 += y * y;
                sa += x;
                sb += y;
            }
        }
    }
    ((d2 / b2.max(1e-30)).sqrt(), sa / sb.max(1e-30))
}

/// `bench refine`: refines a few train views of a finished `run` (its model, emitters, bake
/// cache and config) with the learned field behind the voxel cache and with exact queries, and
/// twice exactly with two seeds (the Monte Carlo noise floor); reports the time of each and
/// the relative RMS difference of L_d and of L_s0 + L_s1 per roughness level.
pub fn refine(scene: &Path, run: &Path, as_json: bool, views: usize) -> Result<()> {
    use crate::pipeline::{bake::bake_cached, refine};
    use fipt_bake::emitters::Emitter;
    use fipt_core::model::FiptModel;
    use fipt_core::model::step::SegMode;
    use fipt_core::shading::ShadingLayout;
    let cfg = crate::config::Config::load(&run.join("config.json"))?;
    let ds = Dataset::load(
        scene,
        &LoadOptions {
            maps: vec![],
            val: false,
        },
    )?;
    let accel = Accel::build(&ds.mesh);
    let (baked, _) = bake_cached(run, &ds, &accel, &cfg.bake_config(), false)?;
    let store = PixelStore::gather(
        &ds.train,
        &baked,
        &baked.light_field.scene_box,
        SegMode::None,
    );
    let device = cfg.backend.device().map_err(anyhow::Error::msg)?;
    let model = FiptModel::load(&run.join("model"), &device).map_err(anyhow::Error::msg)?;
    #[derive(serde::Deserialize)]
    struct Emitters {
        emitters: Vec<Emitter>,
    }
    let em: Emitters = serde_json::from_str(&std::fs::read_to_string(run.join("emitters.json"))?)?;
    let n = ds.train.views.len();
    let picked: Vec<usize> = (0..views.min(n))
        .map(|i| i * n / views.min(n).max(1))
        .collect();
    let go = |cache: bool, seed: u64| {
        let rcfg = fipt_bake::integrators::refine::RefineConfig {
            seed,
            ..cfg.refine.paths.clone()
        };
        let job = refine::RefineJob {
            ds: &ds,
            accel: &accel,
            baked: &baked,
            light_field: &baked.light_field,
            cfg: &rcfg,
            views: &picked,
            material_cache: cache,
            show_progress: false,
        };
        let t = Instant::now();
        let r = refine::refine(&job, &store, &model, &em.emitters)?;
        Ok::<_, anyhow::Error>((r.shadings, t.elapsed().as_secs_f64()))
    };
    let (cached, t_cached) = go(true, 1)?;
    let (exact, t_exact) = go(false, 1)?;
    let (exact2, t_exact2) = go(false, 2)?;
    let mut rows = Vec::new();
    let mut groups = vec![("L_d".to_string(), ShadingLayout::LD)];
    for j in 0..6 {
        groups.push((format!("L_s0 level {j}"), ShadingLayout::ls0(j)));
        groups.push((format!("L_s1 level {j}"), ShadingLayout::ls1(j)));
    }
    for (name, ch) in groups {
        let (cache_rms, cache_ratio) = shading_difference(&cached, &exact, ch.clone());
        let (noise_rms, noise_ratio) = shading_difference(&exact2, &exact, ch);
        if !as_json {
            println!(
                "{name:<16} voxel cache vs exact: rel. RMS {cache_rms:.4}, mean ratio {cache_ratio:.4}; exact seed 2 vs seed 1: {noise_rms:.4}, {noise_ratio:.4}"
            );
        }
        rows.push(
            json!({"shading": name, "cache_rel_rms": cache_rms, "cache_mean_ratio": cache_ratio,
            "noise_rel_rms": noise_rms, "noise_mean_ratio": noise_ratio}),
        );
    }
    if !as_json {
        println!(
            "views {picked:?}: voxel cache {t_cached:.1} s, exact {t_exact:.1} s and {t_exact2:.1} s"
        );
    } else {
        let r = json!({"bench": "refine", "scene": scene.display().to_string(), "views": picked,
            "time_s": {"voxel_cache": t_cached, "exact": t_exact, "exact_seed2": t_exact2},
            "shadings": rows});
        println!("{}", serde_json::to_string_pretty(&r)?);
    }
    Ok(())
}
