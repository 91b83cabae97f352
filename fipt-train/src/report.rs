//! The typed reports of the pipeline commands (`bake.json`, `metrics.json`, `eval.json`),
//! serialised with serde so a renamed field is a compile error, not a silent 0, and their
//! human-readable summaries.
//!
//! Owns: report types and printing. Must not touch: how the figures are computed.

use crate::metrics::GtRenderPsnr;
use crate::pipeline::evaluate::{Metrics, PartRow};
use crate::pipeline::fit::TrainLog;
use fipt_bake::integrators::bake::BakeConfig;
use fipt_core::model::step::{SegMode, StepProfile};
use serde::{Deserialize, Serialize};

/// L′ as built for the bake.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct LightFieldReport {
    pub res: usize,
    pub occupied_voxels: usize,
    pub filled_voxels: usize,
    pub memory_mb: f64,
}

/// The factorised render with ground-truth materials against the photos, over the train views.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct GtRenderSummary {
    pub mean_all_db: f64,
    pub mean_diffuse_db: Option<f64>,
    pub mean_specular_db: Option<f64>,
    pub worst_view: usize,
    pub worst_view_db: f64,
    pub per_view: Vec<GtRenderPsnr>,
}

/// `bake.json`.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct BakeReport {
    pub scene: String,
    pub views: usize,
    pub from_cache: bool,
    pub bake_s: f64,
    pub total_s: f64,
    /// Secondary rays cast by the bake (None when it came from the cache).
    pub secondary_rays: Option<u64>,
    pub rays_per_s: Option<f64>,
    pub light_field: LightFieldReport,
    pub peak_rss_mb: Option<f64>,
    pub gt_render_psnr: Option<GtRenderSummary>,
    pub config: BakeConfig,
}

impl BakeReport {
    pub fn print(&self) {
        let rays = match (self.secondary_rays, self.rays_per_s) {
            (Some(r), Some(s)) => format!(" ({r} secondary rays, {:.2} M rays/s)", s / 1e6),
            _ => String::new(),
        };
        println!(
            "baked {} views in {:.1} s{}{rays}; L' {} voxels ({} filled), {:.1} MB; peak RSS {}",
            self.views,
            self.bake_s,
            if self.from_cache { " (from cache)" } else { "" },
            self.light_field.occupied_voxels,
            self.light_field.filled_voxels,
            self.light_field.memory_mb,
            self.peak_rss_mb
                .map_or("-".into(), |m| format!("{m:.0} MB"))
        );
        if let Some(g) = &self.gt_render_psnr {
            let f = |v: Option<f64>| v.map_or("-".into(), |x| format!("{x:.2}"));
            println!(
                "factorised render with GT materials vs photos: all {:.2} dB, diffuse {} dB, specular {} dB, worst view {} at {:.2} dB",
                g.mean_all_db,
                f(g.mean_diffuse_db),
                f(g.mean_specular_db),
                g.worst_view,
                g.worst_view_db
            );
        }
    }
}

/// Seconds per pipeline stage.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct StageTimes {
    pub load_s: f64,
    pub bake_s: f64,
    pub train_s: f64,
    pub emitters_s: f64,
    pub maps_s: f64,
}

/// The hash grid as used by a run.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct GridReport {
    /// Median pixel footprint of the training views (unit-cube units).
    pub pixel_footprint: f64,
    /// Levels kept (`train.grid.max_resolution`).
    pub levels: usize,
    /// Training steps taken.
    pub steps: u64,
}

/// `metrics.json`: the scores (flattened to the top level), the per-part table, the emitters,
/// the loss log, stage times and memory.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct RunReport {
    pub scene: String,
    pub seg_loss: SegMode,
    pub bake_from_cache: bool,
    #[serde(flatten)]
    pub metrics: Metrics,
    /// Emitter triangles extracted (`emitters.json` lists them).
    pub emitters: usize,
    pub grid: GridReport,
    pub parts: Option<Vec<PartRow>>,
    pub train_log: TrainLog,
    pub step_profile: StepProfile,
    pub time_s: StageTimes,
    pub peak_rss_mb: Option<f64>,
}

/// `eval.json`: the scores recomputed from saved maps.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct EvalReport {
    #[serde(flatten)]
    pub metrics: Metrics,
    pub parts: Option<Vec<PartRow>>,
}

/// The metric table and, where the scene has `scene_meta.json`, the per-part table.
pub fn print_metrics(m: &Metrics, parts: Option<&[PartRow]>) {
    let f = |v: Option<f64>, p: usize| v.map_or("-".into(), |x| format!("{x:.p$}"));
    println!("metric            value");
    println!("kd_psnr           {} dB", f(m.kd_psnr, 2));
    println!("albedo_psnr       {} dB", f(m.albedo_psnr, 2));
    println!("roughness_psnr    {} dB", f(m.roughness_psnr, 2));
    println!("emission_iou      {}", f(m.emission_iou, 3));
    println!(
        "emission_log_l2   {}",
        m.emission_log_l2.map_or("-".into(), |x| format!("{x:.3e}"))
    );
    if let Some(parts) = parts {
        println!(
            "\npart                  pixels   a est / true                          σ est/true     m est/true"
        );
        for r in parts {
            println!(
                "{:<20} {:>7}   ({:.2},{:.2},{:.2}) / ({:.2},{:.2},{:.2})   {:.2} / {:.2}    {:.2} / {:.2}",
                r.name,
                r.pixels,
                r.a_est[0],
                r.a_est[1],
                r.a_est[2],
                r.a_true[0],
                r.a_true[1],
                r.a_true[2],
                r.sigma_est,
                r.sigma_true,
                r.m_est,
                r.m_true
            );
        }
    }
}

impl RunReport {
    pub fn print(&self, out: &std::path::Path) {
        print_metrics(&self.metrics, self.parts.as_deref());
        let t = &self.time_s;
        println!(
            "\nstage times: load {:.1} s, bake {:.1} s, train {:.1} s, emitters {:.1} s, maps {:.1} s",
            t.load_s, t.bake_s, t.train_s, t.emitters_s, t.maps_s
        );
        println!(
            "{} emitter triangles; peak RSS {}; outputs in {}",
            self.emitters,
            self.peak_rss_mb
                .map_or("-".into(), |m| format!("{m:.0} MB")),
            out.display()
        );
    }
}
