//! The process's memory allocator settings.
//!
//! A training step allocates and frees a few hundred tensors of 0.1–30 MB. glibc's malloc
//! serves blocks above its mmap threshold (128 KiB, raised dynamically) with fresh `mmap`s
//! and gives them back on free, so every step would fault its tensors' pages in again. Keeping
//! blocks up to 32 MiB (glibc's ceiling for the threshold) in the heap, and not trimming the
//! heap below 1 GiB of free memory, makes the step reuse warm pages (the same blocks, so peak
//! memory is unchanged). `docs/performance.md` gives the step times.
//!
//! Owns: `mallopt` at start-up. Must not touch: anything else of the process.

/// Sets glibc's mmap and trim thresholds (no-op on other C libraries).
pub fn tune() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only changes allocator parameters; it is called before other threads
    // allocate.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 32 << 20);
        libc::mallopt(libc::M_TRIM_THRESHOLD, 1 << 30);
    }
}
