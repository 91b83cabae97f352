//! Recovery: from shadings and radiance synthesised with a known spatially varying BRDF field
//! (textured base colour, parts with distinct roughness/metallic, one emitter), stage-2 training
//! recovers k_d, σ and the emitter.

use burn::tensor::{Device, Tensor, TensorData};
use fipt_core::model::brdf::reflectances;
use fipt_core::model::render::{Shadings, render};
use fipt_core::model::step::SegMode;
use fipt_core::model::{Batch, HashGridConfig, MaterialFieldConfig, TrainConfig, Trainer};
use fipt_core::rng::Rng;
use fipt_core::scene::SceneBox;
use fipt_core::shading::ShadingLayout;

/// Scene extent in world units; positions in the unit cube are scaled by it.
const EXTENT: f32 = 4.0;
const EMIT: f32 = 20.0;

fn part(x: [f32; 3]) -> usize {
    (x[0] > 0.5) as usize + 2 * (x[1] > 0.5) as usize
}

fn emitter(x: [f32; 3]) -> bool {
    (0.7..0.9).contains(&x[0]) && (0.7..0.9).contains(&x[1]) && (0.1..0.3).contains(&x[2])
}

/// Parts and the emitter are separate objects, as in a real scene: no surface points lie
/// within `GAP` of a part boundary or of the emitter's outside.
const GAP: f32 = 0.06;

fn on_some_object(x: [f32; 3]) -> bool {
    let near_plane = (x[0] - 0.5).abs() < GAP || (x[1] - 0.5).abs() < GAP;
    let near_emitter = !emitter(x)
        && (0.7 - GAP..0.9 + GAP).contains(&x[0])
        && (0.7 - GAP..0.9 + GAP).contains(&x[1])
        && (0.1 - GAP..0.3 + GAP).contains(&x[2]);
    !near_plane && !near_emitter
}

/// Ground truth: (a, σ, m).
fn truth(x: [f32; 3]) -> ([f32; 3], f32, f32) {
    let a = [
        0.5 + 0.35 * (6.0 * x[0] + 1.0).sin(),
        0.5 + 0.3 * (5.0 * x[1]).cos(),
        0.45 + 0.3 * (4.0 * x[2] + x[0]).sin(),
    ];
    let (s, m) = [(0.9, 0.0), (0.3, 0.0), (0.6, 1.0), (0.15, 0.0)][part(x)];
    (a, s, m)
}

fn dataset(n: usize, seed: u64) -> Batch {
    let mut r = Rng::new(seed, 0);
    let mut x_unit: Vec<[f32; 3]> = Vec::with_capacity(n);
    while x_unit.len() < n {
        let x = [r.next_f32(), r.next_f32(), r.next_f32()];
        if on_some_object(x) {
            x_unit.push(x);
        }
    }
    // Per-pixel shadings: positive, varying with the roughness level at a per-pixel rate.
    let mut shadings = Vec::with_capacity(n * ShadingLayout::DIM);
    for _ in 0..n {
        let ld = [0.2 + r.next_f32(), 0.2 + r.next_f32(), 0.2 + r.next_f32()];
        shadings.extend(ld);
        let (b0, k0) = (0.3 + 1.5 * r.next_f32(), 0.2 + 0.6 * r.next_f32());
        let (b1, k1) = (0.2 + 1.0 * r.next_f32(), 0.3 + 0.7 * r.next_f32());
        for (b, k) in [(b0, k0), (b1, k1)] {
            for j in 0..6 {
                let v = b * (-k * j as f32).exp();
                shadings.extend([v, v * (0.8 + 0.4 * r.next_f32()), v]);
            }
        }
    }
    // Radiance from the factorised render with the true material.
    let dev = Device::flex();
    let (a, s, m): (Vec<f32>, Vec<f32>, Vec<f32>) =
        x_unit.iter().fold((vec![], vec![], vec![]), |mut acc, x| {
            let (a, s, m) = truth(*x);
            acc.0.extend(a);
            acc.1.push(s);
            acc.2.push(m);
            acc
        });
    let t = |v: Vec<f32>, c: usize| Tensor::<2>::from_data(TensorData::new(v, [n, c]), &dev);
    let (kd, ks) = reflectances(t(a, 3), t(m, 1));
    let sh = Shadings::from_packed(t(shadings.clone(), ShadingLayout::DIM));
    let (pred, _) = render(kd, ks, t(s, 1), &sh);
    let mut gt: Vec<f32> = pred.try_into_vec_as::<f32>().unwrap();
    for (i, x) in x_unit.iter().enumerate() {
        if emitter(*x) {
            gt[3 * i..3 * i + 3].fill(EMIT);
        }
    }
    Batch {
        x_world: x_unit
            .iter()
            .map(|x| [x[0] * EXTENT, x[1] * EXTENT, x[2] * EXTENT])
            .collect(),
        seg: x_unit
            .iter()
            .map(|x| if emitter(*x) { 4 } else { part(*x) as i32 })
            .collect(),
        x_unit,
        shadings,
        gt,
    }
}

fn subset(b: &Batch, idx: &[usize]) -> Batch {
    Batch {
        x_unit: idx.iter().map(|&i| b.x_unit[i]).collect(),
        x_world: idx.iter().map(|&i| b.x_world[i]).collect(),
        shadings: idx
            .iter()
            .flat_map(|&i| {
                b.shadings[i * ShadingLayout::DIM..(i + 1) * ShadingLayout::DIM].to_vec()
            })
            .collect(),
        gt: idx
            .iter()
            .flat_map(|&i| b.gt[3 * i..3 * i + 3].to_vec())
            .collect(),
        seg: idx.iter().map(|&i| b.seg[i]).collect(),
    }
}

fn psnr(mse: f64) -> f64 {
    -10.0 * mse.log10()
}

#[test]
fn stage2_recovers_known_brdf_and_emitter() {
    let data = dataset(150_000, 1);
    // A grid as coarse as the ground truth is smooth: each finest cell holds several pixels, as
    // real multi-view data does, so per-pixel ambiguities (k_d vs σ) cannot be fit as noise.
    let cfg = TrainConfig::new().with_lr(1e-2).with_material(
        MaterialFieldConfig::new().with_grid(
            HashGridConfig::new()
                .with_levels(8)
                .with_log2_table(17)
                .with_base_resolution(4.0)
                .with_per_level_scale(1.5),
        ),
    );
    let mut tr = Trainer::new(
        cfg,
        SceneBox {
            min: 0.0,
            max: EXTENT,
        },
        &Device::flex(),
        5,
    );
    let mut rng = Rng::new(6, 0);
    let batch = 4096;
    let epochs = 30;
    let mut order: Vec<usize> = (0..data.len()).collect();
    for e in 0..epochs {
        // Exponential decay 1e-2 → 1e-4 over the run.
        tr.cfg.lr = 1e-2 * 0.01f64.powf(e as f64 / (epochs - 1) as f64);
        rng.shuffle(&mut order);
        for chunk in order.chunks(batch) {
            tr.step(&subset(&data, chunk), SegMode::Part);
        }
    }
    // Held-out points.
    let test = dataset(20_000, 2);
    let mat = tr.model.material(&test.x_unit);
    let (mut kd_se, mut s_se, mut n) = (0.0f64, 0.0f64, 0usize);
    for (i, x) in test.x_unit.iter().enumerate() {
        if emitter(*x) {
            continue;
        }
        let (a, s, m) = truth(*x);
        for (c, ac) in a.iter().enumerate() {
            let kd_est = mat.a[3 * i + c] * (1.0 - mat.metallic[i]);
            kd_se += ((ac * (1.0 - m) - kd_est) as f64).powi(2);
        }
        s_se += ((s - mat.sigma[i]) as f64).powi(2);
        n += 1;
    }
    let kd_psnr = psnr(kd_se / (3 * n) as f64);
    let s_psnr = psnr(s_se / n as f64);
    let alpha = tr.model.alpha(&test.x_world);
    let iou = |threshold: f32| {
        let (mut inter, mut uni) = (0, 0);
        for (x, a) in test.x_unit.iter().zip(&alpha) {
            let (t, e) = (emitter(*x), *a > threshold);
            inter += (t && e) as usize;
            uni += (t || e) as usize;
        }
        inter as f64 / uni as f64
    };
    // The mask itself is scored at α > 0.5. At FIPT's extraction threshold (α > 0.01) faint
    // positional-encoding ghosts (α ≈ 0.01–0.15 at shifted copies of the box) also count; it is
    // reported, and extraction averages α over whole triangles.
    let (iou_half, iou_extract) = (iou(0.5), iou(0.01));
    eprintln!(
        "recovery: k_d {kd_psnr:.2} dB, σ {s_psnr:.2} dB, emitter IoU {iou_half:.3} (α > 0.01: {iou_extract:.3}), {} steps",
        tr.steps
    );
    let iou = iou_half;
    assert!(kd_psnr >= 35.0, "k_d PSNR {kd_psnr:.2}");
    assert!(s_psnr >= 25.0, "σ PSNR {s_psnr:.2}");
    assert!(iou >= 0.95, "emitter IoU {iou:.3}");
}
