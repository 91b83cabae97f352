//! Two material sources split by triangle: the triangles marked `from_second` read `second`,
//! every other one `first`, each source in one batched query (diagnostics that swap one part's
//! material for another source's).
//!
//! Owns: the split of a query between the two. Must not touch: what either material is.

use super::{MaterialSource, SurfaceMaterial, query_at};
use glam::Vec3;

pub struct Split<'a> {
    pub first: &'a dyn MaterialSource,
    pub second: &'a dyn MaterialSource,
    /// Per triangle, whether it reads `second` (triangles beyond the list read `first`).
    pub from_second: Vec<bool>,
}

impl Split<'_> {
    fn second(&self, t: u32) -> bool {
        self.from_second.get(t as usize).copied().unwrap_or(false)
    }
}

impl MaterialSource for Split<'_> {
    fn query(&self, points: &[Vec3], tris: &[u32], out: &mut Vec<SurfaceMaterial>) {
        out.clear();
        // Each source's answers, in the order of its points.
        let ask = |src: &dyn MaterialSource, second: bool| {
            let idx: Vec<usize> = (0..tris.len())
                .filter(|&i| self.second(tris[i]) == second)
                .collect();
            query_at(src, points, tris, &idx).into_iter()
        };
        let (mut a, mut b) = (ask(self.first, false), ask(self.second, true));
        out.extend(tris.iter().map(|&t| {
            let next = if self.second(t) { b.next() } else { a.next() };
            next.unwrap_or(SurfaceMaterial::BLACK)
        }));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A source that answers with its own roughness and the triangle id as base colour.
    struct Tagged(f32);
    impl MaterialSource for Tagged {
        fn query(&self, p: &[Vec3], tris: &[u32], out: &mut Vec<SurfaceMaterial>) {
            assert_eq!(p.len(), tris.len());
            out.clear();
            out.extend(tris.iter().zip(p).map(|(&t, x)| SurfaceMaterial {
                base_color: Vec3::new(t as f32, x.x, 0.0),
                roughness: self.0,
                metallic: 0.0,
            }));
        }
    }

    /// Mixed queries keep their order and their points: marked triangles read the second
    /// source, the others (and those beyond the marks) the first.
    #[test]
    fn splits_by_triangle_and_keeps_order() {
        let (a, b) = (Tagged(0.25), Tagged(0.75));
        let s = Split {
            first: &a,
            second: &b,
            from_second: vec![false, true, false, true],
        };
        let tris = [3, 0, 1, 9, 1, 2];
        let points: Vec<Vec3> = (0..tris.len()).map(|i| Vec3::X * i as f32).collect();
        let mut out = Vec::new();
        s.query(&points, &tris, &mut out);
        let rough: Vec<f32> = out.iter().map(|m| m.roughness).collect();
        assert_eq!(rough, [0.75, 0.25, 0.75, 0.25, 0.75, 0.25]);
        for (i, m) in out.iter().enumerate() {
            assert_eq!(m.base_color, Vec3::new(tris[i] as f32, i as f32, 0.0));
        }
    }
}
