//! The differentiable FIPT model on burn: BRDF terms, encodings, the two fields of Eq. 14, the
//! factorised renderer, the losses and the training step, on a `Device` chosen at run time.
//!
//! Owns: everything that is optimised in stage 2. Must not touch: ray tracing, files.

pub mod backend;
pub mod brdf;
pub mod fields;
pub mod fipt_model;
pub mod gather;
pub mod hashgrid;
pub mod hashgrid_device;
pub mod hashgrid_tensor;
pub mod host_mlp;
pub mod loss;
pub mod part_offsets;
pub mod pe;
pub mod render;
pub mod step;
pub mod transfer;

pub use backend::BackendKind;
pub use fields::{EmissionMask, EmissionMaskConfig, MaterialField, MaterialFieldConfig};
pub use fipt_model::{FiptModel, MaterialValues, ModelSpec, Nets, TableFormat};
pub use hashgrid::{HashGrid, HashGridConfig};
pub use part_offsets::{PartColumns, PartMap, PartOffsets};
pub use step::{Batch, LossParts, TrainConfig, Trainer};

#[cfg(test)]
mod tests;
