//! The factorised renderer (paper Eq. 5, 8 and 12): pred = k_d·L_d + k_s·L_s0(σ) + L_s1(σ), with the
//! specular shadings linearly interpolated in σ over the cached levels linspace(0.02, 1, 6),
//! and the emission-masked composite.
//!
//! Owns: shading interpolation and compositing. Must not touch: how shadings are made.

use crate::brdf::SIGMA_MIN;
use crate::shading::{ROUGHNESS_LEVELS, ShadingLayout as S};
use burn::tensor::activation::relu;
use burn::tensor::{Tensor, TensorData};

/// Per-pixel shadings: L_d [N,3], L_s0 and L_s1 [N,6,3] (one RGB per roughness level).
#[derive(Clone, Debug)]
pub struct Shadings {
    pub ld: Tensor<2>,
    pub ls0: Tensor<3>,
    pub ls1: Tensor<3>,
}

impl Shadings {
    /// Splits a packed [N, `ShadingLayout::DIM`] tensor into its blocks.
    pub fn from_packed(p: Tensor<2>) -> Self {
        let [n, c] = p.dims();
        assert_eq!(c, S::DIM);
        let l = S::LEVELS;
        Self {
            ld: p.clone().slice([0..n, S::LD]),
            ls0: p.clone().slice([0..n, S::LS0]).reshape([n, l, 3]),
            ls1: p.slice([0..n, S::LS1]).reshape([n, l, 3]),
        }
    }
}

/// Eq. 8's interpolation weights over the roughness levels, [N,6]: the hat functions
/// w_j = max(0, 1 − |r − j|) with r = (σ − 0.02)/0.98 · 5. They equal the reference's
/// floor/ceil blend, gradient included (zero at the level values).
pub fn roughness_weights(sigma: Tensor<2>) -> Tensor<2> {
    let l = ROUGHNESS_LEVELS;
    let r = sigma
        .sub_scalar(SIGMA_MIN)
        .div_scalar(1.0 - SIGMA_MIN)
        .mul_scalar((l - 1) as f32); // [N,1]
    let j: Vec<f32> = (0..l).map(|j| j as f32).collect();
    let j = Tensor::<2>::from_data(TensorData::new(j, [1, l]), &r.device());
    relu((r - j).abs().neg().add_scalar(1.0))
}

/// Σ_j w_j L_j: [N,6,3] × [N,6] → [N,3].
pub fn lerp_levels(ls: Tensor<3>, w: Tensor<2>) -> Tensor<2> {
    let [n, l, c] = ls.dims();
    (ls * w.reshape([n, l, 1])).sum_dim(1).reshape([n, c])
}

/// Eq. 5 with Eq. 8's lerp: the factorised render. Returns (prediction, specular part k_s·L_s0 + L_s1).
pub fn render(
    kd: Tensor<2>,
    ks: Tensor<2>,
    sigma: Tensor<2>,
    sh: &Shadings,
) -> (Tensor<2>, Tensor<2>) {
    let w = roughness_weights(sigma);
    let spec = ks * lerp_levels(sh.ls0.clone(), w.clone()) + lerp_levels(sh.ls1.clone(), w);
    (kd * sh.ld.clone() + spec.clone(), spec)
}

/// Eq. 12: emission-masked composite C = (1 − α)·pred + α·I.
pub fn composite(pred: Tensor<2>, alpha: Tensor<2>, gt: Tensor<2>) -> Tensor<2> {
    pred * alpha.clone().neg().add_scalar(1.0) + gt * alpha
}
