//! The shading cache on disk: one fast binary file per scene (reused while the scene, the bake
//! config and the code version are unchanged), plus EXR images in the reference's naming so
//! people can look at them, and PNG previews.
//!
//! Owns: cache keys and file formats of the bake's outputs. Must not touch: how shadings are made.

use anyhow::{Context, Result};
use fipt_bake::integrators::bake::BakeConfig;
use fipt_core::io::{Fnv64, Part, write_parts_atomic};
use fipt_core::scene::{Dataset, Image, MapKind};
use fipt_core::shading::ShadingLayout;
use std::io::Read;
use std::path::Path;

const MAGIC: &[u8; 8] = b"FIPTSHD2";
/// The magic of the format before the content hash: such a cache is stale, not damaged.
const OLD_MAGIC: &[u8; 8] = b"FIPTSHD1";

/// The error of a cache that is damaged (not a cache, cut, too long, or its content hash
/// differs), as opposed to one that cannot be read at all.
#[derive(Debug)]
pub struct Damaged(pub String);

impl std::fmt::Display for Damaged {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for Damaged {}

fn damaged(path: &Path, what: &str) -> anyhow::Error {
    Damaged(format!("{}: {what} (delete it to rebake)", path.display())).into()
}
/// Magic, key, views, width, height, shading size, content hash: 8 bytes each.
const HEAD: usize = 56;
/// Bumped whenever the bake's maths or this format changes.
pub const BAKE_CODE_VERSION: u32 = 5;

/// Cache key of a scene's bake: code version, config, seed, mesh, cameras and train images.
pub fn cache_key(ds: &Dataset, cfg: &BakeConfig) -> Result<u64> {
    let mut h = Fnv64::default();
    h.bytes(&BAKE_CODE_VERSION.to_le_bytes());
    h.bytes(env!("CARGO_PKG_VERSION").as_bytes());
    h.bytes(serde_json::to_string(cfg)?.as_bytes());
    h.bytes(&cfg.seed.to_le_bytes());
    ds.mesh.hash_into(&mut h);
    for v in &ds.train.views {
        let c = &v.camera;
        for x in c
            .rotation
            .to_cols_array()
            .iter()
            .chain(&c.origin.to_array())
            .chain(&[c.fx, c.fy, c.cx, c.cy])
        {
            h.bytes(&x.to_le_bytes());
        }
        h.f32s(&v.image.data);
        // The footprints' parts come from the label maps (`bake::part_keys`), in the bake
        // and in the refinements and oracle, whose keys start from this one.
        for kind in [MapKind::IndexMA, MapKind::Segmentation] {
            for l in v.labels(kind).into_iter().flatten() {
                h.bytes(&l.to_le_bytes());
            }
        }
    }
    Ok(h.finish())
}

/// The bytes of `v` as written (little-endian f32s).
fn le_bytes(v: &[f32]) -> std::borrow::Cow<'_, [u8]> {
    #[cfg(target_endian = "little")]
    {
        std::borrow::Cow::Borrowed(bytemuck::cast_slice(v))
    }
    #[cfg(not(target_endian = "little"))]
    {
        std::borrow::Cow::Owned(v.iter().flat_map(|x| x.to_le_bytes()).collect())
    }
}

/// Writes the binary cache atomically, with the content hash of its payload in its header.
pub fn save(
    path: &Path,
    key: u64,
    width: usize,
    height: usize,
    shadings: &[Vec<f32>],
) -> Result<()> {
    let mut head = Vec::with_capacity(HEAD);
    head.extend_from_slice(MAGIC);
    head.extend_from_slice(&key.to_le_bytes());
    for v in [shadings.len(), width, height, ShadingLayout::DIM] {
        head.extend_from_slice(&(v as u64).to_le_bytes());
    }
    // The content hash: XXH3-64 of the payload's bytes, view after view.
    let mut h = xxhash_rust::xxh3::Xxh3::new();
    for s in shadings {
        h.update(&le_bytes(s));
    }
    head.extend_from_slice(&h.digest().to_le_bytes());
    let parts: Vec<Part> = std::iter::once(Part::Bytes(&head))
        .chain(shadings.iter().map(|s| Part::F32s(s)))
        .collect();
    write_parts_atomic(path, &parts)?;
    Ok(())
}

/// Loads the binary cache if it exists and its key, sizes and length match; `Ok(None)` when it
/// is absent or stale, an error naming the file when it is damaged (not a cache, cut, longer
/// than its header says, or its content hash differs).
pub fn load(
    path: &Path,
    key: u64,
    views: usize,
    width: usize,
    height: usize,
) -> Result<Option<Vec<Vec<f32>>>> {
    load_keyed(path, Some(key), views, width, height)
}

/// `load`, but a damaged cache (`Damaged`) is discarded (removed, with a message naming it and
/// why) and reads as absent, so that the caller computes it again. Other errors (a cache that
/// cannot be opened) are errors.
pub fn load_or_discard(
    path: &Path,
    key: u64,
    views: usize,
    width: usize,
    height: usize,
) -> Result<Option<Vec<Vec<f32>>>> {
    match load(path, key, views, width, height) {
        Ok(v) => Ok(v),
        Err(e) if e.is::<Damaged>() => {
            eprintln!("discarded a damaged cache, which is computed again: {e:#}");
            std::fs::remove_file(path)
                .with_context(|| format!("{}: cannot remove the damaged cache", path.display()))?;
            Ok(None)
        }
        Err(e) => Err(e),
    }
}

/// Like `load`, with `None` accepting any key (diagnostics reading another run's shadings).
pub fn load_keyed(
    path: &Path,
    key: Option<u64>,
    views: usize,
    width: usize,
    height: usize,
) -> Result<Option<Vec<Vec<f32>>>> {
    if !path.exists() {
        return Ok(None);
    }
    let mut f =
        std::fs::File::open(path).with_context(|| format!("{}: cannot open", path.display()))?;
    let mut head = [0u8; HEAD];
    let whole = f.read_exact(&mut head).is_ok();
    if &head[..8] == OLD_MAGIC {
        return Ok(None);
    }
    if !whole || &head[..8] != MAGIC {
        return Err(damaged(path, "not a fipt shading cache"));
    }
    let num = |i: usize| u64::from_le_bytes(head[8 + 8 * i..16 + 8 * i].try_into().unwrap());
    if key.is_some_and(|k| num(0) != k) {
        return Ok(None);
    }
    if (num(1), num(2), num(3), num(4))
        != (
            views as u64,
            width as u64,
            height as u64,
            ShadingLayout::DIM as u64,
        )
    {
        return Ok(None);
    }
    let per_view = width * height * ShadingLayout::DIM;
    let mut out = Vec::with_capacity(views);
    let mut buf = vec![0u8; per_view * 4];
    let mut h = xxhash_rust::xxh3::Xxh3::new();
    for k in 0..views {
        f.read_exact(&mut buf)
            .map_err(|_| damaged(path, &format!("truncated at view {k}")))?;
        h.update(&buf);
        out.push(
            buf.chunks_exact(4)
                .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
                .collect(),
        );
    }
    if f.read(&mut [0u8; 1]).is_ok_and(|n| n > 0) {
        return Err(damaged(path, "longer than its header says"));
    }
    if h.digest() != num(5) {
        return Err(damaged(path, "damaged, its content hash differs"));
    }
    Ok(Some(out))
}

/// Writes the shadings as EXRs in the reference's layout: `diffuse/{k:03}.exr` and
/// `specular/{k:03}_{c}_{j}.exr` (Fresnel component c ∈ {0,1}, roughness level j ∈ 0..6).
pub fn write_exrs(dir: &Path, width: usize, height: usize, shadings: &[Vec<f32>]) -> Result<()> {
    use rayon::prelude::*;
    shadings
        .par_iter()
        .enumerate()
        .try_for_each(|(k, s)| -> Result<()> {
            let channel = |block: std::ops::Range<usize>| {
                let data = (0..width * height)
                    .flat_map(|p| ShadingLayout::pixel(s, p)[block.clone()].to_vec())
                    .collect();
                Image::from_data(width, height, 3, data)
            };
            channel(ShadingLayout::LD)
                .write_exr(&dir.join("diffuse").join(format!("{k:03}.exr")))?;
            for j in 0..ShadingLayout::LEVELS {
                for (c, block) in [ShadingLayout::ls0(j), ShadingLayout::ls1(j)]
                    .into_iter()
                    .enumerate()
                {
                    channel(block)
                        .write_exr(&dir.join("specular").join(format!("{k:03}_{c}_{j}.exr")))?;
                }
            }
            Ok(())
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cache_round_trip_stale_key_and_truncation() {
        let dir = std::env::temp_dir().join(format!("fipt-cache-{}", std::process::id()));
        let p = dir.join("shadings.bin");
        let s: Vec<Vec<f32>> = (0..2)
            .map(|k| {
                (0..4 * 3 * ShadingLayout::DIM)
                    .map(|i| (i + k) as f32 * 0.5)
                    .collect()
            })
            .collect();
        save(&p, 42, 4, 3, &s).unwrap();
        assert_eq!(load(&p, 42, 2, 4, 3).unwrap(), Some(s.clone()));
        assert_eq!(load(&p, 43, 2, 4, 3).unwrap(), None, "another key is stale");
        assert_eq!(
            load(&p, 42, 3, 4, 3).unwrap(),
            None,
            "another view count is stale"
        );
        let bytes = std::fs::read(&p).unwrap();
        std::fs::write(&p, &bytes[..bytes.len() - 10]).unwrap();
        let e = load(&p, 42, 2, 4, 3).unwrap_err().to_string();
        assert!(e.contains("shadings.bin") && e.contains("truncated"), "{e}");
        std::fs::write(&p, b"garbage").unwrap();
        assert!(
            load(&p, 42, 2, 4, 3)
                .unwrap_err()
                .to_string()
                .contains("not a fipt shading cache")
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
