//! One writer per folder: an advisory lock (`flock`) on `DIR/.fipt.lock`, holding the pid of
//! the process that writes `DIR`. A second writer gets an error naming that pid; the lock of a
//! process that died is released by the kernel with it, so the next writer simply takes it.
//!
//! `run`, `demo`, `bake` and `render` lock their output folder for their whole life; the zoo is
//! locked around each change of an entry (`register`, `import`, `rm`), waiting a short while
//! for another process's change to end.
//!
//! Owns: the lock file and its message. Must not touch: what the locked folder holds.

use anyhow::{Result, bail};
use std::fs::File;
use std::io::{Read, Seek, Write};
use std::os::fd::AsRawFd;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// The lock file's name inside the locked folder.
pub const LOCK_FILE: &str = ".fipt.lock";

/// A held lock; released when dropped (or when the process ends, however it ends).
#[derive(Debug)]
pub struct DirLock {
    file: File,
    path: PathBuf,
}

impl DirLock {
    /// Locks `dir` (created if absent) for writing, or fails at once naming the holder.
    pub fn acquire(dir: &Path) -> Result<Self> {
        Self::acquire_within(dir, Duration::ZERO)
    }

    /// Like `acquire`, but waits up to `wait` for the holder to let go.
    pub fn acquire_within(dir: &Path, wait: Duration) -> Result<Self> {
        std::fs::create_dir_all(dir)
            .map_err(|e| anyhow::anyhow!("{}: cannot create: {e}", dir.display()))?;
        let path = dir.join(LOCK_FILE);
        let mut file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&path)
            .map_err(|e| anyhow::anyhow!("{}: cannot open the lock file: {e}", path.display()))?;
        let start = Instant::now();
        loop {
            // SAFETY: flock on a file descriptor this function owns for the call's duration.
            let rc = unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) };
            if rc == 0 {
                break;
            }
            let err = std::io::Error::last_os_error();
            if err.raw_os_error() != Some(libc::EWOULDBLOCK) {
                bail!("{}: cannot lock: {err}", path.display());
            }
            if start.elapsed() >= wait {
                let mut holder = String::new();
                let _ = file.read_to_string(&mut holder);
                let holder = holder.trim();
                let who = if holder.is_empty() {
                    "another fipt process".to_string()
                } else {
                    format!("fipt process {holder}")
                };
                bail!(
                    "{}: in use by {who} (lock {}); wait for it to end or stop it",
                    dir.display(),
                    path.display()
                );
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        // The holder's pid, for the message of the next writer.
        let pid = std::process::id().to_string();
        let wrote = file
            .set_len(0)
            .and_then(|_| file.rewind())
            .and_then(|_| file.write_all(pid.as_bytes()));
        if let Err(e) = wrote {
            bail!("{}: cannot write: {e}", path.display());
        }
        Ok(Self { file, path })
    }

    /// The lock file.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

impl Drop for DirLock {
    fn drop(&mut self) {
        // Leave the file (removing it would race with a writer that just opened it); empty it
        // so a stale pid is never named, then let go.
        let _ = self.file.set_len(0);
        // SAFETY: unlocking this struct's own descriptor.
        unsafe {
            libc::flock(self.file.as_raw_fd(), libc::LOCK_UN);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn second_writer_is_refused_naming_the_holder_then_takes_over() {
        let dir = std::env::temp_dir().join(format!("fipt-lock-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let held = DirLock::acquire(&dir).unwrap();
        // flock locks belong to the open file: a second open, even in this process, conflicts.
        let e = DirLock::acquire(&dir).unwrap_err().to_string();
        assert!(
            e.contains(&std::process::id().to_string()) && e.contains(LOCK_FILE),
            "{e}"
        );
        let t = Instant::now();
        let e = DirLock::acquire_within(&dir, Duration::from_millis(200)).unwrap_err();
        assert!(t.elapsed() >= Duration::from_millis(200), "{e}");
        drop(held);
        let again = DirLock::acquire(&dir).unwrap();
        assert!(again.path().is_file());
        drop(again);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
