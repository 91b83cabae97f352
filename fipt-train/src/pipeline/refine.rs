//! Shading refinement (paper §4.3, Eq. 10–11): the training pixels' shadings path-traced with
//! the current model (its material field at every path vertex, through a voxel cache of the
//! field at the training hits), the extracted emitters (from both sides or the observed ones,
//! uniform selection, not reflecting) and L′ as the radiance cache on rough secondary hits. Each round's shadings are
//! cached on disk, keyed by the bake and by the model that produced them.
//!
//! Owns: the glue between the fitted model, the emitters and `fipt_bake::integrators::refine`.
//! Must not touch: the estimators.

use super::bake::Baked;
use super::context::RunContext;
use super::pixels::PixelStore;
use crate::learned::LearnedMaterials;
use crate::progress::progress_bar;
use fipt_bake::Accel;
use fipt_bake::accel::footprint::ViewFootprint;
use fipt_bake::accel::raycast::ViewHits;
use fipt_bake::emitters::{Emitter, EmitterSet, EmitterSides, LightSelection};
use fipt_bake::integrators::path::{PathScene, PathStats, RadianceCache};
use fipt_bake::integrators::refine::{PixelPaths, RefineConfig, refine_view};
use fipt_bake::lightfield::LightField;
use fipt_bake::materials::{MaterialSource, SurfaceMaterial, Unseen, VoxelMaterials};
use fipt_core::io::Fnv64;
use fipt_core::model::FiptModel;
use fipt_core::scene::Dataset;
use fipt_core::shading::ShadingLayout;
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
/// the emitters, the refinement config (with its seed) and the store's pixels (whose hits the
/// material cache averages the field over; `refine.emitter_margin` leaves some out).
pub fn refine_key(
    bake_key: u64,
    model: &FiptModel,
    emitters: &[Emitter],
    cfg: &RefineConfig,
    store: &PixelStore,
) -> anyhow::Result<u64> {
    let mut h = Fnv64::default();
    h.bytes(&bake_key.to_le_bytes());
    h.bytes(&REFINE_CODE_VERSION.to_le_bytes());
    for &(k, p) in &store.origin {
        h.bytes(&k.to_le_bytes());
        h.bytes(&p.to_le_bytes());
    }
    h.f32s(&model.grid.table);
    for p in model.net_params() {
        h.f32s(&p);
    }
    for e in emitters {
        h.bytes(&e.triangle.to_le_bytes());
        h.f32s(&e.radiance);
    }
    h.bytes(serde_json::to_string(cfg)?.as_bytes());
    h.bytes(&cfg.seed.to_le_bytes());
    Ok(h.finish())
}

/// Bumped whenever the refinement's maths changes.
const REFINE_CODE_VERSION: u32 = 1;

/// What a refinement path-traces: the scene, its bake, the estimators' config and which
/// training views.
pub struct RefineJob<'a> {
    pub ds: &'a Dataset,
    pub accel: &'a Accel,
    pub baked: &'a Baked,
    /// The radiance cache's L′ (the bake's, or rebuilt without the pixels next to the
    /// emitters: `RefineConfig::cache_margin`).
    pub light_field: &'a LightField,
    pub cfg: &'a RefineConfig,
    /// Train view indices (all of them in `run`).
    pub views: &'a [usize],
    /// Query the learned field through the voxel cache (`false`: the exact field at every
    /// vertex).
    pub material_cache: bool,
    pub show_progress: bool,
}

/// Path-traces the shadings of the job's training views with `model` and `emitters`.
pub fn refine(
    job: &RefineJob,
    store: &PixelStore,
    model: &FiptModel,
    emitters: &[Emitter],
) -> anyhow::Result<Refined> {
    let mesh = &job.ds.mesh;
    let emitter_tris: Vec<u32> = emitters.iter().map(|e| e.triangle).collect();
    let learned = LearnedMaterials::new(model.clone(), mesh.num_triangles(), &emitter_tris);
    // The field at the training hits, averaged per voxel of L′'s grid; emitter triangles
    // always go to the learned source (black).
    let lf = job.light_field;
    let known =
        (job.material_cache || job.cfg.unseen_cell > 0 || job.cfg.sharp.is_some()).then(|| {
            let mv = model.material(&store.pixels.x_unit, &store.pixels.part);
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
            (points, mats)
        });
    // Where no training pixel saw the surface, the part's mean (`refine.paths.unseen_cell`).
    let unseen = known
        .as_ref()
        .filter(|_| job.cfg.unseen_cell > 0)
        .map(|(p, m)| {
            let keys = super::bake::part_keys(mesh, &job.ds.train, &job.baked.hits);
            Unseen::build(
                lf.scene_box,
                lf.res.div_ceil(job.cfg.unseen_cell),
                (p, &store.tri, m),
                &keys,
                learned.black(),
                &learned,
            )
        });
    let field: &dyn MaterialSource = unseen.as_ref().map_or(&learned, |u| u as _);
    let voxels = known
        .as_ref()
        .filter(|_| job.material_cache)
        .map(|(points, mats)| {
            VoxelMaterials::build(
                lf.scene_box,
                lf.res,
                points,
                mats,
                field,
                learned.black().to_vec(),
            )
        });
    let source: &dyn MaterialSource = match &voxels {
        Some(v) => v,
        None => field,
    };
    // The pixels the field puts below `refine.paths.sharp.below` take its paths per level.
    let sharp = job
        .cfg
        .sharp
        .as_ref()
        .zip(known.as_ref())
        .map(|(s, (_, mats))| {
            let train = &job.ds.train;
            let mut flags = vec![vec![false; train.width * train.height]; train.views.len()];
            for (&(v, p), m) in store.origin.iter().zip(mats) {
                flags[v as usize][p as usize] = m.roughness < s.below;
            }
            flags
        });
    let lights = learned_lights(mesh, emitters, job.cfg);
    let (shadings, stats) = refine_with(job, source, &lights, sharp.as_deref())?;
    Ok(Refined {
        shadings,
        stats,
        material_voxels: voxels.as_ref().map_or(0, VoxelMaterials::len),
    })
}

/// The extracted emitters as the refinement's lights: from the sides the photos saw them from
/// with `observed_sides`, else from both; uniform selection.
fn learned_lights(
    mesh: &fipt_core::scene::Mesh,
    emitters: &[Emitter],
    cfg: &RefineConfig,
) -> EmitterSet {
    EmitterSet::with_sides(
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
    )
}

/// Path-traces the shadings of the job's training views with any material source and
/// emitters (the learned model's in `refine`, the ground truth's for the oracle); `sharp`,
/// per view and pixel, flags the pixels that take `refine.paths.sharp`'s paths.
pub fn refine_with(
    job: &RefineJob,
    materials: &dyn MaterialSource,
    lights: &EmitterSet,
    sharp: Option<&[Vec<bool>]>,
) -> anyhow::Result<(Vec<Vec<f32>>, PathStats)> {
    let (cfg, baked) = (job.cfg, job.baked);
    let scene = PathScene {
        secondary_materials: None,
        accel: job.accel,
        materials,
        emitters: lights,
        cache: Some(RadianceCache {
            light_field: job.light_field,
            min_roughness: cfg.cache_roughness,
        }),
    };
    let keys = (cfg.footprint > 0 || cfg.small_parts > 0)
        .then(|| super::bake::part_keys(&job.ds.mesh, &job.ds.train, &baked.hits));
    let parts = keys.as_deref().filter(|_| cfg.footprint > 0);
    let passes = keys
        .as_deref()
        .filter(|_| cfg.small_parts > 0)
        .map(|keys| small_part_passes(keys, &baked.hits, cfg));
    let pb = progress_bar(job.views.len() as u64, "refine", job.show_progress);
    let mut stats = PathStats::default();
    let mut shadings = Vec::with_capacity(job.views.len());
    for &k in job.views {
        // Ctrl-C stops between views (`interrupt`).
        if crate::interrupt::requested() {
            pb.finish_and_clear();
            return Err(crate::interrupt::Interrupted(
                "interrupted during a refinement (nothing of it saved)".into(),
            )
            .into());
        }
        let (v, h) = (&job.ds.train.views[k], &baked.hits[k]);
        let fp = ViewFootprint::cast(job.accel, &v.camera, h, parts, cfg.footprint);
        let n = passes.as_ref().map(|p| p[k].as_slice());
        let per_pixel = PixelPaths {
            passes: n,
            sharp: sharp.map(|f| f[k].as_slice()),
        };
        let (s, st) = refine_view(&scene, h, &fp, v.camera.fx as f32, cfg, k as u64, per_pixel);
        stats.add(&st);
        pb.inc(1);
        shadings.push(s);
    }
    pb.finish_and_clear();
    Ok((shadings, stats))
}

/// Per view and pixel, how many estimates `refine_view` averages (`RefineConfig::small_parts`):
/// by the number of pixels of the pixel's part (`keys`, per triangle) over every view of
/// `hits`; 1 where the centre ray missed.
fn small_part_passes(keys: &[u64], hits: &[ViewHits], cfg: &RefineConfig) -> Vec<Vec<u32>> {
    let mut seen: std::collections::HashMap<u64, usize> = std::collections::HashMap::new();
    for h in hits {
        for &t in h.tri.iter().filter(|&&t| t >= 0) {
            *seen.entry(keys[t as usize]).or_default() += 1;
        }
    }
    hits.iter()
        .map(|h| {
            h.tri
                .iter()
                .map(|&t| {
                    if t < 0 {
                        1
                    } else {
                        cfg.passes_for(seen[&keys[t as usize]])
                    }
                })
                .collect()
        })
        .collect()
}

/// Oracle shadings of the job's views: path-traced with the scene's true materials and emitters
/// (one-sided, as Mitsuba rendered them), for the ceiling of the factorised model. Needs
/// `scene_meta.json`.
pub fn oracle(scene_dir: &std::path::Path, job: &RefineJob) -> anyhow::Result<Vec<Vec<f32>>> {
    let ds = job.ds;
    let meta_path = scene_dir.join("scene_meta.json");
    let Some(meta) = ds.meta.as_ref() else {
        anyhow::bail!(
            "{}: oracle shadings need the scene's true materials (missing)",
            meta_path.display()
        );
    };
    let ntri = ds.mesh.num_triangles();
    let materials = fipt_bake::materials::TrueMaterials::load(scene_dir, &meta_path, meta, ntri)?;
    Ok(refine_with(job, &materials, &true_lights(ds, meta), None)?.0)
}

/// The scene's true emitters, one-sided as Mitsuba rendered them, uniform selection.
fn true_lights(ds: &Dataset, meta: &fipt_core::scene::meta::SceneMeta) -> EmitterSet {
    let emission = meta.triangle_emission(ds.mesh.num_triangles());
    EmitterSet::new(
        &ds.mesh,
        emission
            .iter()
            .enumerate()
            .map(|(t, e)| (t as u32, Vec3::from(*e))),
        false,
        LightSelection::Uniform,
    )
}

/// Per name in `parts`, which triangles of the scene's mesh its part holds; an error that
/// lists the scene's parts where one is missing, or where the scene has no `scene_meta.json`.
pub fn part_triangles(
    scene: &std::path::Path,
    ds: &Dataset,
    parts: &[String],
) -> anyhow::Result<Vec<(String, Vec<bool>)>> {
    let meta_path = scene.join("scene_meta.json");
    let Some(meta) = ds.meta.as_ref() else {
        anyhow::bail!(
            "{}: swapping parts needs the scene's true materials (missing)",
            meta_path.display()
        );
    };
    let part_of = meta.triangle_part(ds.mesh.num_triangles());
    parts
        .iter()
        .map(|name| {
            let Some(p) = meta.parts.iter().find(|p| &p.name == name) else {
                let names: Vec<&str> = meta.parts.iter().map(|p| p.name.as_str()).collect();
                anyhow::bail!(
                    "{}: no part named {name:?} (its parts: {})",
                    meta_path.display(),
                    names.join(", ")
                );
            };
            Ok((name.clone(), part_of.iter().map(|&q| q == p.id).collect()))
        })
        .collect()
}

/// The shadings of every training view with part of the oracle swapped for a fitted model's
/// (`fipt-train landscape --swap`): its material field (exact queries) with its emitters, with
/// the true emitters, and the true materials with its emitters; the true scene through the
/// refinement's voxel cache of materials (`true_voxels`); then, per part of `parts`
/// (name and triangles, `part_triangles`), the true scene with that part's material the
/// model's. As (name, shadings). All go through
/// the oracle's paths and radiance cache, so that against the oracle's shadings each differs
/// by what it swaps alone.
pub fn swapped(
    ctx: &RunContext,
    baked: &Baked,
    model: &FiptModel,
    emitters: &[Emitter],
    parts: &[(String, Vec<bool>)],
) -> anyhow::Result<Vec<(String, Vec<Vec<f32>>)>> {
    let ds = &ctx.ds;
    let meta_path = ctx.scene.join("scene_meta.json");
    let Some(meta) = ds.meta.as_ref() else {
        anyhow::bail!(
            "{}: swapped shadings need the scene's true materials (missing)",
            meta_path.display()
        );
    };
    let ntri = ds.mesh.num_triangles();
    let truth = fipt_bake::materials::TrueMaterials::load(ctx.scene, &meta_path, meta, ntri)?;
    let rcfg = ctx.cfg.oracle_paths();
    let lf = oracle_light_field(ctx, baked, &rcfg);
    let all: Vec<usize> = (0..ds.train.views.len()).collect();
    let job = oracle_job(ctx, baked, &rcfg, lf.as_ref(), &all);
    let (fitted, real) = (
        learned_lights(&ds.mesh, emitters, &rcfg),
        true_lights(ds, meta),
    );
    // Each material source is black on the triangles that end paths as emitters.
    let learned = |lights: &[u32]| LearnedMaterials::new(model.clone(), ntri, lights);
    let fitted_tris: Vec<u32> = emitters.iter().map(|e| e.triangle).collect();
    let real_tris: Vec<u32> = meta
        .triangle_emission(ntri)
        .iter()
        .enumerate()
        .filter(|(_, e)| e.iter().any(|&c| c > 0.0))
        .map(|(t, _)| t as u32)
        .collect();
    let model_real = learned(&real_tris);
    let mut out = vec![
        (
            "model".to_string(),
            refine_with(&job, &learned(&fitted_tris), &fitted, None)?.0,
        ),
        (
            "model, true emitters".to_string(),
            refine_with(&job, &model_real, &real, None)?.0,
        ),
        (
            "true materials, model emitters".to_string(),
            refine_with(&job, &truth, &fitted, None)?.0,
        ),
        (
            "true materials, voxel cache".to_string(),
            refine_with(
                &job,
                &true_voxels(job.light_field, baked, &truth, ntri, &real_tris),
                &real,
                None,
            )?
            .0,
        ),
    ];
    for (name, from_second) in parts {
        let split = fipt_bake::materials::Split {
            first: &truth,
            second: &model_real,
            from_second: from_second.clone(),
        };
        out.push((
            format!("true scene, the model's {name}"),
            refine_with(&job, &split, &real, None)?.0,
        ));
    }
    Ok(out)
}

/// The true materials as the refinement reads a learned field: their mean per voxel of
/// `light_field`'s grid over the training pixels' first hits, whatever part each hit is on;
/// the `lights` triangles (emitters) and the voxels no hit is in go to `truth`.
fn true_voxels<'a>(
    light_field: &LightField,
    baked: &Baked,
    truth: &'a fipt_bake::materials::TrueMaterials,
    ntri: usize,
    lights: &[u32],
) -> VoxelMaterials<'a> {
    let mut lit = vec![false; ntri];
    for &t in lights {
        lit[t as usize] = true;
    }
    let (points, tris): (Vec<Vec3>, Vec<u32>) = baked
        .hits
        .iter()
        .flat_map(|h| h.position.iter().zip(&h.tri))
        .filter(|&(_, &t)| t >= 0 && !lit[t as usize])
        .map(|(&p, &t)| (p, t as u32))
        .unzip();
    let mut mats = Vec::with_capacity(points.len());
    truth.query(&points, &tris, &mut mats);
    VoxelMaterials::build(
        light_field.scene_box,
        light_field.res,
        &points,
        &mats,
        truth,
        lit,
    )
}

/// The specular radiance k_s·L_s0(σ) + L_s1(σ) of the true materials (the train views' base
/// colour, roughness and metallic maps) on the baked shadings, per view and pixel; None when
/// a map is missing.
fn true_specular(ds: &Dataset, baked: &Baked) -> Option<Vec<Vec<f32>>> {
    use fipt_core::scene::MapKind;
    ds.train
        .views
        .iter()
        .zip(&baked.shadings)
        .map(|(v, sh)| {
            let (a, r, m) = (
                v.map(MapKind::BaseColor)?,
                v.map(MapKind::Roughness)?,
                v.map(MapKind::Metallic)?,
            );
            let n = v.image.num_pixels();
            let mut out = vec![0f32; 3 * n];
            for p in 0..n {
                let (_, ks) = fipt_core::brdf::reflectances(Vec3::from(a.rgb(p)), m.scalar(p));
                let c = fipt_core::brdf::factorised_render(
                    [0.0; 3],
                    ks.to_array(),
                    r.scalar(p),
                    ShadingLayout::pixel(sh, p),
                );
                out[3 * p..3 * p + 3].copy_from_slice(&c);
            }
            Some(out)
        })
        .collect()
}

/// The oracle shadings of every training view of a scene with ground truth, cached in
/// `out/cache/oracle.bin` under the bake's key and the oracle's path config.
pub fn oracle_cached(ctx: &RunContext, baked: &Baked) -> anyhow::Result<Vec<Vec<f32>>> {
    let (ds, cfg) = (&ctx.ds, ctx.cfg);
    let rcfg = cfg.oracle_paths();
    let mut h = Fnv64::default();
    h.bytes(&ctx.bake_key.to_le_bytes());
    h.bytes(b"oracle");
    h.bytes(serde_json::to_string(&rcfg)?.as_bytes());
    h.bytes(&rcfg.seed.to_le_bytes());
    let key = h.finish();
    let path = ctx.out.join("cache").join("oracle.bin");
    let (w, hh) = (ds.train.width, ds.train.height);
    if let Some(s) = crate::cache::load_or_discard(&path, key, ds.train.views.len(), w, hh)? {
        return Ok(s);
    }
    let all: Vec<usize> = (0..ds.train.views.len()).collect();
    let rebuilt = oracle_light_field(ctx, baked, &rcfg);
    let job = oracle_job(ctx, baked, &rcfg, rebuilt.as_ref(), &all);
    let s = oracle(ctx.scene, &job)?;
    crate::cache::save(&path, key, w, hh, &s)?;
    Ok(s)
}

/// The oracle's refinement job over `views`: exact material queries, through `light_field`
/// (`oracle_light_field`; None: the bake's L′).
fn oracle_job<'a>(
    ctx: &'a RunContext,
    baked: &'a Baked,
    cfg: &'a RefineConfig,
    light_field: Option<&'a LightField>,
    views: &'a [usize],
) -> RefineJob<'a> {
    RefineJob {
        ds: &ctx.ds,
        accel: &ctx.accel,
        baked,
        light_field: light_field.unwrap_or(&baked.light_field),
        cfg,
        views,
        material_cache: false,
        show_progress: ctx.progress(),
    }
}

/// The oracle's radiance cache: L′ without the pixels next to the true emitters, as the
/// refinement's leaves out those next to the extracted ones; with `cache_diffuse`, the photos
/// less the true materials' specular radiance. None: the bake's L′.
fn oracle_light_field(ctx: &RunContext, baked: &Baked, rcfg: &RefineConfig) -> Option<LightField> {
    let ds = &ctx.ds;
    match (&ds.meta, rcfg.cache_margin) {
        (Some(meta), m) if m > 0 || rcfg.cache_diffuse => {
            let emission = meta.triangle_emission(ds.mesh.num_triangles());
            let lit = |t: i32| emission[t as usize].iter().any(|&c| c > 0.0);
            let spec = rcfg
                .cache_diffuse
                .then(|| true_specular(ds, baked))
                .flatten();
            match spec {
                Some(spec) => Some(super::bake::light_field_diffuse(
                    ds,
                    baked,
                    &ctx.bake_cfg,
                    &spec,
                    lit,
                    m,
                )),
                None if m > 0 => Some(
                    super::bake::light_field_without_emitters(ds, baked, &ctx.bake_cfg, lit, m).0,
                ),
                None => None,
            }
        }
        _ => None,
    }
}
