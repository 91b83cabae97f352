//! The voxel surface light field L′ (paper §4.2, reference §2.2): the mean HDR value of the
//! training pixels whose pixel-centre first hit falls in each voxel of a cube grid, queried at
//! the nearest voxel (0 where empty). View-independent; the radiance cache of every later stage.
//!
//! Storage is sparse: a coarse table of 8³-voxel bricks, with bricks allocated only where some
//! voxel is occupied, so a query is two array reads.
//!
//! Owns: the bounding cube, voxelisation, accumulation and queries. Must not touch: tracing.

use glam::Vec3;

const BRICK: usize = 8;
const EMPTY: u32 = u32::MAX;

/// The reference's scene cube: the scalar min and max over all coordinates of all first hits,
/// each scaled by 1.1 (`voxel_min = 1.1·min`, `voxel_max = 1.1·max`; the same box normalises
/// positions for the hash grid).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SceneBox {
    pub min: f32,
    pub max: f32,
}

impl SceneBox {
    pub fn from_points<'a>(points: impl IntoIterator<Item = &'a Vec3>) -> Self {
        let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
        for p in points {
            lo = lo.min(p.min_element());
            hi = hi.max(p.max_element());
        }
        Self {
            min: 1.1 * lo,
            max: 1.1 * hi,
        }
    }

    /// Position mapped to the unit cube (not clamped).
    #[inline]
    pub fn to_unit(&self, p: Vec3) -> Vec3 {
        (p - Vec3::splat(self.min)) / (self.max - self.min)
    }
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
    /// Mean radiance per occupied voxel.
    pub radiance: Vec<[f32; 3]>,
    /// Number of pixels averaged per occupied voxel.
    pub count: Vec<u32>,
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

    /// Builds L′ from samples (first-hit position, HDR value).
    pub fn build(
        scene_box: SceneBox,
        res: usize,
        samples: impl IntoIterator<Item = (Vec3, [f32; 3])>,
    ) -> Self {
        assert!(
            res > 0 && res.is_multiple_of(BRICK),
            "resolution must be a multiple of {BRICK}"
        );
        let bpa = res / BRICK;
        let mut lf = Self {
            scene_box,
            res,
            bricks_per_axis: bpa,
            top: vec![EMPTY; bpa * bpa * bpa],
            bricks: Vec::new(),
            radiance: Vec::new(),
            count: Vec::new(),
        };
        let mut sums: Vec<[f64; 3]> = Vec::new();
        for (p, c) in samples {
            let (t, l) = lf.slot(lf.voxel(p));
            if lf.top[t] == EMPTY {
                lf.top[t] = lf.bricks.len() as u32;
                lf.bricks.push([EMPTY; BRICK * BRICK * BRICK]);
            }
            let brick = &mut lf.bricks[lf.top[t] as usize];
            if brick[l] == EMPTY {
                brick[l] = sums.len() as u32;
                sums.push([0.0; 3]);
                lf.count.push(0);
            }
            let k = brick[l] as usize;
            for i in 0..3 {
                sums[k][i] += c[i] as f64;
            }
            lf.count[k] += 1;
        }
        lf.radiance = sums
            .iter()
            .zip(&lf.count)
            .map(|(s, &n)| {
                let n = n as f64;
                [(s[0] / n) as f32, (s[1] / n) as f32, (s[2] / n) as f32]
            })
            .collect();
        lf
    }

    /// Compact index of the voxel containing `p`, if occupied.
    #[inline]
    pub fn index(&self, p: Vec3) -> Option<usize> {
        let (t, l) = self.slot(self.voxel(p));
        let b = self.top[t];
        if b == EMPTY {
            return None;
        }
        let k = self.bricks[b as usize][l];
        (k != EMPTY).then_some(k as usize)
    }

    /// L′(p): the voxel mean, 0 where empty.
    #[inline]
    pub fn query(&self, p: Vec3) -> Vec3 {
        self.index(p)
            .map_or(Vec3::ZERO, |k| Vec3::from(self.radiance[k]))
    }

    pub fn occupied(&self) -> usize {
        self.radiance.len()
    }

    /// Bytes held by the sparse structure.
    pub fn memory_bytes(&self) -> usize {
        self.top.len() * 4
            + self.bricks.len() * BRICK * BRICK * BRICK * 4
            + self.radiance.len() * 12
            + self.count.len() * 4
    }

    /// A light field with the same value everywhere it is occupied (tests, furnaces).
    pub fn fill(&mut self, value: [f32; 3]) {
        self.radiance.iter_mut().for_each(|r| *r = value);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn voxel_means_and_empty_queries() {
        let b = SceneBox { min: 0.0, max: 1.0 };
        let lf = LightField::build(
            b,
            16,
            vec![
                (Vec3::new(0.01, 0.01, 0.01), [1.0, 2.0, 3.0]),
                (Vec3::new(0.05, 0.02, 0.03), [3.0, 2.0, 1.0]),
                (Vec3::new(0.9, 0.9, 0.9), [5.0, 5.0, 5.0]),
                (Vec3::new(2.0, -1.0, 0.5), [7.0, 7.0, 7.0]), // clamped into a border voxel
            ],
        );
        assert_eq!(lf.occupied(), 3);
        assert_eq!(lf.query(Vec3::new(0.03, 0.03, 0.03)), Vec3::splat(2.0));
        assert_eq!(lf.query(Vec3::new(0.92, 0.88, 0.9)), Vec3::splat(5.0));
        assert_eq!(lf.query(Vec3::new(0.5, 0.5, 0.5)), Vec3::ZERO);
        assert_eq!(lf.query(Vec3::new(0.999, 0.0, 0.5)), Vec3::splat(7.0));
        let sb = SceneBox::from_points(&[Vec3::new(0.0, 1.0, 2.0), Vec3::new(5.0, 2.7, 4.0)]);
        assert_eq!(sb, SceneBox { min: 0.0, max: 5.5 });
    }
}
