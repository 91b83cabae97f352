//! `export`: a recovered scene model (or a scene's ground truth) as files other tools read:
//! glTF 2.0 (`.glb`, or `.gltf` with its buffer and PNG textures) and Mitsuba 3 (`scene.xml`,
//! PLY meshes, PNG bitmaps).
//!
//! The material field is baked into textures over a UV atlas made for the mesh (`atlas`,
//! `bake`). Materials follow the scene's parts (one per part of `scene_meta.json`, so users can
//! edit them; one `surface` material without parts), and the emitting triangles of each part
//! get a material of their own (`<part>.light`) carrying their radiance. The cameras of one
//! split (the val views by default) are exported where the scene folder has them. The mapping
//! of fipt's BRDF onto each target's and what it cannot carry over: `docs/export.md`.
//!
//! OUT is locked while the export is written; its files are written in a staging folder inside
//! OUT, moved into place, and `export.json` (the summary) is written last, so `export.json` is
//! there only beside a complete export.
//!
//! Owns: the command, material grouping, texture encoding. Must not touch: the model's maths,
//! light transport.

pub mod atlas;
pub mod bake;
pub mod gltf;
pub mod mitsuba;
pub mod viewer;

use anyhow::{Context, Result, bail};
use fipt_bake::emitters::EmitterSides;
use fipt_bake::materials::{MaterialSource, TrueMaterials};
use fipt_core::scene::meta::SceneMeta;
use fipt_core::scene::{Camera, Mesh};
use glam::Vec3;
use std::path::{Path, PathBuf};

/// What `export` writes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Format {
    /// One binary glTF file, `scene.glb`, textures inside.
    Glb,
    /// `scene.gltf` with `scene.bin` and `textures/*.png` beside it.
    Gltf,
    /// Mitsuba 3: `scene.xml`, `meshes/*.ply`, `textures/*.png`.
    Mitsuba,
    /// `scene.glb` with an offline WebGL viewer beside it: `viewer.html`, `scene.glb.js`.
    Viewer,
}

/// Where the materials and emitters come from.
#[derive(Clone, Debug)]
pub enum Source {
    /// A scene model: a folder or a name in `zoo`.
    Model { name_or_dir: String, zoo: PathBuf },
    /// The ground truth of the scene folder (`scene_meta.json`, its textures and emitters).
    Truth,
}

/// The split of the scene folder whose views become the export's cameras.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum CameraSplit {
    /// The held-out views (`val/transforms.json`).
    #[default]
    Val,
    /// The training views (`train/transforms.json`): renders of them stand in for the photos.
    Train,
}

impl CameraSplit {
    /// The split's folder name, which also prefixes the cameras' names.
    pub fn dir(self) -> &'static str {
        match self {
            CameraSplit::Val => "val",
            CameraSplit::Train => "train",
        }
    }
}

/// One `export` command.
#[derive(Clone, Debug)]
pub struct ExportJob {
    pub source: Source,
    /// The scene folder: parts (`scene_meta.json`) and cameras. For a model, default: the
    /// folder it was recovered from, where it still exists.
    pub scene: Option<PathBuf>,
    /// The split whose cameras are exported, named `<split>_NNN`.
    pub split: CameraSplit,
    pub formats: Vec<Format>,
    pub out: PathBuf,
    /// Side of the square textures, in texels.
    pub texels: usize,
    pub backend: fipt_core::model::BackendKind,
    pub quiet: bool,
}

/// Padding around each chart, in texels.
pub const PAD: usize = 4;
/// The accepted `--texels`.
pub const TEXELS: std::ops::RangeInclusive<u64> = 64..=8192;
/// The summary file, written last.
pub const SUMMARY: &str = "export.json";

/// A material of the export: a part's reflecting triangles, or its emitting ones.
#[derive(Clone, Debug, serde::Serialize)]
pub struct MaterialGroup {
    pub name: String,
    pub triangles: usize,
    /// Emitting triangles: `strength` scales the emission texture; their BRDF is black, but
    /// for the ground truth in Mitsuba (`Scene::emitters_reflect`).
    pub emitter: bool,
    /// The largest radiance component over the group's triangles (1 for reflecting groups).
    pub strength: f32,
}

/// An emitting triangle: radiance and the sides it emits from.
#[derive(Clone, Copy, Debug)]
pub struct Emission {
    pub triangle: u32,
    pub radiance: Vec3,
    pub sides: EmitterSides,
}

/// Everything a writer needs.
pub struct Scene<'a> {
    pub mesh: &'a Mesh,
    pub atlas: &'a atlas::Atlas,
    pub textures: &'a bake::Textures,
    pub groups: &'a [MaterialGroup],
    /// Group of each triangle.
    pub group_of: &'a [u32],
    pub emitters: &'a [Emission],
    /// Named cameras (one split's views).
    pub cameras: &'a [(String, Camera)],
    /// Whether the emitting triangles also reflect with their baked material: true for the
    /// ground truth (the reference scenes' area emitters reflect), false for a model (fipt's
    /// refinement ends paths on emitters, and the field holds no material there).
    pub emitters_reflect: bool,
    /// fipt's version, for the files' generator fields.
    pub generator: String,
}

/// Triangles as an indexed mesh for a writer: one vertex per (mesh vertex, chart), carrying its
/// chart's UV, so that vertices are shared within a chart and split across charts.
pub struct Indexed {
    pub positions: Vec<Vec3>,
    pub uvs: Vec<glam::Vec2>,
    pub faces: Vec<[u32; 3]>,
}

impl Scene<'_> {
    /// The triangles of each material group, in mesh order.
    pub fn triangles_by_group(&self) -> Vec<Vec<u32>> {
        let mut by_group = vec![Vec::new(); self.groups.len()];
        for (t, &g) in self.group_of.iter().enumerate() {
            by_group[g as usize].push(t as u32);
        }
        by_group
    }

    /// The triangles `tris` indexed. With `shift` ≠ 0 each corner gets a vertex of its own,
    /// moved by `shift` along its face's winding normal (the copies share no vertex with their
    /// neighbours, whose normals differ).
    pub fn indexed(&self, tris: &[u32], shift: f32) -> Indexed {
        let mut out = Indexed {
            positions: Vec::new(),
            uvs: Vec::new(),
            faces: Vec::with_capacity(tris.len()),
        };
        let mut local: std::collections::HashMap<(u32, u32), u32> = Default::default();
        for &t in tris {
            let tri = self.mesh.triangles[t as usize];
            let n = self.mesh.normal(t as usize);
            let mut f = [0u32; 3];
            for (k, &v) in tri.iter().enumerate() {
                let key = if shift != 0.0 {
                    (u32::MAX - (3 * t + k as u32), 0)
                } else {
                    (v, self.atlas.chart[t as usize])
                };
                let next = out.positions.len() as u32;
                f[k] = *local.entry(key).or_insert_with(|| {
                    out.positions
                        .push(self.mesh.vertices[v as usize] + n * shift);
                    out.uvs.push(self.atlas.uv[t as usize][k]);
                    next
                });
            }
            out.faces.push(f);
        }
        out
    }
}

/// Groups per triangle: one per part (or one `surface` group), and `<part>.light` for the
/// emitting triangles of each part.
pub fn group_triangles(
    num_triangles: usize,
    meta: Option<&SceneMeta>,
    emitters: &[Emission],
) -> (Vec<MaterialGroup>, Vec<u32>) {
    let part_of = meta.map(|m| m.triangle_part(num_triangles));
    let names: std::collections::HashMap<usize, &str> = meta
        .map(|m| m.parts.iter().map(|p| (p.id, p.name.as_str())).collect())
        .unwrap_or_default();
    let part_name = |t: usize| -> String {
        part_of
            .as_ref()
            .and_then(|p| names.get(&p[t]))
            .map_or_else(|| "surface".into(), |s| s.to_string())
    };
    let mut radiance = vec![None; num_triangles];
    for e in emitters {
        radiance[e.triangle as usize] = Some(e.radiance);
    }
    let mut groups: Vec<MaterialGroup> = Vec::new();
    let mut index: std::collections::HashMap<(String, bool), u32> = Default::default();
    let mut group_of = vec![0u32; num_triangles];
    for t in 0..num_triangles {
        let emitter = radiance[t].is_some();
        let name = part_name(t);
        let k = *index.entry((name.clone(), emitter)).or_insert_with(|| {
            groups.push(MaterialGroup {
                name: if emitter {
                    format!("{name}.light")
                } else {
                    name
                },
                triangles: 0,
                emitter,
                strength: if emitter { 0.0 } else { 1.0 },
            });
            groups.len() as u32 - 1
        });
        let g = &mut groups[k as usize];
        g.triangles += 1;
        if let Some(r) = radiance[t] {
            g.strength = g.strength.max(r.max_element());
        }
        group_of[t] = k;
    }
    for g in &mut groups {
        if g.emitter && g.strength <= 0.0 {
            g.strength = 1.0;
        }
    }
    (groups, group_of)
}

/// sRGB encoding of a linear value in [0, 1] (IEC 61966-2-1), as an 8-bit code.
pub fn srgb8(x: f32) -> u8 {
    let x = x.clamp(0.0, 1.0);
    let s = if x <= 0.003_130_8 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    };
    (s * 255.0 + 0.5) as u8
}

/// A linear value in [0, 1] as an 8-bit code.
pub fn linear8(x: f32) -> u8 {
    (x.clamp(0.0, 1.0) * 255.0 + 0.5) as u8
}

/// PNG bytes of an 8-bit image with `channels` (1 or 3) per pixel.
pub fn png(size: usize, channels: usize, bytes: &[u8]) -> Result<Vec<u8>> {
    use image::ImageEncoder;
    let mut out = Vec::new();
    let color = if channels == 1 {
        image::ExtendedColorType::L8
    } else {
        image::ExtendedColorType::Rgb8
    };
    image::codecs::png::PngEncoder::new(&mut out).write_image(
        bytes,
        size as u32,
        size as u32,
        color,
    )?;
    Ok(out)
}

/// The textures as PNG files: base colour (sRGB), glTF's metallic-roughness (linear; G = σ,
/// B = m), emission (sRGB of radiance / strength), and σ and m alone (linear, one channel) for
/// Mitsuba.
pub struct Pngs {
    pub base_color: Vec<u8>,
    pub metallic_roughness: Vec<u8>,
    pub emission: Vec<u8>,
    pub roughness: Vec<u8>,
    pub metallic: Vec<u8>,
}

impl Pngs {
    pub fn encode(t: &bake::Textures) -> Result<Self> {
        let rgb = |f: &dyn Fn(usize) -> [u8; 3]| -> Vec<u8> {
            (0..t.size * t.size).flat_map(f).collect()
        };
        Ok(Self {
            base_color: png(t.size, 3, &rgb(&|i| t.base_color[i].to_array().map(srgb8)))?,
            metallic_roughness: png(
                t.size,
                3,
                &rgb(&|i| [0, linear8(t.roughness[i]), linear8(t.metallic[i])]),
            )?,
            emission: png(t.size, 3, &rgb(&|i| t.emission[i].to_array().map(srgb8)))?,
            roughness: png(
                t.size,
                1,
                &t.roughness.iter().map(|&x| linear8(x)).collect::<Vec<_>>(),
            )?,
            metallic: png(
                t.size,
                1,
                &t.metallic.iter().map(|&x| linear8(x)).collect::<Vec<_>>(),
            )?,
        })
    }
}

/// What `export` reports (`export.json`).
#[derive(Clone, Debug, serde::Serialize)]
pub struct ExportReport {
    pub source: String,
    pub formats: Vec<Format>,
    pub files: Vec<String>,
    pub texels: usize,
    pub charts: usize,
    /// Texels per world unit.
    pub density: f32,
    /// Share of the texels that some triangle (or its padding) owns.
    pub coverage: f64,
    pub materials: Vec<MaterialGroup>,
    pub emitter_triangles: usize,
    pub cameras: usize,
    pub seconds: f64,
}

/// The source loaded: mesh, materials, emitters, and the scene folder it was read with.
struct Loaded {
    name: String,
    mesh: Mesh,
    materials: Box<dyn MaterialSource>,
    emitters: Vec<Emission>,
    meta: Option<SceneMeta>,
    image_size: Option<(usize, usize)>,
    scene: Option<PathBuf>,
}

fn load(job: &ExportJob) -> Result<Loaded> {
    match &job.source {
        Source::Truth => {
            let Some(scene) = &job.scene else {
                bail!("--truth needs --scene");
            };
            let mesh_path = scene.join("scene.obj");
            let meta_path = scene.join("scene_meta.json");
            let mesh = Mesh::load_obj(&mesh_path)?;
            mesh.validate(&mesh_path)?;
            if !meta_path.is_file() {
                bail!(
                    "{}: file not found (--truth needs the true materials)",
                    meta_path.display()
                );
            }
            let meta = SceneMeta::load(&meta_path)?;
            let n = mesh.num_triangles();
            let truth = TrueMaterials::load(scene, &meta_path, &meta, n)?;
            let emitters = meta
                .triangle_emission(n)
                .iter()
                .enumerate()
                .filter(|(_, e)| e.iter().any(|&c| c > 0.0))
                .map(|(t, e)| Emission {
                    triangle: t as u32,
                    radiance: Vec3::from(*e),
                    sides: EmitterSides::Front,
                })
                .collect();
            Ok(Loaded {
                name: format!("truth of {}", scene.display()),
                mesh,
                materials: Box::new(truth),
                emitters,
                meta: Some(meta),
                image_size: None,
                scene: Some(scene.clone()),
            })
        }
        Source::Model { name_or_dir, zoo } => {
            let m = crate::scene_model::SceneModel::open(name_or_dir, zoo, job.backend)?;
            // The scene folder: given, else the one the model was recovered from if it is still
            // there and holds the same mesh.
            let scene = match &job.scene {
                Some(s) => Some(s.clone()),
                None => {
                    let s = PathBuf::from(&m.manifest.scene);
                    let found = s.join("scene.obj").is_file();
                    if !found && !job.quiet {
                        eprintln!(
                            "export: the model's scene folder {} is not here: one material, no cameras (give --scene)",
                            s.display()
                        );
                    }
                    found.then_some(s)
                }
            };
            let mut meta = None;
            if let Some(s) = &scene {
                let mesh_path = s.join("scene.obj");
                if mesh_path.is_file() {
                    let mesh = Mesh::load_obj(&mesh_path)?;
                    if crate::scene_model::mesh_hash(&mesh) != m.manifest.mesh_hash {
                        bail!(
                            "{}: the scene's mesh differs from the model's ({}): its parts and cameras would not fit",
                            s.display(),
                            m.dir.display()
                        );
                    }
                }
                let meta_path = s.join("scene_meta.json");
                if meta_path.is_file() {
                    meta = Some(SceneMeta::load(&meta_path)?);
                }
            }
            let n = m.mesh.num_triangles();
            let crate::scene_model::SceneModel {
                manifest,
                model,
                mesh,
                emitters,
                ..
            } = m;
            let emitters = emitters
                .iter()
                .map(|e| Emission {
                    triangle: e.triangle,
                    radiance: Vec3::from(e.radiance),
                    sides: e.observed_sides(),
                })
                .collect();
            let size = manifest.image_size;
            Ok(Loaded {
                name: manifest.name,
                materials: Box::new(crate::learned::LearnedMaterials::new(model, n, &[])),
                mesh,
                emitters,
                meta,
                image_size: Some((size[0], size[1])),
                scene,
            })
        }
    }
}

/// The cameras of `split` in `scene`, named `<split>_NNN` (none where the folder has no such
/// split).
fn split_cameras(
    scene: Option<&Path>,
    split: CameraSplit,
    size: Option<(usize, usize)>,
) -> Result<Vec<(String, Camera)>> {
    let Some(scene) = scene else {
        return Ok(vec![]);
    };
    let path = scene.join(split.dir()).join("transforms.json");
    if !path.is_file() {
        return Ok(vec![]);
    }
    let size = match size {
        Some(s) => s,
        None => {
            let img = scene
                .join(split.dir())
                .join("Image")
                .join(fipt_core::scene::dataset::image_file(0));
            let i = fipt_core::scene::Image::read_exr(&img)?;
            (i.width, i.height)
        }
    };
    let cams = fipt_core::scene::dataset::load_cameras(&path, size)?;
    // Neither glTF's perspective camera nor Mitsuba's sensor (as written) takes an off-centre
    // principal point or non-square pixels.
    if let Some((k, _)) = cams.iter().enumerate().find(|(_, c)| {
        (c.cx - 0.5 * c.width as f64).abs() > 0.5
            || (c.cy - 0.5 * c.height as f64).abs() > 0.5
            || (c.fx - c.fy).abs() > 1e-3 * c.fx
    }) {
        eprintln!(
            "warning: {}: frame {k} has an off-centre principal point or non-square pixels; the exported cameras keep fx and a centred principal point",
            path.display()
        );
    }
    Ok(cams
        .into_iter()
        .enumerate()
        .map(|(k, c)| (format!("{}_{k:03}", split.dir()), c))
        .collect())
}

/// Runs the export; returns its report (also written to `OUT/export.json`).
pub fn export(job: &ExportJob) -> Result<ExportReport> {
    let t0 = std::time::Instant::now();
    if !TEXELS.contains(&(job.texels as u64)) {
        bail!(
            "--texels {}: out of its range [{}, {}]",
            job.texels,
            TEXELS.start(),
            TEXELS.end()
        );
    }
    if job.formats.is_empty() {
        bail!("--format: give at least one of glb, gltf, mitsuba, viewer");
    }
    let src = load(job)?;
    let cameras = split_cameras(src.scene.as_deref(), job.split, src.image_size)?;
    let n = src.mesh.num_triangles();
    let (groups, group_of) = group_triangles(n, src.meta.as_ref(), &src.emitters);
    let atlas = atlas::build(&src.mesh, &group_of, job.texels, PAD)?;
    let mut emission = vec![Vec3::ZERO; n];
    for e in &src.emitters {
        emission[e.triangle as usize] =
            e.radiance / groups[group_of[e.triangle as usize] as usize].strength;
    }
    if !job.quiet {
        eprintln!(
            "export: {} triangles in {} charts, {}² texels, {} materials",
            n,
            atlas.charts,
            atlas.size,
            groups.len()
        );
    }
    let textures = bake::bake(&src.mesh, &atlas, src.materials.as_ref(), &emission);
    let pngs = Pngs::encode(&textures)?;
    let scene = Scene {
        mesh: &src.mesh,
        atlas: &atlas,
        textures: &textures,
        groups: &groups,
        group_of: &group_of,
        emitters: &src.emitters,
        cameras: &cameras,
        emitters_reflect: matches!(job.source, Source::Truth),
        generator: format!("fipt {}", env!("CARGO_PKG_VERSION")),
    };
    std::fs::create_dir_all(&job.out)
        .with_context(|| format!("{}: cannot create", job.out.display()))?;
    let _lock = crate::lock::DirLock::acquire(&job.out)?;
    let stage = job.out.join(format!(".export-{}.tmp", std::process::id()));
    let _ = std::fs::remove_dir_all(&stage);
    let written = (|| -> Result<Vec<String>> {
        std::fs::create_dir_all(&stage)
            .with_context(|| format!("{}: cannot create", stage.display()))?;
        let mut files = Vec::new();
        for f in &job.formats {
            files.extend(match f {
                Format::Glb => gltf::write_glb(&scene, &pngs, &stage)?,
                Format::Gltf => gltf::write_gltf(&scene, &pngs, &stage)?,
                Format::Mitsuba => mitsuba::write(&scene, &pngs, &stage)?,
                Format::Viewer => viewer::write(&scene, &pngs, &stage)?,
            });
        }
        files.sort();
        files.dedup();
        Ok(files)
    })();
    let files = match written {
        Ok(f) => f,
        Err(e) => {
            let _ = std::fs::remove_dir_all(&stage);
            return Err(e);
        }
    };
    let report = ExportReport {
        source: src.name.clone(),
        formats: job.formats.clone(),
        files: files.clone(),
        texels: atlas.size,
        charts: atlas.charts,
        density: atlas.density,
        coverage: textures.owner.iter().filter(|&&o| o != bake::EMPTY).count() as f64
            / textures.owner.len() as f64,
        materials: groups.clone(),
        emitter_triangles: src.emitters.len(),
        cameras: cameras.len(),
        seconds: t0.elapsed().as_secs_f64(),
    };
    // Into place: the old summary goes first, the new one comes last.
    crate::output::remove_file_if_present(&job.out.join(SUMMARY))?;
    let moved = (|| -> Result<()> {
        let mut tops: Vec<String> = files
            .iter()
            .map(|f| f.split('/').next().unwrap_or(f).to_string())
            .collect();
        tops.sort();
        tops.dedup();
        for top in tops {
            let (from, to) = (stage.join(&top), job.out.join(&top));
            if from.is_dir() {
                crate::output::replace_dir(&from, &to)?;
            } else {
                std::fs::rename(&from, &to)
                    .with_context(|| format!("{}: cannot write", to.display()))?;
            }
        }
        crate::output::write_json(&job.out.join(SUMMARY), &report)
    })();
    let _ = std::fs::remove_dir_all(&stage);
    moved?;
    Ok(report)
}
