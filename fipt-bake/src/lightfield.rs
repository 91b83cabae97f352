//! The voxel surface light field L′ (paper §4.2, reference §2.2): the mean HDR value of the
//! training pixels whose pixel-centre first hit falls in each voxel of a cube grid, queried at
//! the nearest voxel (0 where empty and not filled, below). View-independent; the radiance cache
//! of every later stage.
//!
//! One refinement of the reference: each voxel keeps a separate mean per *side*, the dominant
//! axis and sign of the hit's normal turned towards the viewer (6 sides). A voxel that holds two
//! surfaces (a room corner, a lamp panel on a ceiling, the front and the unseen back of a thin
//! emitter) no longer blends them: a query from a hit on one side reads that side's pixels. A
//! side nobody photographed falls back to the sides facing the same half-space (a curved
//! surface crossing a side boundary), never to the opposite side; with none, it is 0. This
//! keeps L_d from bleeding across room edges and around emitters (`docs/departures/
//! lightfield.md`).
//!
//! A second refinement: holes are filled. At the reference's 256³ the voxels are about as large
//! as a pixel's footprint, so on a low-resolution capture many voxels of photographed surfaces
//! hold no pixel centre and read 0, and surfaces no photo saw read 0 too; either darkens every
//! shading that sees them. A ring of filling gives each empty voxel next to stored ones, side by
//! side, the pooled mean of its 26 neighbours' records for that side; `HoleFill` sets how many
//! rings, and the bake confines them to the voxels the mesh passes through, so they spread
//! along the surfaces and never into the air. Observed voxels are never changed.
//!
//! Storage is sparse: a coarse table of 8³-voxel bricks, with bricks allocated only where some
//! voxel is occupied, so a query is two array reads.
//!
//! Owns: voxelisation, accumulation and queries. Must not touch: tracing.

use fipt_core::scene::SceneBox;
use glam::Vec3;

const BRICK: usize = 8;
const EMPTY: u32 = u32::MAX;
const LF_MAGIC: &[u8; 8] = b"FIPTLF01";

/// A bounds-checked little-endian cursor.
struct ByteReader<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl<'a> ByteReader<'a> {
    fn remaining(&self) -> usize {
        self.bytes.len() - self.at
    }
    fn take(&mut self, n: usize) -> Result<&'a [u8], String> {
        if n > self.remaining() {
            return Err(format!("truncated at byte {} (wanted {n} more)", self.at));
        }
        let s = &self.bytes[self.at..self.at + n];
        self.at += n;
        Ok(s)
    }
    fn u32(&mut self) -> Result<u32, String> {
        Ok(u32::from_le_bytes(
            self.take(4)?.try_into().expect("4 bytes"),
        ))
    }
    fn f32(&mut self) -> Result<f32, String> {
        Ok(f32::from_le_bytes(
            self.take(4)?.try_into().expect("4 bytes"),
        ))
    }
}

/// How L′'s holes are filled: up to `rings` rings (each fills the empty voxels next to the
/// stored ones, so a hole up to `rings` voxels from an observed voxel reads the pooled mean of
/// the records around it; 0 leaves every hole at 0), into the voxels the `surface` triangles
/// pass through where given (else into any voxel). The rings stop early once one fills
/// nothing.
#[derive(Clone, Copy, Debug)]
pub struct HoleFill<'a> {
    pub rings: usize,
    pub surface: Option<&'a [[Vec3; 3]]>,
}

impl HoleFill<'_> {
    /// One ring into any voxel.
    pub const ONE_RING: HoleFill<'static> = HoleFill {
        rings: 1,
        surface: None,
    };
}

/// L′ on a `res³` grid over a `SceneBox`.
#[derive(Clone, Debug)]
pub struct LightField {
    pub scene_box: SceneBox,
    pub res: usize,
    bricks_per_axis: usize,
    /// Brick index per coarse cell, or EMPTY.
    top: Vec<u32>,
    /// Per brick, the compact voxel index of each of its 512 voxels, or EMPTY.
    bricks: Vec<[u32; BRICK * BRICK * BRICK]>,
    /// Per occupied voxel and side (`side_of`): mean RGB radiance and, in the fourth lane, the
    /// number of pixels averaged (0 = no pixel saw this side). Inline, so a query touches one
    /// record.
    sides: Vec<[[f32; 4]; 6]>,
    /// Voxels holding at least one pixel (the first `observed` records of `sides`; the rest
    /// are filled holes).
    observed: usize,
}

/// Side of a surface by its (viewer-facing) normal: 2·axis + (component < 0).
#[inline]
pub fn side_of(n: Vec3) -> usize {
    let a = n.abs();
    let axis = if a.x >= a.y && a.x >= a.z {
        0
    } else if a.y >= a.z {
        1
    } else {
        2
    };
    2 * axis + (n[axis] < 0.0) as usize
}

/// A voxel's L′ seen from a hit with normal `n`: the side `side_of(n)`'s mean where pixels saw
/// it, else the count-weighted mean of the sides facing the same half-space, else 0.
#[inline]
fn seen_from(sides: &[[f32; 4]; 6], n: Vec3) -> Vec3 {
    let own = sides[side_of(n)];
    if own[3] > 0.0 {
        return Vec3::new(own[0], own[1], own[2]);
    }
    let (mut sum, mut weight) = (Vec3::ZERO, 0.0f32);
    for (s, r) in sides.iter().enumerate() {
        if r[3] > 0.0 && side_direction(s).dot(n) > 0.0 {
            sum += Vec3::new(r[0], r[1], r[2]) * r[3];
            weight += r[3];
        }
    }
    if weight == 0.0 {
        Vec3::ZERO
    } else {
        sum / weight
    }
}

/// Asks the cache for the line holding `x` (a hint: no effect on results).
#[inline(always)]
fn prefetch<T>(x: &T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: a prefetch reads nothing architecturally; `x` is a valid reference anyway.
    unsafe {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        _mm_prefetch::<_MM_HINT_T0>(x as *const T as *const i8);
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = x;
}

/// Unit direction of a side.
#[inline]
fn side_direction(side: usize) -> Vec3 {
    let mut d = Vec3::ZERO;
    d[side / 2] = if side.is_multiple_of(2) { 1.0 } else { -1.0 };
    d
}

impl LightField {
    /// Voxel coordinates of a point: floor((p − min)/(max − min)·res), clamped.
    #[inline]
    fn voxel(&self, p: Vec3) -> [usize; 3] {
        let u = self.scene_box.to_unit(p) * self.res as f32;
        let c = |v: f32| (v.max(0.0) as usize).min(self.res - 1);
        [c(u.x), c(u.y), c(u.z)]
    }

    #[inline]
    fn slot(&self, v: [usize; 3]) -> (usize, usize) {
        let b = self.bricks_per_axis;
        let top = (v[0] / BRICK) + b * ((v[1] / BRICK) + b * (v[2] / BRICK));
        let local = (v[0] % BRICK) + BRICK * ((v[1] % BRICK) + BRICK * (v[2] % BRICK));
        (top, local)
    }

    /// A field with no voxel (room for `capacity` records).
    fn empty(scene_box: SceneBox, res: usize, capacity: usize) -> Self {
        let bpa = res / BRICK;
        Self {
            scene_box,
            res,
            bricks_per_axis: bpa,
            top: vec![EMPTY; bpa * bpa * bpa],
            bricks: Vec::new(),
            sides: Vec::with_capacity(capacity),
            observed: 0,
        }
    }

    /// The compact-index cell of voxel `v`, its brick allocated if needed.
    fn cell_mut(&mut self, v: [usize; 3]) -> &mut u32 {
        let (t, l) = self.slot(v);
        if self.top[t] == EMPTY {
            self.top[t] = self.bricks.len() as u32;
            self.bricks.push([EMPTY; BRICK * BRICK * BRICK]);
        }
        &mut self.bricks[self.top[t] as usize][l]
    }

    /// Builds L′ from samples (first-hit position, normal facing the camera, HDR value), its
    /// holes filled with one ring.
    pub fn build(
        scene_box: SceneBox,
        res: usize,
        samples: impl IntoIterator<Item = (Vec3, Vec3, [f32; 3])>,
    ) -> Self {
        Self::build_filled(scene_box, res, HoleFill::ONE_RING, samples)
    }

    /// `build` with the hole filling `fill` (module doc).
    pub fn build_filled(
        scene_box: SceneBox,
        res: usize,
        fill: HoleFill<'_>,
        samples: impl IntoIterator<Item = (Vec3, Vec3, [f32; 3])>,
    ) -> Self {
        assert!(
            res > 0 && res.is_multiple_of(BRICK),
            "resolution must be a multiple of {BRICK}"
        );
        let mut lf = Self::empty(scene_box, res, 0);
        let mut sums: Vec<[[f64; 4]; 6]> = Vec::new();
        for (p, n, c) in samples {
            let v = lf.voxel(p);
            let cell = lf.cell_mut(v);
            if *cell == EMPTY {
                *cell = sums.len() as u32;
                sums.push([[0.0; 4]; 6]);
            }
            let acc = &mut sums[*cell as usize][side_of(n)];
            for i in 0..3 {
                acc[i] += c[i] as f64;
            }
            acc[3] += 1.0;
        }
        lf.sides = sums
            .iter()
            .map(|v| {
                v.map(|[r, g, b, n]| {
                    let k = if n > 0.0 { 1.0 / n } else { 0.0 };
                    [(r * k) as f32, (g * k) as f32, (b * k) as f32, n as f32]
                })
            })
            .collect();
        lf.observed = lf.sides.len();
        let surface = fill.surface.map(|t| lf.surface_voxels(t));
        let mut ring = lf.voxel_coords();
        for _ in 0..fill.rings {
            ring = lf.fill_holes(surface.as_ref(), &ring);
            if ring.is_empty() {
                break;
            }
        }
        lf
    }

    /// Coordinates of every stored voxel, in `sides` order.
    fn voxel_coords(&self) -> Vec<[usize; 3]> {
        let b = self.bricks_per_axis;
        let mut coords = vec![[0usize; 3]; self.sides.len()];
        for (t, &bi) in self.top.iter().enumerate() {
            if bi == EMPTY {
                continue;
            }
            let (bx, by, bz) = (t % b, (t / b) % b, t / (b * b));
            for (l, &k) in self.bricks[bi as usize].iter().enumerate() {
                if k != EMPTY {
                    let (lx, ly, lz) = (l % BRICK, (l / BRICK) % BRICK, l / (BRICK * BRICK));
                    coords[k as usize] = [bx * BRICK + lx, by * BRICK + ly, bz * BRICK + lz];
                }
            }
        }
        coords
    }

    /// Compact index of voxel `v`, if stored.
    #[inline]
    fn index_of(&self, v: [usize; 3]) -> Option<usize> {
        let (t, l) = self.slot(v);
        let b = self.top[t];
        if b == EMPTY {
            return None;
        }
        let k = self.bricks[b as usize][l];
        (k != EMPTY).then_some(k as usize)
    }

    /// Linear index of voxel `v`.
    #[inline]
    fn linear(&self, v: [usize; 3]) -> u64 {
        (v[0] + self.res * (v[1] + self.res * v[2])) as u64
    }

    /// The voxels `triangles` pass through: each triangle's points on a barycentric grid
    /// whose steps are under half a voxel.
    fn surface_voxels(&self, triangles: &[[Vec3; 3]]) -> std::collections::HashSet<u64> {
        let h = (self.scene_box.max - self.scene_box.min) / self.res as f32;
        let mut set = std::collections::HashSet::new();
        for &[a, b, c] in triangles {
            let longest = (b - a).length().max((c - a).length()).max((c - b).length());
            let n = ((longest / (0.5 * h)).ceil() as usize).clamp(1, 1 << 14);
            for i in 0..=n {
                for j in 0..=n - i {
                    let p = a + (b - a) * (i as f32 / n as f32) + (c - a) * (j as f32 / n as f32);
                    set.insert(self.linear(self.voxel(p)));
                }
            }
        }
        set
    }

    /// The 26 neighbours of voxel `v` inside the grid.
    fn neighbours(&self, v: [usize; 3]) -> impl Iterator<Item = [usize; 3]> {
        let res = self.res as i64;
        (-1i64..=1)
            .flat_map(|dz| (-1i64..=1).flat_map(move |dy| (-1i64..=1).map(move |dx| [dx, dy, dz])))
            .filter(|d| *d != [0, 0, 0])
            .filter_map(move |d| {
                let n = [0, 1, 2].map(|i| v[i] as i64 + d[i]);
                n.iter()
                    .all(|&x| (0..res).contains(&x))
                    .then(|| n.map(|x| x as usize))
            })
    }

    /// One ring of hole filling (module doc): every empty voxel among the 26 neighbours of
    /// the voxels `last` (those the previous ring stored, or the observed ones; an empty
    /// neighbour of an older voxel was filled by an earlier ring), and one the surface passes
    /// through where `surface` is given, gets per side the pooled mean of its stored
    /// neighbours' records of that side (count-weighted, so the pixels count once each).
    /// Returns the voxels filled.
    fn fill_holes(
        &mut self,
        surface: Option<&std::collections::HashSet<u64>>,
        last: &[[usize; 3]],
    ) -> Vec<[usize; 3]> {
        let mut holes: Vec<[usize; 3]> = last
            .iter()
            .flat_map(|&c| self.neighbours(c))
            .filter(|&n| {
                self.index_of(n).is_none() && surface.is_none_or(|s| s.contains(&self.linear(n)))
            })
            .collect();
        // Sorted, so the layout does not depend on the order of `last`.
        holes.sort_unstable_by_key(|v| [v[2], v[1], v[0]]);
        holes.dedup();
        let records: Vec<[[f32; 4]; 6]> = holes
            .iter()
            .map(|&v| {
                let mut a = [[0.0f64; 4]; 6];
                for k in self.neighbours(v).filter_map(|n| self.index_of(n)) {
                    for (dst, r) in a.iter_mut().zip(self.sides[k].iter()) {
                        for i in 0..3 {
                            dst[i] += (r[i] * r[3]) as f64;
                        }
                        dst[3] += r[3] as f64;
                    }
                }
                a.map(|[r, g, b, n]| {
                    let k = if n > 0.0 { 1.0 / n } else { 0.0 };
                    [(r * k) as f32, (g * k) as f32, (b * k) as f32, n as f32]
                })
            })
            .collect();
        for (&v, rec) in holes.iter().zip(records) {
            let k = self.sides.len() as u32;
            *self.cell_mut(v) = k;
            self.sides.push(rec);
        }
        holes
    }

    /// The side records of the voxel containing `p`, if occupied.
    #[inline]
    fn voxel_sides(&self, p: Vec3) -> Option<&[[f32; 4]; 6]> {
        let (t, l) = self.slot(self.voxel(p));
        let b = self.top[t];
        if b == EMPTY {
            return None;
        }
        let k = self.bricks[b as usize][l];
        (k != EMPTY).then(|| &self.sides[k as usize])
    }

    /// L′(p) seen on the side with normal `n` (turned towards the query): that side's mean;
    /// else the count-weighted mean of the voxel's sides facing the same half-space; else 0.
    #[inline]
    pub fn query(&self, p: Vec3, n: Vec3) -> Vec3 {
        match self.voxel_sides(p) {
            Some(sides) => seen_from(sides, n),
            None => Vec3::ZERO,
        }
    }

    /// `query` of every `Some((p, n))` of `queries` into `out` (same length), bit for bit; a
    /// `None` (a ray that hit nothing) reads 0. A query is three dependent reads (brick table, brick, voxel record) that mostly miss the cache
    /// on a scene-sized grid; here each block of queries takes the reads one level at a time
    /// and prefetches the next level for all of them, so their misses overlap instead of
    /// queueing. In the bake this halves the time of the lookups.
    pub fn query_many(&self, queries: &[Option<(Vec3, Vec3)>], out: &mut [Vec3]) {
        assert_eq!(queries.len(), out.len(), "query_many: one output per query");
        const BLOCK: usize = 64;
        for (qs, os) in queries.chunks(BLOCK).zip(out.chunks_mut(BLOCK)) {
            let mut at = [(EMPTY, 0u32); BLOCK];
            for (a, q) in at.iter_mut().zip(qs) {
                let Some((p, _)) = *q else { continue };
                let (t, l) = self.slot(self.voxel(p));
                let b = self.top[t];
                if b != EMPTY {
                    prefetch(&self.bricks[b as usize][l]);
                }
                *a = (b, l as u32);
            }
            let mut rec = [EMPTY; BLOCK];
            for (r, &(b, l)) in rec.iter_mut().zip(&at[..qs.len()]) {
                if b != EMPTY {
                    *r = self.bricks[b as usize][l as usize];
                    if *r != EMPTY {
                        let sides = &self.sides[*r as usize];
                        prefetch(&sides[0]);
                        prefetch(&sides[5]);
                    }
                }
            }
            for ((o, q), &r) in os.iter_mut().zip(qs).zip(&rec) {
                *o = match q {
                    Some((_, n)) if r != EMPTY => seen_from(&self.sides[r as usize], *n),
                    _ => Vec3::ZERO,
                };
            }
        }
    }

    /// Voxels holding at least one pixel.
    pub fn occupied(&self) -> usize {
        self.observed
    }

    /// Empty voxels filled from their observed neighbours.
    pub fn filled(&self) -> usize {
        self.sides.len() - self.observed
    }

    /// Bytes held by the sparse structure.
    pub fn memory_bytes(&self) -> usize {
        self.top.len() * 4
            + self.bricks.len() * BRICK * BRICK * BRICK * 4
            + self.sides.len() * std::mem::size_of::<[[f32; 4]; 6]>()
    }

    /// The compact binary form (the scene model's `lightfield.bin`): a header (magic, res, the
    /// scene box, the observed and stored voxel counts), then per stored voxel in storage order
    /// its linear index `x + res·(y + res·z)`, a byte with one bit per side that holds pixels,
    /// and per such side the mean RGB as f16 and the pixel count as f32. Sides nobody saw are
    /// not stored: on fipt-room this is about 10× smaller than the in-memory records.
    pub fn to_bytes(&self) -> Vec<u8> {
        let coords = self.voxel_coords();
        let mut out = Vec::with_capacity(28 + self.sides.len() * 16);
        out.extend_from_slice(LF_MAGIC);
        for v in [
            self.res as u32,
            self.observed as u32,
            self.sides.len() as u32,
        ] {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out.extend_from_slice(&self.scene_box.min.to_le_bytes());
        out.extend_from_slice(&self.scene_box.max.to_le_bytes());
        for (rec, c) in self.sides.iter().zip(&coords) {
            let idx = self.linear(*c) as u32;
            out.extend_from_slice(&idx.to_le_bytes());
            let mask = rec
                .iter()
                .enumerate()
                .filter(|(_, r)| r[3] > 0.0)
                .fold(0u8, |m, (s, _)| m | (1 << s));
            out.push(mask);
            for r in rec.iter().filter(|r| r[3] > 0.0) {
                for &x in &r[..3] {
                    out.extend_from_slice(&half::f16::from_f32(x).to_le_bytes());
                }
                out.extend_from_slice(&r[3].to_le_bytes());
            }
        }
        out
    }

    /// Reads `to_bytes`' form. Every size field is checked against the bytes present before
    /// anything is allocated; the error says what is wrong (the caller names the file).
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, String> {
        let mut r = ByteReader { bytes, at: 0 };
        if r.take(LF_MAGIC.len())? != LF_MAGIC {
            return Err("not a fipt light field (bad magic)".into());
        }
        let res = r.u32()? as usize;
        let observed = r.u32()? as usize;
        let n = r.u32()? as usize;
        let scene_box = SceneBox {
            min: r.f32()?,
            max: r.f32()?,
        };
        if res == 0 || !res.is_multiple_of(BRICK) || res > 4096 {
            return Err(format!(
                "resolution {res} is not a multiple of {BRICK} in 8..=4096"
            ));
        }
        if !(scene_box.min.is_finite()
            && scene_box.max.is_finite()
            && scene_box.min < scene_box.max)
        {
            return Err(format!(
                "bad scene box [{}, {}]",
                scene_box.min, scene_box.max
            ));
        }
        // Each voxel takes at least 5 bytes.
        if n > r.remaining() / 5 || observed > n {
            return Err(format!(
                "{n} voxels ({observed} observed) do not fit in {} bytes",
                r.remaining()
            ));
        }
        let mut lf = Self::empty(scene_box, res, n);
        lf.observed = observed;
        for k in 0..n {
            let idx = r.u32()? as usize;
            if idx >= res * res * res {
                return Err(format!("voxel {k}: index {idx} outside the {res}³ grid"));
            }
            let v = [idx % res, (idx / res) % res, idx / (res * res)];
            let mask = r.take(1)?[0];
            if mask >> 6 != 0 {
                return Err(format!("voxel {k}: bad side mask {mask:#x}"));
            }
            let mut rec = [[0.0f32; 4]; 6];
            for (s, slot) in rec.iter_mut().enumerate() {
                if mask & (1 << s) == 0 {
                    continue;
                }
                for c in slot.iter_mut().take(3) {
                    let b = r.take(2)?;
                    *c = half::f16::from_le_bytes([b[0], b[1]]).to_f32();
                }
                slot[3] = r.f32()?;
                if !(slot.iter().all(|x| x.is_finite() && *x >= 0.0) && slot[3] > 0.0) {
                    return Err(format!("voxel {k}: bad record {slot:?}"));
                }
            }
            let k = lf.sides.len() as u32;
            let cell = lf.cell_mut(v);
            if *cell != EMPTY {
                return Err(format!("voxel {k}: index {idx} stored twice"));
            }
            *cell = k;
            lf.sides.push(rec);
        }
        if r.remaining() != 0 {
            return Err(format!("{} trailing bytes", r.remaining()));
        }
        Ok(lf)
    }

    /// A light field with the same value everywhere it is occupied (tests, furnaces).
    pub fn fill(&mut self, value: [f32; 3]) {
        for v in &mut self.sides {
            for r in v.iter_mut().filter(|r| r[3] > 0.0) {
                r[..3].copy_from_slice(&value);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn voxel_means_and_empty_queries() {
        let b = SceneBox { min: 0.0, max: 1.0 };
        let up = Vec3::Y;
        let lf = LightField::build(
            b,
            16,
            vec![
                (Vec3::new(0.01, 0.01, 0.01), up, [1.0, 2.0, 3.0]),
                (Vec3::new(0.05, 0.02, 0.03), up, [3.0, 2.0, 1.0]),
                (Vec3::new(0.9, 0.9, 0.9), up, [5.0, 5.0, 5.0]),
                (Vec3::new(2.0, -1.0, 0.5), up, [7.0, 7.0, 7.0]), // clamped into a border voxel
            ],
        );
        assert_eq!(lf.occupied(), 3);
        assert_eq!(lf.query(Vec3::new(0.03, 0.03, 0.03), up), Vec3::splat(2.0));
        assert_eq!(lf.query(Vec3::new(0.92, 0.88, 0.9), up), Vec3::splat(5.0));
        assert_eq!(lf.query(Vec3::new(0.5, 0.5, 0.5), up), Vec3::ZERO);
        assert_eq!(lf.query(Vec3::new(0.999, 0.0, 0.5), up), Vec3::splat(7.0));
    }

    /// The binary form reads back to the same queries (up to f16 rounding of the means) and
    /// the same counts; every truncation and any byte flip in the header is an error or a
    /// valid field, never a panic.
    #[test]
    fn bytes_round_trip_and_reject_damage() {
        let b = SceneBox {
            min: -1.0,
            max: 2.0,
        };
        let mut samples = Vec::new();
        let mut rng = fipt_core::rng::Rng::new(7, 1);
        for i in 0..400 {
            let p = Vec3::new(
                rng.next_f32() * 3.0 - 1.0,
                rng.next_f32() * 3.0 - 1.0,
                rng.next_f32() * 3.0 - 1.0,
            );
            let n = [Vec3::X, -Vec3::Y, Vec3::Z][i % 3];
            samples.push((p, n, [rng.next_f32() * 50.0, 1.0, 0.5]));
        }
        let lf = LightField::build(b, 32, samples.clone());
        let bytes = lf.to_bytes();
        let back = LightField::from_bytes(&bytes).unwrap();
        assert_eq!(
            (back.occupied(), back.filled()),
            (lf.occupied(), lf.filled())
        );
        for (p, _, _) in &samples {
            for n in [Vec3::X, -Vec3::X, Vec3::Y, -Vec3::Y, Vec3::Z, -Vec3::Z] {
                let (a, c) = (lf.query(*p, n), back.query(*p, n));
                assert!(
                    (a - c).abs().max_element() <= 1e-3 * a.max_element().max(1.0),
                    "{a} {c}"
                );
            }
        }
        for cut in [0, 7, 8, 20, 27, bytes.len() / 2, bytes.len() - 1] {
            assert!(LightField::from_bytes(&bytes[..cut]).is_err(), "cut {cut}");
        }
        for at in 0..28 {
            let mut d = bytes.clone();
            d[at] ^= 0x5a;
            let _ = LightField::from_bytes(&d);
        }
        let mut long = bytes.clone();
        long.push(0);
        assert!(LightField::from_bytes(&long).is_err());
    }

    /// A voxel between observed ones reads the pooled mean of its neighbours, side by side; a
    /// voxel two rings away stays empty; observed voxels keep their own mean.
    #[test]
    fn holes_take_their_neighbours_pooled_mean() {
        let b = SceneBox { min: 0.0, max: 1.0 };
        let v = |i: f32| Vec3::new((i + 0.5) / 16.0, 0.5 / 16.0, 0.5 / 16.0);
        let lf = LightField::build(
            b,
            16,
            vec![
                (v(3.0), Vec3::Y, [1.0; 3]),
                (v(3.0), Vec3::Y, [1.0; 3]),
                (v(5.0), Vec3::Y, [4.0; 3]),
                (v(5.0), Vec3::X, [9.0; 3]),
            ],
        );
        assert_eq!(lf.occupied(), 2);
        assert_eq!(lf.query(v(3.0), Vec3::Y), Vec3::splat(1.0));
        // Voxel 4 sits between them: (1 + 1 + 4) / 3 on +y, and 9 on +x.
        assert!(
            (lf.query(v(4.0), Vec3::Y) - Vec3::splat(2.0))
                .abs()
                .max_element()
                < 1e-6
        );
        assert_eq!(lf.query(v(4.0), Vec3::X), Vec3::splat(9.0));
        // Its unseen −y side stays dark.
        assert_eq!(lf.query(v(4.0), -Vec3::Y), Vec3::ZERO);
        // One ring only.
        assert_eq!(lf.query(v(1.0), Vec3::Y), Vec3::ZERO);
        assert_eq!(lf.query(v(2.0), Vec3::Y), Vec3::splat(1.0));
        // 26-neighbourhood of each observed voxel, shared cells counted once: 3×3 columns
        // x ∈ 2..=6, y ∈ 0..=1, z ∈ 0..=1 minus the two observed ones.
        assert_eq!(lf.filled(), 5 * 2 * 2 - 2);
    }

    /// Rings on a surface: a hole several voxels along a photographed floor from the nearest
    /// observed voxel is filled with the rings needed to reach it, and not with fewer; the
    /// voxels off the floor stay empty; the rings stop once one fills nothing.
    #[test]
    fn rings_fill_along_the_surface_only() {
        let b = SceneBox { min: 0.0, max: 1.0 };
        // A floor y = 0.5/16 over x, z in [0, 1]: two triangles; pixels seen at x voxel 2 only.
        let y = 0.5 / 16.0;
        let floor = [
            [
                Vec3::new(0.0, y, 0.0),
                Vec3::new(1.0, y, 0.0),
                Vec3::new(1.0, y, 1.0),
            ],
            [
                Vec3::new(0.0, y, 0.0),
                Vec3::new(1.0, y, 1.0),
                Vec3::new(0.0, y, 1.0),
            ],
        ];
        let at = |x: f32, z: f32| Vec3::new((x + 0.5) / 16.0, y, (z + 0.5) / 16.0);
        let samples: Vec<_> = (0..16)
            .map(|z| (at(2.0, z as f32), Vec3::Y, [3.0; 3]))
            .collect();
        let build = |rings| {
            LightField::build_filled(
                b,
                16,
                HoleFill {
                    rings,
                    surface: Some(&floor),
                },
                samples.clone(),
            )
        };
        // Voxel x = 9 is 7 rings away.
        assert_eq!(build(6).query(at(9.0, 4.0), Vec3::Y), Vec3::ZERO);
        let lf = build(7);
        assert_eq!(lf.query(at(9.0, 4.0), Vec3::Y), Vec3::splat(3.0));
        // Above the floor: nothing filled (unrestricted, one ring fills the voxels above it).
        let above = Vec3::new(2.5 / 16.0, 1.5 / 16.0, 4.5 / 16.0);
        assert_eq!(lf.query(above, Vec3::Y), Vec3::ZERO);
        let loose = LightField::build_filled(b, 16, HoleFill::ONE_RING, samples.clone());
        assert_eq!(loose.query(above, Vec3::Y), Vec3::splat(3.0));
        // The whole floor row of voxels is 16 × 16, 16 of them observed.
        let all = build(64);
        assert_eq!(all.filled(), 16 * 16 - 16);
    }

    /// The batched query is the single one, bit for bit, on 1000 queries (several blocks and
    /// a partial one): occupied, filled and empty voxels, empty bricks, points outside the box
    /// (clamped), own sides and half-space fallbacks; a missing query reads 0.
    #[test]
    fn batched_queries_equal_single_ones() {
        let b = SceneBox { min: 0.0, max: 1.0 };
        let mut rng = fipt_core::rng::Rng::new(3, 9);
        let dirs = [Vec3::X, -Vec3::Y, Vec3::Z, -Vec3::X];
        // Observed points only in one corner (x, y, z < 0.3): most bricks stay empty.
        let samples: Vec<_> = (0..300)
            .map(|i| {
                let p = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 0.3;
                (p, dirs[i % 4], [rng.next_f32() * 9.0, 1.0 + i as f32, 0.25])
            })
            .collect();
        let lf = LightField::build(b, 64, samples);
        // Every seventh query is a miss (None), which reads 0.
        let queries: Vec<Option<(Vec3, Vec3)>> = (0..1000)
            .map(|i| {
                let p = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 0.5 - 0.05;
                let n = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 2.0 - 1.0;
                (i % 7 != 3).then(|| (p, n.normalize()))
            })
            .collect();
        let mut out = vec![Vec3::splat(-1.0); queries.len()];
        lf.query_many(&queries, &mut out);
        let mut lit = 0;
        for (q, o) in queries.iter().zip(&out) {
            let want = q.map_or(Vec3::ZERO, |(p, n)| lf.query(p, n));
            assert_eq!(
                o.to_array().map(f32::to_bits),
                want.to_array().map(f32::to_bits)
            );
            lit += (want != Vec3::ZERO) as usize;
        }
        // Both kinds occur: lit voxels and dark (empty or unseen) ones.
        assert!(lit > 50 && lit < 950, "{lit} of 1000 lit");
    }

    /// Two surfaces in one voxel keep their own means; an unseen back side reads 0, a tilted
    /// query reads the sides of its half-space.
    #[test]
    fn sides_are_kept_apart() {
        let b = SceneBox { min: 0.0, max: 1.0 };
        let p = Vec3::splat(0.5);
        let lf = LightField::build(
            b,
            8,
            vec![
                (p, -Vec3::Y, [16.0; 3]), // a lamp panel facing down
                (p, -Vec3::Y, [16.0; 3]),
                (p, Vec3::X, [0.5; 3]), // a wall in the same voxel
            ],
        );
        assert_eq!(lf.occupied(), 1);
        assert_eq!(lf.query(p, -Vec3::Y), Vec3::splat(16.0));
        assert_eq!(lf.query(p, Vec3::X), Vec3::splat(0.5));
        // The panel's back (facing up) was never photographed.
        assert_eq!(lf.query(p, Vec3::Y), Vec3::ZERO);
        // Facing −x: neither stored side (−y, +x) faces its half-space: 0.
        assert_eq!(lf.query(p, -Vec3::X), Vec3::ZERO);
        // Tilted between −y and +x, dominant +z: both the panel and the wall qualify.
        let tilted = Vec3::new(0.3, -0.3, 0.9).normalize();
        let want = (16.0 * 2.0 + 0.5) / 3.0;
        assert!(
            (lf.query(p, tilted) - Vec3::splat(want))
                .abs()
                .max_element()
                < 1e-5
        );
    }
}
