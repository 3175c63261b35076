//! The hostile-input corpus (`tests/data/hostile/`, written by its
//! `generate.py`): every file reads as exactly the mesh its manifest
//! (`EXPECTED.md`) says, or fails with an error naming the file and the
//! element. Through the library and through `subdfit info`, where a failure
//! must also say "input mesh", exit with status 2 and never panic.

use std::path::{Path, PathBuf};
use std::process::Command;

use subdfit::io;

fn corpus() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/hostile")
}

/// `(file, expected)` rows of the manifest table.
fn manifest() -> Vec<(String, String)> {
    let text = std::fs::read_to_string(corpus().join("EXPECTED.md")).unwrap();
    text.lines()
        .filter(|l| l.starts_with("| ") && !l.starts_with("| file |"))
        .map(|l| {
            let cells: Vec<&str> = l.split(" | ").collect();
            (
                cells[0].trim_start_matches("| ").to_string(),
                cells[1].to_string(),
            )
        })
        .collect()
}

/// Checks an `ok V F i=x,y,z ...` expectation.
fn check_ok(name: &str, path: &Path, spec: &str) {
    let soup = io::read_soup(path).unwrap_or_else(|e| panic!("{name}: {e}"));
    let mut it = spec.split_whitespace().skip(1);
    let nv: usize = it.next().unwrap().parse().unwrap();
    let nf: usize = it.next().unwrap().parse().unwrap();
    assert_eq!(
        (soup.positions.len(), soup.num_faces()),
        (nv, nf),
        "{name}: vertex and face counts"
    );
    for p in it {
        let (i, xyz) = p.split_once('=').unwrap();
        let i: usize = i.parse().unwrap();
        let want: Vec<f64> = xyz.split(',').map(|x| x.parse().unwrap()).collect();
        assert_eq!(
            soup.positions[i].to_array().to_vec(),
            want,
            "{name}: vertex {i}"
        );
    }
    // And it must pass validation: these are all the same closed tetrahedron.
    let v = io::read_mesh(path).unwrap_or_else(|e| panic!("{name}: {e}"));
    assert!(v.report.closed && v.report.manifold, "{name}: {}", v.report);
}

#[test]
fn every_hostile_file_has_its_expected_outcome() {
    let rows = manifest();
    assert!(
        rows.len() >= 40,
        "only {} files in the manifest",
        rows.len()
    );
    // Every mesh file of the folder is in the manifest.
    for e in std::fs::read_dir(corpus()).unwrap() {
        let name = e.unwrap().file_name().into_string().unwrap();
        if [".obj", ".ply", ".off", ".stl"]
            .iter()
            .any(|x| name.ends_with(x))
        {
            assert!(
                rows.iter().any(|(n, _)| *n == name),
                "{name} not in EXPECTED.md"
            );
        }
    }
    // All failures at once: one run shows every file that misbehaves.
    let mut failures = Vec::new();
    for (name, spec) in &rows {
        let path = corpus().join(name);
        if spec.starts_with("ok") {
            let r = std::panic::catch_unwind(|| check_ok(name, &path, spec));
            if r.is_err() {
                failures.push(format!(
                    "{name}: not the expected mesh (see the panic above)"
                ));
            }
            continue;
        }
        let needles = spec.strip_prefix("err ").expect("ok or err");
        let msg = match io::read_mesh(&path) {
            Ok(v) => {
                failures.push(format!(
                    "{name}: accepted ({} vertices, {} faces)",
                    v.report.input_vertices, v.report.input_faces
                ));
                continue;
            }
            Err(e) => e.to_string(),
        };
        if !msg.contains(name.as_str()) {
            failures.push(format!("{name}: does not name the file: {msg}"));
        }
        for n in needles.split(';') {
            if !msg.contains(n) {
                failures.push(format!("{name}: expected '{n}' in: {msg}"));
            }
        }
    }
    assert!(failures.is_empty(), "\n{}", failures.join("\n"));
}

#[test]
fn subdfit_info_on_the_corpus() {
    for (name, spec) in manifest() {
        let out = Command::new(env!("CARGO_BIN_EXE_subdfit"))
            .arg("info")
            .arg(corpus().join(&name))
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!err.contains("panicked"), "{name}: {err}");
        if spec.starts_with("ok") {
            assert_eq!(out.status.code(), Some(0), "{name}: {err}");
        } else {
            assert_eq!(out.status.code(), Some(2), "{name}: {err}");
            assert!(
                err.contains("input mesh") && err.contains(name.as_str()),
                "{name}: {err}"
            );
        }
    }
}
