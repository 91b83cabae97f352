//! The forward and backward of a step on its three execution paths: the table resident on the
//! device (`hashgrid_device`, burn's MLPs), the fused host table with burn's MLPs (the
//! encoding is a leaf of the graph), and the fused host table with the fused host MLPs
//! (`host_mlp`, their outputs are the graph's leaves and their backward runs on the host).
//!
//! Owns: `Trainer::forward` and `Trainer::backward`, and what passes between them. Must not
//! touch: the losses (`objective`), the optimisers, files.

use super::batch::{Pixels, StepInput, host_points, host_positions};
use super::config::SegMode;
use super::copies::{download, upload2};
use super::trainer::{GridOpt, Trainer};
use crate::model::fields::register_host_grads;
use crate::model::hashgrid_device;
use crate::model::host_mlp::{HostMlp, Tape, positional_encoding_host};
use burn::optim::GradientsParams;
use burn::tensor::Tensor;
use std::borrow::Cow;
use std::time::Instant;

/// What the forward pass leaves for the backward: on the host grid's path, the batch's positions
/// the table's backward scatters at and where the encoding's gradient comes from; the total
/// loss and the loss parts (detached, on the device).
pub(super) struct Forward<'a> {
    grid: Option<(HostGridLeaf, Cow<'a, [[f32; 3]]>)>,
    pub(super) total: Tensor<1>,
    pub(super) parts: Tensor<1>,
}

/// Where the host grid's encoding gradient is read.
pub(super) enum HostGridLeaf {
    /// The encoding is a leaf of the graph (burn's MLPs).
    Encoding(Box<Tensor<2>>),
    /// The fused host MLPs: their outputs are the graph's leaves.
    Nets(Box<HostNets>),
}

/// The fused host networks between forward and backward: each one's input, the network, its
/// tape and its output as a leaf of the graph.
pub(super) struct HostNets {
    enc: Vec<f32>,
    material: HostMlp,
    material_tape: Tape,
    raw_material: Tensor<2>,
    pe: Vec<f32>,
    emission: HostMlp,
    emission_tape: Tape,
    raw_emission: Tensor<2>,
}

/// The encoding's gradient (N × `output_dim`) with the batch's unit-cube positions.
pub(super) type EncodingGrad<'a> = (Vec<f32>, Cow<'a, [[f32; 3]]>);

/// What the backward gives: burn's gradients, the encoding's gradient with the batch's positions
/// (host grid) and, from the fused host networks, their parameter gradients.
pub(super) struct Backward<'a> {
    pub(super) grads: burn::tensor::Gradients,
    pub(super) enc: Option<EncodingGrad<'a>>,
    pub(super) host_nets: Option<GradientsParams>,
}

/// The networks' raw outputs on a step's pixels, with what the backward needs from the path
/// that made them.
struct NetOutputs<'a> {
    /// The material MLP's output.
    raw_material: Tensor<2>,
    /// The emission mask's raw output (`fields::alpha_from_raw` makes α of it).
    raw_emission: Tensor<2>,
    /// On the host grid's path: where the encoding gradient is read, and the positions.
    grid: Option<(HostGridLeaf, Cow<'a, [[f32; 3]]>)>,
    /// When the encoding ended (the networks count as forward on every path).
    encoded: Instant,
}

impl Trainer {
    /// The forward pass on `input`: what the backward needs on the host grid's path (its
    /// positions, and the encoding or the fused networks' outputs as leaves), the total loss and
    /// the loss parts.
    pub(super) fn forward<'a>(&mut self, input: StepInput<'a>, mode: SegMode) -> Forward<'a> {
        let dev = self.device.clone();
        let t0 = Instant::now();
        let px = Pixels::of(input, &dev);
        let out = self.network_outputs(&px);
        let t1 = out.encoded;
        let (total, parts) = self.objective(&px, mode, out.raw_material, out.raw_emission);
        let p = &mut self.profile;
        p.encode += (t1 - t0).as_secs_f64();
        p.forward += t1.elapsed().as_secs_f64();
        Forward {
            grid: out.grid,
            total,
            parts,
        }
    }

    /// The encoding and both networks on the step's pixels, on the path the trainer takes.
    fn network_outputs<'a>(&self, px: &Pixels<'a>) -> NetOutputs<'a> {
        let dev = self.device.clone();
        let n = px.t.len();
        let device_tables = match self.grid_opt {
            GridOpt::Device { .. } => self.model.device_grid.as_ref(),
            GridOpt::Host { .. } => None,
        };
        let fused = self.fused_nets();
        // The end of the encoding (the networks count as forward on every path).
        let t1;
        let (raw_mat, raw, grid) = match device_tables {
            Some(tables) => {
                let enc =
                    hashgrid_device::encode(&self.model.grid.levels, tables, px.t.x_unit.clone());
                t1 = Instant::now();
                let raw_mat = self.model.nets.material.forward(enc);
                let raw = self.model.nets.emission.raw(px.t.x_world.clone());
                (raw_mat, raw, None)
            }
            None if fused => {
                let xs = host_positions(px);
                let enc = self.model.grid.encode(&xs);
                t1 = Instant::now();
                let nets = self.host_nets_forward(enc, px);
                let (raw_mat, raw) = (nets.raw_material.clone(), nets.raw_emission.clone());
                (raw_mat, raw, Some((HostGridLeaf::Nets(Box::new(nets)), xs)))
            }
            None => {
                let xs = host_positions(px);
                let d = self.model.grid.output_dim();
                let enc = upload2(self.model.grid.encode(&xs), [n, d], &dev).require_grad();
                t1 = Instant::now();
                let raw_mat = self.model.nets.material.forward(enc.clone());
                let raw = self.model.nets.emission.raw(px.t.x_world.clone());
                (
                    raw_mat,
                    raw,
                    Some((HostGridLeaf::Encoding(Box::new(enc)), xs)),
                )
            }
        };
        NetOutputs {
            raw_material: raw_mat,
            raw_emission: raw,
            grid,
            encoded: t1,
        }
    }

    /// The fused host networks' forward on the batch: the material MLP on the encoding `enc`,
    /// the emission mask on the positional encoding of the batch's world positions, each
    /// output uploaded as a leaf of the graph.
    fn host_nets_forward(&self, enc: Vec<f32>, px: &Pixels) -> HostNets {
        let dev = &self.device;
        let nets = &self.model.nets;
        let xw = host_points(px.host.map(|b| &b.x_world[..]), &px.t.x_world);
        let n = xw.len();
        let material = nets.material.to_host();
        let (out, material_tape) = material.forward(&enc);
        let raw_material = upload2(out, [n, material.output()], dev).require_grad();
        let pe = positional_encoding_host(&xw, nets.emission.freqs);
        let emission = nets.emission.to_host();
        let (out, emission_tape) = emission.forward(&pe);
        let raw_emission = upload2(out, [n, emission.output()], dev).require_grad();
        HostNets {
            enc,
            material,
            material_tape,
            raw_material,
            pe,
            emission,
            emission_tape,
            raw_emission,
        }
    }

    /// The backward from `f.total`; with the fused host networks, through them on the host.
    pub(super) fn backward<'a>(&self, f: Forward<'a>) -> Backward<'a> {
        let grads = f.total.backward();
        let Some((leaf, xs)) = f.grid else {
            return Backward {
                grads,
                enc: None,
                host_nets: None,
            };
        };
        match leaf {
            HostGridLeaf::Encoding(enc) => {
                let g = download(enc.grad(&grads).expect("encoding is a leaf of the graph"));
                Backward {
                    grads,
                    enc: Some((g, xs)),
                    host_nets: None,
                }
            }
            HostGridLeaf::Nets(h) => {
                // A network whose output got no gradient gets none either (Adam skips its
                // parameters, as it does on burn's graph), and passes none to the encoding.
                let plain = self.device.clone().inner();
                let nets = &self.model.nets;
                let mut gp = GradientsParams::new();
                let mut d_enc = vec![0.0; h.enc.len()];
                if let Some(g) = h.raw_material.grad(&grads) {
                    let (gm, dx) =
                        h.material
                            .backward(&h.enc, &h.material_tape, &download(g), true);
                    let material: Vec<&burn::nn::Linear> = nets.material.layers.iter().collect();
                    register_host_grads(&material, &gm, &mut gp, &plain);
                    d_enc = dx.expect("asked for");
                }
                if let Some(g) = h.raw_emission.grad(&grads) {
                    let (ge, _) = h
                        .emission
                        .backward(&h.pe, &h.emission_tape, &download(g), false);
                    register_host_grads(&nets.emission.all_layers(), &ge, &mut gp, &plain);
                }
                // The part offsets are burn parameters on every path.
                if let Some(po) = &nets.part_offsets
                    && let Some(g) = po.table.val().grad(&grads)
                {
                    gp.register(po.table.id, g);
                }
                Backward {
                    grads,
                    enc: Some((d_enc, xs)),
                    host_nets: Some(gp),
                }
            }
        }
    }
}
