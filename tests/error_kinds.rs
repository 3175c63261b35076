//! The kind of an error at representative sites of each kind (issue 36's
//! per-site pass): a malformed input says which element, a bad option
//! which option, a numerical failure which stage, and the CLI exits 2 for
//! input and option errors, 3 for numerical ones. (`tests/house.rs` counts
//! the sites left as `InvalidArgument`, kept for calls against a
//! function's contract.)

mod common;

use std::process::Command;

use subdfit::displace::PatchGrid;
use subdfit::embed::{self_test, Progress};
use subdfit::mesh::{check_loop_triangles, TriMesh};
use subdfit::quad::{quadrangulate, QuadrangulateOptions};
use subdfit::{fixtures, DVec3, Error, ErrorKind};

#[test]
fn a_malformed_input_is_an_input_error_that_names_the_element() {
    // A quad under the Loop scheme: the control mesh's face 0.
    let e = check_loop_triangles(&fixtures::cube()).unwrap_err();
    assert!(matches!(e, Error::Topology { .. }), "{e:?}");
    assert_eq!(e.kind(), ErrorKind::Input);
    assert!(e.to_string().contains("face 0"), "{e}");

    // A mesh with no triangles handed in memory: the input mesh, whole.
    let empty = TriMesh {
        positions: vec![DVec3::ZERO],
        triangles: vec![],
    };
    let e = quadrangulate(&empty, &QuadrangulateOptions::default()).unwrap_err();
    assert!(matches!(e, Error::InvalidData { .. }), "{e:?}");
    assert_eq!(e.kind(), ErrorKind::Input);
    assert!(e.to_string().starts_with("input mesh: "), "{e}");
}

#[test]
fn an_option_out_of_range_is_an_option_error_that_names_the_option() {
    // A displacement resolution beyond any atlas: `--displacement-res`.
    let e = PatchGrid::new(&fixtures::cube(), 1 << 20).unwrap_err();
    match &e {
        Error::InvalidOption { option, .. } => assert_eq!(option, "displacement_res"),
        other => panic!("expected InvalidOption, got {other:?}"),
    }
    assert_eq!(e.kind(), ErrorKind::Option);
}

#[test]
fn the_hosts_self_test_hooks_give_one_error_of_each_kind() {
    // What the C++ and Python hosts map to their own errors; the kind
    // survives the host's prefix (embed's input name).
    for (hook, kind) in [
        ("error", ErrorKind::Input),
        ("error-option", ErrorKind::Option),
        ("error-numerical", ErrorKind::Numerical),
        ("error-internal", ErrorKind::Internal),
    ] {
        let e = self_test(hook, &Progress::none()).unwrap_err();
        assert_eq!(e.kind(), kind, "{hook}: {e}");
        assert_eq!(e.context("bunny.ply").kind(), kind, "{hook}");
        assert_eq!(ErrorKind::from_code(kind.code()), kind);
    }
    let bug = self_test("error-internal", &Progress::none()).unwrap_err();
    assert!(bug.to_string().contains("a bug in subdfit"), "{bug}");
}

fn subdfit(args: &[&std::ffi::OsStr]) -> (i32, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_subdfit"))
        .args(args)
        .output()
        .unwrap();
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn the_cli_exits_by_kind() {
    let tmp = tempfile::tempdir().unwrap();
    // Input: a file of no mesh format, named with the element at fault.
    let xyz = tmp.path().join("points.xyz");
    std::fs::write(&xyz, "0 0 0\n").unwrap();
    let out = tmp.path().join("out");
    let (code, err) = subdfit(&[
        "convert".as_ref(),
        xyz.as_os_str(),
        "-o".as_ref(),
        out.as_os_str(),
    ]);
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains("points.xyz") && err.contains("file name"),
        "{err}"
    );
    assert!(!out.exists(), "an input error wrote {}", out.display());

    // Option: τ outside (0, 1].
    let sphere = tmp.path().join("sphere.ply");
    let m = common::icosphere(3, DVec3::ZERO, 1.0);
    subdfit::io::write_ply(&sphere, &m.positions, &m.triangles, &[], None).unwrap();
    let (code, err) = subdfit(&[
        "convert".as_ref(),
        sphere.as_os_str(),
        "-o".as_ref(),
        out.as_os_str(),
        "--tolerance".as_ref(),
        "5".as_ref(),
    ]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("tolerance"), "{err}");
    assert!(!out.exists());

    // Numerical: a control mesh nowhere near M, so no sample of its limit
    // surface projects onto M (the fit's stage names itself).
    let far = tmp.path().join("far.obj");
    let mut k = fixtures::cube();
    let moved: Vec<DVec3> = k
        .positions()
        .iter()
        .map(|p| *p + DVec3::new(1000.0, 0.0, 0.0))
        .collect();
    k.set_positions(moved).unwrap();
    subdfit::io::write_control_obj(&far, &k).unwrap();
    let (code, err) = subdfit(&[
        "fit".as_ref(),
        sphere.as_os_str(),
        far.as_os_str(),
        "-o".as_ref(),
        out.as_os_str(),
        "--quiet".as_ref(),
    ]);
    assert_eq!(code, 3, "{err}");
    assert!(err.contains("fit"), "{err}");
}
