//! The C++ embedding end to end: configure, build and install the CMake
//! package from the repository root (CMake driving a release cargo build),
//! build `examples/cpp` against the installed package with nothing but
//! `find_package(subdfit)`, and run the example hosts.
//!
//! Slow on a clean machine (a release build of the crate inside CMake); the
//! cargo target dir is `target/cpp-package` so later runs are incremental,
//! while the CMake build trees and the install prefix are fresh every time.
//! Skips, saying so, when `cmake` is not installed.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn run(cmd: &mut Command) -> Output {
    cmd.output()
        .unwrap_or_else(|e| panic!("cannot run {cmd:?}: {e}"))
}

fn run_ok(cmd: &mut Command) -> Output {
    let out = run(cmd);
    assert!(
        out.status.success(),
        "{cmd:?} failed ({})\nstdout:\n{}\nstderr:\n{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// A control mesh that exercises the evaluators: a cube (valence-3
/// extraordinary corners) whose top quad is replaced by a pyramid of four
/// triangles (non-quad faces, a valence-4 apex surrounded by triangles),
/// with a boundary-free, consistently oriented layout. Coordinates are
/// dyadic so that OpenMesh's reader (which parses OBJ coordinates in single
/// precision) and the CLI's (double) read the same numbers.
fn write_control_mesh(path: &Path) {
    let text = "\
v -1 -1 -1
v 1 -1 -1
v -1 1 -1
v 1 1 -1
v -1 -1 1
v 1 -1 1.25
v -1 1 1
v 1.5 1 1
v 0.125 -0.25 2
f 1 3 4 2
f 1 2 6 5
f 3 7 8 4
f 1 5 7 3
f 2 4 8 6
f 5 6 9
f 6 8 9
f 8 7 9
f 7 5 9
";
    std::fs::write(path, text).unwrap();
}

#[test]
fn cpp_package_builds_installs_and_matches_the_cli() {
    if Command::new("cmake").arg("--version").output().is_err() {
        println!("SKIPPED: cmake is not installed; the C++ package test needs it");
        return;
    }
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let cargo_target = root.join("target").join("cpp-package");
    let tmp = tempfile::tempdir().unwrap();
    let build = tmp.path().join("build");
    let prefix = tmp.path().join("prefix");
    let ex_build = tmp.path().join("examples");

    // --- the package, from the repository root ------------------------------
    run_ok(
        Command::new("cmake")
            .arg("-S")
            .arg(root)
            .arg("-B")
            .arg(&build)
            .arg(format!("-DCMAKE_INSTALL_PREFIX={}", prefix.display()))
            .arg(format!(
                "-DSUBDFIT_CARGO_TARGET_DIR={}",
                cargo_target.display()
            ))
            .arg("-DCMAKE_BUILD_TYPE=Release"),
    );
    run_ok(Command::new("cmake").arg("--build").arg(&build));
    run_ok(Command::new("cmake").arg("--install").arg(&build));
    let lib = prefix.join("lib").join("libsubdfit.a");
    assert!(lib.is_file(), "{} not installed", lib.display());
    assert!(prefix.join("include/subdfit/subdfit.hpp").is_file());
    assert!(prefix
        .join("lib/cmake/subdfit/subdfitConfigVersion.cmake")
        .is_file());

    // Everything a host calls is inside the one archive: the public API, the
    // Rust side of the bridge, and the C++ wrappers it calls.
    if let Ok(nm) = Command::new("nm")
        .args(["-C", "--defined-only"])
        .arg(&lib)
        .output()
    {
        let syms = String::from_utf8_lossy(&nm.stdout);
        for want in [
            "subdfit::limit_points(",
            "subdfit::convert(",
            "subdfit::ffi::ProgressSink::report(",
            "$embed_limit_points",
            "subdfit::osd::new_osd_topology(",
        ] {
            assert!(syms.contains(want), "libsubdfit.a does not define {want}");
        }
    }

    // --- the example hosts, against the installed package only --------------
    run_ok(
        Command::new("cmake")
            .arg("-S")
            .arg(root.join("examples/cpp"))
            .arg("-B")
            .arg(&ex_build)
            .arg(format!("-DCMAKE_PREFIX_PATH={}", prefix.display()))
            .arg("-DCMAKE_BUILD_TYPE=Release"),
    );
    run_ok(Command::new("cmake").arg("--build").arg(&ex_build));
    let example = |name: &str| -> PathBuf { ex_build.join(name) };
    let cli = env!("CARGO_BIN_EXE_subdfit");

    // --- limit: byte-identical to `subdfit limit` with both backends ---------
    let control = tmp.path().join("control.obj");
    write_control_mesh(&control);
    let (cpp_osd, cpp_rust) = (
        tmp.path().join("cpp_osd.csv"),
        tmp.path().join("cpp_rust.csv"),
    );
    run_ok(
        Command::new(example("limit"))
            .arg(&control)
            .arg(&cpp_osd)
            .arg(&cpp_rust),
    );
    for (backend, cpp) in [("osd", &cpp_osd), ("rust", &cpp_rust)] {
        let cli_csv = tmp.path().join(format!("cli_{backend}.csv"));
        run_ok(
            Command::new(cli)
                .arg("limit")
                .arg(&control)
                .args(["--backend", backend, "-o"])
                .arg(&cli_csv),
        );
        let (a, b) = (
            std::fs::read_to_string(&cli_csv).unwrap(),
            std::fs::read_to_string(cpp).unwrap(),
        );
        assert_eq!(a.lines().count(), 10, "header + 9 vertices:\n{a}");
        assert_eq!(a, b, "C++ and CLI limit CSVs differ ({backend})");
    }

    // --- errors: a malformed mesh gives the CLI's message, status 1 ----------
    // OpenMesh reads it, the library rejects it: vertices but no faces.
    let bad = tmp.path().join("no_faces.obj");
    std::fs::write(&bad, "v 0 0 0\nv 1 0 0\nv 0 1 0\n").unwrap();
    let out = run(Command::new(example("convert"))
        .arg(&bad)
        .arg(tmp.path().join("x.obj")));
    assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
    let cli_out = run(Command::new(cli).arg("info").arg(&bad));
    let cli_msg = stderr(&cli_out);
    let cli_msg = cli_msg
        .trim()
        .strip_prefix("subdfit: error: ")
        .unwrap_or_else(|| panic!("unexpected CLI output {cli_msg}"));
    assert!(
        cli_msg.contains("no_faces.obj: mesh: has no faces"),
        "{cli_msg}"
    );
    assert!(
        stderr(&out).contains(&format!("convert: error: {cli_msg}")),
        "C++ message {:?} is not the CLI's {cli_msg:?}",
        stderr(&out)
    );

    // --- error kinds: the malformed mesh is bad input, a τ out of (0, 1] a
    // bad option; subdfit::Error::kind() tells them apart as the library's
    // ErrorKind does (the CLI exits 2 on both; a host may not).
    assert!(
        stderr(&out).contains("convert: error kind: input"),
        "{}",
        stderr(&out)
    );
    let spot_in = root.join("data/spot.ply");
    let out = run(Command::new(example("convert"))
        .arg(&spot_in)
        .arg(tmp.path().join("x.obj"))
        .args(["--tolerance", "5"]));
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("tolerance"), "{err}");
    assert!(err.contains("convert: error kind: option"), "{err}");

    // --- a panic inside the library is an error, never an abort --------------
    for hook in ["panic", "panic-in-worker"] {
        let out = run(Command::new(example("convert")).args(["-", "-", "--self-test", hook]));
        let err = stderr(&out);
        assert_eq!(out.status.code(), Some(1), "{hook}: {err}");
        assert!(
            err.contains("convert: error: internal error: subdfit panicked (self-test panic"),
            "{hook}: {err}"
        );
        assert!(
            err.contains("convert: error kind: internal"),
            "{hook}: {err}"
        );
    }

    // --- cancellation: the call returns promptly after the callback says stop
    let out = run(Command::new(example("convert")).args([
        "-",
        "-",
        "--self-test",
        "progress",
        "--cancel-at",
        "self-test:0.3",
    ]));
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("cancelled by the caller"), "{err}");
    let latency_ms = cancel_latency_ms(&err);
    // The bar is 1 s; the fake stage's steps are 1 ms each.
    assert!(
        latency_ms < 1000.0,
        "cancelled call took {latency_ms} ms to return"
    );

    // --- convert on a real mesh: the same control mesh bytes and metrics as
    // the CLI's. Both read `data/spot.ply` under the same name, so even the
    // "run" part of report.json agrees; only timings may differ.
    let spot = root.join("data/spot.ply");
    let cpp_obj = tmp.path().join("spot.obj");
    let cpp_report = tmp.path().join("spot_report.json");
    run_ok(
        Command::new(example("convert"))
            .arg(&spot)
            .arg(&cpp_obj)
            .arg("--report")
            .arg(&cpp_report),
    );
    let cli_dir = tmp.path().join("cli_spot");
    run_ok(
        Command::new(cli)
            .arg("convert")
            .arg(&spot)
            .arg("-o")
            .arg(&cli_dir)
            .arg("--quiet"),
    );
    let cli_obj = std::fs::read(cli_dir.join("control.obj")).unwrap();
    assert!(
        std::fs::read(&cpp_obj).unwrap() == cli_obj,
        "the C++ host's control.obj differs from the CLI's"
    );
    let metrics = |path: &Path| {
        let v: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
        let mut out = Vec::new();
        flatten_numbers(&v, String::new(), &mut out);
        // Wall-clock times and memory peaks vary from run to run.
        out.retain(|(k, _)| !(k.contains("seconds") || k.contains("peak_memory")));
        out
    };
    let (cpp_m, cli_m) = (metrics(&cpp_report), metrics(&cli_dir.join("report.json")));
    assert!(cli_m.len() > 50, "too few metrics: {cli_m:?}");
    assert!(
        cli_m
            .iter()
            .any(|(k, _)| k == "accuracy.limit.rms_permille"),
        "{cli_m:?}"
    );
    assert_eq!(cpp_m, cli_m, "C++ and CLI metrics differ");

    // --- two conversions at once from two host threads: each equals the lone
    // call's result, and an error in one leaves the other alone.
    let (a_obj, b_obj) = (tmp.path().join("a.obj"), tmp.path().join("b.obj"));
    run_ok(
        Command::new(example("convert_concurrent"))
            .arg(&spot)
            .arg(&spot)
            .arg(&a_obj)
            .arg(&b_obj),
    );
    for out in [&a_obj, &b_obj] {
        assert!(std::fs::read(out).unwrap() == cli_obj, "{}", out.display());
    }
    let _ = std::fs::remove_file(&a_obj);
    let out = run(Command::new(example("convert_concurrent"))
        .arg(&spot)
        .arg(&bad)
        .arg(&a_obj)
        .arg(&b_obj));
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains(&format!("{}: error: {cli_msg}", bad.display())),
        "{err}"
    );
    assert!(std::fs::read(&a_obj).unwrap() == cli_obj, "{err}");

    // --- cancelling a real conversion (bunny, ../shared/data) at 30 % of its
    // two long stages: the call returns within 1 s of the cancel.
    let bunny = data_dir().map(|d| d.join("bunny.ply"));
    match bunny {
        Some(bunny) if bunny.is_file() => {
            for stage in ["fitmap", "simplify"] {
                let out = run(Command::new(example("convert"))
                    .arg(&bunny)
                    .arg(tmp.path().join("bunny.obj"))
                    .arg("--cancel-at")
                    .arg(format!("{stage}:0.3")));
                let err = stderr(&out);
                assert_eq!(out.status.code(), Some(1), "{err}");
                assert!(err.contains("cancelled by the caller"), "{err}");
                assert!(!tmp.path().join("bunny.obj").exists());
                let ms = cancel_latency_ms(&err);
                println!("bunny cancelled at {stage} 30 %: returned in {ms:.1} ms");
                assert!(
                    ms < 1000.0,
                    "{stage}: cancelled call took {ms} ms to return"
                );
            }
        }
        _ => println!(
            "SKIPPED (bunny cancellation): bunny.ply not found; set SUBDFIT_DATA or \
             provide ../shared/data"
        ),
    }
}

fn cancel_latency_ms(err: &str) -> f64 {
    err.lines()
        .find_map(|l| l.strip_prefix("cancel latency: "))
        .and_then(|l| l.trim_end_matches(" ms").parse().ok())
        .unwrap_or_else(|| panic!("no cancel latency in {err}"))
}

/// Where the shared test meshes are: `$SUBDFIT_DATA` or `../shared/data`.
fn data_dir() -> Option<PathBuf> {
    let d = std::env::var_os("SUBDFIT_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data"));
    d.is_dir().then_some(d)
}

/// The numeric leaves of a JSON value as (dotted path, value).
fn flatten_numbers(v: &serde_json::Value, key: String, out: &mut Vec<(String, f64)>) {
    match v {
        serde_json::Value::Number(n) => out.push((key, n.as_f64().unwrap())),
        serde_json::Value::Object(m) => {
            for (k, v) in m {
                let k = if key.is_empty() {
                    k.clone()
                } else {
                    format!("{key}.{k}")
                };
                flatten_numbers(v, k, out);
            }
        }
        serde_json::Value::Array(a) => {
            for (i, v) in a.iter().enumerate() {
                flatten_numbers(v, format!("{key}[{i}]"), out);
            }
        }
        _ => {}
    }
}
