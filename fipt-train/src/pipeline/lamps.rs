//! LDR photos only, before the bake: the camera response and the HDR radiance of the clipped
//! lamps, the photos linearised with the one and filled with the other. An LDR photo records a
//! lamp only as its clip level, so L′ and every shading baked from it would see the lamps far
//! too dim, and every base colour they light far too bright. This stage fits a first model on
//! the clipped photos (round 0's fit, without its hop) for its emission mask and its rough
//! surfaces, extracts the emitters, solves the clipped lamps' radiance from the unclipped
//! pixels they light (`crate::ldr::lights`; with `ldr.estimate_response`, together with the
//! response, `crate::ldr::response`, and the photos are then linearised anew with it), and
//! writes the radiance into the clipped channels of the lamps' pixels. From there the run is an
//! HDR run (IRIS re-bakes its shadings with the learned emitter radiance likewise), except that
//! round 0's emitters are solved once more (`extract::solve_clipped_lamps`): the photos' full
//! lamps now show in the mask, faces no photo saw included, which the first solve lacked and
//! made up for in brightness. That solve reads L′ rebuilt without the lamps' pixels and with
//! the clipped surfaces raised to round 0's render (`ldr.solve_without_emitters`,
//! `ldr.fill_clipped_surfaces`).
//!
//! The solve is cached in `OUT/cache/lamps.json`, keyed by the clipped photos' bake key, the
//! config and the program, so a resumed run skips it.
//!
//! Owns: the stage's order and its cache. Must not touch: the solve, the fit.

use super::bake;
use super::context::RunContext;
use super::extract;
use super::fit::{self, FitPlan};
use super::rounds::FitSetup;
use crate::ldr::lights::LightSolve;
use anyhow::Result;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;

#[derive(Serialize, Deserialize)]
struct Cached {
    key: String,
    solve: LightSolve,
}

fn key(ctx: &RunContext) -> Result<String> {
    let mut h = fipt_core::io::Fnv64::default();
    h.bytes(&ctx.bake_key.to_le_bytes());
    h.bytes(serde_json::to_string(ctx.cfg)?.as_bytes());
    h.bytes(&super::checkpoint::program_hash().to_le_bytes());
    Ok(format!("{:016x}", h.finish()))
}

/// Solves the clipped lamps (or reads the solve from the cache), fills their pixels in the
/// train photos and re-keys the bake.
pub fn fill_clipped_lamps(ctx: &mut RunContext) -> Result<()> {
    let path = ctx.out.join("cache").join("lamps.json");
    let key = key(ctx)?;
    let cached: Option<Cached> = std::fs::read_to_string(&path)
        .ok()
        .and_then(|t| serde_json::from_str(&t).ok())
        .filter(|c: &Cached| c.key == key);
    let mut solve = match cached {
        Some(c) => c.solve,
        None => {
            let solve = solve(ctx)?;
            crate::output::write_json(
                &path,
                &Cached {
                    key,
                    solve: solve.clone(),
                },
            )?;
            solve
        }
    };
    // The estimated response replaces the sRGB curve: the photos are linearised anew (and
    // estimated exposures estimated anew) before the lamps are filled.
    if let Some(fit) = &solve.response {
        let estimate = ctx.cfg.ldr.estimate_exposure;
        ctx.ldr = Some(crate::ldr::calibrate::calibrate_with(
            &mut ctx.ds,
            &ctx.accel,
            estimate,
            fit.response(),
        ));
    }
    if ctx.cfg.ldr.solve_emitters {
        fill(ctx, &solve);
    } else {
        // Solved for the response only: the lamps keep their clip level, and say so.
        for l in &mut solve.lamps {
            l.solved_clipped = false;
            l.solved = l.extracted;
        }
    }
    ctx.bake_key = crate::cache::cache_key(&ctx.ds, &ctx.bake_cfg)?;
    ctx.light_solve = Some(solve);
    ctx.times.lamps_s = ctx.lap();
    ctx.check("after the lamps' solve")
}

fn solve(ctx: &mut RunContext) -> Result<LightSolve> {
    let (baked, _) = bake::bake_cached(ctx.out, &ctx.ds, &ctx.accel, &ctx.bake_cfg, ctx.progress())
        .map_err(|e| ctx.reword(e, "during the bake of the clipped photos (it restarts)"))?;
    let setup = FitSetup::new(ctx, &baked)?;
    let (store, parts) = setup.gather_store(ctx, &baked);
    let plan = FitPlan {
        cfg: setup.base_cfg(ctx, 0),
        scene_box: setup.scene_box,
        parts,
        mode: setup.mode,
        schedule: ctx.cfg.train_for_round(0),
        seed: ctx.seeds.fit(0, false),
    };
    let (tr, _) = fit::fit(&store, plan, &setup.device, ctx.progress());
    let mut emitters = extract::extract_emitters(
        &ctx.ds.mesh,
        &ctx.ds.train,
        &baked,
        &tr,
        &fit::reflected(&tr, &store, &baked.hits),
        &ctx.cfg.emitters,
        ctx.seeds.base(),
    );
    Ok(extract::solve_clipped_lamps(
        ctx,
        &baked,
        &store,
        &tr,
        &mut emitters,
        ctx.cfg.ldr.estimate_response,
        // The first fit saw the lamps at their clip level: its renders are no fill.
        None,
    ))
}

/// Writes each solved lamp's radiance into the clipped channels of the train pixels that see
/// it (never lowering a value) and marks those pixels filled.
fn fill(ctx: &mut RunContext, solve: &LightSolve) {
    let radiance: HashMap<u32, [f32; 3]> = solve
        .lamps
        .iter()
        .filter(|l| l.solved_clipped)
        .flat_map(|l| l.triangles.iter().map(move |&t| (t, l.solved)))
        .collect();
    if radiance.is_empty() {
        return;
    }
    let hits = bake::cast_split(&ctx.accel, &ctx.ds.mesh, &ctx.ds.train);
    for (v, h) in ctx.ds.train.views.iter_mut().zip(&hits) {
        let Some(f) = v.ldr.as_mut() else { continue };
        f.filled = vec![false; h.num_pixels()];
        for p in 0..h.num_pixels() {
            let Some(r) = u32::try_from(h.tri[p]).ok().and_then(|t| radiance.get(&t)) else {
                continue;
            };
            for (c, &rc) in r.iter().enumerate() {
                if f.clipped(p, c) {
                    let x = &mut v.image.data[3 * p + c];
                    *x = x.max(rc);
                }
            }
            f.filled[p] = true;
        }
    }
}
