//! Basin hopping on the roughness, per segment (`train.hop`, a departure from the reference:
//! `docs/departures/hop.md`). After a fit, every segment's objective is scored at the model and
//! at hypotheses of its material (`evaluate`). Where a hypothesis lowers it by `gain`, far from
//! the fit, the segment hops (`choose`): the fit continues with σ, and m where the target names
//! one, pulled to the target, then released (`phases`). The hop is kept only if the hopped
//! segments' objective fell by `gain` too; the other segments' objective is not part of the
//! decision (the emitters' pixels, α ≈ 1, would decide it alone). Up to three hops run in order,
//! each kept or undone on its own (`Stage`): the sweep, metal and carried candidates; the plain
//! metals of an undone first hop, alone (`plain_metal`); the patch candidates, with the patch
//! fallbacks of an undone first hop (`patch_fallback`). The segments not hopping are held at
//! their mean σ and m (`anchor`), or on refined shadings a dielectric at its patch hypothesis
//! (`settle`); a kept hop that harmed one of them runs again with it held (`guard`).
//!
//! Why: with the factorised renderer the objective over σ is flat or multi-modal on glossy
//! dielectrics (a rough lobe is nearly flat over σ ∈ [0.8, 1]), and the basin a part settles in
//! is chosen in the first steps of a fit. A part can then sit at σ ≈ 0.95 while its own data and
//! prior favour a much lower σ (`docs/departures/hop.md`); no amount of descent leaves such a
//! plateau, a hop to where the objective already says it should be does.
//!
//! The objective evaluated is that of the fit, Eq. 15 + 17: the tone-mapped MSE of the
//! composite (1 − α)·C + α·I and λ_d·(|σ − σ₀| + m), on up to `pixels` pixels per segment
//! (evenly strided over the store), weighted by segment size, with λ_d = `prior` × the fit's
//! final λ_d. With `prior` 0 (the shipped configs) it is the data term alone: a segment whose
//! data is flat gains less than `gain` anywhere and keeps the σ the fit reached under its
//! prior, while one whose data clearly prefers a σ far away is no longer held on the rough side
//! by the prior. The segmentation loss and the logit bound are left out (a common σ per segment
//! leaves the first at its minimum).
//!
//! Files: `record` (what a hop records), `evaluate` (the objective at the model and the
//! hypotheses), `choose` (which hypotheses count, the candidates and fallbacks, `settle`),
//! `phases` (the pulled and released steps, the keep-or-undo tests, `guard`), `patch` (the
//! patch hypothesis's profile). This file runs the hops in order (`Stage`).
//!
//! Owns: the hop's order and its report. Must not touch: the fit's schedule, the model maths.

mod choose;
mod evaluate;
mod patch;
mod phases;
mod record;
#[cfg(test)]
mod tests;

pub use record::{HopCandidate, HopReport, Hypothesis, SegmentObjective};

use super::pixels::PixelStore;
use crate::config::{HopConfig, TrainSection};
use choose::{
    anchor_target, candidates, patch_as_metal, patch_fallbacks, plain_fallbacks, settled,
    thresholds,
};
use evaluate::{Hypotheses, checks, evaluate, sample, whole};
use fipt_core::model::loss::DiffusePrior;
use fipt_core::model::step::SegMode;
use fipt_core::model::{FiptModel, Trainer};
use patch::PatchSegments;
use phases::{harmed, hop_helped, hop_phases, plain_held};

/// What a hop needs of its fit besides the trainer and the pixels.
pub struct HopPlan<'a> {
    pub cfg: &'a HopConfig,
    pub mode: SegMode,
    pub schedule: &'a TrainSection,
    /// The fit's λ_d at its last step (the objective holds `prior` × this).
    pub lambda_d: f32,
    pub seed: u64,
    pub show_progress: bool,
    /// The last round's model (`train.hop.carry`; None in round 0).
    pub carried: Option<&'a FiptModel>,
    /// Whether the fit ran on refined shadings (rounds after 0: `train.hop.settle` applies).
    pub refined: bool,
    /// A pixel's footprint in world units at the median depth (`train.hop.patch` counts its
    /// cubes' side in these).
    pub footprint: f32,
}

/// Tries a hop after a finished fit on `store`: returns the trainer to keep (the hopped one, or
/// `tr` as it came) and what happened. Without segments (`SegMode::None`) nothing hops.
///
/// Ctrl-C stops it between two steps with `interrupt::Interrupted` (the caller has saved the
/// fit's end; a run again redoes the hop from there).
pub fn hop(
    tr: Trainer,
    store: &PixelStore,
    plan: &HopPlan,
) -> anyhow::Result<(Trainer, HopReport)> {
    if plan.mode == SegMode::None || store.is_empty() {
        return Ok((tr, HopReport::default()));
    }
    let samples = sample(store, plan.cfg.pixels);
    let held = plan.lambda_d * plan.cfg.prior;
    let prior = DiffusePrior {
        lambda_d: held,
        sigma: tr.cfg.prior_sigma,
    };
    let with = Hypotheses {
        sweep: true,
        metal: plan.cfg.metal,
        uniform: &[],
        carried: plan.carried.filter(|_| plan.cfg.carry),
    };
    let before = evaluate(&tr.model, store, &samples, prior, with);
    let mut segments = checks(&samples, &before);
    let patches =
        (plan.cfg.patch > 0.0).then(|| PatchSegments::new(store, plan.cfg.patch * plan.footprint));
    if let Some(p) = &patches {
        for row in &mut segments {
            let metal = patch_as_metal(plan.cfg, row.metallic);
            if let Some((best, share)) = p.profile(&tr.model, row.segment, metal) {
                row.patch = Some(best);
                row.patch_share = Some(share);
            }
            row.settled = settled(plan.cfg, plan.refined, row);
        }
    }
    let mut fallbacks = if plan.cfg.patch_fallback {
        patch_fallbacks(plan.cfg, &segments)
    } else {
        Vec::new()
    };
    let mut plains = plain_fallbacks(plan.cfg, &segments);
    let mut report = HopReport {
        candidates: candidates(plan.cfg, &segments),
        segments,
        objective_before: whole(&samples, &before),
        lambda_d: held as f64,
        ..HopReport::default()
    };
    if report.candidates.is_empty() {
        return Ok((tr, report));
    }
    // Up to three hops, one after the other, each kept or undone on its own (`Stage`).
    let mut tr = tr;
    let mut cands = std::mem::take(&mut report.candidates);
    let mut after = Vec::new();
    // Each segment's mean σ and m before each hop (or its settled σ and m 0): where `anchor`
    // > 0, the segments not hopping are pulled there through both phases.
    let settle: Vec<Option<f64>> = report.segments.iter().map(|r| r.settled).collect();
    let mut held_at: Vec<(i32, f64, f64)> = samples
        .iter()
        .zip(&before)
        .zip(&settle)
        .map(|((s, e), t)| {
            let (sigma, m) = anchor_target(*t, e.sigma, e.metallic);
            (s.id, sigma, m)
        })
        .collect();
    // Each segment's objective as the next hop finds it.
    let mut entering: Vec<f64> = before.iter().map(|e| e.own).collect();
    for stage in [Stage::First, Stage::Plain, Stage::Patch] {
        // The segments of an undone first hop hop again: the plain metals alone, then the
        // patch hypotheses with the patch candidates (but for the segments the plain metals'
        // hop kept).
        if !report.accepted {
            match stage {
                Stage::First => {}
                Stage::Plain => cands.append(&mut plains),
                Stage::Patch => cands.append(&mut fallbacks),
            }
        }
        let group: Vec<usize> = (0..cands.len())
            .filter(|&k| Stage::of(&cands[k]) == stage)
            .collect();
        if group.is_empty() {
            continue;
        }
        let mut chosen: Vec<HopCandidate> = group.iter().map(|&k| cands[k].clone()).collect();
        // What each try is scored at: the plain metals at one colour per segment too (only they).
        let plain: Vec<i32> = match stage {
            Stage::Plain => chosen.iter().map(|c| c.segment).collect(),
            _ => Vec::new(),
        };
        let with = Hypotheses {
            uniform: &plain,
            ..Hypotheses::default()
        };
        let kind = stage.kind();
        let kept = tr.clone();
        let mut guards: Vec<(i32, f64, f64)> = Vec::new();
        let mut helped = false;
        // A first try; with `guard`, a second from the same start where the first harmed a
        // segment that was not hopping, that segment held where it was.
        for attempt in 0..2 {
            let start = if attempt == 0 { tr } else { kept.clone() };
            let (hopped, steps) =
                hop_phases(start, store, plan, &chosen, &guards, &held_at, stage)?;
            tr = hopped;
            report.steps += steps;
            after = evaluate(&tr.model, store, &samples, prior, with);
            for c in &mut chosen {
                if let Some(k) = samples.iter().position(|s| s.id == c.segment) {
                    c.sigma_after = after[k].sigma;
                    c.metallic_after = after[k].metallic;
                    // A plain metal is measured at one colour per segment, as proposed.
                    c.objective_after = if stage == Stage::Plain {
                        after[k].uniform
                    } else {
                        after[k].own
                    };
                }
                // A patch candidate is measured as it was proposed: with the colour solved
                // per patch.
                if let (Stage::Patch, Some(p)) = (stage, &patches) {
                    let metal = patch_as_metal(plan.cfg, c.metallic);
                    c.objective_after = p.at_model(&tr.model, c.segment, metal);
                }
            }
            let gain = thresholds(plan.cfg, kind).0;
            helped = if stage == Stage::Plain {
                plain_held(&chosen, gain)
            } else {
                hop_helped(&chosen, gain)
            };
            if attempt > 0 || !(helped && plan.cfg.guard) {
                break;
            }
            let hopping: Vec<i32> = chosen.iter().map(|c| c.segment).collect();
            guards = harmed(plan.cfg, kind, &hopping, &entering, &after, &held_at);
            if guards.is_empty() {
                break;
            }
            report.guarded.extend(guards.iter().map(|g| g.0));
        }
        match stage {
            Stage::First => report.accepted = helped,
            Stage::Plain => report.plain_accepted = Some(helped),
            Stage::Patch => report.patch_accepted = Some(helped),
        }
        if !helped {
            tr = kept;
            after = evaluate(&tr.model, store, &samples, prior, Hypotheses::default());
        }
        entering = after.iter().map(|e| e.own).collect();
        if stage == Stage::Plain && helped {
            fallbacks.retain(|f| chosen.iter().all(|c| c.segment != f.segment));
        }
        for (&k, c) in group.iter().zip(chosen) {
            cands[k] = c;
        }
        // A segment whose hop was kept is held where it hopped to, not where it settled.
        for ((h, a), t) in held_at.iter_mut().zip(&after).zip(&settle) {
            let hopped = helped && group.iter().any(|&k| cands[k].segment == h.0);
            (h.1, h.2) = anchor_target(if hopped { None } else { *t }, a.sigma, a.metallic);
        }
    }
    report.candidates = cands;
    for (row, a) in report.segments.iter_mut().zip(&after) {
        row.after = Some(a.own);
        row.sigma_after = Some(a.sigma);
        row.metallic_after = Some(a.metallic);
    }
    report.objective_after = Some(whole(&samples, &after));
    Ok((tr, report))
}

/// The hops tried after a fit, in order, each kept or undone on its own.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Stage {
    /// The sweep, metal and carried candidates, measured against the fit.
    First,
    /// The plain metals of an undone first hop's segments, alone (`train.hop.plain_metal`),
    /// held at their targets through both phases and measured at one colour per segment.
    Plain,
    /// The patch candidates, with the fallbacks of an undone first hop, measured in their own
    /// terms and held at their targets through both phases.
    Patch,
}

impl Stage {
    /// The stage a candidate hops in.
    fn of(c: &HopCandidate) -> Stage {
        if c.source == Hypothesis::Patch {
            Stage::Patch
        } else if c.alone {
            Stage::Plain
        } else {
            Stage::First
        }
    }

    /// The hypothesis whose `thresholds` the stage's decision and guard use.
    fn kind(self) -> Hypothesis {
        match self {
            Stage::First => Hypothesis::Sweep,
            Stage::Plain => Hypothesis::Metal,
            Stage::Patch => Hypothesis::Patch,
        }
    }

    /// Whether its candidates stay pulled to their targets through the release phase.
    fn held(self) -> bool {
        self != Stage::First
    }

    /// Its hop's stream of random draws.
    fn stream(self) -> u64 {
        match self {
            Stage::First => 0x40b,
            Stage::Patch => 0x40c,
            Stage::Plain => 0x40d,
        }
    }
}
