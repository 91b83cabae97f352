//! Stage 2 driver (paper §4.4–4.5): gathers every training pixel with a first hit into plain
//! arrays, then runs epochs of shuffled 8192-pixel batches through `Trainer::step`.
//!
//! Owns: the pixel store, shuffling, logging and progress. Must not touch: the model maths.

use crate::stage1::{Baked, progress_bar};
use fipt_bake::bake::SHADING_DIM;
use fipt_bake::lightfield::SceneBox;
use fipt_bake::raycast::ViewHits;
use fipt_core::brdf::{factorised_render, reflectances};
use fipt_core::model::step::SegMode;
use fipt_core::model::{Batch, LossParts, TrainConfig, Trainer};
use fipt_core::rng::Rng;
use fipt_core::scene::{MapKind, Split};

/// Every training pixel whose pixel-centre ray hit the mesh, as one big `Batch`.
pub struct PixelStore {
    pub pixels: Batch,
    /// (view, pixel) of each entry.
    pub origin: Vec<(u32, u32)>,
}

/// Which label map feeds the segmentation loss.
pub fn seg_map(mode: SegMode) -> Option<MapKind> {
    match mode {
        SegMode::Part => Some(MapKind::IndexMA),
        SegMode::Semantic => Some(MapKind::Segmentation),
        SegMode::None => None,
    }
}

impl PixelStore {
    pub fn gather(train: &Split, baked: &Baked, sb: &SceneBox, mode: SegMode) -> Self {
        let mut b = Batch::default();
        let mut origin = Vec::new();
        let labels: Vec<Option<Vec<i32>>> = train
            .views
            .iter()
            .map(|v| seg_map(mode).and_then(|k| v.labels(k)))
            .collect();
        for (k, (v, h)) in train.views.iter().zip(&baked.hits).enumerate() {
            let s = &baked.shadings[k];
            for p in 0..h.num_pixels() {
                if h.tri[p] < 0 {
                    continue;
                }
                let x = h.position[p];
                b.x_unit.push(sb.to_unit(x).to_array());
                b.x_world.push(x.to_array());
                b.shadings
                    .extend_from_slice(&s[p * SHADING_DIM..(p + 1) * SHADING_DIM]);
                b.gt.extend_from_slice(&v.image.data[3 * p..3 * p + 3]);
                b.seg.push(labels[k].as_ref().map_or(0, |l| l[p]));
                origin.push((k as u32, p as u32));
            }
        }
        Self { pixels: b, origin }
    }

    pub fn len(&self) -> usize {
        self.origin.len()
    }

    pub fn is_empty(&self) -> bool {
        self.origin.is_empty()
    }

    /// The batch of the given entries.
    pub fn batch(&self, idx: &[u32]) -> Batch {
        let b = &self.pixels;
        let mut out = Batch {
            x_unit: Vec::with_capacity(idx.len()),
            x_world: Vec::with_capacity(idx.len()),
            shadings: Vec::with_capacity(idx.len() * SHADING_DIM),
            gt: Vec::with_capacity(idx.len() * 3),
            seg: Vec::with_capacity(idx.len()),
        };
        for &i in idx {
            let i = i as usize;
            out.x_unit.push(b.x_unit[i]);
            out.x_world.push(b.x_world[i]);
            out.shadings
                .extend_from_slice(&b.shadings[i * SHADING_DIM..(i + 1) * SHADING_DIM]);
            out.gt.extend_from_slice(&b.gt[3 * i..3 * i + 3]);
            out.seg.push(b.seg[i]);
        }
        out
    }
}

/// The median pixel footprint of the training views in unit-cube units: over every hit, the
/// hit distance times the angle one pixel subtends (1/f_x), divided by the scene box's side.
pub fn pixel_footprint(train: &Split, hits: &[ViewHits], sb: &SceneBox) -> f64 {
    let mut f: Vec<f32> = train
        .views
        .iter()
        .zip(hits)
        .flat_map(|(v, h)| {
            let k = (1.0 / v.camera.fx) as f32;
            h.t.iter()
                .zip(&h.tri)
                .filter(|(_, tri)| **tri >= 0)
                .map(move |(t, _)| t * k)
        })
        .collect();
    if f.is_empty() {
        return 1.0;
    }
    let mid = f.len() / 2;
    let (_, m, _) = f.select_nth_unstable_by(mid, f32::total_cmp);
    *m as f64 / (sb.max - sb.min) as f64
}

/// The reflected radiance the trained BRDF predicts from the baked shadings at every stored
/// pixel, scattered back into per-view images (3 floats per pixel, zeros at misses).
pub fn reflected(tr: &Trainer, store: &PixelStore, pixels_per_view: &[usize]) -> Vec<Vec<f32>> {
    let mat = tr.material(&store.pixels.x_unit);
    let mut out: Vec<Vec<f32>> = pixels_per_view.iter().map(|&n| vec![0.0; 3 * n]).collect();
    for (i, &(k, p)) in store.origin.iter().enumerate() {
        let a = glam::Vec3::from_slice(&mat.a[3 * i..3 * i + 3]);
        let (kd, ks) = reflectances(a, mat.metallic[i]);
        let sh = &store.pixels.shadings[i * SHADING_DIM..(i + 1) * SHADING_DIM];
        let c = factorised_render(kd.to_array(), ks.to_array(), mat.sigma[i], sh);
        out[k as usize][3 * p as usize..3 * p as usize + 3].copy_from_slice(&c);
    }
    out
}

/// Loss log of a training run: the mean of each part per epoch, and every step's total.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct TrainLog {
    pub epochs: Vec<LossParts>,
    pub step_total: Vec<f32>,
}

/// Runs `epochs` epochs of shuffled batches (a new permutation every epoch).
#[allow(clippy::too_many_arguments)]
pub fn train(
    store: &PixelStore,
    cfg: TrainConfig,
    device: &burn::tensor::Device,
    mode: SegMode,
    epochs: usize,
    batch: usize,
    seed: u64,
    show_progress: bool,
) -> (Trainer, TrainLog) {
    let mut tr = Trainer::new(cfg, device, seed);
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
