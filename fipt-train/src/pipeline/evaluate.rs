//! Scoring of predicted maps against the ground truth (issue protocol, reference §3): per-image
//! figures on the train views, then their mean.
//!
//! `kd_psnr`: non-emitter pixels with GT σ ≥ 0.6; `albedo_psnr`: a′ clamped to [0,1], non-emitter
//! pixels; `roughness_psnr`: σ clamped to [0.2,1] on both sides, non-emitter pixels;
//! `emission_iou` and `emission_log_l2` (MSE of ln(1+e)) on views with GT emitters. PSNR =
//! −10·log10(MSE) over the masked pixels.
//!
//! Owns: metrics and the per-part table. Must not touch: prediction.

use super::predict::ViewMaps;
use fipt_bake::ViewHits;
use fipt_core::scene::{MapKind, View, meta::SceneMeta};
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct ViewScore {
    pub view: usize,
    pub kd_psnr: Option<f64>,
    pub albedo_psnr: Option<f64>,
    pub roughness_psnr: Option<f64>,
    pub emission_iou: Option<f64>,
    pub emission_log_l2: Option<f64>,
}

#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct Metrics {
    pub kd_psnr: Option<f64>,
    pub albedo_psnr: Option<f64>,
    pub roughness_psnr: Option<f64>,
    pub emission_iou: Option<f64>,
    pub emission_log_l2: Option<f64>,
    pub per_view: Vec<ViewScore>,
}

fn psnr(se: f64, n: usize) -> Option<f64> {
    (n > 0).then(|| -10.0 * (se / n as f64).max(1e-10).log10())
}

/// Scores one view; figures whose GT map is missing are None.
pub fn score_view(view: &View, m: &ViewMaps) -> ViewScore {
    let n = view.image.num_pixels();
    let emit = view.map(MapKind::Emit);
    let is_emitter = |p: usize| emit.is_some_and(|e| e.rgb(p).iter().sum::<f32>() > 0.0);
    let rough = view.map(MapKind::Roughness);
    let mut s = ViewScore {
        view: view.index,
        ..Default::default()
    };
    if let (Some(kd), Some(r)) = (view.map(MapKind::DiffCol), rough) {
        let (mut se, mut k) = (0.0f64, 0usize);
        for p in (0..n).filter(|&p| !is_emitter(p) && r.scalar(p) >= 0.6) {
            for c in 0..3 {
                se +=
                    (kd.rgb(p)[c].clamp(0.0, 1.0) - m.kd[3 * p + c].clamp(0.0, 1.0)).powi(2) as f64;
            }
            k += 3;
        }
        s.kd_psnr = psnr(se, k);
    }
    if let Some(al) = view.map(MapKind::Albedo) {
        let (mut se, mut k) = (0.0f64, 0usize);
        for p in (0..n).filter(|&p| !is_emitter(p)) {
            for c in 0..3 {
                se += (al.rgb(p)[c].clamp(0.0, 1.0) - m.albedo[3 * p + c].clamp(0.0, 1.0)).powi(2)
                    as f64;
            }
            k += 3;
        }
        s.albedo_psnr = psnr(se, k);
    }
    if let Some(r) = rough {
        let (mut se, mut k) = (0.0f64, 0usize);
        for p in (0..n).filter(|&p| !is_emitter(p)) {
            se += (r.scalar(p).clamp(0.2, 1.0) - m.sigma[p].clamp(0.2, 1.0)).powi(2) as f64;
            k += 1;
        }
        s.roughness_psnr = psnr(se, k);
    }
    if let Some(e) = emit
        && (0..n).any(is_emitter)
    {
        let (mut inter, mut uni) = (0usize, 0usize);
        let mut se = 0.0f64;
        for p in 0..n {
            let t = is_emitter(p);
            let pe = &m.emit[3 * p..3 * p + 3];
            let est = pe.iter().sum::<f32>() > 0.0;
            inter += (t && est) as usize;
            uni += (t || est) as usize;
            for (est_c, gt_c) in pe.iter().zip(e.rgb(p)) {
                se += ((1.0 + est_c.max(0.0)).ln() - (1.0 + gt_c.max(0.0)).ln()).powi(2) as f64;
            }
        }
        s.emission_iou = Some(inter as f64 / uni.max(1) as f64);
        s.emission_log_l2 = Some(se / (3 * n) as f64);
    }
    s
}

fn mean(v: impl Iterator<Item = Option<f64>>) -> Option<f64> {
    let v: Vec<f64> = v.flatten().collect();
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

pub fn summarize(per_view: Vec<ViewScore>) -> Metrics {
    Metrics {
        kd_psnr: mean(per_view.iter().map(|s| s.kd_psnr)),
        albedo_psnr: mean(per_view.iter().map(|s| s.albedo_psnr)),
        roughness_psnr: mean(per_view.iter().map(|s| s.roughness_psnr)),
        emission_iou: mean(per_view.iter().map(|s| s.emission_iou)),
        emission_log_l2: mean(per_view.iter().map(|s| s.emission_log_l2)),
        per_view,
    }
}

/// Mean estimated vs true base colour, σ and m of one part over the train pixels that see it.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct PartRow {
    pub id: usize,
    pub name: String,
    pub pixels: usize,
    pub a_est: [f64; 3],
    pub a_true: [f64; 3],
    pub sigma_est: f64,
    pub sigma_true: f64,
    pub m_est: f64,
    pub m_true: f64,
}

/// The per-part table (needs `scene_meta.json` and the GT BaseColor/Roughness/Metallic maps).
pub fn part_table(
    meta: &SceneMeta,
    num_triangles: usize,
    views: &[View],
    hits: &[ViewHits],
    maps: &[ViewMaps],
) -> Vec<PartRow> {
    let tri_part = meta.triangle_part(num_triangles);
    let mut rows: Vec<PartRow> = meta
        .parts
        .iter()
        .map(|p| PartRow {
            id: p.id,
            name: p.name.clone(),
            ..Default::default()
        })
        .collect();
    for ((v, h), m) in views.iter().zip(hits).zip(maps) {
        let (Some(base), Some(r), Some(mt)) = (
            v.map(MapKind::BaseColor),
            v.map(MapKind::Roughness),
            v.map(MapKind::Metallic),
        ) else {
            continue;
        };
        for p in 0..h.num_pixels() {
            if h.tri[p] < 0 {
                continue;
            }
            let part = tri_part[h.tri[p] as usize];
            let Some(row) = rows.iter_mut().find(|r| r.id == part) else {
                continue;
            };
            row.pixels += 1;
            for c in 0..3 {
                row.a_est[c] += m.base[3 * p + c] as f64;
                row.a_true[c] += base.rgb(p)[c] as f64;
            }
            row.sigma_est += m.sigma[p] as f64;
            row.sigma_true += r.scalar(p) as f64;
            row.m_est += m.metallic[p] as f64;
            row.m_true += mt.scalar(p) as f64;
        }
    }
    for r in &mut rows {
        let k = r.pixels.max(1) as f64;
        for c in 0..3 {
            r.a_est[c] /= k;
            r.a_true[c] /= k;
        }
        r.sigma_est /= k;
        r.sigma_true /= k;
        r.m_est /= k;
        r.m_true /= k;
    }
    rows
}

/// A ground-truth-vs-estimate figure of one view (linear values, for `write_png`): top row the
/// photo and the true k_d, a′, σ and emission; bottom row 4×|k_d error| and the estimates.
/// Missing ground-truth maps are black. Returns (width, height, RGB).
pub fn comparison_figure(view: &View, m: &ViewMaps) -> (usize, usize, Vec<f32>) {
    let (w, h) = (m.width, m.height);
    let n = w * h;
    let gt_rgb = |k: MapKind| -> Vec<f32> {
        view.map(k).map_or(vec![0.0; 3 * n], |i| {
            (0..n).flat_map(|p| i.rgb(p)).collect()
        })
    };
    let grey = |v: &[f32]| -> Vec<f32> { v.iter().flat_map(|&x| [x; 3]).collect() };
    let gt_sigma: Vec<f32> = view
        .map(MapKind::Roughness)
        .map_or(vec![0.0; n], |i| (0..n).map(|p| i.scalar(p)).collect());
    let gt_kd = gt_rgb(MapKind::DiffCol);
    let err: Vec<f32> = gt_kd
        .iter()
        .zip(&m.kd)
        .map(|(a, b)| 4.0 * (a - b).abs())
        .collect();
    let image: Vec<f32> = (0..n).flat_map(|p| view.image.rgb(p)).collect();
    let top = [
        image,
        gt_kd,
        gt_rgb(MapKind::Albedo),
        grey(&gt_sigma),
        gt_rgb(MapKind::Emit),
    ];
    let bottom = [
        err,
        m.kd.clone(),
        m.albedo.clone(),
        grey(&m.sigma),
        m.emit.clone(),
    ];
    let cols = top.len();
    let mut out = vec![0f32; 3 * n * cols * 2];
    for (r, row) in [top, bottom].iter().enumerate() {
        for (c, tile) in row.iter().enumerate() {
            for y in 0..h {
                let dst = 3 * ((r * h + y) * w * cols + c * w);
                out[dst..dst + 3 * w].copy_from_slice(&tile[3 * y * w..3 * (y + 1) * w]);
            }
        }
    }
    (w * cols, 2 * h, out)
}
