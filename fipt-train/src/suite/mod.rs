//! `fipt-train suite`: many rooms drawn at random (`generate`), rendered by fipt's own path
//! tracer into the FIPT synthetic layout (cached per scene), the whole method run on each with
//! one config, one scene after another, and the figures gathered per scene and per part
//! (`report`). Scenes of even seed form the **tuning** half, odd seeds the **held-out** half:
//! defaults are chosen on the first and reported on the second.
//!
//! A killed suite resumes: a scene whose folder is current is not rendered again, a run whose
//! `metrics.json` was written for the scene as it is now, with the same config, by the same
//! program is not run again, and an unfinished run resumes from its checkpoint
//! (`pipeline::run_with`).
//!
//! Owns: the suite's folders (`OUT/scenes/`, `OUT/runs/`) and `OUT/suite.json`. Must not touch:
//! the pipeline's stages.

pub mod generate;
pub mod report;

use crate::config::Config;
use crate::output::write_json;
use crate::pipeline::checkpoint::saved_by_this_program;
use crate::pipeline::report::RunReport;
use crate::pipeline::{RunOptions, run_with};
use anyhow::{Context, Result};
pub use generate::SceneSize;
use report::{SceneRow, SuiteReport};
use std::path::{Path, PathBuf};

/// What a suite runs.
#[derive(Clone, Debug)]
pub struct SuiteJob {
    pub out: PathBuf,
    /// Scene seeds `first_seed .. first_seed + scenes`.
    pub first_seed: u64,
    pub scenes: usize,
    pub size: SceneSize,
    /// The photos' samples per pixel in place of the size's.
    pub spp: Option<usize>,
    pub config: Config,
    pub quiet: bool,
}

/// Which half of the suite a scene seed belongs to.
pub fn half(seed: u64) -> &'static str {
    if seed.is_multiple_of(2) {
        "tuning"
    } else {
        "held-out"
    }
}

/// Renders (or reuses) every scene, runs (or resumes, or reuses) every run, and writes
/// `OUT/suite.json`.
pub fn run_suite(job: &SuiteJob) -> Result<SuiteReport> {
    let Some(end) = job.first_seed.checked_add(job.scenes as u64) else {
        anyhow::bail!(
            "--first-seed {} with --scenes {}: the seeds run past 2^64",
            job.first_seed,
            job.scenes
        );
    };
    let mut rows = Vec::new();
    for seed in job.first_seed..end {
        let scene = scene_folder(&job.out, seed, job.size, job.spp, job.quiet)?;
        let out = job.out.join("runs").join(format!("suite-{seed:03}"));
        let t = std::time::Instant::now();
        let report = run_scene(&scene, &out, &job.config, job.quiet)?;
        let row = SceneRow::new(seed, half(seed), &scene, &report)?;
        if !job.quiet {
            println!(
                "suite scene {seed} ({}): k_d {}, σ {} (constant {}), {:.0} s",
                row.half,
                report::db(row.kd_psnr),
                report::db(row.roughness_psnr),
                report::db(row.constant_roughness_psnr),
                t.elapsed().as_secs_f64()
            );
        }
        rows.push(row);
    }
    let r = SuiteReport::new(job.size, job.spp, rows);
    write_json(&job.out.join("suite.json"), &r)?;
    if !job.quiet {
        r.print();
    }
    Ok(r)
}

/// The folder of suite scene `seed`, rendered (with `spp` samples per pixel in place of the
/// size's, where given) unless it is there and current.
pub fn scene_folder(
    out: &Path,
    seed: u64,
    size: SceneSize,
    spp: Option<usize>,
    quiet: bool,
) -> Result<PathBuf> {
    let dir = out.join("scenes").join(format!("suite-{seed:03}"));
    let mut desc = generate::room(seed, size);
    if let Some(n) = spp {
        desc.spp = n;
    }
    let text = serde_json::to_string_pretty(&desc)?;
    let t = std::time::Instant::now();
    if crate::demo::write_scene_text(&dir, &text, &desc.name, quiet)? && !quiet {
        println!(
            "suite scene {seed} rendered in {:.0} s: {}",
            t.elapsed().as_secs_f64(),
            dir.display()
        );
    }
    Ok(dir)
}

/// The run of one scene: reused when its `metrics.json` was written for the scene as it is now
/// (`same_scene`) with this config by this program (its checkpoint's key names this
/// executable), else run (resuming from its checkpoint when that still holds). No zoo entry.
fn run_scene(scene: &Path, out: &Path, cfg: &Config, quiet: bool) -> Result<RunReport> {
    let metrics = out.join("metrics.json");
    let same_config = Config::load(&out.join("config.json")).is_ok_and(|c| c == *cfg);
    let scene_stamp = crate::demo::scene_stamp(scene);
    if same_scene(scene_stamp.as_deref(), out)
        && same_config
        && saved_by_this_program(out)
        && metrics.is_file()
    {
        let text = fipt_core::io::read_text(&metrics)?;
        if let Ok(r) = serde_json::from_str::<RunReport>(&text) {
            return Ok(r);
        }
    }
    // The scene's stamp is taken away for the run and copied back once it has ended, so a run
    // stopped part-way is never taken for a finished one of this scene.
    let stamp = out.join(SCENE_STAMP);
    match std::fs::remove_file(&stamp) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
            return Err(e).with_context(|| format!("{}: cannot remove", stamp.display()));
        }
        _ => {}
    }
    let opts = RunOptions {
        quiet,
        oracle: false,
        zoo: None,
    };
    let report =
        run_with(scene, out, cfg, &opts).with_context(|| format!("suite run {}", out.display()))?;
    if let Some(s) = scene_stamp {
        fipt_core::io::write_bytes_atomic(&stamp, s.as_bytes())
            .with_context(|| format!("{}: cannot write", stamp.display()))?;
    }
    Ok(report)
}

/// A run folder's copy of the cache stamp of the scene its `metrics.json` was written for.
const SCENE_STAMP: &str = "scene.stamp";

/// Whether the run in `out` ended on the scene whose stamp (`demo::scene_stamp`) is `stamp`: a
/// scene rendered again (another `--spp` or `--size`, another code version) has another stamp.
fn same_scene(stamp: Option<&str>, out: &Path) -> bool {
    let copy = std::fs::read_to_string(out.join(SCENE_STAMP));
    stamp.is_some_and(|s| copy.is_ok_and(|c| c.trim() == s))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_run_is_reused_only_for_the_scene_it_ended_on() {
        let dir = std::env::temp_dir().join(format!("fipt-suite-stamp-{}", std::process::id()));
        let (scene, out) = (dir.join("scene"), dir.join("run"));
        std::fs::create_dir_all(&scene).unwrap();
        std::fs::create_dir_all(&out).unwrap();
        let text = serde_json::to_string(&generate::room(1, SceneSize::Small)).unwrap();
        let mut other = generate::room(1, SceneSize::Small);
        other.spp += 1;
        let other = serde_json::to_string(&other).unwrap();
        let stamp_scene = |t: &str| {
            // The stamp that `demo::write_scene_text` leaves, without rendering the room.
            std::fs::write(scene.join("demo.stamp"), crate::demo::stamp(t)).unwrap();
        };
        let same = |scene: &Path| same_scene(crate::demo::scene_stamp(scene).as_deref(), &out);
        // No scene stamp, no copy: not the same scene.
        assert!(!same(&scene));
        stamp_scene(&text);
        assert!(!same(&scene), "no copy in the run folder");
        std::fs::write(
            out.join(SCENE_STAMP),
            crate::demo::scene_stamp(&scene).unwrap(),
        )
        .unwrap();
        assert!(same(&scene));
        // The same room with other samples per pixel is another scene.
        stamp_scene(&other);
        assert!(!same(&scene), "the photos changed");
        stamp_scene(&text);
        assert!(same(&scene));
        std::fs::remove_file(scene.join("demo.stamp")).unwrap();
        assert!(!same(&scene), "no scene stamp");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
