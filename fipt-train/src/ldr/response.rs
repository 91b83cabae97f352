//! The camera response, estimated jointly with the diffuse albedos and the clipped lamps'
//! radiance of the lamp solve (`super::lights`).
//!
//! - **Model**: g_c(v) = srgb⁻¹(v)^γ_c (`Response::srgb_power`): the sRGB encoding that 8-bit
//!   photos are written in, with one contrast exponent per channel. EMoR's basis (IRIS's) has
//!   three weights per channel, more than one exposure's photos pin down.
//! - **Signal**: for the rough dielectric pixels of a part, the photo is k_P·(Σ_k Le_k·D_k + E),
//!   where D_k, the unit-radiance irradiance from lamp k, is geometry (distance, cosines,
//!   visibility) and E is the light the photos themselves record. Only the true response makes
//!   the linearised pixels follow that falloff with one albedo per part: a wrong γ bends the
//!   bright, directly lit pixels against the dim ones.
//! - **Measure**: for each γ, the radiance and albedos are solved (`super::lights::alternate`)
//!   on the pixels linearised with it, and the prediction is scored in the photo's own code
//!   values, f_γ(e·k_P·S) against the 8-bit code (IRIS's LDR-space loss; a linear-space score
//!   would favour γ → 0, which flattens every value), with a Cauchy loss (scale 0.02).
//! - **Search**: log₂ γ on a grid over [−1, 1] in steps of 0.05, then steps of 0.01 around the
//!   best, per channel.
//!
//! With γ, L′ (made from the photos linearised with γ = 1) becomes L′^γ, and estimated exposures
//! become e^γ (they were fitted to the γ = 1 values); given exposures stay. Both are exact for
//! one exposure shared by all frames (e = 1); where given exposures differ, L′^γ stands for
//! (L′·e)^γ/e, and where γ differs between channels, e^γ for the one exposure per frame that
//! the relinearisation estimates: the search's approximations. The code-value score assumes the
//! photos were linearised with the sRGB curve (γ = 1), as they are before the estimate.
//!
//! Owns: the response's estimate. Must not touch: the photos, the pixel choice, the light terms.

use super::lights::{ALTERNATIONS, SolvePixel, alternate};
use fipt_core::scene::ldr::linear_to_srgb;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// The Cauchy scale of the code-value residual.
const CODE_SCALE: f64 = 0.02;

/// Pixels of the grid search (the final solve takes all).
const SEARCH_PIXELS: usize = 5000;

/// Alternation rounds per γ of the search.
const SEARCH_ROUNDS: usize = 60;

/// The estimate: γ per channel, the cost curve it was read from, and the clipped lamps'
/// radiance solved at that γ.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ResponseFit {
    pub gamma: [f64; 3],
    /// (γ, mean cost per channel) over the coarse grid.
    pub curve: Vec<(f64, [f64; 3])>,
    /// Le_k per clipped lamp at the estimated γ (radiance linearised with it).
    pub radiance: Vec<[f64; 3]>,
}

impl ResponseFit {
    pub fn response(&self) -> fipt_core::scene::Response {
        fipt_core::scene::Response::srgb_power(self.gamma)
    }
}

/// One channel's observations, shadings and clip levels under a γ.
pub struct ChannelTerms {
    pub obs: Vec<f64>,
    pub rest: Vec<f64>,
    /// E from each half of L′'s samples where the pixel has halves (`SolvePixel::direct_half`),
    /// else E twice.
    pub rest_half: Vec<[f64; 2]>,
    pub level: Vec<f64>,
    /// The exposure of each pixel's view under γ.
    pub exposure: Vec<f64>,
}

impl ChannelTerms {
    /// Channel `c` of `pixels` linearised with exponent `gamma`: obs = g(code)^γ / e_γ,
    /// E = mean of the L′ samples^γ, T = T^γ where exposures were estimated (else T).
    pub fn new(
        pixels: &[SolvePixel],
        level: &[[f64; 3]],
        c: usize,
        gamma: f64,
        exposures_estimated: bool,
    ) -> Self {
        // What moves with γ where the exposures were estimated: the exposures and clip levels.
        let moved = |x: f64| {
            if exposures_estimated {
                x.powf(gamma)
            } else {
                x
            }
        };
        let exposure: Vec<f64> = pixels.iter().map(|p| moved(p.exposure)).collect();
        let mean = |ls: &[[f32; 3]]| {
            ls.iter().map(|l| (l[c] as f64).powf(gamma)).sum::<f64>() / ls.len().max(1) as f64
        };
        let rest: Vec<f64> = pixels.iter().map(|p| mean(&p.lprime)).collect();
        let rest_half = pixels
            .iter()
            .zip(&rest)
            .map(|(p, &r)| {
                let m = p.lprime.len() / 2;
                if p.direct_half.is_empty() || m == 0 {
                    [r; 2]
                } else {
                    [mean(&p.lprime[..m]), mean(&p.lprime[m..])]
                }
            })
            .collect();
        Self {
            obs: pixels
                .iter()
                .zip(&exposure)
                .map(|(p, e)| p.value[c].powf(gamma) / e)
                .collect(),
            rest,
            rest_half,
            level: level.iter().map(|t| moved(t[c])).collect(),
            exposure,
        }
    }

    /// Pixel `j`'s shading, E + Σ_k Le_k·D_k, for the radiance `le` of this channel.
    pub fn shading(&self, j: usize, px: &SolvePixel, le: &[f64]) -> f64 {
        self.rest[j]
            + le.iter()
                .zip(&px.direct)
                .map(|(l, &d)| l * d as f64)
                .sum::<f64>()
    }

    /// Pixel `j`'s shading from half `h` of the light terms' samples (the whole estimate where
    /// the pixel has no halves).
    pub fn shading_half(&self, j: usize, px: &SolvePixel, le: &[f64], h: usize) -> f64 {
        self.rest_half[j][h]
            + le.iter()
                .enumerate()
                .map(|(k, l)| l * px.direct_of(k, h) as f64)
                .sum::<f64>()
    }
}

/// Le_k per clipped lamp, each channel `c` solved with exponent `gamma[c]` (`ALTERNATIONS`
/// rounds).
pub fn solve_radiance(
    pixels: &[SolvePixel],
    n_parts: usize,
    level: &[[f64; 3]],
    gamma: [f64; 3],
    exposures_estimated: bool,
) -> Vec<[f64; 3]> {
    let le = [0, 1, 2].map(|c| {
        let t = ChannelTerms::new(pixels, level, c, gamma[c], exposures_estimated);
        alternate(&t, pixels, n_parts, ALTERNATIONS).0
    });
    (0..level.len())
        .map(|k| [le[0][k], le[1][k], le[2][k]])
        .collect()
}

/// The mean Cauchy cost, in code values, of the solve `(le, kd)` on channel `c`.
fn code_cost(
    pixels: &[SolvePixel],
    t: &ChannelTerms,
    le: &[f64],
    kd: &[f64],
    c: usize,
    gamma: f64,
) -> f64 {
    let sum: f64 = pixels
        .iter()
        .enumerate()
        .map(|(j, p)| {
            let x = (kd[p.part] * t.shading(j, p, le) * t.exposure[j]).clamp(0.0, 1.0);
            let r = p.code[c] - linear_to_srgb(x.powf(1.0 / gamma));
            (1.0 + (r / CODE_SCALE).powi(2)).ln()
        })
        .sum();
    sum / pixels.len().max(1) as f64
}

/// The cost of exponent `gamma` on channel `c` (solve, then score).
fn cost_at(
    pixels: &[SolvePixel],
    n_parts: usize,
    level: &[[f64; 3]],
    c: usize,
    gamma: f64,
    est: bool,
) -> f64 {
    let t = ChannelTerms::new(pixels, level, c, gamma, est);
    let (le, kd) = alternate(&t, pixels, n_parts, SEARCH_ROUNDS);
    code_cost(pixels, &t, &le, &kd, c, gamma)
}

/// Estimates γ per channel from the solve's pixels and returns it with the lamps' radiance
/// solved at it. `level`: the clipped lamps' clip levels (γ = 1); `exposures_estimated`: see
/// the module's note.
pub fn estimate(
    pixels: &[SolvePixel],
    n_parts: usize,
    level: &[[f64; 3]],
    exposures_estimated: bool,
) -> ResponseFit {
    let stride = (pixels.len() / SEARCH_PIXELS).max(1);
    let sub: Vec<SolvePixel> = pixels.iter().step_by(stride).cloned().collect();
    let grid = |lo: f64, hi: f64, step: f64| -> Vec<f64> {
        let n = ((hi - lo) / step).round() as usize;
        (0..=n).map(|i| lo + i as f64 * step).collect()
    };
    let cost = |c: usize, lg: f64| cost_at(&sub, n_parts, level, c, lg.exp2(), exposures_estimated);
    let coarse = grid(-1.0, 1.0, 0.05);
    let curve_cost: Vec<[f64; 3]> = coarse
        .par_iter()
        .map(|&lg| [0, 1, 2].map(|c| cost(c, lg)))
        .collect();
    let best = |xs: &[f64], cs: &[f64]| {
        let i = (0..cs.len())
            .min_by(|&a, &b| cs[a].total_cmp(&cs[b]))
            .unwrap_or(0);
        xs[i]
    };
    let gamma = [0, 1, 2].map(|c| {
        let cs: Vec<f64> = curve_cost.iter().map(|k| k[c]).collect();
        let lg = best(&coarse, &cs);
        let fine = grid(lg - 0.05, lg + 0.05, 0.01);
        let fc: Vec<f64> = fine.par_iter().map(|&x| cost(c, x)).collect();
        best(&fine, &fc).exp2()
    });
    ResponseFit {
        gamma,
        curve: coarse
            .iter()
            .zip(curve_cost)
            .map(|(lg, k)| (lg.exp2(), k))
            .collect(),
        radiance: solve_radiance(pixels, n_parts, level, gamma, exposures_estimated),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fipt_core::rng::Rng;
    use fipt_core::scene::ldr::srgb_to_linear;

    /// The pixels, the part count, the lamps' clip levels and their true radiance.
    type Scene = (Vec<SolvePixel>, usize, Vec<[f64; 3]>, Vec<[f64; 3]>);

    /// Pixels of a made-up scene photographed through g = srgb⁻¹^γ: 6 parts, 2 lamps, direct
    /// terms and L′ samples drawn at random, codes quantised to 8 bits. L′ holds what the
    /// photos linearised with γ = 1 give: the true radiance^(1/γ).
    fn scene(gamma: [f64; 3], n: usize) -> Scene {
        let mut rng = Rng::new(3, 0);
        let kd: Vec<[f64; 3]> = (0..6)
            .map(|_| [0, 1, 2].map(|_| 0.2 + 0.6 * rng.next_f32() as f64))
            .collect();
        let le = vec![[40.0, 30.0, 20.0], [15.0, 25.0, 35.0]];
        let level = vec![[1.0; 3]; 2];
        let pixels = (0..n)
            .map(|j| {
                let part = j % 6;
                let direct: Vec<f32> = (0..2).map(|_| 0.02 * rng.next_f32().powi(2)).collect();
                let truth: Vec<[f64; 3]> = (0..16)
                    .map(|_| [0, 1, 2].map(|_| 0.3 * rng.next_f32() as f64))
                    .collect();
                let code = [0, 1, 2].map(|c| {
                    let e: f64 = truth.iter().map(|t| t[c]).sum::<f64>() / truth.len() as f64;
                    let s = e + (0..2).map(|k| le[k][c] * direct[k] as f64).sum::<f64>();
                    let x = (kd[part][c] * s).clamp(0.0, 1.0).powf(1.0 / gamma[c]);
                    (linear_to_srgb(x) * 255.0).round() / 255.0
                });
                let lprime = truth
                    .iter()
                    .map(|t| [0, 1, 2].map(|c| t[c].powf(1.0 / gamma[c]) as f32))
                    .collect();
                SolvePixel {
                    code,
                    value: code.map(srgb_to_linear),
                    exposure: 1.0,
                    part,
                    direct,
                    lprime,
                    direct_half: Vec::new(),
                }
            })
            .filter(|p| p.code.iter().all(|&c| c > 0.02 && c < 0.98))
            .collect();
        (pixels, 6, level, le)
    }

    #[test]
    fn recovers_the_exponent_and_the_lamps() {
        let truth = [0.8, 1.0, 1.3];
        let (pixels, parts, level, le) = scene(truth, 6000);
        let fit = estimate(&pixels, parts, &level, true);
        for c in 0..3 {
            let err = (fit.gamma[c] / truth[c]).log2().abs();
            assert!(
                err <= 0.03,
                "channel {c}: γ {} against {}",
                fit.gamma[c],
                truth[c]
            );
            for (k, (fk, tk)) in fit.radiance.iter().zip(&le).enumerate() {
                let rel = fk[c] / tk[c] - 1.0;
                assert!(rel.abs() < 0.1, "lamp {k} channel {c}: {rel}");
            }
        }
        // The response it stands for, against the truth, in the measure.
        let rms = fit
            .response()
            .rms_forward(&fipt_core::scene::Response::srgb_power(truth));
        assert!(rms < 0.01, "{rms}");
        // The γ = 1 solve (the sRGB curve) scores worse where the truth is not 1.
        let at = |c: usize, g: f64| cost_at(&pixels, parts, &level, c, g, true);
        assert!(at(0, 1.0) > at(0, truth[0]) && at(2, 1.0) > at(2, truth[2]));
    }
}
