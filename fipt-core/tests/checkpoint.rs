//! A fit saved between two steps and restored continues exactly: the same losses and the same
//! parameters (networks and table) as the fit that was never interrupted; a damaged checkpoint
//! is refused with a message naming the file.

use burn::tensor::Device;
use fipt_core::model::step::SegMode;
mod common;
use common::batch;
use fipt_core::model::{Batch, HashGridConfig, MaterialFieldConfig, TrainConfig, Trainer};
use fipt_core::scene::SceneBox;
use std::path::PathBuf;

const UNIT: SceneBox = SceneBox { min: 0.0, max: 1.0 };

fn config() -> TrainConfig {
    let grid = HashGridConfig::new().with_levels(8).with_log2_table(12);
    TrainConfig::new()
        .with_material(MaterialFieldConfig::new().with_grid(grid))
        .with_sem_partners(16)
        .with_lr(1e-2)
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("fipt-ckpt-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

fn params(t: &Trainer) -> (Vec<Vec<f32>>, Vec<f32>) {
    (t.net_params(), t.table())
}

#[test]
fn restored_fit_continues_bit_identically() {
    restore_and_continue(false);
}

/// The same with the table resident on the device: its burn record (parameter ids included)
/// and burn's Adam state of it are saved and restored.
#[test]
fn restored_device_grid_fit_continues_bit_identically() {
    restore_and_continue(true);
}

fn restore_and_continue(device_grid: bool) {
    let config = || config().with_device_grid(device_grid);
    let dev = Device::flex();
    let batches: Vec<Batch> = (0..6).map(|s| batch(256, 40 + s)).collect();
    let mut whole = Trainer::new(config(), UNIT, &dev, 5);
    let losses: Vec<f32> = batches
        .iter()
        .map(|b| whole.step(b, SegMode::Semantic).total)
        .collect();

    let mut first = Trainer::new(config(), UNIT, &dev, 5);
    for b in &batches[..3] {
        first.step(b, SegMode::Semantic);
    }
    let dir = tmp(if device_grid { "ok-dev" } else { "ok" });
    first.save_state(&dir).unwrap();
    drop(first);
    let mut resumed = Trainer::restore(config(), &dev, 5, &dir).unwrap();
    assert_eq!(resumed.steps, 3);
    for (k, b) in batches[3..].iter().enumerate() {
        let l = resumed.step(b, SegMode::Semantic).total;
        assert_eq!(l, losses[3 + k], "loss of step {}", 3 + k);
    }
    let (nets_a, table_a) = params(&whole);
    let (nets_b, table_b) = params(&resumed);
    assert_eq!(nets_a, nets_b, "network parameters after 6 steps");
    assert_eq!(table_a, table_b, "hash table after 6 steps");
    // Without the optimiser state the continuation differs: the test can tell.
    let mut fresh_optim = Trainer::new(config(), UNIT, &dev, 5);
    fresh_optim.model = Trainer::restore(config(), &dev, 5, &dir).unwrap().model;
    for b in &batches[3..] {
        fresh_optim.step(b, SegMode::Semantic);
    }
    assert_ne!(params(&fresh_optim).1, table_a);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn damaged_checkpoints_are_refused_by_name() {
    let dev = Device::flex();
    let mut t = Trainer::new(config(), UNIT, &dev, 1);
    t.step(&batch(64, 1), SegMode::Part);
    let cases: [(&str, &str, &str); 4] = [
        ("table_adam.bin", "truncate", "table_adam.bin"),
        ("table_adam.bin", "garbage", "table_adam.bin"),
        ("optim.bpk", "remove", "optim.bpk"),
        ("trainer.json", "garbage", "trainer.json"),
    ];
    for (file, how, needle) in cases {
        let dir = tmp(&format!("bad-{how}-{}", file.replace('.', "_")));
        t.save_state(&dir).unwrap();
        let p = dir.join(file);
        match how {
            "truncate" => {
                let b = std::fs::read(&p).unwrap();
                std::fs::write(&p, &b[..b.len() - 7]).unwrap();
            }
            "garbage" => std::fs::write(&p, b"{not json at all").unwrap(),
            _ => std::fs::remove_file(&p).unwrap(),
        }
        let err = Trainer::restore(config(), &dev, 1, &dir)
            .err()
            .unwrap_or_else(|| panic!("{file} {how}: accepted"));
        assert!(err.contains(needle), "{file} {how}: {err}");
        std::fs::remove_dir_all(&dir).ok();
    }
    // A config with another network shape is refused.
    let dir = tmp("shape");
    t.save_state(&dir).unwrap();
    let other = config().with_material(
        MaterialFieldConfig::new()
            .with_grid(HashGridConfig::new().with_levels(4).with_log2_table(12)),
    );
    let err = Trainer::restore(other, &dev, 1, &dir)
        .err()
        .expect("refused");
    assert!(err.contains("model.json"), "{err}");
    std::fs::remove_dir_all(&dir).ok();
}
