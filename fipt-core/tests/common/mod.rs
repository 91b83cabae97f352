//! Helpers shared by fipt-core's integration tests.

use fipt_core::model::Batch;

/// `n` random training pixels (`Batch::synthetic`).
pub fn batch(n: usize, seed: u64) -> Batch {
    Batch::synthetic(n, seed)
}
