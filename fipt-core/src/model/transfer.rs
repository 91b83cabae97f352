//! Counters of the bytes the model code moves between host and device (uploads of batches,
//! indices and weights; reads of losses, gradients and outputs), so that `bench step` can report
//! what a step transfers on each path. burn has no transfer counter of its own; every transfer
//! of the training step goes through a call site that counts here.
//!
//! Owns: the counters. Must not touch: tensors.

use std::sync::atomic::{AtomicU64, Ordering};

static UP: AtomicU64 = AtomicU64::new(0);
static DOWN: AtomicU64 = AtomicU64::new(0);

/// Counts `bytes` sent from the host to the device.
pub fn upload(bytes: usize) {
    UP.fetch_add(bytes as u64, Ordering::Relaxed);
}

/// Counts `bytes` read from the device back to the host.
pub fn download(bytes: usize) {
    DOWN.fetch_add(bytes as u64, Ordering::Relaxed);
}

/// (uploaded, downloaded) bytes since the last call; resets both.
pub fn take() -> (u64, u64) {
    (
        UP.swap(0, Ordering::Relaxed),
        DOWN.swap(0, Ordering::Relaxed),
    )
}
