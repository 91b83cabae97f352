//! The hash-grid encoding resident on the device: the table as one burn parameter per level,
//! and the corner indices, the spatial hash, the trilinear weights, the gather and (through
//! autodiff) the backward's scatter computed with tensor ops on the device, so that a GPU step
//! moves no table, encoding or encoding gradient between host and device. burn's Adam then
//! updates the table on the device (dense: every entry, as PyTorch's Adam does on tcnn's
//! parameters in the reference; the host path's `TableAdam` is sparse).
//!
//! The level layout (`Level`: offset, size, scale, dense or hashed) and the hash primes are
//! `hashgrid`'s; the indexing itself is written twice (the host loop `cell`, the tensor ops
//! `level_corners`) and checked against each other: bit for bit on flex (tests in this file),
//! and through the encoding, the gradients and a training step on wgpu (`tests/wgpu_parity.rs`).
//! A GPU compiler may fuse `x·scale + 0.5` into one rounding (FMA), which can move a point
//! lying within rounding of a cell face into the neighbouring cell; the encoding is continuous
//! there, so the values agree to rounding.
//!
//! Owns: the device formulation of the grid. Must not touch: the layout or the hash (owned by
//! `hashgrid`).

use super::gather::select_rows_dev;
use super::hashgrid::{HashGrid, Level, PRIMES};
use burn::module::{Module, Param};
use burn::tensor::{Device, Int, Tensor, TensorData};

/// The table on the device: level `l` is a `[size_l, F]` parameter, in `HashGrid::levels` order.
#[derive(Module, Debug)]
pub struct GridTables {
    pub levels: Vec<Param<Tensor<2>>>,
}

impl GridTables {
    /// The host table of `grid`, uploaded level by level onto `device`.
    pub fn from_host(grid: &HashGrid, device: &Device) -> Self {
        let nf = grid.features;
        let levels = grid
            .levels
            .iter()
            .map(|l| {
                let v = grid.table[l.offset * nf..(l.offset + l.size) * nf].to_vec();
                Param::from_tensor(Tensor::from_data(TensorData::new(v, [l.size, nf]), device))
            })
            .collect();
        Self { levels }
    }

    /// The table in the host layout (`HashGrid::table`: entries × features, level after level).
    pub fn to_host(&self) -> Vec<f32> {
        let mut out = Vec::new();
        for p in &self.levels {
            out.extend(p.val().try_into_vec_as::<f32>().expect("f32 table"));
        }
        out
    }

    /// Values in the table.
    pub fn len(&self) -> usize {
        self.levels
            .iter()
            .map(|p| p.val().shape().num_elements())
            .sum()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Corner offsets of a cell along x, y, z, in `hashgrid::cell`'s corner order (bit k of the
/// corner number is the offset along axis k): row k of a [3, 8] tensor, uploaded once per
/// encoding (an upload is a host–device round trip on a GPU, so not once per level).
pub struct CornerOffsets([Tensor<2, Int>; 3]);

impl CornerOffsets {
    pub fn new(device: &Device) -> Self {
        crate::model::transfer::upload(3 * 8 * 8);
        let v: Vec<i64> = (0..3)
            .flat_map(|k| (0..8).map(move |c| ((c >> k) & 1) as i64))
            .collect();
        let all = Tensor::<2, Int>::from_data(TensorData::new(v, [3, 8]), device);
        Self(std::array::from_fn(|k| all.clone().slice([k..k + 1, 0..8])))
    }
}

/// The 8 corners of each point's cell on `level`, on the device: local entry indices [N, 8]
/// and trilinear weights [N, 8]. The same arithmetic as `hashgrid::cell`: p = clamp(x, 0, 1)·
/// scale + 0.5, corner vertex floor(p) + b; dense levels index v_x + r·(v_y + r·v_z) with each
/// coordinate clamped to r − 1, hashed levels (v_x·1 ⊕ v_y·π₂ ⊕ v_z·π₃) mod T, where the
/// products wrap (i32 on GPUs) or not (i64 on the CPU backends): T is a power of two, so the
/// residue is the same; weights Π_k (b_k ? f_k : 1 − f_k), multiplied in axis order.
pub fn level_corners(
    level: &Level,
    x_unit: Tensor<2>,
    offsets: &CornerOffsets,
) -> (Tensor<2, Int>, Tensor<2>) {
    let [n, _] = x_unit.dims();
    let p = x_unit
        .clamp(0.0, 1.0)
        .mul_scalar(level.scale)
        .add_scalar(0.5);
    let f = p.clone().floor();
    let frac = p - f.clone();
    let g = f.int();
    let b = &offsets.0;
    let axis = |k: usize| -> (Tensor<2, Int>, Tensor<2>) {
        let v = g.clone().slice([0..n, k..k + 1]) + b[k].clone();
        let fk = frac.clone().slice([0..n, k..k + 1]);
        let bf = b[k].clone().float();
        // b·f + (1 − b)·(1 − f): exactly f where b = 1 and 1 − f where b = 0.
        let w = bf.clone() * fk.clone() + bf.neg().add_scalar(1.0) * fk.neg().add_scalar(1.0);
        (v, w)
    };
    let (vx, wx) = axis(0);
    let (vy, wy) = axis(1);
    let (vz, wz) = axis(2);
    let idx = if level.dense {
        let r = level.res as i64;
        let c = |v: Tensor<2, Int>| v.clamp_max(r - 1);
        c(vx) + (c(vy) + c(vz).mul_scalar(r)).mul_scalar(r)
    } else {
        debug_assert!(level.size.is_power_of_two());
        // The primes as the i32 bit patterns of their u32 values: the same residue mod 2^32.
        let prime = |k: usize| PRIMES[k] as i32 as i64;
        vx.mul_scalar(prime(0))
            .bitwise_xor(vy.mul_scalar(prime(1)))
            .bitwise_xor(vz.mul_scalar(prime(2)))
            .bitwise_and_scalar(level.size as i64 - 1)
    };
    (idx, wx * wy * wz)
}

/// One level's features [N, F]: Σ_c w_c · T_l[idx_c] (gathered on the device).
fn encode_level(
    level: &Level,
    table: Tensor<2>,
    x_unit: Tensor<2>,
    offsets: &CornerOffsets,
) -> Tensor<2> {
    let [n, _] = x_unit.dims();
    let [_, nf] = table.dims();
    let (idx, w) = level_corners(level, x_unit, offsets);
    let feats = select_rows_dev(table, idx.reshape([n * 8])).reshape([n, 8, nf]);
    (feats * w.reshape([n, 8, 1])).sum_dim(1).reshape([n, nf])
}

/// The encoding [N, levels·F] of unit-cube points `x_unit` [N, 3], levels side by side as
/// `HashGrid::encode` lays them out; differentiable w.r.t. every level's table.
pub fn encode(levels: &[Level], tables: &GridTables, x_unit: Tensor<2>) -> Tensor<2> {
    let offsets = CornerOffsets::new(&x_unit.device());
    let parts = levels
        .iter()
        .zip(&tables.levels)
        .map(|(l, t)| encode_level(l, t.val(), x_unit.clone(), &offsets))
        .collect();
    Tensor::cat(parts, 1)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::hashgrid::{HashGridConfig, TableGrad};
    use crate::rng::Rng;

    fn grid() -> HashGrid {
        let mut g = HashGridConfig::new()
            .with_levels(10)
            .with_log2_table(10)
            .with_base_resolution(4.0)
            .with_per_level_scale(1.6)
            .init(3);
        assert!(g.levels.iter().any(|l| l.dense) && g.levels.iter().any(|l| !l.dense));
        let mut r = Rng::new(2, 2);
        g.table.iter_mut().for_each(|v| *v = r.next_f32() - 0.5);
        g
    }

    /// Points anywhere in the cube, on its faces and outside it (clamped).
    fn points(n: usize) -> Vec<[f32; 3]> {
        let mut r = Rng::new(8, 8);
        let mut xs: Vec<[f32; 3]> = (0..n)
            .map(|_| [r.next_f32(), r.next_f32(), r.next_f32()])
            .collect();
        xs.extend([[0.0; 3], [1.0; 3], [-0.2, 1.3, 0.5], [1.0, 0.0, 0.999_999]]);
        xs
    }

    fn tensor(xs: &[[f32; 3]], dev: &Device) -> Tensor<2> {
        let v: Vec<f32> = xs.iter().flatten().copied().collect();
        Tensor::from_data(TensorData::new(v, [xs.len(), 3]), dev)
    }

    /// The device corners equal the host's `cell` on every level: the same entries (bit for
    /// bit, dense and hashed levels) and the same weights.
    #[test]
    fn device_corners_equal_host_cells() {
        let g = grid();
        let xs = points(500);
        let dev = Device::flex();
        for level in &g.levels {
            let (idx, w) = level_corners(level, tensor(&xs, &dev), &CornerOffsets::new(&dev));
            let idx: Vec<i64> = idx.into_data().convert::<i64>().try_to_vec().unwrap();
            let w: Vec<f32> = w.try_into_vec_as::<f32>().unwrap();
            for (p, &x) in xs.iter().enumerate() {
                let (hi, hw) = g.cell_corners(level, x);
                for c in 0..8 {
                    assert_eq!(idx[8 * p + c], hi[c] as i64, "level {level:?} point {x:?}");
                    assert_eq!(w[8 * p + c], hw[c], "weight, level {level:?} point {x:?}");
                }
            }
        }
    }

    /// Forward equals `HashGrid::encode`; autodiff's table gradient equals the host backward.
    #[test]
    fn device_encoding_and_gradient_equal_host() {
        let g = grid();
        let xs = points(700);
        let dev = Device::flex().autodiff();
        let tables = GridTables::from_host(&g, &dev);
        assert_eq!(tables.to_host(), g.table);
        let enc = encode(&g.levels, &tables, tensor(&xs, &dev));
        let host = g.encode(&xs);
        let dv: Vec<f32> = enc.clone().try_into_vec_as::<f32>().unwrap();
        for (a, b) in dv.iter().zip(&host) {
            assert!((a - b).abs() <= 1e-6, "{a} vs {b}");
        }
        let mut r = Rng::new(5, 5);
        let c: Vec<f32> = (0..host.len()).map(|_| r.next_f32() - 0.5).collect();
        let ct =
            Tensor::<2>::from_data(TensorData::new(c.clone(), [xs.len(), g.output_dim()]), &dev);
        let grads = (enc * ct).sum().backward();
        let mut dg = Vec::new();
        for p in &tables.levels {
            dg.extend(
                p.val()
                    .grad(&grads)
                    .unwrap()
                    .try_into_vec_as::<f32>()
                    .unwrap(),
            );
        }
        let mut tg = TableGrad::new(&g);
        g.backward_table(&xs, &c, &mut tg);
        assert_eq!(dg.len(), tg.values.len());
        assert!(tg.values.iter().filter(|v| **v != 0.0).count() > 1000);
        for (a, b) in dg.iter().zip(&tg.values) {
            assert!((a - b).abs() <= 1e-5, "{a} vs {b}");
        }
    }
}
