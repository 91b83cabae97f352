//! The camera response and the per-frame exposures of LDR photos, and the photos linearised with
//! them (L = g(I)/e) before anything reads them.
//!
//! - **Response**: the sRGB curve, the encoding an 8-bit photo is written in, unless the
//!   estimate from the pixels on the occluding contours (`super::edges`, `ldr.edge_response`)
//!   departs from it by more than `ldr.edge_tolerance` (RMS), the estimate's own error on
//!   rendered twins. With `ldr.estimate_response`, the lamp solve's estimate (`super::response`)
//!   replaces it before the bake.
//! - **Exposure**: a frame's `exposure` where the capture gives it; else estimated. Every
//!   surface point seen in several views has one radiance (up to its specular part), so the
//!   log-ratio of a frame's linearised pixels to the cross-view radiance of the points they see
//!   is that frame's log exposure. Points are keyed by (triangle, voxel of a 64³ grid); the
//!   per-point radiance and the per-frame exposure are alternated as medians (robust to
//!   highlights) over unclipped pixels until no exposure moves.
//! - **Scale**: nothing records the absolute radiance, so the median train frame's exposure is
//!   1: radiance is in units of that frame's clip level.
//!
//! Owns: those estimates and the relinearisation. Must not touch: the fit, emitter radiance.

use fipt_bake::{Accel, cast_view};
use fipt_core::scene::{Dataset, Response, Split};
use serde::{Deserialize, Serialize};
use std::collections::HashMap;

/// Where a split's exposures came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ExposureSource {
    Given,
    Estimated,
    /// Not given and not estimated (`ldr.estimate_exposure` off): every frame's is 1.
    Unit,
}

/// What a run assumed and estimated about its LDR photos (`metrics.json` → `ldr.calibration`).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Calibration {
    pub response: Response,
    /// The estimate from the occluding contours (None: not read, or too few pixels); `response`
    /// is it where it departs from the sRGB curve by more than `ldr.edge_tolerance`.
    #[serde(default)]
    pub edges: Option<super::edges::EdgeFit>,
    pub exposure_source: ExposureSource,
    /// e_i of the train frames (median 1) and of the val frames.
    pub train_exposures: Vec<f64>,
    pub val_exposures: Vec<f64>,
    /// The share of pixels with a clipped channel, per train frame.
    pub clipped_share: Vec<f64>,
}

/// Voxels per side of the grid that keys surface points.
const GRID: f32 = 64.0;

/// The most rounds of the exposure estimate's alternation.
const MAX_ROUNDS: usize = 400;

/// Per view, per surface point (triangle, voxel): the mean code value in [0, 1] of each
/// channel over the view's unclipped pixels there.
type PointCodes = Vec<HashMap<u64, [f64; 3]>>;

fn point_codes(ds: &Dataset, accel: &Accel, split: &Split) -> PointCodes {
    let sb = fipt_core::scene::SceneBox::from_points(&ds.mesh.vertices);
    split
        .views
        .iter()
        .map(|v| {
            let f = v.ldr.as_ref().expect("LDR views");
            let hits = cast_view(accel, &ds.mesh, &v.camera);
            let mut sum: HashMap<u64, ([f64; 3], u32)> = HashMap::new();
            for p in 0..hits.num_pixels() {
                let t = hits.tri[p];
                if t < 0 || f.pixel_clipped(p) {
                    continue;
                }
                let q = (sb
                    .to_unit(hits.position[p])
                    .clamp(glam::Vec3::ZERO, glam::Vec3::ONE)
                    * (GRID - 1.0))
                    .as_uvec3();
                let key =
                    ((t as u64) << 24) ^ ((q.x as u64) << 16) ^ ((q.y as u64) << 8) ^ q.z as u64;
                let e = sum.entry(key).or_default();
                for c in 0..3 {
                    e.0[c] += f.value(p, c);
                }
                e.1 += 1;
            }
            sum.into_iter()
                .map(|(k, (s, n))| (k, s.map(|x| x / n as f64)))
                .collect()
        })
        .collect()
}

/// The log of the mean linear luminance (response `r`, exposure 1) of every point of every
/// view, where the luminance is above 1e-4.
fn point_logs(codes: &PointCodes, r: &Response) -> Vec<HashMap<u64, f64>> {
    codes
        .iter()
        .map(|m| {
            m.iter()
                .map(|(k, v)| (*k, (0..3).map(|c| r.inverse(c, v[c])).sum::<f64>() / 3.0))
                .filter(|(_, y)| *y > 1e-4)
                .map(|(k, y)| (k, y.ln()))
                .collect()
        })
        .collect()
}

fn median(v: &mut [f64]) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    let mid = v.len() / 2;
    let (_, m, _) = v.select_nth_unstable_by(mid, f64::total_cmp);
    Some(*m)
}

/// Log exposures of `views` (per-point log luminance) against per-point log radiance
/// `radiance` (frames that share no point with it keep 0).
fn exposures_against(views: &[HashMap<u64, f64>], radiance: &HashMap<u64, f64>) -> Vec<f64> {
    views
        .iter()
        .map(|m| {
            let mut d: Vec<f64> = m
                .iter()
                .filter_map(|(k, ly)| radiance.get(k).map(|r| ly - r))
                .collect();
            median(&mut d).unwrap_or(0.0)
        })
        .collect()
}

/// Per-point log radiance: the median over views of log y − log e (`views`: log y).
fn radiance_of(views: &[HashMap<u64, f64>], log_e: &[f64], min_views: usize) -> HashMap<u64, f64> {
    let mut per: HashMap<u64, Vec<f64>> = HashMap::new();
    for (m, le) in views.iter().zip(log_e) {
        for (k, ly) in m {
            per.entry(*k).or_default().push(ly - le);
        }
    }
    per.into_iter()
        .filter(|(_, v)| v.len() >= min_views)
        .filter_map(|(k, mut v)| median(&mut v).map(|m| (k, m)))
        .collect()
}

/// The train frames' exposures estimated from their overlap (median 1), and the val frames'
/// against the train frames' radiance.
fn estimate_exposures(
    train: &PointCodes,
    val: Option<&PointCodes>,
    r: &Response,
) -> (Vec<f64>, Vec<f64>) {
    let train = point_logs(train, r);
    // Views that share few points pass an exposure change on slowly: alternate until no
    // exposure moves by more than 0.01 %.
    let mut log_e = vec![0.0; train.len()];
    for _ in 0..MAX_ROUNDS {
        let rad = radiance_of(&train, &log_e, 2);
        let mut next = exposures_against(&train, &rad);
        let mut m = next.clone();
        let mid = median(&mut m).unwrap_or(0.0);
        next.iter_mut().for_each(|e| *e -= mid);
        let moved = next
            .iter()
            .zip(&log_e)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        log_e = next;
        if moved < 1e-4 {
            break;
        }
    }
    let rad = radiance_of(&train, &log_e, 2);
    let val = match val {
        Some(v) => exposures_against(&point_logs(v, r), &rad),
        None => Vec::new(),
    };
    (
        log_e.iter().map(|e| e.exp()).collect(),
        val.iter().map(|e| e.exp()).collect(),
    )
}

/// The given exposures of a split, scaled by `scale`.
fn given(split: &Split, scale: f64) -> Option<Vec<f64>> {
    split
        .views
        .iter()
        .map(|v| v.ldr.as_ref().and_then(|f| f.exposure).map(|e| e * scale))
        .collect()
}

/// How the response is chosen: read from the occluding contours or not, and how far (RMS over
/// the forward curves) the contours' estimate must lie from the sRGB curve to replace it.
#[derive(Clone, Copy, Debug)]
pub struct ResponseChoice {
    pub edges: bool,
    pub tolerance: f64,
}

/// Takes the response (the sRGB curve, or the estimate from the occluding contours where
/// `choice` reads them and the estimate departs from sRGB by more than its tolerance),
/// estimates the exposures of an LDR dataset and relinearises its photos with them
/// (`View::image`). `estimate`: estimate exposures that the capture does not give (else every
/// frame has exposure 1).
pub fn calibrate(
    ds: &mut Dataset,
    accel: &Accel,
    estimate: bool,
    choice: ResponseChoice,
) -> Calibration {
    let fit = choice
        .edges
        .then(|| super::edges::estimate(ds, accel))
        .flatten();
    let response = match &fit {
        Some(f) if f.response().rms_forward(&Response::srgb()) > choice.tolerance => f.response(),
        _ => Response::srgb(),
    };
    Calibration {
        edges: fit,
        ..calibrate_with(ds, accel, estimate, response)
    }
}

/// `calibrate` with a given response (the estimated one, `super::response`).
pub fn calibrate_with(
    ds: &mut Dataset,
    accel: &Accel,
    estimate: bool,
    response: Response,
) -> Calibration {
    let train_given = given(&ds.train, 1.0);
    let (source, train_e, val_e) = match train_given {
        Some(t) => {
            let mut m = t.clone();
            let scale = 1.0 / median(&mut m).unwrap_or(1.0);
            let val = ds
                .val
                .as_ref()
                .map(|v| given(v, scale).unwrap_or_else(|| vec![1.0; v.views.len()]))
                .unwrap_or_default();
            let t: Vec<f64> = t.iter().map(|e| e * scale).collect();
            (ExposureSource::Given, t, val)
        }
        None if estimate => {
            let train_codes = point_codes(ds, accel, &ds.train);
            let val_codes = ds.val.as_ref().map(|v| point_codes(ds, accel, v));
            let (t, v) = estimate_exposures(&train_codes, val_codes.as_ref(), &response);
            (ExposureSource::Estimated, t, v)
        }
        None => (
            ExposureSource::Unit,
            vec![1.0; ds.train.views.len()],
            ds.val
                .as_ref()
                .map_or(Vec::new(), |v| vec![1.0; v.views.len()]),
        ),
    };
    let relinearise = |split: &mut Split, e: &[f64]| {
        for (v, &e) in split.views.iter_mut().zip(e) {
            if let Some(f) = &v.ldr {
                v.image = f.linearise(&response, e);
            }
        }
    };
    relinearise(&mut ds.train, &train_e);
    if let Some(v) = ds.val.as_mut() {
        relinearise(v, &val_e);
    }
    Calibration {
        clipped_share: ds
            .train
            .views
            .iter()
            .map(|v| v.ldr.as_ref().map_or(0.0, |f| f.clipped_share()))
            .collect(),
        response,
        edges: None,
        exposure_source: source,
        train_exposures: train_e,
        val_exposures: val_e,
    }
}
