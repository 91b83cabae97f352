//! The fields can represent what FIPT needs: the hash-grid field fits a smooth 3-D RGB function,
//! and the emission mask learns a box indicator, within fixed step budgets.

use burn::module::Module;
use burn::optim::{AdamConfig, GradientsParams};
use burn::tensor::activation::sigmoid;
use burn::tensor::{Device, Tensor, TensorData};
use fipt_core::model::fields::{EmissionMaskConfig, Mlp, alpha_from_raw};
use fipt_core::model::hashgrid::{HashGridConfig, TableAdam, TableGrad};
use fipt_core::rng::Rng;

fn target(x: [f32; 3]) -> [f32; 3] {
    use std::f32::consts::TAU;
    [
        0.5 + 0.35 * (TAU * x[0] + 1.0).sin() * (TAU * x[1]).cos(),
        0.5 + 0.3 * (TAU * 1.5 * x[2]).sin() + 0.1 * x[0],
        0.4 + 0.4 * x[1] * x[2] + 0.1 * (TAU * (x[0] + x[2])).cos(),
    ]
}

fn points(n: usize, rng: &mut Rng) -> Vec<[f32; 3]> {
    (0..n)
        .map(|_| [rng.next_f32(), rng.next_f32(), rng.next_f32()])
        .collect()
}

#[test]
fn hash_grid_field_fits_smooth_rgb_function() {
    let dev = Device::flex().autodiff();
    dev.seed(1);
    let mut grid = HashGridConfig::new()
        .with_levels(12)
        .with_log2_table(15)
        .with_base_resolution(4.0)
        .with_per_level_scale(1.45)
        .init(1);
    // The production MLP: bias-free, tiny-cuda-nn init (as `MaterialFieldConfig::init`).
    let mut mlp = Mlp::tcnn(&[grid.output_dim(), 64, 64, 3], 1, &dev);
    let mut optim = AdamConfig::new().with_epsilon(1e-15).init();
    let mut tadam = TableAdam::new(&grid, 0.9, 0.999, 1e-15);
    let mut tgrad = TableGrad::new(&grid);
    let mut rng = Rng::new(2, 0);
    let (steps, batch, lr) = (500, 4096, 1e-2);
    for _ in 0..steps {
        let xs = points(batch, &mut rng);
        let y: Vec<f32> = xs.iter().flat_map(|x| target(*x)).collect();
        let enc = Tensor::<2>::from_data(
            TensorData::new(grid.encode(&xs), [batch, grid.output_dim()]),
            &dev,
        )
        .require_grad();
        let pred = sigmoid(mlp.forward(enc.clone()));
        let loss = (pred - Tensor::<2>::from_data(TensorData::new(y, [batch, 3]), &dev))
            .powi_scalar(2)
            .mean();
        let grads = loss.backward();
        let ge: Vec<f32> = enc.grad(&grads).unwrap().try_into_vec_as::<f32>().unwrap();
        grid.backward_table(&xs, &ge, &mut tgrad);
        tadam.step(&mut grid, &mut tgrad, lr as f32);
        mlp = optim.step(lr, mlp.clone(), GradientsParams::from_grads(grads, &mlp));
    }
    let infer = mlp.valid();
    let plain = dev.clone().inner();
    let test = points(20_000, &mut Rng::new(99, 0));
    let enc = Tensor::<2>::from_data(
        TensorData::new(grid.encode(&test), [test.len(), grid.output_dim()]),
        &plain,
    );
    let pred: Vec<f32> = sigmoid(infer.forward(enc))
        .try_into_vec_as::<f32>()
        .unwrap();
    let mse: f64 = test
        .iter()
        .flat_map(|x| target(*x))
        .zip(&pred)
        .map(|(a, b)| ((a - b) as f64).powi(2))
        .sum::<f64>()
        / pred.len() as f64;
    let psnr = -10.0 * mse.log10();
    eprintln!("hash-grid fit: held-out PSNR {psnr:.2} dB after {steps} steps");
    assert!(psnr >= 35.0, "held-out PSNR {psnr:.2} dB < 35");
}

#[test]
fn emission_mask_learns_a_box() {
    let dev = Device::flex().autodiff();
    dev.seed(3);
    let mut mask = EmissionMaskConfig::new().init(&dev, 3);
    let mut optim = AdamConfig::new().with_epsilon(1e-8).init();
    // A lamp-sized box in a 5 × 2.7 × 4 m room (world coordinates, as FIPT feeds them).
    let (lo, hi) = ([1.5f32, 0.8, 1.0], [2.3f32, 1.4, 1.6]);
    let inside = |p: &[f32; 3]| (0..3).all(|k| p[k] >= lo[k] && p[k] <= hi[k]);
    let room = |rng: &mut Rng| {
        [
            5.0 * rng.next_f32(),
            2.7 * rng.next_f32(),
            4.0 * rng.next_f32(),
        ]
    };
    let mut rng = Rng::new(4, 0);
    let (steps, batch, lr) = (600, 2048, 1e-3);
    for _ in 0..steps {
        // Half the batch near the box so its boundary is well sampled.
        let xs: Vec<[f32; 3]> = (0..batch)
            .map(|i| {
                if i % 2 == 0 {
                    room(&mut rng)
                } else {
                    let c = [1.9, 1.1, 1.3];
                    [
                        c[0] + 1.0 * (rng.next_f32() - 0.5),
                        c[1] + 0.9 * (rng.next_f32() - 0.5),
                        c[2] + 0.9 * (rng.next_f32() - 0.5),
                    ]
                }
            })
            .collect();
        let y: Vec<f32> = xs.iter().map(|p| inside(p) as u8 as f32).collect();
        let x = Tensor::<2>::from_data(
            TensorData::new(xs.iter().flatten().copied().collect::<Vec<_>>(), [batch, 3]),
            &dev,
        );
        let alpha = alpha_from_raw(mask.raw(x));
        let loss = (alpha - Tensor::<2>::from_data(TensorData::new(y, [batch, 1]), &dev))
            .powi_scalar(2)
            .mean();
        let grads = loss.backward();
        mask = optim.step(lr, mask.clone(), GradientsParams::from_grads(grads, &mask));
    }
    let infer = mask.valid();
    let plain = dev.clone().inner();
    let mut r = Rng::new(77, 1);
    let test: Vec<[f32; 3]> = (0..40_000).map(|_| room(&mut r)).collect::<Vec<_>>();
    let test: Vec<[f32; 3]> = test
        .into_iter()
        .chain((0..10_000).map(|_| {
            [
                1.9 + 1.0 * (r.next_f32() - 0.5),
                1.1 + 0.9 * (r.next_f32() - 0.5),
                1.3 + 0.9 * (r.next_f32() - 0.5),
            ]
        }))
        .collect();
    let x = Tensor::<2>::from_data(
        TensorData::new(
            test.iter().flatten().copied().collect::<Vec<_>>(),
            [test.len(), 3],
        ),
        &plain,
    );
    let a: Vec<f32> = alpha_from_raw(infer.raw(x))
        .try_into_vec_as::<f32>()
        .unwrap();
    let (mut inter, mut uni) = (0usize, 0usize);
    for (p, &al) in test.iter().zip(&a) {
        let (t, e) = (inside(p), al > 0.5);
        inter += (t && e) as usize;
        uni += (t || e) as usize;
    }
    let iou = inter as f64 / uni as f64;
    eprintln!("emission mask: IoU {iou:.4} after {steps} steps");
    assert!(iou >= 0.95, "IoU {iou:.4} < 0.95");
}
