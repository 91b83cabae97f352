//! One stage-2 training step (paper §4.4–4.5, reference §2.3): forward through both fields and
//! the factorised renderer, the loss parts, backward, Adam. The hash grid is a fused host op:
//! its encoding enters the graph as a leaf, and the leaf's gradient is scattered into the table
//! by `HashGrid::backward_table` and applied by `TableAdam`; the MLPs use burn's Adam.
//!
//! Owns: `TrainConfig`, `Batch`, `Trainer::step`. Must not touch: pixel sampling, data loading.

use super::brdf::reflectances;
use super::fields::{EmissionMaskConfig, MaterialFieldConfig, alpha_from_raw, decode_material};
use super::fipt_model::{FiptModel, ModelSpec, TableFormat};
use super::hashgrid::{TableAdam, TableGrad};
use super::loss;
use super::render::{Shadings, composite, render};
use crate::rng::Rng;
use crate::scene::SceneBox;
use crate::shading::ShadingLayout;
use burn::config::Config;
use burn::module::{Module, ModuleVisitor, Param};
use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer};
use burn::tensor::{Device, Tensor, TensorData};
use std::collections::HashMap;
use std::path::Path;
use std::time::Instant;

const OPTIM_FILE: &str = "optim.bpk";
const TABLE_ADAM_FILE: &str = "table_adam.bin";
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

/// The fit: a `FiptModel` on an autodiff device and its optimisers.
pub struct Trainer {
    pub cfg: TrainConfig,
    /// Autodiff device.
    pub device: Device,
    /// The model being fitted.
    pub model: FiptModel,
    optim: ModuleOptimizer,
    grid_grad: TableGrad,
    grid_adam: TableAdam,
    /// Seeds the semantic-loss partner draws, keyed by step: `gradients` and `step` at the
    /// same step see the same pairs.
    seed: u64,
    pub steps: u64,
    /// Accumulated time per phase of `step`.
    pub profile: StepProfile,
}

/// Seconds spent per phase of the training step, summed over `steps` steps.
#[derive(Clone, Copy, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct StepProfile {
    /// Hash-grid encoding on the host.
    pub encode: f64,
    /// Tensor forward: MLPs, renderer, losses (incl. reading the loss values).
    pub forward: f64,
    /// Autodiff backward and reading the encoding gradient.
    pub backward: f64,
    /// Hash-grid backward and sparse Adam.
    pub grid_update: f64,
    /// burn Adam on the MLPs.
    pub net_update: f64,
    pub steps: u64,
}

fn tensor2(v: Vec<f32>, shape: [usize; 2], dev: &Device) -> Tensor<2> {
    Tensor::from_data(TensorData::new(v, shape), dev)
}

fn flat3(v: &[[f32; 3]]) -> Vec<f32> {
    v.iter().flatten().copied().collect()
}

/// Backward from `total`: the gradients and, on the host, d total / d encoding.
fn backward(enc: Tensor<2>, total: Tensor<1>) -> (burn::tensor::Gradients, Vec<f32>) {
    let grads = total.backward();
    let g_enc = enc
        .grad(&grads)
        .expect("encoding is a leaf of the graph")
        .try_into_vec_as::<f32>()
        .expect("f32 gradient");
    (grads, g_enc)
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
        Self::assemble(cfg, ad, model, seed, None)
    }

    /// A trainer around `model` (on the autodiff `device`) with fresh optimisers, or burn's
    /// Adam state from `record` (the table's moments are the caller's to restore).
    fn assemble(
        cfg: TrainConfig,
        device: Device,
        model: FiptModel,
        seed: u64,
        record: Option<burn::optim::OptimizerRecord>,
    ) -> Self {
        let mut optim = AdamConfig::new()
            .with_beta_1(cfg.beta1)
            .with_beta_2(cfg.beta2)
            .with_epsilon(cfg.eps)
            .init();
        if let Some(r) = record {
            optim = optim.load_record(r);
        }
        let grid_grad = TableGrad::new(&model.grid);
        let grid_adam = TableAdam::new(&model.grid, cfg.beta1, cfg.beta2, cfg.eps);
        Self {
            cfg,
            device,
            model,
            optim,
            grid_grad,
            grid_adam,
            seed,
            steps: 0,
            profile: StepProfile::default(),
        }
    }

    /// Writes the whole state of the fit between two steps into `dir` (a checkpoint): the model
    /// with its f32 table (`FiptModel::save`), burn's Adam state of the networks (`optim.bpk`),
    /// the table's Adam moments (`table_adam.bin`) and the step count (`trainer.json`). Each file
    /// goes through a temporary name; the caller makes the folder appear atomically.
    pub fn save_state(&self, dir: &Path) -> Result<(), String> {
        self.model.save(dir, TableFormat::F32)?;
        let optim = self
            .optim
            .to_record()
            .into_bytes()
            .map_err(|e| format!("{}: {e:?}", dir.join(OPTIM_FILE).display()))?;
        crate::io::write_bytes_atomic(&dir.join(OPTIM_FILE), &optim).map_err(|e| e.to_string())?;
        self.grid_adam
            .save(&dir.join(TABLE_ADAM_FILE))
            .map_err(|e| e.to_string())?;
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
        let model = FiptModel::load(dir, &ad)?;
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
        let optim_path = dir.join(OPTIM_FILE);
        if !optim_path.is_file() {
            return Err(format!("{}: missing", optim_path.display()));
        }
        let record = burn::optim::OptimizerRecord::load(&optim_path)
            .map_err(|e| format!("{}: cannot read: {e:?}", optim_path.display()))?;
        let adam_path = dir.join(TABLE_ADAM_FILE);
        let adam = crate::io::read_bytes(&adam_path).map_err(|e| e.to_string())?;
        let state_path = dir.join(TRAINER_FILE);
        let text = crate::io::read_text(&state_path).map_err(|e| e.to_string())?;
        let steps = serde_json::from_str::<serde_json::Value>(&text)
            .ok()
            .and_then(|v| v.get("steps")?.as_u64())
            .ok_or_else(|| format!("{}: no step count", state_path.display()))?;
        let mut t = Self::assemble(cfg, ad, model, seed, Some(record));
        t.grid_adam
            .load_bytes(&adam)
            .map_err(|e| format!("{}: {e}", adam_path.display()))?;
        t.steps = steps;
        Ok(t)
    }

    /// The forward pass: the encoding leaf, the total loss and its parts.
    fn forward(&mut self, batch: &Batch, mode: SegMode) -> (Tensor<2>, Tensor<1>, LossParts) {
        let n = batch.len();
        let dev = self.device.clone();
        let d = self.model.grid.output_dim();
        let t0 = Instant::now();
        let enc = tensor2(self.model.grid.encode(&batch.x_unit), [n, d], &dev).require_grad();
        let t1 = Instant::now();
        let mat = decode_material(self.model.nets.material.forward(enc.clone()));
        let (kd, ks) = reflectances(mat.a.clone(), mat.metallic.clone());
        let sh = Shadings::from_packed(tensor2(
            batch.shadings.clone(),
            [n, ShadingLayout::DIM],
            &dev,
        ));
        let (pred, spec) = render(kd, ks, mat.sigma.clone(), &sh);
        let raw = self
            .model
            .nets
            .emission
            .raw(tensor2(flat3(&batch.x_world), [n, 3], &dev));
        let alpha = alpha_from_raw(raw.clone());
        let gt = tensor2(batch.gt.clone(), [n, 3], &dev);
        let lc = loss::color_loss(composite(pred, alpha, gt.clone()), gt);
        let le = loss::emission_loss(raw, self.cfg.lambda_e);
        let ld = loss::diffuse_loss(mat.sigma.clone(), mat.metallic.clone(), self.cfg.lambda_d);
        let lseg = self.seg_loss(batch, mode, &mat, spec);
        let total = lc.clone() + le.clone() + ld.clone() + lseg.clone();
        let parts = LossParts {
            total: total.clone().into_scalar(),
            color: lc.into_scalar(),
            emission: le.into_scalar(),
            diffuse: ld.into_scalar(),
            seg: lseg.into_scalar(),
        };
        let p = &mut self.profile;
        p.encode += (t1 - t0).as_secs_f64();
        p.forward += t1.elapsed().as_secs_f64();
        (enc, total, parts)
    }

    /// One optimisation step on `batch` with segmentation loss `mode`.
    pub fn step(&mut self, batch: &Batch, mode: SegMode) -> LossParts {
        let (enc, total, parts) = self.forward(batch, mode);
        let t2 = Instant::now();
        let (grads, g_enc) = backward(enc, total);
        let t3 = Instant::now();
        let lr = self.cfg.lr as f32;
        let m = &mut self.model;
        m.grid.backward_adam(
            &batch.x_unit,
            &g_enc,
            &mut self.grid_grad,
            &mut self.grid_adam,
            lr,
        );
        let t4 = Instant::now();
        let gp = GradientsParams::from_grads(grads, &self.model.nets);
        self.model.nets = self.optim.step(self.cfg.lr, self.model.nets.clone(), gp);
        let t5 = Instant::now();
        let p = &mut self.profile;
        p.backward += (t3 - t2).as_secs_f64();
        p.grid_update += (t4 - t3).as_secs_f64();
        p.net_update += (t5 - t4).as_secs_f64();
        p.steps += 1;
        self.steps += 1;
        parts
    }

    /// Forward and backward without an update: the loss parts, the gradient of the loss w.r.t.
    /// the hash-grid encoding (N × `output_dim`, host) and w.r.t. every network parameter in
    /// module order (host). For parity tests across backends and for diagnostics.
    pub fn gradients(&mut self, batch: &Batch, mode: SegMode) -> StepGradients {
        let (enc, total, parts) = self.forward(batch, mode);
        let (grads, encoding) = backward(enc, total);
        let mut visitor = ParamGrads {
            grads: &grads,
            out: Vec::new(),
        };
        self.model.nets.visit(&mut visitor);
        StepGradients {
            parts,
            encoding,
            params: visitor.out,
        }
    }

    /// Every network parameter in module order, as host vectors (`FiptModel::net_params`).
    pub fn net_params(&self) -> Vec<Vec<f32>> {
        self.model.net_params()
    }

    fn seg_loss(
        &mut self,
        batch: &Batch,
        mode: SegMode,
        mat: &super::fields::Material,
        spec: Tensor<2>,
    ) -> Tensor<1> {
        let dev = self.device.clone();
        // Compact the batch's segment ids to 0..S−1.
        let mut map: HashMap<i32, i64> = HashMap::new();
        let compact: Vec<i64> = batch
            .seg
            .iter()
            .map(|s| {
                let k = map.len() as i64;
                *map.entry(*s).or_insert(k)
            })
            .collect();
        match mode {
            SegMode::None => Tensor::<1>::zeros([1], &dev),
            SegMode::Part => loss::part_loss(
                mat.sigma.clone(),
                mat.metallic.clone(),
                spec,
                &compact,
                map.len(),
                self.cfg.lambda_part,
            ),
            SegMode::Semantic => {
                let labels: Vec<i32> = compact.iter().map(|&k| k as i32).collect();
                let pairs = loss::semantic_pairs(
                    &labels,
                    self.cfg.sem_partners,
                    &mut Rng::new(self.seed ^ 0x5e9, self.steps),
                );
                let pos: Vec<f32> = batch
                    .x_unit
                    .iter()
                    .flatten()
                    .map(|v| 2.0 * v - 1.0)
                    .collect();
                let a: Vec<f32> = mat.a.clone().try_into_vec_as::<f32>().expect("f32");
                let w = loss::semantic_weights(
                    &pairs,
                    &a,
                    &pos,
                    self.cfg.sem_sigma_a,
                    self.cfg.sem_sigma_p,
                );
                loss::semantic_loss(
                    mat.sigma.clone(),
                    mat.metallic.clone(),
                    &pairs,
                    &w,
                    &compact,
                    map.len(),
                    self.cfg.lambda_sem,
                )
            }
        }
    }
}

/// What `Trainer::gradients` returns.
#[derive(Clone, Debug)]
pub struct StepGradients {
    pub parts: LossParts,
    /// d loss / d encoding, N × `output_dim`.
    pub encoding: Vec<f32>,
    /// d loss / d parameter, one vector per parameter in module order (zeros where unused).
    pub params: Vec<Vec<f32>>,
}

struct ParamGrads<'a> {
    grads: &'a burn::tensor::Gradients,
    out: Vec<Vec<f32>>,
}

impl ModuleVisitor for ParamGrads<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        let v = param.val();
        let n = v.shape().num_elements();
        self.out.push(match v.grad(self.grads) {
            Some(g) => g.try_into_vec_as::<f32>().expect("f32 gradient"),
            None => vec![0.0; n],
        });
    }
}
