//! The fit of the material field and the emission mask (paper §4.4–4.5, Eq. 12 and 15–20):
//! epochs of shuffled batches from the pixel store through `Trainer::step`.
//!
//! Owns: shuffling, the loss log, progress. Must not touch: the model maths, the pixel store.

use super::pixels::PixelStore;
use crate::progress::progress_bar;
use fipt_core::brdf::{factorised_render, reflectances};
use fipt_core::model::step::SegMode;
use fipt_core::model::{LossParts, TrainConfig, Trainer};
use fipt_core::rng::Rng;
use fipt_core::scene::SceneBox;
use fipt_core::shading::ShadingLayout;

/// The reflected radiance the trained BRDF predicts from the baked shadings at every stored
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

/// What one fit runs: the model and optimiser config, the scene box, the segmentation loss,
/// the schedule and the seed.
pub struct FitPlan {
    pub cfg: TrainConfig,
    pub scene_box: SceneBox,
    pub mode: SegMode,
    pub epochs: usize,
    pub batch: usize,
    pub seed: u64,
}

/// Runs `epochs` epochs of shuffled batches (a new permutation every epoch) from a fresh model.
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
        epochs,
        batch,
        seed,
    } = plan;
    let mut tr = Trainer::new(cfg, scene_box, device, seed);
    let mut rng = Rng::new(seed, 0x7a1);
    let mut order: Vec<u32> = (0..store.len() as u32).collect();
    let steps_per_epoch = store.len().div_ceil(batch);
    let pb = progress_bar((epochs * steps_per_epoch) as u64, "train", show_progress);
    let mut log = TrainLog::default();
    for _ in 0..epochs {
        rng.shuffle(&mut order);
        let mut sum = LossParts::default();
        for chunk in order.chunks(batch) {
            let l = tr.step(&store.batch(chunk), mode);
            log.step_total.push(l.total);
            sum.total += l.total;
            sum.color += l.color;
            sum.emission += l.emission;
            sum.diffuse += l.diffuse;
            sum.seg += l.seg;
            pb.set_message(format!("loss {:.4}", l.total));
            pb.inc(1);
        }
        let n = steps_per_epoch.max(1) as f32;
        log.epochs.push(LossParts {
            total: sum.total / n,
            color: sum.color / n,
            emission: sum.emission / n,
            diffuse: sum.diffuse / n,
            seg: sum.seg / n,
        });
    }
    pb.finish_and_clear();
    (tr, log)
}
