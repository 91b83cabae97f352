//! The offline viewer of a `.glb` export: `viewer.html` (WebGL 2, no library) beside
//! `scene.glb` and `scene.glb.js`, the same bytes as base64 in a script, because a page opened
//! from `file://` may load a script but not fetch a file. It orbits the scene or takes the
//! exported cameras, and shows the shaded scene, base colour, roughness, metallic or emission.
//!
//! Owns: the page and the script wrapper. Must not touch: the glTF layout (`gltf`).

use super::gltf;
use super::{Pngs, Scene};
use anyhow::Result;
use fipt_core::io::write_bytes_atomic;
use std::path::Path;

/// The page (`viewer.html`): it reads `scene.glb.js` from its own folder.
pub const PAGE: &str = include_str!("viewer.html");

/// Standard base64 (RFC 4648) with padding.
pub fn base64(bytes: &[u8]) -> String {
    const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for c in bytes.chunks(3) {
        let n = (c[0] as u32) << 16
            | (*c.get(1).unwrap_or(&0) as u32) << 8
            | *c.get(2).unwrap_or(&0) as u32;
        for k in 0..4 {
            if k <= c.len() {
                out.push(A[(n >> (18 - 6 * k) & 63) as usize] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}

/// Writes `scene.glb`, `scene.glb.js` and `viewer.html` into `dir`; returns the file names.
pub fn write(s: &Scene, pngs: &Pngs, dir: &Path) -> Result<Vec<String>> {
    let mut files = gltf::write_glb(s, pngs, dir)?;
    let glb = std::fs::read(dir.join("scene.glb"))?;
    let js = format!("window.FIPT_GLB = \"{}\";\n", base64(&glb));
    write_bytes_atomic(&dir.join("scene.glb.js"), js.as_bytes())?;
    write_bytes_atomic(&dir.join("viewer.html"), PAGE.as_bytes())?;
    files.extend(["scene.glb.js".to_string(), "viewer.html".to_string()]);
    Ok(files)
}

#[cfg(test)]
mod tests {
    use super::base64;

    /// RFC 4648's test vectors.
    #[test]
    fn base64_matches_the_rfc() {
        for (i, o) in [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foob", "Zm9vYg=="),
            ("fooba", "Zm9vYmE="),
            ("foobar", "Zm9vYmFy"),
        ] {
            assert_eq!(base64(i.as_bytes()), o);
        }
    }
}
