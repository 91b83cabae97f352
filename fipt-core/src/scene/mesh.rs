//! The triangle mesh: vertices and triangles in OBJ file order. The triangle index defined here
//! is shared by ray casting, segmentation fusion and emitter extraction downstream.
//!
//! Owns: OBJ parsing and mesh validation. Must not touch: acceleration structures.

use crate::io::{FileError, Result, read_text};
use glam::Vec3;
use std::path::Path;

/// A triangle mesh as plain arrays.
#[derive(Clone, Debug, Default)]
pub struct Mesh {
    pub vertices: Vec<Vec3>,
    pub triangles: Vec<[u32; 3]>,
}

impl Mesh {
    pub fn num_triangles(&self) -> usize {
        self.triangles.len()
    }

    /// Every triangle split into 4^k by midpoint subdivision, as an unshared vertex soup: the
    /// same surface with 4^k times the triangles (`bench trace --mesh-scale`, the peer
    /// script's subdivision; tests of watertight traversal over many shared edges).
    pub fn subdivided(&self, k: u32) -> Mesh {
        let mut tris: Vec<[Vec3; 3]> = (0..self.num_triangles()).map(|t| self.corners(t)).collect();
        for _ in 0..k {
            tris = tris
                .iter()
                .flat_map(|&[a, b, c]| {
                    let (ab, bc, ca) = ((a + b) * 0.5, (b + c) * 0.5, (c + a) * 0.5);
                    [[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]
                })
                .collect();
        }
        Mesh {
            vertices: tris.iter().flatten().copied().collect(),
            triangles: (0..tris.len() as u32)
                .map(|t| [3 * t, 3 * t + 1, 3 * t + 2])
                .collect(),
        }
    }

    /// The three corners of triangle `t`.
    #[inline]
    pub fn corners(&self, t: usize) -> [Vec3; 3] {
        let [a, b, c] = self.triangles[t];
        [
            self.vertices[a as usize],
            self.vertices[b as usize],
            self.vertices[c as usize],
        ]
    }

    /// Unnormalised winding normal `cross(v1 - v0, v2 - v0)` (length = 2 × area).
    #[inline]
    pub fn cross(&self, t: usize) -> Vec3 {
        let [a, b, c] = self.corners(t);
        (b - a).cross(c - a)
    }

    pub fn area(&self, t: usize) -> f32 {
        0.5 * self.cross(t).length()
    }

    /// The point of triangle `t` at (u, v) ∈ [0, 1)²: `v0 + u·e1 + v·e2`, folded back into the
    /// triangle where u + v > 1 (uniform in area for uniform u, v).
    pub fn point_at(&self, t: usize, u: f32, v: f32) -> Vec3 {
        let [a, b, c] = self.corners(t);
        let (u, v) = if u + v > 1.0 {
            (1.0 - u, 1.0 - v)
        } else {
            (u, v)
        };
        a + (b - a) * u + (c - a) * v
    }

    /// Cumulative triangle areas (f64 sums of the f32 areas), for drawing triangles by area
    /// with `triangle_by_area`.
    pub fn area_cdf(&self) -> Vec<f64> {
        let mut total = 0.0f64;
        (0..self.num_triangles())
            .map(|t| {
                total += self.area(t) as f64;
                total
            })
            .collect()
    }

    /// The triangle of `range` (a slice of `cdf = area_cdf()`) that a uniform `u` ∈ [0, 1)
    /// picks, with probability proportional to its area.
    pub fn triangle_by_area(cdf: &[f64], range: [usize; 2], u: f64) -> usize {
        let below = if range[0] == 0 {
            0.0
        } else {
            cdf[range[0] - 1]
        };
        let x = below + (cdf[range[1] - 1] - below) * u;
        (range[0] + cdf[range[0]..range[1]].partition_point(|&c| c < x)).min(range[1] - 1)
    }

    /// Feeds the vertices and triangles into an FNV-64 hash (cache keys, model manifests).
    pub fn hash_into(&self, h: &mut crate::io::Fnv64) {
        for v in &self.vertices {
            h.f32s(&v.to_array());
        }
        for t in &self.triangles {
            for i in t {
                h.bytes(&i.to_le_bytes());
            }
        }
    }

    /// Unit winding normal of triangle `t`.
    pub fn normal(&self, t: usize) -> Vec3 {
        self.cross(t).normalize_or_zero()
    }

    /// Axis-aligned bounds (min, max) of all vertices.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        self.vertices.iter().fold(
            (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(lo, hi), v| (lo.min(*v), hi.max(*v)),
        )
    }

    /// Checks the mesh is usable: non-empty, finite vertices, indices in range, no degenerate
    /// (zero-area) triangles. `path` names the source in the error.
    pub fn validate(&self, path: &Path) -> Result<()> {
        if self.triangles.is_empty() {
            return Err(FileError::new(path, "mesh has no triangles"));
        }
        if let Some(i) = self.vertices.iter().position(|v| !v.is_finite()) {
            return Err(FileError::new(
                path,
                format!("vertex {} is not finite", i + 1),
            ));
        }
        let n = self.vertices.len() as u32;
        for (t, tri) in self.triangles.iter().enumerate() {
            if let Some(&bad) = tri.iter().find(|&&i| i >= n) {
                return Err(FileError::new(
                    path,
                    format!(
                        "triangle {t} refers to vertex {} but the file has {n} vertices",
                        bad + 1
                    ),
                ));
            }
        }
        let degenerate: Vec<usize> = (0..self.triangles.len())
            .filter(|&t| {
                let c = self.cross(t);
                c.length_squared() <= 0.0 || !c.is_finite()
            })
            .collect();
        if let Some(&first) = degenerate.first() {
            return Err(FileError::new(
                path,
                format!(
                    "{} degenerate (zero-area) triangle(s), first is triangle {first} (face line order, 0-based)",
                    degenerate.len()
                ),
            ));
        }
        Ok(())
    }

    /// Loads a Wavefront OBJ: `v` and `f` lines; polygons are fan-triangulated in order; `vt`,
    /// `vn`, groups, objects, materials and comments are ignored. Face indices may be `a`,
    /// `a/b`, `a//c`, `a/b/c`, 1-based or negative (relative).
    pub fn load_obj(path: &Path) -> Result<Mesh> {
        let text = read_text(path)?;
        let mesh = Self::parse_obj(&text)
            .map_err(|(line, msg)| FileError::new(path, format!("line {line}: {msg}")))?;
        mesh.validate(path)?;
        Ok(mesh)
    }

    /// Parses OBJ text; errors carry the 1-based line number.
    pub fn parse_obj(text: &str) -> std::result::Result<Mesh, (usize, String)> {
        let mut mesh = Mesh::default();
        let mut face: Vec<u32> = Vec::with_capacity(8);
        for (ln, line) in text.lines().enumerate() {
            let ln = ln + 1;
            let line = line.split('#').next().unwrap_or("");
            let mut it = line.split_ascii_whitespace();
            match it.next() {
                Some("v") => {
                    let mut xyz = [0f32; 3];
                    for c in &mut xyz {
                        let tok = it
                            .next()
                            .ok_or((ln, "vertex needs 3 coordinates".to_string()))?;
                        *c = tok
                            .parse::<f32>()
                            .map_err(|_| (ln, format!("bad vertex coordinate '{tok}'")))?;
                    }
                    mesh.vertices.push(Vec3::from(xyz));
                }
                Some("f") => {
                    face.clear();
                    for tok in it {
                        let idx = tok.split('/').next().unwrap_or("");
                        let i: i64 = idx
                            .parse()
                            .map_err(|_| (ln, format!("bad face index '{tok}'")))?;
                        let nv = mesh.vertices.len() as i64;
                        let abs = if i > 0 {
                            i - 1
                        } else if i < 0 {
                            nv + i
                        } else {
                            return Err((ln, "face index 0 (OBJ indices start at 1)".into()));
                        };
                        if abs < 0 || abs >= nv {
                            return Err((
                                ln,
                                format!(
                                    "face index {i} out of range ({nv} vertices defined so far)"
                                ),
                            ));
                        }
                        face.push(abs as u32);
                    }
                    if face.len() < 3 {
                        return Err((ln, format!("face has {} vertices, needs 3", face.len())));
                    }
                    for k in 1..face.len() - 1 {
                        mesh.triangles.push([face[0], face[k], face[k + 1]]);
                    }
                }
                _ => {}
            }
        }
        Ok(mesh)
    }

    /// Writes the mesh as OBJ (vertices and triangles only), atomically.
    pub fn save_obj(&self, path: &Path, header: &str) -> Result<()> {
        use std::fmt::Write;
        let mut s = String::with_capacity(self.vertices.len() * 32 + self.triangles.len() * 24);
        for l in header.lines() {
            let _ = writeln!(s, "# {l}");
        }
        for v in &self.vertices {
            let _ = writeln!(s, "v {} {} {}", v.x, v.y, v.z);
        }
        for t in &self.triangles {
            let _ = writeln!(s, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1);
        }
        crate::io::write_bytes_atomic(path, s.as_bytes())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fan_triangulation_and_index_forms() {
        let m = Mesh::parse_obj(
            "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nf 1/1 2//3 3/1/2 4\nf -4 -3 -1\n",
        )
        .unwrap();
        assert_eq!(m.triangles, vec![[0, 1, 2], [0, 2, 3], [0, 1, 3]]);
        assert!((m.area(0) - 0.5).abs() < 1e-6);
        assert_eq!(m.normal(0), Vec3::Z);
    }

    #[test]
    fn errors_name_the_line() {
        let e = Mesh::parse_obj("v 0 0 0\nv 1 0 0\nf 1 2 5\n").unwrap_err();
        assert_eq!(e.0, 3);
        assert!(e.1.contains("out of range"));
        assert_eq!(Mesh::parse_obj("v 0 zero 0\n").unwrap_err().0, 1);
        assert!(
            Mesh::parse_obj("v 0 0 0\nf 1 1\n")
                .unwrap_err()
                .1
                .contains("needs 3")
        );
    }

    #[test]
    fn validation_catches_degenerate_and_empty() {
        let p = Path::new("m.obj");
        let m = Mesh::parse_obj("v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n").unwrap();
        let e = m.validate(p).unwrap_err().to_string();
        assert!(e.contains("m.obj") && e.contains("degenerate"), "{e}");
        let e = Mesh::default().validate(p).unwrap_err().to_string();
        assert!(e.contains("no triangles"));
    }
}
