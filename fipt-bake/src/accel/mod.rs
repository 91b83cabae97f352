//! The ray-casting acceleration structure: a binned-SAH BVH2 (`sah`), collapsed into `wide`'s
//! eight-wide BVH and traversed with AVX2 where the CPU has AVX2 and FMA, else collapsed by
//! obvhs into its compressed wide BVH (CWBVH) and traversed by obvhs. Only the one in use is
//! built.
//!
//! Owns: BVH build, closest-hit and occlusion queries, pixel-centre ray casting (`raycast`) and
//! the pixels' sub-pixel footprints (`footprint`).
//! Must not touch: shading.

pub mod footprint;
pub mod raycast;
mod sah;
mod wide;

use fipt_core::scene::Mesh;
use glam::{Vec3, Vec3A};
use obvhs::{
    aabb::Aabb,
    bvh2::Bvh2,
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
    traversal: Traversal,
    /// Unit winding normal per triangle (mesh order).
    normals: Vec<Vec3>,
}

/// The tree and the traversal that answer queries.
enum Traversal {
    /// `wide`'s eight-wide AVX2 traversal.
    Wide(wide::Bvh8),
    /// obvhs's CWBVH traversal: CPUs without AVX2/FMA, a tree too deep for the wide stack,
    /// or `FIPT_TRAVERSAL=obvhs`.
    Obvhs(ObvhsBvh),
}

/// obvhs's compressed wide BVH, with the triangles copied into its leaf order so that a leaf
/// reads contiguous memory.
struct ObvhsBvh {
    bvh: CwBvh,
    leaf_tris: Vec<LeafTri>,
    leaf_prim: Vec<u32>,
}

impl ObvhsBvh {
    fn build(bvh2: &Bvh2, tris: &[LeafTri]) -> Self {
        let bvh = bvh2_to_cwbvh(bvh2, 3, true, false);
        let leaf_prim = bvh.primitive_indices.clone();
        let leaf_tris = leaf_prim.iter().map(|&p| tris[p as usize]).collect();
        Self {
            bvh,
            leaf_tris,
            leaf_prim,
        }
    }

    fn closest(&self, o: Vec3, d: Vec3, tmin: f32, tmax: f32) -> Option<Hit> {
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

    fn occluded(&self, o: Vec3, d: Vec3, tmin: f32, tmax: f32) -> bool {
        let ray = Ray::new(Vec3A::from(o), Vec3A::from(d) + Vec3A::ZERO, tmin, tmax);
        let tris = &self.leaf_tris;
        !self.bvh.ray_traverse_miss(ray, |r, id| {
            tris[id].intersect(r.origin, r.direction, r.tmin, r.tmax)
        })
    }
}

impl Accel {
    /// Builds the BVH: a binned-SAH BVH2 (`sah`), collapsed for the wide traversal where this
    /// CPU runs it, else for obvhs's. `FIPT_TRAVERSAL=obvhs` forces obvhs's (to compare the
    /// two on one machine).
    pub fn build(mesh: &Mesh) -> Self {
        let forced = std::env::var("FIPT_TRAVERSAL").is_ok_and(|v| v == "obvhs");
        Self::build_with(mesh, wide::Bvh8::supported() && !forced)
    }

    /// `build`, with the wide traversal only if `wide` (the caller checked the CPU).
    fn build_with(mesh: &Mesh, wide: bool) -> Self {
        let tris: Vec<LeafTri> = (0..mesh.num_triangles())
            .map(|t| LeafTri::new(mesh.corners(t)))
            .collect();
        let boxes: Vec<Aabb> = (0..mesh.num_triangles())
            .map(|t| {
                let [a, b, c] = mesh.corners(t);
                Triangle {
                    v0: a.into(),
                    v1: b.into(),
                    v2: c.into(),
                }
                .aabb()
            })
            .collect();
        let bvh2 = sah::build_bvh2(&boxes);
        let traversal = match wide
            .then(|| wide::Bvh8::from_bvh2(&bvh2, &tris))
            .filter(|w| w.fits_stack())
        {
            Some(w) => Traversal::Wide(w),
            None => Traversal::Obvhs(ObvhsBvh::build(&bvh2, &tris)),
        };
        Self {
            traversal,
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
        match self.traversal {
            Traversal::Wide(_) => "avx2-bvh8",
            Traversal::Obvhs(_) => "obvhs-cwbvh",
        }
    }

    /// Closest hit along `o + t·d`, t ∈ (tmin, tmax). `d` should be unit length. The wide
    /// traversal breaks a tie between triangles at the same distance by the lower triangle
    /// index, so its answer is the brute-force one and does not depend on the tree or the
    /// order of the walk.
    #[inline]
    pub fn closest(&self, o: Vec3, d: Vec3, tmin: f32, tmax: f32) -> Option<Hit> {
        match &self.traversal {
            Traversal::Wide(w) => w.closest(o, d, tmin, tmax),
            Traversal::Obvhs(b) => b.closest(o, d, tmin, tmax),
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
        match &self.traversal {
            Traversal::Wide(w) => w.closest_many(rays, tmin, tmax, out),
            Traversal::Obvhs(b) => {
                for (o, &(org, d)) in out.iter_mut().zip(rays) {
                    *o = b.closest(org, d, tmin, tmax);
                }
            }
        }
    }

    /// True when anything lies along `o + t·d`, t ∈ (tmin, tmax).
    #[inline]
    pub fn occluded(&self, o: Vec3, d: Vec3, tmin: f32, tmax: f32) -> bool {
        match &self.traversal {
            Traversal::Wide(w) => w.occluded(o, d, tmin, tmax),
            Traversal::Obvhs(b) => b.occluded(o, d, tmin, tmax),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fipt_core::rng::Rng;
    use fipt_core::scene::procedural::room;

    /// The traversals to test on this CPU: the wide one where it runs, and obvhs's.
    fn both(mesh: &Mesh) -> Vec<Accel> {
        let mut v = vec![Accel::build_with(mesh, false)];
        if wide::Bvh8::supported() {
            v.push(Accel::build_with(mesh, true));
        }
        v
    }

    /// The closest hit by brute force over every triangle: distance and the first triangle
    /// at it in mesh order (+inf and `u32::MAX` on a miss).
    fn brute_closest(mesh: &Mesh, o: Vec3, d: Vec3) -> (f32, u32) {
        let mut best = (f32::INFINITY, u32::MAX);
        for t in 0..mesh.num_triangles() {
            let tt =
                LeafTri::new(mesh.corners(t)).intersect(o.into(), d.into(), 0.0, f32::INFINITY);
            if tt < best.0 {
                best = (tt, t as u32);
            }
        }
        best
    }

    /// Axis-aligned rays hit the closed room in all six directions, with negative-zero
    /// components too (`-Vec3::X` is (-1, -0, -0), which obvhs alone misses).
    #[test]
    fn axis_rays_with_negative_zero_hit() {
        let r = room(Vec3::new(4.0, 2.6, 3.2), 1);
        for accel in both(&r.mesh) {
            let o = Vec3::new(1.03, 1.31, 0.57);
            for d in [Vec3::X, -Vec3::X, Vec3::Y, -Vec3::Y, Vec3::Z, -Vec3::Z] {
                let tr = accel.traversal();
                assert!(
                    accel.closest(o, d, 0.0, f32::INFINITY).is_some(),
                    "{tr} {d}"
                );
                assert!(accel.occluded(o, d, 0.0, 100.0), "{tr} {d}");
            }
        }
    }

    /// Brute force over all triangles agrees with the BVH on random rays, for both
    /// traversals.
    #[test]
    fn bvh_matches_brute_force() {
        let r = room(Vec3::new(5.0, 2.7, 4.0), 1);
        let mesh = &r.mesh;
        for accel in both(mesh) {
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
                let best = brute_closest(mesh, o, d);
                match accel.closest(o, d, 0.0, f32::INFINITY) {
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
            assert_eq!(hits, 3000, "{}", accel.traversal());
        }
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
    /// leaf test is the scalar test's arithmetic), a triangle at that distance (for the wide
    /// traversal, brute force's: the lowest index among ties), the same occlusion just before
    /// and after it; the batched query equals the single one.
    #[test]
    fn traversals_agree_with_brute_force() {
        let r = room(Vec3::new(5.0, 2.7, 4.0), 2);
        let mesh = &r.mesh;
        let accel = Accel::build(mesh);
        let reference = Accel::build_with(mesh, false);
        let (lo, hi) = mesh.bounds();
        let rays = probe_rays(lo, hi, 4000, 3);
        let mut batch = vec![None; rays.len()];
        accel.closest_many(&rays, 0.0, f32::INFINITY, &mut batch);
        let mut hits = 0;
        for (&(o, d), many) in rays.iter().zip(&batch) {
            let (want, want_tri) = brute_closest(mesh, o, d);
            let h = accel.closest(o, d, 0.0, f32::INFINITY);
            assert_eq!(h, *many, "batched query differs at {o} {d}");
            assert_eq!(
                h.map(|h| h.t),
                reference.closest(o, d, 0.0, f32::INFINITY).map(|h| h.t),
                "obvhs differs at {o} {d}"
            );
            let h = h.unwrap_or_else(|| panic!("ray {o} {d} left a closed room"));
            assert_eq!(h.t.to_bits(), want.to_bits(), "{o} {d}: {} vs {want}", h.t);
            if accel.traversal() == "avx2-bvh8" {
                // Of triangles at the same distance, the lowest index, as brute force finds.
                assert_eq!(h.tri, want_tri, "{o} {d}: triangle");
            }
            let lt = LeafTri::new(mesh.corners(h.tri as usize));
            assert_eq!(lt.intersect(o.into(), d.into(), 0.0, f32::INFINITY), h.t);
            assert!(accel.occluded(o, d, 0.0, h.t * 1.001));
            assert!(!accel.occluded(o, d, 0.0, h.t * 0.999));
            assert_eq!(
                accel.occluded(o, d, 0.0, h.t * 1.001),
                reference.occluded(o, d, 0.0, h.t * 1.001)
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
    /// distance to the bit, and the wide traversal the same triangle. (obvhs's traversal
    /// differs on about 1 ray in 20,000 here.)
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
            let best = brute_closest(mesh, o, d);
            let ht = h.map_or(f32::INFINITY, |h| h.t);
            assert_eq!(
                ht.to_bits(),
                best.0.to_bits(),
                "{o} {d}: {ht} vs {}",
                best.0
            );
            if accel.traversal() == "avx2-bvh8" {
                assert_eq!(h.map_or(u32::MAX, |h| h.tri), best.1, "{o} {d}: triangle");
            }
        }
    }
}
