//! Edge-aware denoising of shading images on the CPU (the reference uses the OptiX AI denoiser).
//!
//! A joint (cross) bilateral filter in image space, guided by the first-hit geometry: weights
//! fall off with world distance (scaled by the pixel footprint), normal difference and distance
//! from the centre pixel's tangent plane, so nothing is blurred across geometry edges; misses
//! are never mixed in. It returns the window's weighted mean (`order` 0) or the value at the
//! centre of its weighted least-squares plane (`order` 1), which is not biased by a gradient
//! up to an edge, where the window is one-sided.
//!
//! Owns: the filter. Must not touch: how the shadings were estimated.

use crate::accel::raycast::ViewHits;
use glam::Vec3;
use rayon::prelude::*;

/// Filter settings (serde: part of the bake config).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FilterConfig {
    /// Window radius in pixels (0 disables the filter).
    pub radius: usize,
    /// Std-dev of the world-distance weight, in pixel footprints at the centre pixel's depth.
    pub sigma_px: f32,
    /// Exponent of the normal weight max(0, n_i·n_j)^k.
    pub normal_power: f32,
    /// Std-dev of the distance to the centre pixel's tangent plane, in pixel footprints.
    pub sigma_plane_px: f32,
    /// Specular levels (0..6) that are filtered; sharp lobes are left alone.
    pub specular_levels: Vec<usize>,
    /// 1 (default): the weighted least-squares plane over the centre's tangent plane, read at
    /// the centre, which follows a shading gradient up to an edge; 0: the weighted mean of the
    /// window (the reference's denoiser has no such setting), biased there because the window
    /// is one-sided.
    pub order: usize,
}

impl Default for FilterConfig {
    fn default() -> Self {
        Self {
            radius: 4,
            sigma_px: 2.5,
            normal_power: 64.0,
            sigma_plane_px: 1.0,
            specular_levels: vec![2, 3, 4, 5],
            order: 1,
        }
    }
}

/// Filters the channel groups `groups` (each a list of channel offsets into the per-pixel
/// vector of `dim` values) of one view's shading buffer in place. `focal` is the camera focal
/// length in pixels (for the footprint t/f).
pub fn filter_view(
    cfg: &FilterConfig,
    hits: &ViewHits,
    focal: f32,
    data: &mut [f32],
    dim: usize,
    groups: &[Vec<usize>],
) {
    if cfg.radius == 0 || groups.is_empty() {
        return;
    }
    let (w, h) = (hits.width, hits.height);
    let src = data.to_vec();
    let r = cfg.radius as isize;
    data.par_chunks_mut(dim).enumerate().for_each(|(p, out)| {
        if hits.tri[p] < 0 {
            return;
        }
        let (y, x) = ((p / w) as isize, (p % w) as isize);
        let (pi, ni) = (hits.position[p], hits.normal[p]);
        let foot = (hits.t[p] / focal).max(1e-6);
        let inv_s2 = 1.0 / (2.0 * (cfg.sigma_px * foot).powi(2));
        let inv_pl2 = 1.0 / (2.0 * (cfg.sigma_plane_px * foot).powi(2));
        let nc: usize = groups.iter().map(|g| g.len()).sum();
        let mut acc = vec![0f32; nc];
        let mut wsum = 0f32;
        // First order only: tangent axes of the centre, moments of [1, u, v] and their
        // products with each channel (u, v in footprints).
        let axes = (cfg.order > 0).then(|| ni.any_orthonormal_pair());
        let mut m = [0f64; 5];
        let mut mu = vec![0f64; if axes.is_some() { 2 * nc } else { 0 }];
        for dy in -r..=r {
            let yy = y + dy;
            if yy < 0 || yy >= h as isize {
                continue;
            }
            for dx in -r..=r {
                let xx = x + dx;
                if xx < 0 || xx >= w as isize {
                    continue;
                }
                let q = yy as usize * w + xx as usize;
                if hits.tri[q] < 0 {
                    continue;
                }
                let (pq, nq) = (hits.position[q], hits.normal[q]);
                let d: Vec3 = pq - pi;
                let nd = ni.dot(nq).max(0.0);
                if nd <= 0.0 {
                    continue;
                }
                let plane = ni.dot(d);
                let wgt = (-(d.length_squared() * inv_s2) - plane * plane * inv_pl2).exp()
                    * nd.powf(cfg.normal_power);
                if wgt < 1e-6 {
                    continue;
                }
                // (w·u, w·v) of this pixel, first order only.
                let wuv = axes.map(|(ta, tb)| {
                    let (u, v) = ((ta.dot(d) / foot) as f64, (tb.dot(d) / foot) as f64);
                    let wd = wgt as f64;
                    for (mm, x) in m.iter_mut().zip([u, v, u * u, u * v, v * v]) {
                        *mm += wd * x;
                    }
                    (wd * u, wd * v)
                });
                let mut k = 0;
                for g in groups {
                    for &c in g {
                        let y = src[q * dim + c];
                        acc[k] += wgt * y;
                        if let Some((wu, wv)) = wuv {
                            mu[2 * k] += wu * y as f64;
                            mu[2 * k + 1] += wv * y as f64;
                        }
                        k += 1;
                    }
                }
                wsum += wgt;
            }
        }
        if wsum > 0.0 {
            let plane = axes.and_then(|_| Plane::new(wsum as f64, &m));
            let mut k = 0;
            for g in groups {
                for &c in g {
                    out[c] = match &plane {
                        Some(pl) => pl.at_centre(acc[k] as f64, mu[2 * k], mu[2 * k + 1]) as f32,
                        None => acc[k] / wsum,
                    };
                    k += 1;
                }
            }
        }
    });
}

/// The weighted least-squares plane y ≈ β0 + β1·u + β2·v of a window: the inverse of its
/// moment matrix, from which β0 (the value at the centre) follows for each channel.
struct Plane {
    /// First row of the inverse of [[S, Su, Sv], [Su, Suu, Suv], [Sv, Suv, Svv]].
    row: [f64; 3],
}

impl Plane {
    /// From the weight sum `s` and the moments [Su, Sv, Suu, Suv, Svv]; None where the
    /// window's points do not span a plane (a line of pixels), and the mean is used.
    fn new(s: f64, m: &[f64; 5]) -> Option<Self> {
        let [su, sv, suu, suv, svv] = *m;
        let c00 = suu * svv - suv * suv;
        let c01 = sv * suv - su * svv;
        let c02 = su * suv - sv * suu;
        let det = s * c00 + su * c01 + sv * c02;
        // Relative to the scale of the moments: a window spread over less than a thin line.
        (det > 1e-6 * s * (suu * svv).max(1e-30)).then(|| Self {
            row: [c00 / det, c01 / det, c02 / det],
        })
    }

    /// β0 from the channel's sums Σw·y, Σw·u·y, Σw·v·y.
    fn at_centre(&self, sy: f64, suy: f64, svy: f64) -> f64 {
        self.row[0] * sy + self.row[1] * suy + self.row[2] * svy
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fipt_core::rng::Rng;

    const W: usize = 24;
    const H: usize = 16;
    /// Focal length in pixels: pixel footprints are ~t/16, a few cm at t ≈ 1.
    const F: f32 = 16.0;

    /// Pixel-centre hits of a camera at the origin looking down +z (OpenCV axes) on the plane
    /// n·x = c chosen per pixel (n facing the camera); None is a miss.
    fn hits(plane: impl Fn(usize, usize, Vec3) -> Option<(Vec3, f32)>) -> ViewHits {
        let mut v = ViewHits {
            width: W,
            height: H,
            origin: Vec3::ZERO,
            direction: vec![],
            t: vec![],
            tri: vec![],
            position: vec![],
            normal: vec![],
        };
        for p in 0..W * H {
            let (row, col) = (p / W, p % W);
            let d = Vec3::new(
                (col as f32 + 0.5 - 0.5 * W as f32) / F,
                (row as f32 + 0.5 - 0.5 * H as f32) / F,
                1.0,
            )
            .normalize();
            v.direction.push(d);
            match plane(row, col, d) {
                Some((n, c)) => {
                    let t = c / n.dot(d);
                    assert!(t > 0.0 && n.dot(d) < 0.0);
                    v.t.push(t);
                    v.tri.push(p as i32);
                    v.position.push(d * t);
                    v.normal.push(n);
                }
                None => {
                    v.t.push(f32::INFINITY);
                    v.tri.push(-1);
                    v.position.push(Vec3::ZERO);
                    v.normal.push(Vec3::ZERO);
                }
            }
        }
        v
    }

    /// Left half: the wall z = 1; right half: the wall z = 1.5 (same normal, a depth step).
    fn depth_step() -> ViewHits {
        hits(|_, col, _| {
            let c = if col < W / 2 { -1.0 } else { -1.5 };
            Some((Vec3::NEG_Z, c))
        })
    }

    /// Left half: z = 1; right half: the plane z = 1 + x through the same line x = 0, z = 1 —
    /// a 45° crease, continuous in position, only the normal changes.
    fn crease() -> ViewHits {
        let nb = Vec3::new(1.0, 0.0, -1.0).normalize();
        hits(move |_, _, d| {
            if d.x < 0.0 {
                Some((Vec3::NEG_Z, -1.0))
            } else {
                Some((nb, -std::f32::consts::FRAC_1_SQRT_2))
            }
        })
    }

    fn left(p: usize) -> bool {
        p % W < W / 2
    }

    #[test]
    fn constants_are_preserved() {
        let cfg = FilterConfig::default();
        for h in [depth_step(), crease()] {
            let mut data: Vec<f32> = (0..W * H).flat_map(|_| [0.37, -2.5, 11.0]).collect();
            let orig = data.clone();
            filter_view(&cfg, &h, F, &mut data, 3, &[vec![0, 1, 2]]);
            for (a, b) in data.iter().zip(&orig) {
                assert!((a - b).abs() <= 1e-5 * b.abs(), "{a} vs {b}");
            }
        }
    }

    #[test]
    fn step_edges_are_not_blurred_and_noise_drops() {
        let cfg = FilterConfig::default();
        for (name, h) in [("depth step", depth_step()), ("crease", crease())] {
            // Noise-free: 1 on the left surface, 5 on the right. A filter that mixes across the
            // edge gives in-between values next to it; this one must give exactly 1 and 5.
            let truth: Vec<f32> = (0..W * H)
                .map(|p| if left(p) { 1.0 } else { 5.0 })
                .collect();
            let mut data = truth.clone();
            filter_view(&cfg, &h, F, &mut data, 1, &[vec![0]]);
            for (p, (a, b)) in data.iter().zip(&truth).enumerate() {
                assert!((a - b).abs() < 1e-5, "{name}: pixel {p}: {a} vs {b}");
            }
            // Uniform noise ±0.5 (variance 1/12) on each side: the error variance must drop at
            // least 8× (a 9×9 window with σ = 2.5 px averages tens of pixels), and every output
            // stays a convex combination of its own side's inputs, within ±0.5 of its truth.
            let mut rng = Rng::new(5, 0);
            let mut data: Vec<f32> = truth.iter().map(|t| t + rng.next_f32() - 0.5).collect();
            let var = |d: &[f32], side: bool| {
                let e: Vec<f64> = (0..W * H)
                    .filter(|&p| left(p) == side)
                    .map(|p| (d[p] - truth[p]) as f64)
                    .collect();
                e.iter().map(|x| x * x).sum::<f64>() / e.len() as f64
            };
            let before = [var(&data, true), var(&data, false)];
            filter_view(&cfg, &h, F, &mut data, 1, &[vec![0]]);
            for (side, b) in [true, false].into_iter().zip(before) {
                let a = var(&data, side);
                assert!(a < b / 8.0, "{name}, left={side}: variance {b} -> {a}");
            }
            for (p, (a, b)) in data.iter().zip(&truth).enumerate() {
                assert!((a - b).abs() <= 0.5, "{name}: pixel {p}: {a} vs truth {b}");
            }
        }
    }

    /// A shading that rises linearly towards a depth step: the first-order filter reads it
    /// back exactly, up to the edge, where the mean of the one-sided window falls short of it;
    /// on noise it still averages (variance down at least 4×, against 8× for the mean).
    #[test]
    fn first_order_follows_a_gradient_up_to_an_edge() {
        let h = depth_step();
        let truth: Vec<f32> = (0..W * H)
            .map(|p| {
                if left(p) {
                    1.0 + 0.1 * (p % W) as f32
                } else {
                    5.0
                }
            })
            .collect();
        let run = |order: usize, data: &[f32]| {
            let cfg = FilterConfig {
                order,
                ..FilterConfig::default()
            };
            let mut d = data.to_vec();
            filter_view(&cfg, &h, F, &mut d, 1, &[vec![0]]);
            d
        };
        let edge = W / 2 - 1;
        let (mean, plane) = (run(0, &truth), run(1, &truth));
        for p in 0..W * H {
            assert!(
                (plane[p] - truth[p]).abs() < 1e-3,
                "pixel {p}: {} vs {}",
                plane[p],
                truth[p]
            );
            if p % W == edge {
                assert!(
                    truth[p] - mean[p] > 0.1,
                    "the mean at the edge: {}",
                    mean[p]
                );
            }
        }
        let mut rng = Rng::new(7, 0);
        let noisy: Vec<f32> = truth.iter().map(|t| t + rng.next_f32() - 0.5).collect();
        let var = |d: &[f32]| {
            d.iter()
                .zip(&truth)
                .map(|(a, b)| ((a - b) as f64).powi(2))
                .sum::<f64>()
                / (W * H) as f64
        };
        let after = var(&run(1, &noisy));
        assert!(
            after < var(&noisy) / 4.0,
            "variance {} -> {after}",
            var(&noisy)
        );
    }

    #[test]
    fn channels_outside_groups_are_untouched() {
        let cfg = FilterConfig::default();
        let h = depth_step();
        let dim = 5;
        let mut rng = Rng::new(9, 1);
        let mut data: Vec<f32> = (0..W * H * dim).map(|_| rng.next_f32()).collect();
        let orig = data.clone();
        filter_view(&cfg, &h, F, &mut data, dim, &[vec![0, 1], vec![3]]);
        let changed = |c: usize| (0..W * H).any(|p| data[p * dim + c] != orig[p * dim + c]);
        for c in [2, 4] {
            assert!(!changed(c), "channel {c} is outside the groups");
        }
        for c in [0, 1, 3] {
            assert!(changed(c), "channel {c} was not filtered");
        }
        // A zero radius or no groups disables the filter.
        for (r, groups) in [(0, vec![vec![0]]), (4, vec![])] {
            let mut d = orig.clone();
            let cfg = FilterConfig {
                radius: r,
                ..FilterConfig::default()
            };
            filter_view(&cfg, &h, F, &mut d, dim, &groups);
            assert_eq!(d, orig);
        }
    }

    #[test]
    fn misses_stay_zero_and_do_not_leak() {
        let cfg = FilterConfig::default();
        // The wall z = 1 with a block of misses in the middle; the missed pixels still carry a
        // plausible position and normal, so only `tri < 0` can keep them out.
        let mut h = hits(|_, _, _| Some((Vec3::NEG_Z, -1.0)));
        let miss = |p: usize| (5..11).contains(&(p / W)) && (8..14).contains(&(p % W));
        for p in (0..W * H).filter(|&p| miss(p)) {
            h.tri[p] = -1;
        }
        let mut data: Vec<f32> = (0..W * H)
            .flat_map(|p| if miss(p) { [0.0; 2] } else { [3.0, 7.0] })
            .collect();
        filter_view(&cfg, &h, F, &mut data, 2, &[vec![0, 1]]);
        for p in 0..W * H {
            let want = if miss(p) { [0.0, 0.0] } else { [3.0, 7.0] };
            for c in 0..2 {
                assert!(
                    (data[2 * p + c] - want[c]).abs() < 1e-5,
                    "pixel {p} channel {c}: {} vs {}",
                    data[2 * p + c],
                    want[c]
                );
            }
        }
    }
}
