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

/// A contact sheet: a grid of same-sized linear RGB images (`None`: a black tile), tone-mapped
/// as `write_png` does, with a 2-pixel gap, written atomically.
pub fn write_sheet(
    path: &Path,
    width: usize,
    height: usize,
    rows: &[Vec<Option<&[f32]>>],
) -> Result<()> {
    const GAP: usize = 2;
    let cols = rows.iter().map(Vec::len).max().unwrap_or(0);
    let (sw, sh) = (
        cols * width + cols.saturating_sub(1) * GAP,
        rows.len() * height + rows.len().saturating_sub(1) * GAP,
    );
    let mut rgb = vec![0.0f32; sw * sh * 3];
    for (r, row) in rows.iter().enumerate() {
        for (c, tile) in row.iter().enumerate() {
            let Some(tile) = tile.filter(|t| t.len() == width * height * 3) else {
                continue;
            };
            let (x0, y0) = (c * (width + GAP), r * (height + GAP));
            for y in 0..height {
                let dst = 3 * ((y0 + y) * sw + x0);
                rgb[dst..dst + 3 * width]
                    .copy_from_slice(&tile[3 * y * width..3 * (y + 1) * width]);
            }
        }
    }
    write_png(path, sw, sh, &rgb, 1.0)
}
