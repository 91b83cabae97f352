//! What the stages of a run share: the scene as loaded, its ray-tracing structure, the config
//! and its seeds, the output folder, the stage clock, and the words of an interrupted run.
//!
//! Owns: loading a run's inputs once, the stage times, the interrupt messages. Must not touch:
//! what any stage computes.

use crate::config::{Config, Seeds};
use crate::pipeline::report::StageTimes;
use anyhow::Result;
use fipt_bake::Accel;
use fipt_bake::integrators::bake::BakeConfig;
use fipt_core::scene::{Dataset, LoadOptions, MapKind};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The maps FIPT reads, plus BaseColor and Metallic for the per-part table, and the relit
/// photos.
pub fn load_opts() -> LoadOptions {
    let mut maps = MapKind::FIPT.to_vec();
    maps.extend([MapKind::BaseColor, MapKind::Metallic, MapKind::Relight]);
    LoadOptions { maps, val: true }
}

/// How `run` runs besides its config.
#[derive(Clone, Debug, Default)]
pub struct RunOptions {
    /// No progress bars and no summary.
    pub quiet: bool,
    /// Fit the oracle shadings (see `run_with`).
    pub oracle: bool,
    /// Register the scene model in this zoo folder, under this name.
    pub zoo: Option<(PathBuf, String)>,
}

/// A run's shared inputs and bookkeeping.
pub struct RunContext<'a> {
    pub scene: &'a Path,
    pub out: &'a Path,
    pub cfg: &'a Config,
    pub opts: &'a RunOptions,
    pub seeds: Seeds,
    pub ds: Dataset,
    pub accel: Accel,
    /// The bake's config with the run's seed, and the key of its cached shadings.
    pub bake_cfg: BakeConfig,
    pub bake_key: u64,
    /// LDR photos: the response and exposures they were linearised with, and (after round 0)
    /// the solve of the clipped emitters.
    pub ldr: Option<crate::ldr::Calibration>,
    pub light_solve: Option<crate::ldr::lights::LightSolve>,
    pub times: StageTimes,
    clock: Instant,
    /// OUT's lock, held for the run's life (`crate::lock`).
    _lock: crate::lock::DirLock,
}

impl<'a> RunContext<'a> {
    /// Locks OUT against a second writer, loads the scene and builds its acceleration
    /// structure.
    pub fn load(
        scene: &'a Path,
        out: &'a Path,
        cfg: &'a Config,
        opts: &'a RunOptions,
    ) -> Result<Self> {
        let clock = Instant::now();
        let mut ds = Dataset::load(scene, &load_opts())?;
        let lock = crate::lock::DirLock::acquire(out)?;
        let accel = Accel::build(&ds.mesh);
        if cfg.ldr.jpeg_reconstruct {
            crate::ldr::reconstruct_jpegs(&mut ds, cfg.ldr.jpeg_iterations);
        }
        let ldr = ds.is_ldr().then(|| {
            crate::ldr::calibrate(
                &mut ds,
                &accel,
                cfg.ldr.estimate_exposure,
                crate::ldr::ResponseChoice {
                    edges: cfg.ldr.edge_response && !cfg.ldr.estimate_response,
                    tolerance: cfg.ldr.edge_tolerance,
                },
            )
        });
        let bake_cfg = cfg.bake_config();
        let bake_key = crate::cache::cache_key(&ds, &bake_cfg)?;
        Ok(Self {
            scene,
            out,
            cfg,
            opts,
            seeds: cfg.seeds(),
            ds,
            accel,
            bake_cfg,
            bake_key,
            ldr,
            light_solve: None,
            times: StageTimes::default(),
            clock,
            _lock: lock,
        })
    }

    /// Whether progress bars and summaries show.
    pub fn progress(&self) -> bool {
        !self.opts.quiet
    }

    /// Seconds since the last lap (or the load), restarting the clock.
    pub fn lap(&mut self) -> f64 {
        let s = self.clock.elapsed().as_secs_f64();
        self.clock = Instant::now();
        s
    }

    /// The one-line message of a run stopped by Ctrl-C at a stage boundary.
    pub fn stopped(&self, after: &str) -> String {
        format!(
            "interrupted {after}; what is done is saved in {}: run the same command again to continue",
            self.out.display()
        )
    }

    /// Stops the run here if Ctrl-C asked for it (`after`: where, for the message).
    pub fn check(&self, after: &str) -> Result<()> {
        crate::interrupt::check(|| self.stopped(after))
    }

    /// An error of a stage, reworded when it is an interruption `during` that stage.
    pub fn reword(&self, e: anyhow::Error, during: &str) -> anyhow::Error {
        crate::interrupt::reword(e, || self.stopped(during))
    }
}
