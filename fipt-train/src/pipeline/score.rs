//! Scoring predicted maps against a scene's ground truth: a run's train maps as it goes, the
//! maps a finished run saved (`eval`), and a saved scene model's maps predicted afresh
//! (`eval_model`).
//!
//! Owns: the `eval` outputs (`out/eval.json`). Must not touch: the per-pixel scores
//! (`evaluate`), the prediction (`predict`).

use super::bake::cast_split;
use super::context::load_opts;
use super::evaluate::{self, Metrics, PartRow};
use super::predict::{ViewMaps, predict_views};
use super::report::EvalReport;
use crate::config::Config;
use crate::output::write_json;
use anyhow::{Context, Result};
use fipt_bake::{Accel, ViewHits, emitters};
use fipt_core::scene::Dataset;
use std::path::Path;

/// Scores the train maps and builds the per-part table.
pub fn score(
    ds: &Dataset,
    train_hits: &[ViewHits],
    maps: &[ViewMaps],
) -> (Metrics, Option<Vec<PartRow>>) {
    let per_view = ds
        .train
        .views
        .iter()
        .zip(maps)
        .map(|(v, m)| evaluate::score_view(v, m))
        .collect();
    let parts = ds.meta.as_ref().map(|meta| {
        evaluate::part_table(
            meta,
            ds.mesh.num_triangles(),
            &ds.train.views,
            train_hits,
            maps,
        )
    });
    (evaluate::summarize(per_view), parts)
}

/// Scores a scene model (`scene_model`) against a scene's ground truth: its train maps
/// predicted afresh (as `run` does, with the model's own config) into `out/eval.json`. What
/// `run` scored from its in-memory model, from the saved model instead.
pub fn eval_model(scene: &Path, model_dir: &Path, out: &Path) -> Result<EvalReport> {
    let device = burn::tensor::Device::flex();
    let sm = crate::scene_model::SceneModel::load(model_dir, &device)?;
    let cfg = Config::load(&model_dir.join("config.json"))?;
    let ds = Dataset::load(scene, &load_opts())?;
    if crate::scene_model::mesh_hash(&ds.mesh) != sm.manifest.mesh_hash {
        anyhow::bail!(
            "{}: the scene's mesh differs from the model's ({})",
            scene.display(),
            model_dir.display()
        );
    }
    let accel = Accel::build(&ds.mesh);
    let hits = cast_split(&accel, &ds.mesh, &ds.train);
    let emission = emitters::radiance_per_triangle(ds.mesh.num_triangles(), &sm.emitters);
    let maps = predict_views(&sm.model, &hits, &emission, &cfg);
    write_eval(&ds, &hits, &maps, out)
}

/// Recomputes the metrics from `out/maps/train` (written by `run`) into `out/eval.json`.
pub fn eval(scene: &Path, out: &Path) -> Result<EvalReport> {
    let ds = Dataset::load(scene, &load_opts())?;
    let accel = Accel::build(&ds.mesh);
    let maps = read_train_maps(&ds, out)?;
    let hits = cast_split(&accel, &ds.mesh, &ds.train);
    write_eval(&ds, &hits, &maps, out)
}

/// Scores `maps` into `out/eval.json`.
fn write_eval(
    ds: &Dataset,
    hits: &[ViewHits],
    maps: &[ViewMaps],
    out: &Path,
) -> Result<EvalReport> {
    let (metrics, parts) = score(ds, hits, maps);
    let r = EvalReport { metrics, parts };
    write_json(&out.join("eval.json"), &r)?;
    Ok(r)
}

/// The train views' maps a `run` saved in `out/maps/train`, checked against the scene's sizes.
pub fn read_train_maps(ds: &Dataset, out: &Path) -> Result<Vec<ViewMaps>> {
    let dir = out.join("maps").join("train");
    let maps: Vec<ViewMaps> = (0..ds.train.views.len())
        .map(|k| ViewMaps::read(&dir, k))
        .collect::<Result<_>>()
        .with_context(|| {
            format!(
                "{}: predicted maps missing or unreadable (run `fipt-train run` first)",
                dir.display()
            )
        })?;
    for (k, (m, v)) in maps.iter().zip(&ds.train.views).enumerate() {
        if (m.width, m.height) != (v.image.width, v.image.height) {
            anyhow::bail!(
                "{}: the maps of view {k} are {}x{}, the scene's images {}x{}",
                dir.display(),
                m.width,
                m.height,
                v.image.width,
                v.image.height
            );
        }
    }
    Ok(maps)
}
