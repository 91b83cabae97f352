//! A hop's training steps and its decision: the fit continued with the candidates pulled to
//! their targets, then released; whether the hop helped (or, for the plain metals, held); which
//! segments a kept hop harmed (`guard`).
//!
//! Owns: the pulls and the steps. Must not touch: the choice of candidates (`choose`), the
//! objective (`evaluate`).

use super::choose::thresholds;
use super::evaluate::SegmentEval;
use super::record::{HopCandidate, Hypothesis};
use super::{HopPlan, Stage};
use crate::config::HopConfig;
use crate::pipeline::batches::{Sampler, Shape, step_entries};
use crate::pipeline::pixels::PixelStore;
use crate::progress::progress_bar;
use fipt_core::model::Trainer;
use fipt_core::model::step::{DeviceStore, SigmaPull};
use fipt_core::rng::Rng;

/// Whether the plain metals' hop held (`train.hop.plain_metal`): their size-weighted objective
/// at one colour per segment, after the hop, lies within `gain` of the fit's objective before
/// it (the colour free), as it did when the metal was proposed.
pub(super) fn plain_held(c: &[HopCandidate], gain: f32) -> bool {
    let sum = |f: fn(&HopCandidate) -> f64| c.iter().map(|c| f(c) * c.pixels as f64).sum::<f64>();
    sum(|c| c.objective_after) <= (1.0 + gain as f64) * sum(|c| c.objective)
}

/// The segments a kept hop harmed (`train.hop.guard`), with the σ and m to hold them at: those
/// not hopping whose objective rose by more than the hop's own `gain` (the share that calls
/// for a hop of that kind) while their mean σ left where the anchor held them (`held_at`) by at
/// least its `min_move` (as far as such a hop goes). The extra steps move a flat segment's σ
/// without raising its objective; a segment the hopping ones carried off its own minimum both
/// moves and scores worse.
pub(super) fn harmed(
    cfg: &HopConfig,
    kind: Hypothesis,
    hopping: &[i32],
    entering: &[f64],
    after: &[SegmentEval],
    held_at: &[(i32, f64, f64)],
) -> Vec<(i32, f64, f64)> {
    let (gain, min_move) = thresholds(cfg, kind);
    held_at
        .iter()
        .zip(entering.iter().zip(after))
        .filter(|(h, (was, a))| {
            !hopping.contains(&h.0)
                && a.own > (1.0 + gain as f64) * **was
                && (a.sigma - h.1).abs() >= min_move as f64
        })
        .map(|(h, _)| *h)
        .collect()
}

/// The hop's two phases on `tr` for `chosen`: the fit continues with σ (and m where a target
/// names one) pulled to their targets, then as many steps again released, except where the
/// `stage` holds them (`Stage::held`: the patch candidates, at the fit's free colour their data
/// flat over σ and the prior alone would take them back; the plain metals, whose data is as
/// flat between the metal and a dielectric) and, with `hold_metals` > 0, the candidates that
/// hop as metals,
/// pulled at that weight (with the colour free again the data is flat over a mirror's σ, and
/// the prior takes it rough). Where `anchor` > 0, every other segment of `held_at` (segment,
/// mean σ, mean m) is pulled to its σ and m through both phases. `guards` (segment, σ, m) are
/// pulled like the candidates, through the pull phase and, where held, the release too.
/// Returns the hopped trainer and the steps run.
pub(super) fn hop_phases(
    mut tr: Trainer,
    store: &PixelStore,
    plan: &HopPlan,
    chosen: &[HopCandidate],
    guards: &[(i32, f64, f64)],
    held_at: &[(i32, f64, f64)],
    stage: Stage,
) -> anyhow::Result<(Trainer, usize)> {
    let held = stage.held();
    // The fit's batch sizes and segments; draws of its own (uniform with replacement).
    let Shape {
        batch,
        balanced,
        steps: total,
        ..
    } = Shape::of(store, plan.mode, plan.schedule);
    let phase = ((plan.cfg.steps as f64 * total as f64).round() as usize).max(1);
    let segments = Sampler::segments_of(store, true);
    let mut rng = Rng::new(plan.seed, stage.stream());
    let ds = tr
        .device_resident()
        .then(|| DeviceStore::upload(&store.pixels, &tr.device));
    let lambda_d = tr.cfg.lambda_d;
    tr.cfg.lr = plan.schedule.lr_at(total.saturating_sub(1), total);
    tr.cfg.lambda_d = plan.lambda_d;
    let pull_of = |cands: &[&HopCandidate], weight: f32| SigmaPull {
        weight,
        target: cands.iter().map(|c| (c.segment, c.target as f32)).collect(),
        metallic: cands
            .iter()
            .filter_map(|c| Some((c.segment, c.target_metallic? as f32)))
            .collect(),
    };
    let mut pull = pull_of(&chosen.iter().collect::<Vec<_>>(), plan.cfg.pull);
    // The guarded segments, pulled where they were as the candidates are to their targets.
    for &(segment, sigma, m) in guards {
        pull.target.insert(segment, sigma as f32);
        pull.metallic.insert(segment, m as f32);
    }
    // The pull of the release phase: the same where `held`, else the candidates that hop as
    // metals at `hold_metals` (None: none).
    let release = if held {
        Some(pull.clone())
    } else {
        let metals: Vec<&HopCandidate> =
            chosen.iter().filter(|c| holds_metal(plan.cfg, c)).collect();
        (!metals.is_empty()).then(|| pull_of(&metals, plan.cfg.hold_metals))
    };
    // The segments not hopping, held where they were (`anchor`).
    let anchor = (plan.cfg.anchor > 0.0).then(|| {
        let others = held_at
            .iter()
            .filter(|h| chosen.iter().all(|c| c.segment != h.0));
        SigmaPull {
            weight: plan.cfg.anchor,
            target: others.clone().map(|h| (h.0, h.1 as f32)).collect(),
            metallic: others.map(|h| (h.0, h.2 as f32)).collect(),
        }
    });
    tr.pull = Some(pull);
    tr.anchor = anchor;
    let pb = progress_bar(2 * phase as u64, "hop", plan.show_progress);
    let mut idx = Vec::with_capacity(batch);
    for s in 0..2 * phase {
        if let Err(e) = crate::interrupt::check(|| "interrupted during a basin hop".into()) {
            pb.finish_and_clear();
            return Err(e);
        }
        if s == phase {
            tr.pull = release.clone();
        }
        idx.clear();
        for _ in 0..batch - balanced {
            idx.push(rng.below(store.len() as u64) as u32);
        }
        for _ in 0..balanced {
            let seg = &segments[rng.below(segments.len() as u64) as usize];
            idx.push(seg[rng.below(seg.len() as u64) as usize]);
        }
        // The loss is not logged: the decision evaluates the objective itself.
        drop(step_entries(&mut tr, ds.as_ref(), store, &idx, plan.mode));
        pb.inc(1);
    }
    pb.finish_and_clear();
    tr.pull = None;
    tr.anchor = None;
    tr.cfg.lambda_d = lambda_d;
    tr.sync_host_table();
    Ok((tr, 2 * phase))
}

/// Whether `c` hops as a metal that `train.hop.hold_metals` keeps pulled to its target through
/// the release phase: its target names m ≥ 0.5, or names no m and the fit has it at m ≥ 0.5.
pub(super) fn holds_metal(cfg: &HopConfig, c: &HopCandidate) -> bool {
    cfg.hold_metals > 0.0 && c.target_metallic.unwrap_or(c.metallic) >= 0.5
}

/// Whether the candidates' size-weighted objective fell by at least `gain` of itself (the
/// share that called for the hop: the extra steps alone move a segment's objective by a few
/// per cent either way).
pub(super) fn hop_helped(c: &[HopCandidate], gain: f32) -> bool {
    let sum = |f: fn(&HopCandidate) -> f64| c.iter().map(|c| f(c) * c.pixels as f64).sum::<f64>();
    sum(|c| c.objective_after) <= (1.0 - gain as f64) * sum(|c| c.objective)
}
