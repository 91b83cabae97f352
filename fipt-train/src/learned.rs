//! The learned model as a material source for the path tracer: `FiptModel` inference (burn)
//! behind fipt-bake's batched `MaterialSource` query, one call per wavefront.
//!
//! Owns: the adapter. Must not touch: light transport, the model's maths.

use fipt_bake::materials::{MaterialSource, SurfaceMaterial};
use fipt_core::model::FiptModel;
use glam::Vec3;
use std::sync::Mutex;

/// The fitted material field at hit points. Triangles in `black` (e.g. the extracted
/// emitters, as the reference's relighting does) reflect nothing.
pub struct LearnedMaterials {
    model: Mutex<FiptModel>,
    black: Vec<bool>,
}

impl LearnedMaterials {
    /// `black_triangles` of a mesh of `num_triangles` get a black BRDF.
    pub fn new(model: FiptModel, num_triangles: usize, black_triangles: &[u32]) -> Self {
        let mut black = vec![false; num_triangles];
        for &t in black_triangles {
            if let Some(b) = black.get_mut(t as usize) {
                *b = true;
            }
        }
        Self {
            model: Mutex::new(model),
            black,
        }
    }
}

impl LearnedMaterials {
    /// Per triangle, whether it is black.
    pub fn black(&self) -> &[bool] {
        &self.black
    }
}

impl MaterialSource for LearnedMaterials {
    fn query(&self, points: &[Vec3], tris: &[u32], out: &mut Vec<SurfaceMaterial>) {
        out.clear();
        if points.is_empty() {
            return;
        }
        let m = self
            .model
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .material_world(points, tris);
        out.extend(tris.iter().enumerate().map(|(i, &t)| {
            if self.black.get(t as usize).copied().unwrap_or(false) {
                SurfaceMaterial::BLACK
            } else {
                SurfaceMaterial {
                    base_color: Vec3::from_slice(&m.a[3 * i..3 * i + 3]),
                    roughness: m.sigma[i],
                    metallic: m.metallic[i],
                }
            }
        }));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fipt_core::model::{HashGridConfig, MaterialFieldConfig, TrainConfig, Trainer};
    use fipt_core::scene::SceneBox;

    /// The adapter returns the model's own inference, in order, and black on listed triangles.
    #[test]
    fn queries_the_model_in_order() {
        let cfg = TrainConfig::new().with_material(
            MaterialFieldConfig::new()
                .with_grid(HashGridConfig::new().with_levels(4).with_log2_table(10)),
        );
        let sb = SceneBox {
            min: -1.0,
            max: 3.0,
        };
        let tr = Trainer::new(cfg, sb, &burn::tensor::Device::flex(), 3);
        let pts: Vec<Vec3> = (0..50)
            .map(|i| Vec3::new(0.05 * i as f32, 1.0, 2.0 - 0.03 * i as f32))
            .collect();
        let tris: Vec<u32> = (0..50).map(|i| i % 5).collect();
        let direct = tr.model.material_world(&pts, &tris);
        let src = LearnedMaterials::new(tr.model, 5, &[3]);
        let mut out = Vec::new();
        src.query(&pts, &tris, &mut out);
        assert_eq!(out.len(), 50);
        for (i, m) in out.iter().enumerate() {
            if tris[i] == 3 {
                assert_eq!(*m, SurfaceMaterial::BLACK);
            } else {
                assert_eq!(m.base_color, Vec3::from_slice(&direct.a[3 * i..3 * i + 3]));
                assert_eq!(m.roughness, direct.sigma[i]);
                assert_eq!(m.metallic, direct.metallic[i]);
                assert!(m.roughness >= 0.02 && m.roughness <= 1.0);
            }
        }
    }
}
