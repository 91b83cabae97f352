//! The suite's figures: per scene and per part, and per half (tuning, held-out) the mean and
//! the worst of each score, the best constant σ beside the fitted one, and the share of glossy
//! parts and metals recovered.
//!
//! Owns: `suite.json`'s schema and its printed table. Must not touch: the scores themselves
//! (`pipeline::evaluate`).

use super::SceneSize;
use crate::pipeline::context::load_opts;
use crate::pipeline::evaluate::constant_predictor;
use crate::pipeline::report::RunReport;
use anyhow::Result;
use fipt_core::scene::Dataset;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// A part is glossy when its true σ is at most this.
pub const GLOSSY_SIGMA: f64 = 0.5;
/// A glossy part is recovered when its mean fitted σ is within this of the truth.
pub const SIGMA_TOLERANCE: f64 = 0.15;
/// A part is a metal when its true m is at least this; recovered when its fitted m is too.
pub const METAL: f64 = 0.5;

/// One part's σ and m, true and fitted.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct PartScore {
    pub name: String,
    pub pixels: usize,
    pub sigma_true: f64,
    pub sigma_est: f64,
    pub m_true: f64,
    pub m_est: f64,
    pub glossy: bool,
    pub metal: bool,
    /// Every property it has recovered: a glossy part's σ (`sigma_recovered`) and a metal's m
    /// (`metal_recovered`).
    pub recovered: bool,
}

impl PartScore {
    /// A glossy part whose fitted σ is within `SIGMA_TOLERANCE` of the truth.
    pub fn sigma_recovered(&self) -> bool {
        self.glossy && (self.sigma_est - self.sigma_true).abs() <= SIGMA_TOLERANCE
    }

    /// A metal fitted as one (m ≥ `METAL`).
    pub fn metal_recovered(&self) -> bool {
        self.metal && self.m_est >= METAL
    }
}

/// One scene's figures.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct SceneRow {
    pub seed: u64,
    pub half: String,
    pub scene: String,
    pub kd_psnr: Option<f64>,
    /// k_d of the best constant predictor (the masked mean), scored as the fit is.
    pub constant_kd_psnr: Option<f64>,
    /// Round 0's k_d (before any refinement).
    pub round0_kd_psnr: Option<f64>,
    pub albedo_psnr: Option<f64>,
    pub roughness_psnr: Option<f64>,
    /// σ of the best constant predictor (the masked mean), scored as the fit is.
    pub constant_roughness_psnr: Option<f64>,
    pub emission_iou: Option<f64>,
    pub emission_log_l2: Option<f64>,
    pub view_psnr: Option<f64>,
    pub relight_psnr: Option<f64>,
    pub parts: Vec<PartScore>,
}

impl SceneRow {
    /// The row of a finished run of the suite scene in `scene`.
    pub fn new(seed: u64, half: &str, scene: &Path, r: &RunReport) -> Result<Self> {
        let ds = Dataset::load(scene, &load_opts())?;
        let constant = constant_predictor(&ds.train.views);
        let parts = r
            .parts
            .iter()
            .flatten()
            .filter(|p| p.pixels > 0)
            .map(|p| {
                let mut s = PartScore {
                    name: p.name.clone(),
                    pixels: p.pixels,
                    sigma_true: p.sigma_true,
                    sigma_est: p.sigma_est,
                    m_true: p.m_true,
                    m_est: p.m_est,
                    glossy: p.sigma_true <= GLOSSY_SIGMA,
                    metal: p.m_true >= METAL,
                    recovered: false,
                };
                s.recovered =
                    (!s.glossy || s.sigma_recovered()) && (!s.metal || s.metal_recovered());
                s
            })
            .collect();
        let m = &r.metrics;
        Ok(Self {
            seed,
            half: half.into(),
            scene: scene.display().to_string(),
            kd_psnr: m.kd_psnr,
            constant_kd_psnr: constant.as_ref().and_then(|c| c.metrics.kd_psnr),
            round0_kd_psnr: r.rounds.first().and_then(|r0| r0.kd_psnr),
            albedo_psnr: m.albedo_psnr,
            roughness_psnr: m.roughness_psnr,
            constant_roughness_psnr: constant.and_then(|c| c.metrics.roughness_psnr),
            emission_iou: m.emission_iou,
            emission_log_l2: m.emission_log_l2,
            view_psnr: r.view_psnr,
            relight_psnr: r.relight_psnr,
            parts,
        })
    }
}

/// The mean and the worst of one score over a half's scenes (None where no scene has it).
#[derive(Clone, Copy, Debug, Default, Serialize, Deserialize)]
pub struct MeanWorst {
    pub mean: Option<f64>,
    pub worst: Option<f64>,
}

impl MeanWorst {
    /// Over `v`; the worst is the least, or with `lower_is_better` the greatest. A NaN score
    /// makes both NaN.
    fn of(v: impl Iterator<Item = Option<f64>>, lower_is_better: bool) -> Self {
        let v: Vec<f64> = v.flatten().collect();
        if v.is_empty() {
            return Self::default();
        }
        let mean = v.iter().sum::<f64>() / v.len() as f64;
        let worst = v.iter().copied().reduce(|a, b| {
            if a.is_nan() || b.is_nan() {
                f64::NAN
            } else if lower_is_better {
                a.max(b)
            } else {
                a.min(b)
            }
        });
        Self {
            mean: Some(mean),
            worst,
        }
    }
}

/// One half's summary.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct HalfSummary {
    pub half: String,
    pub scenes: usize,
    pub kd_psnr: MeanWorst,
    pub albedo_psnr: MeanWorst,
    pub roughness_psnr: MeanWorst,
    pub constant_roughness_psnr: MeanWorst,
    pub emission_iou: MeanWorst,
    pub emission_log_l2: MeanWorst,
    pub view_psnr: MeanWorst,
    pub relight_psnr: MeanWorst,
    pub glossy_parts: usize,
    pub glossy_recovered: usize,
    pub metals: usize,
    pub metals_recovered: usize,
    /// Scenes whose final k_d is below their round 0's.
    pub kd_below_round0: Vec<u64>,
}

impl HalfSummary {
    fn new(half: &str, rows: &[&SceneRow]) -> Self {
        let f = |g: fn(&SceneRow) -> Option<f64>, lower| {
            MeanWorst::of(rows.iter().map(|r| g(r)), lower)
        };
        let parts = || rows.iter().flat_map(|r| &r.parts);
        Self {
            half: half.into(),
            scenes: rows.len(),
            kd_psnr: f(|r| r.kd_psnr, false),
            albedo_psnr: f(|r| r.albedo_psnr, false),
            roughness_psnr: f(|r| r.roughness_psnr, false),
            constant_roughness_psnr: f(|r| r.constant_roughness_psnr, false),
            emission_iou: f(|r| r.emission_iou, false),
            emission_log_l2: f(|r| r.emission_log_l2, true),
            view_psnr: f(|r| r.view_psnr, false),
            relight_psnr: f(|r| r.relight_psnr, false),
            glossy_parts: parts().filter(|p| p.glossy).count(),
            glossy_recovered: parts().filter(|p| p.sigma_recovered()).count(),
            metals: parts().filter(|p| p.metal).count(),
            metals_recovered: parts().filter(|p| p.metal_recovered()).count(),
            kd_below_round0: rows
                .iter()
                .filter(|r| matches!((r.kd_psnr, r.round0_kd_psnr), (Some(k), Some(k0)) if k < k0))
                .map(|r| r.seed)
                .collect(),
        }
    }
}

/// `suite.json`.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct SuiteReport {
    pub size: SceneSize,
    /// The photos' samples per pixel where `--spp` replaced the size's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub spp: Option<usize>,
    pub halves: Vec<HalfSummary>,
    pub scenes: Vec<SceneRow>,
}

/// A PSNR for printing.
pub fn db(v: Option<f64>) -> String {
    v.map_or("-".into(), |x| format!("{x:.2} dB"))
}

impl SuiteReport {
    pub fn new(size: SceneSize, spp: Option<usize>, scenes: Vec<SceneRow>) -> Self {
        let halves = ["tuning", "held-out"]
            .iter()
            .map(|h| {
                let rows: Vec<&SceneRow> = scenes.iter().filter(|r| r.half == *h).collect();
                HalfSummary::new(h, &rows)
            })
            .filter(|s| s.scenes > 0)
            .collect();
        Self {
            size,
            spp,
            halves,
            scenes,
        }
    }

    /// The per-scene table, the glossy parts and metals, and the halves' means and worsts.
    pub fn print(&self) {
        let f = |v: Option<f64>| v.map_or("-".into(), |x| format!("{x:.2}"));
        println!("\nseed  half      k_d (r0)        a'      σ (const)       IoU    view   relight");
        for r in &self.scenes {
            println!(
                "{:>4}  {:<8}  {:>6} ({:>6})  {:>6}  {:>6} ({:>6})  {:>5}  {:>6}  {:>6}",
                r.seed,
                r.half,
                f(r.kd_psnr),
                f(r.round0_kd_psnr),
                f(r.albedo_psnr),
                f(r.roughness_psnr),
                f(r.constant_roughness_psnr),
                f(r.emission_iou),
                f(r.view_psnr),
                f(r.relight_psnr)
            );
            for p in r.parts.iter().filter(|p| p.glossy || p.metal) {
                println!(
                    "        {:<16} σ {:.2} → {:.2}   m {:.2} → {:.2}   {}",
                    p.name,
                    p.sigma_true,
                    p.sigma_est,
                    p.m_true,
                    p.m_est,
                    if p.recovered { "ok" } else { "LOST" }
                );
            }
        }
        for h in &self.halves {
            println!(
                "{} ({} scenes): k_d mean {} worst {}; σ mean {} worst {} (constant {}); glossy {}/{}, metals {}/{}; k_d below round 0: {:?}",
                h.half,
                h.scenes,
                f(h.kd_psnr.mean),
                f(h.kd_psnr.worst),
                f(h.roughness_psnr.mean),
                f(h.roughness_psnr.worst),
                f(h.constant_roughness_psnr.mean),
                h.glossy_recovered,
                h.glossy_parts,
                h.metals_recovered,
                h.metals,
                h.kd_below_round0
            );
        }
    }
}
