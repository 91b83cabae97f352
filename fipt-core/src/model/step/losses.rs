//! What a step reports: its loss parts (`LossParts`), read at once or left on the device until
//! the caller reads them (`StepLoss`).
//!
//! Owns: the loss values and their read-back. Must not touch: how the losses are computed.

use crate::model::transfer;
use burn::tensor::Tensor;

/// Loss values of one step.
#[derive(Clone, Copy, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct LossParts {
    pub total: f32,
    pub color: f32,
    pub emission: f32,
    pub diffuse: f32,
    pub seg: f32,
}

impl LossParts {
    pub(super) fn from_slice(v: &[f32]) -> Self {
        Self {
            total: v[0],
            color: v[1],
            emission: v[2],
            diffuse: v[3],
            seg: v[4],
        }
    }
}

/// A step's loss parts: read already, or still on the device (`[total, color, emission,
/// diffuse, seg]`) until `read` or `read_all` fetches them.
#[derive(Clone, Debug)]
pub enum StepLoss {
    Ready(LossParts),
    Pending(Box<Tensor<1>>),
}

impl StepLoss {
    /// The values (one device read if pending).
    pub fn read(self) -> LossParts {
        Self::read_all(vec![self])[0]
    }

    /// The values of several steps, with one device read for all the pending ones.
    pub fn read_all(losses: Vec<StepLoss>) -> Vec<LossParts> {
        let pending: Vec<Tensor<1>> = losses
            .iter()
            .filter_map(|l| match l {
                StepLoss::Pending(t) => Some((**t).clone()),
                StepLoss::Ready(_) => None,
            })
            .collect();
        let values = if pending.is_empty() {
            Vec::new()
        } else {
            transfer::download(pending.len() * 5 * 4);
            Tensor::cat(pending, 0)
                .try_into_vec_as::<f32>()
                .expect("f32 losses")
        };
        let mut k = 0;
        losses
            .into_iter()
            .map(|l| match l {
                StepLoss::Ready(p) => p,
                StepLoss::Pending(_) => {
                    k += 1;
                    LossParts::from_slice(&values[5 * (k - 1)..5 * k])
                }
            })
            .collect()
    }
}
