//! Stage 1 driver: ray cast the training views, build L′, bake and filter the shadings.
//!
//! Owns: the glue between the dataset and fipt-bake, progress display. Must not touch: the
//! estimators (fipt-bake) or file formats (`cache`).

use fipt_bake::bake::{BakeConfig, BakeView, bake_views, build_light_field};
use fipt_bake::lightfield::LightField;
use fipt_bake::{Accel, ViewHits, cast_view};
use fipt_core::scene::Split;
use indicatif::{ProgressBar, ProgressStyle};

/// The products of stage 1 for one split.
pub struct Baked {
    pub hits: Vec<ViewHits>,
    pub light_field: LightField,
    /// `SHADING_DIM` values per pixel, per view.
    pub shadings: Vec<Vec<f32>>,
}

/// Casts every pixel-centre ray of a split.
pub fn cast_split(accel: &Accel, mesh: &fipt_core::scene::Mesh, split: &Split) -> Vec<ViewHits> {
    split
        .views
        .iter()
        .map(|v| cast_view(accel, mesh, &v.camera))
        .collect()
}

/// A progress bar (hidden when `show` is false).
pub fn progress_bar(len: u64, msg: &str, show: bool) -> ProgressBar {
    if !show {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::new(len);
    pb.set_style(
        ProgressStyle::with_template(
            "{msg:>12} [{bar:40}] {pos}/{len} {elapsed_precise} eta {eta}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    pb.set_message(msg.to_string());
    pb
}

/// Runs stage 1 on the training split.
pub fn bake(
    accel: &Accel,
    mesh: &fipt_core::scene::Mesh,
    train: &Split,
    cfg: &BakeConfig,
    show_progress: bool,
) -> Baked {
    let hits = cast_split(accel, mesh, train);
    let views: Vec<BakeView> = train
        .views
        .iter()
        .zip(&hits)
        .map(|(v, h)| BakeView {
            hits: h,
            image: &v.image.data,
            focal: v.camera.fx as f32,
        })
        .collect();
    let light_field = build_light_field(&views, cfg.voxel_res);
    let pb = progress_bar(views.len() as u64, "bake", show_progress);
    let shadings = bake_views(accel, &light_field, &views, cfg, &|_| pb.inc(1));
    pb.finish_and_clear();
    drop(views);
    Baked {
        hits,
        light_field,
        shadings,
    }
}
