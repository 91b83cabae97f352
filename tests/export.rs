//! `fipt-train export`, end to end: the glTF files pass the Khronos validator, the Mitsuba scene
//! renders with Mitsuba 3 and matches the photos, σ and a reach the textures as the mapping in
//! `docs/export.md` says, materials follow the parts, and bad input writes nothing.
//!
//! Needs the external checkers that `bash .ci/test` installs: the npm package `gltf-validator`
//! (folder `$FIPT_GLTF_VALIDATOR`, default `~/.cache/fipt-tools/npm`) and Mitsuba 3.9.1 in a
//! Python environment (`$FIPT_MITSUBA_PYTHON`, default `~/.cache/fipt-tools/mitsuba/bin/python`).

mod common;

use common::{scene_dir, tmp_dir};
use fipt_bake::emitters::Emitter;
use fipt_bake::lightfield::LightField;
use fipt_core::model::{HashGridConfig, MaterialFieldConfig, TrainConfig, Trainer};
use fipt_core::scene::meta::SceneMeta;
use fipt_core::scene::{Mesh, SceneBox};
use glam::Vec3;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;

fn fipt() -> Command {
    Command::new(env!("CARGO_BIN_EXE_fipt-train"))
}

fn tool_path(var: &str, default: &str) -> PathBuf {
    std::env::var_os(var)
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(std::env::var("HOME").unwrap_or_default()).join(default))
}

/// Runs the Khronos validator on `file`; returns its report.
fn validate(file: &Path) -> Value {
    let npm = tool_path("FIPT_GLTF_VALIDATOR", ".cache/fipt-tools/npm");
    assert!(
        npm.join("node_modules/gltf-validator").is_dir(),
        "{}: no gltf-validator (bash .ci/test installs it; or set FIPT_GLTF_VALIDATOR)",
        npm.display()
    );
    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../tests/gltf/validate.js");
    let o = Command::new("node")
        .arg(&script)
        .arg(file)
        .env("NODE_PATH", npm.join("node_modules"))
        .output()
        .expect("node");
    let text = String::from_utf8_lossy(&o.stdout);
    serde_json::from_str(text.trim()).unwrap_or_else(|e| {
        panic!(
            "{}: no report ({e}): {text} {}",
            file.display(),
            String::from_utf8_lossy(&o.stderr)
        )
    })
}

fn export(args: &[&str]) -> std::process::Output {
    fipt().arg("export").args(args).output().unwrap()
}

fn ok(o: &std::process::Output) -> Value {
    assert!(
        o.status.success(),
        "export failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    serde_json::from_slice(&o.stdout).unwrap()
}

/// Decodes an 8-bit PNG of the export.
fn png(path: &Path) -> image::DynamicImage {
    image::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// Renders `views` of the Mitsuba export in `out` with Mitsuba 3 (a quarter of the pixels, 128
/// spp) and scores them against the photos in `refs`: the mean PSNR and the trivial predictor's.
fn mitsuba_psnr(out: &Path, views: &str, refs: &Path) -> (f64, f64) {
    let python = tool_path(
        "FIPT_MITSUBA_PYTHON",
        ".cache/fipt-tools/mitsuba/bin/python",
    );
    assert!(
        python.exists(),
        "{}: no Python with Mitsuba 3 (bash .ci/test installs it; or set FIPT_MITSUBA_PYTHON)",
        python.display()
    );
    let script =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../tests/mitsuba/render_export.py");
    let o = Command::new(&python)
        .arg(&script)
        .arg(out.join("scene.xml"))
        .args(["--out", out.join("mitsuba").to_str().unwrap()])
        .args(["--views", views, "--spp", "128", "--scale", "2"])
        .args(["--reference", refs.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let m: Value = serde_json::from_slice(&o.stdout).unwrap();
    let key = refs.to_str().unwrap();
    (
        m["mean_psnr"][key].as_f64().unwrap(),
        m["mean_trivial_psnr"][key].as_f64().unwrap(),
    )
}

/// The true scene of fipt-room: every glTF file validates with 0 errors; one material per part
/// and per emitting part; σ, m and a land in the textures at each part's triangles with the
/// documented mapping (glTF roughness = σ, metallic = m, base colour sRGB-encoded); the Mitsuba
/// scene renders the val views close to the photos, far above the trivial predictor.
#[test]
fn truth_export_validates_maps_and_renders() {
    let scene = scene_dir();
    let out = tmp_dir("export-truth");
    let r = ok(&export(&[
        "--truth",
        "--scene",
        scene.to_str().unwrap(),
        "--format",
        "glb,gltf,mitsuba",
        "--texels",
        "512",
        "--out",
        out.to_str().unwrap(),
        "--json",
    ]));
    for f in ["scene.glb", "scene.gltf"] {
        let v = validate(&out.join(f));
        assert_eq!(v["errors"], 0, "{f}: {v}");
    }
    let meta = SceneMeta::load(&scene.join("scene_meta.json")).unwrap();
    let names: Vec<&str> = r["materials"]
        .as_array()
        .unwrap()
        .iter()
        .map(|m| m["name"].as_str().unwrap())
        .collect();
    for p in &meta.parts {
        let want = if p.emission.is_some() {
            format!("{}.light", p.name)
        } else {
            p.name.clone()
        };
        assert!(names.contains(&want.as_str()), "{want} not in {names:?}");
    }
    assert_eq!(r["cameras"], 8);

    // The maps at each part: rasterise the glTF's own UVs, read the texel at each triangle's
    // UV centroid.
    let doc: Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("scene.gltf")).unwrap()).unwrap();
    let bin = std::fs::read(out.join("scene.bin")).unwrap();
    let mr = png(&out.join("textures/metallic_roughness.png")).to_rgb8();
    let base = png(&out.join("textures/base_color.png")).to_rgb8();
    let size = mr.width() as f32;
    let mut checked = 0;
    for prim in doc["meshes"][0]["primitives"].as_array().unwrap() {
        let mat = &doc["materials"][prim["material"].as_u64().unwrap() as usize];
        let name = mat["name"].as_str().unwrap();
        let Some(part) = meta.parts.iter().find(|p| p.name == name) else {
            continue; // an emitter group: no reflectance maps
        };
        let acc = |k: &str| &doc["accessors"][prim[k].as_u64().unwrap() as usize];
        let read = |a: &Value, comps: usize| -> Vec<f32> {
            let view = &doc["bufferViews"][a["bufferView"].as_u64().unwrap() as usize];
            let off = view["byteOffset"].as_u64().unwrap() as usize
                + a["byteOffset"].as_u64().unwrap_or(0) as usize;
            let n = a["count"].as_u64().unwrap() as usize * comps;
            bin[off..off + 4 * n]
                .chunks_exact(4)
                .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
                .collect()
        };
        let uv_acc = &doc["accessors"][prim["attributes"]["TEXCOORD_0"].as_u64().unwrap() as usize];
        let uv = read(uv_acc, 2);
        let ia = acc("indices");
        let view = &doc["bufferViews"][ia["bufferView"].as_u64().unwrap() as usize];
        let off = view["byteOffset"].as_u64().unwrap() as usize
            + ia["byteOffset"].as_u64().unwrap() as usize;
        let idx: Vec<u32> = bin[off..off + 4 * ia["count"].as_u64().unwrap() as usize]
            .chunks_exact(4)
            .map(|b| u32::from_le_bytes(b.try_into().unwrap()))
            .collect();
        let m = &part.material;
        for tri in idx.chunks_exact(3) {
            let c =
                |k: usize| glam::Vec2::new(uv[2 * tri[k] as usize], uv[2 * tri[k] as usize + 1]);
            let p = (c(0) + c(1) + c(2)) / 3.0 * size;
            let px = mr.get_pixel(p.x as u32, p.y as u32);
            assert!(
                (px[1] as f32 / 255.0 - m.roughness).abs() <= 0.6 / 255.0,
                "{name}: roughness {} against σ {}",
                px[1],
                m.roughness
            );
            assert!(
                (px[2] as f32 / 255.0 - m.metallic).abs() <= 0.6 / 255.0,
                "{name}: metallic"
            );
            if let (Some(a), None) = (m.base_color, &m.texture) {
                let b = base.get_pixel(p.x as u32, p.y as u32);
                for ch in 0..3 {
                    assert_eq!(
                        b[ch],
                        fipt_train::export::srgb8(a[ch]),
                        "{name}: base colour"
                    );
                }
            }
            checked += 1;
        }
    }
    assert!(checked > 1000, "{checked} triangles checked");

    // Mitsuba renders the exported truth: at a quarter of the pixels and 128 spp, the val views
    // against the photos.
    let (psnr, trivial) = mitsuba_psnr(&out, "0,3", &scene.join("val/Image"));
    println!("Mitsuba's render of the exported truth: {psnr:.2} dB (trivial {trivial:.2})");
    assert!(
        psnr > 25.0 && psnr > trivial + 8.0,
        "{psnr} dB, trivial {trivial} dB"
    );
    let _ = std::fs::remove_dir_all(&out);
}

/// `--split train`: the training views become the cameras, named `train_NNN`, and Mitsuba's
/// renders of them match the training photos (a camera taken from the wrong split, or mapped
/// wrongly, renders another view and scores near the trivial predictor); the true emitters
/// carry their material.
#[test]
fn truth_export_of_the_train_views_renders_the_photos() {
    let scene = scene_dir();
    let out = tmp_dir("export-train");
    let r = ok(&export(&[
        "--truth",
        "--scene",
        scene.to_str().unwrap(),
        "--format",
        "mitsuba",
        "--split",
        "train",
        "--texels",
        "512",
        "--out",
        out.to_str().unwrap(),
        "--json",
    ]));
    assert_eq!(r["cameras"], 48);
    let xml = std::fs::read_to_string(out.join("scene.xml")).unwrap();
    assert!(xml.contains("\"train_047\"") && !xml.contains("\"val_000\""));
    // The true emitters reflect with their own material, as the photos' do.
    let emitting: Vec<&str> = xml
        .split("<shape")
        .filter(|s| s.contains("<emitter"))
        .collect();
    assert!(!emitting.is_empty());
    assert!(emitting.iter().all(|s| s.contains("\"principled\"")));
    let (psnr, trivial) = mitsuba_psnr(&out, "0,1", &scene.join("train/Image"));
    println!("Mitsuba's render of train views 0 and 1: {psnr:.2} dB (trivial {trivial:.2})");
    assert!(
        psnr > 22.0 && psnr > trivial + 12.0,
        "{psnr} dB, trivial {trivial} dB"
    );
    let _ = std::fs::remove_dir_all(&out);
}

/// A scene model on fipt-room's mesh (a random field, three emitting triangles): exported to
/// .glb beside its recovered scene's parts and cameras; the emitters' strengths are their
/// largest radiance; the file validates.
#[test]
fn model_export_carries_emitters_and_validates() {
    let scene = scene_dir();
    let root = tmp_dir("export-model");
    let mesh = Mesh::load_obj(&scene.join("scene.obj")).unwrap();
    let (lo, hi) = mesh.bounds();
    let sb = SceneBox {
        min: lo.min_element() - 0.1,
        max: hi.max_element() + 0.1,
    };
    let cfg = TrainConfig::new().with_material(
        MaterialFieldConfig::new()
            .with_grid(HashGridConfig::new().with_levels(6).with_log2_table(12)),
    );
    let model = Trainer::new(cfg, sb, &burn::tensor::Device::flex(), 3).model;
    let meta = SceneMeta::load(&scene.join("scene_meta.json")).unwrap();
    let lamp = meta.parts.iter().find(|p| p.emission.is_some()).unwrap();
    let t0 = lamp.triangles[0];
    let em: Vec<Emitter> = (0..3)
        .map(|k| Emitter {
            pixels: 10,
            seen_front: 10,
            ..Emitter::on_triangle(&mesh, t0 + k, [4.0 + k as f32, 3.0, 2.0])
        })
        .collect();
    let lf = LightField::build(
        sb,
        16,
        mesh.vertices.iter().map(|&p| (p, Vec3::Y, [1.0, 1.0, 1.0])),
    );
    let cfg_json = serde_json::json!({"seed": 3});
    let dir = root.join("model");
    fipt_train::scene_model::save(
        &dir,
        &model,
        &mesh,
        &em,
        &lf,
        &fipt_train::scene_model::SaveInfo {
            name: "room-random",
            scene: &scene,
            image_size: [32, 24],
            seed: 3,
            metrics: Default::default(),
            config: &cfg_json,
            run_metrics: &cfg_json,
        },
    )
    .unwrap();
    let out = root.join("out");
    let r = ok(&export(&[
        "--model",
        dir.to_str().unwrap(),
        "--format",
        "glb",
        "--texels",
        "256",
        "--out",
        out.to_str().unwrap(),
        "--json",
    ]));
    assert_eq!(r["emitter_triangles"], 3);
    assert_eq!(r["cameras"], 8);
    let light = r["materials"]
        .as_array()
        .unwrap()
        .iter()
        .find(|m| m["emitter"] == true)
        .unwrap();
    assert_eq!(light["name"], format!("{}.light", lamp.name));
    assert_eq!(light["strength"], 6.0);
    let v = validate(&out.join("scene.glb"));
    assert_eq!(v["errors"], 0, "{v}");
    let glb = std::fs::read(out.join("scene.glb")).unwrap();
    let doc = fipt_train::export::gltf::glb_json(&glb).unwrap();
    assert_eq!(doc["cameras"].as_array().unwrap().len(), 8);
    assert_eq!(doc["extensionsUsed"][0], "KHR_materials_emissive_strength");

    // A damaged model: the file is named, nothing is written.
    let fields = dir.join("fields.bpk");
    let mut bytes = std::fs::read(&fields).unwrap();
    bytes.truncate(bytes.len() / 2);
    std::fs::write(&fields, bytes).unwrap();
    let out2 = root.join("out2");
    let o = export(&[
        "--model",
        dir.to_str().unwrap(),
        "--format",
        "glb",
        "--out",
        out2.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("fields.bpk"), "{err}");
    assert!(!out2.exists());
    let _ = std::fs::remove_dir_all(&root);
}

/// A texel budget out of range names the flag; an OUT that cannot be created is named, and
/// nothing is left behind.
#[test]
fn bad_flags_and_unwritable_out_are_refused() {
    let scene = scene_dir();
    let root = tmp_dir("export-bad");
    let out = root.join("out");
    let s = scene.to_str().unwrap();
    for texels in ["16", "100000"] {
        let o = export(&[
            "--truth",
            "--scene",
            s,
            "--format",
            "glb",
            "--texels",
            texels,
            "--out",
            out.to_str().unwrap(),
        ]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && err.contains("--texels"), "{err}");
    }
    let blocker = root.join("file");
    std::fs::write(&blocker, "not a folder").unwrap();
    let bad_out = blocker.join("out");
    let o = export(&[
        "--truth",
        "--scene",
        s,
        "--format",
        "mitsuba",
        "--texels",
        "128",
        "--out",
        bad_out.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains(&*bad_out.to_string_lossy()),
        "{err}"
    );
    assert!(!out.exists());
    let names: Vec<_> = std::fs::read_dir(&root).unwrap().collect();
    assert_eq!(names.len(), 1);
    let _ = std::fs::remove_dir_all(&root);
}

/// Headless Chromium (`$FIPT_CHROMIUM`, else `chromium` on PATH; `bash .ci/test` installs it)
/// with WebGL on SwiftShader.
fn chromium() -> Command {
    let exe = std::env::var_os("FIPT_CHROMIUM").unwrap_or_else(|| "chromium".into());
    let mut c = Command::new(exe);
    c.args([
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--use-angle=swiftshader",
        "--enable-unsafe-swiftshader",
        "--hide-scrollbars",
        "--enable-logging=stderr",
        "--v=0",
        "--virtual-time-budget=10000",
        "--window-size=960,640",
    ]);
    c
}

/// The viewer export opens from `file://` in headless Chromium: it draws (`data-ready`), counts
/// no error of its own (`data-errors` 0: script errors, `console.error`, WebGL errors, rejected
/// promises), the browser's console shows no error, and the screenshot shows the scene, not a
/// blank canvas.
#[test]
fn viewer_loads_in_headless_chromium() {
    let scene = scene_dir();
    let out = tmp_dir("export-viewer");
    ok(&export(&[
        "--truth",
        "--scene",
        scene.to_str().unwrap(),
        "--format",
        "viewer",
        "--texels",
        "256",
        "--out",
        out.to_str().unwrap(),
        "--json",
    ]));
    let page = format!(
        "file://{}#view=3&show=base",
        out.join("viewer.html").display()
    );
    // Headless Chromium's virtual time runs on while the browser decodes the page's textures off
    // its main thread, so on a busy machine the DOM may be dumped, or the screenshot taken,
    // before the first frame: each is tried up to `TRIES` times. An error the page counts fails
    // at once.
    const TRIES: usize = 5;
    let mut ready = false;
    for attempt in 1..=TRIES {
        let o = chromium()
            .arg("--dump-dom")
            .arg(&page)
            .output()
            .unwrap_or_else(|e| {
                panic!("chromium: {e} (bash .ci/test installs it; or set FIPT_CHROMIUM)")
            });
        let dom = String::from_utf8_lossy(&o.stdout);
        let log = String::from_utf8_lossy(&o.stderr);
        let body = dom
            .lines()
            .find(|l| l.contains("<body"))
            .unwrap_or_default();
        assert!(body.contains("data-errors=\"0\""), "{body}\n{log}");
        // The browser's console: no uncaught exception, failed load or error (WebGL's
        // performance notes from SwiftShader are not errors).
        for line in log
            .lines()
            .filter(|l| l.contains("CONSOLE") && !l.contains("GL Driver Message"))
        {
            assert!(
                !["Uncaught", "Failed", "Error", "error"]
                    .iter()
                    .any(|w| line.contains(w)),
                "{line}"
            );
        }
        ready = body.contains("data-ready=\"1\"");
        if ready {
            break;
        }
        eprintln!("try {attempt}: the page had not drawn yet: {body}");
    }
    assert!(ready, "the page never drew in {TRIES} tries");
    let shot = out.join("shot.png");
    let mut colours = std::collections::HashSet::new();
    for attempt in 1..=TRIES {
        let o = chromium()
            .arg(format!("--screenshot={}", shot.display()))
            .arg(&page)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let img = png(&shot).to_rgb8();
        // Below the tool bar: many distinct colours (a blank canvas has one).
        colours.clear();
        for y in (80..img.height()).step_by(7) {
            for x in (0..img.width()).step_by(7) {
                colours.insert(img.get_pixel(x, y).0);
            }
        }
        if colours.len() > 20 {
            break;
        }
        eprintln!("try {attempt}: {} colours in the canvas", colours.len());
    }
    assert!(
        colours.len() > 20,
        "{} colours in the canvas",
        colours.len()
    );
    let _ = std::fs::remove_dir_all(&out);
}
