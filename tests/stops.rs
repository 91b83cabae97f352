//! Stopping `bake` (on 8 views of the reference scene) and `render` (on its val views): SIGKILL
//! and Ctrl-C (SIGINT) at random points, five times each, into one output folder. After every
//! stop the folder holds no partial file and each output set is complete or absent; a Ctrl-C
//! ends with exit 130 and one line. The same command then completes with outputs equal, byte
//! for byte, to an uninterrupted run's. A second writer into a folder in use is refused with
//! the holder's pid.

mod common;

use common::{scene_dir, tmp_dir};
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// The command `args` with `--out out`, its stderr to `err`.
fn spawn(args: &[String], out: &Path, err: &Path) -> Child {
    Command::new(env!("CARGO_BIN_EXE_fipt-train"))
        .args(args)
        .arg("--out")
        .arg(out)
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(err).unwrap())
        .spawn()
        .unwrap()
}

/// Runs the command to its end; its wall time.
fn complete(args: &[String], out: &Path) -> Duration {
    let t = Instant::now();
    let err = out.with_extension("stderr");
    let st = spawn(args, out, &err).wait().unwrap();
    assert!(
        st.success(),
        "{args:?} failed: {}",
        std::fs::read_to_string(&err).unwrap_or_default()
    );
    t.elapsed()
}

/// A small deterministic generator of the stop times (splitmix64).
struct Points(u64);

impl Points {
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// Starts the command and stops it after `after` (SIGINT when `sigint`, else SIGKILL). A
/// command that ended first must have succeeded. A SIGINT must end it with exit code 130 and
/// one line on stderr.
fn stop_at(args: &[String], out: &Path, after: Duration, sigint: bool) {
    let err = out.with_extension("stderr");
    let mut child = spawn(args, out, &err);
    let t = Instant::now();
    while t.elapsed() < after {
        if child.try_wait().unwrap().is_some() {
            break;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    if let Some(st) = child.try_wait().unwrap() {
        assert!(st.success(), "{args:?} ended before its stop: {st}");
        eprintln!("ended before its stop at {after:?}");
        return;
    }
    if !sigint {
        child.kill().unwrap();
        child.wait().unwrap();
        return;
    }
    // SAFETY: a plain kill(2) of our own child, which has not been waited for.
    assert_eq!(
        unsafe { libc::kill(child.id() as libc::pid_t, libc::SIGINT) },
        0
    );
    let st = child.wait().unwrap();
    let text = std::fs::read_to_string(&err).unwrap();
    let lines: Vec<&str> = text.lines().filter(|l| !l.trim().is_empty()).collect();
    if st.success() && lines.is_empty() {
        // The signal came after the command had ended its work (it was exiting).
        eprintln!("Ctrl-C after {after:?}: the command had finished");
        return;
    }
    assert_eq!(st.code(), Some(130), "Ctrl-C: {st}: {text}");
    assert_eq!(lines.len(), 1, "Ctrl-C: not one line: {text}");
    assert!(lines[0].starts_with("interrupted"), "{text}");
    eprintln!("Ctrl-C after {after:?}: {}", lines[0]);
}

/// Every file under `dir`, recursively (folders too).
fn walk(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).into_iter().flatten().flatten() {
        let p = e.path();
        out.push(p.clone());
        if p.is_dir() {
            out.extend(walk(&p));
        }
    }
    out.sort();
    out
}

/// No partial file outside temporaries (names with `.tmp`): every file but the lock reads as
/// what its extension says.
fn assert_no_partial(out: &Path) {
    for p in walk(out) {
        let s = p.to_string_lossy().into_owned();
        if s.contains(".tmp") || p.is_dir() || s.ends_with(".fipt.lock") {
            continue;
        }
        common::assert_readable(&p);
    }
}

/// The files of `dir` (relative paths), in order.
fn files(dir: &Path) -> Vec<PathBuf> {
    walk(dir)
        .into_iter()
        .filter(|p| p.is_file())
        .map(|p| p.strip_prefix(dir).unwrap().to_path_buf())
        .collect()
}

/// Whether the folder `dir` is absent or holds exactly `want`'s files.
fn complete_or_absent(dir: &Path, want: &[PathBuf]) -> bool {
    !dir.exists() || files(dir) == want
}

/// The folders `a` and `b` hold the same files with the same bytes.
fn assert_same_files(a: &Path, b: &Path) {
    let (fa, fb) = (files(a), files(b));
    assert_eq!(
        fa,
        fb,
        "{} and {} hold other files",
        a.display(),
        b.display()
    );
    for f in &fa {
        assert!(
            std::fs::read(a.join(f)).unwrap() == std::fs::read(b.join(f)).unwrap(),
            "{} differs",
            f.display()
        );
    }
}

/// `report` without what differs between equal runs (times, rates, memory, the cache flag).
fn comparable(mut report: Value) -> Value {
    fn strip(v: &mut Value) {
        match v {
            Value::Object(m) => {
                m.retain(|k, _| {
                    !(k.ends_with("_s")
                        || k.ends_with("per_s")
                        || k == "seconds"
                        || k == "peak_rss_mb"
                        || k == "from_cache"
                        || k == "secondary_rays"
                        || k == "threads")
                });
                m.values_mut().for_each(strip);
            }
            Value::Array(a) => a.iter_mut().for_each(strip),
            _ => {}
        }
    }
    strip(&mut report);
    report
}

fn read_json(p: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap()
}

/// Kills and Ctrl-Cs of `args` into one folder at random points of an uninterrupted run's
/// time, then the command to its end: `check` holds after every stop, and the outputs equal
/// the uninterrupted run's (`outputs`: the folders compared byte for byte; `marker`: the
/// report, compared without its times). `fresh`: folders removed before each stop, so that
/// each stop cuts the whole work (a cache would make the next run short).
fn stop_and_finish(
    tag: &str,
    args: &[String],
    outputs: &[&str],
    marker: &str,
    fresh: &[&str],
    check: &dyn Fn(&Path, &Path),
) {
    let root = tmp_dir(tag);
    let (a, b) = (root.join("a"), root.join("b"));
    let took = complete(args, &a);
    let mut points = Points(0x5eed ^ tag.len() as u64);
    for k in 0..10 {
        for f in fresh {
            let _ = std::fs::remove_dir_all(b.join(f));
        }
        let after = took.mul_f64(points.next());
        stop_at(args, &b, after, k % 2 == 1);
        assert_no_partial(&b);
        check(&a, &b);
    }
    complete(args, &b);
    for o in outputs {
        assert_same_files(&a.join(o), &b.join(o));
    }
    assert_eq!(
        comparable(read_json(&a.join(marker))),
        comparable(read_json(&b.join(marker))),
        "{marker} differs"
    );
    let left: Vec<PathBuf> = walk(&b)
        .into_iter()
        .filter(|p| p.to_string_lossy().contains(".tmp"))
        .collect();
    assert!(left.is_empty(), "temporaries left: {left:?}");
    std::fs::remove_dir_all(&root).unwrap();
}

#[test]
fn bake_stopped_anywhere_finishes_like_an_uninterrupted_bake() {
    let root = tmp_dir("bake-config");
    let cfg = root.join("small.json");
    std::fs::write(
        &cfg,
        r#"{"bake": {"voxel_res": 64, "samples": {"diffuse": 4, "specular": [2, 2, 2, 2, 2, 2]}}}"#,
    )
    .unwrap();
    // The first 8 train views: a bake of the whole scene takes 7 times as long and stops no
    // differently.
    let scene = root.join("scene");
    common::small_scene(&scene, 8, false);
    let args: Vec<String> = ["bake", "--json", "--scene"]
        .iter()
        .map(|s| s.to_string())
        .chain([scene.display().to_string()])
        .chain(["--config".to_string(), cfg.display().to_string()])
        .collect();
    // `shading/` is whole or absent; `bake.json` is there only beside the whole set.
    let check = |a: &Path, b: &Path| {
        let want = files(&a.join("shading"));
        assert!(
            complete_or_absent(&b.join("shading"), &want),
            "shading/ is partial"
        );
        if b.join("bake.json").exists() {
            assert!(b.join("shading").exists(), "bake.json without shading/");
        }
    };
    let outputs = ["shading", "cache"];
    stop_and_finish("bake", &args, &outputs, "bake.json", &["cache"], &check);
    std::fs::remove_dir_all(&root).unwrap();
}

#[test]
fn render_stopped_anywhere_finishes_like_an_uninterrupted_render() {
    let args: Vec<String> = ["render", "--truth", "--json", "--spp", "8", "--scene"]
        .iter()
        .map(|s| s.to_string())
        .chain([scene_dir().display().to_string()])
        .collect();
    let check = |a: &Path, b: &Path| {
        let want = files(&a.join("val/Image"));
        assert!(
            complete_or_absent(&b.join("val/Image"), &want),
            "val/Image is partial"
        );
        if b.join("render.json").exists() {
            assert!(b.join("val/Image").exists(), "render.json without images");
        }
    };
    stop_and_finish("render", &args, &["val/Image"], "render.json", &[], &check);
}

/// A `render` into a folder another process holds exits 1 naming the lock and the holder's pid
/// (here the test's own), and writes nothing; once the lock is let go it renders.
#[test]
fn a_second_writer_is_refused_naming_the_holder() {
    let root = tmp_dir("lock");
    let out = root.join("out");
    let args: Vec<String> = ["render", "--truth", "--spp", "2", "--views", "0", "--scene"]
        .iter()
        .map(|s| s.to_string())
        .chain([scene_dir().display().to_string()])
        .collect();
    let held = fipt_train::lock::DirLock::acquire(&out).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_fipt-train"))
        .args(&args)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains(&format!("in use by fipt process {}", std::process::id()))
            && err.contains(".fipt.lock"),
        "{err}"
    );
    assert!(!out.join("val").exists() && !out.join("render.json").exists());
    drop(held);
    complete(&args, &out);
    assert!(out.join("render.json").is_file());
    std::fs::remove_dir_all(&root).unwrap();
}

/// A render of some views (`--views`) replaces only those: the other views' images stay.
#[test]
fn a_render_of_some_views_keeps_the_others() {
    let root = tmp_dir("views");
    let out = root.join("out");
    let base: Vec<String> = ["render", "--truth", "--spp", "2", "--scene"]
        .iter()
        .map(|s| s.to_string())
        .chain([scene_dir().display().to_string()])
        .collect();
    let with = |views: &str| {
        let mut a = base.clone();
        a.extend(["--views".to_string(), views.to_string()]);
        a
    };
    complete(&with("0,1"), &out);
    let dir = out.join("val/Image");
    let before = std::fs::read(dir.join("000_0001.exr")).unwrap();
    let mut again = with("1");
    again.extend(["--max-depth".to_string(), "2".to_string()]);
    complete(&again, &out);
    assert_eq!(
        std::fs::read(dir.join("000_0001.exr")).unwrap(),
        before,
        "view 0 changed"
    );
    assert!(dir.join("preview/000.png").is_file() && dir.join("001_0001.exr").is_file());
    std::fs::remove_dir_all(&root).unwrap();
}
