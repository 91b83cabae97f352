//! 8-bit LDR photos (PNG, JPEG) and the camera response that maps scene radiance to their code
//! values: I = f(clip(e·L, 0, 1)), with L linear radiance, e the frame's exposure and f a
//! monotone curve per channel with f(0) = 0 and f(1) = 1 (the model of IRIS, §1 of
//! `iris-reference.md`).
//!
//! The response is stored as its inverse g = f⁻¹, piecewise linear on a uniform grid of code
//! values, so that linearising a photo (L = g(I)/e) is a table lookup and f is its exact inverse.
//! A code of 255 is clipped: the photo says only that e·L ≥ 1 on that channel.
//!
//! A JPEG's code values can be reconstructed within its quantisation (`super::jpeg`); the
//! clipped test reads the decoder's codes.
//!
//! Owns: decoding LDR files with their checks, the response curve. Must not touch: how the
//! response or the exposures are estimated (fipt-train's `ldr`), ray tracing, tensors.

use super::Image;
use super::jpeg::{JpegTables, Reconstruction, reconstruct};
use crate::io::{FileError, Result, read_bytes};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The largest 8-bit code: a channel of a PNG at this code is clipped.
pub const CLIPPED: u8 = 255;

/// A channel of a JPEG at or above this code is taken as clipped: the compression's ringing
/// leaves a clipped region a few codes below 255.
pub const CLIPPED_JPEG: u8 = 250;

/// Whether a file name's extension marks an LDR photo (`png`, `jpg`, `jpeg`).
pub fn is_ldr_ext(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| ["png", "jpg", "jpeg"].contains(&e.to_ascii_lowercase().as_str()))
}

/// An LDR photo as read: 8-bit codes, 3 per pixel, rows top to bottom, and the exposure the
/// capture gives for it (`exposure` in `transforms.json`), relative to the other frames.
#[derive(Clone, Debug, PartialEq)]
pub struct LdrFrame {
    pub width: usize,
    pub height: usize,
    pub codes: Vec<u8>,
    pub exposure: Option<f64>,
    /// Codes at or above this are clipped (`CLIPPED`, or `CLIPPED_JPEG` for a JPEG).
    pub clip_at: u8,
    /// Pixels whose clipped channels a run has filled with a solved radiance (a lamp's): the
    /// view's linear image holds that radiance there, no longer a lower bound. Empty: none.
    pub filled: Vec<bool>,
    /// A JPEG's quantisation tables, where the file's markers give them.
    pub jpeg: Option<JpegTables>,
    /// The code values in [0, 1] that linearising and the response's estimates read, 3 per
    /// pixel, where they are not `codes`/255: a JPEG reconstructed within its quantisation
    /// (`reconstruct_jpeg`). Empty: `codes`/255.
    pub values: Vec<f32>,
}

impl LdrFrame {
    /// Whether channel `c` of pixel `p` is clipped.
    pub fn clipped(&self, p: usize, c: usize) -> bool {
        self.codes[3 * p + c] >= self.clip_at
    }

    /// The code value in [0, 1] of channel `c` of pixel `p` (`values`, else `codes`/255).
    pub fn value(&self, p: usize, c: usize) -> f64 {
        match self.values.get(3 * p + c) {
            Some(&v) => v as f64,
            None => self.codes[3 * p + c] as f64 / 255.0,
        }
    }

    /// Replaces the values of a JPEG's channels with its reconstruction within its
    /// quantisation (`super::jpeg::reconstruct`); a PNG, or a JPEG whose tables were not read,
    /// keeps its codes. Returns whether it did.
    pub fn reconstruct_jpeg(&mut self, how: &Reconstruction) -> bool {
        let Some(t) = &self.jpeg else {
            return false;
        };
        self.values = reconstruct(&self.codes, self.width, self.height, t, how);
        true
    }

    /// Whether the clipped channels of pixel `p` hold a solved radiance (`filled`).
    pub fn is_filled(&self, p: usize) -> bool {
        self.filled.get(p).copied().unwrap_or(false)
    }

    /// Whether any channel of pixel `p` is clipped.
    pub fn pixel_clipped(&self, p: usize) -> bool {
        (0..3).any(|c| self.clipped(p, c))
    }

    /// The share of pixels with a clipped channel.
    pub fn clipped_share(&self) -> f64 {
        let n = self.width * self.height;
        (0..n).filter(|&p| self.pixel_clipped(p)).count() as f64 / n.max(1) as f64
    }

    /// The linear radiance g(I)/e of every pixel, 3 channels (a clipped channel reads its
    /// lower bound 1/e).
    pub fn linearise(&self, response: &Response, exposure: f64) -> Image {
        let lut = response.lut();
        let s = (1.0 / exposure) as f32;
        let clip = self.clip_at as usize;
        let data = self
            .codes
            .chunks_exact(3)
            .enumerate()
            .flat_map(|(p, px)| {
                [0, 1, 2].map(|c| {
                    let code = px[c] as usize;
                    let g = if code >= clip {
                        1.0
                    } else if let Some(&v) = self.values.get(3 * p + c) {
                        response.inverse(c, v as f64) as f32
                    } else {
                        lut[c][code]
                    };
                    g * s
                })
            })
            .collect();
        Image::from_data(self.width, self.height, 3, data)
    }
}

/// Reads an 8-bit PNG or JPEG photo as RGB codes (grey is repeated, alpha is dropped).
///
/// Errors name the file: not decodable, 16-bit samples, a JPEG without its end-of-image marker
/// (a truncated file), or a frame where every pixel is clipped.
pub fn read_ldr(path: &Path) -> Result<LdrFrame> {
    let bytes = read_bytes(path)?;
    let is_jpeg = bytes.starts_with(&[0xFF, 0xD8]);
    if is_jpeg {
        // A decoder fills what a truncated JPEG lacks with grey, so the end marker is checked.
        let end = bytes.iter().rposition(|&b| b != 0).map_or(0, |i| i + 1);
        if end < 4 || bytes[end - 2..end] != [0xFF, 0xD9] {
            return Err(FileError::new(
                path,
                "truncated JPEG: the file ends before its end-of-image marker (FF D9)",
            ));
        }
    }
    let format = image::guess_format(&bytes)
        .map_err(|_| FileError::new(path, "not a PNG or JPEG file (unrecognised signature)"))?;
    if !matches!(format, image::ImageFormat::Png | image::ImageFormat::Jpeg) {
        return Err(FileError::new(
            path,
            format!("is a {format:?} file; fipt reads 8-bit PNG or JPEG photos, or HDR EXR"),
        ));
    }
    let img = image::load_from_memory_with_format(&bytes, format)
        .map_err(|e| FileError::new(path, format!("cannot decode the image: {e}")))?;
    use image::ColorType as C;
    match img.color() {
        C::L8 | C::La8 | C::Rgb8 | C::Rgba8 => {}
        c => {
            return Err(FileError::new(
                path,
                format!(
                    "has {c:?} samples: fipt reads 8-bit LDR photos (16-bit or float images must be HDR EXR files)"
                ),
            ));
        }
    }
    let rgb = img.to_rgb8();
    let (w, h) = (rgb.width() as usize, rgb.height() as usize);
    let frame = LdrFrame {
        width: w,
        height: h,
        codes: rgb.into_raw(),
        exposure: None,
        clip_at: if is_jpeg { CLIPPED_JPEG } else { CLIPPED },
        filled: Vec::new(),
        jpeg: if is_jpeg {
            JpegTables::read(&bytes)
        } else {
            None
        },
        values: Vec::new(),
    };
    if frame.codes.iter().all(|&c| c >= frame.clip_at) {
        return Err(FileError::new(
            path,
            "every pixel is white (clipped): the frame is over-exposed and records no radiance",
        ));
    }
    Ok(frame)
}

/// The sRGB EOTF (code value in [0, 1] to linear).
pub fn srgb_to_linear(v: f64) -> f64 {
    if v <= 0.04045 {
        v / 12.92
    } else {
        ((v + 0.055) / 1.055).powf(2.4)
    }
}

/// The sRGB OETF (linear in [0, 1] to code value).
pub fn linear_to_srgb(x: f64) -> f64 {
    if x <= 0.003_130_8 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    }
}

/// A camera response per channel, kept as its inverse g: the linear value at each of `knots`
/// uniform code values 0, 1/K, …, 1 (g(0) = 0, g(1) = 1, strictly increasing), linear between.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Response {
    /// `[channel][j]` = g(j/K).
    pub knots: [Vec<f64>; 3],
}

impl Response {
    /// Knot count of the curves fipt builds (K + 1 = 33 values per channel).
    pub const SEGMENTS: usize = 32;

    /// A response whose forward curve is `f` on every channel (f monotone, f(0)=0, f(1)=1),
    /// sampled by inverting f at the knots.
    pub fn from_forward(f: impl Fn(usize, f64) -> f64) -> Self {
        let k = Self::SEGMENTS;
        let knots = [0, 1, 2].map(|c| {
            (0..=k)
                .map(|j| {
                    let v = j as f64 / k as f64;
                    // Bisection on the monotone f.
                    let (mut lo, mut hi) = (0.0f64, 1.0f64);
                    for _ in 0..60 {
                        let mid = 0.5 * (lo + hi);
                        if f(c, mid) < v {
                            lo = mid;
                        } else {
                            hi = mid;
                        }
                    }
                    if j == 0 {
                        0.0
                    } else if j == k {
                        1.0
                    } else {
                        0.5 * (lo + hi)
                    }
                })
                .collect()
        });
        Self { knots }
    }

    /// The sRGB curve on every channel.
    pub fn srgb() -> Self {
        Self::from_forward(|_, x| linear_to_srgb(x))
    }

    /// The response family fipt estimates: the sRGB curve after a power per channel,
    /// g_c(v) = srgb⁻¹(v)^γ_c (γ = 1: sRGB). A camera's tone curve departs from the sRGB
    /// encoding chiefly in contrast, which γ_c carries; one number per channel is what a single
    /// exposure's photos determine (`fipt-train/src/ldr/response.rs`).
    pub fn srgb_power(gamma: [f64; 3]) -> Self {
        Self::from_forward(|c, x| linear_to_srgb(x.powf(1.0 / gamma[c])))
    }

    /// A pure power law f(x) = x^(1/γ_c) per channel.
    pub fn gamma(g: [f64; 3]) -> Self {
        Self::from_forward(|c, x| x.powf(1.0 / g[c]))
    }

    /// g_c(v): the linear value of code value v ∈ [0, 1].
    pub fn inverse(&self, c: usize, v: f64) -> f64 {
        let k = &self.knots[c];
        let n = k.len() - 1;
        let t = v.clamp(0.0, 1.0) * n as f64;
        let j = (t.floor() as usize).min(n - 1);
        let u = t - j as f64;
        k[j] + u * (k[j + 1] - k[j])
    }

    /// f_c(x): the code value of linear x (clipped to [0, 1]), the exact inverse of `inverse`.
    pub fn forward(&self, c: usize, x: f64) -> f64 {
        let k = &self.knots[c];
        let n = k.len() - 1;
        let x = x.clamp(0.0, 1.0);
        let j = k.partition_point(|&g| g <= x).clamp(1, n) - 1;
        let span = k[j + 1] - k[j];
        let u = if span > 0.0 { (x - k[j]) / span } else { 0.0 };
        (j as f64 + u.clamp(0.0, 1.0)) / n as f64
    }

    /// g at the 256 codes of an 8-bit photo, per channel.
    pub fn lut(&self) -> [Vec<f32>; 3] {
        [0, 1, 2].map(|c| {
            (0..256)
                .map(|i| self.inverse(c, i as f64 / 255.0) as f32)
                .collect()
        })
    }

    /// The RMS distance between two responses' forward curves over 1024 uniform linear values
    /// in [0, 1], all channels (the measure of a recovered response).
    pub fn rms_forward(&self, other: &Response) -> f64 {
        let n = 1024;
        let mut s = 0.0;
        for c in 0..3 {
            for i in 0..n {
                let x = i as f64 / (n - 1) as f64;
                let d = self.forward(c, x) - other.forward(c, x);
                s += d * d;
            }
        }
        (s / (3 * n) as f64).sqrt()
    }

    /// Checks the invariants (finite, g(0) = 0, g(1) = 1, strictly increasing).
    pub fn validate(&self) -> std::result::Result<(), String> {
        for (c, k) in self.knots.iter().enumerate() {
            if k.len() < 2 {
                return Err(format!("channel {c}: fewer than 2 knots"));
            }
            if k[0] != 0.0 || k[k.len() - 1] != 1.0 {
                return Err(format!("channel {c}: g(0) must be 0 and g(1) must be 1"));
            }
            if k.windows(2)
                .any(|w| w[1] <= w[0] || !w[1].is_finite() || w[0].is_nan())
            {
                return Err(format!("channel {c}: not strictly increasing"));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn forward_inverts_inverse_and_matches_the_curve() {
        for r in [Response::srgb(), Response::gamma([1.8, 2.2, 2.6])] {
            r.validate().unwrap();
            for c in 0..3 {
                for i in 0..=200 {
                    let v = i as f64 / 200.0;
                    let x = r.inverse(c, v);
                    assert!((r.forward(c, x) - v).abs() < 1e-9, "c {c} v {v}");
                }
            }
        }
        // The piecewise-linear inverse against the analytic sRGB curve.
        let r = Response::srgb();
        for i in 0..=255 {
            let v = i as f64 / 255.0;
            assert!(
                (r.inverse(1, v) - srgb_to_linear(v)).abs() < 2e-3,
                "code {i}"
            );
        }
        let g = Response::gamma([2.2; 3]);
        assert!(r.rms_forward(&r) < 1e-12);
        let d = r.rms_forward(&g);
        assert!(d > 0.003 && d < 0.01, "sRGB against gamma 2.2: {d}");
    }
}
