//! The fit (`Trainer`): a `FiptModel` with its optimisers, built fresh or around a restored
//! model, and one optimisation step (`step`, `step_on`): forward and backward (`paths`), then
//! the table's update and burn's Adam on the networks.
//!
//! Owns: `Trainer` and its optimisers, `SigmaPull`, `StepProfile`, the update. Must not touch:
//! the forward's paths and losses, checkpoint files.

use super::batch::{Batch, StepInput};
use super::config::{SegMode, TrainConfig};
use super::losses::{LossParts, StepLoss};
use crate::model::fipt_model::{FiptModel, ModelSpec};
use crate::model::hashgrid::{TableAdam, TableGrad};
use crate::model::hashgrid_device::GridTables;
use crate::model::part_offsets::PartMap;
use crate::model::transfer;
use crate::scene::SceneBox;
use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer};
use burn::tensor::Device;
use std::collections::HashMap;
use std::time::Instant;

/// How the hash table is optimised.
#[derive(Clone)]
pub(super) enum GridOpt {
    /// The fused host op's sparse table gradient and Adam.
    Host { grad: TableGrad, adam: TableAdam },
    /// burn's Adam on the device-resident table (`FiptModel::device_grid`).
    Device { optim: ModuleOptimizer },
}

/// A pull of the roughness, and where given the metallic, towards per-segment targets, added
/// to the loss of every step while it is set (`Trainer::pull`): the phases of a basin hop
/// (`loss::sigma_pull_loss` on each, reported with the prior). Segment ids are the batch's own
/// (`Batch::seg`); pixels of other segments are not pulled.
#[derive(Clone, Debug, Default)]
pub struct SigmaPull {
    pub weight: f32,
    /// σ target per segment.
    pub target: HashMap<i32, f32>,
    /// m target per segment (a segment absent here keeps its m free).
    pub metallic: HashMap<i32, f32>,
}

/// The fit: a `FiptModel` on an autodiff device and its optimisers. A clone is an independent
/// snapshot (model, optimiser states, step count) to return to.
#[derive(Clone)]
pub struct Trainer {
    pub cfg: TrainConfig,
    /// Autodiff device.
    pub device: Device,
    /// The model being fitted. On the device path its host table (`model.grid.table`) is
    /// brought up to date by `sync_host_table` (and by every save); in between it is stale.
    pub model: FiptModel,
    pub(super) optim: ModuleOptimizer,
    pub(super) grid_opt: GridOpt,
    /// Seeds the semantic-loss partner draws, keyed by step: `gradients` and `step` at the
    /// same step see the same pairs.
    pub(super) seed: u64,
    pub steps: u64,
    /// Accumulated time per phase of `step`.
    pub profile: StepProfile,
    /// A σ pull added to the loss of every step while set (None: the objective of Eq. 15–20).
    pub pull: Option<SigmaPull>,
    /// A second pull of the same form, holding the segments that do not hop where they were
    /// (`train.hop.anchor`).
    pub anchor: Option<SigmaPull>,
    /// Per segment (`Batch::seg`), the weight s of Eq. 17's m term in place of
    /// `cfg.metallic_scale`; segments absent keep that (empty: every pixel keeps it).
    pub metallic_scales: HashMap<i32, f32>,
}

/// Seconds spent per phase of the training step, summed over `steps` steps. On a device that runs
/// ahead of the host (wgpu) a phase measures the time to queue its work, not to run it.
#[derive(Clone, Copy, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct StepProfile {
    /// The batch's upload (or gather from the device store) and the hash-grid encoding (on the
    /// host, or queued on the device).
    pub encode: f64,
    /// Forward: MLPs (fused host ones included), renderer, losses.
    pub forward: f64,
    /// Autodiff backward and, on the host path, reading the encoding gradient (through the
    /// fused host MLPs' backward where they run).
    pub backward: f64,
    /// The table's update: the host path's backward scatter and sparse Adam, or the device
    /// path's dense Adam.
    pub grid_update: f64,
    /// burn Adam on the MLPs.
    pub net_update: f64,
    pub steps: u64,
}

/// Whether `device` runs on the host CPU (flex, or ndarray where built).
fn is_cpu(device: &Device) -> bool {
    let plain = device.clone().inner();
    #[cfg(feature = "ndarray")]
    #[allow(deprecated)]
    if plain == Device::ndarray() {
        return true;
    }
    plain == Device::flex()
}

impl Trainer {
    /// A fresh model over `scene_box` on `device` (a plain device; autodiff is added here),
    /// seeded by `seed`.
    pub fn new(cfg: TrainConfig, scene_box: SceneBox, device: &Device, seed: u64) -> Self {
        Self::with_parts(cfg, scene_box, PartMap::default(), device, seed)
    }

    /// As `new`, with part offsets (`part_offsets`) over the parts of `parts` where it has
    /// any: the batches then carry each pixel's row (`Batch::part`).
    pub fn with_parts(
        cfg: TrainConfig,
        scene_box: SceneBox,
        parts: PartMap,
        device: &Device,
        seed: u64,
    ) -> Self {
        device.seed(seed);
        let ad = device.clone().autodiff();
        let spec = ModelSpec {
            material: cfg.material.clone(),
            emission: cfg.emission.clone(),
            scene_box,
            parts: parts.parts,
            part_columns: cfg.part_columns,
        };
        let mut model = FiptModel::init(spec, &ad, seed);
        model.part_map = parts;
        Self::assemble(cfg, ad, model, seed, None, None)
    }

    /// A trainer around `model` (on the autodiff `device`) with fresh optimisers, or burn's
    /// Adam state of the networks from `record` and, on the device path, of the table from
    /// `grid_record` (the host path's table moments are the caller's to restore). On the device
    /// path the model's host table is uploaded unless it is there already.
    pub(super) fn assemble(
        cfg: TrainConfig,
        device: Device,
        mut model: FiptModel,
        seed: u64,
        record: Option<burn::optim::OptimizerRecord>,
        grid_record: Option<burn::optim::OptimizerRecord>,
    ) -> Self {
        let adam = || {
            AdamConfig::new()
                .with_beta_1(cfg.beta1)
                .with_beta_2(cfg.beta2)
                .with_epsilon(cfg.eps)
                .init()
        };
        let with = |r: Option<burn::optim::OptimizerRecord>| match r {
            Some(r) => adam().load_record(r),
            None => adam(),
        };
        let optim = with(record);
        let grid_opt = if cfg.device_grid {
            if model.device_grid.is_none() {
                model.device_grid = Some(GridTables::from_host(&model.grid, &device));
            }
            GridOpt::Device {
                optim: with(grid_record),
            }
        } else {
            // The host path trains `grid.table`: bring it up to date first.
            model.sync_host_table();
            model.device_grid = None;
            GridOpt::Host {
                grad: TableGrad::new(&model.grid),
                adam: TableAdam::new(&model.grid, cfg.beta1, cfg.beta2, cfg.eps),
            }
        };
        Self {
            cfg,
            device,
            model,
            optim,
            grid_opt,
            seed,
            steps: 0,
            profile: StepProfile::default(),
            pull: None,
            anchor: None,
            metallic_scales: HashMap::new(),
        }
    }

    /// Whether the step runs the MLPs as fused host kernels (`TrainConfig::host_nets`, with the
    /// table on the host and a CPU device) rather than as burn graph ops.
    pub fn fused_nets(&self) -> bool {
        !self.device_resident() && self.cfg.host_nets && is_cpu(&self.device)
    }

    /// Whether the table lives on the device (`TrainConfig::device_grid`).
    pub fn device_resident(&self) -> bool {
        matches!(self.grid_opt, GridOpt::Device { .. })
    }

    /// Copies the device-resident table into `model.grid.table` (nothing on the host path).
    pub fn sync_host_table(&mut self) {
        self.model.sync_host_table();
    }

    /// One optimisation step on `batch` with segmentation loss `mode`.
    pub fn step(&mut self, batch: &Batch, mode: SegMode) -> LossParts {
        self.step_on(StepInput::Host(batch), mode).read()
    }

    /// One optimisation step on `input`. The host grid reads its loss at once (`Ready`); the
    /// device path leaves it on the device (`Pending`) for the caller to read when it logs.
    pub fn step_on(&mut self, input: StepInput, mode: SegMode) -> StepLoss {
        let f = self.forward(input, mode);
        let parts = f.parts.clone();
        let t2 = Instant::now();
        let b = self.backward(f);
        let (mut grads, g_enc) = (b.grads, b.enc);
        let t3 = Instant::now();
        let lr = self.cfg.lr;
        let m = &mut self.model;
        match (&mut self.grid_opt, g_enc) {
            (GridOpt::Host { grad, adam }, Some((g, xs))) => {
                m.grid.backward_adam(&xs, &g, grad, adam, lr as f32);
                // An inference copy on the device (`upload_table`) is stale now.
                m.device_grid = None;
            }
            (GridOpt::Device { optim }, None) => {
                let tables = m.device_grid.take().expect("device table");
                let gp = GradientsParams::from_module(&mut grads, &tables);
                m.device_grid = Some(optim.step(lr, tables, gp));
            }
            _ => unreachable!("the grid's optimiser matches where the table lives"),
        }
        let t4 = Instant::now();
        let gp = match b.host_nets {
            Some(gp) => gp,
            None => GradientsParams::from_grads(grads, &self.model.nets),
        };
        self.model.nets = self.optim.step(lr, self.model.nets.clone(), gp);
        let t5 = Instant::now();
        let p = &mut self.profile;
        p.backward += (t3 - t2).as_secs_f64();
        p.grid_update += (t4 - t3).as_secs_f64();
        p.net_update += (t5 - t4).as_secs_f64();
        p.steps += 1;
        self.steps += 1;
        if self.device_resident() {
            // Read later, with others (`StepLoss::read_all`).
            StepLoss::Pending(Box::new(parts))
        } else {
            transfer::download(5 * 4);
            StepLoss::Ready(LossParts::from_slice(
                &parts.try_into_vec_as::<f32>().expect("f32 losses"),
            ))
        }
    }

    /// Every network parameter in module order, as host vectors (`FiptModel::net_params`).
    pub fn net_params(&self) -> Vec<Vec<f32>> {
        self.model.net_params()
    }

    /// The table in the host layout, wherever it lives.
    pub fn table(&self) -> Vec<f32> {
        self.model.current_table()
    }
}
