//! The patch hypothesis's pixels: every segment's pixels (all of them, not the check's sample)
//! grouped into cubes, and its profile over σ with the base colour solved per cube
//! (`pipeline::patches`).
//!
//! Owns: which pixels a segment's patch profile reads, and its best σ. Must not touch: the
//! per-cube solve (`patches`), the hop's decision.

use super::evaluate::profile_min;
use crate::pipeline::landscape::sweep;
use crate::pipeline::patches::{self, PatchPixel};
use crate::pipeline::pixels::PixelStore;
use fipt_core::model::FiptModel;
use fipt_core::shading::ShadingLayout;
use std::collections::BTreeMap;

/// (`SegmentObjective::patch`).
pub(super) type PatchBest = (f64, f64, f64);

/// The share of pixels whose cube prefers the best σ, and the effective number of cubes
/// (`SegmentObjective::patch_share`).
pub(super) type PatchShare = (f64, f64);

/// Every segment's pixels (all of them, not the check's sample) grouped into cubes for the
/// patch hypothesis (`patches`).
pub(super) struct PatchSegments<'a> {
    store: &'a PixelStore,
    /// Per segment id: its entries in the store and their cubes (indices into the entries).
    segments: BTreeMap<i32, (Vec<u32>, Vec<Vec<u32>>)>,
}

impl<'a> PatchSegments<'a> {
    pub(super) fn new(store: &'a PixelStore, side: f32) -> Self {
        let mut by: BTreeMap<i32, Vec<u32>> = BTreeMap::new();
        let b = &store.pixels;
        for (i, &s) in b.seg.iter().enumerate() {
            // Clipped LDR pixels only bound the photo: no colour solve takes them.
            let clipped = !b.cap.is_empty()
                && b.cap[3 * i..3 * i + 3]
                    .iter()
                    .any(|&c| c < fipt_core::model::step::CAP_NONE);
            if !clipped {
                by.entry(s).or_default().push(i as u32);
            }
        }
        let segments = by
            .into_iter()
            .map(|(id, idx)| {
                let pos: Vec<[f32; 3]> = idx.iter().map(|&i| b.x_world[i as usize]).collect();
                (id, (idx, patches::cubes(&pos, side.max(1e-6))))
            })
            .collect();
        Self { store, segments }
    }

    /// Calls `f` with segment `id`'s pixels as a dielectric (m = 0: the hypothesis is a
    /// dielectric of one σ), or as a metal (m = 1) where `metal`, under the model's mask, their
    /// cubes and the model's mean σ over them; None for a segment without pixels.
    pub(super) fn with_pixels<R>(
        &self,
        model: &FiptModel,
        id: i32,
        metal: bool,
        f: impl FnOnce(&[PatchPixel], &[Vec<u32>], f32) -> R,
    ) -> Option<R> {
        let (idx, cubes) = self.segments.get(&id)?;
        let b = self.store.batch(idx);
        let mat = model.material(&b.x_unit, &b.part);
        let alpha = model.alpha(&b.x_world);
        let pixels: Vec<PatchPixel> = (0..idx.len())
            .map(|i| PatchPixel {
                shading: ShadingLayout::pixel(&b.shadings, i),
                gt: [b.gt[3 * i], b.gt[3 * i + 1], b.gt[3 * i + 2]],
                metallic: if metal { 1.0 } else { 0.0 },
                alpha: alpha[i],
            })
            .collect();
        let n = idx.len().max(1) as f64;
        let mean = (mat.sigma.iter().map(|&s| s as f64).sum::<f64>() / n) as f32;
        Some(f(&pixels, cubes, mean))
    }

    /// The segment's best swept σ, the patch objective there, and at the model's mean σ; and
    /// how many of its cubes prefer that best σ to the mean σ (`patches::preference`).
    pub(super) fn profile(
        &self,
        model: &FiptModel,
        id: i32,
        metal: bool,
    ) -> Option<(PatchBest, PatchShare)> {
        use patches::{objective, per_cube, preference};
        self.with_pixels(model, id, metal, |pixels, cubes, mean| {
            let n = pixels.len().max(1) as f64;
            let per = |s: f32| per_cube(pixels, cubes, &move |_| s);
            let swept: Vec<f64> = sweep()
                .iter()
                .map(|&s| objective(pixels, cubes, &move |_| s) / n)
                .collect();
            let (best_sigma, best) = profile_min(&swept);
            let at_mean = per(mean);
            let share = preference(cubes, &per(best_sigma as f32), &at_mean);
            ((best_sigma, best, at_mean.iter().sum::<f64>() / n), share)
        })
    }

    /// The patch objective (mean per pixel) at the model's mean σ (NaN for a segment without
    /// pixels).
    pub(super) fn at_model(&self, model: &FiptModel, id: i32, metal: bool) -> f64 {
        self.with_pixels(model, id, metal, |pixels, cubes, mean| {
            patches::objective(pixels, cubes, &move |_| mean) / pixels.len().max(1) as f64
        })
        .unwrap_or(f64::NAN)
    }
}
