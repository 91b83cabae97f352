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
//! The step lives in one file per role: `config` (settings), `batch` (the pixels a step trains
//! on), `synthetic` (made-up pixels for tests and benchmarks), `copies` (host↔device copies),
//! `losses` (what a step reports), `trainer` (the fit and its update), `paths` (forward and
//! backward on the three paths), `objective` (the losses), `gradients` (gradients without an
//! update) and `state` (checkpoints).
//!
//! Owns: the step's public names, re-exported here from those files. Must not touch: pixel
//! sampling, data loading.

mod batch;
mod config;
mod copies;
mod gradients;
mod losses;
mod objective;
mod paths;
mod state;
mod synthetic;
mod trainer;

pub use batch::{Batch, CAP_NONE, DeviceStore, StepInput};
pub use config::{SegMode, TrainConfig};
pub use gradients::StepGradients;
pub use losses::{LossParts, StepLoss};
pub use trainer::{SigmaPull, StepProfile, Trainer};
