//! The fit of the material field and the emission mask (paper §4.4–4.5, Eq. 12 and 15–20):
//! shuffled batches from the pixel store through `Trainer::step` (host batches), or by index from
//! a `DeviceStore` through `Trainer::step_on` when the grid lives on the device, on a schedule.
//!
//! Owns: the schedule (steps, learning rate, which pixels a batch holds), the loss log,
//! progress. Must not touch: the model maths, the pixel store.

use super::batches::{Sampler, Shape, step_entries};
use super::pixels::PixelStore;
use crate::config::TrainSection;
use crate::progress::progress_bar;
use fipt_core::brdf::{factorised_render, reflectances};
use fipt_core::model::step::{DeviceStore, SegMode, StepLoss};
use fipt_core::model::{LossParts, PartMap, TrainConfig, Trainer};
use fipt_core::scene::SceneBox;
use fipt_core::shading::ShadingLayout;
use std::path::Path;

/// The reflected radiance the trained BRDF predicts from the stored shadings at every stored
/// pixel, scattered back into per-view images of the sizes of `hits` (3 floats per pixel, zeros
/// at misses).
pub fn reflected(tr: &Trainer, store: &PixelStore, hits: &[fipt_bake::ViewHits]) -> Vec<Vec<f32>> {
    rendered(&tr.model, store, hits, true)
}

/// The specular part of `reflected`, k_s·L_s0(σ) + L_s1(σ) (Eq. 5 without k_d·L_d), that
/// `model` predicts from the stored shadings at every stored pixel, scattered back into
/// per-view images of the sizes of `hits` (zeros where no pixel is stored).
pub fn specular(
    model: &fipt_core::model::FiptModel,
    store: &PixelStore,
    hits: &[fipt_bake::ViewHits],
) -> Vec<Vec<f32>> {
    rendered(model, store, hits, false)
}

/// Eq. 5 at every stored pixel with `model`'s material and the stored shadings, its k_d·L_d
/// term included or not (`diffuse`), scattered back into per-view images of the sizes of `hits`.
fn rendered(
    model: &fipt_core::model::FiptModel,
    store: &PixelStore,
    hits: &[fipt_bake::ViewHits],
    diffuse: bool,
) -> Vec<Vec<f32>> {
    let mat = model.material(&store.pixels.x_unit, &store.pixels.part);
    let mut out: Vec<Vec<f32>> = hits.iter().map(|h| vec![0.0; 3 * h.num_pixels()]).collect();
    for (i, &(k, p)) in store.origin.iter().enumerate() {
        let a = glam::Vec3::from_slice(&mat.a[3 * i..3 * i + 3]);
        let (kd, ks) = reflectances(a, mat.metallic[i]);
        let kd = if diffuse { kd.to_array() } else { [0.0; 3] };
        let sh = ShadingLayout::pixel(&store.pixels.shadings, i);
        let c = factorised_render(kd, ks.to_array(), mat.sigma[i], sh);
        out[k as usize][3 * p as usize..3 * p as usize + 3].copy_from_slice(&c);
    }
    out
}

/// The segments (`Batch::seg`) whose mean m under `model`, over their stored pixels, is at
/// least 0.5: the metals of a fit.
pub fn metal_segments(model: &fipt_core::model::FiptModel, store: &PixelStore) -> Vec<i32> {
    let mat = model.material(&store.pixels.x_unit, &store.pixels.part);
    let mut sums: std::collections::BTreeMap<i32, (f64, usize)> = Default::default();
    for (&s, &m) in store.pixels.seg.iter().zip(&mat.metallic) {
        let e = sums.entry(s).or_default();
        e.0 += m as f64;
        e.1 += 1;
    }
    sums.into_iter()
        .filter(|(_, (sum, n))| *sum >= 0.5 * *n as f64)
        .map(|(s, _)| s)
        .collect()
}

/// Log of a training run: the pixels it drew from, the mean of each loss part per epoch, and
/// every step's total.
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct TrainLog {
    /// The training pixels the fit drew its batches from (saved with the fit, so that a round
    /// restored from its checkpoint reports them too).
    #[serde(default)]
    pub pixels: usize,
    pub epochs: Vec<LossParts>,
    pub step_total: Vec<f32>,
    /// The basin hop after the fit (`hop`), once it has run; None before, or without one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub hop: Option<super::hop::HopReport>,
}

/// What one fit runs: the model and optimiser config, the scene box, the segmentation loss,
/// the schedule and the seed.
pub struct FitPlan {
    pub cfg: TrainConfig,
    pub scene_box: SceneBox,
    /// The part offsets' map (`pixels::part_map`; no parts: none).
    pub parts: PartMap,
    pub mode: SegMode,
    pub schedule: TrainSection,
    pub seed: u64,
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
        schedule: &TrainSection,
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
        let log_ok = p.log.pixels == store.len()
            && p.log.step_total.len() == p.step
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
        parts,
        mode,
        schedule,
        seed,
    } = plan;
    let tr = Trainer::with_parts(cfg, scene_box, parts, device, seed);
    fit_more(tr, store, mode, &schedule, seed, show_progress)
}

/// Runs the schedule on a trainer, from its first step, without checkpoints.
pub fn fit_more(
    tr: Trainer,
    store: &PixelStore,
    mode: SegMode,
    schedule: &TrainSection,
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
    pub schedule: &'a TrainSection,
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
        log: TrainLog {
            pixels: store.len(),
            ..TrainLog::default()
        },
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pipeline::test_data::{toy_fit, toy_store};
    use glam::Vec3;

    /// One view of `n` pixels in a row, as `toy_store` places them.
    fn row(n: usize) -> Vec<fipt_bake::ViewHits> {
        vec![fipt_bake::ViewHits {
            width: n,
            height: 1,
            origin: Vec3::ZERO,
            direction: vec![Vec3::Z; n],
            t: vec![1.0; n],
            tri: vec![0; n],
            position: vec![Vec3::ZERO; n],
            normal: vec![Vec3::Z; n],
        }]
    }

    /// Eq. 5 splits into its diffuse and specular parts: at every stored pixel the reflected
    /// radiance less `specular` is k_d·L_d of the model's material, and `specular` is zero
    /// where L_s0 and L_s1 are, while the reflected radiance is not.
    #[test]
    fn specular_is_the_reflected_radiance_less_kd_ld() {
        let n = 64;
        let mut st = toy_store(n);
        // Pixel 0 without specular shadings.
        for s in ShadingLayout::LS0.chain(ShadingLayout::LS1) {
            st.pixels.shadings[s] = 0.0;
        }
        let (cfg, _) = toy_fit();
        let tr = Trainer::new(
            cfg,
            SceneBox { min: 0.0, max: 1.0 },
            &burn::tensor::Device::flex(),
            5,
        );
        let hits = row(n);
        let (refl, spec) = (reflected(&tr, &st, &hits), specular(&tr.model, &st, &hits));
        let mat = tr.model.material(&st.pixels.x_unit, &st.pixels.part);
        let mut specular_sum = 0.0;
        for i in 0..n {
            let a = glam::Vec3::from_slice(&mat.a[3 * i..3 * i + 3]);
            let (kd, _) = reflectances(a, mat.metallic[i]);
            let ld = &ShadingLayout::pixel(&st.pixels.shadings, i)[ShadingLayout::LD];
            for c in 0..3 {
                let diffuse = kd.to_array()[c] * ld[c];
                let (r, s) = (refl[0][3 * i + c], spec[0][3 * i + c]);
                assert!(
                    (r - s - diffuse).abs() < 1e-5,
                    "pixel {i}: {r} - {s} != {diffuse}"
                );
                assert!(s >= 0.0);
                if i == 0 {
                    assert_eq!(s, 0.0, "no specular shading, no specular radiance");
                    assert!(r > 0.0);
                }
                specular_sum += s;
            }
        }
        assert!(specular_sum > 0.0, "the toy shadings have specular parts");
    }
}
