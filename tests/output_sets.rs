//! An output folder always holds one run's complete set (`report::output`):
//! nothing left from a run in another mode or with other options, never half
//! old and half new, even when the run is killed mid-write; SIGINT/SIGTERM
//! clean up and exit 130/143; the next run removes what a SIGKILL left.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("data")
        .join(name)
}

fn convert(input: &Path, out: &Path, extra: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_subdfit"))
        .arg("convert")
        .arg(input)
        .arg("-o")
        .arg(out)
        .arg("--quiet")
        .args(extra)
        .output()
        .unwrap()
}

/// File name → bytes of every entry of `dir`.
fn contents(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| {
            let e = e.unwrap();
            (
                e.file_name().to_string_lossy().into_owned(),
                std::fs::read(e.path()).unwrap(),
            )
        })
        .collect()
}

/// Staging folders beside `out` (this version's) and inside it (older ones').
fn staging(out: &Path) -> Vec<PathBuf> {
    let name = out.file_name().unwrap().to_string_lossy().into_owned();
    let beside = format!(".{name}.subdfit-staging-");
    let mut found = Vec::new();
    for (dir, prefix) in [
        (out.parent().unwrap(), beside.as_str()),
        (out, ".subdfit-staging-"),
    ] {
        if let Ok(rd) = std::fs::read_dir(dir) {
            for e in rd.flatten() {
                if e.file_name().to_string_lossy().starts_with(prefix) {
                    found.push(e.path());
                }
            }
        }
    }
    found
}

#[test]
fn a_folder_holds_one_runs_set() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let o = convert(&data("spot.ply"), &out, &["--report"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for f in ["fitmap.ply", "report.html", "control.obj", "report.json"] {
        assert!(out.join(f).is_file(), "organic run: {f} missing");
    }
    // A file of the user's in the folder survives the swap.
    std::fs::write(out.join("notes.txt"), "mine").unwrap();
    let o = convert(&data("fandisk.ply"), &out, &["--mode", "mechanical"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let names: Vec<String> = contents(&out).into_keys().collect();
    assert_eq!(
        names,
        [
            "control.obj",
            "control.usda",
            "displaced.ply",
            "displacement.exr",
            "displacement_vector.exr",
            "limit.ply",
            "notes.txt",
            "report.json"
        ],
        "the mechanical run's set, nothing of the organic run's"
    );
    assert_eq!(std::fs::read(out.join("notes.txt")).unwrap(), b"mine");
    let report = std::fs::read_to_string(out.join("report.json")).unwrap();
    assert!(
        report.contains("\"mechanical\""),
        "report.json is not the mechanical run's"
    );
    assert!(
        staging(&out).is_empty(),
        "staging left: {:?}",
        staging(&out)
    );
}

#[test]
fn a_folder_inside_the_output_folder_is_an_error_before_anything_is_written() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    std::fs::create_dir_all(out.join("pictures")).unwrap();
    let o = convert(&data("fandisk.ply"), &out, &[]);
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("pictures"), "{err}");
    let left: Vec<String> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(left, ["pictures"]);
    assert!(staging(&out).is_empty());
}

/// Starts a conversion of fandisk into `out` that holds its staged set for
/// a minute before the swap, and waits until the whole set is staged.
// The child is returned to the caller, which signals and waits for it.
#[allow(clippy::zombie_processes)]
fn start_paused(out: &Path) -> Child {
    let mut child = Command::new(env!("CARGO_BIN_EXE_subdfit"))
        .arg("convert")
        .arg(data("fandisk.ply"))
        .arg("-o")
        .arg(out)
        .args(["--quiet", "--mode", "mechanical"])
        .env("SUBDFIT_TEST_PAUSE_BEFORE_SWAP_MS", "60000")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let t0 = Instant::now();
    loop {
        let staged = staging(out)
            .into_iter()
            .any(|s| s.join("report.json").is_file());
        if staged {
            // The other files were written before report.json's rename in
            // the same parallel batch; give the slowest a moment.
            std::thread::sleep(Duration::from_millis(300));
            return child;
        }
        if t0.elapsed() > Duration::from_secs(240) {
            let _ = child.kill();
            let _ = child.wait();
            panic!("the set was never staged");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

fn signal(child: &Child, sig: i32) {
    // SAFETY: kill(2) on a child this test spawned and has not reaped.
    assert_eq!(unsafe { libc::kill(child.id() as i32, sig) }, 0);
}

#[test]
fn killed_mid_write_the_folder_keeps_the_old_set() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let o = convert(&data("spot.ply"), &out, &[]);
    assert!(o.status.success());
    let before = contents(&out);

    // SIGINT and SIGTERM: staging removed, exit 128 + signal, old set intact.
    for (sig, code) in [(libc::SIGINT, 130), (libc::SIGTERM, 143)] {
        let mut child = start_paused(&out);
        signal(&child, sig);
        let status = child.wait().unwrap();
        assert_eq!(status.code(), Some(code), "signal {sig}");
        assert!(staging(&out).is_empty(), "signal {sig}: staging left");
        assert!(contents(&out) == before, "signal {sig}: the folder changed");
    }

    // SIGKILL: nothing can clean up; the folder still holds the old set,
    // and the next run removes the dead run's staging folder.
    let mut child = start_paused(&out);
    signal(&child, libc::SIGKILL);
    child.wait().unwrap();
    assert!(contents(&out) == before, "SIGKILL: the folder changed");
    assert_eq!(staging(&out).len(), 1, "SIGKILL leaves its staging folder");
    let o = convert(&data("fandisk.ply"), &out, &["--mode", "mechanical"]);
    assert!(o.status.success());
    assert!(
        staging(&out).is_empty(),
        "the next run left the dead run's staging"
    );
    assert!(
        !out.join("fitmap.ply").exists(),
        "mixed set after the next run"
    );
}
