//! The self-contained scene model: everything `run` recovered, in one folder that renders
//! without the photos.
//!
//! ```text
//! MODEL/
//!   manifest.json   format and code version, name, scene, mesh hash, grid layout, sizes, date,
//!                   headline metrics, and every file's size and FNV-64 hash
//!   model.json      field configs and scene box      }
//!   fields.bpk      material MLP and emission mask   } fipt-core's FiptModel
//!   hashgrid.f16    hash table, IEEE half            }
//!   parts.bin       part offsets' triangle map       } (with `train.part_offsets` only)
//!   mesh.obj        the scene's triangle mesh (triangle order kept)
//!   emitters.json   the extracted emitters (per-triangle radiance, observed sides)
//!   lightfield.bin  L′, the radiance cache of view synthesis (fipt-bake's compact form)
//!   config.json     the run's config
//!   metrics.json    the run's metrics
//! ```
//!
//! A model folder is written under a temporary name and renamed: it is complete or absent.
//! Loading checks the format version, every file's size and hash (a truncated or altered file is
//! named), then each file's own consistency.
//!
//! Owns: the folder format, save and load. Must not touch: how its parts were made (pipeline),
//! the zoo's bookkeeping (`zoo`).

use anyhow::{Context, Result, bail};
use fipt_bake::emitters::Emitter;
use fipt_bake::lightfield::LightField;
use fipt_core::io::Fnv64;
use fipt_core::model::{FiptModel, TableFormat};
use fipt_core::scene::Mesh;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The `format` field of every manifest.
pub const FORMAT: &str = "fipt-scene-model";
/// Bumped whenever a file of the folder changes meaning.
pub const FORMAT_VERSION: u32 = 1;
pub const MANIFEST: &str = "manifest.json";

/// One file of the folder.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct FileEntry {
    pub name: String,
    pub bytes: u64,
    /// FNV-64 of the content, hex.
    pub fnv64: String,
}

/// The headline figures a listing shows (None where the scene had no ground truth).
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq)]
pub struct Headline {
    pub kd_psnr: Option<f64>,
    pub albedo_psnr: Option<f64>,
    pub roughness_psnr: Option<f64>,
    pub emission_iou: Option<f64>,
    pub view_psnr: Option<f64>,
    pub relight_psnr: Option<f64>,
}

/// `manifest.json`.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Manifest {
    pub format: String,
    pub format_version: u32,
    /// fipt's version that wrote it.
    pub code_version: String,
    pub name: String,
    /// The scene folder the model was recovered from.
    pub scene: String,
    /// FNV-64 of the mesh (vertices and triangles), hex.
    pub mesh_hash: String,
    pub triangles: usize,
    /// Size of the training images: the default size of new cameras.
    pub image_size: [usize; 2],
    pub grid_levels: usize,
    pub grid_log2_table: u32,
    pub grid_features: usize,
    pub table_entries: usize,
    pub table_format: String,
    pub emitter_triangles: usize,
    pub light_field_voxels: usize,
    /// UTC, ISO 8601.
    pub created: String,
    pub seed: u64,
    pub metrics: Headline,
    pub files: Vec<FileEntry>,
    pub total_bytes: u64,
}

/// A loaded scene model.
pub struct SceneModel {
    pub manifest: Manifest,
    pub model: FiptModel,
    pub mesh: Mesh,
    pub emitters: Vec<Emitter>,
    pub light_field: LightField,
    pub dir: PathBuf,
}

/// What `save` writes besides the model itself.
pub struct SaveInfo<'a> {
    pub name: &'a str,
    pub scene: &'a Path,
    pub image_size: [usize; 2],
    pub seed: u64,
    pub metrics: Headline,
    pub config: &'a serde_json::Value,
    pub run_metrics: &'a serde_json::Value,
}

/// FNV-64 of a mesh's vertices and triangles, hex (the manifest's `mesh_hash`).
pub fn mesh_hash(mesh: &Mesh) -> String {
    let mut h = Fnv64::default();
    mesh.hash_into(&mut h);
    format!("{:016x}", h.finish())
}

fn file_hash(bytes: &[u8]) -> String {
    format!("{:016x}", Fnv64::default().bytes(bytes).finish())
}

/// The current UTC time as `YYYY-MM-DDThh:mm:ssZ`.
pub fn utc_now() -> String {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs()) as i64;
    let (days, rem) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    // Days since 1970-01-01 to a civil date (H. Hinnant's algorithm).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + (m <= 2) as i64;
    format!(
        "{y:04}-{m:02}-{d:02}T{:02}:{:02}:{:02}Z",
        rem / 3600,
        (rem / 60) % 60,
        rem % 60
    )
}

/// Writes the scene model into `dir` (replacing what is there) through a temporary sibling
/// folder renamed at the end, so `dir` is complete or absent.
pub fn save(
    dir: &Path,
    model: &FiptModel,
    mesh: &Mesh,
    emitters: &[Emitter],
    light_field: &LightField,
    info: &SaveInfo,
) -> Result<Manifest> {
    crate::output::staged_dir(dir, |tmp| {
        model
            .save(tmp, TableFormat::F16)
            .map_err(anyhow::Error::msg)?;
        mesh.save_obj(
            &tmp.join("mesh.obj"),
            &format!(
                "fipt scene model '{}': the mesh of {}",
                info.name,
                info.scene.display()
            ),
        )?;
        let write = |name: &str, bytes: &[u8]| -> Result<()> {
            fipt_core::io::write_bytes_atomic(&tmp.join(name), bytes)?;
            Ok(())
        };
        write(
            "emitters.json",
            serde_json::to_string_pretty(&serde_json::json!({ "emitters": emitters }))?.as_bytes(),
        )?;
        write("lightfield.bin", &light_field.to_bytes())?;
        write(
            "config.json",
            serde_json::to_string_pretty(info.config)?.as_bytes(),
        )?;
        write(
            "metrics.json",
            serde_json::to_string_pretty(info.run_metrics)?.as_bytes(),
        )?;
        let mut files = Vec::new();
        let mut names: Vec<String> = std::fs::read_dir(tmp)?
            .filter_map(|e| e.ok())
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        for name in names {
            let bytes = std::fs::read(tmp.join(&name))?;
            files.push(FileEntry {
                fnv64: file_hash(&bytes),
                bytes: bytes.len() as u64,
                name,
            });
        }
        let g = &model.spec.material.grid;
        let manifest = Manifest {
            format: FORMAT.into(),
            format_version: FORMAT_VERSION,
            code_version: env!("CARGO_PKG_VERSION").into(),
            name: info.name.into(),
            scene: info.scene.display().to_string(),
            mesh_hash: mesh_hash(mesh),
            triangles: mesh.num_triangles(),
            image_size: info.image_size,
            grid_levels: g.levels,
            grid_log2_table: g.log2_table,
            grid_features: g.features,
            table_entries: model.grid.table.len(),
            table_format: "f16".into(),
            emitter_triangles: emitters.len(),
            light_field_voxels: light_field.occupied() + light_field.filled(),
            created: utc_now(),
            seed: info.seed,
            metrics: info.metrics.clone(),
            total_bytes: files.iter().map(|f| f.bytes).sum(),
            files,
        };
        write(
            MANIFEST,
            serde_json::to_string_pretty(&manifest)?.as_bytes(),
        )?;
        Ok(manifest)
    })
}

/// Copies a model folder (only the files its manifest lists) to `to`, atomically.
pub fn copy_dir(from: &Path, manifest: &Manifest, to: &Path) -> Result<()> {
    crate::output::staged_dir(to, |tmp| {
        for f in &manifest.files {
            std::fs::copy(from.join(&f.name), tmp.join(&f.name))
                .with_context(|| format!("{}: cannot copy", from.join(&f.name).display()))?;
        }
        std::fs::copy(from.join(MANIFEST), tmp.join(MANIFEST))
            .with_context(|| format!("{}: cannot copy", from.join(MANIFEST).display()))?;
        Ok(())
    })
}

/// Reads and checks `DIR/manifest.json` alone (format, version); no file is opened.
pub fn read_manifest(dir: &Path) -> Result<Manifest> {
    let path = dir.join(MANIFEST);
    if !dir.is_dir() {
        bail!("{}: not a folder", dir.display());
    }
    let text = fipt_core::io::read_text(&path)
        .map_err(|e| anyhow::anyhow!("{e} (is this a fipt scene model?)"))?;
    let value: serde_json::Value = serde_json::from_str(&text)
        .map_err(|e| anyhow::anyhow!("{}: malformed JSON: {e}", path.display()))?;
    let format = value.get("format").and_then(|v| v.as_str()).unwrap_or("");
    if format != FORMAT {
        bail!(
            "{}: format '{format}', expected '{FORMAT}' (not a fipt scene model)",
            path.display()
        );
    }
    let version = value.get("format_version").and_then(|v| v.as_u64());
    if version != Some(FORMAT_VERSION as u64) {
        bail!(
            "{}: format version {}, this fipt ({}) reads version {FORMAT_VERSION}; re-run `fipt-train run` with this version to rebuild the model",
            path.display(),
            version.map_or("missing".into(), |v| v.to_string()),
            env!("CARGO_PKG_VERSION"),
        );
    }
    let m: Manifest = serde_path_to_error::deserialize(value)
        .map_err(|e| anyhow::anyhow!("{}: {}: {}", path.display(), e.path(), e.inner()))?;
    if let Some(f) = m
        .files
        .iter()
        .find(|f| f.name.contains(['/', '\\']) || f.name.starts_with('.') || f.name == MANIFEST)
    {
        bail!("{}: bad file name '{}'", path.display(), f.name);
    }
    Ok(m)
}

/// Checks every listed file's presence and size, and that the model's files are listed
/// (cheap: no file is read).
pub fn verify_sizes(dir: &Path, m: &Manifest) -> Result<()> {
    for name in [
        "model.json",
        "fields.bpk",
        "hashgrid.f16",
        "mesh.obj",
        "emitters.json",
        "lightfield.bin",
    ] {
        if !m.files.iter().any(|f| f.name == name) {
            bail!("{}: does not list {name}", dir.join(MANIFEST).display());
        }
    }
    for f in &m.files {
        let path = dir.join(&f.name);
        let len = std::fs::metadata(&path)
            .map_err(|_| anyhow::anyhow!("{}: missing (listed in {MANIFEST})", path.display()))?
            .len();
        if len != f.bytes {
            bail!(
                "{}: {len} bytes, the manifest says {} (truncated or replaced)",
                path.display(),
                f.bytes
            );
        }
    }
    Ok(())
}

/// Checks every listed file's presence, size and hash.
pub fn verify_files(dir: &Path, m: &Manifest) -> Result<()> {
    verify_sizes(dir, m)?;
    for f in &m.files {
        let path = dir.join(&f.name);
        let bytes =
            std::fs::read(&path).with_context(|| format!("{}: cannot read", path.display()))?;
        if file_hash(&bytes) != f.fnv64 {
            bail!(
                "{}: content differs from the manifest's hash (damaged or edited)",
                path.display()
            );
        }
    }
    Ok(())
}

impl SceneModel {
    /// The model `name_or_dir` (a folder, or a name in the zoo `zoo`) loaded for `backend`:
    /// on a GPU backend its hash table is uploaded to the device.
    pub fn open(
        name_or_dir: &str,
        zoo: &Path,
        backend: fipt_core::model::BackendKind,
    ) -> Result<Self> {
        let dir = crate::zoo::Zoo::new(zoo).locate(name_or_dir)?;
        let device = backend.device().map_err(anyhow::Error::msg)?;
        let mut m = Self::load(&dir, &device)?;
        if backend.is_gpu() {
            m.model.upload_table();
        }
        Ok(m)
    }

    /// Loads a model folder on `device`; every error names the file and the problem.
    pub fn load(dir: &Path, device: &burn::tensor::Device) -> Result<Self> {
        let manifest = read_manifest(dir)?;
        verify_files(dir, &manifest)?;
        let model = FiptModel::load(dir, device).map_err(anyhow::Error::msg)?;
        let mesh = Mesh::load_obj(&dir.join("mesh.obj"))?;
        let mesh_path = dir.join("mesh.obj");
        if mesh_hash(&mesh) != manifest.mesh_hash {
            bail!(
                "{}: the mesh differs from the manifest's hash",
                mesh_path.display()
            );
        }
        let rows = model.part_map.tri_row.len();
        if model.spec.parts > 0 && rows != mesh.num_triangles() {
            bail!(
                "{}: {rows} triangles, but the mesh has {}",
                dir.join("parts.bin").display(),
                mesh.num_triangles()
            );
        }
        let em_path = dir.join("emitters.json");
        let text = fipt_core::io::read_text(&em_path)?;
        #[derive(Deserialize)]
        struct Emitters {
            emitters: Vec<Emitter>,
        }
        let em: Emitters = serde_json::from_str(&text)
            .map_err(|e| anyhow::anyhow!("{}: malformed: {e}", em_path.display()))?;
        if let Some(e) = em.emitters.iter().find(|e| {
            e.triangle as usize >= mesh.num_triangles()
                || !e.radiance.iter().all(|x| x.is_finite() && *x >= 0.0)
        }) {
            bail!(
                "{}: emitter on triangle {} (the mesh has {}) or radiance {:?} is invalid",
                em_path.display(),
                e.triangle,
                mesh.num_triangles(),
                e.radiance
            );
        }
        let lf_path = dir.join("lightfield.bin");
        let light_field = LightField::from_bytes(&fipt_core::io::read_bytes(&lf_path)?)
            .map_err(|e| anyhow::anyhow!("{}: {e}", lf_path.display()))?;
        if light_field.scene_box != model.spec.scene_box {
            bail!("{}: scene box differs from model.json's", lf_path.display());
        }
        Ok(Self {
            manifest,
            model,
            mesh,
            emitters: em.emitters,
            light_field,
            dir: dir.to_path_buf(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::zoo::Zoo;
    use fipt_core::model::{HashGridConfig, MaterialFieldConfig, TrainConfig, Trainer};
    use fipt_core::scene::SceneBox;
    use glam::Vec3;

    /// A small random model, the procedural room, two emitters and a light field.
    fn parts() -> (FiptModel, Mesh, Vec<Emitter>, LightField) {
        let cfg = TrainConfig::new().with_material(
            MaterialFieldConfig::new()
                .with_grid(HashGridConfig::new().with_levels(6).with_log2_table(12)),
        );
        let sb = SceneBox {
            min: -0.5,
            max: 4.5,
        };
        let mut tr = Trainer::new(cfg, sb, &burn::tensor::Device::flex(), 5);
        // Spread the table like a trained one (the init is ±1e-4).
        let mut rng = fipt_core::rng::Rng::new(3, 0);
        for v in &mut tr.model.grid.table {
            *v = (rng.next_f32() - 0.5) * 4.0;
        }
        let room = fipt_core::scene::procedural::room(Vec3::new(4.0, 2.5, 3.0), 1);
        let mesh = room.mesh;
        let em = (0..2usize)
            .map(|t| Emitter {
                pixels: 10,
                seen_front: 10,
                ..Emitter::on_triangle(&mesh, t, [5.0, 4.0, 3.0])
            })
            .collect();
        let samples = mesh.vertices.iter().map(|&p| (p, Vec3::Y, [1.0, 2.0, 3.0]));
        let lf = LightField::build(sb, 32, samples);
        (tr.model, mesh, em, lf)
    }

    fn info<'a>(cfg: &'a serde_json::Value, name: &'a str) -> SaveInfo<'a> {
        SaveInfo {
            name,
            scene: Path::new("/nowhere/room"),
            image_size: [16, 12],
            seed: 0,
            metrics: Headline {
                kd_psnr: Some(27.0),
                ..Default::default()
            },
            config: cfg,
            run_metrics: cfg,
        }
    }

    fn tmp(tag: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("fipt-sm-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        d
    }

    /// Saved and loaded, the model answers material queries as before up to the f16 table
    /// (which moves them far less than a random model differs from this one), with the same
    /// mesh, emitters and L′; every kind of damage is refused with the file named.
    #[test]
    fn round_trip_and_damage() {
        let (model, mesh, em, lf) = parts();
        let root = tmp("rt");
        let dir = root.join("m");
        let cfg = serde_json::json!({"seed": 0});
        let man = save(&dir, &model, &mesh, &em, &lf, &info(&cfg, "room-s0")).unwrap();
        assert!(
            man.total_bytes > 0 && man.files.len() == 8,
            "{:?}",
            man.files
        );
        // No temporary folder is left beside it.
        let names: Vec<_> = std::fs::read_dir(&root)
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names.len(), 1, "{names:?}");
        let dev = burn::tensor::Device::flex();
        let back = SceneModel::load(&dir, &dev).unwrap();
        assert_eq!(back.mesh.triangles, mesh.triangles);
        assert_eq!(back.mesh.vertices, mesh.vertices);
        assert_eq!(back.emitters, em);
        let pts: Vec<Vec3> = (0..200)
            .map(|i| {
                Vec3::new(
                    0.02 * i as f32,
                    1.0 + 0.005 * i as f32,
                    2.9 - 0.014 * i as f32,
                )
            })
            .collect();
        let (a, b) = (
            model.material_world(&pts, &[]),
            back.model.material_world(&pts, &[]),
        );
        let diff = |x: &[f32], y: &[f32]| {
            x.iter()
                .zip(y)
                .map(|(p, q)| (p - q).abs())
                .fold(0.0, f32::max)
        };
        let d16 = diff(&a.a, &b.a)
            .max(diff(&a.sigma, &b.sigma))
            .max(diff(&a.metallic, &b.metallic));
        let other = parts_seeded(9).material_world(&pts, &[]);
        let dother = diff(&a.a, &other.a).max(diff(&a.sigma, &other.sigma));
        assert!(
            d16 < 2e-3 && d16 * 20.0 < dother,
            "f16 {d16}, another model {dother}"
        );
        for p in &pts {
            let (x, y) = (lf.query(*p, Vec3::Y), back.light_field.query(*p, Vec3::Y));
            assert!((x - y).abs().max_element() < 4e-3, "{x} {y}");
        }

        // Damage: each case is a copy of the good folder with one thing wrong.
        let damaged = |tag: &str, f: &dyn Fn(&Path)| -> String {
            let d = root.join(tag);
            copy_dir(&dir, &read_manifest(&dir).unwrap(), &d).unwrap();
            f(&d);
            match SceneModel::load(&d, &dev) {
                Ok(_) => panic!("{tag}: loaded"),
                Err(e) => format!("{e:#}"),
            }
        };
        let e = damaged("trunc", &|d| {
            let p = d.join("hashgrid.f16");
            let b = std::fs::read(&p).unwrap();
            std::fs::write(&p, &b[..b.len() / 2]).unwrap();
        });
        assert!(e.contains("hashgrid.f16") && e.contains("truncated"), "{e}");
        let e = damaged("flip", &|d| {
            let p = d.join("lightfield.bin");
            let mut b = std::fs::read(&p).unwrap();
            let k = b.len() / 2;
            b[k] ^= 1;
            std::fs::write(&p, &b).unwrap();
        });
        assert!(e.contains("lightfield.bin") && e.contains("hash"), "{e}");
        let e = damaged("missing", &|d| {
            std::fs::remove_file(d.join("mesh.obj")).unwrap()
        });
        assert!(e.contains("mesh.obj") && e.contains("missing"), "{e}");
        let e = damaged("version", &|d| {
            let p = d.join(MANIFEST);
            let t = std::fs::read_to_string(&p).unwrap();
            std::fs::write(
                &p,
                t.replace("\"format_version\": 1", "\"format_version\": 99"),
            )
            .unwrap();
        });
        assert!(
            e.contains("manifest.json") && e.contains("version 99"),
            "{e}"
        );
        let e = damaged("foreign", &|d| {
            std::fs::write(d.join(MANIFEST), "{\"format\": \"something-else\"}").unwrap();
        });
        assert!(e.contains("not a fipt scene model"), "{e}");
        let e = damaged("sizes", &|d| {
            // A consistent manifest whose model.json asks for a larger table.
            let p = d.join("model.json");
            let t = std::fs::read_to_string(&p).unwrap();
            std::fs::write(&p, t.replace("\"log2_table\": 12", "\"log2_table\": 13")).unwrap();
            let mut m = read_manifest(d).unwrap();
            let bytes = std::fs::read(&p).unwrap();
            let f = m.files.iter_mut().find(|f| f.name == "model.json").unwrap();
            f.bytes = bytes.len() as u64;
            f.fnv64 = file_hash(&bytes);
            crate::output::write_json(&d.join(MANIFEST), &m).unwrap();
        });
        assert!(e.contains("hashgrid.f16") && e.contains("needs"), "{e}");
        let e = match SceneModel::load(&root.join("nothing"), &dev) {
            Ok(_) => panic!("loaded nothing"),
            Err(e) => format!("{e:#}"),
        };
        assert!(e.contains("not a folder"), "{e}");

        // The zoo: register under a new name, list, locate, a damaged entry, remove.
        let zoo = Zoo::new(root.join("zoo"));
        let to = zoo.register(&dir, "kept").unwrap();
        assert_eq!(read_manifest(&to).unwrap().name, "kept");
        SceneModel::load(&to, &dev).unwrap();
        assert_eq!(zoo.locate("kept").unwrap(), to);
        assert!(
            zoo.locate("absent")
                .unwrap_err()
                .to_string()
                .contains("kept")
        );
        assert!(zoo.register(&dir, "../evil").is_err());
        zoo.import(&dir, Some("second")).unwrap();
        assert!(zoo.import(&root.join("trunc"), Some("bad")).is_err());
        assert!(!root.join("zoo").join("bad").exists());
        std::fs::remove_file(root.join("zoo/second/emitters.json")).unwrap();
        let list = zoo.list().unwrap();
        assert_eq!(list.len(), 2);
        assert!(list[0].manifest.is_some() && list[0].error.is_none());
        assert!(
            list[1].error.as_deref().unwrap().contains("emitters.json"),
            "{list:?}"
        );
        zoo.remove("second").unwrap();
        assert!(zoo.remove("second").is_err());
        assert_eq!(zoo.list().unwrap().len(), 1);
        let _ = std::fs::remove_dir_all(&root);
    }

    fn parts_seeded(seed: u64) -> FiptModel {
        let (mut m, ..) = parts();
        let mut rng = fipt_core::rng::Rng::new(seed, 0);
        for v in &mut m.grid.table {
            *v = (rng.next_f32() - 0.5) * 4.0;
        }
        m
    }

    #[test]
    fn civil_dates() {
        let s = utc_now();
        assert_eq!(s.len(), 20, "{s}");
        assert!(s.starts_with("20") && s.ends_with('Z'));
    }
}
