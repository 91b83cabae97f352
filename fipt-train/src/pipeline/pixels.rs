//! The stage-2 pixel store (paper §4.5): every training pixel with a first hit, as plain arrays
//! of unit-cube and world positions, packed shadings, photo values and segment ids; batches are
//! gathered from it by index.
//!
//! Owns: the store, the segmentation map choice, the pixel footprint. Must not touch: training.

use super::bake::Baked;
use fipt_bake::ViewHits;
use fipt_core::model::Batch;
use fipt_core::model::step::CAP_NONE;
use fipt_core::model::step::SegMode;
use fipt_core::scene::{MapKind, SceneBox, Split};
use fipt_core::shading::ShadingLayout;

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
                b.shadings.extend_from_slice(ShadingLayout::pixel(s, p));
                b.gt.extend_from_slice(&v.image.data[3 * p..3 * p + 3]);
                b.seg.push(labels[k].as_ref().map_or(0, |l| l[p]));
                if let Some(f) = &v.ldr {
                    for c in 0..3 {
                        b.cap.push(if f.clipped(p, c) && !f.is_filled(p) {
                            v.image.data[3 * p + c]
                        } else {
                            CAP_NONE
                        });
                    }
                }
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

    /// Replaces every entry's shadings by those of its (view, pixel) in `per_view`
    /// (`ShadingLayout::DIM` values per pixel, per view), e.g. after a refinement.
    pub fn set_shadings(&mut self, per_view: &[Vec<f32>]) {
        let d = ShadingLayout::DIM;
        for (i, &(k, p)) in self.origin.iter().enumerate() {
            self.pixels.shadings[i * d..(i + 1) * d]
                .copy_from_slice(ShadingLayout::pixel(&per_view[k as usize], p as usize));
        }
    }

    /// The batch of the given entries.
    pub fn batch(&self, idx: &[u32]) -> Batch {
        let b = &self.pixels;
        let mut out = Batch {
            x_unit: Vec::with_capacity(idx.len()),
            x_world: Vec::with_capacity(idx.len()),
            shadings: Vec::with_capacity(idx.len() * ShadingLayout::DIM),
            gt: Vec::with_capacity(idx.len() * 3),
            seg: Vec::with_capacity(idx.len()),
            cap: Vec::new(),
        };
        for &i in idx {
            let i = i as usize;
            out.x_unit.push(b.x_unit[i]);
            out.x_world.push(b.x_world[i]);
            out.shadings
                .extend_from_slice(ShadingLayout::pixel(&b.shadings, i));
            out.gt.extend_from_slice(&b.gt[3 * i..3 * i + 3]);
            out.seg.push(b.seg[i]);
            if !b.cap.is_empty() {
                out.cap.extend_from_slice(&b.cap[3 * i..3 * i + 3]);
            }
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
