//! Output files: JSON and PNG previews, each written to a temporary name and renamed.
//!
//! Owns: those writers. Must not touch: what is written.

use anyhow::Result;
use fipt_core::io::{write_atomic, write_bytes_atomic};
use std::path::Path;

/// Writes `v` as pretty JSON, atomically.
pub fn write_json(path: &Path, v: &impl serde::Serialize) -> Result<()> {
    write_bytes_atomic(path, serde_json::to_string_pretty(v)?.as_bytes())?;
    Ok(())
}

/// Writes an RGB image as an 8-bit PNG of clip(x·scale, 0, 1)^(1/2.2), atomically.
pub fn write_png(path: &Path, width: usize, height: usize, rgb: &[f32], scale: f32) -> Result<()> {
    let bytes: Vec<u8> = rgb
        .iter()
        .map(|&x| (crate::metrics::gamma(x * scale) * 255.0 + 0.5) as u8)
        .collect();
    write_atomic(path, |tmp| {
        image::save_buffer_with_format(
            tmp,
            &bytes,
            width as u32,
            height as u32,
            image::ColorType::Rgb8,
            image::ImageFormat::Png,
        )
        .map_err(|e| e.to_string())
    })?;
    Ok(())
}
