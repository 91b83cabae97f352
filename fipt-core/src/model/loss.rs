//! The stage-2 losses (paper Eq. 15–20, reference §2.3) as tensor ops.
//!
//! Owns: tone mapping and every loss term. Must not touch: which pixels are in a batch.

use burn::tensor::{Device, IndexingUpdateOp, Int, Tensor, TensorData};

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

/// Eq. 15: L_c = mean (Γ(C) − Γ(I))².
pub fn color_loss(c: Tensor<2>, gt: Tensor<2>) -> Tensor<1> {
    (tonemap(c) - tonemap(gt)).powi_scalar(2).mean()
}

/// Eq. 16: L_e = λ_e · mean |raw| (on the raw mask output, reference §5.5).
pub fn emission_loss(raw: Tensor<2>, weight: f32) -> Tensor<1> {
    raw.abs().mean().mul_scalar(weight)
}

/// Eq. 17: L_d = λ_d · (mean |σ − 1| + mean m), a pull towards rough dielectrics.
pub fn diffuse_loss(sigma: Tensor<2>, metallic: Tensor<2>, weight: f32) -> Tensor<1> {
    (sigma.sub_scalar(1.0).abs().mean() + metallic.mean()).mul_scalar(weight)
}

/// Eq. 18–19 (part variant): per segment, weighted means of σ and m with weights
/// w = mean_rgb(specular shading).detach() + 1e-4; L = λ·(mean|m − m̄_s| + mean|σ − σ̄_s|).
/// `seg` holds compact segment ids 0..n_seg−1. Gradients flow through the means too.
pub fn part_loss(
    sigma: Tensor<2>,
    metallic: Tensor<2>,
    spec: Tensor<2>,
    seg: Tensor<1, Int>,
    n_seg: usize,
    weight: f32,
) -> Tensor<1> {
    let [n, _] = sigma.dims();
    let dev = sigma.device();
    let w = spec.detach().mean_dim(1).add_scalar(1e-4).reshape([n]);
    let seg_mean = |v: Tensor<1>| {
        let z = Tensor::<1>::zeros([n_seg], &dev);
        let sw = z
            .clone()
            .select_assign(0, seg.clone(), w.clone(), IndexingUpdateOp::Add);
        let swv = z.select_assign(0, seg.clone(), w.clone() * v, IndexingUpdateOp::Add);
        (swv / sw).select(0, seg.clone())
    };
    let s = sigma.reshape([n]);
    let m = metallic.reshape([n]);
    let dm = (m.clone() - seg_mean(m)).abs().mean();
    let ds = (s.clone() - seg_mean(s)).abs().mean();
    (dm + ds).mul_scalar(weight)
}

/// Partner pairs for the semantic loss: for each pixel i and each of `partners` draws, a random
/// pixel j with the same label (with replacement); labels with ≤ `partners` pixels use all
/// pairs. Returns (i, j, label of i) as flat lists, grouped by label.
pub fn semantic_pairs(
    labels: &[i32],
    partners: usize,
    rng: &mut crate::rng::Rng,
) -> (Vec<i64>, Vec<i64>, Vec<i64>) {
    let mut by_label: std::collections::BTreeMap<i32, Vec<usize>> = Default::default();
    for (i, &l) in labels.iter().enumerate() {
        by_label.entry(l).or_default().push(i);
    }
    let (mut is, mut js, mut ls) = (vec![], vec![], vec![]);
    for (k, (_, members)) in by_label.iter().enumerate() {
        for &i in members {
            if members.len() <= partners {
                for &j in members {
                    is.push(i as i64);
                    js.push(j as i64);
                    ls.push(k as i64);
                }
            } else {
                for _ in 0..partners {
                    let j = members[rng.below(members.len() as u64) as usize];
                    is.push(i as i64);
                    js.push(j as i64);
                    ls.push(k as i64);
                }
            }
        }
    }
    (is, js, ls)
}

/// Eq. 20 (semantic variant): bilateral smoothing of σ and m within each label. For pairs
/// (i, j): w_ij = exp(−|a_i − a_j|²/(2 s_a²))·exp(−|p_i − p_j|²/(2 s_p²)) with detached base
/// colour a and bbox-normalised positions p; r̄_i = Σ_j w_ij r_j / (1e-4 + Σ_j w_ij), likewise m̄.
/// The per-pixel |r̄_i − r_i| + |m̄_i − m_i| is averaged per label and summed over labels.
#[allow(clippy::too_many_arguments)]
pub fn semantic_loss(
    sigma: Tensor<2>,
    metallic: Tensor<2>,
    a: Tensor<2>,
    pos: Tensor<2>,
    pairs: &(Vec<i64>, Vec<i64>, Vec<i64>),
    labels_per_pixel: &[i64],
    n_labels: usize,
    s_a: f32,
    s_p: f32,
    weight: f32,
) -> Tensor<1> {
    let [n, _] = sigma.dims();
    let dev: Device = sigma.device();
    let np = pairs.0.len();
    let idx = |v: &Vec<i64>| Tensor::<1, Int>::from_data(TensorData::new(v.clone(), [np]), &dev);
    let (ii, jj) = (idx(&pairs.0), idx(&pairs.1));
    let a = a.detach();
    let da = (a.clone().select(0, ii.clone()) - a.select(0, jj.clone()))
        .powi_scalar(2)
        .sum_dim(1);
    let dp = (pos.clone().select(0, ii.clone()) - pos.select(0, jj.clone()))
        .powi_scalar(2)
        .sum_dim(1);
    let w = (da.div_scalar(-2.0 * s_a * s_a) + dp.div_scalar(-2.0 * s_p * s_p))
        .exp()
        .reshape([np]);
    let s = sigma.reshape([n]);
    let m = metallic.reshape([n]);
    let z = Tensor::<1>::zeros([n], &dev);
    let sw = z
        .clone()
        .select_assign(0, ii.clone(), w.clone(), IndexingUpdateOp::Add)
        .add_scalar(1e-4);
    let bar = |v: Tensor<1>| {
        z.clone().select_assign(
            0,
            ii.clone(),
            w.clone() * v.select(0, jj.clone()),
            IndexingUpdateOp::Add,
        ) / sw.clone()
    };
    let per_pixel = (bar(s.clone()) - s).abs() + (bar(m.clone()) - m).abs();
    // Mean per label, summed over labels.
    let lab = Tensor::<1, Int>::from_data(TensorData::new(labels_per_pixel.to_vec(), [n]), &dev);
    let zl = Tensor::<1>::zeros([n_labels], &dev);
    let count = zl.clone().select_assign(
        0,
        lab.clone(),
        Tensor::<1>::ones([n], &dev),
        IndexingUpdateOp::Add,
    );
    let sum = zl.select_assign(0, lab, per_pixel, IndexingUpdateOp::Add);
    (sum / count.clamp_min(1.0)).sum().mul_scalar(weight)
}
