//! Small pixel stores and fits the pipeline's unit tests share.
//!
//! Owns: test data only (compiled for tests). Must not touch: anything the pipeline runs.

use super::pixels::PixelStore;
use crate::config::TrainSection;
use fipt_core::model::Batch;
use fipt_core::shading::ShadingLayout;

pub(crate) fn store(seg: &[i32]) -> PixelStore {
    let n = seg.len();
    PixelStore {
        pixels: Batch {
            x_unit: vec![[0.5; 3]; n],
            x_world: vec![[0.0; 3]; n],
            shadings: vec![0.0; n * ShadingLayout::DIM],
            gt: vec![0.0; 3 * n],
            seg: seg.to_vec(),
            cap: Vec::new(),
            part: Vec::new(),
        },
        origin: (0..n as u32).map(|i| (0, i)).collect(),
        tri: vec![0; n],
    }
}

/// `n` pixels of five segments with varied positions, shadings and colours.
pub(crate) fn toy_store(n: usize) -> PixelStore {
    let seg: Vec<i32> = (0..n).map(|i| (i % 5) as i32).collect();
    let mut st = store(&seg);
    for i in 0..n {
        let t = i as f32 / n as f32;
        st.pixels.x_unit[i] = [t, (3.0 * t).fract(), (7.0 * t).fract()];
        for c in 0..ShadingLayout::DIM {
            st.pixels.shadings[i * ShadingLayout::DIM + c] = 0.2 + 0.5 * ((i + c) % 7) as f32 / 7.0;
        }
        st.pixels.gt[3 * i..3 * i + 3].copy_from_slice(&[0.3 + 0.4 * t, 0.5, 0.2]);
    }
    st
}

/// A small model and a 25-step schedule.
pub(crate) fn toy_fit() -> (fipt_core::model::TrainConfig, TrainSection) {
    let mut train = crate::config::Config::default().train;
    train.grid.log2_table = 8;
    train.mlp_hidden = 16;
    train.emission_width = 16;
    train.emission_depth = 2;
    let schedule = TrainSection {
        min_steps: 25,
        balance: 0.25,
        lr_end: 0.1,
        lambda_d_end: 0.5,
        ..TrainSection::reference(1, 64, 1e-2)
    };
    (
        train.model_config(3, fipt_core::model::BackendKind::Flex),
        schedule,
    )
}
