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

/// How the path tracer picks between the diffuse and the GGX lobe when sampling the BRDF.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LobeChoice {
    /// 50/50, the reference's `path_tracing` (§2.1).
    Half,
    /// GGX with probability lum(k_s)/(lum(k_s) + lum(k_d)), clamped to [0.05, 1]: the sampler
    /// of the Mitsuba plugin that rendered the reference scenes.
    Luminance,
}

impl std::str::FromStr for LobeChoice {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "half" => Ok(Self::Half),
            "luminance" => Ok(Self::Luminance),
            _ => Err(format!("unknown lobe choice '{s}' (half, luminance)")),
        }
    }
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

    /// pdf of the GGX-sampled reflected direction (`ggx_reflection_pdf`).
    pub fn pdf_spec(&self, wo: Vec3, wi: Vec3) -> f32 {
        ggx_reflection_pdf(wo, wi, self.sigma)
    }

    /// The reference's mixture pdf: 0.5·pdf_spec + 0.5·pdf_cosine.
    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        self.pdf_mix(wo, wi, 0.5)
    }

    /// Mixture pdf with the GGX lobe chosen with probability `p_spec`.
    pub fn pdf_mix(&self, wo: Vec3, wi: Vec3, p_spec: f32) -> f32 {
        p_spec * self.pdf_spec(wo, wi) + (1.0 - p_spec) * cosine_pdf(wi.z)
    }

    /// The probability of the GGX lobe under `lobe`.
    pub fn spec_probability(&self, lobe: LobeChoice) -> f32 {
        match lobe {
            LobeChoice::Half => 0.5,
            LobeChoice::Luminance => {
                let lum = |c: Vec3| c.dot(Vec3::new(0.2126, 0.7152, 0.0722));
                let (s, d) = (lum(self.ks), lum(self.kd));
                if s + d > 0.0 {
                    (s / (s + d)).clamp(0.05, 1.0)
                } else {
                    1.0
                }
            }
        }
    }

    /// Samples ω_i from the reference's mixture (diffuse if u0 > 0.5, else GGX). Returns
    /// (ω_i, f·cos/pdf, pdf); the weight is zero where the pdf is zero or the direction is below
    /// the horizon.
    pub fn sample_f(&self, wo: Vec3, u0: f32, u1: f32, u2: f32) -> (Vec3, Vec3, f32) {
        self.sample_f_mix(wo, u0, u1, u2, 0.5)
    }

    /// The same with the GGX lobe chosen when u0 ≤ `p_spec`.
    pub fn sample_f_mix(
        &self,
        wo: Vec3,
        u0: f32,
        u1: f32,
        u2: f32,
        p_spec: f32,
    ) -> (Vec3, Vec3, f32) {
        let wi = if u0 > p_spec {
            sample_cosine(u1, u2)
        } else {
            let h = sample_ggx_h(u1, u2, self.sigma);
            (2.0 * wo.dot(h) * h - wo).normalize()
        };
        let pdf = self.pdf_mix(wo, wi, p_spec);
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

/// Solid-angle pdf of the direction ω_i reflected about a GGX-sampled half vector at roughness
/// σ (local frame, reference §2.1): D·(n·h)/(4·max(v·h, 1e-4)); 0 below the horizon.
pub fn ggx_reflection_pdf(wo: Vec3, wi: Vec3, sigma: f32) -> f32 {
    if wi.z <= 0.0 {
        return 0.0;
    }
    let h = (wo + wi).normalize();
    ggx_d(h.z, sigma) * h.z.max(0.0) / (4.0 * wo.dot(h).max(1e-4))
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    /// Some rough-to-glossy materials and view directions (local frame).
    fn cases() -> Vec<(Brdf, Vec3)> {
        let mut v = Vec::new();
        for (a, s, m) in [
            (0.8, 1.0, 0.0),
            (0.5, 0.6, 0.3),
            (0.9, 0.3, 1.0),
            (0.2, 0.45, 0.0),
        ] {
            for cos_o in [0.9f32, 0.4] {
                let wo = Vec3::new((1.0 - cos_o * cos_o).sqrt(), 0.0, cos_o);
                v.push((Brdf::from_material(Vec3::splat(a), s, m), wo));
            }
        }
        v
    }

    /// ∫ over the upper hemisphere of the mixture pdf, by midpoint quadrature in (cos θ, φ)
    /// over `[mu0, mu1] × [phi0, phi1]`.
    fn pdf_integral(
        b: &Brdf,
        wo: Vec3,
        mu: (f64, f64),
        phi: (f64, f64),
        n: usize,
        p_spec: f32,
    ) -> f64 {
        let mut s = 0.0f64;
        for i in 0..n {
            let m = mu.0 + (mu.1 - mu.0) * (i as f64 + 0.5) / n as f64;
            let st = (1.0 - m * m).max(0.0).sqrt();
            for j in 0..n {
                let p = phi.0 + (phi.1 - phi.0) * (j as f64 + 0.5) / n as f64;
                let wi = Vec3::new((st * p.cos()) as f32, (st * p.sin()) as f32, m as f32);
                s += b.pdf_mix(wo, wi, p_spec) as f64;
            }
        }
        s * (mu.1 - mu.0) * (phi.1 - phi.0) / (n * n) as f64
    }

    /// Share of `sample_f` draws that land below the horizon (weight 0, no direction).
    fn below_horizon(b: &Brdf, wo: Vec3, n: usize, rng: &mut Rng, p: f32) -> f64 {
        let below = (0..n)
            .filter(|_| {
                let (wi, _, _) =
                    b.sample_f_mix(wo, rng.next_f32(), rng.next_f32(), rng.next_f32(), p);
                wi.z <= 0.0
            })
            .count();
        below as f64 / n as f64
    }

    /// The pdf integrates to 1: its integral over the upper hemisphere plus the share of
    /// samples the GGX half of the mixture sends below the horizon.
    #[test]
    fn pdf_integrates_to_one() {
        let mut rng = Rng::new(3, 1);
        for (b, wo) in cases() {
            let up = pdf_integral(&b, wo, (0.0, 1.0), (0.0, std::f64::consts::TAU), 1200, 0.5);
            let below = below_horizon(&b, wo, 400_000, &mut rng, 0.5);
            assert!(
                (up + below - 1.0).abs() < 6e-3,
                "σ {}: ∫pdf {up:.5} + below {below:.5}",
                b.sigma
            );
        }
    }

    /// `sample_f`'s weight is f·cos/pdf at the sampled direction, and its pdf is `pdf`.
    #[test]
    fn sample_weight_is_f_cos_over_pdf() {
        let mut rng = Rng::new(5, 1);
        for (b, wo) in cases() {
            for lobe in [LobeChoice::Half, LobeChoice::Luminance] {
                let p = b.spec_probability(lobe);
                for _ in 0..2000 {
                    let (u0, u1, u2) = (rng.next_f32(), rng.next_f32(), rng.next_f32());
                    let (wi, w, pdf) = b.sample_f_mix(wo, u0, u1, u2, p);
                    if wi.z <= 0.0 {
                        assert_eq!(w, Vec3::ZERO);
                        continue;
                    }
                    assert!((pdf - b.pdf_mix(wo, wi, p)).abs() <= 1e-5 * pdf.max(1.0));
                    let want = b.f(wo, wi) * wi.z / pdf;
                    assert!(
                        (w - want).length() <= 1e-4 * want.length().max(1e-3),
                        "{w} vs {want}"
                    );
                }
            }
        }
    }

    /// Upper quantile of χ² with `k` degrees of freedom at z standard deviations
    /// (Wilson–Hilferty).
    fn chi2_quantile(k: f64, z: f64) -> f64 {
        let a = 2.0 / (9.0 * k);
        k * (1.0 - a + z * a.sqrt()).powi(3)
    }

    /// χ² test of the sampled directions against `pdf`: 12 × 16 bins in (cos θ, φ) plus one
    /// bin for the samples below the horizon, bins with fewer than 5 expected merged, 3.1σ
    /// (p ≈ 0.001) critical value.
    #[test]
    fn sampled_directions_follow_the_pdf() {
        use std::f64::consts::TAU;
        let (nt, np, n) = (12usize, 16usize, 300_000usize);
        let mut rng = Rng::new(9, 1);
        for ((b, wo), lobe) in cases()
            .into_iter()
            .flat_map(|c| [(c, LobeChoice::Half), (c, LobeChoice::Luminance)])
        {
            let p = b.spec_probability(lobe);
            let mut counts = vec![0f64; nt * np + 1];
            for _ in 0..n {
                let (wi, _, _) =
                    b.sample_f_mix(wo, rng.next_f32(), rng.next_f32(), rng.next_f32(), p);
                if wi.z <= 0.0 {
                    counts[nt * np] += 1.0;
                    continue;
                }
                let it = ((wi.z as f64) * nt as f64).min(nt as f64 - 1.0) as usize;
                let ph = (wi.y as f64).atan2(wi.x as f64).rem_euclid(TAU);
                let ip = (ph / TAU * np as f64).min(np as f64 - 1.0) as usize;
                counts[it * np + ip] += 1.0;
            }
            let mut expected = Vec::with_capacity(nt * np + 1);
            for it in 0..nt {
                for ip in 0..np {
                    let mu = (it as f64 / nt as f64, (it + 1) as f64 / nt as f64);
                    let phi = (
                        TAU * ip as f64 / np as f64,
                        TAU * (ip + 1) as f64 / np as f64,
                    );
                    expected.push(n as f64 * pdf_integral(&b, wo, mu, phi, 24, p));
                }
            }
            let up: f64 = expected.iter().sum();
            expected.push(n as f64 - up);
            // Merge small bins into one.
            let (mut chi2, mut dof) = (0.0, 0usize);
            let (mut small_o, mut small_e) = (0.0, 0.0);
            for (o, e) in counts.iter().zip(&expected) {
                if *e < 5.0 {
                    small_o += o;
                    small_e += e;
                } else {
                    chi2 += (o - e).powi(2) / e;
                    dof += 1;
                }
            }
            if small_e >= 5.0 {
                chi2 += (small_o - small_e).powi(2) / small_e;
                dof += 1;
            }
            let crit = chi2_quantile((dof - 1) as f64, 3.1);
            assert!(
                chi2 < crit,
                "σ {} cos θo {}: χ² {chi2:.1} ≥ {crit:.1} ({dof} bins)",
                b.sigma,
                wo.z
            );
        }
    }
}
