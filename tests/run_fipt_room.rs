//! End to end on the Mitsuba reference scene with `configs/fast.json`: `fipt-train run` (bake →
//! fit → emitters → refine → fit → maps → metrics) beats the best constant predictor of k_d and
//! a′ (computed here from the ground-truth maps and scored by the same scorer) by a margin, gets
//! the glossy parts' roughness far closer than the best constant σ, and the metal metallic;
//! refinement does not make the metrics worse and moves the glossy parts toward the truth; all
//! three emitters are extracted with no false emitter area above 1 % of the true area; the val
//! views re-rendered and relit from the recovered scene beat the trivial predictors; the scene
//! model lands in the zoo and renders from there with inserted objects and switched-off
//! emitters; and a run killed at points across all stages and rounds (and once stopped by
//! Ctrl-C, and once resumed over a damaged saved table) resumes to the metrics of the same run
//! uninterrupted to 1e-4, never showing a partial file (these runs fit 8 views with a small
//! config).

mod common;

use common::scene_dir;
use fipt_core::scene::{Dataset, LoadOptions, MapKind};
use fipt_train::pipeline::evaluate::constant_predictor;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn run(scene: &Path, out: &Path, config: &Path, zoo: Option<&Path>) -> Value {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_fipt-train"));
    cmd.args(["run", "--json", "--scene"])
        .arg(scene)
        .arg("--out")
        .arg(out)
        .arg("--config")
        .arg(config);
    match zoo {
        Some(z) => cmd.arg("--zoo").arg(z),
        None => cmd.arg("--no-zoo"),
    };
    let o = cmd.output().unwrap();
    assert!(
        o.status.success(),
        "fipt-train run failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    read_json(&out.join("metrics.json"))
}

/// Runs `fipt-train ARGS`; returns (success, stdout, stderr).
fn cli(args: &[&str]) -> (bool, String, String) {
    let o = Command::new(env!("CARGO_BIN_EXE_fipt-train"))
        .args(args)
        .output()
        .unwrap();
    (
        o.status.success(),
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

/// The trivial predictors of the val re-renders (`rerender::trivial_render_scores`).
fn trivial_render_scores() -> (f64, f64) {
    let ds = Dataset::load(
        &scene_dir(),
        &LoadOptions {
            maps: vec![MapKind::Relight],
            val: true,
        },
    )
    .unwrap();
    let (v, r) = fipt_train::rerender::trivial_render_scores(&ds.val.as_ref().unwrap().views);
    (v.unwrap(), r.unwrap())
}

fn em_count(p: &Path) -> Option<u64> {
    Some(read_json(p)["emitters"].as_array()?.len() as u64)
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
    let zoo = base.join("zoo");
    let m = run(&scene_dir(), &base.join("a"), &fast, Some(&zoo));
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
    // glossy parts' roughness toward the truth. Measured: k_d 25.84 → 28.57 dB, a′ 26.29 →
    // 27.94, σ 13.87 → 17.28; glossy parts' mean |σ error| 0.267 → 0.195 (best constant 0.620);
    // against the constants 13.99 / 13.57 / 15.78 dB. With the reference's prior (λ_d = 5e-4
    // throughout, no warm-up) every diffuse-looking part sat at σ = 1 and σ scored 14.2 dB,
    // below its constant; round 1's σ must now beat it (see the README's departures).
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
    let sigma = get(&rounds[1], "roughness_psnr");
    assert!(
        sigma >= c[2] + 1.0,
        "roughness_psnr {sigma:.2} dB vs the best constant's {:.2} dB",
        c[2]
    );
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

    // The landscape at the fitted model's maps (`landscape --fitted`): on the shadings the last
    // fit saw (round 1's), the model's own data term is what the fit minimised, so on every
    // part it lies below the true material's (measured: 2.0x below on the ceiling to 13x on
    // the table legs; the cabinet 4.7e-4 against 2.2e-3), and the sweep at the fitted a and m
    // comes within 1.7x of it (the cabinet's, whose σ varies over the part where the sweep
    // holds it constant). A misread map (wrong view, channel or pixel) scores at the truth's
    // level or above.
    let out_a = base.join("a");
    let (ok, json, err) = cli(&[
        "landscape",
        "--scene",
        scene_dir().to_str().unwrap(),
        "--out",
        out_a.to_str().unwrap(),
        "--config",
        fast.to_str().unwrap(),
        "--fitted",
        "--json",
    ]);
    assert!(ok, "{err}");
    let land: Value = serde_json::from_str(&json).unwrap();
    for part in land["refined1"].as_array().expect("round 1's landscape") {
        let name = part["name"].as_str().unwrap();
        let f = &part["fitted"];
        let (fit, truth) = (
            f["loss"].as_f64().unwrap(),
            part["loss_true"].as_f64().unwrap(),
        );
        let best = f["data"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .fold(f64::INFINITY, f64::min);
        eprintln!("landscape {name}: fitted data {fit:.3e}, at the truth {truth:.3e}");
        assert!(fit < truth, "{name}: fitted {fit:.3e} vs truth {truth:.3e}");
        assert!(
            best <= 2.0 * fit,
            "{name}: sweep minimum {best:.3e} vs fitted {fit:.3e}"
        );
    }

    // The lamp views (train views 1 and 31) look at the wall beside the lamp, lit mostly by the
    // lamp's face turned to it, which no photo sees. `emitters.fill_unseen` gives that face its
    // neighbours' radiance; without it the refined shadings there are ~2x too dark and these
    // views score 18.2 / 16.4 dB k_d (measured, fast config). With it: 25.4 / 26.6 dB.
    for k in [1, 31] {
        let v = m["per_view"][k]["kd_psnr"].as_f64().unwrap();
        eprintln!("lamp view {k}: k_d {v:.2} dB");
        assert!(v >= 22.0, "lamp view {k}: k_d {v:.2} dB");
    }

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

    // The val re-renders: view synthesis and relighting of the recovered scene at 32 spp
    // (measured 28.18 and 32.79 dB; view synthesis at 256 spp 33.9: it is noise-bound at
    // this budget) against the trivial predictors (a constant image of each photo's mean
    // colour; the photo under the old lights, 15.8 dB).
    let (view_trivial, relight_trivial) = trivial_render_scores();
    let (view, relight) = (get(&m, "view_psnr"), get(&m, "relight_psnr"));
    eprintln!(
        "val re-renders: view {view:.2} dB (trivial {view_trivial:.2}), relight {relight:.2} dB (trivial {relight_trivial:.2})"
    );
    assert!(
        view >= 25.0 && view >= view_trivial + 8.0,
        "view_psnr {view:.2}"
    );
    assert!(
        relight >= 26.0 && relight >= relight_trivial + 8.0,
        "relight_psnr {relight:.2}"
    );
    for k in 0..8 {
        for folder in ["Image", "Relight"] {
            let p = base.join(format!("a/render/val/{folder}/{k:03}_0001.exr"));
            assert!(p.is_file(), "{} missing", p.display());
        }
    }

    // The HTML report: every image it shows exists and is a PNG, every figure in its tables
    // is finite, and it has every section of a scene with ground truth.
    let page = std::fs::read_to_string(base.join("a/report.html")).unwrap();
    let mut images = 0;
    for part in page.split("<img src=\"").skip(1) {
        let src = &part[..part.find('"').unwrap()];
        let bytes =
            std::fs::read(base.join("a").join(src)).unwrap_or_else(|_| panic!("{src} missing"));
        assert!(bytes.starts_with(b"\x89PNG"), "{src} is not a PNG");
        images += 1;
    }
    // The recovered scene's viewer: the page it frames and the .glb it links.
    assert!(page.contains("<iframe src=\"report/viewer/viewer.html\""));
    assert!(base.join("a/report/viewer/viewer.html").is_file());
    let glb = std::fs::read(base.join("a/report/viewer/scene.glb")).unwrap();
    assert!(
        glb.starts_with(b"glTF"),
        "report/viewer/scene.glb is not a GLB"
    );
    // Three views × (photo, re-render, and truth, estimate, error of 5 maps), and the sheet.
    assert_eq!(images, 3 * 17 + 1, "images in the report");
    let mut cells = 0;
    for part in page.split("<td>").skip(1) {
        let cell = &part[..part.find("</td>").unwrap()];
        assert!(
            !cell.contains("NaN") && !cell.contains("inf") && !cell.contains("not finite"),
            "cell {cell}"
        );
        for tok in cell.split([',', ' ', '(', ')']) {
            if let Ok(x) = tok.parse::<f64>() {
                assert!(x.is_finite());
                cells += 1;
            }
        }
    }
    assert!(cells > 100, "{cells} numbers");
    for section in [
        "Metrics",
        "Time and memory",
        "Views",
        "Parts",
        "Emitters",
        "Loss",
        "Re-renders",
    ] {
        assert!(
            page.contains(&format!("<h2>{section}</h2>")),
            "no {section} section"
        );
    }

    // The scene model: in OUT/model and in the zoo, listed with its metrics.
    let zoo_s = zoo.to_str().unwrap();
    let (ok, out, err) = cli(&["zoo", "list", "--json", "--zoo", zoo_s]);
    assert!(ok, "{err}");
    let list: Value = serde_json::from_str(&out).unwrap();
    let entry = &list.as_array().unwrap()[0];
    assert_eq!(entry["name"], "fipt-room-s0");
    let man = &entry["manifest"];
    assert_eq!(man["metrics"]["view_psnr"].as_f64(), Some(view));
    assert_eq!(
        man["emitter_triangles"].as_u64(),
        em_count(&base.join("a/emitters.json"))
    );
    let mb = man["total_bytes"].as_f64().unwrap() / 1e6;
    eprintln!("scene model: {mb:.1} MB");
    // Scored from the saved model (f16 hash table) instead of run's in-memory one (f32): the
    // same maps within 0.05 dB.
    let ev = base.join("eval");
    let (ok, _, err) = cli(&[
        "eval",
        "--model",
        "fipt-room-s0",
        "--zoo",
        zoo_s,
        "--scene",
        scene_dir().to_str().unwrap(),
        "--out",
        ev.to_str().unwrap(),
        "--json",
    ]);
    assert!(ok, "{err}");
    let e = read_json(&ev.join("eval.json"));
    for k in ["kd_psnr", "albedo_psnr", "roughness_psnr"] {
        let (a, b) = (get(&m, k), get(&e, k));
        eprintln!("{k}: run (f32) {a:.4}, saved model (f16) {b:.4}");
        assert!((a - b).abs() <= 0.05, "{k}: {a} vs {b}");
    }

    // Rendered from the zoo without the photos' run: an inserted emitting cube in front of
    // val camera 0 covers the centre pixel, which then reads its radiance exactly (camera rays
    // that hit an emitter end there); every emitter switched off and none added leaves black.
    let ds = Dataset::load(
        &scene_dir(),
        &LoadOptions {
            maps: vec![],
            val: true,
        },
    )
    .unwrap();
    let cam = &ds.val.as_ref().unwrap().views[0].camera;
    let (w, h) = (cam.width, cam.height);
    let centre = cam.origin_f32() + cam.direction_at(w as f64 / 2.0, h as f64 / 2.0) * 0.5;
    let insert = base.join("insert.json");
    std::fs::write(
        &insert,
        format!(
            r#"{{"objects": [{{"name": "bulb", "shape": "cube", "scale": 0.05, "translate": [{}, {}, {}], "emission": [3, 2, 1]}},
                {{"name": "ball", "shape": "sphere", "scale": 0.2, "translate": [2.5, 0.2, 2.0],
                  "material": {{"base_color": [0.8, 0.8, 0.8], "roughness": 0.2, "metallic": 1}}}}]}}"#,
            centre.x, centre.y, centre.z
        ),
    )
    .unwrap();
    let scene = scene_dir();
    let scene_s = scene.to_str().unwrap();
    let ins_out = base.join("insert");
    let (ok, _, err) = cli(&[
        "render",
        "--model",
        "fipt-room-s0",
        "--zoo",
        zoo_s,
        "--scene",
        scene_s,
        "--views",
        "0",
        "--spp",
        "4",
        "--insert",
        insert.to_str().unwrap(),
        "--json",
        "--out",
        ins_out.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let img = fipt_core::scene::Image::read_exr(&ins_out.join("val/Image/000_0001.exr")).unwrap();
    let px = img.rgb((h / 2) * w + w / 2);
    for (c, want) in px.iter().zip([3.0, 2.0, 1.0]) {
        assert!((c - want).abs() <= 1e-4 * want, "centre pixel {px:?}");
    }
    let off = base.join("off.json");
    std::fs::write(&off, r#"{"emitters_off": ["all"]}"#).unwrap();
    let dark = base.join("dark");
    let (ok, _, err) = cli(&[
        "render",
        "--model",
        base.join("a/model").to_str().unwrap(),
        "--scene",
        scene_s,
        "--views",
        "1",
        "--spp",
        "2",
        "--relight",
        off.to_str().unwrap(),
        "--json",
        "--out",
        dark.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let img = fipt_core::scene::Image::read_exr(&dark.join("val/Relight/001_0001.exr")).unwrap();
    assert!(img.data.iter().all(|&x| x == 0.0));
    let (ok, _, err) = cli(&[
        "render",
        "--model",
        "no-such-model",
        "--zoo",
        zoo_s,
        "--scene",
        scene_s,
        "--out",
        dark.to_str().unwrap(),
    ]);
    assert!(
        !ok && err.contains("no model 'no-such-model'") && err.contains("fipt-room-s0"),
        "{err}"
    );

    // The model renders without the photos it was fitted to (a scene folder with only val/),
    // and a copy imported into the zoo from elsewhere renders identically; a damaged one is
    // refused with the file named, exit code 1.
    let bare = base.join("bare");
    std::fs::create_dir_all(&bare).unwrap();
    for f in ["val", "scene.obj", "scene_meta.json"] {
        std::os::unix::fs::symlink(scene.join(f), bare.join(f)).unwrap();
    }
    let render_to = |model: &str, out: &Path| {
        cli(&[
            "render",
            "--model",
            model,
            "--zoo",
            zoo_s,
            "--scene",
            bare.to_str().unwrap(),
            "--views",
            "2",
            "--spp",
            "2",
            "--json",
            "--out",
            out.to_str().unwrap(),
        ])
    };
    let (ok, _, err) = render_to("fipt-room-s0", &base.join("r1"));
    assert!(ok, "{err}");
    let copy = base.join("elsewhere/m");
    std::fs::create_dir_all(&copy).unwrap();
    for e in std::fs::read_dir(base.join("a/model")).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), copy.join(e.file_name())).unwrap();
    }
    let (ok, _, err) = cli(&[
        "zoo",
        "import",
        copy.to_str().unwrap(),
        "--name",
        "copy",
        "--zoo",
        zoo_s,
    ]);
    assert!(ok, "{err}");
    let (ok, out, err) = cli(&["zoo", "list", "--json", "--zoo", zoo_s]);
    assert!(ok, "{err}");
    let names: Vec<String> = serde_json::from_str::<Value>(&out)
        .unwrap()
        .as_array()
        .unwrap()
        .iter()
        .map(|e| e["name"].as_str().unwrap().to_string())
        .collect();
    assert_eq!(names, ["copy", "fipt-room-s0"]);
    let (ok, _, err) = render_to("copy", &base.join("r2"));
    assert!(ok, "{err}");
    let exr = |d: &str| std::fs::read(base.join(d).join("val/Image/002_0001.exr")).unwrap();
    assert!(
        exr("r1") == exr("r2"),
        "the imported copy renders differently"
    );
    let grid = copy.join("hashgrid.f16");
    let bytes = std::fs::read(&grid).unwrap();
    std::fs::write(&grid, &bytes[..bytes.len() - 2]).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_fipt-train"))
        .args([
            "render",
            "--model",
            copy.to_str().unwrap(),
            "--scene",
            bare.to_str().unwrap(),
            "--out",
        ])
        .arg(base.join("r3"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("hashgrid.f16") && err.contains("truncated") && !err.contains("panicked"),
        "{err}"
    );

    // A run killed (SIGKILL) at points across every stage and round and once stopped by
    // Ctrl-C (SIGINT) during a fit, each time run again: it resumes from its checkpoints, never
    // shows a partial file, and ends with the uninterrupted run's metrics to 1e-4 (the whole
    // metrics.json but times, paths and the resume note) and its scene model. Both runs fit the
    // first views of the scene with a small config (`stops_config`): what is compared is
    // resuming, not the fit's quality.
    let small = base.join("small");
    common::small_scene(&small, STOP_VIEWS, true);
    let cfg = stops_config(&base);
    let c = base.join("c");
    let mc = run(&small, &c, &cfg, None);
    let b = base.join("b");
    let stops = [
        Stop::kill("the bake", |o, _| o.join("config.json").exists(), 2000),
        Stop {
            name: "round 0's fit (Ctrl-C)",
            when: |o, _| newest_step(o, 0) >= Some(STOP_EVERY),
            delay_ms: 0,
            sigint: true,
            contend: false,
            damaged: false,
        },
        Stop {
            contend: true,
            ..Stop::kill(
                "round 0's fit",
                |o, _| newest_step(o, 0) >= Some(3 * STOP_EVERY),
                100,
            )
        },
        Stop::kill(
            "refinement 1",
            |o, _| o.join("checkpoint/round0/report.json").exists(),
            1500,
        ),
        Stop::kill(
            "round 1's fit",
            |o, _| newest_step(o, 1) >= Some(2 * STOP_EVERY),
            100,
        ),
        // A byte flipped in round 1's newest saved table: the run names the file, discards
        // that round's fit and fits it again; it is killed once the new fit has saved a step,
        // and the next run resumes that fit.
        Stop {
            damaged: true,
            ..Stop::kill(
                "round 1's fit again",
                |o, _| matches!(newest_step(o, 1), Some(s) if s < 2 * STOP_EVERY),
                100,
            )
        },
        Stop::kill("the maps", |o, pid| staged(o, "maps", pid), 300),
        Stop::kill("the re-renders", |o, pid| staged(o, "render", pid), 1000),
    ];
    for stop in &stops {
        interrupt(&small, &b, &cfg, stop);
        assert_complete(&b);
    }
    // The last run, after every fit has finished, restores all rounds and reports them as the
    // uninterrupted run did (the fit pixels of each round among them).
    let o = run_cmd(&small, &b, &cfg).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "the last run: {err}");
    assert!(!err.contains("discarded"), "the last run: {err}");
    let m2 = read_json(&b.join("metrics.json"));
    assert!(
        m2["resumed"].as_str().is_some(),
        "the last run did not resume"
    );
    assert_complete(&b);
    let mut diffs = Vec::new();
    same_json(&mc, &m2, "", &mut diffs);
    assert!(diffs.is_empty(), "resumed vs uninterrupted: {diffs:?}");
    // The scene models agree exactly: the f16 table byte for byte, the network weights value
    // for value (burn's record files also hold per-process parameter ids).
    let read = |d: &str| std::fs::read(base.join(d).join("model/hashgrid.f16")).unwrap();
    assert!(
        read("c") == read("b"),
        "model/hashgrid.f16 differs after resuming"
    );
    let device = burn::tensor::Device::flex();
    let nets = |d: &str| {
        fipt_train::scene_model::SceneModel::load(&base.join(d).join("model"), &device)
            .unwrap()
            .model
            .net_params()
    };
    assert!(nets("c") == nets("b"), "the networks differ after resuming");
    let leftovers: Vec<_> = walk(&b)
        .into_iter()
        .filter(|p| p.to_string_lossy().contains(".tmp"))
        .collect();
    assert!(leftovers.is_empty(), "temporaries left: {leftovers:?}");
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
    let c = constant_predictor(&ds.train.views).expect("ground truth");
    let m = &c.metrics;
    (
        [
            m.kd_psnr.unwrap(),
            m.albedo_psnr.unwrap(),
            m.roughness_psnr.unwrap(),
        ],
        c.sigma,
    )
}

/// The train views of the reference scene that the stopped runs fit.
const STOP_VIEWS: usize = 8;

/// The steps between the stopped runs' checkpoints.
const STOP_EVERY: usize = 25;

/// `common::small_fast_config` for the stopped runs: fits of 200 steps saved every
/// `STOP_EVERY` steps, fewer samples in refinement, the albedo maps and the re-renders. Every
/// stage and round of the fast config still runs, the hop included.
fn stops_config(dir: &Path) -> PathBuf {
    let mut c = common::small_fast_config(200);
    c["checkpoint"]["every_steps"] = STOP_EVERY.into();
    let paths = &mut c["refine"]["paths"];
    paths["samples"] = serde_json::json!({"diffuse": 8, "specular": [4, 4, 4, 4, 4, 4]});
    paths["light_samples"] = 8.into();
    c["render"]["spp"] = 4.into();
    c["render"]["relight_spp"] = 4.into();
    c["maps"]["albedo_samples"] = 8.into();
    let p = dir.join("stops.json");
    std::fs::write(&p, c.to_string()).unwrap();
    p
}

/// One interruption of a run: once `when` holds for its output folder and process id, wait
/// `delay_ms`, then send SIGKILL (or SIGINT).
struct Stop {
    name: &'static str,
    when: fn(&Path, u32) -> bool,
    delay_ms: u64,
    sigint: bool,
    /// Before the stop, a second `run` into the same folder is refused naming the first.
    contend: bool,
    /// Before the run, a byte of round 1's newest saved table is flipped: the run must name
    /// the file and discard that round's fit.
    damaged: bool,
}

/// The newest saved step of `round`'s fit in a run's checkpoint folder.
fn newest_step(out: &Path, round: usize) -> Option<usize> {
    std::fs::read_dir(out.join(format!("checkpoint/round{round}")))
        .ok()?
        .flatten()
        .filter_map(|e| e.file_name().to_str()?.strip_prefix("step")?.parse().ok())
        .max()
}

impl Stop {
    fn kill(name: &'static str, when: fn(&Path, u32) -> bool, delay_ms: u64) -> Self {
        Self {
            name,
            when,
            delay_ms,
            sigint: false,
            contend: false,
            damaged: false,
        }
    }
}

/// Whether process `pid` is staging a folder `name` (written before it replaces `OUT/name`).
fn staged(out: &Path, name: &str, pid: u32) -> bool {
    out.join(format!(".{name}.tmp-{pid}.tmp")).exists()
}

/// `fipt-train run --json --no-zoo` of `scene` into `out` with `config`.
fn run_cmd(scene: &Path, out: &Path, config: &Path) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_fipt-train"));
    c.args(["run", "--json", "--no-zoo", "--scene"])
        .arg(scene)
        .arg("--out")
        .arg(out)
        .arg("--config")
        .arg(config);
    c
}

/// Starts `fipt-train run` of `scene` with `config` into `out` and stops it as `stop` says. A
/// SIGINT must end it with exit code 130, one line on stderr, and a checkpoint of the step
/// that line names.
fn interrupt(scene: &Path, out: &Path, config: &Path, stop: &Stop) {
    std::fs::create_dir_all(out).unwrap();
    if stop.damaged {
        let newest = newest_step(out, 1).expect("round 1's saved fit");
        let table = out.join(format!("checkpoint/round1/step{newest:07}/hashgrid.bin"));
        let mut bytes = std::fs::read(&table).unwrap();
        let mid = bytes.len() / 2;
        bytes[mid] ^= 0x10;
        std::fs::write(&table, bytes).unwrap();
    }
    let err_path = out.with_extension("stderr");
    let mut child = run_cmd(scene, out, config)
        .stdout(std::process::Stdio::null())
        .stderr(std::fs::File::create(&err_path).unwrap())
        .spawn()
        .unwrap();
    loop {
        if let Some(st) = child.try_wait().unwrap() {
            panic!(
                "the run ended ({st}) before the stop in {}: {}",
                stop.name,
                std::fs::read_to_string(&err_path).unwrap_or_default()
            );
        }
        if (stop.when)(out, child.id()) {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
    if stop.contend {
        let o = run_cmd(scene, out, config).output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(
            o.status.code(),
            Some(1),
            "a second run into one folder: {err}"
        );
        assert!(
            err.contains(&format!("in use by fipt process {}", child.id()))
                && err.contains(".fipt.lock"),
            "a second run into one folder: {err}"
        );
        assert!(
            child.try_wait().unwrap().is_none(),
            "the first run ended when the second started"
        );
    }
    std::thread::sleep(std::time::Duration::from_millis(stop.delay_ms));
    // A resumed run neither discarded its saved state nor failed, unless its state was
    // damaged: then it names the file and the round it discards.
    let check_resume = |err: &str| {
        if stop.damaged {
            assert!(
                err.contains("discarded round 1's saved fit") && err.contains("hashgrid.bin"),
                "{}: the flipped byte was not named: {err}",
                stop.name
            );
            return;
        }
        assert!(
            !err.contains("discarded") && !err.contains("error"),
            "{}: {err}",
            stop.name
        )
    };
    if !stop.sigint {
        child.kill().unwrap();
        let st = child.wait().unwrap();
        use std::os::unix::process::ExitStatusExt;
        let err = std::fs::read_to_string(&err_path).unwrap();
        assert_eq!(
            st.signal(),
            Some(9),
            "{}: not killed: {st} {err}",
            stop.name
        );
        check_resume(&err);
        eprintln!("killed during {}: {st}", stop.name);
        return;
    }
    // SAFETY: a plain kill(2) of our own child, which has not been waited for.
    let sent = unsafe { libc::kill(child.id() as libc::pid_t, libc::SIGINT) };
    assert_eq!(sent, 0, "SIGINT not sent");
    let st = child.wait().unwrap();
    let err = std::fs::read_to_string(&err_path).unwrap();
    assert_eq!(st.code(), Some(130), "Ctrl-C in {}: {st}, {err}", stop.name);
    check_resume(&err);
    let lines: Vec<&str> = err.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "Ctrl-C: not one line: {err}");
    eprintln!("Ctrl-C during {}: {}", stop.name, lines[0]);
    let step: usize = lines[0]
        .strip_prefix("interrupted: round 0's fit saved at step ")
        .and_then(|r| r.split_whitespace().next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("Ctrl-C message: {err}"));
    let newest = std::fs::read_dir(out.join("checkpoint/round0"))
        .unwrap()
        .flatten()
        .filter_map(|e| {
            e.file_name()
                .to_str()?
                .strip_prefix("step")?
                .parse::<usize>()
                .ok()
        })
        .max();
    assert_eq!(
        newest,
        Some(step),
        "the checkpoint is not the step the message names"
    );
    assert!(step >= STOP_EVERY);
}

/// Every file under `dir`, recursively.
fn walk(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).into_iter().flatten().flatten() {
        let p = e.path();
        if p.is_dir() {
            out.push(p.clone());
            out.extend(walk(&p));
        } else {
            out.push(p);
        }
    }
    out
}

/// No partial file is visible in a run's output folder: outside temporaries (names with
/// `.tmp`, which the next run removes), every file is non-empty and reads as what its
/// extension says, every checkpoint folder holds the whole state, and every map folder the
/// same views for each map.
fn assert_complete(out: &Path) {
    for p in walk(out) {
        let s = p.to_string_lossy().into_owned();
        // Temporaries, and the lock file (empty while no one holds it).
        if s.contains(".tmp") || s.ends_with(".fipt.lock") {
            continue;
        }
        let name = p.file_name().unwrap().to_string_lossy().into_owned();
        if p.is_dir() {
            if name.starts_with("step") && s.contains("checkpoint") {
                for f in [
                    "progress.json",
                    "sampler.bin",
                    "trainer.json",
                    "optim.bpk",
                    "table_adam.bin",
                    "model.json",
                    "fields.bpk",
                    "hashgrid.bin",
                    "manifest.json",
                ] {
                    assert!(p.join(f).is_file(), "{s}: {f} missing");
                }
            }
            continue;
        }
        common::assert_readable(&p);
    }
    // A map folder holds every view of every map it has.
    for split in ["train", "val"] {
        let dir = out.join("maps").join(split);
        let Ok(entries) = std::fs::read_dir(&dir) else {
            continue;
        };
        let by_kind: std::collections::BTreeMap<String, usize> = entries
            .flatten()
            .filter(|e| e.file_name() != "preview")
            .map(|e| {
                let n = std::fs::read_dir(e.path()).unwrap().count();
                (e.file_name().to_string_lossy().into_owned(), n)
            })
            .collect();
        let counts: std::collections::BTreeSet<usize> = by_kind.values().copied().collect();
        assert!(
            counts.len() <= 1,
            "{}: views missing: {by_kind:?}",
            dir.display()
        );
    }
}

/// Keys of metrics.json that may differ between an uninterrupted and a resumed run.
const NOT_COMPARED: [&str; 11] = [
    "time_s",
    "peak_rss_mb",
    "step_profile",
    "resumed",
    "bake_from_cache",
    "model_dir",
    "zoo_entry",
    "refine_s",
    "train_s",
    "seconds",
    "refine_paths",
];

/// The dotted paths where `a` and `b` differ (numbers by more than 1e-4 relative).
fn same_json(a: &Value, b: &Value, at: &str, out: &mut Vec<String>) {
    match (a, b) {
        (Value::Object(x), Value::Object(y)) => {
            for (k, u) in x {
                if NOT_COMPARED.contains(&k.as_str()) {
                    continue;
                }
                match y.get(k) {
                    Some(v) => same_json(u, v, &format!("{at}.{k}"), out),
                    None => out.push(format!("{at}.{k} missing")),
                }
            }
        }
        (Value::Array(x), Value::Array(y)) if x.len() == y.len() => {
            for (i, (u, v)) in x.iter().zip(y).enumerate() {
                same_json(u, v, &format!("{at}[{i}]"), out);
            }
        }
        (Value::Number(x), Value::Number(y)) => {
            let (x, y) = (x.as_f64().unwrap(), y.as_f64().unwrap());
            if (x - y).abs() > 1e-4 * x.abs().max(1.0) {
                out.push(format!("{at}: {x} vs {y}"));
            }
        }
        _ if a != b => out.push(format!("{at}: {a} vs {b}")),
        _ => {}
    }
}
