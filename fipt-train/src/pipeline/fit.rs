//! The fit of the material field and the emission mask (paper §4.4–4.5, Eq. 12 and 15–20):
//! shuffled batches from the pixel store through `Trainer::step`, on a schedule.
//!
//! Owns: the schedule (steps, learning rate, which pixels a batch holds), the loss log,
//! progress. Must not touch: the model maths, the pixel store.

use super::pixels::PixelStore;
use crate::progress::progress_bar;
use fipt_core::brdf::{factorised_render, reflectances};
use fipt_core::model::step::SegMode;
use fipt_core::model::{LossParts, TrainConfig, Trainer};
use fipt_core::rng::Rng;
use fipt_core::scene::SceneBox;
use fipt_core::shading::ShadingLayout;

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
        }
    }

    /// The factor on λ_d at step `s` of `total`.
    pub fn lambda_d_at(&self, s: usize, total: usize) -> f32 {
        let f = if total > 1 {
            s as f32 / (total - 1) as f32
        } else {
            0.0
        };
        1.0 + (self.lambda_d_end - 1.0) * f
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
struct Sampler {
    rng: Rng,
    order: Vec<u32>,
    next: usize,
    /// Pixel indices of each segment.
    segments: Vec<Vec<u32>>,
}

impl Sampler {
    fn new(store: &PixelStore, seed: u64, balanced: bool) -> Self {
        let mut segments = Vec::new();
        if balanced {
            let mut by: std::collections::BTreeMap<i32, Vec<u32>> = Default::default();
            for (i, &s) in store.pixels.seg.iter().enumerate() {
                by.entry(s).or_default().push(i as u32);
            }
            segments = by.into_values().collect();
        }
        Self {
            rng: Rng::new(seed, 0x7a1),
            order: (0..store.len() as u32).collect(),
            next: usize::MAX,
            segments,
        }
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

/// Runs the schedule on an existing trainer (a warm start).
pub fn fit_more(
    mut tr: Trainer,
    store: &PixelStore,
    mode: SegMode,
    schedule: &Schedule,
    seed: u64,
    show_progress: bool,
) -> (Trainer, TrainLog) {
    let batch = schedule.batch.min(store.len()).max(1);
    let steps = schedule.steps(store.len());
    let balanced = ((schedule.balance.clamp(0.0, 1.0) * batch as f32).round() as usize).min(batch)
        * usize::from(mode != SegMode::None);
    let mut sampler = Sampler::new(store, seed, balanced > 0);
    let steps_per_epoch = store.len().div_ceil(batch).max(1);
    let pb = progress_bar(steps as u64, "train", show_progress);
    let mut log = TrainLog::default();
    let mut sum = LossParts::default();
    let mut in_epoch = 0;
    let mut idx = Vec::with_capacity(batch);
    let lambda_d = tr.cfg.lambda_d;
    for s in 0..steps {
        sampler.draw(batch - balanced, balanced, &mut idx);
        tr.cfg.lr = schedule.lr_at(s, steps);
        tr.cfg.lambda_d = lambda_d * schedule.lambda_d_at(s, steps);
        let l = tr.step(&store.batch(&idx), mode);
        log.step_total.push(l.total);
        sum.total += l.total;
        sum.color += l.color;
        sum.emission += l.emission;
        sum.diffuse += l.diffuse;
        sum.seg += l.seg;
        in_epoch += 1;
        if in_epoch == steps_per_epoch || s + 1 == steps {
            let n = in_epoch as f32;
            log.epochs.push(LossParts {
                total: sum.total / n,
                color: sum.color / n,
                emission: sum.emission / n,
                diffuse: sum.diffuse / n,
                seg: sum.seg / n,
            });
            sum = LossParts::default();
            in_epoch = 0;
        }
        pb.set_message(format!("loss {:.4}", l.total));
        pb.inc(1);
    }
    pb.finish_and_clear();
    tr.cfg.lambda_d = lambda_d;
    (tr, log)
}

#[cfg(test)]
mod tests {
    use super::*;
    use fipt_core::model::Batch;

    fn store(seg: &[i32]) -> PixelStore {
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
