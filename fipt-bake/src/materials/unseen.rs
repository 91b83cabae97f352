//! Points no photo saw read their part's mean material: a coarse grid marks the cells that hold
//! a known surface point (a training pixel's first hit); a query on a triangle whose part has
//! known points, in a cell that holds none, gets the mean of that part's known materials; every
//! other query goes to the wrapped source, batched. A fitted field is only constrained where
//! photos saw the surface; elsewhere (under a table, behind a counter) it keeps what it was
//! initialised to, and a path that reflects off such a point reads that instead of the part.
//!
//! Owns: the seen cells, the part means and the split of a query. Must not touch: what the
//! wrapped source computes.

use super::{MaterialSource, MaterialSum, SurfaceMaterial, query_at};
use fipt_core::scene::SceneBox;
use glam::Vec3;
use std::collections::HashMap;

pub struct Unseen<'a> {
    inner: &'a dyn MaterialSource,
    scene_box: SceneBox,
    /// Cells per axis of the seen grid.
    cells: usize,
    seen: Vec<bool>,
    /// Per triangle, its part's mean (None: forwarded).
    mean_of: Vec<Option<SurfaceMaterial>>,
}

impl<'a> Unseen<'a> {
    /// `materials[i]` of the known point `points[i]` on triangle `tris[i]`, averaged per part
    /// (`part_keys`, per triangle); `cells` per axis over `scene_box`. Triangles flagged in
    /// `forward` (e.g. emitters, which are black) always read `inner` and add nothing to a
    /// mean; their points still mark their cells seen.
    pub fn build(
        scene_box: SceneBox,
        cells: usize,
        (points, tris, materials): (&[Vec3], &[u32], &[SurfaceMaterial]),
        part_keys: &[u64],
        forward: &[bool],
        inner: &'a dyn MaterialSource,
    ) -> Self {
        let cells = cells.clamp(1, 1 << 10);
        let mut u = Self {
            inner,
            scene_box,
            cells,
            seen: vec![false; cells * cells * cells],
            mean_of: Vec::new(),
        };
        let forwarded = |t: usize| forward.get(t).copied().unwrap_or(false);
        let mut sums: HashMap<u64, MaterialSum> = HashMap::new();
        for ((&p, &t), m) in points.iter().zip(tris).zip(materials) {
            let c = u.cell(p);
            u.seen[c] = true;
            if let Some(&key) = part_keys.get(t as usize)
                && !forwarded(t as usize)
            {
                sums.entry(key).or_default().add(m);
            }
        }
        u.mean_of = part_keys
            .iter()
            .enumerate()
            .map(|(t, key)| {
                let sum = sums.get(key).filter(|_| !forwarded(t));
                sum.map(MaterialSum::mean)
            })
            .collect();
        u
    }

    fn cell(&self, p: Vec3) -> usize {
        let x = self.scene_box.to_unit(p) * self.cells as f32;
        let c = |v: f32| (v.max(0.0) as usize).min(self.cells - 1);
        c(x.x) + self.cells * (c(x.y) + self.cells * c(x.z))
    }

    /// The part mean a query at `p` on triangle `t` reads, if it reads one.
    fn mean_at(&self, p: Vec3, t: u32) -> Option<SurfaceMaterial> {
        let m = (*self.mean_of.get(t as usize)?)?;
        (!self.seen[self.cell(p)]).then_some(m)
    }
}

impl MaterialSource for Unseen<'_> {
    fn query(&self, points: &[Vec3], tris: &[u32], out: &mut Vec<SurfaceMaterial>) {
        out.clear();
        let own: Vec<Option<SurfaceMaterial>> = points
            .iter()
            .zip(tris)
            .map(|(&p, &t)| self.mean_at(p, t))
            .collect();
        let fwd: Vec<usize> = (0..own.len()).filter(|&i| own[i].is_none()).collect();
        let mut next = query_at(self.inner, points, tris, &fwd).into_iter();
        out.extend(
            own.into_iter()
                .map(|m| m.or_else(|| next.next()).unwrap_or(SurfaceMaterial::BLACK)),
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Roughness 0.9 and the query's x as base colour, so a query tells which source answered.
    struct Field;
    impl MaterialSource for Field {
        fn query(&self, p: &[Vec3], _t: &[u32], out: &mut Vec<SurfaceMaterial>) {
            out.clear();
            out.extend(p.iter().map(|x| SurfaceMaterial {
                base_color: Vec3::splat(x.x),
                roughness: 0.9,
                metallic: 0.5,
            }));
        }
    }

    fn mat(r: f32, m: f32) -> SurfaceMaterial {
        SurfaceMaterial {
            base_color: Vec3::splat(0.5),
            roughness: r,
            metallic: m,
        }
    }

    /// Two parts (triangles 0–1 and 2) with known points in the cells at x < 0.25; triangle 3
    /// has no part mean, triangle 1 is forwarded: an unseen point on a part with known points
    /// reads the part's mean, a seen one or one without a mean reads the field, in order.
    #[test]
    fn unseen_points_read_their_parts_mean() {
        let sb = SceneBox { min: 0.0, max: 1.0 };
        let known = [Vec3::new(0.1, 0.1, 0.1), Vec3::new(0.2, 0.1, 0.1)];
        let u = Unseen::build(
            sb,
            4,
            (&known, &[0, 2], &[mat(0.2, 1.0), mat(0.4, 0.0)]),
            &[7, 7, 9, 11],
            &[false, true, false, false],
            &Field,
        );
        let far = Vec3::new(0.9, 0.9, 0.9);
        let near = Vec3::new(0.15, 0.2, 0.05);
        let q = [(far, 0), (near, 0), (far, 1), (far, 2), (far, 3), (near, 2)];
        let (pts, tris): (Vec<Vec3>, Vec<u32>) = q.iter().copied().unzip();
        let mut out = Vec::new();
        u.query(&pts, &tris, &mut out);
        let got: Vec<(f32, f32)> = out.iter().map(|m| (m.roughness, m.metallic)).collect();
        assert_eq!(
            got,
            [
                (0.2, 1.0),
                (0.9, 0.5),
                (0.9, 0.5),
                (0.4, 0.0),
                (0.9, 0.5),
                (0.9, 0.5)
            ]
        );
        assert_eq!(out[1].base_color, Vec3::splat(0.15));
        assert_eq!(out[2].base_color, Vec3::splat(0.9));
    }
}
