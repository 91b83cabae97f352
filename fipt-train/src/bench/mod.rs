//! `fipt-train bench ...`: speed benchmarks with JSON output (medians over repetitions), one
//! file each; `workloads` builds the scenes, rays and pixel stores they time.
//!
//! Owns: benchmark workloads and timing. Must not touch: correctness checks (those are tests;
//! `bench refine` reports the voxel cache's error beside its speed because the two trade off).

pub mod bake;
pub mod query;
pub mod refine;
pub mod render;
pub mod step;
pub mod trace;
pub mod workloads;

use anyhow::Result;
use std::time::Instant;

pub use workloads::{incoherent_rays, pixel_store, surface_sample};

/// Median of a set of durations in seconds.
pub fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n == 0 {
        return f64::NAN;
    }
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// Runs `f` once to warm up, then `reps` times on a pool of `threads`; returns seconds each.
pub fn time_on_pool(threads: usize, reps: usize, f: &(dyn Fn() + Sync)) -> Result<Vec<f64>> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()?;
    Ok(pool.install(|| {
        f();
        (0..reps)
            .map(|_| {
                let t = Instant::now();
                f();
                t.elapsed().as_secs_f64()
            })
            .collect()
    }))
}

/// Median time and throughput of one thread count.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Throughput {
    pub median_s: f64,
    pub rays_per_s: f64,
    pub times_s: Vec<f64>,
}

impl Throughput {
    pub fn of(rays: u64, times: Vec<f64>) -> Self {
        let median_s = median(times.clone());
        Self {
            median_s,
            rays_per_s: rays as f64 / median_s,
            times_s: times,
        }
    }
}
