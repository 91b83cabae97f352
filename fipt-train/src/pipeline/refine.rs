//! Shading refinement (paper §4.3, Eq. 10–11): the training pixels' shadings path-traced with
//! the current model (its material field at every path vertex, through a voxel cache of the
//! field at the training hits), the extracted emitters (from both sides or the observed ones,
//! uniform selection, not reflecting) and L′ as the radiance cache on rough secondary hits. Each round's shadings are
//! cached on disk, keyed by the bake and by the model that produced them.
//!
//! Owns: the glue between the fitted model, the emitters and `fipt_bake::integrators::refine`.
//! Must not touch: the estimators.

use super::bake::Baked;
use super::pixels::PixelStore;
use crate::learned::LearnedMaterials;
use crate::progress::progress_bar;
use fipt_bake::Accel;
use fipt_bake::emitters::{Emitter, EmitterSet, EmitterSides, LightSelection};
use fipt_bake::integrators::path::{PathScene, PathStats, RadianceCache};
use fipt_bake::integrators::refine::{RefineConfig, refine_view};
use fipt_bake::materials::{MaterialSource, SurfaceMaterial, VoxelMaterials};
use fipt_core::io::Fnv64;
use fipt_core::model::FiptModel;
use fipt_core::scene::{Mesh, Split};
use glam::Vec3;

/// The refined shadings of one round.
pub struct Refined {
    /// `ShadingLayout::DIM` values per pixel, per view.
    pub shadings: Vec<Vec<f32>>,
    pub stats: PathStats,
    /// Voxels of the material cache (0 with exact queries).
    pub material_voxels: usize,
}

/// A key of everything the refined shadings depend on beyond the bake: the model's parameters,
/// the emitters and the refinement config (with its seed).
pub fn refine_key(
    bake_key: u64,
    model: &FiptModel,
    emitters: &[Emitter],
    cfg: &RefineConfig,
) -> u64 {
    let mut h = Fnv64::default();
    h.bytes(&bake_key.to_le_bytes());
    h.bytes(&REFINE_CODE_VERSION.to_le_bytes());
    h.f32s(&model.grid.table);
    for p in model.net_params() {
        h.f32s(&p);
    }
    for e in emitters {
        h.bytes(&e.triangle.to_le_bytes());
        h.f32s(&e.radiance);
    }
    h.bytes(serde_json::to_string(cfg).unwrap_or_default().as_bytes());
    h.bytes(&cfg.seed.to_le_bytes());
    h.finish()
}

/// Bumped whenever the refinement's maths changes.
const REFINE_CODE_VERSION: u32 = 1;

/// Which views to refine and how the learned field is queried.
pub struct RefineScope<'a> {
    /// Train view indices (all of them in `run`).
    pub views: &'a [usize],
    /// Query the field through the voxel cache (`false`: the exact field at every vertex).
    pub material_cache: bool,
}

/// Path-traces the shadings of the scope's training views with `model` and `emitters`.
#[allow(clippy::too_many_arguments)]
pub fn refine(
    mesh: &Mesh,
    accel: &Accel,
    train: &Split,
    baked: &Baked,
    store: &PixelStore,
    model: &FiptModel,
    emitters: &[Emitter],
    cfg: &RefineConfig,
    scope: &RefineScope,
    show_progress: bool,
) -> anyhow::Result<Refined> {
    let emitter_tris: Vec<u32> = emitters.iter().map(|e| e.triangle).collect();
    let learned = LearnedMaterials::new(model.clone(), mesh.num_triangles(), &emitter_tris);
    // The field at the training hits, averaged per voxel of L′'s grid; emitter triangles
    // always go to the learned source (black).
    let voxels = scope.material_cache.then(|| {
        let mv = model.material(&store.pixels.x_unit);
        let mats: Vec<SurfaceMaterial> = (0..store.len())
            .map(|i| SurfaceMaterial {
                base_color: Vec3::from_slice(&mv.a[3 * i..3 * i + 3]),
                roughness: mv.sigma[i],
                metallic: mv.metallic[i],
            })
            .collect();
        let points: Vec<Vec3> = store
            .pixels
            .x_world
            .iter()
            .map(|p| Vec3::from(*p))
            .collect();
        let lf = &baked.light_field;
        VoxelMaterials::build(
            lf.scene_box,
            lf.res,
            &points,
            &mats,
            &learned,
            learned.black().to_vec(),
        )
    });
    let source: &dyn MaterialSource = match &voxels {
        Some(v) => v,
        None => &learned,
    };
    let lights = EmitterSet::with_sides(
        mesh,
        emitters.iter().map(|e| {
            let sides = if cfg.observed_sides {
                e.observed_sides()
            } else {
                EmitterSides::Both
            };
            (e.triangle, Vec3::from(e.radiance), sides)
        }),
        LightSelection::Uniform,
    );
    let (shadings, stats) = refine_with(
        accel,
        train,
        baked,
        source,
        &lights,
        cfg,
        scope.views,
        show_progress,
    )?;
    Ok(Refined {
        shadings,
        stats,
        material_voxels: voxels.as_ref().map_or(0, VoxelMaterials::len),
    })
}

/// Path-traces the shadings of the given training views with any material source and
/// emitters (the learned model's in `refine`, the ground truth's for the oracle).
#[allow(clippy::too_many_arguments)]
pub fn refine_with(
    accel: &Accel,
    train: &Split,
    baked: &Baked,
    materials: &dyn MaterialSource,
    lights: &EmitterSet,
    cfg: &RefineConfig,
    views: &[usize],
    show_progress: bool,
) -> anyhow::Result<(Vec<Vec<f32>>, PathStats)> {
    let scene = PathScene {
        secondary_materials: None,
        accel,
        materials,
        emitters: lights,
        cache: Some(RadianceCache {
            light_field: &baked.light_field,
            min_roughness: cfg.cache_roughness,
        }),
    };
    let pb = progress_bar(views.len() as u64, "refine", show_progress);
    let mut stats = PathStats::default();
    let mut shadings = Vec::with_capacity(views.len());
    for &k in views {
        // Ctrl-C stops between views (`interrupt`).
        if crate::interrupt::requested() {
            pb.finish_and_clear();
            return Err(crate::interrupt::Interrupted(
                "interrupted during a refinement (nothing of it saved)".into(),
            )
            .into());
        }
        let (v, h) = (&train.views[k], &baked.hits[k]);
        let (s, st) = refine_view(&scene, h, v.camera.fx as f32, cfg, k as u64);
        stats.add(&st);
        pb.inc(1);
        shadings.push(s);
    }
    pb.finish_and_clear();
    Ok((shadings, stats))
}

/// Oracle shadings: path-traced with the scene's true materials and emitters (one-sided, as
/// Mitsuba rendered them), for the ceiling of the factorised model. Needs `scene_meta.json`.
pub fn oracle(
    scene_dir: &std::path::Path,
    ds: &fipt_core::scene::Dataset,
    accel: &Accel,
    baked: &Baked,
    cfg: &RefineConfig,
    show_progress: bool,
) -> anyhow::Result<Vec<Vec<f32>>> {
    let meta_path = scene_dir.join("scene_meta.json");
    let Some(meta) = ds.meta.as_ref() else {
        anyhow::bail!(
            "{}: oracle shadings need the scene's true materials (missing)",
            meta_path.display()
        );
    };
    let ntri = ds.mesh.num_triangles();
    let materials = fipt_bake::materials::TrueMaterials::load(scene_dir, &meta_path, meta, ntri)?;
    let emission = meta.triangle_emission(ntri);
    let lights = EmitterSet::new(
        &ds.mesh,
        emission
            .iter()
            .enumerate()
            .map(|(t, e)| (t as u32, Vec3::from(*e))),
        false,
        LightSelection::Uniform,
    );
    let all: Vec<usize> = (0..ds.train.views.len()).collect();
    Ok(refine_with(
        accel,
        &ds.train,
        baked,
        &materials,
        &lights,
        cfg,
        &all,
        show_progress,
    )?
    .0)
}
