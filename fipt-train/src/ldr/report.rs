//! What a run on LDR photos reports (`metrics.json`'s `ldr`): the response and exposures it
//! used, the solve of the clipped emitters, and view synthesis scored as IRIS scores it, in
//! LDR: the re-render through the response at the view's exposure, f(clip(e·L, 0, 1)), against
//! the 8-bit photo, PSNR with a data range of 1.
//!
//! Owns: those figures. Must not touch: the renders themselves.

use super::Calibration;
use super::lights::LightSolve;
use crate::image_metrics::psnr_gamma;
use fipt_core::scene::{Image, MapKind, Split};
use serde::{Deserialize, Serialize};
use std::path::Path;

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct LdrReport {
    pub calibration: Calibration,
    /// The clipped lamps solved before the bake (`pipeline::lamps`), and again after round 0
    /// (the radiance the run keeps).
    pub light_solve: Option<LightSolve>,
    pub light_resolve: Option<LightSolve>,
    /// Where the scene is an LDR twin (`ldr.json` beside its photos, which the method never
    /// reads): the RMS distance of the response used from the true one (`Response::rms_forward`).
    #[serde(default)]
    pub response_rms_to_truth: Option<f64>,
    /// Mean over the val views of the LDR PSNR, and per view.
    pub view_psnr_ldr: Option<f64>,
    pub view_psnr_ldr_per_view: Vec<f64>,
    /// The relit renders against the relit photos (HDR, in the scene's own units) after one
    /// global scale, which no LDR photo records: the scale, and the mean PSNR of
    /// clip(x, 0, 1)^(1/2.2) as `relight_psnr` scores it.
    pub relight_scale: Option<f64>,
    pub relight_psnr_aligned: Option<f64>,
}

impl LdrReport {
    /// The report of a run: its calibration and solves, and the scores of the val re-renders
    /// in `render_dir` (`Image/`, `Relight/`) where `val` is given (the renders were made).
    pub fn new(
        cal: &Calibration,
        light_solve: Option<LightSolve>,
        light_resolve: Option<LightSolve>,
        val: Option<&Split>,
        render_dir: &Path,
        scene: &Path,
    ) -> Self {
        let per_view = val.map_or(Vec::new(), |v| val_psnr(v, cal, &render_dir.join("Image")));
        let relit = val.and_then(|v| relight_aligned(v, &render_dir.join("Relight")));
        Self {
            calibration: cal.clone(),
            light_solve,
            light_resolve,
            response_rms_to_truth: super::TwinTruth::load(&scene.join("ldr.json"))
                .ok()
                .map(|t| cal.response.rms_forward(&t.response)),
            view_psnr_ldr: crate::rerender::mean(&per_view),
            view_psnr_ldr_per_view: per_view,
            relight_scale: relit.map(|r| r.0),
            relight_psnr_aligned: relit.map(|r| r.1),
        }
    }
}

/// PSNR (data range 1, `image_metrics::psnr`) of `render` (linear) through the response at
/// exposure `e`, against the codes of the LDR photo.
pub fn ldr_psnr(render: &Image, codes: &[u8], cal: &Calibration, e: f64) -> f64 {
    let mut se = 0.0f64;
    for (i, (&l, &code)) in render.data.iter().zip(codes).enumerate() {
        let c = i % 3;
        let v = cal.response.forward(c, e * l.max(0.0) as f64);
        let v = (255.0 * v).round() / 255.0;
        let d = v - code as f64 / 255.0;
        se += d * d;
    }
    crate::image_metrics::psnr(se, codes.len()).unwrap_or(f64::NAN)
}

/// The LDR PSNR of every val view whose re-render `render_dir/{k:03}_0001.exr` exists.
pub fn val_psnr(val: &Split, cal: &Calibration, render_dir: &Path) -> Vec<f64> {
    val.views
        .iter()
        .enumerate()
        .filter_map(|(k, v)| {
            let f = v.ldr.as_ref()?;
            let img = Image::read_exr(&render_dir.join(format!("{k:03}_0001.exr"))).ok()?;
            let e = cal.val_exposures.get(k).copied().unwrap_or(1.0);
            Some(ldr_psnr(&img, &f.codes, cal, e))
        })
        .collect()
}

/// The relit val renders in `relight_dir` against the scene's relit photos after the one
/// least-squares scale s = Σ ref·ren / Σ ren² over every view: (s, mean PSNR).
pub fn relight_aligned(val: &Split, relight_dir: &Path) -> Option<(f64, f64)> {
    let pairs: Vec<(&Image, Image)> = val
        .views
        .iter()
        .enumerate()
        .filter_map(|(k, v)| {
            let reference = v.map(MapKind::Relight)?;
            let img = Image::read_exr(&relight_dir.join(format!("{k:03}_0001.exr"))).ok()?;
            Some((reference, img))
        })
        .collect();
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for (r, x) in &pairs {
        for (&a, &b) in r.data.iter().zip(&x.data) {
            num += a as f64 * b as f64;
            den += b as f64 * b as f64;
        }
    }
    if pairs.is_empty() || den <= 0.0 {
        return None;
    }
    let s = num / den;
    let scores: Vec<f64> = pairs
        .iter()
        .filter_map(|(r, x)| {
            let scaled: Vec<f32> = x.data.iter().map(|&v| v * s as f32).collect();
            psnr_gamma(&scaled, &r.data, |_| true)
        })
        .collect();
    Some((s, crate::rerender::mean(&scores)?))
}
