//! Model checks: tensor/scalar BRDF agreement, the roughness lerp, the semantic loss against its
//! formula, the tcnn init, and the device grid's step against the host path. The finite-
//! difference gradient checks (f64) are in `tests/gradients.rs`.

use super::brdf as tb;
use super::loss;
use super::render::roughness_weights;
use crate::brdf as sb;
use crate::rng::Rng;
use crate::shading::ShadingLayout;
use burn::tensor::{Device, Tensor, TensorData};
use glam::Vec3;

fn dev() -> Device {
    Device::flex()
}

fn t2(v: &[f32], shape: [usize; 2], d: &Device) -> Tensor<2> {
    Tensor::from_data(TensorData::new(v.to_vec(), shape), d)
}

fn to_vec(t: Tensor<2>) -> Vec<f32> {
    t.try_into_vec_as::<f32>().unwrap()
}

fn uniform(n: usize, lo: f32, hi: f32, seed: u64) -> Vec<f32> {
    let mut r = Rng::new(seed, 77);
    (0..n).map(|_| lo + (hi - lo) * r.next_f32()).collect()
}

#[test]
fn brdf_tensor_matches_scalar() {
    let d = dev();
    let mut r = Rng::new(1, 1);
    let n = 64;
    let (mut kd, mut ks, mut sig, mut cos) = (vec![], vec![], vec![], vec![[0f32; 4]; 0]);
    let mut want = vec![];
    for _ in 0..n {
        let a = Vec3::new(r.next_f32(), r.next_f32(), r.next_f32());
        let m = r.next_f32();
        let s = 0.02 + 0.98 * r.next_f32();
        let b = sb::Brdf::from_material(a, s, m);
        let wo = sb::sample_cosine(r.next_f32(), r.next_f32());
        let wi = sb::sample_cosine(r.next_f32(), r.next_f32());
        let h = (wo + wi).normalize();
        want.push(b.f(wo, wi));
        kd.extend(b.kd.to_array());
        ks.extend(b.ks.to_array());
        sig.push(s);
        cos.push([wo.z, wi.z, h.z, wo.dot(h)]);
    }
    let col = |k: usize| t2(&cos.iter().map(|c| c[k]).collect::<Vec<_>>(), [n, 1], &d);
    let f = to_vec(tb::eval_f(
        t2(&kd, [n, 3], &d),
        t2(&ks, [n, 3], &d),
        t2(&sig, [n, 1], &d),
        col(0),
        col(1),
        col(2),
        col(3),
    ));
    for (i, w) in want.iter().enumerate() {
        for c in 0..3 {
            let (a, b) = (f[i * 3 + c], w[c]);
            assert!(
                (a - b).abs() <= 1e-5 + 1e-4 * b.abs(),
                "sample {i}: {a} vs {b}"
            );
        }
    }
    // Reflectances.
    let a = uniform(30, 0.0, 1.0, 2);
    let m = uniform(10, 0.0, 1.0, 3);
    let (kd, ks) = tb::reflectances(t2(&a, [10, 3], &d), t2(&m, [10, 1], &d));
    let (kd, ks) = (to_vec(kd), to_vec(ks));
    for i in 0..10 {
        let (wkd, wks) = sb::reflectances(Vec3::from_slice(&a[i * 3..]), m[i]);
        for c in 0..3 {
            assert!((kd[i * 3 + c] - wkd[c]).abs() < 1e-6 && (ks[i * 3 + c] - wks[c]).abs() < 1e-6);
        }
    }
}

/// The logit bound: nothing inside ±z_max, λ·Σ(|z| − z_max)²/N outside, on both signs.
#[test]
fn logit_bound_is_zero_inside_and_quadratic_outside() {
    let d = dev();
    let z = [0.0f32, 4.9, -4.9, 5.0, 6.0, -7.0];
    let inside = loss::logit_bound_loss(t2(&z[..4], [2, 2], &d), 5.0, 1e-3).into_scalar::<f32>();
    assert_eq!(inside, 0.0);
    let l = loss::logit_bound_loss(t2(&z, [3, 2], &d), 5.0, 1e-3).into_scalar::<f32>();
    let want = 1e-3 * (1.0 + 4.0) / 3.0;
    assert!((l - want).abs() < 1e-9, "{l} vs {want}");
}

#[test]
fn roughness_weights_are_the_reference_lerp() {
    let d = dev();
    let s = [0.02f32, 0.1, 0.216, 0.5, 0.999, 1.0];
    let w = to_vec(roughness_weights(t2(&s, [6, 1], &d)));
    for (i, &sig) in s.iter().enumerate() {
        let r = (sig - 0.02) / 0.98 * 5.0;
        let (r0, r1) = (r.floor(), r.ceil());
        for j in 0..6 {
            let want = if r0 == r1 {
                (j as f32 == r0) as u8 as f32
            } else if j as f32 == r0 {
                r1 - r
            } else if j as f32 == r1 {
                r - r0
            } else {
                0.0
            };
            assert!((w[i * 6 + j] - want).abs() < 1e-5, "σ={sig} level {j}");
        }
    }
}

/// Eq. 20 against a direct evaluation of the formula, pair by pair, in f64: both the sampled
/// branch (labels larger than the partner count) and the all-pairs branch with padding.
#[test]
fn semantic_loss_matches_the_direct_formula() {
    let d = dev();
    let n = 40;
    // Label 0: 30 pixels (> 8 partners, sampled); label 1: 7 pixels; label 2: 3 pixels.
    let labels: Vec<i32> = (0..n)
        .map(|i| {
            if i < 30 {
                0
            } else if i < 37 {
                1
            } else {
                2
            }
        })
        .collect();
    let (s, m) = (uniform(n, 0.1, 0.9, 40), uniform(n, 0.0, 1.0, 41));
    let a = uniform(3 * n, 0.3, 0.7, 42);
    let p = uniform(3 * n, -0.5, 0.5, 43);
    let (sa, sp) = (0.2f32, 0.4f32);
    let pairs = loss::semantic_pairs(&labels, 8, &mut Rng::new(5, 5));
    assert_eq!(pairs.width, 8);
    let w = loss::semantic_weights(&pairs, &a, &p, sa, sp);
    let lab64: Vec<i64> = labels.iter().map(|&l| l as i64).collect();
    let got: f32 = loss::semantic_loss(
        t2(&s, [n, 1], &d),
        t2(&m, [n, 1], &d),
        &pairs,
        &w,
        &lab64,
        3,
        1.0,
    )
    .into_scalar();
    let mut per_label = [(0f64, 0usize); 3];
    for i in 0..n {
        let (mut sw, mut ss, mut sm) = (1e-4f64, 0f64, 0f64);
        for k in 0..pairs.width {
            let slot = i * pairs.width + k;
            if !pairs.valid[slot] {
                continue;
            }
            let j = pairs.partner[slot] as usize;
            assert_eq!(labels[j], labels[i], "partners share the label");
            let dist = |v: &[f32]| -> f64 {
                (0..3)
                    .map(|c| (v[3 * i + c] as f64 - v[3 * j + c] as f64).powi(2))
                    .sum()
            };
            let wij = (-dist(&a) / (2.0 * (sa as f64).powi(2))
                - dist(&p) / (2.0 * (sp as f64).powi(2)))
            .exp();
            sw += wij;
            ss += wij * s[j] as f64;
            sm += wij * m[j] as f64;
        }
        let l = labels[i] as usize;
        per_label[l].0 += (ss / sw - s[i] as f64).abs() + (sm / sw - m[i] as f64).abs();
        per_label[l].1 += 1;
    }
    // Small labels take every member exactly once.
    let row = |i: usize| -> Vec<i64> {
        let mut v: Vec<i64> = (0..8)
            .filter(|&k| pairs.valid[i * 8 + k])
            .map(|k| pairs.partner[i * 8 + k])
            .collect();
        v.sort();
        v
    };
    assert_eq!(row(31), (30..37).collect::<Vec<i64>>());
    assert_eq!(row(38), (37..40).collect::<Vec<i64>>());
    let want: f64 = per_label.iter().map(|(sum, c)| sum / *c as f64).sum();
    // The weights are f32 on the host: agreement to f32 rounding.
    assert!(
        (got as f64 - want).abs() < 1e-5 * want.abs().max(1.0),
        "{got} vs {want}"
    );
}

#[test]
fn tonemap_is_the_srgb_curve() {
    let d = dev();
    let x = [0.0f32, 0.001, 0.0031308, 0.01, 0.5, 1.0, 4.0];
    let y = to_vec(loss::tonemap(t2(&x, [7, 1], &d)));
    for (xi, yi) in x.iter().zip(&y) {
        let want = if *xi <= 0.0031308 {
            12.92 * xi
        } else {
            1.055 * xi.powf(1.0 / 2.4) - 0.055
        };
        assert!((yi - want).abs() < 1e-5, "{xi}: {yi} vs {want}");
        // The host copy is the same curve.
        assert!((loss::tonemap_host(*xi) - want as f64).abs() < 1e-6, "{xi}");
    }
}

/// The material MLP starts as tiny-cuda-nn's FullyFusedMLP: no biases and Xavier-uniform
/// weights over 16-padded widths, U(±√(6/(fan_in + fan_out))). A PyTorch-default init
/// (U(±1/√fan_in), 0.125 here) fails the lower bound on every layer.
#[test]
fn material_mlp_uses_the_tcnn_init() {
    use super::fields::MaterialFieldConfig;
    use super::hashgrid::HashGridConfig;
    let d = dev();
    // 20 levels × 2 features = 40 inputs, padded to 48.
    let cfg = MaterialFieldConfig::new()
        .with_grid(HashGridConfig::new().with_levels(20).with_log2_table(8));
    let field = cfg.init(&d, 3);
    let bounds = [
        (6.0f32 / (48.0 + 64.0)).sqrt(),
        (6.0f32 / 128.0).sqrt(),
        (6.0f32 / (64.0 + 16.0)).sqrt(),
    ];
    assert_eq!(field.mlp.layers.len(), 3);
    for (layer, bound) in field.mlp.layers.iter().zip(bounds) {
        assert!(layer.bias.is_none());
        let w: Vec<f32> = layer.weight.val().try_into_vec_as::<f32>().expect("f32");
        let max = w.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        assert!(
            max <= bound && max > 0.97 * bound,
            "max |w| {max} vs bound {bound}"
        );
        let mean = w.iter().sum::<f32>() / w.len() as f32;
        assert!(mean.abs() < 0.1 * bound, "mean {mean}");
    }
}

/// max |a − b| / max |b|.
fn rel_err(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    let scale = b.iter().fold(0f32, |m, v| m.max(v.abs()));
    let err = a.iter().zip(b).fold(0f32, |m, (x, y)| m.max((x - y).abs()));
    if scale == 0.0 { err } else { err / scale }
}

/// The device-resident grid (`hashgrid_device`: tables, hashing, gather, autodiff scatter and
/// burn's dense Adam) gives the host path's step: the same loss parts, network gradients and
/// table gradient; after one step (dense and sparse Adam coincide on the first step: zero
/// moments, and entries without gradient stay put) the same table and networks where the
/// gradient is above rounding. A batch drawn from a `DeviceStore` by index gives the same loss
/// as the same pixels uploaded whole, and pending losses read back the values of a read step.
#[test]
fn device_grid_step_matches_host_step() {
    use super::step::{DeviceStore, SegMode, StepInput, StepLoss, TrainConfig, Trainer};
    use super::{HashGridConfig, MaterialFieldConfig};
    use crate::scene::SceneBox;
    let unit = SceneBox { min: 0.0, max: 1.0 };
    let cfg = |device_grid: bool| {
        let grid = HashGridConfig::new()
            .with_levels(8)
            .with_log2_table(12)
            .with_base_resolution(4.0)
            .with_per_level_scale(1.6);
        TrainConfig::new()
            .with_material(MaterialFieldConfig::new().with_grid(grid))
            .with_device_grid(device_grid)
    };
    let store = super::Batch::synthetic(6000, 3);
    let mut r = Rng::new(7, 7);
    let idx: Vec<u32> = (0..2048).map(|_| r.below(6000) as u32).collect();
    let mut batch = super::Batch::default();
    for &i in &idx {
        let i = i as usize;
        batch.x_unit.push(store.x_unit[i]);
        batch.x_world.push(store.x_world[i]);
        batch
            .shadings
            .extend_from_slice(ShadingLayout::pixel(&store.shadings, i));
        batch.gt.extend_from_slice(&store.gt[3 * i..3 * i + 3]);
        batch.seg.push(store.seg[i]);
    }
    let table: Vec<f32> = {
        let n = Trainer::new(cfg(false), unit, &dev(), 5)
            .model
            .grid
            .table
            .len();
        (0..n).map(|_| r.next_f32() - 0.5).collect()
    };
    let make = |device_grid: bool| {
        let mut t = Trainer::new(cfg(device_grid), unit, &dev(), 5);
        t.model.grid.table.clone_from(&table);
        if device_grid {
            t.model.upload_table();
        }
        t
    };
    let (mut host, mut devt) = (make(false), make(true));
    assert!(devt.device_resident() && !host.device_resident());
    assert_eq!(devt.table(), table);
    for mode in [SegMode::Part, SegMode::Semantic] {
        let (gh, gd) = (host.gradients(&batch, mode), devt.gradients(&batch, mode));
        let parts = |p: super::LossParts| vec![p.total, p.color, p.emission, p.diffuse, p.seg];
        assert!(
            rel_err(&parts(gd.parts), &parts(gh.parts)) <= 1e-5,
            "{mode:?} loss"
        );
        assert!(gh.parts.seg > 0.0);
        assert!(
            rel_err(&[gd.parts.seg], &[gh.parts.seg]) <= 1e-5,
            "{mode:?} seg loss"
        );
        assert!(gh.table.iter().filter(|g| **g != 0.0).count() > 4000);
        assert!(
            rel_err(&gd.table, &gh.table) <= 1e-4,
            "{mode:?} table gradient"
        );
        for (i, (a, b)) in gd.params.iter().zip(&gh.params).enumerate() {
            assert!(rel_err(a, b) <= 1e-4, "{mode:?} gradient of parameter {i}");
        }
    }
    // The store path: the same pixels by index, the loss left on the device.
    let ds = DeviceStore::upload(&store, &devt.device);
    assert_eq!(ds.n_seg, 3);
    let whole = devt.gradients(&batch, SegMode::Part).table;
    let g = host.gradients(&batch, SegMode::Part);
    let p0 = devt.net_params();
    let by_index = devt.step_on(
        StepInput::Device {
            store: &ds,
            idx: &idx,
            host: None,
        },
        SegMode::Part,
    );
    assert!(matches!(by_index, StepLoss::Pending(_)));
    let read = StepLoss::read_all(vec![by_index])[0];
    let parts = |p: super::LossParts| vec![p.total, p.color, p.emission, p.diffuse, p.seg];
    // Every part: a wrong segment id would show in `seg` (a small share of the total).
    assert!(
        rel_err(&parts(read), &parts(g.parts)) <= 1e-5,
        "step by index"
    );
    assert!(read.seg > 0.0);
    assert!(rel_err(&whole, &g.table) <= 1e-4);
    let lh = host.step(&batch, SegMode::Part);
    assert!(rel_err(&parts(lh), &parts(read)) <= 1e-5);
    // One Adam step: −lr·g/(|g| + ε) on both paths where |g| is above rounding.
    let (lr, eps) = (host.cfg.lr as f32, host.cfg.eps);
    let (th, td) = (host.table(), devt.table());
    let gmax = g.table.iter().fold(0f32, |m, v| m.max(v.abs()));
    let mut checked = 0;
    for j in 0..table.len() {
        let gj = g.table[j];
        if gj == 0.0 {
            assert_eq!(th[j], table[j], "an entry without gradient moved (host)");
            assert_eq!(td[j], table[j], "an entry without gradient moved (device)");
        } else if gj.abs() > 1e-3 * gmax {
            let want = table[j] - lr * gj / (gj.abs() + eps);
            assert!((th[j] - want).abs() <= 1e-4 * lr, "host entry {j}");
            assert!((td[j] - want).abs() <= 1e-4 * lr, "device entry {j}");
            checked += 1;
        }
    }
    assert!(checked > 3000, "{checked} entries checked");
    for (i, ((a, b), p)) in devt
        .net_params()
        .iter()
        .zip(host.net_params())
        .zip(&p0)
        .enumerate()
    {
        let gmax = g.params[i].iter().fold(0f32, |m, v| m.max(v.abs()));
        for j in 0..a.len() {
            if g.params[i][j].abs() > 1e-3 * gmax {
                assert!((a[j] - b[j]).abs() <= 1e-4 * lr, "parameter {i}[{j}]");
                assert!(
                    (a[j] - p[j]).abs() > 0.5 * lr,
                    "parameter {i}[{j}] did not move"
                );
            }
        }
    }
}

/// Largest |a − b| over the largest |b| (at least 1e-6).
fn max_rel(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    let scale = b.iter().fold(1e-6f32, |m, v| m.max(v.abs()));
    a.iter().zip(b).fold(0f32, |m, (x, y)| m.max((x - y).abs())) / scale
}

/// burn's autodiff gradient of Σ out ⊙ g for every parameter of `layers`, weights flat.
fn burn_layer_grads(
    layers: &[&burn::nn::Linear],
    grads: &burn::tensor::Gradients,
) -> Vec<(Vec<f32>, Option<Vec<f32>>)> {
    let host = |t: Tensor<1>| t.try_into_vec_as::<f32>().unwrap();
    layers
        .iter()
        .map(|l| {
            let [i, o] = l.weight.val().dims();
            let w = host(l.weight.val().grad(grads).unwrap().reshape([i * o]));
            let b = l.bias.as_ref().map(|b| host(b.val().grad(grads).unwrap()));
            (w, b)
        })
        .collect()
}

/// The fused host emission mask (positional encoding, skip layer, biases) against burn's graph:
/// the output and every parameter gradient of Σ raw ⊙ g, over a batch of two gradient groups
/// with a partial block.
#[test]
fn host_emission_mask_matches_burn() {
    use super::fields::EmissionMaskConfig;
    use super::host_mlp::positional_encoding_host;
    let ad = dev().autodiff();
    let mask = EmissionMaskConfig::new()
        .with_width(48)
        .with_depth(5)
        .with_skip(2)
        .with_freqs(6)
        .init(&ad, 5);
    let n = 1300;
    let xw = uniform(3 * n, -2.0, 2.5, 1);
    let g = uniform(n, -1.0, 1.0, 2);
    let xt = t2(&xw, [n, 3], &ad).require_grad();
    let raw = mask.raw(xt.clone());
    let grads = (raw.clone() * t2(&g, [n, 1], &ad)).sum().backward();
    let want = burn_layer_grads(&mask.all_layers(), &grads);
    let want_dxw = to_vec(xt.grad(&grads).unwrap());

    let host = mask.to_host();
    host.check().unwrap();
    assert_eq!(host.skip, Some(2));
    let pts: Vec<[f32; 3]> = xw.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    let pe = positional_encoding_host(&pts, 6);
    let (out, tape) = host.forward(&pe);
    let e = max_rel(&out, &to_vec(raw));
    assert!(e < 1e-5, "output differs by {e}");
    let (got, dx) = host.backward(&pe, &tape, &g, true);
    // The input gradient (layer 0's and the skip layer's parts) carried through the encoding
    // to the positions: d[x, sin(f x), cos(f x)]/dx = [1, f cos(f x), −f sin(f x)].
    let dx = dx.unwrap();
    let dim = pe.len() / n;
    let mut dxw = vec![0f32; 3 * n];
    for (i, p) in pts.iter().enumerate() {
        let d = &dx[i * dim..(i + 1) * dim];
        for k in 0..3 {
            let mut v = d[k];
            for l in 0..6 {
                let f = (2f64.powi(l) * std::f64::consts::PI) as f32;
                let (sn, cs) = (p[k] * f).sin_cos();
                v += f * (cs * d[3 + 3 * l as usize + k] - sn * d[3 + 18 + 3 * l as usize + k]);
            }
            dxw[3 * i + k] = v;
        }
    }
    let e = max_rel(&dxw, &want_dxw);
    assert!(e < 1e-3, "input gradient differs by {e}");
    for (k, (w, b)) in want.iter().enumerate() {
        let e = max_rel(&got.weight[k], w);
        assert!(e < 1e-4, "layer {k}: weight gradient differs by {e}");
        let e = max_rel(got.bias[k].as_ref().unwrap(), b.as_ref().unwrap());
        assert!(e < 1e-4, "layer {k}: bias gradient differs by {e}");
    }
    // A skip the gradient did not reach would leave the rows for the encoding at zero.
    let skip_rows = &got.weight[2][..pe.len() / n * 48];
    assert!(skip_rows.iter().any(|v| v.abs() > 1e-3));
}

/// The fused host material MLP (no biases) against burn's graph, including the gradient with
/// respect to its input (the hash-grid encoding).
#[test]
fn host_material_mlp_matches_burn_with_input_gradient() {
    use super::fields::Mlp;
    let ad = dev().autodiff();
    let mlp = Mlp::tcnn(&[32, 64, 64, 5], 9, &ad);
    let n = 777;
    let x = uniform(32 * n, -0.5, 0.5, 3);
    let g = uniform(5 * n, -1.0, 1.0, 4);
    let xt = t2(&x, [n, 32], &ad).require_grad();
    let out = mlp.forward(xt.clone());
    let grads = (out.clone() * t2(&g, [n, 5], &ad)).sum().backward();
    let layers: Vec<&burn::nn::Linear> = mlp.layers.iter().collect();
    let want = burn_layer_grads(&layers, &grads);
    let want_dx = to_vec(xt.grad(&grads).unwrap());

    let host = mlp.to_host();
    let (hout, tape) = host.forward(&x);
    let e = max_rel(&hout, &to_vec(out));
    assert!(e < 1e-5, "output differs by {e}");
    let (got, dx) = host.backward(&x, &tape, &g, true);
    for (k, (w, _)) in want.iter().enumerate() {
        let e = max_rel(&got.weight[k], w);
        assert!(e < 1e-4, "layer {k}: weight gradient differs by {e}");
        assert!(got.bias[k].is_none());
    }
    let e = max_rel(&dx.unwrap(), &want_dx);
    assert!(e < 1e-4, "input gradient differs by {e}");
}

/// The LDR data term (`loss::clip_to`): a clipped channel whose render is above its clip level
/// costs nothing and gets no gradient; below it, it costs and pulls exactly as an unclipped
/// channel would; unclipped channels (cap `CAP_NONE`) are untouched. Checked against central
/// finite differences of the loss.
#[test]
fn clipped_channels_pull_up_only() {
    use super::step::CAP_NONE;
    let ad = dev().autodiff();
    // Pixel 0: clipped at 2.0 on R (render 3.0, above) and G (render 1.2, below); B unclipped.
    let c = [3.0f32, 1.2, 0.4];
    let gt = [2.0f32, 2.0, 0.3];
    let cap = [2.0f32, 2.0, CAP_NONE];
    let loss_of = |c: &[f32]| -> f32 {
        let l = loss::color_loss(
            loss::clip_to(t2(c, [1, 3], &dev()), t2(&cap, [1, 3], &dev())),
            t2(&gt, [1, 3], &dev()),
        );
        l.into_data().try_to_vec::<f32>().unwrap()[0]
    };
    let ct = t2(&c, [1, 3], &ad).require_grad();
    let l = loss::color_loss(
        loss::clip_to(ct.clone(), t2(&cap, [1, 3], &ad)),
        t2(&gt, [1, 3], &ad),
    );
    let grads = l.backward();
    let g = to_vec(ct.grad(&grads).unwrap());
    assert_eq!(
        g[0], 0.0,
        "a clipped channel above its level gets no gradient"
    );
    assert!(
        g[1] < 0.0,
        "a clipped channel below its level is pulled up: {}",
        g[1]
    );
    for k in 0..3 {
        let h = 1e-3;
        let (mut up, mut dn) = (c, c);
        up[k] += h;
        dn[k] -= h;
        let fd = (loss_of(&up) - loss_of(&dn)) / (2.0 * h);
        assert!(
            (fd - g[k]).abs() < 1e-3 + 1e-2 * fd.abs(),
            "channel {k}: {} against {fd}",
            g[k]
        );
    }
    // Without the cap, the same render costs more: the R channel is pulled down towards 2.
    let plain = loss::color_loss(t2(&c, [1, 3], &dev()), t2(&gt, [1, 3], &dev()));
    assert!(plain.into_data().try_to_vec::<f32>().unwrap()[0] > loss_of(&c));
}

/// Eq. 17's m term weighted per segment (`Trainer::metallic_scales`): the diffuse part is
/// λ_d · (mean |σ − σ₀| + mean s_k·m), each pixel's s_k from the map or, for a segment absent
/// from it, `cfg.metallic_scale`. A batch drawn from a `DeviceStore` (the labels read from its
/// host batch) gives the same part.
#[test]
fn metallic_scales_weigh_the_m_term_per_segment() {
    use super::step::{Batch, DeviceStore, SegMode, StepInput, TrainConfig, Trainer};
    use super::{HashGridConfig, MaterialFieldConfig};
    use crate::scene::SceneBox;
    let unit = SceneBox { min: 0.0, max: 1.0 };
    let cfg = |device_grid: bool| {
        let grid = HashGridConfig::new().with_levels(4).with_log2_table(10);
        TrainConfig::new()
            .with_material(MaterialFieldConfig::new().with_grid(grid))
            .with_device_grid(device_grid)
            .with_lambda_d(1e-2)
            .with_metallic_scale(5.0)
    };
    let batch = Batch::synthetic(512, 9);
    let n = batch.len() as f64;
    // Segments 0, 2 and 7: 0 spared (s = 1), 7 priced out (s = 20), 2 keeps s = 5.
    let spared: std::collections::HashMap<i32, f32> = [(0, 1.0), (7, 20.0)].into();
    let s_of = |k: i32| spared.get(&k).copied().unwrap_or(5.0) as f64;
    for k in [0, 2, 7] {
        assert!(batch.seg.contains(&k), "segment {k} in the batch");
    }
    let mut tr = Trainer::new(cfg(false), unit, &dev(), 3);
    let mat = tr.model.material(&batch.x_unit, &[]);
    let sigma_term = mat
        .sigma
        .iter()
        .map(|&s| (s as f64 - tr.cfg.prior_sigma as f64).abs())
        .sum::<f64>()
        / n;
    let m_term = |s: &dyn Fn(i32) -> f64| {
        batch
            .seg
            .iter()
            .zip(&mat.metallic)
            .map(|(&k, &m)| s(k) * m as f64)
            .sum::<f64>()
            / n
    };
    let want = |s: &dyn Fn(i32) -> f64| 1e-2 * (sigma_term + m_term(s));
    let uniform_part = tr.gradients(&batch, SegMode::None).parts.diffuse as f64;
    let w = want(&|_| 5.0);
    assert!((uniform_part - w).abs() < 1e-5 * w, "{uniform_part} vs {w}");
    tr.metallic_scales = spared.clone();
    let per_segment = tr.gradients(&batch, SegMode::None).parts.diffuse as f64;
    let w = want(&|k| s_of(k));
    assert!((per_segment - w).abs() < 1e-5 * w, "{per_segment} vs {w}");
    // The weights change the part by more than its rounding.
    assert!((per_segment - uniform_part).abs() > 1e-3 * w);

    let mut dt = Trainer::new(cfg(true), unit, &dev(), 3);
    dt.model.grid.table.clone_from(&tr.model.grid.table);
    dt.model.upload_table();
    dt.metallic_scales = spared;
    let store = DeviceStore::upload(&batch, &dt.device);
    let idx: Vec<u32> = (0..batch.len() as u32).collect();
    let input = StepInput::Device {
        store: &store,
        idx: &idx,
        host: Some(&batch),
    };
    let on_device = dt.step_on(input, SegMode::None).read().diffuse as f64;
    assert!(
        (on_device - per_segment).abs() < 1e-5 * w,
        "{on_device} vs {per_segment}"
    );
}
