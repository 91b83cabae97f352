//! Small file helpers shared by every crate: atomic writes (temporary file, then rename) so a
//! failed run never leaves a half-written output, and error values that name the file.
//!
//! Owns: `FileError`, `write_atomic`. Must not touch: any format knowledge.

use std::fmt;
use std::io::Write;
use std::path::{Path, PathBuf};

/// An error tied to one file: says which file and what is wrong with it.
#[derive(Debug, Clone)]
pub struct FileError {
    pub path: PathBuf,
    pub msg: String,
}

impl FileError {
    pub fn new(path: impl AsRef<Path>, msg: impl Into<String>) -> Self {
        Self {
            path: path.as_ref().to_path_buf(),
            msg: msg.into(),
        }
    }
}

impl fmt::Display for FileError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: {}", self.path.display(), self.msg)
    }
}

impl std::error::Error for FileError {}

pub type Result<T> = std::result::Result<T, FileError>;

/// Reads a whole file, naming it in the error.
pub fn read_bytes(path: &Path) -> Result<Vec<u8>> {
    std::fs::read(path).map_err(|e| FileError::new(path, io_msg(&e)))
}

/// Reads a whole UTF-8 text file, naming it in the error.
pub fn read_text(path: &Path) -> Result<String> {
    let bytes = read_bytes(path)?;
    String::from_utf8(bytes).map_err(|_| FileError::new(path, "not valid UTF-8 text"))
}

fn io_msg(e: &std::io::Error) -> String {
    match e.kind() {
        std::io::ErrorKind::NotFound => "file not found".to_string(),
        _ => e.to_string(),
    }
}

/// Writes `path` atomically: `write` fills a temporary file beside it, which is renamed over
/// `path` only when everything succeeded. Parent folders are created.
pub fn write_atomic(
    path: &Path,
    write: impl FnOnce(&Path) -> std::result::Result<(), String>,
) -> Result<()> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| FileError::new(dir, e.to_string()))?;
    }
    let tmp = tmp_path(path);
    let res = write(&tmp);
    if let Err(msg) = res {
        let _ = std::fs::remove_file(&tmp);
        return Err(FileError::new(path, msg));
    }
    std::fs::rename(&tmp, path).map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        FileError::new(path, e.to_string())
    })
}

/// Writes bytes atomically.
pub fn write_bytes_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    write_parts_atomic(path, &[Part::Bytes(bytes)])
}

/// Writes `v` as little-endian f32 values (one write, no copy, on a little-endian machine).
pub fn write_f32s(w: &mut impl Write, v: &[f32]) -> std::io::Result<()> {
    #[cfg(target_endian = "little")]
    {
        w.write_all(bytemuck::cast_slice(v))
    }
    #[cfg(not(target_endian = "little"))]
    {
        for x in v {
            w.write_all(&x.to_le_bytes())?;
        }
        Ok(())
    }
}

/// Writes `path` atomically from `parts` (byte strings and f32 slices, in order), synced to
/// disk before the rename: large tables go out without an intermediate byte copy.
pub fn write_parts_atomic(path: &Path, parts: &[Part]) -> Result<()> {
    write_atomic(path, |tmp| {
        let f = std::fs::File::create(tmp).map_err(|e| e.to_string())?;
        let mut w = std::io::BufWriter::with_capacity(1 << 20, f);
        for p in parts {
            match p {
                Part::Bytes(b) => w.write_all(b),
                Part::F32s(v) => write_f32s(&mut w, v),
            }
            .map_err(|e| e.to_string())?;
        }
        let f = w.into_inner().map_err(|e| e.to_string())?;
        f.sync_all().map_err(|e| e.to_string())
    })
}

/// A piece of a file written by `write_parts_atomic`.
pub enum Part<'a> {
    Bytes(&'a [u8]),
    F32s(&'a [f32]),
}

fn tmp_path(path: &Path) -> PathBuf {
    let mut name = path
        .file_name()
        .map(|n| n.to_os_string())
        .unwrap_or_default();
    name.push(format!(".{}.tmp", std::process::id()));
    path.with_file_name(name)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn failed_write_leaves_nothing() {
        let dir = std::env::temp_dir().join(format!("fipt-io-{}", std::process::id()));
        let p = dir.join("x.bin");
        let e = write_atomic(&p, |tmp| {
            std::fs::write(tmp, b"half").unwrap();
            Err("boom".into())
        })
        .unwrap_err();
        assert!(e.to_string().contains("x.bin") && e.to_string().contains("boom"));
        assert!(!p.exists());
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 0);
        write_bytes_atomic(&p, b"whole").unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"whole");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}

/// FNV-1a 64-bit hash, for cache keys (stable across runs and platforms).
#[derive(Clone, Copy, Debug)]
pub struct Fnv64(pub u64);

impl Default for Fnv64 {
    fn default() -> Self {
        Self(0xcbf2_9ce4_8422_2325)
    }
}

impl Fnv64 {
    pub fn bytes(&mut self, b: &[u8]) -> &mut Self {
        for &x in b {
            self.0 ^= x as u64;
            self.0 = self.0.wrapping_mul(0x0000_0100_0000_01b3);
        }
        self
    }

    pub fn f32s(&mut self, v: &[f32]) -> &mut Self {
        for x in v {
            self.bytes(&x.to_le_bytes());
        }
        self
    }

    pub fn finish(&self) -> u64 {
        self.0
    }
}

/// Peak resident memory of this process in MiB (Linux `VmHWM`), if known.
pub fn peak_rss_mb() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}
