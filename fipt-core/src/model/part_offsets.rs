//! Per-part offsets of the material head's logits (`train.part_offsets`, a departure from the
//! reference): a learned row of logits per segment of the training labels (all five, or σ and
//! m, or σ alone: `PartColumns`), added to the material MLP's raw output at every point of that
//! segment's triangles.
//!
//! The hash grid cannot tell apart two parts that share its cells: a thin metal table leg takes
//! in the floor around it. An offset per part lets such a part differ from its neighbours by a
//! constant in logit space while the field keeps the spatial detail. The offsets start at zero,
//! so a fit starts from the field alone.
//!
//! Owns: the offset table (`PartOffsets`), the triangle → row map (`PartMap`) and its file
//! form. Must not touch: where the labels come from (the pipeline fuses them per triangle), the
//! losses.

use super::fields::{METALLIC_COL, SIGMA_COL};
use super::gather::select_rows_dev;
use burn::module::{Module, Param};
use burn::tensor::ops::PadMode;
use burn::tensor::{Device, Int, Tensor};
use std::ops::Range;

/// Columns of the material head (`fields::decode_material`: a, σ, m).
const COLS: usize = 5;

/// Which of the material head's logits the offsets move (`train.part_offset_columns`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PartColumns {
    /// Base colour, σ and m: all five.
    #[default]
    All,
    /// σ and m: a part's base colour comes from the field alone.
    RoughnessMetallic,
    /// σ alone.
    Roughness,
}

impl PartColumns {
    /// The columns of the material head's raw output that the table's columns move, in order.
    pub fn range(self) -> Range<usize> {
        match self {
            Self::All => 0..COLS,
            Self::RoughnessMetallic => SIGMA_COL..METALLIC_COL + 1,
            Self::Roughness => SIGMA_COL..SIGMA_COL + 1,
        }
    }
}

/// The offsets are `GAIN` × the table. Adam moves a parameter by about the learning rate per
/// step whatever its gradient's scale, so a bare table would travel about 1.3 logits over a
/// 300-step fit at 1e-2 → 1e-3: short of the 3 logits between σ 0.8 and σ 0.2, or the 10
/// between m = 0 and m = 1. The field's own outputs move faster: every point sums 16 levels of
/// table entries through the MLP's gain.
pub const GAIN: f32 = 10.0;

/// The learned offsets: `GAIN` × `table` [parts, k], added to the k columns of the material
/// head's raw output that start at `first` (`PartColumns::range`).
#[derive(Module, Debug)]
pub struct PartOffsets {
    pub table: Param<Tensor<2>>,
    /// The first column of the raw output that the table's first column moves.
    pub first: usize,
}

impl PartOffsets {
    /// `parts` rows of zeros over `columns`, on `device`.
    pub fn zeros(parts: usize, columns: PartColumns, device: &Device) -> Self {
        let r = columns.range();
        Self {
            table: Param::from_tensor(Tensor::zeros([parts, r.len()], device)),
            first: r.start,
        }
    }

    /// raw [N,5] + GAIN · table[rows] [N,k], placed at columns `first..first + k` (the others
    /// get zero). `rows` [N] index the table; the row one past its last (`PartMap::parts`, the
    /// "no part" row) adds zero and is never trained. The table is widened to the five columns,
    /// and given that zero row, before the gather: [parts + 1, 5], not [N, 5].
    pub fn forward(&self, raw: Tensor<2>, rows: Tensor<1, Int>) -> Tensor<2> {
        let t = self.table.val().mul_scalar(GAIN);
        let [_, k] = t.dims();
        let wide = t.pad(
            [(0, 1), (self.first, COLS - self.first - k)],
            PadMode::Constant(0.0),
        );
        raw + select_rows_dev(wide, rows)
    }
}

/// Which row of the offset table each triangle of the mesh reads: the rows are the distinct
/// labels ≥ 0 in increasing order; a triangle without a label reads the "no part" row, `parts`.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct PartMap {
    pub tri_row: Vec<u32>,
    pub parts: usize,
}

impl PartMap {
    /// The map of per-triangle labels (negative: unlabelled).
    pub fn from_labels(tri_labels: &[i32]) -> Self {
        let mut labels: Vec<i32> = tri_labels.iter().copied().filter(|&l| l >= 0).collect();
        labels.sort_unstable();
        labels.dedup();
        let parts = labels.len();
        let tri_row = tri_labels
            .iter()
            .map(|l| match labels.binary_search(l) {
                Ok(r) if *l >= 0 => r as u32,
                _ => parts as u32,
            })
            .collect();
        Self { tri_row, parts }
    }

    /// The "no part" row (zero offset).
    pub fn none_row(&self) -> u32 {
        self.parts as u32
    }

    /// The row of each triangle of `tris`; a triangle outside the map (a mesh the map was not
    /// made for, an inserted object) reads the "no part" row.
    pub fn rows(&self, tris: &[u32]) -> Vec<u32> {
        tris.iter()
            .map(|&t| {
                self.tri_row
                    .get(t as usize)
                    .copied()
                    .unwrap_or(self.none_row())
            })
            .collect()
    }

    /// Little-endian u32 per triangle.
    pub fn to_bytes(&self) -> Vec<u8> {
        self.tri_row.iter().flat_map(|r| r.to_le_bytes()).collect()
    }

    /// The map `to_bytes` wrote, for a table of `parts` rows; rows past `parts` are refused.
    pub fn from_bytes(bytes: &[u8], parts: usize) -> Result<Self, String> {
        if !bytes.len().is_multiple_of(4) {
            return Err(format!("{} bytes, not a whole number of u32", bytes.len()));
        }
        let tri_row: Vec<u32> = bytes
            .chunks_exact(4)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect();
        if let Some(t) = tri_row.iter().position(|&r| r as usize > parts) {
            return Err(format!(
                "triangle {t} reads row {}, but the table has {parts} parts",
                tri_row[t]
            ));
        }
        Ok(Self { tri_row, parts })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::TensorData;

    #[test]
    fn rows_follow_sorted_labels_and_unlabelled_reads_none() {
        let m = PartMap::from_labels(&[7, -1, 3, 7, 12, 3]);
        assert_eq!(m.parts, 3);
        assert_eq!(m.tri_row, vec![1, 3, 0, 1, 2, 0]);
        assert_eq!(m.rows(&[4, 1, 99]), vec![2, 3, 3]);
        let back = PartMap::from_bytes(&m.to_bytes(), 3).unwrap();
        assert_eq!(back, m);
        assert!(PartMap::from_bytes(&m.to_bytes(), 2).is_err());
        assert!(PartMap::from_bytes(&[0, 0, 0], 2).is_err());
    }

    /// The forward adds row r to each point of row r, zero on the none row; the gradient of a
    /// sum over points reaches each row once per point and never the none row.
    #[test]
    fn offsets_add_their_row_and_gradients_count_points() {
        let dev = Device::flex().autodiff();
        let mut po = PartOffsets::zeros(2, PartColumns::All, &dev);
        let vals: Vec<f32> = (0..10).map(|i| i as f32).collect();
        po.table = Param::from_tensor(Tensor::from_data(TensorData::new(vals, [2, 5]), &dev));
        let raw = Tensor::<2>::ones([4, 5], &dev);
        let rows = Tensor::<1, Int>::from_data(TensorData::new(vec![1i64, 0, 2, 1], [4]), &dev);
        let out = po.forward(raw, rows);
        let v = out.clone().try_into_vec_as::<f32>().unwrap();
        let want =
            |r: usize| -> Vec<f32> { (0..5).map(|c| 1.0 + GAIN * (5 * r + c) as f32).collect() };
        assert_eq!(&v[0..5], &want(1)[..]);
        assert_eq!(&v[5..10], &want(0)[..]);
        assert_eq!(&v[10..15], &[1.0; 5]);
        let grads = out.sum().backward();
        let g = po.table.val().grad(&grads).unwrap();
        let g = g.try_into_vec_as::<f32>().unwrap();
        assert_eq!(g, [vec![GAIN; 5], vec![2.0 * GAIN; 5]].concat());
    }

    /// Offsets over σ and m move columns 3 and 4 alone; the base colour's columns get neither
    /// an offset nor a path back to the table.
    #[test]
    fn column_subsets_move_only_their_columns() {
        let dev = Device::flex().autodiff();
        for (cols, moved) in [
            (PartColumns::RoughnessMetallic, 3..5),
            (PartColumns::Roughness, 3..4),
        ] {
            let mut po = PartOffsets::zeros(2, cols, &dev);
            let k = moved.len();
            let vals: Vec<f32> = (0..2 * k).map(|i| 1.0 + i as f32).collect();
            po.table = Param::from_tensor(Tensor::from_data(TensorData::new(vals, [2, k]), &dev));
            let raw = Tensor::<2>::zeros([3, 5], &dev);
            let rows = Tensor::<1, Int>::from_data(TensorData::new(vec![1i64, 2, 0], [3]), &dev);
            let out = po.forward(raw, rows);
            let v = out.clone().try_into_vec_as::<f32>().unwrap();
            for (p, row) in [(0, Some(1)), (1, None), (2, Some(0))] {
                for c in 0..5 {
                    let want = match row {
                        Some(r) if moved.contains(&c) => {
                            GAIN * (1 + r * k + c - moved.start) as f32
                        }
                        _ => 0.0,
                    };
                    assert_eq!(v[5 * p + c], want, "{cols:?}: point {p}, column {c}");
                }
            }
            // Weighting each column by its index: row r's gradient is GAIN · column index,
            // once for each point that reads it.
            let w: Vec<f32> = (0..15).map(|i| (i % 5) as f32).collect();
            let w = Tensor::<2>::from_data(TensorData::new(w, [3, 5]), &dev);
            let grads = (out * w).sum().backward();
            let g = po.table.val().grad(&grads).unwrap();
            let g = g.try_into_vec_as::<f32>().unwrap();
            let want: Vec<f32> = (0..2)
                .flat_map(|_| moved.clone().map(|c| GAIN * c as f32))
                .collect();
            assert_eq!(g, want, "{cols:?}");
        }
    }
}
