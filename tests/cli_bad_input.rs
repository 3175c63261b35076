//! Bad input through the command line: a clear error naming the file and the
//! element, exit status 2, no panic, no partial output.

use std::path::{Path, PathBuf};
use std::process::Command;

fn subdfit(args: &[&str]) -> (i32, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_subdfit"))
        .args(args)
        .output()
        .unwrap();
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

const QUAD_HEADER: &str = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n";

#[test]
fn bad_control_meshes_fail_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let cases: Vec<(&str, String, &[&str])> = vec![
        ("garbage.obj", "v 0 0 zero\nf 1 2 3\n".into(), &["line 1"]),
        (
            "range.obj",
            format!("{QUAD_HEADER}f 1 2 9\n"),
            &["face 0", "9"],
        ),
        (
            "nan.obj",
            "v 0 0 0\nv 1 0 nan\nv 0 1 0\nf 1 2 3\n".into(),
            &["vertex 1"],
        ),
        // (Non-manifold edges and vertices, and faces that repeat a
        // corner, are accepted as OpenSubdiv takes them:
        // tests/nonmanifold_limit.rs. A face whose repeated corners one fan
        // joins is not: no manifold copy keeps them apart.)
        (
            "folded.obj",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3 3\nf 2 1 3\n".into(),
            &["face 0", "one fan"],
        ),
        ("empty.obj", String::new(), &["no faces"]),
    ];
    for (name, text, needles) in cases {
        let p = write(dir.path(), name, &text);
        let out = dir.path().join(format!("{name}.csv"));
        let (code, _, err) = subdfit(&["limit", p.to_str().unwrap(), "-o", out.to_str().unwrap()]);
        assert_eq!(code, 2, "{name}: exit {code}, stderr: {err}");
        assert!(!err.contains("panicked"), "{name}: {err}");
        assert!(
            err.contains(name),
            "{name}: error does not name the file: {err}"
        );
        for n in needles {
            assert!(
                err.contains(n),
                "{name}: error does not mention `{n}`: {err}"
            );
        }
        assert!(!out.exists(), "{name}: partial output left behind");
    }
}

#[test]
fn missing_file_and_bad_locations_fail_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let (code, _, err) = subdfit(&["info", dir.path().join("nope.ply").to_str().unwrap()]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("nope.ply"), "{err}");

    let p = write(dir.path(), "quad.obj", &format!("{QUAD_HEADER}f 1 2 3 4\n"));
    let at = write(dir.path(), "at.csv", "face,u,v\n0,0.5,0.5\n3,0.5,0.5\n");
    let out = dir.path().join("out.csv");
    for backend in ["osd", "rust"] {
        let (code, _, err) = subdfit(&[
            "limit",
            p.to_str().unwrap(),
            "--backend",
            backend,
            "--at",
            at.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
        ]);
        assert_eq!(code, 2, "{backend}: {err}");
        assert!(
            err.contains("face 3") || err.contains("location 1"),
            "{backend}: {err}"
        );
        assert!(!err.contains("panicked"), "{err}");
        assert!(!out.exists());
    }
}

#[test]
fn limit_of_the_cube_corners_through_the_cli() {
    // Closed form: the Catmull-Clark limit of a corner of [-1,1]^3 is ±1/2.
    let dir = tempfile::tempdir().unwrap();
    let mut text = String::new();
    for i in 0..8 {
        let c = |b: i32| if (i >> b) & 1 == 1 { 1 } else { -1 };
        text += &format!("v {} {} {}\n", c(0), c(1), c(2));
    }
    text += "f 1 3 4 2\nf 5 6 8 7\nf 1 2 6 5\nf 3 7 8 4\nf 1 5 7 3\nf 2 4 8 6\n";
    let p = write(dir.path(), "cube.obj", &text);
    for backend in ["osd", "rust"] {
        let out = dir.path().join(format!("{backend}.csv"));
        let (code, _, err) = subdfit(&[
            "limit",
            p.to_str().unwrap(),
            "--backend",
            backend,
            "-o",
            out.to_str().unwrap(),
        ]);
        assert_eq!(code, 0, "{err}");
        let csv = std::fs::read_to_string(&out).unwrap();
        let mut lines = csv.lines();
        assert_eq!(lines.next(), Some("vertex,x,y,z,nx,ny,nz"));
        let rows: Vec<Vec<f64>> = lines
            .map(|l| l.split(',').map(|x| x.parse().unwrap()).collect())
            .collect();
        assert_eq!(rows.len(), 8);
        for r in rows {
            for k in 1..4 {
                assert!((r[k].abs() - 0.5).abs() < 1e-12, "{backend}: {r:?}");
                // The normal points outward along the diagonal.
                assert!(
                    (r[k + 3] - r[k].signum() / 3f64.sqrt()).abs() < 1e-9,
                    "{backend}: {r:?}"
                );
            }
        }
    }
}

/// A command reading two meshes says which one is bad: "input mesh" for M,
/// "control mesh" for the given control mesh, each with its file.
#[test]
fn fit_names_the_role_of_the_bad_mesh() {
    let dir = tempfile::tempdir().unwrap();
    let good = write(dir.path(), "quad.obj", &format!("{QUAD_HEADER}f 1 2 3 4\n"));
    let bad = write(
        dir.path(),
        "bom_nan.off",
        "\u{feff}OFF\n3 1 0\n0 0 0\n1 nan 0\n0 1 0\n3 0 1 2\n",
    );
    let out = dir.path().join("out");
    let run = |mesh: &Path, control: &Path| {
        subdfit(&[
            "fit",
            mesh.to_str().unwrap(),
            control.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--quiet",
        ])
    };
    let (code, _, err) = run(&bad, &good);
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains("input mesh: ")
            && err.contains("bom_nan.off: vertex 1 (line 4)")
            && err.contains("NaN"),
        "{err}"
    );
    let (code, _, err) = run(&good, &bad);
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains("control mesh: ") && err.contains("bom_nan.off: vertex 1 (line 4)"),
        "{err}"
    );
    assert!(!out.exists(), "partial output left behind");
}

#[test]
fn render_says_which_mesh_is_bad() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(
        dir.path(),
        "nan_input.obj",
        "v 0 0 0\nv 1 0 nan\nv 0 1 0\nf 1 2 3\n",
    );
    let png = dir.path().join("x.png");
    let (code, _, err) = subdfit(&["render", p.to_str().unwrap(), "-o", png.to_str().unwrap()]);
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains("input mesh") && err.contains("nan_input.obj"),
        "{err}"
    );
    assert!(err.contains("vertex 1"), "{err}");
    assert_eq!(
        err.matches("nan_input.obj").count(),
        1,
        "file named twice: {err}"
    );
    assert!(!png.exists());
}
