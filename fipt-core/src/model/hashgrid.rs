//! Multiresolution hash-grid encoding (Instant-NGP) as a fused host op with its own backward.
//!
//! The table lives in host memory as plain `f32`s. `encode` gathers and trilinearly blends the
//! 8 corners of every level for a batch of points (points in parallel); `backward_table`
//! scatters the output gradient into a sparse table gradient (levels in parallel: each level
//! owns a disjoint slice of the table, so the result is deterministic); `backward_input` gives
//! d(encoding)/d(position) for completeness and checks. `TableAdam` is the matching optimiser: it
//! updates only the entries that received a gradient this step, as tiny-cuda-nn does for grid
//! parameters, so a step costs O(batch · levels · 8), not O(table).
//!
//! Inputs are in [0,1]³ (the reference feeds [-1,1] and aliases, §5.1). Coarse levels whose
//! vertex grid fits the level's table are indexed densely; finer ones use the spatial hash
//! (x·1 ⊕ y·2654435761 ⊕ z·805459861) mod T.
//!
//! Owns: the table and its indexing, forward, backward and optimiser. Must not touch: tensors
//! (the caller moves encodings and gradients to and from the device).

use crate::rng::Rng;
use rayon::prelude::*;

/// The hash grid's configuration: one schema for the model and for config files
/// (`train.grid` in `configs/*.json`; unknown keys are errors).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct HashGridConfig {
    /// Number of levels.
    pub levels: usize,
    /// Features per level.
    pub features: usize,
    /// log2 of the maximum entries per level.
    pub log2_table: u32,
    /// Coarsest grid resolution over [0,1] (the reference's 16 over [-1,1], §5.1).
    pub base_resolution: f64,
    /// Resolution growth factor per level.
    pub per_level_scale: f64,
    /// Finest grid resolution (cells per unit-cube side) kept: levels finer than this are
    /// dropped by `levels_for`. `"none"` (the reference) keeps all. `"auto"` puts it at one cell
    /// per median pixel footprint: finer levels see at most one pixel per cell, so base colour
    /// there can absorb each pixel's residual. What it measures: `docs/departures/
    /// grid-max-resolution.md`.
    pub max_resolution: MaxResolution,
    /// Cells per median pixel footprint at which `"auto"` stops: 1 puts the finest kept level at
    /// one cell per footprint, 0.5 at one cell per two footprints. Not used otherwise.
    pub cells_per_footprint: f64,
    /// Entries start uniform in [-init, init] (tiny-cuda-nn: 1e-4); not a config-file key.
    #[serde(skip, default = "default_init")]
    pub init: f32,
}

fn default_init() -> f32 {
    1e-4
}

impl Default for HashGridConfig {
    /// The reference: 32 levels, 2 features, 2^19 entries, base 16 over [-1,1] (= 32 over
    /// [0,1]), scale 1.3, all levels kept.
    fn default() -> Self {
        Self {
            levels: 32,
            features: 2,
            log2_table: 19,
            base_resolution: 32.0,
            per_level_scale: 1.3,
            max_resolution: MaxResolution::Keyword(ResolutionKeyword::None),
            cells_per_footprint: 1.0,
            init: default_init(),
        }
    }
}

impl burn::config::Config for HashGridConfig {}

/// `"auto"`, `"none"` or a number (cells per unit-cube side).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(untagged)]
pub enum MaxResolution {
    Keyword(ResolutionKeyword),
    Fixed(f64),
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ResolutionKeyword {
    /// One grid cell per median pixel footprint of the training views.
    Auto,
    /// No cap: all `levels` levels.
    None,
}

impl HashGridConfig {
    /// The reference configuration (`Default`).
    pub fn new() -> Self {
        Self::default()
    }

    pub fn with_levels(mut self, levels: usize) -> Self {
        self.levels = levels;
        self
    }

    pub fn with_features(mut self, features: usize) -> Self {
        self.features = features;
        self
    }

    pub fn with_log2_table(mut self, log2_table: u32) -> Self {
        self.log2_table = log2_table;
        self
    }

    pub fn with_base_resolution(mut self, base_resolution: f64) -> Self {
        self.base_resolution = base_resolution;
        self
    }

    pub fn with_per_level_scale(mut self, per_level_scale: f64) -> Self {
        self.per_level_scale = per_level_scale;
        self
    }

    /// The levels kept for a scene whose median pixel footprint is `footprint` (unit-cube
    /// units): those with base·scale^l ≤ the maximum resolution, at least one.
    pub fn levels_for(&self, footprint: f64) -> usize {
        let max = match self.max_resolution {
            MaxResolution::Keyword(ResolutionKeyword::None) => return self.levels,
            MaxResolution::Keyword(ResolutionKeyword::Auto) => self.cells_per_footprint / footprint,
            MaxResolution::Fixed(r) => r,
        };
        let kept = ((max / self.base_resolution).ln() / self.per_level_scale.ln()).floor() + 1.0;
        if kept.is_finite() {
            (kept.max(1.0) as usize).min(self.levels)
        } else {
            self.levels
        }
    }
}

/// One level's place in the table and its grid.
#[derive(Clone, Copy, Debug)]
pub struct Level {
    /// First entry of the level in the table.
    pub offset: usize,
    /// Entries in the level.
    pub size: usize,
    /// Continuous scale: position = x·scale + 0.5.
    pub scale: f32,
    /// Vertices per axis when indexed densely.
    pub res: u32,
    pub dense: bool,
}

/// The hash-grid encoding and its parameters.
#[derive(Clone, Debug)]
pub struct HashGrid {
    pub levels: Vec<Level>,
    pub features: usize,
    /// `entries × features` values, level after level.
    pub table: Vec<f32>,
}

/// The spatial hash's primes (one definition for the host op and `hashgrid_device`).
pub(crate) const PRIMES: [u32; 3] = [1, 2_654_435_761, 805_459_861];

impl HashGridConfig {
    /// The finest level's resolution `init` may build (a cube of 2^20 cells a side).
    pub const MAX_RESOLUTION: f64 = (1u64 << 20) as f64;

    /// Range checks that keep `init` finite and bounded (a saved model's sizes may be
    /// damaged): levels in [1, 64], features in [1, 8], log2_table in [1, 24], base resolution
    /// and per-level scale finite and >= 1, the finest level at most `MAX_RESOLUTION`, at most
    /// 2^30 table values; the reason names the key (`grid.levels: ...`).
    pub fn check(&self) -> Result<(), String> {
        let fail = |k: &str, what: &str| Err(format!("grid.{k}: {what}"));
        if !(1..=64).contains(&self.levels) {
            return fail("levels", "must be in [1, 64]");
        }
        if !(1..=8).contains(&self.features) {
            return fail("features", "must be in [1, 8]");
        }
        if !(1..=24).contains(&self.log2_table) {
            return fail("log2_table", "must be in [1, 24]");
        }
        if !(self.base_resolution.is_finite() && self.base_resolution >= 1.0) {
            return fail("base_resolution", "must be finite and >= 1");
        }
        if !(self.per_level_scale.is_finite() && self.per_level_scale >= 1.0) {
            return fail("per_level_scale", "must be finite and >= 1");
        }
        let finest = self.base_resolution * self.per_level_scale.powi(self.levels as i32 - 1);
        if finest > Self::MAX_RESOLUTION {
            return fail(
                "per_level_scale",
                "base_resolution × per_level_scale^(levels − 1) must be at most 2^20",
            );
        }
        if let MaxResolution::Fixed(r) = self.max_resolution
            && !(r.is_finite() && r >= 1.0)
        {
            return fail("max_resolution", "must be finite and >= 1");
        }
        if !(self.cells_per_footprint.is_finite() && self.cells_per_footprint > 0.0) {
            return fail("cells_per_footprint", "must be finite and > 0");
        }
        let values = ((self.levels * self.features) as u64) << self.log2_table;
        if values > 1 << 30 {
            return fail(
                "log2_table",
                "levels × features × 2^log2_table must be at most 2^30 values (4 GB)",
            );
        }
        Ok(())
    }

    /// Builds the level layout and a table initialised from `seed`.
    pub fn init(&self, seed: u64) -> HashGrid {
        let max = 1usize << self.log2_table;
        let mut levels = Vec::with_capacity(self.levels);
        let mut offset = 0;
        for l in 0..self.levels {
            let scale = self.base_resolution * self.per_level_scale.powi(l as i32) - 1.0;
            let res = scale.ceil() as u64 + 2;
            let dense_size = res * res * res;
            let dense = dense_size <= max as u64;
            let size = if dense {
                (dense_size as usize).div_ceil(8) * 8
            } else {
                max
            };
            levels.push(Level {
                offset,
                size,
                scale: scale as f32,
                res: res as u32,
                dense,
            });
            offset += size;
        }
        let n = offset * self.features;
        let init = self.init;
        let table = (0..n)
            .into_par_iter()
            .with_min_len(1 << 16)
            .map(|i| {
                let mut r = Rng::new(seed, i as u64);
                (2.0 * r.next_f32() - 1.0) * init
            })
            .collect();
        HashGrid {
            levels,
            features: self.features,
            table,
        }
    }
}

/// The 8 corners of a point's cell on one level: local entry indices and trilinear weights,
/// plus what the input gradient needs.
struct Cell {
    idx: [u32; 8],
    w: [f32; 8],
    frac: [f32; 3],
}

#[inline(always)]
fn cell(level: &Level, x: [f32; 3]) -> Cell {
    let mut g = [0u32; 3];
    let mut frac = [0f32; 3];
    for k in 0..3 {
        let p = x[k].clamp(0.0, 1.0) * level.scale + 0.5;
        let f = p.floor();
        g[k] = f as u32;
        frac[k] = p - f;
    }
    let mut idx = [0u32; 8];
    let mut w = [0f32; 8];
    for c in 0..8 {
        let b = [(c & 1) as u32, ((c >> 1) & 1) as u32, ((c >> 2) & 1) as u32];
        let v = [g[0] + b[0], g[1] + b[1], g[2] + b[2]];
        let i = if level.dense {
            let r = level.res;
            v[0].min(r - 1) + r * (v[1].min(r - 1) + r * v[2].min(r - 1))
        } else {
            (v[0].wrapping_mul(PRIMES[0])
                ^ v[1].wrapping_mul(PRIMES[1])
                ^ v[2].wrapping_mul(PRIMES[2]))
                % level.size as u32
        };
        idx[c] = i;
        let mut wc = 1.0;
        for k in 0..3 {
            wc *= if b[k] == 1 { frac[k] } else { 1.0 - frac[k] };
        }
        w[c] = wc;
    }
    Cell { idx, w, frac }
}

/// Entries of a level whose table, gradient and marks stay in a core's L2 cache (1 MiB at 2
/// features): such a level is read and updated in point order (`encode_level_direct`,
/// `dense_adam_level`) rather than by sorting its touches.
const L2_LEVEL: usize = 1 << 17;

/// Batches from this size on are encoded level by level (larger levels in entry order).
const SORTED_ENCODE_MIN: usize = 2048;

/// Σ_k w[k]·value(k) in corner order (the one summation order every encode path uses).
#[inline(always)]
fn blend(w: &[f32; 8], value: impl Fn(usize) -> f32) -> f32 {
    let mut s = 0.0;
    for (k, wk) in w.iter().enumerate() {
        s += wk * value(k);
    }
    s
}

/// Bits needed for a local entry index of `level`.
fn entry_bits(level: &Level) -> u32 {
    usize::BITS - (level.size.max(2) - 1).leading_zeros()
}

/// Splits `data` (entries × features) into one mutable slice per level.
fn split_levels<'a, T>(
    levels: &[Level],
    features: usize,
    mut data: &'a mut [T],
) -> Vec<&'a mut [T]> {
    let mut out = Vec::with_capacity(levels.len());
    for l in levels {
        let (a, b) = data.split_at_mut(l.size * features);
        out.push(a);
        data = b;
    }
    out
}

impl HashGrid {
    /// Local entry indices and trilinear weights of the 8 corners around `x` on `level`.
    pub fn cell_corners(&self, level: &Level, x: [f32; 3]) -> ([u32; 8], [f32; 8]) {
        let c = cell(level, x);
        (c.idx, c.w)
    }

    pub fn num_params(&self) -> usize {
        self.table.len()
    }

    pub fn output_dim(&self) -> usize {
        self.levels.len() * self.features
    }

    /// Encodes points in [0,1]³: returns `n × (levels · features)` values, row-major.
    ///
    /// Small batches go point by point. Large ones go level by level in entry order (the
    /// corner reads of a level are radix-sorted by entry, so the table is read in address
    /// order, and the 8 corners are then blended in corner order): the same values bit for
    /// bit, without a cache miss per corner on the large hashed levels.
    pub fn encode(&self, xs: &[[f32; 3]]) -> Vec<f32> {
        let (nl, nf) = (self.levels.len(), self.features);
        let mut out = vec![0f32; xs.len() * nl * nf];
        if xs.len() < SORTED_ENCODE_MIN {
            out.par_chunks_mut(nl * nf)
                .zip(xs.par_iter())
                .with_min_len(64)
                .for_each(|(o, &x)| {
                    for (l, level) in self.levels.iter().enumerate() {
                        let c = cell(level, x);
                        let t = self.level_table(level);
                        for f in 0..nf {
                            o[l * nf + f] = blend(&c.w, |k| t[c.idx[k] as usize * nf + f]);
                        }
                    }
                });
            return out;
        }
        let per_level: Vec<Vec<f32>> = self
            .levels
            .par_iter()
            .map(|level| {
                if level.size <= L2_LEVEL {
                    self.encode_level_direct(level, xs)
                } else {
                    self.encode_level_sorted(level, xs)
                }
            })
            .collect();
        out.par_chunks_mut(nl * nf)
            .enumerate()
            .with_min_len(256)
            .for_each(|(p, o)| {
                for (l, v) in per_level.iter().enumerate() {
                    o[l * nf..(l + 1) * nf].copy_from_slice(&v[p * nf..(p + 1) * nf]);
                }
            });
        out
    }

    /// One level's slice of the table.
    #[inline(always)]
    fn level_table(&self, level: &Level) -> &[f32] {
        let nf = self.features;
        &self.table[level.offset * nf..(level.offset + level.size) * nf]
    }

    /// One level's encoding (`n × features`), reading the table in point order: for a level
    /// that stays in a core's L2 cache (`L2_LEVEL`), where sorting the reads costs more than
    /// their misses.
    fn encode_level_direct(&self, level: &Level, xs: &[[f32; 3]]) -> Vec<f32> {
        let nf = self.features;
        let t = self.level_table(level);
        let mut out = vec![0f32; xs.len() * nf];
        for (o, &x) in out.chunks_exact_mut(nf).zip(xs) {
            let c = cell(level, x);
            for (f, of) in o.iter_mut().enumerate() {
                *of = blend(&c.w, |k| t[c.idx[k] as usize * nf + f]);
            }
        }
        out
    }

    /// One level's encoding (`n × features`), reading the table in entry order.
    fn encode_level_sorted(&self, level: &Level, xs: &[[f32; 3]]) -> Vec<f32> {
        let nf = self.features;
        let t = self.level_table(level);
        let mut keys = Vec::with_capacity(xs.len() * 8);
        let mut weights = Vec::with_capacity(xs.len() * 8);
        for (p, &x) in xs.iter().enumerate() {
            let c = cell(level, x);
            for k in 0..8 {
                keys.push(((c.idx[k] as u64) << 32) | (p * 8 + k) as u64);
                weights.push(c.w[k]);
            }
        }
        radix_sort_high(&mut keys, entry_bits(level));
        // Each touch's table value, fetched in entry order.
        let mut vals = vec![0f32; xs.len() * 8 * nf];
        for &key in &keys {
            let (e, touch) = ((key >> 32) as usize, (key & 0xffff_ffff) as usize);
            vals[touch * nf..(touch + 1) * nf].copy_from_slice(&t[e * nf..(e + 1) * nf]);
        }
        let mut out = vec![0f32; xs.len() * nf];
        for p in 0..xs.len() {
            let w: &[f32; 8] = weights[p * 8..p * 8 + 8].try_into().expect("8 corners");
            for f in 0..nf {
                out[p * nf + f] = blend(w, |k| vals[(p * 8 + k) * nf + f]);
            }
        }
        out
    }

    /// Accumulates d loss / d table for the output gradient `grad_out` (`n × levels·features`)
    /// into `grad` and records the touched entries.
    pub fn backward_table(&self, xs: &[[f32; 3]], grad_out: &[f32], grad: &mut TableGrad) {
        let (nl, nf) = (self.levels.len(), self.features);
        assert_eq!(grad_out.len(), xs.len() * nl * nf);
        grad.step += 1;
        let stamp = grad.step;
        let up = Upstream {
            xs,
            grad_out,
            nl,
            nf,
        };
        let g_levels = split_levels(&self.levels, nf, &mut grad.values);
        let m_levels = split_levels(&self.levels, 1, &mut grad.mark);
        let touched: Vec<Vec<u32>> = g_levels
            .into_par_iter()
            .zip(m_levels)
            .zip(self.levels.par_iter())
            .enumerate()
            .map(|(l, ((values, mark), level))| {
                let grad = LevelGrad {
                    values,
                    mark,
                    stamp,
                };
                scatter_level(level, l, &up, grad)
            })
            .collect();
        grad.touched = touched;
    }

    /// `backward_table` followed by `TableAdam::step`, fused per level: each level's gradient
    /// is scattered and applied while its part of the table is still in cache.
    pub fn backward_adam(
        &mut self,
        xs: &[[f32; 3]],
        grad_out: &[f32],
        grad: &mut TableGrad,
        adam: &mut TableAdam,
        lr: f32,
    ) {
        let (nl, nf) = (self.levels.len(), self.features);
        assert_eq!(grad_out.len(), xs.len() * nl * nf);
        grad.step += 1;
        let stamp = grad.step;
        let coef = adam.advance(lr);
        let up = Upstream {
            xs,
            grad_out,
            nl,
            nf,
        };
        let levels = self.levels.clone();
        let p_l = split_levels(&levels, nf, &mut self.table);
        let m_l = split_levels(&levels, nf, &mut adam.m);
        let v_l = split_levels(&levels, nf, &mut adam.v);
        let g_l = split_levels(&levels, nf, &mut grad.values);
        let k_l = split_levels(&levels, 1, &mut grad.mark);
        p_l.into_par_iter()
            .zip(m_l)
            .zip(v_l)
            .zip(g_l)
            .zip(k_l)
            .zip(levels.par_iter())
            .enumerate()
            .for_each(|(l, (((((p, m), v), values), mark), level))| {
                let params = AdamLevel { p, m, v };
                if dense_update(level, xs.len()) {
                    let grad = LevelGrad {
                        values,
                        mark,
                        stamp,
                    };
                    dense_adam_level(&coef, level, l, &up, params, grad);
                } else {
                    sorted_adam_level(&coef, level, l, &up, params);
                }
            });
        grad.touched.clear();
    }

    /// d loss / d x for the output gradient (`n × levels·features`), through the trilinear
    /// weights (the floor is piecewise constant). Points clamped at the border get zero.
    pub fn backward_input(&self, xs: &[[f32; 3]], grad_out: &[f32]) -> Vec<[f32; 3]> {
        let (nl, nf) = (self.levels.len(), self.features);
        xs.par_iter()
            .enumerate()
            .map(|(p, &x)| {
                let mut gx = [0f32; 3];
                for (l, level) in self.levels.iter().enumerate() {
                    let c = cell(level, x);
                    let t = &self.table[level.offset * nf..(level.offset + level.size) * nf];
                    let go = &grad_out[p * nl * nf + l * nf..p * nl * nf + (l + 1) * nf];
                    for k in 0..8 {
                        let b = [k & 1, (k >> 1) & 1, (k >> 2) & 1];
                        let mut dot = 0.0;
                        for f in 0..nf {
                            dot += go[f] * t[c.idx[k] as usize * nf + f];
                        }
                        for (d, gxd) in gx.iter_mut().enumerate() {
                            let mut dw = if b[d] == 1 { 1.0 } else { -1.0 };
                            for (e, (&be, &fe)) in b.iter().zip(&c.frac).enumerate() {
                                if e != d {
                                    dw *= if be == 1 { fe } else { 1.0 - fe };
                                }
                            }
                            *gxd += dot * dw * level.scale;
                        }
                    }
                }
                for (d, g) in gx.iter_mut().enumerate() {
                    if !(0.0..=1.0).contains(&x[d]) {
                        *g = 0.0;
                    }
                }
                gx
            })
            .collect()
    }
}

/// A sparse table gradient: dense storage, plus the entries touched since the last reset.
#[derive(Clone, Debug)]
pub struct TableGrad {
    pub values: Vec<f32>,
    mark: Vec<u32>,
    step: u32,
    /// Touched entries (global entry index), one list per level, each without repeats.
    pub touched: Vec<Vec<u32>>,
}

impl TableGrad {
    pub fn new(grid: &HashGrid) -> Self {
        let entries = grid.table.len() / grid.features;
        Self {
            values: vec![0.0; grid.table.len()],
            mark: vec![0; entries],
            step: 0,
            touched: vec![],
        }
    }

    /// Zeroes the touched entries (O(touched)).
    pub fn clear(&mut self, features: usize) {
        for list in &self.touched {
            for &e in list {
                let e = e as usize * features;
                self.values[e..e + features].fill(0.0);
            }
        }
        self.touched.clear();
    }
}

const ADAM_MAGIC: &[u8; 8] = b"FIPTADM1";

/// Adam for the table, applied to touched entries only (global step count for bias correction).
#[derive(Clone, Debug)]
pub struct TableAdam {
    pub beta1: f32,
    pub beta2: f32,
    pub eps: f32,
    m: Vec<f32>,
    v: Vec<f32>,
    t: i32,
}

impl TableAdam {
    pub fn new(grid: &HashGrid, beta1: f32, beta2: f32, eps: f32) -> Self {
        Self {
            beta1,
            beta2,
            eps,
            m: vec![0.0; grid.table.len()],
            v: vec![0.0; grid.table.len()],
            t: 0,
        }
    }

    /// The state as bytes (a checkpoint): magic, step count, entry count, then m and v as
    /// little-endian f32.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(20 + 8 * self.m.len());
        out.extend_from_slice(&self.header());
        for v in [&self.m, &self.v] {
            crate::io::write_f32s(&mut out, v).expect("writing to memory");
        }
        out
    }

    /// The bytes `to_bytes` writes before the moments.
    fn header(&self) -> [u8; 20] {
        let mut h = [0u8; 20];
        h[..8].copy_from_slice(ADAM_MAGIC);
        h[8..12].copy_from_slice(&self.t.to_le_bytes());
        h[12..].copy_from_slice(&(self.m.len() as u64).to_le_bytes());
        h
    }

    /// Writes what `to_bytes` returns to `path` atomically, without building it in memory.
    pub fn save(&self, path: &std::path::Path) -> crate::io::Result<()> {
        use crate::io::Part;
        let h = self.header();
        crate::io::write_parts_atomic(
            path,
            &[Part::Bytes(&h), Part::F32s(&self.m), Part::F32s(&self.v)],
        )
    }

    /// Restores a state written by `to_bytes` for a table of this optimiser's size; the error
    /// says what does not fit (the size field is checked against the bytes before anything is allocated).
    pub fn load_bytes(&mut self, bytes: &[u8]) -> Result<(), String> {
        if bytes.len() < 20 || &bytes[..8] != ADAM_MAGIC {
            return Err("not a fipt table optimiser state".into());
        }
        let t = i32::from_le_bytes(bytes[8..12].try_into().expect("4 bytes"));
        let n = u64::from_le_bytes(bytes[12..20].try_into().expect("8 bytes"));
        if n != self.m.len() as u64 {
            return Err(format!("{n} table entries, the model has {}", self.m.len()));
        }
        if t < 0 || (bytes.len() - 20) as u64 != 8 * n {
            return Err(format!(
                "{} bytes of state for {n} entries (truncated or damaged)",
                bytes.len() - 20
            ));
        }
        let mut vals = bytes[20..]
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes(b.try_into().expect("4 bytes")));
        for x in self.m.iter_mut().chain(self.v.iter_mut()) {
            *x = vals.next().expect("sized above");
        }
        if self.m.iter().chain(&self.v).any(|x| !x.is_finite()) || self.v.iter().any(|&x| x < 0.0) {
            return Err("non-finite or negative moments".into());
        }
        self.t = t;
        Ok(())
    }

    /// One Adam step on the touched entries; clears the gradient.
    pub fn step(&mut self, grid: &mut HashGrid, grad: &mut TableGrad, lr: f32) {
        let coef = self.advance(lr);
        let nf = grid.features;
        let levels = grid.levels.clone();
        let p_l = split_levels(&levels, nf, &mut grid.table);
        let m_l = split_levels(&levels, nf, &mut self.m);
        let v_l = split_levels(&levels, nf, &mut self.v);
        let g_l = split_levels(&levels, nf, &mut grad.values);
        let touched = std::mem::take(&mut grad.touched);
        p_l.into_par_iter()
            .zip(m_l)
            .zip(v_l)
            .zip(g_l)
            .zip(levels.par_iter())
            .zip(touched.par_iter())
            .for_each(|(((((p, m), v), g), level), list)| {
                adam_level(&coef, level, nf, list, AdamLevel { p, m, v }, g)
            });
    }

    /// Counts a step and returns its constants.
    fn advance(&mut self, lr: f32) -> AdamCoef {
        self.t += 1;
        AdamCoef {
            b1: self.beta1,
            b2: self.beta2,
            eps: self.eps,
            c1: 1.0 - self.beta1.powi(self.t),
            c2: 1.0 - self.beta2.powi(self.t),
            lr,
        }
    }
}

/// Constants of one Adam step.
struct AdamCoef {
    b1: f32,
    b2: f32,
    eps: f32,
    c1: f32,
    c2: f32,
    lr: f32,
}

impl AdamCoef {
    /// One Adam update of a parameter `p` with moments `m`, `v` and gradient `g`.
    #[inline(always)]
    fn apply(&self, p: &mut f32, m: &mut f32, v: &mut f32, g: f32) {
        *m = self.b1 * *m + (1.0 - self.b1) * g;
        *v = self.b2 * *v + (1.0 - self.b2) * g * g;
        *p -= self.lr * (*m / self.c1) / ((*v / self.c2).sqrt() + self.eps);
    }
}

/// The output gradient of a batch: points, `n × levels·features` values and the layout.
struct Upstream<'a> {
    xs: &'a [[f32; 3]],
    grad_out: &'a [f32],
    nl: usize,
    nf: usize,
}

impl Upstream<'_> {
    /// Point `p`'s output gradient on level `l`.
    #[inline(always)]
    fn at(&self, p: usize, l: usize) -> &[f32] {
        let base = p * self.nl * self.nf + l * self.nf;
        &self.grad_out[base..base + self.nf]
    }
}

/// One level's part of the table and of Adam's two moments (features per entry each).
struct AdamLevel<'a> {
    p: &'a mut [f32],
    m: &'a mut [f32],
    v: &'a mut [f32],
}

/// One level's part of the dense table gradient and its touch marks: an entry was touched this
/// step where its mark equals `stamp`.
struct LevelGrad<'a> {
    values: &'a mut [f32],
    mark: &'a mut [u32],
    stamp: u32,
}

/// Scatters one level's share of the output gradient; returns its touched entries (global).
fn scatter_level(level: &Level, l: usize, up: &Upstream, grad: LevelGrad) -> Vec<u32> {
    let LevelGrad {
        values: gv,
        mark,
        stamp,
    } = grad;
    let nf = up.nf;
    let mut t = Vec::new();
    for (p, &x) in up.xs.iter().enumerate() {
        let c = cell(level, x);
        let go = up.at(p, l);
        for k in 0..8 {
            let e = c.idx[k] as usize;
            if mark[e] != stamp {
                mark[e] = stamp;
                t.push((level.offset + e) as u32);
            }
            for f in 0..nf {
                gv[e * nf + f] += c.w[k] * go[f];
            }
        }
    }
    t
}

/// Whether `backward_adam` updates `level` through its dense gradient (`dense_adam_level`)
/// rather than by sorting its touches (`sorted_adam_level`): where the level's gradient and
/// marks stay in a core's L2 cache (≤ 2^17 entries, 1 MiB at 2 features), or where the touches
/// outnumber half its entries, a scatter and one sweep over the level beat the sort.
fn dense_update(level: &Level, points: usize) -> bool {
    level.size <= L2_LEVEL || level.size <= 2 * 8 * points
}

/// One level of the fused backward + Adam through the level's dense gradient: every corner
/// touch is added to its entry in touch order (the order `scatter_level` and
/// `sorted_adam_level` sum in, so the update is bit-identical to both), then one sweep in
/// entry order applies Adam to the entries touched this step (`stamp`) and zeroes them.
fn dense_adam_level(
    c: &AdamCoef,
    level: &Level,
    l: usize,
    up: &Upstream,
    params: AdamLevel,
    grad: LevelGrad,
) {
    let LevelGrad {
        values: gv,
        mark,
        stamp,
    } = grad;
    let nf = up.nf;
    for (pi, &x) in up.xs.iter().enumerate() {
        let cl = cell(level, x);
        let go = up.at(pi, l);
        for k in 0..8 {
            let e = cl.idx[k] as usize;
            mark[e] = stamp;
            for (f, &g) in go.iter().enumerate() {
                gv[e * nf + f] += cl.w[k] * g;
            }
        }
    }
    // The feature count a constant where it is the usual 2, so that the sweep vectorises.
    let grad = LevelGrad {
        values: gv,
        mark,
        stamp,
    };
    if nf == 2 {
        sweep(c, params, grad, 2);
    } else {
        sweep(c, params, grad, nf);
    }
}

/// Adam on the entries of one level marked `stamp` (`nf` features each), without branches:
/// every entry's update is computed (`AdamCoef::apply` on copies) and kept where marked, so the
/// loop vectorises and the kept values are `apply`'s. The gradient is zeroed everywhere
/// (unmarked entries hold zero already).
#[inline(always)]
fn sweep(c: &AdamCoef, params: AdamLevel, grad: LevelGrad, nf: usize) {
    let AdamLevel { p, m, v } = params;
    let LevelGrad {
        values: gv,
        mark,
        stamp,
    } = grad;
    for ((((pe, me), ve), ge), &mk) in p
        .chunks_exact_mut(nf)
        .zip(m.chunks_exact_mut(nf))
        .zip(v.chunks_exact_mut(nf))
        .zip(gv.chunks_exact_mut(nf))
        .zip(mark.iter())
    {
        let keep = mk == stamp;
        for f in 0..nf {
            let (mut pn, mut mn, mut vn) = (pe[f], me[f], ve[f]);
            c.apply(&mut pn, &mut mn, &mut vn, ge[f]);
            pe[f] = if keep { pn } else { pe[f] };
            me[f] = if keep { mn } else { me[f] };
            ve[f] = if keep { vn } else { ve[f] };
            ge[f] = 0.0;
        }
    }
}

/// One level of the fused backward + Adam, in entry order. Every corner touch becomes a
/// (entry, touch) pair, stably radix-sorted by entry; each run of equal entries is summed in
/// touch order, which is the order `scatter_level` adds them in, so the gradient and the update
/// are bit-identical to the two-pass path. Walking the table in address order instead of in
/// first-touch order turns ~6 cache misses per touched entry into sequential sweeps.
fn sorted_adam_level(c: &AdamCoef, level: &Level, l: usize, up: &Upstream, params: AdamLevel) {
    let AdamLevel { p, m, v } = params;
    let nf = up.nf;
    let touches = up.xs.len() * 8;
    // (entry << 32 | touch) pairs and each touch's contribution, in touch order.
    let mut keys = Vec::with_capacity(touches);
    let mut contrib = Vec::with_capacity(touches * nf);
    for (pi, &x) in up.xs.iter().enumerate() {
        let cl = cell(level, x);
        let go = up.at(pi, l);
        for k in 0..8 {
            keys.push(((cl.idx[k] as u64) << 32) | (pi * 8 + k) as u64);
            for &g in go {
                contrib.push(cl.w[k] * g);
            }
        }
    }
    radix_sort_high(&mut keys, entry_bits(level));
    let mut g = vec![0f32; nf];
    let mut i = 0;
    while i < keys.len() {
        let e = (keys[i] >> 32) as usize;
        g.fill(0.0);
        while i < keys.len() && (keys[i] >> 32) as usize == e {
            let t = (keys[i] & 0xffff_ffff) as usize;
            for (gf, &cf) in g.iter_mut().zip(&contrib[t * nf..(t + 1) * nf]) {
                *gf += cf;
            }
            i += 1;
        }
        for (f, &gi) in g.iter().enumerate() {
            let j = e * nf + f;
            c.apply(&mut p[j], &mut m[j], &mut v[j], gi);
        }
    }
}

/// Stable LSD radix sort of `keys` by their bits 32..32+`key_bits` (11 bits a pass).
fn radix_sort_high(keys: &mut Vec<u64>, key_bits: u32) {
    const BITS: u32 = 11;
    let mut tmp = vec![0u64; keys.len()];
    let mut shift = 32;
    while shift < 32 + key_bits {
        let bits = BITS.min(32 + key_bits - shift);
        let mask = (1u64 << bits) - 1;
        let mut start = vec![0usize; (1 << bits) + 1];
        for &k in keys.iter() {
            start[((k >> shift) & mask) as usize + 1] += 1;
        }
        for b in 1..start.len() {
            start[b] += start[b - 1];
        }
        for &k in keys.iter() {
            let b = ((k >> shift) & mask) as usize;
            tmp[start[b]] = k;
            start[b] += 1;
        }
        std::mem::swap(keys, &mut tmp);
        shift += bits;
    }
}

/// Adam on one level's touched entries (`list`, global indices); zeroes their gradient `g`.
fn adam_level(
    c: &AdamCoef,
    level: &Level,
    nf: usize,
    list: &[u32],
    params: AdamLevel,
    g: &mut [f32],
) {
    let AdamLevel { p, m, v } = params;
    for &e in list {
        let base = (e as usize - level.offset) * nf;
        for i in base..base + nf {
            c.apply(&mut p[i], &mut m[i], &mut v[i], g[i]);
            g[i] = 0.0;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn small() -> HashGrid {
        let mut g = HashGridConfig::new()
            .with_levels(6)
            .with_log2_table(10)
            .with_base_resolution(4.0)
            .with_per_level_scale(1.8)
            .init(3);
        // Larger values than the default init so gradients w.r.t. x are not tiny.
        let mut r = Rng::new(9, 9);
        g.table.iter_mut().for_each(|v| *v = r.next_f32() - 0.5);
        g
    }

    /// `"auto"` keeps the levels no finer than `cells_per_footprint` cells per footprint: the
    /// finest kept one is at most that fine, and the next would be finer.
    #[test]
    fn auto_levels_stop_at_the_footprint() {
        let mut c = HashGridConfig::new();
        c.max_resolution = MaxResolution::Keyword(ResolutionKeyword::Auto);
        for (cells, footprint) in [(1.0, 0.0064), (0.5, 0.0064), (1.0, 0.0089), (2.0, 0.02)] {
            c.cells_per_footprint = cells;
            let kept = c.levels_for(footprint);
            let res = |l: usize| c.base_resolution * c.per_level_scale.powi(l as i32);
            let max = cells / footprint;
            assert!(
                res(kept - 1) <= max && res(kept) > max,
                "{cells} {footprint}: {kept}"
            );
        }
        c.cells_per_footprint = 0.5;
        assert!(
            c.levels_for(0.0064)
                < HashGridConfig {
                    cells_per_footprint: 1.0,
                    ..c.clone()
                }
                .levels_for(0.0064)
        );
        c.max_resolution = MaxResolution::Keyword(ResolutionKeyword::None);
        assert_eq!(c.levels_for(0.0064), c.levels);
    }

    fn points(n: usize, seed: u64) -> Vec<[f32; 3]> {
        let mut r = Rng::new(seed, 0);
        (0..n)
            .map(|_| {
                [
                    0.05 + 0.9 * r.next_f32(),
                    0.05 + 0.9 * r.next_f32(),
                    0.05 + 0.9 * r.next_f32(),
                ]
            })
            .collect()
    }

    #[test]
    fn layout_dense_then_hashed() {
        let g = HashGridConfig::new().init(0);
        assert_eq!(g.levels.len(), 32);
        assert!(g.levels[0].dense && !g.levels[31].dense);
        assert!(g.levels.iter().all(|l| l.size <= 1 << 19));
        // Finest resolution ≈ 32·1.3^31 ≈ 1.1e5 vertices per unit.
        assert!(g.levels[31].scale > 1e5);
    }

    /// The encoding is linear in the table: d loss/d table from `backward_table` equals a
    /// finite difference of loss = Σ c·enc for random c (exact up to f32 rounding).
    #[test]
    fn table_gradient_matches_finite_differences() {
        let mut g = small();
        let xs = points(50, 1);
        let mut r = Rng::new(5, 5);
        let c: Vec<f32> = (0..xs.len() * g.output_dim())
            .map(|_| r.next_f32() - 0.5)
            .collect();
        let loss = |g: &HashGrid| -> f64 {
            g.encode(&xs)
                .iter()
                .zip(&c)
                .map(|(a, b)| (*a as f64) * (*b as f64))
                .sum()
        };
        let mut tg = TableGrad::new(&g);
        g.backward_table(&xs, &c, &mut tg);
        let touched: Vec<u32> = tg.touched.iter().flatten().copied().collect();
        assert!(!touched.is_empty());
        // Entries not touched have zero gradient.
        let nz = tg.values.iter().filter(|v| **v != 0.0).count();
        assert!(nz <= touched.len() * g.features);
        for &e in touched.iter().step_by(7).take(60) {
            for f in 0..g.features {
                let i = e as usize * g.features + f;
                let h = 1e-2;
                let old = g.table[i];
                g.table[i] = old + h;
                let lp = loss(&g);
                g.table[i] = old - h;
                let lm = loss(&g);
                g.table[i] = old;
                let fd = (lp - lm) / (2.0 * h as f64);
                let an = tg.values[i] as f64;
                assert!(
                    (fd - an).abs() <= 1e-4 + 1e-3 * an.abs(),
                    "entry {e}: fd {fd} vs {an}"
                );
            }
        }
    }

    /// d loss / d x against central differences (within a cell the encoding is smooth).
    #[test]
    fn input_gradient_matches_finite_differences() {
        let g = small();
        let xs = points(40, 2);
        let mut r = Rng::new(6, 6);
        let c: Vec<f32> = (0..g.output_dim()).map(|_| r.next_f32() - 0.5).collect();
        let f = |x: [f32; 3]| -> f64 {
            let e = g.encode(&[x]);
            e.iter().zip(&c).map(|(a, b)| *a as f64 * *b as f64).sum()
        };
        let grad_out: Vec<f32> = xs.iter().flat_map(|_| c.iter().copied()).collect();
        let gx = g.backward_input(&xs, &grad_out);
        let mut checked = 0;
        for (p, &x) in xs.iter().enumerate() {
            for d in 0..3 {
                let h = 1e-4f32;
                let (mut a, mut b) = (x, x);
                a[d] += h;
                b[d] -= h;
                // Skip if the step crosses a cell boundary on any level (the encoding has a kink).
                let crosses = g
                    .levels
                    .iter()
                    .any(|l| (a[d] * l.scale + 0.5).floor() != (b[d] * l.scale + 0.5).floor());
                if crosses {
                    continue;
                }
                let fd = (f(a) - f(b)) / (2.0 * h as f64);
                let an = gx[p][d] as f64;
                assert!(
                    (fd - an).abs() <= 2e-2 * (1.0 + an.abs()),
                    "point {p} dim {d}: fd {fd} vs {an}"
                );
                checked += 1;
            }
        }
        assert!(checked > 60, "only {checked} checks");
    }

    /// A large batch (level by level, entry order) encodes bit for bit as small ones (point by
    /// point), on dense and hashed levels, with points outside the cube clamped alike.
    #[test]
    fn sorted_encode_equals_point_encode() {
        let g = small();
        assert!(g.levels.iter().any(|l| l.dense) && g.levels.iter().any(|l| !l.dense));
        let mut xs = points(3 * SORTED_ENCODE_MIN / 2, 21);
        xs[7] = [-0.2, 1.3, 0.5];
        let whole = g.encode(&xs);
        let parts: Vec<f32> = xs
            .chunks(SORTED_ENCODE_MIN / 2)
            .flat_map(|c| g.encode(c))
            .collect();
        assert_eq!(whole, parts);
        // Both large-batch paths of a level (entry order, point order) give the same bits.
        for level in &g.levels {
            assert_eq!(
                g.encode_level_sorted(level, &xs),
                g.encode_level_direct(level, &xs)
            );
        }
        // A level too large for L2 is read in entry order, and still equals the point path.
        let big = HashGridConfig::new()
            .with_levels(2)
            .with_log2_table(18)
            .with_base_resolution(16.0)
            .with_per_level_scale(8.0)
            .init(6);
        assert!(big.levels.iter().any(|l| l.size > L2_LEVEL));
        let xs = points(SORTED_ENCODE_MIN, 22);
        let small_batches: Vec<f32> = xs.chunks(100).flat_map(|c| big.encode(c)).collect();
        assert_eq!(big.encode(&xs), small_batches);
    }

    #[test]
    fn fused_backward_adam_equals_separate_passes() {
        let mut a = small();
        let mut b = a.clone();
        let mut r = Rng::new(8, 8);
        let (mut ga, mut gb) = (TableGrad::new(&a), TableGrad::new(&b));
        let (mut aa, mut ab) = (
            TableAdam::new(&a, 0.9, 0.99, 1e-8),
            TableAdam::new(&b, 0.9, 0.99, 1e-8),
        );
        for step in 0..3 {
            let xs = points(30, 10 + step);
            let go: Vec<f32> = (0..xs.len() * a.output_dim())
                .map(|_| r.next_f32() - 0.5)
                .collect();
            a.backward_table(&xs, &go, &mut ga);
            aa.step(&mut a, &mut ga, 1e-2);
            b.backward_adam(&xs, &go, &mut gb, &mut ab, 1e-2);
        }
        assert_eq!(a.table, b.table);
        assert!(gb.values.iter().all(|v| *v == 0.0));
    }

    /// The two ways `backward_adam` updates a level give the same bits, on dense and hashed
    /// levels, over steps where entries are touched once, many times, or not at all; and a
    /// grid with levels too large for the dense way (the sorted one) still equals the
    /// separate passes.
    #[test]
    fn dense_and_sorted_level_updates_agree() {
        let g0 = HashGridConfig::new()
            .with_levels(5)
            .with_log2_table(12)
            .with_base_resolution(4.0)
            .with_per_level_scale(2.5)
            .init(5);
        assert!(g0.levels.iter().any(|l| l.dense) && g0.levels.iter().any(|l| !l.dense));
        let nf = g0.features;
        let mut r = Rng::new(4, 4);
        let (mut a, mut b) = (g0.clone(), g0.clone());
        let (mut ga, mut aa) = (TableGrad::new(&a), TableAdam::new(&a, 0.9, 0.99, 1e-8));
        let mut ab = TableAdam::new(&b, 0.9, 0.99, 1e-8);
        for step in 0..4 {
            let xs = points(40 + 300 * step, 30 + step as u64);
            let go: Vec<f32> = (0..xs.len() * a.output_dim())
                .map(|_| r.next_f32() - 0.5)
                .collect();
            let up = Upstream {
                xs: &xs,
                grad_out: &go,
                nl: a.levels.len(),
                nf,
            };
            ga.step += 1;
            let (ca, cb) = (aa.advance(1e-2), ab.advance(1e-2));
            let levels = a.levels.clone();
            let mut gl = split_levels(&levels, nf, &mut ga.values);
            let mut kl = split_levels(&levels, 1, &mut ga.mark);
            let (mut pa, mut ma, mut va) = (
                split_levels(&levels, nf, &mut a.table),
                split_levels(&levels, nf, &mut aa.m),
                split_levels(&levels, nf, &mut aa.v),
            );
            let (mut pb, mut mb, mut vb) = (
                split_levels(&levels, nf, &mut b.table),
                split_levels(&levels, nf, &mut ab.m),
                split_levels(&levels, nf, &mut ab.v),
            );
            for (l, level) in levels.iter().enumerate() {
                let a_parts = AdamLevel {
                    p: &mut *pa[l],
                    m: &mut *ma[l],
                    v: &mut *va[l],
                };
                let a_grad = LevelGrad {
                    values: &mut *gl[l],
                    mark: &mut *kl[l],
                    stamp: ga.step,
                };
                dense_adam_level(&ca, level, l, &up, a_parts, a_grad);
                let b_parts = AdamLevel {
                    p: &mut *pb[l],
                    m: &mut *mb[l],
                    v: &mut *vb[l],
                };
                sorted_adam_level(&cb, level, l, &up, b_parts);
            }
            assert!(ga.values.iter().all(|v| *v == 0.0));
        }
        assert_eq!(a.table, b.table);
        assert_eq!((&aa.m, &aa.v), (&ab.m, &ab.v));
        assert_ne!(a.table, g0.table);
        // A level of 2^18 entries and few points takes the sorted way.
        let mut big = HashGridConfig::new()
            .with_levels(3)
            .with_log2_table(18)
            .with_base_resolution(16.0)
            .with_per_level_scale(8.0)
            .init(6);
        assert!(big.levels.iter().any(|l| !dense_update(l, 50)));
        assert!(big.levels.iter().any(|l| dense_update(l, 50)));
        let mut sep = big.clone();
        let xs = points(50, 77);
        let go: Vec<f32> = (0..xs.len() * big.output_dim())
            .map(|_| r.next_f32() - 0.5)
            .collect();
        let (mut g1, mut g2) = (TableGrad::new(&big), TableGrad::new(&sep));
        let mut a1 = TableAdam::new(&big, 0.9, 0.99, 1e-8);
        let mut a2 = TableAdam::new(&sep, 0.9, 0.99, 1e-8);
        big.backward_adam(&xs, &go, &mut g1, &mut a1, 1e-2);
        sep.backward_table(&xs, &go, &mut g2);
        a2.step(&mut sep, &mut g2, 1e-2);
        assert_eq!(big.table, sep.table);
    }

    #[test]
    fn adam_updates_only_touched_entries_and_clears() {
        let mut g = small();
        let before = g.table.clone();
        let xs = points(10, 3);
        let go = vec![1.0; xs.len() * g.output_dim()];
        let mut tg = TableGrad::new(&g);
        let mut adam = TableAdam::new(&g, 0.9, 0.999, 1e-8);
        g.backward_table(&xs, &go, &mut tg);
        let touched: std::collections::HashSet<u32> =
            tg.touched.iter().flatten().copied().collect();
        adam.step(&mut g, &mut tg, 1e-2);
        for e in 0..g.table.len() / g.features {
            let changed = (0..g.features).any(|f| g.table[e * 2 + f] != before[e * 2 + f]);
            assert_eq!(changed, touched.contains(&(e as u32)), "entry {e}");
        }
        assert!(tg.values.iter().all(|v| *v == 0.0));
        // First Adam step moves each touched value by lr·sign(g) (|m̂/√v̂| = 1).
        let e = *touched.iter().next().unwrap() as usize * 2;
        assert!(((before[e] - g.table[e]).abs() - 1e-2).abs() < 1e-5);
    }
}
