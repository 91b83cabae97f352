//! The stage-2 losses (paper Eq. 15–20, reference §2.3) as tensor ops.
//!
//! Owns: tone mapping and every loss term. Must not touch: which pixels are in a batch.

use super::gather::{scatter_add, scatter_add_dev, select_1d_dev, select_rows};
use burn::tensor::{Device, Int, Tensor, TensorData};
use rayon::prelude::*;

/// The sRGB OETF Γ, no clamp: 12.92x for x ≤ 0.0031308, else 1.055·x^(1/2.4) − 0.055.
pub fn tonemap(x: Tensor<2>) -> Tensor<2> {
    const T: f32 = 0.003_130_8;
    let low = x.clone().lower_equal_elem(T);
    let lin = x.clone().mul_scalar(12.92);
    // The power branch sees x ≥ T only, so neither it nor its gradient is ever NaN.
    let pw = x
        .clamp_min(T)
        .powf_scalar(1.0 / 2.4)
        .mul_scalar(1.055)
        .sub_scalar(0.055);
    pw.mask_where(low, lin)
}

/// `tonemap` of one value on the host, in f64 (for host evaluations of Eq. 15).
pub fn tonemap_host(x: f32) -> f64 {
    let x = x as f64;
    if x <= 0.003_130_8 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    }
}

/// Eq. 15: L_c = mean (Γ(C) − Γ(I))².
pub fn color_loss(c: Tensor<2>, gt: Tensor<2>) -> Tensor<1> {
    (tonemap(c) - tonemap(gt)).powi_scalar(2).mean()
}

/// The render as an LDR photo records it (IRIS's clamp, `iris-reference.md` §1): min(C, cap)
/// per channel, where `cap` is the clip level of a clipped channel and `CAP_NONE` elsewhere.
/// A clipped channel of the photo (`gt` = cap) then costs nothing once C reaches it and pulls C
/// up below it, without pulling it towards the clip level from above.
pub fn clip_to(c: Tensor<2>, cap: Tensor<2>) -> Tensor<2> {
    c.min_pair(cap)
}

/// Eq. 16: L_e = λ_e · mean |raw| (on the raw mask output, reference §5.5).
pub fn emission_loss(raw: Tensor<2>, weight: f32) -> Tensor<1> {
    raw.abs().mean().mul_scalar(weight)
}

/// Eq. 17: L_d = λ_d · (mean |σ − σ₀| + s·mean m), a pull towards rough dielectrics; σ₀ = 1
/// and s = 1 are the paper's (σ₀: `TrainConfig::prior_sigma`, s: `TrainConfig::metallic_scale`).
/// The host form of one pixel's summand is [`DiffusePrior::at`].
pub fn diffuse_loss(
    sigma: Tensor<2>,
    metallic: Tensor<2>,
    weight: f32,
    metallic_scale: f32,
    prior_sigma: f32,
) -> Tensor<1> {
    (sigma.sub_scalar(prior_sigma).abs().mean() + metallic.mean().mul_scalar(metallic_scale))
        .mul_scalar(weight)
}

/// Eq. 17 on the host, as the hop and the landscape add it to the data term: its weight λ_d
/// and the roughness σ₀ it pulls towards.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DiffusePrior {
    pub lambda_d: f32,
    pub sigma: f32,
}

impl DiffusePrior {
    /// No prior: the data term alone.
    pub const NONE: DiffusePrior = DiffusePrior {
        lambda_d: 0.0,
        sigma: 1.0,
    };

    /// One pixel's summand, λ_d · (|σ − σ₀| + m).
    pub fn at(self, sigma: f32, metallic: f32) -> f32 {
        self.lambda_d * ((sigma - self.sigma).abs() + metallic)
    }
}

/// A soft bound on the material head's σ and m logits z (a departure from the reference):
/// λ_z · mean_pixels Σ_columns max(|z| − z_max, 0)². Without it, the L1 prior of Eq. 17 keeps
/// pushing the logits of every pixel without highlights towards σ = 1, m = 0 and the sigmoid
/// saturates (σ = 0.9999 is a logit of 9.4, where the sigmoid passes 1e-4 of the gradient), so
/// a glossy or metal part whose highlights only show once its base colour is right can no
/// longer leave the diffuse basin. At z_max = 5 the sigmoid passes 0.0066 and σ and m still reach
/// [0.027, 0.993] and [0.0067, 0.9933].
pub fn logit_bound_loss(z: Tensor<2>, z_max: f32, weight: f32) -> Tensor<1> {
    let [n, _] = z.dims();
    let over = z.abs().sub_scalar(z_max).clamp_min(0.0);
    over.powi_scalar(2)
        .sum()
        .div_scalar(n as f32)
        .mul_scalar(weight)
}

/// The pull of a basin hop on σ or m (a departure from the reference, `train.hop`):
/// λ · mean_pixels w·(σ − t)², with a target t and a weight w ∈ {0, 1} per pixel [N,1].
pub fn sigma_pull_loss(
    sigma: Tensor<2>,
    target: Tensor<2>,
    w: Tensor<2>,
    weight: f32,
) -> Tensor<1> {
    ((sigma - target).powi_scalar(2) * w)
        .mean()
        .mul_scalar(weight)
}

/// Mean of `v` per label (`labels` in 0..n_labels, on the device), weighted by `w` (> 0),
/// gathered back to every pixel. A label no pixel carries has weight sum 0: the clamp keeps its
/// (never gathered) mean and its gradient finite.
fn weighted_label_mean(
    v: Tensor<1>,
    w: Tensor<1>,
    labels: Tensor<1, Int>,
    n_labels: usize,
) -> Tensor<1> {
    let sw = scatter_add_dev(n_labels, labels.clone(), w.clone()).clamp_min(1e-12);
    let swv = scatter_add_dev(n_labels, labels.clone(), w * v);
    select_1d_dev(swv / sw, labels)
}

/// Eq. 18–19 (part variant): per segment, weighted means of σ and m with weights
/// w = mean_rgb(specular shading).detach() + 1e-4; L = λ·(mean|m − m̄_s| + mean|σ − σ̄_s|).
/// `seg` holds segment ids in 0..n_seg (on the device; ids no pixel of the batch carries are
/// allowed). Gradients flow through the means too.
pub fn part_loss(
    sigma: Tensor<2>,
    metallic: Tensor<2>,
    spec: Tensor<2>,
    seg: Tensor<1, Int>,
    n_seg: usize,
    weight: f32,
) -> Tensor<1> {
    let [n, _] = sigma.dims();
    let w = spec.detach().mean_dim(1).add_scalar(1e-4).reshape([n]);
    let s = sigma.reshape([n]);
    let m = metallic.reshape([n]);
    let dm = (m.clone() - weighted_label_mean(m, w.clone(), seg.clone(), n_seg))
        .abs()
        .mean();
    let ds = (s.clone() - weighted_label_mean(s, w, seg, n_seg))
        .abs()
        .mean();
    (dm + ds).mul_scalar(weight)
}

/// Partner slots of the semantic loss (Eq. 20 with the reference's sampling): `width` slots per
/// pixel, in pixel order. A pixel whose label has more than `partners` pixels draws `partners`
/// partners of its label at random, with replacement; otherwise it takes every pixel of its
/// label (itself included) and the slots left over are padding.
#[derive(Clone, Debug)]
pub struct SemanticPairs {
    pub width: usize,
    /// Partner index per slot (n × width); padding points at the pixel itself.
    pub partner: Vec<i64>,
    /// False on padding slots.
    pub valid: Vec<bool>,
}

pub fn semantic_pairs(labels: &[i32], partners: usize, rng: &mut crate::rng::Rng) -> SemanticPairs {
    let mut by_label: std::collections::BTreeMap<i32, Vec<i64>> = Default::default();
    for (i, &l) in labels.iter().enumerate() {
        by_label.entry(l).or_default().push(i as i64);
    }
    let width = by_label
        .values()
        .map(|m| m.len().min(partners))
        .max()
        .unwrap_or(0);
    let n = labels.len();
    let mut partner = Vec::with_capacity(n * width);
    let mut valid = Vec::with_capacity(n * width);
    for (i, l) in labels.iter().enumerate() {
        let members = &by_label[l];
        if members.len() > partners {
            for _ in 0..width {
                partner.push(members[rng.below(members.len() as u64) as usize]);
                valid.push(true);
            }
        } else {
            partner.extend_from_slice(members);
            valid.extend(std::iter::repeat_n(true, members.len()));
            partner.extend(std::iter::repeat_n(i as i64, width - members.len()));
            valid.extend(std::iter::repeat_n(false, width - members.len()));
        }
    }
    SemanticPairs {
        width,
        partner,
        valid,
    }
}

/// Eq. 20's normalised bilateral weights ŵ_ij = w_ij / (1e-4 + Σ_j w_ij), with
/// w_ij = exp(−|a_i − a_j|²/(2 s_a²))·exp(−|p_i − p_j|²/(2 s_p²)), base colour `a` and
/// bbox-normalised positions `pos` (3 floats per pixel each). Computed on the host: a is
/// detached and p is data, so no gradient flows through them.
pub fn semantic_weights(
    pairs: &SemanticPairs,
    a: &[f32],
    pos: &[f32],
    s_a: f32,
    s_p: f32,
) -> Vec<f32> {
    let (ka, kp) = (-0.5 / (s_a * s_a), -0.5 / (s_p * s_p));
    let d2 = |v: &[f32], i: usize, j: usize| -> f32 {
        (0..3).map(|c| (v[3 * i + c] - v[3 * j + c]).powi(2)).sum()
    };
    let mut out = vec![0f32; pairs.partner.len()];
    if pairs.width == 0 {
        return out;
    }
    out.par_chunks_mut(pairs.width)
        .enumerate()
        .for_each(|(i, row)| {
            let mut sum = 1e-4f32;
            for (k, w) in row.iter_mut().enumerate() {
                let slot = i * pairs.width + k;
                if pairs.valid[slot] {
                    let j = pairs.partner[slot] as usize;
                    *w = (ka * d2(a, i, j) + kp * d2(pos, i, j)).exp();
                    sum += *w;
                }
            }
            row.iter_mut().for_each(|w| *w /= sum);
        });
    out
}

/// Eq. 20 (semantic variant): bilateral smoothing of σ and m within each label:
/// r̄_i = Σ_j ŵ_ij r_j (weights from `semantic_weights`), likewise m̄; the per-pixel
/// |r̄_i − r_i| + |m̄_i − m_i| is averaged per label and the label means are summed.
pub fn semantic_loss(
    sigma: Tensor<2>,
    metallic: Tensor<2>,
    pairs: &SemanticPairs,
    weights: &[f32],
    labels_per_pixel: &[i64],
    n_labels: usize,
    weight: f32,
) -> Tensor<1> {
    let [n, _] = sigma.dims();
    let dev: Device = sigma.device();
    let sm = Tensor::cat(vec![sigma, metallic], 1);
    let p = pairs.width;
    let w = Tensor::<3>::from_data(TensorData::new(weights.to_vec(), [n, p, 1]), &dev);
    let bar = (select_rows(sm.clone(), &pairs.partner).reshape([n, p, 2]) * w)
        .sum_dim(1)
        .reshape([n, 2]);
    let per_pixel = (bar - sm).abs().sum_dim(1).reshape([n]);
    // Mean per label, summed over labels.
    let count = scatter_add(n_labels, labels_per_pixel, Tensor::<1>::ones([n], &dev));
    let sum = scatter_add(n_labels, labels_per_pixel, per_pixel);
    (sum / count.clamp_min(1.0)).sum().mul_scalar(weight)
}
