//! A voxel cache in front of an expensive material source: the mean material of known surface
//! points (the training pixels' first hits, evaluated once) per voxel of a cube grid; a query
//! in a voxel that holds none goes to the wrapped source, batched. The cheap form of the
//! learned field that shading refinement queries at every path vertex.
//!
//! Owns: the per-voxel means and the split between cached and forwarded queries. Must not
//! touch: what the wrapped source computes.

use super::{MaterialSource, MaterialSum, SurfaceMaterial, query_at};
use fipt_core::scene::SceneBox;
use glam::Vec3;
use rayon::prelude::*;

/// The 26 neighbour offsets, face neighbours first.
const NEIGHBOURS: [[i64; 3]; 26] = {
    let mut out = [[0i64; 3]; 26];
    let (mut faces, mut rest) = (0, 6);
    let mut i = 0;
    while i < 27 {
        let d = [i as i64 % 3 - 1, (i as i64 / 3) % 3 - 1, i as i64 / 9 - 1];
        let nz = (d[0] != 0) as i32 + (d[1] != 0) as i32 + (d[2] != 0) as i32;
        if nz == 1 {
            out[faces] = d;
            faces += 1;
        } else if nz > 1 {
            out[rest] = d;
            rest += 1;
        }
        i += 1;
    }
    out
};

const BRICK: usize = 8;
const EMPTY: u32 = u32::MAX;

/// Sparse voxel → mean index: a table of 8³-voxel bricks over the coarse grid, bricks only
/// where some voxel holds a mean, so a lookup is two array reads (a hash map was 2× slower on
/// the 180k voxels of fipt-room).
#[derive(Default)]
struct VoxelIndex {
    per_axis: usize,
    top: Vec<u32>,
    bricks: Vec<[u32; BRICK * BRICK * BRICK]>,
}

impl VoxelIndex {
    fn new(res: usize) -> Self {
        let per_axis = res.div_ceil(BRICK);
        Self {
            per_axis,
            top: vec![EMPTY; per_axis * per_axis * per_axis],
            bricks: Vec::new(),
        }
    }

    #[inline]
    fn slot(&self, v: [usize; 3]) -> (usize, usize) {
        let b = self.per_axis;
        let top = v[0] / BRICK + b * (v[1] / BRICK + b * (v[2] / BRICK));
        let local = v[0] % BRICK + BRICK * (v[1] % BRICK + BRICK * (v[2] % BRICK));
        (top, local)
    }

    #[inline]
    fn get(&self, v: [usize; 3]) -> Option<u32> {
        let (t, l) = self.slot(v);
        let b = self.top[t];
        if b == EMPTY {
            return None;
        }
        let k = self.bricks[b as usize][l];
        (k != EMPTY).then_some(k)
    }

    fn get_or_insert(&mut self, v: [usize; 3], next: u32) -> u32 {
        let (t, l) = self.slot(v);
        if self.top[t] == EMPTY {
            self.top[t] = self.bricks.len() as u32;
            self.bricks.push([EMPTY; BRICK * BRICK * BRICK]);
        }
        let cell = &mut self.bricks[self.top[t] as usize][l];
        if *cell == EMPTY {
            *cell = next;
        }
        *cell
    }
}

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
    index: VoxelIndex,
    means: Vec<SurfaceMaterial>,
    fallback: &'a dyn MaterialSource,
    /// Triangles the fallback must always answer (e.g. emitters, which are black).
    always_forward: Vec<bool>,
    /// A point in a voxel without a mean takes a neighbouring voxel's (the 6 face neighbours,
    /// then the other 20) before it is forwarded.
    near: bool,
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
        let res = res.clamp(1, 1 << 10);
        let mut v = Self {
            scene_box,
            res,
            index: VoxelIndex::new(res),
            means: Vec::new(),
            fallback,
            always_forward,
            near: false,
        };
        let mut sums: Vec<MaterialSum> = Vec::new();
        for (p, m) in points.iter().zip(materials) {
            let key = v.key(*p);
            let k = v.index.get_or_insert(key, sums.len() as u32) as usize;
            if k == sums.len() {
                sums.push(MaterialSum::default());
            }
            sums[k].add(m);
        }
        v.means = sums.iter().map(MaterialSum::mean).collect();
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
                ((mesh.area(t) * per_area).ceil() as usize).clamp(1, 1 << 20)
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
                let mut rng = fipt_core::rng::Rng::new(seed, t as u64);
                (0..counts[t]).map(move |_| {
                    let (u, v) = (rng.next_f32(), rng.next_f32());
                    (mesh.point_at(t, u, v), t as u32)
                })
            })
            .unzip();
        debug_assert_eq!(points.len(), total);
        let mut mats = Vec::with_capacity(total);
        fallback.query(&points, &tris, &mut mats);
        let mut v = Self::build(scene_box, res, &points, &mats, fallback, always_forward);
        v.near = true;
        (v, total)
    }

    /// Voxels holding a cached mean.
    pub fn len(&self) -> usize {
        self.means.len()
    }

    pub fn is_empty(&self) -> bool {
        self.means.is_empty()
    }

    #[inline]
    fn key(&self, p: Vec3) -> [usize; 3] {
        let u = self.scene_box.to_unit(p) * self.res as f32;
        let c = |x: f32| (x.max(0.0) as usize).min(self.res - 1);
        [c(u.x), c(u.y), c(u.z)]
    }

    /// The cached mean at `p`, if its voxel has one.
    /// The cached mean at `p`, or with `near` a neighbouring voxel's.
    fn lookup(&self, p: Vec3) -> Option<SurfaceMaterial> {
        let v = self.key(p);
        if let Some(k) = self.index.get(v) {
            return Some(self.means[k as usize]);
        }
        if !self.near {
            return None;
        }
        let r = self.res as i64;
        NEIGHBOURS.iter().find_map(|d| {
            let n = [0, 1, 2].map(|a| v[a] as i64 + d[a]);
            if n.iter().any(|&x| x < 0 || x >= r) {
                return None;
            }
            self.index
                .get(n.map(|x| x as usize))
                .map(|k| self.means[k as usize])
        })
    }

    pub fn cached(&self, p: Vec3) -> Option<SurfaceMaterial> {
        self.index.get(self.key(p)).map(|k| self.means[k as usize])
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
                (!forced).then(|| self.lookup(p)).flatten()
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
        let fwd = query_at(self.fallback, points, tris, &missing);
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

    /// From a surface: the field's mean over the points spread on each voxel's patch of a
    /// quad; a point in an empty voxel next to the quad takes a neighbour's mean, a point two
    /// voxels away is forwarded; forced triangles get no points.
    #[test]
    fn from_surface_means_and_neighbours() {
        let sb = SceneBox { min: 0.0, max: 1.0 };
        // A quad at z = 0.5 over x, y ∈ [0, 1] (two triangles) and a forced triangle.
        let mesh = fipt_core::scene::Mesh::parse_obj(
            "v 0 0 0.5\nv 1 0 0.5\nv 1 1 0.5\nv 0 1 0.5\nv 0 0 0.9\nv 1 0 0.9\nv 0 1 0.9\nf 1 2 3\nf 1 3 4\nf 5 6 7\n",
        )
        .unwrap();
        let (v, n) =
            VoxelMaterials::from_surface(sb, 8, &mesh, &ByX, vec![false, false, true], 4.0, 3);
        // 2 triangles of area 0.5 at 4 points per 1/64 face area: 128 points each.
        assert_eq!(n, 256);
        assert!(v.len() > 50 && v.len() <= 64, "{}", v.len());
        let mut out = Vec::new();
        let q = [
            Vec3::new(0.30, 0.55, 0.51),  // on the quad: the voxel's mean x
            Vec3::new(0.30, 0.55, 0.70),  // one voxel above: the neighbour's
            Vec3::new(0.30, 0.55, 0.95),  // far: forwarded (exact x)
            Vec3::new(0.30, 0.55, 0.505), // forced triangle: forwarded
        ];
        v.query(&q, &[0, 0, 0, 2], &mut out);
        // Voxel x-range [0.25, 0.375): its mean x lies inside, not at the query's 0.30.
        assert!((0.25..0.375).contains(&out[0].roughness) && out[0].roughness != 0.30);
        assert_eq!(out[1].roughness, out[0].roughness);
        assert_eq!(out[2].roughness, 0.30);
        assert_eq!(out[3].roughness, 0.30);
    }
}
