//! `scene_meta.json`: the optional ground truth of generated scenes (parts, materials, emitters),
//! used for scoring and tests, never for training.
//!
//! Owns: the serde types of `scene_meta.json` and `relight.json`. Must not touch: loaders of
//! anything else.

use crate::io::{FileError, Result, read_text};
use serde::{Deserialize, Serialize};
use std::path::Path;

#[derive(Clone, Debug, Serialize, Deserialize, Default)]
pub struct SceneMeta {
    #[serde(default)]
    pub scene: String,
    #[serde(default)]
    pub semantic_labels: Vec<String>,
    pub parts: Vec<Part>,
    #[serde(default)]
    pub resolution: Option<[usize; 2]>,
    #[serde(default)]
    pub camera_angle_x: Option<f64>,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Part {
    pub id: usize,
    pub name: String,
    #[serde(default)]
    pub semantic: String,
    #[serde(default)]
    pub semantic_id: usize,
    /// Triangle range `[start, end)` into `scene.obj`.
    pub triangles: [usize; 2],
    #[serde(default)]
    pub area: f64,
    pub material: PartMaterial,
    #[serde(default)]
    pub emission: Option<PartEmission>,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct PartMaterial {
    pub base_color: Option<[f32; 3]>,
    pub roughness: f32,
    pub metallic: f32,
    #[serde(default)]
    pub texture: Option<serde_json::Value>,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct PartEmission {
    pub radiance: [f32; 3],
    #[serde(default)]
    pub side: String,
}

impl SceneMeta {
    /// Reads `scene_meta.json`: every number in its range (`crate::ranges`), every part's
    /// triangle range ordered (`Dataset::load` checks it against the mesh).
    pub fn load(path: &Path) -> Result<SceneMeta> {
        let text = read_text(path)?;
        let v: serde_json::Value = serde_json::from_str(&text)
            .map_err(|e| FileError::new(path, format!("bad JSON: {e}")))?;
        crate::ranges::check(crate::ranges::Kind::SceneMeta, &v, path)?;
        let m: SceneMeta = serde_json::from_value(v)
            .map_err(|e| FileError::new(path, format!("bad JSON: {e}")))?;
        if let Some((k, p)) = m
            .parts
            .iter()
            .enumerate()
            .find(|(_, p)| p.triangles[0] > p.triangles[1])
        {
            return Err(FileError::new(
                path,
                format!(
                    "parts[{k}].triangles: [{}, {}] is not a range (start > end)",
                    p.triangles[0], p.triangles[1]
                ),
            ));
        }
        Ok(m)
    }

    /// Ground-truth emitted radiance per triangle (0 for non-emitters).
    pub fn triangle_emission(&self, num_triangles: usize) -> Vec<[f32; 3]> {
        let mut out = vec![[0.0; 3]; num_triangles];
        for p in &self.parts {
            if let Some(e) = &p.emission {
                let end = p.triangles[1].min(num_triangles);
                let start = p.triangles[0].min(end);
                out[start..end].fill(e.radiance);
            }
        }
        out
    }

    /// Part id per triangle (`usize::MAX` where no part covers it).
    pub fn triangle_part(&self, num_triangles: usize) -> Vec<usize> {
        let mut out = vec![usize::MAX; num_triangles];
        for p in &self.parts {
            let end = p.triangles[1].min(num_triangles);
            let start = p.triangles[0].min(end);
            out[start..end].fill(p.id);
        }
        out
    }
}

/// `relight.json`: emitters switched off by part name and new emitters added.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Relight {
    /// Emitters switched off: emitter parts of `scene_meta.json` by name, or `"all"`.
    #[serde(default)]
    pub emitters_off: Vec<String>,
    /// Emitters rescaled (radiance × factor), named as in `emitters_off`.
    #[serde(default)]
    pub emitters_scale: std::collections::BTreeMap<String, f32>,
    #[serde(default)]
    pub new_emitter: Option<NewEmitter>,
    #[serde(default)]
    pub new_emitters: Vec<NewEmitter>,
}

/// A new emitting mesh: one-sided towards its triangles' winding normal.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct NewEmitter {
    #[serde(default)]
    pub name: String,
    pub vertices: Vec<[f32; 3]>,
    pub triangles: Vec<[u32; 3]>,
    pub radiance: [f32; 3],
    /// Its reflectance (black when absent).
    #[serde(default)]
    pub bsdf: Option<RelightBsdf>,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct RelightBsdf {
    pub base_color: [f32; 3],
    pub roughness: f32,
    pub metallic: f32,
}

impl Relight {
    /// Reads and checks `relight.json`: every switched-off or rescaled name is `"all"` or an
    /// emitter part of the scene's `meta` (without one, only `"all"`), scale factors are finite
    /// and ≥ 0, every new triangle indexes its vertices, radiances are finite and ≥ 0.
    pub fn load(path: &Path, meta: Option<&SceneMeta>) -> Result<Relight> {
        let text = read_text(path)?;
        let v: serde_json::Value = serde_json::from_str(&text)
            .map_err(|e| FileError::new(path, format!("bad JSON: {e}")))?;
        crate::ranges::check(crate::ranges::Kind::Relight, &v, path)?;
        let r: Relight = serde_json::from_value(v)
            .map_err(|e| FileError::new(path, format!("bad JSON: {e}")))?;
        for (key, name) in r
            .emitters_off
            .iter()
            .map(|n| ("emitters_off", n))
            .chain(r.emitters_scale.keys().map(|n| ("emitters_scale", n)))
        {
            if name == "all" {
                continue;
            }
            match meta {
                Some(meta) => {
                    if !meta
                        .parts
                        .iter()
                        .any(|p| &p.name == name && p.emission.is_some())
                    {
                        return Err(FileError::new(
                            path,
                            format!("{key}: '{name}' is not an emitter part of scene_meta.json"),
                        ));
                    }
                }
                None => {
                    return Err(FileError::new(
                        path,
                        format!(
                            "{key}: '{name}': naming emitters needs the scene's scene_meta.json (give --scene); \"all\" needs none"
                        ),
                    ));
                }
            }
        }
        if let Some((n, f)) = r
            .emitters_scale
            .iter()
            .find(|(_, f)| !f.is_finite() || **f < 0.0)
        {
            return Err(FileError::new(
                path,
                format!("emitters_scale: '{n}': factor {f} is not finite and ≥ 0"),
            ));
        }
        for e in r.added() {
            let n = e.vertices.len() as u32;
            if let Some(t) = e.triangles.iter().find(|t| t.iter().any(|&i| i >= n)) {
                return Err(FileError::new(
                    path,
                    format!(
                        "new emitter '{}': triangle {t:?} indexes past its {n} vertices",
                        e.name
                    ),
                ));
            }
            let area = |t: &[u32; 3]| {
                let p = t.map(|i| glam::Vec3::from(e.vertices[i as usize]));
                (p[1] - p[0]).cross(p[2] - p[0]).length()
            };
            if let Some(t) = e.triangles.iter().find(|t| area(t) <= 0.0) {
                return Err(FileError::new(
                    path,
                    format!("new emitter '{}': triangle {t:?} has no area", e.name),
                ));
            }
            if e.radiance.iter().any(|c| !c.is_finite() || *c < 0.0)
                || e.vertices.iter().flatten().any(|c| !c.is_finite())
            {
                return Err(FileError::new(
                    path,
                    format!("new emitter '{}': non-finite or negative values", e.name),
                ));
            }
        }
        Ok(r)
    }

    /// The radiance factor of an emitter on a triangle of part `part` (None: no part known):
    /// 0 when switched off (by name or `"all"`), else the product of its scale factors.
    pub fn factor(&self, part: Option<&str>) -> f32 {
        let named = |n: &String| n == "all" || Some(n.as_str()) == part;
        if self.emitters_off.iter().any(named) {
            return 0.0;
        }
        self.emitters_scale
            .iter()
            .filter(|(n, _)| named(n))
            .map(|(_, f)| *f)
            .product()
    }

    /// Every added emitter (`new_emitter` and `new_emitters`).
    pub fn added(&self) -> impl Iterator<Item = &NewEmitter> {
        self.new_emitter.iter().chain(&self.new_emitters)
    }
}
