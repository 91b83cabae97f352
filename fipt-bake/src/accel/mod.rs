//! The ray-casting acceleration structure: an obvhs compressed wide BVH (CWBVH) over the mesh,
//! with the triangles copied into BVH leaf order so a leaf reads contiguous memory.
//!
//! Owns: BVH build (`sah`), closest-hit and occlusion queries, pixel-centre ray casting
//! (`raycast`). Must not touch: shading.

pub mod raycast;
mod sah;

use fipt_core::scene::Mesh;
use glam::{Vec3, Vec3A};
use obvhs::{
    cwbvh::{CwBvh, bvh2_to_cwbvh::bvh2_to_cwbvh},
    ray::{Ray, RayHit},
    triangle::Triangle,
};

/// A closest hit: distance along the (unit) ray direction and the mesh triangle index.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    pub t: f32,
    pub tri: u32,
}

/// Triangle in the form the intersector wants: a vertex and two edges.
#[derive(Clone, Copy, Debug)]
struct LeafTri {
    v0: Vec3A,
    e1: Vec3A,
    e2: Vec3A,
}

/// Barycentric slack: lets rays through shared edges hit one of the two triangles instead of
/// slipping between them (Möller–Trumbore is not watertight).
const BARY_EPS: f32 = 1e-6;

impl LeafTri {
    /// Möller–Trumbore intersection; returns t in (tmin, tmax) or +inf.
    #[inline(always)]
    fn intersect(&self, o: Vec3A, d: Vec3A, tmin: f32, tmax: f32) -> f32 {
        let p = d.cross(self.e2);
        let det = self.e1.dot(p);
        if det == 0.0 {
            return f32::INFINITY;
        }
        let inv = 1.0 / det;
        let s = o - self.v0;
        let u = s.dot(p) * inv;
        let q = s.cross(self.e1);
        let v = d.dot(q) * inv;
        if u < -BARY_EPS || v < -BARY_EPS || u + v > 1.0 + BARY_EPS {
            return f32::INFINITY;
        }
        let t = self.e2.dot(q) * inv;
        if t > tmin && t < tmax {
            t
        } else {
            f32::INFINITY
        }
    }
}

/// BVH over a mesh, answering closest-hit and any-hit queries.
pub struct Accel {
    bvh: CwBvh,
    leaf_tris: Vec<LeafTri>,
    leaf_prim: Vec<u32>,
    /// Unit winding normal per triangle (mesh order).
    normals: Vec<Vec3>,
}

impl Accel {
    /// Builds the BVH: a binned-SAH BVH2 (`sah`) collapsed into obvhs' compressed wide BVH.
    pub fn build(mesh: &Mesh) -> Self {
        let tris: Vec<Triangle> = (0..mesh.num_triangles())
            .map(|t| {
                let [a, b, c] = mesh.corners(t);
                Triangle {
                    v0: a.into(),
                    v1: b.into(),
                    v2: c.into(),
                }
            })
            .collect();
        let boxes: Vec<_> = tris.iter().map(|t| t.aabb()).collect();
        let bvh = bvh2_to_cwbvh(&sah::build_bvh2(&boxes), 3, true, false);
        let leaf_prim: Vec<u32> = bvh.primitive_indices.clone();
        let leaf_tris = leaf_prim
            .iter()
            .map(|&p| {
                let t = &tris[p as usize];
                LeafTri {
                    v0: t.v0,
                    e1: t.v1 - t.v0,
                    e2: t.v2 - t.v0,
                }
            })
            .collect();
        Self {
            bvh,
            leaf_tris,
            leaf_prim,
            normals: (0..mesh.num_triangles()).map(|t| mesh.normal(t)).collect(),
        }
    }

    /// Unit normal of triangle `tri` turned to face against direction `d` (the side a ray
    /// along `d` hits).
    #[inline]
    pub fn facing_normal(&self, tri: u32, d: Vec3) -> Vec3 {
        let n = self.normals[tri as usize];
        if n.dot(d) > 0.0 { -n } else { n }
    }

    /// Closest hit along `o + t·d`, t ∈ (tmin, tmax). `d` should be unit length.
    #[inline]
    pub fn closest(&self, o: Vec3, d: Vec3, tmin: f32, tmax: f32) -> Option<Hit> {
        // -0.0 components become +0.0: obvhs's traversal misses every hit of a ray with a
        // negative-zero component (found by the demo room's axis-aligned probes).
        let (o, d) = (Vec3A::from(o), Vec3A::from(d) + Vec3A::ZERO);
        let ray = Ray::new(o, d, tmin, tmax);
        let mut hit = RayHit::none();
        let tris = &self.leaf_tris;
        if self.bvh.ray_traverse(ray, &mut hit, |r, id| {
            tris[id].intersect(r.origin, r.direction, r.tmin, r.tmax)
        }) {
            Some(Hit {
                t: hit.t,
                tri: self.leaf_prim[hit.primitive_id as usize],
            })
        } else {
            None
        }
    }

    /// True when anything lies along `o + t·d`, t ∈ (tmin, tmax).
    #[inline]
    pub fn occluded(&self, o: Vec3, d: Vec3, tmin: f32, tmax: f32) -> bool {
        let ray = Ray::new(Vec3A::from(o), Vec3A::from(d) + Vec3A::ZERO, tmin, tmax);
        let tris = &self.leaf_tris;
        !self.bvh.ray_traverse_miss(ray, |r, id| {
            tris[id].intersect(r.origin, r.direction, r.tmin, r.tmax)
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fipt_core::rng::Rng;
    use fipt_core::scene::procedural::room;

    /// Axis-aligned rays hit the closed room in all six directions, with negative-zero
    /// components too (`-Vec3::X` is (-1, -0, -0), which obvhs alone misses).
    #[test]
    fn axis_rays_with_negative_zero_hit() {
        let r = room(Vec3::new(4.0, 2.6, 3.2), 1);
        let accel = Accel::build(&r.mesh);
        let o = Vec3::new(1.03, 1.31, 0.57);
        for d in [Vec3::X, -Vec3::X, Vec3::Y, -Vec3::Y, Vec3::Z, -Vec3::Z] {
            assert!(accel.closest(o, d, 0.0, f32::INFINITY).is_some(), "{d}");
            assert!(accel.occluded(o, d, 0.0, 100.0), "{d}");
        }
    }

    /// Brute force over all triangles agrees with the BVH on random rays.
    #[test]
    fn bvh_matches_brute_force() {
        let r = room(Vec3::new(5.0, 2.7, 4.0), 1);
        let mesh = &r.mesh;
        let accel = Accel::build(mesh);
        let mut rng = Rng::new(1, 2);
        let mut hits = 0;
        for _ in 0..3000 {
            let o = Vec3::new(
                0.2 + 4.6 * rng.next_f32(),
                0.1 + 2.5 * rng.next_f32(),
                0.2 + 3.6 * rng.next_f32(),
            );
            let z = 2.0 * rng.next_f32() - 1.0;
            let ph = std::f32::consts::TAU * rng.next_f32();
            let s = (1.0 - z * z).sqrt();
            let d = Vec3::new(s * ph.cos(), z, s * ph.sin());
            let mut best = (f32::INFINITY, u32::MAX);
            for t in 0..mesh.num_triangles() {
                let [a, b, c] = mesh.corners(t);
                let lt = LeafTri {
                    v0: a.into(),
                    e1: (b - a).into(),
                    e2: (c - a).into(),
                };
                let tt = lt.intersect(o.into(), d.into(), 0.0, f32::INFINITY);
                if tt < best.0 {
                    best = (tt, t as u32);
                }
            }
            let h = accel.closest(o, d, 0.0, f32::INFINITY);
            match h {
                Some(h) => {
                    hits += 1;
                    assert!((h.t - best.0).abs() < 1e-5, "{h:?} vs {best:?}");
                    assert!(accel.occluded(o, d, 0.0, h.t * 1.01));
                    assert!(!accel.occluded(o, d, 0.0, h.t * 0.99));
                }
                None => assert!(best.0.is_infinite()),
            }
        }
        // A closed room: every ray from inside hits something.
        assert_eq!(hits, 3000);
    }
}
