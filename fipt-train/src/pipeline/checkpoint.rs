//! The resumable state of `run` in `OUT/checkpoint/`: what the stages after the bake computed,
//! so that running the same command again continues where a killed or interrupted run
//! stopped.
//!
//! - `key.json`: what every saved state depends on — the program (a hash of the executable),
//!   the scene (mesh, cameras, photos and maps) and the config keys that change a fit. A
//!   mismatch discards the whole folder, and the message says what changed.
//! - `round{r}/step{s:07}/`: the fit of round `r` after `s` steps (`Trainer::save_state` plus
//!   `FitProgress::save`), saved every `checkpoint.every_steps` steps, on Ctrl-C, and when the
//!   fit ends; only the newest stays. Each folder is written under a `.tmp` name and renamed,
//!   so it is complete or absent, and sealed by `manifest.json` (every file's size and XXH3-64
//!   content hash), checked before a state is restored: a damaged folder is named and discarded
//!   with the rounds after it, which are then fitted again. After the fit's basin hop (`pipeline::hop`) its last folder
//!   is written again with the hopped state and the hop's report (`save_again`).
//! - `round{r}/emitters.json` (round 0) and `round{r}/report.json` (every round but the last):
//!   what follows a finished fit.
//!
//! The bake and each refinement round have their own keyed caches in `OUT/cache/`.
//!
//! Owns: this folder's layout, keys and validation, and the removal of what a killed run left
//! in `OUT` (`remove_stale_tmp`). Must not touch: what the stages compute.

use super::fit::{FitProgress, FitRun};
use super::pixels::PixelStore;
use anyhow::{Context, Result};
use fipt_core::model::{TrainConfig, Trainer};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Bumped whenever this folder's layout or a saved file's format changes.
const FORMAT: u32 = 2;
const KEY_FILE: &str = "key.json";
/// The seal of a step folder: every other file's size and content hash.
pub const MANIFEST_FILE: &str = "manifest.json";

/// `MANIFEST_FILE`: file name → (bytes, XXH3-64 of the content, hex).
#[derive(Debug, Default, Serialize, Deserialize)]
struct StepManifest {
    files: std::collections::BTreeMap<String, (u64, String)>,
}

/// Size and XXH3-64 (hex) of the file at `p`, read in 1 MiB pieces.
fn file_hash(p: &Path) -> Result<(u64, String)> {
    use std::io::Read;
    let mut f = std::fs::File::open(p).with_context(|| format!("{}: cannot open", p.display()))?;
    let mut h = xxhash_rust::xxh3::Xxh3::new();
    let (mut buf, mut len) = (vec![0u8; 1 << 20], 0u64);
    loop {
        let n = f
            .read(&mut buf)
            .with_context(|| format!("{}: cannot read", p.display()))?;
        if n == 0 {
            break;
        }
        h.update(&buf[..n]);
        len += n as u64;
    }
    Ok((len, format!("{:016x}", h.digest())))
}

/// Writes the manifest of the step folder `dir` (every file in it).
fn seal(dir: &Path) -> Result<()> {
    let mut m = StepManifest::default();
    for e in std::fs::read_dir(dir).with_context(|| format!("{}: cannot list", dir.display()))? {
        let e = e.with_context(|| format!("{}: cannot list", dir.display()))?;
        let name = e.file_name().to_string_lossy().into_owned();
        if name != MANIFEST_FILE && e.file_type().is_ok_and(|t| t.is_file()) {
            m.files.insert(name, file_hash(&e.path())?);
        }
    }
    crate::output::write_json(&dir.join(MANIFEST_FILE), &m)
}

/// Checks the step folder `dir` against its manifest: an error naming the first file that is
/// missing, of another size or of another content hash (or the manifest itself).
pub fn verify_step(dir: &Path) -> Result<()> {
    let mp = dir.join(MANIFEST_FILE);
    let m: StepManifest = serde_json::from_str(&fipt_core::io::read_text(&mp)?)
        .map_err(|e| anyhow::anyhow!("{}: damaged: {e}", mp.display()))?;
    if m.files.is_empty() {
        anyhow::bail!("{}: damaged: lists no file", mp.display());
    }
    for (name, want) in &m.files {
        let p = dir.join(name);
        let got = file_hash(&p)?;
        if got.0 != want.0 {
            anyhow::bail!(
                "{}: damaged: {} bytes, {} says {}",
                p.display(),
                got.0,
                mp.display(),
                want.0
            );
        }
        if got.1 != want.1 {
            anyhow::bail!(
                "{}: damaged: its content hash differs from the one in {}",
                p.display(),
                mp.display()
            );
        }
    }
    Ok(())
}

/// What every saved state depends on.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunKey {
    pub format: u32,
    /// XXH3-64 of the running executable, hex.
    pub program: String,
    /// FNV-64 of the scene as loaded, hex.
    pub scene: String,
    /// The config keys that change any fit or the saved scores (everything but
    /// `refine.rounds`, `render` and `checkpoint`), plus whether the run fits the oracle
    /// shadings.
    pub config: serde_json::Value,
}

impl RunKey {
    pub fn new(
        program: u64,
        scene: u64,
        cfg: &crate::config::Config,
        oracle: bool,
    ) -> Result<Self> {
        let mut c = serde_json::to_value(cfg)?;
        if let Some(m) = c.as_object_mut() {
            for k in ["render", "checkpoint"] {
                m.remove(k);
            }
            if let Some(r) = m.get_mut("refine").and_then(|r| r.as_object_mut()) {
                r.remove("rounds");
            }
            m.insert("oracle".into(), oracle.into());
        }
        Ok(Self {
            format: FORMAT,
            program: hex(program),
            scene: hex(scene),
            config: c,
        })
    }

    /// Why `self` (saved) does not hold for `now`, in words; None when it does.
    fn mismatch(&self, now: &RunKey) -> Option<String> {
        let mut why = Vec::new();
        if self.format != now.format {
            why.push("the checkpoint format changed".to_string());
        }
        if self.program != now.program {
            why.push("the program changed (fipt-train was rebuilt)".to_string());
        }
        if self.scene != now.scene {
            why.push("the scene changed (its mesh, cameras, photos or maps)".to_string());
        }
        let mut keys = Vec::new();
        json_diff(&self.config, &now.config, "", &mut keys);
        if !keys.is_empty() {
            keys.truncate(6);
            why.push(format!("the config changed at {}", keys.join(", ")));
        }
        (!why.is_empty()).then(|| why.join("; "))
    }
}

/// The dotted paths where `a` and `b` differ.
fn json_diff(a: &serde_json::Value, b: &serde_json::Value, at: &str, out: &mut Vec<String>) {
    use serde_json::Value::Object;
    match (a, b) {
        (Object(x), Object(y)) => {
            let keys: std::collections::BTreeSet<&String> = x.keys().chain(y.keys()).collect();
            for k in keys {
                let path = if at.is_empty() {
                    k.clone()
                } else {
                    format!("{at}.{k}")
                };
                match (x.get(k), y.get(k)) {
                    (Some(u), Some(v)) => json_diff(u, v, &path, out),
                    _ => out.push(path),
                }
            }
        }
        _ if a != b => out.push(if at.is_empty() {
            "(root)".into()
        } else {
            at.into()
        }),
        _ => {}
    }
}

/// A key's hashes as written in `key.json`: 16 hex digits.
fn hex(h: u64) -> String {
    format!("{h:016x}")
}

/// The key a checkpoint folder `dir` was saved under; None where it is missing or unreadable.
fn saved_key(dir: &Path) -> Option<RunKey> {
    fipt_core::io::read_text(&dir.join(KEY_FILE))
        .ok()
        .and_then(|t| serde_json::from_str::<RunKey>(&t).ok())
}

/// Whether the checkpoint in `out` was saved by the running program (its `key.json` names this
/// executable's hash); false where there is none or it cannot be read.
pub fn saved_by_this_program(out: &Path) -> bool {
    saved_key(&out.join("checkpoint")).is_some_and(|k| k.program == hex(program_hash()))
}

/// XXH3-64 of the running executable: a different build is a different program. When the
/// executable cannot be read, a warning says so and the hash is this process's own (time and
/// pid), so no saved state is taken for this build's and this run's is taken by no other.
pub fn program_hash() -> u64 {
    static HASH: std::sync::OnceLock<u64> = std::sync::OnceLock::new();
    *HASH.get_or_init(|| match std::env::current_exe().and_then(std::fs::read) {
        Ok(bytes) => xxhash_rust::xxh3::xxh3_64(&bytes),
        Err(e) => {
            eprintln!(
                "warning: cannot read the running executable to key the checkpoints ({e}): \
                     this run's saved state will not be resumed by another process"
            );
            let nanos = std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.as_nanos() as u64);
            xxhash_rust::xxh3::xxh3_64(
                &[
                    nanos.to_le_bytes(),
                    (std::process::id() as u64).to_le_bytes(),
                ]
                .concat(),
            )
        }
    })
}

/// FNV-64 of a loaded scene: the bake's key (mesh, cameras, photos, bake config), its
/// `scene_meta.json` (the parts of the scores) and every map of every split.
pub fn scene_hash(ds: &fipt_core::scene::Dataset, bake_key: u64) -> Result<u64> {
    let mut h = fipt_core::io::Fnv64::default();
    h.bytes(&bake_key.to_le_bytes());
    h.bytes(serde_json::to_string(&ds.meta)?.as_bytes());
    for split in ds.splits() {
        h.bytes(split.name.as_bytes());
        for v in &split.views {
            for (kind, img) in &v.maps {
                h.bytes(format!("{kind:?}").as_bytes());
                h.f32s(&img.data);
            }
        }
    }
    Ok(h.finish())
}

/// The checkpoint folder of one run.
pub struct Checkpoints {
    pub dir: PathBuf,
    /// Save every this many steps (0: only when a fit ends or is interrupted).
    pub every: usize,
}

/// The fit a saved state must belong to: its base trainer config (before the schedule sets
/// each step's rate and λ_d), device, trainer seed, pixels and run.
pub struct FitOf<'a> {
    pub cfg: &'a TrainConfig,
    pub device: &'a burn::tensor::Device,
    pub seed: u64,
    pub store: &'a PixelStore,
    pub run: &'a FitRun<'a>,
}

/// A fit restored from its newest checkpoint.
pub struct Restored {
    pub trainer: Trainer,
    pub progress: FitProgress,
}

impl Checkpoints {
    /// Opens `out/checkpoint` for `key`: a folder saved under another key is removed first,
    /// and the returned message says what was thrown away and why. Stale temporary files
    /// anywhere under `out` (left by a killed run) are removed.
    pub fn open(out: &Path, key: &RunKey, every: usize) -> Result<(Self, Option<String>)> {
        remove_stale_tmp(out);
        let dir = out.join("checkpoint");
        let key_path = dir.join(KEY_FILE);
        let mut note = None;
        if dir.exists() {
            let why = match &saved_key(&dir) {
                None => Some(format!("{} is missing or unreadable", key_path.display())),
                Some(s) => s.mismatch(key),
            };
            if let Some(why) = why {
                let what = describe(&dir);
                remove_dir_aside(&dir);
                if dir.exists() {
                    anyhow::bail!("{}: cannot remove", dir.display());
                }
                if let Some(what) = what {
                    note = Some(format!(
                        "discarded the saved state in {} ({what}): {why}",
                        dir.display()
                    ));
                }
            }
        }
        if !key_path.exists() {
            crate::output::write_json(&key_path, key)?;
        }
        Ok((Self { dir, every }, note))
    }

    fn round_dir(&self, round: usize) -> PathBuf {
        self.dir.join(format!("round{round}"))
    }

    /// The newest step folder of `round`'s fit, with its step.
    fn newest(&self, round: usize) -> Option<(usize, PathBuf)> {
        step_dirs(&self.round_dir(round)).into_iter().last()
    }

    /// Whether `round`'s saved fit has also run its basin hop (`TrainLog::hop`). Asked only of
    /// a round whose `fit_done` holds, which has checked the folder against its manifest.
    pub fn hop_done(&self, round: usize) -> bool {
        self.newest(round)
            .is_some_and(|(_, d)| FitProgress::load_log(&d).is_ok_and(|l| l.hop.is_some()))
    }

    /// Whether `round`'s fit has a saved state that has run every step.
    pub fn fit_done(&self, round: usize) -> bool {
        self.newest(round)
            .is_some_and(|(_, d)| verify_step(&d).is_ok() && FitProgress::saved_done(&d))
    }

    /// Removes the saved states of `round` and of every round after it.
    pub fn discard_from(&self, round: usize) {
        for r in round.. {
            let rd = self.round_dir(r);
            if !rd.exists() {
                break;
            }
            remove_dir_aside(&rd);
        }
    }

    /// Like `restore`, but a damaged state is discarded (with the rounds after it) with a
    /// message naming the file instead of failing the run: the fit then starts afresh.
    pub fn restore_or_discard(&self, round: usize, fit: &FitOf) -> Option<Restored> {
        match self.restore(round, fit) {
            Ok(r) => r,
            Err(e) => {
                eprintln!("discarded round {round}'s saved fit, which is damaged: {e:#}");
                self.discard_from(round);
                None
            }
        }
    }

    /// The newest saved state of `round`'s fit; None when there is none. A damaged state is an
    /// error naming its file.
    pub fn restore(&self, round: usize, fit: &FitOf) -> Result<Option<Restored>> {
        let Some((_, dir)) = self.newest(round) else {
            return Ok(None);
        };
        verify_step(&dir)?;
        let progress = FitProgress::load(&dir, fit.store, fit.run.mode, fit.run.schedule)?;
        let trainer = Trainer::restore(fit.cfg.clone(), fit.device, fit.seed, &dir)
            .map_err(anyhow::Error::msg)?;
        Ok(Some(Restored { trainer, progress }))
    }

    /// The newest trainer of a finished `round` without its sampler (what the rounds after it
    /// and the outputs need).
    pub fn restore_trainer(
        &self,
        round: usize,
        cfg: &TrainConfig,
        device: &burn::tensor::Device,
        seed: u64,
    ) -> Result<(Trainer, super::fit::TrainLog)> {
        let (_, dir) = self
            .newest(round)
            .with_context(|| format!("{}: no saved fit", self.round_dir(round).display()))?;
        verify_step(&dir)?;
        let trainer =
            Trainer::restore(cfg.clone(), device, seed, &dir).map_err(anyhow::Error::msg)?;
        let log = FitProgress::load_log(&dir)?;
        Ok((trainer, log))
    }

    /// Saves the state of `round`'s fit after `p.step` steps as a new step folder (staged
    /// under a `.tmp` name, then renamed), then removes the older ones.
    pub fn save(&self, round: usize, tr: &Trainer, p: &mut FitProgress) -> Result<()> {
        self.save_step(round, tr, p, false)
    }

    /// `save`, replacing a folder already saved at this step: for a fit whose state changed
    /// after its last step (the basin hop, `pipeline::hop`). The old folder is renamed
    /// `stepN.prev` until the new one is in place; a run killed in between finds it there, and
    /// `remove_stale_tmp` puts it back (the round then redoes only what followed that save).
    pub fn save_again(&self, round: usize, tr: &Trainer, p: &mut FitProgress) -> Result<()> {
        self.save_step(round, tr, p, true)
    }

    fn save_step(
        &self,
        round: usize,
        tr: &Trainer,
        p: &mut FitProgress,
        replace: bool,
    ) -> Result<()> {
        p.settle();
        let rd = self.round_dir(round);
        let name = format!("step{:07}", p.step);
        let fin = rd.join(&name);
        if fin.exists() && !replace {
            return Ok(());
        }
        let tmp = rd.join(format!("{name}.tmp"));
        let _ = std::fs::remove_dir_all(&tmp);
        std::fs::create_dir_all(&tmp)
            .with_context(|| format!("{}: cannot create", tmp.display()))?;
        tr.save_state(&tmp).map_err(anyhow::Error::msg)?;
        p.save(&tmp)?;
        seal(&tmp)?;
        let prev = rd.join(format!("{name}.prev"));
        if fin.exists() {
            remove_dir_aside(&prev);
            std::fs::rename(&fin, &prev).with_context(|| {
                format!("{}: cannot rename to {}", fin.display(), prev.display())
            })?;
        }
        std::fs::rename(&tmp, &fin)
            .with_context(|| format!("{}: cannot rename to {}", tmp.display(), fin.display()))?;
        remove_dir_aside(&prev);
        for (s, d) in step_dirs(&rd) {
            if s < p.step {
                remove_dir_aside(&d);
            }
        }
        Ok(())
    }

    /// Whether a fit that has just run `p.step` steps saves now (every `every` steps, and at
    /// its end).
    pub fn due(&self, p: &FitProgress) -> bool {
        p.done() || (self.every > 0 && p.step.is_multiple_of(self.every))
    }

    /// Writes `round{round}/{name}` atomically.
    pub fn put<T: Serialize>(&self, round: usize, name: &str, v: &T) -> Result<()> {
        crate::output::write_json(&self.round_dir(round).join(name), v)
    }

    /// Whether `round{round}/{name}` exists.
    pub fn has(&self, round: usize, name: &str) -> bool {
        self.round_dir(round).join(name).is_file()
    }

    /// Reads `round{round}/{name}`; None when absent, an error naming the file when damaged.
    pub fn get<T: for<'de> Deserialize<'de>>(&self, round: usize, name: &str) -> Result<Option<T>> {
        let p = self.round_dir(round).join(name);
        if !p.exists() {
            return Ok(None);
        }
        let t = fipt_core::io::read_text(&p)?;
        serde_json::from_str(&t)
            .map(Some)
            .map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))
    }
}

/// The step folders of a round, oldest first (temporary ones left out).
fn step_dirs(round_dir: &Path) -> Vec<(usize, PathBuf)> {
    let mut v: Vec<(usize, PathBuf)> = std::fs::read_dir(round_dir)
        .into_iter()
        .flatten()
        .flatten()
        .filter_map(|e| {
            let name = e.file_name().into_string().ok()?;
            let s = name.strip_prefix("step")?.parse().ok()?;
            Some((s, e.path()))
        })
        .collect();
    v.sort();
    v
}

/// "round 1 at step 300; round 0 finished" for a checkpoint folder; None when it holds no fit.
fn describe(dir: &Path) -> Option<String> {
    let mut parts = Vec::new();
    for r in 0.. {
        let rd = dir.join(format!("round{r}"));
        if !rd.exists() {
            break;
        }
        if let Some((s, _)) = step_dirs(&rd).into_iter().last() {
            parts.push(format!("round {r} at step {s}"));
        }
    }
    (!parts.is_empty()).then(|| parts.join(", "))
}

/// Renames `dir` to a temporary name, then removes it: a kill in between never leaves a
/// half-deleted folder under its own name.
fn remove_dir_aside(dir: &Path) {
    let aside = crate::output::sibling(dir, "gone");
    if std::fs::rename(dir, &aside).is_ok() {
        let _ = std::fs::remove_dir_all(aside);
    }
}

/// Whether `name` is a temporary of a fipt process that is no longer running: a file
/// `NAME.PID.tmp` (`fipt_core::io::write_atomic`), a folder `.NAME.TAG-PID.tmp`
/// (`scene_model::sibling`), or a checkpoint step folder `stepN.tmp`.
fn stale_tmp(name: &str) -> bool {
    let Some(stem) = name.strip_suffix(".tmp") else {
        return false;
    };
    if stem.starts_with("step") && stem[4..].bytes().all(|b| b.is_ascii_digit()) {
        return true;
    }
    let pid = stem
        .rsplit(['.', '-'])
        .next()
        .filter(|p| !p.is_empty() && p.bytes().all(|b| b.is_ascii_digit()));
    pid.is_some_and(|p| !Path::new("/proc").join(p).exists() || p == std::process::id().to_string())
}

/// Removes the temporaries a killed run left (`stale_tmp`) in `out`, `out/cache` and,
/// recursively, `out/checkpoint`. A folder staged to replace `out/NAME` whose old copy was set
/// aside (`.NAME.old-PID.tmp`) while `NAME` is missing is put back first.
pub fn remove_stale_tmp(out: &Path) {
    restore_set_aside(out);
    clean(out, false);
    clean(&out.join("cache"), false);
    clean(&out.join("checkpoint"), true);
}

/// Removes the temporaries a killed process left directly in `dir` (`stale_tmp`), after putting
/// back a folder of `dir` set aside by a replacement the kill cut short.
pub fn remove_stale_tmp_in(dir: &Path) {
    restore_set_aside(dir);
    clean(dir, false);
}

fn restore_set_aside(out: &Path) {
    for e in std::fs::read_dir(out).into_iter().flatten().flatten() {
        let n = e.file_name().to_string_lossy().into_owned();
        let Some(name) = n
            .strip_prefix('.')
            .and_then(|r| r.split_once(".old-"))
            .map(|(name, _)| name.to_string())
        else {
            continue;
        };
        if stale_tmp(&n) && !out.join(&name).exists() {
            let _ = std::fs::rename(e.path(), out.join(&name));
        }
    }
}

/// The step folder a folder `stepN.prev` (the old state `save_again` sets aside) belongs to:
/// a name `step_dirs` reads.
fn replaced_step(name: &str) -> Option<&str> {
    let stem = name.strip_suffix(".prev")?;
    stem.strip_prefix("step")?.parse::<usize>().ok()?;
    Some(stem)
}

fn clean(dir: &Path, recurse: bool) {
    for e in std::fs::read_dir(dir).into_iter().flatten().flatten() {
        let p = e.path();
        let is_dir = e.file_type().is_ok_and(|t| t.is_dir());
        let name = e.file_name().to_string_lossy().into_owned();
        if let Some(step) = replaced_step(&name).filter(|_| recurse) {
            // A `save_again` killed before its new folder was in place: the old one returns.
            let fin = dir.join(step);
            if fin.exists() {
                remove_dir_aside(&p);
            } else {
                let _ = std::fs::rename(&p, &fin);
            }
        } else if stale_tmp(&name) {
            if is_dir {
                let _ = std::fs::remove_dir_all(&p);
            } else {
                let _ = std::fs::remove_file(&p);
            }
        } else if is_dir && recurse {
            clean(&p, true);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pipeline::fit::{FitRun, fit_resumable};
    use crate::pipeline::test_data::{toy_fit, toy_store};
    use fipt_core::model::step::SegMode;
    use fipt_core::scene::SceneBox;

    /// A fit stopped after some steps, saved (`Checkpoints::save`), restored and continued
    /// ends bit-identical to the uninterrupted fit: the same table, networks and loss log; a
    /// sampler state of another store is refused with the file named.
    #[test]
    fn interrupted_fit_continues_exactly() {
        interrupted_fit(false);
    }

    /// The same on the device path: pixels in a `DeviceStore`, losses read in blocks (settled
    /// at each epoch's end and before the save), the table and its Adam state on the device.
    #[test]
    fn interrupted_device_grid_fit_continues_exactly() {
        interrupted_fit(true);
    }

    fn interrupted_fit(device_grid: bool) {
        let build = toy_store;
        // The device fit reads its losses every `LOSS_READ_EVERY` steps and at epoch ends: with
        // 32 steps per epoch and 60 steps both kinds of read happen (25, 32, 57, 60).
        let (n, steps) = if device_grid { (2000, 60) } else { (600, 25) };
        let st = build(n);
        let (cfg, mut schedule) = toy_fit();
        schedule.min_steps = steps;
        let cfg = cfg.with_device_grid(device_grid);
        let device = burn::tensor::Device::flex();
        let scene_box = SceneBox { min: 0.0, max: 1.0 };
        let run = FitRun {
            mode: SegMode::Part,
            schedule: &schedule,
            seed: 3,
            show_progress: false,
        };
        let fresh = || Trainer::new(cfg.clone(), scene_box, &device, 3);
        let (whole, pw) = fit_resumable(fresh(), &st, &run, None, &mut |_, _| Ok(())).unwrap();
        assert_eq!(whole.device_resident(), device_grid);
        assert_eq!(pw.log.step_total.len(), steps);
        assert_eq!(pw.log.epochs.len(), steps.div_ceil(n.div_ceil(64)));
        assert!(pw.log.step_total.iter().all(|l| l.is_finite() && *l > 0.0));

        let dir = std::env::temp_dir().join(format!(
            "fipt-fit-resume-{device_grid}-{}",
            std::process::id()
        ));
        let _ = std::fs::remove_dir_all(&dir);
        let ck = Checkpoints {
            dir: dir.clone(),
            every: 0,
        };
        let e = fit_resumable(fresh(), &st, &run, None, &mut |tr, p| {
            if p.step == 11 {
                ck.save(0, tr, p)?;
                anyhow::bail!("stop");
            }
            Ok(())
        });
        assert!(e.is_err());
        let of = |store| FitOf {
            cfg: &cfg,
            device: &device,
            seed: 3,
            store,
            run: &run,
        };
        let c = ck.restore(0, &of(&st)).unwrap().expect("a saved state");
        assert_eq!(c.progress.step, 11);
        let (resumed, pr) =
            fit_resumable(c.trainer, &st, &run, Some(c.progress), &mut |_, _| Ok(())).unwrap();
        assert_eq!(pw.log.step_total, pr.log.step_total);
        let epochs = |p: &FitProgress| {
            p.log
                .epochs
                .iter()
                .map(|e| [e.total, e.color, e.emission, e.diffuse, e.seg])
                .collect::<Vec<_>>()
        };
        assert_eq!(epochs(&pw), epochs(&pr));
        assert_eq!(whole.steps, resumed.steps);
        assert_eq!(whole.model.grid.table, resumed.model.grid.table);
        assert_eq!(whole.model.net_params(), resumed.model.net_params());

        // Another store (one pixel fewer) does not take this sampler state.
        let small = build(n - 1);
        let e = ck
            .restore(0, &of(&small))
            .err()
            .expect("refused")
            .to_string();
        assert!(
            e.contains("sampler.bin") || e.contains("progress.json"),
            "{e}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A finished run is the running program's only where its checkpoint's key names this
    /// executable: another build's key, an unreadable key or none is not (the suite then runs
    /// the scene again rather than reuse its figures).
    #[test]
    fn saved_by_this_program_reads_the_key() {
        let out = std::env::temp_dir().join(format!("fipt-prog-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&out);
        assert!(!saved_by_this_program(&out));
        std::fs::create_dir_all(out.join("checkpoint")).unwrap();
        let cfg = crate::config::Config::default();
        let write = |program: u64| {
            let key = RunKey::new(program, 7, &cfg, false).unwrap();
            let text = serde_json::to_string(&key).unwrap();
            std::fs::write(out.join("checkpoint").join(KEY_FILE), text).unwrap();
        };
        write(program_hash());
        assert!(saved_by_this_program(&out));
        write(program_hash() ^ 1);
        assert!(!saved_by_this_program(&out));
        std::fs::write(out.join("checkpoint").join(KEY_FILE), "{").unwrap();
        assert!(!saved_by_this_program(&out));
        std::fs::remove_dir_all(&out).unwrap();
    }

    /// A `save_again` killed between setting the old folder aside and putting the new one in
    /// place leaves `stepN.prev` alone: the next run puts it back. Killed after, the new folder
    /// stays and the old one goes.
    #[test]
    fn a_killed_save_again_returns_the_old_state() {
        let out = std::env::temp_dir().join(format!("fipt-prev-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&out);
        let rd = out.join("checkpoint").join("round0");
        let put = |name: &str, text: &str| {
            std::fs::create_dir_all(rd.join(name)).unwrap();
            std::fs::write(rd.join(name).join("progress.json"), text).unwrap();
        };
        let read = |name: &str| std::fs::read_to_string(rd.join(name).join("progress.json")).ok();
        // Killed between the two renames: the new state still under its `.tmp` name.
        put("step0000300.prev", "old");
        put("step0000300.tmp", "new, unfinished");
        remove_stale_tmp(&out);
        assert!(!rd.join("step0000300.tmp").exists());
        assert_eq!(read("step0000300").as_deref(), Some("old"));
        assert!(!rd.join("step0000300.prev").exists());
        assert_eq!(step_dirs(&rd).len(), 1);
        // Killed after the second rename: the new state stays.
        put("step0000300.prev", "older");
        remove_stale_tmp(&out);
        assert_eq!(read("step0000300").as_deref(), Some("old"));
        assert!(!rd.join("step0000300.prev").exists());
        // Only checkpoint step folders are restored.
        assert_eq!(replaced_step("step0000300.prev"), Some("step0000300"));
        assert_eq!(replaced_step("step.prev"), None);
        assert_eq!(replaced_step("maps.prev"), None);
        assert_eq!(
            describe(&out.join("checkpoint")).as_deref(),
            Some("round 0 at step 300")
        );
        std::fs::remove_dir_all(&out).unwrap();
    }

    #[test]
    fn key_mismatch_names_what_changed() {
        let cfg = crate::config::Config::default();
        let a = RunKey::new(1, 2, &cfg, false).unwrap();
        assert_eq!(a.mismatch(&a), None);
        let mut c2 = cfg.clone();
        c2.train.lr *= 2.0;
        c2.refine.rounds += 1;
        c2.render.spp += 1;
        let b = RunKey::new(1, 2, &c2, false).unwrap();
        assert_eq!(
            a.mismatch(&b).as_deref(),
            Some("the config changed at train.lr")
        );
        let c = RunKey::new(3, 4, &cfg, true).unwrap();
        let why = a.mismatch(&c).unwrap();
        assert!(
            why.contains("program") && why.contains("scene") && why.contains("oracle"),
            "{why}"
        );
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig {
            cases: 500,
            failure_persistence: None,
            rng_seed: proptest::test_runner::RngSeed::Fixed(0x5eed),
            ..Default::default()
        })]

        /// A key written to `key.json` and read back holds for the config it was made from,
        /// whatever its numbers (f32 keys are widened to f64 in the key): the default config,
        /// `refine.paths.sharp.below` and `train.lr` drawn at random. Without exact float
        /// parsing about one f32 in eleven reads back one ulp off, the default's 0.412 among
        /// them, and the run starts again.
        #[test]
        fn a_saved_key_holds_for_its_config(below in 0.0f32..1.0, lr in 1e-6f64..1.0) {
            let out = std::env::temp_dir().join(format!("fipt-key-{}", std::process::id()));
            let dir = out.join("checkpoint");
            std::fs::create_dir_all(&dir).unwrap();
            let mut cfg = crate::config::Config::default();
            let default_key = RunKey::new(1, 2, &cfg, false).unwrap();
            crate::output::write_json(&dir.join(KEY_FILE), &default_key).unwrap();
            proptest::prop_assert_eq!(saved_key(&dir).unwrap().mismatch(&default_key), None);
            if let Some(s) = cfg.refine.paths.sharp.as_mut() {
                s.below = below;
            }
            cfg.train.lr = lr;
            let key = RunKey::new(1, 2, &cfg, false).unwrap();
            crate::output::write_json(&dir.join(KEY_FILE), &key).unwrap();
            proptest::prop_assert_eq!(saved_key(&dir).unwrap().mismatch(&key), None);
            std::fs::remove_dir_all(&out).unwrap();
        }
    }

    /// One kind of damage to a file: cut at a fraction of its length, flip a byte, or write a
    /// huge little-endian u64 at an offset.
    #[derive(Clone, Debug)]
    enum Damage {
        Truncate(f64),
        Flip(f64, u8),
        Huge(f64),
    }

    fn damage() -> impl proptest::strategy::Strategy<Value = Damage> {
        use proptest::prelude::*;
        prop_oneof![
            (0.0..1.0f64).prop_map(Damage::Truncate),
            (0.0..1.0f64, 1u8..=255).prop_map(|(at, x)| Damage::Flip(at, x)),
            (0.0..1.0f64).prop_map(Damage::Huge),
        ]
    }

    fn apply(b: &mut Vec<u8>, d: &Damage) {
        let at = |f: f64, len: usize| ((f * len as f64) as usize).min(len.saturating_sub(1));
        match *d {
            Damage::Truncate(f) => b.truncate(at(f, b.len())),
            Damage::Flip(f, x) => {
                let i = at(f, b.len());
                b[i] ^= x;
            }
            Damage::Huge(f) => {
                let i = at(f, b.len().saturating_sub(8));
                let n = 8.min(b.len() - i);
                b[i..i + n].copy_from_slice(&(u64::MAX / 3).to_le_bytes()[..n]);
            }
        }
    }

    const STATE_FILES: [&str; 8] = [
        "model.json",
        "fields.bpk",
        "hashgrid.bin",
        "optim.bpk",
        "table_adam.bin",
        "trainer.json",
        "progress.json",
        "sampler.bin",
    ];

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig {
            cases: 240,
            failure_persistence: None,
            rng_seed: proptest::test_runner::RngSeed::Fixed(0x5eed),
            ..Default::default()
        })]

        /// A saved fit state with one file damaged (truncated, a byte flipped, a huge size
        /// written): restoring it never panics nor allocates from a size field; every damaged
        /// file is refused with its name in the message (the manifest's content hashes).
        #[test]
        fn damaged_state_is_refused_by_name(file in 0..STATE_FILES.len(), d in damage()) {
            use crate::pipeline::test_data::{toy_fit, toy_store};
            use crate::pipeline::fit::{FitRun, fit_resumable};
            use fipt_core::model::step::SegMode;
            static SAVED: std::sync::OnceLock<PathBuf> = std::sync::OnceLock::new();
            let st = toy_store(200);
            let (cfg, schedule) = toy_fit();
            let device = burn::tensor::Device::flex();
            let run = FitRun { mode: SegMode::Part, schedule: &schedule, seed: 1, show_progress: false };
            let good = SAVED.get_or_init(|| {
                let dir = std::env::temp_dir().join(format!("fipt-ck-fuzz-{}", std::process::id()));
                let _ = std::fs::remove_dir_all(&dir);
                let ck = Checkpoints { dir: dir.clone(), every: 0 };
                let tr = Trainer::new(cfg.clone(), fipt_core::scene::SceneBox { min: 0.0, max: 1.0 }, &device, 1);
                let _ = fit_resumable(tr, &st, &run, None, &mut |tr, p| {
                    if p.step == 3 {
                        ck.save(0, tr, p)?;
                        anyhow::bail!("stop");
                    }
                    Ok(())
                });
                dir
            });
            let case = good.with_file_name(format!(
                "fipt-ck-fuzz-{}-{file}",
                std::process::id()
            ));
            let _ = std::fs::remove_dir_all(&case);
            let (src, dst) = (good.join("round0/step0000003"), case.join("round0/step0000003"));
            std::fs::create_dir_all(&dst).unwrap();
            let mut changed = false;
            for f in STATE_FILES.iter().chain(&[MANIFEST_FILE]) {
                let mut b = std::fs::read(src.join(f)).unwrap();
                if *f == STATE_FILES[file] {
                    let before = b.clone();
                    apply(&mut b, &d);
                    changed = b != before;
                }
                std::fs::write(dst.join(f), b).unwrap();
            }
            let ck = Checkpoints { dir: case.clone(), every: 0 };
            let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                let fit = FitOf { cfg: &cfg, device: &device, seed: 1, store: &st, run: &run };
                ck.restore(0, &fit).map(|o| o.is_some())
            }));
            std::fs::remove_dir_all(&case).unwrap();
            proptest::prop_assert!(r.is_ok(), "panicked on {} {:?}", STATE_FILES[file], d);
            // Every change is caught by the manifest's content hashes, and the file named.
            if let (true, Ok(res)) = (changed, r) {
                let e = res.err().map(|e| format!("{e:#}"));
                proptest::prop_assert!(
                    e.as_deref().is_some_and(|e| e.contains(STATE_FILES[file]) && e.contains("damaged")),
                    "{} {:?}: {:?}", STATE_FILES[file], d, e
                );
            }
        }
    }
}
