//! The full BRDF f(ω_o, ω_i) and its sampling: cosine hemisphere, GGX half vectors and the 50/50
//! mixture of the path tracer (reference §2.1), pbrt-style `f`, `sample_f`, `pdf` side by side.

use super::{Frame, g_schlick_over, ggx_d, reflectances};
use glam::Vec3;
use std::f32::consts::{FRAC_1_PI, PI, TAU};

/// Cosine-weighted hemisphere direction in the local frame: θ = asin(√u1), φ = 2π u2.
#[inline]
pub fn sample_cosine(u1: f32, u2: f32) -> Vec3 {
    let s = u1.sqrt();
    let z = (1.0 - u1).max(0.0).sqrt();
    let ph = TAU * u2;
    Vec3::new(s * ph.cos(), s * ph.sin(), z)
}

/// pdf of `sample_cosine` (solid angle): cos θ / π.
#[inline]
pub fn cosine_pdf(cos_theta: f32) -> f32 {
    cos_theta.max(0.0) * FRAC_1_PI
}

/// GGX half vector in the local frame: cos²θ_h = (1 − u1)/(u1(α² − 1) + 1), φ = 2π u2.
#[inline]
pub fn sample_ggx_h(u1: f32, u2: f32, sigma: f32) -> Vec3 {
    let a2 = (sigma * sigma) * (sigma * sigma);
    let c2 = ((1.0 - u1) / (u1 * (a2 - 1.0) + 1.0)).clamp(0.0, 1.0);
    let c = c2.sqrt();
    let s = (1.0 - c2).max(0.0).sqrt();
    let ph = TAU * u2;
    Vec3::new(s * ph.cos(), s * ph.sin(), c)
}

/// A BRDF instance at a surface point.
#[derive(Clone, Copy, Debug)]
pub struct Brdf {
    pub kd: Vec3,
    pub ks: Vec3,
    pub sigma: f32,
}

impl Brdf {
    pub fn from_material(a: Vec3, sigma: f32, m: f32) -> Self {
        let (kd, ks) = reflectances(a, m);
        Self { kd, ks, sigma }
    }

    /// Eq. 1: f = k_d/π + D·F·G_s/4 with F = k_s + (1 − k_s)(1 − v·h)⁵; ω in the local frame.
    pub fn f(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        if wo.z <= 0.0 || wi.z <= 0.0 {
            return Vec3::ZERO;
        }
        let h = (wo + wi).normalize();
        let vh = wo.dot(h).max(0.0);
        let x = (1.0 - vh).powi(5);
        let f = self.ks + (Vec3::ONE - self.ks) * x;
        let spec = ggx_d(h.z, self.sigma) * g_schlick_over(wo.z, wi.z, self.sigma) / 4.0;
        self.kd * FRAC_1_PI + f * spec
    }

    /// pdf of the GGX-sampled reflected direction: D·(n·h)/(4·max(v·h, 1e-4)).
    pub fn pdf_spec(&self, wo: Vec3, wi: Vec3) -> f32 {
        if wi.z <= 0.0 {
            return 0.0;
        }
        let h = (wo + wi).normalize();
        ggx_d(h.z, self.sigma) * h.z.max(0.0) / (4.0 * wo.dot(h).max(1e-4))
    }

    /// Mixture pdf: 0.5·pdf_spec + 0.5·pdf_cosine.
    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        0.5 * self.pdf_spec(wo, wi) + 0.5 * cosine_pdf(wi.z)
    }

    /// Samples ω_i from the mixture (diffuse if u0 > 0.5, else GGX). Returns (ω_i, f·cos/pdf,
    /// pdf); the weight is zero where the pdf is zero or the direction is below the horizon.
    pub fn sample_f(&self, wo: Vec3, u0: f32, u1: f32, u2: f32) -> (Vec3, Vec3, f32) {
        let wi = if u0 > 0.5 {
            sample_cosine(u1, u2)
        } else {
            let h = sample_ggx_h(u1, u2, self.sigma);
            (2.0 * wo.dot(h) * h - wo).normalize()
        };
        let pdf = self.pdf(wo, wi);
        if pdf.is_nan() || pdf <= 0.0 || wi.z <= 0.0 {
            return (wi, Vec3::ZERO, pdf);
        }
        let w = self.f(wo, wi) * wi.z / pdf;
        (wi, if w.is_finite() { w } else { Vec3::ZERO }, pdf)
    }

    /// The same in world space about normal `n`.
    pub fn f_world(&self, n: Vec3, wo: Vec3, wi: Vec3) -> Vec3 {
        let fr = Frame::new(n);
        self.f(fr.to_local(wo), fr.to_local(wi))
    }
}

/// Numerical directional albedo ∫ f cos dω over the hemisphere (midpoint rule in (cos θ, φ)),
/// for tests and reference values.
pub fn directional_albedo_quadrature(brdf: &Brdf, wo: Vec3, n_theta: usize, n_phi: usize) -> Vec3 {
    let mut s = Vec3::ZERO;
    for i in 0..n_theta {
        // Substitution μ = cos θ = t² concentrates samples at grazing angles less; use μ directly.
        let mu = (i as f32 + 0.5) / n_theta as f32;
        let st = (1.0 - mu * mu).sqrt();
        for j in 0..n_phi {
            let ph = TAU * (j as f32 + 0.5) / n_phi as f32;
            let wi = Vec3::new(st * ph.cos(), st * ph.sin(), mu);
            s += brdf.f(wo, wi) * mu;
        }
    }
    s * (2.0 * PI / (n_theta * n_phi) as f32)
}
