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
use crate::image_metrics::psnr;
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

/// The best constant predictor of a split's maps: k_d, a′ and σ each set to the mean of the
/// (clamped) ground truth over the pixels its metric scores, no emission; and its scores by
/// this scorer: the scale every estimate is read against. None without the GT maps.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ConstantPredictor {
    pub kd: [f32; 3],
    pub albedo: [f32; 3],
    pub sigma: f32,
    pub metrics: Metrics,
}

pub fn constant_predictor(views: &[View]) -> Option<ConstantPredictor> {
    // Sums over the masked pixels of every view: k_d (3), a′ (3), σ (1) and their counts.
    let (mut kd, mut al, mut sg) = ([0f64; 3], [0f64; 3], 0f64);
    let (mut n_kd, mut n_rest) = (0usize, 0usize);
    for v in views {
        let (e, r) = (v.map(MapKind::Emit)?, v.map(MapKind::Roughness)?);
        let (d, a) = (v.map(MapKind::DiffCol)?, v.map(MapKind::Albedo)?);
        for p in 0..v.image.num_pixels() {
            if e.rgb(p).iter().sum::<f32>() > 0.0 {
                continue;
            }
            n_rest += 1;
            sg += r.scalar(p).clamp(0.2, 1.0) as f64;
            for (sum, v) in al.iter_mut().zip(a.rgb(p)) {
                *sum += v.clamp(0.0, 1.0) as f64;
            }
            if r.scalar(p) >= 0.6 {
                n_kd += 1;
                for (sum, v) in kd.iter_mut().zip(d.rgb(p)) {
                    *sum += v.clamp(0.0, 1.0) as f64;
                }
            }
        }
    }
    if n_kd == 0 || n_rest == 0 {
        return None;
    }
    let kd = kd.map(|x| (x / n_kd as f64) as f32);
    let albedo = al.map(|x| (x / n_rest as f64) as f32);
    let sigma = (sg / n_rest as f64) as f32;
    let scores = views
        .iter()
        .map(|v| {
            let n = v.image.num_pixels();
            let maps = ViewMaps {
                width: v.image.width,
                height: v.image.height,
                kd: kd.repeat(n),
                sigma: vec![sigma; n],
                metallic: vec![0.0; n],
                base: kd.repeat(n),
                albedo: albedo.repeat(n),
                emit: vec![0.0; 3 * n],
            };
            score_view(v, &maps)
        })
        .collect();
    Some(ConstantPredictor {
        kd,
        albedo,
        sigma,
        metrics: summarize(scores),
    })
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

#[cfg(test)]
mod tests {
    //! Hand-made 4×2 views whose scores are worked out by hand (pixel p = row·4 + col).
    use super::*;
    use fipt_core::scene::{Camera, Image};
    use glam::DVec3;
    use std::collections::BTreeMap;

    const W: usize = 4;
    const H: usize = 2;
    const N: usize = W * H;

    fn img(channels: usize, data: &[f32]) -> Image {
        Image::from_data(W, H, channels, data.to_vec())
    }

    fn flat(px: [[f32; 3]; N]) -> Vec<f32> {
        px.iter().flatten().copied().collect()
    }

    // Ground truth. Pixel 7 is the only emitter.
    const GT_SIGMA: [f32; N] = [0.6, 0.1, 1.0, 0.59, 1.2, 0.3, 0.7, 1.0];
    const GT_KD: [[f32; 3]; N] = [
        [0.5, 0.5, 0.5],
        [0.4, 0.4, 0.4],
        [1.4, 0.2, 0.2],
        [0.4, 0.4, 0.4],
        [0.3, 0.3, 0.3],
        [0.4, 0.4, 0.4],
        [0.2, 0.2, 0.9],
        [0.0, 0.0, 0.0],
    ];
    const GT_ALBEDO: [[f32; 3]; N] = [
        [0.5, 0.5, 0.5],
        [1.3, 0.4, 0.4],
        [0.5, 0.5, 0.5],
        [0.5, 0.5, 0.5],
        [0.5, 0.5, 0.5],
        [0.5, 0.5, 0.5],
        [0.5, 0.5, 0.5],
        [0.0, 0.0, 0.0],
    ];
    const GT_EMIT: [[f32; 3]; N] = [
        [0.0; 3],
        [0.0; 3],
        [0.0; 3],
        [0.0; 3],
        [0.0; 3],
        [0.0; 3],
        [0.0; 3],
        [2.0, 1.0, 0.0],
    ];

    fn gt_view(kinds: &[MapKind]) -> View {
        let mut maps = BTreeMap::new();
        for &k in kinds {
            let m = match k {
                MapKind::DiffCol => img(3, &flat(GT_KD)),
                MapKind::Roughness => img(1, &GT_SIGMA),
                MapKind::Albedo => img(3, &flat(GT_ALBEDO)),
                MapKind::Emit => img(3, &flat(GT_EMIT)),
                _ => unreachable!(),
            };
            maps.insert(k, m);
        }
        View {
            index: 3,
            camera: Camera::look_at_fov(DVec3::ZERO, DVec3::Z, DVec3::Y, 1.0, W, H),
            image: Image::new(W, H, 3),
            ldr: None,
            maps,
        }
    }

    const ALL: [MapKind; 4] = [
        MapKind::DiffCol,
        MapKind::Roughness,
        MapKind::Albedo,
        MapKind::Emit,
    ];

    fn maps(kd: Vec<f32>, sigma: Vec<f32>, albedo: Vec<f32>, emit: Vec<f32>) -> ViewMaps {
        ViewMaps {
            width: W,
            height: H,
            kd,
            sigma,
            metallic: vec![0.0; N],
            base: vec![0.0; 3 * N],
            albedo,
            emit,
        }
    }

    fn db(mse: f64) -> f64 {
        -10.0 * mse.log10()
    }

    fn close(a: Option<f64>, b: f64, tol: f64, what: &str) {
        let a = a.unwrap_or_else(|| panic!("{what} is None"));
        assert!((a - b).abs() <= tol, "{what}: {a} vs expected {b}");
    }

    /// Every clamp, mask and exclusion of `score_view`, with the squared errors summed by hand.
    #[test]
    fn hand_computed_scores() {
        let v = gt_view(&ALL);
        // k_d mask: non-emitter and GT σ ≥ 0.6 → pixels 0 (σ = 0.6 exactly), 2, 4, 6.
        // Pixels 1, 3 (σ = 0.59), 5 and the emitter 7 get large errors that must not count.
        let kd = flat([
            [0.6, 0.5, 0.5],  // 0: 0.1² = 0.01
            [0.9, 0.9, 0.9],  // 1: excluded (σ 0.1)
            [1.0, 0.2, 0.2],  // 2: GT 1.4 clamps to 1 → 0
            [0.9, 0.9, 0.9],  // 3: excluded (σ 0.59)
            [-0.5, 0.3, 0.3], // 4: prediction clamps to 0 → 0.3² = 0.09
            [0.9, 0.9, 0.9],  // 5: excluded (σ 0.3)
            [0.2, 0.2, 1.7],  // 6: prediction clamps to 1 → 0.1² = 0.01
            [0.9, 0.9, 0.9],  // 7: emitter
        ]);
        // σ on non-emitter pixels 0..7, both sides clamped to [0.2, 1]:
        // 0: 0; 1: GT 0.1→0.2 vs 0.2 → 0; 2: 1.0 vs 1.5→1 → 0; 3: 0; 4: GT 1.2→1 vs 0.5 → 0.25;
        // 5: 0.3 vs 0.1→0.2 → 0.01; 6: 0; 7: emitter (would add (1 − 0.2)²).
        let sigma = vec![0.6, 0.2, 1.5, 0.59, 0.5, 0.1, 0.7, 0.0];
        // a′ on non-emitter pixels, clamped to [0, 1]: 1: GT 1.3→1 vs 1 → 0; 3: 0.3² = 0.09;
        // 5: −0.2→0 vs 0.5 → 0.25; 7: emitter.
        let mut albedo = flat(GT_ALBEDO);
        albedo[3..6].copy_from_slice(&[1.0, 0.4, 0.4]);
        albedo[9..12].copy_from_slice(&[0.5, 0.5, 0.8]);
        albedo[15..18].copy_from_slice(&[-0.2, 0.5, 0.5]);
        albedo[21..24].copy_from_slice(&[5.0, 5.0, 5.0]);
        // Emission: the true emitter 7 is found (ln(1+e) = 1 in R), pixel 3 is a false emitter
        // (ln(1+e) = 2 in B), pixel 0 is negative (not an emitter, clamped to 0 in the log).
        let e1 = std::f32::consts::E - 1.0;
        let e2 = std::f32::consts::E * std::f32::consts::E - 1.0;
        let mut emit = vec![0.0; 3 * N];
        emit[0] = -1.0;
        emit[9..12].copy_from_slice(&[0.0, 0.0, e2]);
        emit[21..24].copy_from_slice(&[e1, 1.0, 0.0]);

        let s = score_view(&v, &maps(kd, sigma, albedo, emit));
        assert_eq!(s.view, 3);
        close(s.kd_psnr, db(0.11 / 12.0), 1e-4, "kd_psnr");
        close(s.roughness_psnr, db(0.26 / 7.0), 1e-4, "roughness_psnr");
        close(s.albedo_psnr, db(0.34 / 21.0), 1e-4, "albedo_psnr");
        // GT emitters {7}, predicted {3, 7}: IoU 1/2.
        close(s.emission_iou, 0.5, 1e-12, "emission_iou");
        // Over all 3·8 values: pixel 7 R (1 − ln 3)², G (ln 2 − ln 2)² = 0, pixel 3 B 2².
        let ln3 = 3f64.ln();
        close(
            s.emission_log_l2,
            ((1.0 - ln3).powi(2) + 4.0) / 24.0,
            1e-6,
            "emission_log_l2",
        );
    }

    #[test]
    fn ground_truth_scores_the_cap() {
        let v = gt_view(&ALL);
        let m = maps(
            flat(GT_KD),
            GT_SIGMA.to_vec(),
            flat(GT_ALBEDO),
            flat(GT_EMIT),
        );
        let s = score_view(&v, &m);
        for (name, x) in [
            ("kd", s.kd_psnr),
            ("albedo", s.albedo_psnr),
            ("roughness", s.roughness_psnr),
        ] {
            assert_eq!(x, Some(100.0), "{name}");
        }
        assert_eq!(s.emission_iou, Some(1.0));
        assert_eq!(s.emission_log_l2, Some(0.0));
    }

    /// k_d = 0.5, σ = 1, a′ = 0.5, no emission everywhere.
    #[test]
    fn constant_predictor() {
        let v = gt_view(&ALL);
        let m = maps(
            vec![0.5; 3 * N],
            vec![1.0; N],
            vec![0.5; 3 * N],
            vec![0.0; 3 * N],
        );
        let s = score_view(&v, &m);
        // k_d on pixels 0, 2, 4, 6 (GT clamped): 0 + (0.25 + 0.09 + 0.09) + 3·0.04
        // + (0.09 + 0.09 + 0.16) = 0.89 over 12 values.
        close(s.kd_psnr, db(0.89 / 12.0), 1e-4, "kd_psnr");
        // σ = 1 vs clamped GT [0.6, 0.2, 1, 0.59, 1, 0.3, 0.7]:
        // 0.16 + 0.64 + 0 + 0.1681 + 0 + 0.49 + 0.09 = 1.5481 over 7.
        close(s.roughness_psnr, db(1.5481 / 7.0), 1e-4, "roughness_psnr");
        // a′ = 0.5 vs clamped GT: only pixel 1 differs, (1 − 0.5)² + 2·0.1² = 0.27 over 21.
        close(s.albedo_psnr, db(0.27 / 21.0), 1e-4, "albedo_psnr");
        // No predicted emitter: IoU 0; log-L2 = (ln² 3 + ln² 2) / 24.
        close(s.emission_iou, 0.0, 0.0, "emission_iou");
        let expect = (3f64.ln().powi(2) + 2f64.ln().powi(2)) / 24.0;
        close(s.emission_log_l2, expect, 1e-6, "emission_log_l2");
    }

    #[test]
    fn missing_maps_and_views_without_emitters_give_none() {
        let m = maps(
            flat(GT_KD),
            GT_SIGMA.to_vec(),
            flat(GT_ALBEDO),
            flat(GT_EMIT),
        );
        // No Emit map: no emission figures, the rest still scored.
        let s = score_view(
            &gt_view(&[MapKind::DiffCol, MapKind::Roughness, MapKind::Albedo]),
            &m,
        );
        assert!(s.emission_iou.is_none() && s.emission_log_l2.is_none());
        assert!(s.kd_psnr.is_some() && s.albedo_psnr.is_some() && s.roughness_psnr.is_some());
        // An Emit map without emitters: None too, even though the prediction has emission.
        let mut v = gt_view(&ALL);
        v.maps.insert(MapKind::Emit, img(3, &[0.0; 3 * N]));
        let s = score_view(&v, &m);
        assert!(s.emission_iou.is_none() && s.emission_log_l2.is_none());
        // k_d needs both DiffCol and Roughness.
        let s = score_view(&gt_view(&[MapKind::DiffCol, MapKind::Emit]), &m);
        assert!(s.kd_psnr.is_none() && s.roughness_psnr.is_none() && s.albedo_psnr.is_none());
        assert_eq!(s.emission_iou, Some(1.0));
        let s = score_view(&gt_view(&[MapKind::Roughness]), &m);
        assert!(s.kd_psnr.is_none() && s.albedo_psnr.is_none());
        assert_eq!(s.roughness_psnr, Some(100.0));
    }

    #[test]
    fn summarize_averages_present_values() {
        let vs = |view, kd, iou| ViewScore {
            view,
            kd_psnr: kd,
            albedo_psnr: Some(10.0 * view as f64),
            roughness_psnr: None,
            emission_iou: iou,
            emission_log_l2: None,
        };
        let m = summarize(vec![
            vs(0, Some(10.0), None),
            vs(1, None, Some(0.25)),
            vs(2, Some(40.0), None),
            vs(3, None, None),
        ]);
        assert_eq!(m.kd_psnr, Some(25.0));
        assert_eq!(m.albedo_psnr, Some(15.0));
        assert_eq!(m.roughness_psnr, None);
        assert_eq!(m.emission_iou, Some(0.25));
        assert_eq!(m.emission_log_l2, None);
        assert_eq!(
            m.per_view.iter().map(|s| s.view).collect::<Vec<_>>(),
            [0, 1, 2, 3]
        );
        assert!(summarize(Vec::new()).kd_psnr.is_none());
    }
}
