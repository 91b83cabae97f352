//! The training step's settings: the loss weights, Adam's constants and which execution path
//! the step takes (`TrainConfig`), and the segmentation loss (`SegMode`).
//!
//! Owns: `TrainConfig`, `SegMode`. Must not touch: the step itself, tensors, files.

use crate::model::fields::{EmissionMaskConfig, MaterialFieldConfig};
use crate::model::part_offsets::PartColumns;
use burn::config::Config;

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
    /// Weight of Eq. 17's m term as a multiple of λ_d (1: the paper's λ_d·(|σ − 1| + m)).
    #[config(default = 1.0)]
    pub metallic_scale: f32,
    /// σ₀ of Eq. 17, the roughness its prior pulls towards (1: the paper's).
    #[config(default = 1.0)]
    pub prior_sigma: f32,
    /// λ_p of Eq. 18–19.
    #[config(default = 5e-3)]
    pub lambda_part: f32,
    /// Bound z_max on the material head's σ and m logits, held by [`crate::model::loss::logit_bound_loss`]
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
    /// The logits the part offsets move, where the trainer has them (`Trainer::with_parts`).
    #[config(default = "PartColumns::All")]
    pub part_columns: PartColumns,
}
