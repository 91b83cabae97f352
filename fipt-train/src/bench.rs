//! `fipt-train bench ...`: speed benchmarks with JSON output (medians over repetitions).
//!
//! Owns: benchmark workloads and timing. Must not touch: correctness checks (those are tests).

use crate::pipeline::pixels::PixelStore;
use anyhow::Result;
use fipt_bake::Accel;
use fipt_core::rng::Rng;
use fipt_core::scene::{Camera, Dataset, LoadOptions, Mesh, procedural};
use glam::{DVec3, Vec3};
use rayon::prelude::*;
use serde_json::{Value, json};
use std::path::Path;
use std::time::Instant;

/// Median of a set of durations in seconds.
pub fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n == 0 {
        return f64::NAN;
    }
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// Runs `f` once to warm up, then `reps` times on a pool of `threads`; returns seconds each.
fn time_on_pool(threads: usize, reps: usize, f: &(dyn Fn() + Sync)) -> Result<Vec<f64>> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()?;
    Ok(pool.install(|| {
        f();
        (0..reps)
            .map(|_| {
                let t = Instant::now();
                f();
                t.elapsed().as_secs_f64()
            })
            .collect()
    }))
}

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

fn camera_rays(cams: &[Camera]) -> Vec<(Vec3, Vec3)> {
    cams.iter()
        .flat_map(|c| {
            let o = c.origin_f32();
            c.pixel_directions().into_iter().map(move |d| (o, d))
        })
        .collect()
}

/// Cameras spread through a box-shaped room, looking at its centre region.
fn procedural_cameras(mesh: &Mesh, n: usize) -> Vec<Camera> {
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

/// Median time and throughput of one thread count.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Throughput {
    pub median_s: f64,
    pub rays_per_s: f64,
    pub times_s: Vec<f64>,
}

impl Throughput {
    fn of(rays: u64, times: Vec<f64>) -> Self {
        let median_s = median(times.clone());
        Self {
            median_s,
            rays_per_s: rays as f64 / median_s,
            times_s: times,
        }
    }
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

/// `n` cameras of 160×120 (70° field of view) looking into the procedural room, as a capture.
fn capture_cameras(mesh: &Mesh, n: usize) -> Vec<Camera> {
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
    PixelStore { pixels: b, origin }
}

/// Times `steps` training steps after `warmup` ones, each on the next batch of a shuffled pass
/// over `store` (as an epoch does); returns per-step seconds, parameters, the phase means and
/// the bytes moved between host and device per step.
///
/// On the device path (`cfg.device_grid`) the store is uploaded once and each step sends only
/// its batch's indices; its losses stay on the device and are read every 25 steps, as in a fit.
/// The device then runs ahead of the host, so per-step times are not separable: every step is
/// given the mean of the timed loop, which ends with a read of the pending losses (a sync).
fn time_steps(
    cfg: fipt_core::model::TrainConfig,
    backend: fipt_core::model::BackendKind,
    store: &PixelStore,
    batch: usize,
    warmup: usize,
    steps: usize,
    mode: fipt_core::model::step::SegMode,
) -> Result<(Vec<f64>, usize, serde_json::Value, serde_json::Value)> {
    use fipt_core::model::step::{DeviceStore, StepLoss};
    use fipt_core::model::transfer;
    let device = backend.device().map_err(anyhow::Error::msg)?;
    let sb = fipt_core::scene::SceneBox { min: 0.0, max: 1.0 };
    let mut tr = fipt_core::model::Trainer::new(cfg, sb, &device, 7);
    let params = tr.model.grid.num_params() + burn::module::Module::num_params(&tr.model.nets);
    let mut order: Vec<u32> = (0..store.len() as u32).collect();
    Rng::new(11, 2).shuffle(&mut order);
    let mut batches = order.chunks(batch).cycle();
    let ds = tr
        .device_resident()
        .then(|| DeviceStore::upload(&store.pixels, &tr.device));
    let mut pending = Vec::new();
    for _ in 0..warmup {
        let idx = batches.next().expect("cycle");
        bench_step(&mut tr, ds.as_ref(), store, idx, mode, &mut pending);
    }
    StepLoss::read_all(std::mem::take(&mut pending));
    tr.profile = Default::default();
    transfer::take();
    let times: Vec<f64> = if ds.is_some() {
        let t = Instant::now();
        for _ in 0..steps {
            let idx = batches.next().expect("cycle");
            bench_step(&mut tr, ds.as_ref(), store, idx, mode, &mut pending);
        }
        StepLoss::read_all(std::mem::take(&mut pending));
        vec![t.elapsed().as_secs_f64() / steps.max(1) as f64; steps]
    } else {
        (0..steps)
            .map(|_| {
                let idx = batches.next().expect("cycle");
                // The host batch is gathered outside the timed step.
                let b = store.batch(idx);
                let t = Instant::now();
                tr.step(&b, mode);
                t.elapsed().as_secs_f64()
            })
            .collect()
    };
    let (up, down) = transfer::take();
    let k = steps.max(1) as f64;
    let nets = if tr.fused_nets() {
        "fused host"
    } else {
        "burn graph"
    };
    let bytes = json!({"grid": if ds.is_some() { "device" } else { "host" }, "nets": nets,
        "upload_bytes_per_step": up as f64 / k, "download_bytes_per_step": down as f64 / k});
    let p = tr.profile;
    let k = p.steps.max(1) as f64;
    let phases = json!({"encode_s": p.encode / k, "forward_s": p.forward / k, "backward_s": p.backward / k,
        "grid_update_s": p.grid_update / k, "net_update_s": p.net_update / k});
    Ok((times, params, phases, bytes))
}

/// One step of `time_steps` on the entries `idx`, as a fit takes it (`fit::step_entries`),
/// its loss read with the pending ones every `fit::LOSS_READ_EVERY` steps.
fn bench_step(
    tr: &mut fipt_core::model::Trainer,
    ds: Option<&fipt_core::model::step::DeviceStore>,
    store: &PixelStore,
    idx: &[u32],
    mode: fipt_core::model::step::SegMode,
    pending: &mut Vec<fipt_core::model::step::StepLoss>,
) {
    use crate::pipeline::fit::{LOSS_READ_EVERY, step_entries};
    pending.push(step_entries(tr, ds, store, idx, mode));
    if pending.len() == LOSS_READ_EVERY {
        fipt_core::model::step::StepLoss::read_all(std::mem::take(pending));
    }
}

/// `bench step`: median time of one stage-2 training step at the reference model size and at a
/// CPU-sized configuration (with `peer_sizes`, also at the peer scripts' `--cpu-config`), per
/// backend. `burn_nets`: the MLPs as burn graph ops on the CPU too (`TrainConfig::host_nets`
/// off).
#[allow(clippy::too_many_arguments)]
pub fn step(
    backends: &[fipt_core::model::BackendKind],
    as_json: bool,
    batch: usize,
    steps: usize,
    peer_sizes: bool,
    place: crate::config::GridPlace,
    modes: &[fipt_core::model::step::SegMode],
    burn_nets: bool,
) -> Result<()> {
    use fipt_core::model::{HashGridConfig, MaterialFieldConfig, TrainConfig};
    let grid = |levels, log2_table, scale| {
        TrainConfig::new().with_material(
            MaterialFieldConfig::new().with_grid(
                HashGridConfig::new()
                    .with_levels(levels)
                    .with_log2_table(log2_table)
                    .with_per_level_scale(scale),
            ),
        )
    };
    let mut configs = vec![
        ("reference", TrainConfig::new()),
        ("cpu", grid(16, 17, 1.6)),
    ];
    if peer_sizes {
        // The peers' `--cpu-config`: L = 16, T = 2^16, base 16 over [-1, 1] (32 over fipt's
        // [0, 1]), scale 1.3; the MLPs are the reference's in both.
        configs.push(("peer-cpu", grid(16, 16, 1.3)));
    }
    let store = pixel_store(48);
    let mut rows = Vec::new();
    for (name, cfg) in configs {
        for &b in backends {
            for &mode in modes {
                let cfg = cfg
                    .clone()
                    .with_device_grid(place.on_device(b))
                    .with_host_nets(!burn_nets);
                let (times, params, phases, bytes) =
                    time_steps(cfg, b, &store, batch, 2, steps, mode)?;
                let med = median(times.clone());
                let loss = format!("{mode:?}").to_lowercase();
                let nets = bytes["nets"].as_str().unwrap_or_default();
                if !as_json {
                    println!(
                        "{name:>10} {:>8} {loss:>8} ({nets} MLPs): {:.1} ms/step (batch {batch}, {params} params) {phases} {bytes}",
                        b.name(),
                        med * 1e3
                    );
                }
                rows.push(
                    json!({"config": name, "backend": b.name(), "seg_loss": loss,
                    "batch": batch, "params": params, "median_s": med, "times_s": times,
                    "phases_mean_s": phases, "transfer": bytes}),
                );
            }
        }
    }
    let encoding = bench_encoding(backends[0], batch, steps.min(5))?;
    if !as_json {
        println!("encoding {encoding}");
    }
    let r = json!({"bench": "step", "pixel_store": store.len(), "results": rows,
        "encoding": encoding});
    if as_json {
        println!("{}", serde_json::to_string_pretty(&r)?);
    }
    Ok(())
}

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
            focal: c.fx as f32,
        })
        .collect();
    let cfg = BakeConfig::default();
    let lf = build_light_field(&views, cfg.voxel_res);
    // Rays actually cast (GGX samples below the horizon cast none); the same every repetition.
    let rays = bake_views(&accel, &lf, &views, &cfg, &|_| true)
        .ok_or_else(|| anyhow::anyhow!("bake stopped"))?
        .rays;
    let time = |threads: usize| -> Result<Throughput> {
        let times = time_on_pool(threads, reps, &|| {
            bake_views(&accel, &lf, &views, &cfg, &|_| true);
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

/// The hash-grid encoding alone (forward + backward to the table) at the reference size: the
/// fused host op against the plain tensor-op formulation, in the same process.
fn bench_encoding(
    backend: fipt_core::model::BackendKind,
    batch: usize,
    reps: usize,
) -> Result<Value> {
    use fipt_core::model::HashGridConfig;
    use fipt_core::model::hashgrid::TableGrad;
    use fipt_core::model::hashgrid_tensor::{encode_tensor, table_tensor};
    let grid = HashGridConfig::new().init(1);
    let store = pixel_store(8);
    let idx: Vec<u32> = (0..batch.min(store.len()) as u32).collect();
    let b = store.batch(&idx);
    let go: Vec<f32> = vec![1e-3; b.len() * grid.output_dim()];
    let mut tg = TableGrad::new(&grid);
    let mut fused = Vec::new();
    for _ in 0..reps + 1 {
        let t = Instant::now();
        let e = grid.encode(&b.x_unit);
        grid.backward_table(&b.x_unit, &go, &mut tg);
        tg.clear(grid.features);
        std::hint::black_box(e);
        fused.push(t.elapsed().as_secs_f64());
    }
    let dev = backend.device().map_err(anyhow::Error::msg)?.autodiff();
    let table = table_tensor(&grid, &dev).require_grad();
    let mut tensor = Vec::new();
    for _ in 0..reps + 1 {
        let t = Instant::now();
        let enc = encode_tensor(&grid, table.clone(), &b.x_unit);
        let g = enc.sum().backward();
        let gt = table.grad(&g).expect("table gradient");
        std::hint::black_box(gt.try_into_vec_as::<f32>().ok());
        tensor.push(t.elapsed().as_secs_f64());
    }
    fused.remove(0);
    tensor.remove(0);
    let (f, t) = (median(fused), median(tensor));
    Ok(
        json!({"backend": backend.name(), "batch": batch, "levels": grid.levels.len(),
        "fused_host_s": f, "tensor_ops_s": t, "speedup": t / f}),
    )
}

/// `bench render`: paths and rays per second of the path tracer on a scene's true materials and
/// emitters (`render --truth`), 1 and 2 threads: `views` val views (train where there is no
/// val split) at `spp` samples per pixel, max depth 7, power-weighted light selection.
pub fn render(scene: &Path, as_json: bool, spp: usize, views: usize, reps: usize) -> Result<()> {
    use crate::render::{RenderJob, render};
    use fipt_bake::emitters::LightSelection;
    use fipt_bake::integrators::path::PathConfig;
    let out = std::env::temp_dir().join(format!("fipt-bench-render-{}", std::process::id()));
    let has_val = scene.join("val").is_dir();
    let job = RenderJob {
        scene: Some(scene.to_path_buf()),
        out: out.clone(),
        source: crate::render::Source::Truth,
        insert: None,
        cache: false,
        material_cache: false,
        off_reflect: false,
        split: if has_val { "val" } else { "train" }.into(),
        views: (0..views).collect(),
        cameras: None,
        relight: None,
        selection: LightSelection::Power,
        path: PathConfig {
            spp,
            ..Default::default()
        },
        quiet: true,
        backend: fipt_core::model::BackendKind::Flex,
    };
    let mut rows = Vec::new();
    for threads in [1usize, 2] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()?;
        let runs = pool.install(|| (0..reps).map(|_| render(&job)).collect::<Result<Vec<_>>>())?;
        let pick =
            |f: &dyn Fn(&crate::render::RenderReport) -> f64| median(runs.iter().map(f).collect());
        let (paths, rays) = (pick(&|r| r.paths_per_s), pick(&|r| r.rays_per_s));
        if !as_json {
            println!(
                "render {threads} thread(s): {:.3} M paths/s, {:.2} M rays/s ({} paths per run, median of {reps})",
                paths / 1e6,
                rays / 1e6,
                runs[0].stats.paths
            );
        }
        rows.push(
            json!({"threads": threads, "paths_per_s": paths, "rays_per_s": rays,
            "paths": runs[0].stats.paths, "rays": runs[0].stats.rays + runs[0].stats.shadow_rays,
            "wall_s": runs.iter().map(|r| r.wall_s).collect::<Vec<_>>()}),
        );
    }
    let _ = std::fs::remove_dir_all(&out);
    if as_json {
        let r = json!({"bench": "render", "scene": scene.display().to_string(), "spp": spp,
            "views": views, "max_depth": 7, "results": rows});
        println!("{}", serde_json::to_string_pretty(&r)?);
    }
    Ok(())
}

/// Relative RMS difference ‖a − b‖/‖b‖ and mean ratio Σa/Σb of one shading channel group over
/// the hit pixels of some views.
fn shading_difference(
    a: &[Vec<f32>],
    b: &[Vec<f32>],
    channels: std::ops::Range<usize>,
) -> (f64, f64) {
    use fipt_core::shading::ShadingLayout;
    let (mut d2, mut b2, mut sa, mut sb) = (0f64, 0f64, 0f64, 0f64);
    for (va, vb) in a.iter().zip(b) {
        for p in 0..va.len() / ShadingLayout::DIM {
            let (pa, pb) = (ShadingLayout::pixel(va, p), ShadingLayout::pixel(vb, p));
            for c in channels.clone() {
                let (x, y) = (pa[c] as f64, pb[c] as f64);
                d2 += (x - y) * (x - y);
                b2 += y * y;
                sa += x;
                sb += y;
            }
        }
    }
    ((d2 / b2.max(1e-30)).sqrt(), sa / sb.max(1e-30))
}

/// `bench refine`: refines a few train views of a finished `run` (its model, emitters, bake
/// cache and config) with the learned field behind the voxel cache and with exact queries, and
/// twice exactly with two seeds (the Monte Carlo noise floor); reports the time of each and
/// the relative RMS difference of L_d and of L_s0 + L_s1 per roughness level.
pub fn refine(scene: &Path, run: &Path, as_json: bool, views: usize) -> Result<()> {
    use crate::pipeline::{bake::bake_cached, refine};
    use fipt_bake::emitters::Emitter;
    use fipt_core::model::FiptModel;
    use fipt_core::model::step::SegMode;
    use fipt_core::shading::ShadingLayout;
    let cfg = crate::config::Config::load(&run.join("config.json"))?;
    let ds = Dataset::load(
        scene,
        &LoadOptions {
            maps: vec![],
            val: false,
        },
    )?;
    let accel = Accel::build(&ds.mesh);
    let mut bake_cfg = cfg.bake.clone();
    bake_cfg.seed = cfg.seed;
    let (baked, _) = bake_cached(run, &ds, &accel, &bake_cfg, false)?;
    let store = PixelStore::gather(
        &ds.train,
        &baked,
        &baked.light_field.scene_box,
        SegMode::None,
    );
    let device = cfg.backend.device().map_err(anyhow::Error::msg)?;
    let model = FiptModel::load(&run.join("model"), &device).map_err(anyhow::Error::msg)?;
    #[derive(serde::Deserialize)]
    struct Emitters {
        emitters: Vec<Emitter>,
    }
    let em: Emitters = serde_json::from_str(&std::fs::read_to_string(run.join("emitters.json"))?)?;
    let n = ds.train.views.len();
    let picked: Vec<usize> = (0..views.min(n))
        .map(|i| i * n / views.min(n).max(1))
        .collect();
    let go = |cache: bool, seed: u64| {
        let mut rcfg = cfg.refine.paths.clone();
        rcfg.seed = seed;
        let scope = refine::RefineScope {
            views: &picked,
            material_cache: cache,
        };
        let t = Instant::now();
        let r = refine::refine(
            &ds.mesh,
            &accel,
            &ds.train,
            &baked,
            &store,
            &model,
            &em.emitters,
            &rcfg,
            &scope,
            false,
        )?;
        Ok::<_, anyhow::Error>((r.shadings, t.elapsed().as_secs_f64()))
    };
    let (cached, t_cached) = go(true, 1)?;
    let (exact, t_exact) = go(false, 1)?;
    let (exact2, t_exact2) = go(false, 2)?;
    let mut rows = Vec::new();
    let mut groups = vec![("L_d".to_string(), ShadingLayout::LD)];
    for j in 0..6 {
        groups.push((format!("L_s0 level {j}"), ShadingLayout::ls0(j)));
        groups.push((format!("L_s1 level {j}"), ShadingLayout::ls1(j)));
    }
    for (name, ch) in groups {
        let (cache_rms, cache_ratio) = shading_difference(&cached, &exact, ch.clone());
        let (noise_rms, noise_ratio) = shading_difference(&exact2, &exact, ch);
        if !as_json {
            println!(
                "{name:<16} voxel cache vs exact: rel. RMS {cache_rms:.4}, mean ratio {cache_ratio:.4}; exact seed 2 vs seed 1: {noise_rms:.4}, {noise_ratio:.4}"
            );
        }
        rows.push(
            json!({"shading": name, "cache_rel_rms": cache_rms, "cache_mean_ratio": cache_ratio,
            "noise_rel_rms": noise_rms, "noise_mean_ratio": noise_ratio}),
        );
    }
    if !as_json {
        println!(
            "views {picked:?}: voxel cache {t_cached:.1} s, exact {t_exact:.1} s and {t_exact2:.1} s"
        );
    } else {
        let r = json!({"bench": "refine", "scene": scene.display().to_string(), "views": picked,
            "time_s": {"voxel_cache": t_cached, "exact": t_exact, "exact_seed2": t_exact2},
            "shadings": rows});
        println!("{}", serde_json::to_string_pretty(&r)?);
    }
    Ok(())
}

/// `bench query`: material queries per second of a scene model's learned field, as the path
/// tracer makes them (batches of `batch` points spread on the mesh): exact (hash-grid encoding
/// and MLP; the encoding alone reported beside) and through the voxel cache of `render`.
pub fn query(model_dir: &Path, as_json: bool, batch: usize, reps: usize) -> Result<()> {
    use fipt_bake::materials::{MaterialSource, VoxelMaterials};
    let device = burn::tensor::Device::flex();
    let sm = crate::scene_model::SceneModel::load(model_dir, &device)?;
    let learned =
        crate::learned::LearnedMaterials::new(sm.model.clone(), sm.mesh.num_triangles(), &[]);
    let lf = &sm.light_field;
    let t0 = std::time::Instant::now();
    let (voxels, evaluated) = VoxelMaterials::from_surface(
        lf.scene_box,
        lf.res,
        &sm.mesh,
        &learned,
        vec![false; sm.mesh.num_triangles()],
        2.0,
        0,
    );
    let build_s = t0.elapsed().as_secs_f64();
    // Points spread on the surface (another seed than the cache's).
    let (pts, tris) = surface_sample(&sm.mesh, batch, 7);
    let x_unit: Vec<[f32; 3]> = pts
        .iter()
        .map(|&p| sm.model.spec.scene_box.to_unit(p).to_array())
        .collect();
    let mut out = Vec::new();
    let time = |f: &mut dyn FnMut()| {
        median(
            (0..reps)
                .map(|_| {
                    let t = std::time::Instant::now();
                    f();
                    t.elapsed().as_secs_f64()
                })
                .collect(),
        )
    };
    let exact = time(&mut || learned.query(&pts, &tris, &mut out));
    let encode = time(&mut || {
        std::hint::black_box(sm.model.grid.encode(&x_unit));
    });
    let cached = time(&mut || voxels.query(&pts, &tris, &mut out));
    let mut probe = Vec::new();
    let missed = {
        // Forwarded points answer exactly; a cached answer differs from the exact one.
        let mut exact = Vec::new();
        learned.query(&pts, &tris, &mut exact);
        voxels.query(&pts, &tris, &mut probe);
        probe.iter().zip(&exact).filter(|(a, b)| a == b).count()
    };
    let j = serde_json::json!({
        "bench": "query",
        "model": model_dir.display().to_string(),
        "batch": batch,
        "threads": rayon::current_num_threads(),
        "exact_points_per_s": batch as f64 / exact,
        "encode_points_per_s": batch as f64 / encode,
        "encode_share": encode / exact,
        "cached_points_per_s": batch as f64 / cached,
        "cache_voxels": voxels.len(),
        "cache_miss_share": missed as f64 / batch as f64,
        "cache_points_evaluated": evaluated,
        "cache_build_s": build_s,
    });
    if as_json {
        println!("{}", serde_json::to_string_pretty(&j)?);
    } else {
        println!(
            "exact field: {:.2} M points/s (encoding {:.0} % of it); voxel cache: {:.1} M points/s ({:.1} % forwarded; {} voxels from {} points in {:.2} s)",
            batch as f64 / exact / 1e6,
            100.0 * encode / exact,
            batch as f64 / cached / 1e6,
            100.0 * missed as f64 / batch as f64,
            voxels.len(),
            evaluated,
            build_s
        );
    }
    Ok(())
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
