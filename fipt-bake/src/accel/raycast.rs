//! Camera ray casting: one pixel-centre ray per pixel, first hit → position, triangle id and the
//! geometric normal turned towards the ray origin (FIPT's double-sided flat shading).
//!
//! Owns: per-view hit buffers (structs of arrays). Must not touch: shading, images.

use crate::accel::Accel;
use fipt_core::scene::{Camera, Mesh};
use glam::Vec3;
use rayon::prelude::*;

/// First hits of every pixel-centre ray of one view, row-major. `tri` is -1 on a miss (then
/// position and normal are zero and `t` is +inf).
#[derive(Clone, Debug, Default)]
pub struct ViewHits {
    pub width: usize,
    pub height: usize,
    pub origin: Vec3,
    pub direction: Vec<Vec3>,
    pub t: Vec<f32>,
    pub tri: Vec<i32>,
    pub position: Vec<Vec3>,
    pub normal: Vec<Vec3>,
}

impl ViewHits {
    pub fn num_pixels(&self) -> usize {
        self.width * self.height
    }

    pub fn num_hits(&self) -> usize {
        self.tri.iter().filter(|&&t| t >= 0).count()
    }
}

/// Unit face normal of `tri`, flipped to face against the direction `d`.
#[inline]
pub fn facing_normal(mesh: &Mesh, tri: usize, d: Vec3) -> Vec3 {
    let n = mesh.normal(tri);
    if n.dot(d) > 0.0 { -n } else { n }
}

/// One pixel's first hit, before it is split into the struct of arrays.
struct PixelHit {
    d: Vec3,
    t: f32,
    tri: i32,
    p: Vec3,
    n: Vec3,
}

/// Casts all pixel-centre rays of a camera (rows in parallel, each row as one batch).
pub fn cast_view(accel: &Accel, mesh: &Mesh, cam: &Camera) -> ViewHits {
    let (w, h) = (cam.width, cam.height);
    let o = cam.origin_f32();
    let pixels: Vec<PixelHit> = (0..h)
        .into_par_iter()
        .flat_map_iter(|row| {
            let rays: Vec<(Vec3, Vec3)> = (0..w)
                .map(|col| (o, cam.pixel_direction(row, col)))
                .collect();
            let mut hits = vec![None; w];
            accel.closest_many(&rays, 0.0, f32::INFINITY, &mut hits);
            rays.into_iter().zip(hits).map(|((_, d), hit)| match hit {
                Some(hit) => PixelHit {
                    d,
                    t: hit.t,
                    tri: hit.tri as i32,
                    p: o + d * hit.t,
                    n: facing_normal(mesh, hit.tri as usize, d),
                },
                None => PixelHit {
                    d,
                    t: f32::INFINITY,
                    tri: -1,
                    p: Vec3::ZERO,
                    n: Vec3::ZERO,
                },
            })
        })
        .collect();
    ViewHits {
        width: w,
        height: h,
        origin: o,
        direction: pixels.iter().map(|x| x.d).collect(),
        t: pixels.iter().map(|x| x.t).collect(),
        tri: pixels.iter().map(|x| x.tri).collect(),
        position: pixels.iter().map(|x| x.p).collect(),
        normal: pixels.iter().map(|x| x.n).collect(),
    }
}

/// Casts every view's pixel-centre rays.
pub fn cast_views<'a>(
    accel: &Accel,
    mesh: &Mesh,
    cams: impl IntoIterator<Item = &'a Camera>,
) -> Vec<ViewHits> {
    cams.into_iter()
        .map(|c| cast_view(accel, mesh, c))
        .collect()
}
