//! `fipt-train render`: path-traced images of a scene's cameras with the wavefront path tracer
//! of fipt-bake. `--truth` renders the true scene of `scene_meta.json` (materials, textures,
//! emitters); with `--relight` its `relight.json` switches emitters off and adds new ones. Where
//! the scene has reference images (`Image/`, or `Relight/` when relighting) each view is scored
//! against them (PSNR of clip(x, 0, 1)^(1/2.2), mean-radiance ratio).
//!
//! Owns: the render job (scene assembly, outputs, scores, `render.json`). Must not touch: light
//! transport (fipt-bake), materials of a learned model (the re-rendering issue adds them here as
//! another `MaterialSource`).

use crate::metrics::psnr_gamma;
use crate::output::{write_json, write_png};
use crate::progress::progress_bar;
use anyhow::{Result, bail};
use fipt_bake::Accel;
use fipt_bake::emitters::{EmitterSet, LightSelection};
use fipt_bake::integrators::path::{PathConfig, PathScene, PathStats};
use fipt_bake::materials::{SurfaceMaterial, TrueMaterials};
use fipt_core::scene::dataset::load_cameras;
use fipt_core::scene::meta::{Relight, SceneMeta};
use fipt_core::scene::{Camera, Dataset, Image, LoadOptions, MapKind, Mesh};
use glam::Vec3;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// What to render.
#[derive(Clone, Debug)]
pub struct RenderJob {
    pub scene: PathBuf,
    pub out: PathBuf,
    /// `train` or `val`.
    pub split: String,
    /// Render only these views (all when empty).
    pub views: Vec<usize>,
    /// Cameras from this `transforms.json` (FIPT or nerfstudio) instead of the split's; written
    /// to `OUT/cameras/`, unscored.
    pub cameras: Option<PathBuf>,
    pub relight: Option<PathBuf>,
    pub selection: LightSelection,
    pub path: PathConfig,
    pub quiet: bool,
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
    pub scene: String,
    pub split: String,
    pub relight: bool,
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

/// The scene mesh with the relighting emitters appended, the emitters `(triangle, radiance)`,
/// and the material of the added triangles.
fn assemble(
    mesh: &Mesh,
    meta: &SceneMeta,
    relight: Option<&Relight>,
) -> (Mesh, Vec<(u32, Vec3)>, SurfaceMaterial) {
    let mut mesh = mesh.clone();
    let off: Vec<&str> = relight
        .map(|r| r.emitters_off.iter().map(String::as_str).collect())
        .unwrap_or_default();
    let mut emitters: Vec<(u32, Vec3)> = Vec::new();
    for p in &meta.parts {
        if let Some(e) = &p.emission
            && !off.contains(&p.name.as_str())
        {
            for t in p.triangles[0]..p.triangles[1] {
                emitters.push((t as u32, Vec3::from(e.radiance)));
            }
        }
    }
    let mut extra = SurfaceMaterial::BLACK;
    for e in relight.into_iter().flat_map(|r| r.added()) {
        let base = mesh.vertices.len() as u32;
        mesh.vertices
            .extend(e.vertices.iter().map(|v| Vec3::from(*v)));
        for t in &e.triangles {
            emitters.push((mesh.triangles.len() as u32, Vec3::from(e.radiance)));
            mesh.triangles.push(t.map(|i| i + base));
        }
        if let Some(b) = &e.bsdf {
            extra = SurfaceMaterial {
                base_color: Vec3::from(b.base_color),
                roughness: b.roughness,
                metallic: b.metallic,
            };
        }
    }
    (mesh, emitters, extra)
}

/// Renders the job's views; writes `OUT/<split>/Image/{k:03}_0001.exr` (or `Relight/`), PNG
/// previews and `OUT/render.json`.
pub fn render(job: &RenderJob) -> Result<RenderReport> {
    // The photos (`Image/`) are always loaded; `Relight/` where relighting.
    let opts = LoadOptions {
        maps: if job.relight.is_some() {
            vec![MapKind::Relight]
        } else {
            vec![]
        },
        val: job.split == "val",
    };
    let ds = Dataset::load(&job.scene, &opts)?;
    let split = match job.split.as_str() {
        "train" => &ds.train,
        "val" => ds
            .val
            .as_ref()
            .ok_or_else(|| anyhow::anyhow!("{}: no val split", job.scene.display()))?,
        s => bail!("--split {s}: expected train or val"),
    };
    let meta_path = job.scene.join("scene_meta.json");
    let Some(meta) = ds.meta.as_ref() else {
        bail!(
            "{}: --truth needs the scene's ground truth (missing)",
            meta_path.display()
        );
    };
    let relight = job
        .relight
        .as_ref()
        .map(|p| Relight::load(p, meta))
        .transpose()?;
    let (mesh, emitters, extra) = assemble(&ds.mesh, meta, relight.as_ref());
    let materials = TrueMaterials::load(&job.scene, &meta_path, meta, ds.mesh.num_triangles())?
        .with_extra(extra);
    let accel = Accel::build(&mesh);
    let lights = EmitterSet::new(&mesh, emitters, false, job.selection);
    let scene = PathScene {
        cache: None,
        accel: &accel,
        materials: &materials,
        emitters: &lights,
    };
    // (view index, camera, reference image) of every view to render.
    let cams: Vec<(usize, Camera, Option<&Image>)> = match &job.cameras {
        Some(file) => load_cameras(file, (ds.train.width, ds.train.height))?
            .into_iter()
            .enumerate()
            .map(|(k, c)| (k, c, None))
            .collect(),
        None => split
            .views
            .iter()
            .enumerate()
            .map(|(k, v)| {
                let r = if job.relight.is_some() {
                    v.map(MapKind::Relight)
                } else {
                    Some(&v.image)
                };
                (k, v.camera.clone(), r)
            })
            .collect(),
    };
    if let Some(&k) = job.views.iter().find(|&&k| k >= cams.len()) {
        bail!("view {k}: there are {} cameras", cams.len());
    }
    let picked: Vec<&(usize, Camera, Option<&Image>)> = if job.views.is_empty() {
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
    let pb = progress_bar((picked.len() * job.path.spp) as u64, "render", !job.quiet);
    let mut rows = Vec::new();
    let mut stats = PathStats::default();
    let t_render = Instant::now();
    for &&(k, ref camera, refimg) in &picked {
        let t = Instant::now();
        let base = pb.position();
        let (rgb, st) = scene.render_view(camera, &job.path, k as u64, &|n| {
            pb.set_position(base + n as u64)
        });
        let seconds = t.elapsed().as_secs_f64();
        stats.add(&st);
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
    let wall = t_render.elapsed().as_secs_f64();
    let scores: Vec<f64> = rows.iter().filter_map(|r| r.psnr_db).collect();
    let report = RenderReport {
        scene: job.scene.display().to_string(),
        split: group.to_string(),
        relight: job.relight.is_some(),
        spp: job.path.spp,
        max_depth: job.path.max_depth,
        light_selection: job.selection,
        emitter_triangles: lights.lights.len(),
        mean_psnr_db: (!scores.is_empty())
            .then(|| scores.iter().sum::<f64>() / scores.len() as f64),
        min_psnr_db: scores.iter().cloned().reduce(f64::min),
        views: rows,
        wall_s: wall,
        paths_per_s: stats.paths as f64 / wall,
        rays_per_s: (stats.rays + stats.shadow_rays) as f64 / wall,
        stats,
        threads: rayon::current_num_threads(),
    };
    write_json(&job.out.join("render.json"), &report)?;
    Ok(report)
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
