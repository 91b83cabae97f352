//! The data term (Eq. 15) with the base colour free per surface patch: pixels are grouped into
//! cubes by the world position of their centre ray's hit, and at a given roughness every cube
//! takes the base colour that fits its photos best. A fit's base colour is free at every point,
//! so at the fitted colour a glossy part's data is flat over σ (the colour has absorbed its
//! highlights); re-solving the colour at each σ, as here, compares the roughness hypotheses on
//! equal terms, and the view dependence of the cubes seen from several views decides between
//! them. Used by the basin hop (`train.hop.patch`) and by `landscape`.
//!
//! Owns: the grouping into cubes and the per-cube colour solve. Must not touch: the model, the
//! fit, the shadings.

use fipt_core::brdf::specular_shadings;
use fipt_core::model::loss::tonemap_host as tonemap;
use fipt_core::shading::ShadingLayout;
use std::collections::BTreeMap;

/// One pixel as the solve sees it: its packed shadings, photo, metallic and emission mask.
#[derive(Clone, Copy)]
pub struct PatchPixel<'a> {
    pub shading: &'a [f32],
    pub gt: [f32; 3],
    pub metallic: f32,
    pub alpha: f32,
}

/// The entries (indices into `positions`) of every cube of side `side` that holds one, in the
/// cubes' order (so that sums over them are the same on any number of threads).
pub fn cubes(positions: &[[f32; 3]], side: f32) -> Vec<Vec<u32>> {
    let mut by: BTreeMap<[i64; 3], Vec<u32>> = BTreeMap::new();
    for (i, p) in positions.iter().enumerate() {
        let key = p.map(|x| (x / side).floor() as i64);
        by.entry(key).or_default().push(i as u32);
    }
    by.into_values().collect()
}

/// Slope of the tone curve at a photo value: the weight that makes a linear least-squares
/// colour solve approximate the tone-mapped error.
fn slope(g: f32) -> f64 {
    let e = (g.abs() * 1e-3).max(1e-5);
    let lo = (g - e).max(0.0);
    (tonemap(g + e) - tonemap(lo)) / (g + e - lo) as f64
}

/// The sum over `pixels` of Eq. 15's summand, (Γ((1 − α)·C + α·I) − Γ(I))² averaged over the
/// channels, where C = k_d·L_d + k_s·L_s0(σ) + L_s1(σ) at each pixel's `sigma(i)` and metallic,
/// and every cube of `cubes` takes one base colour: per channel the least-squares fit of
/// a·P + Q to the photos, P = (1 − m)·L_d + m·L_s0(σ), Q = 0.04·(1 − m)·L_s0(σ) + L_s1(σ), each
/// pixel weighted by (1 − α)² and the tone curve's slope² at its photo; clamped to [0, 1].
pub fn objective(
    pixels: &[PatchPixel],
    cubes: &[Vec<u32>],
    sigma: &(dyn Fn(usize) -> f32 + Sync),
) -> f64 {
    per_cube(pixels, cubes, sigma).iter().sum()
}

/// `objective`'s summand of every cube of `cubes`, in their order.
pub fn per_cube(
    pixels: &[PatchPixel],
    cubes: &[Vec<u32>],
    sigma: &(dyn Fn(usize) -> f32 + Sync),
) -> Vec<f64> {
    use rayon::prelude::*;
    cubes
        .par_iter()
        .map(|cube| {
            let terms: Vec<([f32; 3], [f32; 3], &PatchPixel)> = cube
                .iter()
                .map(|&i| {
                    let px = &pixels[i as usize];
                    let (s0, s1) = specular_shadings(sigma(i as usize), px.shading);
                    let m = px.metallic;
                    let p = std::array::from_fn(|c| {
                        (1.0 - m) * px.shading[ShadingLayout::LD.start + c] + m * s0[c]
                    });
                    let q = std::array::from_fn(|c| 0.04 * (1.0 - m) * s0[c] + s1[c]);
                    (p, q, px)
                })
                .collect();
            let (mut num, mut den) = ([0f64; 3], [0f64; 3]);
            for (p, q, px) in &terms {
                let share = ((1.0 - px.alpha) * (1.0 - px.alpha)) as f64;
                for c in 0..3 {
                    let w = share * slope(px.gt[c]).powi(2);
                    num[c] += w * (p[c] * (px.gt[c] - q[c])) as f64;
                    den[c] += w * (p[c] * p[c]) as f64;
                }
            }
            let a: [f32; 3] = std::array::from_fn(|c| {
                if den[c] > 0.0 {
                    (num[c] / den[c]).clamp(0.0, 1.0) as f32
                } else {
                    0.0
                }
            });
            terms
                .iter()
                .map(|(p, q, px)| {
                    (0..3)
                        .map(|c| {
                            let render = a[c] * p[c] + q[c];
                            let comp = (1.0 - px.alpha) * render + px.alpha * px.gt[c];
                            (tonemap(comp) - tonemap(px.gt[c])).powi(2)
                        })
                        .sum::<f64>()
                        / 3.0
                })
                .sum::<f64>()
        })
        .collect()
}

/// How many of a surface's cubes prefer σ hypothesis A to B: the share of the pixels whose
/// cube scores lower at A (`at_a`, `per_cube` at A) than at B (`at_b`), and the effective
/// number of cubes that share is a mean over, (Σ n)² / Σ n² for cubes of n pixels. A
/// hypothesis that a few cubes carry (where the shadings are off, say) scores lower in sum
/// but is preferred by fewer than half of them.
pub fn preference(cubes: &[Vec<u32>], at_a: &[f64], at_b: &[f64]) -> (f64, f64) {
    let (mut won, mut all, mut sq) = (0.0, 0.0, 0.0);
    for ((cube, a), b) in cubes.iter().zip(at_a).zip(at_b) {
        let n = cube.len() as f64;
        all += n;
        sq += n * n;
        if a < b {
            won += n;
        }
    }
    if all > 0.0 {
        (won / all, all * all / sq)
    } else {
        (f64::NAN, 0.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fipt_core::brdf::{factorised_render, reflectances};

    /// Packed shadings whose specular levels differ, so that σ changes the render.
    fn shading(seed: u32) -> Vec<f32> {
        (0..ShadingLayout::DIM)
            .map(|k| 0.2 + 0.7 * (((k as u32 * 7 + seed * 13) % 11) as f32 / 11.0))
            .collect()
    }

    /// Photos rendered with one base colour per cube and σ 0.3: the objective is zero at σ 0.3
    /// (the solve recovers the colours) and positive at σ 0.9, where no colour explains the
    /// view dependence.
    #[test]
    fn recovers_the_rendered_roughness() {
        let positions: Vec<[f32; 3]> = (0..40)
            .map(|i| [(i % 4) as f32 * 0.5 + 0.1, 0.2, 0.3])
            .collect();
        let cubes = cubes(&positions, 0.5);
        assert_eq!(cubes.len(), 4);
        let sh: Vec<Vec<f32>> = (0..40).map(shading).collect();
        let colour = |i: usize| glam::Vec3::new(0.2 + 0.15 * (i % 4) as f32, 0.5, 0.3);
        let pixels: Vec<PatchPixel> = (0..40)
            .map(|i| {
                let (kd, ks) = reflectances(colour(i), 0.0);
                let gt = factorised_render(kd.to_array(), ks.to_array(), 0.3, &sh[i]);
                PatchPixel {
                    shading: &sh[i],
                    gt,
                    metallic: 0.0,
                    alpha: 0.0,
                }
            })
            .collect();
        let at = |s: f32| objective(&pixels, &cubes, &move |_| s);
        assert!(at(0.3) < 1e-9, "{}", at(0.3));
        assert!(at(0.9) > 1e-5, "{}", at(0.9));
        // One cube over everything cannot fit four colours even at the true σ.
        let one = vec![(0..40).collect::<Vec<u32>>()];
        assert!(objective(&pixels, &one, &|_| 0.3) > 1e-4);
        // The objective is the sum of the cubes' summands.
        let per = per_cube(&pixels, &cubes, &|_| 0.9);
        assert_eq!(per.len(), 4);
        assert!((per.iter().sum::<f64>() - at(0.9)).abs() <= 1e-12 * at(0.9));
        // Every cube prefers the true σ.
        let truth = per_cube(&pixels, &cubes, &|_| 0.3);
        assert_eq!(preference(&cubes, &truth, &per), (1.0, 4.0));
        assert_eq!(preference(&cubes, &per, &truth).0, 0.0);
    }

    /// One cube far better at A and three a little worse: A wins the sum, but a quarter of
    /// the pixels prefer it; cubes of 3, 1 and 1 pixels count as (5²)/11 of equal size.
    #[test]
    fn preference_counts_pixels_not_the_sum() {
        let cubes: Vec<Vec<u32>> = vec![vec![0], vec![1], vec![2], vec![3]];
        let (a, b) = ([0.1, 1.01, 1.01, 1.01], [1.0; 4]);
        assert!(a.iter().sum::<f64>() < b.iter().sum::<f64>());
        assert_eq!(preference(&cubes, &a, &b), (0.25, 4.0));
        let uneven: Vec<Vec<u32>> = vec![vec![0, 1, 2], vec![3], vec![4]];
        let (share, n) = preference(&uneven, &[0.0, 1.0, 1.0], &[1.0, 0.0, 0.0]);
        assert_eq!(share, 0.6);
        assert!((n - 25.0 / 11.0).abs() < 1e-12);
        assert!(preference(&[], &[], &[]).0.is_nan());
    }
}
