//! `fipt-train run`: bake (reusing a valid cache) → stage 2 → emitters → maps → metrics, and
//! `fipt-train eval`, which recomputes the metrics from the saved maps.
//!
//! Owns: the pipeline order, output files and the summary. Must not touch: stage internals.

use crate::config::Config;
use crate::eval::{self, Metrics, PartRow};
use crate::maps::{ViewMaps, predict_view};
use crate::{stage1, stage2};
use anyhow::{Context, Result};
use fipt_bake::emitters::{self, Emitter, ExtractConfig, ObservedView};
use fipt_bake::{Accel, ViewHits};
use fipt_core::io::{peak_rss_mb, write_bytes_atomic};
use fipt_core::scene::{Dataset, LoadOptions, MapKind};
use serde_json::json;
use std::path::Path;
use std::time::Instant;

/// The maps FIPT reads, plus BaseColor and Metallic for the per-part table.
fn load_opts() -> LoadOptions {
    let mut maps = MapKind::FIPT.to_vec();
    maps.extend([MapKind::BaseColor, MapKind::Metallic]);
    LoadOptions { maps, val: true }
}

fn write_json(path: &Path, v: &impl serde::Serialize) -> Result<()> {
    write_bytes_atomic(path, serde_json::to_string_pretty(v)?.as_bytes())?;
    Ok(())
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
        .map(|(v, m)| eval::score_view(v, m))
        .collect();
    let parts = ds.meta.as_ref().map(|meta| {
        eval::part_table(
            meta,
            ds.mesh.num_triangles(),
            &ds.train.views,
            train_hits,
            maps,
        )
    });
    (eval::summarize(per_view), parts)
}

pub fn print_summary(m: &Metrics, parts: Option<&Vec<PartRow>>) {
    let f = |v: Option<f64>, p: usize| v.map_or("-".into(), |x| format!("{x:.p$}"));
    println!("metric            value");
    println!("kd_psnr           {} dB", f(m.kd_psnr, 2));
    println!("albedo_psnr       {} dB", f(m.albedo_psnr, 2));
    println!("roughness_psnr    {} dB", f(m.roughness_psnr, 2));
    println!("emission_iou      {}", f(m.emission_iou, 3));
    println!(
        "emission_log_l2   {}",
        m.emission_log_l2.map_or("-".into(), |x| format!("{x:.3e}"))
    );
    if let Some(parts) = parts {
        println!(
            "\npart                  pixels   a est / true                          σ est/true     m est/true"
        );
        for r in parts {
            println!(
                "{:<20} {:>7}   ({:.2},{:.2},{:.2}) / ({:.2},{:.2},{:.2})   {:.2} / {:.2}    {:.2} / {:.2}",
                r.name,
                r.pixels,
                r.a_est[0],
                r.a_est[1],
                r.a_est[2],
                r.a_true[0],
                r.a_true[1],
                r.a_true[2],
                r.sigma_est,
                r.sigma_true,
                r.m_est,
                r.m_true
            );
        }
    }
}

/// The whole pipeline; returns the metrics JSON that is also written to `out/metrics.json`.
pub fn run(scene: &Path, out: &Path, cfg: &Config, quiet: bool) -> Result<serde_json::Value> {
    let mut times = serde_json::Map::new();
    let t = Instant::now();
    let ds = Dataset::load(scene, &load_opts())?;
    let accel = Accel::build(&ds.mesh);
    times.insert("load_s".into(), json!(t.elapsed().as_secs_f64()));
    write_json(&out.join("config.json"), cfg)?;

    let t = Instant::now();
    let mut bake_cfg = cfg.bake.clone();
    bake_cfg.seed = cfg.seed;
    let (baked, cached) = stage1::bake_cached(out, &ds, &accel, &bake_cfg, !quiet)?;
    times.insert("bake_s".into(), json!(t.elapsed().as_secs_f64()));

    let t = Instant::now();
    let mode = cfg.train.seg_mode(
        ds.train.has_map(MapKind::IndexMA),
        ds.train.has_map(MapKind::Segmentation),
    );
    let sb = baked.light_field.scene_box;
    let store = stage2::PixelStore::gather(&ds.train, &baked, &sb, mode);
    let device = cfg.backend.device().map_err(anyhow::Error::msg)?;
    let footprint = stage2::pixel_footprint(&ds.train, &baked.hits, &sb);
    let grid_levels = cfg.train.grid.levels_for(footprint);
    let (tr, log) = stage2::train(
        &store,
        cfg.train.model_config(grid_levels),
        &device,
        mode,
        cfg.train.epochs,
        cfg.train.batch,
        cfg.seed,
        !quiet,
    );
    tr.save(&out.join("model")).map_err(anyhow::Error::msg)?;
    times.insert("train_s".into(), json!(t.elapsed().as_secs_f64()));

    // Emitters: the reflected radiance is only needed for the extraction rule.
    let t = Instant::now();
    let sizes: Vec<usize> = baked.hits.iter().map(|h| h.num_pixels()).collect();
    let reflected = stage2::reflected(&tr, &store, &sizes);
    drop(store);
    let views: Vec<ObservedView> = baked
        .hits
        .iter()
        .zip(&ds.train.views)
        .zip(&reflected)
        .map(|((hits, v), r)| ObservedView {
            hits,
            image: v.image.data.as_slice(),
            reflected: r,
        })
        .collect();
    let em: Vec<Emitter> = emitters::extract(
        &ds.mesh,
        &mut |p| tr.alpha(p),
        &views,
        &ExtractConfig {
            samples_per_triangle: cfg.emitters.samples_per_triangle,
            threshold: cfg.emitters.threshold,
            min_unexplained: cfg.emitters.min_unexplained,
            seed: cfg.seed,
        },
    );
    write_json(&out.join("emitters.json"), &json!({"emitters": em}))?;
    times.insert("emitters_s".into(), json!(t.elapsed().as_secs_f64()));

    let t = Instant::now();
    let emission = emitters::radiance_per_triangle(ds.mesh.num_triangles(), &em);
    let mut train_maps = Vec::new();
    for split in ds.splits() {
        let cast: Vec<ViewHits>;
        let hits: &[ViewHits] = if split.name == "train" {
            &baked.hits
        } else {
            cast = stage1::cast_split(&accel, &ds.mesh, split);
            &cast
        };
        for (k, h) in hits.iter().enumerate() {
            let m = predict_view(
                &tr,
                &sb,
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
    times.insert("maps_s".into(), json!(t.elapsed().as_secs_f64()));

    let (metrics, parts) = score(&ds, &baked.hits, &train_maps);
    // Ground truth vs estimate of the worst and the best view by k_d PSNR.
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
        let (w, h, rgb) = eval::comparison_figure(&ds.train.views[k], &train_maps[k]);
        crate::cache::write_png(
            &out.join("compare").join(format!("train_{k:03}.png")),
            w,
            h,
            &rgb,
            1.0,
        )?;
    }
    let report = json!({
        "scene": scene.display().to_string(),
        "seg_loss": format!("{mode:?}").to_lowercase(),
        "bake_from_cache": cached,
        "metrics": &metrics,
        "kd_psnr": metrics.kd_psnr, "albedo_psnr": metrics.albedo_psnr, "roughness_psnr": metrics.roughness_psnr,
        "emission_iou": metrics.emission_iou, "emission_log_l2": metrics.emission_log_l2,
        "emitters": em.len(),
        "grid": json!({"pixel_footprint": footprint, "levels": grid_levels, "steps": tr.steps}),
        "parts": parts,
        "train_log": log,
        "step_profile": tr.profile,
        "time_s": times,
        "peak_rss_mb": peak_rss_mb(),
    });
    write_json(&out.join("metrics.json"), &report)?;
    if !quiet {
        print_summary(&metrics, parts.as_ref());
        println!("\nstage times {}", serde_json::Value::Object(times));
        println!(
            "peak RSS {:.0} MB; outputs in {}",
            peak_rss_mb().unwrap_or(0.0),
            out.display()
        );
    }
    Ok(report)
}

/// Recomputes the metrics from `out/maps/train` (written by `run`).
pub fn eval(scene: &Path, out: &Path) -> Result<serde_json::Value> {
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
    let hits = stage1::cast_split(&accel, &ds.mesh, &ds.train);
    let (metrics, parts) = score(&ds, &hits, &maps);
    print_summary(&metrics, parts.as_ref());
    let r = json!({"metrics": &metrics, "kd_psnr": metrics.kd_psnr, "albedo_psnr": metrics.albedo_psnr,
        "roughness_psnr": metrics.roughness_psnr, "emission_iou": metrics.emission_iou,
        "emission_log_l2": metrics.emission_log_l2, "parts": parts});
    write_json(&out.join("eval.json"), &r)?;
    Ok(r)
}
