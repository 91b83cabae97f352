//! Object insertion (`render --insert FILE`): objects placed in a recovered room, each an OBJ
//! file or a built-in shape, with a FIPT material or an emission.
//!
//! ```json
//! {"objects": [
//!   {"name": "ball", "shape": "sphere", "scale": 0.2, "translate": [2.5, 0.2, 2.0],
//!    "material": {"base_color": [0.8, 0.1, 0.1], "roughness": 0.3, "metallic": 0.0}},
//!   {"name": "statue", "obj": "statue.obj", "scale": [0.5, 0.5, 0.5], "rotate_deg": [0, 30, 0],
//!    "translate": [1, 0, 1], "material": {"base_color": [0.9, 0.9, 0.9], "roughness": 0.1,
//!    "metallic": 1.0}},
//!   {"name": "bulb", "shape": "cube", "scale": 0.05, "translate": [2, 2, 2],
//!    "emission": [20, 18, 15]}
//! ]}
//! ```
//! The placement is x ↦ translate + R(rotate_deg: about x, then y, then z)·(scale ⊙ x), shapes
//! are the unit sphere and the cube [-1, 1]³ (outward normals); OBJ paths are relative to the
//! file. An emitter emits from the front of its triangles and reflects nothing.
//!
//! Owns: the file format and the placed geometry. Must not touch: rendering.

use super::Mesh;
use super::procedural::PartMesh;
use crate::io::{FileError, Result, read_text};
use glam::{Mat3, Vec3};
use serde::Deserialize;
use std::path::Path;

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct InsertFile {
    objects: Vec<ObjectSpec>,
}

#[derive(Clone, Debug, Deserialize)]
#[serde(untagged)]
enum Scale {
    Uniform(f32),
    Axes([f32; 3]),
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ObjectSpec {
    #[serde(default)]
    name: String,
    #[serde(default)]
    obj: Option<String>,
    #[serde(default)]
    shape: Option<String>,
    #[serde(default)]
    scale: Option<Scale>,
    #[serde(default)]
    rotate_deg: [f32; 3],
    #[serde(default)]
    translate: [f32; 3],
    #[serde(default)]
    material: Option<InsertMaterial>,
    #[serde(default)]
    emission: Option<[f32; 3]>,
}

/// FIPT BRDF parameters of an inserted object.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct InsertMaterial {
    pub base_color: [f32; 3],
    pub roughness: f32,
    pub metallic: f32,
}

/// One placed object.
#[derive(Clone, Debug)]
pub struct Inserted {
    pub name: String,
    /// World-space geometry.
    pub mesh: Mesh,
    /// Its reflectance (black for an emitter).
    pub material: Option<InsertMaterial>,
    pub emission: Option<[f32; 3]>,
}

/// Reads an insertion file; every error names the file and the object.
pub fn load_insert(path: &Path) -> Result<Vec<Inserted>> {
    let text = read_text(path)?;
    let v: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| FileError::new(path, format!("bad JSON: {e}")))?;
    crate::ranges::check(crate::ranges::Kind::Insert, &v, path)?;
    let f: InsertFile =
        serde_json::from_value(v).map_err(|e| FileError::new(path, format!("bad JSON: {e}")))?;
    if f.objects.is_empty() {
        return Err(FileError::new(path, "no objects"));
    }
    let dir = path.parent().unwrap_or(Path::new("."));
    f.objects
        .iter()
        .enumerate()
        .map(|(k, o)| {
            let name = if o.name.is_empty() {
                format!("object {k}")
            } else {
                o.name.clone()
            };
            let err = |msg: String| FileError::new(path, format!("{name}: {msg}"));
            let local = match (&o.obj, o.shape.as_deref()) {
                (Some(obj), None) => {
                    Mesh::load_obj(&dir.join(obj)).map_err(|e| err(e.to_string()))?
                }
                (None, Some("sphere")) => {
                    let mut pm = PartMesh::default();
                    pm.sphere("sphere", Vec3::ZERO, 1.0, 24, 48);
                    pm.mesh
                }
                (None, Some("cube")) => {
                    let mut pm = PartMesh::default();
                    pm.cuboid("cube", Vec3::splat(-1.0), Vec3::ONE, 1);
                    pm.mesh
                }
                (None, Some(s)) => {
                    return Err(err(format!("unknown shape '{s}' (sphere or cube)")));
                }
                _ => return Err(err("give exactly one of \"obj\" and \"shape\"".into())),
            };
            let scale = match o.scale {
                None => Vec3::ONE,
                Some(Scale::Uniform(s)) => Vec3::splat(s),
                Some(Scale::Axes(a)) => Vec3::from(a),
            };
            let finite = scale.is_finite()
                && o.rotate_deg
                    .iter()
                    .chain(&o.translate)
                    .all(|x| x.is_finite());
            if !finite || scale.min_element() <= 0.0 {
                return Err(err("scale must be > 0 and the placement finite".into()));
            }
            match (&o.material, &o.emission) {
                (Some(m), None) => {
                    let ok = m.base_color.iter().all(|c| (0.0..=1.0).contains(c))
                        && (0.0..=1.0).contains(&m.roughness)
                        && (0.0..=1.0).contains(&m.metallic);
                    if !ok {
                        return Err(err("material values must lie in [0, 1]".into()));
                    }
                }
                (None, Some(e)) => {
                    if !e.iter().all(|c| c.is_finite() && *c >= 0.0) {
                        return Err(err("emission must be finite and ≥ 0".into()));
                    }
                }
                _ => {
                    return Err(err(
                        "give exactly one of \"material\" and \"emission\"".into()
                    ));
                }
            }
            let r = o.rotate_deg.map(f32::to_radians);
            let rot = Mat3::from_rotation_z(r[2])
                * Mat3::from_rotation_y(r[1])
                * Mat3::from_rotation_x(r[0]);
            let t = Vec3::from(o.translate);
            let mut mesh = local;
            for v in &mut mesh.vertices {
                *v = t + rot * (scale * *v);
            }
            Ok(Inserted {
                name,
                mesh,
                material: o.material,
                emission: o.emission,
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(dir: &Path, name: &str, text: &str) -> std::path::PathBuf {
        std::fs::create_dir_all(dir).unwrap();
        let p = dir.join(name);
        std::fs::write(&p, text).unwrap();
        p
    }

    #[test]
    fn places_shapes_and_objs() {
        let d = std::env::temp_dir().join(format!("fipt-insert-{}", std::process::id()));
        write(&d, "tri.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
        let p = write(
            &d,
            "insert.json",
            r#"{"objects": [
                {"name": "ball", "shape": "sphere", "scale": 0.5, "translate": [1, 2, 3],
                 "material": {"base_color": [0.5, 0.5, 0.5], "roughness": 0.2, "metallic": 0}},
                {"obj": "tri.obj", "rotate_deg": [0, 90, 0], "translate": [0, 0, 1], "emission": [1, 2, 3]}
            ]}"#,
        );
        let objs = load_insert(&p).unwrap();
        assert_eq!(objs.len(), 2);
        for v in &objs[0].mesh.vertices {
            assert!(((*v - Vec3::new(1.0, 2.0, 3.0)).length() - 0.5).abs() < 1e-5);
        }
        // (1, 0, 0) turned 90° about y lands on (0, 0, -1), then moves by (0, 0, 1).
        assert!((objs[1].mesh.vertices[1] - Vec3::ZERO).length() < 1e-6);
        assert_eq!(objs[1].emission, Some([1.0, 2.0, 3.0]));
        assert_eq!(objs[1].name, "object 1");
        for bad in [
            r#"{"objects": []}"#,
            r#"{"objects": [{"shape": "torus", "emission": [1,1,1]}]}"#,
            r#"{"objects": [{"shape": "cube"}]}"#,
            r#"{"objects": [{"shape": "cube", "scale": 0, "emission": [1,1,1]}]}"#,
            r#"{"objects": [{"shape": "cube", "obj": "tri.obj", "emission": [1,1,1]}]}"#,
            r#"{"objects": [{"obj": "missing.obj", "emission": [1,1,1]}]}"#,
            r#"{"objects": [{"shape": "cube", "material": {"base_color": [2,0,0], "roughness": 0.5, "metallic": 0}}]}"#,
            r#"{"objects": [{"shape": "cube", "emission": [1,1,1], "colour": 1}]}"#,
        ] {
            let p = write(&d, "bad.json", bad);
            let e = load_insert(&p).unwrap_err().to_string();
            assert!(e.contains("bad.json"), "{e}");
        }
        let _ = std::fs::remove_dir_all(&d);
    }
}
