//! Stage 1 of FIPT (paper §4.1–4.2, reference §2.2): per training pixel, the diffuse shading
//! L_d and the specular shadings L_s0, L_s1 at the roughness levels linspace(0.02, 1, 6), each a
//! Monte Carlo mean of L′ at the first hit of secondary rays from x + ε·ω.
//!
//! Random numbers come from (seed, view, pixel), so results are bit-identical for any thread
//! count.
//!
//! Owns: the shading estimators and the per-view shading buffers. Must not touch: files, the
//! filter (see `filter`), tensors.

use crate::accel::Accel;
use crate::lightfield::LightField;
use crate::raycast::ViewHits;
use fipt_core::brdf::{
    Frame, ROUGHNESS_LEVELS, roughness_levels, sample_cosine, sample_ggx_h, specular_weights,
};
use fipt_core::rng::Rng;
use glam::Vec3;
use rayon::prelude::*;

/// Values per pixel: L_d (3), L_s0 (6 levels × 3), L_s1 (6 × 3).
pub const SHADING_DIM: usize = 3 + 6 * ROUGHNESS_LEVELS;

/// Secondary-ray offset along the new direction (Mitsuba's RayEpsilon, reference §2.1).
pub const RAY_EPS: f32 = 1500.0 / (1u32 << 24) as f32;

/// Sample counts of the bake.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BakeSamples {
    /// Cosine samples for L_d.
    pub diffuse: usize,
    /// GGX samples per roughness level.
    pub specular: [usize; ROUGHNESS_LEVELS],
}

impl Default for BakeSamples {
    /// The reference's counts: 256 diffuse; 64 at level 0, 128 at levels 1–5.
    fn default() -> Self {
        Self {
            diffuse: 256,
            specular: [64, 128, 128, 128, 128, 128],
        }
    }
}

impl BakeSamples {
    pub fn rays_per_pixel(&self) -> usize {
        self.diffuse + self.specular.iter().sum::<usize>()
    }
}

/// L′ seen along a ray from `x`: the light field at the first hit, 0 on a miss.
#[inline]
pub fn radiance_along(accel: &Accel, lf: &LightField, x: Vec3, w: Vec3) -> Vec3 {
    let o = x + w * RAY_EPS;
    match accel.closest(o, w, 0.0, f32::INFINITY) {
        Some(h) => lf.query(o + w * h.t),
        None => Vec3::ZERO,
    }
}

/// The shading estimator over one scene: geometry, L′ and sample counts.
pub struct Baker<'a> {
    pub accel: &'a Accel,
    pub lf: &'a LightField,
    pub samples: BakeSamples,
}

impl Baker<'_> {
    /// Shadings of one surface point seen from direction `wo` (unit, pointing away from the
    /// surface), normal `n` facing `wo`; `out` receives `SHADING_DIM` values.
    pub fn shade_point(&self, x: Vec3, n: Vec3, wo: Vec3, rng: &mut Rng, out: &mut [f32]) {
        let frame = Frame::new(n);
        let mut ld = Vec3::ZERO;
        for _ in 0..self.samples.diffuse {
            let wi = frame.to_world(sample_cosine(rng.next_f32(), rng.next_f32()));
            ld += radiance_along(self.accel, self.lf, x, wi);
        }
        ld /= self.samples.diffuse.max(1) as f32;
        out[..3].copy_from_slice(&ld.to_array());
        let wo_l = frame.to_local(wo);
        for (j, sigma) in roughness_levels().into_iter().enumerate() {
            let (mut s0, mut s1) = (Vec3::ZERO, Vec3::ZERO);
            let spp = self.samples.specular[j];
            for _ in 0..spp {
                let h = sample_ggx_h(rng.next_f32(), rng.next_f32(), sigma);
                let vh = wo_l.dot(h);
                let wi = 2.0 * vh * h - wo_l;
                if wi.z <= 0.0 || vh <= 0.0 {
                    continue;
                }
                let (g0, g1) = specular_weights(wo_l.z, wi.z, h.z, vh, sigma);
                let l = radiance_along(self.accel, self.lf, x, frame.to_world(wi).normalize());
                s0 += l * g0;
                s1 += l * g1;
            }
            let inv = 1.0 / spp.max(1) as f32;
            out[3 + 3 * j..6 + 3 * j].copy_from_slice(&(s0 * inv).to_array());
            out[21 + 3 * j..24 + 3 * j].copy_from_slice(&(s1 * inv).to_array());
        }
    }

    /// Bakes every pixel of one view (`SHADING_DIM` values per pixel, zeros where the
    /// pixel-centre ray missed). `view_key` distinguishes views in the random streams.
    pub fn bake_view(&self, hits: &ViewHits, seed: u64, view_key: u64) -> Vec<f32> {
        let mut out = vec![0f32; hits.num_pixels() * SHADING_DIM];
        out.par_chunks_mut(SHADING_DIM)
            .enumerate()
            .with_min_len(16)
            .for_each(|(p, o)| {
                if hits.tri[p] < 0 {
                    return;
                }
                let mut rng = Rng::new(seed, (view_key << 32) | p as u64);
                self.shade_point(
                    hits.position[p],
                    hits.normal[p],
                    -hits.direction[p],
                    &mut rng,
                    o,
                );
            });
        out
    }
}
