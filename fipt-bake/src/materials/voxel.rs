//! A voxel cache in front of an expensive material source: the mean material of known surface
//! points (the training pixels' first hits, evaluated once) per voxel of a cube grid; a query
//! in a voxel that holds none goes to the wrapped source, batched. The cheap form of the
//! learned field that shading refinement queries at every path vertex.
//!
//! Owns: the per-voxel means and the split between cached and forwarded queries. Must not
//! touch: what the wrapped source computes.

use super::{MaterialSource, SurfaceMaterial};
use fipt_core::scene::SceneBox;
use glam::Vec3;
use rayon::prelude::*;
use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

/// A multiplicative hash for voxel indices (std's SipHash is several times slower here, and
/// the keys are not attacker-controlled).
#[derive(Default)]
struct VoxelHasher(u64);

impl Hasher for VoxelHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0 ^ b as u64).wrapping_mul(0x0100_0000_01b3);
        }
    }
    fn write_u32(&mut self, k: u32) {
        self.0 = (k as u64)
            .wrapping_mul(0x9e37_79b9_7f4a_7c15)
            .rotate_left(29);
    }
}

type VoxelMap = HashMap<u32, u32, BuildHasherDefault<VoxelHasher>>;

/// Marks a point the cache does not answer (a roughness no material has).
const MISSING: SurfaceMaterial = SurfaceMaterial {
    base_color: Vec3::ZERO,
    roughness: f32::NAN,
    metallic: 0.0,
};

/// Per-voxel mean materials over a `res³` grid, with a fallback source.
pub struct VoxelMaterials<'a> {
    scene_box: SceneBox,
    res: usize,
    index: VoxelMap,
    means: Vec<SurfaceMaterial>,
    fallback: &'a dyn MaterialSource,
    /// Triangles the fallback must always answer (e.g. emitters, which are black).
    always_forward: Vec<bool>,
}

impl<'a> VoxelMaterials<'a> {
    /// Averages `materials[i]` at `points[i]` per voxel.
    pub fn build(
        scene_box: SceneBox,
        res: usize,
        points: &[Vec3],
        materials: &[SurfaceMaterial],
        fallback: &'a dyn MaterialSource,
        always_forward: Vec<bool>,
    ) -> Self {
        let mut v = Self {
            scene_box,
            res: res.clamp(1, 1 << 10),
            index: VoxelMap::default(),
            means: Vec::new(),
            fallback,
            always_forward,
        };
        let mut sums: Vec<([f64; 5], u32)> = Vec::new();
        for (p, m) in points.iter().zip(materials) {
            let key = v.key(*p);
            let k = *v.index.entry(key).or_insert_with(|| {
                sums.push(([0.0; 5], 0));
                (sums.len() - 1) as u32
            }) as usize;
            let s = &mut sums[k];
            for (c, x) in [
                m.base_color.x,
                m.base_color.y,
                m.base_color.z,
                m.roughness,
                m.metallic,
            ]
            .into_iter()
            .enumerate()
            {
                s.0[c] += x as f64;
            }
            s.1 += 1;
        }
        v.means = sums
            .iter()
            .map(|(s, n)| {
                let f = |c: usize| (s[c] / *n as f64) as f32;
                SurfaceMaterial {
                    base_color: Vec3::new(f(0), f(1), f(2)),
                    roughness: f(3),
                    metallic: f(4),
                }
            })
            .collect();
        v
    }

    /// Averages `fallback`'s materials over points spread on `mesh`'s surface: per triangle
    /// (not flagged in `always_forward`) ⌈area · `per_voxel` / voxel face area⌉ uniform points,
    /// so every voxel a surface crosses gets about `per_voxel` of them; deterministic in
    /// `seed`. The cheap form of a material field on a scene without training pixels (a
    /// loaded scene model). Returns the cache and the number of points evaluated.
    pub fn from_surface(
        scene_box: SceneBox,
        res: usize,
        mesh: &fipt_core::scene::Mesh,
        fallback: &'a dyn MaterialSource,
        always_forward: Vec<bool>,
        per_voxel: f32,
        seed: u64,
    ) -> (Self, usize) {
        let cell = (scene_box.max - scene_box.min) / res.max(1) as f32;
        let per_area = per_voxel / (cell * cell);
        let counts: Vec<usize> = (0..mesh.num_triangles())
            .map(|t| {
                if always_forward.get(t).copied().unwrap_or(false) {
                    return 0;
                }
                let [a, b, c] = mesh.corners(t);
                let area = 0.5 * (b - a).cross(c - a).length();
                ((area * per_area).ceil() as usize).clamp(1, 1 << 20)
            })
            .collect();
        let mut offsets = Vec::with_capacity(counts.len() + 1);
        offsets.push(0usize);
        for c in &counts {
            offsets.push(offsets.last().copied().unwrap_or(0) + c);
        }
        let total = offsets.last().copied().unwrap_or(0);
        let (points, tris): (Vec<Vec3>, Vec<u32>) = (0..mesh.num_triangles())
            .into_par_iter()
            .flat_map_iter(|t| {
                let [a, b, c] = mesh.corners(t);
                let mut rng = fipt_core::rng::Rng::new(seed, t as u64);
                (0..counts[t]).map(move |_| {
                    let (mut u, mut v) = (rng.next_f32(), rng.next_f32());
                    if u + v > 1.0 {
                        (u, v) = (1.0 - u, 1.0 - v);
                    }
                    (a + (b - a) * u + (c - a) * v, t as u32)
                })
            })
            .unzip();
        debug_assert_eq!(points.len(), total);
        let mut mats = Vec::with_capacity(total);
        fallback.query(&points, &tris, &mut mats);
        (
            Self::build(scene_box, res, &points, &mats, fallback, always_forward),
            total,
        )
    }

    /// Voxels holding a cached mean.
    pub fn len(&self) -> usize {
        self.means.len()
    }

    pub fn is_empty(&self) -> bool {
        self.means.is_empty()
    }

    #[inline]
    fn key(&self, p: Vec3) -> u32 {
        let u = self.scene_box.to_unit(p) * self.res as f32;
        let c = |x: f32| (x.max(0.0) as usize).min(self.res - 1) as u32;
        let r = self.res as u32;
        c(u.x) + r * (c(u.y) + r * c(u.z))
    }

    /// The cached mean at `p`, if its voxel has one.
    pub fn cached(&self, p: Vec3) -> Option<SurfaceMaterial> {
        self.index
            .get(&self.key(p))
            .map(|&k| self.means[k as usize])
    }
}

impl MaterialSource for VoxelMaterials<'_> {
    fn query(&self, points: &[Vec3], tris: &[u32], out: &mut Vec<SurfaceMaterial>) {
        out.clear();
        points
            .par_iter()
            .zip(tris)
            .with_min_len(4096)
            .map(|(&p, &t)| {
                let forced = self
                    .always_forward
                    .get(t as usize)
                    .copied()
                    .unwrap_or(false);
                (!forced).then(|| self.cached(p)).flatten()
            })
            .map(|m| m.unwrap_or(MISSING))
            .collect_into_vec(out);
        let missing: Vec<usize> = out
            .iter()
            .enumerate()
            .filter(|(_, m)| m.roughness.is_nan())
            .map(|(i, _)| i)
            .collect();
        if missing.is_empty() {
            return;
        }
        let (mp, mt): (Vec<Vec3>, Vec<u32>) = missing.iter().map(|&i| (points[i], tris[i])).unzip();
        let mut fwd = Vec::with_capacity(missing.len());
        self.fallback.query(&mp, &mt, &mut fwd);
        for (&i, m) in missing.iter().zip(fwd) {
            out[i] = m;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Roughness = x coordinate, so a query tells which source answered.
    struct ByX;
    impl MaterialSource for ByX {
        fn query(&self, points: &[Vec3], _tris: &[u32], out: &mut Vec<SurfaceMaterial>) {
            out.clear();
            out.extend(points.iter().map(|p| SurfaceMaterial {
                base_color: Vec3::ONE,
                roughness: p.x,
                metallic: 0.0,
            }));
        }
    }

    #[test]
    fn means_per_voxel_and_forwarding() {
        let sb = SceneBox { min: 0.0, max: 1.0 };
        let m = |r: f32| SurfaceMaterial {
            base_color: Vec3::splat(r),
            roughness: r,
            metallic: 1.0 - r,
        };
        // Two points in voxel (0,0,0) of a 4³ grid, one in voxel (3,3,3).
        let pts = [Vec3::splat(0.05), Vec3::splat(0.2), Vec3::splat(0.9)];
        let mats = [m(0.2), m(0.6), m(0.9)];
        let src = ByX;
        let v = VoxelMaterials::build(sb, 4, &pts, &mats, &src, vec![false, true]);
        assert_eq!(v.len(), 2);
        let q = [
            Vec3::new(0.1, 0.1, 0.1),   // cached: mean of 0.2 and 0.6
            Vec3::new(0.6, 0.1, 0.1),   // empty voxel: forwarded
            Vec3::new(0.95, 0.8, 0.76), // cached 0.9
            Vec3::new(0.1, 0.1, 0.1),   // cached voxel but a forced triangle
        ];
        let mut out = Vec::new();
        v.query(&q, &[0, 0, 0, 1], &mut out);
        assert!((out[0].roughness - 0.4).abs() < 1e-6);
        assert!((out[0].metallic - 0.6).abs() < 1e-6);
        assert!((out[0].base_color.x - 0.4).abs() < 1e-6);
        assert_eq!(out[1].roughness, 0.6);
        assert!((out[2].roughness - 0.9).abs() < 1e-6);
        assert_eq!(out[3].roughness, 0.1);
    }
}
