//! The built-in workloads of the benchmarks: a procedural room, cameras in it, incoherent rays,
//! points on its surfaces and a realistic stage-2 pixel store.
//!
//! Owns: those generators (deterministic in their seeds). Must not touch: timing.

use crate::pipeline::pixels::PixelStore;
use fipt_bake::Accel;
use fipt_core::rng::Rng;
use fipt_core::scene::{Camera, Mesh, procedural};
use glam::{DVec3, Vec3};
use rayon::prelude::*;

/// Incoherent rays: origins uniform in the bounding box shrunk by 5 % about its centre,
/// directions uniform on the sphere.
pub fn incoherent_rays(mesh: &Mesh, n: usize, seed: u64) -> Vec<(Vec3, Vec3)> {
    let (lo, hi) = mesh.bounds();
    let (c, half) = ((lo + hi) * 0.5, (hi - lo) * 0.5 * 0.95);
    (0..n)
        .into_par_iter()
        .map(|i| {
            let mut r = Rng::new(seed, i as u64);
            let o = c + half
                * Vec3::new(
                    2.0 * r.next_f32() - 1.0,
                    2.0 * r.next_f32() - 1.0,
                    2.0 * r.next_f32() - 1.0,
                );
            let z = 2.0 * r.next_f32() - 1.0;
            let ph = std::f32::consts::TAU * r.next_f32();
            let s = (1.0 - z * z).max(0.0).sqrt();
            (o, Vec3::new(s * ph.cos(), z, s * ph.sin()))
        })
        .collect()
}

/// Cameras spread through a box-shaped room, looking at its centre region.
pub fn procedural_cameras(mesh: &Mesh, n: usize) -> Vec<Camera> {
    let (lo, hi) = mesh.bounds();
    let (lo, hi) = (lo.as_dvec3(), hi.as_dvec3());
    let mut r = Rng::new(11, 0);
    (0..n)
        .map(|_| {
            let mut p = || DVec3::new(r.next_f64(), r.next_f64(), r.next_f64());
            let eye = lo + (hi - lo) * (DVec3::splat(0.15) + 0.7 * p());
            let target = lo + (hi - lo) * (DVec3::splat(0.3) + 0.4 * p());
            Camera::look_at_fov(eye, target, DVec3::Y, 70f64.to_radians(), 320, 240)
        })
        .collect()
}

/// `n` cameras of 160×120 (70° field of view) looking into the procedural room, as a capture.
pub fn capture_cameras(mesh: &Mesh, n: usize) -> Vec<Camera> {
    procedural_cameras(mesh, n)
        .into_iter()
        .map(|c| {
            Camera::look_at_fov(
                c.origin,
                c.origin + c.rotation.z_axis,
                DVec3::Y,
                70f64.to_radians(),
                160,
                120,
            )
        })
        .collect()
}

/// A realistic stage-2 pixel store of `views` views of 160×120: the first hits of camera rays
/// in the built-in procedural room (world and unit-cube positions, part ids as segments), with
/// smooth shadings and photo values. Batches drawn from it by a shuffled order touch the hash
/// table as a real epoch does, not one cached batch.
pub fn pixel_store(views: usize) -> PixelStore {
    use fipt_core::shading::ShadingLayout;
    let room = procedural::room(Vec3::new(5.0, 2.7, 4.0), 2);
    let accel = Accel::build(&room.mesh);
    let cams = capture_cameras(&room.mesh, views);
    let mut b = fipt_core::model::Batch::default();
    let mut r = Rng::new(3, 1);
    let points: Vec<(Vec3, usize)> = cams
        .iter()
        .flat_map(|c| {
            let h = fipt_bake::cast_view(&accel, &room.mesh, c);
            (0..h.num_pixels())
                .filter(|&p| h.tri[p] >= 0)
                .map(|p| (h.position[p], h.tri[p] as usize))
                .collect::<Vec<_>>()
        })
        .collect();
    let sb = fipt_core::scene::SceneBox::from_points(points.iter().map(|(p, _)| p));
    let tris = points.iter().map(|&(_, t)| t as u32).collect();
    for (p, tri) in points {
        b.x_unit.push(sb.to_unit(p).to_array());
        b.x_world.push(p.to_array());
        let lit = 0.2 + 0.8 * (p.x * 1.3).sin().abs() * (p.z * 0.7).cos().abs();
        b.shadings.extend(
            (0..ShadingLayout::DIM)
                .map(|k| lit / (1.0 + 0.1 * k as f32) * (0.9 + 0.2 * r.next_f32())),
        );
        b.gt.extend((0..3).map(|_| lit * (0.3 + 0.4 * r.next_f32())));
        b.seg.push(room.part_of(tri).unwrap_or(0) as i32);
    }
    let origin = (0..b.len() as u32).map(|i| (0, i)).collect();
    PixelStore {
        pixels: b,
        origin,
        tri: tris,
    }
}

/// `n` points uniform by area on `mesh` with their triangles (deterministic in `seed`).
pub fn surface_sample(mesh: &Mesh, n: usize, seed: u64) -> (Vec<Vec3>, Vec<u32>) {
    let cdf = mesh.area_cdf();
    let all = [0, mesh.num_triangles()];
    let mut rng = fipt_core::rng::Rng::new(seed, 0);
    (0..n)
        .map(|_| {
            let t = Mesh::triangle_by_area(&cdf, all, rng.next_f64());
            let (u, v) = (rng.next_f32(), rng.next_f32());
            (mesh.point_at(t, u, v), t as u32)
        })
        .unzip()
}
