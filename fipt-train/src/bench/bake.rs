//! `bench bake`: secondary rays per second of the stage-1 bake on a built-in scene.
//!
//! Owns: that benchmark. Must not touch: the bake.

use super::workloads::capture_cameras;
use super::{Throughput, time_on_pool};
use anyhow::Result;
use fipt_bake::Accel;
use fipt_core::scene::procedural;
use glam::Vec3;
use serde_json::json;

/// `bench bake`: secondary rays per second of the stage-1 bake on a built-in scene (procedural
/// room, 8 views of 160×120, reference sample counts), 1 and 2 threads, plus the filter's cost.
pub fn bake(as_json: bool, reps: usize) -> Result<()> {
    use fipt_bake::integrators::bake::{BakeConfig, BakeView, bake_views, build_light_field};
    let room = procedural::room(Vec3::new(5.0, 2.7, 4.0), 2);
    let accel = Accel::build(&room.mesh);
    let cams = capture_cameras(&room.mesh, 8);
    let hits: Vec<_> = cams
        .iter()
        .map(|c| fipt_bake::cast_view(&accel, &room.mesh, c))
        .collect();
    // Radiance: a bright ceiling panel, a grey room.
    let images: Vec<Vec<f32>> = hits
        .iter()
        .map(|h| {
            h.tri
                .iter()
                .flat_map(|&t| {
                    let lit = t >= 0 && room.part_of(t as usize) == Some(room.parts.len() - 1);
                    if lit {
                        [20.0, 19.0, 17.0]
                    } else {
                        [0.3, 0.3, 0.3]
                    }
                })
                .collect()
        })
        .collect();
    let views: Vec<BakeView> = hits
        .iter()
        .zip(&images)
        .zip(&cams)
        .map(|((h, i), c)| BakeView {
            hits: h,
            image: i,
            camera: c,
        })
        .collect();
    let cfg = BakeConfig::default();
    let lf = build_light_field(&views, &room.mesh, cfg.voxel_res, cfg.fill_rings);
    // Rays actually cast (GGX samples below the horizon cast none); the same every repetition.
    let rays = bake_views(&accel, &lf, &views, &cfg, None, &|_| true)
        .ok_or_else(|| anyhow::anyhow!("bake stopped"))?
        .rays;
    let time = |threads: usize| -> Result<Throughput> {
        let times = time_on_pool(threads, reps, &|| {
            bake_views(&accel, &lf, &views, &cfg, None, &|_| true);
        })?;
        Ok(Throughput::of(rays, times))
    };
    let (t1, t2) = (time(1)?, time(2)?);
    if as_json {
        let r = json!({"bench": "bake", "scene": "builtin:procedural-room", "triangles": room.mesh.num_triangles(),
            "views": views.len(), "secondary_rays": rays, "samples": cfg.samples,
            "results": {"threads_1": &t1, "threads_2": &t2}});
        println!("{}", serde_json::to_string_pretty(&r)?);
    } else {
        for (t, x) in [("threads_1", &t1), ("threads_2", &t2)] {
            println!(
                "bake {t}: {:.2} M rays/s ({rays} rays, median {:.2} s)",
                x.rays_per_s / 1e6,
                x.median_s
            );
        }
    }
    Ok(())
}
