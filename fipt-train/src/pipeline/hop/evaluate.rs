//! The hop's objective, Eq. 15 + 17, per segment on a sample of its pixels: at the model, and
//! at the hypotheses (the σ sweep at the fitted colour, a metal with one colour per segment,
//! one colour at the fitted σ and m, the last round's material); and each segment's check.
//!
//! Owns: the evaluation and the checks. Must not touch: which hypothesis counts
//! (`choose`), the model.

use super::record::SegmentObjective;
use crate::pipeline::landscape::sweep;
use crate::pipeline::pixels::PixelStore;
use fipt_core::brdf::{factorised_render, reflectances};
use fipt_core::model::FiptModel;
use fipt_core::model::loss::{DiffusePrior, tonemap_host as tonemap};
use fipt_core::shading::ShadingLayout;
use std::collections::BTreeMap;

/// One segment's pixels in the evaluation: its id, its size in the store, the entries used.
pub(super) struct SegmentSample {
    pub(super) id: i32,
    pub(super) size: usize,
    pub(super) idx: Vec<u32>,
}

/// Up to `per` entries of every segment, evenly strided.
pub(super) fn sample(store: &PixelStore, per: usize) -> Vec<SegmentSample> {
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
pub(super) struct SegmentEval {
    pub(super) sigma: f64,
    pub(super) metallic: f64,
    pub(super) own: f64,
    /// At each swept σ, the least objective over the base-colour scales (`SCALES`).
    pub(super) sweep: Vec<f64>,
    /// At each swept σ, the least objective of a metal over the scales of its colour.
    pub(super) metal: Vec<f64>,
    /// The least objective over the scales of one colour per segment at the fitted mean σ and
    /// m (NaN where the metal was not tried).
    pub(super) uniform: f64,
    /// The carried material's mean σ, mean m and objective.
    pub(super) carried: Option<(f64, f64, f64)>,
}

/// Scales of the fitted base colour tried at each swept σ: 0.5, 0.55, …, 1.5. A part fitted in
/// the wrong σ basin has a base colour that absorbed its highlights (a rough fit is brighter), so
/// σ alone at that colour under-rates the other basin; the profile over one common scale per
/// segment does not.
pub(super) const SCALES: usize = 21;

pub(super) fn scale(j: usize) -> f32 {
    0.5 + j as f32 / (SCALES - 1) as f32
}

/// What `evaluate` scores besides the model itself.
#[derive(Clone, Copy, Default)]
pub(super) struct Hypotheses<'a> {
    /// The σ sweep at the fitted base colour (scaled) and metallic.
    pub(super) sweep: bool,
    /// The σ sweep of a metal with one base colour per segment.
    pub(super) metal: bool,
    /// The segments also scored at one colour per segment at the fitted mean σ and m (every
    /// segment where `metal`).
    pub(super) uniform: &'a [i32],
    /// The last round's model, whose material is scored under these shadings.
    pub(super) carried: Option<&'a FiptModel>,
}

/// One pixel's objective (Eq. 15 + Eq. 17's summand) at base colour `a`, roughness `sigma`
/// and metallic `m`, for emission mask `alpha`, packed shadings `sh` and photo `gt`.
pub(super) fn pixel_objective(
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
pub(super) fn uniform_colour(
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
pub(super) fn evaluate(
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
            let uniform = if with.metal || with.uniform.contains(&s.id) {
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
pub(super) fn whole(samples: &[SegmentSample], evals: &[SegmentEval]) -> f64 {
    let n: usize = samples.iter().map(|s| s.size).sum();
    samples
        .iter()
        .zip(evals)
        .map(|(s, e)| e.own * s.size as f64)
        .sum::<f64>()
        / n.max(1) as f64
}

/// The least value of a profile over the swept σ and where it lies (NaN without a profile).
pub(super) fn profile_min(profile: &[f64]) -> (f64, f64) {
    let sig = sweep();
    profile
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(b.1))
        .map_or((f64::NAN, f64::NAN), |(j, b)| (sig[j] as f64, *b))
}

/// Every segment's check: its mean fitted σ, m and objective, and each hypothesis's best
/// (NaN or None where it was not scored).
pub(super) fn checks(samples: &[SegmentSample], evals: &[SegmentEval]) -> Vec<SegmentObjective> {
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
