//! The FIPT BRDF (paper Eq. 1, its Fresnel split Eq. 7; reference §2.1) as scalar code on glam types, for the CPU
//! tracer, sampling and pdfs. The tensor version lives in `model::brdf`; a test holds them equal.
//!
//! Owns: k_d/k_s from (a, m), GGX D, Schlick-GGX G, the split Schlick Fresnel, the local frame,
//! cosine and GGX sampling with their pdfs. Must not touch: tensors, rays.

mod frame;
mod ggx;
mod sample;

/// The number of roughness levels; defined with the shading layout (`crate::shading`).
pub use crate::shading::ROUGHNESS_LEVELS;
use crate::shading::ShadingLayout;
pub use frame::Frame;
pub use ggx::{fresnel_split, g_schlick_over, ggx_d, reflectances, specular_weights};
pub use sample::{
    Brdf, LobeChoice, cosine_pdf, directional_albedo_quadrature, ggx_reflection_pdf, sample_cosine,
    sample_ggx_h,
};

/// Roughness floor of the material field (reference: σ = 0.02 + 0.98·s).
pub const SIGMA_MIN: f32 = 0.02;
/// The roughness levels linspace(0.02, 1, 6) of the shading cache.
pub fn roughness_levels() -> [f32; ROUGHNESS_LEVELS] {
    let mut r = [0.0; ROUGHNESS_LEVELS];
    for (j, v) in r.iter_mut().enumerate() {
        *v = SIGMA_MIN + (1.0 - SIGMA_MIN) * j as f32 / (ROUGHNESS_LEVELS - 1) as f32;
    }
    r
}

/// Linear interpolation weights over the roughness levels for roughness σ (reference: r =
/// (σ − 0.02)/0.98·5, blend of floor(r) and ceil(r)). The tensor twin is
/// `model::render::roughness_weights`.
pub fn level_weights(sigma: f32) -> [f32; ROUGHNESS_LEVELS] {
    let r = ((sigma - SIGMA_MIN) / (1.0 - SIGMA_MIN) * (ROUGHNESS_LEVELS - 1) as f32)
        .clamp(0.0, (ROUGHNESS_LEVELS - 1) as f32);
    let mut w = [0.0; ROUGHNESS_LEVELS];
    for (j, wj) in w.iter_mut().enumerate() {
        *wj = (1.0 - (r - j as f32).abs()).max(0.0);
    }
    w
}

/// Eq. 5 with Eq. 8's roughness lerp on one pixel's packed shadings (`ShadingLayout`):
/// k_d·L_d + k_s·L_s0(σ) + L_s1(σ).
pub fn factorised_render(kd: [f32; 3], ks: [f32; 3], sigma: f32, shading: &[f32]) -> [f32; 3] {
    let (s0, s1) = specular_shadings(sigma, shading);
    std::array::from_fn(|c| kd[c] * shading[ShadingLayout::LD.start + c] + ks[c] * s0[c] + s1[c])
}

/// Eq. 8's roughness lerp of one pixel's packed specular shadings: (L_s0(σ), L_s1(σ)), RGB.
pub fn specular_shadings(sigma: f32, shading: &[f32]) -> ([f32; 3], [f32; 3]) {
    let w = level_weights(sigma);
    let (mut s0, mut s1) = ([0.0; 3], [0.0; 3]);
    for c in 0..3 {
        for (j, wj) in w.iter().enumerate() {
            s0[c] += wj * shading[ShadingLayout::ls0(j).start + c];
            s1[c] += wj * shading[ShadingLayout::ls1(j).start + c];
        }
    }
    (s0, s1)
}

/// One GGX-sampled reflection at roughness σ in the local frame (ω_o = `wo`, z = normal):
/// returns (ω_i, g0, g1) with the specular weights of `specular_weights`, or None when the
/// sampled direction is below the horizon (the sample then counts with weight zero).
#[inline]
pub fn sample_specular(
    wo: glam::Vec3,
    sigma: f32,
    u1: f32,
    u2: f32,
) -> Option<(glam::Vec3, f32, f32)> {
    let h = sample_ggx_h(u1, u2, sigma);
    let vh = wo.dot(h);
    let wi = 2.0 * vh * h - wo;
    if wi.z <= 0.0 || vh <= 0.0 {
        return None;
    }
    let (g0, g1) = specular_weights(wo.z, wi.z, h.z, vh, sigma);
    Some((wi, g0, g1))
}
