//! The loss landscape per part (a diagnostic for issue-level questions such as "do the
//! shadings carry the roughness?"): at every training pixel of a part, the stage-2 data term
//! (MSE of sRGB-encoded HDR, Eq. 15) of the factorised render with the **true** base colour and
//! metallic and a swept roughness σ, and the diffuse prior λ_d(|σ − σ₀| + m) of Eq. 17. The
//! minimiser of the data term over σ says what the shadings support; that of data + prior what
//! the objective supports; that of the patch profile (`patch_profile`: the colour solved per
//! surface patch instead of the true one) what a fit whose colour is free can read from them.
//!
//! Owns: the sweep and its table. Must not touch: shadings, training.

use fipt_bake::ViewHits;
use fipt_core::brdf::{factorised_render, reflectances};
use fipt_core::model::loss::tonemap_host as srgb;
use fipt_core::scene::{Dataset, MapKind};
use fipt_core::shading::ShadingLayout;
use glam::Vec3;

use super::predict::ViewMaps;

/// Roughness values swept.
pub const SWEEP: usize = 50;

/// The swept σ values: σ_i = 0.02 + 0.98·i/(SWEEP − 1).
pub fn sweep() -> Vec<f32> {
    (0..SWEEP)
        .map(|i| 0.02 + 0.98 * i as f32 / (SWEEP - 1) as f32)
        .collect()
}

/// One part's landscape.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct PartLandscape {
    pub name: String,
    pub pixels: usize,
    pub sigma_true: f64,
    pub m_true: f64,
    /// σ_i = 0.02 + 0.98·i/(SWEEP − 1).
    pub sigma: Vec<f64>,
    /// Mean data term at each σ_i.
    pub data: Vec<f64>,
    /// Mean prior at each σ_i.
    pub prior: Vec<f64>,
    pub argmin_data: f64,
    pub argmin_total: f64,
    /// Σ render / Σ photo (all channels) with the true a, σ and m: 1 for unbiased shadings.
    pub render_ratio: f64,
    /// Mean data term at the true a, σ and m.
    pub loss_true: f64,
    /// The data term at each σ_i with the base colour solved per patch (`patch_profile`), the
    /// true m; empty where not computed.
    #[serde(default)]
    pub patch: Vec<f64>,
    #[serde(default)]
    pub argmin_patch: f64,
    /// With a fitted model's maps (`fitted`): the same sweep at its a and m, per pixel.
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub fitted: Option<FittedLandscape>,
}

/// The sweep at a fitted model's base colour and metallic, and the model's own data term: where
/// the fit stands on these shadings, against where its a and m let σ go.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct FittedLandscape {
    /// Mean fitted σ and m over the part's pixels.
    pub sigma: f64,
    pub metallic: f64,
    /// Mean data term at the fitted a, σ and m.
    pub loss: f64,
    /// Mean data term at the fitted a and m and each swept σ.
    pub data: Vec<f64>,
    pub argmin_data: f64,
}

/// The pixels of a view that the tables take, with their part's index in `meta.parts`: those
/// whose centre ray hits a part and that `left` (of view `k`) does not leave out.
fn part_pixels(
    meta: &fipt_core::scene::meta::SceneMeta,
    tri_part: &[usize],
    (k, v, h): (usize, &fipt_core::scene::View, &ViewHits),
    left: &LeftOut,
) -> Vec<(usize, usize)> {
    let emit = v.map(MapKind::Emit);
    let lit: Vec<bool> = (0..h.num_pixels())
        .map(|p| emit.is_some_and(|e| e.rgb(p).iter().sum::<f32>() > 0.0))
        .collect();
    let near = super::pixels::ring_around(&lit, h.width, left.margin);
    let covered = |p: usize| left.cover.as_ref().is_none_or(|(c, tau)| c[k][p] >= *tau);
    (0..h.num_pixels())
        .filter(|&p| h.tri[p] >= 0 && !lit[p] && !near[p] && covered(p))
        .filter_map(|p| {
            let part = meta
                .parts
                .iter()
                .position(|x| x.id == tri_part[h.tri[p] as usize])?;
            Some((p, part))
        })
        .collect()
}

/// The pixels every table leaves out, as the fits do: those within `margin` pixels of a true
/// emitter's (`refine.emitter_margin`), and with `cover` (per view and pixel, and τ) those
/// that the part their centre ray hits covers less than τ of (`train.min_coverage`).
pub struct LeftOut {
    pub margin: usize,
    pub cover: Option<(Vec<Vec<f32>>, f32)>,
}

/// The landscape of every part of a scene with ground truth (`scene_meta.json` and the
/// BaseColor/Roughness/Metallic maps); empty without. `shadings` are per train view. The
/// pixels `left` names are left out, as the fits leave them out.
pub fn landscape(
    ds: &Dataset,
    hits: &[ViewHits],
    shadings: &[Vec<f32>],
    prior: fipt_core::model::loss::DiffusePrior,
    fitted: Option<&[ViewMaps]>,
    left: &LeftOut,
) -> Vec<PartLandscape> {
    let Some(meta) = ds.meta.as_ref() else {
        return Vec::new();
    };
    let tri_part = meta.triangle_part(ds.mesh.num_triangles());
    let sweep = sweep();
    let mut sums = vec![(0f64, 0f64); meta.parts.len()];
    let mut rows: Vec<PartLandscape> = meta
        .parts
        .iter()
        .map(|p| PartLandscape {
            name: p.name.clone(),
            pixels: 0,
            sigma_true: 0.0,
            m_true: 0.0,
            sigma: sweep.iter().map(|&s| s as f64).collect(),
            data: vec![0.0; SWEEP],
            prior: vec![0.0; SWEEP],
            argmin_data: f64::NAN,
            argmin_total: f64::NAN,
            render_ratio: f64::NAN,
            loss_true: 0.0,
            patch: Vec::new(),
            argmin_patch: f64::NAN,
            fitted: fitted.map(|_| FittedLandscape {
                sigma: 0.0,
                metallic: 0.0,
                loss: 0.0,
                data: vec![0.0; SWEEP],
                argmin_data: f64::NAN,
            }),
        })
        .collect();
    let err = |c: [f32; 3], gt: &[f32]| -> f64 {
        (0..3)
            .map(|k| (srgb(c[k]) - srgb(gt[k])).powi(2))
            .sum::<f64>()
            / 3.0
    };
    for (k, ((v, h), sh)) in ds.train.views.iter().zip(hits).zip(shadings).enumerate() {
        let (Some(base), Some(r), Some(mt)) = (
            v.map(MapKind::BaseColor),
            v.map(MapKind::Roughness),
            v.map(MapKind::Metallic),
        ) else {
            continue;
        };
        for (p, part) in part_pixels(meta, &tri_part, (k, v, h), left) {
            let row = &mut rows[part];
            let a = Vec3::from(base.rgb(p));
            let m = mt.scalar(p);
            let (kd, ks) = reflectances(a, m);
            let gt = &v.image.data[3 * p..3 * p + 3];
            let s = ShadingLayout::pixel(sh, p);
            let c = factorised_render(kd.to_array(), ks.to_array(), r.scalar(p), s);
            sums[part].0 += c.iter().map(|&x| x as f64).sum::<f64>();
            sums[part].1 += gt.iter().map(|&x| x as f64).sum::<f64>();
            row.loss_true += err(c, gt);
            row.pixels += 1;
            row.sigma_true += r.scalar(p) as f64;
            row.m_true += m as f64;
            for (i, &sig) in sweep.iter().enumerate() {
                let c = factorised_render(kd.to_array(), ks.to_array(), sig, s);
                row.data[i] += err(c, gt);
                row.prior[i] += prior.at(sig, m) as f64;
            }
            if let (Some(f), Some(maps)) = (row.fitted.as_mut(), fitted) {
                let mp = &maps[k];
                let a = Vec3::from_slice(&mp.base[3 * p..3 * p + 3]);
                let (kd, ks) = reflectances(a, mp.metallic[p]);
                let (kd, ks) = (kd.to_array(), ks.to_array());
                f.sigma += mp.sigma[p] as f64;
                f.metallic += mp.metallic[p] as f64;
                f.loss += err(factorised_render(kd, ks, mp.sigma[p], s), gt);
                for (i, &sig) in sweep.iter().enumerate() {
                    f.data[i] += err(factorised_render(kd, ks, sig, s), gt);
                }
            }
        }
    }
    for (r, (a, b)) in rows.iter_mut().zip(&sums) {
        r.render_ratio = a / b;
    }
    rows.retain(|r| r.pixels > 0);
    for r in &mut rows {
        let n = r.pixels as f64;
        r.sigma_true /= n;
        r.loss_true /= n;
        r.m_true /= n;
        for i in 0..SWEEP {
            r.data[i] /= n;
            r.prior[i] /= n;
        }
        let argmin = |f: &dyn Fn(usize) -> f64| {
            (0..SWEEP)
                .min_by(|&a, &b| f(a).total_cmp(&f(b)))
                .map_or(f64::NAN, |i| r.sigma[i])
        };
        r.argmin_data = argmin(&|i| r.data[i]);
        r.argmin_total = argmin(&|i| r.data[i] + r.prior[i]);
        let fitted_argmin = r.fitted.as_ref().map(|f| argmin(&|i| f.data[i]));
        if let (Some(f), Some(am)) = (r.fitted.as_mut(), fitted_argmin) {
            f.sigma /= n;
            f.metallic /= n;
            f.loss /= n;
            f.data.iter_mut().for_each(|d| *d /= n);
            f.argmin_data = am;
        }
    }
    rows
}

/// The data term over σ with the base colour solved per surface patch (`patches`): every
/// part's pixels grouped into cubes of side `side` (world units) by their centre ray's hit, at
/// the true metallic. A fit's base colour is free at every point; this profile says which σ
/// the view dependence supports when the colour is free too. Fills `patch` and `argmin_patch`
/// of `rows` (by part name).
pub fn patch_profile(
    ds: &Dataset,
    hits: &[ViewHits],
    shadings: &[Vec<f32>],
    left: &LeftOut,
    side: f32,
    rows: &mut [PartLandscape],
) {
    use super::patches::{PatchPixel, cubes, objective};
    let Some(meta) = ds.meta.as_ref() else {
        return;
    };
    let tri_part = meta.triangle_part(ds.mesh.num_triangles());
    let mut by_part: Vec<Vec<(usize, usize)>> = vec![Vec::new(); meta.parts.len()];
    for (k, (v, h)) in ds.train.views.iter().zip(hits).enumerate() {
        for (p, part) in part_pixels(meta, &tri_part, (k, v, h), left) {
            by_part[part].push((k, p));
        }
    }
    let sweep = sweep();
    for r in rows.iter_mut() {
        let Some(part) = meta.parts.iter().position(|p| p.name == r.name) else {
            continue;
        };
        let px = &by_part[part];
        if px.is_empty() {
            continue;
        }
        let pixels: Vec<PatchPixel> = px
            .iter()
            .map(|&(k, p)| {
                let v = &ds.train.views[k];
                let gt = &v.image.data[3 * p..3 * p + 3];
                PatchPixel {
                    shading: ShadingLayout::pixel(&shadings[k], p),
                    gt: [gt[0], gt[1], gt[2]],
                    metallic: v.map(MapKind::Metallic).map_or(0.0, |m| m.scalar(p)),
                    alpha: 0.0,
                }
            })
            .collect();
        let positions: Vec<[f32; 3]> = px
            .iter()
            .map(|&(k, p)| hits[k].position[p].to_array())
            .collect();
        let cubes = cubes(&positions, side);
        let n = pixels.len() as f64;
        r.patch = sweep
            .iter()
            .map(|&s| objective(&pixels, &cubes, &move |_| s) / n)
            .collect();
        r.argmin_patch = (0..SWEEP)
            .min_by(|&a, &b| r.patch[a].total_cmp(&r.patch[b]))
            .map_or(f64::NAN, |j| sweep[j] as f64);
    }
}
