//! A pixel's footprint on its part (`bake.footprint`, `refine.paths.footprint`;
//! `docs/departures/footprint.md`): the first hits of an n×n grid of rays inside the pixel's
//! square that land on the part of its pixel-centre hit. A photo's pixel is the mean over its
//! square (a box filter), and the shadings are linear in one material's terms, so estimators
//! that spread their samples over these points estimate the shadings whose factorised render
//! is that mean wherever one part covers the pixel.
//!
//! Owns: the sub-pixel casts and the per-pixel point lists. Must not touch: the estimators,
//! where the part keys come from.

use crate::accel::Accel;
use crate::accel::raycast::ViewHits;
use fipt_core::scene::Camera;
use glam::Vec3;
use rayon::prelude::*;

/// A surface point seen through a pixel: position `x`, unit normal `n` facing the camera and
/// unit direction `wo` towards it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SurfacePoint {
    pub x: Vec3,
    pub n: Vec3,
    pub wo: Vec3,
}

/// Per pixel of one view, the points its estimators spread their samples over: none where the
/// centre ray missed, else at least one.
#[derive(Clone, Debug, Default)]
pub struct ViewFootprint {
    /// `start[p]..start[p + 1]` indexes pixel p's points.
    start: Vec<u32>,
    points: Vec<SurfacePoint>,
}

impl ViewFootprint {
    /// The pixel-centre hits alone (the reference: the shadings at the centre's point).
    pub fn centres(hits: &ViewHits) -> Self {
        Self::from_lists((0..hits.num_pixels()).map(|p| centre(hits, p).into_iter().collect()))
    }

    /// The hits of an `n`×`n` grid of rays through each pixel's square
    /// (`Camera::grid_rays`) whose triangle has the centre hit's key in `parts` (one key per
    /// triangle); the centre hit where none has. `n` = 0 or no `parts` gives `centres`.
    pub fn cast(
        accel: &Accel,
        cam: &Camera,
        hits: &ViewHits,
        parts: Option<&[u64]>,
        n: usize,
    ) -> Self {
        let Some(parts) = parts.filter(|_| n > 0) else {
            return Self::centres(hits);
        };
        let w = hits.width;
        let lists: Vec<Vec<SurfacePoint>> = (0..hits.num_pixels())
            .into_par_iter()
            .with_min_len(16)
            .map(|p| {
                let Some(c) = centre(hits, p) else {
                    return Vec::new();
                };
                let key = parts[hits.tri[p] as usize];
                let rays = cam.grid_rays(p % w, p / w, n);
                let mut sub = vec![None; rays.len()];
                accel.closest_many(&rays, 0.0, f32::INFINITY, &mut sub);
                let same: Vec<SurfacePoint> = rays
                    .iter()
                    .zip(&sub)
                    .filter_map(|(&(o, d), h)| {
                        let h = h.filter(|h| parts[h.tri as usize] == key)?;
                        Some(SurfacePoint {
                            x: o + d * h.t,
                            n: accel.facing_normal(h.tri, d),
                            wo: -d,
                        })
                    })
                    .collect();
                if same.is_empty() { vec![c] } else { same }
            })
            .collect();
        Self::from_lists(lists.into_iter())
    }

    /// From each pixel's list of points, row-major.
    pub fn from_lists(lists: impl Iterator<Item = Vec<SurfacePoint>>) -> Self {
        let mut fp = Self {
            start: vec![0],
            points: Vec::new(),
        };
        for l in lists {
            fp.points.extend(l);
            fp.start.push(fp.points.len() as u32);
        }
        fp
    }

    /// Pixel `p`'s points.
    pub fn of(&self, p: usize) -> &[SurfacePoint] {
        &self.points[self.start[p] as usize..self.start[p + 1] as usize]
    }

    pub fn num_pixels(&self) -> usize {
        self.start.len() - 1
    }
}

/// The point that sample `i` of an estimator of `count` samples starts from, among `k` points:
/// ⌊i·k / count⌋. The points take equal shares of the samples to within one, spread over the
/// whole grid when there are fewer samples than points; with one point, always 0.
pub fn point_of_sample(i: usize, count: usize, k: usize) -> usize {
    i * k / count.max(1)
}

/// Pixel `p`'s centre hit as a surface point (None on a miss).
fn centre(hits: &ViewHits, p: usize) -> Option<SurfacePoint> {
    (hits.tri[p] >= 0).then(|| SurfacePoint {
        x: hits.position[p],
        n: hits.normal[p],
        wo: -hits.direction[p],
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use fipt_core::scene::Mesh;
    use glam::DVec3;

    /// A camera at the origin looking down +z at a wall (z = 10) in front of which stands the
    /// corner of a box: two faces at 90° that recede from an edge along y, which runs through
    /// pixel column 4 a quarter of a pixel from its left side.
    fn corner_scene() -> (Accel, Camera, Mesh) {
        let (w, h) = (8, 4);
        let cam = Camera::look_at_fov(DVec3::ZERO, DVec3::Z, DVec3::Y, 1.0, w, h);
        let z = 5.0f32;
        let e = cam.direction_at(4.25, 2.0);
        let ex = e.x / e.z * z;
        let d = 1.0f32;
        let quad = |a: Vec3, b: Vec3| [a, b, b + Vec3::Y * 40.0, a + Vec3::Y * 40.0];
        let mut vertices =
            quad(Vec3::new(-20.0, -20.0, 10.0), Vec3::new(20.0, -20.0, 10.0)).to_vec();
        let edge = Vec3::new(ex, -20.0, z);
        vertices.extend(quad(edge, edge + Vec3::new(-d, 0.0, d)));
        vertices.extend(quad(edge, edge + Vec3::new(d, 0.0, d)));
        let quad_tris = |o: u32| [[o, o + 1, o + 2], [o, o + 2, o + 3]];
        let triangles = [quad_tris(0), quad_tris(4), quad_tris(8)].concat();
        let mesh = Mesh {
            vertices,
            triangles,
        };
        (Accel::build(&mesh), cam, mesh)
    }

    #[test]
    fn a_footprint_keeps_the_sub_hits_on_the_centres_part() {
        let (accel, cam, mesh) = corner_scene();
        let hits = crate::cast_view(&accel, &mesh, &cam);
        let w = hits.width;
        // Pixel 4 of row 1: the edge leaves one column of its 4×4 grid on the other face.
        let p = w + 4;
        let c = hits.tri[p];
        assert!(c >= 2, "the centre sees the box");
        let centre_n = hits.normal[p];
        let on_centres_face = |q: &SurfacePoint| (q.n - centre_n).length() < 1e-6;
        // Wall, one face, the other face: each its own part.
        let own = [0, 0, 1, 1, 2, 2];
        let fp = ViewFootprint::cast(&accel, &cam, &hits, Some(&own), 4);
        let pts = fp.of(p);
        assert_eq!(pts.len(), 12, "three columns of the grid");
        assert!(pts.iter().all(on_centres_face));
        // The box as one part: the other face's column joins.
        let boxed = [0, 0, 1, 1, 1, 1];
        let fp = ViewFootprint::cast(&accel, &cam, &hits, Some(&boxed), 4);
        let pts = fp.of(p);
        assert_eq!(pts.len(), 16);
        assert_eq!(pts.iter().filter(|q| !on_centres_face(q)).count(), 4);
        for q in pts {
            assert!((q.wo.length() - 1.0).abs() < 1e-5);
            assert!(q.n.dot(q.wo) > 0.0, "normals face the camera");
            // Every point lies on its ray back to the camera at the origin.
            assert!(q.x.normalize().dot(-q.wo) > 1.0 - 1e-5);
        }
        // A wall pixel away from the box: 16 points on the wall's plane.
        let wall = fp.of(w);
        assert_eq!(wall.len(), 16);
        assert!(wall.iter().all(|q| (q.x.z - 10.0).abs() < 1e-4));
        // Grid 0 gives the centre hit alone.
        let c = ViewFootprint::cast(&accel, &cam, &hits, Some(&boxed), 0);
        assert_eq!(
            c.of(p),
            [SurfacePoint {
                x: hits.position[p],
                n: centre_n,
                wo: -hits.direction[p]
            }]
        );
        assert_eq!(c.num_pixels(), hits.num_pixels());
    }

    #[test]
    fn samples_spread_evenly_over_the_points() {
        let share = |count: usize, k: usize| {
            let mut n = vec![0; k];
            for i in 0..count {
                n[point_of_sample(i, count, k)] += 1;
            }
            n
        };
        assert_eq!(share(64, 16), vec![4; 16]);
        let uneven = share(64, 12);
        assert!(uneven.iter().all(|&c| c == 5 || c == 6), "{uneven:?}");
        // Fewer samples than points: every other point, over the whole grid.
        let few = share(32, 64);
        assert_eq!(few.iter().sum::<usize>(), 32);
        assert!(few.iter().step_by(2).all(|&c| c == 1));
        assert_eq!(share(7, 1), vec![7]);
    }

    #[test]
    fn a_missed_pixel_has_no_points() {
        let (accel, cam, mesh) = corner_scene();
        let mut hits = crate::cast_view(&accel, &mesh, &cam);
        hits.tri[3] = -1;
        let fp = ViewFootprint::cast(&accel, &cam, &hits, Some(&[0; 6]), 2);
        assert!(fp.of(3).is_empty());
        assert_eq!(fp.of(2).len(), 4);
    }
}
