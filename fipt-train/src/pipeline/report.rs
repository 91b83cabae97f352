//! The typed reports of the pipeline commands (`bake.json`, `metrics.json`, `eval.json`),
//! serialised with serde so a renamed field is a compile error, not a silent 0, and their
//! human-readable summaries.
//!
//! Owns: report types and printing. Must not touch: how the figures are computed.

use super::evaluate::{Metrics, PartRow};
use super::fit::TrainLog;
use crate::image_metrics::GtRenderPsnr;
use fipt_bake::integrators::bake::BakeConfig;
use fipt_bake::integrators::path::PathStats;
use fipt_core::model::step::{SegMode, StepProfile};
use fipt_core::model::{LossParts, Trainer};
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
    /// LDR photos: the first fit, emitter extraction and solve of the clipped lamps (with the
    /// clipped photos' bake).
    #[serde(default)]
    pub lamps_s: f64,
    pub bake_s: f64,
    /// All fits, every round.
    pub train_s: f64,
    pub emitters_s: f64,
    /// All shading refinements.
    pub refine_s: f64,
    pub maps_s: f64,
    /// The val re-renders (view synthesis and relighting).
    #[serde(default)]
    pub render_s: f64,
    /// Saving the fits' checkpoints (part of `train_s`).
    #[serde(default)]
    pub checkpoint_s: f64,
}

impl StageTimes {
    /// (stage, seconds) in the pipeline's order, for the printed and HTML reports.
    pub fn rows(&self) -> [(&'static str, f64); 8] {
        [
            ("load", self.load_s),
            ("bake", self.bake_s),
            ("fit (all rounds)", self.train_s),
            ("of which checkpoints", self.checkpoint_s),
            ("emitters", self.emitters_s),
            ("refinement (all rounds)", self.refine_s),
            ("maps", self.maps_s),
            ("val re-renders", self.render_s),
        ]
    }
}

/// The re-renders of the val views by `run`: view synthesis against `val/Image` and
/// relighting against `val/Relight` (`OUT/render/val/{Image,Relight}/`).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ValRenders {
    pub spp: usize,
    pub relight_spp: usize,
    /// Whether view synthesis took L′ on rough secondary hits.
    pub cache: bool,
    pub view: Vec<crate::rerender::ViewRender>,
    pub relight: Vec<crate::rerender::ViewRender>,
}

/// One round of the alternation: its shadings (baked for round 0, refined after), its fit and
/// the scores of its model's train maps.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct RoundReport {
    pub round: usize,
    pub kd_psnr: Option<f64>,
    pub albedo_psnr: Option<f64>,
    pub roughness_psnr: Option<f64>,
    pub emission_iou: Option<f64>,
    pub emission_log_l2: Option<f64>,
    /// Per-view k_d PSNR.
    pub kd_psnr_per_view: Vec<Option<f64>>,
    pub parts: Option<Vec<PartRow>>,
    pub steps: u64,
    /// Mean loss of the fit's last epoch.
    pub final_loss: Option<LossParts>,
    /// Seconds of the refinement that made this round's shadings (0 for round 0).
    pub refine_s: f64,
    /// Its path counters (None for round 0 or when the shadings came from the cache).
    pub refine_paths: Option<PathStats>,
    pub train_s: f64,
    /// The training pixels its fit saw (fewer in the refined rounds with
    /// `refine.emitter_margin`).
    #[serde(default)]
    pub fit_pixels: usize,
    /// The fit's loss (every step's total), averaged into at most 200 bins: (step, loss).
    #[serde(default)]
    pub loss_curve: Vec<(u64, f32)>,
    /// The basin hop after the fit (`train.hop`), where one ran.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub hop: Option<crate::pipeline::hop::HopReport>,
}

/// `v` averaged into at most `bins` consecutive bins: (first index of the bin, mean).
pub fn binned(v: &[f32], bins: usize) -> Vec<(u64, f32)> {
    let per = v.len().div_ceil(bins.max(1)).max(1);
    v.chunks(per)
        .enumerate()
        .map(|(i, c)| ((i * per) as u64, c.iter().sum::<f32>() / c.len() as f32))
        .collect()
}

/// The time and the path statistics of a round's refinement, and the time of its fit.
#[derive(Clone, Debug, Default)]
pub struct RoundWork {
    pub refine_s: f64,
    /// None for round 0 and for shadings from the refinement cache.
    pub refine_paths: Option<PathStats>,
    pub train_s: f64,
}

impl RoundReport {
    /// Round `round`'s report: its scores `m` and `parts`, its trainer and loss log, its work.
    pub fn new(
        round: usize,
        m: &Metrics,
        parts: Option<Vec<PartRow>>,
        tr: &Trainer,
        log: &TrainLog,
        work: RoundWork,
    ) -> Self {
        Self {
            round,
            kd_psnr: m.kd_psnr,
            albedo_psnr: m.albedo_psnr,
            roughness_psnr: m.roughness_psnr,
            emission_iou: m.emission_iou,
            emission_log_l2: m.emission_log_l2,
            kd_psnr_per_view: m.per_view.iter().map(|v| v.kd_psnr).collect(),
            parts,
            steps: tr.steps,
            final_loss: log.epochs.last().copied(),
            refine_s: work.refine_s,
            refine_paths: work.refine_paths,
            train_s: work.train_s,
            fit_pixels: log.pixels,
            loss_curve: binned(&log.step_total, 200),
            hop: log.hop.clone(),
        }
    }
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
    /// Where the table lived during the fit: `host` (fused op, sparse Adam) or `device`
    /// (`train.grid_place`).
    #[serde(default)]
    pub place: String,
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
    /// Every round's scores (the last is the final model, also flattened above).
    pub rounds: Vec<RoundReport>,
    pub train_log: TrainLog,
    pub step_profile: StepProfile,
    pub time_s: StageTimes,
    pub peak_rss_mb: Option<f64>,
    /// Mean over the val views of PSNR(clip(x,0,1)^(1/2.2)) of the re-render vs `val/Image`.
    pub view_psnr: Option<f64>,
    /// The same for the relit val views vs `val/Relight`.
    pub relight_psnr: Option<f64>,
    pub renders: Option<ValRenders>,
    /// The scene model folder (`OUT/model`) and, where registered, its zoo entry.
    pub model_dir: Option<String>,
    pub zoo_entry: Option<String>,
    /// Where this run continued an interrupted one (`pipeline::checkpoint`), if it did.
    #[serde(default)]
    pub resumed: Option<String>,
    /// LDR photos: the calibration, the emitter solve and LDR view synthesis.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ldr: Option<crate::ldr::report::LdrReport>,
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
        if self.rounds.len() > 1 {
            let f = |v: Option<f64>| v.map_or("-".into(), |x| format!("{x:.2}"));
            println!("\nround   k_d dB   a' dB   σ dB   refine s   train s");
            for r in &self.rounds {
                println!(
                    "{:>5}   {:>6}   {:>5}   {:>4}   {:>8.1}   {:>7.1}",
                    r.round,
                    f(r.kd_psnr),
                    f(r.albedo_psnr),
                    f(r.roughness_psnr),
                    r.refine_s,
                    r.train_s
                );
            }
        }
        if self.view_psnr.is_some() || self.relight_psnr.is_some() {
            let f = |v: Option<f64>| v.map_or("-".into(), |x| format!("{x:.2} dB"));
            println!(
                "\nval re-renders: view synthesis {}, relighting {}",
                f(self.view_psnr),
                f(self.relight_psnr)
            );
        }
        let times: Vec<String> = self
            .time_s
            .rows()
            .iter()
            .map(|(k, v)| format!("{k} {v:.1} s"))
            .collect();
        println!("\nstage times: {}", times.join(", "));
        println!(
            "{} emitter triangles; peak RSS {}; outputs in {}",
            self.emitters,
            self.peak_rss_mb
                .map_or("-".into(), |m| format!("{m:.0} MB")),
            out.display()
        );
        if let Some(m) = &self.model_dir {
            println!("scene model: {m}");
        }
        if let Some(z) = &self.zoo_entry {
            println!("zoo entry: {z}");
        }
    }
}
