//! Emitter extraction (paper §4.4, Eq. 13): the reflected radiance the fitted BRDF predicts at
//! every training pixel, then the per-triangle α test and median emission of fipt-bake.
//!
//! With LDR photos, the clipped lamps among the emitters have their radiance solved from the
//! pixels they light (`solve_clipped_lamps`, `crate::ldr::lights`).
//!
//! Owns: the glue between the fitted model, the photos and `fipt_bake::emitters`. Must not
//! touch: the extraction rule itself.

use super::bake::Baked;
use super::context::RunContext;
use super::fit::reflected;
use super::pixels::PixelStore;
use crate::config::EmitterSection;
use fipt_bake::emitters::{self, Emitter, ExtractConfig, ObservedView};
use fipt_core::model::Trainer;
use fipt_core::scene::{Mesh, Split};

/// The emitters of the fitted model, from the training photos.
pub fn extract_emitters(
    mesh: &Mesh,
    train: &Split,
    baked: &Baked,
    store: &PixelStore,
    tr: &Trainer,
    cfg: &EmitterSection,
    seed: u64,
) -> Vec<Emitter> {
    // The reflected radiance is only needed for the extraction rule.
    let sizes: Vec<usize> = baked.hits.iter().map(|h| h.num_pixels()).collect();
    let reflected = reflected(tr, store, &sizes);
    let views: Vec<ObservedView> = baked
        .hits
        .iter()
        .zip(&train.views)
        .zip(&reflected)
        .map(|((hits, v), r)| ObservedView {
            hits,
            image: v.image.data.as_slice(),
            reflected: r,
        })
        .collect();
    emitters::extract(
        mesh,
        &mut |p| tr.model.alpha(p),
        &views,
        &ExtractConfig {
            samples_per_triangle: cfg.samples_per_triangle,
            threshold: cfg.threshold,
            min_unexplained: cfg.min_unexplained,
            fill_unseen: cfg.fill_unseen,
            seed,
        },
    )
}

/// LDR photos: the solve of the clipped lamps among `emitters` (their radiance set in place),
/// on the fit `tr` of `store`.
pub fn solve_clipped_lamps(
    ctx: &RunContext,
    baked: &Baked,
    store: &PixelStore,
    tr: &Trainer,
    emitters: &mut [Emitter],
) -> crate::ldr::lights::LightSolve {
    let cal = ctx.ldr.as_ref().expect("LDR photos");
    crate::ldr::lights::solve_clipped(
        &ctx.ds.mesh,
        &ctx.accel,
        &baked.light_field,
        &ctx.ds.train,
        &cal.train_exposures,
        &baked.hits,
        store,
        tr,
        emitters,
        crate::ldr::lights::SolveConfig {
            pixels: ctx.cfg.ldr.solve_pixels,
            light_samples: ctx.cfg.ldr.light_samples,
            seed: ctx.seeds.base(),
        },
    )
}
