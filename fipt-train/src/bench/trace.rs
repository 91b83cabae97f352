//! `bench trace`: closest-hit rays per second, incoherent and camera rays, 1 and 2 threads.
//!
//! Owns: that benchmark. Must not touch: the traversal.

use super::workloads::{incoherent_rays, procedural_cameras};
use super::{Throughput, time_on_pool};
use anyhow::Result;
use fipt_bake::Accel;
use fipt_core::scene::{Camera, Dataset, LoadOptions, procedural};
use glam::Vec3;
use rayon::prelude::*;
use serde_json::json;
use std::path::Path;
use std::time::Instant;

/// Traces all rays (closest hit) in parallel chunks, writing hit distances.
fn trace_all(accel: &Accel, rays: &[(Vec3, Vec3)], out: &mut [f32]) {
    out.par_chunks_mut(4096)
        .zip(rays.par_chunks(4096))
        .for_each(|(o, r)| {
            let mut hits = vec![None; r.len()];
            accel.closest_many(r, 0.0, f32::INFINITY, &mut hits);
            for (t, h) in o.iter_mut().zip(hits) {
                *t = h.map_or(f32::INFINITY, |h: fipt_bake::Hit| h.t);
            }
        });
}

fn camera_rays(cams: &[Camera]) -> Vec<(Vec3, Vec3)> {
    cams.iter()
        .flat_map(|c| {
            let o = c.origin_f32();
            c.pixel_directions().into_iter().map(move |d| (o, d))
        })
        .collect()
}

/// Closest-hit throughput of one ray set with 1 and 2 threads.
#[derive(Clone, Debug, serde::Serialize)]
pub struct RayBench {
    pub threads_1: Throughput,
    pub threads_2: Throughput,
    pub rays: usize,
    pub hit_fraction: f64,
}

fn bench_rays(accel: &Accel, rays: &[(Vec3, Vec3)], reps: usize) -> Result<RayBench> {
    let mut out = vec![0f32; rays.len()];
    let out_ptr = std::sync::Mutex::new(&mut out);
    let time = |threads: usize| -> Result<Throughput> {
        let times = time_on_pool(threads, reps, &|| {
            let mut o = out_ptr.lock().unwrap();
            trace_all(accel, rays, &mut o);
        })?;
        Ok(Throughput::of(rays.len() as u64, times))
    };
    let (threads_1, threads_2) = (time(1)?, time(2)?);
    let hit = out.iter().filter(|t| t.is_finite()).count() as f64 / rays.len().max(1) as f64;
    Ok(RayBench {
        threads_1,
        threads_2,
        rays: rays.len(),
        hit_fraction: hit,
    })
}

/// `bench trace`: closest-hit throughput on incoherent and camera rays, 1 and 2 threads.
pub fn trace(
    scene: Option<&Path>,
    as_json: bool,
    n_rays: usize,
    reps: usize,
    mesh_scale: u32,
) -> Result<()> {
    let (name, mesh, cams) = match scene {
        Some(dir) => {
            let ds = Dataset::load(
                dir,
                &LoadOptions {
                    maps: vec![],
                    val: false,
                },
            )?;
            let cams: Vec<Camera> = ds.train.views.iter().map(|v| v.camera.clone()).collect();
            (dir.display().to_string(), ds.mesh, cams)
        }
        None => {
            let room = procedural::room(Vec3::new(5.0, 2.7, 4.0), 8);
            let cams = procedural_cameras(&room.mesh, 16);
            ("builtin:procedural-room".to_string(), room.mesh, cams)
        }
    };
    let mesh = mesh.subdivided(mesh_scale);
    let t0 = Instant::now();
    let accel = Accel::build(&mesh);
    let build_s = t0.elapsed().as_secs_f64();
    let incoherent = incoherent_rays(&mesh, n_rays, 0x5eed);
    let camera = camera_rays(&cams);
    let inc = bench_rays(&accel, &incoherent, reps)?;
    let cam = bench_rays(&accel, &camera, reps)?;
    let r = json!({
        "bench": "trace",
        "scene": name,
        "triangles": mesh.num_triangles(),
        "mesh_scale": mesh_scale,
        "traversal": accel.traversal(),
        "bvh_build_s": build_s,
        "reps": reps,
        "incoherent": &inc,
        "camera": &cam,
    });
    if as_json {
        println!("{}", serde_json::to_string_pretty(&r)?);
    } else {
        println!(
            "scene {name}: {} triangles, BVH build {build_s:.3} s, traversal {}",
            mesh.num_triangles(),
            accel.traversal()
        );
        for (kind, b) in [("incoherent", &inc), ("camera", &cam)] {
            for (t, x) in [("threads_1", &b.threads_1), ("threads_2", &b.threads_2)] {
                println!(
                    "{kind:>10} {t}: {:.2} M rays/s ({} rays, hit fraction {:.3})",
                    x.rays_per_s / 1e6,
                    b.rays,
                    b.hit_fraction
                );
            }
        }
    }
    Ok(())
}
