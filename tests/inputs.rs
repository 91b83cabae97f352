//! Every numeric field of every input file has a range, the table in `docs/inputs.md` is the
//! code's (`fipt_core::ranges::FIELDS`), and each loader refuses a value just outside each range
//! with an error naming the file and the field. Flags out of their range are refused naming the
//! flag.

use fipt_core::ranges::{FIELDS, Kind, field, markdown_table, walk};
use serde_json::{Value, json};
use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn scratch(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("fipt-inputs-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

const MATRIX: [[f64; 4]; 4] = [
    [1.0, 0.0, 0.0, 2.0],
    [0.0, 1.0, 0.0, 1.0],
    [0.0, 0.0, 1.0, 2.0],
    [0.0, 0.0, 0.0, 1.0],
];

/// A file of `kind` with every field fipt reads. Config, scene meta and relight files go
/// through their types (parsed, then written back), so a field added to a type is here.
fn example(kind: Kind) -> Value {
    match kind {
        Kind::Config => {
            let mut v = serde_json::to_value(fipt_train::config::Config::default()).unwrap();
            // The fields that are null by default.
            v["refine"]["lambda_d_warmup"] = json!(0.5);
            v["refine"]["lambda_m"] = json!(1e-4);
            v["train"]["grid"]["max_resolution"] = json!(2048.0);
            v["refine"]["paths"]["sharp"] =
                json!({"below": 0.4, "specular": [128, 128, 32, 32, 32, 32]});
            v
        }
        Kind::SceneMeta => {
            let m = fipt_core::scene::meta::SceneMeta::load(
                &root().join("scenes/fipt-room/scene_meta.json"),
            )
            .unwrap();
            serde_json::to_value(m).unwrap()
        }
        Kind::Relight => {
            let emitter = json!({
                "name": "panel",
                "vertices": [[0.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 1.0]],
                "triangles": [[0, 1, 2]],
                "radiance": [5.0, 5.0, 5.0],
                "bsdf": {"base_color": [0.5, 0.5, 0.5], "roughness": 0.5, "metallic": 0.0}
            });
            let r: fipt_core::scene::meta::Relight = serde_json::from_value(json!({
                "emitters_off": ["all"],
                "emitters_scale": {"all": 2.0},
                "new_emitter": emitter,
                "new_emitters": [emitter],
            }))
            .unwrap();
            serde_json::to_value(r).unwrap()
        }
        Kind::Insert => json!({"objects": [
            {"name": "ball", "shape": "sphere", "scale": 0.2, "rotate_deg": [0, 30, 0],
             "translate": [2.5, 0.2, 2.0],
             "material": {"base_color": [0.8, 0.1, 0.1], "roughness": 0.3, "metallic": 0.0}},
            {"name": "box", "shape": "cube", "scale": [0.5, 0.5, 0.5], "translate": [1, 0, 1],
             "emission": [20, 18, 15]}
        ]}),
        Kind::Transforms => json!({
            "camera_angle_x": 1.2,
            "fl_x": 100.0, "fl_y": 100.0, "cx": 48.0, "cy": 36.0, "w": 96, "h": 72,
            "frames": [
                {"file_path": "a", "transform_matrix": MATRIX, "exposure": 0.5},
                {"file_path": "b", "transform_matrix": MATRIX,
                 "fl_x": 90.0, "fl_y": 90.0, "cx": 47.0, "cy": 35.0, "w": 96, "h": 72}
            ]
        }),
    }
}

/// Loads `text` as a file of `kind` written at `path`; the error's text.
fn load(kind: Kind, path: &Path, text: &str) -> Result<(), String> {
    std::fs::write(path, text).unwrap();
    let s = |e: &dyn std::fmt::Display| format!("{e:#}");
    match kind {
        Kind::Config => fipt_train::config::Config::load(path)
            .map(|_| ())
            .map_err(|e| format!("{e:#}")),
        Kind::SceneMeta => fipt_core::scene::meta::SceneMeta::load(path)
            .map(|_| ())
            .map_err(|e| s(&e)),
        Kind::Relight => fipt_core::scene::meta::Relight::load(path, None)
            .map(|_| ())
            .map_err(|e| s(&e)),
        Kind::Insert => fipt_core::scene::insert::load_insert(path)
            .map(|_| ())
            .map_err(|e| s(&e)),
        Kind::Transforms => fipt_core::scene::dataset::load_cameras(path, (96, 72))
            .map(|_| ())
            .map_err(|e| s(&e)),
    }
}

/// The concrete paths of `v`'s numbers.
fn leaves(v: &Value) -> Vec<String> {
    let mut out = Vec::new();
    walk(v, &mut String::new(), &mut |p, _| out.push(p.to_string()));
    out
}

/// `a.b[2].c` as the JSON pointer `/a/b/2/c`.
fn pointer(path: &str) -> String {
    let mut s = String::new();
    for part in path.split('.') {
        let (key, idx) = part.split_once('[').unwrap_or((part, ""));
        if !key.is_empty() {
            s.push('/');
            s.push_str(key);
        }
        for i in idx.split(['[', ']']).filter(|x| !x.is_empty()) {
            s.push('/');
            s.push_str(i);
        }
    }
    s
}

#[test]
fn every_field_read_has_a_range() {
    for kind in Kind::ALL {
        for p in leaves(&example(kind)) {
            assert!(
                field(kind, &p).is_some(),
                "{kind:?}: the field {p} has no range in fipt_core::ranges::FIELDS"
            );
        }
    }
}

#[test]
fn the_docs_table_is_the_code_table() {
    let doc = std::fs::read_to_string(root().join("docs/inputs.md")).unwrap();
    let table = markdown_table();
    assert!(
        doc.contains(&table),
        "docs/inputs.md does not hold the table of fipt_core::ranges::FIELDS; it should read:\n{table}"
    );
}

/// For every field and every value just outside its range (below, above, a fraction for an
/// integer, and null-free huge values): the loader refuses it, naming the file and the field;
/// the unchanged example loads.
#[test]
fn every_range_is_enforced_by_its_loader() {
    let dir = scratch("ranges");
    let mut cases = 0;
    for kind in Kind::ALL {
        let before = cases;
        let good = example(kind);
        let path = dir.join(format!("{kind:?}.json"));
        load(kind, &path, &good.to_string())
            .unwrap_or_else(|e| panic!("{kind:?}: the example is refused: {e}"));
        let all = leaves(&good);
        for f in FIELDS.iter().filter(|f| f.kind == kind) {
            let at = all
                .iter()
                .find(|p| field(kind, p).is_some_and(|g| g.path == f.path))
                .unwrap_or_else(|| panic!("{kind:?}: no example of {}", f.path));
            for x in f.range.outside().into_iter().chain([1e300, -1e300]) {
                if f.range.holds(x) {
                    continue;
                }
                let mut bad = good.clone();
                *bad.pointer_mut(&pointer(at)).unwrap() = json!(x);
                let e = load(kind, &path, &bad.to_string())
                    .err()
                    .unwrap_or_else(|| panic!("{kind:?}: {at} = {x} was accepted"));
                let named = e.contains(&path.display().to_string()) && e.contains(at.as_str());
                assert!(named, "{kind:?}: {at} = {x}: {e}");
                assert!(!e.contains("panicked"), "{e}");
                cases += 1;
            }
        }
        let fields = FIELDS.iter().filter(|f| f.kind == kind).count();
        eprintln!(
            "{kind:?}: {fields} fields, {} values refused",
            cases - before
        );
    }
    eprintln!("{cases} out-of-range values refused");
    assert!(cases >= 400, "{cases}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Flags out of their range exit non-zero naming the flag; nothing is written.
#[test]
fn flags_out_of_range_are_refused() {
    let dir = scratch("flags");
    let out = dir.join("out");
    let scene = root().join("scenes/fipt-room");
    let s = scene.to_str().unwrap();
    let o = out.to_str().unwrap();
    let cases: &[(&[&str], &str)] = &[
        (
            &["render", "--truth", "--scene", s, "--out", o, "--spp", "0"],
            "--spp",
        ),
        (
            &[
                "render", "--truth", "--scene", s, "--out", o, "--spp", "70000",
            ],
            "--spp",
        ),
        (
            &[
                "render",
                "--truth",
                "--scene",
                s,
                "--out",
                o,
                "--max-depth",
                "0",
            ],
            "--max-depth",
        ),
        (
            &[
                "render",
                "--truth",
                "--scene",
                s,
                "--out",
                o,
                "--max-depth",
                "65",
            ],
            "--max-depth",
        ),
        (
            &[
                "render",
                "--truth",
                "--scene",
                s,
                "--out",
                o,
                "--pixel-positions",
                "5000",
            ],
            "--pixel-positions",
        ),
        (
            &["render", "--truth", "--scene", s, "--out", o, "--views=-1"],
            "--views",
        ),
        (&["suite", "--out", o, "--scenes", "0"], "--scenes"),
        (
            &[
                "suite",
                "--out",
                o,
                "--scenes",
                "2",
                "--first-seed",
                "18446744073709551615",
            ],
            "--first-seed",
        ),
        (&["bench", "render", "--scene", s, "--reps", "0"], "--reps"),
        (
            &["bench", "render", "--scene", s, "--views", "0"],
            "--views",
        ),
        (&["bench", "render", "--scene", s, "--spp", "0"], "--spp"),
        (&["bench", "trace", "--rays", "0"], "--rays"),
        (&["bench", "trace", "--mesh-scale", "9"], "--mesh-scale"),
        (
            &["bench", "query", "--model", "x", "--batch", "0"],
            "--batch",
        ),
        (&["bench", "step", "--steps", "0"], "--steps"),
        (&["bench", "bake", "--reps", "0"], "--reps"),
    ];
    for (args, flag) in cases {
        let r = Command::new(env!("CARGO_BIN_EXE_fipt-train"))
            .args(*args)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&r.stderr);
        assert!(!r.status.success(), "{args:?} was accepted");
        assert!(
            err.contains(flag) && !err.contains("panicked"),
            "{args:?}: {err}"
        );
        assert!(!out.exists(), "{args:?} wrote {}", out.display());
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
