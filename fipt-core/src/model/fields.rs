//! The two neural fields of paper Eq. 14: the material field (hash grid → MLP → a, σ, m) and
//! the emission mask (positional encoding → 6×128 MLP with a skip at layer 3 → α).
//!
//! Owns: the fields' configs, parameters and forward passes, and their copies for the fused
//! host MLPs (`to_host`, `register_host_grads`). Must not touch: losses, data.

use super::hashgrid::{HashGrid, HashGridConfig};
use super::host_mlp::{Dense, HostMlp, MlpGrads};
use super::pe::{pe_dim, positional_encoding};
use crate::rng::Rng;
use burn::config::Config;
use burn::module::{Module, Param};
use burn::nn::Linear;
use burn::optim::GradientsParams;
use burn::tensor::activation::{relu, sigmoid};
use burn::tensor::{Device, Tensor, TensorData};

/// A plain ReLU MLP (no activation after the last layer).
#[derive(Module, Debug)]
pub struct Mlp {
    pub layers: Vec<Linear>,
}

/// A linear layer `input → output` initialised on the host from `rng` with PyTorch's and
/// burn's default, U(−k, k) with k = 1/√input for weights and biases. Host initialisation makes
/// a seed give the same network on every backend.
pub fn linear(input: usize, output: usize, bias: bool, rng: &mut Rng, device: &Device) -> Linear {
    let k = 1.0 / (input as f32).sqrt();
    let mut uniform =
        |n: usize| -> Vec<f32> { (0..n).map(|_| (2.0 * rng.next_f32() - 1.0) * k).collect() };
    let w = uniform(input * output);
    let weight = Param::from_tensor(Tensor::from_data(
        TensorData::new(w, [input, output]),
        device,
    ));
    let bias = bias.then(|| {
        Param::from_tensor(Tensor::from_data(
            TensorData::new(uniform(output), [output]),
            device,
        ))
    });
    Linear { weight, bias }
}

/// A bias-free linear layer initialised as tiny-cuda-nn's FullyFusedMLP does: Xavier uniform,
/// U(−k, k) with k = √(6 / (fan_in + fan_out)), where both widths are padded to a multiple of
/// 16 (tcnn pads the input and output widths of its fused kernels and initialises the padded
/// matrices). For the reference field (64 inputs, 64 wide, 5 → 16 outputs) this gives weights
/// 1.7× (hidden) and 2.2× (output) larger than the PyTorch default, 6.6× more gain from the
/// hash features to the outputs.
pub fn linear_tcnn(input: usize, output: usize, rng: &mut Rng, device: &Device) -> Linear {
    let pad = |n: usize| n.div_ceil(16) * 16;
    let k = (6.0 / (pad(input) + pad(output)) as f32).sqrt();
    let w: Vec<f32> = (0..input * output)
        .map(|_| (2.0 * rng.next_f32() - 1.0) * k)
        .collect();
    Linear {
        weight: Param::from_tensor(Tensor::from_data(
            TensorData::new(w, [input, output]),
            device,
        )),
        bias: None,
    }
}

impl Mlp {
    /// Layers `dims[0] → dims[1] → …`, with biases, initialised from (`seed`, stream 1).
    pub fn new(dims: &[usize], seed: u64, device: &Device) -> Self {
        let mut rng = Rng::new(seed, 0x31f);
        Self {
            layers: dims
                .windows(2)
                .map(|w| linear(w[0], w[1], true, &mut rng, device))
                .collect(),
        }
    }

    /// tiny-cuda-nn's FullyFusedMLP: no biases, Xavier-uniform weights over 16-padded widths
    /// ([`linear_tcnn`]), initialised from (`seed`, stream 1).
    pub fn tcnn(dims: &[usize], seed: u64, device: &Device) -> Self {
        let mut rng = Rng::new(seed, 0x31f);
        Self {
            layers: dims
                .windows(2)
                .map(|w| linear_tcnn(w[0], w[1], &mut rng, device))
                .collect(),
        }
    }

    /// The same network with its parameters copied to the host (`host_mlp`).
    pub fn to_host(&self) -> HostMlp {
        HostMlp {
            layers: self.layers.iter().map(dense).collect(),
            skip: None,
        }
    }

    pub fn forward(&self, mut x: Tensor<2>) -> Tensor<2> {
        let n = self.layers.len();
        for (i, l) in self.layers.iter().enumerate() {
            x = l.forward(x);
            if i + 1 < n {
                x = relu(x);
            }
        }
        x
    }
}

/// A layer's parameters copied to the host (`host_mlp`).
fn dense(l: &Linear) -> Dense {
    let [input, output] = l.weight.val().dims();
    let host = |t: Tensor<1>| t.try_into_vec_as::<f32>().expect("f32 parameter");
    Dense {
        input,
        output,
        weight: host(l.weight.val().reshape([input * output])),
        bias: l.bias.as_ref().map(|b| host(b.val())),
    }
}

/// Registers host gradients `g` of `layers` (in order) in `gp`, as tensors on `device` (the
/// plain device burn's optimiser reads gradients on).
pub fn register_host_grads(
    layers: &[&Linear],
    g: &MlpGrads,
    gp: &mut GradientsParams,
    device: &Device,
) {
    for ((l, w), b) in layers.iter().zip(&g.weight).zip(&g.bias) {
        let [input, output] = l.weight.val().dims();
        let t = Tensor::<2>::from_data(TensorData::new(w.clone(), [input, output]), device);
        gp.register(l.weight.id, t);
        if let (Some(p), Some(b)) = (&l.bias, b) {
            let t = Tensor::<1>::from_data(TensorData::new(b.clone(), [b.len()]), device);
            gp.register(p.id, t);
        }
    }
}

#[derive(Config, Debug)]
pub struct MaterialFieldConfig {
    #[config(default = "HashGridConfig::new()")]
    pub grid: HashGridConfig,
    /// Hidden width of the MLP.
    #[config(default = 64)]
    pub hidden: usize,
    /// Hidden layers of the MLP.
    #[config(default = 2)]
    pub hidden_layers: usize,
}

/// Material parameters per point: base colour a [N,3], roughness σ [N,1], metallic m [N,1].
#[derive(Clone, Debug)]
pub struct Material {
    pub a: Tensor<2>,
    pub sigma: Tensor<2>,
    pub metallic: Tensor<2>,
}

/// The material field: a host hash grid (fused op, `hashgrid`) and a burn MLP.
#[derive(Debug)]
pub struct MaterialField {
    pub grid: HashGrid,
    pub mlp: Mlp,
}

impl MaterialFieldConfig {
    /// Builds the field; the grid and the MLP are initialised on the host from `seed`.
    pub fn init(&self, device: &Device, seed: u64) -> MaterialField {
        let grid = self.grid.init(seed);
        let mut dims = vec![grid.output_dim()];
        dims.extend(std::iter::repeat_n(self.hidden, self.hidden_layers));
        dims.push(5);
        // As tcnn's FullyFusedMLP: no biases (a shared output bias would let the regulariser
        // and the majority of (diffuse) pixels saturate m → 0 and σ → 1 everywhere at once,
        // after which the sigmoid gives rare metal/glossy pixels no gradient) and tcnn's
        // Xavier init, whose larger gain sets how far one Adam step on the table moves a, σ, m.
        MaterialField {
            grid,
            mlp: Mlp::tcnn(&dims, seed, device),
        }
    }
}

/// The material head's output columns: base colour, roughness, metallic.
const A_COLS: std::ops::Range<usize> = 0..3;
pub(crate) const SIGMA_COL: usize = 3;
pub(crate) const METALLIC_COL: usize = 4;

/// Eq. 14 (material head): sigmoid outputs → a = s[0..3], σ = 0.02 + 0.98·s[3], m = s[4].
pub fn decode_material(raw: Tensor<2>) -> Material {
    let [n, _] = raw.dims();
    let s = sigmoid(raw);
    Material {
        a: s.clone().slice([0..n, A_COLS]),
        sigma: s
            .clone()
            .slice([0..n, SIGMA_COL..SIGMA_COL + 1])
            .mul_scalar(0.98)
            .add_scalar(0.02),
        metallic: s.slice([0..n, METALLIC_COL..METALLIC_COL + 1]),
    }
}

/// The σ and m logits of the material head's raw output [N,5] (the columns [`decode_material`]
/// turns into σ and m): [N,2].
pub fn sigma_metallic_logits(raw: Tensor<2>) -> Tensor<2> {
    let [n, _] = raw.dims();
    const _: () = assert!(METALLIC_COL == SIGMA_COL + 1);
    raw.slice([0..n, SIGMA_COL..METALLIC_COL + 1])
}

impl MaterialField {
    /// Material at points in the unit cube (inference: encoding on the host, MLP on `device`).
    pub fn query(&self, x_unit: &[[f32; 3]], device: &Device) -> Material {
        let enc = self.grid.encode(x_unit);
        let t = Tensor::<2>::from_data(
            TensorData::new(enc, [x_unit.len(), self.grid.output_dim()]),
            device,
        );
        decode_material(self.mlp.forward(t))
    }
}

#[derive(Config, Debug)]
pub struct EmissionMaskConfig {
    /// Positional-encoding frequencies L.
    #[config(default = 10)]
    pub freqs: usize,
    /// Hidden layers D.
    #[config(default = 6)]
    pub depth: usize,
    /// Hidden width C.
    #[config(default = 128)]
    pub width: usize,
    /// Layer whose input is concat(PE, h).
    #[config(default = 3)]
    pub skip: usize,
}

/// The emission mask: α = 1 − exp(−ReLU(raw)) from an MLP on the positional encoding.
#[derive(Module, Debug)]
pub struct EmissionMask {
    pub layers: Vec<Linear>,
    pub out: Linear,
    pub freqs: usize,
    pub skip: usize,
}

impl EmissionMaskConfig {
    /// Builds the mask, initialised on the host from `seed`.
    pub fn init(&self, device: &Device, seed: u64) -> EmissionMask {
        let mut rng = Rng::new(seed, 0xe31);
        let pe = pe_dim(self.freqs);
        let layers = (0..self.depth)
            .map(|i| {
                let input = match i {
                    0 => pe,
                    i if i == self.skip => self.width + pe,
                    _ => self.width,
                };
                linear(input, self.width, true, &mut rng, device)
            })
            .collect();
        EmissionMask {
            layers,
            out: linear(self.width, 1, true, &mut rng, device),
            freqs: self.freqs,
            skip: self.skip,
        }
    }
}

impl EmissionMask {
    /// The layers in order, the output layer last.
    pub fn all_layers(&self) -> Vec<&Linear> {
        self.layers.iter().chain([&self.out]).collect()
    }

    /// The same network with its parameters copied to the host (`host_mlp`); it reads the
    /// positional encoding (`host_mlp::positional_encoding_host`), not positions.
    pub fn to_host(&self) -> HostMlp {
        HostMlp {
            layers: self.all_layers().into_iter().map(dense).collect(),
            skip: (self.skip > 0 && self.skip < self.layers.len()).then_some(self.skip),
        }
    }

    /// Raw mask output [N,1] at world positions `x` [N,3].
    pub fn raw(&self, x: Tensor<2>) -> Tensor<2> {
        let pe = positional_encoding(x, self.freqs);
        let mut h = pe.clone();
        for (i, l) in self.layers.iter().enumerate() {
            if i == self.skip && i > 0 {
                h = Tensor::cat(vec![pe.clone(), h], 1);
            }
            h = relu(l.forward(h));
        }
        self.out.forward(h)
    }
}

/// Eq. 14 (emission head): α = 1 − exp(−ReLU(raw)).
pub fn alpha_from_raw(raw: Tensor<2>) -> Tensor<2> {
    relu(raw).neg().exp().neg().add_scalar(1.0)
}
