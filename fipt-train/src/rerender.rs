//! `fipt-train render`: path-traced images with the wavefront path tracer of fipt-bake, of
//! either scene:
//! - `--truth`: the true scene of `scene_meta.json` (materials, textures, emitters);
//! - `--model NAME_OR_DIR`: a recovered scene model (`scene_model`): the learned BRDF at every
//!   hit, the extracted emitters (emitting from the sides the photos saw; their own BRDF black,
//!   as the reference's relighting demo), and for view synthesis the reference's scheme (§2.7):
//!   BRDF-sampled rays that hit a surface rougher than 0.6 take L′ there (`--no-cache`: pure
//!   path tracing). Relighting never uses L′ (it holds the old lighting).
//!
//! With `--relight` a `relight.json` switches emitters off or rescales them (by part name or
//! `"all"`) and adds new ones; renders go to `Relight/`. With `--insert` objects are placed in
//! the scene (`fipt_core::scene::insert`). Where the scene has reference images (`Image/`, or
//! `Relight/` when relighting) each view is scored against them (PSNR of clip(x, 0, 1)^(1/2.2),
//! mean-radiance ratio).
//!
//! Owns: the render job (scene assembly, outputs, scores, `render.json`). Must not touch: light
//! transport (fipt-bake), the model's inference (`learned`).

use crate::image_metrics::psnr_gamma;
use crate::learned::LearnedMaterials;
use crate::output::{write_json, write_png};
use crate::progress::progress_bar;
use anyhow::{Result, bail};
use fipt_bake::Accel;
use fipt_bake::emitters::{Emitter, EmitterSet, EmitterSides, LightSelection};
use fipt_bake::integrators::path::{PathConfig, PathScene, PathStats, RadianceCache};
use fipt_bake::lightfield::LightField;
use fipt_bake::materials::{MaterialSource, Memo, Overlay, SurfaceMaterial, TrueMaterials};
use fipt_core::model::FiptModel;
use fipt_core::scene::dataset::load_cameras;
use fipt_core::scene::insert::{Inserted, load_insert};
use fipt_core::scene::meta::{Relight, SceneMeta};
use fipt_core::scene::{Camera, Dataset, Image, LoadOptions, MapKind, Mesh};
use glam::Vec3;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The roughness above which view synthesis takes L′ on secondary hits (reference §2.7,
/// the same threshold as the refinement's).
pub const CACHE_ROUGHNESS: f32 = 0.6;

/// Which scene renders.
#[derive(Clone, Debug)]
pub enum Source {
    /// The true scene of the scene folder's `scene_meta.json`.
    Truth,
    /// A scene model: a folder, or a name in the zoo.
    Model { name_or_dir: String, zoo: PathBuf },
}

/// What to render.
#[derive(Clone, Debug)]
pub struct RenderJob {
    /// The scene folder: its cameras, reference images and `scene_meta.json` (required for
    /// `--truth`; for a model only where cameras or references come from it).
    pub scene: Option<PathBuf>,
    pub out: PathBuf,
    pub source: Source,
    /// `train` or `val`.
    pub split: String,
    /// Render only these views (all when empty).
    pub views: Vec<usize>,
    /// Cameras from this `transforms.json` (FIPT or nerfstudio) instead of the split's; written
    /// to `OUT/cameras/`, unscored.
    pub cameras: Option<PathBuf>,
    pub relight: Option<PathBuf>,
    pub insert: Option<PathBuf>,
    /// L′ on rough secondary hits (models only, never when relighting).
    pub cache: bool,
    /// The voxel cache of the learned field after the first segment (models only; see
    /// `RecoveredOptions`).
    pub material_cache: bool,
    /// Switched-off emitters reflect with the learned field (see `RecoveredOptions`).
    pub off_reflect: bool,
    pub selection: LightSelection,
    pub path: PathConfig,
    pub quiet: bool,
    /// Where a model's field is queried: on a GPU backend its table is uploaded and encoded
    /// there (`hashgrid_device`), on the CPU backends on the host.
    pub backend: fipt_core::model::BackendKind,
}

/// One view's figures.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ViewRender {
    pub view: usize,
    pub seconds: f64,
    /// Against the reference image, where the scene has one.
    pub psnr_db: Option<f64>,
    /// Mean radiance of the render over that of the reference.
    pub mean_ratio: Option<f64>,
}

/// `render.json`.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct RenderReport {
    /// `truth` or the model's name.
    pub source: String,
    pub scene: String,
    pub split: String,
    pub relight: bool,
    /// Objects inserted.
    pub inserted: usize,
    /// Whether L′ served rough secondary hits.
    pub cache: bool,
    pub spp: usize,
    pub max_depth: usize,
    pub light_selection: LightSelection,
    pub emitter_triangles: usize,
    pub views: Vec<ViewRender>,
    pub mean_psnr_db: Option<f64>,
    pub min_psnr_db: Option<f64>,
    pub wall_s: f64,
    pub paths_per_s: f64,
    pub rays_per_s: f64,
    pub stats: PathStats,
    pub threads: usize,
}

/// The recovered scene as the renderer needs it (borrowed from a loaded scene model, or from
/// `run`'s state).
pub struct Recovered<'a> {
    pub model: &'a FiptModel,
    pub mesh: &'a Mesh,
    pub emitters: &'a [Emitter],
    pub light_field: &'a LightField,
}

/// Changes to a scene: relighting and inserted objects.
#[derive(Default)]
pub struct Edits<'a> {
    pub relight: Option<&'a Relight>,
    /// Names the parts that `relight` refers to.
    pub meta: Option<&'a SceneMeta>,
    pub inserted: &'a [Inserted],
}

/// `mesh` with the new emitters of the relighting and the inserted objects appended: the
/// mesh, the added emitters `(triangle, radiance, sides)` and one material per added triangle.
fn append(
    mesh: &Mesh,
    edits: &Edits,
) -> (Mesh, Vec<(u32, Vec3, EmitterSides)>, Vec<SurfaceMaterial>) {
    let mut mesh = mesh.clone();
    let first = mesh.num_triangles();
    let mut emitters = Vec::new();
    let mut mats = Vec::new();
    let mut add =
        |mesh: &mut Mesh, vs: &[Vec3], ts: &[[u32; 3]], em: Option<Vec3>, m: SurfaceMaterial| {
            let base = mesh.vertices.len() as u32;
            mesh.vertices.extend_from_slice(vs);
            for t in ts {
                if let Some(r) = em {
                    emitters.push((mesh.triangles.len() as u32, r, EmitterSides::Front));
                }
                mesh.triangles.push(t.map(|i| i + base));
                mats.push(m);
            }
        };
    for e in edits.relight.into_iter().flat_map(|r| r.added()) {
        let vs: Vec<Vec3> = e.vertices.iter().map(|v| Vec3::from(*v)).collect();
        let m = e
            .bsdf
            .as_ref()
            .map_or(SurfaceMaterial::BLACK, |b| SurfaceMaterial {
                base_color: Vec3::from(b.base_color),
                roughness: b.roughness,
                metallic: b.metallic,
            });
        add(
            &mut mesh,
            &vs,
            &e.triangles,
            Some(Vec3::from(e.radiance)),
            m,
        );
    }
    for o in edits.inserted {
        let m = o
            .material
            .map_or(SurfaceMaterial::BLACK, |m| SurfaceMaterial {
                base_color: Vec3::from(m.base_color),
                roughness: m.roughness,
                metallic: m.metallic,
            });
        add(
            &mut mesh,
            &o.mesh.vertices,
            &o.mesh.triangles,
            o.emission.map(Vec3::from),
            m,
        );
    }
    debug_assert_eq!(mats.len(), mesh.num_triangles() - first);
    (mesh, emitters, mats)
}

/// The part name of every triangle of the meta's mesh.
fn part_names(meta: Option<&SceneMeta>, num_triangles: usize) -> Vec<Option<&str>> {
    let mut names = vec![None; num_triangles];
    for p in meta.into_iter().flat_map(|m| &m.parts) {
        let end = p.triangles[1].min(num_triangles);
        for n in names.iter_mut().take(end).skip(p.triangles[0]) {
            *n = Some(p.name.as_str());
        }
    }
    names
}

/// A reference-less or referenced camera to render: (view index, camera, reference image).
pub type CamRef<'a> = (usize, Camera, Option<&'a Image>);

/// Renders `cams` of `scene` into `dir` (EXR and PNG previews) and scores them against their
/// references.
fn render_cams(
    scene: &PathScene,
    cams: &[&CamRef],
    cfg: &PathConfig,
    memo: Option<&Memo>,
    dir: &Path,
    quiet: bool,
) -> Result<(Vec<ViewRender>, PathStats)> {
    let pb = progress_bar((cams.len() * cfg.spp) as u64, "render", !quiet);
    let mut rows = Vec::new();
    let mut stats = PathStats::default();
    for &&(k, ref camera, refimg) in cams {
        // Ctrl-C stops between views (`interrupt`); `run` rewords where it was.
        crate::interrupt::check(|| "interrupted during the re-renders".into())?;
        let t = Instant::now();
        let base = pb.position();
        let (rgb, st) =
            scene.render_view(camera, cfg, k as u64, &|n| pb.set_position(base + n as u64));
        let seconds = t.elapsed().as_secs_f64();
        stats.add(&st);
        if let Some(m) = memo {
            m.clear();
        }
        let (w, h) = (camera.width, camera.height);
        let img = Image::from_data(w, h, 3, rgb);
        img.write_exr(&dir.join(format!("{k:03}_0001.exr")))?;
        write_png(
            &dir.join("preview").join(format!("{k:03}.png")),
            w,
            h,
            &img.data,
            1.0,
        )?;
        let (psnr_db, mean_ratio) = match refimg {
            Some(r) if r.data.len() == img.data.len() => {
                let mean = |d: &[f32]| d.iter().map(|&x| x as f64).sum::<f64>();
                (
                    psnr_gamma(&img.data, &r.data, |_| true),
                    Some(mean(&img.data) / mean(&r.data)),
                )
            }
            _ => (None, None),
        };
        rows.push(ViewRender {
            view: k,
            seconds,
            psnr_db,
            mean_ratio,
        });
    }
    pb.finish_and_clear();
    Ok((rows, stats))
}

/// What a render of a scene produced.
pub struct Rendered {
    pub views: Vec<ViewRender>,
    pub stats: PathStats,
    pub emitter_triangles: usize,
    pub cache: bool,
}

/// How a recovered scene renders.
#[derive(Clone, Copy, Debug)]
pub struct RecoveredOptions {
    pub selection: LightSelection,
    /// L′ on rough secondary hits (the reference's view synthesis; ignored when relighting).
    pub cache: bool,
    /// Hits after the first segment read the learned field through a voxel cache (the field
    /// averaged over points spread on the surfaces, per voxel of L′'s grid); camera hits
    /// always read the exact field.
    pub material_cache: bool,
    /// Switched-off emitters reflect light with the learned field at their surface. A departure
    /// from the reference's relighting, which makes every estimated emitter black
    /// (`docs/departures/off-reflect.md`).
    pub off_reflect: bool,
}

/// Points per voxel of the material cache.
const MATERIAL_CACHE_POINTS: f32 = 2.0;

/// Renders the recovered scene with `edits` from `cams` into `dir`. L′ serves rough secondary
/// hits when `opts.cache` is set and nothing relights the scene.
pub fn render_recovered(
    rec: &Recovered,
    edits: &Edits,
    cams: &[&CamRef],
    cfg: &PathConfig,
    opts: &RecoveredOptions,
    dir: &Path,
    quiet: bool,
) -> Result<Rendered> {
    let selection = opts.selection;
    let n = rec.mesh.num_triangles();
    let (mesh, added, mats) = append(rec.mesh, edits);
    let parts = part_names(edits.meta, n);
    let factor = |t: u32| {
        edits
            .relight
            .map_or(1.0, |r| r.factor(parts.get(t as usize).copied().flatten()))
    };
    // Emitting triangles reflect nothing (the reference); switched-off ones reflect with the
    // learned field there when `off_reflect` is set.
    let black: Vec<u32> = rec
        .emitters
        .iter()
        .filter(|e| !(opts.off_reflect && factor(e.triangle) == 0.0))
        .map(|e| e.triangle)
        .collect();
    let learned = LearnedMaterials::new(rec.model.clone(), n, &black);
    let materials = Overlay {
        inner: &learned,
        first: n as u32,
        materials: mats,
    };
    let lights = EmitterSet::with_sides(
        &mesh,
        rec.emitters
            .iter()
            .map(|e| {
                (
                    e.triangle,
                    Vec3::from(e.radiance) * factor(e.triangle),
                    e.observed_sides(),
                )
            })
            .chain(added),
        selection,
    );
    let accel = Accel::build(&mesh);
    let cache = opts.cache && edits.relight.is_none();
    // Emitters and appended geometry always read their own (exact) materials.
    let mut forward = vec![false; mesh.num_triangles()];
    for &t in &black {
        forward[t as usize] = true;
    }
    forward[n..].iter_mut().for_each(|f| *f = true);
    let voxels = opts.material_cache.then(|| {
        fipt_bake::materials::VoxelMaterials::from_surface(
            rec.light_field.scene_box,
            rec.light_field.res,
            rec.mesh,
            &materials,
            forward,
            MATERIAL_CACHE_POINTS,
            cfg.seed,
        )
        .0
    });
    // Camera hits repeat with fixed pixel positions: a memo answers the repeats.
    let memo = (cfg.pixel_positions > 0).then(|| Memo::new(&materials));
    let first: &dyn MaterialSource = match &memo {
        Some(m) => m,
        None => &materials,
    };
    let scene = PathScene {
        secondary_materials: voxels.as_ref().map(|v| v as &dyn MaterialSource),
        cache: cache.then_some(RadianceCache {
            light_field: rec.light_field,
            min_roughness: CACHE_ROUGHNESS,
        }),
        accel: &accel,
        materials: first,
        emitters: &lights,
    };
    let mut cfg = cfg.clone();
    cfg.emitters_reflect = false;
    let (views, stats) = render_cams(&scene, cams, &cfg, memo.as_ref(), dir, quiet)?;
    Ok(Rendered {
        views,
        stats,
        emitter_triangles: lights.lights.len(),
        cache,
    })
}

/// A scene's true geometry and materials (`scene_meta.json`, textures in its folder).
pub struct TrueScene<'a> {
    pub dir: &'a Path,
    pub mesh: &'a Mesh,
    pub meta: &'a SceneMeta,
}

/// Renders the true scene with `edits` from `cams` into `dir`.
pub fn render_truth(
    truth_scene: &TrueScene,
    edits: &Edits,
    cams: &[&CamRef],
    cfg: &PathConfig,
    selection: LightSelection,
    dir: &Path,
    quiet: bool,
) -> Result<Rendered> {
    let TrueScene {
        dir: scene_dir,
        mesh,
        meta,
    } = *truth_scene;
    let n = mesh.num_triangles();
    let (full, added, mats) = append(mesh, edits);
    let parts = part_names(Some(meta), n);
    let truth = TrueMaterials::load(scene_dir, &scene_dir.join("scene_meta.json"), meta, n)?;
    let materials = Overlay {
        inner: &truth,
        first: n as u32,
        materials: mats,
    };
    let emission = meta.triangle_emission(n);
    let lights = EmitterSet::with_sides(
        &full,
        emission
            .iter()
            .enumerate()
            .filter(|(_, e)| e.iter().any(|&c| c > 0.0))
            .map(|(t, e)| {
                let f = edits.relight.map_or(1.0, |r| r.factor(parts[t]));
                (t as u32, Vec3::from(*e) * f, EmitterSides::Front)
            })
            .chain(added),
        selection,
    );
    let accel = Accel::build(&full);
    let scene = PathScene {
        secondary_materials: None,
        cache: None,
        accel: &accel,
        materials: &materials as &dyn MaterialSource,
        emitters: &lights,
    };
    let mut cfg = cfg.clone();
    cfg.pixel_positions = 0;
    let (views, stats) = render_cams(&scene, cams, &cfg, None, dir, quiet)?;
    Ok(Rendered {
        views,
        stats,
        emitter_triangles: lights.lights.len(),
        cache: false,
    })
}

/// What `render` reads from a scene folder.
struct SceneViews {
    /// The split's cameras and reference images (None with `--cameras`).
    split: Option<fipt_core::scene::Split>,
    meta: Option<SceneMeta>,
    mesh: Option<Mesh>,
}

/// Renders the job's views; writes `OUT/<split>/Image/{k:03}_0001.exr` (or `Relight/`), PNG
/// previews and `OUT/render.json`.
pub fn render(job: &RenderJob) -> Result<RenderReport> {
    let model = load_model(job)?;
    if !matches!(job.split.as_str(), "train" | "val") {
        bail!("--split {}: expected train or val", job.split);
    }
    let views = load_scene_views(job, model.is_some())?;
    let meta = views.as_ref().and_then(|v| v.meta.as_ref());
    let relight = job
        .relight
        .as_ref()
        .map(|p| Relight::load(p, meta))
        .transpose()?;
    let inserted = job
        .insert
        .as_ref()
        .map(|p| load_insert(p))
        .transpose()?
        .unwrap_or_default();
    let split = views.as_ref().and_then(|v| v.split.as_ref());
    let cams = job_cameras(job, split, model.as_ref(), !inserted.is_empty())?;
    if let Some(&k) = job.views.iter().find(|&&k| k >= cams.len()) {
        bail!("view {k}: there are {} cameras", cams.len());
    }
    let picked: Vec<&CamRef> = if job.views.is_empty() {
        cams.iter().collect()
    } else {
        job.views.iter().map(|&k| &cams[k]).collect()
    };
    let folder = if job.relight.is_some() {
        "Relight"
    } else {
        "Image"
    };
    let group = if job.cameras.is_some() {
        "cameras"
    } else {
        job.split.as_str()
    };
    let dir = job.out.join(group).join(folder);
    // One writer per OUT; the views go to a staged folder that replaces `dir` whole once every
    // view is rendered (with the other views of `dir` carried over when only some are
    // rendered), and `render.json` (removed just before) marks the finished set.
    let _lock = crate::lock::DirLock::acquire(&job.out)?;
    crate::pipeline::checkpoint::remove_stale_tmp_in(&job.out);
    crate::pipeline::checkpoint::remove_stale_tmp_in(&job.out.join(group));
    let marker = job.out.join("render.json");
    let edits = Edits {
        relight: relight.as_ref(),
        meta,
        inserted: &inserted,
    };
    let t_render = Instant::now();
    let mesh = views.as_ref().and_then(|v| v.mesh.as_ref());
    let rendered = crate::output::staged_dir(&dir, |staged| {
        let (source, r) = match &model {
            Some(m) => render_model(job, m, mesh, &edits, &picked, staged)?,
            None => {
                let (Some(mesh), Some(scene)) = (mesh, &job.scene) else {
                    bail!("--truth needs --scene");
                };
                let Some(meta) = meta else {
                    bail!(
                        "{}: --truth needs the scene's ground truth (missing)",
                        scene.join("scene_meta.json").display()
                    );
                };
                let truth = TrueScene {
                    dir: scene,
                    mesh,
                    meta,
                };
                let q = job.quiet;
                let r = render_truth(&truth, &edits, &picked, &job.path, job.selection, staged, q)?;
                ("truth".to_string(), r)
            }
        };
        if !job.views.is_empty() {
            let rendered: Vec<usize> = picked.iter().map(|c| c.0).collect();
            carry_other_views(&dir, staged, &rendered)?;
        }
        crate::output::remove_file_if_present(&marker)?;
        Ok((source, r))
    });
    let (source, r) = rendered.map_err(|e| {
        // The group's folder, when this render created it (removed only when empty).
        let _ = std::fs::remove_dir(job.out.join(group));
        crate::interrupt::reword(e, || {
            format!(
                "interrupted during the render; {} is as it was",
                job.out.display()
            )
        })
    })?;
    let wall = t_render.elapsed().as_secs_f64();
    let scores: Vec<f64> = r.views.iter().filter_map(|v| v.psnr_db).collect();
    let report = RenderReport {
        source,
        scene: job
            .scene
            .as_ref()
            .map_or(String::new(), |s| s.display().to_string()),
        split: group.to_string(),
        relight: job.relight.is_some(),
        inserted: inserted.len(),
        cache: r.cache,
        spp: job.path.spp,
        max_depth: job.path.max_depth,
        light_selection: job.selection,
        emitter_triangles: r.emitter_triangles,
        mean_psnr_db: mean(&scores),
        min_psnr_db: scores.iter().cloned().reduce(f64::min),
        views: r.views,
        wall_s: wall,
        paths_per_s: r.stats.paths as f64 / wall,
        rays_per_s: (r.stats.rays + r.stats.shadow_rays) as f64 / wall,
        stats: r.stats,
        threads: rayon::current_num_threads(),
    };
    write_json(&marker, &report)?;
    Ok(report)
}

/// Hard-links (or copies) into `staged` the images and previews in `dir` of the views not in
/// `rendered` (files named from their view, `{k:03}…`), so that a render of some views keeps the
/// others.
fn carry_other_views(dir: &Path, staged: &Path, rendered: &[usize]) -> Result<()> {
    for sub in ["", "preview"] {
        let (from, to) = (dir.join(sub), staged.join(sub));
        for e in std::fs::read_dir(&from).into_iter().flatten().flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            let view: Option<usize> = name.get(..3).and_then(|s| s.parse().ok());
            if !(e.path().is_file() && view.is_some_and(|k| !rendered.contains(&k))) {
                continue;
            }
            std::fs::create_dir_all(&to)
                .map_err(|err| anyhow::anyhow!("{}: cannot create: {err}", to.display()))?;
            let dst = to.join(&name);
            if std::fs::hard_link(e.path(), &dst).is_err() {
                std::fs::copy(e.path(), &dst).map_err(|err| {
                    anyhow::anyhow!(
                        "{}: cannot copy to {}: {err}",
                        e.path().display(),
                        dst.display()
                    )
                })?;
            }
        }
    }
    Ok(())
}

/// The job's scene model (its table on the device for a GPU backend); None for `--truth`.
fn load_model(job: &RenderJob) -> Result<Option<crate::scene_model::SceneModel>> {
    let Source::Model { name_or_dir, zoo } = &job.source else {
        return Ok(None);
    };
    crate::scene_model::SceneModel::open(name_or_dir, zoo, job.backend).map(Some)
}

/// What the job reads from its scene folder (None without `--scene`). The photos (`Image/`)
/// are always loaded, `Relight/` where relighting. A model needs only the split it renders
/// (the photos of the other may be gone); the true scene needs the whole folder.
fn load_scene_views(job: &RenderJob, for_model: bool) -> Result<Option<SceneViews>> {
    let opts = LoadOptions {
        maps: if job.relight.is_some() {
            vec![MapKind::Relight]
        } else {
            vec![]
        },
        val: job.split == "val",
    };
    Ok(match &job.scene {
        None => None,
        Some(scene) if for_model && !scene.join("train/transforms.json").is_file() => {
            let meta_path = scene.join("scene_meta.json");
            let mesh_path = scene.join("scene.obj");
            Some(SceneViews {
                split: if job.cameras.is_none() {
                    Some(fipt_core::scene::dataset::load_split(
                        scene, &job.split, &opts,
                    )?)
                } else {
                    None
                },
                meta: meta_path
                    .is_file()
                    .then(|| SceneMeta::load(&meta_path))
                    .transpose()?,
                mesh: mesh_path
                    .is_file()
                    .then(|| Mesh::load_obj(&mesh_path))
                    .transpose()?,
            })
        }
        Some(scene) => {
            let ds = Dataset::load(scene, &opts)?;
            let split = match job.split.as_str() {
                "train" => Some(ds.train),
                _ => Some(
                    ds.val
                        .ok_or_else(|| anyhow::anyhow!("{}: no val split", scene.display()))?,
                ),
            };
            Some(SceneViews {
                split,
                meta: ds.meta,
                mesh: Some(ds.mesh),
            })
        }
    })
}

/// (view index, camera, reference image) of every view the job can render: from `--cameras`
/// (unscored) or the split's views (scored against their photos, or relit photos; not when
/// objects are inserted, which change the image).
fn job_cameras<'a>(
    job: &RenderJob,
    split: Option<&'a fipt_core::scene::Split>,
    model: Option<&crate::scene_model::SceneModel>,
    inserting: bool,
) -> Result<Vec<CamRef<'a>>> {
    Ok(match (&job.cameras, split) {
        (Some(file), _) => {
            let size = match (split, model) {
                (Some(s), _) => (s.width, s.height),
                (None, Some(m)) => (m.manifest.image_size[0], m.manifest.image_size[1]),
                (None, None) => bail!("--truth needs --scene"),
            };
            load_cameras(file, size)?
                .into_iter()
                .enumerate()
                .map(|(k, c)| (k, c, None))
                .collect()
        }
        (None, Some(split)) => split
            .views
            .iter()
            .enumerate()
            .map(|(k, v)| {
                let r = if job.relight.is_some() {
                    v.map(MapKind::Relight)
                } else {
                    Some(&v.image)
                };
                (k, v.camera.clone(), r.filter(|_| !inserting))
            })
            .collect(),
        (None, None) => bail!("give --scene (its cameras) or --cameras FILE"),
    })
}

/// Renders a scene model for the job (after checking that the scene's mesh, where there is
/// one, is the model's); returns the model's name and the renders.
fn render_model(
    job: &RenderJob,
    m: &crate::scene_model::SceneModel,
    scene_mesh: Option<&Mesh>,
    edits: &Edits,
    picked: &[&CamRef],
    dir: &Path,
) -> Result<(String, Rendered)> {
    if let Some(mesh) = scene_mesh
        && crate::scene_model::mesh_hash(mesh) != m.manifest.mesh_hash
    {
        bail!(
            "{}: the scene's mesh differs from the model's ({}); its cameras would not see the same room",
            job.scene.as_ref().expect("scene").display(),
            m.dir.display()
        );
    }
    let rec = Recovered {
        model: &m.model,
        mesh: &m.mesh,
        emitters: &m.emitters,
        light_field: &m.light_field,
    };
    let opts = RecoveredOptions {
        selection: job.selection,
        cache: job.cache,
        material_cache: job.material_cache,
        off_reflect: job.off_reflect,
    };
    let r = render_recovered(&rec, edits, picked, &job.path, &opts, dir, job.quiet)?;
    Ok((m.manifest.name.clone(), r))
}

/// The trivial predictors of re-rendered views, scored as the renders are: for view synthesis
/// each photo's own mean colour as a constant image; for relighting the photo under the old
/// lights (None where the views have no `Relight` map).
pub fn trivial_render_scores(views: &[fipt_core::scene::View]) -> (Option<f64>, Option<f64>) {
    let (mut view, mut relight) = (Vec::new(), Vec::new());
    for v in views {
        let img = &v.image.data;
        let n = (img.len() / 3).max(1);
        let mean: Vec<f32> = (0..3)
            .map(|c| img.iter().skip(c).step_by(3).sum::<f32>() / n as f32)
            .collect();
        let constant: Vec<f32> = (0..img.len()).map(|i| mean[i % 3]).collect();
        view.extend(psnr_gamma(&constant, img, |_| true));
        if let Some(r) = v.map(MapKind::Relight) {
            relight.extend(psnr_gamma(img, &r.data, |_| true));
        }
    }
    (mean(&view), mean(&relight))
}

/// Mean of a list (None when empty).
pub fn mean(v: &[f64]) -> Option<f64> {
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

impl RenderReport {
    pub fn print(&self, out: &Path) {
        for v in &self.views {
            println!(
                "view {:>3}: {:.1} s, PSNR {} dB, mean ratio {}",
                v.view,
                v.seconds,
                v.psnr_db.map_or("-".into(), |x| format!("{x:.2}")),
                v.mean_ratio.map_or("-".into(), |x| format!("{x:.4}"))
            );
        }
        println!(
            "{} views at {} spp in {:.1} s: {:.2} M paths/s, {:.2} M rays/s ({} threads); mean PSNR {} dB, min {}; outputs in {}",
            self.views.len(),
            self.spp,
            self.wall_s,
            self.paths_per_s / 1e6,
            self.rays_per_s / 1e6,
            self.threads,
            self.mean_psnr_db.map_or("-".into(), |x| format!("{x:.2}")),
            self.min_psnr_db.map_or("-".into(), |x| format!("{x:.2}")),
            out.display()
        );
    }
}
