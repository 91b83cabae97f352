//! Predicted per-view maps (reference §2.7): k_d, σ, m, base colour, directional albedo a′ and
//! emission at every pixel-centre hit, written in the ground truth's layout and naming so any
//! FIPT-layout tool reads both; plus PNG previews.
//!
//! Owns: map prediction and map files. Must not touch: scoring (`evaluate`).

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
    let mat = model.material_world(&xs);
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

fn rgb_of_scalar(v: &[f32]) -> Vec<f32> {
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
