//! A fit saved between two steps and restored continues exactly: the same losses and the same
//! parameters (networks and table) as the fit that was never interrupted; a damaged checkpoint
//! is refused with a message naming the file.

use burn::tensor::Device;
use fipt_core::model::step::SegMode;
mod common;
use common::batch;
use fipt_core::model::{
    Batch, HashGridConfig, MaterialFieldConfig, PartColumns, PartMap, TrainConfig, Trainer,
};
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
    restore_and_continue(false, false, PartColumns::All);
}

/// The same with the table resident on the device: its burn record (parameter ids included)
/// and burn's Adam state of it are saved and restored.
#[test]
fn restored_device_grid_fit_continues_bit_identically() {
    restore_and_continue(true, false, PartColumns::All);
}

/// The same with part offsets (`part_offsets`): their table, its Adam state and the triangle
/// map (`parts.bin`) are saved and restored.
#[test]
fn restored_fit_with_part_offsets_continues_bit_identically() {
    restore_and_continue(false, true, PartColumns::All);
}

/// The same with offsets of σ alone: the saved model names its columns (`model.json`), so the
/// restored table has one column a part.
#[test]
fn restored_fit_with_roughness_offsets_continues_bit_identically() {
    restore_and_continue(false, true, PartColumns::Roughness);
}

/// A map of five triangles over two labelled parts, one triangle unlabelled.
fn part_map() -> PartMap {
    PartMap::from_labels(&[4, 9, -1, 9, 4])
}

fn restore_and_continue(device_grid: bool, parts: bool, columns: PartColumns) {
    let config = || {
        config()
            .with_device_grid(device_grid)
            .with_part_columns(columns)
    };
    let dev = Device::flex();
    let map = if parts {
        part_map()
    } else {
        PartMap::default()
    };
    let batches: Vec<Batch> = (0..6)
        .map(|s| {
            let mut b = batch(256, 40 + s);
            if parts {
                let tris: Vec<u32> = (0..b.len() as u32).map(|i| i % 5).collect();
                b.part = map.rows(&tris);
            }
            b
        })
        .collect();
    let fresh = || Trainer::with_parts(config(), UNIT, map.clone(), &dev, 5);
    let mut whole = fresh();
    let losses: Vec<f32> = batches
        .iter()
        .map(|b| whole.step(b, SegMode::Semantic).total)
        .collect();

    let mut first = fresh();
    for b in &batches[..3] {
        first.step(b, SegMode::Semantic);
    }
    let dir = tmp(&format!("ok-{device_grid}-{parts}-{columns:?}"));
    first.save_state(&dir).unwrap();
    drop(first);
    let mut resumed = Trainer::restore(config(), &dev, 5, &dir).unwrap();
    assert_eq!(resumed.steps, 3);
    assert_eq!(resumed.model.part_map, map);
    for (k, b) in batches[3..].iter().enumerate() {
        let l = resumed.step(b, SegMode::Semantic).total;
        assert_eq!(l, losses[3 + k], "loss of step {}", 3 + k);
    }
    let (nets_a, table_a) = params(&whole);
    let (nets_b, table_b) = params(&resumed);
    if parts {
        // The offsets are the last parameters; they moved away from zero.
        let offsets = nets_a.last().unwrap();
        assert_eq!(offsets.len(), map.parts * columns.range().len());
        assert!(
            offsets.iter().any(|&v| v != 0.0),
            "part offsets never trained"
        );
    }
    assert_eq!(nets_a, nets_b, "network parameters after 6 steps");
    assert_eq!(table_a, table_b, "hash table after 6 steps");
    // Without the optimiser state the continuation differs: the test can tell.
    let mut fresh_optim = fresh();
    fresh_optim.model = Trainer::restore(config(), &dev, 5, &dir).unwrap().model;
    for b in &batches[3..] {
        fresh_optim.step(b, SegMode::Semantic);
    }
    assert_ne!(params(&fresh_optim).1, table_a);
    std::fs::remove_dir_all(&dir).ok();
}

/// A part map that names rows past the model's parts, or is cut short, is refused by name.
#[test]
fn damaged_part_maps_are_refused_by_name() {
    let dev = Device::flex();
    let t = Trainer::with_parts(config(), UNIT, part_map(), &dev, 1);
    for (how, bytes) in [("cut", vec![0u8; 7]), ("row", 7u32.to_le_bytes().to_vec())] {
        let dir = tmp(&format!("bad-parts-{how}"));
        t.save_state(&dir).unwrap();
        std::fs::write(dir.join("parts.bin"), bytes).unwrap();
        let err = Trainer::restore(config(), &dev, 1, &dir)
            .err()
            .unwrap_or_else(|| panic!("parts.bin {how}: accepted"));
        assert!(err.contains("parts.bin"), "{how}: {err}");
        std::fs::remove_dir_all(&dir).ok();
    }
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
