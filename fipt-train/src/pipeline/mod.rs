//! The FIPT pipeline (paper Fig. 2), one module per role:
//!
//! - `context`: what the stages share (the scene, its accel, the config and seeds, the clock);
//! - `lamps`: LDR photos only, the clipped lamps' radiance solved and filled in first;
//! - `bake`: L′ and the baked shadings (§4.2, Eq. 9), through the shading cache;
//! - `pixels`: the training pixels as one store; `batches`: which pixels each step sees;
//! - `fit`: the material field and emission mask (§4.5, Eq. 12, 15–20); `hop`: a basin hop on
//!   the roughness after each fit (a departure, `train.hop`);
//! - `extract`: emitters from the emission mask (§4.4, Eq. 13);
//! - `refine`: the shadings path-traced with the current estimate (§4.3, Eq. 10–11);
//! - `rounds`: the alternation of fit and refinement, resumable through `checkpoint`;
//! - `predict`: per-view maps of the fitted model; `evaluate`: per-pixel scores; `score`:
//!   scores of a run or a saved model; `outputs`: maps, re-renders, the scene model, reports;
//! - `bake_cmd`, `landscape_cmd`: the `bake` and `landscape` commands (`landscape`: the
//!   per-part loss over σ).
//!
//! Owns: the order of the stages. Must not touch: stage internals, argument parsing.

pub mod bake;
pub mod bake_cmd;
pub mod batches;
pub mod checkpoint;
pub mod context;
pub mod evaluate;
pub mod extract;
pub mod fit;
pub mod hop;
pub mod lamps;
pub mod landscape;
pub mod landscape_cmd;
pub mod outputs;
pub mod patches;
pub mod pixels;
pub mod predict;
pub mod refine;
pub mod report;
pub mod rounds;
pub mod score;
#[cfg(test)]
pub(crate) mod test_data;

use crate::config::Config;
use anyhow::Result;
use context::RunContext;
pub use context::RunOptions;
use report::RunReport;
use std::path::Path;

pub use landscape_cmd::landscapes;
pub use outputs::default_model_name;
pub use score::{eval, eval_model};

/// The whole pipeline; returns the report that is also written to `out/metrics.json`.
pub fn run(scene: &Path, out: &Path, cfg: &Config, quiet: bool) -> Result<RunReport> {
    let opts = RunOptions {
        quiet,
        ..Default::default()
    };
    run_with(scene, out, cfg, &opts)
}

/// `run`, as paper Fig. 2. With `oracle`, round 0 fits the oracle shadings (path-traced with
/// the true materials and emitters, see `refine::oracle`) instead of the baked ones and no
/// refinement follows: the ceiling of the factorised model.
///
/// Resumable: the fits save their state in `OUT/checkpoint` (see `checkpoint`), and a second
/// call with the same scene, config and program continues from there with the same results.
pub fn run_with(scene: &Path, out: &Path, cfg: &Config, opts: &RunOptions) -> Result<RunReport> {
    let mut ctx = RunContext::load(scene, out, cfg, opts)?;
    // LDR photos: the clipped lamps' HDR radiance (and, asked, the response), applied to the
    // photos before the bake.
    if ctx.ldr.is_some() && (cfg.ldr.solve_emitters || cfg.ldr.estimate_response) {
        lamps::fill_clipped_lamps(&mut ctx)?;
    }
    let ck = rounds::open_checkpoints(&ctx)?;
    ctx.times.load_s = ctx.lap();
    crate::output::write_json(&out.join("config.json"), cfg)?;

    // (1) Bake L′ and the shadings (with `oracle`: path-trace them with the true scene).
    let (mut baked, bake_from_cache) = shadings(&mut ctx)?;

    // (2) Fit the material field and the emission mask; (3) extract the emitters; (4) refine
    // the shadings by path tracing with the current estimate and fit again, round by round.
    let (setup, mut fitted) = rounds::run_rounds(&mut ctx, &mut baked, ck)?;

    // (5) Predict and score the maps of every view; re-render and relight the val views.
    let scores = outputs::maps(&mut ctx, &baked, &mut fitted)?;
    let renders = outputs::render_val(&mut ctx, &baked, &fitted)?;

    // What the user keeps: the scene model, metrics.json, the zoo entry, the HTML report.
    let mut report =
        outputs::run_report(&ctx, &setup, bake_from_cache, &mut fitted, scores, renders);
    outputs::save(&ctx, &baked, &fitted, &mut report)?;
    Ok(report)
}

/// Stage (1): the baked shadings (from the shading cache when they are there), or with
/// `oracle` the oracle shadings; and whether the bake came from the cache.
fn shadings(ctx: &mut RunContext) -> Result<(bake::Baked, bool)> {
    let (mut baked, cached) =
        bake::bake_cached(ctx.out, &ctx.ds, &ctx.accel, &ctx.bake_cfg, ctx.progress())
            .map_err(|e| ctx.reword(e, "during the bake (it restarts)"))?;
    if ctx.opts.oracle {
        baked.shadings = refine::oracle_cached(ctx, &baked)
            .map_err(|e| ctx.reword(e, "during the oracle shadings"))?;
    }
    ctx.times.bake_s = ctx.lap();
    ctx.check("after the bake")?;
    Ok((baked, cached))
}
