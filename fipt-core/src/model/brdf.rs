//! The FIPT BRDF as tensor ops (the scalar twin is `crate::brdf`; a test holds them equal).
//!
//! Owns: the BRDF of Eq. 1 (k_d, k_s, GGX D, Schlick-GGX G, Schlick F) on tensors. Must not touch: sampling (scalar side only).

use burn::tensor::Tensor;
use std::f32::consts::PI;

/// Eq. 1's reflectances: k_d = a(1 − m), k_s = 0.04(1 − m) + a·m; a [N,3], m [N,1].
pub fn reflectances(a: Tensor<2>, m: Tensor<2>) -> (Tensor<2>, Tensor<2>) {
    let one_m = m.clone().neg().add_scalar(1.0);
    let kd = a.clone() * one_m.clone();
    let ks = one_m.mul_scalar(0.04) + a * m;
    (kd, ks)
}

/// Eq. 1's D: GGX D(n·h) with α = σ².
pub fn ggx_d(n_dot_h: Tensor<2>, sigma: Tensor<2>) -> Tensor<2> {
    let a2 = sigma.powi_scalar(4);
    let nh = n_dot_h.clamp(0.0, 1.0);
    // (n·h)²(α² − 1) + 1 as sin²θ_h + α² cos²θ_h (no cancellation for tiny α).
    let nh2 = nh.clone() * nh.clone();
    let d = nh.clone().neg().add_scalar(1.0) * nh.add_scalar(1.0) + a2.clone() * nh2;
    a2 / (d.clone() * d).mul_scalar(PI)
}

/// Eq. 1's G (Schlick-GGX, UE4 remap) over (n·l)(n·v): G_s = 1/((n·v(1−k)+k)(n·l(1−k)+k)), k = (σ+1)²/8.
pub fn g_schlick_over(n_dot_v: Tensor<2>, n_dot_l: Tensor<2>, sigma: Tensor<2>) -> Tensor<2> {
    let k = sigma.add_scalar(1.0).powi_scalar(2).div_scalar(8.0);
    let one_k = k.clone().neg().add_scalar(1.0);
    let gv = n_dot_v.clamp_min(0.0) * one_k.clone() + k.clone();
    let gl = n_dot_l.clamp_min(0.0) * one_k + k;
    (gv * gl).recip()
}

/// Eq. 1: f = k_d/π + D·(k_s + (1−k_s)(1−v·h)⁵)·G_s/4 for given cosines (all [N,1]).
pub fn eval_f(
    kd: Tensor<2>,
    ks: Tensor<2>,
    sigma: Tensor<2>,
    n_dot_v: Tensor<2>,
    n_dot_l: Tensor<2>,
    n_dot_h: Tensor<2>,
    v_dot_h: Tensor<2>,
) -> Tensor<2> {
    let x = v_dot_h.clamp_min(0.0).neg().add_scalar(1.0).powi_scalar(5);
    let f = ks.clone() + (ks.neg().add_scalar(1.0)) * x;
    let spec = ggx_d(n_dot_h, sigma.clone()) * g_schlick_over(n_dot_v, n_dot_l, sigma) / 4.0;
    kd.div_scalar(PI) + f * spec
}
