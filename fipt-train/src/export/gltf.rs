//! glTF 2.0 writer: `.glb` (one file) or `.gltf` + `scene.bin` + `textures/*.png`.
//!
//! - One mesh, one primitive per material group; vertices are split per chart (each carries
//!   its chart's UV); no normals, so viewers shade flat, as fipt does.
//! - Materials: core metallic-roughness. `roughness` = σ (both parameterise GGX by α = r²),
//!   `metallic` = m, `baseColor` = a; emitters: black base colour, the emission texture scaled
//!   by `KHR_materials_emissive_strength`. All materials are double-sided.
//! - Cameras: one node per val view, a perspective camera looking down its local −Z.
//!
//! Owns: the glTF layout and GLB packing. Must not touch: the texture contents (`bake`).

use super::{Pngs, Scene};
use anyhow::Result;
use fipt_core::io::write_bytes_atomic;
use serde_json::{Value, json};
use std::path::Path;

/// glTF component and target codes.
const FLOAT: u32 = 5126;
const UNSIGNED_INT: u32 = 5125;
const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;
const LINEAR: u32 = 9729;
const CLAMP_TO_EDGE: u32 = 33071;

/// The geometry and textures as one binary buffer plus the glTF JSON that describes it.
struct Packed {
    json: Value,
    bin: Vec<u8>,
}

fn align4(v: &mut Vec<u8>) {
    while !v.len().is_multiple_of(4) {
        v.push(0);
    }
}

/// Builds the document. `embed`: images go into the buffer (GLB); else they are referenced as
/// `textures/<name>.png` and `buffer_uri` names the buffer file.
fn pack(s: &Scene, pngs: &Pngs, embed: bool, buffer_uri: Option<&str>) -> Packed {
    // Per group: its indexed triangles, appended to shared position, UV and index arrays.
    let mut positions: Vec<f32> = Vec::new();
    let mut uvs: Vec<f32> = Vec::new();
    let mut indices: Vec<u32> = Vec::new();
    let mut prims = Vec::new(); // (group, first vertex, vertex count, first index, index count, min, max)
    for (g, tris) in s.triangles_by_group().iter().enumerate() {
        let m = s.indexed(tris, 0.0);
        let (v0, i0) = (positions.len() / 3, indices.len());
        let mut min = [f32::INFINITY; 3];
        let mut max = [f32::NEG_INFINITY; 3];
        for p in &m.positions {
            for (c, x) in p.to_array().into_iter().enumerate() {
                min[c] = min[c].min(x);
                max[c] = max[c].max(x);
            }
            positions.extend(p.to_array());
        }
        uvs.extend(m.uvs.iter().flat_map(|u| u.to_array()));
        indices.extend(m.faces.iter().flatten());
        prims.push((g, v0, m.positions.len(), i0, indices.len() - i0, min, max));
    }
    let mut bin: Vec<u8> = Vec::new();
    let mut views = Vec::new();
    // Vertex views are shared by several accessors, so they state their stride.
    let mut push_view = |bin: &mut Vec<u8>, bytes: &[u8], target: Option<u32>, stride: usize| {
        align4(bin);
        let offset = bin.len();
        bin.extend_from_slice(bytes);
        let mut v = json!({"buffer": 0, "byteOffset": offset, "byteLength": bytes.len()});
        if let Some(t) = target {
            v["target"] = json!(t);
        }
        if stride > 0 {
            v["byteStride"] = json!(stride);
        }
        views.push(v);
        views.len() - 1
    };
    let pos_view = push_view(
        &mut bin,
        bytemuck::cast_slice(&positions),
        Some(ARRAY_BUFFER),
        12,
    );
    let uv_view = push_view(&mut bin, bytemuck::cast_slice(&uvs), Some(ARRAY_BUFFER), 8);
    let idx_view = push_view(
        &mut bin,
        bytemuck::cast_slice(&indices),
        Some(ELEMENT_ARRAY_BUFFER),
        0,
    );
    let has_emission = s.groups.iter().any(|g| g.emitter);
    let mut image_list: Vec<(&str, &[u8])> = vec![
        ("base_color", &pngs.base_color),
        ("metallic_roughness", &pngs.metallic_roughness),
    ];
    if has_emission {
        image_list.push(("emission", &pngs.emission));
    }
    let images: Vec<Value> = image_list
        .iter()
        .map(|(name, bytes)| {
            if embed {
                let v = push_view(&mut bin, bytes, None, 0);
                json!({"name": name, "bufferView": v, "mimeType": "image/png"})
            } else {
                json!({"name": name, "uri": format!("textures/{name}.png")})
            }
        })
        .collect();
    align4(&mut bin);
    let mut accessors = Vec::new();
    let mut primitives = Vec::new();
    for &(g, v0, nv, i0, ni, min, max) in &prims {
        if ni == 0 {
            continue;
        }
        accessors.push(
            json!({"bufferView": pos_view, "byteOffset": v0 * 12, "componentType": FLOAT,
            "count": nv, "type": "VEC3", "min": min, "max": max}),
        );
        accessors.push(
            json!({"bufferView": uv_view, "byteOffset": v0 * 8, "componentType": FLOAT,
            "count": nv, "type": "VEC2"}),
        );
        accessors.push(json!({"bufferView": idx_view, "byteOffset": i0 * 4,
            "componentType": UNSIGNED_INT, "count": ni, "type": "SCALAR"}));
        let a = accessors.len() - 3;
        primitives.push(json!({"attributes": {"POSITION": a, "TEXCOORD_0": a + 1},
            "indices": a + 2, "material": g, "mode": 4}));
    }
    let materials: Vec<Value> = s
        .groups
        .iter()
        .map(|g| {
            if g.emitter {
                json!({"name": g.name, "doubleSided": true,
                    "pbrMetallicRoughness": {"baseColorFactor": [0.0, 0.0, 0.0, 1.0],
                        "metallicFactor": 0.0, "roughnessFactor": 1.0},
                    "emissiveTexture": {"index": 2},
                    "emissiveFactor": [1.0, 1.0, 1.0],
                    "extensions": {"KHR_materials_emissive_strength":
                        {"emissiveStrength": g.strength}}})
            } else {
                json!({"name": g.name, "doubleSided": true,
                    "pbrMetallicRoughness": {"baseColorTexture": {"index": 0},
                        "metallicRoughnessTexture": {"index": 1},
                        "metallicFactor": 1.0, "roughnessFactor": 1.0}})
            }
        })
        .collect();
    let textures: Vec<Value> = (0..images.len())
        .map(|k| json!({"sampler": 0, "source": k}))
        .collect();
    let mut nodes = vec![json!({"name": "scene", "mesh": 0})];
    let mut cameras = Vec::new();
    for (name, c) in s.cameras {
        let m = c.to_opengl_c2w();
        // Column-major.
        let matrix: Vec<f64> = (0..4).flat_map(|j| (0..4).map(move |i| m[i][j])).collect();
        let yfov = 2.0 * (0.5 * c.height as f64 / c.fy).atan();
        cameras.push(json!({"name": name, "type": "perspective", "perspective": {
            "yfov": yfov, "aspectRatio": c.width as f64 / c.height as f64, "znear": 0.01}}));
        nodes.push(json!({"name": name, "camera": cameras.len() - 1, "matrix": matrix}));
    }
    let mut buffer = json!({"byteLength": bin.len()});
    if let Some(uri) = buffer_uri {
        buffer["uri"] = json!(uri);
    }
    let mut doc = json!({
        "asset": {"version": "2.0", "generator": s.generator},
        "scene": 0,
        "scenes": [{"name": "fipt", "nodes": (0..nodes.len()).collect::<Vec<_>>()}],
        "nodes": nodes,
        "meshes": [{"name": "scene", "primitives": primitives}],
        "materials": materials,
        "textures": textures,
        "images": images,
        "samplers": [{"magFilter": LINEAR, "minFilter": LINEAR,
            "wrapS": CLAMP_TO_EDGE, "wrapT": CLAMP_TO_EDGE}],
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [buffer],
    });
    if !cameras.is_empty() {
        doc["cameras"] = json!(cameras);
    }
    if has_emission {
        doc["extensionsUsed"] = json!(["KHR_materials_emissive_strength"]);
    }
    Packed { json: doc, bin }
}

/// GLB container: the 12-byte header, the JSON chunk (space-padded) and the binary chunk
/// (zero-padded), each length a multiple of 4.
fn glb_bytes(json: &Value, bin: &[u8]) -> Vec<u8> {
    let mut j = serde_json::to_vec(json).expect("JSON");
    while !j.len().is_multiple_of(4) {
        j.push(b' ');
    }
    let mut b = bin.to_vec();
    align4(&mut b);
    let total = 12 + 8 + j.len() + 8 + b.len();
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(j.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&j);
    out.extend_from_slice(&(b.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&b);
    out
}

/// Writes `dir/scene.glb`; returns the file names written.
pub fn write_glb(s: &Scene, pngs: &Pngs, dir: &Path) -> Result<Vec<String>> {
    let p = pack(s, pngs, true, None);
    write_bytes_atomic(&dir.join("scene.glb"), &glb_bytes(&p.json, &p.bin))?;
    Ok(vec!["scene.glb".into()])
}

/// Writes `dir/scene.gltf`, `dir/scene.bin` and `dir/textures/*.png`; returns the file names.
pub fn write_gltf(s: &Scene, pngs: &Pngs, dir: &Path) -> Result<Vec<String>> {
    let p = pack(s, pngs, false, Some("scene.bin"));
    std::fs::create_dir_all(dir.join("textures"))?;
    let mut files = vec!["scene.gltf".to_string(), "scene.bin".to_string()];
    write_bytes_atomic(&dir.join("scene.bin"), &p.bin)?;
    for img in p.json["images"].as_array().into_iter().flatten() {
        let name = img["name"].as_str().unwrap_or_default();
        let bytes: &[u8] = match name {
            "base_color" => &pngs.base_color,
            "metallic_roughness" => &pngs.metallic_roughness,
            _ => &pngs.emission,
        };
        let rel = format!("textures/{name}.png");
        write_bytes_atomic(&dir.join(&rel), bytes)?;
        files.push(rel);
    }
    write_bytes_atomic(
        &dir.join("scene.gltf"),
        serde_json::to_string_pretty(&p.json)?.as_bytes(),
    )?;
    Ok(files)
}

/// The parsed JSON chunk of a GLB file (for tests and the viewer's checks).
pub fn glb_json(bytes: &[u8]) -> Option<Value> {
    if bytes.len() < 20 || &bytes[0..4] != b"glTF" || &bytes[16..20] != b"JSON" {
        return None;
    }
    let n = u32::from_le_bytes(bytes[12..16].try_into().ok()?) as usize;
    serde_json::from_slice(bytes.get(20..20 + n)?).ok()
}
