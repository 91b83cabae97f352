//! Fused ReLU MLPs on the host: the forward and backward of the two networks of Eq. 14 for the
//! training step's CPU path, tiny-cuda-nn's fully fused MLP done the CPU's way.
//!
//! A step over B = 8192 points runs each network block by block (`BLOCK` rows): a block goes
//! through every layer while its activations stay in the core's cache, and each layer is one
//! f32 GEMM (the `gemm` crate, which also serves burn's flex backend) followed by one pass that
//! adds the bias and applies the ReLU. Burn's graph runs the same network layer by layer over the
//! whole batch, with the bias add, the ReLU, its backward and the bias gradient as separate
//! passes over B × width floats each; here they are in-cache passes over one block.
//!
//! Weight and bias gradients are summed per group of `GROUP` rows and the groups' sums added in
//! group order, so a result does not depend on the number of threads.
//!
//! Owns: `HostMlp` (weights as plain host arrays, in burn's `Linear` layout), its forward and
//! backward, and the host positional encoding. Must not touch: burn tensors, optimisers, losses.

use gemm::{Parallelism, gemm};
use rayon::prelude::*;

/// Rows per block: one block's activations (256 × 128 floats, 128 KiB per layer) stay in L2.
const BLOCK: usize = 256;
/// Rows per gradient group (a whole number of blocks): the unit of the deterministic reduction.
const GROUP: usize = 4 * BLOCK;

/// One dense layer y = x·W + b in burn's `Linear` layout: `weight` is input × output, row-major.
#[derive(Clone, Debug, PartialEq)]
pub struct Dense {
    pub input: usize,
    pub output: usize,
    pub weight: Vec<f32>,
    pub bias: Option<Vec<f32>>,
}

/// A ReLU MLP: a ReLU after every layer but the last. Layer `skip` (when set, ≥ 1) reads
/// concat(x, h) — the network's input first, then the previous layer's output — as the emission
/// mask's layer 3 does (`EmissionMask::raw`).
#[derive(Clone, Debug, PartialEq)]
pub struct HostMlp {
    pub layers: Vec<Dense>,
    pub skip: Option<usize>,
}

/// What the forward pass keeps for the backward: every hidden layer's output after its ReLU,
/// N × width, row-major.
#[derive(Debug)]
pub struct Tape {
    n: usize,
    hidden: Vec<Vec<f32>>,
}

/// Parameter gradients, one per layer: d loss / d W (input × output) and d loss / d b.
#[derive(Clone, Debug)]
pub struct MlpGrads {
    pub weight: Vec<Vec<f32>>,
    pub bias: Vec<Option<Vec<f32>>>,
}

/// What a backward reads: the forward's input (N × input) and tape, and d loss / d output
/// (N × output).
#[derive(Clone, Copy)]
struct BackwardRun<'a> {
    x: &'a [f32],
    tape: &'a Tape,
    d_out: &'a [f32],
}

/// The rows r0..r0 + m one block covers.
#[derive(Clone, Copy)]
struct BlockRows {
    r0: usize,
    m: usize,
}

/// One task's working rows for a block's backward (`BLOCK` × the widest layer each): the
/// current layer's pre-activation gradient dz and its input's gradient dh.
struct BlockScratch {
    dz: Vec<f32>,
    dh: Vec<f32>,
}

/// One part of a layer's input, in the order of the layer's weight rows.
#[derive(Clone, Copy)]
enum Part {
    /// The network's input x (layer 0, and the first rows of the skip layer).
    Input,
    /// The previous layer's output h.
    Hidden,
}

/// A raw pointer that may cross into rayon tasks; every task writes disjoint rows.
#[derive(Clone, Copy)]
struct Rows(*mut f32);
unsafe impl Send for Rows {}
unsafe impl Sync for Rows {}

/// The shape of a product A·B: A is m × k, B is k × n.
#[derive(Clone, Copy)]
struct Shape {
    m: usize,
    n: usize,
    k: usize,
}

/// A matrix `mm` reads: its first element and its row and column strides (in floats).
#[derive(Clone, Copy)]
struct MatRef {
    ptr: *const f32,
    row_stride: usize,
    col_stride: usize,
}

/// The matrix `mm` writes: its first element, its row stride (columns are contiguous) and
/// whether the product is added to what it holds rather than replacing it.
#[derive(Clone, Copy)]
struct MatDst {
    ptr: *mut f32,
    row_stride: usize,
    accumulate: bool,
}

/// dst (m × n) = [dst +] A·B; single-threaded (the caller parallelises over blocks).
///
/// # Safety
/// Every pointer must address its whole matrix under its strides; dst must not alias A or B.
unsafe fn mm(shape: Shape, dst: MatDst, a: MatRef, b: MatRef) {
    let Shape { m, n, k } = shape;
    let MatDst {
        ptr: dst,
        row_stride: dst_rs,
        accumulate,
    } = dst;
    if m == 0 || n == 0 {
        return;
    }
    if k == 0 {
        if !accumulate {
            for r in 0..m {
                unsafe { std::slice::from_raw_parts_mut(dst.add(r * dst_rs), n).fill(0.0) };
            }
        }
        return;
    }
    unsafe {
        gemm(
            m,
            n,
            k,
            dst,
            1,
            dst_rs as isize,
            accumulate,
            a.ptr,
            a.col_stride as isize,
            a.row_stride as isize,
            b.ptr,
            b.col_stride as isize,
            b.row_stride as isize,
            1.0,
            1.0,
            false,
            false,
            false,
            Parallelism::None,
        )
    }
}

impl HostMlp {
    /// Input width.
    pub fn input(&self) -> usize {
        self.layers[0].input
    }

    /// Output width.
    pub fn output(&self) -> usize {
        self.layers.last().expect("at least one layer").output
    }

    /// Checks the layer shapes chain (with the skip layer's extra input) and the array sizes.
    pub fn check(&self) -> Result<(), String> {
        let Some(first) = self.layers.first() else {
            return Err("an MLP needs a layer".into());
        };
        let x = first.input;
        for (i, l) in self.layers.iter().enumerate() {
            let expect = match i {
                0 => x,
                i if Some(i) == self.skip => x + self.layers[i - 1].output,
                i => self.layers[i - 1].output,
            };
            if l.input != expect
                || l.weight.len() != l.input * l.output
                || l.bias.as_ref().is_some_and(|b| b.len() != l.output)
            {
                return Err(format!("layer {i}: shapes do not chain"));
            }
        }
        if self.skip.is_some_and(|k| k == 0 || k >= self.layers.len()) {
            return Err("the skip layer must be ≥ 1 and one of the layers".into());
        }
        Ok(())
    }

    /// Layer i's input parts in the order of its weight rows: the skip layer reads [x, h].
    fn parts(&self, i: usize) -> &'static [Part] {
        match i {
            0 => &[Part::Input],
            i if Some(i) == self.skip => &[Part::Input, Part::Hidden],
            _ => &[Part::Hidden],
        }
    }

    /// Forward over `x` (N × input, row-major): the output (N × output) and the tape the
    /// backward needs.
    ///
    /// # Panics
    /// If the layers do not chain ([`HostMlp::check`]) or `x` is not whole rows.
    pub fn forward(&self, x: &[f32]) -> (Vec<f32>, Tape) {
        if let Err(e) = self.check() {
            panic!("HostMlp::forward: {e}");
        }
        let din = self.input();
        assert_eq!(x.len() % din, 0, "input rows of {din}");
        let n = x.len() / din;
        let last = self.layers.len() - 1;
        // Allocated, not zeroed: the blocks write every element (zeroing these N × width
        // buffers on the calling thread would hold both cores up once per layer).
        let mut hidden: Vec<Vec<f32>> = self.layers[..last]
            .iter()
            .map(|l| Vec::with_capacity(n * l.output))
            .collect();
        let mut out: Vec<f32> = Vec::with_capacity(n * self.output());
        let hp: Vec<Rows> = hidden.iter_mut().map(|h| Rows(h.as_mut_ptr())).collect();
        let op = Rows(out.as_mut_ptr());
        (0..n.div_ceil(BLOCK)).into_par_iter().for_each(|blk| {
            let r0 = blk * BLOCK;
            let m = BLOCK.min(n - r0);
            for (i, l) in self.layers.iter().enumerate() {
                let dst = if i < last { hp[i] } else { op };
                // SAFETY: rows r0..r0+m of each buffer belong to this block alone.
                unsafe {
                    let d = dst.0.add(r0 * l.output);
                    self.layer_forward(i, x, &hp, BlockRows { r0, m }, d);
                    let rows = std::slice::from_raw_parts_mut(d, m * l.output);
                    bias_relu(rows, l.bias.as_deref(), l.output, i < last);
                }
            }
        });
        // SAFETY: every block wrote all its rows of every buffer (`mm` overwrites its first
        // part's product without reading the destination), so all n rows are initialised.
        unsafe {
            for (h, l) in hidden.iter_mut().zip(&self.layers) {
                h.set_len(n * l.output);
            }
            out.set_len(n * self.output());
        }
        (out, Tape { n, hidden })
    }

    /// z = inputs(i)·W_i for rows r0..r0+m into `dst` (before bias and ReLU).
    ///
    /// # Safety
    /// `hp` holds the hidden buffers of a forward over `x`; rows r0..r0+m of layer i − 1 are
    /// written; `dst` has room for m rows of layer i.
    unsafe fn layer_forward(
        &self,
        i: usize,
        x: &[f32],
        hp: &[Rows],
        rows: BlockRows,
        dst: *mut f32,
    ) {
        let BlockRows { r0, m } = rows;
        let (o, w) = (self.layers[i].output, self.layers[i].weight.as_ptr());
        let din = self.input();
        // Each part of the input times its rows of W_i, summed into dst.
        let mut row = 0;
        for (k, part) in self.parts(i).iter().enumerate() {
            let (a, width) = match part {
                Part::Input => (unsafe { x.as_ptr().add(r0 * din) }, din),
                Part::Hidden => {
                    let prev = self.layers[i - 1].output;
                    (unsafe { hp[i - 1].0.add(r0 * prev) as *const f32 }, prev)
                }
            };
            unsafe {
                mm(
                    Shape { m, n: o, k: width },
                    MatDst {
                        ptr: dst,
                        row_stride: o,
                        accumulate: k > 0,
                    },
                    MatRef {
                        ptr: a,
                        row_stride: width,
                        col_stride: 1,
                    },
                    MatRef {
                        ptr: w.add(row * o),
                        row_stride: o,
                        col_stride: 1,
                    },
                )
            };
            row += width;
        }
    }

    /// Backward from `d_out` (N × output): the parameter gradients and, when `want_dx`, d loss
    /// / d x (N × input). `x` and `tape` are the forward's.
    ///
    /// # Panics
    /// If `tape` is not from a forward of this network over `x`'s row count.
    pub fn backward(
        &self,
        x: &[f32],
        tape: &Tape,
        d_out: &[f32],
        want_dx: bool,
    ) -> (MlpGrads, Option<Vec<f32>>) {
        let n = tape.n;
        let din = self.input();
        assert_eq!(x.len(), n * din, "input of the forward");
        assert_eq!(d_out.len(), n * self.output(), "output gradient rows");
        // The tape must be this network's (its width per hidden layer bounds the reads below).
        let widths = self.layers[..self.layers.len() - 1]
            .iter()
            .map(|l| n * l.output);
        assert!(
            tape.hidden.len() + 1 == self.layers.len()
                && tape.hidden.iter().map(Vec::len).eq(widths),
            "a tape of another network"
        );
        let mut dx = want_dx.then(|| vec![0.0; n * din]);
        let dxp = dx.as_mut().map(|d| Rows(d.as_mut_ptr()));
        let run = BackwardRun { x, tape, d_out };
        let partials: Vec<MlpGrads> = (0..n.div_ceil(GROUP))
            .into_par_iter()
            .map(|g| {
                let mut acc = self.zero_grads();
                let width = self.layers.iter().map(|l| l.input.max(l.output)).max();
                let width = width.unwrap_or(0);
                let mut scratch = BlockScratch {
                    dz: vec![0.0; BLOCK * width],
                    dh: vec![0.0; BLOCK * width],
                };
                let end = ((g + 1) * GROUP).min(n);
                for r0 in (g * GROUP..end).step_by(BLOCK) {
                    let m = BLOCK.min(end - r0);
                    // SAFETY: rows r0..r0+m of dx belong to this block alone.
                    let dxb = dxp.map(|p| unsafe { p.0.add(r0 * din) });
                    let rows = BlockRows { r0, m };
                    self.block_backward(&run, rows, &mut acc, &mut scratch, dxb);
                }
                acc
            })
            .collect();
        let mut total = self.zero_grads();
        for p in &partials {
            for (t, v) in total.weight.iter_mut().zip(&p.weight) {
                t.iter_mut().zip(v).for_each(|(t, v)| *t += v);
            }
            for (t, v) in total.bias.iter_mut().zip(&p.bias) {
                if let (Some(t), Some(v)) = (t, v) {
                    t.iter_mut().zip(v).for_each(|(t, v)| *t += v);
                }
            }
        }
        (total, dx)
    }

    fn zero_grads(&self) -> MlpGrads {
        MlpGrads {
            weight: self
                .layers
                .iter()
                .map(|l| vec![0.0; l.weight.len()])
                .collect(),
            bias: self
                .layers
                .iter()
                .map(|l| l.bias.as_ref().map(|b| vec![0.0; b.len()]))
                .collect(),
        }
    }

    /// One block's backward, layers in reverse: dW_i += inputs(i)ᵀ·dz_i, db_i += Σ_rows dz_i,
    /// d inputs(i) = dz_i·W_iᵀ, and dz_{i−1} = d h_{i−1} ⊙ [h_{i−1} > 0]. `dx`, when given,
    /// points at the block's first row of d loss / d x.
    fn block_backward(
        &self,
        run: &BackwardRun,
        rows: BlockRows,
        acc: &mut MlpGrads,
        scratch: &mut BlockScratch,
        dx: Option<*mut f32>,
    ) {
        let BackwardRun { x, tape, d_out } = *run;
        let BlockRows { r0, m } = rows;
        let BlockScratch { dz, dh } = scratch;
        let din = self.input();
        let last = self.layers.len() - 1;
        let out = self.output();
        dz[..m * out].copy_from_slice(&d_out[r0 * out..(r0 + m) * out]);
        let xb = x[r0 * din..].as_ptr();
        let mut dx_written = false;
        for i in (0..=last).rev() {
            let l = &self.layers[i];
            let (o, w) = (l.output, l.weight.as_ptr());
            let dzp = dz.as_ptr();
            if let Some(db) = &mut acc.bias[i] {
                for row in dz[..m * o].chunks_exact(o) {
                    db.iter_mut().zip(row).for_each(|(b, g)| *b += g);
                }
            }
            let dw = acc.weight[i].as_mut_ptr();
            // Per part of the input, with its rows of W_i: dW_rows += partᵀ·dz, and the part's
            // gradient dz·W_rowsᵀ (into dx, which layer 0 and the skip layer both add to, or dh).
            let mut row = 0;
            for part in self.parts(i) {
                let (a, width, d_part, accumulate) = match part {
                    Part::Input => (xb, din, dx, dx_written),
                    Part::Hidden => {
                        let prev = self.layers[i - 1].output;
                        let hb = tape.hidden[i - 1][r0 * prev..].as_ptr();
                        (hb, prev, Some(dh.as_mut_ptr()), false)
                    }
                };
                // SAFETY: all matrices lie inside their buffers; dW, dh and dx are distinct
                // from the inputs they are computed from.
                unsafe {
                    let w_rows = w.add(row * o);
                    let dz_mat = MatRef {
                        ptr: dzp,
                        row_stride: o,
                        col_stride: 1,
                    };
                    mm(
                        Shape {
                            m: width,
                            n: o,
                            k: m,
                        },
                        MatDst {
                            ptr: dw.add(row * o),
                            row_stride: o,
                            accumulate: true,
                        },
                        MatRef {
                            ptr: a,
                            row_stride: 1,
                            col_stride: width,
                        },
                        dz_mat,
                    );
                    if let Some(d) = d_part {
                        mm(
                            Shape { m, n: width, k: o },
                            MatDst {
                                ptr: d,
                                row_stride: width,
                                accumulate,
                            },
                            dz_mat,
                            MatRef {
                                ptr: w_rows,
                                row_stride: 1,
                                col_stride: o,
                            },
                        );
                    }
                }
                dx_written |= matches!(part, Part::Input) && dx.is_some();
                row += width;
            }
            if i == 0 {
                break;
            }
            // dz_{i−1} = dh ⊙ [h_{i−1} > 0].
            let prev = self.layers[i - 1].output;
            let h = &tape.hidden[i - 1][r0 * prev..(r0 + m) * prev];
            for ((z, g), h) in dz[..m * prev].iter_mut().zip(&dh[..m * prev]).zip(h) {
                *z = if *h > 0.0 { *g } else { 0.0 };
            }
        }
    }
}

/// Adds the bias to every row of `rows` (width `w`) and, for a hidden layer, applies the ReLU.
fn bias_relu(rows: &mut [f32], bias: Option<&[f32]>, w: usize, relu: bool) {
    match (bias, relu) {
        (Some(b), true) => rows.chunks_exact_mut(w).for_each(|r| {
            r.iter_mut()
                .zip(b)
                .for_each(|(v, b)| *v = (*v + b).max(0.0));
        }),
        (Some(b), false) => rows.chunks_exact_mut(w).for_each(|r| {
            r.iter_mut().zip(b).for_each(|(v, b)| *v += b);
        }),
        (None, true) => rows.iter_mut().for_each(|v| *v = v.max(0.0)),
        (None, false) => {}
    }
}

/// NeRF positional encoding on the host, as `pe::positional_encoding` computes it:
/// [x, sin(2^l π x), cos(2^l π x)] with the sines (then the cosines) ordered l-major, N × (3 + 6L).
pub fn positional_encoding_host(x: &[[f32; 3]], freqs: usize) -> Vec<f32> {
    let f: Vec<f32> = (0..freqs)
        .map(|l| (2f64.powi(l as i32) * std::f64::consts::PI) as f32)
        .collect();
    let dim = 3 + 6 * freqs;
    let mut out = vec![0.0; x.len() * dim];
    out.par_chunks_mut(dim * 1024)
        .zip(x.par_chunks(1024))
        .for_each(|(o, xs)| {
            for (row, p) in o.chunks_exact_mut(dim).zip(xs) {
                row[..3].copy_from_slice(p);
                let (s, c) = row[3..].split_at_mut(3 * freqs);
                for (l, fl) in f.iter().enumerate() {
                    for k in 0..3 {
                        let v = p[k] * fl;
                        s[3 * l + k] = v.sin();
                        c[3 * l + k] = v.cos();
                    }
                }
            }
        });
    out
}
