//! Mitsuba 3 writer: `scene.xml`, `meshes/*.ply` (binary), `textures/*.png`.
//!
//! - Reflecting groups: a PLY with per-vertex UVs, flat-shaded (`face_normals`), and the stock
//!   `principled` BSDF inside `twosided`: `base_color` = a (sRGB PNG), `roughness` = σ and
//!   `metallic` = m (one-channel PNGs read raw), `specular` 0.5 (F0 = 0.04). It differs from
//!   fipt's BRDF in its masking term (separable Smith GGX against Schlick-GGX), its diffuse
//!   lobe (Burley's, with retro-reflection, against Lambert) and its dielectric Fresnel (exact,
//!   η = 1.5, against Schlick): `docs/export.md`.
//! - Emitting groups: area lights, one shape per radiance value (Mitsuba 3.9.1's scalar
//!   variant crashes on a per-face `mesh_attribute` radiance). Where the emitters reflect
//!   (`Scene::emitters_reflect`: the ground truth) they carry the reflecting groups' BSDF with
//!   their own texels, else a black one.
//!   Mitsuba's area light emits along the winding normal only: triangles fipt saw emit from
//!   their back get a copy with flipped normals; two-sided ones get that copy too, moved a
//!   hair behind the front face (coincident copies would hide one side).
//! - Sensors: one perspective sensor per exported view (`look_at` convention: columns left, up,
//!   forward), a box filter; `$spp` and `$max_depth` are parameters with defaults.
//!
//! Owns: the Mitsuba scene layout. Must not touch: the texture contents.

use super::{Pngs, Scene};
use anyhow::Result;
use fipt_bake::emitters::EmitterSides;
use fipt_core::io::write_bytes_atomic;
use std::fmt::Write as _;
use std::path::Path;

/// The reflecting BSDF: `principled` on the baked textures, both sides.
const PRINCIPLED: &str = "        <bsdf type=\"twosided\">\n            <bsdf type=\"principled\">\n                <ref name=\"base_color\" id=\"base_color\"/>\n                <ref name=\"roughness\" id=\"roughness\"/>\n                <ref name=\"metallic\" id=\"metallic\"/>\n                <float name=\"specular\" value=\"0.5\"/>\n            </bsdf>\n        </bsdf>\n";
/// The BSDF of emitters that do not reflect.
const BLACK: &str = "        <bsdf type=\"diffuse\">\n            <rgb name=\"reflectance\" value=\"0, 0, 0\"/>\n        </bsdf>\n";

/// A PLY (binary little-endian) of the triangles `tris` (`Scene::indexed`): positions and
/// optional per-vertex UVs; vertices offset by `shift` along each face's winding normal.
fn ply(s: &Scene, tris: &[u32], uv: bool, shift: f32) -> Vec<u8> {
    let m = s.indexed(tris, shift);
    let nv = m.positions.len();
    let mut h = String::from("ply\nformat binary_little_endian 1.0\ncomment written by fipt\n");
    let _ = writeln!(h, "element vertex {nv}");
    h.push_str("property float x\nproperty float y\nproperty float z\n");
    if uv {
        h.push_str("property float u\nproperty float v\n");
    }
    let _ = writeln!(h, "element face {}", m.faces.len());
    h.push_str("property list uchar int vertex_indices\n");
    h.push_str("end_header\n");
    let mut out = h.into_bytes();
    for (p, t) in m.positions.iter().zip(&m.uvs) {
        let vertex = if uv {
            &[p.x, p.y, p.z, t.x, t.y][..]
        } else {
            &[p.x, p.y, p.z][..]
        };
        for v in vertex {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    for f in &m.faces {
        out.push(3);
        for i in f {
            out.extend_from_slice(&(*i as i32).to_le_bytes());
        }
    }
    out
}

/// A file name made of the group's name: letters, digits, '-', '_' kept, the rest '_'.
fn file_stem(k: usize, name: &str) -> String {
    let clean: String = name
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect();
    format!("{k:02}_{clean}")
}

/// XML-escapes an attribute value.
fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// Writes the Mitsuba scene into `dir`; returns the file names written.
pub fn write(s: &Scene, pngs: &Pngs, dir: &Path) -> Result<Vec<String>> {
    std::fs::create_dir_all(dir.join("meshes"))?;
    std::fs::create_dir_all(dir.join("textures"))?;
    let mut files = Vec::new();
    for (name, bytes) in [
        ("base_color", &pngs.base_color),
        ("roughness", &pngs.roughness),
        ("metallic", &pngs.metallic),
    ] {
        let rel = format!("textures/{name}.png");
        write_bytes_atomic(&dir.join(&rel), bytes)?;
        files.push(rel);
    }
    let (lo, hi) = s.mesh.bounds();
    let eps = 1e-4 * (hi - lo).length().max(1e-3);
    let mut x = String::new();
    x.push_str("<scene version=\"3.0.0\">\n");
    let _ = writeln!(
        x,
        "    <!-- {}: the recovered scene; see export.json -->",
        esc(&s.generator)
    );
    x.push_str(
        "    <default name=\"spp\" value=\"64\"/>\n    <default name=\"max_depth\" value=\"7\"/>\n",
    );
    x.push_str("    <integrator type=\"path\">\n        <integer name=\"max_depth\" value=\"$max_depth\"/>\n        <integer name=\"rr_depth\" value=\"1000\"/>\n    </integrator>\n");
    for (id, file, raw) in [
        ("base_color", "textures/base_color.png", false),
        ("roughness", "textures/roughness.png", true),
        ("metallic", "textures/metallic.png", true),
    ] {
        let _ = write!(
            x,
            "    <texture type=\"bitmap\" id=\"{id}\">\n        <string name=\"filename\" value=\"{file}\"/>\n        <boolean name=\"raw\" value=\"{raw}\"/>\n        <string name=\"wrap_mode\" value=\"clamp\"/>\n    </texture>\n"
        );
    }
    let by_group = s.triangles_by_group();
    let sides: std::collections::HashMap<u32, (EmitterSides, [f32; 3])> = s
        .emitters
        .iter()
        .map(|e| (e.triangle, (e.sides, e.radiance.to_array())))
        .collect();
    for (k, g) in s.groups.iter().enumerate() {
        let tris = &by_group[k];
        if tris.is_empty() {
            continue;
        }
        let stem = file_stem(k, &g.name);
        if !g.emitter {
            let rel = format!("meshes/{stem}.ply");
            write_bytes_atomic(&dir.join(&rel), &ply(s, tris, true, 0.0))?;
            files.push(rel.clone());
            let _ = write!(
                x,
                "    <shape type=\"ply\" id=\"{}\">\n        <string name=\"filename\" value=\"{rel}\"/>\n        <boolean name=\"face_normals\" value=\"true\"/>\n{}    </shape>\n",
                esc(&g.name),
                PRINCIPLED
            );
            continue;
        }
        // Emitters: the front copies (front or both sides), then the flipped ones.
        let front: Vec<u32> = tris
            .iter()
            .copied()
            .filter(|t| sides.get(t).is_none_or(|s| s.0 != EmitterSides::Back))
            .collect();
        let back_only: Vec<u32> = tris
            .iter()
            .copied()
            .filter(|t| sides.get(t).is_some_and(|s| s.0 == EmitterSides::Back))
            .collect();
        let both: Vec<u32> = tris
            .iter()
            .copied()
            .filter(|t| sides.get(t).is_some_and(|s| s.0 == EmitterSides::Both))
            .collect();
        // One shape per radiance value (Mitsuba's area light takes one radiance per shape).
        let mut shape = 0;
        for (suffix, ts, flip, shift) in [
            ("", &front, false, 0.0),
            ("_back", &back_only, true, 0.0),
            ("_both", &both, true, -eps),
        ] {
            let mut by_radiance: std::collections::BTreeMap<[u32; 3], Vec<u32>> =
                Default::default();
            for t in ts {
                let r = sides.get(t).map_or([0.0; 3], |s| s.1);
                by_radiance.entry(r.map(f32::to_bits)).or_default().push(*t);
            }
            for (r, tris) in by_radiance {
                let r = r.map(f32::from_bits);
                let rel = format!("meshes/{stem}{suffix}_{shape:03}.ply");
                write_bytes_atomic(&dir.join(&rel), &ply(s, &tris, s.emitters_reflect, shift))?;
                files.push(rel.clone());
                let _ = write!(
                    x,
                    "    <shape type=\"ply\" id=\"{}{suffix}_{shape:03}\">\n        <string name=\"filename\" value=\"{rel}\"/>\n        <boolean name=\"face_normals\" value=\"true\"/>\n        <boolean name=\"flip_normals\" value=\"{flip}\"/>\n        <emitter type=\"area\">\n            <rgb name=\"radiance\" value=\"{}, {}, {}\"/>\n        </emitter>\n{}    </shape>\n",
                    esc(&g.name),
                    r[0],
                    r[1],
                    r[2],
                    if s.emitters_reflect {
                        PRINCIPLED
                    } else {
                        BLACK
                    }
                );
                shape += 1;
            }
        }
    }
    for (name, c) in s.cameras {
        let m = c.to_fipt_c2w();
        let rows: Vec<String> = m
            .iter()
            .map(|r| format!("{} {} {} {}", r[0], r[1], r[2], r[3]))
            .collect();
        let fov = (2.0 * (0.5 * c.width as f64 / c.fx).atan()).to_degrees();
        let _ = write!(
            x,
            "    <sensor type=\"perspective\" id=\"{}\">\n        <float name=\"fov\" value=\"{fov}\"/>\n        <string name=\"fov_axis\" value=\"x\"/>\n        <float name=\"near_clip\" value=\"0.01\"/>\n        <float name=\"far_clip\" value=\"10000\"/>\n        <transform name=\"to_world\">\n            <matrix value=\"{}\"/>\n        </transform>\n        <sampler type=\"independent\">\n            <integer name=\"sample_count\" value=\"$spp\"/>\n        </sampler>\n        <film type=\"hdrfilm\">\n            <integer name=\"width\" value=\"{}\"/>\n            <integer name=\"height\" value=\"{}\"/>\n            <string name=\"pixel_format\" value=\"rgb\"/>\n            <rfilter type=\"box\"/>\n        </film>\n    </sensor>\n",
            esc(name),
            rows.join("  "),
            c.width,
            c.height
        );
    }
    x.push_str("</scene>\n");
    write_bytes_atomic(&dir.join("scene.xml"), x.as_bytes())?;
    files.push("scene.xml".into());
    Ok(files)
}
