//! Image metrics and the ground-truth checks of the bake.
//!
//! Owns: `psnr`, the one PSNR of the project (maps, bake checks, re-renders all score through
//! it), PSNR on tone-mapped images, the factorised render with ground-truth materials.
//! Must not touch: training.

use fipt_core::brdf::factorised_render;
use fipt_core::scene::{MapKind, View};
use fipt_core::shading::ShadingLayout;

/// Display tone map of the reference's comparisons: clip(x, 0, 1)^(1/2.2).
#[inline]
pub fn gamma(x: f32) -> f32 {
    x.clamp(0.0, 1.0).powf(1.0 / 2.2)
}

/// PSNR of a summed squared error `se` over `n` values, −10·log10(se / n), capped at 100 dB
/// (MSE floor 1e-10); None for no values; NaN when the error is not finite, so that a NaN
/// prediction never scores as perfect (`f64::max` would drop the NaN).
pub fn psnr(se: f64, n: usize) -> Option<f64> {
    (n > 0).then(|| {
        if se.is_finite() {
            -10.0 * (se / n as f64).max(1e-10).log10()
        } else {
            f64::NAN
        }
    })
}

/// PSNR between the tone-mapped RGB images `a` and `b` over the pixels where `mask` holds.
pub fn psnr_gamma(a: &[f32], b: &[f32], mask: impl Fn(usize) -> bool) -> Option<f64> {
    let (mut se, mut n) = (0.0f64, 0usize);
    for p in 0..a.len() / 3 {
        if !mask(p) {
            continue;
        }
        for c in 0..3 {
            se += ((gamma(a[3 * p + c]) - gamma(b[3 * p + c])) as f64).powi(2);
        }
        n += 3;
    }
    psnr(se, n)
}

/// The ground-truth maps `gt_render` needs.
pub const GT_RENDER_MAPS: [MapKind; 5] = [
    MapKind::DiffCol,
    MapKind::BaseColor,
    MapKind::Metallic,
    MapKind::Roughness,
    MapKind::Emit,
];

/// PSNR of the factorised render with the ground-truth materials against `Image`.
#[derive(Clone, Copy, Debug, serde::Serialize, serde::Deserialize)]
pub struct GtRenderPsnr {
    pub all: f64,
    /// Pixels with ground-truth σ ≥ 0.6.
    pub diffuse: Option<f64>,
    /// Pixels with ground-truth σ < 0.6.
    pub specular: Option<f64>,
}

/// The factorised render of a view from its baked `shading` (`ShadingLayout`) with ground-truth
/// k_d (`DiffCol`), k_s (from `BaseColor`, `Metallic`), σ (`Roughness`), plus `Emit`.
/// Needs those maps; returns None where one is missing.
pub fn gt_render(view: &View, shading: &[f32]) -> Option<Vec<f32>> {
    let kd = view.map(MapKind::DiffCol)?;
    let base = view.map(MapKind::BaseColor)?;
    let metal = view.map(MapKind::Metallic)?;
    let rough = view.map(MapKind::Roughness)?;
    let emit = view.map(MapKind::Emit)?;
    let n = view.image.num_pixels();
    let mut out = vec![0f32; 3 * n];
    for p in 0..n {
        let (a, m) = (base.rgb(p), metal.scalar(p));
        let ks = [0, 1, 2].map(|c| 0.04 * (1.0 - m) + a[c] * m);
        let r = factorised_render(
            kd.rgb(p),
            ks,
            rough.scalar(p),
            ShadingLayout::pixel(shading, p),
        );
        let e = emit.rgb(p);
        for c in 0..3 {
            out[3 * p + c] = r[c] + e[c];
        }
    }
    Some(out)
}

/// `gt_render` scored against the view's `Image`: all pixels, diffuse and specular pixels.
pub fn gt_render_psnr(view: &View, shading: &[f32]) -> Option<GtRenderPsnr> {
    let pred = gt_render(view, shading)?;
    let rough = view.map(MapKind::Roughness)?;
    let img = &view.image.data;
    Some(GtRenderPsnr {
        all: psnr_gamma(&pred, img, |_| true)?,
        diffuse: psnr_gamma(&pred, img, |p| rough.scalar(p) >= 0.6),
        specular: psnr_gamma(&pred, img, |p| rough.scalar(p) < 0.6),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn psnr_scores_nan_as_nan_and_caps_at_100_db() {
        assert!((psnr(0.03, 3).unwrap() - 20.0).abs() < 1e-9);
        assert!((psnr(4.0, 4).unwrap()).abs() < 1e-9);
        assert!((psnr(0.0, 5).unwrap() - 100.0).abs() < 1e-9);
        assert!((psnr(1e-13, 1).unwrap() - 100.0).abs() < 1e-9);
        assert!(psnr(f64::NAN, 3).unwrap().is_nan());
        assert!(psnr(f64::INFINITY, 3).unwrap().is_nan());
        assert_eq!(psnr(0.0, 0), None);
    }

    #[test]
    fn a_nan_render_scores_nan_not_perfect() {
        let truth = vec![0.5f32; 12];
        let mut pred = truth.clone();
        pred[4] = f32::NAN;
        assert!(psnr_gamma(&pred, &truth, |_| true).unwrap().is_nan());
        let close = psnr_gamma(&truth, &truth, |_| true).unwrap();
        assert!((close - 100.0).abs() < 1e-9, "identical images: {close}");
        assert_eq!(psnr_gamma(&pred, &truth, |_| false), None);
    }
}
