//! The fit of the material field and the emission mask (paper §4.4–4.5, Eq. 12 and 15–20):
//! shuffled batches from the pixel store through `Trainer::step` (host batches), or by index from
//! a `DeviceStore` through `Trainer::step_on` when the grid lives on the device, on a schedule.
//!
//! Owns: the schedule (steps, learning rate, which pixels a batch holds), the loss log,
//! progress. Must not touch: the model maths, the pixel store.

use super::pixels::PixelStore;
use crate::progress::progress_bar;
use fipt_core::brdf::{factorised_render, reflectances};
use fipt_core::model::step::{DeviceStore, SegMode, StepInput, StepLoss};
use fipt_core::model::{LossParts, TrainConfig, Trainer};
use fipt_core::rng::Rng;
use fipt_core::scene::SceneBox;
use fipt_core::shading::ShadingLayout;
use std::path::Path;

/// The reflected radiance the trained BRDF predicts from the stored shadings at every stored
/// pixel, scattered back into per-view images (3 floats per pixel, zeros at misses).
pub fn reflected(tr: &Trainer, store: &PixelStore, pixels_per_view: &[usize]) -> Vec<Vec<f32>> {
    let mat = tr.model.material(&store.pixels.x_unit);
    let mut out: Vec<Vec<f32>> = pixels_per_view.iter().map(|&n| vec![0.0; 3 * n]).collect();
    for (i, &(k, p)) in store.origin.iter().enumerate() {
        let a = glam::Vec3::from_slice(&mat.a[3 * i..3 * i + 3]);
        let (kd, ks) = reflectances(a, mat.metallic[i]);
        let sh = ShadingLayout::pixel(&store.pixels.shadings, i);
        let c = factorised_render(kd.to_array(), ks.to_array(), mat.sigma[i], sh);
        out[k as usize][3 * p as usize..3 * p as usize + 3].copy_from_slice(&c);
    }
    out
}

/// Loss log of a training run: the mean of each part per epoch, and every step's total.
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct TrainLog {
    pub epochs: Vec<LossParts>,
    pub step_total: Vec<f32>,
    /// The basin hop after the fit (`hop`), once it has run; None before, or without one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub hop: Option<super::hop::HopReport>,
}

/// How long a fit runs and what each step sees.
///
/// The reference trains `epochs` epochs of ceil(N / batch) steps at a constant learning rate
/// (its milestone never fires), which is ~10k steps on its 41 M-pixel kitchen but ~226 on a
/// 0.9 M-pixel scene. `min_steps` puts a floor under the step count so that the schedule
/// transfers between scenes of different pixel counts, `lr_end` decays the learning rate
/// exponentially to `lr_end × lr` at the last step, and `balance` draws that share of every
/// batch uniformly over segments (then uniformly within the segment), so that small parts are
/// seen. `Schedule::reference` reproduces the reference.
#[derive(Clone, Debug, PartialEq)]
pub struct Schedule {
    pub epochs: usize,
    pub batch: usize,
    pub min_steps: usize,
    /// Learning rate at the first step.
    pub lr: f64,
    /// Learning rate at the last step as a fraction of `lr` (1: constant).
    pub lr_end: f64,
    /// Share of each batch drawn segment-balanced (0: all uniform over pixels).
    pub balance: f32,
    /// λ_d (Eq. 17) at the last step as a fraction of its configured value, reached linearly
    /// (1: constant, the reference).
    pub lambda_d_end: f32,
    /// Share of the steps over which λ_d first rises linearly from 0 (0: none, the reference).
    pub lambda_d_warmup: f32,
}

impl Schedule {
    /// The reference's schedule: `epochs` epochs at constant `lr`, uniform batches.
    pub fn reference(epochs: usize, batch: usize, lr: f64) -> Self {
        Self {
            epochs,
            batch,
            min_steps: 0,
            lr,
            lr_end: 1.0,
            balance: 0.0,
            lambda_d_end: 1.0,
            lambda_d_warmup: 0.0,
        }
    }

    /// The factor on λ_d at step `s` of `total`.
    pub fn lambda_d_at(&self, s: usize, total: usize) -> f32 {
        let f = if total > 1 {
            s as f32 / (total - 1) as f32
        } else {
            0.0
        };
        let ramp = if self.lambda_d_warmup > 0.0 {
            (f / self.lambda_d_warmup).min(1.0)
        } else {
            1.0
        };
        ramp * (1.0 + (self.lambda_d_end - 1.0) * f)
    }

    /// Steps of a fit over `n` pixels.
    pub fn steps(&self, n: usize) -> usize {
        (self.epochs * n.div_ceil(self.batch.max(1))).max(self.min_steps)
    }

    /// The learning rate of step `s` of `total`.
    pub fn lr_at(&self, s: usize, total: usize) -> f64 {
        let f = if total > 1 {
            s as f64 / (total - 1) as f64
        } else {
            0.0
        };
        self.lr * self.lr_end.powf(f)
    }
}

/// What one fit runs: the model and optimiser config, the scene box, the segmentation loss,
/// the schedule and the seed.
pub struct FitPlan {
    pub cfg: TrainConfig,
    pub scene_box: SceneBox,
    pub mode: SegMode,
    pub schedule: Schedule,
    pub seed: u64,
}

/// Draws batch indices: shuffled epochs over all pixels, and the balanced share by segment.
#[derive(Clone, Debug)]
pub(super) struct Sampler {
    rng: Rng,
    /// The current permutation of all pixels (each epoch shuffles the last one further).
    order: Vec<u32>,
    /// Position in `order`; past its end, the next draw shuffles first.
    next: usize,
    /// Pixel indices of each segment (derived from the store, not saved).
    segments: Vec<Vec<u32>>,
}

const SAMPLER_MAGIC: &[u8; 8] = b"FIPTSMP1";

impl Sampler {
    fn new(store: &PixelStore, seed: u64, balanced: bool) -> Self {
        Self {
            rng: Rng::new(seed, 0x7a1),
            order: (0..store.len() as u32).collect(),
            next: usize::MAX,
            segments: Self::segments_of(store, balanced),
        }
    }

    /// Pixel indices of each segment, in segment-id order (none unless `balanced`).
    pub(super) fn segments_of(store: &PixelStore, balanced: bool) -> Vec<Vec<u32>> {
        if !balanced {
            return Vec::new();
        }
        let mut by: std::collections::BTreeMap<i32, Vec<u32>> = Default::default();
        for (i, &s) in store.pixels.seg.iter().enumerate() {
            by.entry(s).or_default().push(i as u32);
        }
        by.into_values().collect()
    }

    /// `uniform` pixels in epoch order (a new permutation whenever one is used up), then
    /// `balanced` pixels drawn segment-first.
    fn draw(&mut self, uniform: usize, balanced: usize, out: &mut Vec<u32>) {
        out.clear();
        while out.len() < uniform {
            if self.next >= self.order.len() {
                self.rng.shuffle(&mut self.order);
                self.next = 0;
            }
            let take = (uniform - out.len()).min(self.order.len() - self.next);
            out.extend_from_slice(&self.order[self.next..self.next + take]);
            self.next += take;
        }
        if !self.segments.is_empty() {
            for _ in 0..balanced {
                let s = &self.segments[self.rng.below(self.segments.len() as u64) as usize];
                out.push(s[self.rng.below(s.len() as u64) as usize]);
            }
        }
    }

    /// The saved state: magic, RNG state, position, order length, the order (little-endian).
    fn to_bytes(&self) -> Vec<u8> {
        let mut b = Vec::with_capacity(32 + 4 * self.order.len());
        b.extend_from_slice(SAMPLER_MAGIC);
        b.extend_from_slice(&self.rng.state().to_le_bytes());
        b.extend_from_slice(&(self.next as u64).to_le_bytes());
        b.extend_from_slice(&(self.order.len() as u64).to_le_bytes());
        for i in &self.order {
            b.extend_from_slice(&i.to_le_bytes());
        }
        b
    }

    /// The sampler `to_bytes` saved, for `store`; the reason when the bytes are not one (wrong
    /// magic, size, length, or an order that is not a permutation).
    fn from_bytes(b: &[u8], store: &PixelStore, balanced: bool) -> Result<Self, String> {
        if b.len() < 32 || &b[..8] != SAMPLER_MAGIC {
            return Err("not a fipt sampler state".into());
        }
        let word = |i: usize| u64::from_le_bytes(b[8 + 8 * i..16 + 8 * i].try_into().unwrap());
        let (state, next, n) = (word(0), word(1), word(2));
        if n != store.len() as u64 || b.len() as u64 != 32 + 4 * n {
            return Err(format!(
                "holds {n} pixels in {} bytes, the fit has {}",
                b.len(),
                store.len()
            ));
        }
        let order: Vec<u32> = b[32..]
            .chunks_exact(4)
            .map(|c| u32::from_le_bytes(c.try_into().unwrap()))
            .collect();
        let mut seen = vec![false; order.len()];
        for &i in &order {
            match seen.get_mut(i as usize) {
                Some(s) if !*s => *s = true,
                _ => return Err("the pixel order is not a permutation".into()),
            }
        }
        let next = if next == u64::MAX {
            usize::MAX
        } else if next <= n {
            next as usize
        } else {
            return Err(format!("position {next} past the {n} pixels"));
        };
        Ok(Self {
            rng: Rng::from_state(state),
            order,
            next,
            segments: Self::segments_of(store, balanced),
        })
    }
}

/// Everything of a running fit besides the trainer: the step, the loss log so far and the
/// batch sampler (RNG state and pixel order). With the trainer's own state
/// (`Trainer::save_state`) it continues the fit exactly (`fit_resumable`).
#[derive(Clone, Debug)]
pub struct FitProgress {
    /// Steps done.
    pub step: usize,
    /// Steps of the whole fit.
    pub total: usize,
    pub log: TrainLog,
    /// Loss sums of the current epoch, and its steps so far (steps settled into the log).
    sum: LossParts,
    in_epoch: usize,
    sampler: Sampler,
    /// Losses of the steps after the log's last one, still on the device (`settle` reads them).
    pending: Vec<StepLoss>,
    /// Steps per epoch of the fit (for the epoch means).
    per_epoch: usize,
}

/// The JSON part of `FitProgress` (the sampler goes into its own binary file).
#[derive(serde::Serialize, serde::Deserialize)]
struct ProgressFile {
    step: usize,
    total: usize,
    log: TrainLog,
    sum: LossParts,
    in_epoch: usize,
}

const PROGRESS_FILE: &str = "progress.json";
const SAMPLER_FILE: &str = "sampler.bin";

impl FitProgress {
    /// Whether every step has run.
    pub fn done(&self) -> bool {
        self.step >= self.total
    }

    /// Reads the pending losses (one device read) into the log and the epoch sums.
    pub fn settle(&mut self) {
        if self.pending.is_empty() {
            return;
        }
        let first = self.step - self.pending.len();
        let losses = StepLoss::read_all(std::mem::take(&mut self.pending));
        for (k, l) in losses.into_iter().enumerate() {
            self.account(first + k, l);
        }
    }

    /// Logs step `s`'s loss; closes the epoch at its last step or the fit's.
    fn account(&mut self, s: usize, l: LossParts) {
        self.log.step_total.push(l.total);
        self.sum.total += l.total;
        self.sum.color += l.color;
        self.sum.emission += l.emission;
        self.sum.diffuse += l.diffuse;
        self.sum.seg += l.seg;
        self.in_epoch += 1;
        if self.in_epoch == self.per_epoch || s + 1 == self.total {
            let n = self.in_epoch as f32;
            self.log.epochs.push(LossParts {
                total: self.sum.total / n,
                color: self.sum.color / n,
                emission: self.sum.emission / n,
                diffuse: self.sum.diffuse / n,
                seg: self.sum.seg / n,
            });
            self.sum = LossParts::default();
            self.in_epoch = 0;
        }
    }

    /// Writes `progress.json` and `sampler.bin` into `dir`, each atomically. The progress must
    /// be settled (`settle`).
    pub fn save(&self, dir: &Path) -> anyhow::Result<()> {
        anyhow::ensure!(
            self.pending.is_empty(),
            "internal: saving a fit progress with unread losses"
        );
        let p = ProgressFile {
            step: self.step,
            total: self.total,
            log: self.log.clone(),
            sum: self.sum,
            in_epoch: self.in_epoch,
        };
        crate::output::write_json(&dir.join(PROGRESS_FILE), &p)?;
        fipt_core::io::write_bytes_atomic(&dir.join(SAMPLER_FILE), &self.sampler.to_bytes())?;
        Ok(())
    }

    /// Only the loss log of the progress `save` wrote into `dir`.
    pub fn load_log(dir: &Path) -> anyhow::Result<TrainLog> {
        Ok(read_progress(dir)?.log)
    }

    /// Whether the progress `save` wrote into `dir` reads and has run every step.
    pub fn saved_done(dir: &Path) -> bool {
        read_progress(dir).is_ok_and(|p| p.step == p.total)
    }

    /// The progress `save` wrote into `dir`, for a fit over `store` with `schedule`; an error
    /// naming the file when it is damaged or belongs to another fit.
    pub fn load(
        dir: &Path,
        store: &PixelStore,
        mode: SegMode,
        schedule: &Schedule,
    ) -> anyhow::Result<Self> {
        let path = dir.join(PROGRESS_FILE);
        let p = read_progress(dir)?;
        let shape = Shape::of(store, mode, schedule);
        // The last step closes a partial epoch.
        let (epochs, in_epoch) = if p.step == shape.steps {
            (p.step.div_ceil(shape.steps_per_epoch), 0)
        } else {
            (
                p.step / shape.steps_per_epoch,
                p.step % shape.steps_per_epoch,
            )
        };
        let log_ok = p.log.step_total.len() == p.step
            && p.log.epochs.len() == epochs
            && p.in_epoch == in_epoch;
        if p.total != shape.steps || p.step > p.total || !log_ok {
            anyhow::bail!(
                "{}: step {} of {} does not fit this fit ({} steps) or its log",
                path.display(),
                p.step,
                p.total,
                shape.steps
            );
        }
        let spath = dir.join(SAMPLER_FILE);
        let sampler = Sampler::from_bytes(
            &fipt_core::io::read_bytes(&spath)?,
            store,
            shape.balanced > 0,
        )
        .map_err(|e| anyhow::anyhow!("{}: {e}", spath.display()))?;
        Ok(Self {
            step: p.step,
            total: p.total,
            log: p.log,
            sum: p.sum,
            in_epoch: p.in_epoch,
            sampler,
            pending: Vec::new(),
            per_epoch: shape.steps_per_epoch,
        })
    }
}

/// `dir/progress.json`, parsed; the error names the file.
fn read_progress(dir: &Path) -> anyhow::Result<ProgressFile> {
    let path = dir.join(PROGRESS_FILE);
    serde_json::from_str(&fipt_core::io::read_text(&path)?)
        .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
}

/// The batch sizes and step counts of a fit over a store (also the basin hop's batches).
pub(super) struct Shape {
    pub(super) batch: usize,
    pub(super) balanced: usize,
    pub(super) steps: usize,
    steps_per_epoch: usize,
}

impl Shape {
    pub(super) fn of(store: &PixelStore, mode: SegMode, schedule: &Schedule) -> Self {
        let batch = schedule.batch.min(store.len()).max(1);
        let balanced = ((schedule.balance.clamp(0.0, 1.0) * batch as f32).round() as usize)
            .min(batch)
            * usize::from(mode != SegMode::None);
        Self {
            batch,
            balanced,
            steps: schedule.steps(store.len()),
            steps_per_epoch: store.len().div_ceil(batch).max(1),
        }
    }
}

/// Runs the schedule from a fresh model.
pub fn fit(
    store: &PixelStore,
    plan: FitPlan,
    device: &burn::tensor::Device,
    show_progress: bool,
) -> (Trainer, TrainLog) {
    let FitPlan {
        cfg,
        scene_box,
        mode,
        schedule,
        seed,
    } = plan;
    let tr = Trainer::new(cfg, scene_box, device, seed);
    fit_more(tr, store, mode, &schedule, seed, show_progress)
}

/// Runs the schedule on a trainer, from its first step, without checkpoints.
pub fn fit_more(
    tr: Trainer,
    store: &PixelStore,
    mode: SegMode,
    schedule: &Schedule,
    seed: u64,
    show_progress: bool,
) -> (Trainer, TrainLog) {
    let run = FitRun {
        mode,
        schedule,
        seed,
        show_progress,
    };
    match fit_resumable(tr, store, &run, None, &mut |_, _| Ok(())) {
        Ok((tr, p)) => (tr, p.log),
        Err(_) => unreachable!("a fit without an observer does not fail"),
    }
}

/// How a fit runs besides its trainer and pixels.
pub struct FitRun<'a> {
    pub mode: SegMode,
    pub schedule: &'a Schedule,
    pub seed: u64,
    pub show_progress: bool,
}

/// Runs the schedule on `tr`, from the start or from `resume` (the progress saved with `tr`'s
/// state), calling `after_step` after every step with the trainer and the progress: the place
/// to save a checkpoint (the progress may hold losses still on the device; `settle` reads
/// them, and `Checkpoints::save` does), or to stop the fit by returning an error. `tr` must hold the step's
/// base config (the schedule sets the learning rate and λ_d of each step from it).
pub fn fit_resumable(
    mut tr: Trainer,
    store: &PixelStore,
    run: &FitRun,
    resume: Option<FitProgress>,
    after_step: &mut dyn FnMut(&Trainer, &mut FitProgress) -> anyhow::Result<()>,
) -> anyhow::Result<(Trainer, FitProgress)> {
    let schedule = run.schedule;
    let shape = Shape::of(store, run.mode, schedule);
    let mut p = resume.unwrap_or_else(|| FitProgress {
        step: 0,
        total: shape.steps,
        log: TrainLog::default(),
        sum: LossParts::default(),
        in_epoch: 0,
        sampler: Sampler::new(store, run.seed, shape.balanced > 0),
        pending: Vec::new(),
        per_epoch: shape.steps_per_epoch,
    });
    let pb = progress_bar(shape.steps as u64, "train", run.show_progress);
    pb.set_position(p.step as u64);
    let mut idx = Vec::with_capacity(shape.batch);
    let lambda_d = tr.cfg.lambda_d;
    // The device path keeps the pixels on the device and uploads only each batch's indices;
    // its losses are read every `LOSS_READ_EVERY` steps (and at every epoch's end), in one read.
    let device_store = tr
        .device_resident()
        .then(|| DeviceStore::upload(&store.pixels, &tr.device));
    while p.step < shape.steps {
        let s = p.step;
        p.sampler
            .draw(shape.batch - shape.balanced, shape.balanced, &mut idx);
        tr.cfg.lr = schedule.lr_at(s, shape.steps);
        tr.cfg.lambda_d = lambda_d * schedule.lambda_d_at(s, shape.steps);
        let l = step_entries(&mut tr, device_store.as_ref(), store, &idx, run.mode);
        tr.cfg.lambda_d = lambda_d;
        p.pending.push(l);
        p.step += 1;
        let epoch_end = (p.in_epoch + p.pending.len()) == shape.steps_per_epoch;
        if device_store.is_none() || p.pending.len() >= LOSS_READ_EVERY || epoch_end || p.done() {
            p.settle();
            if let Some(l) = p.log.step_total.last() {
                pb.set_message(format!("loss {l:.4}"));
            }
        }
        pb.inc(1);
        if let Err(e) = after_step(&tr, &mut p) {
            pb.finish_and_clear();
            return Err(e);
        }
    }
    p.settle();
    tr.sync_host_table();
    pb.finish_and_clear();
    Ok((tr, p))
}

/// Steps between two reads of the device path's losses.
pub const LOSS_READ_EVERY: usize = 25;

/// One step on the entries `idx` of `store`: by index from its device copy `ds` when the grid
/// lives on the device (the loss left there; the semantic loss also gets the host batch), else
/// as a host batch.
pub fn step_entries(
    tr: &mut Trainer,
    ds: Option<&DeviceStore>,
    store: &PixelStore,
    idx: &[u32],
    mode: SegMode,
) -> StepLoss {
    match ds {
        Some(ds) => {
            // The semantic loss and a σ pull read the batch's labels on the host.
            let host = (mode == SegMode::Semantic || tr.pull.is_some()).then(|| store.batch(idx));
            let input = StepInput::Device {
                store: ds,
                idx,
                host: host.as_ref(),
            };
            tr.step_on(input, mode)
        }
        None => StepLoss::Ready(tr.step(&store.batch(idx), mode)),
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use fipt_core::model::Batch;

    pub(crate) fn store(seg: &[i32]) -> PixelStore {
        let n = seg.len();
        PixelStore {
            pixels: Batch {
                x_unit: vec![[0.5; 3]; n],
                x_world: vec![[0.0; 3]; n],
                shadings: vec![0.0; n * ShadingLayout::DIM],
                gt: vec![0.0; 3 * n],
                seg: seg.to_vec(),
            },
            origin: (0..n as u32).map(|i| (0, i)).collect(),
        }
    }

    /// `n` pixels of five segments with varied positions, shadings and colours.
    pub(crate) fn toy_store(n: usize) -> PixelStore {
        let seg: Vec<i32> = (0..n).map(|i| (i % 5) as i32).collect();
        let mut st = store(&seg);
        for i in 0..n {
            let t = i as f32 / n as f32;
            st.pixels.x_unit[i] = [t, (3.0 * t).fract(), (7.0 * t).fract()];
            for c in 0..ShadingLayout::DIM {
                st.pixels.shadings[i * ShadingLayout::DIM + c] =
                    0.2 + 0.5 * ((i + c) % 7) as f32 / 7.0;
            }
            st.pixels.gt[3 * i..3 * i + 3].copy_from_slice(&[0.3 + 0.4 * t, 0.5, 0.2]);
        }
        st
    }

    /// A small model and a 25-step schedule.
    pub(crate) fn toy_fit() -> (fipt_core::model::TrainConfig, Schedule) {
        let mut train = crate::config::Config::default().train;
        train.grid.log2_table = 8;
        train.mlp_hidden = 16;
        train.emission_width = 16;
        train.emission_depth = 2;
        let schedule = Schedule {
            min_steps: 25,
            balance: 0.25,
            lr_end: 0.1,
            lambda_d_end: 0.5,
            ..Schedule::reference(1, 64, 1e-2)
        };
        (
            train.model_config(3, fipt_core::model::BackendKind::Flex),
            schedule,
        )
    }

    /// A fit stopped after some steps, saved (`Checkpoints::save`), restored and continued
    /// ends bit-identical to the uninterrupted fit: the same table, networks and loss log; a
    /// sampler state of another store is refused with the file named.
    #[test]
    fn interrupted_fit_continues_exactly() {
        interrupted_fit(false);
    }

    /// The same on the device path: pixels in a `DeviceStore`, losses read in blocks (settled
    /// at each epoch's end and before the save), the table and its Adam state on the device.
    #[test]
    fn interrupted_device_grid_fit_continues_exactly() {
        interrupted_fit(true);
    }

    fn interrupted_fit(device_grid: bool) {
        use crate::pipeline::checkpoint::Checkpoints;
        let build = toy_store;
        // The device fit reads its losses every `LOSS_READ_EVERY` steps and at epoch ends: with
        // 32 steps per epoch and 60 steps both kinds of read happen (25, 32, 57, 60).
        let (n, steps) = if device_grid { (2000, 60) } else { (600, 25) };
        let st = build(n);
        let (cfg, mut schedule) = toy_fit();
        schedule.min_steps = steps;
        let cfg = cfg.with_device_grid(device_grid);
        let device = burn::tensor::Device::flex();
        let scene_box = SceneBox { min: 0.0, max: 1.0 };
        let run = FitRun {
            mode: SegMode::Part,
            schedule: &schedule,
            seed: 3,
            show_progress: false,
        };
        let fresh = || Trainer::new(cfg.clone(), scene_box, &device, 3);
        let (whole, pw) = fit_resumable(fresh(), &st, &run, None, &mut |_, _| Ok(())).unwrap();
        assert_eq!(whole.device_resident(), device_grid);
        assert_eq!(pw.log.step_total.len(), steps);
        assert_eq!(pw.log.epochs.len(), steps.div_ceil(n.div_ceil(64)));
        assert!(pw.log.step_total.iter().all(|l| l.is_finite() && *l > 0.0));

        let dir = std::env::temp_dir().join(format!(
            "fipt-fit-resume-{device_grid}-{}",
            std::process::id()
        ));
        let _ = std::fs::remove_dir_all(&dir);
        let ck = Checkpoints {
            dir: dir.clone(),
            every: 0,
        };
        let e = fit_resumable(fresh(), &st, &run, None, &mut |tr, p| {
            if p.step == 11 {
                ck.save(0, tr, p)?;
                anyhow::bail!("stop");
            }
            Ok(())
        });
        assert!(e.is_err());
        let of = |store| crate::pipeline::checkpoint::FitOf {
            cfg: &cfg,
            device: &device,
            seed: 3,
            store,
            run: &run,
        };
        let c = ck.restore(0, &of(&st)).unwrap().expect("a saved state");
        assert_eq!(c.progress.step, 11);
        let (resumed, pr) =
            fit_resumable(c.trainer, &st, &run, Some(c.progress), &mut |_, _| Ok(())).unwrap();
        assert_eq!(pw.log.step_total, pr.log.step_total);
        let epochs = |p: &FitProgress| {
            p.log
                .epochs
                .iter()
                .map(|e| [e.total, e.color, e.emission, e.diffuse, e.seg])
                .collect::<Vec<_>>()
        };
        assert_eq!(epochs(&pw), epochs(&pr));
        assert_eq!(whole.steps, resumed.steps);
        assert_eq!(whole.model.grid.table, resumed.model.grid.table);
        assert_eq!(whole.model.net_params(), resumed.model.net_params());

        // Another store (one pixel fewer) does not take this sampler state.
        let small = build(n - 1);
        let e = ck
            .restore(0, &of(&small))
            .err()
            .expect("refused")
            .to_string();
        assert!(
            e.contains("sampler.bin") || e.contains("progress.json"),
            "{e}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// The reference schedule: epochs × ceil(N/B) steps at a constant rate; the floor and the
    /// decay as documented.
    #[test]
    fn schedule_steps_and_rates() {
        let r = Schedule::reference(2, 8192, 1e-3);
        assert_eq!(r.steps(921_600), 226);
        assert_eq!(r.lr_at(0, 226), 1e-3);
        assert_eq!(r.lr_at(225, 226), 1e-3);
        let s = Schedule {
            min_steps: 1000,
            lr_end: 0.1,
            ..r
        };
        assert_eq!(s.steps(921_600), 1000);
        assert_eq!(s.steps(50_000_000), 2 * 6104);
        assert!((s.lr_at(999, 1000) - 1e-4).abs() < 1e-12);
        assert!((s.lr_at(0, 1000) - 1e-3).abs() < 1e-15);
        let mid = s.lr_at(500, 1000) / 1e-3;
        assert!((mid - 0.1f64.powf(500.0 / 999.0)).abs() < 1e-12);
        // λ_d: 0 at the first step, linear to full at `lambda_d_warmup` of the steps, then the
        // `lambda_d_end` line.
        let w = Schedule {
            lambda_d_warmup: 0.5,
            lambda_d_end: 0.5,
            ..r.clone()
        };
        assert_eq!(w.lambda_d_at(0, 101), 0.0);
        assert!((w.lambda_d_at(25, 101) - 0.5 * (1.0 - 0.5 * 0.25)).abs() < 1e-6);
        assert!((w.lambda_d_at(50, 101) - (1.0 - 0.5 * 0.5)).abs() < 1e-6);
        assert!((w.lambda_d_at(100, 101) - 0.5).abs() < 1e-6);
        assert_eq!(r.lambda_d_at(0, 101), 1.0);
    }

    /// Uniform draws cover every pixel once per epoch; balanced draws give a 1 %-segment the
    /// same share as a 99 %-segment.
    #[test]
    fn sampler_epochs_and_balance() {
        let seg: Vec<i32> = (0..1000).map(|i| if i < 10 { 7 } else { 3 }).collect();
        let st = store(&seg);
        let mut sa = Sampler::new(&st, 1, false);
        let mut seen = vec![0u32; 1000];
        let mut idx = Vec::new();
        for _ in 0..10 {
            sa.draw(100, 0, &mut idx);
            for &i in &idx {
                seen[i as usize] += 1;
            }
        }
        assert!(seen.iter().all(|&c| c == 1));
        let mut sb = Sampler::new(&st, 1, true);
        let mut small = 0;
        for _ in 0..100 {
            sb.draw(0, 100, &mut idx);
            small += idx.iter().filter(|&&i| i < 10).count();
        }
        // Expected 5000 of 10000; uniform sampling would give 100.
        assert!((4700..5300).contains(&small), "{small}");
    }
}
