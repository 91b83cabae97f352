//! The true materials of a generated scene, from its `scene_meta.json`: a constant base colour
//! or a planar-world texture per part, constant σ and m (the layout of `shared/scenes`):
//! `u = dot(p − origin, axis_u)/size_u`, `v = dot(p − origin, axis_v)/size_v`,
//! `col = floor(frac(u)·width)`, `row = floor(frac(v)·height)`, nearest, repeat.
//!
//! Owns: the part → material table and texture lookup. Must not touch: light transport.

use super::{MaterialSource, SurfaceMaterial};
use fipt_core::io::FileError;
use fipt_core::scene::Image;
use fipt_core::scene::meta::SceneMeta;
use glam::Vec3;
use rayon::prelude::*;
use serde::Deserialize;
use std::path::Path;

/// A `planar-world` texture as `scene_meta.json` describes it.
#[derive(Clone, Debug, Deserialize)]
struct TextureSpec {
    file: String,
    mapping: String,
    origin: [f32; 3],
    axis_u: [f32; 3],
    axis_v: [f32; 3],
    size_u: f32,
    size_v: f32,
}

#[derive(Clone, Debug)]
struct Texture {
    image: Image,
    origin: Vec3,
    axis_u: Vec3,
    axis_v: Vec3,
    size_u: f32,
    size_v: f32,
}

impl Texture {
    fn lookup(&self, p: Vec3) -> Vec3 {
        let u = (p - self.origin).dot(self.axis_u) / self.size_u;
        let v = (p - self.origin).dot(self.axis_v) / self.size_v;
        let (w, h) = (self.image.width, self.image.height);
        let col = ((u - u.floor()) * w as f32).floor() as usize;
        let row = ((v - v.floor()) * h as f32).floor() as usize;
        Vec3::from(self.image.rgb(row.min(h - 1) * w + col.min(w - 1)))
    }
}

#[derive(Clone, Debug)]
struct PartMat {
    base: Result<Vec3, Texture>,
    roughness: f32,
    metallic: f32,
}

/// The ground-truth materials of every triangle of a scene.
#[derive(Clone, Debug)]
pub struct TrueMaterials {
    parts: Vec<PartMat>,
    /// Index into `parts` per triangle.
    tri_part: Vec<u32>,
    /// Triangles from this index on (added geometry: see `Overlay`) are black.
    extra_from: usize,
}

impl TrueMaterials {
    /// Reads the materials of `meta` (from `meta_path`, textures relative to `scene_dir`) for a
    /// mesh of `num_triangles`. Errors name the file: a part range that leaves triangles
    /// uncovered or overlaps, a missing or malformed texture.
    pub fn load(
        scene_dir: &Path,
        meta_path: &Path,
        meta: &SceneMeta,
        num_triangles: usize,
    ) -> Result<Self, FileError> {
        let mut tri_part = vec![u32::MAX; num_triangles];
        let mut parts = Vec::with_capacity(meta.parts.len());
        for (k, p) in meta.parts.iter().enumerate() {
            let [start, end] = p.triangles;
            if start > end || end > num_triangles {
                return Err(FileError::new(
                    meta_path,
                    format!(
                        "part '{}': triangles [{start}, {end}) outside the mesh's {num_triangles}",
                        p.name
                    ),
                ));
            }
            for t in &mut tri_part[start..end] {
                if *t != u32::MAX {
                    return Err(FileError::new(
                        meta_path,
                        format!("part '{}' overlaps another part's triangles", p.name),
                    ));
                }
                *t = k as u32;
            }
            let m = &p.material;
            let base = match (&m.texture, m.base_color) {
                (Some(spec), _) if !spec.is_null() => {
                    let spec: TextureSpec = serde_json::from_value(spec.clone()).map_err(|e| {
                        FileError::new(meta_path, format!("part '{}': texture: {e}", p.name))
                    })?;
                    if spec.mapping != "planar-world" {
                        return Err(FileError::new(
                            meta_path,
                            format!(
                                "part '{}': texture mapping '{}' (only planar-world)",
                                p.name, spec.mapping
                            ),
                        ));
                    }
                    if !(spec.size_u > 0.0 && spec.size_v > 0.0) {
                        return Err(FileError::new(
                            meta_path,
                            format!("part '{}': texture sizes must be > 0", p.name),
                        ));
                    }
                    let image = Image::read_exr(&scene_dir.join(&spec.file))?;
                    if image.channels < 3 || image.num_pixels() == 0 {
                        return Err(FileError::new(
                            scene_dir.join(&spec.file),
                            "a texture needs RGB pixels",
                        ));
                    }
                    Err(Texture {
                        image,
                        origin: Vec3::from(spec.origin),
                        axis_u: Vec3::from(spec.axis_u),
                        axis_v: Vec3::from(spec.axis_v),
                        size_u: spec.size_u,
                        size_v: spec.size_v,
                    })
                }
                (_, Some(c)) => Ok(Vec3::from(c)),
                (_, None) => {
                    return Err(FileError::new(
                        meta_path,
                        format!("part '{}': neither base_color nor texture", p.name),
                    ));
                }
            };
            parts.push(PartMat {
                base,
                roughness: m.roughness,
                metallic: m.metallic,
            });
        }
        if let Some(t) = tri_part.iter().position(|&p| p == u32::MAX) {
            return Err(FileError::new(
                meta_path,
                format!("triangle {t} of {num_triangles} belongs to no part"),
            ));
        }
        Ok(Self {
            parts,
            tri_part,
            extra_from: num_triangles,
        })
    }

    /// The material at one point.
    pub fn at(&self, p: Vec3, tri: u32) -> SurfaceMaterial {
        let t = tri as usize;
        if t >= self.extra_from {
            return SurfaceMaterial::BLACK;
        }
        let part = &self.parts[self.tri_part[t] as usize];
        SurfaceMaterial {
            base_color: match &part.base {
                Ok(c) => *c,
                Err(tex) => tex.lookup(p),
            },
            roughness: part.roughness,
            metallic: part.metallic,
        }
    }
}

impl MaterialSource for TrueMaterials {
    fn query(&self, points: &[Vec3], tris: &[u32], out: &mut Vec<SurfaceMaterial>) {
        out.clear();
        points
            .par_iter()
            .zip(tris)
            .with_min_len(1024)
            .map(|(&p, &t)| self.at(p, t))
            .collect_into_vec(out);
    }
}
