//! OpenSubdiv shape-file tags: every tag the reader knows lands in the
//! scheme options (or sharpness) it names, a tag it does not know is an
//! error naming the file and the line, and the command line's flags
//! override the file while `diff-limit --json` states the options in force.

use std::path::Path;
use std::process::Command;

use subdfit::io::{parse_obj, read_control_file, read_control_mesh};
use subdfit::mesh::{
    BoundaryInterpolation, CreaseMethod, FVarLinear, FaceId, SchemeOptions, TriangleSubdivision,
};

/// A 3x1 strip of quads (8 vertices), then `tags`.
fn strip(tags: &str) -> String {
    let mut s = String::new();
    for y in 0..2 {
        for x in 0..4 {
            s += &format!("v {x} {y} {}\n", 0.1 * (x * x) as f64);
        }
    }
    s += "f 1 2 6 5\nf 2 3 7 6\nf 3 4 8 7\n";
    s + tags
}

fn parse(text: &str) -> subdfit::Result<subdfit::io::ObjMesh> {
    parse_obj(text.as_bytes(), Path::new("shape.obj"))
}

fn scheme(tags: &str) -> SchemeOptions {
    parse(&strip(tags))
        .unwrap_or_else(|e| panic!("{tags}: {e}"))
        .scheme
}

#[test]
fn every_known_tag_is_honoured() {
    use BoundaryInterpolation as B;
    for (v, want) in [(0, B::None), (1, B::EdgeAndCorner), (2, B::EdgeOnly)] {
        let s = scheme(&format!("t interpolateboundary 1/0/0 {v}\n"));
        assert_eq!(s.boundary, want);
    }
    use FVarLinear as F;
    let fvars = [
        F::None,
        F::CornersOnly,
        F::CornersPlus1,
        F::CornersPlus2,
        F::Boundaries,
        F::All,
    ];
    for (v, want) in fvars.into_iter().enumerate() {
        let s = scheme(&format!("t facevaryinginterpolateboundary 1/0/0 {v}\n"));
        assert_eq!(s.fvar, want);
    }
    // Propagate corners: Hbr's edge-and-corner + propagate = corners plus 2,
    // in either tag order.
    let s =
        scheme("t facevaryingpropagatecorners 1/0/0 1\nt facevaryinginterpolateboundary 1/0/0 2\n");
    assert_eq!(s.fvar, F::CornersPlus2);
    let s =
        scheme("t facevaryinginterpolateboundary 1/0/0 2\nt facevaryingpropagatecorners 1/0/0 0\n");
    assert_eq!(s.fvar, F::CornersPlus1);
    for (v, want) in [
        ("normal", CreaseMethod::Uniform),
        ("uniform", CreaseMethod::Uniform),
        ("chaikin", CreaseMethod::Chaikin),
    ] {
        assert_eq!(
            scheme(&format!("t creasemethod 0/0/1 {v}\n")).crease_method,
            want
        );
    }
    use TriangleSubdivision as T;
    for (tag, want) in [
        ("0/0/1 smooth", T::Smooth),
        ("0/0/1 catmark", T::Catmark),
        ("1/0/0 2", T::Smooth),
        ("1/0/0 0", T::Catmark),
    ] {
        assert_eq!(
            scheme(&format!("t smoothtriangles {tag}\n")).triangles,
            want
        );
    }
    let s = scheme("t hole 2/0/0 2 0\nt hole 1/0/0 2\n");
    assert_eq!(s.holes, vec![FaceId(0), FaceId(2)]);
    let o = parse(&strip(
        "t crease 3/1/0 1 2 3 2.5\nt corner 2/2/0 0 7 1.5 10\n",
    ))
    .unwrap();
    assert_eq!(o.creases, vec![(1, 2, 2.5), (2, 3, 2.5)]);
    assert_eq!(o.corners, vec![(0, 1.5), (7, 10.0)]);
    // No tag: the crate's defaults.
    assert!(scheme("").is_default());
}

#[test]
fn unknown_and_malformed_tags_are_errors_naming_the_line() {
    let bad = [
        (
            "t vertexedit 3/2/1 0 1 2 0.5 0.5 add",
            "unknown tag `vertexedit`",
        ),
        ("t faceedit 1/0/0 0", "unknown tag `faceedit`"),
        (
            "t interpolateboundry 1/0/0 1",
            "unknown tag `interpolateboundry`",
        ),
        (
            "t interpolateboundary 1/0/0 3",
            "interpolateboundary value 3",
        ),
        ("t interpolateboundary 2/0/0 1 1", "1/0/0 arguments"),
        ("t facevaryinginterpolateboundary 1/0/0 6", "value 6"),
        (
            "t facevaryingpropagatecorners 1/0/0 1",
            "facevaryingpropagatecorners 1 needs",
        ),
        ("t creasemethod 0/0/1 sharp", "creasemethod `sharp`"),
        ("t smoothtriangles 1/0/0 1", "k_Old"),
        ("t smoothtriangles 0/0/1 loop", "smoothtriangles `loop`"),
        ("t hole 0/0/0", "hole tag takes"),
        ("t hole 1/0/0 3", "face 3 out of range"),
        ("t hole 1/0/0 -1", "negative"),
    ];
    for (tag, want) in bad {
        let text = strip(&format!("# tags\n{tag}\n"));
        let line = text.lines().count();
        let e = parse(&text).expect_err(tag).to_string();
        assert!(e.contains("shape.obj"), "{tag}: {e}");
        assert!(e.contains(&format!("line {line}")), "{tag}: {e}");
        assert!(e.contains(want), "{tag}: `{e}` lacks `{want}`");
    }
}

/// Readers that keep only the crate's default rules refuse a file asking
/// for others, rather than dropping them.
#[test]
fn default_only_reader_refuses_other_options() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("chaikin.obj");
    std::fs::write(&p, strip("t creasemethod 0/0/1 chaikin\n")).unwrap();
    let e = read_control_mesh(&p).expect_err("must not drop creasemethod");
    assert!(e.to_string().contains("chaikin"), "{e}");
    let f = read_control_file(&p).unwrap();
    assert_eq!(f.scheme.crease_method, CreaseMethod::Chaikin);
    assert_eq!(f.mesh.num_faces(), 3);
}

fn subdfit(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_subdfit"))
        .args(args)
        .output()
        .unwrap()
}

/// Flags override the file; the JSON report states what was in force, and
/// the text output of `limit` too.
#[test]
fn flags_override_the_file_and_the_report_says_so() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("s.obj");
    std::fs::write(
        &p,
        strip("t interpolateboundary 1/0/0 0\nt creasemethod 0/0/1 chaikin\nt hole 1/0/0 1\nt crease 2/1/0 1 5 1.5\n"),
    )
    .unwrap();
    let ps = p.to_str().unwrap();
    let o = subdfit(&["diff-limit", ps, "--samples", "200", "--json"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(j["scheme"]["boundary"], "none");
    assert_eq!(j["scheme"]["crease_method"], "chaikin");
    assert_eq!(j["scheme"]["holes"], serde_json::json!([1]));
    let o = subdfit(&[
        "diff-limit",
        ps,
        "--samples",
        "200",
        "--json",
        "--boundary",
        "edge-only",
        "--crease-method",
        "uniform",
        "--holes",
        "0,2",
        "--triangles",
        "smooth",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(j["scheme"]["boundary"], "edge-only");
    assert_eq!(j["scheme"]["crease_method"], "uniform");
    assert_eq!(j["scheme"]["triangles"], "smooth");
    assert_eq!(j["scheme"]["holes"], serde_json::json!([0, 2]));
    let out = dir.path().join("l.csv");
    let o = subdfit(&[
        "limit",
        ps,
        "-o",
        out.to_str().unwrap(),
        "--fvar",
        "boundaries",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(
        text.contains("boundary none") && text.contains("face-varying linear boundaries"),
        "{text}"
    );
    // A hole out of range on the command line: an error, not a panic.
    let o = subdfit(&["diff-limit", ps, "--holes", "9"]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("hole face 9 out of range"));
}

/// `limit --at` on a hole: an error naming the face (exit 2), not a panic;
/// off the hole it evaluates.
#[test]
fn limit_on_a_hole_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("h.obj");
    std::fs::write(&p, strip("t hole 1/0/0 1\n")).unwrap();
    let at = dir.path().join("at.csv");
    let out = dir.path().join("o.csv");
    for (face, ok) in [(1, false), (0, true)] {
        std::fs::write(&at, format!("face,u,v\n{face},0.5,0.5\n")).unwrap();
        let o = subdfit(&[
            "limit",
            p.to_str().unwrap(),
            "--at",
            at.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--backend",
            "rust",
        ]);
        let err = String::from_utf8_lossy(&o.stderr);
        if ok {
            assert!(o.status.success(), "{err}");
        } else {
            assert_eq!(o.status.code(), Some(2), "{err}");
            assert!(err.contains("face 1 is a hole"), "{err}");
        }
    }
}
