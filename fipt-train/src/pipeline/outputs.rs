//! The last stage of `run` (paper Fig. 2, right): the recovered scene's maps of every view and
//! their scores, the val views re-rendered and relit, and what a user keeps: the scene model,
//! `metrics.json`, the zoo entry and the HTML report.
//!
//! Owns: the output folders `maps/`, `compare/`, `render/`, `model/` and the files
//! `emitters.json`, `metrics.json`. Must not touch: the fit, the renderer's maths.

use super::bake::{Baked, cast_split};
use super::context::RunContext;
use super::evaluate::{self, Metrics, PartRow};
use super::predict::{ViewMaps, for_each_view};
use super::report::{GridReport, RoundReport, RunReport, ValRenders};
use super::rounds::{FitSetup, Fitted};
use super::score::score;
use crate::output::{staged_dir, write_json, write_png};
use crate::rerender::{CamRef, Edits, Recovered, RecoveredOptions, ViewRender, render_recovered};
use anyhow::Result;
use fipt_bake::integrators::path::PathConfig;
use fipt_bake::{ViewHits, emitters};
use fipt_core::io::peak_rss_mb;
use fipt_core::scene::{Dataset, Image, MapKind, View};
use std::path::Path;

/// The maps of every view of every split, predicted with the last fit into a staged folder that
/// replaces `maps/` whole, and the train maps' scores (the last round's report, and the
/// worst and best train view side by side with the truth in `compare/`).
pub fn maps(
    ctx: &mut RunContext,
    baked: &Baked,
    fitted: &mut Fitted,
) -> Result<(Metrics, Option<Vec<PartRow>>)> {
    write_json(
        &ctx.out.join("emitters.json"),
        &serde_json::json!({ "emitters": fitted.emitters }),
    )?;
    let emission = emitters::radiance_per_triangle(ctx.ds.mesh.num_triangles(), &fitted.emitters);
    ctx.check("after the fits")?;
    let model = &fitted.trainer.model;
    let mut train_maps = Vec::new();
    staged_dir(&ctx.out.join("maps"), |dir| {
        for split in ctx.ds.splits() {
            let cast: Vec<ViewHits>;
            let hits: &[ViewHits] = if split.name == "train" {
                &baked.hits
            } else {
                cast = cast_split(&ctx.accel, &ctx.ds.mesh, split);
                &cast
            };
            for_each_view(model, hits, &emission, ctx.cfg, |k, m| {
                ctx.check("during the maps (they restart)")?;
                m.write(&dir.join(&split.name), k)?;
                if split.name == "train" {
                    train_maps.push(m);
                }
                Ok(())
            })?;
        }
        Ok(())
    })?;
    ctx.times.maps_s = ctx.lap();
    let (metrics, parts) = score(&ctx.ds, &baked.hits, &train_maps);
    let last = fitted.reports.len();
    let work = std::mem::take(&mut fitted.work);
    let report = RoundReport::new(
        last,
        &metrics,
        parts.clone(),
        &fitted.trainer,
        &fitted.log,
        work,
    );
    fitted.reports.push(report);
    write_comparisons(&ctx.ds, &metrics, &train_maps, ctx.out)?;
    Ok((metrics, parts))
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
    staged_dir(&out.join("compare"), |dir| {
        for &(k, _) in worst.into_iter().chain(best) {
            let (w, h, rgb) = evaluate::comparison_figure(&ds.train.views[k], &maps[k]);
            write_png(&dir.join(format!("train_{k:03}.png")), w, h, &rgb, 1.0)?;
        }
        Ok(())
    })
}

/// The recovered scene as the renderer reads it.
fn recovered<'a>(ctx: &'a RunContext, baked: &'a Baked, fitted: &'a Fitted) -> Recovered<'a> {
    Recovered {
        model: &fitted.trainer.model,
        mesh: &ctx.ds.mesh,
        emitters: &fitted.emitters,
        light_field: &baked.light_field,
    }
}

/// View synthesis of the val views against `val/Image` and, where the scene has
/// `relight.json` and `val/Relight`, relighting against them, into a staged folder that
/// replaces `render/` whole (None without val views or with `render.val` off).
pub fn render_val(
    ctx: &mut RunContext,
    baked: &Baked,
    fitted: &Fitted,
) -> Result<Option<ValRenders>> {
    let renders = if ctx.cfg.render.val {
        let rec = recovered(ctx, baked, fitted);
        render_val_views(ctx, &rec)
            .map_err(|e| ctx.reword(e, "during the re-renders (they restart)"))?
    } else {
        None
    };
    ctx.times.render_s = ctx.lap();
    Ok(renders)
}

fn render_val_views(ctx: &RunContext, rec: &Recovered) -> Result<Option<ValRenders>> {
    let Some(val) = &ctx.ds.val else {
        return Ok(None);
    };
    let rc = &ctx.cfg.render;
    let path = PathConfig {
        spp: rc.spp,
        max_depth: rc.max_depth,
        seed: ctx.seeds.base(),
        pixel_positions: rc.pixel_positions,
        ..Default::default()
    };
    let opts = RecoveredOptions {
        selection: fipt_bake::emitters::LightSelection::Power,
        cache: rc.cache,
        material_cache: rc.material_cache,
        off_reflect: rc.off_reflect,
    };
    let quiet = !ctx.progress();
    staged_dir(&ctx.out.join("render"), |staged| {
        let dir = staged.join("val");
        // Every val camera with its reference: the photo, or the relit photo.
        let cams_with = |reference: &dyn Fn(&View) -> Option<&Image>| -> Vec<CamRef> {
            let views = val.views.iter().enumerate();
            views
                .map(|(k, v)| (k, v.camera.clone(), reference(v)))
                .collect()
        };
        let cams = cams_with(&|v| Some(&v.image));
        let picked: Vec<&CamRef> = cams.iter().collect();
        let none = Edits::default();
        let view =
            render_recovered(rec, &none, &picked, &path, &opts, &dir.join("Image"), quiet)?.views;
        let relight_path = ctx.scene.join("relight.json");
        let relight = if relight_path.is_file() && val.has_map(MapKind::Relight) {
            let r = fipt_core::scene::meta::Relight::load(&relight_path, ctx.ds.meta.as_ref())?;
            let cams = cams_with(&|v| v.map(MapKind::Relight));
            let picked: Vec<&CamRef> = cams.iter().collect();
            let edits = Edits {
                relight: Some(&r),
                meta: ctx.ds.meta.as_ref(),
                inserted: &[],
            };
            let path = PathConfig {
                spp: rc.relight_spp,
                ..path
            };
            render_recovered(
                rec,
                &edits,
                &picked,
                &path,
                &opts,
                &dir.join("Relight"),
                quiet,
            )?
            .views
        } else {
            Vec::new()
        };
        write_val_sheet(&ctx.ds, &dir)?;
        Ok(Some(ValRenders {
            spp: rc.spp,
            relight_spp: rc.relight_spp,
            cache: rc.cache,
            view,
            relight,
        }))
    })
}

/// The contact sheet of the val renders in `dir`: per val view, photo | re-render | relit
/// photo | relit re-render.
fn write_val_sheet(ds: &Dataset, dir: &Path) -> Result<()> {
    let Some(val) = &ds.val else {
        return Ok(());
    };
    let read = |folder: &str, k: usize| {
        fipt_core::scene::Image::read_exr(&dir.join(folder).join(format!("{k:03}_0001.exr")))
            .ok()
            .map(|i| i.data)
    };
    let tiles: Vec<[Option<Vec<f32>>; 2]> = (0..val.views.len())
        .map(|k| [read("Image", k), read("Relight", k)])
        .collect();
    let rows: Vec<Vec<Option<&[f32]>>> = val
        .views
        .iter()
        .zip(&tiles)
        .map(|(v, [img, relit])| {
            vec![
                Some(v.image.data.as_slice()),
                img.as_deref(),
                v.map(MapKind::Relight).map(|r| r.data.as_slice()),
                relit.as_deref(),
            ]
        })
        .collect();
    crate::output::write_sheet(&dir.join("sheet.png"), val.width, val.height, &rows)
}

/// The run's report (what `metrics.json` holds); takes the rounds' reports and the last loss
/// log out of `fitted`.
pub fn run_report(
    ctx: &RunContext,
    setup: &FitSetup,
    bake_from_cache: bool,
    fitted: &mut Fitted,
    (metrics, parts): (Metrics, Option<Vec<PartRow>>),
    renders: Option<ValRenders>,
) -> RunReport {
    let scored = |v: &[ViewRender]| {
        crate::rerender::mean(&v.iter().filter_map(|r| r.psnr_db).collect::<Vec<_>>())
    };
    let tr = &fitted.trainer;
    let renders_done = renders.is_some();
    RunReport {
        scene: ctx.scene.display().to_string(),
        seg_loss: setup.mode,
        bake_from_cache,
        metrics,
        emitters: fitted.emitters.len(),
        grid: GridReport {
            pixel_footprint: setup.footprint,
            levels: setup.grid_levels,
            steps: tr.steps,
            place: if tr.device_resident() {
                "device"
            } else {
                "host"
            }
            .into(),
        },
        parts,
        rounds: std::mem::take(&mut fitted.reports),
        train_log: std::mem::take(&mut fitted.log),
        step_profile: tr.profile,
        time_s: ctx.times.clone(),
        peak_rss_mb: peak_rss_mb(),
        view_psnr: renders.as_ref().and_then(|r| scored(&r.view)),
        relight_psnr: renders.as_ref().and_then(|r| scored(&r.relight)),
        renders,
        model_dir: None,
        zoo_entry: None,
        resumed: fitted.resumed.take(),
        ldr: ctx.ldr.as_ref().map(|cal| {
            crate::ldr::report::LdrReport::new(
                cal,
                ctx.light_solve.clone(),
                fitted.light_resolve.clone(),
                ctx.ds.val.as_ref().filter(|_| renders_done),
                &ctx.out.join("render").join("val"),
                ctx.scene,
            )
        }),
    }
}

/// What a user keeps: the scene model (everything recovered, in one folder that renders
/// without the photos), `metrics.json`, the zoo entry and the HTML report.
pub fn save(
    ctx: &RunContext,
    baked: &Baked,
    fitted: &Fitted,
    report: &mut RunReport,
) -> Result<()> {
    ctx.check("before the scene model was saved")?;
    let rec = recovered(ctx, baked, fitted);
    let (out, cfg, scene) = (ctx.out, ctx.cfg, ctx.scene);
    let model_dir = out.join("model");
    let name = ctx
        .opts
        .zoo
        .as_ref()
        .map_or_else(|| default_model_name(scene, cfg.seed), |(_, n)| n.clone());
    report.model_dir = Some(model_dir.display().to_string());
    if let Some((zoo, _)) = &ctx.opts.zoo {
        report.zoo_entry = Some(zoo.join(&name).display().to_string());
    }
    let m = &report.metrics;
    crate::scene_model::save(
        &model_dir,
        rec.model,
        rec.mesh,
        rec.emitters,
        rec.light_field,
        &crate::scene_model::SaveInfo {
            name: &name,
            scene,
            image_size: [ctx.ds.train.width, ctx.ds.train.height],
            seed: cfg.seed,
            metrics: crate::scene_model::Headline {
                kd_psnr: m.kd_psnr,
                albedo_psnr: m.albedo_psnr,
                roughness_psnr: m.roughness_psnr,
                emission_iou: m.emission_iou,
                view_psnr: report.view_psnr,
                relight_psnr: report.relight_psnr,
            },
            config: &serde_json::to_value(cfg)?,
            run_metrics: &serde_json::to_value(&*report)?,
        },
    )?;
    write_json(&out.join("metrics.json"), &*report)?;
    if let Some((zoo, name)) = &ctx.opts.zoo {
        crate::zoo::Zoo::new(zoo).register(&model_dir, name)?;
    }
    let page = crate::html_report::write(scene, out)?;
    if ctx.progress() {
        report.print(out);
        println!("report: {}", page.display());
    }
    Ok(())
}

/// The default name of a scene's model: the scene folder's name and the seed.
pub fn default_model_name(scene: &Path, seed: u64) -> String {
    let base: String = std::path::absolute(scene)
        .ok()
        .and_then(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
        .unwrap_or_else(|| "scene".into())
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.') {
                c
            } else {
                '_'
            }
        })
        .collect();
    format!("{}-s{seed}", base.trim_start_matches('.'))
}
