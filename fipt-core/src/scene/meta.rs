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
    pub fn load(path: &Path) -> Result<SceneMeta> {
        let text = read_text(path)?;
        serde_json::from_str(&text).map_err(|e| FileError::new(path, format!("bad JSON: {e}")))
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
