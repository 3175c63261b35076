//! `subdfit convert` end to end gives the same bytes at 1 and 2 rayon
//! threads: every parallel step (the Fitmap, the simplification's batched
//! φ queries and the quadrangulation beside the Fitmap, the fit, the
//! displacement and the metrics) maps in input order and reduces in a fixed
//! order. report.json is compared without its timings, memory peaks and
//! thread counts, which are the run's, not the result's.

mod common;

use std::path::Path;
use std::process::Command;

fn convert(mesh: &Path, out: &Path, threads: usize) {
    let o = Command::new(env!("CARGO_BIN_EXE_subdfit"))
        .arg("convert")
        .arg(mesh)
        .arg("-o")
        .arg(out)
        .env("RAYON_NUM_THREADS", threads.to_string())
        .output()
        .expect("run subdfit");
    assert!(
        o.status.success(),
        "convert at {threads} threads: {}",
        String::from_utf8_lossy(&o.stderr)
    );
}

/// report.json without the lines that describe the run rather than the
/// result.
fn stable_report(path: &Path) -> String {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .filter(|l| !(l.contains("seconds") || l.contains("peak_memory") || l.contains("thread")))
        .collect::<Vec<_>>()
        .join("\n")
}

#[test]
fn convert_bytes_do_not_depend_on_thread_count() {
    let Some(dir) = common::data_dir() else {
        return;
    };
    let mesh = dir.join("spot.ply");
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = (tmp.path().join("t1"), tmp.path().join("t2"));
    convert(&mesh, &a, 1);
    convert(&mesh, &b, 2);
    let mut names: Vec<_> = std::fs::read_dir(&a)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    names.sort();
    // The outputs a conversion always writes must be among those compared.
    for must in ["control.obj", "limit.ply", "displaced.ply", "report.json"] {
        assert!(names.iter().any(|n| n == must), "{must} missing");
    }
    for n in names {
        let (pa, pb) = (a.join(&n), b.join(&n));
        if n == "report.json" {
            assert_eq!(stable_report(&pa), stable_report(&pb), "report.json");
        } else {
            let (x, y) = (std::fs::read(&pa).unwrap(), std::fs::read(&pb).unwrap());
            assert!(x == y, "{n:?} differs between 1 and 2 threads");
        }
    }
}
