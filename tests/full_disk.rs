//! Writes that fail: a full disk (a small tmpfs) and a read-only folder, each in a private mount
//! namespace (`unshare -m`, so nothing stays mounted). The command ends with exit code 1 and a
//! message naming the file it could not write; the outputs of an earlier run stay as they were,
//! byte for byte, and no temporary is left.

mod common;

use common::{scene_dir, tmp_dir};
use std::path::Path;
use std::process::Command;

/// Whether this process may make a private mount namespace (`unshare -m`: root, as in CI).
/// Root must; anyone else is told the test was skipped.
fn can_mount() -> bool {
    let ok = Command::new("unshare")
        .args(["-m", "true"])
        .status()
        .is_ok_and(|s| s.success());
    // SAFETY: geteuid has no preconditions.
    let root = unsafe { libc::geteuid() } == 0;
    assert!(
        ok || !root,
        "root cannot run `unshare -m` (util-linux is needed)"
    );
    if !ok {
        eprintln!("skipped: full-disk tests need `unshare -m` (run them as root)");
    }
    ok
}

/// Runs the shell `script` in a private mount namespace in which `mnt` is a tmpfs of `kb` KiB;
/// `$FIPT` is the binary. Returns (exit code of the script, its stdout, its stderr).
fn in_tmpfs(mnt: &Path, kb: usize, script: &str) -> (i32, String, String) {
    std::fs::create_dir_all(mnt).unwrap();
    let full = format!(
        "set -u; mount -t tmpfs -o size={kb}k tmpfs '{}' || exit 99; {script}",
        mnt.display()
    );
    let o = Command::new("unshare")
        .args(["-m", "sh", "-c", &full])
        .env("FIPT", env!("CARGO_BIN_EXE_fipt-train"))
        .output()
        .expect("unshare (util-linux) is needed");
    let code = o.status.code().unwrap_or(-1);
    assert_ne!(
        code,
        99,
        "cannot mount a tmpfs: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    (
        code,
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

/// Bytes used by the files under `dir`.
fn du(dir: &Path) -> u64 {
    std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| {
            let p = e.path();
            if p.is_dir() {
                du(&p)
            } else {
                std::fs::metadata(&p).map_or(0, |m| m.len())
            }
        })
        .sum()
}

/// `render --truth` of two val views of the reference scene at 4 spp into `$1`.
const RENDER_2: &str = "render --truth --spp 4 --views 0,1 --scene";

/// A render that runs out of space beside an earlier render's outputs, and one into a
/// read-only folder: exit 1, the file named, the earlier outputs unchanged, no temporary left.
#[test]
fn render_on_a_full_or_read_only_disk_keeps_the_old_outputs() {
    if !can_mount() {
        return;
    }
    let root = tmp_dir("render");
    let old = root.join("old");
    let scene = scene_dir();
    let o = Command::new(env!("CARGO_BIN_EXE_fipt-train"))
        .args(RENDER_2.split(' '))
        .arg(&scene)
        .arg("--out")
        .arg(&old)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let mnt = root.join("mnt");
    // Room for the old outputs and a little more: the 8 new views do not fit.
    let kb = (du(&old) / 1024) as usize + 150;
    let script = format!(
        "cp -a '{old}' '{m}/out' && \"$FIPT\" render --truth --spp 4 --scene '{scene}' --out '{m}/out'; \
         echo \"rc=$?\"; diff -r '{old}' '{m}/out' >/dev/null && echo SAME; \
         find '{m}/out' -name '*.tmp*' | sed 's/^/LEFT /'",
        old = old.display(),
        m = mnt.display(),
        scene = scene.display()
    );
    let (_, out, err) = in_tmpfs(&mnt, kb, &script);
    assert!(out.contains("rc=1"), "full disk: {out} {err}");
    assert!(
        err.contains("No space left on device") && err.contains(&format!("{}/out/", mnt.display())),
        "full disk: {err}"
    );
    assert!(!err.contains("panicked"), "{err}");
    assert!(
        out.contains("SAME"),
        "full disk: the old outputs changed: {out}"
    );
    assert!(!out.contains("LEFT"), "full disk: temporaries left: {out}");
    // A read-only folder.
    let script = format!(
        "cp -a '{old}' '{m}/out' && mount -o remount,ro '{m}' && \
         \"$FIPT\" render --truth --spp 4 --scene '{scene}' --out '{m}/out'; \
         echo \"rc=$?\"; diff -r '{old}' '{m}/out' >/dev/null && echo SAME",
        old = old.display(),
        m = mnt.display(),
        scene = scene.display()
    );
    let (_, out, err) = in_tmpfs(&mnt, 64 * 1024, &script);
    assert!(out.contains("rc=1"), "read-only: {out} {err}");
    assert!(
        err.contains("Read-only file system") && err.contains(&format!("{}/out", mnt.display())),
        "read-only: {err}"
    );
    assert!(
        out.contains("SAME"),
        "read-only: the old outputs changed: {out}"
    );
    std::fs::remove_dir_all(&root).unwrap();
}

/// `bake` and `run` on a disk too small for the shading cache: exit 1 naming the cache file;
/// no cache, no shading folder, no temporary left.
#[test]
fn bake_and_run_on_a_full_disk_name_the_file() {
    if !can_mount() {
        return;
    }
    let root = tmp_dir("bake");
    let cfg = root.join("small.json");
    std::fs::write(
        &cfg,
        r#"{"bake": {"voxel_res": 64, "samples": {"diffuse": 4, "specular": [2, 2, 2, 2, 2, 2]}}}"#,
    )
    .unwrap();
    let mnt = root.join("mnt");
    for cmd in ["bake", "run --no-zoo"] {
        let script = format!(
            "\"$FIPT\" {cmd} --scene '{scene}' --config '{cfg}' --out '{m}/out'; echo \"rc=$?\"; \
             ls '{m}/out' '{m}/out/cache' | sed 's/^/HAS /'; find '{m}/out' -name '*.tmp*' | sed 's/^/LEFT /'",
            scene = scene_dir().display(),
            cfg = cfg.display(),
            m = mnt.display()
        );
        let (_, out, err) = in_tmpfs(&mnt, 4096, &script);
        assert!(out.contains("rc=1"), "{cmd}: {out} {err}");
        assert!(
            err.contains("No space left on device")
                && err.contains(&format!("{}/out/cache/shadings.bin", mnt.display())),
            "{cmd}: {err}"
        );
        assert!(!err.contains("panicked"), "{err}");
        assert!(
            !out.contains("HAS shadings.bin") && !out.contains("HAS shading\n"),
            "{cmd}: partial outputs: {out}"
        );
        assert!(!out.contains("LEFT"), "{cmd}: temporaries left: {out}");
    }
    std::fs::remove_dir_all(&root).unwrap();
}
