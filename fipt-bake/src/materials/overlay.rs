//! Appended geometry over another material source: triangles from `first` on (relighting
//! emitters, inserted objects) get their own constant materials; every other triangle goes to
//! the inner source in one batched query.
//!
//! Owns: the split of a query between the two. Must not touch: what either material is.

use super::{MaterialSource, SurfaceMaterial, query_at};
use glam::Vec3;

pub struct Overlay<'a> {
    pub inner: &'a dyn MaterialSource,
    /// The first appended triangle.
    pub first: u32,
    /// One material per appended triangle (`first + i`); triangles beyond get the last one,
    /// or black when there is none.
    pub materials: Vec<SurfaceMaterial>,
}

impl MaterialSource for Overlay<'_> {
    fn query(&self, points: &[Vec3], tris: &[u32], out: &mut Vec<SurfaceMaterial>) {
        out.clear();
        if tris.iter().all(|&t| t < self.first) {
            return self.inner.query(points, tris, out);
        }
        let inner_idx: Vec<usize> = (0..tris.len()).filter(|&i| tris[i] < self.first).collect();
        let mut next = query_at(self.inner, points, tris, &inner_idx).into_iter();
        out.extend(tris.iter().map(|&t| {
            if t < self.first {
                next.next().unwrap_or(SurfaceMaterial::BLACK)
            } else {
                let k = (t - self.first) as usize;
                self.materials
                    .get(k)
                    .or(self.materials.last())
                    .copied()
                    .unwrap_or(SurfaceMaterial::BLACK)
            }
        }));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    struct ByTri;
    impl MaterialSource for ByTri {
        fn query(&self, _p: &[Vec3], tris: &[u32], out: &mut Vec<SurfaceMaterial>) {
            out.clear();
            out.extend(tris.iter().map(|&t| SurfaceMaterial {
                base_color: Vec3::splat(t as f32),
                roughness: 0.5,
                metallic: 0.0,
            }));
        }
    }

    /// Mixed queries keep their order: inner triangles read the inner source, appended ones
    /// their own material.
    #[test]
    fn splits_and_keeps_order() {
        let red = SurfaceMaterial {
            base_color: Vec3::X,
            roughness: 0.1,
            metallic: 1.0,
        };
        let o = Overlay {
            inner: &ByTri,
            first: 10,
            materials: vec![SurfaceMaterial::BLACK, red],
        };
        let tris = [3, 10, 11, 4, 12, 9];
        let mut out = Vec::new();
        o.query(&[Vec3::ZERO; 6], &tris, &mut out);
        assert_eq!(out[0].base_color, Vec3::splat(3.0));
        assert_eq!(out[1], SurfaceMaterial::BLACK);
        assert_eq!(out[2], red);
        assert_eq!(out[3].base_color, Vec3::splat(4.0));
        assert_eq!(out[4], red);
        assert_eq!(out[5].base_color, Vec3::splat(9.0));
    }
}
