//! The bake (paper §4.2, Eq. 9): ray cast the training views, build L′, bake and filter the
//! shadings, through the on-disk shading cache.
//!
//! Owns: the glue between the dataset and fipt-bake. Must not touch: the estimators
//! (fipt-bake) or the cache format (`cache`).

use crate::progress::progress_bar;
use fipt_bake::integrators::bake::{
    BakeConfig, BakeView, bake_views, build_light_field, build_light_field_without,
};
use fipt_bake::lightfield::LightField;
use fipt_bake::{Accel, ViewHits, cast_view};
use fipt_core::scene::{MapKind, Mesh, Split};

/// The products of the bake for one split.
pub struct Baked {
    pub hits: Vec<ViewHits>,
    pub light_field: LightField,
    /// `ShadingLayout::DIM` values per pixel, per view.
    pub shadings: Vec<Vec<f32>>,
    /// Secondary rays the bake cast (0 when the shadings came from the cache).
    pub rays: u64,
}

/// Casts every pixel-centre ray of a split.
pub fn cast_split(accel: &Accel, mesh: &Mesh, split: &Split) -> Vec<ViewHits> {
    split
        .views
        .iter()
        .map(|v| cast_view(accel, mesh, &v.camera))
        .collect()
}

/// Bakes the training split.
pub fn bake(
    accel: &Accel,
    mesh: &Mesh,
    train: &Split,
    cfg: &BakeConfig,
    show_progress: bool,
) -> anyhow::Result<Baked> {
    let hits = cast_split(accel, mesh, train);
    let views = train_views(train, &hits);
    let light_field = build_light_field(&views, mesh, cfg.voxel_res, cfg.fill_rings);
    let parts = (cfg.footprint > 0).then(|| part_keys(mesh, train, &hits));
    let pb = progress_bar(views.len() as u64, "bake", show_progress);
    // Ctrl-C stops after the current view (`interrupt`).
    let baked = bake_views(accel, &light_field, &views, cfg, parts.as_deref(), &|_| {
        pb.inc(1);
        !crate::interrupt::requested()
    });
    pb.finish_and_clear();
    drop(views);
    let baked = baked.ok_or_else(|| {
        crate::interrupt::Interrupted("interrupted during the bake (nothing of it saved)".into())
    })?;
    Ok(Baked {
        hits,
        light_field,
        shadings: baked.shadings,
        rays: baked.rays,
    })
}

/// Per triangle, the key of its part for the shadings' footprint (`bake.footprint`,
/// `refine.paths.footprint`): the majority label of the pixel-centre hits on it
/// (`segfuse::fuse_labels`) in the training split's part maps, else in its semantic maps; the
/// triangle's plane of the mesh (`ldr::edges::plane_keys`) without maps or votes.
pub fn part_keys(mesh: &Mesh, train: &Split, hits: &[ViewHits]) -> Vec<u64> {
    let planes = crate::ldr::edges::plane_keys(mesh);
    let kind = [MapKind::IndexMA, MapKind::Segmentation]
        .into_iter()
        .find(|&k| train.has_map(k));
    let Some(kind) = kind else {
        return planes;
    };
    let labels: Vec<Vec<i32>> = train
        .views
        .iter()
        .map(|v| v.labels(kind).unwrap_or_default())
        .collect();
    let fused = fipt_bake::segfuse::fuse_labels(mesh.num_triangles(), hits, &labels, None);
    fused
        .into_iter()
        .zip(planes)
        .map(|(l, plane)| {
            if l == fipt_bake::segfuse::UNLABELLED {
                plane
            } else {
                LABEL_KEY | l as u32 as u64
            }
        })
        .collect()
}

/// Marks a part key that is a label, apart from the planes' keys.
const LABEL_KEY: u64 = 1 << 63;

/// The bake with the on-disk cache: loads `out/cache/shadings.bin` when its key matches, else
/// bakes and writes it. Returns the products and whether they came from the cache.
pub fn bake_cached(
    out: &std::path::Path,
    ds: &fipt_core::scene::Dataset,
    accel: &Accel,
    cfg: &BakeConfig,
    show_progress: bool,
) -> anyhow::Result<(Baked, bool)> {
    let key = crate::cache::cache_key(ds, cfg)?;
    let path = out.join("cache").join("shadings.bin");
    let (w, h) = (ds.train.width, ds.train.height);
    if let Some(shadings) = crate::cache::load_or_discard(&path, key, ds.train.views.len(), w, h)? {
        let hits = cast_split(accel, &ds.mesh, &ds.train);
        let views: Vec<BakeView> = train_views(&ds.train, &hits);
        let light_field = build_light_field(&views, &ds.mesh, cfg.voxel_res, cfg.fill_rings);
        drop(views);
        return Ok((
            Baked {
                hits,
                light_field,
                shadings,
                rays: 0,
            },
            true,
        ));
    }
    let baked = bake(accel, &ds.mesh, &ds.train, cfg, show_progress)?;
    crate::cache::save(&path, key, w, h, &baked.shadings)?;
    Ok((baked, false))
}

/// L′ rebuilt from the training photos without the pixels that show an emitter
/// (`is_emitter` of their triangle) and those within `margin` pixels of one
/// (`pixels::on_or_near_emitters`), on the same grid and scene box, its holes filled as the
/// bake's; with the number of pixels left out.
pub fn light_field_without_emitters(
    ds: &fipt_core::scene::Dataset,
    baked: &Baked,
    cfg: &BakeConfig,
    is_emitter: impl Fn(i32) -> bool,
    margin: usize,
) -> (LightField, usize) {
    let left_out = super::pixels::on_or_near_emitters(&baked.hits, is_emitter, margin);
    let gone = left_out.iter().flatten().filter(|b| **b).count();
    let lf = light_field_replacing(ds, baked, cfg, |_, _| None, &|k, p| left_out[k][p]);
    (lf, gone)
}

/// L′ rebuilt as `light_field_without_emitters`, from the training photos less `specular`
/// (per view, 3 floats per pixel, as `fit::specular` gives it), clamped at 0: the radiance
/// cache of `refine.paths.cache_diffuse`.
pub fn light_field_diffuse(
    ds: &fipt_core::scene::Dataset,
    baked: &Baked,
    cfg: &BakeConfig,
    specular: &[Vec<f32>],
    is_emitter: impl Fn(i32) -> bool,
    margin: usize,
) -> LightField {
    let left_out =
        (margin > 0).then(|| super::pixels::on_or_near_emitters(&baked.hits, is_emitter, margin));
    light_field_replacing(
        ds,
        baked,
        cfg,
        |k, p| {
            let (img, s) = (
                ds.train.views[k].image.rgb(p),
                &specular[k][3 * p..3 * p + 3],
            );
            Some(std::array::from_fn(|c| (img[c] - s[c]).max(0.0)))
        },
        &|k, p| left_out.as_ref().is_some_and(|l| l[k][p]),
    )
}

/// L′ rebuilt from the training photos with some pixels' values replaced and some left out:
/// `replace(k, p)` gives pixel `p` of view `k` its value, or None to keep the photo's (only a
/// view with a replaced pixel is copied), and `left_out(k, p)` leaves it out; same grid, scene
/// box and hole filling as the bake's.
pub fn light_field_replacing(
    ds: &fipt_core::scene::Dataset,
    baked: &Baked,
    cfg: &BakeConfig,
    replace: impl Fn(usize, usize) -> Option<[f32; 3]>,
    left_out: &(dyn Fn(usize, usize) -> bool + Sync),
) -> LightField {
    let images: Vec<Option<Vec<f32>>> = ds
        .train
        .views
        .iter()
        .enumerate()
        .map(|(k, v)| {
            let mut img: Option<Vec<f32>> = None;
            for p in 0..v.image.data.len() / 3 {
                if let Some(x) = replace(k, p) {
                    img.get_or_insert_with(|| v.image.data.clone())[3 * p..3 * p + 3]
                        .copy_from_slice(&x);
                }
            }
            img
        })
        .collect();
    let mut views = train_views(&ds.train, &baked.hits);
    for (v, img) in views.iter_mut().zip(&images) {
        if let Some(img) = img {
            v.image = img;
        }
    }
    build_light_field_without(&views, &ds.mesh, cfg.voxel_res, cfg.fill_rings, left_out)
}

fn train_views<'a>(train: &'a Split, hits: &'a [ViewHits]) -> Vec<BakeView<'a>> {
    train
        .views
        .iter()
        .zip(hits)
        .map(|(v, h)| BakeView {
            hits: h,
            image: &v.image.data,
            camera: &v.camera,
        })
        .collect()
}
