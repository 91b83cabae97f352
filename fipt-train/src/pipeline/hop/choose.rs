//! Which hypotheses count and which segments hop: the candidates of the first hop, the
//! fallbacks of an undone one (the patch's and the plain metals'), and where the anchor holds
//! the segments that do not hop (`settle`).
//!
//! Owns: the thresholds and the choice. Must not touch: the objective (`evaluate`), the
//! training steps (`phases`).

use super::record::{HopCandidate, Hypothesis, SegmentObjective};
use crate::config::HopConfig;

/// A hypothesis's (gain, min_move): the patch hypothesis has its own (`patch_gain`,
/// `patch_min_move`), the others share `gain` and `min_move`.
pub(super) fn thresholds(cfg: &HopConfig, source: Hypothesis) -> (f32, f32) {
    if source == Hypothesis::Patch {
        (cfg.patch_gain, cfg.patch_min_move)
    } else {
        (cfg.gain, cfg.min_move)
    }
}

/// The segments to hop and their targets. Each hypothesis proposes a target: the sweep's best σ
/// (m left free), a metal's best σ with m = 1 (for a segment fitted non-metallic), and the
/// last round's mean σ and m. Each is measured against a baseline of its own kind: the sweep
/// and the carried material against the fit's objective, the metal (one colour per segment)
/// against one colour per segment at the fitted σ and m, since the fit's own base colour, free
/// at every point, explains any σ better than one colour does. One counts where it lowers its
/// baseline by at least `gain` of it and, for the sweep and the metal, lies far from the fit
/// (σ at least `min_move` away, or m across 0.5; nearer minima are descent's to find). The
/// carried material needs no distance: it is a whole material that a fit already reached, and
/// a mirror's σ 0.1 against 0.25 is a lost part. Of those, the largest relative gain wins;
/// with `carried_first`, a metal hypothesis only where no carried material counts. A segment
/// already at zero (e.g. all behind the emission mask) has nothing to gain.
pub(super) fn candidates(cfg: &HopConfig, checks: &[SegmentObjective]) -> Vec<HopCandidate> {
    checks
        .iter()
        .filter_map(|c| options(cfg, c).into_iter().next())
        .collect()
}

/// The segments whose winning hypothesis is not the patch's, with their patch hypothesis where
/// it counts too: if the first hop is undone, these hop with the patch candidates.
pub(super) fn patch_fallbacks(cfg: &HopConfig, checks: &[SegmentObjective]) -> Vec<HopCandidate> {
    first_hop_fallbacks(cfg, checks, cfg, |h| h.source == Hypothesis::Patch)
}

/// For each segment whose winning hypothesis (under `cfg`) is not the patch's, so that it hops
/// in the first hop: the first of its hypotheses under `alternatives`, best first, that `pick`
/// accepts.
pub(super) fn first_hop_fallbacks(
    cfg: &HopConfig,
    checks: &[SegmentObjective],
    alternatives: &HopConfig,
    pick: impl Fn(&HopCandidate) -> bool,
) -> Vec<HopCandidate> {
    checks
        .iter()
        .filter_map(|c| {
            let first = options(cfg, c).into_iter().next()?;
            (first.source != Hypothesis::Patch)
                .then(|| options(alternatives, c).into_iter().find(&pick))
                .flatten()
        })
        .collect()
}

/// The segments whose winning hypothesis is not the patch's and whose metal hypothesis counts
/// and is plain (`train.hop.plain_metal`), with that metal hypothesis, whether it won or gave
/// way to the carried material or a larger gain: if the first hop is undone, these hop again
/// as that metal, alone.
pub(super) fn plain_fallbacks(cfg: &HopConfig, checks: &[SegmentObjective]) -> Vec<HopCandidate> {
    if !cfg.plain_metal {
        return Vec::new();
    }
    let every = HopConfig {
        carried_first: false,
        ..cfg.clone()
    };
    first_hop_fallbacks(cfg, checks, &every, |h| h.plain)
        .into_iter()
        .map(|c| HopCandidate { alone: true, ..c })
        .collect()
}

/// Every hypothesis that counts for one segment (`candidates`), the largest relative gain
/// first.
pub(super) fn options(cfg: &HopConfig, c: &SegmentObjective) -> Vec<HopCandidate> {
    if c.before <= 0.0 {
        return Vec::new();
    }
    let far = |source: Hypothesis, sigma: f64, m: Option<f64>| {
        (sigma - c.sigma).abs() >= thresholds(cfg, source).1 as f64
            || m.is_some_and(|m| (m >= 0.5) != (c.metallic >= 0.5))
    };
    // (hypothesis, σ, m, objective, baseline)
    let mut options = vec![(Hypothesis::Sweep, c.best_sigma, None, c.best, c.before)];
    if let Some((sigma, obj, base)) = c.metal
        && c.metallic < 0.5
    {
        options.push((Hypothesis::Metal, sigma, Some(1.0), obj, base));
    }
    if let Some((sigma, m, obj)) = c.carried {
        let m = ((m >= 0.5) != (c.metallic >= 0.5)).then_some(m);
        options.push((Hypothesis::Carried, sigma, m, obj, c.before));
    }
    // Dielectrics, and with `patch_metals` metals too (else a metal's σ is the sweep's and the
    // metal's to find). With `patch_dielectric` it names the m it was solved at: 0 for a
    // dielectric, 1 for a metal.
    if let Some((sigma, obj, base)) = c.patch
        && (c.metallic < 0.5 || cfg.patch_metals)
        && preferred(cfg, c.patch_share)
    {
        let m = cfg
            .patch_dielectric
            .then_some(if patch_as_metal(cfg, c.metallic) {
                1.0
            } else {
                0.0
            });
        options.push((Hypothesis::Patch, sigma, m, obj, base));
    }
    let gain = |obj: f64, base: f64| 1.0 - obj / base;
    options.retain(|&(source, sigma, m, obj, base)| {
        obj.is_finite()
            && base > 0.0
            && (source == Hypothesis::Carried || far(source, sigma, m))
            && gain(obj, base) >= thresholds(cfg, source).0 as f64
    });
    // With `carried_first`, a carried material that counts outranks the metal hypothesis.
    if cfg.carried_first && options.iter().any(|o| o.0 == Hypothesis::Carried) {
        options.retain(|o| o.0 != Hypothesis::Metal);
    }
    options.sort_by(|a, b| gain(b.3, b.4).total_cmp(&gain(a.3, a.4)));
    options
        .into_iter()
        .map(|(source, target, target_metallic, obj, base)| {
            // A patch candidate is measured in its own terms throughout.
            let measured = if source == Hypothesis::Patch {
                base
            } else {
                c.before
            };
            let plain = cfg.plain_metal
                && source == Hypothesis::Metal
                && obj <= (1.0 + cfg.gain as f64) * c.before;
            HopCandidate {
                segment: c.segment,
                pixels: c.pixels,
                sigma: c.sigma,
                target,
                sigma_after: c.sigma,
                source,
                metallic: c.metallic,
                target_metallic,
                metallic_after: c.metallic,
                objective: measured,
                objective_target: obj,
                objective_after: measured,
                plain,
                alone: false,
            }
        })
        .collect()
}

/// Whether a segment of mean fitted m `metallic` has its patch hypothesis solved as a metal
/// (`train.hop.patch_metals`, fitted m ≥ 0.5) rather than as a dielectric.
pub(super) fn patch_as_metal(cfg: &HopConfig, metallic: f64) -> bool {
    cfg.patch_metals && metallic >= 0.5
}

/// Whether most of a segment's surface prefers its patch hypothesis (`train.hop.patch_majority`
/// z): the share of its pixels whose cube scores lower at the hypothesis than at the fit lies
/// no more than z standard errors of a fair coin's share, 0.5 / √(effective cubes), below a
/// half. A hypothesis that lowers the sum on a few cubes, where the shadings are off, while
/// most of the surface prefers the fit, does not count; a small part's few cubes cannot tell
/// and pass. Null, or no share: every patch hypothesis passes.
pub(super) fn preferred(cfg: &HopConfig, share: Option<(f64, f64)>) -> bool {
    match (cfg.patch_majority, share) {
        (Some(z), Some((share, cubes))) if cubes > 0.0 => {
            share >= 0.5 - z as f64 * 0.5 / cubes.sqrt()
        }
        _ => true,
    }
}

/// The σ the anchor holds a segment at in place of its fitted one (`train.hop.settle`), with
/// m 0: on refined shadings, a dielectric's patch sweep minimum where it lies within `min_move`
/// of the fit (nearer than any hop goes; its data is flat there, and the prior decided where
/// the fit left it), or its fitted σ where that minimum scores no lower than the fitted σ
/// does (the minimum is the fit's σ, between two swept values); its fitted σ where its patch
/// hypothesis counts by gain and distance but most of its surface prefers the fit
/// (`preferred`: the hypothesis is a dielectric's, and so is the fit it loses to). None: held
/// at its fitted σ and m.
pub(super) fn settled(cfg: &HopConfig, refined: bool, c: &SegmentObjective) -> Option<f64> {
    if !(cfg.settle && refined && cfg.anchor > 0.0) || c.metallic >= 0.5 {
        return None;
    }
    let (sigma, obj, base) = c.patch?;
    if !obj.is_finite() {
        return None;
    }
    let far = (sigma - c.sigma).abs();
    if far < cfg.min_move as f64 {
        // Where no swept σ scores below the fitted one, the patch minimum is the fit's σ.
        return Some(if obj < base { sigma } else { c.sigma });
    }
    if obj >= base {
        return None;
    }
    let (gain, min_move) = thresholds(cfg, Hypothesis::Patch);
    let counts = far >= min_move as f64 && 1.0 - obj / base >= gain as f64;
    (counts && !preferred(cfg, c.patch_share)).then_some(c.sigma)
}

/// The σ and m the anchor holds a segment at: where it is settled, its patch hypothesis (the
/// settled σ, and m 0: a dielectric's), else its fitted `sigma` and `m`.
pub(super) fn anchor_target(settled: Option<f64>, sigma: f64, m: f64) -> (f64, f64) {
    settled.map_or((sigma, m), |s| (s, 0.0))
}
