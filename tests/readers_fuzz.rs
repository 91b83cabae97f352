//! Property tests of every reader of files fipt did not write in this run, on damaged input:
//! scene folders (each layout), `scene_meta.json`, `relight.json`, run configs, the shading
//! cache, zoo scene models, L′ bytes, the table optimiser's state, EXR images and OBJ meshes
//! (checkpoint folders: `pipeline::checkpoint`'s own test). Each case starts from a small valid input built once per test
//! and damages one file: a random truncation, a flipped byte, a huge little-endian u32/u64
//! written over it, or, for text, an empty file, a number replaced by NaN / Infinity / 1e308 /
//! -1 / a huge integer, a JSON key (or a line) removed, a key renamed (or a line doubled).
//!
//! Every reader must return a value or an error, never panic (`catch_unwind`), and never make a
//! huge allocation from a size field (a counting global allocator records the largest single
//! allocation of each call). A truncation that removes content is an error, and an error names
//! the damaged file. A fixed seed and a fixed number of cases per reader keep CI time bounded
//! and runs repeatable.

use fipt_bake::emitters::Emitter;
use fipt_bake::lightfield::LightField;
use fipt_core::model::hashgrid::TableAdam;
use fipt_core::model::{
    EmissionMaskConfig, FiptModel, HashGridConfig, MaterialFieldConfig, ModelSpec,
};
use fipt_core::scene::dataset::{Layout, LoadOptions, MapKind, load_cameras};
use fipt_core::scene::insert::load_insert;
use fipt_core::scene::meta::{Relight, SceneMeta};
use fipt_core::scene::{Camera, Dataset, Image, Mesh, SceneBox};
use fipt_core::shading::ShadingLayout;
use fipt_train::config::Config;
use fipt_train::scene_model::{self, Headline, Manifest, SaveInfo, SceneModel};
use glam::{DVec3, Vec3};
use proptest::prelude::*;
use proptest::test_runner::{RngSeed, TestCaseResult, TestRunner};
use serde_json::{Value, json};
use std::alloc::{GlobalAlloc, System};
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Mutex, Once, OnceLock};

// ---------------------------------------------------------------------------------------------
// Allocation watch and quiet panics.

/// The global allocator of this test binary: the system's, recording the largest single
/// allocation (or reallocation) since the last reset.
struct Watch;

static BIGGEST: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Watch {
    unsafe fn alloc(&self, layout: std::alloc::Layout) -> *mut u8 {
        BIGGEST.fetch_max(layout.size(), Ordering::Relaxed);
        unsafe { System.alloc(layout) }
    }

    unsafe fn alloc_zeroed(&self, layout: std::alloc::Layout) -> *mut u8 {
        BIGGEST.fetch_max(layout.size(), Ordering::Relaxed);
        unsafe { System.alloc_zeroed(layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: std::alloc::Layout, new_size: usize) -> *mut u8 {
        BIGGEST.fetch_max(new_size, Ordering::Relaxed);
        unsafe { System.realloc(ptr, layout, new_size) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: std::alloc::Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static WATCH: Watch = Watch;

/// The largest single allocation a reader may make on these inputs (a few KiB each). The
/// largest by design is L′'s top grid at its highest accepted resolution (4096³ voxels:
/// 512³ u32 = 512 MiB); anything above this limit came from an unchecked size field.
const ALLOC_LIMIT: usize = 600 << 20;

/// Calls in progress whose panics are expected and kept quiet (the decoders' caught panics
/// included); outside them the default hook prints as usual.
static QUIET: AtomicUsize = AtomicUsize::new(0);
static LAST_PANIC: Mutex<String> = Mutex::new(String::new());

fn quiet_hook() {
    static HOOK: Once = Once::new();
    HOOK.call_once(|| {
        let default = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if QUIET.load(Ordering::SeqCst) > 0 {
                *LAST_PANIC.lock().unwrap_or_else(|e| e.into_inner()) = info.to_string();
            } else {
                default(info);
            }
        }));
    });
}

/// Runs a reader: its value, or the message of a panic that escaped it.
fn guarded<T>(f: impl FnOnce() -> T) -> (Result<T, String>, usize) {
    quiet_hook();
    QUIET.fetch_add(1, Ordering::SeqCst);
    BIGGEST.store(0, Ordering::SeqCst);
    let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(f));
    let biggest = BIGGEST.load(Ordering::SeqCst);
    QUIET.fetch_sub(1, Ordering::SeqCst);
    let r = r.map_err(|_| LAST_PANIC.lock().unwrap_or_else(|e| e.into_inner()).clone());
    (r, biggest)
}

/// `guarded`, failing the case on a panic or an allocation over `ALLOC_LIMIT`.
fn sound<T>(what: &str, f: impl FnOnce() -> T) -> Result<T, TestCaseError> {
    let (r, biggest) = guarded(f);
    let v = r.map_err(|p| TestCaseError::fail(format!("{what}: panicked: {p}")))?;
    prop_assert!(
        biggest <= ALLOC_LIMIT,
        "{what}: allocated {biggest} bytes at once"
    );
    Ok(v)
}

// ---------------------------------------------------------------------------------------------
// Damage.

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

/// Damage of a text file: byte damage, or damage that keeps it text.
#[derive(Clone, Debug)]
enum TextDamage {
    Bytes(Damage),
    /// An empty file.
    Empty,
    /// The `k`-th number (modulo their count) replaced by the given text.
    Number(usize, &'static str),
    /// JSON: the `k`-th key (modulo their count, depth first) removed with its value;
    /// other text: line `k` removed.
    DeleteKey(usize),
    /// JSON: the `k`-th key renamed; other text: line `k` doubled.
    RenameKey(usize),
}

/// What a number is replaced with: non-finite, out of range, huge integers (the first fits a
/// u64, the next ones only wider types), and other JSON types.
const REPLACEMENTS: &[&str] = &[
    "NaN",
    "Infinity",
    "-Infinity",
    "1e308",
    "-1e308",
    "1e-320",
    "-1",
    "0",
    "4294967296",
    "9223372036854775807",
    "18446744073709551616",
    "123456789012345678901234567890",
    "\"x\"",
    "null",
    "[]",
    "{}",
    "true",
];

fn text_damage() -> impl Strategy<Value = TextDamage> {
    // The first number of a file is often a count or a size: it gets a quarter of the picks.
    let index = prop_oneof![1 => Just(0usize), 3 => any::<usize>()];
    prop_oneof![
        3 => damage().prop_map(TextDamage::Bytes),
        1 => Just(TextDamage::Empty),
        4 => (index, proptest::sample::select(REPLACEMENTS))
            .prop_map(|(k, r)| TextDamage::Number(k, r)),
        1 => any::<usize>().prop_map(TextDamage::DeleteKey),
        1 => any::<usize>().prop_map(TextDamage::RenameKey),
    ]
}

/// Byte ranges of the numbers of `text`: runs of `0-9 . e E + -` holding a digit that are not
/// part of a word (so not the digits of `Image/000_0001`).
fn number_tokens(text: &str) -> Vec<Range<usize>> {
    let b = text.as_bytes();
    let num = |c: u8| c.is_ascii_digit() || b".eE+-".contains(&c);
    let word = |c: u8| c.is_ascii_alphanumeric() || c == b'_' || c == b'/';
    let mut out = Vec::new();
    let mut i = 0;
    while i < b.len() {
        if num(b[i]) && (i == 0 || !word(b[i - 1])) {
            let mut j = i;
            while j < b.len() && num(b[j]) {
                j += 1;
            }
            if b[i..j].iter().any(u8::is_ascii_digit) && (j == b.len() || !word(b[j])) {
                out.push(i..j);
            }
            i = j.max(i + 1);
        } else {
            i += 1;
        }
    }
    out
}

fn count_keys(v: &Value) -> usize {
    match v {
        Value::Object(o) => o.len() + o.values().map(count_keys).sum::<usize>(),
        Value::Array(a) => a.iter().map(count_keys).sum(),
        _ => 0,
    }
}

/// Removes (or renames) the `left`-th key of `v`, depth first.
fn edit_key(v: &mut Value, left: &mut usize, rename: bool) -> bool {
    match v {
        Value::Object(o) => {
            if *left < o.len() {
                let key = o.keys().nth(*left).cloned().unwrap_or_default();
                if let Some(val) = o.remove(&key)
                    && rename
                {
                    o.insert(format!("{key}_renamed"), val);
                }
                return true;
            }
            *left -= o.len();
            o.values_mut().any(|x| edit_key(x, left, rename))
        }
        Value::Array(a) => a.iter_mut().any(|x| edit_key(x, left, rename)),
        _ => false,
    }
}

fn apply_text(good: &str, d: &TextDamage) -> Vec<u8> {
    match d {
        TextDamage::Bytes(b) => apply(good.as_bytes(), b),
        TextDamage::Empty => Vec::new(),
        TextDamage::Number(k, r) => {
            let t = number_tokens(good);
            if t.is_empty() {
                return good.as_bytes().to_vec();
            }
            let mut s = good.to_string();
            s.replace_range(t[k % t.len()].clone(), r);
            s.into_bytes()
        }
        TextDamage::DeleteKey(k) | TextDamage::RenameKey(k) => {
            let rename = matches!(d, TextDamage::RenameKey(_));
            if let Ok(mut v) = serde_json::from_str::<Value>(good) {
                let n = count_keys(&v);
                if n > 0 {
                    edit_key(&mut v, &mut (k % n), rename);
                }
                return serde_json::to_string_pretty(&v).unwrap().into_bytes();
            }
            let mut lines: Vec<&str> = good.split_inclusive('\n').collect();
            if !lines.is_empty() {
                let i = k % lines.len();
                if rename {
                    lines.insert(i, lines[i]);
                } else {
                    lines.remove(i);
                }
            }
            lines.concat().into_bytes()
        }
    }
}

/// True when the damage cut content (not only trailing white space) off `good`, or emptied it:
/// every reader must then refuse the file.
fn cuts_content(good: &[u8], bad: &[u8], d: &TextDamage) -> bool {
    match d {
        TextDamage::Empty => true,
        TextDamage::Bytes(Damage::Truncate(_)) => {
            good[bad.len()..].iter().any(|c| !c.is_ascii_whitespace())
        }
        _ => false,
    }
}

// ---------------------------------------------------------------------------------------------
// Shared set-up.

/// This test's scratch folder (one per test and process).
fn scratch(test: &str) -> PathBuf {
    std::env::temp_dir().join(format!("fipt-rfuzz-{test}-{}", std::process::id()))
}

fn config(cases: u32) -> ProptestConfig {
    ProptestConfig {
        cases,
        failure_persistence: None,
        rng_seed: RngSeed::Fixed(0x5eed),
        ..ProptestConfig::default()
    }
}

/// Runs `cases` cases of `test`, then removes the scratch folder `dir`.
fn check<S: Strategy>(
    cases: u32,
    dir: &Path,
    strategy: S,
    test: impl Fn(S::Value) -> TestCaseResult,
) {
    let mut runner = TestRunner::new(config(cases));
    let result = runner.run(&strategy, test);
    let _ = std::fs::remove_dir_all(dir);
    if let Err(e) = result {
        panic!("{e}");
    }
}

/// Writes `bytes` over `path`, runs `f`, and puts the original back.
fn with_file<T>(path: &Path, bytes: &[u8], f: impl FnOnce() -> T) -> T {
    let good = std::fs::read(path).unwrap();
    std::fs::write(path, bytes).unwrap();
    let r = f();
    std::fs::write(path, good).unwrap();
    r
}

fn write(path: &Path, bytes: impl AsRef<[u8]>) {
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    std::fs::write(path, bytes).unwrap();
}

/// The file at `path` damaged (text damage for a text file, byte damage else), and whether
/// the damage cut content.
fn damaged(path: &Path, td: &TextDamage, bd: &Damage) -> (Vec<u8>, bool) {
    let good = std::fs::read(path).unwrap();
    if is_text(path) {
        let bad = apply_text(std::str::from_utf8(&good).unwrap(), td);
        let cut = cuts_content(&good, &bad, td);
        (bad, cut)
    } else {
        (apply(&good, bd), matches!(bd, Damage::Truncate(_)))
    }
}

fn is_text(path: &Path) -> bool {
    path.extension()
        .is_some_and(|e| e == "json" || e == "obj" || e == "txt")
}

// ---------------------------------------------------------------------------------------------
// Scene folders.

const W: usize = 8;
const H: usize = 6;

/// A tetrahedron: 4 triangles.
const TETRA: &str =
    "# fuzz tetrahedron\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n";

fn meta_json() -> Value {
    json!({
        "scene": "fuzz",
        "semantic_labels": ["wall", "lamp"],
        "parts": [
            {"id": 0, "name": "wall", "semantic": "wall", "semantic_id": 0, "triangles": [0, 3],
             "area": 1.5, "material": {"base_color": [0.5, 0.4, 0.3], "roughness": 0.5, "metallic": 0.0}},
            {"id": 1, "name": "lamp", "semantic": "lamp", "semantic_id": 1, "triangles": [3, 4],
             "area": 0.5, "material": {"base_color": null, "roughness": 1.0, "metallic": 0.0},
             "emission": {"radiance": [5.0, 4.0, 3.0], "side": "front"}}
        ],
        "resolution": [W, H],
        "camera_angle_x": 0.9
    })
}

fn relight_json() -> Value {
    json!({
        "emitters_off": ["lamp"],
        "emitters_scale": {"all": 0.5, "lamp": 2.0},
        "new_emitter": {"name": "panel", "vertices": [[0.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 1.0]],
            "triangles": [[0, 1, 2]], "radiance": [3.0, 3.0, 3.0],
            "bsdf": {"base_color": [0.8, 0.8, 0.8], "roughness": 0.3, "metallic": 0.0}},
        "new_emitters": [{"name": "spot", "vertices": [[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, 1.0, 1.0], [1.0, 1.0, 1.0]],
            "triangles": [[0, 1, 2], [1, 3, 2]], "radiance": [1.0, 2.0, 3.0]}]
    })
}

fn cameras() -> Vec<Camera> {
    [(2.0, 1.5, 2.5), (-1.5, 1.0, 2.0)]
        .iter()
        .map(|&(x, y, z)| {
            Camera::look_at_fov(DVec3::new(x, y, z), DVec3::splat(0.3), DVec3::Y, 0.9, W, H)
        })
        .collect()
}

fn photo(k: usize) -> Image {
    let data = (0..W * H * 3).map(|i| (i + 7 * k) as f32 * 0.01).collect();
    Image::from_data(W, H, 3, data)
}

fn label_map() -> Image {
    Image::from_data(W, H, 1, (0..W * H).map(|i| (i % 3) as f32).collect())
}

/// A tiny valid scene folder of one layout: the tetrahedron, 2 views of 8×6 pixels with
/// DiffCol and segmentation maps, and `scene_meta.json`.
struct Scene {
    dir: PathBuf,
    /// The layout's camera files.
    cameras: Vec<PathBuf>,
    /// Every EXR file of the scene.
    exrs: Vec<PathBuf>,
}

fn opts() -> LoadOptions {
    LoadOptions {
        maps: vec![MapKind::DiffCol, MapKind::Segmentation],
        val: true,
    }
}

fn build_scene(layout: Layout) -> Scene {
    let dir = scratch(&format!("{layout:?}").to_lowercase()).join("scene");
    let _ = std::fs::remove_dir_all(&dir);
    write(&dir.join("scene.obj"), TETRA);
    write(
        &dir.join("scene_meta.json"),
        serde_json::to_string_pretty(&meta_json()).unwrap(),
    );
    let cams = cameras();
    let mut exrs = Vec::new();
    let mut exr = |path: PathBuf, img: &Image| {
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        img.write_exr(&path).unwrap();
        exrs.push(path);
    };
    let cameras = match layout {
        Layout::FiptSynthetic => {
            let frames: Vec<Value> = cams
                .iter()
                .enumerate()
                .map(|(k, c)| json!({"file_path": format!("Image/{k:03}_0001"), "transform_matrix": c.to_fipt_c2w()}))
                .collect();
            let t = dir.join("train/transforms.json");
            write(
                &t,
                serde_json::to_string_pretty(&json!({"camera_angle_x": 0.9, "frames": frames}))
                    .unwrap(),
            );
            for k in 0..cams.len() {
                exr(dir.join(format!("train/Image/{k:03}_0001.exr")), &photo(k));
                exr(
                    dir.join(format!("train/DiffCol/{k:03}_0001.exr")),
                    &photo(k + 1),
                );
                exr(
                    dir.join(format!("train/segmentation/{k:03}.exr")),
                    &label_map(),
                );
            }
            vec![t]
        }
        Layout::FiptReal => {
            let v3 = |v: DVec3| format!("{:?} {:?} {:?}\n", v.x, v.y, v.z);
            let (mut cam, mut kl) = (format!("{}\n", cams.len()), format!("{}\n", cams.len()));
            for c in &cams {
                let (down, fwd) = (c.rotation.y_axis, c.rotation.z_axis);
                cam += &(v3(c.origin) + &v3(c.origin + 2.5 * fwd) + &v3(-down));
                kl += &format!("{:?} 0 {:?}\n0 {:?} {:?}\n0 0 1\n", c.fx, c.cx, c.fy, c.cy);
            }
            let (cp, kp) = (dir.join("cam.txt"), dir.join("K_list.txt"));
            write(&cp, cam);
            write(&kp, kl);
            for k in 0..cams.len() {
                exr(dir.join(format!("Image/{k:03}_0001.exr")), &photo(k));
                exr(dir.join(format!("DiffCol/{k:03}_0001.exr")), &photo(k + 1));
                exr(dir.join(format!("segmentation/{k:03}.exr")), &label_map());
            }
            vec![cp, kp]
        }
        Layout::Nerfstudio => {
            let frames: Vec<Value> = cams
                .iter()
                .enumerate()
                .map(|(k, c)| {
                    let m = c.to_opengl_c2w();
                    let ext = if k == 0 { ".exr" } else { "" };
                    json!({"file_path": format!("images/{k:03}_0001{ext}"), "transform_matrix": m})
                })
                .collect();
            let c0 = &cams[0];
            let t = dir.join("transforms.json");
            let body = json!({
                "camera_model": "OPENCV",
                "fl_x": c0.fx, "fl_y": c0.fy, "cx": c0.cx, "cy": c0.cy, "w": W, "h": H,
                "frames": frames,
            });
            write(&t, serde_json::to_string_pretty(&body).unwrap());
            for k in 0..cams.len() {
                exr(dir.join(format!("images/{k:03}_0001.exr")), &photo(k));
                exr(
                    dir.join(format!("segmentation/{k:03}_0001.exr")),
                    &label_map(),
                );
            }
            vec![t]
        }
    };
    let ds = Dataset::load(&dir, &opts()).unwrap();
    assert_eq!(ds.layout, layout);
    assert_eq!(ds.train.views.len(), 2);
    assert!(ds.train.has_map(MapKind::Segmentation));
    assert!(ds.meta.is_some());
    Scene { dir, cameras, exrs }
}

/// One case of a scene folder: which file (camera file, OBJ, an EXR, `scene_meta.json`),
/// which of several, and the damage (text damage for text files, byte damage for EXRs).
fn dataset_case(
    scene: &Scene,
    (which, pick, td, bd): (usize, usize, TextDamage, Damage),
) -> TestCaseResult {
    let path = match which {
        0 => scene.cameras[pick % scene.cameras.len()].clone(),
        1 => scene.dir.join("scene.obj"),
        2 => scene.exrs[pick % scene.exrs.len()].clone(),
        _ => scene.dir.join("scene_meta.json"),
    };
    let (bad, cut) = damaged(&path, &td, &bd);
    let what = if is_text(&path) {
        format!("{} damaged by {td:?}", path.display())
    } else {
        format!("{} damaged by {bd:?}", path.display())
    };
    let r = with_file(&path, &bad, || {
        sound(&what, || Dataset::load(&scene.dir, &opts()).map(|_| ()))
    })?;
    // An OBJ or a `cam.txt` cut between lines (or inside a number) can stay valid.
    let json = path.extension().is_some_and(|e| e == "json");
    let must_fail = cut && (which == 2 || json);
    if must_fail {
        prop_assert!(r.is_err(), "{what}: accepted");
    }
    if which == 0 && json {
        // The same file as new cameras to render (`render --cameras`).
        let cams = with_file(&path, &bad, || {
            sound(&what, || load_cameras(&path, (W, H)).map(|_| ()))
        })?;
        if cut {
            prop_assert!(cams.is_err(), "{what}: load_cameras accepted");
        }
        if let Err(e) = cams {
            prop_assert!(
                e.path == path,
                "{what}: load_cameras names another file: {e}"
            );
        }
    }
    if let Err(e) = r {
        // The error names the damaged file, or for an image, the image whose size no longer
        // matches the damaged one's, or for a camera file, the image a frame now points at.
        let named = e.path == path
            || ((which == 2 || which == 0)
                && e.path.starts_with(&scene.dir)
                && e.path.extension().is_some_and(|x| x == "exr"));
        prop_assert!(named, "{what}: the error names another file: {e}");
    }
    Ok(())
}

fn dataset_strategy() -> impl Strategy<Value = (usize, usize, TextDamage, Damage)> {
    (0usize..4, any::<usize>(), text_damage(), damage())
}

const DATASET_CASES: u32 = 1000;

/// `DATASET_CASES` damaged copies of a tiny scene in `layout`.
fn dataset_fuzz(layout: Layout) {
    let scene = build_scene(layout);
    check(
        DATASET_CASES,
        scene.dir.parent().unwrap(),
        dataset_strategy(),
        |c| dataset_case(&scene, c),
    );
}

/// FIPT synthetic layout (`train/transforms.json`, `train/Image`, maps, OBJ,
/// `scene_meta.json`): `Dataset::load` (and `load_cameras` on the damaged camera file) never
/// panics; a cut JSON or EXR file is an error; the error names the damaged file.
#[test]
fn dataset_fipt_synthetic() {
    dataset_fuzz(Layout::FiptSynthetic);
}

/// FIPT real layout (`cam.txt`, `K_list.txt`, `Image`, maps, OBJ, `scene_meta.json`): as
/// above; `cam.txt`'s count line gets damaged too (the first number of the file).
#[test]
fn dataset_fipt_real() {
    dataset_fuzz(Layout::FiptReal);
}

/// nerfstudio layout (`transforms.json` with intrinsics, `images`, segmentation, OBJ,
/// `scene_meta.json`): as above.
#[test]
fn dataset_nerfstudio() {
    dataset_fuzz(Layout::Nerfstudio);
}

/// The tetrahedron's triangles: the size of `scene_meta.json`'s per-triangle tables.
const TRIANGLES: usize = 4;

/// `scene_meta.json` alone (`SceneMeta::load`, then its per-triangle tables),
/// `relight.json` (`Relight::load` with and without the scene's meta) and an insert file
/// (`load_insert`): never a panic, a cut file is an error, every error names the file.
#[test]
fn meta_and_relight_readers() {
    let dir = scratch("meta");
    std::fs::create_dir_all(&dir).unwrap();
    let meta: SceneMeta = serde_json::from_value(meta_json()).unwrap();
    let texts = [
        (
            "scene_meta.json",
            serde_json::to_string_pretty(&meta_json()).unwrap(),
        ),
        (
            "relight.json",
            serde_json::to_string_pretty(&relight_json()).unwrap(),
        ),
        (
            "insert.json",
            serde_json::to_string_pretty(&serde_json::json!({"objects": [
                {"name": "ball", "shape": "sphere", "scale": 0.2, "rotate_deg": [0, 30, 0],
                 "translate": [2.5, 0.2, 2.0],
                 "material": {"base_color": [0.8, 0.1, 0.1], "roughness": 0.3, "metallic": 0.0}},
                {"name": "bulb", "shape": "cube", "scale": [0.05, 0.05, 0.05],
                 "translate": [2, 2, 2], "emission": [20, 18, 15]}
            ]}))
            .unwrap(),
        ),
    ];
    let ok = dir.join("ok.json");
    write(&ok, &texts[1].1);
    Relight::load(&ok, Some(&meta)).unwrap();
    write(&ok, &texts[2].1);
    load_insert(&ok).unwrap();
    check(
        4000,
        &dir,
        (0usize..3, text_damage(), 0u32..1_000_000),
        |(which, d, k)| {
            let (name, good) = &texts[which];
            let bad = apply_text(good, &d);
            let path = dir.join(format!("case{k}-{name}"));
            write(&path, &bad);
            let what = format!("{name} damaged by {d:?}");
            let results: Vec<Result<(), String>> = if which == 2 {
                vec![sound(&what, || load_insert(&path).map(|_| ()))?.map_err(|e| e.to_string())]
            } else if which == 1 {
                vec![
                    sound(&what, || Relight::load(&path, Some(&meta)).map(|_| ()))?,
                    sound(&what, || Relight::load(&path, None).map(|_| ()))?,
                ]
                .into_iter()
                .map(|r| r.map_err(|e| e.to_string()))
                .collect()
            } else {
                vec![
                    sound(&what, || {
                        SceneMeta::load(&path).map(|m| {
                            m.triangle_emission(TRIANGLES);
                            m.triangle_part(TRIANGLES);
                        })
                    })?
                    .map_err(|e| e.to_string()),
                ]
            };
            std::fs::remove_file(&path).ok();
            for r in results {
                if cuts_content(good.as_bytes(), &bad, &d) {
                    prop_assert!(r.is_err(), "{what}: accepted");
                }
                if let Err(e) = r {
                    prop_assert!(e.contains(&path.display().to_string()), "{what}: {e}");
                }
            }
            Ok(())
        },
    );
}

/// Run configs: damaged versions of `configs/fast.json` through `Config::from_json` and
/// `Config::load`: never a panic, a cut file is an error, both agree, and `load`'s error
/// names the file.
#[test]
fn config_reader() {
    let good = include_str!("../configs/fast.json");
    Config::from_json(good).unwrap();
    let dir = scratch("config");
    std::fs::create_dir_all(&dir).unwrap();
    check(3000, &dir, (text_damage(), 0u32..1_000_000), |(d, k)| {
        let bad = apply_text(good, &d);
        let path = dir.join(format!("case{k}.json"));
        write(&path, &bad);
        let what = format!("fast.json damaged by {d:?}");
        let loaded = sound(&what, || Config::load(&path).map(|_| ()))?;
        std::fs::remove_file(&path).ok();
        let text = String::from_utf8_lossy(&bad);
        let parsed = sound(&what, || Config::from_json(&text).map(|_| ()))?;
        if cuts_content(good.as_bytes(), &bad, &d) {
            prop_assert!(loaded.is_err() && parsed.is_err(), "{what}: accepted");
        }
        if std::str::from_utf8(&bad).is_ok() {
            prop_assert_eq!(loaded.is_ok(), parsed.is_ok(), "{}", what);
        }
        if let Err(e) = loaded {
            let e = e.to_string();
            prop_assert!(e.contains(&path.display().to_string()), "{what}: {e}");
        }
        if let Err(e) = parsed {
            prop_assert!(!format!("{e:#}").trim().is_empty(), "{what}: empty error");
        }
        Ok(())
    });
}

/// The shading cache (`cache::load`, and `load_keyed` without a key): never a panic, never an
/// allocation from its header's sizes; a cut file is an error naming it; a damaged key or size
/// in the header is stale (`None`; `load_keyed` ignores the key); a changed payload or content
/// hash is an error; a loaded cache has the asked-for sizes.
#[test]
fn shading_cache_reader() {
    const KEY: u64 = 0x00c0_ffee;
    let (views, w, h) = (2, 4, 3);
    let dir = scratch("cache");
    let good_path = dir.join("good.bin");
    let shadings: Vec<Vec<f32>> = (0..views)
        .map(|k| {
            (0..w * h * ShadingLayout::DIM)
                .map(|i| (i + k) as f32 * 0.25)
                .collect()
        })
        .collect();
    fipt_train::cache::save(&good_path, KEY, w, h, &shadings).unwrap();
    let good = std::fs::read(&good_path).unwrap();
    check(1000, &dir, (damage(), 0u32..1_000_000), |(d, k)| {
        let path = dir.join(format!("case{k}.bin"));
        let bad = apply(&good, &d);
        write(&path, &bad);
        let what = format!("shading cache damaged by {d:?}");
        let keyed = sound(&what, || fipt_train::cache::load(&path, KEY, views, w, h))?;
        let any = sound(&what, || {
            fipt_train::cache::load_keyed(&path, None, views, w, h)
        })?;
        std::fs::remove_file(&path).ok();
        // Bytes 8..16 hold the key, 16..48 the view count, width, height and shading size.
        let changed: Vec<usize> = (0..bad.len().min(good.len()))
            .filter(|&i| bad[i] != good[i])
            .collect();
        if bad.len() == good.len()
            && !changed.is_empty()
            && changed.iter().all(|i| (8..48).contains(i))
        {
            let sizes = changed.iter().any(|&i| i >= 16);
            prop_assert!(matches!(keyed, Ok(None)), "{what}: not stale");
            prop_assert_eq!(matches!(any, Ok(None)), sizes, "{}", what);
        }
        // Bytes 48..56 hold the content hash of the payload after them: any change there or in
        // the payload is damage, refused by name.
        if bad.len() == good.len() && !changed.is_empty() && changed.iter().all(|&i| i >= 48) {
            for r in [&keyed, &any] {
                prop_assert!(
                    matches!(r, Err(e) if format!("{e:#}").contains("damaged")),
                    "{what}: a changed payload was accepted"
                );
            }
        }
        for r in [keyed, any] {
            if matches!(d, Damage::Truncate(_)) {
                prop_assert!(r.is_err(), "{what}: accepted");
            }
            match r {
                Ok(Some(s)) => prop_assert!(
                    s.len() == views && s.iter().all(|v| v.len() == w * h * ShadingLayout::DIM),
                    "{what}: wrong sizes"
                ),
                Ok(None) => {}
                Err(e) => {
                    let e = format!("{e:#}");
                    prop_assert!(e.contains(&path.display().to_string()), "{what}: {e}");
                }
            }
        }
        Ok(())
    });
}

// ---------------------------------------------------------------------------------------------
// Scene models.

/// A tiny scene model (4-level hash grid of 2^8 entries, small MLPs, the tetrahedron, two
/// emitters, a 16³ light field), saved in `root/good`.
fn build_model(root: &Path) -> (PathBuf, Manifest) {
    let dir = root.join("good");
    let sb = SceneBox {
        min: -0.5,
        max: 1.5,
    };
    let spec = ModelSpec {
        material: MaterialFieldConfig::new()
            .with_grid(HashGridConfig::new().with_levels(4).with_log2_table(8))
            .with_hidden(16)
            .with_hidden_layers(1),
        emission: EmissionMaskConfig::new()
            .with_freqs(2)
            .with_depth(2)
            .with_width(8)
            .with_skip(1),
        scene_box: sb,
        parts: 0,
        part_columns: Default::default(),
    };
    let device = burn::tensor::Device::flex();
    let model = FiptModel::init(spec, &device, 5);
    let mesh = Mesh::parse_obj(TETRA).unwrap();
    let emitters: Vec<Emitter> = (0..2usize)
        .map(|t| Emitter {
            pixels: 10,
            seen_front: 10,
            ..Emitter::on_triangle(&mesh, t, [5.0, 4.0, 3.0])
        })
        .collect();
    let samples = (0..200).map(|i| {
        let t = i as f32 / 200.0;
        (Vec3::new(t, 0.5 * t, 1.0 - t), Vec3::Y, [t, 1.0 - t, 0.5])
    });
    let lf = LightField::build(sb, 16, samples);
    let cfg = json!({"seed": 0});
    let info = SaveInfo {
        name: "fuzz",
        scene: Path::new("/nowhere/fuzz"),
        image_size: [W, H],
        seed: 0,
        metrics: Headline::default(),
        config: &cfg,
        run_metrics: &cfg,
    };
    let manifest = scene_model::save(&dir, &model, &mesh, &emitters, &lf, &info).unwrap();
    SceneModel::load(&dir, &device).unwrap();
    (dir, manifest)
}

/// The files of a scene model, manifest first.
const MODEL_FILES: [&str; 9] = [
    scene_model::MANIFEST,
    "model.json",
    "fields.bpk",
    "hashgrid.f16",
    "lightfield.bin",
    "emitters.json",
    "mesh.obj",
    "config.json",
    "metrics.json",
];

/// The manifest with `name`'s entry updated to `bytes` (as if written with them).
fn resealed(m: &Manifest, name: &str, bytes: &[u8]) -> Vec<u8> {
    let mut m = m.clone();
    for f in m.files.iter_mut().filter(|f| f.name == name) {
        f.bytes = bytes.len() as u64;
        f.fnv64 = format!(
            "{:016x}",
            fipt_core::io::Fnv64::default().bytes(bytes).finish()
        );
    }
    m.total_bytes = m.files.iter().map(|f| f.bytes).sum();
    serde_json::to_string_pretty(&m).unwrap().into_bytes()
}

/// Zoo scene models (`SceneModel::load`): one file damaged per case, with the manifest left as
/// it was (the size and hash checks must name the file) or resealed to match (the file's own
/// reader must cope: model.json, the burn networks, the f16 table, L′, emitters, mesh). Never a
/// panic; a cut file the loader reads is an error naming it; any error names a file of the model.
#[test]
fn scene_model_reader() {
    let root = scratch("model");
    let (good_dir, manifest) = &build_model(&root);
    let device = burn::tensor::Device::flex();
    check(
        1000,
        &root,
        (
            0usize..MODEL_FILES.len(),
            any::<bool>(),
            text_damage(),
            damage(),
            0u32..1_000_000,
        ),
        |(which, reseal, td, bd, k)| {
            let name = MODEL_FILES[which];
            let dir = root.join(format!("case{k}"));
            std::fs::create_dir_all(&dir).unwrap();
            for f in MODEL_FILES {
                std::fs::copy(good_dir.join(f), dir.join(f)).unwrap();
            }
            let path = dir.join(name);
            let good = std::fs::read(&path).unwrap();
            let (bad, cut) = damaged(&path, &td, &bd);
            write(&path, &bad);
            let reseal = reseal && which > 0;
            if reseal {
                write(
                    &dir.join(scene_model::MANIFEST),
                    resealed(manifest, name, &bad),
                );
            }
            let what = format!(
                "{name} damaged by {} (manifest {})",
                if is_text(&path) {
                    format!("{td:?}")
                } else {
                    format!("{bd:?}")
                },
                if reseal { "resealed" } else { "kept" }
            );
            let r = sound(&what, || {
                SceneModel::load(&dir, &device)
                    .map(|_| ())
                    .map_err(|e| format!("{e:#}"))
            })?;
            let _ = std::fs::remove_dir_all(&dir);
            // config.json and metrics.json are not read by `load`: only their hash is checked.
            let read = !matches!(name, "config.json" | "metrics.json");
            let must_fail = match (which, reseal) {
                (0, _) => cut,
                (_, false) => bad != good,
                (_, true) => cut && read,
            };
            if must_fail {
                prop_assert!(r.is_err(), "{what}: accepted");
            }
            if let Err(e) = r {
                // A damaged manifest or model.json can make another file look wrong.
                let named = e.contains(&path.display().to_string())
                    || ((which == 0 || (reseal && name == "model.json"))
                        && MODEL_FILES
                            .iter()
                            .any(|f| e.contains(&dir.join(f).display().to_string())));
                prop_assert!(named, "{what}: the error names another file: {e}");
            }
            Ok(())
        },
    );
}

/// `FiptModel::load` checks `model.json`'s sizes (`ModelSpec::check`) before it builds the
/// hash grid and the networks from them: a `model.json` edited together with its manifest (or
/// read without one, as checkpoints and `bench` do) with an overflowing scale or a huge count
/// (`"levels": 4294967296` would ask for 137 GB) is an error naming model.json, with no panic and
/// no allocation above the limit.
#[test]
fn model_json_sizes() {
    let root = scratch("sizes");
    let (good_dir, manifest) = &build_model(&root);
    let dir = root.join("case");
    let device = burn::tensor::Device::flex();
    let good = std::fs::read_to_string(good_dir.join("model.json")).unwrap();
    let mut failures = Vec::new();
    // Panics first (caught here), the aborting allocations last.
    for (from, to) in [
        ("\"log2_table\": 8", "\"log2_table\": 98"),
        ("\"per_level_scale\": 1.3", "\"per_level_scale\": 91.3"),
        ("\"base_resolution\": 32.0", "\"base_resolution\": 1e300"),
        ("\"levels\": 4", "\"levels\": 4294967296"),
        ("\"hidden\": 16", "\"hidden\": 4294967296"),
        ("\"width\": 8", "\"width\": 4294967296"),
    ] {
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        for f in MODEL_FILES {
            std::fs::copy(good_dir.join(f), dir.join(f)).unwrap();
        }
        assert!(good.contains(from), "{from}");
        let bad = good.replace(from, to);
        write(&dir.join("model.json"), &bad);
        write(
            &dir.join(scene_model::MANIFEST),
            resealed(manifest, "model.json", bad.as_bytes()),
        );
        match guarded(|| SceneModel::load(&dir, &device).map(|_| ())) {
            (Err(p), _) => failures.push(format!("{to}: panicked: {p}")),
            (Ok(Ok(())), _) => failures.push(format!("{to}: accepted")),
            (Ok(Err(e)), biggest)
                if biggest > ALLOC_LIMIT || !format!("{e:#}").contains("model.json") =>
            {
                failures.push(format!("{to}: {e:#} (largest allocation {biggest} bytes)"))
            }
            _ => {}
        }
    }
    let _ = std::fs::remove_dir_all(&root);
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

// ---------------------------------------------------------------------------------------------
// Binary readers of fipt-bake and fipt-core: L′, the table optimiser's state, EXR, OBJ.

/// Cases per binary reader below.
const BINARY_CASES: u32 = 500;

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

proptest! {
    #![proptest_config(ProptestConfig {
        cases: BINARY_CASES,
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
