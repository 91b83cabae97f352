//! Forward and backward without an update (`Trainer::gradients`): the gradients of the loss
//! with respect to the encoding, the table and every network parameter, for parity tests across
//! backends and paths and for diagnostics.
//!
//! Owns: `StepGradients` and their collection. Must not touch: the model's parameters, the
//! optimisers.

use super::batch::{Batch, StepInput};
use super::config::SegMode;
use super::losses::LossParts;
use super::trainer::Trainer;
use crate::model::hashgrid::TableGrad;
use burn::module::{Module, ModuleVisitor, Param};
use burn::optim::GradientsParams;
use burn::tensor::Tensor;

impl Trainer {
    /// Forward and backward without an update: the loss parts, the gradient of the loss w.r.t.
    /// the hash-grid encoding (N × `output_dim`, host path only; empty on the device path),
    /// w.r.t. the table (host layout, both paths) and w.r.t. every network parameter in module
    /// order (host). For parity tests across backends and paths, and for diagnostics.
    pub fn gradients(&mut self, batch: &Batch, mode: SegMode) -> StepGradients {
        let f = self.forward(StepInput::Host(batch), mode);
        let parts = LossParts::from_slice(&f.parts.clone().try_into_vec_as::<f32>().expect("f32"));
        let b = self.backward(f);
        let grads = b.grads;
        let (encoding, table) = match (b.enc, &self.model.device_grid) {
            (Some((g, xs)), _) => {
                let mut tg = TableGrad::new(&self.model.grid);
                self.model.grid.backward_table(&xs, &g, &mut tg);
                (g, tg.values)
            }
            (None, Some(tables)) => {
                let mut t = Vec::with_capacity(tables.len());
                for p in &tables.levels {
                    t.extend(match p.val().grad(&grads) {
                        Some(g) => g.try_into_vec_as::<f32>().expect("f32"),
                        None => vec![0.0; p.val().shape().num_elements()],
                    });
                }
                (Vec::new(), t)
            }
            (None, None) => unreachable!("a grid on the host has an encoding leaf"),
        };
        let mut visitor = ParamGrads {
            grads: &grads,
            host: b.host_nets.as_ref(),
            out: Vec::new(),
        };
        self.model.nets.visit(&mut visitor);
        StepGradients {
            parts,
            encoding,
            table,
            params: visitor.out,
        }
    }
}

/// What `Trainer::gradients` returns.
#[derive(Clone, Debug)]
pub struct StepGradients {
    pub parts: LossParts,
    /// d loss / d encoding, N × `output_dim` (host grid only; empty on the device path).
    pub encoding: Vec<f32>,
    /// d loss / d table, in the host table's layout.
    pub table: Vec<f32>,
    /// d loss / d parameter, one vector per parameter in module order (zeros where unused).
    pub params: Vec<Vec<f32>>,
}

/// Each parameter's gradient, from the fused host networks' (`host`) or from burn's graph.
struct ParamGrads<'a> {
    grads: &'a burn::tensor::Gradients,
    host: Option<&'a GradientsParams>,
    out: Vec<Vec<f32>>,
}

impl ModuleVisitor for ParamGrads<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        let v = param.val();
        let n = v.shape().num_elements();
        let host = self.host.and_then(|h| h.get::<D>(param.id));
        self.out.push(match host.or_else(|| v.grad(self.grads)) {
            Some(g) => g.try_into_vec_as::<f32>().expect("f32 gradient"),
            None => vec![0.0; n],
        });
    }
}
