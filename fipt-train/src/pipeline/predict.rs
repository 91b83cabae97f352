//! Predicted per-view maps (reference §2.7): k_d, σ, m, base colour, directional albedo a′ and
//! emission at every pixel-centre hit, written in the ground truth's layout and naming so any
//! FIPT-layout tool reads both; plus PNG previews.
//!
//! Owns: map prediction and map files. Must not touch: scoring (`evaluate`).

use crate::config::Config;
use anyhow::Result;
use fipt_bake::ViewHits;
use fipt_core::brdf::{Frame, reflectances, sample_specular};
use fipt_core::model::FiptModel;
use fipt_core::rng::Rng;
use fipt_core::scene::{Image, MapKind};
use glam::Vec3;
use rayon::prelude::*;
use std::path::Path;

/// One view's predicted maps (row-major; 3 values per pixel for colours, 1 for scalars).
#[derive(Clone, Debug)]
pub struct ViewMaps {
    pub width: usize,
    pub height: usize,
    pub kd: Vec<f32>,
    pub sigma: Vec<f32>,
    pub metallic: Vec<f32>,
    pub base: Vec<f32>,
    pub albedo: Vec<f32>,
    pub emit: Vec<f32>,
}

/// Monte Carlo directional albedo a′ = k_d + mean(k_s·g0 + g1) over GGX samples at σ.
pub fn albedo_mc(
    kd: Vec3,
    ks: Vec3,
    sigma: f32,
    n: Vec3,
    wo: Vec3,
    samples: usize,
    rng: &mut Rng,
) -> Vec3 {
    let frame = Frame::new(n);
    let wo_l = frame.to_local(wo);
    let (mut s0, mut s1) = (0.0f32, 0.0f32);
    for _ in 0..samples {
        if let Some((_, g0, g1)) = sample_specular(wo_l, sigma, rng.next_f32(), rng.next_f32()) {
            s0 += g0;
            s1 += g1;
        }
    }
    let inv = 1.0 / samples.max(1) as f32;
    kd + ks * (s0 * inv) + Vec3::splat(s1 * inv)
}

/// Predicts the maps of one view. Emitter pixels get the emitter's radiance and zero material
/// (as the reference does); missed pixels are zero.
pub fn predict_view(
    model: &FiptModel,
    hits: &ViewHits,
    emission: &[Vec3],
    albedo_samples: usize,
    seed: u64,
) -> ViewMaps {
    let n = hits.num_pixels();
    let idx: Vec<usize> = (0..n).filter(|&p| hits.tri[p] >= 0).collect();
    let xs: Vec<Vec3> = idx.iter().map(|&p| hits.position[p]).collect();
    let tris: Vec<u32> = idx.iter().map(|&p| hits.tri[p] as u32).collect();
    let mat = model.material_world(&xs, &tris);
    let mut m = ViewMaps {
        width: hits.width,
        height: hits.height,
        kd: vec![0.0; 3 * n],
        sigma: vec![0.0; n],
        metallic: vec![0.0; n],
        base: vec![0.0; 3 * n],
        albedo: vec![0.0; 3 * n],
        emit: vec![0.0; 3 * n],
    };
    let albedo: Vec<Vec3> = idx
        .par_iter()
        .enumerate()
        .map(|(i, &p)| {
            let a = Vec3::from_slice(&mat.a[3 * i..]);
            let (kd, ks) = reflectances(a, mat.metallic[i]);
            let mut rng = Rng::new(seed, p as u64);
            albedo_mc(
                kd,
                ks,
                mat.sigma[i],
                hits.normal[p],
                -hits.direction[p],
                albedo_samples,
                &mut rng,
            )
        })
        .collect();
    for (i, &p) in idx.iter().enumerate() {
        let e = emission[hits.tri[p] as usize];
        if e != Vec3::ZERO {
            m.emit[3 * p..3 * p + 3].copy_from_slice(&e.to_array());
            continue;
        }
        let a = Vec3::from_slice(&mat.a[3 * i..]);
        let (kd, _) = reflectances(a, mat.metallic[i]);
        m.kd[3 * p..3 * p + 3].copy_from_slice(&kd.to_array());
        m.base[3 * p..3 * p + 3].copy_from_slice(&a.to_array());
        m.albedo[3 * p..3 * p + 3].copy_from_slice(&albedo[i].to_array());
        m.sigma[p] = mat.sigma[i];
        m.metallic[p] = mat.metallic[i];
    }
    m
}

/// The maps of every view of `hits`, in view order, as `run` predicts them (the config's
/// albedo samples, each view's seed from `Seeds::view_maps`), each handed to `each` with its
/// view index.
pub fn for_each_view(
    model: &FiptModel,
    hits: &[ViewHits],
    emission: &[Vec3],
    cfg: &Config,
    mut each: impl FnMut(usize, ViewMaps) -> Result<()>,
) -> Result<()> {
    for (k, h) in hits.iter().enumerate() {
        let seed = cfg.seeds().view_maps(k);
        each(
            k,
            predict_view(model, h, emission, cfg.maps.albedo_samples, seed),
        )?;
    }
    Ok(())
}

/// `for_each_view`'s maps, collected.
pub fn predict_views(
    model: &FiptModel,
    hits: &[ViewHits],
    emission: &[Vec3],
    cfg: &Config,
) -> Vec<ViewMaps> {
    let mut maps = Vec::with_capacity(hits.len());
    let _ = for_each_view(model, hits, emission, cfg, |_, m| {
        maps.push(m);
        Ok(())
    });
    maps
}

pub(crate) fn rgb_of_scalar(v: &[f32]) -> Vec<f32> {
    v.iter().flat_map(|&x| [x, x, x]).collect()
}

impl ViewMaps {
    /// Writes the maps of frame `k` under `dir` (`DiffCol/{k:03}_0001.exr`, …, `albedo/{k:03}.exr`)
    /// and PNG previews under `dir/preview/`.
    pub fn write(&self, dir: &Path, k: usize) -> Result<()> {
        let (w, h) = (self.width, self.height);
        let maps: [(MapKind, Vec<f32>); 6] = [
            (MapKind::DiffCol, self.kd.clone()),
            (MapKind::Roughness, rgb_of_scalar(&self.sigma)),
            (MapKind::Metallic, rgb_of_scalar(&self.metallic)),
            (MapKind::BaseColor, self.base.clone()),
            (MapKind::Albedo, self.albedo.clone()),
            (MapKind::Emit, self.emit.clone()),
        ];
        for (kind, data) in maps {
            let img = Image::from_data(w, h, 3, data);
            img.write_exr(&dir.join(kind.folder()).join(kind.file_name(k)))?;
            let scale = if kind == MapKind::Emit { 0.1 } else { 1.0 };
            crate::output::write_png(
                &dir.join("preview")
                    .join(format!("{k:03}_{}.png", kind.folder())),
                w,
                h,
                &img.data,
                scale,
            )?;
        }
        Ok(())
    }

    /// Reads maps written by `write`.
    pub fn read(dir: &Path, k: usize) -> Result<ViewMaps> {
        let rd = |kind: MapKind| Image::read_exr(&dir.join(kind.folder()).join(kind.file_name(k)));
        let kd = rd(MapKind::DiffCol)?;
        let first = |img: Image| img.first_channel().data;
        Ok(ViewMaps {
            width: kd.width,
            height: kd.height,
            sigma: first(rd(MapKind::Roughness)?),
            metallic: first(rd(MapKind::Metallic)?),
            base: rd(MapKind::BaseColor)?.data,
            albedo: rd(MapKind::Albedo)?.data,
            emit: rd(MapKind::Emit)?.data,
            kd: kd.data,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fipt_core::brdf::{Brdf, directional_albedo_quadrature};

    /// `albedo_mc` (k_d + mean of the GGX-sampled specular weights) against the midpoint
    /// quadrature of the full BRDF ∫ f cos dω_i (whose diffuse part integrates to k_d).
    ///
    /// Tolerance per channel: 4 standard errors of the mean over independent seeds, plus the
    /// quadrature's own error estimated as |Q(n) − Q(n/2)|, plus the worst case of the f32
    /// running sums inside one `albedo_mc` call (half an ulp of the final sum per addition).
    /// Both sides accumulate in f32, so neither is pushed far: the quadrature drifts by over 1 %
    /// beyond ~2M grid points (its small terms fall below the sum's ulp), and a single
    /// `albedo_mc` call with ~1M samples is biased by ~0.5 %; hence grids of at most 512×1024
    /// and many seeds of 1024 samples.
    #[test]
    fn albedo_mc_matches_quadrature() {
        let n = Vec3::new(0.3, -0.5, 0.8).normalize();
        let frame = Frame::new(n);
        // (k_d, k_s, σ, view angle from the normal in degrees, quadrature resolution).
        let cases = [
            (
                Vec3::new(0.6, 0.4, 0.2),
                Vec3::splat(0.04),
                1.0f32,
                30f32,
                256usize,
            ),
            (
                Vec3::new(0.25, 0.2, 0.1),
                Vec3::new(0.29, 0.24, 0.14),
                0.5,
                75.0,
                256,
            ),
            (Vec3::ZERO, Vec3::new(0.95, 0.64, 0.54), 0.1, 20.0, 512),
            (Vec3::new(0.5, 0.1, 0.1), Vec3::splat(0.04), 0.12, 45.0, 512),
        ];
        let (seeds, samples) = (256usize, 1024usize);
        for (kd, ks, sigma, deg, res) in cases {
            let th = deg.to_radians();
            let wo_local = Vec3::new(th.sin() * 0.6, th.sin() * 0.8, th.cos());
            let wo = frame.to_world(wo_local);
            let brdf = Brdf { kd, ks, sigma };
            let q = directional_albedo_quadrature(&brdf, wo_local, res, 2 * res);
            let q_half = directional_albedo_quadrature(&brdf, wo_local, res / 2, res);
            let est: Vec<Vec3> = (0..seeds)
                .map(|s| albedo_mc(kd, ks, sigma, n, wo, samples, &mut Rng::new(17, s as u64)))
                .collect();
            let mean = est.iter().sum::<Vec3>() / seeds as f32;
            let var =
                est.iter().map(|e| (*e - mean) * (*e - mean)).sum::<Vec3>() / (seeds - 1) as f32;
            let se = (var / seeds as f32).powf(0.5);
            let spec = q - kd;
            for c in 0..3 {
                let rounding = (mean[c] - kd[c]).abs() * samples as f32 * f32::EPSILON;
                let quad_err = (q[c] - q_half[c]).abs();
                let tol = 4.0 * se[c] + quad_err + rounding;
                assert!(
                    (mean[c] - q[c]).abs() <= tol,
                    "σ {sigma}, {deg}°, channel {c}: albedo_mc {} vs quadrature {} (tol {tol})",
                    mean[c],
                    q[c]
                );
                // The check resolves the specular lobe: its tolerance is a small fraction of it.
                assert!(
                    tol < 0.05 * spec[c],
                    "channel {c}: tolerance {tol} vs lobe {}",
                    spec[c]
                );
            }
        }
    }
}
