//! Emitter extraction (paper §4.4, Eq. 13): the reflected radiance the fitted BRDF predicts at
//! every training pixel, then the per-triangle α test and median emission of fipt-bake.
//!
//! With LDR photos, triangles whose pixels are all but always clipped are emitters too
//! (`add_saturated`), and the clipped lamps among the emitters have their radiance solved from
//! the pixels they light (`solve_clipped_lamps`, `crate::ldr::lights`).
//!
//! Owns: the glue between the fitted model, the photos and `fipt_bake::emitters`. Must not
//! touch: the extraction rule itself.

use super::bake::Baked;
use super::context::RunContext;
use super::pixels::PixelStore;
use crate::config::EmitterSection;
use fipt_bake::emitters::{self, Emitter, ExtractConfig, ObservedView};
use fipt_core::model::Trainer;
use fipt_core::scene::{Mesh, Split};

/// The emitters of the fitted model `tr`, from the training photos and the radiance it
/// reflects at every training pixel (`fit::reflected`).
pub fn extract_emitters(
    mesh: &Mesh,
    train: &Split,
    baked: &Baked,
    tr: &Trainer,
    reflected: &[Vec<f32>],
    cfg: &EmitterSection,
    seed: u64,
) -> Vec<Emitter> {
    let views: Vec<ObservedView> = baked
        .hits
        .iter()
        .zip(&train.views)
        .zip(reflected)
        .map(|((hits, v), r)| ObservedView {
            hits,
            image: v.image.data.as_slice(),
            reflected: r,
        })
        .collect();
    let mut found = emitters::extract(
        mesh,
        &mut |p| tr.model.alpha(p),
        &views,
        &ExtractConfig {
            samples_per_triangle: cfg.samples_per_triangle,
            threshold: cfg.threshold,
            min_unexplained: cfg.min_unexplained,
            fill_unseen: cfg.fill_unseen,
            interior: cfg.interior,
            seed,
        },
    );
    if train.is_ldr() {
        add_saturated(mesh, train, &baked.hits, &mut found);
    }
    found
}

/// Fewest photo pixels of a triangle for the saturation rule.
const SATURATED_MIN_PIXELS: u32 = 4;
/// Share of a triangle's photo pixels that must be clipped for the saturation rule.
const SATURATED_SHARE: f64 = 0.9;

/// LDR photos: a triangle whose photo pixels are clipped in at least 90 % of its observations
/// (4 or more, at every exposure the views were taken at) joins the emitters, at its pixels'
/// mean value (its clip level). A lamp's render can reach a low clip level through its base
/// colour, which leaves the emission mask nothing to learn there; saturation alone finds it
/// (IRIS's rule is a mean LDR value above 0.99 per triangle).
fn add_saturated(
    mesh: &Mesh,
    train: &Split,
    hits: &[fipt_bake::ViewHits],
    found: &mut Vec<Emitter>,
) {
    use std::collections::HashMap;
    let known: std::collections::HashSet<u32> = found.iter().map(|e| e.triangle).collect();
    // Per triangle: pixels, clipped pixels, sum of values, pixels seen from the front and back.
    let mut seen: HashMap<u32, (u32, u32, [f64; 3], [u32; 2])> = HashMap::new();
    for (v, h) in train.views.iter().zip(hits) {
        let Some(f) = &v.ldr else { continue };
        for p in 0..h.num_pixels() {
            let Ok(t) = u32::try_from(h.tri[p]) else {
                continue;
            };
            if known.contains(&t) {
                continue;
            }
            let e = seen.entry(t).or_default();
            e.0 += 1;
            e.1 += u32::from(f.pixel_clipped(p));
            for c in 0..3 {
                e.2[c] += v.image.data[3 * p + c] as f64;
            }
            let front = mesh.normal(t as usize).dot(h.direction[p]) < 0.0;
            e.3[usize::from(!front)] += 1;
        }
    }
    let mut add: Vec<(u32, Emitter)> = seen
        .into_iter()
        .filter(|(_, s)| s.0 >= SATURATED_MIN_PIXELS && s.1 as f64 >= SATURATED_SHARE * s.0 as f64)
        .map(|(t, s)| {
            let radiance = s.2.map(|x| (x / s.0 as f64) as f32);
            let e = Emitter {
                pixels: s.0,
                seen_front: s.3[0],
                seen_back: s.3[1],
                ..Emitter::on_triangle(mesh, t as usize, radiance)
            };
            (t, e)
        })
        .collect();
    add.sort_by_key(|(t, _)| *t);
    found.extend(add.into_iter().map(|(_, e)| e));
}

/// LDR photos: the solve of the clipped lamps among `emitters` (their radiance set in place),
/// on the fit `tr` of `store`. After round 0, `round0` holds the radiance that fit reflects at
/// every training pixel (`fit::reflected`), and the solve reads L′ as `solve_light_field`
/// rebuilds it where `ldr.fill_clipped_surfaces` or `ldr.solve_without_emitters` asks; the
/// solve before the bake (None) reads the bake's.
pub fn solve_clipped_lamps(
    ctx: &RunContext,
    baked: &Baked,
    store: &PixelStore,
    tr: &Trainer,
    emitters: &mut [Emitter],
    estimate_response: bool,
    round0: Option<&[Vec<f32>]>,
) -> crate::ldr::lights::LightSolve {
    let cal = ctx.ldr.as_ref().expect("LDR photos");
    let fill = round0.filter(|_| ctx.cfg.ldr.fill_clipped_surfaces);
    let without = round0.is_some() && ctx.cfg.ldr.solve_without_emitters;
    let rebuilt =
        (fill.is_some() || without).then(|| solve_light_field(ctx, baked, emitters, fill, without));
    let light_field = rebuilt.as_ref().map_or(&baked.light_field, |(lf, _)| lf);
    let mut solve = crate::ldr::lights::solve_clipped(
        &ctx.ds.mesh,
        &ctx.accel,
        light_field,
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
            estimate_response,
            exposures_estimated: cal.exposure_source
                == crate::ldr::calibrate::ExposureSource::Estimated,
            instruments: ctx.cfg.ldr.solve_instruments,
        },
    );
    solve.surface_pixels_filled = rebuilt.filter(|_| fill.is_some()).map(|(_, n)| n);
    solve
}

/// L′ for the solve after round 0. With `fill` (round 0's reflected radiance per training
/// pixel): every clipped channel of a surface pixel (one on no emitter and not filled with a
/// lamp's radiance) raised to that render, where it is more. A clipped channel records only
/// its clip level, so L′ lacks the light of every surface brighter than that (a red cabinet
/// next to a warm lamp, in its red), and the solve, which reads the light from everything but
/// the lamps off L′, would give what is missing to the lamps that light the same pixels. With `without`: the pixels on
/// and within `refine.paths.cache_margin` of an emitter left out, as in the refinement's L′
/// (`Rounds::rebuild_cache`), so that no voxel or filled hole next to a lamp holds its
/// radiance. Returns L′ and the number of pixels raised.
fn solve_light_field(
    ctx: &RunContext,
    baked: &Baked,
    emitters: &[Emitter],
    fill: Option<&[Vec<f32>]>,
    without: bool,
) -> (fipt_bake::lightfield::LightField, usize) {
    let emitter_tris: std::collections::HashSet<u32> =
        emitters.iter().map(|e| e.triangle).collect();
    let on_emitter = |t: i32| u32::try_from(t).is_ok_and(|t| emitter_tris.contains(&t));
    let left_out = if without {
        super::pixels::on_or_near_emitters(
            &baked.hits,
            on_emitter,
            ctx.cfg.refine.paths.cache_margin,
        )
    } else {
        Vec::new()
    };
    let left = |k: usize, p: usize| left_out.get(k).is_some_and(|v| v[p]);
    let raised = std::sync::atomic::AtomicUsize::new(0);
    let views = &ctx.ds.train.views;
    let replace = |k: usize, p: usize| {
        let pred = fill?;
        let f = views[k].ldr.as_ref()?;
        if f.is_filled(p) || on_emitter(baked.hits[k].tri[p]) || left(k, p) {
            return None;
        }
        let photo: [f32; 3] = std::array::from_fn(|c| views[k].image.data[3 * p + c]);
        let render: [f32; 3] = std::array::from_fn(|c| pred[k][3 * p + c]);
        let x = raise_clipped(photo, std::array::from_fn(|c| f.clipped(p, c)), render)?;
        raised.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        Some(x)
    };
    let lf = super::bake::light_field_replacing(&ctx.ds, baked, &ctx.bake_cfg, replace, &left);
    (lf, raised.into_inner())
}

/// A surface pixel's photo value with each clipped channel raised to the render where that is
/// more (a clipped channel reads its clip level, a lower bound); None where nothing rises.
fn raise_clipped(photo: [f32; 3], clipped: [bool; 3], render: [f32; 3]) -> Option<[f32; 3]> {
    let x: [f32; 3] = std::array::from_fn(|c| {
        if clipped[c] {
            photo[c].max(render[c])
        } else {
            photo[c]
        }
    });
    (x != photo).then_some(x)
}

#[cfg(test)]
mod tests {
    use super::raise_clipped;
    use proptest::prelude::*;

    proptest! {
        /// Only clipped channels move, never down, and only to the render.
        #[test]
        fn only_clipped_channels_rise_to_the_render(
            photo in prop::array::uniform3(0.0f32..4.0),
            clipped in prop::array::uniform3(any::<bool>()),
            render in prop::array::uniform3(0.0f32..8.0),
        ) {
            match raise_clipped(photo, clipped, render) {
                None => {
                    for c in 0..3 {
                        prop_assert!(!clipped[c] || render[c] <= photo[c]);
                    }
                }
                Some(x) => {
                    prop_assert!(x != photo);
                    for c in 0..3 {
                        if clipped[c] {
                            prop_assert_eq!(x[c], photo[c].max(render[c]));
                        } else {
                            prop_assert_eq!(x[c], photo[c]);
                        }
                    }
                }
            }
        }
    }
}
