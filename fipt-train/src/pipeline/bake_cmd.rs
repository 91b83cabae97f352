//! `fipt-train bake`: the bake alone, with cache, EXR/PNG outputs and, where the scene has
//! ground-truth materials, the check that the factorised render reproduces the photos.
//!
//! The outputs are complete or absent: OUT is locked against a second writer, `shading/` is
//! written into a staged folder that replaces the old one whole, and `bake.json` (written last,
//! removed before anything else is replaced) marks a complete set. Ctrl-C stops the bake itself
//! (nothing of it is written); once the outputs are being written they are finished first (and
//! the command then exits 130, see `main`).
//!
//! Owns: the command's outputs (`bake.json`, previews). Must not touch: the estimators.

use super::bake;
use crate::config::Config;
use crate::output::{write_json, write_png};
use crate::pipeline::report::{BakeReport, GtRenderSummary, LightFieldReport};
use crate::{cache, image_metrics};
use anyhow::Result;
use fipt_bake::Accel;
use fipt_core::scene::{Dataset, LoadOptions};
use fipt_core::shading::ShadingLayout;
use std::path::Path;
use std::time::Instant;

/// Bakes the scene's training views into `out` and writes `out/bake.json`.
pub fn bake_job(scene: &Path, out: &Path, cfg: &Config, quiet: bool) -> Result<BakeReport> {
    let t0 = Instant::now();
    let opts = LoadOptions {
        maps: image_metrics::GT_RENDER_MAPS.to_vec(),
        val: false,
    };
    let ds = Dataset::load(scene, &opts)?;
    let _lock = crate::lock::DirLock::acquire(out)?;
    crate::pipeline::checkpoint::remove_stale_tmp(out);
    let accel = Accel::build(&ds.mesh);
    let bake_cfg = cfg.bake_config();
    let t1 = Instant::now();
    let (baked, cached) = bake::bake_cached(out, &ds, &accel, &bake_cfg, !quiet).map_err(|e| {
        crate::interrupt::reword(e, || {
            format!(
                "interrupted during the bake; {} is as it was",
                out.display()
            )
        })
    })?;
    let bake_s = t1.elapsed().as_secs_f64();
    let (w, h) = (ds.train.width, ds.train.height);
    // From here on the old set is replaced: first its marker goes.
    let marker = out.join("bake.json");
    crate::output::remove_file_if_present(&marker)?;
    crate::output::staged_dir(&out.join("shading"), |dir| {
        cache::write_exrs(dir, w, h, &baked.shadings)?;
        for (k, s) in baked.shadings.iter().enumerate() {
            let ld: Vec<f32> = (0..w * h)
                .flat_map(|p| ShadingLayout::pixel(s, p)[ShadingLayout::LD].to_vec())
                .collect();
            write_png(
                &dir.join("preview").join(format!("{k:03}_diffuse.png")),
                w,
                h,
                &ld,
                1.0,
            )?;
        }
        Ok(())
    })?;
    remove_view_pngs(out)?;
    let scores: Vec<Option<image_metrics::GtRenderPsnr>> = ds
        .train
        .views
        .iter()
        .zip(&baked.shadings)
        .map(|(v, s)| image_metrics::gt_render_psnr(v, s))
        .collect();
    let gt = if scores.iter().all(|s| s.is_some()) {
        let s: Vec<image_metrics::GtRenderPsnr> = scores.into_iter().flatten().collect();
        let mean = |f: &dyn Fn(&image_metrics::GtRenderPsnr) -> Option<f64>| {
            let v: Vec<f64> = s.iter().filter_map(f).collect();
            (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
        };
        let worst = (0..s.len())
            .min_by(|&a, &b| s[a].all.total_cmp(&s[b].all))
            .unwrap_or(0);
        // The worst view's error image: |Γ(pred) − Γ(photo)| × 4.
        let view = &ds.train.views[worst];
        if let Some(pred) = image_metrics::gt_render(view, &baked.shadings[worst]) {
            let err: Vec<f32> = pred
                .iter()
                .zip(&view.image.data)
                .map(|(a, b)| {
                    ((image_metrics::gamma(*a) - image_metrics::gamma(*b)).abs() * 4.0).powf(2.2)
                })
                .collect();
            write_png(
                &out.join(format!("bake_error_view{worst:03}.png")),
                w,
                h,
                &err,
                1.0,
            )?;
            write_png(
                &out.join(format!("bake_render_view{worst:03}.png")),
                w,
                h,
                &pred,
                1.0,
            )?;
            write_png(
                &out.join(format!("bake_photo_view{worst:03}.png")),
                w,
                h,
                &view.image.data,
                1.0,
            )?;
        }
        Some(GtRenderSummary {
            mean_all_db: mean(&|x| Some(x.all)).unwrap_or(f64::NAN),
            mean_diffuse_db: mean(&|x| x.diffuse),
            mean_specular_db: mean(&|x| x.specular),
            worst_view: worst,
            worst_view_db: s[worst].all,
            per_view: s,
        })
    } else {
        None
    };
    let rays = (!cached).then_some(baked.rays);
    let report = BakeReport {
        scene: scene.display().to_string(),
        views: ds.train.views.len(),
        from_cache: cached,
        bake_s,
        total_s: t0.elapsed().as_secs_f64(),
        secondary_rays: rays,
        rays_per_s: rays.map(|r| r as f64 / bake_s),
        light_field: LightFieldReport {
            res: bake_cfg.voxel_res,
            occupied_voxels: baked.light_field.occupied(),
            filled_voxels: baked.light_field.filled(),
            memory_mb: baked.light_field.memory_bytes() as f64 / 1048576.0,
        },
        peak_rss_mb: fipt_core::io::peak_rss_mb(),
        gt_render_psnr: gt,
        config: bake_cfg,
    };
    write_json(&marker, &report)?;
    Ok(report)
}

/// Removes the `bake_{error,render,photo}_viewNNN.png` of an earlier bake (whose worst view may
/// differ from this one's).
fn remove_view_pngs(out: &Path) -> Result<()> {
    for e in std::fs::read_dir(out).into_iter().flatten().flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let old = ["bake_error_view", "bake_render_view", "bake_photo_view"]
            .iter()
            .any(|p| name.starts_with(p))
            && name.ends_with(".png");
        if old {
            crate::output::remove_file_if_present(&e.path())?;
        }
    }
    Ok(())
}
