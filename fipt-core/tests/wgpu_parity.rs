//! wgpu parity: the same forward pass, gradients and one Adam step on wgpu as on the CPU backend
//! (flex), within 1e-4 relative; and the tensor-op hash grid with more than 600k gathered
//! indices, the size at which Mesa's lavapipe silently drops `select`/`select_assign` work
//! unless index ops are chunked to 65,535.
//!
//! Built and run only with `--features wgpu` (see README: CI installs `mesa-vulkan-drivers`).

use burn::tensor::{Device, Tensor, TensorData};
use fipt_core::model::backend::BackendKind;
use fipt_core::model::hashgrid::TableGrad;
use fipt_core::model::hashgrid_tensor::{encode_tensor, table_tensor};
use fipt_core::model::step::SegMode;
use fipt_core::scene::SceneBox;

/// Positions are already in the unit cube.
const UNIT: SceneBox = SceneBox { min: 0.0, max: 1.0 };
mod common;
use common::batch;
use fipt_core::model::{HashGridConfig, MaterialFieldConfig, TrainConfig, Trainer};
use fipt_core::rng::Rng;

const TOL: f32 = 1e-4;

fn wgpu() -> Device {
    BackendKind::Wgpu.device().expect("wgpu device")
}

/// max |a − b| / max |b|: the error relative to the vector's scale.
fn rel_err(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    let scale = b.iter().fold(0f32, |m, v| m.max(v.abs()));
    let err = a.iter().zip(b).fold(0f32, |m, (x, y)| m.max((x - y).abs()));
    if scale == 0.0 { err } else { err / scale }
}

/// Whether Adam's first update −lr·g/(|g| + ε) of an entry with gradient `g` is fixed to TOL
/// by the gradient's own agreement across backends (|Δg| ≤ TOL·`gmax`, checked before): its
/// slope ε/(|g| + ε)² times that error stays ≤ TOL where (|g| + ε)² ≥ `gmax`·ε. Below that,
/// an entry's update is set by rounding, however the backends sum (flex runs the networks as
/// fused host MLPs, wgpu as burn graph ops). Also |g| above 1e-3·`gmax`.
fn update_is_stable(g: f32, gmax: f32, eps: f32) -> bool {
    g.abs() > 1e-3 * gmax && (g.abs() + eps).powi(2) >= gmax * eps
}

fn assert_close(what: &str, a: &[f32], b: &[f32]) {
    let e = rel_err(a, b);
    assert!(
        e <= TOL,
        "{what}: wgpu vs flex relative error {e:.3e} > {TOL:e}"
    );
}

/// A trained-looking table: outputs vary across pixels, so the L1 terms (|σ − σ̄|, …) are away
/// from their kinks, where sign(0 ± rounding) would differ between backends. Set on `cpu`, copied
/// to `gpu` (and uploaded where its table lives on the device); returns it.
fn trained_looking_table(cpu: &mut Trainer, gpu: &mut Trainer) -> Vec<f32> {
    let mut r = Rng::new(4, 4);
    cpu.model
        .grid
        .table
        .iter_mut()
        .for_each(|v| *v = r.next_f32() - 0.5);
    gpu.model.grid.table.clone_from(&cpu.model.grid.table);
    if gpu.device_resident() {
        gpu.model.upload_table();
    }
    cpu.model.grid.table.clone()
}

fn config() -> TrainConfig {
    let grid = HashGridConfig::new().with_levels(16).with_log2_table(17);
    TrainConfig::new().with_material(MaterialFieldConfig::new().with_grid(grid))
}

/// A batch of 8192 pixels: two parts and a bright emitter, shadings and radiance positive.

#[test]
fn trainer_step_matches_cpu_backend() {
    for mode in [SegMode::Part, SegMode::Semantic] {
        let mut cpu = Trainer::new(config(), UNIT, &Device::flex(), 11);
        let mut gpu = Trainer::new(config(), UNIT, &wgpu(), 11);
        trained_looking_table(&mut cpu, &mut gpu);
        let (p0, g0) = (cpu.net_params(), gpu.net_params());
        assert_eq!(
            p0, g0,
            "a seed must give the same networks on every backend"
        );
        let b = batch(8192, 3);

        // Forward and gradients.
        let gc = cpu.gradients(&b, mode);
        let gg = gpu.gradients(&b, mode);
        let parts = |p: fipt_core::model::step::LossParts| {
            vec![p.total, p.color, p.emission, p.diffuse, p.seg]
        };
        assert_close(
            &format!("{mode:?} loss parts"),
            &parts(gg.parts),
            &parts(gc.parts),
        );
        assert!(
            gc.parts.seg > 0.0,
            "the segmentation loss must be exercised"
        );
        assert_close(
            &format!("{mode:?} d/d encoding"),
            &gg.encoding,
            &gc.encoding,
        );
        assert_eq!(gc.params.len(), gg.params.len());
        for (i, (w, c)) in gg.params.iter().zip(&gc.params).enumerate() {
            assert!(c.iter().any(|v| *v != 0.0), "parameter {i} got no gradient");
            assert_close(&format!("{mode:?} d/d parameter {i}"), w, c);
        }
        // The table gradient follows from the encoding gradient (host op on both).
        let (mut tc, mut tg) = (
            TableGrad::new(&cpu.model.grid),
            TableGrad::new(&gpu.model.grid),
        );
        cpu.model
            .grid
            .backward_table(&b.x_unit, &gc.encoding, &mut tc);
        gpu.model
            .grid
            .backward_table(&b.x_unit, &gg.encoding, &mut tg);
        assert_close(&format!("{mode:?} d/d table"), &tg.values, &tc.values);

        // One Adam step. Its first update is −lr·g/(|g| + ε) per entry, so entries whose
        // gradient is at rounding level (|g| ≪ max|g|) flip freely between backends. Each
        // backend's update must equal that formula on its own gradient, and the updates must
        // agree across backends wherever the gradient is well above rounding.
        cpu.step(&b, mode);
        gpu.step(&b, mode);
        let (p1c, p1g) = (cpu.net_params(), gpu.net_params());
        let (lr, eps) = (config().lr as f32, config().eps);
        for i in 0..p0.len() {
            let delta =
                |p1: &Vec<f32>| -> Vec<f32> { p1.iter().zip(&p0[i]).map(|(a, b)| a - b).collect() };
            let adam = |g: &Vec<f32>| -> Vec<f32> {
                g.iter().map(|g| -lr * g / (g.abs() + eps)).collect()
            };
            let (dc, dw) = (delta(&p1c[i]), delta(&p1g[i]));
            assert_close(
                &format!("{mode:?} flex Adam update of parameter {i}"),
                &dc,
                &adam(&gc.params[i]),
            );
            assert_close(
                &format!("{mode:?} wgpu Adam update of parameter {i}"),
                &dw,
                &adam(&gg.params[i]),
            );
            let gmax = gc.params[i].iter().fold(0f32, |m, v| m.max(v.abs()));
            let keep: Vec<usize> = (0..dc.len())
                .filter(|&j| update_is_stable(gc.params[i][j], gmax, eps))
                .collect();
            let pick = |v: &[f32]| -> Vec<f32> { keep.iter().map(|&j| v[j]).collect() };
            assert!(
                keep.len() * 2 > dc.len(),
                "parameter {i}: most gradients are at rounding level"
            );
            assert_close(
                &format!("{mode:?} Adam update of parameter {i}"),
                &pick(&dw),
                &pick(&dc),
            );
        }
        assert_close(
            &format!("{mode:?} table after Adam"),
            &gpu.model.grid.table,
            &cpu.model.grid.table,
        );
        // And the next forward pass agrees.
        let (lc, lg) = (cpu.gradients(&b, mode).parts, gpu.gradients(&b, mode).parts);
        assert_close(
            &format!("{mode:?} loss after one step"),
            &parts(lg),
            &parts(lc),
        );
    }
}

/// The tensor-op hash grid on wgpu with 8192 × 16 levels × 8 corners = 1,048,576 gathered
/// indices: forward equals the host encoding and burn's autodiff table gradient equals the host
/// backward. Unchunked, lavapipe gathers wrong values at 524k indices and its `select_assign`
/// (select's backward) keeps only the first 65,535 rows.
#[test]
fn tensor_hash_grid_over_600k_indices_matches_host() {
    let mut grid = HashGridConfig::new()
        .with_levels(16)
        .with_log2_table(16)
        .with_base_resolution(8.0)
        .with_per_level_scale(1.5)
        .init(5);
    let mut r = Rng::new(9, 9);
    grid.table.iter_mut().for_each(|v| *v = r.next_f32() - 0.5);
    let xs: Vec<[f32; 3]> = (0..8192)
        .map(|_| [r.next_f32(), r.next_f32(), r.next_f32()])
        .collect();
    assert!(xs.len() * grid.levels.len() * 8 >= 600_000);
    let dev = wgpu().autodiff();
    let table = table_tensor(&grid, &dev).require_grad();
    let enc = encode_tensor(&grid, table.clone(), &xs);
    let host = grid.encode(&xs);
    assert_close(
        "tensor-op encoding on wgpu",
        &enc.clone().try_into_vec_as::<f32>().unwrap(),
        &host,
    );
    let c: Vec<f32> = (0..host.len()).map(|_| r.next_f32() - 0.5).collect();
    let ct = Tensor::<2>::from_data(
        TensorData::new(c.clone(), [xs.len(), grid.output_dim()]),
        &dev,
    );
    let g = (enc * ct).sum().backward();
    let g_dev: Vec<f32> = table.grad(&g).unwrap().try_into_vec_as::<f32>().unwrap();
    let mut tg = TableGrad::new(&grid);
    grid.backward_table(&xs, &c, &mut tg);
    assert_close("tensor-op table gradient on wgpu", &g_dev, &tg.values);
}

/// The training step resident on wgpu (`TrainConfig::device_grid`: table, hashing, gather,
/// autodiff scatter and burn's dense Adam on the device; the pixels in a `DeviceStore`) against
/// the CPU path (flex, fused host op, sparse Adam): the same loss parts and network gradients,
/// the same table gradient over 8192 × 16 levels × 8 corners = 1,048,576 table touches, the
/// same table and networks after one Adam step where the gradient is above rounding; then the
/// model queried on wgpu with its table on the device equals the host query on flex.
#[test]
fn device_resident_step_matches_cpu_path() {
    use fipt_core::model::step::{DeviceStore, StepInput};
    let cfg = |device_grid: bool| config().with_device_grid(device_grid);
    let mut cpu = Trainer::new(cfg(false), UNIT, &Device::flex(), 11);
    let mut gpu = Trainer::new(cfg(true), UNIT, &wgpu(), 11);
    assert!(gpu.device_resident());
    let table0 = trained_looking_table(&mut cpu, &mut gpu);
    assert_eq!(
        gpu.table(),
        table0,
        "the table round-trips through the device"
    );
    let b = batch(8192, 3);
    assert!(b.len() * 16 * 8 >= 600_000);
    let parts =
        |p: fipt_core::model::step::LossParts| vec![p.total, p.color, p.emission, p.diffuse, p.seg];
    for mode in [SegMode::Part, SegMode::Semantic] {
        let (gc, gg) = (cpu.gradients(&b, mode), gpu.gradients(&b, mode));
        assert_close(
            &format!("{mode:?} loss parts"),
            &parts(gg.parts),
            &parts(gc.parts),
        );
        let touched = gc.table.iter().filter(|g| **g != 0.0).count();
        assert!(touched > 100_000, "{touched} table entries with a gradient");
        assert_close(&format!("{mode:?} d/d table"), &gg.table, &gc.table);
        for (i, (w, c)) in gg.params.iter().zip(&gc.params).enumerate() {
            assert_close(&format!("{mode:?} d/d parameter {i}"), w, c);
        }
    }
    // One step: the batch by index from the device store, the loss read afterwards.
    let g = cpu.gradients(&b, SegMode::Part);
    let nets0 = cpu.net_params();
    let store = DeviceStore::upload(&b, &gpu.device);
    let idx: Vec<u32> = (0..b.len() as u32).collect();
    let pending = gpu.step_on(
        StepInput::Device {
            store: &store,
            idx: &idx,
            host: None,
        },
        SegMode::Part,
    );
    let lc = cpu.step(&b, SegMode::Part);
    assert_close("loss of the step", &parts(pending.read()), &parts(lc));
    let (lr, eps) = (config().lr as f32, config().eps);
    let (tc, tg) = (cpu.table(), gpu.table());
    let gmax = g.table.iter().fold(0f32, |m, v| m.max(v.abs()));
    let mut checked = 0;
    for j in 0..table0.len() {
        let gj = g.table[j];
        if gj.abs() > 1e-3 * gmax {
            let want = table0[j] - lr * gj / (gj.abs() + eps);
            assert!((tc[j] - want).abs() <= TOL * lr, "flex entry {j}");
            assert!((tg[j] - want).abs() <= TOL * lr, "wgpu entry {j}");
            checked += 1;
        } else if gj == 0.0 {
            assert_eq!(
                tg[j], table0[j],
                "wgpu moved entry {j}, which has no gradient"
            );
        }
    }
    assert!(checked > 50_000, "{checked} table entries checked");
    // The networks after the step: −lr·g/(|g| + ε) on both where |g| is above rounding.
    for (i, ((pg, pc), p0)) in gpu
        .net_params()
        .iter()
        .zip(cpu.net_params())
        .zip(&nets0)
        .enumerate()
    {
        let gmax = g.params[i].iter().fold(0f32, |m, v| m.max(v.abs()));
        for j in 0..pg.len() {
            let gj = g.params[i][j];
            if update_is_stable(gj, gmax, eps) {
                let want = p0[j] - lr * gj / (gj.abs() + eps);
                assert!((pc[j] - want).abs() <= TOL * lr, "flex parameter {i}[{j}]");
                assert!((pg[j] - want).abs() <= TOL * lr, "wgpu parameter {i}[{j}]");
            }
        }
    }
    // Inference with the table on the device.
    gpu.sync_host_table();
    let xs: Vec<[f32; 3]> = b.x_unit.iter().take(5000).copied().collect();
    let mut host_model = gpu.model.clone();
    host_model.device_grid = None;
    let on_device = gpu.model.material(&xs, &[]);
    let on_host = host_model.material(&xs, &[]);
    assert_close("a queried on the device", &on_device.a, &on_host.a);
    assert_close("σ queried on the device", &on_device.sigma, &on_host.sigma);
    assert_close(
        "m queried on the device",
        &on_device.metallic,
        &on_host.metallic,
    );
}
