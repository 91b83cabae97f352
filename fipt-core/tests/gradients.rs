//! Finite-difference checks of every differentiable piece of the model in f64: the BRDF terms,
//! the factorised renderer with its roughness lerp and the composite, and every loss term
//! (colour, emission, diffuse prior, part and semantic segmentation). This binary configures the
//! flex device to f64 (a device's default dtype is set once per process), so it holds only
//! these checks.

use burn::tensor::{Device, Tensor, TensorData};
use fipt_core::model::brdf as tb;
use fipt_core::model::loss;
use fipt_core::model::render::{Shadings, composite, render};
use fipt_core::rng::Rng;
use fipt_core::shading::ShadingLayout;

/// Tensors built inside the checked functions come from f32 host data; on this binary's device
/// they compute in f64.
fn t2(v: &[f32], shape: [usize; 2], d: &Device) -> Tensor<2> {
    Tensor::from_data(TensorData::new(v.to_vec(), shape), d)
}

/// The flex device computing in f64 (configured once, before any tensor of this process; every
/// test of this binary computes in f64): finite differences are then accurate to ~1e-10.
fn dev64() -> Device {
    static DEV: std::sync::OnceLock<Device> = std::sync::OnceLock::new();
    DEV.get_or_init(|| {
        let mut d = Device::flex();
        d.configure(burn::tensor::FloatDType::F64)
            .expect("flex computes in f64 (configured before any tensor of this test binary)");
        d
    })
    .clone()
}

fn t64(v: &[f64], shape: [usize; 2], d: &Device) -> Tensor<2> {
    Tensor::from_data(TensorData::new(v.to_vec(), shape), d)
}

/// Checks d f / d inputs[k] against central differences in f64 for every input tensor, at every
/// entry. `f` maps the input tensors to a scalar. Tolerance: |fd − an| ≤ atol + rtol·max(|fd|,|an|).
fn grad_check(
    name: &str,
    inputs: &[(Vec<f32>, [usize; 2])],
    f: &dyn Fn(&[Tensor<2>]) -> Tensor<1>,
    h: f32,
    rtol: f64,
    atol: f64,
) {
    let _ = h;
    let h = 1e-6f64;
    let d = dev64();
    let ad = d.clone().autodiff();
    let inputs: Vec<(Vec<f64>, [usize; 2])> = inputs
        .iter()
        .map(|(v, s)| (v.iter().map(|&x| x as f64).collect(), *s))
        .collect();
    let leaves: Vec<Tensor<2>> = inputs
        .iter()
        .map(|(v, s)| t64(v, *s, &ad).require_grad())
        .collect();
    let out = f(&leaves);
    assert_eq!(
        out.dtype(),
        burn::tensor::DType::F64,
        "{name}: the check must run in f64"
    );
    let grads = out.backward();
    for (k, (v, s)) in inputs.iter().enumerate() {
        let an: Vec<f64> = leaves[k]
            .grad(&grads)
            .unwrap_or_else(|| Tensor::zeros(*s, &d))
            .try_into_vec_as::<f64>()
            .unwrap();
        for i in 0..v.len() {
            let eval = |delta: f64| {
                let ts: Vec<Tensor<2>> = inputs
                    .iter()
                    .enumerate()
                    .map(|(j, (w, sj))| {
                        let mut w = w.clone();
                        if j == k {
                            w[i] += delta;
                        }
                        t64(&w, *sj, &d)
                    })
                    .collect();
                f(&ts).into_scalar::<f64>()
            };
            let fd = (eval(h) - eval(-h)) / (2.0 * h);
            let a = an[i];
            assert!(
                (fd - a).abs() <= atol + rtol * fd.abs().max(a.abs()),
                "{name}: input {k} entry {i}: finite difference {fd:.9e} vs autodiff {a:.9e}"
            );
        }
    }
}

fn uniform(n: usize, lo: f32, hi: f32, seed: u64) -> Vec<f32> {
    let mut r = Rng::new(seed, 77);
    (0..n).map(|_| lo + (hi - lo) * r.next_f32()).collect()
}

#[test]
fn brdf_gradients() {
    let n = 12;
    let a = uniform(3 * n, 0.05, 0.95, 4);
    let m = uniform(n, 0.05, 0.95, 5);
    let s = uniform(n, 0.1, 0.95, 6);
    let cv = uniform(n, 0.2, 0.9, 7);
    let cl = uniform(n, 0.2, 0.9, 8);
    let ch = uniform(n, 0.5, 0.99, 9);
    let vh = uniform(n, 0.2, 0.9, 10);
    grad_check(
        "brdf f(a, σ, m)",
        &[(a, [n, 3]), (s, [n, 1]), (m, [n, 1])],
        &|x| {
            let (kd, ks) = tb::reflectances(x[0].clone(), x[2].clone());
            let d = x[0].device();
            let c = |v: &Vec<f32>| t2(v, [n, 1], &d);
            tb::eval_f(kd, ks, x[1].clone(), c(&cv), c(&cl), c(&ch), c(&vh)).sum()
        },
        1e-6,
        1e-6,
        1e-9,
    );
}

#[test]
fn render_gradients_including_roughness_lerp() {
    let n = 10;
    let kd = uniform(3 * n, 0.0, 1.0, 11);
    let ks = uniform(3 * n, 0.0, 1.0, 12);
    // Keep σ away from the level values (the lerp has kinks there).
    let s: Vec<f32> = uniform(n, 0.0, 1.0, 13)
        .iter()
        .map(|u| 0.02 + 0.196 * ((u * 5.0).floor() + 0.2 + 0.6 * (u * 5.0).fract()))
        .collect();
    let sh = uniform(n * ShadingLayout::DIM, 0.0, 2.0, 14);
    let alpha = uniform(n, 0.0, 1.0, 15);
    let gt = uniform(3 * n, 0.0, 3.0, 16);
    grad_check(
        "factorised render + composite",
        &[
            (kd, [n, 3]),
            (ks, [n, 3]),
            (s, [n, 1]),
            (sh, [n, ShadingLayout::DIM]),
            (alpha, [n, 1]),
        ],
        &|x| {
            let shd = Shadings::from_packed(x[3].clone());
            let (pred, spec) = render(x[0].clone(), x[1].clone(), x[2].clone(), &shd);
            let g = t2(&gt, [n, 3], &x[0].device());
            (composite(pred, x[4].clone(), g) + spec)
                .powi_scalar(2)
                .sum()
        },
        1e-6,
        1e-6,
        1e-9,
    );
}

#[test]
fn loss_gradients() {
    let n = 16;
    // Keep values away from the tone-map knee.
    let c = uniform(3 * n, 0.01, 2.0, 20);
    let g = uniform(3 * n, 0.01, 2.0, 21);
    grad_check(
        "L_c",
        &[(c, [n, 3]), (g, [n, 3])],
        &|x| loss::color_loss(x[0].clone(), x[1].clone()),
        1e-6,
        1e-6,
        1e-9,
    );
    let raw: Vec<f32> = uniform(n, 0.1, 1.0, 22)
        .iter()
        .enumerate()
        .map(|(i, v)| if i % 2 == 0 { *v } else { -v })
        .collect();
    grad_check(
        "L_e",
        &[(raw, [n, 1])],
        &|x| loss::emission_loss(x[0].clone(), 1.0),
        1e-6,
        1e-6,
        1e-9,
    );
    let s = uniform(n, 0.1, 0.9, 23);
    let m = uniform(n, 0.1, 0.9, 24);
    grad_check(
        "L_d",
        &[(s.clone(), [n, 1]), (m.clone(), [n, 1])],
        &|x| loss::diffuse_loss(x[0].clone(), x[1].clone(), 5e-4, 1.0, 1.0),
        1e-6,
        1e-6,
        1e-12,
    );
    // Eq. 17 with the m term weighted apart (`TrainConfig::metallic_scale` 5) and σ₀: its
    // closed form λ·(mean|σ − σ₀| + 5·mean m), the host summand and the gradients.
    let t = |v: &[f32]| Tensor::<2>::from_data(TensorData::new(v.to_vec(), [n, 1]), &dev64());
    let mean =
        |v: &[f32], f: &dyn Fn(f32) -> f32| v.iter().map(|&x| f(x) as f64).sum::<f64>() / n as f64;
    let prior_case = |what: &str, sigma: &[f32], s0: f32| {
        let got = loss::diffuse_loss(t(sigma), t(&m), 1e-4, 5.0, s0).into_scalar::<f64>();
        let want = 1e-4 * (mean(sigma, &|x| (x - s0).abs()) + 5.0 * mean(&m, &|x| x));
        assert!((got - want).abs() < 1e-9, "{what}: {got} vs {want}");
        let prior = loss::DiffusePrior {
            lambda_d: 1e-4,
            sigma: s0,
        };
        let host = sigma
            .iter()
            .zip(&m)
            .map(|(&x, &y)| prior.at(x, 5.0 * y) as f64)
            .sum::<f64>()
            / n as f64;
        assert!(
            (host - want).abs() < 1e-9,
            "{what}, the host summand: {host} vs {want}"
        );
        grad_check(
            what,
            &[(sigma.to_vec(), [n, 1]), (m.clone(), [n, 1])],
            &|x| loss::diffuse_loss(x[0].clone(), x[1].clone(), 1e-4, 5.0, s0),
            1e-6,
            1e-6,
            1e-12,
        );
    };
    prior_case("L_d, m term ×5", &s, 1.0);
    // A prior σ₀ = 0.85 inside the range: σ on both sides of it (kept 0.05 away from the kink),
    // so the pull changes sign at σ₀.
    let s0 = 0.85f32;
    let sk: Vec<f32> = uniform(n, 0.0, 1.0, 29)
        .iter()
        .map(|&u| if u < 0.5 { 0.3 + u } else { 0.4 + u })
        .collect();
    assert!(sk.iter().any(|&x| x < s0) && sk.iter().any(|&x| x > s0));
    prior_case("L_d, σ₀ = 0.85", &sk, s0);
    // Logits on both sides of ±z_max (kept 0.05 away from the kinks).
    let z: Vec<f32> = uniform(2 * n, 0.0, 1.0, 28)
        .iter()
        .enumerate()
        .map(|(i, v)| {
            let mag = if i % 3 == 0 {
                3.0 + 1.5 * v
            } else {
                5.05 + 3.0 * v
            };
            if i % 2 == 0 { mag } else { -mag }
        })
        .collect();
    grad_check(
        "L_z",
        &[(z, [n, 2])],
        &|x| loss::logit_bound_loss(x[0].clone(), 5.0, 1e-3),
        1e-6,
        1e-6,
        1e-12,
    );
    let spec = uniform(3 * n, 0.0, 1.0, 25);
    let seg: Vec<i64> = (0..n as i64).map(|i| i % 3).collect();
    grad_check(
        "L_seg part",
        &[(s.clone(), [n, 1]), (m.clone(), [n, 1])],
        &|x| {
            let d = x[0].device();
            loss::part_loss(
                x[0].clone(),
                x[1].clone(),
                t2(&spec, [n, 3], &d),
                fipt_core::model::gather::index_tensor(&seg, &d),
                // Labels 3 and 4 carry no pixel (the device path runs the part loss over all of
                // the store's labels): the gradient stays exact.
                5,
                1.0,
            )
        },
        1e-6,
        1e-6,
        1e-9,
    );
    let a = uniform(3 * n, 0.4, 0.6, 26);
    let p = uniform(3 * n, -0.2, 0.2, 27);
    let labels: Vec<i32> = (0..n as i32).map(|i| i % 2).collect();
    let pairs = loss::semantic_pairs(&labels, 4, &mut Rng::new(3, 3));
    let w = loss::semantic_weights(&pairs, &a, &p, 0.05, 0.3);
    let lab64: Vec<i64> = labels.iter().map(|&l| l as i64).collect();
    grad_check(
        "L_seg semantic",
        &[(s, [n, 1]), (m, [n, 1])],
        &|x| loss::semantic_loss(x[0].clone(), x[1].clone(), &pairs, &w, &lab64, 2, 1.0),
        1e-6,
        1e-6,
        1e-9,
    );
}
