//! One stage-2 training step (paper §4.4–4.5, reference §2.3): forward through both fields and
//! the factorised renderer, the loss parts, backward, Adam. The hash grid runs one of two ways
//! (`TrainConfig::device_grid`):
//! - the fused host op (CPU backends): its encoding enters the graph as a leaf, and the leaf's
//!   gradient is scattered into the table by `HashGrid::backward_table` and applied by the sparse
//!   `TableAdam`;
//! - resident on the device (GPU backends, `hashgrid_device`): the table is a set of burn
//!   parameters updated by burn's (dense) Adam, and with a `DeviceStore` the pixels live on the
//!   device too, so a step uploads only its batch's indices and its losses are read back only
//!   when the caller asks (`StepLoss`).
//!
//! On the host path on a CPU device (`TrainConfig::host_nets`), the two MLPs run as fused host
//! kernels too (`host_mlp`): their outputs enter the graph as leaves, and the leaves' gradients
//! are carried back through the networks on the host. Elsewhere they are burn graph ops.
//!
//! The MLPs use burn's Adam on every path.
//!
//! Owns: `TrainConfig`, `Batch`, `Trainer::step`. Must not touch: pixel sampling, data loading.

use super::brdf::reflectances;
use super::fields::{
    EmissionMaskConfig, MaterialFieldConfig, alpha_from_raw, decode_material, register_host_grads,
    sigma_metallic_logits,
};
use super::fipt_model::{FiptModel, ModelSpec, TableFormat};
use super::gather::{index_tensor, select_int_dev, select_rows_dev};
use super::hashgrid::{TableAdam, TableGrad};
use super::hashgrid_device::{self, GridTables};
use super::host_mlp::{HostMlp, Tape, positional_encoding_host};
use super::loss;
use super::render::{Shadings, composite, render};
use super::transfer;
use crate::rng::Rng;
use crate::scene::SceneBox;
use crate::shading::ShadingLayout;
use burn::config::Config;
use burn::module::{Module, ModuleVisitor, Param};
use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer};
use burn::tensor::{Device, Int, Tensor, TensorData};
use std::borrow::Cow;
use std::collections::HashMap;
use std::path::Path;
use std::time::Instant;

const OPTIM_FILE: &str = "optim.bpk";
const TABLE_ADAM_FILE: &str = "table_adam.bin";
/// The device path's table (a burn record, which keeps the parameter ids its Adam state refers
/// to) and that Adam state.
const GRID_TABLES_FILE: &str = "grid_tables.bpk";
const GRID_OPTIM_FILE: &str = "grid_optim.bpk";
const TRAINER_FILE: &str = "trainer.json";

/// Which segmentation loss to use.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SegMode {
    /// Eq. 18–19 on part ids (`IndexMA`).
    Part,
    /// Eq. 20 on semantic labels.
    Semantic,
    /// No segmentation loss.
    None,
}

#[derive(Config, Debug)]
pub struct TrainConfig {
    #[config(default = "MaterialFieldConfig::new()")]
    pub material: MaterialFieldConfig,
    #[config(default = "EmissionMaskConfig::new()")]
    pub emission: EmissionMaskConfig,
    #[config(default = 1e-3)]
    pub lr: f64,
    #[config(default = 0.9)]
    pub beta1: f32,
    #[config(default = 0.999)]
    pub beta2: f32,
    #[config(default = 1e-8)]
    pub eps: f32,
    /// λ_e of Eq. 16.
    #[config(default = 1.0)]
    pub lambda_e: f32,
    /// λ_d of Eq. 17.
    #[config(default = 5e-4)]
    pub lambda_d: f32,
    /// λ_p of Eq. 18–19.
    #[config(default = 5e-3)]
    pub lambda_part: f32,
    /// Bound z_max on the material head's σ and m logits, held by [`loss::logit_bound_loss`]
    /// (None: unbounded, the reference).
    #[config(default = "None")]
    pub logit_bound: Option<f32>,
    /// Weight of the logit bound's penalty.
    #[config(default = 1e-3)]
    pub lambda_logit: f32,
    /// λ_s of Eq. 20.
    #[config(default = 1e-3)]
    pub lambda_sem: f32,
    /// Bilateral colour scale s_a of Eq. 20.
    #[config(default = 0.016_666_668)]
    pub sem_sigma_a: f32,
    /// Bilateral position scale s_p of Eq. 20.
    #[config(default = 0.1)]
    pub sem_sigma_p: f32,
    /// Random partners per pixel in Eq. 20.
    #[config(default = 1024)]
    pub sem_partners: usize,
    /// The hash grid resident on the device (`hashgrid_device`: table, indices, gradient and a
    /// dense Adam as device tensors) instead of the fused host op with its sparse Adam.
    #[config(default = false)]
    pub device_grid: bool,
    /// On the host grid's path on a CPU device, run both MLPs as fused host kernels
    /// (`host_mlp`) rather than as burn graph ops; the same step within float rounding.
    #[config(default = true)]
    pub host_nets: bool,
}

/// A batch of training pixels as plain host arrays.
#[derive(Clone, Debug, Default)]
pub struct Batch {
    /// First-hit positions normalised to the unit cube of the scene box (hash-grid input).
    pub x_unit: Vec<[f32; 3]>,
    /// First-hit positions in world space (emission-mask input).
    pub x_world: Vec<[f32; 3]>,
    /// `ShadingLayout::DIM` values per pixel.
    pub shadings: Vec<f32>,
    /// Ground-truth HDR radiance, 3 per pixel.
    pub gt: Vec<f32>,
    /// Segment id per pixel (part or semantic label).
    pub seg: Vec<i32>,
}

impl Batch {
    /// `n` random training pixels in a 4 × 2.7 × 3 m room, for tests and benchmarks: unit-cube
    /// and world positions, positive shadings, photo values (an emitter in one corner, 20×
    /// brighter) and three segments (0 and 2 by depth, 7 on the emitter).
    pub fn synthetic(n: usize, seed: u64) -> Batch {
        let mut r = Rng::new(seed, 1);
        let mut b = Batch::default();
        for _ in 0..n {
            let x = [r.next_f32(), r.next_f32(), r.next_f32()];
            b.x_unit.push(x);
            b.x_world
                .push([4.0 * x[0] - 2.0, 2.7 * x[1], 3.0 * x[2] - 1.5]);
            b.shadings.extend(
                (0..ShadingLayout::DIM).map(|k| 0.05 + r.next_f32() / (1.0 + k as f32 * 0.1)),
            );
            let emitter = x[0] > 0.8 && x[1] > 0.8;
            let scale = if emitter { 20.0 } else { 1.0 };
            b.gt.extend((0..3).map(|_| scale * (0.05 + r.next_f32())));
            b.seg
                .push(if emitter { 7 } else { 2 * (x[2] > 0.5) as i32 });
        }
        b
    }

    pub fn len(&self) -> usize {
        self.x_unit.len()
    }

    pub fn is_empty(&self) -> bool {
        self.x_unit.is_empty()
    }
}

/// Loss values of one step.
#[derive(Clone, Copy, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct LossParts {
    pub total: f32,
    pub color: f32,
    pub emission: f32,
    pub diffuse: f32,
    pub seg: f32,
}

impl LossParts {
    fn from_slice(v: &[f32]) -> Self {
        Self {
            total: v[0],
            color: v[1],
            emission: v[2],
            diffuse: v[3],
            seg: v[4],
        }
    }
}

/// A step's loss parts: read already, or still on the device (`[total, color, emission,
/// diffuse, seg]`) until `read` or `read_all` fetches them.
#[derive(Clone, Debug)]
pub enum StepLoss {
    Ready(LossParts),
    Pending(Box<Tensor<1>>),
}

impl StepLoss {
    /// The values (one device read if pending).
    pub fn read(self) -> LossParts {
        Self::read_all(vec![self])[0]
    }

    /// The values of several steps, with one device read for all the pending ones.
    pub fn read_all(losses: Vec<StepLoss>) -> Vec<LossParts> {
        let pending: Vec<Tensor<1>> = losses
            .iter()
            .filter_map(|l| match l {
                StepLoss::Pending(t) => Some((**t).clone()),
                StepLoss::Ready(_) => None,
            })
            .collect();
        let values = if pending.is_empty() {
            Vec::new()
        } else {
            transfer::download(pending.len() * 5 * 4);
            Tensor::cat(pending, 0)
                .try_into_vec_as::<f32>()
                .expect("f32 losses")
        };
        let mut k = 0;
        losses
            .into_iter()
            .map(|l| match l {
                StepLoss::Ready(p) => p,
                StepLoss::Pending(_) => {
                    k += 1;
                    LossParts::from_slice(&values[5 * (k - 1)..5 * k])
                }
            })
            .collect()
    }
}

/// Training pixels as device tensors: unit-cube and world positions, packed shadings, photo
/// values and segment ids (made compact, 0..n_seg, by `compact_ids`). As the device path's
/// pixel store it is uploaded once, and a step gathers its batch from it by index
/// (`rows`), uploading only the indices; a host batch is uploaded into one for its step.
pub struct DeviceStore {
    pub x_unit: Tensor<2>,
    pub x_world: Tensor<2>,
    pub shadings: Tensor<2>,
    pub gt: Tensor<2>,
    pub seg: Tensor<1, Int>,
    pub n_seg: usize,
}

impl DeviceStore {
    /// Uploads every pixel of `pixels` onto `device`.
    pub fn upload(pixels: &Batch, device: &Device) -> Self {
        let n = pixels.len();
        let (seg, n_seg) = compact_ids(&pixels.seg);
        Self {
            x_unit: upload2(flat3(&pixels.x_unit), [n, 3], device),
            x_world: upload2(flat3(&pixels.x_world), [n, 3], device),
            shadings: upload2(pixels.shadings.clone(), [n, ShadingLayout::DIM], device),
            gt: upload2(pixels.gt.clone(), [n, 3], device),
            seg: index_tensor(&seg, device),
            n_seg,
        }
    }

    /// Entries `idx`, gathered on the device (only the indices are uploaded); the segment ids
    /// keep the store's numbering.
    fn rows(&self, idx: &[u32], device: &Device) -> Self {
        let i: Vec<i64> = idx.iter().map(|&i| i as i64).collect();
        let i = index_tensor(&i, device);
        let rows = |t: &Tensor<2>| select_rows_dev(t.clone(), i.clone());
        Self {
            x_unit: rows(&self.x_unit),
            x_world: rows(&self.x_world),
            shadings: rows(&self.shadings),
            gt: rows(&self.gt),
            seg: select_int_dev(self.seg.clone(), i.clone()),
            n_seg: self.n_seg,
        }
    }

    /// Pixels held.
    fn len(&self) -> usize {
        self.x_unit.dims()[0]
    }
}

/// What a step trains on.
#[derive(Clone, Copy)]
pub enum StepInput<'a> {
    /// A batch gathered on the host and uploaded.
    Host(&'a Batch),
    /// Entries `idx` of a `DeviceStore` (only the indices are uploaded). The semantic loss
    /// also needs the batch's labels and positions on the host (`host`, gathered there from the
    /// host store); the part loss does not.
    Device {
        store: &'a DeviceStore,
        idx: &'a [u32],
        host: Option<&'a Batch>,
    },
}

/// Segment ids made compact, 0..S−1 in order of first appearance, and S.
fn compact_ids(seg: &[i32]) -> (Vec<i64>, usize) {
    let mut map: HashMap<i32, i64> = HashMap::new();
    let compact = seg
        .iter()
        .map(|s| {
            let k = map.len() as i64;
            *map.entry(*s).or_insert(k)
        })
        .collect();
    (compact, map.len())
}

/// A step's pixels as device tensors, and the host batch where the semantic loss needs it.
struct Pixels<'a> {
    t: DeviceStore,
    /// The batch on the host (always with a host batch; with a device store, only where the
    /// semantic loss needs it).
    host: Option<&'a Batch>,
}

impl<'a> Pixels<'a> {
    fn of(input: StepInput<'a>, dev: &Device) -> Self {
        match input {
            StepInput::Host(b) => Pixels {
                t: DeviceStore::upload(b, dev),
                host: Some(b),
            },
            StepInput::Device { store, idx, host } => Pixels {
                t: store.rows(idx, dev),
                host,
            },
        }
    }
}

/// How the hash table is optimised.
#[derive(Clone)]
enum GridOpt {
    /// The fused host op's sparse table gradient and Adam.
    Host { grad: TableGrad, adam: TableAdam },
    /// burn's Adam on the device-resident table (`FiptModel::device_grid`).
    Device { optim: ModuleOptimizer },
}

/// A pull of the roughness towards per-segment targets, added to the loss while it is set
/// (`Trainer::pull`): the first phase of a basin hop (`loss::sigma_pull_loss`, reported with
/// the prior). Segment ids are the batch's own (`Batch::seg`); pixels of other segments are
/// not pulled.
#[derive(Clone, Debug, Default)]
pub struct SigmaPull {
    pub weight: f32,
    pub target: HashMap<i32, f32>,
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
    optim: ModuleOptimizer,
    grid_opt: GridOpt,
    /// Seeds the semantic-loss partner draws, keyed by step: `gradients` and `step` at the
    /// same step see the same pairs.
    seed: u64,
    pub steps: u64,
    /// Accumulated time per phase of `step`.
    pub profile: StepProfile,
    /// A σ pull added to the loss of every step while set (None: the objective of Eq. 15–20).
    pub pull: Option<SigmaPull>,
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

/// Host values onto the device (counted).
fn upload2(v: Vec<f32>, shape: [usize; 2], dev: &Device) -> Tensor<2> {
    transfer::upload(v.len() * 4);
    Tensor::from_data(TensorData::new(v, shape), dev)
}

fn flat3(v: &[[f32; 3]]) -> Vec<f32> {
    v.iter().flatten().copied().collect()
}

/// A device tensor read back to the host (counted).
fn download(t: Tensor<2>) -> Vec<f32> {
    let v = t.try_into_vec_as::<f32>().expect("f32");
    transfer::download(v.len() * 4);
    v
}

/// What the forward pass leaves for the backward: on the host grid's path, the batch's positions
/// the table's backward scatters at and where the encoding's gradient comes from; the total
/// loss and the loss parts (detached, on the device).
struct Forward<'a> {
    grid: Option<(HostGridLeaf, Cow<'a, [[f32; 3]]>)>,
    total: Tensor<1>,
    parts: Tensor<1>,
}

/// Where the host grid's encoding gradient is read.
enum HostGridLeaf {
    /// The encoding is a leaf of the graph (burn's MLPs).
    Encoding(Box<Tensor<2>>),
    /// The fused host MLPs: their outputs are the graph's leaves.
    Nets(Box<HostNets>),
}

/// The fused host networks between forward and backward: each one's input, the network, its
/// tape and its output as a leaf of the graph.
struct HostNets {
    enc: Vec<f32>,
    material: HostMlp,
    material_tape: Tape,
    raw_material: Tensor<2>,
    pe: Vec<f32>,
    emission: HostMlp,
    emission_tape: Tape,
    raw_emission: Tensor<2>,
}

/// The encoding's gradient (N × `output_dim`) with the batch's unit-cube positions.
type EncodingGrad<'a> = (Vec<f32>, Cow<'a, [[f32; 3]]>);

/// What the backward gives: burn's gradients, the encoding's gradient with the batch's positions
/// (host grid) and, from the fused host networks, their parameter gradients.
struct Backward<'a> {
    grads: burn::tensor::Gradients,
    enc: Option<EncodingGrad<'a>>,
    host_nets: Option<GradientsParams>,
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
        device.seed(seed);
        let ad = device.clone().autodiff();
        let spec = ModelSpec {
            material: cfg.material.clone(),
            emission: cfg.emission.clone(),
            scene_box,
        };
        let model = FiptModel::init(spec, &ad, seed);
        Self::assemble(cfg, ad, model, seed, None, None)
    }

    /// A trainer around `model` (on the autodiff `device`) with fresh optimisers, or burn's
    /// Adam state of the networks from `record` and, on the device path, of the table from
    /// `grid_record` (the host path's table moments are the caller's to restore). On the device
    /// path the model's host table is uploaded unless it is there already.
    fn assemble(
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

    /// Writes the whole state of the fit between two steps into `dir` (a checkpoint): the model
    /// with its f32 table (`FiptModel::save`), burn's Adam state of the networks (`optim.bpk`),
    /// and the table's optimiser state: the host path's moments (`table_adam.bin`), or the
    /// device path's table record and burn Adam state (`grid_tables.bpk`, `grid_optim.bpk`);
    /// and the step count (`trainer.json`). Each file goes through a temporary name; the caller
    /// makes the folder appear atomically.
    pub fn save_state(&self, dir: &Path) -> Result<(), String> {
        self.model.save(dir, TableFormat::F32)?;
        let record_bytes = |r: burn::optim::OptimizerRecord, name: &str| {
            r.into_bytes()
                .map_err(|e| format!("{}: {e:?}", dir.join(name).display()))
        };
        let optim = record_bytes(self.optim.to_record(), OPTIM_FILE)?;
        crate::io::write_bytes_atomic(&dir.join(OPTIM_FILE), &optim).map_err(|e| e.to_string())?;
        match &self.grid_opt {
            GridOpt::Host { adam, .. } => adam
                .save(&dir.join(TABLE_ADAM_FILE))
                .map_err(|e| e.to_string())?,
            GridOpt::Device { optim } => {
                let tables = self.model.device_grid.as_ref().expect("device table");
                let tmp = dir.join("grid_tables.tmp.bpk");
                tables
                    .clone()
                    .save_file(&tmp)
                    .map_err(|e| format!("{}: {e:?}", tmp.display()))?;
                std::fs::rename(&tmp, dir.join(GRID_TABLES_FILE)).map_err(|e| e.to_string())?;
                let bytes = record_bytes(optim.to_record(), GRID_OPTIM_FILE)?;
                crate::io::write_bytes_atomic(&dir.join(GRID_OPTIM_FILE), &bytes)
                    .map_err(|e| e.to_string())?;
            }
        }
        let state = serde_json::json!({ "steps": self.steps });
        crate::io::write_bytes_atomic(&dir.join(TRAINER_FILE), state.to_string().as_bytes())
            .map_err(|e| e.to_string())
    }

    /// The trainer `save_state` wrote into `dir`, on `device` (plain; autodiff is added here),
    /// continuing exactly where it stopped: the next `step` gives what the uninterrupted fit's
    /// would. `cfg` and `seed` must be the fit's own; a model of another shape is refused.
    pub fn restore(
        cfg: TrainConfig,
        device: &Device,
        seed: u64,
        dir: &Path,
    ) -> Result<Self, String> {
        let ad = device.clone().autodiff();
        let mut model = FiptModel::load(dir, &ad)?;
        let same = |a: serde_json::Result<serde_json::Value>,
                    b: serde_json::Result<serde_json::Value>| {
            matches!((a, b), (Ok(a), Ok(b)) if a == b)
        };
        if !same(
            serde_json::to_value(&model.spec.material),
            serde_json::to_value(&cfg.material),
        ) || !same(
            serde_json::to_value(&model.spec.emission),
            serde_json::to_value(&cfg.emission),
        ) {
            return Err(format!(
                "{}: the checkpoint's networks differ from the config's",
                dir.join("model.json").display()
            ));
        }
        let load_record = |name: &str| -> Result<burn::optim::OptimizerRecord, String> {
            let path = dir.join(name);
            if !path.is_file() {
                return Err(format!("{}: missing", path.display()));
            }
            burn::optim::OptimizerRecord::load(&path)
                .map_err(|e| format!("{}: cannot read: {e:?}", path.display()))
        };
        let record = load_record(OPTIM_FILE)?;
        let state_path = dir.join(TRAINER_FILE);
        let text = crate::io::read_text(&state_path).map_err(|e| e.to_string())?;
        let steps = serde_json::from_str::<serde_json::Value>(&text)
            .ok()
            .and_then(|v| v.get("steps")?.as_u64())
            .ok_or_else(|| format!("{}: no step count", state_path.display()))?;
        let grid_record = if cfg.device_grid {
            let path = dir.join(GRID_TABLES_FILE);
            if !path.is_file() {
                return Err(format!("{}: missing", path.display()));
            }
            let tables = GridTables::from_host(&model.grid, &ad)
                .try_load_file(&path)
                .map_err(|e| format!("{}: cannot load the table: {e:?}", path.display()))?;
            if tables.to_host() != model.grid.table {
                return Err(format!(
                    "{}: differs from the checkpoint's hashgrid.bin",
                    path.display()
                ));
            }
            model.device_grid = Some(tables);
            Some(load_record(GRID_OPTIM_FILE)?)
        } else {
            None
        };
        let mut t = Self::assemble(cfg, ad, model, seed, Some(record), grid_record);
        if let GridOpt::Host { adam, .. } = &mut t.grid_opt {
            let adam_path = dir.join(TABLE_ADAM_FILE);
            let bytes = crate::io::read_bytes(&adam_path).map_err(|e| e.to_string())?;
            adam.load_bytes(&bytes)
                .map_err(|e| format!("{}: {e}", adam_path.display()))?;
        }
        t.steps = steps;
        Ok(t)
    }

    /// The forward pass on `input`: what the backward needs on the host grid's path (its
    /// positions, and the encoding or the fused networks' outputs as leaves), the total loss and
    /// the loss parts.
    fn forward<'a>(&mut self, input: StepInput<'a>, mode: SegMode) -> Forward<'a> {
        let dev = self.device.clone();
        let t0 = Instant::now();
        let px = Pixels::of(input, &dev);
        let n = px.t.len();
        let device_tables = match self.grid_opt {
            GridOpt::Device { .. } => self.model.device_grid.as_ref(),
            GridOpt::Host { .. } => None,
        };
        let fused = self.fused_nets();
        // The end of the encoding (the networks count as forward on every path).
        let t1;
        let (raw_mat, raw, grid) = match device_tables {
            Some(tables) => {
                let enc =
                    hashgrid_device::encode(&self.model.grid.levels, tables, px.t.x_unit.clone());
                t1 = Instant::now();
                let raw_mat = self.model.nets.material.forward(enc);
                let raw = self.model.nets.emission.raw(px.t.x_world.clone());
                (raw_mat, raw, None)
            }
            None if fused => {
                let xs = host_positions(&px);
                let enc = self.model.grid.encode(&xs);
                t1 = Instant::now();
                let nets = self.host_nets_forward(enc, &px);
                let (raw_mat, raw) = (nets.raw_material.clone(), nets.raw_emission.clone());
                (raw_mat, raw, Some((HostGridLeaf::Nets(Box::new(nets)), xs)))
            }
            None => {
                let xs = host_positions(&px);
                let d = self.model.grid.output_dim();
                let enc = upload2(self.model.grid.encode(&xs), [n, d], &dev).require_grad();
                t1 = Instant::now();
                let raw_mat = self.model.nets.material.forward(enc.clone());
                let raw = self.model.nets.emission.raw(px.t.x_world.clone());
                (
                    raw_mat,
                    raw,
                    Some((HostGridLeaf::Encoding(Box::new(enc)), xs)),
                )
            }
        };
        let mat = decode_material(raw_mat.clone());
        let (kd, ks) = reflectances(mat.a.clone(), mat.metallic.clone());
        let sh = Shadings::from_packed(px.t.shadings.clone());
        let (pred, spec) = render(kd, ks, mat.sigma.clone(), &sh);
        let alpha = alpha_from_raw(raw.clone());
        let lc = loss::color_loss(composite(pred, alpha, px.t.gt.clone()), px.t.gt.clone());
        let le = loss::emission_loss(raw, self.cfg.lambda_e);
        let mut ld = loss::diffuse_loss(mat.sigma.clone(), mat.metallic.clone(), self.cfg.lambda_d);
        if let Some(z_max) = self.cfg.logit_bound {
            // Reported with the prior it bounds (the loss parts keep their five slots).
            let z = sigma_metallic_logits(raw_mat);
            ld = ld + loss::logit_bound_loss(z, z_max, self.cfg.lambda_logit);
        }
        if let Some(pull) = &self.pull {
            let b = px
                .host
                .expect("the σ pull needs the batch on the host (StepInput::Device { host })");
            let (t, w): (Vec<f32>, Vec<f32>) = b
                .seg
                .iter()
                .map(|s| pull.target.get(s).map_or((0.0, 0.0), |&t| (t, 1.0)))
                .unzip();
            let (t, w) = (upload2(t, [n, 1], &dev), upload2(w, [n, 1], &dev));
            ld = ld + loss::sigma_pull_loss(mat.sigma.clone(), t, w, pull.weight);
        }
        let lseg = self.seg_loss(&px, mode, &mat, spec);
        let total = lc.clone() + le.clone() + ld.clone() + lseg.clone();
        let parts = Tensor::cat(vec![total.clone(), lc, le, ld, lseg], 0).detach();
        let p = &mut self.profile;
        p.encode += (t1 - t0).as_secs_f64();
        p.forward += t1.elapsed().as_secs_f64();
        Forward { grid, total, parts }
    }

    /// The fused host networks' forward on the batch: the material MLP on the encoding `enc`,
    /// the emission mask on the positional encoding of the batch's world positions, each
    /// output uploaded as a leaf of the graph.
    fn host_nets_forward(&self, enc: Vec<f32>, px: &Pixels) -> HostNets {
        let dev = &self.device;
        let nets = &self.model.nets;
        let xw = host_points(px.host.map(|b| &b.x_world[..]), &px.t.x_world);
        let n = xw.len();
        let material = nets.material.to_host();
        let (out, material_tape) = material.forward(&enc);
        let raw_material = upload2(out, [n, material.output()], dev).require_grad();
        let pe = positional_encoding_host(&xw, nets.emission.freqs);
        let emission = nets.emission.to_host();
        let (out, emission_tape) = emission.forward(&pe);
        let raw_emission = upload2(out, [n, emission.output()], dev).require_grad();
        HostNets {
            enc,
            material,
            material_tape,
            raw_material,
            pe,
            emission,
            emission_tape,
            raw_emission,
        }
    }

    /// The backward from `f.total`; with the fused host networks, through them on the host.
    fn backward<'a>(&self, f: Forward<'a>) -> Backward<'a> {
        let grads = f.total.backward();
        let Some((leaf, xs)) = f.grid else {
            return Backward {
                grads,
                enc: None,
                host_nets: None,
            };
        };
        match leaf {
            HostGridLeaf::Encoding(enc) => {
                let g = download(enc.grad(&grads).expect("encoding is a leaf of the graph"));
                Backward {
                    grads,
                    enc: Some((g, xs)),
                    host_nets: None,
                }
            }
            HostGridLeaf::Nets(h) => {
                // A network whose output got no gradient gets none either (Adam skips its
                // parameters, as it does on burn's graph), and passes none to the encoding.
                let plain = self.device.clone().inner();
                let nets = &self.model.nets;
                let mut gp = GradientsParams::new();
                let mut d_enc = vec![0.0; h.enc.len()];
                if let Some(g) = h.raw_material.grad(&grads) {
                    let (gm, dx) =
                        h.material
                            .backward(&h.enc, &h.material_tape, &download(g), true);
                    let material: Vec<&burn::nn::Linear> = nets.material.layers.iter().collect();
                    register_host_grads(&material, &gm, &mut gp, &plain);
                    d_enc = dx.expect("asked for");
                }
                if let Some(g) = h.raw_emission.grad(&grads) {
                    let (ge, _) = h
                        .emission
                        .backward(&h.pe, &h.emission_tape, &download(g), false);
                    register_host_grads(&nets.emission.all_layers(), &ge, &mut gp, &plain);
                }
                Backward {
                    grads,
                    enc: Some((d_enc, xs)),
                    host_nets: Some(gp),
                }
            }
        }
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

    /// Forward and backward without an update: the loss parts, the gradient of the loss w.r.t.
    /// the hash-grid encoding (N × `output_dim`, host path only; empty on the device path),
    /// w.r.t. the table (host layout, both paths) and w.r.t. every network parameter in module
    /// order (host). For parity tests across backends and paths, and for diagnostics.
    pub fn gradients(&mut self, batch: &Batch, mode: SegMode) -> StepGradients {
        let f = self.forward(StepInput::Host(batch), mode);
        let parts = LossParts::from_slice(&f.parts.clone().try_into_vec_as::<f32>().expect("f32"));
        let b = self.backward(f);
        let grads = b.grads;
        let (encoding, table) = match (b.enc, &self.model.device_grid) {
            (Some((g, xs)), _) => {
                let mut tg = TableGrad::new(&self.model.grid);
                self.model.grid.backward_table(&xs, &g, &mut tg);
                (g, tg.values)
            }
            (None, Some(tables)) => {
                let mut t = Vec::with_capacity(tables.len());
                for p in &tables.levels {
                    t.extend(match p.val().grad(&grads) {
                        Some(g) => g.try_into_vec_as::<f32>().expect("f32"),
                        None => vec![0.0; p.val().shape().num_elements()],
                    });
                }
                (Vec::new(), t)
            }
            (None, None) => unreachable!("a grid on the host has an encoding leaf"),
        };
        let mut visitor = ParamGrads {
            grads: &grads,
            host: b.host_nets.as_ref(),
            out: Vec::new(),
        };
        self.model.nets.visit(&mut visitor);
        StepGradients {
            parts,
            encoding,
            table,
            params: visitor.out,
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

    fn seg_loss(
        &mut self,
        px: &Pixels,
        mode: SegMode,
        mat: &super::fields::Material,
        spec: Tensor<2>,
    ) -> Tensor<1> {
        let dev = self.device.clone();
        match mode {
            SegMode::None => Tensor::<1>::zeros([1], &dev),
            SegMode::Part => loss::part_loss(
                mat.sigma.clone(),
                mat.metallic.clone(),
                spec,
                px.t.seg.clone(),
                px.t.n_seg,
                self.cfg.lambda_part,
            ),
            SegMode::Semantic => {
                // Partner draws and bilateral weights on the host: the batch's labels and
                // positions come from the host batch, the base colour is read back.
                let b = px.host.expect(
                    "the semantic loss needs the batch on the host (StepInput::Device { host })",
                );
                let (compact, n_labels) = compact_ids(&b.seg);
                let labels: Vec<i32> = compact.iter().map(|&k| k as i32).collect();
                let pairs = loss::semantic_pairs(
                    &labels,
                    self.cfg.sem_partners,
                    &mut Rng::new(self.seed ^ 0x5e9, self.steps),
                );
                let pos: Vec<f32> = b.x_unit.iter().flatten().map(|v| 2.0 * v - 1.0).collect();
                let a = download(mat.a.clone());
                let w = loss::semantic_weights(
                    &pairs,
                    &a,
                    &pos,
                    self.cfg.sem_sigma_a,
                    self.cfg.sem_sigma_p,
                );
                // The partner indices are counted where they are uploaded (`index_tensor`).
                transfer::upload(w.len() * 4);
                loss::semantic_loss(
                    mat.sigma.clone(),
                    mat.metallic.clone(),
                    &pairs,
                    &w,
                    &compact,
                    n_labels,
                    self.cfg.lambda_sem,
                )
            }
        }
    }
}

/// The batch's unit-cube positions on the host: from the host batch, else read back.
fn host_positions<'a>(px: &Pixels<'a>) -> Cow<'a, [[f32; 3]]> {
    host_points(px.host.map(|b| &b.x_unit[..]), &px.t.x_unit)
}

/// Points on the host: `host` where the batch is there, else `t` read back.
fn host_points<'a>(host: Option<&'a [[f32; 3]]>, t: &Tensor<2>) -> Cow<'a, [[f32; 3]]> {
    match host {
        Some(b) => Cow::Borrowed(b),
        None => Cow::Owned(
            download(t.clone())
                .chunks_exact(3)
                .map(|c| [c[0], c[1], c[2]])
                .collect(),
        ),
    }
}

/// What `Trainer::gradients` returns.
#[derive(Clone, Debug)]
pub struct StepGradients {
    pub parts: LossParts,
    /// d loss / d encoding, N × `output_dim` (host grid only; empty on the device path).
    pub encoding: Vec<f32>,
    /// d loss / d table, in the host table's layout.
    pub table: Vec<f32>,
    /// d loss / d parameter, one vector per parameter in module order (zeros where unused).
    pub params: Vec<Vec<f32>>,
}

/// Each parameter's gradient, from the fused host networks' (`host`) or from burn's graph.
struct ParamGrads<'a> {
    grads: &'a burn::tensor::Gradients,
    host: Option<&'a GradientsParams>,
    out: Vec<Vec<f32>>,
}

impl ModuleVisitor for ParamGrads<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        let v = param.val();
        let n = v.shape().num_elements();
        let host = self.host.and_then(|h| h.get::<D>(param.id));
        self.out.push(match host.or_else(|| v.grad(self.grads)) {
            Some(g) => g.try_into_vec_as::<f32>().expect("f32 gradient"),
            None => vec![0.0; n],
        });
    }
}
