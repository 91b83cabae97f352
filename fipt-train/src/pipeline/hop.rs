//! Basin hopping on the roughness, per segment (a departure from the reference, `train.hop`):
//! after a fit, the fit's objective (its data term, and `prior` × its diffuse prior) is swept
//! over one common σ per segment at the fitted base colour and metallic; where a σ far from the
//! fitted one scores clearly lower, the fit
//! continues with σ pulled there (`SigmaPull`), then released (trained as in the fit's last
//! step), and the hopped model is kept only if the hopped segments' objective fell by at least
//! `gain` too. The other
//! segments see only more steps of the same fit, held at their mean σ and m by a pull of their
//! own where `anchor` > 0 (the networks are shared, and a strong pull on some segments carries
//! the rest along); their objective is not part of the decision: on fipt-room it moves by
//! ±1–4 % per segment in those steps, and the emitters' pixels (α ≈ 1, objective ~0.4 per pixel
//! against ~1e-3 elsewhere) would decide it alone. With `patch_fallback`, a segment whose first
//! hop (sweep, metal or carried) is undone tries its patch hypothesis in the second. With
//! `settle`, the anchor holds a dielectric of a refined round at its patch hypothesis (its
//! sweep's nearby minimum, and m = 0) rather than where the prior left it. With `hold_metals`,
//! a candidate that hops as a metal stays pulled to its target through the release phase.
//! With `plain_metal`, a segment of an undone first hop whose metal hypothesis scores within
//! `gain` of the fit with one colour per segment hops again as that metal, alone, measured at
//! one colour per segment.
//! With `patch_majority` z, a patch hypothesis counts only where the share of the segment's
//! cubes that prefer it lies at most z standard errors below a half (`patches::preference`),
//! and a refined round's dielectric whose far patch hypothesis fails that test is settled at
//! its fitted σ with m = 0.
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
//! Owns: the sweep, the hop's two phases and its decision. Must not touch: the fit's schedule,
//! the model maths.

use super::batches::{Sampler, Shape, step_entries};
use super::landscape::sweep;
use super::pixels::PixelStore;
use crate::config::{HopConfig, TrainSection};
use crate::progress::progress_bar;
use fipt_core::brdf::{factorised_render, reflectances};
use fipt_core::model::loss::{DiffusePrior, tonemap_host as tonemap};
use fipt_core::model::step::{DeviceStore, SegMode, SigmaPull};
use fipt_core::model::{FiptModel, Trainer};
use fipt_core::rng::Rng;
use fipt_core::shading::ShadingLayout;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// A segment the sweep sent hopping.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct HopCandidate {
    /// Segment id (part or semantic label).
    pub segment: i32,
    /// Its pixels in the store.
    pub pixels: usize,
    /// Mean fitted σ before the hop, the target, and the mean σ after it.
    pub sigma: f64,
    pub target: f64,
    pub sigma_after: f64,
    /// Which hypothesis proposed the target (`Hypothesis`).
    #[serde(default)]
    pub source: Hypothesis,
    /// Mean fitted m before the hop, its target (None: m is not pulled) and after it.
    #[serde(default)]
    pub metallic: f64,
    #[serde(default)]
    pub target_metallic: Option<f64>,
    #[serde(default)]
    pub metallic_after: f64,
    /// The segment's objective at the fit, at the target σ (fitted a and m) and after the hop.
    pub objective: f64,
    pub objective_target: f64,
    pub objective_after: f64,
    /// A metal hypothesis whose one colour scores within `gain` of the fit
    /// (`train.hop.plain_metal`). In the plain metals' own hop, `objective_after` is the
    /// hopped segment's objective at one colour per segment.
    #[serde(default)]
    pub plain: bool,
    /// This record is the plain metal's second hop, alone, after the first was undone (kept
    /// or undone by `HopReport::plain_accepted`).
    #[serde(default)]
    pub alone: bool,
}

/// A segment at the hop's check: its mean fitted σ and objective, the sweep's best σ and
/// objective there, and its objective after the hop (None where none ran).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SegmentObjective {
    pub segment: i32,
    pub pixels: usize,
    pub sigma: f64,
    pub before: f64,
    pub best_sigma: f64,
    pub best: f64,
    pub after: Option<f64>,
    /// Mean σ and m after the hop (the model kept).
    #[serde(default)]
    pub sigma_after: Option<f64>,
    #[serde(default)]
    pub metallic_after: Option<f64>,
    /// Mean fitted m.
    #[serde(default)]
    pub metallic: f64,
    /// The metal hypothesis's best σ and objective, and the objective of one colour per
    /// segment at the fitted mean σ and m, which it is measured against (`train.hop.metal`;
    /// None: not tried).
    #[serde(default)]
    pub metal: Option<(f64, f64, f64)>,
    /// The last round's material on this segment under these shadings: its mean σ and m, and
    /// its objective (`train.hop.carry`; None: round 0, or off).
    #[serde(default)]
    pub carried: Option<(f64, f64, f64)>,
    /// With the base colour solved per patch over all the segment's pixels
    /// (`train.hop.patch`), at one common σ as a dielectric (as a metal for a segment fitted
    /// metallic, with `train.hop.patch_metals`): the best swept σ, the objective there, and the
    /// objective at the fitted mean σ (None: not tried).
    #[serde(default)]
    pub patch: Option<(f64, f64, f64)>,
    /// How many of the patch hypothesis's cubes prefer its best σ to the fitted mean σ
    /// (`patches::preference`): the share of the segment's pixels in those cubes, and the
    /// effective number of cubes (None: not tried).
    #[serde(default)]
    pub patch_share: Option<(f64, f64)>,
    /// The σ the anchor held it at in place of its fitted one, with m 0 (`train.hop.settle`;
    /// None: its fitted σ and m, or not held).
    #[serde(default)]
    pub settled: Option<f64>,
}

/// What proposed a hop's target.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Hypothesis {
    /// The sweep over σ at the fitted base colour (scaled) and metallic.
    #[default]
    Sweep,
    /// The sweep over σ of a metal (m = 1) with one base colour per segment.
    Metal,
    /// The last round's material (σ and m) on the segment.
    Carried,
    /// The sweep over σ with the base colour solved per surface patch (`patches`).
    Patch,
}

/// What a hop did: the candidates, whether the hopped model was kept (the candidates'
/// size-weighted objective fell by `gain`), and for the record every segment's check and the whole
/// objective (every segment, size-weighted) before and after.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct HopReport {
    pub candidates: Vec<HopCandidate>,
    #[serde(default)]
    pub segments: Vec<SegmentObjective>,
    pub objective_before: f64,
    pub objective_after: Option<f64>,
    pub accepted: bool,
    /// Whether the plain metals' hop, run after an undone first hop, was kept (None: none
    /// ran; `train.hop.plain_metal`).
    #[serde(default)]
    pub plain_accepted: Option<bool>,
    /// Whether the patch candidates' hop, run after the others, was kept (None: none ran).
    #[serde(default)]
    pub patch_accepted: Option<bool>,
    /// Steps run (both phases of each hop).
    pub steps: usize,
    /// The λ_d the objectives above hold (`prior` × the fit's final λ_d; 0: the data term).
    #[serde(default)]
    pub lambda_d: f64,
    /// The segments a kept hop harmed, held where they were on its second try
    /// (`train.hop.guard`).
    #[serde(default)]
    pub guarded: Vec<i32>,
}

/// One segment's pixels in the evaluation: its id, its size in the store, the entries used.
struct SegmentSample {
    id: i32,
    size: usize,
    idx: Vec<u32>,
}

/// Up to `per` entries of every segment, evenly strided.
fn sample(store: &PixelStore, per: usize) -> Vec<SegmentSample> {
    let mut by: BTreeMap<i32, Vec<u32>> = BTreeMap::new();
    for (i, &s) in store.pixels.seg.iter().enumerate() {
        by.entry(s).or_default().push(i as u32);
    }
    by.into_iter()
        .map(|(id, all)| {
            let size = all.len();
            let take = size.min(per.max(1));
            let idx = (0..take).map(|k| all[k * size / take]).collect();
            SegmentSample { id, size, idx }
        })
        .collect()
}

/// A segment's objective at the model, and over the hypotheses.
struct SegmentEval {
    sigma: f64,
    metallic: f64,
    own: f64,
    /// At each swept σ, the least objective over the base-colour scales (`SCALES`).
    sweep: Vec<f64>,
    /// At each swept σ, the least objective of a metal over the scales of its colour.
    metal: Vec<f64>,
    /// The least objective over the scales of one colour per segment at the fitted mean σ and
    /// m (NaN where the metal was not tried).
    uniform: f64,
    /// The carried material's mean σ, mean m and objective.
    carried: Option<(f64, f64, f64)>,
}

/// Scales of the fitted base colour tried at each swept σ: 0.5, 0.55, …, 1.5. A part fitted in
/// the wrong σ basin has a base colour that absorbed its highlights (a rough fit is brighter), so
/// σ alone at that colour under-rates the other basin; the profile over one common scale per
/// segment does not.
const SCALES: usize = 21;

fn scale(j: usize) -> f32 {
    0.5 + j as f32 / (SCALES - 1) as f32
}

/// What `evaluate` scores besides the model itself.
#[derive(Clone, Copy, Default)]
struct Hypotheses<'a> {
    /// The σ sweep at the fitted base colour (scaled) and metallic.
    sweep: bool,
    /// The σ sweep of a metal with one base colour per segment.
    metal: bool,
    /// One colour per segment at the fitted mean σ and m (scored with `metal` too).
    uniform: bool,
    /// The last round's model, whose material is scored under these shadings.
    carried: Option<&'a FiptModel>,
}

/// One pixel's objective (Eq. 15 + Eq. 17's summand) at base colour `a`, roughness `sigma`
/// and metallic `m`, for emission mask `alpha`, packed shadings `sh` and photo `gt`.
fn pixel_objective(
    (a, sigma, m): (glam::Vec3, f32, f32),
    alpha: f32,
    sh: &[f32],
    gt: &[f32],
    prior: DiffusePrior,
) -> f64 {
    let (kd, ks) = reflectances(a, m);
    let c = factorised_render(kd.to_array(), ks.to_array(), sigma, sh);
    let data = (0..3)
        .map(|k| (tonemap((1.0 - alpha) * c[k] + alpha * gt[k]) - tonemap(gt[k])).powi(2))
        .sum::<f64>()
        / 3.0;
    data + prior.at(sigma, m) as f64
}

/// One base colour for a segment's pixels at roughness `sigma` and metallic `m`: the render
/// k_d·L_d + k_s·L_s0(σ) + L_s1(σ) is a·P + Q per channel, with P = (1 − m)·L_d + m·L_s0 and
/// Q = 0.04·(1 − m)·L_s0 + L_s1, and a is its linear least-squares fit to the photos, each pixel
/// weighted by its share (1 − α)² of the composite; clamped to [0, 1]. With m = 1 it is a
/// metal's colour, a·L_s0(σ) + L_s1(σ).
fn uniform_colour(
    b: &fipt_core::model::step::Batch,
    alpha: &[f32],
    sigma: f32,
    m: f32,
) -> glam::Vec3 {
    let (mut num, mut den) = ([0.0f64; 3], [0.0f64; 3]);
    for (i, al) in alpha.iter().enumerate() {
        let sh = ShadingLayout::pixel(&b.shadings, i);
        let (s0, s1) = fipt_core::brdf::specular_shadings(sigma, sh);
        let wt = ((1.0 - al) * (1.0 - al)) as f64;
        for c in 0..3 {
            let p = (1.0 - m) * sh[ShadingLayout::LD.start + c] + m * s0[c];
            let q = 0.04 * (1.0 - m) * s0[c] + s1[c];
            num[c] += wt * (p * (b.gt[3 * i + c] - q)) as f64;
            den[c] += wt * (p * p) as f64;
        }
    }
    glam::Vec3::from_array(std::array::from_fn(|c| {
        if den[c] > 0.0 {
            (num[c] / den[c]).clamp(0.0, 1.0) as f32
        } else {
            0.0
        }
    }))
}

/// Eq. 15 + 17 per segment of `samples` at the model's a, σ, m and α, and at the hypotheses
/// asked for: the profile over σ at the fitted (scaled) base colour and metallic, that of a
/// metal, and the last round's material.
fn evaluate(
    model: &FiptModel,
    store: &PixelStore,
    samples: &[SegmentSample],
    prior: DiffusePrior,
    with: Hypotheses,
) -> Vec<SegmentEval> {
    use rayon::prelude::*;
    let sig = sweep();
    samples
        .iter()
        .map(|s| {
            let b = store.batch(&s.idx);
            let mat = model.material(&b.x_unit, &b.part);
            let alpha = model.alpha(&b.x_world);
            let n = s.idx.len() as f64;
            let term = |i: usize, am: (glam::Vec3, f32, f32)| -> f64 {
                let sh = ShadingLayout::pixel(&b.shadings, i);
                pixel_objective(am, alpha[i], sh, &b.gt[3 * i..3 * i + 3], prior)
            };
            let base = |i: usize| glam::Vec3::from_slice(&mat.a[3 * i..3 * i + 3]);
            // Sums over pixels, each in pixel order (so that a run gives the same bits on any
            // number of threads), per (σ, scale) cell of a profile in parallel over the cells.
            let pixels = 0..s.idx.len();
            let mean = |v: &[f32]| v.iter().map(|&x| x as f64).sum::<f64>() / n;
            let own: f64 = pixels
                .clone()
                .map(|i| term(i, (base(i), mat.sigma[i], mat.metallic[i])))
                .sum();
            // At each σ of `sigmas` (the k-th), the least objective over the scales of
            // `colour(k, pixel)`, with `metallic(pixel)`.
            let profile = |sigmas: &[f32],
                           colour: &(dyn Fn(usize, usize) -> glam::Vec3 + Sync),
                           metallic: &(dyn Fn(usize) -> f32 + Sync)| {
                let grid: Vec<f64> = (0..sigmas.len() * SCALES)
                    .into_par_iter()
                    .map(|cell| {
                        let (k, j) = (cell / SCALES, cell % SCALES);
                        pixels
                            .clone()
                            .map(|i| {
                                let a = (colour(k, i) * scale(j)).min(glam::Vec3::ONE);
                                term(i, (a, sigmas[k], metallic(i)))
                            })
                            .sum()
                    })
                    .collect();
                grid.chunks(SCALES)
                    .map(|c| c.iter().fold(f64::INFINITY, |a, &b| a.min(b)) / n)
                    .collect::<Vec<f64>>()
            };
            let sweep = if with.sweep {
                profile(&sig, &|_, i| base(i), &|i| mat.metallic[i])
            } else {
                Vec::new()
            };
            let (sigma, metallic) = (mean(&mat.sigma), mean(&mat.metallic));
            let metal = if with.metal {
                let colours: Vec<glam::Vec3> = sig
                    .iter()
                    .map(|&sg| uniform_colour(&b, &alpha, sg, 1.0))
                    .collect();
                profile(&sig, &|k, _| colours[k], &|_| 1.0)
            } else {
                Vec::new()
            };
            // The same one-colour model at the fit's mean σ and m: what the metal is measured
            // against (the fit's own a, free per point, fits any σ better).
            let uniform = if with.metal || with.uniform {
                let (sg, m) = (sigma as f32, metallic as f32);
                let a = uniform_colour(&b, &alpha, sg, m);
                profile(&[sg], &|_, _| a, &|_| m)[0]
            } else {
                f64::NAN
            };
            let carried = with.carried.map(|prev| {
                let pm = prev.material(&b.x_unit, &b.part);
                let obj: f64 = pixels
                    .clone()
                    .map(|i| {
                        let a = glam::Vec3::from_slice(&pm.a[3 * i..3 * i + 3]);
                        term(i, (a, pm.sigma[i], pm.metallic[i]))
                    })
                    .sum();
                (mean(&pm.sigma), mean(&pm.metallic), obj / n)
            });
            SegmentEval {
                sigma,
                metallic,
                own: own / n,
                sweep,
                metal,
                uniform,
                carried,
            }
        })
        .collect()
}

/// The objective over all segments, each weighted by its size.
fn whole(samples: &[SegmentSample], evals: &[SegmentEval]) -> f64 {
    let n: usize = samples.iter().map(|s| s.size).sum();
    samples
        .iter()
        .zip(evals)
        .map(|(s, e)| e.own * s.size as f64)
        .sum::<f64>()
        / n.max(1) as f64
}

/// The least value of a profile over the swept σ and where it lies (NaN without a profile).
fn profile_min(profile: &[f64]) -> (f64, f64) {
    let sig = sweep();
    profile
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(b.1))
        .map_or((f64::NAN, f64::NAN), |(j, b)| (sig[j] as f64, *b))
}

/// Every segment's check: its mean fitted σ, m and objective, and each hypothesis's best
/// (NaN or None where it was not scored).
fn checks(samples: &[SegmentSample], evals: &[SegmentEval]) -> Vec<SegmentObjective> {
    samples
        .iter()
        .zip(evals)
        .map(|(s, e)| {
            let (best_sigma, best) = profile_min(&e.sweep);
            SegmentObjective {
                segment: s.id,
                pixels: s.size,
                sigma: e.sigma,
                before: e.own,
                best_sigma,
                best,
                after: None,
                sigma_after: None,
                metallic_after: None,
                metallic: e.metallic,
                metal: (!e.metal.is_empty()).then(|| {
                    let (sigma, obj) = profile_min(&e.metal);
                    (sigma, obj, e.uniform)
                }),
                carried: e.carried,
                patch: None,
                patch_share: None,
                settled: None,
            }
        })
        .collect()
}

/// A hypothesis's (gain, min_move): the patch hypothesis has its own (`patch_gain`,
/// `patch_min_move`), the others share `gain` and `min_move`.
fn thresholds(cfg: &HopConfig, source: Hypothesis) -> (f32, f32) {
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
fn candidates(cfg: &HopConfig, checks: &[SegmentObjective]) -> Vec<HopCandidate> {
    checks
        .iter()
        .filter_map(|c| options(cfg, c).into_iter().next())
        .collect()
}

/// The segments whose winning hypothesis is not the patch's, with their patch hypothesis where
/// it counts too: if the first hop is undone, these hop with the patch candidates.
fn patch_fallbacks(cfg: &HopConfig, checks: &[SegmentObjective]) -> Vec<HopCandidate> {
    first_hop_fallbacks(cfg, checks, cfg, |h| h.source == Hypothesis::Patch)
}

/// For each segment whose winning hypothesis (under `cfg`) is not the patch's, so that it hops
/// in the first hop: the first of its hypotheses under `alternatives`, best first, that `pick`
/// accepts.
fn first_hop_fallbacks(
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
fn plain_fallbacks(cfg: &HopConfig, checks: &[SegmentObjective]) -> Vec<HopCandidate> {
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
fn options(cfg: &HopConfig, c: &SegmentObjective) -> Vec<HopCandidate> {
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
fn patch_as_metal(cfg: &HopConfig, metallic: f64) -> bool {
    cfg.patch_metals && metallic >= 0.5
}

/// Whether most of a segment's surface prefers its patch hypothesis (`train.hop.patch_majority`
/// z): the share of its pixels whose cube scores lower at the hypothesis than at the fit lies
/// no more than z standard errors of a fair coin's share, 0.5 / √(effective cubes), below a
/// half. A hypothesis that lowers the sum on a few cubes, where the shadings are off, while
/// most of the surface prefers the fit, does not count; a small part's few cubes cannot tell
/// and pass. Null, or no share: every patch hypothesis passes.
fn preferred(cfg: &HopConfig, share: Option<(f64, f64)>) -> bool {
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
fn settled(cfg: &HopConfig, refined: bool, c: &SegmentObjective) -> Option<f64> {
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
fn anchor_target(settled: Option<f64>, sigma: f64, m: f64) -> (f64, f64) {
    settled.map_or((sigma, m), |s| (s, 0.0))
}

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
        uniform: false,
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
            let with = Hypotheses {
                uniform: stage == Stage::Plain,
                ..Hypotheses::default()
            };
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

/// Whether the plain metals' hop held (`train.hop.plain_metal`): their size-weighted objective
/// at one colour per segment, after the hop, lies within `gain` of the fit's objective before
/// it (the colour free), as it did when the metal was proposed.
fn plain_held(c: &[HopCandidate], gain: f32) -> bool {
    let sum = |f: fn(&HopCandidate) -> f64| c.iter().map(|c| f(c) * c.pixels as f64).sum::<f64>();
    sum(|c| c.objective_after) <= (1.0 + gain as f64) * sum(|c| c.objective)
}

/// The segments a kept hop harmed (`train.hop.guard`), with the σ and m to hold them at: those
/// not hopping whose objective rose by more than the hop's own `gain` (the share that calls
/// for a hop of that kind) while their mean σ left where the anchor held them (`held_at`) by at
/// least its `min_move` (as far as such a hop goes). The extra steps move a flat segment's σ
/// without raising its objective; a segment the hopping ones carried off its own minimum both
/// moves and scores worse.
fn harmed(
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
fn hop_phases(
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
fn holds_metal(cfg: &HopConfig, c: &HopCandidate) -> bool {
    cfg.hold_metals > 0.0 && c.target_metallic.unwrap_or(c.metallic) >= 0.5
}

/// Whether the candidates' size-weighted objective fell by at least `gain` of itself (the
/// share that called for the hop: the extra steps alone move a segment's objective by a few
/// per cent either way).
fn hop_helped(c: &[HopCandidate], gain: f32) -> bool {
    let sum = |f: fn(&HopCandidate) -> f64| c.iter().map(|c| f(c) * c.pixels as f64).sum::<f64>();
    sum(|c| c.objective_after) <= (1.0 - gain as f64) * sum(|c| c.objective)
}

/// The patch sweep's best σ, its objective there and at the fitted mean σ
/// (`SegmentObjective::patch`).
type PatchBest = (f64, f64, f64);

/// The share of pixels whose cube prefers the best σ, and the effective number of cubes
/// (`SegmentObjective::patch_share`).
type PatchShare = (f64, f64);

/// Every segment's pixels (all of them, not the check's sample) grouped into cubes for the
/// patch hypothesis (`patches`).
struct PatchSegments<'a> {
    store: &'a PixelStore,
    /// Per segment id: its entries in the store and their cubes (indices into the entries).
    segments: BTreeMap<i32, (Vec<u32>, Vec<Vec<u32>>)>,
}

impl<'a> PatchSegments<'a> {
    fn new(store: &'a PixelStore, side: f32) -> Self {
        let mut by: BTreeMap<i32, Vec<u32>> = BTreeMap::new();
        let b = &store.pixels;
        for (i, &s) in b.seg.iter().enumerate() {
            // Clipped LDR pixels only bound the photo: no colour solve takes them.
            let clipped = !b.cap.is_empty()
                && b.cap[3 * i..3 * i + 3]
                    .iter()
                    .any(|&c| c < fipt_core::model::step::CAP_NONE);
            if !clipped {
                by.entry(s).or_default().push(i as u32);
            }
        }
        let segments = by
            .into_iter()
            .map(|(id, idx)| {
                let pos: Vec<[f32; 3]> = idx.iter().map(|&i| b.x_world[i as usize]).collect();
                (id, (idx, super::patches::cubes(&pos, side.max(1e-6))))
            })
            .collect();
        Self { store, segments }
    }

    /// Calls `f` with segment `id`'s pixels as a dielectric (m = 0: the hypothesis is a
    /// dielectric of one σ), or as a metal (m = 1) where `metal`, under the model's mask, their
    /// cubes and the model's mean σ over them; None for a segment without pixels.
    fn with_pixels<R>(
        &self,
        model: &FiptModel,
        id: i32,
        metal: bool,
        f: impl FnOnce(&[super::patches::PatchPixel], &[Vec<u32>], f32) -> R,
    ) -> Option<R> {
        let (idx, cubes) = self.segments.get(&id)?;
        let b = self.store.batch(idx);
        let mat = model.material(&b.x_unit, &b.part);
        let alpha = model.alpha(&b.x_world);
        let pixels: Vec<super::patches::PatchPixel> = (0..idx.len())
            .map(|i| super::patches::PatchPixel {
                shading: ShadingLayout::pixel(&b.shadings, i),
                gt: [b.gt[3 * i], b.gt[3 * i + 1], b.gt[3 * i + 2]],
                metallic: if metal { 1.0 } else { 0.0 },
                alpha: alpha[i],
            })
            .collect();
        let n = idx.len().max(1) as f64;
        let mean = (mat.sigma.iter().map(|&s| s as f64).sum::<f64>() / n) as f32;
        Some(f(&pixels, cubes, mean))
    }

    /// The segment's best swept σ, the patch objective there, and at the model's mean σ; and
    /// how many of its cubes prefer that best σ to the mean σ (`patches::preference`).
    fn profile(&self, model: &FiptModel, id: i32, metal: bool) -> Option<(PatchBest, PatchShare)> {
        use super::patches::{objective, per_cube, preference};
        self.with_pixels(model, id, metal, |pixels, cubes, mean| {
            let n = pixels.len().max(1) as f64;
            let per = |s: f32| per_cube(pixels, cubes, &move |_| s);
            let swept: Vec<f64> = sweep()
                .iter()
                .map(|&s| objective(pixels, cubes, &move |_| s) / n)
                .collect();
            let (best_sigma, best) = profile_min(&swept);
            let at_mean = per(mean);
            let share = preference(cubes, &per(best_sigma as f32), &at_mean);
            ((best_sigma, best, at_mean.iter().sum::<f64>() / n), share)
        })
    }

    /// The patch objective (mean per pixel) at the model's mean σ (NaN for a segment without
    /// pixels).
    fn at_model(&self, model: &FiptModel, id: i32, metal: bool) -> f64 {
        self.with_pixels(model, id, metal, |pixels, cubes, mean| {
            super::patches::objective(pixels, cubes, &move |_| mean) / pixels.len().max(1) as f64
        })
        .unwrap_or(f64::NAN)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pipeline::landscape::SWEEP;
    use crate::pipeline::test_data::{store, toy_fit, toy_store};
    use fipt_core::scene::SceneBox;

    /// The toy model fitted on `st` (part loss, 25 steps), and its schedule.
    fn toy_fitted(st: &PixelStore) -> (Trainer, TrainSection) {
        let (cfg, schedule) = toy_fit();
        let (tr, _) = crate::pipeline::fit::fit_more(
            toy_trainer(cfg),
            st,
            SegMode::Part,
            &schedule,
            5,
            false,
        );
        (tr, schedule)
    }

    /// A hop plan over the toy fit's schedule, without a carried model.
    fn toy_plan<'a>(
        cfg: &'a HopConfig,
        schedule: &'a TrainSection,
        lambda_d: f32,
        footprint: f32,
    ) -> HopPlan<'a> {
        HopPlan {
            cfg,
            mode: SegMode::Part,
            schedule,
            lambda_d,
            seed: 5,
            show_progress: false,
            carried: None,
            refined: false,
            footprint,
        }
    }

    fn toy_trainer(cfg: fipt_core::model::TrainConfig) -> Trainer {
        let scene_box = SceneBox { min: 0.0, max: 1.0 };
        Trainer::new(cfg, scene_box, &burn::tensor::Device::flex(), 5)
    }

    /// The host objective is the fit's own: on one segment, the mean of Eq. 15 + 17 that
    /// `evaluate` computes at the model equals the colour loss plus the prior of the trainer's
    /// forward pass on the same pixels.
    #[test]
    fn objective_is_the_fit_loss() {
        let mut st = toy_store(300);
        st.pixels.seg.iter_mut().for_each(|s| *s = 0);
        for (i, x) in st.pixels.x_world.iter_mut().enumerate() {
            *x = [i as f32 / 300.0, 0.3, 0.7];
        }
        let (cfg, _) = toy_fit();
        let mut tr = toy_trainer(cfg.with_logit_bound(None).with_lambda_d(3e-2));
        let samples = sample(&st, usize::MAX);
        assert_eq!(samples.len(), 1);
        assert_eq!(samples[0].idx.len(), 300);
        let e = evaluate(
            &tr.model,
            &st,
            &samples,
            DiffusePrior {
                lambda_d: 3e-2,
                sigma: tr.cfg.prior_sigma,
            },
            Hypotheses {
                sweep: true,
                ..Default::default()
            },
        );
        let all: Vec<u32> = (0..300).collect();
        let parts = tr.gradients(&st.batch(&all), SegMode::None).parts;
        let want = (parts.color + parts.diffuse) as f64;
        assert!(
            (e[0].own - want).abs() < 1e-5 * want.abs().max(1e-3),
            "{} vs {want}",
            e[0].own
        );
        assert_eq!(e[0].sweep.len(), SWEEP);
        assert!(e[0].sigma > 0.02 && e[0].sigma < 1.0);
        // `prior` 0 holds no λ_d: the data term alone, Eq. 15.
        let data = evaluate(
            &tr.model,
            &st,
            &samples,
            DiffusePrior::NONE,
            Hypotheses::default(),
        );
        let want = parts.color as f64;
        assert!(
            (data[0].own - want).abs() < 1e-5 * want.abs().max(1e-3),
            "{} vs {want}",
            data[0].own
        );
        assert!(data[0].own < e[0].own);
    }

    fn eval(sigma: f64, own: f64, best_at: usize, best: f64) -> SegmentEval {
        let mut sweep = vec![own + 1.0; SWEEP];
        sweep[best_at] = best;
        SegmentEval {
            sigma,
            metallic: 0.0,
            own,
            sweep,
            metal: Vec::new(),
            uniform: f64::NAN,
            carried: None,
        }
    }

    /// Only a deep minimum far from the fit sends a segment hopping, to the swept σ there.
    #[test]
    fn only_deep_far_minima_hop() {
        let st = store(&[0, 1, 2, 2]);
        let samples = sample(&st, 8);
        assert_eq!(
            samples.iter().map(|s| s.size).collect::<Vec<_>>(),
            [1, 1, 2]
        );
        let sig = sweep();
        let near = sig.iter().position(|&s| s >= 0.9).unwrap();
        let far = sig.iter().position(|&s| s >= 0.3).unwrap();
        let evals = [
            // 20 % lower at σ ≈ 0.3, fitted at 0.95: hops.
            eval(0.95, 1.0, far, 0.8),
            // 2 % lower: the gain is too small.
            eval(0.95, 1.0, far, 0.98),
            // 50 % lower but 0.05 away: no hop (descent reaches it).
            eval(0.95, 1.0, near, 0.5),
        ];
        let cfg = HopConfig::default();
        let c = candidates(&cfg, &checks(&samples, &evals));
        assert_eq!(c.len(), 1);
        assert_eq!(c[0].segment, 0);
        assert_eq!(c[0].target, sig[far] as f64);
        assert_eq!(c[0].objective_target, 0.8);
        // The whole objective weighs each segment by its size.
        let w = whole(&samples, &evals);
        assert!((w - 1.0).abs() < 1e-12);
        // A segment already at zero (all behind the emission mask) has nothing to gain.
        let zero = [eval(0.95, 0.0, far, 0.0)];
        assert!(candidates(&cfg, &checks(&samples[..1], &zero)).is_empty());
    }

    /// A segment rendered as a metal (m = 1) of known colour and roughness: `uniform_colour`
    /// recovers the colour at the true σ (and a dielectric's, rendered so, at m = 0), and the metal profile's least objective lies at the
    /// true σ with (nearly) zero data term, far below the dielectric profile's at the fit.
    #[test]
    fn the_metal_hypothesis_finds_a_metal() {
        let n = 400;
        let mut st = toy_store(n);
        st.pixels.seg.iter_mut().for_each(|s| *s = 0);
        let (a, sigma) = (glam::Vec3::new(0.9, 0.6, 0.3), sweep()[12]);
        let d = ShadingLayout::DIM;
        for i in 0..n {
            // Specular shadings that vary over σ and pixels, so σ is identifiable.
            for j in 0..fipt_core::brdf::ROUGHNESS_LEVELS {
                for c in 0..3 {
                    let v = 0.2 + ((i * 7 + j * 13 + c * 5) % 11) as f32 / 11.0;
                    st.pixels.shadings[i * d + ShadingLayout::ls0(j).start + c] = v;
                    st.pixels.shadings[i * d + ShadingLayout::ls1(j).start + c] = 0.05 * v;
                }
            }
            let sh = ShadingLayout::pixel(&st.pixels.shadings, i).to_vec();
            let c = factorised_render([0.0; 3], a.to_array(), sigma, &sh);
            st.pixels.gt[3 * i..3 * i + 3].copy_from_slice(&c);
        }
        let all: Vec<u32> = (0..n as u32).collect();
        let b = st.batch(&all);
        let alpha = vec![0.0; n];
        let fitted = uniform_colour(&b, &alpha, sigma, 1.0);
        assert!((fitted - a).abs().max_element() < 1e-4, "{fitted} vs {a}");
        let mut dielectric = st.batch(&all);
        for i in 0..n {
            let sh = ShadingLayout::pixel(&dielectric.shadings, i).to_vec();
            let (kd, ks) = reflectances(a, 0.0);
            let c = factorised_render(kd.to_array(), ks.to_array(), sigma, &sh);
            dielectric.gt[3 * i..3 * i + 3].copy_from_slice(&c);
        }
        let fitted = uniform_colour(&dielectric, &alpha, sigma, 0.0);
        assert!((fitted - a).abs().max_element() < 1e-4, "{fitted} vs {a}");
        let (cfg, _) = toy_fit();
        let tr = toy_trainer(cfg);
        let samples = sample(&st, usize::MAX);
        let with = Hypotheses {
            sweep: true,
            metal: true,
            uniform: false,
            carried: None,
        };
        let e = evaluate(&tr.model, &st, &samples, DiffusePrior::NONE, with).remove(0);
        let (best_sigma, best) = profile_min(&e.metal);
        assert_eq!(best_sigma, sigma as f64);
        let (_, dielectric) = profile_min(&e.sweep);
        assert!(
            best < 1e-9 && best < 1e-3 * dielectric.min(e.own),
            "{best} vs {dielectric}, {}",
            e.own
        );
        // One colour at the fit's σ and m explains it far worse than the metal does.
        assert!(best < 1e-3 * e.uniform, "{best} vs {}", e.uniform);
        // The check proposes the metal for a segment fitted non-metallic, pulling m to 1 with σ.
        let mut rows = checks(&samples, &[e]);
        rows[0].metallic = 0.1;
        let c = candidates(&HopConfig::default(), &rows);
        assert_eq!(c.len(), 1);
        assert_eq!(c[0].source, Hypothesis::Metal);
        assert_eq!(
            (c[0].target, c[0].target_metallic),
            (sigma as f64, Some(1.0))
        );
    }

    /// A pull that names an m target moves that segment's m towards it, beyond what the same
    /// steps without it do.
    #[test]
    fn the_pull_moves_m_where_it_names_a_target() {
        // Black photos and shadings: the data term does not see m, the pull and priors do.
        let mut st = toy_store(400);
        st.pixels.shadings.iter_mut().for_each(|v| *v = 0.0);
        st.pixels.gt.iter_mut().for_each(|v| *v = 0.0);
        let (tr, _) = toy_fitted(&st);
        let samples = sample(&st, 64);
        let m_of = |t: &Trainer| -> Vec<f64> {
            evaluate(
                &t.model,
                &st,
                &samples,
                DiffusePrior::NONE,
                Hypotheses::default(),
            )
            .iter()
            .map(|e| e.metallic)
            .collect()
        };
        let run = |pull: Option<SigmaPull>| {
            let mut t = tr.clone();
            t.pull = pull;
            let mut rng = Rng::new(9, 1);
            for _ in 0..100 {
                let idx: Vec<u32> = (0..64).map(|_| rng.below(400) as u32).collect();
                drop(step_entries(&mut t, None, &st, &idx, SegMode::Part));
            }
            t.sync_host_table();
            m_of(&t)
        };
        let free = run(None);
        let pulled = run(Some(SigmaPull {
            weight: 10.0,
            target: Default::default(),
            metallic: [(2, 1.0)].into_iter().collect(),
        }));
        let k = samples.iter().position(|s| s.id == 2).unwrap();
        // Adam's step size bounds the move in 100 steps (about 0.04 here, whatever the weight).
        assert!(
            pulled[k] > free[k] + 0.02,
            "m {} with the pull, {} without",
            pulled[k],
            free[k]
        );
    }

    /// A metal hypothesis is plain where its one colour per segment scores within `gain` of
    /// the fit's objective (`plain_metal`), and only then: a metal that wins against one colour
    /// at the fitted σ and m but needs more than the fit's free colour to match it is not, nor
    /// is any other hypothesis; a plain metal is its segment's fallback where another
    /// hypothesis won; the plain metals' hop holds while their one colour after it stays within
    /// `gain` of the fit's objective before it.
    #[test]
    fn a_plain_metal_matches_the_fit_with_one_colour() {
        let sig = sweep();
        let samples = [SegmentSample {
            id: 6,
            size: 300,
            idx: Vec::new(),
        }];
        // The fit: σ 0.9, m 0, objective 1; the sweep finds nothing lower.
        let fit = checks(&samples, &[eval(0.9, 1.0, 0, 2.0)]).remove(0);
        let row = |metal: (f64, f64, f64)| SegmentObjective {
            metal: Some(metal),
            ..fit.clone()
        };
        let cfg = HopConfig::default();
        let gain = cfg.gain as f64;
        // One metal colour at σ 0.46 as good as the fit (colour free), and far better than one
        // colour at the fitted σ and m: plain.
        let c = candidates(&cfg, &[row((0.46, 1.0, 3.0))]);
        assert_eq!(c[0].source, Hypothesis::Metal);
        assert!(c[0].plain);
        // Just within `gain` of the fit, and just beyond it.
        assert!(candidates(&cfg, &[row((0.46, 1.0 + 0.9 * gain, 3.0))])[0].plain);
        let beyond = candidates(&cfg, &[row((0.46, 1.0 + 1.1 * gain, 3.0))]);
        assert_eq!(beyond[0].source, Hypothesis::Metal);
        assert!(!beyond[0].plain);
        // A metal three times the fit's objective that still halves its own baseline: a
        // candidate, not plain (a dielectric counter whose colour one metal colour cannot
        // carry).
        let counter = candidates(&cfg, &[row((0.46, 3.0, 6.0))]);
        assert_eq!(counter[0].source, Hypothesis::Metal);
        assert!(!counter[0].plain);
        // The key off: no metal is plain.
        let off = HopConfig {
            plain_metal: false,
            ..HopConfig::default()
        };
        assert!(!candidates(&off, &[row((0.46, 1.0, 3.0))])[0].plain);
        // The sweep's candidate is never plain, however low its objective.
        let far = sig.iter().position(|&s| s >= 0.3).unwrap();
        let sweep_row = checks(&samples, &[eval(0.95, 1.0, far, 0.5)]);
        let c = candidates(&cfg, &sweep_row);
        assert_eq!(c[0].source, Hypothesis::Sweep);
        assert!(!c[0].plain);
        // The plain hop holds at one colour within `gain` of the fit's objective, size-weighted.
        let hopped = |after: f64, pixels: usize| HopCandidate {
            objective: 1.0,
            objective_after: after,
            pixels,
            ..c[0].clone()
        };
        assert!(plain_held(&[hopped(1.0 + 0.9 * gain, 300)], cfg.gain));
        assert!(!plain_held(&[hopped(1.0 + 1.1 * gain, 300)], cfg.gain));
        assert!(plain_held(
            &[hopped(1.0 + 2.0 * gain, 100), hopped(1.0, 300)],
            cfg.gain
        ));
        assert!(!plain_held(
            &[hopped(1.0 + 2.0 * gain, 300), hopped(1.0, 100)],
            cfg.gain
        ));
        // A carried material that counts wins the first hop with `carried_first`; the plain
        // metal is still the segment's fallback if that hop is undone, and a metal that is not
        // plain is none.
        let carried = SegmentObjective {
            carried: Some((0.5, 0.98, 0.8)),
            ..row((0.46, 1.0, 3.0))
        };
        let c = candidates(&cfg, std::slice::from_ref(&carried));
        assert_eq!(c[0].source, Hypothesis::Carried);
        let again = plain_fallbacks(&cfg, std::slice::from_ref(&carried));
        assert_eq!(again.len(), 1);
        assert_eq!(
            (again[0].source, again[0].target, again[0].target_metallic),
            (Hypothesis::Metal, 0.46, Some(1.0))
        );
        assert!(again[0].plain && again[0].alone);
        let rough = SegmentObjective {
            metal: Some((0.46, 3.0, 6.0)),
            ..carried.clone()
        };
        assert!(plain_fallbacks(&cfg, &[rough]).is_empty());
        assert!(plain_fallbacks(&off, &[carried]).is_empty());
        // Its hop stays pulled through the release, on a stream of its own.
        assert!(Stage::Plain.held() && !Stage::First.held());
        let streams = [Stage::First, Stage::Plain, Stage::Patch].map(Stage::stream);
        assert!(streams[0] != streams[1] && streams[1] != streams[2] && streams[0] != streams[2]);
    }

    /// The last round's material is scored under this round's shadings: with the same model it
    /// scores the model's own objective; a carried candidate wins over the sweep only with the
    /// lower objective, and pulls m only when it lies across 0.5 from the fit; where it counts,
    /// it wins over the metal hypothesis (`carried_first`).
    #[test]
    fn carried_material_is_scored_and_chosen_by_its_objective() {
        let st = toy_store(300);
        let (cfg, _) = toy_fit();
        let tr = toy_trainer(cfg);
        let samples = sample(&st, 64);
        let with = Hypotheses {
            carried: Some(&tr.model),
            ..Hypotheses::default()
        };
        for e in evaluate(&tr.model, &st, &samples, DiffusePrior::NONE, with) {
            let (sigma, m, obj) = e.carried.unwrap();
            assert_eq!((sigma, m, obj), (e.sigma, e.metallic, e.own));
        }
        let sig = sweep();
        let far = sig.iter().position(|&s| s >= 0.3).unwrap();
        let row = |carried: (f64, f64, f64)| SegmentObjective {
            carried: Some(carried),
            ..checks(&samples[..1], &[eval(0.95, 1.0, far, 0.8)]).remove(0)
        };
        let cfg = HopConfig::default();
        // Lower than the sweep's best, and a metal where the fit is not: pulls σ and m.
        let c = candidates(&cfg, &[row((0.1, 0.9, 0.5))]);
        assert_eq!(c[0].source, Hypothesis::Carried);
        assert_eq!((c[0].target, c[0].target_metallic), (0.1, Some(0.9)));
        // Higher than the sweep's best: the sweep wins.
        let c = candidates(&cfg, &[row((0.1, 0.9, 0.9))]);
        assert_eq!(c[0].source, Hypothesis::Sweep);
        // Non-metallic like the fit: σ alone is pulled.
        let c = candidates(&cfg, &[row((0.1, 0.2, 0.5))]);
        assert_eq!(
            (c[0].source, c[0].target_metallic),
            (Hypothesis::Carried, None)
        );
        // Near the fit in σ and m, but lower: it still wins (no distance asked of it).
        let c = candidates(&cfg, &[row((0.9, 0.1, 0.1))]);
        assert_eq!((c[0].source, c[0].target), (Hypothesis::Carried, 0.9));
        // Not lower by `gain`: the sweep's target.
        let c = candidates(&cfg, &[row((0.2, 0.9, 0.97))]);
        assert_eq!(c[0].source, Hypothesis::Sweep);
        // A metal hypothesis whose gain against its own baseline (one colour per segment, 0.8)
        // is larger than the carried material's against the fit (0.5) gives way to it with
        // `carried_first`, and wins without it.
        let both = SegmentObjective {
            metal: Some((0.3, 0.2, 1.0)),
            ..row((0.06, 0.98, 0.5))
        };
        let c = candidates(&cfg, std::slice::from_ref(&both));
        assert_eq!((c[0].source, c[0].target), (Hypothesis::Carried, 0.06));
        let off = HopConfig {
            carried_first: false,
            ..HopConfig::default()
        };
        let c = candidates(&off, std::slice::from_ref(&both));
        assert_eq!((c[0].source, c[0].target), (Hypothesis::Metal, 0.3));
        // A carried material that does not count leaves the metal its win.
        let weak = SegmentObjective {
            carried: Some((0.06, 0.98, 0.97)),
            ..both
        };
        assert_eq!(candidates(&cfg, &[weak])[0].source, Hypothesis::Metal);
    }

    /// The check holds `prior` × the fit's λ_d: with 0 each segment's objective is its data
    /// term, with 1 the data term plus λ_d·mean(|σ − σ₀| + m).
    #[test]
    fn the_check_holds_its_share_of_the_prior() {
        let st = toy_store(400);
        let (tr, schedule) = toy_fitted(&st);
        let lambda_d = 0.05;
        let report = |prior: f32| {
            // gain 1: no segment can gain it all, so nothing hops.
            let hc = HopConfig {
                gain: 1.0,
                patch_gain: 1.0,
                pixels: 64,
                prior,
                ..HopConfig::default()
            };
            let plan = toy_plan(&hc, &schedule, lambda_d, 0.01);
            hop(tr.clone(), &st, &plan).unwrap().1
        };
        let (data, full) = (report(0.0), report(1.0));
        assert!(data.candidates.is_empty() && full.candidates.is_empty());
        assert_eq!((data.lambda_d, full.lambda_d), (0.0, lambda_d as f64));
        let samples = sample(&st, 64);
        let want = evaluate(
            &tr.model,
            &st,
            &samples,
            DiffusePrior::NONE,
            Hypotheses::default(),
        );
        let mat = |s: &SegmentSample| {
            let b = st.batch(&s.idx);
            tr.model.material(&b.x_unit, &b.part)
        };
        for ((d, f), (s, w)) in data
            .segments
            .iter()
            .zip(&full.segments)
            .zip(samples.iter().zip(&want))
        {
            assert_eq!(d.before, w.own);
            let m = mat(s);
            let prior = (0..s.idx.len())
                .map(|i| ((m.sigma[i] - tr.cfg.prior_sigma).abs() + m.metallic[i]) as f64)
                .sum::<f64>()
                / s.idx.len() as f64;
            assert!(
                (f.before - d.before - lambda_d as f64 * prior).abs() < 1e-6,
                "segment {}: {} − {} vs λ_d·{prior}",
                d.segment,
                f.before,
                d.before
            );
        }
    }

    /// A hop pulls every candidate's σ towards its target, and the model it returns is the
    /// hopped one only when the objective fell (else the very model it was given).
    #[test]
    fn hop_pulls_and_keeps_only_a_lower_objective() {
        let st = toy_store(400);
        let (cfg, schedule) = toy_fit();
        let run = crate::pipeline::fit::FitRun {
            mode: SegMode::Part,
            schedule: &schedule,
            seed: 5,
            show_progress: false,
        };
        let (tr, _) =
            crate::pipeline::fit::fit_more(toy_trainer(cfg), &st, run.mode, &schedule, 5, false);
        let before = (tr.model.net_params(), tr.model.grid.table.clone());
        // Every segment whose sweep finds anything lower hops; long phases, a strong pull.
        let hc = HopConfig {
            gain: 0.0,
            min_move: 0.0,
            steps: 2.0,
            pull: 10.0,
            pixels: 64,
            prior: 1.0,
            // The sweep's hop alone.
            patch: 0.0,
            ..HopConfig::default()
        };
        let plan = toy_plan(&hc, &schedule, 5e-4, 0.01);
        let (out, rep) = hop(tr, &st, &plan).unwrap();
        assert!(!rep.candidates.is_empty());
        assert_eq!(rep.steps, 2 * 50);
        for c in &rep.candidates {
            assert!(
                (c.sigma_after - c.target).abs() < (c.sigma - c.target).abs(),
                "segment {}: σ {} → {} for target {}",
                c.segment,
                c.sigma,
                c.sigma_after,
                c.target
            );
            if let Some(t) = c.target_metallic {
                assert!(
                    (c.metallic_after - t).abs() < (c.metallic - t).abs(),
                    "segment {}: m {} → {} for target {t}",
                    c.segment,
                    c.metallic,
                    c.metallic_after
                );
            }
        }
        assert!(rep.objective_after.is_some());
        assert_eq!(rep.segments.len(), 5);
        assert_eq!(rep.accepted, hop_helped(&rep.candidates, hc.gain));
        let now = (out.model.net_params(), out.model.grid.table.clone());
        assert_eq!(now == before, !rep.accepted);
    }

    /// A config with a patch gain of 2 % and the check of one segment fitted at σ 0.8 whose sweep
    /// is flat.
    fn one_flat_segment() -> (HopConfig, Vec<SegmentObjective>) {
        let samples = sample(&store(&[0]), 8);
        let cfg = HopConfig {
            patch_gain: 0.02,
            patch_min_move: 0.15,
            ..HopConfig::default()
        };
        (cfg, checks(&samples, &[eval(0.8, 1.0, 0, 1.0)]))
    }

    /// A patch candidate counts by its own gain and distance, and is kept by its own measure and
    /// gain; the other hypotheses keep theirs.
    #[test]
    fn patch_candidates_have_their_own_thresholds() {
        let (cfg, mut rows) = one_flat_segment();
        // The sweep is flat (no hop of its own); the patch sweep lies 0.2 away.
        let mut with = |patch: (f64, f64, f64)| {
            rows[0].patch = Some(patch);
            candidates(&cfg, &rows)
        };
        let c = with((0.6, 0.97, 1.0));
        assert_eq!(
            (c.len(), c[0].source, c[0].target, c[0].target_metallic),
            (1, Hypothesis::Patch, 0.6, Some(0.0))
        );
        // Measured against the patch objective at the fitted σ, not the fit's own.
        assert_eq!((c[0].objective, c[0].objective_target), (1.0, 0.97));
        // 1 % lower: too little; 0.1 away: too near.
        assert!(with((0.6, 0.99, 1.0)).is_empty());
        assert!(with((0.7, 0.9, 1.0)).is_empty());
        let cand = |source, objective, after| HopCandidate {
            source,
            objective,
            objective_after: after,
            ..c[0].clone()
        };
        let (p, s) = (Hypothesis::Patch, Hypothesis::Sweep);
        let kept =
            |c: HopCandidate| hop_helped(std::slice::from_ref(&c), thresholds(&cfg, c.source).0);
        assert!(kept(cand(p, 1.0, 0.97)));
        assert!(!kept(cand(p, 1.0, 0.99)));
        // A sweep candidate needs its 5 %, where a patch candidate's 2 % would do.
        assert!(!kept(cand(s, 1.0, 0.97)));
        assert!(kept(cand(s, 1.0, 0.9)));
        // With `patch_dielectric` (the default) it hops as the dielectric it was solved as, m
        // pulled to 0; without it, σ alone.
        let sigma_alone = HopConfig {
            patch_dielectric: false,
            ..cfg.clone()
        };
        let d = candidates(
            &sigma_alone,
            &[SegmentObjective {
                patch: Some((0.6, 0.97, 1.0)),
                ..rows[0].clone()
            }],
        );
        assert_eq!((d.len(), d[0].target, d[0].target_metallic), (1, 0.6, None));
    }

    /// A segment fitted metallic has no patch candidate unless `patch_metals`; with it, its
    /// patch hypothesis counts by the same gain and distance and hops as the metal it was solved
    /// as, m pulled to 1.
    #[test]
    fn a_metal_hops_on_its_patch_only_with_patch_metals() {
        let (cfg, mut rows) = one_flat_segment();
        rows[0].metallic = 0.9;
        rows[0].patch = Some((0.6, 0.9, 1.0));
        assert!(candidates(&cfg, &rows).is_empty());
        let metals = HopConfig {
            patch_metals: true,
            ..cfg.clone()
        };
        let c = candidates(&metals, &rows);
        assert_eq!(
            (c.len(), c[0].source, c[0].target, c[0].target_metallic),
            (1, Hypothesis::Patch, 0.6, Some(1.0))
        );
        assert!(holds_metal(&metals, &c[0]));
        // A dielectric still hops as one.
        rows[0].metallic = 0.1;
        assert_eq!(candidates(&metals, &rows)[0].target_metallic, Some(0.0));
        // Too near is too near for a metal too.
        rows[0].metallic = 0.9;
        rows[0].patch = Some((0.7, 0.9, 1.0));
        assert!(candidates(&metals, &rows).is_empty());
    }

    /// With `patch_majority` z, a patch hypothesis that lowers the sum but that well under half
    /// of many cubes prefer (more than z standard errors below) does not count; over few cubes
    /// the same share cannot tell, and counts; z 0 asks for a half whatever the cubes; null lets
    /// every share count. A patch candidate that falls back after an undone first hop is held to
    /// the same test.
    #[test]
    fn a_patch_hypothesis_needs_most_of_the_surface() {
        let (cfg, mut rows) = one_flat_segment();
        let cfg = HopConfig {
            patch_majority: Some(2.0),
            ..cfg
        };
        rows[0].patch = Some((0.6, 0.97, 1.0));
        let mut with = |cfg: &HopConfig, share: Option<(f64, f64)>| {
            rows[0].patch_share = share;
            candidates(cfg, &rows).len()
        };
        // 4000 cubes: a fair coin's share lies within 2 × 0.5 / √4000 ≈ 0.016 of a half.
        assert_eq!(with(&cfg, Some((0.46, 4000.0))), 0);
        assert_eq!(with(&cfg, Some((0.49, 4000.0))), 1);
        assert_eq!(with(&cfg, Some((0.6, 4000.0))), 1);
        // 16 cubes: the bound is 0.25.
        assert_eq!(with(&cfg, Some((0.3, 16.0))), 1);
        assert_eq!(with(&cfg, Some((0.2, 16.0))), 0);
        assert_eq!(with(&cfg, None), 1);
        let half = HopConfig {
            patch_majority: Some(0.0),
            ..cfg.clone()
        };
        assert_eq!(with(&half, Some((0.49, 4000.0))), 0);
        assert_eq!(with(&half, Some((0.3, 16.0))), 0);
        assert_eq!(with(&half, Some((0.5, 16.0))), 1);
        assert_eq!(with(&half, Some((0.6, 4000.0))), 1);
        let off = HopConfig {
            patch_majority: None,
            ..cfg.clone()
        };
        assert_eq!(with(&off, Some((0.1, 4000.0))), 1);
        // The metal wins the first hop; its patch fallback passes the same test.
        rows[0].metal = Some((0.3, 0.5, 1.0));
        rows[0].metallic = 0.1;
        let fallbacks = |share: (f64, f64)| {
            let r = SegmentObjective {
                patch_share: Some(share),
                ..rows[0].clone()
            };
            patch_fallbacks(&cfg, &[r]).len()
        };
        assert_eq!(fallbacks((0.6, 4000.0)), 1);
        assert_eq!(fallbacks((0.4, 4000.0)), 0);
    }

    /// The data term (λ_d 0) of every sampled segment at `tr`'s model.
    fn data_at(tr: &Trainer, st: &PixelStore, samples: &[SegmentSample]) -> Vec<SegmentEval> {
        let prior = DiffusePrior {
            lambda_d: 0.0,
            sigma: tr.cfg.prior_sigma,
        };
        evaluate(&tr.model, st, samples, prior, Hypotheses::default())
    }

    /// A candidate of `source` for the first sampled segment, as `before` has it, hopping to
    /// σ `target` (and m `target_metallic`).
    fn first_candidate(
        samples: &[SegmentSample],
        before: &[SegmentEval],
        target: f64,
        source: Hypothesis,
        target_metallic: Option<f64>,
    ) -> HopCandidate {
        HopCandidate {
            segment: samples[0].id,
            pixels: samples[0].size,
            sigma: before[0].sigma,
            target,
            sigma_after: before[0].sigma,
            source,
            metallic: before[0].metallic,
            target_metallic,
            metallic_after: before[0].metallic,
            objective: 1.0,
            objective_target: 0.5,
            objective_after: 1.0,
            plain: false,
            alone: false,
        }
    }

    /// With `anchor`, the segments that do not hop stay near their σ and m while one segment is
    /// pulled far away; without it, the shared networks carry them along.
    #[test]
    fn the_anchor_holds_the_segments_not_hopping() {
        // Five segments, each a stretch of the toy's curve (apart in space).
        let mut st = toy_store(400);
        for (i, s) in st.pixels.seg.iter_mut().enumerate() {
            *s = (i / 80) as i32;
        }
        let (tr, schedule) = toy_fitted(&st);
        let samples = sample(&st, 80);
        let at = |tr: &Trainer| data_at(tr, &st, &samples);
        let before = at(&tr);
        let held_at: Vec<(i32, f64, f64)> = samples
            .iter()
            .zip(&before)
            .map(|(s, e)| (s.id, e.sigma, e.metallic))
            .collect();
        let target = if before[0].sigma > 0.5 { 0.05 } else { 0.95 };
        let chosen = [first_candidate(
            &samples,
            &before,
            target,
            Hypothesis::Sweep,
            None,
        )];
        let moved = |anchor: f32, guards: &[(i32, f64, f64)]| {
            let hc = HopConfig {
                steps: 2.0,
                pull: 10.0,
                anchor,
                ..HopConfig::default()
            };
            let plan = toy_plan(&hc, &schedule, 5e-4, 0.01);
            let (out, _) = hop_phases(
                tr.clone(),
                &st,
                &plan,
                &chosen,
                guards,
                &held_at,
                Stage::Patch,
            )
            .unwrap();
            let after = at(&out);
            let others = 1..samples.len();
            let drift = others
                .clone()
                .map(|k| {
                    (after[k].sigma - before[k].sigma)
                        .abs()
                        .max((after[k].metallic - before[k].metallic).abs())
                })
                .fold(0.0f64, f64::max);
            // How far the hopping segment's σ got from the others', towards its target.
            let mean = others.map(|k| after[k].sigma).sum::<f64>() / (samples.len() - 1) as f64;
            (
                drift,
                (after[0].sigma - mean) * (target - before[0].sigma).signum(),
            )
        };
        // The toy's small networks share most of what σ depends on: free, every segment goes
        // where the pulled one goes.
        let (free, free_apart) = moved(0.0, &[]);
        let (held, held_apart) = moved(10.0, &[]);
        // Guarded (`guard`), the others are pulled where they were as the candidate is to its
        // target, without the anchor.
        let (guarded, guarded_apart) = moved(0.0, &held_at[1..]);
        assert!(
            free > 0.05,
            "without the anchor the others moved only {free}"
        );
        assert!(
            held < 0.5 * free,
            "the others moved {held} with the anchor, {free} without"
        );
        assert!(
            held_apart > free_apart + 0.03,
            "the hopping segment {held_apart} apart from the others held, {free_apart} free"
        );
        assert!(
            guarded < 0.5 * free && guarded_apart > free_apart + 0.03,
            "guarded, the others moved {guarded} (free {free}), the hopping one {guarded_apart} \
             apart (free {free_apart})"
        );
    }

    /// `guard` names the segments a kept hop harmed: not hopping, their objective up by more
    /// than the hop's gain and their σ moved by at least its `min_move` from where they were
    /// held; with the σ and m to hold them at.
    #[test]
    fn the_guard_names_the_segments_a_hop_harmed() {
        let cfg = HopConfig {
            patch_gain: 0.01,
            patch_min_move: 0.15,
            gain: 0.05,
            min_move: 0.25,
            ..HopConfig::default()
        };
        let held_at = [
            (0, 0.9, 0.0),
            (1, 0.3, 0.6),
            (2, 0.9, 0.0),
            (3, 0.9, 0.0),
            (4, 0.5, 0.0),
        ];
        let entering = [1e-3; 5];
        // 2 % worse: past the patch hop's gain (1 %), short of the sweep's (5 %).
        let worse = 1.02e-3;
        let after = [
            // Hopping: it moves and scores worse, and is the hop's to judge.
            eval(0.2, worse, 0, 0.0),
            // Carried off its minimum: moved by 0.26, and worse.
            eval(0.04, worse, 0, 0.0),
            // Moved by 0.3 on flat data: 0.5 % worse.
            eval(0.6, 1.005e-3, 0, 0.0),
            // Worse but 0.1 from where it was held.
            eval(0.8, worse, 0, 0.0),
            // Moved up by 0.3, and worse.
            eval(0.8, worse, 0, 0.0),
        ];
        let got = harmed(&cfg, Hypothesis::Patch, &[0], &entering, &after, &held_at);
        assert_eq!(got, vec![(1, 0.3, 0.6), (4, 0.5, 0.0)]);
        assert!(harmed(&cfg, Hypothesis::Sweep, &[0], &entering, &after, &held_at).is_empty());
        // Without the hopping segment named, it is a bystander like any other.
        let all = harmed(&cfg, Hypothesis::Patch, &[], &entering, &after, &held_at);
        assert_eq!(all[0], (0, 0.9, 0.0));
    }

    /// With `hold_metals`, a candidate hopping as a metal stays pulled through the release
    /// phase: on photos of a dielectric, a metal hop (m 1) ends nearer its target held than
    /// released, where the data takes it back. A dielectric candidate is released either way.
    #[test]
    fn hold_metals_keeps_a_metal_hop_at_its_target() {
        let st = rendered_store(400, 0.3);
        let (tr, mut schedule) = toy_fitted(&st);
        // The hop runs at the schedule's last rate: keep it at the first so the steps move σ.
        schedule.lr_end = 1.0;
        let samples = sample(&st, 400);
        let at = |tr: &Trainer| data_at(tr, &st, &samples);
        let before = at(&tr);
        let target = 0.7;
        let metal = first_candidate(&samples, &before, target, Hypothesis::Metal, Some(1.0));
        let dielectric = HopCandidate {
            source: Hypothesis::Sweep,
            target_metallic: None,
            metallic: 0.0,
            ..metal.clone()
        };
        let base = HopConfig {
            steps: 1.0,
            pull: 1.0,
            anchor: 0.0,
            hold_metals: 0.0,
            ..HopConfig::default()
        };
        let hold = HopConfig {
            hold_metals: 1.0,
            ..base.clone()
        };
        assert!(holds_metal(&hold, &metal) && !holds_metal(&base, &metal));
        assert!(!holds_metal(&hold, &dielectric));
        // A candidate that names no m holds where the fit already has a metal.
        let fitted_metal = HopCandidate {
            metallic: 0.8,
            ..dielectric.clone()
        };
        assert!(holds_metal(&hold, &fitted_metal));
        let hopped = |cfg: &HopConfig, c: &HopCandidate| {
            let plan = toy_plan(cfg, &schedule, 5e-4, 0.01);
            let (out, _) = hop_phases(
                tr.clone(),
                &st,
                &plan,
                std::slice::from_ref(c),
                &[],
                &[],
                Stage::First,
            )
            .unwrap();
            let a = at(&out);
            (a[0].sigma, a[0].metallic)
        };
        let (released, m_released) = hopped(&base, &metal);
        let (held, m_held) = hopped(&hold, &metal);
        // The data (a dielectric) takes a released metal back; held, m stays at its target.
        assert!(
            (1.0 - m_held) + 0.2 < 1.0 - m_released,
            "m {m_held} held, {m_released} released (σ {held} and {released}, for {target})"
        );
        // Held at a weight too small to matter, it ends where released: the weight is the hold's.
        let faint = HopConfig {
            hold_metals: 1e-6,
            ..base.clone()
        };
        let (_, m_faint) = hopped(&faint, &metal);
        assert!(
            (m_faint - m_released).abs() < 0.05,
            "m {m_faint} held at 1e-6, {m_released} released"
        );
        // A dielectric's hop is the same with the key as without.
        assert_eq!(hopped(&base, &dielectric), hopped(&hold, &dielectric));
    }

    /// `settle` holds a dielectric of a refined round at its patch minimum (and m 0) where that
    /// scores lower and lies within `min_move`; anywhere else the anchor keeps the fitted σ.
    #[test]
    fn settle_holds_at_the_nearby_patch_minimum() {
        let (mut cfg, mut rows) = one_flat_segment();
        (cfg.settle, cfg.anchor, cfg.min_move) = (true, 1e-2, 0.25);
        rows[0].metallic = 0.05;
        rows[0].patch = Some((0.62, 0.99, 1.0));
        assert_eq!(settled(&cfg, true, &rows[0]), Some(0.62));
        // Held as the patch hypothesis is: a dielectric, m 0; unsettled, at its fitted m.
        assert_eq!(anchor_target(Some(0.62), 0.9, 0.05), (0.62, 0.0));
        assert_eq!(anchor_target(None, 0.9, 0.05), (0.9, 0.05));
        // Not on round 0's baked shadings, nor without the anchor or the key.
        assert_eq!(settled(&cfg, false, &rows[0]), None);
        let off = |f: fn(&mut HopConfig)| {
            let mut c = cfg.clone();
            f(&mut c);
            settled(&c, true, &rows[0])
        };
        assert_eq!(off(|c| c.anchor = 0.0), None);
        assert_eq!(off(|c| c.settle = false), None);
        // A near minimum that scores no lower than the fitted σ: the minimum is the fit's σ,
        // held there as a dielectric, m 0.
        rows[0].patch = Some((0.78, 1.0, 1.0));
        assert_eq!(settled(&cfg, true, &rows[0]), Some(0.8));
        // One a hop's distance away, and a metal: held as fitted.
        rows[0].patch = Some((0.5, 0.9, 1.0));
        assert_eq!(settled(&cfg, true, &rows[0]), None);
        // That far hypothesis, where most of the surface prefers the fit (`patch_majority`):
        // held at its fitted σ as a dielectric, m 0; without the test, as fitted.
        let lost = SegmentObjective {
            patch_share: Some((0.4, 4000.0)),
            ..rows[0].clone()
        };
        assert_eq!(settled(&cfg, true, &lost), Some(0.8));
        let untested = HopConfig {
            patch_majority: None,
            ..cfg.clone()
        };
        assert_eq!(settled(&untested, true, &lost), None);
        rows[0].patch = Some((0.62, 0.9, 1.0));
        rows[0].metallic = 0.7;
        assert_eq!(settled(&cfg, true, &rows[0]), None);
    }

    /// A segment whose metal hypothesis wins keeps its patch hypothesis as a fallback for the
    /// second hop; one whose patch hypothesis wins, or whose patch does not count, has none.
    #[test]
    fn an_undone_hop_falls_back_to_the_patch() {
        let (cfg, mut rows) = one_flat_segment();
        // The metal (σ 0.3, m 1) halves its baseline; the patch (σ 0.1) gains 13 %.
        rows[0].metallic = 0.1;
        rows[0].metal = Some((0.3, 0.5, 1.0));
        rows[0].patch = Some((0.1, 0.87, 1.0));
        let c = candidates(&cfg, &rows);
        assert_eq!((c.len(), c[0].source), (1, Hypothesis::Metal));
        let f = patch_fallbacks(&cfg, &rows);
        assert_eq!(
            (f.len(), f[0].source, f[0].target, f[0].objective),
            (1, Hypothesis::Patch, 0.1, 1.0)
        );
        // The patch gains more than the metal: it is the candidate, and no fallback.
        rows[0].patch = Some((0.1, 0.4, 1.0));
        assert_eq!(candidates(&cfg, &rows)[0].source, Hypothesis::Patch);
        assert!(patch_fallbacks(&cfg, &rows).is_empty());
        // A patch that does not count (1 % lower) is no fallback either.
        rows[0].patch = Some((0.1, 0.99, 1.0));
        assert_eq!(candidates(&cfg, &rows)[0].source, Hypothesis::Metal);
        assert!(patch_fallbacks(&cfg, &rows).is_empty());
    }

    /// One segment of `n` pixels in four cubes, one base colour per cube, dielectric, whose
    /// photos are the factorised render at σ `truth`.
    fn rendered_store(n: usize, truth: f32) -> PixelStore {
        rendered_store_m(n, truth, 0.0)
    }

    /// `rendered_store` at metallic `m`.
    fn rendered_store_m(n: usize, truth: f32, m: f32) -> PixelStore {
        let mut st = toy_store(n);
        st.pixels.seg.iter_mut().for_each(|s| *s = 0);
        let d = ShadingLayout::DIM;
        for i in 0..n {
            let cube = i % 4;
            st.pixels.x_world[i] = [0.1 + cube as f32, 0.5, 0.5];
            for j in 0..fipt_core::brdf::ROUGHNESS_LEVELS {
                for c in 0..3 {
                    let v = 0.2 + ((i * 7 + j * 13 + c * 5) % 11) as f32 / 11.0;
                    st.pixels.shadings[i * d + ShadingLayout::ls0(j).start + c] = 3.0 * v;
                    st.pixels.shadings[i * d + ShadingLayout::ls1(j).start + c] = 0.1 * v;
                }
            }
            let sh = ShadingLayout::pixel(&st.pixels.shadings, i).to_vec();
            let a = glam::Vec3::new(0.2 + 0.2 * cube as f32, 0.4, 0.3);
            let (kd, ks) = reflectances(a, m);
            let c = factorised_render(kd.to_array(), ks.to_array(), truth, &sh);
            st.pixels.gt[3 * i..3 * i + 3].copy_from_slice(&c);
        }
        st
    }

    /// On photos rendered at σ 0.3 with one colour per cube, the patch sweep proposes σ near
    /// 0.3 for a fit that is not there, and the hop takes the segment most of the way there.
    #[test]
    fn the_patch_hypothesis_finds_the_rendered_roughness() {
        let truth = 0.3;
        let st = rendered_store(400, truth);
        let (tr, mut schedule) = toy_fitted(&st);
        // The hop runs at the schedule's last rate: keep it at the first so 50 steps can move σ.
        schedule.lr_end = 1.0;
        let hc = HopConfig {
            gain: 1.0,
            metal: false,
            patch: 1.0,
            patch_gain: 0.0,
            patch_min_move: 0.0,
            steps: 1.0,
            pull: 10.0,
            ..HopConfig::default()
        };
        let plan = toy_plan(&hc, &schedule, 5e-4, 1.0);
        let (_, rep) = hop(tr, &st, &plan).unwrap();
        let (best, obj, at_fit) = rep.segments[0].patch.expect("patch profile");
        assert!((best - truth as f64).abs() < 0.05, "best σ {best}");
        assert!(obj < 0.5 * at_fit, "{obj} vs {at_fit}");
        let c = &rep.candidates[0];
        assert_eq!(c.source, Hypothesis::Patch);
        assert!(
            (c.sigma_after - c.target).abs() < 0.5 * (c.sigma - c.target).abs(),
            "{} → {} for {}",
            c.sigma,
            c.sigma_after,
            c.target
        );
        // Its own hop, with its own decision; no other hop ran.
        assert_eq!(
            rep.patch_accepted,
            Some(hop_helped(&rep.candidates, hc.patch_gain))
        );
        assert!(!rep.accepted);
        assert_eq!(rep.steps, 2 * 25);
    }

    /// On a metal's photos (m 1, σ 0.3, one colour per cube), the patch sweep solved as a metal
    /// (`patch_metals`) puts its best σ near 0.3 and scores there below half its objective at
    /// the fitted σ; solved as a dielectric, as without the key, it scores worse at its best.
    #[test]
    fn the_patch_hypothesis_as_a_metal_finds_a_metals_roughness() {
        let truth = 0.3;
        let st = rendered_store_m(400, truth, 1.0);
        let (tr, _) = toy_fitted(&st);
        // Cubes of side 1: the store's four.
        let p = PatchSegments::new(&st, 1.0);
        let profile = |metal: bool| p.profile(&tr.model, 0, metal).expect("patch profile").0;
        let (best, obj, at_fit) = profile(true);
        assert!((best - truth as f64).abs() < 0.05, "best σ {best}");
        assert!(obj < 0.5 * at_fit, "{obj} vs {at_fit}");
        let (_, as_dielectric, _) = profile(false);
        assert!(obj < 0.5 * as_dielectric, "{obj} vs {as_dielectric}");
    }
}
