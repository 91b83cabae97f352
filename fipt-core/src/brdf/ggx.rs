//! GGX microfacet terms of the FIPT BRDF.

use glam::Vec3;

/// Eq. 1's diffuse and specular reflectances from base colour a and metallic m:
/// k_d = a(1 − m), k_s = 0.04(1 − m) + a·m.
#[inline]
pub fn reflectances(a: Vec3, m: f32) -> (Vec3, Vec3) {
    (a * (1.0 - m), Vec3::splat(0.04 * (1.0 - m)) + a * m)
}

/// Eq. 1's D: GGX normal distribution D(h) = α² / (π ((n·h)²(α² − 1) + 1)²), α = σ².
#[inline]
pub fn ggx_d(n_dot_h: f32, sigma: f32) -> f32 {
    let a2 = (sigma * sigma) * (sigma * sigma);
    let nh = n_dot_h.clamp(0.0, 1.0);
    // (n·h)²(α² − 1) + 1 written as sin²θ_h + α² cos²θ_h: no cancellation for tiny α.
    let d = (1.0 - nh) * (1.0 + nh) + a2 * nh * nh;
    a2 / (std::f32::consts::PI * d * d)
}

/// Eq. 1's G (Schlick-GGX) divided by (n·l)(n·v): G_s = 1 / ((n·v(1−k) + k)(n·l(1−k) + k)), k = (σ+1)²/8
/// (Schlick-GGX with the UE4 remap), so f_s = D·F·G_s / 4.
#[inline]
pub fn g_schlick_over(n_dot_v: f32, n_dot_l: f32, sigma: f32) -> f32 {
    let k = (sigma + 1.0) * (sigma + 1.0) / 8.0;
    let (nv, nl) = (n_dot_v.max(0.0), n_dot_l.max(0.0));
    1.0 / ((nv * (1.0 - k) + k) * (nl * (1.0 - k) + k))
}

/// Eq. 7: the Schlick Fresnel split F = k_s·F0 + F1 with F0 = 1 − (1 − v·h)⁵, F1 = (1 − v·h)⁵.
#[inline]
pub fn fresnel_split(v_dot_h: f32) -> (f32, f32) {
    let x = (1.0 - v_dot_h.max(0.0)).powi(5);
    (1.0 - x, x)
}

/// Per-sample specular weights of a GGX-sampled direction (reference §2.1):
/// g0 = F0·fac, g1 = F1·fac with fac = G_s·(v·h)·(n·l)/max(n·h, 1e-4); so the estimator of
/// L_s0 (L_s1) is the mean of L·g0 (L·g1). Zero below the horizon.
#[inline]
pub fn specular_weights(
    n_dot_v: f32,
    n_dot_l: f32,
    n_dot_h: f32,
    v_dot_h: f32,
    sigma: f32,
) -> (f32, f32) {
    if n_dot_l <= 0.0 || n_dot_v <= 0.0 {
        return (0.0, 0.0);
    }
    let fac =
        g_schlick_over(n_dot_v, n_dot_l, sigma) * v_dot_h.max(0.0) * n_dot_l / n_dot_h.max(1e-4);
    let (f0, f1) = fresnel_split(v_dot_h);
    (f0 * fac, f1 * fac)
}
