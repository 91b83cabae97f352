//! Row gathers and scatter-adds chunked to at most 65,535 indices per call.
//!
//! Measured on Mesa's lavapipe (wgpu on the CPU): `select_assign` with more indices silently
//! keeps only the first 65,535, and `select` gathers wrong values at 524k indices. Every index
//! op of the model goes through here so that wgpu stays correct (checked by
//! `tests/wgpu_parity.rs` with over 600k indices). GPUs whose dispatch limits are larger can
//! take longer chunks (fewer launches): `FIPT_INDEX_CHUNK` sets the chunk length (at least
//! 1024); only lavapipe's limit has been measured. Indices given on the host are uploaded once;
//! indices already on the device (`*_dev`) are cut with `narrow` on the device.
//!
//! Owns: chunking. Must not touch: what is gathered.

use burn::tensor::{Device, IndexingUpdateOp, Int, Tensor, TensorData};

/// Largest index count per `select`/`select_assign` call by default (lavapipe's limit).
pub const INDEX_CHUNK: usize = 65_535;

/// The chunk length: `FIPT_INDEX_CHUNK` if set to a number ≥ 1024, else `INDEX_CHUNK`.
pub fn index_chunk() -> usize {
    static CHUNK: std::sync::OnceLock<usize> = std::sync::OnceLock::new();
    *CHUNK.get_or_init(|| {
        std::env::var("FIPT_INDEX_CHUNK")
            .ok()
            .and_then(|v| v.parse::<usize>().ok())
            .filter(|&c| c >= 1024)
            .unwrap_or(INDEX_CHUNK)
    })
}

/// Host indices as a device tensor (one upload).
pub fn index_tensor(idx: &[i64], device: &Device) -> Tensor<1, Int> {
    crate::model::transfer::upload(idx.len() * 8);
    Tensor::from_data(TensorData::new(idx.to_vec(), [idx.len()]), device)
}

/// The chunks of an index tensor of length `m`: (start, length).
fn chunks(m: usize) -> impl Iterator<Item = (usize, usize)> {
    let c = index_chunk();
    (0..m).step_by(c).map(move |s| (s, c.min(m - s)))
}

/// Rows `idx` of `table` [rows, F] → [m, F], with the indices on the device.
pub fn select_rows_dev(table: Tensor<2>, idx: Tensor<1, Int>) -> Tensor<2> {
    let m = idx.dims()[0];
    if m <= index_chunk() {
        return table.select(0, idx);
    }
    let parts: Vec<Tensor<2>> = chunks(m)
        .map(|(s, l)| table.clone().select(0, idx.clone().narrow(0, s, l)))
        .collect();
    Tensor::cat(parts, 0)
}

/// Rows `idx` of `table` [rows, F] → [idx.len(), F].
pub fn select_rows(table: Tensor<2>, idx: &[i64]) -> Tensor<2> {
    let device = table.device();
    select_rows_dev(table, index_tensor(idx, &device))
}

/// Elements `idx` of an int vector, with the indices on the device.
pub fn select_int_dev(v: Tensor<1, Int>, idx: Tensor<1, Int>) -> Tensor<1, Int> {
    let m = idx.dims()[0];
    if m <= index_chunk() {
        return v.select(0, idx);
    }
    let parts: Vec<Tensor<1, Int>> = chunks(m)
        .map(|(s, l)| v.clone().select(0, idx.clone().narrow(0, s, l)))
        .collect();
    Tensor::cat(parts, 0)
}

/// `out[idx[k]] += values[k]` into zeros of length `len`, with the indices on the device.
pub fn scatter_add_dev(len: usize, idx: Tensor<1, Int>, values: Tensor<1>) -> Tensor<1> {
    let device = values.device();
    let mut out = Tensor::<1>::zeros([len], &device);
    for (s, l) in chunks(idx.dims()[0]) {
        let v = values.clone().narrow(0, s, l);
        out = out.select_assign(0, idx.clone().narrow(0, s, l), v, IndexingUpdateOp::Add);
    }
    out
}

/// `out[idx[k]] += values[k]` into zeros of length `len`.
pub fn scatter_add(len: usize, idx: &[i64], values: Tensor<1>) -> Tensor<1> {
    let device = values.device();
    scatter_add_dev(len, index_tensor(idx, &device), values)
}

/// Elements `idx` of `v`, with the indices on the device.
pub fn select_1d_dev(v: Tensor<1>, idx: Tensor<1, Int>) -> Tensor<1> {
    let n = v.dims()[0];
    let m = idx.dims()[0];
    select_rows_dev(v.reshape([n, 1]), idx).reshape([m])
}

/// Elements `idx` of `v`.
pub fn select_1d(v: Tensor<1>, idx: &[i64]) -> Tensor<1> {
    let device = v.device();
    select_1d_dev(v, index_tensor(idx, &device))
}
