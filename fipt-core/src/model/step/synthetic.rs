//! Made-up training pixels for tests and benchmarks (`Batch::synthetic`); public because the
//! integration tests of fipt-core use them.
//!
//! Owns: the synthetic batch. Must not touch: anything a real fit reads.

use super::batch::Batch;
use crate::rng::Rng;
use crate::shading::ShadingLayout;

impl Batch {
    /// `n` random training pixels in a 4 × 2.7 × 3 m room, for tests and benchmarks: unit-cube
    /// and world positions, positive shadings, photo values (an emitter in one corner, 20×
    /// brighter) and three segments (0 and 2 by depth, 7 on the emitter).
    pub fn synthetic(n: usize, seed: u64) -> Batch {
        let mut r = Rng::new(seed, 1);
        let mut b = Batch::default();
        for _ in 0..n {
            let x = [r.next_f32(), r.next_f32(), r.next_f32()];
            b.x_unit.push(x);
            b.x_world
                .push([4.0 * x[0] - 2.0, 2.7 * x[1], 3.0 * x[2] - 1.5]);
            b.shadings.extend(
                (0..ShadingLayout::DIM).map(|k| 0.05 + r.next_f32() / (1.0 + k as f32 * 0.1)),
            );
            let emitter = x[0] > 0.8 && x[1] > 0.8;
            let scale = if emitter { 20.0 } else { 1.0 };
            b.gt.extend((0..3).map(|_| scale * (0.05 + r.next_f32())));
            b.seg
                .push(if emitter { 7 } else { 2 * (x[2] > 0.5) as i32 });
        }
        b
    }
}
