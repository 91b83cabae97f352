//! Edge-aware denoising of shading images on the CPU (the reference uses the OptiX AI denoiser).
//!
//! A joint (cross) bilateral filter in image space, guided by the first-hit geometry: weights
//! fall off with world distance (scaled by the pixel footprint), normal difference and distance
//! from the centre pixel's tangent plane, so nothing is blurred across geometry edges; misses
//! are never mixed in.
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
}

impl Default for FilterConfig {
    fn default() -> Self {
        Self {
            radius: 4,
            sigma_px: 2.5,
            normal_power: 64.0,
            sigma_plane_px: 1.0,
            specular_levels: vec![2, 3, 4, 5],
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
        let mut acc = vec![0f32; groups.iter().map(|g| g.len()).sum()];
        let mut wsum = 0f32;
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
                let mut k = 0;
                for g in groups {
                    for &c in g {
                        acc[k] += wgt * src[q * dim + c];
                        k += 1;
                    }
                }
                wsum += wgt;
            }
        }
        if wsum > 0.0 {
            let mut k = 0;
            for g in groups {
                for &c in g {
                    out[c] = acc[k] / wsum;
                    k += 1;
                }
            }
        }
    });
}
