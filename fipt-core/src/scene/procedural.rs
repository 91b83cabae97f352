//! Procedural geometry: a room with furniture and spheres built from grids, boxes and UV spheres,
//! for benchmarks and the project's own test scenes (no data needed).
//!
//! Owns: mesh construction helpers and the built-in rooms. Must not touch: files or rendering.

use super::Mesh;
use glam::Vec3;
use std::ops::Range;

/// A mesh with named parts (contiguous triangle ranges).
#[derive(Clone, Debug, Default)]
pub struct PartMesh {
    pub mesh: Mesh,
    pub parts: Vec<(String, Range<usize>)>,
}

impl PartMesh {
    fn begin(&mut self) -> usize {
        self.mesh.triangles.len()
    }

    fn end(&mut self, name: &str, start: usize) {
        let end = self.mesh.triangles.len();
        self.parts.push((name.to_string(), start..end));
    }

    fn vertex(&mut self, p: Vec3) -> u32 {
        self.mesh.vertices.push(p);
        (self.mesh.vertices.len() - 1) as u32
    }

    /// A parallelogram `origin + s·u + t·v`, s,t ∈ [0,1], split into `nu × nv` cells; winding
    /// normal along `u × v`.
    pub fn grid(&mut self, name: &str, origin: Vec3, u: Vec3, v: Vec3, nu: usize, nv: usize) {
        let start = self.begin();
        let base = self.mesh.vertices.len() as u32;
        for j in 0..=nv {
            for i in 0..=nu {
                let p = origin + u * (i as f32 / nu as f32) + v * (j as f32 / nv as f32);
                self.vertex(p);
            }
        }
        let row = nu as u32 + 1;
        for j in 0..nv as u32 {
            for i in 0..nu as u32 {
                let a = base + j * row + i;
                let (b, c, d) = (a + 1, a + row + 1, a + row);
                self.mesh.triangles.push([a, b, c]);
                self.mesh.triangles.push([a, c, d]);
            }
        }
        self.end(name, start);
    }

    /// An axis-aligned box with outward normals, each face an `n × n` grid.
    pub fn cuboid(&mut self, name: &str, lo: Vec3, hi: Vec3, n: usize) {
        let start = self.begin();
        let d = hi - lo;
        let (x, y, z) = (Vec3::X * d.x, Vec3::Y * d.y, Vec3::Z * d.z);
        let faces = [
            (lo, y, x),     // -z
            (lo + z, x, y), // +z
            (lo, z, y),     // -x
            (lo + x, y, z), // +x
            (lo, x, z),     // -y
            (lo + y, z, x), // +y
        ];
        let mut sub = PartMesh::default();
        for (o, u, v) in faces {
            sub.grid("", o, u, v, n, n);
        }
        self.append(&sub.mesh);
        self.end(name, start);
    }

    /// A UV sphere with `n_lat` rings and `n_lon` segments, outward normals, triangle caps.
    pub fn sphere(&mut self, name: &str, centre: Vec3, r: f32, n_lat: usize, n_lon: usize) {
        let start = self.begin();
        let base = self.mesh.vertices.len() as u32;
        let top = self.vertex(centre + Vec3::Y * r);
        for j in 1..n_lat {
            let th = std::f32::consts::PI * j as f32 / n_lat as f32;
            for i in 0..n_lon {
                let ph = std::f32::consts::TAU * i as f32 / n_lon as f32;
                let dir = Vec3::new(th.sin() * ph.cos(), th.cos(), th.sin() * ph.sin());
                self.vertex(centre + dir * r);
            }
        }
        let bottom = self.vertex(centre - Vec3::Y * r);
        let ring = |j: usize, i: usize| base + 1 + (j * n_lon + i % n_lon) as u32;
        for i in 0..n_lon {
            self.mesh.triangles.push([top, ring(0, i + 1), ring(0, i)]);
        }
        for j in 0..n_lat - 2 {
            for i in 0..n_lon {
                let (a, b) = (ring(j, i), ring(j, i + 1));
                let (c, d) = (ring(j + 1, i + 1), ring(j + 1, i));
                self.mesh.triangles.push([a, b, c]);
                self.mesh.triangles.push([a, c, d]);
            }
        }
        for i in 0..n_lon {
            self.mesh
                .triangles
                .push([bottom, ring(n_lat - 2, i), ring(n_lat - 2, i + 1)]);
        }
        self.end(name, start);
    }

    fn append(&mut self, m: &Mesh) {
        let off = self.mesh.vertices.len() as u32;
        self.mesh.vertices.extend_from_slice(&m.vertices);
        self.mesh.triangles.extend(
            m.triangles
                .iter()
                .map(|t| [t[0] + off, t[1] + off, t[2] + off]),
        );
    }

    /// The part a triangle belongs to.
    pub fn part_of(&self, tri: usize) -> Option<usize> {
        self.parts.iter().position(|(_, r)| r.contains(&tri))
    }
}

/// A closed room `size` (x, y up, z) with inward-facing walls: table, cabinet, two spheres, a
/// ceiling panel. `detail` scales the tessellation (1 gives a few thousand triangles, 8 about
/// 115k).
pub fn room(size: Vec3, detail: usize) -> PartMesh {
    let d = detail.max(1);
    let (sx, sy, sz) = (size.x, size.y, size.z);
    let mut m = PartMesh::default();
    let g = 10 * d;
    m.grid("floor", Vec3::ZERO, Vec3::Z * sz, Vec3::X * sx, g, g);
    m.grid("ceiling", Vec3::Y * sy, Vec3::X * sx, Vec3::Z * sz, g, g);
    m.grid("wall_x0", Vec3::ZERO, Vec3::Y * sy, Vec3::Z * sz, g, g);
    m.grid("wall_x1", Vec3::X * sx, Vec3::Z * sz, Vec3::Y * sy, g, g);
    m.grid("wall_z0", Vec3::ZERO, Vec3::X * sx, Vec3::Y * sy, g, g);
    m.grid("wall_z1", Vec3::Z * sz, Vec3::Y * sy, Vec3::X * sx, g, g);
    let c = Vec3::new(sx * 0.5, 0.0, sz * 0.5);
    m.cuboid(
        "table",
        c + Vec3::new(-0.6, 0.7, -0.4),
        c + Vec3::new(0.6, 0.75, 0.4),
        2 * d,
    );
    m.cuboid(
        "cabinet",
        Vec3::new(0.1, 0.0, sz * 0.2),
        Vec3::new(0.6, 0.9, sz * 0.2 + 1.0),
        2 * d,
    );
    m.sphere(
        "sphere_a",
        c + Vec3::new(0.0, 1.0, 0.0),
        0.25,
        8 * d,
        16 * d,
    );
    m.sphere(
        "sphere_b",
        Vec3::new(sx * 0.75, 0.3, sz * 0.7),
        0.3,
        8 * d,
        16 * d,
    );
    m.grid(
        "ceiling_light",
        Vec3::new(c.x - 0.5, sy - 0.01, c.z - 0.3),
        Vec3::X * 1.0,
        Vec3::Z * 0.6,
        1,
        1,
    );
    m
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    #[test]
    fn room_is_valid_and_closed_facing_inward() {
        let r = room(Vec3::new(5.0, 2.7, 4.0), 1);
        r.mesh.validate(Path::new("room")).unwrap();
        // Inward walls: floor normal +y, ceiling -y, light panel -y (emits down).
        let floor = &r.parts[0].1;
        assert_eq!(r.mesh.normal(floor.start), Vec3::Y);
        assert_eq!(r.mesh.normal(r.parts[1].1.start), -Vec3::Y);
        assert_eq!(r.mesh.normal(r.parts.last().unwrap().1.start), -Vec3::Y);
        // Spheres: normals point away from the centre.
        let (_, s) = &r.parts[8];
        for t in s.clone() {
            let [a, b, c] = r.mesh.corners(t);
            let mid = (a + b + c) / 3.0 - Vec3::new(2.5, 1.0, 2.0);
            assert!(r.mesh.normal(t).dot(mid) > 0.0, "triangle {t}");
        }
        // Box faces point outward.
        let (_, tb) = &r.parts[6];
        for t in tb.clone() {
            let [a, b, c] = r.mesh.corners(t);
            let mid = (a + b + c) / 3.0 - Vec3::new(2.5, 0.725, 2.0);
            assert!(r.mesh.normal(t).dot(mid) > 0.0, "triangle {t}");
        }
        // Total area of the six walls.
        let walls: f32 = r.parts[..6]
            .iter()
            .flat_map(|(_, rg)| rg.clone())
            .map(|t| r.mesh.area(t))
            .sum();
        let want = 2.0 * (5.0 * 2.7 + 5.0 * 4.0 + 2.7 * 4.0);
        assert!((walls - want).abs() < 1e-3 * want);
        assert!(room(Vec3::new(5.0, 2.7, 4.0), 8).mesh.num_triangles() >= 100_000);
    }
}
