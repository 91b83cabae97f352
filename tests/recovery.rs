//! Recovery: from shadings and radiance synthesised with a known spatially varying BRDF field
//! (textured base colour, parts with distinct roughness and metallic, one emitter), the fit that
//! `run` ships (`pipeline::fit::fit` with `configs/fast.json`'s model, learning rate, batch and
//! step count) recovers k_d, σ, m and the emitter mask.

use burn::tensor::{Device, Tensor, TensorData};
use fipt_core::model::brdf::reflectances;
use fipt_core::model::render::{Shadings, render};
use fipt_core::model::step::SegMode;
use fipt_core::model::{Batch, FiptModel, PartMap};
use fipt_core::rng::Rng;
use fipt_core::scene::SceneBox;
use fipt_core::shading::ShadingLayout;
use fipt_train::config::Config;
use fipt_train::pipeline::fit::{FitPlan, fit};
use fipt_train::pipeline::pixels::{PixelStore, part_map};

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
    let shadings = shadings(n, &mut r);
    let (a, s, m): (Vec<f32>, Vec<f32>, Vec<f32>) =
        x_unit.iter().fold((vec![], vec![], vec![]), |mut acc, x| {
            let (a, s, m) = truth(*x);
            acc.0.extend(a);
            acc.1.push(s);
            acc.2.push(m);
            acc
        });
    let mut gt = radiance(&shadings, a, s, m);
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
        cap: Vec::new(),
        part: Vec::new(),
        x_unit,
        shadings,
        gt,
    }
}

/// Per-pixel shadings of `n` pixels: positive, varying with the roughness level at a per-pixel
/// rate.
fn shadings(n: usize, r: &mut Rng) -> Vec<f32> {
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
    shadings
}

/// The factorised render of base colours `a` (3 per pixel), roughness `s` and metallic `m`
/// under `shadings`: 3 values per pixel.
fn radiance(shadings: &[f32], a: Vec<f32>, s: Vec<f32>, m: Vec<f32>) -> Vec<f32> {
    let n = s.len();
    let dev = Device::flex();
    let t = |v: Vec<f32>, c: usize| Tensor::<2>::from_data(TensorData::new(v, [n, c]), &dev);
    let (kd, ks) = reflectances(t(a, 3), t(m, 1));
    let sh = Shadings::from_packed(t(shadings.to_vec(), ShadingLayout::DIM));
    let (pred, _) = render(kd, ks, t(s, 1), &sh);
    pred.try_into_vec_as::<f32>().unwrap()
}

fn psnr(mse: f64) -> f64 {
    -10.0 * mse.log10()
}

/// The held-out scores of a fitted model.
struct Scores {
    kd_psnr: f64,
    sigma_psnr: f64,
    /// Mean |m − m_true| on the metal part and on the dielectric parts.
    m_err_metal: f64,
    m_err_dielectric: f64,
    /// Emitter IoU at the extraction threshold α > 0.01 and at α > 0.5.
    iou_extract: f64,
    iou_half: f64,
}

fn score(
    model: &fipt_core::model::FiptModel,
    test: &Batch,
    kd_of: impl Fn(&[f32; 3], f32) -> [f32; 3],
) -> Scores {
    let mat = model.material(&test.x_unit, &test.part);
    let (mut kd_se, mut s_se, mut n) = (0.0f64, 0.0f64, 0usize);
    let (mut m_metal, mut n_metal, mut m_diel, mut n_diel) = (0.0f64, 0usize, 0.0f64, 0usize);
    for (i, x) in test.x_unit.iter().enumerate() {
        if emitter(*x) {
            continue;
        }
        let (a, s, m) = truth(*x);
        let a_est = [mat.a[3 * i], mat.a[3 * i + 1], mat.a[3 * i + 2]];
        let kd_est = kd_of(&a_est, mat.metallic[i]);
        for c in 0..3 {
            kd_se += ((a[c] * (1.0 - m) - kd_est[c]) as f64).powi(2);
        }
        s_se += ((s - mat.sigma[i]) as f64).powi(2);
        let e = (mat.metallic[i] - m).abs() as f64;
        if m > 0.5 {
            m_metal += e;
            n_metal += 1;
        } else {
            m_diel += e;
            n_diel += 1;
        }
        n += 1;
    }
    let alpha = model.alpha(&test.x_world);
    let iou = |threshold: f32| {
        let (mut inter, mut uni) = (0, 0);
        for (x, a) in test.x_unit.iter().zip(&alpha) {
            let (t, e) = (emitter(*x), *a > threshold);
            inter += (t && e) as usize;
            uni += (t || e) as usize;
        }
        inter as f64 / uni as f64
    };
    Scores {
        kd_psnr: psnr(kd_se / (3 * n) as f64),
        sigma_psnr: psnr(s_se / n as f64),
        m_err_metal: m_metal / n_metal as f64,
        m_err_dielectric: m_diel / n_diel as f64,
        iou_extract: iou(0.01),
        iou_half: iou(0.5),
    }
}

#[test]
fn shipped_fit_recovers_known_brdf_and_emitter() {
    let cfg = Config::load(&root().join("configs/fast.json")).unwrap();
    let t = &cfg.train;
    // As many points as fipt-room has training pixels, so one epoch is as many steps as `run`
    // takes with this config.
    let data = dataset(900_000, 1);
    let store = PixelStore {
        origin: (0..data.len() as u32).map(|i| (0, i)).collect(),
        tri: vec![0; data.len()],
        pixels: data,
    };
    let plan = FitPlan {
        cfg: t.model_config(t.grid.levels, cfg.backend),
        scene_box: SceneBox {
            min: 0.0,
            max: EXTENT,
        },
        parts: PartMap::default(),
        mode: SegMode::Part,
        schedule: t.clone(),
        seed: cfg.seed,
    };
    let (tr, _) = fit(&store, plan, &Device::flex(), false);
    let test = dataset(20_000, 2);
    let s = score(&tr.model, &test, |a, m| a.map(|c| c * (1.0 - m)));
    // Scale: the best constant k_d (the mean) and σ (the area mean of the parts).
    let c = score_constant(&test);
    eprintln!(
        "recovery ({} steps): k_d {:.2} dB (constant {:.2}), σ {:.2} dB (constant {:.2}), |m err| metal {:.3} dielectric {:.3}, emitter IoU α>0.01 {:.3}, α>0.5 {:.3}",
        tr.steps,
        s.kd_psnr,
        c.0,
        s.sigma_psnr,
        c.1,
        s.m_err_metal,
        s.m_err_dielectric,
        s.iou_extract,
        s.iou_half
    );
    // Measured: k_d 40.32 dB (constant 10.84), σ 33.34 (10.87), |m err| 0.003 / 0.001, IoU
    // 0.995 / 1.000 after the 600 steps the fast config ships (`train.min_steps`, the learning
    // rate decayed from 1e-2 to 1e-3, a quarter of each batch segment-balanced). The reference's
    // schedule at this size (220 steps at 1e-3) reached 15.19 / 13.97 dB and 0.091 / 0.132.
    assert!(s.kd_psnr >= c.0 + 20.0, "k_d PSNR {:.2}", s.kd_psnr);
    assert!(s.sigma_psnr >= c.1 + 15.0, "σ PSNR {:.2}", s.sigma_psnr);
    // A constant m = 0.5 errs by 0.5 everywhere; m = 0 errs by 1 on the metal.
    assert!(
        s.m_err_metal <= 0.05,
        "metal part m error {:.3}",
        s.m_err_metal
    );
    assert!(
        s.m_err_dielectric <= 0.05,
        "dielectric m error {:.3}",
        s.m_err_dielectric
    );
    assert!(
        s.iou_extract >= 0.95,
        "emitter IoU at α > 0.01: {:.3}",
        s.iou_extract
    );
    assert!(
        s.iou_half >= 0.95,
        "emitter IoU at α > 0.5: {:.3}",
        s.iou_half
    );
}

/// Two parts on the same points: a rough dielectric everywhere (triangle 0, label 3), and in
/// the box x < 0.4 also a glossy metal (triangle 1, label 8) whose pixels share the
/// dielectric's positions, as a thin table leg shares the floor's hash cells. The field alone
/// can only give both one material there; with `train.part_offsets` the metal's offset row
/// separates them. Returns the pixels and each one's triangle (1: the metal).
fn shared_points(n: usize, seed: u64) -> (Batch, Vec<u32>) {
    const DIELECTRIC: (f32, f32) = (0.8, 0.0);
    const METAL: (f32, f32) = (0.2, 1.0);
    let mut r = Rng::new(seed, 7);
    let mut x_unit = Vec::with_capacity(n);
    let mut tri = Vec::with_capacity(n);
    while x_unit.len() < n {
        let x = [r.next_f32(), r.next_f32(), r.next_f32()];
        let metal = x[0] < 0.4 && r.next_f32() < 0.5;
        x_unit.push(x);
        tri.push(metal as u32);
    }
    let shadings = shadings(n, &mut r);
    let a: Vec<f32> = x_unit
        .iter()
        .flat_map(|x| [0.3 + 0.4 * x[1], 0.5, 0.7 - 0.3 * x[2]])
        .collect();
    let (s, m): (Vec<f32>, Vec<f32>) = tri
        .iter()
        .map(|&t| if t == 1 { METAL } else { DIELECTRIC })
        .unzip();
    let gt = radiance(&shadings, a, s, m);
    let batch = Batch {
        x_world: x_unit
            .iter()
            .map(|x| [x[0] * EXTENT, x[1] * EXTENT, x[2] * EXTENT])
            .collect(),
        seg: tri.iter().map(|&t| if t == 1 { 8 } else { 3 }).collect(),
        cap: Vec::new(),
        part: Vec::new(),
        x_unit,
        shadings,
        gt,
    };
    (batch, tri)
}

/// The metal's mean |σ − 0.2| and mean m on held-out points of `shared_points`.
fn metal_error(model: &FiptModel, test: &Batch, tri: &[u32]) -> (f64, f64) {
    let rows = model.part_rows(tri);
    let mat = model.material(&test.x_unit, &rows);
    let metal: Vec<usize> = (0..tri.len()).filter(|&i| tri[i] == 1).collect();
    let n = metal.len() as f64;
    let s = metal
        .iter()
        .map(|&i| (mat.sigma[i] - 0.2).abs() as f64)
        .sum::<f64>()
        / n;
    let m = metal.iter().map(|&i| mat.metallic[i] as f64).sum::<f64>() / n;
    (s, m)
}

/// `train.part_offsets`: a metal that shares every point with a dielectric is recovered with
/// the offsets (σ within 0.05, m ≥ 0.8) and not without them (the field's one material there
/// is neither), through the pipeline's store, map and fit (the fused host step).
#[test]
fn part_offsets_separate_parts_that_share_their_points() {
    let cfg = Config::load(&root().join("configs/fast.json")).unwrap();
    let mut t = cfg.train.clone();
    t.min_steps = 300;
    let (data, tri) = shared_points(60_000, 1);
    let (test, test_tri) = shared_points(10_000, 2);
    let fit_with = |on: bool| {
        let mut store = PixelStore {
            origin: (0..data.len() as u32).map(|i| (0, i)).collect(),
            tri: tri.clone(),
            pixels: data.clone(),
        };
        let parts = part_map(&store, 2, on, SegMode::Part);
        store.set_parts(&parts);
        let plan = FitPlan {
            cfg: t.model_config(t.grid.levels, cfg.backend),
            scene_box: SceneBox {
                min: 0.0,
                max: EXTENT,
            },
            parts,
            mode: SegMode::Part,
            schedule: t.clone(),
            seed: cfg.seed,
        };
        let (tr, _) = fit(&store, plan, &Device::flex(), false);
        metal_error(&tr.model, &test, &test_tri)
    };
    let (with, without) = (fit_with(true), fit_with(false));
    eprintln!(
        "shared points: metal |σ err| {:.3}, m {:.3} with part offsets; {:.3}, {:.3} without",
        with.0, with.1, without.0, without.1
    );
    assert!(with.0 <= 0.05 && with.1 >= 0.8, "with offsets: {with:?}");
    assert!(without.0 > 0.15 || without.1 < 0.6, "without: {without:?}");
}

/// PSNRs of the best constant k_d (per channel) and σ on the held-out points.
fn score_constant(test: &Batch) -> (f64, f64) {
    let pts: Vec<_> = test
        .x_unit
        .iter()
        .filter(|x| !emitter(**x))
        .map(|x| truth(*x))
        .collect();
    let n = pts.len() as f64;
    let kd_mean: Vec<f64> = (0..3)
        .map(|c| {
            pts.iter()
                .map(|(a, _, m)| (a[c] * (1.0 - m)) as f64)
                .sum::<f64>()
                / n
        })
        .collect();
    let s_mean = pts.iter().map(|(_, s, _)| *s as f64).sum::<f64>() / n;
    let kd_se: f64 = pts
        .iter()
        .map(|(a, _, m)| {
            (0..3)
                .map(|c| ((a[c] * (1.0 - m)) as f64 - kd_mean[c]).powi(2))
                .sum::<f64>()
        })
        .sum();
    let s_se: f64 = pts
        .iter()
        .map(|(_, s, _)| (*s as f64 - s_mean).powi(2))
        .sum();
    (psnr(kd_se / (3.0 * n)), psnr(s_se / n))
}

fn root() -> std::path::PathBuf {
    std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}
