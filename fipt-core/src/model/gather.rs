//! Row gathers and scatter-adds chunked to at most 65,535 indices per call.
//!
//! Measured on Mesa's lavapipe (wgpu on the CPU): `select_assign` with more indices silently
//! keeps only the first 65,535, and `select` gathers wrong values at 524k indices. Every index
//! op of the model goes through here so that wgpu stays correct (checked by
//! `tests/wgpu_parity.rs` with over 600k indices).
//!
//! Owns: chunking. Must not touch: what is gathered.

use burn::tensor::{Device, IndexingUpdateOp, Int, Tensor, TensorData};

/// Largest index count per `select`/`select_assign` call.
pub const INDEX_CHUNK: usize = 65_535;

fn index_tensor(idx: &[i64], device: &Device) -> Tensor<1, Int> {
    Tensor::from_data(TensorData::new(idx.to_vec(), [idx.len()]), device)
}

/// Rows `idx` of `table` [rows, F] → [idx.len(), F].
pub fn select_rows(table: Tensor<2>, idx: &[i64]) -> Tensor<2> {
    let device = table.device();
    let parts: Vec<Tensor<2>> = idx
        .chunks(INDEX_CHUNK)
        .map(|c| table.clone().select(0, index_tensor(c, &device)))
        .collect();
    Tensor::cat(parts, 0)
}

/// `out[idx[k]] += values[k]` into zeros of length `len`.
pub fn scatter_add(len: usize, idx: &[i64], values: Tensor<1>) -> Tensor<1> {
    let device = values.device();
    let mut out = Tensor::<1>::zeros([len], &device);
    for (c, chunk) in idx.chunks(INDEX_CHUNK).enumerate() {
        let start = c * INDEX_CHUNK;
        let v = values.clone().narrow(0, start, chunk.len());
        out = out.select_assign(0, index_tensor(chunk, &device), v, IndexingUpdateOp::Add);
    }
    out
}

/// Elements `idx` of `v`.
pub fn select_1d(v: Tensor<1>, idx: &[i64]) -> Tensor<1> {
    let n = v.dims()[0];
    select_rows(v.reshape([n, 1]), idx).reshape([idx.len()])
}
