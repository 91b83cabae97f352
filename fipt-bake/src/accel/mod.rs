//! The ray-casting acceleration structure: a binned-SAH BVH2 (`sah`) collapsed by obvhs into
//! its compressed wide BVH (CWBVH), traversed by `wide`'s eight-wide AVX2 traversal where the
//! CPU has AVX2 and FMA, else by obvhs's own.
//!
//! Owns: BVH build, closest-hit and occlusion queries, pixel-centre ray casting (`raycast`).
//! Must not touch: shading.

pub mod raycast;
mod sah;
mod wide;

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
    fn new([a, b, c]: [Vec3; 3]) -> Self {
        LeafTri {
            v0: a.into(),
            e1: (b - a).into(),
            e2: (c - a).into(),
        }
    }

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
    /// The wide SIMD traversal's copy of the tree; `None` where the CPU lacks AVX2/FMA (then
    /// obvhs's traversal answers).
    wide: Option<wide::Bvh8>,
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
        let bvh2 = sah::build_bvh2(&boxes);
        let bvh = bvh2_to_cwbvh(&bvh2, 3, true, false);
        let leaf_prim: Vec<u32> = bvh.primitive_indices.clone();
        let leaf_tris: Vec<LeafTri> = leaf_prim
            .iter()
            .map(|&p| LeafTri::new(mesh.corners(p as usize)))
            .collect();
        // `FIPT_TRAVERSAL=obvhs` forces obvhs's traversal (to compare the two on one machine).
        let forced = std::env::var("FIPT_TRAVERSAL").is_ok_and(|v| v == "obvhs");
        let wide = (wide::Bvh8::supported() && !forced)
            .then(|| {
                let tris: Vec<wide::TriIn> = tris
                    .iter()
                    .map(|t| wide::TriIn {
                        v0: t.v0.into(),
                        e1: (t.v1 - t.v0).into(),
                        e2: (t.v2 - t.v0).into(),
                    })
                    .collect();
                wide::Bvh8::from_bvh2(&bvh2, &tris)
            })
            .filter(|w| w.fits_stack());
        Self {
            bvh,
            wide,
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

    /// Which traversal answers queries: `"avx2-bvh8"` or `"obvhs-cwbvh"`.
    pub fn traversal(&self) -> &'static str {
        if self.wide.is_some() {
            "avx2-bvh8"
        } else {
            "obvhs-cwbvh"
        }
    }

    /// Closest hit along `o + t·d`, t ∈ (tmin, tmax). `d` should be unit length.
    #[inline]
    pub fn closest(&self, o: Vec3, d: Vec3, tmin: f32, tmax: f32) -> Option<Hit> {
        match &self.wide {
            Some(w) => w.closest(o, d, tmin, tmax),
            None => self.closest_obvhs(o, d, tmin, tmax),
        }
    }

    /// `closest` of every ray `(o, d)` of `rays` into `out` (same length). Where the wide
    /// traversal runs, several rays are traced interleaved, which hides one ray's memory and
    /// branch latency behind another's work; each result equals `closest`'s.
    pub fn closest_many(
        &self,
        rays: &[(Vec3, Vec3)],
        tmin: f32,
        tmax: f32,
        out: &mut [Option<Hit>],
    ) {
        assert_eq!(rays.len(), out.len(), "closest_many: one output per ray");
        match &self.wide {
            Some(w) => w.closest_many(rays, tmin, tmax, out),
            None => {
                for (o, &(org, d)) in out.iter_mut().zip(rays) {
                    *o = self.closest_obvhs(org, d, tmin, tmax);
                }
            }
        }
    }

    /// True when anything lies along `o + t·d`, t ∈ (tmin, tmax).
    #[inline]
    pub fn occluded(&self, o: Vec3, d: Vec3, tmin: f32, tmax: f32) -> bool {
        match &self.wide {
            Some(w) => w.occluded(o, d, tmin, tmax),
            None => self.occluded_obvhs(o, d, tmin, tmax),
        }
    }

    /// `closest` by obvhs's CWBVH traversal.
    fn closest_obvhs(&self, o: Vec3, d: Vec3, tmin: f32, tmax: f32) -> Option<Hit> {
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

    /// `occluded` by obvhs's CWBVH traversal.
    fn occluded_obvhs(&self, o: Vec3, d: Vec3, tmin: f32, tmax: f32) -> bool {
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
                let lt = LeafTri::new(mesh.corners(t));
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

    /// Random rays from inside a room: origins uniform in the room, directions uniform on
    /// the sphere, plus axis-parallel and grazing rays (one or two direction components zero
    /// or tiny) that skim the walls' flat boxes.
    fn probe_rays(lo: Vec3, hi: Vec3, n: usize, seed: u64) -> Vec<(Vec3, Vec3)> {
        let mut rng = Rng::new(seed, 7);
        let mut rays = Vec::with_capacity(n);
        for i in 0..n {
            let u = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
            let o = lo + (hi - lo) * (Vec3::splat(0.02) + 0.96 * u);
            let z = 2.0 * rng.next_f32() - 1.0;
            let ph = std::f32::consts::TAU * rng.next_f32();
            let s = (1.0 - z * z).sqrt();
            let mut d = Vec3::new(s * ph.cos(), z, s * ph.sin());
            match i % 8 {
                5 => d[i % 3] = 0.0,
                6 => d[(i / 8) % 3] = 1e-7 * d[(i / 8) % 3].signum(),
                7 => {
                    d = Vec3::ZERO;
                    d[(i / 8) % 3] = if rng.next_f32() < 0.5 { 1.0 } else { -1.0 };
                }
                _ => {}
            }
            rays.push((o, d.normalize()));
        }
        rays
    }

    /// The wide traversal (where this CPU runs it), obvhs's traversal and brute force agree
    /// on every probe ray of a furnished room: the same hit distance to the bit (the wide
    /// leaf test is the scalar test's arithmetic), a triangle at that distance, the same
    /// occlusion just before and after it; the batched query equals the single one.
    #[test]
    fn traversals_agree_with_brute_force() {
        let r = room(Vec3::new(5.0, 2.7, 4.0), 2);
        let mesh = &r.mesh;
        let accel = Accel::build(mesh);
        let (lo, hi) = mesh.bounds();
        let rays = probe_rays(lo, hi, 4000, 3);
        let brute = |o: Vec3, d: Vec3| {
            let mut best = f32::INFINITY;
            for t in 0..mesh.num_triangles() {
                let lt = LeafTri::new(mesh.corners(t));
                best = best.min(lt.intersect(o.into(), d.into(), 0.0, f32::INFINITY));
            }
            best
        };
        let mut batch = vec![None; rays.len()];
        accel.closest_many(&rays, 0.0, f32::INFINITY, &mut batch);
        let mut hits = 0;
        for (&(o, d), many) in rays.iter().zip(&batch) {
            let want = brute(o, d);
            let h = accel.closest(o, d, 0.0, f32::INFINITY);
            let reference = accel.closest_obvhs(o, d, 0.0, f32::INFINITY);
            assert_eq!(h, *many, "batched query differs at {o} {d}");
            assert_eq!(
                h.map(|h| h.t),
                reference.map(|h| h.t),
                "obvhs differs at {o} {d}"
            );
            let h = h.unwrap_or_else(|| panic!("ray {o} {d} left a closed room"));
            assert_eq!(h.t.to_bits(), want.to_bits(), "{o} {d}: {} vs {want}", h.t);
            let lt = LeafTri::new(mesh.corners(h.tri as usize));
            assert_eq!(lt.intersect(o.into(), d.into(), 0.0, f32::INFINITY), h.t);
            assert!(accel.occluded(o, d, 0.0, h.t * 1.001));
            assert!(!accel.occluded(o, d, 0.0, h.t * 0.999));
            assert_eq!(
                accel.occluded(o, d, 0.0, h.t * 1.001),
                accel.occluded_obvhs(o, d, 0.0, h.t * 1.001)
            );
            hits += 1;
        }
        assert_eq!(hits, rays.len());
        if wide::Bvh8::supported() {
            assert_eq!(accel.traversal(), "avx2-bvh8");
        }
    }

    /// No ray slips between triangles: the room's walls split into 4^3 triangles each (many
    /// shared edges and flat coplanar boxes) still stop every ray from inside, and at the
    /// unsplit room's distance.
    #[test]
    fn subdivided_room_is_watertight() {
        let r = room(Vec3::new(4.0, 2.6, 3.2), 1);
        let (coarse, fine) = (Accel::build(&r.mesh), Accel::build(&r.mesh.subdivided(3)));
        let (lo, hi) = r.mesh.bounds();
        let rays = probe_rays(lo, hi, 20000, 5);
        let mut out = vec![None; rays.len()];
        fine.closest_many(&rays, 0.0, f32::INFINITY, &mut out);
        for (&(o, d), h) in rays.iter().zip(out) {
            let h = h.unwrap_or_else(|| panic!("ray {o} {d} slipped through"));
            let c = coarse.closest(o, d, 0.0, f32::INFINITY).unwrap();
            assert!(
                (h.t - c.t).abs() <= 1e-4 * c.t.max(1.0),
                "{o} {d}: {} vs {}",
                h.t,
                c.t
            );
        }
    }

    /// Rays leaving surfaces as the bake casts them (from a point on a triangle, offset by
    /// RAY_EPS along a direction in its hemisphere) hit what brute force hits, at the same
    /// distance to the bit. (obvhs's traversal differs on about 1 ray in 20,000 here.)
    #[test]
    fn surface_rays_agree_with_brute_force() {
        let r = room(Vec3::new(5.0, 2.7, 4.0), 2);
        let mesh = &r.mesh;
        let accel = Accel::build(mesh);
        let mut rng = Rng::new(11, 3);
        for _ in 0..20000 {
            let t = (rng.next_f32() * mesh.num_triangles() as f32) as usize % mesh.num_triangles();
            let [a, b, c] = mesh.corners(t);
            let (mut u, mut v) = (rng.next_f32(), rng.next_f32());
            if u + v > 1.0 {
                (u, v) = (1.0 - u, 1.0 - v);
            }
            let x = a + (b - a) * u + (c - a) * v;
            let z = 2.0 * rng.next_f32() - 1.0;
            let ph = std::f32::consts::TAU * rng.next_f32();
            let s = (1.0 - z * z).sqrt();
            let mut d = Vec3::new(s * ph.cos(), z, s * ph.sin());
            if d.dot(mesh.normal(t)) < 0.0 {
                d = -d;
            }
            let o = x + d * crate::integrators::bake::RAY_EPS;
            let h = accel.closest(o, d, 0.0, f32::INFINITY);
            let mut best = (f32::INFINITY, u32::MAX);
            for k in 0..mesh.num_triangles() {
                let tt =
                    LeafTri::new(mesh.corners(k)).intersect(o.into(), d.into(), 0.0, f32::INFINITY);
                if tt < best.0 {
                    best = (tt, k as u32);
                }
            }
            let ht = h.map_or(f32::INFINITY, |h| h.t);
            assert_eq!(
                ht.to_bits(),
                best.0.to_bits(),
                "{o} {d}: {ht} vs {}",
                best.0
            );
        }
    }
}
