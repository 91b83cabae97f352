//! Property tests of the binary and text readers on damaged input (issue "A run survives…"):
//! random truncations, byte flips, and size fields set to huge values. Every reader must
//! return an error (or, for a flip that keeps the data well formed, a value), never panic and
//! never allocate from an unchecked size field. A fixed number of cases per reader keeps CI
//! time bounded.

use fipt_bake::lightfield::LightField;
use fipt_core::model::HashGridConfig;
use fipt_core::model::hashgrid::TableAdam;
use fipt_core::scene::{Image, Mesh, SceneBox};
use glam::Vec3;
use proptest::prelude::*;
use std::path::PathBuf;
use std::sync::OnceLock;

const CASES: u32 = 500;

/// The folder of this run's EXR cases.
fn fuzz_dir() -> PathBuf {
    std::env::temp_dir().join(format!("fipt-fuzz-exr-{}", std::process::id()))
}

/// A valid input, built once per test binary and shared by every case.
fn once(cell: &'static OnceLock<Vec<u8>>, make: fn() -> Vec<u8>) -> &'static [u8] {
    cell.get_or_init(make)
}

fn light_field_bytes() -> Vec<u8> {
    let b = SceneBox { min: 0.0, max: 1.0 };
    let samples = (0..400).map(|i| {
        let t = i as f32 / 400.0;
        (
            Vec3::new(t, 0.5 + 0.3 * (7.0 * t).sin(), 0.25),
            Vec3::Z,
            [t, 1.0 - t, 0.5],
        )
    });
    LightField::build(b, 16, samples).to_bytes()
}

fn adam() -> (TableAdam, Vec<u8>) {
    let grid = HashGridConfig::new()
        .with_levels(4)
        .with_log2_table(8)
        .init(3);
    let a = TableAdam::new(&grid, 0.9, 0.99, 1e-8);
    let bytes = a.to_bytes();
    (a, bytes)
}

fn exr_bytes() -> Vec<u8> {
    let dir = fuzz_dir();
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join("ok.exr");
    let data = (0..8 * 6 * 3).map(|i| i as f32 * 0.01).collect();
    Image::from_data(8, 6, 3, data).write_exr(&p).unwrap();
    std::fs::read(&p).unwrap()
}

const OBJ: &str = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 3 4\nf 2 3 4\n";

/// One kind of damage: cut at a fraction of the length, flip a byte, or write a huge
/// little-endian u32/u64 at an offset.
#[derive(Clone, Debug)]
enum Damage {
    Truncate(f64),
    Flip(f64, u8),
    Huge(f64, bool),
}

fn damage() -> impl Strategy<Value = Damage> {
    prop_oneof![
        (0.0..1.0f64).prop_map(Damage::Truncate),
        (0.0..1.0f64, 1u8..=255).prop_map(|(at, x)| Damage::Flip(at, x)),
        (0.0..1.0f64, any::<bool>()).prop_map(|(at, wide)| Damage::Huge(at, wide)),
    ]
}

fn apply(bytes: &[u8], d: &Damage) -> Vec<u8> {
    let mut b = bytes.to_vec();
    let at = |f: f64, len: usize| ((f * len as f64) as usize).min(len.saturating_sub(1));
    match *d {
        Damage::Truncate(f) => b.truncate(at(f, bytes.len())),
        Damage::Flip(f, x) => {
            let i = at(f, b.len());
            b[i] ^= x;
        }
        Damage::Huge(f, wide) => {
            let w = if wide { 8 } else { 4 };
            let i = at(f, b.len().saturating_sub(w));
            let v: Vec<u8> = if wide {
                (u64::MAX / 3).to_le_bytes().to_vec()
            } else {
                (u32::MAX - 5).to_le_bytes().to_vec()
            };
            b[i..i + w].copy_from_slice(&v);
        }
    }
    b
}

proptest! {
    #![proptest_config(ProptestConfig {
        cases: CASES,
        failure_persistence: None,
        rng_seed: proptest::test_runner::RngSeed::Fixed(0x5eed),
        ..ProptestConfig::default()
    })]

    /// L′ (`lightfield.bin` of a scene model): never a panic; a truncation is always an error.
    #[test]
    fn light_field_reader(d in damage()) {
        static GOOD: OnceLock<Vec<u8>> = OnceLock::new();
        let bad = apply(once(&GOOD, light_field_bytes), &d);
        let r = std::panic::catch_unwind(|| LightField::from_bytes(&bad).map(|_| ()));
        prop_assert!(r.is_ok(), "panicked on {:?}", d);
        if matches!(d, Damage::Truncate(_)) {
            prop_assert!(r.unwrap().is_err(), "accepted a truncation {:?}", d);
        }
    }

    /// The table optimiser's state of a checkpoint.
    #[test]
    fn table_adam_reader(d in damage()) {
        let (mut a, good) = adam();
        let bad = apply(&good, &d);
        let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| a.load_bytes(&bad)));
        prop_assert!(r.is_ok(), "panicked on {:?}", d);
        if matches!(d, Damage::Truncate(_)) {
            prop_assert!(r.unwrap().is_err(), "accepted a truncation {:?}", d);
        }
    }

    /// EXR photos and maps, through the file reader.
    #[test]
    fn exr_reader(d in damage(), k in 0u32..1_000_000) {
        static GOOD: OnceLock<Vec<u8>> = OnceLock::new();
        let bad = apply(once(&GOOD, exr_bytes), &d);
        let p = fuzz_dir().join(format!("case{k}.exr"));
        std::fs::write(&p, &bad).unwrap();
        let r = std::panic::catch_unwind(|| Image::read_exr(&p).map(|_| ()));
        std::fs::remove_file(&p).ok();
        prop_assert!(r.is_ok(), "panicked on {:?}", d);
        if let Ok(Err(e)) = r {
            prop_assert!(e.to_string().contains(&format!("case{k}.exr")), "{e}");
        }
    }

    /// OBJ meshes: any damage to the text gives a mesh or a line-numbered error.
    #[test]
    fn obj_parser(d in damage()) {
        let bad = apply(OBJ.as_bytes(), &d);
        let text = String::from_utf8_lossy(&bad);
        let r = std::panic::catch_unwind(|| Mesh::parse_obj(&text).map(|m| m.num_triangles()));
        prop_assert!(r.is_ok(), "panicked on {:?}", d);
    }
}
