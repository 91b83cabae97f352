//! HDR images as plain `f32` arrays, and EXR reading/writing through the `exr` crate.
//!
//! Owns: the `Image` type, EXR decoding (RGB, alpha ignored; single-channel maps accepted) with
//! validation (finite values, sizes), atomic EXR writing. Must not touch: what the pixels mean.

use crate::io::{FileError, Result};
use std::path::Path;

/// An image: `channels` interleaved `f32` values per pixel, rows top to bottom.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    pub width: usize,
    pub height: usize,
    pub channels: usize,
    pub data: Vec<f32>,
}

impl Image {
    pub fn new(width: usize, height: usize, channels: usize) -> Self {
        Self {
            width,
            height,
            channels,
            data: vec![0.0; width * height * channels],
        }
    }

    pub fn from_data(width: usize, height: usize, channels: usize, data: Vec<f32>) -> Self {
        assert_eq!(data.len(), width * height * channels);
        Self {
            width,
            height,
            channels,
            data,
        }
    }

    pub fn num_pixels(&self) -> usize {
        self.width * self.height
    }

    /// Pixel `p` (row-major index) as a slice of `channels` values.
    #[inline]
    pub fn pixel(&self, p: usize) -> &[f32] {
        &self.data[p * self.channels..(p + 1) * self.channels]
    }

    /// RGB of pixel `p`; a single-channel image is replicated.
    #[inline]
    pub fn rgb(&self, p: usize) -> [f32; 3] {
        match self.channels {
            1 => [self.data[p]; 3],
            _ => {
                let s = &self.data[p * self.channels..];
                [s[0], s[1], s[2]]
            }
        }
    }

    /// First channel of pixel `p`.
    #[inline]
    pub fn scalar(&self, p: usize) -> f32 {
        self.data[p * self.channels]
    }

    /// A copy reduced to its first channel.
    pub fn first_channel(&self) -> Image {
        if self.channels == 1 {
            return self.clone();
        }
        let data = (0..self.num_pixels()).map(|p| self.scalar(p)).collect();
        Image::from_data(self.width, self.height, 1, data)
    }

    /// Reads an EXR file. RGB files give 3 channels (alpha and other channels ignored); files
    /// with one channel (e.g. `Y`) give 1. Non-finite values are an error.
    pub fn read_exr(path: &Path) -> Result<Image> {
        let img = read_exr_unchecked(path)?;
        if let Some(i) = img.data.iter().position(|v| !v.is_finite()) {
            let bad = img.data.iter().filter(|v| !v.is_finite()).count();
            let p = i / img.channels;
            return Err(FileError::new(
                path,
                format!(
                    "{bad} non-finite (NaN/Inf) value(s), first at row {} col {}",
                    p / img.width,
                    p % img.width
                ),
            ));
        }
        Ok(img)
    }

    /// Writes the image as a float32 EXR (RGB for 3 channels, `Y` for 1), atomically.
    pub fn write_exr(&self, path: &Path) -> Result<()> {
        use exr::prelude::*;
        let (w, h) = (self.width, self.height);
        crate::io::write_atomic(path, |tmp| {
            let names: &[&str] = match self.channels {
                1 => &["Y"],
                3 => &["R", "G", "B"],
                n => return Err(format!("cannot write a {n}-channel image as EXR")),
            };
            let list: Vec<AnyChannel<FlatSamples>> = names
                .iter()
                .enumerate()
                .map(|(c, name)| {
                    let v: Vec<f32> = (0..w * h)
                        .map(|p| self.data[p * self.channels + c])
                        .collect();
                    AnyChannel::new(*name, FlatSamples::F32(v))
                })
                .collect();
            let layer = Layer::new(
                (w, h),
                LayerAttributes::default(),
                Encoding::SMALL_LOSSLESS,
                AnyChannels::sort(list.into()),
            );
            Image::from_layer(layer)
                .write()
                .to_file(tmp)
                .map_err(|e| e.to_string())
        })
    }
}

/// Runs one step of the EXR decoder; its error or panic becomes an error naming `path`.
fn decode<T>(
    path: &Path,
    f: impl FnOnce() -> exr::error::Result<T> + std::panic::UnwindSafe,
) -> Result<T> {
    match std::panic::catch_unwind(f) {
        Ok(Ok(v)) => Ok(v),
        Ok(Err(e)) => Err(FileError::new(
            path,
            format!("not a readable EXR file: {e}"),
        )),
        Err(_) => Err(FileError::new(
            path,
            "not a readable EXR file (decoder failed)",
        )),
    }
}

/// The largest image `read_exr` accepts: 2^28 pixels (16k × 16k) and 2^30 channel values.
const MAX_EXR_PIXELS: u128 = 1 << 28;
const MAX_EXR_VALUES: u128 = 1 << 30;

fn read_exr_unchecked(path: &Path) -> Result<Image> {
    use exr::prelude::*;
    if !path.exists() {
        return Err(FileError::new(path, "file not found"));
    }
    // The decoder must never take the process down: a panic on a malformed file becomes an error,
    // and the header's sizes are checked before the decoder allocates from them (a flipped byte
    // in the data window once asked for 103 GB and aborted the process).
    let meta = decode(path, || exr::meta::MetaData::read_from_file(path, true))?;
    for h in meta.headers.iter() {
        let pixels = h.layer_size.area() as u128;
        let values = pixels * h.channels.list.len() as u128;
        if pixels > MAX_EXR_PIXELS || values > MAX_EXR_VALUES {
            return Err(FileError::new(
                path,
                format!(
                    "EXR header declares a {}x{} image with {} channel(s), over fipt's limit of {MAX_EXR_VALUES} values (damaged header?)",
                    h.layer_size.width(),
                    h.layer_size.height(),
                    h.channels.list.len()
                ),
            ));
        }
    }
    let img = decode(path, || {
        read()
            .no_deep_data()
            .largest_resolution_level()
            .all_channels()
            .first_valid_layer()
            .all_attributes()
            .pedantic()
            .from_file(path)
    })?;
    let layer = img.layer_data;
    let (w, h) = (layer.size.width(), layer.size.height());
    let chans = &layer.channel_data.list;
    let find = |n: &str| {
        chans.iter().position(|c| {
            let s = c.name.to_string();
            s == n || s.ends_with(&format!(".{n}"))
        })
    };
    let picked: Vec<usize> = match (find("R"), find("G"), find("B")) {
        (Some(r), Some(g), Some(b)) => vec![r, g, b],
        _ => {
            let non_alpha: Vec<usize> = (0..chans.len())
                .filter(|&i| {
                    let s = chans[i].name.to_string();
                    s != "A" && !s.ends_with(".A")
                })
                .collect();
            match non_alpha.as_slice() {
                [one] => vec![*one],
                _ => {
                    let names: Vec<String> = chans.iter().map(|c| c.name.to_string()).collect();
                    return Err(FileError::new(
                        path,
                        format!("expected R,G,B or one channel, found channels {names:?}"),
                    ));
                }
            }
        }
    };
    let nc = picked.len();
    let mut data = vec![0f32; w * h * nc];
    for (k, &ci) in picked.iter().enumerate() {
        let samples = &chans[ci].sample_data;
        if samples.len() != w * h {
            return Err(FileError::new(path, "channel is subsampled; not supported"));
        }
        for (p, v) in samples.values_as_f32().enumerate() {
            data[p * nc + k] = v;
        }
    }
    Ok(crate::scene::Image {
        width: w,
        height: h,
        channels: nc,
        data,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tmpdir(name: &str) -> std::path::PathBuf {
        let d = std::env::temp_dir().join(format!("fipt-img-{name}-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn exr_round_trip_rgb_and_single() {
        let d = tmpdir("rt");
        let rgb = Image::from_data(3, 2, 3, (0..18).map(|i| i as f32 * 0.25 - 1.0).collect());
        rgb.write_exr(&d.join("a.exr")).unwrap();
        assert_eq!(Image::read_exr(&d.join("a.exr")).unwrap(), rgb);
        let y = Image::from_data(3, 2, 1, (0..6).map(|i| i as f32 * 1000.0).collect());
        y.write_exr(&d.join("b.exr")).unwrap();
        assert_eq!(Image::read_exr(&d.join("b.exr")).unwrap(), y);
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn bad_files_are_errors() {
        let d = tmpdir("bad");
        let p = d.join("nan.exr");
        let mut img = Image::new(4, 4, 3);
        img.data[3 * 5 + 1] = f32::NAN;
        img.write_exr(&p).unwrap();
        let e = Image::read_exr(&p).unwrap_err().to_string();
        assert!(
            e.contains("nan.exr") && e.contains("NaN") && e.contains("row 1 col 1"),
            "{e}"
        );
        let good = d.join("good.exr");
        Image::new(64, 64, 3).write_exr(&good).unwrap();
        let bytes = std::fs::read(&good).unwrap();
        let t = d.join("trunc.exr");
        std::fs::write(&t, &bytes[..bytes.len() / 2]).unwrap();
        let e = Image::read_exr(&t).unwrap_err().to_string();
        assert!(e.contains("trunc.exr"), "{e}");
        let j = d.join("junk.exr");
        std::fs::write(&j, b"this is not an exr").unwrap();
        assert!(
            Image::read_exr(&j)
                .unwrap_err()
                .to_string()
                .contains("junk.exr")
        );
        let m = d.join("missing.exr");
        assert!(
            Image::read_exr(&m)
                .unwrap_err()
                .to_string()
                .contains("not found")
        );
        std::fs::remove_dir_all(&d).unwrap();
    }
}
