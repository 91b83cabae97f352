//! Output files: JSON and PNG previews, each written to a temporary name and renamed, and
//! output folders, each staged under a temporary name and put in place whole.
//!
//! Owns: those writers and the staging of folders. Must not touch: what is written.

use anyhow::{Context, Result};
use fipt_core::io::{write_atomic, write_bytes_atomic};
use std::path::{Path, PathBuf};

/// Writes `v` as pretty JSON, atomically.
pub fn write_json(path: &Path, v: &impl serde::Serialize) -> Result<()> {
    write_bytes_atomic(path, serde_json::to_string_pretty(v)?.as_bytes())?;
    Ok(())
}

/// Removes the file `path` if it is there; an error names it.
pub fn remove_file_if_present(path: &Path) -> Result<()> {
    match std::fs::remove_file(path) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
            anyhow::bail!("{}: cannot remove: {e}", path.display())
        }
        _ => Ok(()),
    }
}

/// Writes an RGB image as an 8-bit PNG of clip(x·scale, 0, 1)^(1/2.2), atomically.
pub fn write_png(path: &Path, width: usize, height: usize, rgb: &[f32], scale: f32) -> Result<()> {
    let bytes: Vec<u8> = rgb
        .iter()
        .map(|&x| (crate::image_metrics::gamma(x * scale) * 255.0 + 0.5) as u8)
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

/// `dir` with `.name.<tag>-<pid>.tmp` as its last component (same parent, so renames stay on
/// one file system; the `.tmp` ending marks it as a temporary a later run may remove).
pub fn sibling(dir: &Path, tag: &str) -> PathBuf {
    let name = dir
        .file_name()
        .map_or("folder".into(), |n| n.to_string_lossy().into_owned());
    dir.with_file_name(format!(".{name}.{tag}-{}.tmp", std::process::id()))
}

/// Moves the complete folder `from` to `to`, replacing `to`: the old folder is first renamed
/// aside, so `to` is the old complete folder, then absent for an instant, then the new one; a
/// run killed in that instant leaves the old copy aside, which the next `run` puts back
/// (`pipeline::checkpoint::remove_stale_tmp`).
pub fn replace_dir(from: &Path, to: &Path) -> Result<()> {
    if let Some(p) = to.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(p).with_context(|| format!("{}: cannot create", p.display()))?;
    }
    let old = sibling(to, "old");
    let had_old = to.exists();
    if had_old {
        let _ = std::fs::remove_dir_all(&old);
        std::fs::rename(to, &old).with_context(|| format!("{}: cannot replace", to.display()))?;
    }
    std::fs::rename(from, to).with_context(|| format!("{}: cannot write", to.display()))?;
    if had_old {
        let _ = std::fs::remove_dir_all(&old);
    }
    Ok(())
}

/// Writes the folder `dir` whole: `write` fills a staged sibling folder (created empty), which
/// then replaces `dir` (`replace_dir`); when `write` fails the staged folder is removed and
/// `dir` stays as it was.
pub fn staged_dir<T>(dir: &Path, write: impl FnOnce(&Path) -> Result<T>) -> Result<T> {
    let tmp = sibling(dir, "tmp");
    let _ = std::fs::remove_dir_all(&tmp);
    std::fs::create_dir_all(&tmp).with_context(|| format!("{}: cannot create", tmp.display()))?;
    match write(&tmp) {
        Ok(v) => {
            replace_dir(&tmp, dir)?;
            Ok(v)
        }
        Err(e) => {
            let _ = std::fs::remove_dir_all(&tmp);
            Err(e)
        }
    }
}
