//! End to end on the Mitsuba reference scene with `configs/fast.json`: `fipt-train run` (bake →
//! fit → emitters → refine → fit → maps → metrics) beats the best constant predictor of k_d and
//! a′ (computed here from the ground-truth maps and scored by the same scorer) by a margin, gets
//! the glossy parts' roughness far closer than the best constant σ, and the metal metallic;
//! refinement does not make the metrics worse and moves the glossy parts toward the truth; all
//! three emitters are extracted with no false emitter area above 1 % of the true area; and a
//! rerun with the same seed gives the same round-0 metrics to 1e-4.

use fipt_core::scene::{Dataset, LoadOptions, MapKind};
use fipt_train::pipeline::evaluate::{score_view, summarize};
use fipt_train::pipeline::predict::ViewMaps;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn scene_dir() -> PathBuf {
    root().join("../shared/scenes/fipt-room")
}

fn run(out: &Path, config: &Path) -> Value {
    let o = Command::new(env!("CARGO_BIN_EXE_fipt-train"))
        .args(["run", "--json", "--scene"])
        .arg(scene_dir())
        .arg("--out")
        .arg(out)
        .arg("--config")
        .arg(config)
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "fipt-train run failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    read_json(&out.join("metrics.json"))
}

fn read_json(p: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap()
}

const METRICS: [&str; 5] = [
    "kd_psnr",
    "albedo_psnr",
    "roughness_psnr",
    "emission_iou",
    "emission_log_l2",
];

/// The parts whose true roughness is at most 0.3 (the glossy ones).
const GLOSSY: [&str; 3] = ["cabinet", "mirror_sphere", "plastic_sphere"];

/// Mean |σ_est − σ_true| over the glossy parts of a round's (or the run's) part table.
fn glossy_sigma_error(parts: &Value) -> f64 {
    let rows = parts.as_array().expect("per-part table");
    let errs: Vec<f64> = GLOSSY
        .iter()
        .map(|name| {
            let r = rows
                .iter()
                .find(|r| r["name"] == *name)
                .unwrap_or_else(|| panic!("part {name} missing"));
            (r["sigma_est"].as_f64().unwrap() - r["sigma_true"].as_f64().unwrap()).abs()
        })
        .collect();
    errs.iter().sum::<f64>() / errs.len() as f64
}

#[test]
fn fast_run_recovers_materials_and_emitters_deterministically() {
    let base = std::env::temp_dir().join(format!("fipt-e2e-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&base);
    let fast = root().join("configs/fast.json");
    let m = run(&base.join("a"), &fast);
    let get = |m: &Value, k: &str| m[k].as_f64().unwrap_or_else(|| panic!("{k} missing"));
    eprintln!(
        "fast run: {}",
        METRICS.map(|k| format!("{k} {:.4}", get(&m, k))).join(", ")
    );
    // The scale: the best constant predictor of each map, scored by the same scorer.
    let (c, sigma_const) = constant_predictor_scores();
    eprintln!(
        "best constants: kd_psnr {:.4}, albedo_psnr {:.4}, roughness_psnr {:.4}",
        c[0], c[1], c[2]
    );
    for (k, (key, margin)) in [("kd_psnr", 6.0), ("albedo_psnr", 6.0)]
        .into_iter()
        .enumerate()
    {
        let est = get(&m, key);
        assert!(
            est >= c[k] + margin,
            "{key} {est:.2} dB does not beat the best constant ({:.2} dB) by {margin} dB",
            c[k]
        );
    }
    assert!(get(&m, "emission_iou") >= 0.85);
    assert!(get(&m, "emission_log_l2") <= 5e-3);

    // Two rounds: round 0 on the baked shadings, round 1 on shadings path-traced with round
    // 0's model. Refinement must not make the metrics worse (beyond 0.5 dB of Monte Carlo
    // noise: the refined shadings have 32 + 16 light samples per pixel) and must move the
    // glossy parts' roughness toward the truth. Measured: k_d 26.60 → 27.51 dB, a′ 26.19 →
    // 26.12, σ 14.26 → 14.21; glossy parts' mean |σ error| 0.277 → 0.262 (best constant 0.620);
    // against the constants 13.99 / 13.57 / 15.78 dB. σ no longer beats its constant: the
    // converged fit puts every diffuse-looking part at the prior's σ = 1 (see the README).
    let rounds = m["rounds"].as_array().expect("rounds");
    assert_eq!(rounds.len(), 2, "fast.json runs one refinement round");
    for key in ["kd_psnr", "albedo_psnr", "roughness_psnr"] {
        let (r0, r1) = (get(&rounds[0], key), get(&rounds[1], key));
        eprintln!("{key}: round 0 {r0:.3}, round 1 {r1:.3}");
        assert!(
            r1 >= r0 - 0.5,
            "{key}: round 1 {r1:.2} dB vs round 0 {r0:.2} dB"
        );
    }
    let (e0, e1) = (
        glossy_sigma_error(&rounds[0]["parts"]),
        glossy_sigma_error(&rounds[1]["parts"]),
    );
    // The scale: the best constant σ errs on these parts by |σ̄ − σ_true|.
    let rows = m["parts"].as_array().unwrap();
    let e_const = GLOSSY
        .iter()
        .map(|name| {
            let r = rows.iter().find(|r| r["name"] == *name).unwrap();
            (sigma_const as f64 - r["sigma_true"].as_f64().unwrap()).abs()
        })
        .sum::<f64>()
        / GLOSSY.len() as f64;
    eprintln!(
        "glossy parts |σ error|: round 0 {e0:.3}, round 1 {e1:.3}, best constant {e_const:.3}"
    );
    assert!(e1 <= e0 + 0.02, "glossy σ error grew: {e0:.3} -> {e1:.3}");
    assert!(
        e1 <= 0.6 * e_const,
        "glossy σ error {e1:.3} vs the best constant's {e_const:.3}"
    );
    let p = |name: &str, k: &str| {
        rows.iter().find(|r| r["name"] == name).unwrap()[k]
            .as_f64()
            .unwrap()
    };
    // The mirror sphere is a metal (m = 1, σ = 0.06).
    assert!(p("mirror_sphere", "m_est") >= 0.5);
    assert!((p("mirror_sphere", "sigma_est") - p("mirror_sphere", "sigma_true")).abs() <= 0.15);

    // Emitters against the ground truth per triangle (scene_meta.json's emitter parts).
    let meta = read_json(&scene_dir().join("scene_meta.json"));
    let parts: Vec<Value> = meta["parts"].as_array().unwrap().clone();
    let part_of = |t: usize| -> String {
        let p = parts.iter().find(|p| {
            let r = p["triangles"].as_array().unwrap();
            (r[0].as_u64().unwrap() as usize..r[1].as_u64().unwrap() as usize).contains(&t)
        });
        p.expect("every triangle is in a part")["name"]
            .as_str()
            .unwrap()
            .to_string()
    };
    let emitter_parts: Vec<&Value> = parts.iter().filter(|p| !p["emission"].is_null()).collect();
    assert_eq!(emitter_parts.len(), 3);
    let true_area: f64 = emitter_parts
        .iter()
        .map(|p| p["area"].as_f64().unwrap())
        .sum();
    let em = read_json(&base.join("a/emitters.json"));
    let mut found = std::collections::BTreeSet::new();
    let mut false_area = 0.0;
    for e in em["emitters"].as_array().unwrap() {
        let t = e["triangle"].as_u64().unwrap() as usize;
        let name = part_of(t);
        if emitter_parts.iter().any(|p| p["name"] == name.as_str()) {
            found.insert(name);
        } else {
            false_area += e["area"].as_f64().unwrap();
        }
    }
    assert_eq!(found.len(), 3, "emitter parts found: {found:?}");
    assert!(
        false_area <= 0.01 * true_area,
        "false emitter area {false_area:.4} m² vs true {true_area:.4} m²"
    );

    // Same seed, same round 0 (the bake cache is reused; the fit and everything after rerun,
    // without the refinement round, whose determinism the integrator's tests check).
    std::fs::create_dir_all(base.join("b/cache")).unwrap();
    std::fs::copy(
        base.join("a/cache/shadings.bin"),
        base.join("b/cache/shadings.bin"),
    )
    .unwrap();
    let mut cfg: Value = read_json(&fast);
    cfg["refine"]["rounds"] = Value::from(0);
    let round0 = base.join("round0.json");
    std::fs::write(&round0, serde_json::to_string(&cfg).unwrap()).unwrap();
    let m2 = run(&base.join("b"), &round0);
    assert_eq!(m2["bake_from_cache"], Value::Bool(true));
    for k in METRICS {
        let (a, b) = (get(&rounds[0], k), get(&m2, k));
        assert!((a - b).abs() <= 1e-4 * a.abs().max(1.0), "{k}: {a} vs {b}");
    }
    let _ = std::fs::remove_dir_all(&base);
}

/// The metrics of the best constant predictors: k_d, a′ and σ each set to the mean of the
/// (clamped) ground truth over the pixels its metric scores, on every train view; no emission.
/// Returns [kd_psnr, albedo_psnr, roughness_psnr] and the constant σ.
fn constant_predictor_scores() -> ([f64; 3], f32) {
    let opts = LoadOptions {
        maps: vec![
            MapKind::DiffCol,
            MapKind::Albedo,
            MapKind::Roughness,
            MapKind::Emit,
        ],
        val: false,
    };
    let ds = Dataset::load(&scene_dir(), &opts).unwrap();
    // Sums over the masked pixels of every view: k_d (3), a′ (3), σ (1) and their counts.
    let (mut kd, mut al, mut sg) = ([0f64; 3], [0f64; 3], 0f64);
    let (mut n_kd, mut n_rest) = (0usize, 0usize);
    for v in &ds.train.views {
        let (e, r) = (
            v.map(MapKind::Emit).unwrap(),
            v.map(MapKind::Roughness).unwrap(),
        );
        let (d, a) = (
            v.map(MapKind::DiffCol).unwrap(),
            v.map(MapKind::Albedo).unwrap(),
        );
        for p in 0..v.image.num_pixels() {
            if e.rgb(p).iter().sum::<f32>() > 0.0 {
                continue;
            }
            n_rest += 1;
            sg += r.scalar(p).clamp(0.2, 1.0) as f64;
            for (sum, v) in al.iter_mut().zip(a.rgb(p)) {
                *sum += v.clamp(0.0, 1.0) as f64;
            }
            if r.scalar(p) >= 0.6 {
                n_kd += 1;
                for (sum, v) in kd.iter_mut().zip(d.rgb(p)) {
                    *sum += v.clamp(0.0, 1.0) as f64;
                }
            }
        }
    }
    let kd = kd.map(|x| (x / n_kd as f64) as f32);
    let al = al.map(|x| (x / n_rest as f64) as f32);
    let sg = (sg / n_rest as f64) as f32;
    let scores = ds
        .train
        .views
        .iter()
        .map(|v| {
            let n = v.image.num_pixels();
            let maps = ViewMaps {
                width: v.image.width,
                height: v.image.height,
                kd: kd.repeat(n),
                sigma: vec![sg; n],
                metallic: vec![0.0; n],
                base: kd.repeat(n),
                albedo: al.repeat(n),
                emit: vec![0.0; 3 * n],
            };
            score_view(v, &maps)
        })
        .collect();
    let m = summarize(scores);
    (
        [
            m.kd_psnr.unwrap(),
            m.albedo_psnr.unwrap(),
            m.roughness_psnr.unwrap(),
        ],
        sg,
    )
}
