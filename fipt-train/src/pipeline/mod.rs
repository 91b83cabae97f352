//! The FIPT pipeline (paper Fig. 2), one module per role:
//!
//! - `bake`: L′ and the baked shadings (§4.2, Eq. 9), through the shading cache;
//! - `pixels`: the training pixels as one store;
//! - `fit`: the material field and emission mask (§4.5, Eq. 12, 15–20); `hop`: a basin hop on
//!   the roughness after each fit (a departure, `train.hop`);
//! - `extract`: emitters from the emission mask (§4.4, Eq. 13);
//! - `predict`: per-view maps of the fitted model; `evaluate`: scores against ground truth.
//!
//! - `refine`: the shadings path-traced with the current estimate (§4.3, Eq. 10–11);
//! - `checkpoint`: the fits' saved state, so that a killed run resumes.
//!
//! `run` reads as the figure: bake → fit → extract → (refine → fit) × rounds → predict →
//! evaluate.
//!
//! Owns: the order of the stages and the output files of `run` and `eval`. Must not touch:
//! stage internals, argument parsing.

pub mod bake;
pub mod bake_job;
pub mod checkpoint;
pub mod evaluate;
pub mod extract;
pub mod fit;
pub mod hop;
pub mod landscape;
pub mod pixels;
pub mod predict;
pub mod refine;

use crate::config::Config;
use crate::output::{write_json, write_png};
use crate::report::{EvalReport, GridReport, RoundReport, RunReport, StageTimes};
use anyhow::{Context, Result};
use evaluate::{Metrics, PartRow};
use fipt_bake::{Accel, ViewHits, emitters};
use fipt_core::io::peak_rss_mb;
use fipt_core::scene::{Dataset, LoadOptions, MapKind};
use predict::{ViewMaps, predict_view};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The maps FIPT reads, plus BaseColor and Metallic for the per-part table.
fn load_opts() -> LoadOptions {
    let mut maps = MapKind::FIPT.to_vec();
    maps.extend([MapKind::BaseColor, MapKind::Metallic, MapKind::Relight]);
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

/// The scores of `model`'s train maps (where the scene has ground truth).
fn score_model(
    ds: &Dataset,
    hits: &[ViewHits],
    model: &fipt_core::model::FiptModel,
    emission: &[glam::Vec3],
    cfg: &Config,
) -> (Metrics, Option<Vec<PartRow>>) {
    let maps: Vec<ViewMaps> = hits
        .iter()
        .enumerate()
        .map(|(k, h)| {
            predict_view(
                model,
                h,
                emission,
                cfg.maps.albedo_samples,
                cfg.seed ^ k as u64,
            )
        })
        .collect();
    score(ds, hits, &maps)
}

/// How `run` runs besides its config.
#[derive(Clone, Debug, Default)]
pub struct RunOptions {
    /// No progress bars and no summary.
    pub quiet: bool,
    /// Fit the oracle shadings (see `run_with`).
    pub oracle: bool,
    /// Register the scene model in this zoo folder, under this name.
    pub zoo: Option<(PathBuf, String)>,
}

/// The whole pipeline; returns the report that is also written to `out/metrics.json`.
pub fn run(scene: &Path, out: &Path, cfg: &Config, quiet: bool) -> Result<RunReport> {
    run_with(
        scene,
        out,
        cfg,
        &RunOptions {
            quiet,
            ..Default::default()
        },
    )
}

/// Oracle shadings of a scene with ground truth, cached in `out/cache/oracle.bin`.
#[allow(clippy::too_many_arguments)]
fn oracle_cached(
    scene: &Path,
    out: &Path,
    ds: &Dataset,
    accel: &Accel,
    baked: &bake::Baked,
    bake_key: u64,
    cfg: &Config,
    quiet: bool,
) -> Result<Vec<Vec<f32>>> {
    let mut rcfg = cfg.refine.paths.clone();
    rcfg.seed = cfg.seed ^ 0x0_7ac1e;
    let mut h = fipt_core::io::Fnv64::default();
    h.bytes(&bake_key.to_le_bytes());
    h.bytes(b"oracle");
    h.bytes(serde_json::to_string(&rcfg)?.as_bytes());
    h.bytes(&rcfg.seed.to_le_bytes());
    let key = h.finish();
    let path = out.join("cache").join("oracle.bin");
    let (w, hh) = (ds.train.width, ds.train.height);
    if let Some(s) = crate::cache::load(&path, key, ds.train.views.len(), w, hh)? {
        return Ok(s);
    }
    let s = refine::oracle(scene, ds, accel, baked, &rcfg, !quiet)?;
    crate::cache::save(&path, key, w, hh, &s)?;
    Ok(s)
}

/// `fipt-train landscape`: the per-part loss landscape (see `landscape`) of the baked
/// shadings, of every refined round cached in `out/cache`, and with `oracle` of the oracle
/// shadings; written to `out/landscape.json` and returned as (shadings name, table). With
/// `fitted`, every table also sweeps σ at the base colour and metallic of the model `run` left in
/// `out/maps/train`, and gives that model's own data term.
pub fn landscapes(
    scene: &Path,
    out: &Path,
    cfg: &Config,
    oracle: bool,
    fitted: bool,
    quiet: bool,
) -> Result<Vec<(String, Vec<landscape::PartLandscape>)>> {
    let ds = Dataset::load(scene, &load_opts())?;
    let maps = if fitted {
        Some(read_train_maps(&ds, out)?)
    } else {
        None
    };
    let maps = maps.as_deref();
    let accel = Accel::build(&ds.mesh);
    let mut bake_cfg = cfg.bake.clone();
    bake_cfg.seed = cfg.seed;
    let (baked, _) = bake::bake_cached(out, &ds, &accel, &bake_cfg, !quiet)?;
    // Each table's prior is the λ_d of the fit on those shadings (round 0's for the baked and
    // the oracle shadings, round r's for `refine{r}.bin`).
    let lambda = |r: usize| cfg.train_for_round(r).lambda_d;
    let mut tables = vec![(
        "baked".to_string(),
        landscape::landscape(&ds, &baked.hits, &baked.shadings, lambda(0), maps),
    )];
    let (w, h, n) = (ds.train.width, ds.train.height, ds.train.views.len());
    for r in 1.. {
        let path = out.join("cache").join(format!("refine{r}.bin"));
        let Some(s) = crate::cache::load_keyed(&path, None, n, w, h)? else {
            break;
        };
        tables.push((
            format!("refined{r}"),
            landscape::landscape(&ds, &baked.hits, &s, lambda(r), maps),
        ));
    }
    if oracle {
        let key = crate::cache::cache_key(&ds, &bake_cfg);
        let s = oracle_cached(scene, out, &ds, &accel, &baked, key, cfg, quiet)?;
        tables.push((
            "oracle".to_string(),
            landscape::landscape(&ds, &baked.hits, &s, lambda(0), maps),
        ));
    }
    let json: serde_json::Map<String, serde_json::Value> = tables
        .iter()
        .map(|(k, v)| (k.clone(), serde_json::to_value(v).unwrap_or_default()))
        .collect();
    write_json(&out.join("landscape.json"), &json)?;
    Ok(tables)
}

/// The one-line message of a run stopped by Ctrl-C at a stage boundary.
fn stopped(out: &Path, after: &str) -> String {
    format!(
        "interrupted {after}; what is done is saved in {}: run the same command again to continue",
        out.display()
    )
}

/// A round's report in its checkpoint folder.
const ROUND_REPORT: &str = "report.json";
/// Round 0's emitters in its checkpoint folder.
const ROUND_EMITTERS: &str = "emitters.json";

/// `run`; with `oracle`, round 0 fits the oracle shadings (path-traced with the true materials
/// and emitters, see `refine::oracle`) instead of the baked ones and no refinement follows: the
/// ceiling of the factorised model.
///
/// Resumable: the fits save their state in `OUT/checkpoint` (see `checkpoint`), and a second
/// call with the same scene, config and program continues from there with the same results.
pub fn run_with(scene: &Path, out: &Path, cfg: &Config, opts: &RunOptions) -> Result<RunReport> {
    let (quiet, oracle) = (opts.quiet, opts.oracle);
    let mut times = StageTimes::default();
    let mut t = Instant::now();
    let ds = Dataset::load(scene, &load_opts())?;
    let accel = Accel::build(&ds.mesh);
    let mut bake_cfg = cfg.bake.clone();
    bake_cfg.seed = cfg.seed;
    let bake_key = crate::cache::cache_key(&ds, &bake_cfg);
    // What an earlier, killed or interrupted, run saved (stale temporaries and state saved
    // under another scene, config or program are removed first).
    let run_key = checkpoint::RunKey::new(
        checkpoint::program_hash(),
        checkpoint::scene_hash(&ds, bake_key),
        cfg,
        oracle,
    );
    let (ck, discarded) = checkpoint::Checkpoints::open(out, &run_key, cfg.checkpoint.every_steps)?;
    if let Some(d) = discarded {
        eprintln!("{d}");
    }
    times.load_s = lap(&mut t);
    write_json(&out.join("config.json"), cfg)?;

    // (1) Bake L′ and the shadings.
    let (mut baked, cached) =
        bake::bake_cached(out, &ds, &accel, &bake_cfg, !quiet).map_err(|e| {
            crate::interrupt::reword(e, || stopped(out, "during the bake (it restarts)"))
        })?;
    let rounds_total = if oracle {
        baked.shadings = oracle_cached(scene, out, &ds, &accel, &baked, bake_key, cfg, quiet)
            .map_err(|e| {
                crate::interrupt::reword(e, || stopped(out, "during the oracle shadings"))
            })?;
        0
    } else {
        cfg.refine.rounds
    };
    times.bake_s = lap(&mut t);
    crate::interrupt::check(|| stopped(out, "after the bake"))?;

    // (2) Fit the material field and the emission mask to the photos; (3) extract the
    // emitters; (4) refine the shadings by path tracing with the current estimate and fit
    // again, `rounds_total` times.
    let mode = cfg.train.seg_mode(
        ds.train.has_map(MapKind::IndexMA),
        ds.train.has_map(MapKind::Segmentation),
    );
    let scene_box = baked.light_field.scene_box;
    let device = cfg.backend.device().map_err(anyhow::Error::msg)?;
    let footprint = pixels::pixel_footprint(&ds.train, &baked.hits, &scene_box);
    let grid_levels = cfg.train.grid.levels_for(footprint);
    // Round r's trainer config (before its schedule sets the rate and λ_d of each step) and
    // schedule.
    let base_cfg = |r: usize| {
        cfg.train_for_round(r)
            .model_config(grid_levels, cfg.backend)
    };
    // The first round not finished in the checkpoint: rounds before it are restored.
    let finished = |r: usize| {
        ck.fit_done(r)
            && (cfg.train_for_round(r).hop.is_none() || ck.hop_done(r))
            && (r == rounds_total || ck.has(r, ROUND_REPORT))
            && ck.has(0, ROUND_EMITTERS)
    };
    let mut resume = (0..=rounds_total)
        .find(|&r| !finished(r))
        .unwrap_or(rounds_total + 1);
    // What the finished rounds left: their reports, the emitters and the last fit (trainer,
    // log). A damaged file there discards every saved round, with a message naming it.
    let restored = || -> Result<_> {
        let mut rounds: Vec<RoundReport> = Vec::new();
        for r in 0..resume.min(rounds_total) {
            rounds.push(ck.get(r, ROUND_REPORT)?.context("round report vanished")?);
        }
        let em: Option<Vec<emitters::Emitter>> = ck.get(0, ROUND_EMITTERS)?;
        let prev = match resume {
            0 => None,
            r => Some(ck.restore_trainer(r - 1, &base_cfg(r - 1), &device, cfg.seed)?),
        };
        Ok((rounds, em, prev))
    };
    let (mut rounds, mut em, mut prev) = match restored() {
        Ok(x) => x,
        Err(e) => {
            eprintln!("discarded the saved rounds, which are damaged: {e:#}");
            ck.discard_from(0);
            resume = 0;
            (Vec::new(), None, None)
        }
    };
    let mut resumed = match resume {
        0 => None,
        r if r > rounds_total => Some(format!("the outputs (all {r} fits restored)")),
        r => Some(format!("round {r} (the {r} rounds before it restored)")),
    };
    if let Some(r) = &resumed
        && !quiet
    {
        eprintln!("resuming at {r} from {}", ck.dir.display());
    }
    let mut store: Option<pixels::PixelStore> = None;
    // What made the current round: its refinement (none for round 0) and its fit.
    let (mut refine_s, mut refine_stats, mut train_s) = (0.0, None, 0.0);
    for r in resume..=rounds_total {
        lap(&mut t);
        let st = store
            .get_or_insert_with(|| pixels::PixelStore::gather(&ds.train, &baked, &scene_box, mode));
        if r > 0 {
            let (tr_prev, _) = prev.as_ref().context("no previous round")?;
            let em = em.as_ref().context("no emitters")?;
            let mut rcfg = cfg.refine.paths.clone();
            rcfg.seed = cfg.seed ^ ((r as u64) << 32);
            let key = refine::refine_key(bake_key, &tr_prev.model, em, &rcfg);
            let path = out.join("cache").join(format!("refine{r}.bin"));
            let (w, h) = (ds.train.width, ds.train.height);
            let shadings = match crate::cache::load(&path, key, ds.train.views.len(), w, h)? {
                Some(s) => {
                    refine_stats = None;
                    s
                }
                None => {
                    let all: Vec<usize> = (0..ds.train.views.len()).collect();
                    let scope = refine::RefineScope {
                        views: &all,
                        material_cache: true,
                    };
                    let rf = refine::refine(
                        &ds.mesh,
                        &accel,
                        &ds.train,
                        &baked,
                        st,
                        &tr_prev.model,
                        em,
                        &rcfg,
                        &scope,
                        !quiet,
                    )
                    .map_err(|e| {
                        crate::interrupt::reword(e, || {
                            stopped(out, &format!("during refinement {r} (it restarts)"))
                        })
                    })?;
                    crate::cache::save(&path, key, w, h, &rf.shadings)?;
                    refine_stats = Some(rf.stats);
                    rf.shadings
                }
            };
            st.set_shadings(&shadings);
            drop(shadings);
            refine_s = lap(&mut t);
            times.refine_s += refine_s;
            crate::interrupt::check(|| stopped(out, &format!("after refinement {r}")))?;
        }

        // The fit: from its checkpoint, from the last round's model (warm start) or afresh
        // from the same initial model as round 0 (the reference, whose seed is fixed), so
        // that a round differs from the last only by its shadings.
        let warm = r > 0 && cfg.refine.warm_start;
        let round_train = cfg.train_for_round(r);
        let run = fit::FitRun {
            mode,
            schedule: &round_train.schedule(),
            seed: if warm {
                cfg.seed.wrapping_add(r as u64)
            } else {
                cfg.seed
            },
            show_progress: !quiet,
        };
        let base = base_cfg(r);
        let of = checkpoint::FitOf {
            cfg: &base,
            device: &device,
            seed: cfg.seed,
            store: st,
            run: &run,
        };
        let (tr0, progress) = match ck.restore_or_discard(r, &of) {
            Some(c) => {
                if !quiet && resumed.is_none() {
                    eprintln!(
                        "resuming round {r}'s fit at step {} of {} from {}",
                        c.progress.step,
                        c.progress.total,
                        ck.dir.display()
                    );
                }
                resumed.get_or_insert_with(|| {
                    format!(
                        "round {r}, step {} of {}",
                        c.progress.step, c.progress.total
                    )
                });
                (c.trainer, Some(c.progress))
            }
            None if warm => {
                let (mut tr, _) = prev.take().context("no previous round")?;
                tr.cfg.lambda_d = base.lambda_d;
                (tr, None)
            }
            None => (
                fipt_core::model::Trainer::new(base.clone(), scene_box, &device, cfg.seed),
                None,
            ),
        };
        let mut ck_s = 0.0;
        let (tr, mut p) = fit::fit_resumable(tr0, st, &run, progress, &mut |tr, p| {
            // The flag is read once: a stop always follows a save of this very step.
            let stop = crate::interrupt::requested();
            if stop || ck.due(p) {
                let t0 = Instant::now();
                ck.save(r, tr, p)?;
                ck_s += t0.elapsed().as_secs_f64();
            }
            if stop {
                return Err(crate::interrupt::Interrupted(format!(
                    "interrupted: round {r}'s fit saved at step {} of {} in {}; run the same command again to continue",
                    p.step,
                    p.total,
                    ck.dir.display()
                ))
                .into());
            }
            Ok(())
        })?;
        // The basin hop, once per fit (a fit restored after its hop is not hopped again).
        let tr = match &round_train.hop {
            Some(h) if p.log.hop.is_none() => {
                let plan = hop::HopPlan {
                    cfg: h,
                    mode,
                    schedule: run.schedule,
                    lambda_d: base.lambda_d
                        * run.schedule.lambda_d_at(p.total.saturating_sub(1), p.total),
                    seed: cfg.seed ^ ((r as u64) << 40),
                    show_progress: !quiet,
                };
                let (tr, rep) = hop::hop(tr, st, &plan).map_err(|e| {
                    crate::interrupt::reword(e, || {
                        stopped(out, &format!("during round {r}'s basin hop (it restarts)"))
                    })
                })?;
                p.log.hop = Some(rep);
                // Over the state saved at the fit's last step: a resumed run restores the
                // hopped model and its report, and does not hop again.
                ck.save_again(r, &tr, &mut p)?;
                tr
            }
            _ => tr,
        };
        ck.save(r, &tr, &mut p)?;
        times.checkpoint_s += ck_s;
        train_s = lap(&mut t);
        times.train_s += train_s;
        crate::interrupt::check(|| stopped(out, &format!("after round {r}'s fit")))?;

        if r == 0 && em.is_none() {
            let e = extract::extract_emitters(
                &ds.mesh,
                &ds.train,
                &baked,
                st,
                &tr,
                &cfg.emitters,
                cfg.seed,
            );
            ck.put(0, ROUND_EMITTERS, &e)?;
            em = Some(e);
            times.emitters_s = lap(&mut t);
        }
        if r < rounds_total {
            let emission = emitters::radiance_per_triangle(
                ds.mesh.num_triangles(),
                em.as_deref().unwrap_or_default(),
            );
            let (m, parts) = score_model(&ds, &baked.hits, &tr.model, &emission, cfg);
            let rr = RoundReport::new(
                r,
                &m,
                parts,
                &tr,
                &p.log,
                refine_s,
                refine_stats.take(),
                train_s,
            );
            ck.put(r, ROUND_REPORT, &rr)?;
            rounds.push(rr);
            lap(&mut t);
        }
        prev = Some((tr, p.log));
    }
    drop(store);
    let (tr, log) = prev.context("no fit")?;
    let em = em.context("no emitters")?;
    write_json(
        &out.join("emitters.json"),
        &serde_json::json!({ "emitters": em }),
    )?;
    let emission = emitters::radiance_per_triangle(ds.mesh.num_triangles(), &em);
    crate::interrupt::check(|| stopped(out, "after the fits"))?;

    // (5) Predict the maps of every view and score them (into a staged folder that replaces
    // `maps/` whole).
    let maps_final = out.join("maps");
    let maps_dir = crate::scene_model::sibling(&maps_final, "tmp");
    let _ = std::fs::remove_dir_all(&maps_dir);
    let mut train_maps_final = Vec::new();
    for split in ds.splits() {
        let cast: Vec<ViewHits>;
        let hits: &[ViewHits] = if split.name == "train" {
            &baked.hits
        } else {
            cast = bake::cast_split(&accel, &ds.mesh, split);
            &cast
        };
        for (k, h) in hits.iter().enumerate() {
            crate::interrupt::check(|| stopped(out, "during the maps (they restart)"))?;
            let m = predict_view(
                &tr.model,
                h,
                &emission,
                cfg.maps.albedo_samples,
                cfg.seed ^ k as u64,
            );
            m.write(&maps_dir.join(&split.name), k)?;
            if split.name == "train" {
                train_maps_final.push(m);
            }
        }
    }
    crate::scene_model::replace_dir(&maps_dir, &maps_final)?;
    times.maps_s = lap(&mut t);

    let (metrics, parts) = score(&ds, &baked.hits, &train_maps_final);
    rounds.push(RoundReport::new(
        rounds_total,
        &metrics,
        parts.clone(),
        &tr,
        &log,
        refine_s,
        refine_stats,
        train_s,
    ));
    write_comparisons(&ds, &metrics, &train_maps_final, out)?;

    // (6) Re-render the val views: view synthesis and relighting, scored against the photos.
    let recovered = crate::render::Recovered {
        model: &tr.model,
        mesh: &ds.mesh,
        emitters: &em,
        light_field: &baked.light_field,
    };
    let renders = if cfg.render.val {
        render_val(scene, out, &ds, &recovered, cfg, quiet).map_err(|e| {
            crate::interrupt::reword(e, || stopped(out, "during the re-renders (they restart)"))
        })?
    } else {
        None
    };
    times.render_s = lap(&mut t);
    let scored = |v: &[crate::render::ViewRender]| {
        crate::render::mean(&v.iter().filter_map(|r| r.psnr_db).collect::<Vec<_>>())
    };
    let mut report = RunReport {
        scene: scene.display().to_string(),
        seg_loss: mode,
        bake_from_cache: cached,
        metrics,
        emitters: em.len(),
        grid: GridReport {
            pixel_footprint: footprint,
            levels: grid_levels,
            steps: tr.steps,
            place: if tr.device_resident() {
                "device"
            } else {
                "host"
            }
            .into(),
        },
        parts,
        rounds,
        train_log: log,
        step_profile: tr.profile,
        time_s: times,
        peak_rss_mb: peak_rss_mb(),
        view_psnr: renders.as_ref().and_then(|r| scored(&r.view)),
        relight_psnr: renders.as_ref().and_then(|r| scored(&r.relight)),
        renders,
        model_dir: None,
        zoo_entry: None,
        resumed,
    };

    crate::interrupt::check(|| stopped(out, "before the scene model was saved"))?;
    // The scene model: everything recovered, in one folder that renders without the photos.
    let model_dir = out.join("model");
    let m = &report.metrics;
    let name = opts
        .zoo
        .as_ref()
        .map_or_else(|| default_model_name(scene, cfg.seed), |(_, n)| n.clone());
    report.model_dir = Some(model_dir.display().to_string());
    if let Some((zoo, _)) = &opts.zoo {
        report.zoo_entry = Some(zoo.join(&name).display().to_string());
    }
    crate::scene_model::save(
        &model_dir,
        &tr.model,
        &ds.mesh,
        &em,
        &baked.light_field,
        &crate::scene_model::SaveInfo {
            name: &name,
            scene,
            image_size: [ds.train.width, ds.train.height],
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
            run_metrics: &serde_json::to_value(&report)?,
        },
    )?;
    write_json(&out.join("metrics.json"), &report)?;
    if let Some((zoo, name)) = &opts.zoo {
        crate::zoo::Zoo::new(zoo).register(&model_dir, name)?;
    }
    let page = crate::html_report::write(scene, out)?;
    if !quiet {
        report.print(out);
        println!("report: {}", page.display());
    }
    Ok(report)
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

/// View synthesis of the val views against `val/Image` and, where the scene has
/// `relight.json` and `val/Relight`, relighting against them (None without val views).
fn render_val(
    scene: &Path,
    out: &Path,
    ds: &Dataset,
    rec: &crate::render::Recovered,
    cfg: &Config,
    quiet: bool,
) -> Result<Option<crate::report::ValRenders>> {
    let Some(val) = &ds.val else {
        return Ok(None);
    };
    let rc = &cfg.render;
    let path = fipt_bake::integrators::path::PathConfig {
        spp: rc.spp,
        max_depth: rc.max_depth,
        seed: cfg.seed,
        pixel_positions: rc.pixel_positions,
        ..Default::default()
    };
    let opts = crate::render::RecoveredOptions {
        selection: fipt_bake::emitters::LightSelection::Power,
        cache: rc.cache,
        material_cache: rc.material_cache,
        off_reflect: rc.off_reflect,
    };
    // Into a staged folder that replaces `render/` whole.
    let fin = out.join("render");
    let staged = crate::scene_model::sibling(&fin, "tmp");
    let _ = std::fs::remove_dir_all(&staged);
    let dir = staged.join("val");
    let cams: Vec<crate::render::CamRef> = val
        .views
        .iter()
        .enumerate()
        .map(|(k, v)| (k, v.camera.clone(), Some(&v.image)))
        .collect();
    let picked: Vec<&crate::render::CamRef> = cams.iter().collect();
    let none = crate::render::Edits::default();
    let view = crate::render::render_recovered(
        rec,
        &none,
        &picked,
        &path,
        &opts,
        &dir.join("Image"),
        quiet,
    )?
    .views;
    let relight_path = scene.join("relight.json");
    let relight = if relight_path.is_file() && val.has_map(MapKind::Relight) {
        let r = fipt_core::scene::meta::Relight::load(&relight_path, ds.meta.as_ref())?;
        let cams: Vec<crate::render::CamRef> = val
            .views
            .iter()
            .enumerate()
            .map(|(k, v)| (k, v.camera.clone(), v.map(MapKind::Relight)))
            .collect();
        let picked: Vec<&crate::render::CamRef> = cams.iter().collect();
        let edits = crate::render::Edits {
            relight: Some(&r),
            meta: ds.meta.as_ref(),
            inserted: &[],
        };
        let path = fipt_bake::integrators::path::PathConfig {
            spp: rc.relight_spp,
            ..path
        };
        crate::render::render_recovered(
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
    // The contact sheet: per val view, photo | re-render | relit photo | relit re-render.
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
    crate::output::write_sheet(&dir.join("sheet.png"), val.width, val.height, &rows)?;
    crate::scene_model::replace_dir(&staged, &fin)?;
    Ok(Some(crate::report::ValRenders {
        spp: rc.spp,
        relight_spp: rc.relight_spp,
        cache: rc.cache,
        view,
        relight,
    }))
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
    let fin = out.join("compare");
    let dir = crate::scene_model::sibling(&fin, "tmp");
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir)?;
    for &(k, _) in worst.into_iter().chain(best) {
        let (w, h, rgb) = evaluate::comparison_figure(&ds.train.views[k], &maps[k]);
        write_png(&dir.join(format!("train_{k:03}.png")), w, h, &rgb, 1.0)?;
    }
    crate::scene_model::replace_dir(&dir, &fin)
}

/// Scores a scene model (`scene_model`) against a scene's ground truth: its train maps
/// predicted afresh (as `run` does, with the model's own config) into `out/eval.json`. What
/// `run` scored from its in-memory model, from the saved model instead.
pub fn eval_model(scene: &Path, model_dir: &Path, out: &Path) -> Result<EvalReport> {
    let device = burn::tensor::Device::flex();
    let sm = crate::scene_model::SceneModel::load(model_dir, &device)?;
    let cfg_path = model_dir.join("config.json");
    let cfg = Config::load(&cfg_path)?;
    let ds = Dataset::load(scene, &load_opts())?;
    if crate::scene_model::mesh_hash(&ds.mesh) != sm.manifest.mesh_hash {
        anyhow::bail!(
            "{}: the scene's mesh differs from the model's ({})",
            scene.display(),
            model_dir.display()
        );
    }
    let accel = Accel::build(&ds.mesh);
    let hits = bake::cast_split(&accel, &ds.mesh, &ds.train);
    let emission = emitters::radiance_per_triangle(ds.mesh.num_triangles(), &sm.emitters);
    let maps: Vec<ViewMaps> = hits
        .iter()
        .enumerate()
        .map(|(k, h)| {
            predict_view(
                &sm.model,
                h,
                &emission,
                cfg.maps.albedo_samples,
                cfg.seed ^ k as u64,
            )
        })
        .collect();
    let (metrics, parts) = score(&ds, &hits, &maps);
    let r = EvalReport { metrics, parts };
    write_json(&out.join("eval.json"), &r)?;
    Ok(r)
}

/// Recomputes the metrics from `out/maps/train` (written by `run`) into `out/eval.json`.
pub fn eval(scene: &Path, out: &Path) -> Result<EvalReport> {
    let ds = Dataset::load(scene, &load_opts())?;
    let accel = Accel::build(&ds.mesh);
    let maps = read_train_maps(&ds, out)?;
    let hits = bake::cast_split(&accel, &ds.mesh, &ds.train);
    let (metrics, parts) = score(&ds, &hits, &maps);
    let r = EvalReport { metrics, parts };
    write_json(&out.join("eval.json"), &r)?;
    Ok(r)
}

/// The train views' maps a `run` saved in `out/maps/train`, checked against the scene's sizes.
fn read_train_maps(ds: &Dataset, out: &Path) -> Result<Vec<ViewMaps>> {
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
    Ok(maps)
}
