//! The alternation of paper Fig. 2: round 0 fits the baked shadings and extracts the emitters;
//! every later round refines the shadings with the last estimate and fits again. Each round's
//! fit, hop, emitters and report are saved in the run's checkpoint, so a killed run resumes at
//! the first unfinished round (or inside its fit).
//!
//! Owns: the rounds' order, their resume bookkeeping, the refinement cache, the fit's checkpoint
//! observer. Must not touch: the fit, the hop, the refinement or the extraction themselves.

use super::bake::Baked;
use super::checkpoint::{self, Checkpoints, FitOf};
use super::context::RunContext;
use super::fit::{self, FitRun, TrainLog};
use super::pixels::{self, PixelStore};
use super::{extract, hop, refine, score};
use crate::pipeline::report::{RoundReport, RoundWork};
use anyhow::{Context, Result};
use fipt_bake::emitters::{self, Emitter};
use fipt_core::model::step::SegMode;
use fipt_core::model::{PartMap, TrainConfig, Trainer};
use fipt_core::scene::{MapKind, SceneBox};
use std::time::Instant;

/// A round's report in its checkpoint folder.
const ROUND_REPORT: &str = "report.json";
/// Round 0's emitters in its checkpoint folder.
const ROUND_EMITTERS: &str = "emitters.json";
/// LDR photos: round 0's solve of the clipped lamps.
const LIGHT_SOLVE: &str = "light_solve.json";

/// What every round's fit shares: the segmentation loss, the scene box, the device and the
/// hash grid's levels (from the pixel footprint).
pub struct FitSetup {
    pub mode: SegMode,
    pub scene_box: SceneBox,
    pub device: burn::tensor::Device,
    pub footprint: f64,
    pub grid_levels: usize,
    /// The part offsets' map (`pixels::part_map`), set once the store is gathered.
    pub parts: PartMap,
    /// The last round (0 with oracle shadings, which are not refined).
    pub last_round: usize,
}

impl FitSetup {
    pub fn new(ctx: &RunContext, baked: &Baked) -> Result<Self> {
        let (cfg, train) = (ctx.cfg, &ctx.ds.train);
        let scene_box = baked.light_field.scene_box;
        let footprint = pixels::pixel_footprint(train, &baked.hits, &scene_box);
        Ok(Self {
            mode: cfg.train.seg_mode(
                train.has_map(MapKind::IndexMA),
                train.has_map(MapKind::Segmentation),
            ),
            scene_box,
            device: cfg.backend.device().map_err(anyhow::Error::msg)?,
            footprint,
            grid_levels: cfg.train.grid.levels_for(footprint),
            parts: PartMap::default(),
            last_round: if ctx.opts.oracle {
                0
            } else {
                cfg.refine.rounds
            },
        })
    }

    /// The stage-2 pixel store of `baked` with each entry's part-offset row, and the part map
    /// (`pixels::part_map`; without `train.part_offsets`, a map without parts).
    pub fn gather_store(&self, ctx: &RunContext, baked: &Baked) -> (PixelStore, PartMap) {
        let mut st = PixelStore::gather(&ctx.ds.train, baked, &self.scene_box, self.mode);
        let parts = pixels::part_map(
            &st,
            ctx.ds.mesh.num_triangles(),
            ctx.cfg.train.part_offsets,
            self.mode,
        );
        st.set_parts(&parts);
        self.leave_out_mixed_pixels(ctx, baked, &mut st);
        (st, parts)
    }

    /// With `train.min_coverage` τ > 0: the pixels whose square the part their centre ray hits
    /// covers less than τ of (`pixels::coverage`; planes of the mesh without labels; within
    /// `train.coverage_crease` of the centre's normal) leave the store, for every round's fit.
    fn leave_out_mixed_pixels(&self, ctx: &RunContext, baked: &Baked, st: &mut PixelStore) {
        let tau = ctx.cfg.train.min_coverage;
        if tau <= 0.0 {
            return;
        }
        let keys: Vec<u64> = match self.mode {
            SegMode::None => crate::ldr::edges::plane_keys(&ctx.ds.mesh),
            _ => st
                .triangle_labels(ctx.ds.mesh.num_triangles())
                .into_iter()
                .map(|l| l as u32 as u64)
                .collect(),
        };
        let cover = pixels::coverage(
            &ctx.accel,
            ctx.ds.train.views.iter().map(|v| &v.camera),
            &baked.hits,
            &pixels::CoverKeys::with_crease(keys, &ctx.ds.mesh, ctx.cfg.train.coverage_crease),
        );
        let gone = st.retain(|k, p| cover[k as usize][p as usize] >= tau);
        if ctx.progress() {
            eprintln!(
                "left {gone} pixels that their part covers less than {tau} of out of the fits (train.min_coverage)"
            );
        }
    }

    /// Round `r`'s trainer config, before its schedule sets the rate and λ_d of each step.
    pub fn base_cfg(&self, ctx: &RunContext, r: usize) -> TrainConfig {
        ctx.cfg
            .train_for_round(r)
            .model_config(self.grid_levels, ctx.cfg.backend)
            .with_metallic_scale(ctx.cfg.metallic_scale(r))
    }
}

/// The rounds' state: the reports and emitters of the finished rounds, the last fit, and what
/// made the current round.
pub struct Rounds {
    ck: Checkpoints,
    pub reports: Vec<RoundReport>,
    emitters: Option<Vec<Emitter>>,
    /// LDR photos: round 0's solve of the clipped lamps.
    light_resolve: Option<crate::ldr::lights::LightSolve>,
    /// The last finished fit: its trainer and loss log.
    prev: Option<(Trainer, TrainLog)>,
    /// Where the run resumed, for its report (None: from the start).
    pub resumed: Option<String>,
    /// The first round to run (past `last_round`: all were restored).
    pub first: usize,
    /// The current round's refinement and fit.
    work: RoundWork,
    /// Whether the pixels on and next to the emitters have left the store
    /// (`refine.emitter_margin`, `refine.emitter_pixels`).
    margin_applied: bool,
    /// Whether L′ has been rebuilt without them (`refine.paths.cache_margin`).
    cache_rebuilt: bool,
}

/// What the rounds leave: the last fit and the emitters.
pub struct Fitted {
    pub trainer: Trainer,
    pub log: TrainLog,
    pub emitters: Vec<Emitter>,
    /// LDR photos: round 0's solve of the clipped lamps (the radiance the emitters keep).
    pub light_resolve: Option<crate::ldr::lights::LightSolve>,
    /// The last round's refinement and fit.
    pub work: RoundWork,
    pub reports: Vec<RoundReport>,
    pub resumed: Option<String>,
}

impl Rounds {
    /// Restores what an earlier, killed or interrupted, run finished: the first round not
    /// finished in the checkpoint is the first to run, the rounds before it are restored. A
    /// damaged file there discards every saved round, with a message naming it.
    pub fn resume(ctx: &RunContext, setup: &FitSetup, ck: Checkpoints) -> Self {
        let last = setup.last_round;
        let finished = |r: usize| {
            ck.fit_done(r)
                && (ctx.cfg.train_for_round(r).hop.is_none() || ck.hop_done(r))
                && (r == last || ck.has(r, ROUND_REPORT))
                && ck.has(0, ROUND_EMITTERS)
        };
        let mut first = (0..=last).find(|&r| !finished(r)).unwrap_or(last + 1);
        let restored = || -> Result<_> {
            let mut reports: Vec<RoundReport> = Vec::new();
            for r in 0..first.min(last) {
                reports.push(ck.get(r, ROUND_REPORT)?.context("round report vanished")?);
            }
            let em: Option<Vec<Emitter>> = ck.get(0, ROUND_EMITTERS)?;
            let prev = match first {
                0 => None,
                r => Some(ck.restore_trainer(
                    r - 1,
                    &setup.base_cfg(ctx, r - 1),
                    &setup.device,
                    ctx.seeds.base(),
                )?),
            };
            Ok((reports, em, prev))
        };
        let (reports, emitters, prev) = match restored() {
            Ok(x) => x,
            Err(e) => {
                eprintln!("discarded the saved rounds, which are damaged: {e:#}");
                ck.discard_from(0);
                first = 0;
                (Vec::new(), None, None)
            }
        };
        // Only for the report: a damaged solve is left out of it, not a reason to refit.
        let light_resolve = ck.get(0, LIGHT_SOLVE).ok().flatten();
        let resumed = match first {
            0 => None,
            r if r > last => Some(format!("the outputs (all {r} fits restored)")),
            r => Some(format!("round {r} (the {r} rounds before it restored)")),
        };
        if let Some(r) = &resumed
            && ctx.progress()
        {
            eprintln!("resuming at {r} from {}", ck.dir.display());
        }
        Self {
            ck,
            reports,
            emitters,
            light_resolve,
            prev,
            resumed,
            first,
            work: RoundWork::default(),
            margin_applied: false,
            cache_rebuilt: false,
        }
    }

    /// Per mesh triangle, whether it is an extracted emitter (None before the extraction).
    fn emitter_triangles(&self, ctx: &RunContext) -> Option<Vec<bool>> {
        let mut lit = vec![false; ctx.ds.mesh.num_triangles()];
        for e in self.emitters.as_ref()? {
            lit[e.triangle as usize] = true;
        }
        Some(lit)
    }

    /// Before the fits on refined shadings, once: the pixels within `refine.emitter_margin`
    /// of one that shows an extracted emitter leave the store (their footprint takes in part of
    /// the emitter, far brighter than the surface their centre ray hits), and, unless
    /// `refine.emitter_pixels`, the pixels that show one (the emitters are fixed after round 0;
    /// fitted, their composite pulls the field towards white around them).
    pub fn leave_out_near_emitters(
        &mut self,
        ctx: &RunContext,
        baked: &Baked,
        store: &mut PixelStore,
    ) {
        let (margin, keep_on) = (ctx.cfg.refine.emitter_margin, ctx.cfg.refine.emitter_pixels);
        if self.margin_applied {
            return;
        }
        let Some(lit) = self.emitter_triangles(ctx) else {
            return;
        };
        self.margin_applied = true;
        let Some(near) =
            pixels::left_out_of_refined_fits(&baked.hits, |t| lit[t as usize], margin, keep_on)
        else {
            return;
        };
        let gone = store.retain(|k, p| !near[k as usize][p as usize]);
        if ctx.progress() {
            let on = if keep_on { "" } else { "on and " };
            eprintln!(
                "left {gone} pixels {on}next to the emitters out of the refined fits (refine.emitter_margin {margin})"
            );
        }
    }

    /// Once the emitters are known, once: L′ rebuilt without the training pixels within
    /// `refine.paths.cache_margin` of one that shows an extracted emitter. Their footprint
    /// takes in part of the emitter; kept, they light the scene as a ring of emitter around
    /// each one wherever a path ends in the radiance cache. The emitters' own pixels leave with
    /// them, so that the hole filling carries no emitter radiance back into the ring. The
    /// refinement, the renders and the saved scene model use the rebuilt L′; round 0's bake
    /// used the whole one.
    pub fn rebuild_cache(&mut self, ctx: &RunContext, baked: &mut Baked) {
        let margin = ctx.cfg.refine.paths.cache_margin;
        if self.cache_rebuilt || margin == 0 {
            return;
        }
        let Some(lit) = self.emitter_triangles(ctx) else {
            return;
        };
        self.cache_rebuilt = true;
        let (lf, gone) = super::bake::light_field_without_emitters(
            &ctx.ds,
            baked,
            &ctx.bake_cfg,
            |t| lit[t as usize],
            margin,
        );
        baked.light_field = lf;
        if ctx.progress() {
            eprintln!(
                "left {gone} pixels on and next to the emitters out of L′ (refine.paths.cache_margin {margin})"
            );
        }
    }

    /// (4) Round `r`'s shadings, path-traced with the last fit and the emitters (from the
    /// refinement cache when the same model made them before), into the pixel store; with
    /// `refine.paths.cache_diffuse`, through L′ rebuilt from the photos less the specular
    /// radiance the last fit predicts on the store's shadings.
    pub fn refine(
        &mut self,
        ctx: &mut RunContext,
        baked: &Baked,
        store: &mut PixelStore,
        r: usize,
    ) -> Result<()> {
        let (tr_prev, _) = self.prev.as_ref().context("no previous round")?;
        let em = self.emitters.as_ref().context("no emitters")?;
        let rcfg = ctx.cfg.refine_paths(r);
        let key = refine::refine_key(ctx.bake_key, &tr_prev.model, em, &rcfg, store)?;
        let path = ctx.out.join("cache").join(format!("refine{r}.bin"));
        let (w, h) = (ctx.ds.train.width, ctx.ds.train.height);
        let (shadings, stats) =
            match crate::cache::load_or_discard(&path, key, ctx.ds.train.views.len(), w, h)? {
                Some(s) => (s, None),
                None => {
                    let all: Vec<usize> = (0..ctx.ds.train.views.len()).collect();
                    let diffuse = rcfg
                        .cache_diffuse
                        .then(|| self.emitter_triangles(ctx))
                        .flatten()
                        .map(|lit| {
                            super::bake::light_field_diffuse(
                                &ctx.ds,
                                baked,
                                &ctx.bake_cfg,
                                &fit::specular(&tr_prev.model, store, &baked.hits),
                                |t| lit[t as usize],
                                rcfg.cache_margin,
                            )
                        });
                    let job = refine::RefineJob {
                        ds: &ctx.ds,
                        accel: &ctx.accel,
                        baked,
                        light_field: diffuse.as_ref().unwrap_or(&baked.light_field),
                        cfg: &rcfg,
                        views: &all,
                        material_cache: true,
                        show_progress: ctx.progress(),
                    };
                    let rf = refine::refine(&job, store, &tr_prev.model, em).map_err(|e| {
                        ctx.reword(e, &format!("during refinement {r} (it restarts)"))
                    })?;
                    crate::cache::save(&path, key, w, h, &rf.shadings)?;
                    (rf.shadings, Some(rf.stats))
                }
            };
        store.set_shadings(&shadings);
        drop(shadings);
        self.work.refine_paths = stats;
        self.work.refine_s = ctx.lap();
        ctx.times.refine_s += self.work.refine_s;
        ctx.check(&format!("after refinement {r}"))
    }

    /// (2) Round `r`'s fit of the material field and the emission mask, then its basin hop:
    /// from its checkpoint, from the last round's model (warm start) or afresh from the same
    /// initial model as round 0 (the reference, whose seed is fixed), so that a round differs
    /// from the last only by its shadings.
    pub fn fit(
        &mut self,
        ctx: &mut RunContext,
        setup: &FitSetup,
        store: &PixelStore,
        r: usize,
    ) -> Result<(Trainer, fit::FitProgress)> {
        let warm = ctx.cfg.warm_start(r);
        let round_train = ctx.cfg.train_for_round(r);
        let run = FitRun {
            mode: setup.mode,
            schedule: &round_train,
            seed: ctx.seeds.fit(r, warm),
            show_progress: ctx.progress(),
        };
        let base = setup.base_cfg(ctx, r);
        let of = FitOf {
            cfg: &base,
            device: &setup.device,
            seed: ctx.seeds.base(),
            store,
            run: &run,
        };
        let spared = self.metals_spared(ctx, setup, store, r);
        let (mut tr0, progress) = self.start_fit(ctx, setup, &of, r)?;
        tr0.metallic_scales = spared.iter().map(|&s| (s, 1.0)).collect();
        let ck = &self.ck;
        let mut ck_s = 0.0;
        let (tr, mut p) = fit::fit_resumable(tr0, store, &run, progress, &mut |tr, p| {
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
                    mode: setup.mode,
                    schedule: run.schedule,
                    lambda_d: base.lambda_d
                        * run.schedule.lambda_d_at(p.total.saturating_sub(1), p.total),
                    seed: ctx.seeds.hop(r),
                    show_progress: ctx.progress(),
                    carried: self.prev.as_ref().map(|(t, _)| &t.model),
                    refined: r > 0,
                    footprint: setup.footprint as f32 * (setup.scene_box.max - setup.scene_box.min),
                };
                let (tr, rep) = hop::hop(tr, store, &plan).map_err(|e| {
                    ctx.reword(e, &format!("during round {r}'s basin hop (it restarts)"))
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
        ctx.times.checkpoint_s += ck_s;
        self.work.train_s = ctx.lap();
        ctx.times.train_s += self.work.train_s;
        ctx.check(&format!("after round {r}'s fit"))?;
        Ok((tr, p))
    }

    /// With `refine.lambda_m` on the dielectrics alone (`MetalPriorOn::Dielectrics`), round
    /// `r`'s segments that the previous round left metal: their m term keeps the round's λ_d
    /// (s = 1) in place of `refine.lambda_m`. None in round 0, without `refine.lambda_m`, with
    /// the key on all segments, or without labels (one segment: the whole scene).
    fn metals_spared(
        &self,
        ctx: &RunContext,
        setup: &FitSetup,
        store: &PixelStore,
        r: usize,
    ) -> Vec<i32> {
        let on = ctx.cfg.refine.lambda_m_on == crate::config::MetalPriorOn::Dielectrics
            && setup.mode != SegMode::None;
        let Some((prev, _)) = self
            .prev
            .as_ref()
            .filter(|_| r > 0 && on && ctx.cfg.refine.lambda_m.is_some())
        else {
            return Vec::new();
        };
        let metals = fit::metal_segments(&prev.model, store);
        if ctx.progress() {
            eprintln!(
                "round {r}: refine.lambda_m spares the {} segments round {} left metal {metals:?}",
                metals.len(),
                r - 1
            );
        }
        metals
    }

    /// The trainer round `r`'s fit (`of`) starts from, and its saved progress when it resumes.
    fn start_fit(
        &mut self,
        ctx: &RunContext,
        setup: &FitSetup,
        of: &FitOf,
        r: usize,
    ) -> Result<(Trainer, Option<fit::FitProgress>)> {
        let warm = ctx.cfg.warm_start(r);
        let base = of.cfg;
        Ok(match self.ck.restore_or_discard(r, of) {
            Some(c) => {
                if ctx.progress() && self.resumed.is_none() {
                    eprintln!(
                        "resuming round {r}'s fit at step {} of {} from {}",
                        c.progress.step,
                        c.progress.total,
                        self.ck.dir.display()
                    );
                }
                self.resumed.get_or_insert_with(|| {
                    format!(
                        "round {r}, step {} of {}",
                        c.progress.step, c.progress.total
                    )
                });
                (c.trainer, Some(c.progress))
            }
            None if warm => {
                let (mut tr, _) = self.prev.take().context("no previous round")?;
                tr.cfg.lambda_d = base.lambda_d;
                tr.cfg.metallic_scale = base.metallic_scale;
                (tr, None)
            }
            None => (
                Trainer::with_parts(
                    base.clone(),
                    setup.scene_box,
                    setup.parts.clone(),
                    &setup.device,
                    ctx.seeds.base(),
                ),
                None,
            ),
        })
    }

    /// (3) The emitters from round 0's emission mask (once: a resumed run restores them).
    pub fn extract(
        &mut self,
        ctx: &mut RunContext,
        baked: &Baked,
        store: &PixelStore,
        tr: &Trainer,
    ) -> Result<()> {
        if self.emitters.is_some() {
            return Ok(());
        }
        let reflected = super::fit::reflected(tr, store, &baked.hits);
        let mut e = extract::extract_emitters(
            &ctx.ds.mesh,
            &ctx.ds.train,
            baked,
            tr,
            &reflected,
            &ctx.cfg.emitters,
            ctx.seeds.base(),
        );
        if ctx.ldr.is_some() && ctx.cfg.ldr.solve_emitters {
            let solve = extract::solve_clipped_lamps(
                ctx,
                baked,
                store,
                tr,
                &mut e,
                false,
                Some(&reflected),
            );
            self.ck.put(0, LIGHT_SOLVE, &solve)?;
            self.light_resolve = Some(solve);
        }
        self.ck.put(0, ROUND_EMITTERS, &e)?;
        self.emitters = Some(e);
        ctx.times.emitters_s = ctx.lap();
        Ok(())
    }

    /// Closes round `r`: a round before the last is scored on the train views and its report
    /// saved; its fit becomes the previous one.
    pub fn close(
        &mut self,
        ctx: &mut RunContext,
        setup: &FitSetup,
        baked: &Baked,
        r: usize,
        (tr, p): (Trainer, fit::FitProgress),
    ) -> Result<()> {
        if r < setup.last_round {
            let emission = emitters::radiance_per_triangle(
                ctx.ds.mesh.num_triangles(),
                self.emitters.as_deref().unwrap_or_default(),
            );
            let maps = super::predict::predict_views(&tr.model, &baked.hits, &emission, ctx.cfg);
            let (m, parts) = score::score(&ctx.ds, &baked.hits, &maps);
            let rr = RoundReport::new(r, &m, parts, &tr, &p.log, self.take_work());
            self.ck.put(r, ROUND_REPORT, &rr)?;
            self.reports.push(rr);
            ctx.lap();
        }
        self.prev = Some((tr, p.log));
        Ok(())
    }

    /// The current round's refinement and fit, leaving the refinement's path statistics
    /// behind (a later report of the same round has none).
    fn take_work(&mut self) -> RoundWork {
        RoundWork {
            refine_s: self.work.refine_s,
            refine_paths: self.work.refine_paths.take(),
            train_s: self.work.train_s,
        }
    }

    /// The last fit and the emitters, once every round has run.
    pub fn finish(mut self) -> Result<Fitted> {
        let work = self.take_work();
        let (trainer, log) = self.prev.context("no fit")?;
        Ok(Fitted {
            trainer,
            log,
            emitters: self.emitters.context("no emitters")?,
            light_resolve: self.light_resolve,
            work,
            reports: self.reports,
            resumed: self.resumed,
        })
    }
}

/// Every round from the first unfinished one, in the order of Fig. 2: refine (rounds after 0),
/// fit, extract (round 0), score.
pub fn run_rounds(
    ctx: &mut RunContext,
    baked: &mut Baked,
    ck: Checkpoints,
) -> Result<(FitSetup, Fitted)> {
    let mut setup = FitSetup::new(ctx, baked)?;
    let mut rounds = Rounds::resume(ctx, &setup, ck);
    let mut store: Option<PixelStore> = None;
    for r in rounds.first..=setup.last_round {
        ctx.lap();
        if store.is_none() {
            let (st, parts) = setup.gather_store(ctx, baked);
            setup.parts = parts;
            store = Some(st);
        }
        let st = store.as_mut().context("the store is gathered")?;
        if r > 0 {
            rounds.rebuild_cache(ctx, baked);
            rounds.leave_out_near_emitters(ctx, baked, st);
            rounds.refine(ctx, baked, st, r)?;
        }
        let fitted = rounds.fit(ctx, &setup, st, r)?;
        if r == 0 {
            rounds.extract(ctx, baked, st, &fitted.0)?;
        }
        rounds.close(ctx, &setup, baked, r, fitted)?;
    }
    drop(store);
    // Every round restored from the checkpoint: the renders still get the rebuilt L′.
    if setup.last_round > 0 {
        rounds.rebuild_cache(ctx, baked);
    }
    Ok((setup, rounds.finish()?))
}

/// The key of the saved state of a run (`checkpoint::RunKey`): the program, the scene and its
/// bake, the config and whether it fits the oracle shadings.
pub fn open_checkpoints(ctx: &RunContext) -> Result<Checkpoints> {
    let run_key = checkpoint::RunKey::new(
        checkpoint::program_hash(),
        checkpoint::scene_hash(&ctx.ds, ctx.bake_key)?,
        ctx.cfg,
        ctx.opts.oracle,
    )?;
    let (ck, discarded) = Checkpoints::open(ctx.out, &run_key, ctx.cfg.checkpoint.every_steps)?;
    if let Some(d) = discarded {
        eprintln!("{d}");
    }
    Ok(ck)
}
