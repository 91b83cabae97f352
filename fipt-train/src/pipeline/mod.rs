//! The FIPT pipeline (paper Fig. 2), one module per role:
//!
//! - `bake`: L′ and the baked shadings (§4.2, Eq. 9), through the shading cache;
//! - `pixels`: the training pixels as one store;
//! - `fit`: the material field and emission mask (§4.5, Eq. 12, 15–20);
//! - `extract`: emitters from the emission mask (§4.4, Eq. 13);
//! - `predict`: per-view maps of the fitted model; `evaluate`: scores against ground truth.
//!
//! `run` reads as the figure: bake → fit → extract → predict → evaluate. Shading refinement by
//! path tracing (§4.3, Eq. 10–11) does not exist yet, so there is one round.
//!
//! Owns: the order of the stages and the output files of `run` and `eval`. Must not touch:
//! stage internals, argument parsing.

pub mod bake;
pub mod bake_job;
pub mod evaluate;
pub mod extract;
pub mod fit;
pub mod pixels;
pub mod predict;

use crate::config::Config;
use crate::output::{write_json, write_png};
use crate::report::{EvalReport, GridReport, RunReport, StageTimes};
use anyhow::{Context, Result};
use evaluate::{Metrics, PartRow};
use fipt_bake::{Accel, ViewHits, emitters};
use fipt_core::io::peak_rss_mb;
use fipt_core::scene::{Dataset, LoadOptions, MapKind};
use predict::{ViewMaps, predict_view};
use std::path::Path;
use std::time::Instant;

/// The maps FIPT reads, plus BaseColor and Metallic for the per-part table.
fn load_opts() -> LoadOptions {
    let mut maps = MapKind::FIPT.to_vec();
    maps.extend([MapKind::BaseColor, MapKind::Metallic]);
    LoadOptions { maps, val: true }
}

/// Scores the train maps and builds the per-part table.
fn score(
    ds: &Dataset,
    train_hits: &[ViewHits],
    maps: &[ViewMaps],
) -> (Metrics, Option<Vec<PartRow>>) {
    let per_view = ds
        .train
        .views
        .iter()
        .zip(maps)
        .map(|(v, m)| evaluate::score_view(v, m))
        .collect();
    let parts = ds.meta.as_ref().map(|meta| {
        evaluate::part_table(
            meta,
            ds.mesh.num_triangles(),
            &ds.train.views,
            train_hits,
            maps,
        )
    });
    (evaluate::summarize(per_view), parts)
}

/// Seconds since `t`, restarting it.
fn lap(t: &mut Instant) -> f64 {
    let s = t.elapsed().as_secs_f64();
    *t = Instant::now();
    s
}

/// The whole pipeline; returns the report that is also written to `out/metrics.json`.
pub fn run(scene: &Path, out: &Path, cfg: &Config, quiet: bool) -> Result<RunReport> {
    let mut times = StageTimes::default();
    let mut t = Instant::now();
    let ds = Dataset::load(scene, &load_opts())?;
    let accel = Accel::build(&ds.mesh);
    times.load_s = lap(&mut t);
    write_json(&out.join("config.json"), cfg)?;

    // (1) Bake L′ and the shadings.
    let mut bake_cfg = cfg.bake.clone();
    bake_cfg.seed = cfg.seed;
    let (baked, cached) = bake::bake_cached(out, &ds, &accel, &bake_cfg, !quiet)?;
    times.bake_s = lap(&mut t);

    // (2) Fit the material field and the emission mask to the photos.
    let mode = cfg.train.seg_mode(
        ds.train.has_map(MapKind::IndexMA),
        ds.train.has_map(MapKind::Segmentation),
    );
    let scene_box = baked.light_field.scene_box;
    let store = pixels::PixelStore::gather(&ds.train, &baked, &scene_box, mode);
    let device = cfg.backend.device().map_err(anyhow::Error::msg)?;
    let footprint = pixels::pixel_footprint(&ds.train, &baked.hits, &scene_box);
    let grid_levels = cfg.train.grid.levels_for(footprint);
    let plan = fit::FitPlan {
        cfg: cfg.train.model_config(grid_levels),
        scene_box,
        mode,
        epochs: cfg.train.epochs,
        batch: cfg.train.batch,
        seed: cfg.seed,
    };
    let (tr, log) = fit::fit(&store, plan, &device, !quiet);
    tr.model
        .save(&out.join("model"))
        .map_err(anyhow::Error::msg)?;
    times.train_s = lap(&mut t);

    // (3) Extract the emitters.
    let em = extract::extract_emitters(
        &ds.mesh,
        &ds.train,
        &baked,
        &store,
        &tr,
        &cfg.emitters,
        cfg.seed,
    );
    drop(store);
    write_json(
        &out.join("emitters.json"),
        &serde_json::json!({ "emitters": em }),
    )?;
    times.emitters_s = lap(&mut t);

    // (4) Shading refinement by path tracing (§4.3) is not built yet: one round.
    // (5) Predict the maps of every view and score them.
    let emission = emitters::radiance_per_triangle(ds.mesh.num_triangles(), &em);
    let mut train_maps = Vec::new();
    for split in ds.splits() {
        let cast: Vec<ViewHits>;
        let hits: &[ViewHits] = if split.name == "train" {
            &baked.hits
        } else {
            cast = bake::cast_split(&accel, &ds.mesh, split);
            &cast
        };
        for (k, h) in hits.iter().enumerate() {
            let m = predict_view(
                &tr.model,
                h,
                &emission,
                cfg.maps.albedo_samples,
                cfg.seed ^ k as u64,
            );
            m.write(&out.join("maps").join(&split.name), k)?;
            if split.name == "train" {
                train_maps.push(m);
            }
        }
    }
    times.maps_s = lap(&mut t);

    let (metrics, parts) = score(&ds, &baked.hits, &train_maps);
    write_comparisons(&ds, &metrics, &train_maps, out)?;
    let report = RunReport {
        scene: scene.display().to_string(),
        seg_loss: mode,
        bake_from_cache: cached,
        metrics,
        emitters: em.len(),
        grid: GridReport {
            pixel_footprint: footprint,
            levels: grid_levels,
            steps: tr.steps,
        },
        parts,
        train_log: log,
        step_profile: tr.profile,
        time_s: times,
        peak_rss_mb: peak_rss_mb(),
    };
    write_json(&out.join("metrics.json"), &report)?;
    if !quiet {
        report.print(out);
    }
    Ok(report)
}

/// Ground truth vs estimate of the worst and the best train view by k_d PSNR
/// (`out/compare/train_{k}.png`).
fn write_comparisons(ds: &Dataset, metrics: &Metrics, maps: &[ViewMaps], out: &Path) -> Result<()> {
    let by_kd: Vec<(usize, f64)> = metrics
        .per_view
        .iter()
        .enumerate()
        .filter_map(|(k, s)| s.kd_psnr.map(|v| (k, v)))
        .collect();
    let worst = by_kd.iter().min_by(|a, b| a.1.total_cmp(&b.1));
    let best = by_kd.iter().max_by(|a, b| a.1.total_cmp(&b.1));
    std::fs::create_dir_all(out.join("compare"))?;
    for &(k, _) in worst.into_iter().chain(best) {
        let (w, h, rgb) = evaluate::comparison_figure(&ds.train.views[k], &maps[k]);
        write_png(
            &out.join("compare").join(format!("train_{k:03}.png")),
            w,
            h,
            &rgb,
            1.0,
        )?;
    }
    Ok(())
}

/// Recomputes the metrics from `out/maps/train` (written by `run`) into `out/eval.json`.
pub fn eval(scene: &Path, out: &Path) -> Result<EvalReport> {
    let ds = Dataset::load(scene, &load_opts())?;
    let accel = Accel::build(&ds.mesh);
    let dir = out.join("maps").join("train");
    let maps: Vec<ViewMaps> = (0..ds.train.views.len())
        .map(|k| ViewMaps::read(&dir, k))
        .collect::<Result<_>>()
        .with_context(|| {
            format!(
                "{}: predicted maps missing or unreadable (run `fipt-train run` first)",
                dir.display()
            )
        })?;
    for (k, (m, v)) in maps.iter().zip(&ds.train.views).enumerate() {
        if (m.width, m.height) != (v.image.width, v.image.height) {
            anyhow::bail!(
                "{}: the maps of view {k} are {}x{}, the scene's images {}x{}",
                dir.display(),
                m.width,
                m.height,
                v.image.width,
                v.image.height
            );
        }
    }
    let hits = bake::cast_split(&accel, &ds.mesh, &ds.train);
    let (metrics, parts) = score(&ds, &hits, &maps);
    let r = EvalReport { metrics, parts };
    write_json(&out.join("eval.json"), &r)?;
    Ok(r)
}
