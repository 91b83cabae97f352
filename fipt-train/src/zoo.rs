//! The model zoo: a folder of scene models (`scene_model`), one sub-folder per name.
//!
//! Where it is: `--zoo DIR`, else `$FIPT_ZOO`, else `zoo/` beside the run's output folder (for
//! `run`) or in the working directory (every other command). Entries are complete or absent
//! (copied under a temporary name and renamed); a damaged entry is listed as damaged with the
//! reason, never skipped silently.
//!
//! Changes (`register`, `import`, `rm`) hold the zoo's lock (`crate::lock`), waiting up to a
//! minute for another process's change; an entry removed is first renamed aside, so a reader
//! sees it whole or not at all.
//!
//! Owns: naming, listing, registering, importing and removing entries. Must not touch: the
//! model folder's format (`scene_model`).

use crate::scene_model::{self, Manifest};
use anyhow::{Result, bail};
use serde::Serialize;
use std::path::{Path, PathBuf};

/// The environment variable naming the zoo folder.
pub const ZOO_ENV: &str = "FIPT_ZOO";

/// The zoo folder: the explicit one, else `$FIPT_ZOO`, else `fallback`.
pub fn resolve(explicit: Option<&Path>, fallback: &Path) -> PathBuf {
    explicit
        .map(Path::to_path_buf)
        .or_else(|| std::env::var_os(ZOO_ENV).map(PathBuf::from))
        .unwrap_or_else(|| fallback.to_path_buf())
}

/// The zoo of every command but `run`: the explicit one, else `$FIPT_ZOO`, else `./zoo`.
pub fn working(explicit: Option<&Path>) -> PathBuf {
    resolve(explicit, Path::new("zoo"))
}

/// The default zoo of `run`: `zoo/` beside the output folder.
pub fn beside(out: &Path) -> PathBuf {
    let parent = std::path::absolute(out)
        .ok()
        .and_then(|p| p.parent().map(Path::to_path_buf))
        .unwrap_or_else(|| PathBuf::from("."));
    parent.join("zoo")
}

/// A name is a plain folder name: letters, digits, `-`, `_`, `.`, not starting with `.`.
pub fn check_name(name: &str) -> Result<()> {
    if name.is_empty()
        || name.len() > 100
        || name.starts_with('.')
        || !name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'))
    {
        bail!(
            "model name '{name}': use 1-100 letters, digits, '-', '_' or '.', not starting with '.'"
        );
    }
    Ok(())
}

/// One listed entry.
#[derive(Clone, Debug, Serialize)]
pub struct Entry {
    pub name: String,
    pub path: String,
    /// None when the entry is damaged (`error` says why).
    pub manifest: Option<Manifest>,
    pub error: Option<String>,
}

pub struct Zoo {
    pub dir: PathBuf,
}

impl Zoo {
    pub fn new(dir: impl Into<PathBuf>) -> Self {
        Self { dir: dir.into() }
    }

    /// Every entry, sorted by name (temporary folders of unfinished copies are not entries).
    pub fn list(&self) -> Result<Vec<Entry>> {
        if !self.dir.exists() {
            return Ok(Vec::new());
        }
        let rd = std::fs::read_dir(&self.dir)
            .map_err(|e| anyhow::anyhow!("{}: cannot list: {e}", self.dir.display()))?;
        let mut names: Vec<String> = rd
            .filter_map(|e| e.ok())
            .filter(|e| e.path().is_dir())
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .filter(|n| !n.starts_with('.'))
            .collect();
        names.sort();
        Ok(names
            .into_iter()
            .map(|name| {
                let path = self.dir.join(&name);
                let (manifest, error) = match scene_model::read_manifest(&path)
                    .and_then(|m| scene_model::verify_sizes(&path, &m).map(|_| m))
                {
                    Ok(m) => (Some(m), None),
                    Err(e) => (None, Some(format!("{e:#}"))),
                };
                Entry {
                    name,
                    path: path.display().to_string(),
                    manifest,
                    error,
                }
            })
            .collect())
    }

    /// The folder of `name_or_dir`: an existing model folder as given, else the zoo's entry.
    pub fn locate(&self, name_or_dir: &str) -> Result<PathBuf> {
        let p = Path::new(name_or_dir);
        if p.join(scene_model::MANIFEST).is_file() {
            return Ok(p.to_path_buf());
        }
        check_name(name_or_dir).map_err(|_| {
            anyhow::anyhow!("{name_or_dir}: not a model folder and not a model name")
        })?;
        let d = self.dir.join(name_or_dir);
        if !d.is_dir() {
            let names: Vec<String> = self
                .list()
                .unwrap_or_default()
                .into_iter()
                .map(|e| e.name)
                .collect();
            bail!(
                "{}: no model '{name_or_dir}' in the zoo (it has: {})",
                self.dir.display(),
                if names.is_empty() {
                    "nothing".to_string()
                } else {
                    names.join(", ")
                }
            );
        }
        Ok(d)
    }

    /// Copies the model folder `from` into the zoo as `name` (replacing an entry of that name),
    /// after checking every file against its manifest.
    pub fn register(&self, from: &Path, name: &str) -> Result<PathBuf> {
        check_name(name)?;
        let _lock = self.lock()?;
        let m = scene_model::read_manifest(from)?;
        scene_model::verify_files(from, &m)?;
        let to = self.dir.join(name);
        scene_model::copy_dir(from, &m, &to)?;
        if m.name != name {
            // The entry's own manifest carries its zoo name (the hash list is unchanged).
            let mut m2 = m;
            m2.name = name.to_string();
            crate::output::write_json(&to.join(scene_model::MANIFEST), &m2)?;
        }
        Ok(to)
    }

    /// `zoo import DIR [--name N]`: loads the folder fully first (a damaged or foreign model is
    /// refused with the reason), then registers it.
    pub fn import(&self, from: &Path, name: Option<&str>) -> Result<PathBuf> {
        let device = burn::tensor::Device::flex();
        let sm = scene_model::SceneModel::load(from, &device)?;
        let name = name.unwrap_or(&sm.manifest.name).to_string();
        self.register(from, &name)
    }

    /// Removes an entry.
    pub fn remove(&self, name: &str) -> Result<()> {
        check_name(name)?;
        let d = self.dir.join(name);
        if !d.is_dir() {
            bail!("{}: no model '{name}' in the zoo", self.dir.display());
        }
        let _lock = self.lock()?;
        let aside = crate::output::sibling(&d, "gone");
        std::fs::rename(&d, &aside)
            .map_err(|e| anyhow::anyhow!("{}: cannot remove: {e}", d.display()))?;
        std::fs::remove_dir_all(&aside)
            .map_err(|e| anyhow::anyhow!("{}: cannot remove: {e}", aside.display()))
    }

    /// The zoo's lock, waiting up to a minute for another process's change to end.
    fn lock(&self) -> Result<crate::lock::DirLock> {
        crate::lock::DirLock::acquire_within(&self.dir, std::time::Duration::from_secs(60))
    }
}

/// `zoo list`'s table.
pub fn print_list(entries: &[Entry]) {
    if entries.is_empty() {
        println!("(the zoo is empty)");
        return;
    }
    let f = |v: Option<f64>| v.map_or("-".into(), |x| format!("{x:.2}"));
    println!(
        "{:<24} {:<16} {:<20} {:>8}  {:>6} {:>6} {:>6} {:>5} {:>6} {:>7}",
        "name", "scene", "created", "MB", "kd", "a'", "σ", "IoU", "view", "relight"
    );
    for e in entries {
        match &e.manifest {
            Some(m) => {
                let scene = Path::new(&m.scene)
                    .file_name()
                    .map_or(m.scene.clone(), |n| n.to_string_lossy().into_owned());
                println!(
                    "{:<24} {:<16} {:<20} {:>8.1}  {:>6} {:>6} {:>6} {:>5} {:>6} {:>7}",
                    e.name,
                    scene,
                    m.created,
                    m.total_bytes as f64 / 1e6,
                    f(m.metrics.kd_psnr),
                    f(m.metrics.albedo_psnr),
                    f(m.metrics.roughness_psnr),
                    f(m.metrics.emission_iou),
                    f(m.metrics.view_psnr),
                    f(m.metrics.relight_psnr)
                );
            }
            None => println!(
                "{:<24} DAMAGED: {}",
                e.name,
                e.error.as_deref().unwrap_or("?")
            ),
        }
    }
}
