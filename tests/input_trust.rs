//! Issue 38, inputs as exporters write them: a mesh without area is
//! refused (exit 2, the file named, nothing written); a triangle soup
//! (every triangle its own three vertices, as some OBJ and PLY exporters
//! write and as every STL is) is welded on load and converts like the
//! welded mesh.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::Command;

use subdfit::mesh::PolySoup;
use subdfit::DVec3;

fn subdfit(args: &[&str]) -> (i32, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_subdfit"))
        .args(args)
        .output()
        .unwrap();
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

fn obj_text(v: &[DVec3], f: &[[u32; 3]]) -> String {
    let mut s = String::new();
    for p in v {
        writeln!(s, "v {} {} {}", p.x, p.y, p.z).unwrap();
    }
    for t in f {
        writeln!(s, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1).unwrap();
    }
    s
}

fn write(dir: &Path, name: &str, v: &[DVec3], f: &[[u32; 3]]) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, obj_text(v, f)).unwrap();
    p
}

/// An `n × n` grid of points in the plane z = 0, spacing 1.
fn grid(n: u32) -> Vec<DVec3> {
    (0..n * n)
        .map(|i| DVec3::new((i % n) as f64, (i / n) as f64, 0.0))
        .collect()
}

/// Its triangles, two per cell, consistently oriented.
fn grid_triangles(n: u32) -> Vec<[u32; 3]> {
    let mut f = Vec::new();
    for j in 0..n - 1 {
        for i in 0..n - 1 {
            let a = j * n + i;
            f.push([a, a + 1, a + n + 1]);
            f.push([a, a + n + 1, a + n]);
        }
    }
    f
}

#[test]
fn meshes_without_area_are_refused_by_every_command() {
    let dir = tempfile::tempdir().unwrap();
    // Every vertex on one line (slightly off the axes, so no coordinate is
    // constant): every face has zero area.
    let line: Vec<DVec3> = (0..40)
        .map(|i| DVec3::new(1.0, 2.0, 3.0) * (i as f64 * 0.25))
        .collect();
    let line_faces: Vec<[u32; 3]> = (0..38).map(|i| [i, i + 1, i + 2]).collect();
    // Vertices spanning a plane, but every triangle three points of one
    // grid row: all faces degenerate though the points are not colinear.
    let n = 8;
    let rows: Vec<[u32; 3]> = (0..n)
        .flat_map(|j| (0..n - 2).map(move |i| [j * n + i, j * n + i + 1, j * n + i + 2]))
        .collect();
    let cases = [
        write(dir.path(), "colinear.obj", &line, &line_faces),
        write(dir.path(), "slivers.obj", &grid(n), &rows),
    ];
    for input in &cases {
        let name = input.file_name().unwrap().to_str().unwrap();
        let out = dir.path().join(format!("{name}.out"));
        for cmd in ["convert", "info"] {
            let mut args = vec![cmd, input.to_str().unwrap()];
            if cmd == "convert" {
                args.extend(["-o", out.to_str().unwrap(), "--quiet"]);
            }
            let (code, err) = subdfit(&args);
            assert_eq!(code, 2, "{cmd} {name}: exit {code}, stderr: {err}");
            assert!(!err.contains("panicked"), "{cmd} {name}: {err}");
            assert!(err.contains(name), "{cmd} {name}: file not named: {err}");
            assert!(
                err.contains("no area"),
                "{cmd} {name}: reason not said: {err}"
            );
            assert!(!out.exists(), "{cmd} {name}: output written");
        }
    }
    // The same through the library (what embed, Python and C++ call).
    let soup = PolySoup::from_faces(line, &line_faces);
    let e = subdfit::mesh::validate_soup(soup, Path::new("mem.obj")).unwrap_err();
    assert!(e.to_string().contains("mem.obj"), "{e}");

    // A flat plate (zero thickness, positive area) is a surface.
    let plate = write(dir.path(), "plate.obj", &grid(12), &grid_triangles(12));
    let (code, err) = subdfit(&["info", plate.to_str().unwrap()]);
    assert_eq!(code, 0, "the flat plate was refused: {err}");
    let out = dir.path().join("plate.out");
    let (code, err) = subdfit(&[
        "convert",
        plate.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--quiet",
    ]);
    assert_eq!(code, 0, "the flat plate was refused: {err}");
    assert!(out.join("report.json").exists());
}

fn convert(input: &Path, out: &Path) -> serde_json::Value {
    let (code, err) = subdfit(&[
        "convert",
        input.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--quiet",
    ]);
    assert_eq!(code, 0, "{}: {err}", input.display());
    serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap()
}

#[test]
fn an_unwelded_soup_of_spot_converts_like_spot() {
    let spot = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/spot.ply");
    let mesh = subdfit::io::read_mesh(&spot).unwrap().mesh;
    // Every triangle its own three vertices.
    let corners: Vec<DVec3> = mesh
        .triangles
        .iter()
        .flatten()
        .map(|&v| mesh.positions[v as usize])
        .collect();
    let faces: Vec<[u32; 3]> = (0..mesh.triangles.len() as u32)
        .map(|t| [3 * t, 3 * t + 1, 3 * t + 2])
        .collect();
    let dir = tempfile::tempdir().unwrap();
    let ply = dir.path().join("spot_soup.ply");
    subdfit::io::write_ply(&ply, &corners, &faces, &[], None).unwrap();
    let obj = write(dir.path(), "spot_soup.obj", &corners, &faces);

    // Both soups load as the same welded mesh, with the weld said; it has
    // spot's triangles and vertex count (the numbering is the soup's).
    let from_ply = subdfit::io::read_mesh(&ply).unwrap();
    let from_obj = subdfit::io::read_mesh(&obj).unwrap();
    assert_eq!(from_ply.mesh, from_obj.mesh);
    assert_eq!(from_ply.mesh.positions.len(), mesh.positions.len());
    assert_eq!(from_ply.mesh.triangles.len(), mesh.triangles.len());
    let welded = corners.len() - mesh.positions.len();
    assert_eq!(from_ply.report.welded_vertices, welded);
    assert!(from_ply.report.manifold && from_ply.report.closed);

    let a = convert(&spot, &dir.path().join("plain"));
    let b = convert(&ply, &dir.path().join("soup"));
    let notes = b["input"]["notes"].to_string();
    assert!(
        notes.contains(&format!("welded {welded} vertices")),
        "{notes}"
    );
    let patches = |r: &serde_json::Value| r["control"]["faces"].as_f64().unwrap();
    let rms = |r: &serde_json::Value| r["accuracy"]["limit"]["rms_permille"].as_f64().unwrap();
    let (pa, pb) = (patches(&a), patches(&b));
    let (ra, rb) = (rms(&a), rms(&b));
    println!("spot: {pa} patches RMS {ra:.4}‰; soup: {pb} patches RMS {rb:.4}‰");
    assert!((pb - pa).abs() <= 0.05 * pa, "patches {pb} vs {pa}");
    assert!((rb - ra).abs() <= 0.10 * ra, "RMS L {rb} vs {ra}");
}
