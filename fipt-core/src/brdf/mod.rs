//! The FIPT BRDF (paper Eq. 1, 5–7; reference §2.1) as scalar code on glam types, for the CPU
//! tracer, sampling and pdfs. The tensor version lives in `model::brdf`; a test holds them equal.
//!
//! Owns: k_d/k_s from (a, m), GGX D, Schlick-GGX G, the split Schlick Fresnel, the local frame,
//! cosine and GGX sampling with their pdfs. Must not touch: tensors, rays.

mod frame;
mod ggx;
mod sample;

pub use frame::Frame;
pub use ggx::{fresnel_split, g_schlick_over, ggx_d, reflectances, specular_weights};
pub use sample::{Brdf, cosine_pdf, directional_albedo_quadrature, sample_cosine, sample_ggx_h};

/// Roughness floor of the material field (reference: σ = 0.02 + 0.98·s).
pub const SIGMA_MIN: f32 = 0.02;
/// Number of pre-integrated roughness levels in the shading cache.
pub const ROUGHNESS_LEVELS: usize = 6;

/// The roughness levels linspace(0.02, 1, 6) of the shading cache.
pub fn roughness_levels() -> [f32; ROUGHNESS_LEVELS] {
    let mut r = [0.0; ROUGHNESS_LEVELS];
    for (j, v) in r.iter_mut().enumerate() {
        *v = SIGMA_MIN + (1.0 - SIGMA_MIN) * j as f32 / (ROUGHNESS_LEVELS - 1) as f32;
    }
    r
}
