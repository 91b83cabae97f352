//! The hash-grid encoding as plain burn tensor ops (gather with `select`, blend, sum), with the
//! corner indices and trilinear weights computed on the host by the same code as the fused op.
//!
//! It is the baseline the fused host op (`hashgrid`) is measured against, and an independent
//! check of the fused backward (burn's autodiff differentiates this one). Index ops are chunked
//! (`gather`), the limit past which some Vulkan drivers (lavapipe) drop writes.
//!
//! Owns: the tensor formulation. Must not touch: the table layout (owned by `hashgrid`).

use super::gather::select_rows;
use super::hashgrid::HashGrid;
use burn::tensor::{Device, Tensor, TensorData};

/// Host-side corner indices (global entries) and weights of a batch, in [point, level, corner]
/// order.
pub fn corners(grid: &HashGrid, xs: &[[f32; 3]]) -> (Vec<i64>, Vec<f32>) {
    let nl = grid.levels.len();
    let mut idx = Vec::with_capacity(xs.len() * nl * 8);
    let mut w = Vec::with_capacity(xs.len() * nl * 8);
    for &x in xs {
        for level in &grid.levels {
            let (ci, cw) = grid.cell_corners(level, x);
            idx.extend(ci.iter().map(|&i| (level.offset + i as usize) as i64));
            w.extend(cw);
        }
    }
    (idx, w)
}

/// Encodes `xs` with the table as a tensor `[entries, F]` (differentiable w.r.t. the table).
pub fn encode_tensor(grid: &HashGrid, table: Tensor<2>, xs: &[[f32; 3]]) -> Tensor<2> {
    let (n, nl, nf) = (xs.len(), grid.levels.len(), grid.features);
    let device = table.device();
    let (idx, w) = corners(grid, xs);
    let feats = select_rows(table, &idx).reshape([n, nl, 8, nf]);
    let w = Tensor::<4>::from_data(TensorData::new(w, [n, nl, 8, 1]), &device);
    (feats * w).sum_dim(2).reshape([n, nl * nf])
}

/// The table as a `[entries, F]` tensor.
pub fn table_tensor(grid: &HashGrid, device: &Device) -> Tensor<2> {
    let entries = grid.table.len() / grid.features;
    Tensor::from_data(
        TensorData::new(grid.table.clone(), [entries, grid.features]),
        device,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::hashgrid::{HashGridConfig, TableGrad};
    use crate::rng::Rng;

    /// The fused op and the tensor formulation agree: forward values, and the fused backward
    /// equals burn's autodiff gradient of the tensor formulation.
    #[test]
    fn fused_matches_tensor_ops_forward_and_backward() {
        let mut grid = HashGridConfig::new()
            .with_levels(8)
            .with_log2_table(12)
            .with_base_resolution(4.0)
            .with_per_level_scale(1.7)
            .init(4);
        let mut r = Rng::new(2, 2);
        grid.table.iter_mut().for_each(|v| *v = r.next_f32() - 0.5);
        let xs: Vec<[f32; 3]> = (0..500)
            .map(|_| [r.next_f32(), r.next_f32(), r.next_f32()])
            .collect();
        let dev = Device::flex().autodiff();
        let table = table_tensor(&grid, &dev).require_grad();
        let enc = encode_tensor(&grid, table.clone(), &xs);
        let fused = grid.encode(&xs);
        let t: Vec<f32> = enc.clone().try_into_vec_as::<f32>().unwrap();
        for (a, b) in t.iter().zip(&fused) {
            assert!((a - b).abs() < 1e-6, "{a} vs {b}");
        }
        let c: Vec<f32> = (0..fused.len()).map(|_| r.next_f32() - 0.5).collect();
        let ct = Tensor::<2>::from_data(
            TensorData::new(c.clone(), [xs.len(), grid.output_dim()]),
            &dev,
        );
        let g = (enc * ct).sum().backward();
        let g_tensor: Vec<f32> = table.grad(&g).unwrap().try_into_vec_as::<f32>().unwrap();
        let mut tg = TableGrad::new(&grid);
        grid.backward_table(&xs, &c, &mut tg);
        for (i, (a, b)) in g_tensor.iter().zip(&tg.values).enumerate() {
            assert!(
                (a - b).abs() < 1e-5 + 1e-5 * b.abs(),
                "entry {i}: {a} vs {b}"
            );
        }
    }
}
