//! `bench step`: the median time of one stage-2 training step, and of the hash-grid encoding
//! alone.
//!
//! Owns: that benchmark. Must not touch: the step.

use super::median;
use super::workloads::pixel_store;
use crate::pipeline::pixels::PixelStore;
use anyhow::Result;
use fipt_core::rng::Rng;
use serde_json::{Value, json};
use std::time::Instant;

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
    use crate::pipeline::batches::step_entries;
    use crate::pipeline::fit::LOSS_READ_EVERY;
    pending.push(step_entries(tr, ds, store, idx, mode));
    if pending.len() == LOSS_READ_EVERY {
        fipt_core::model::step::StepLoss::read_all(std::mem::take(pending));
    }
}

/// What `bench step` times (its command-line flags).
#[derive(Clone, Debug, clap::Args)]
pub struct StepArgs {
    /// Backend(s) to time: flex, wgpu, ndarray (default: flex).
    #[arg(long)]
    pub backend: Vec<fipt_core::model::BackendKind>,
    #[arg(long)]
    pub json: bool,
    #[arg(long, default_value_t = 8192, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=1 << 24))]
    pub batch: usize,
    /// Timed steps (after 2 warm-up steps).
    #[arg(long, default_value_t = 10, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=100_000))]
    pub steps: usize,
    /// Also time the peers' `--cpu-config` sizes (16 levels, 2^16 entries, scale 1.3).
    #[arg(long)]
    pub peer_sizes: bool,
    /// Where the hash grid lives: auto (on the device for wgpu), host or device.
    #[arg(long, default_value = "auto")]
    pub grid: crate::config::GridPlace,
    /// Time only the part loss (the default config's) instead of both segmentation losses.
    #[arg(long)]
    pub part_only: bool,
    /// Run the MLPs as burn graph ops on the CPU too, instead of the fused host MLPs (for
    /// comparison).
    #[arg(long)]
    pub burn_nets: bool,
}

/// `bench step`: median time of one stage-2 training step at the reference model size and at a
/// CPU-sized configuration (with `peer_sizes`, also at the peer scripts' `--cpu-config`), per
/// backend (flex when none is named) and segmentation loss (the part loss only with
/// `part_only`). `burn_nets`: the MLPs as burn graph ops on the CPU too
/// (`TrainConfig::host_nets` off).
pub fn step(args: &StepArgs) -> Result<()> {
    use fipt_core::model::BackendKind;
    use fipt_core::model::step::SegMode;
    let backends: &[BackendKind] = if args.backend.is_empty() {
        &[BackendKind::Flex]
    } else {
        &args.backend
    };
    let modes: &[SegMode] = if args.part_only {
        &[SegMode::Part]
    } else {
        &[SegMode::Part, SegMode::Semantic]
    };
    let (as_json, batch, steps, place) = (args.json, args.batch, args.steps, args.grid);
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
    if args.peer_sizes {
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
                    .with_host_nets(!args.burn_nets);
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
