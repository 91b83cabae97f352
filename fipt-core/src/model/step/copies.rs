//! The step's host↔device copies, counted in `model::transfer`.
//!
//! Owns: uploading host arrays and reading tensors back. Must not touch: what is copied.

use crate::model::transfer;
use burn::tensor::{Device, Tensor, TensorData};

/// Host values onto the device (counted).
pub(super) fn upload2(v: Vec<f32>, shape: [usize; 2], dev: &Device) -> Tensor<2> {
    transfer::upload(v.len() * 4);
    Tensor::from_data(TensorData::new(v, shape), dev)
}

pub(super) fn flat3(v: &[[f32; 3]]) -> Vec<f32> {
    v.iter().flatten().copied().collect()
}

/// A device tensor read back to the host (counted).
pub(super) fn download(t: Tensor<2>) -> Vec<f32> {
    let v = t.try_into_vec_as::<f32>().expect("f32");
    transfer::download(v.len() * 4);
    v
}
