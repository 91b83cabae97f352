//! `bench render`: paths and rays per second of the path tracer on a scene's true materials.
//!
//! Owns: that benchmark. Must not touch: the path tracer.

use super::median;
use anyhow::Result;
use serde_json::json;
use std::path::Path;

/// `bench render`: paths and rays per second of the path tracer on a scene's true materials and
/// emitters (`render --truth`), 1 and 2 threads: `views` val views (train where there is no
/// val split) at `spp` samples per pixel, max depth 7, power-weighted light selection.
pub fn render(scene: &Path, as_json: bool, spp: usize, views: usize, reps: usize) -> Result<()> {
    use crate::rerender::{RenderJob, render};
    use fipt_bake::emitters::LightSelection;
    use fipt_bake::integrators::path::PathConfig;
    let out = std::env::temp_dir().join(format!("fipt-bench-render-{}", std::process::id()));
    let has_val = scene.join("val").is_dir();
    let job = RenderJob {
        scene: Some(scene.to_path_buf()),
        out: out.clone(),
        source: crate::rerender::Source::Truth,
        insert: None,
        cache: false,
        material_cache: false,
        off_reflect: false,
        split: if has_val { "val" } else { "train" }.into(),
        views: (0..views).collect(),
        cameras: None,
        relight: None,
        selection: LightSelection::Power,
        path: PathConfig {
            spp,
            ..Default::default()
        },
        quiet: true,
        backend: fipt_core::model::BackendKind::Flex,
    };
    let mut rows = Vec::new();
    for threads in [1usize, 2] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()?;
        let runs = pool.install(|| (0..reps).map(|_| render(&job)).collect::<Result<Vec<_>>>())?;
        let pick = |f: &dyn Fn(&crate::rerender::RenderReport) -> f64| {
            median(runs.iter().map(f).collect())
        };
        let (paths, rays) = (pick(&|r| r.paths_per_s), pick(&|r| r.rays_per_s));
        if !as_json {
            println!(
                "render {threads} thread(s): {:.3} M paths/s, {:.2} M rays/s ({} paths per run, median of {reps})",
                paths / 1e6,
                rays / 1e6,
                runs[0].stats.paths
            );
        }
        rows.push(
            json!({"threads": threads, "paths_per_s": paths, "rays_per_s": rays,
            "paths": runs[0].stats.paths, "rays": runs[0].stats.rays + runs[0].stats.shadow_rays,
            "wall_s": runs.iter().map(|r| r.wall_s).collect::<Vec<_>>()}),
        );
    }
    let _ = std::fs::remove_dir_all(&out);
    if as_json {
        let r = json!({"bench": "render", "scene": scene.display().to_string(), "spp": spp,
            "views": views, "max_depth": 7, "results": rows});
        println!("{}", serde_json::to_string_pretty(&r)?);
    }
    Ok(())
}
