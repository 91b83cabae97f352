//! The camera response read from the photos' edges, after Lin et al. ("Radiometric calibration
//! from a single image", CVPR 2004), with the scene's mesh in place of their edge detection.
//!
//! - **Signal**: a photo's pixel records the mean radiance over its square (a box filter). Where
//!   the square straddles two surfaces A and B, covering shares α and 1 − α of it, the linear
//!   value is the mix of theirs: g(I_p) = α·g(I_A) + (1 − α)·g(I_B). Only the true inverse
//!   response g makes the code of every such pixel sit where the mix puts it; a wrong one bends
//!   the mix towards the brighter or the darker side. Neither the exposure nor the lighting
//!   nor the materials enter, so one photo at one exposure carries it.
//! - **Samples** (`edge_samples`): the mesh gives each pixel's coverage. Pixels whose 3×3
//!   neighbourhood of centre rays meets more than one plane are cast again on an 8×8 grid of
//!   points inside the pixel. A pixel whose points land on exactly two planes, each with at
//!   least 15 % of them, at depths 5 % or more apart (an occluding contour), is a sample. Each
//!   side's code is a plane fitted to the codes of the pixels of the 5×5 window that lie
//!   whole on it, read at the side's centroid inside the pixel (the light changes across a
//!   few pixels). Creases, where two surfaces meet at one depth, are left out: the light falls
//!   off into a concave corner faster than such a plane follows, and on fipt-room's twins they
//!   read γ 0.5–0.9 where the contours read the truth. A channel is left out where a side's
//!   plane misses a neighbour by more than 0.01 + 5 % (texture, a shadow's edge), where the
//!   two sides are within 0.1 of each other (no curvature to read), or where a code is clipped.
//! - **Estimate** (`fit_gamma`): one γ of the family g(v) = srgb⁻¹(v)^γ
//!   (`Response::srgb_power`) for the three channels, minimising a Cauchy loss of the code
//!   residual f_γ(α·g_γ(I_A) + (1 − α)·g_γ(I_B)) − I_p over log₂ γ in [−1, 1].
//!
//! The photos' pixel filter must be a box (the renderers of the FIPT layouts, fipt's and
//! Mitsuba's `box`, use one); a camera's demosaicing and sharpening are not modelled.
//!
//! Owns: the edge samples and the γ they give. Must not touch: the photos, the exposures.

use fipt_bake::Accel;
use fipt_core::scene::ldr::{linear_to_srgb, srgb_to_linear};
use fipt_core::scene::{Camera, LdrFrame, Mesh};
use glam::{DMat3, DVec3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Points per side of the grid cast inside a pixel.
const SUB: usize = 8;

/// Smallest share of a pixel each of its two surfaces must cover.
const MIN_SHARE: f64 = 0.15;

/// Smallest code difference between the two sides of a channel.
const MIN_CONTRAST: f64 = 0.1;

/// Largest residual of a side's plane fit to its neighbours' codes: this code value plus this
/// share of their mean.
const RESIDUAL: (f64, f64) = (0.01, 0.05);

/// Smallest relative difference between the two sides' depths for an occluding contour.
const CONTOUR_DEPTH: f64 = 0.05;

/// The Cauchy scale of the code residual (2.5 codes of 255).
const CODE_SCALE: f64 = 0.01;

/// Fewest samples of a channel for an estimate.
pub const MIN_SAMPLES: usize = 50;

/// One pixel on the edge between two surfaces: its code, the codes of the two sides, the share
/// α of the pixel the first side covers, and which channels are usable.
#[derive(Clone, Debug, PartialEq)]
pub struct EdgeSample {
    pub alpha: f64,
    pub a: [f64; 3],
    pub b: [f64; 3],
    pub p: [f64; 3],
    pub usable: [bool; 3],
}

/// The estimate: γ (one for all channels), how many samples each channel read, and the cost
/// curve.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct EdgeFit {
    pub gamma: [f64; 3],
    pub samples: [usize; 3],
    /// (γ, mean cost) over the coarse grid.
    pub curve: Vec<(f64, f64)>,
}

impl EdgeFit {
    pub fn response(&self) -> fipt_core::scene::Response {
        fipt_core::scene::Response::srgb_power(self.gamma)
    }
}

/// A key per plane of the mesh: the triangle's unit normal and offset, quantised (coplanar
/// triangles share it).
pub fn plane_keys(mesh: &Mesh) -> Vec<u64> {
    (0..mesh.num_triangles())
        .map(|t| {
            let n = mesh.normal(t);
            let d = n.dot(mesh.point_at(t, 0.0, 0.0));
            let q = |x: f32, s: f32| ((x * s).round() as i64 & 0xffff) as u64;
            (q(n.x, 256.0) << 48) ^ (q(n.y, 256.0) << 32) ^ (q(n.z, 256.0) << 16) ^ q(d, 500.0)
        })
        .collect()
}

/// One plane's points inside a pixel: how many, and the sums of their depths and offsets from
/// the pixel's centre (in pixels).
#[derive(Clone, Copy, Debug)]
struct Surface {
    key: u64,
    points: usize,
    depth: f64,
    dx: f64,
    dy: f64,
}

/// No surface (a ray that leaves the scene).
const MISS: u64 = u64::MAX;

/// The edge samples of one view of `mesh`; `keys` are its `plane_keys`.
pub fn edge_samples(
    mesh: &Mesh,
    keys: &[u64],
    accel: &Accel,
    cam: &Camera,
    frame: &LdrFrame,
) -> Vec<EdgeSample> {
    let (w, h) = (cam.width, cam.height);
    let key_of = |hit: Option<fipt_bake::Hit>| hit.map_or(MISS, |x| keys[x.tri as usize]);
    let centre: Vec<u64> = fipt_bake::cast_view(accel, mesh, cam)
        .tri
        .iter()
        .map(|&t| if t < 0 { MISS } else { keys[t as usize] })
        .collect();
    let at = |x: i64, y: i64| -> Option<usize> {
        (x >= 0 && y >= 0 && (x as usize) < w && (y as usize) < h)
            .then(|| y as usize * w + x as usize)
    };
    // A pixel is pure where its 3×3 neighbourhood of centre rays lies on its own plane.
    let pure: Vec<bool> = (0..w * h)
        .map(|p| {
            let (x, y) = ((p % w) as i64, (p / w) as i64);
            centre[p] != MISS
                && (-1..=1).all(|dy| {
                    (-1..=1).all(|dx| at(x + dx, y + dy).is_none_or(|q| centre[q] == centre[p]))
                })
        })
        .collect();
    let code = |p: usize, c: usize| frame.value(p, c);
    // The surfaces inside every pixel that is not pure: (plane, points) over an 8×8 grid.
    let inside: Vec<Option<Vec<Surface>>> = (0..w * h)
        .into_par_iter()
        .map(|p| {
            if pure[p] {
                return None;
            }
            let rays = cam.grid_rays(p % w, p / w, SUB);
            let mut hits = vec![None; rays.len()];
            accel.closest_many(&rays, 0.0, f32::INFINITY, &mut hits);
            let mut counts: Vec<Surface> = Vec::new();
            for (s, hit) in hits.into_iter().enumerate() {
                let t = hit.map_or(0.0, |x| x.t as f64);
                let k = key_of(hit);
                // The point's offset from the pixel's centre.
                let u = (s % SUB) as f64 + 0.5 - SUB as f64 / 2.0;
                let v = (s / SUB) as f64 + 0.5 - SUB as f64 / 2.0;
                let (u, v) = (u / SUB as f64, v / SUB as f64);
                match counts.iter_mut().find(|e| e.key == k) {
                    Some(e) => {
                        e.points += 1;
                        e.depth += t;
                        e.dx += u;
                        e.dy += v;
                    }
                    None => counts.push(Surface {
                        key: k,
                        points: 1,
                        depth: t,
                        dx: u,
                        dy: v,
                    }),
                }
            }
            Some(counts)
        })
        .collect();
    // The plane a pixel lies on whole, if it does.
    let whole = |q: usize| -> Option<u64> {
        match &inside[q] {
            None => (centre[q] != MISS).then_some(centre[q]),
            Some(c) if c.len() == 1 && c[0].key != MISS => Some(c[0].key),
            Some(_) => None,
        }
    };
    let total = (SUB * SUB) as f64;
    (0..w * h)
        .into_par_iter()
        .filter_map(|p| {
            let counts = inside[p].as_ref()?;
            let (x, y) = ((p % w) as i64, (p / w) as i64);
            if counts.len() != 2
                || counts
                    .iter()
                    .any(|e| e.key == MISS || (e.points as f64) < MIN_SHARE * total)
            {
                return None;
            }
            // Occluding contours only: where two surfaces meet in a concave crease, the light
            // falls off into it faster than a plane through the neighbours follows.
            let (ta, tb) = (
                counts[0].depth / counts[0].points as f64,
                counts[1].depth / counts[1].points as f64,
            );
            if (ta - tb).abs() <= CONTOUR_DEPTH * ta.min(tb) {
                return None;
            }
            // Each side: the codes of the pixels of the 5×5 window that lie whole on its plane,
            // extrapolated to where the side lies inside the pixel.
            let side = |e: &Surface| -> Option<([f64; 3], [bool; 3])> {
                let key = e.key;
                let (cx, cy) = (e.dx / e.points as f64, e.dy / e.points as f64);
                let mut got: Vec<(usize, f64, f64)> = Vec::new();
                for dy in -2i64..=2 {
                    for dx in -2i64..=2 {
                        if let Some(q) = at(x + dx, y + dy)
                            && whole(q) == Some(key)
                        {
                            got.push((q, dx as f64, dy as f64));
                        }
                    }
                }
                if got.len() < 3 {
                    return None;
                }
                let plane = PlaneFit::new(&got)?;
                let mut mean = [0.0; 3];
                let mut ok = [true; 3];
                for c in 0..3 {
                    let v: Vec<f64> = got.iter().map(|&(q, _, _)| code(q, c)).collect();
                    let m = v.iter().sum::<f64>() / v.len() as f64;
                    let clipped = got.iter().any(|&(q, _, _)| frame.clipped(q, c));
                    // v ≈ c0 + c1·dx + c2·dy by least squares, read at the side's centroid
                    // inside the pixel; a side it does not fit closely is left out.
                    let fit = plane.fit(&got, &v);
                    let worst = got
                        .iter()
                        .zip(&v)
                        .map(|(&(_, dx, dy), &val)| {
                            (val - fit[0] - fit[1] * dx - fit[2] * dy).abs()
                        })
                        .fold(0.0f64, f64::max);
                    mean[c] = (fit[0] + fit[1] * cx + fit[2] * cy).clamp(0.0, 1.0);
                    ok[c] = worst <= RESIDUAL.0 + RESIDUAL.1 * m && !clipped;
                }
                Some((mean, ok))
            };
            let (a, oka) = side(&counts[0])?;
            let (b, okb) = side(&counts[1])?;
            let pc = [0, 1, 2].map(|c| code(p, c));
            let usable = [0, 1, 2].map(|c| {
                oka[c] && okb[c] && !frame.clipped(p, c) && (a[c] - b[c]).abs() >= MIN_CONTRAST
            });
            usable.iter().any(|&u| u).then_some(EdgeSample {
                alpha: counts[0].points as f64 / total,
                a,
                b,
                p: pc,
                usable,
            })
        })
        .collect()
}

/// Least squares of v ≈ c0 + c1·dx + c2·dy over a set of points (dx, dy): the inverse of its
/// normal matrix, shared by every channel's values.
struct PlaneFit(DMat3);

impl PlaneFit {
    /// None where the points do not span a plane.
    fn new(pts: &[(usize, f64, f64)]) -> Option<Self> {
        let normal = pts.iter().fold(DMat3::ZERO, |acc, &(_, dx, dy)| {
            let r = DVec3::new(1.0, dx, dy);
            acc + DMat3::from_cols(r * r.x, r * r.y, r * r.z)
        });
        let d = normal.determinant();
        (d.abs() >= 1e-6 * normal.x_axis.x.powi(3).max(1.0)).then(|| Self(normal.inverse()))
    }

    /// (c0, c1, c2) for the values `v` at the points it was made from.
    fn fit(&self, pts: &[(usize, f64, f64)], v: &[f64]) -> [f64; 3] {
        let rhs = pts
            .iter()
            .zip(v)
            .fold(DVec3::ZERO, |acc, (&(_, dx, dy), &val)| {
                acc + DVec3::new(1.0, dx, dy) * val
            });
        (self.0 * rhs).to_array()
    }
}

/// The mean Cauchy cost of the samples' usable channels under γ.
fn cost(samples: &[EdgeSample], gamma: f64) -> f64 {
    let g = |v: f64| srgb_to_linear(v).powf(gamma);
    let f = |x: f64| linear_to_srgb(x.max(0.0).powf(1.0 / gamma));
    let (mut sum, mut n) = (0.0, 0usize);
    for s in samples {
        for c in (0..3).filter(|&c| s.usable[c]) {
            let pred = f(s.alpha * g(s.a[c]) + (1.0 - s.alpha) * g(s.b[c]));
            let r = (pred - s.p[c]) / CODE_SCALE;
            sum += (1.0 + r * r).ln();
            n += 1;
        }
    }
    sum / n.max(1) as f64
}

/// The estimate from the edges of every train view (None where a channel has fewer than
/// `MIN_SAMPLES` samples, or the photos are HDR).
pub fn estimate(ds: &fipt_core::scene::Dataset, accel: &Accel) -> Option<EdgeFit> {
    let keys = plane_keys(&ds.mesh);
    let samples: Vec<EdgeSample> = ds
        .train
        .views
        .iter()
        .filter_map(|v| {
            v.ldr
                .as_ref()
                .map(|f| edge_samples(&ds.mesh, &keys, accel, &v.camera, f))
        })
        .flatten()
        .collect();
    fit_gamma(&samples)
}

/// One γ for all three channels from the samples (None where a channel has fewer than
/// `MIN_SAMPLES`): a grid over log₂ γ ∈ [−1, 1] in steps of 0.02, then steps of 0.002 around
/// the best. One exponent, not one per channel: a camera's curves differ little between
/// channels, and per-channel exponents fitted to a few hundred pixels each differ by their
/// noise.
pub fn fit_gamma(samples: &[EdgeSample]) -> Option<EdgeFit> {
    let counts = [0, 1, 2].map(|c| samples.iter().filter(|s| s.usable[c]).count());
    if counts.iter().any(|&n| n < MIN_SAMPLES) {
        return None;
    }
    let coarse: Vec<f64> = (0..=100).map(|i| -1.0 + 0.02 * i as f64).collect();
    let curve: Vec<(f64, f64)> = coarse
        .par_iter()
        .map(|&l| (2f64.powf(l), cost(samples, 2f64.powf(l))))
        .collect();
    let best = curve
        .iter()
        .min_by(|x, y| x.1.total_cmp(&y.1))
        .map_or(0.0, |x| x.0.log2());
    let fine = (-10..=10)
        .map(|i| best + 0.002 * i as f64)
        .map(|l| (l, cost(samples, 2f64.powf(l))))
        .min_by(|x, y| x.1.total_cmp(&y.1))
        .map_or(best, |x| x.0);
    Some(EdgeFit {
        gamma: [2f64.powf(fine); 3],
        samples: counts,
        curve,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use fipt_core::rng::Rng;

    /// Samples drawn from the mixing model under a known γ, 8-bit codes with a code of noise,
    /// and 10 % of them outliers: the fit recovers γ within 2 %, and the sRGB curve (γ = 1)
    /// would be 0.02 RMS or more off.
    #[test]
    fn fit_recovers_the_gamma_of_mixed_pixels() {
        let truth = [0.8; 3];
        let mut rng = Rng::new(3, 9);
        let enc = |c: usize, x: f64| {
            let v = linear_to_srgb(x.clamp(0.0, 1.0).powf(1.0 / truth[c]));
            (v * 255.0).round() / 255.0
        };
        let samples: Vec<EdgeSample> = (0..600)
            .map(|i| {
                let la = [0, 1, 2].map(|_| 0.02 + 0.8 * rng.next_f32() as f64);
                let lb = [0, 1, 2].map(|_| 0.002 + 0.1 * rng.next_f32() as f64);
                let alpha = 0.15 + 0.7 * rng.next_f32() as f64;
                let p = [0, 1, 2].map(|c| {
                    let mut v = enc(c, alpha * la[c] + (1.0 - alpha) * lb[c]);
                    v += (rng.next_f32() as f64 - 0.5) * 2.0 / 255.0;
                    if i % 10 == 0 {
                        v = rng.next_f32() as f64;
                    }
                    v
                });
                EdgeSample {
                    alpha,
                    a: [0, 1, 2].map(|c| enc(c, la[c])),
                    b: [0, 1, 2].map(|c| enc(c, lb[c])),
                    p,
                    usable: [true; 3],
                }
            })
            .collect();
        let fit = fit_gamma(&samples).expect("enough samples");
        for (c, want) in truth.iter().enumerate() {
            assert!(
                (fit.gamma[c] / want - 1.0).abs() < 0.02,
                "channel {c}: γ {} against {}",
                fit.gamma[c],
                want
            );
        }
        let truth_r = fipt_core::scene::Response::srgb_power(truth);
        assert!(fit.response().rms_forward(&truth_r) < 0.005);
        assert!(fipt_core::scene::Response::srgb().rms_forward(&truth_r) > 0.02);
        // Too few samples of a channel: no estimate.
        let few: Vec<EdgeSample> = samples[..MIN_SAMPLES - 1].to_vec();
        assert!(fit_gamma(&few).is_none());
    }
}
