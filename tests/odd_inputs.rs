//! Inputs as people have them (issue 22): a "scan" with several parts, a
//! bow-tie vertex, an open boundary and zero-area faces converts; so does a
//! mesh coarser than the Fitmap's radii (a tetrahedron, reproduced exactly
//! with creases), with the result stated in `report.json`.

use std::f64::consts::PI;
use std::fmt::Write as _;
use std::path::Path;
use std::process::Command;

struct Obj {
    v: Vec<[f64; 3]>,
    f: Vec<[usize; 3]>,
}

impl Obj {
    /// A UV sphere (`n` rings, `m` segments) centred at `c`; returns the
    /// indices of its north and south poles.
    fn sphere(&mut self, c: [f64; 3], r: f64, n: usize, m: usize) -> (usize, usize) {
        let o = self.v.len();
        self.v.push([c[0], c[1], c[2] + r]);
        for i in 1..n {
            let th = PI * i as f64 / n as f64;
            for j in 0..m {
                let ph = 2.0 * PI * j as f64 / m as f64;
                self.v.push([
                    c[0] + r * th.sin() * ph.cos(),
                    c[1] + r * th.sin() * ph.sin(),
                    c[2] + r * th.cos(),
                ]);
            }
        }
        self.v.push([c[0], c[1], c[2] - r]);
        let s = self.v.len() - 1;
        let idx = |i: usize, j: usize| o + 1 + (i - 1) * m + j % m;
        for j in 0..m {
            self.f.push([o, idx(1, j), idx(1, j + 1)]);
            self.f.push([s, idx(n - 1, j + 1), idx(n - 1, j)]);
        }
        for i in 1..n - 1 {
            for j in 0..m {
                let (a, b, c2, d) = (idx(i, j), idx(i + 1, j), idx(i + 1, j + 1), idx(i, j + 1));
                self.f.push([a, b, c2]);
                self.f.push([a, c2, d]);
            }
        }
        (o, s)
    }

    fn text(&self) -> String {
        let mut s = String::new();
        for p in &self.v {
            writeln!(s, "v {} {} {}", p[0], p[1], p[2]).unwrap();
        }
        for t in &self.f {
            writeln!(s, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1).unwrap();
        }
        s
    }
}

fn convert(input: &Path, out: &Path) -> (bool, String, serde_json::Value) {
    let o = Command::new(env!("CARGO_BIN_EXE_subdfit"))
        .arg("convert")
        .arg(input)
        .arg("-o")
        .arg(out)
        .arg("--quiet")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    let report = std::fs::read_to_string(out.join("report.json"))
        .ok()
        .and_then(|t| serde_json::from_str(&t).ok())
        .unwrap_or(serde_json::Value::Null);
    (o.status.success(), err, report)
}

#[test]
fn a_scan_with_several_parts_a_bow_tie_holes_and_slivers_converts() {
    let mut m = Obj {
        v: Vec::new(),
        f: Vec::new(),
    };
    let (_, south) = m.sphere([0.0, 0.0, 0.0], 1.0, 16, 32);
    // A second part touching the first at one vertex: its north pole is
    // the first sphere's south pole (a bow-tie vertex).
    let (north2, _) = m.sphere([0.0, 0.0, -2.0], 1.0, 16, 32);
    for t in m.f.iter_mut() {
        for x in t.iter_mut() {
            if *x == north2 {
                *x = south;
            }
        }
    }
    // A third part, open: a sphere with a cap of faces removed (a hole).
    let first = m.f.len();
    m.sphere([4.0, 0.0, 0.0], 1.0, 16, 32);
    m.f.drain(first..first + 12);
    // A zero-area sliver inside the open part: edge a–b of a triangle
    // (a, b, c) split at its midpoint p into (a, p, c), (p, b, c), plus
    // the flat (a, b, p) between the edge and its midpoint.
    let [a, b, c] = m.f[first + 40];
    let p = m.v.len();
    let (va, vb) = (m.v[a], m.v[b]);
    m.v.push([
        0.5 * (va[0] + vb[0]),
        0.5 * (va[1] + vb[1]),
        0.5 * (va[2] + vb[2]),
    ]);
    m.f[first + 40] = [a, p, c];
    m.f.push([p, b, c]);
    m.f.push([a, b, p]);
    // A small fourth part far off.
    m.sphere([0.0, 5.0, 0.0], 0.3, 8, 16);

    let tmp = tempfile::tempdir().unwrap();
    let input = tmp.path().join("scan.obj");
    std::fs::write(&input, m.text()).unwrap();
    let out = tmp.path().join("out");
    let (ok, err, report) = convert(&input, &out);
    assert!(ok, "the scan was refused: {err}");
    let notes = report["input"]["notes"].to_string();
    assert!(notes.contains("split 1 non-manifold vertex"), "{notes}");
    assert!(
        report["input"]["manifold"].as_bool().unwrap(),
        "{}",
        report["input"]
    );
    assert_eq!(report["input"]["components"].as_u64(), Some(4));
    assert!(report["input"]["zero_area_faces"].as_u64().unwrap() >= 1);
    // Every part is fitted: the surface is near the whole input, and the
    // input is reached from the surface (holes and parts kept).
    let rms = report["accuracy"]["limit"]["rms_permille"]
        .as_f64()
        .unwrap();
    let unproj = report["projectability"]["unprojectable_area_percent"]
        .as_f64()
        .unwrap();
    assert!(rms < 5.0, "RMS L {rms}‰");
    assert!(unproj < 1.0, "unprojectable {unproj} %");
}

#[test]
fn a_tetrahedron_becomes_its_own_creased_control_mesh() {
    let tmp = tempfile::tempdir().unwrap();
    let input = tmp.path().join("tet.obj");
    std::fs::write(
        &input,
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 2 3 4\nf 1 4 3\n",
    )
    .unwrap();
    let out = tmp.path().join("out");
    let (ok, err, report) = convert(&input, &out);
    assert!(ok, "the tetrahedron was refused: {err}");
    assert_eq!(
        report["control"]["faces"].as_u64(),
        Some(12),
        "one level of refinement"
    );
    assert_eq!(report["control"]["corners"].as_u64(), Some(4));
    // Planar faces with creased borders: the limit surface is the
    // tetrahedron itself, to round-off.
    let rms = report["accuracy"]["limit"]["rms_permille"]
        .as_f64()
        .unwrap();
    assert!(rms < 1e-9, "RMS L {rms}‰");
    assert!(
        report["options"]["run"]["coarse_input"].is_string(),
        "{}",
        report["options"]
    );
}

/// Converts spot at unit scale and at `f` (library API, default options)
/// and returns (unit-scale result, scaled result).
fn convert_spot_scaled(factors: &[f64]) -> Vec<subdfit::convert::Converted> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/spot.ply");
    let opts = subdfit::convert::ConvertOptions::default();
    factors
        .iter()
        .map(|&f| {
            let mut soup = subdfit::io::read_soup(&path).unwrap();
            soup.positions.iter_mut().for_each(|p| *p *= f);
            let m = subdfit::mesh::validate_soup(soup, &path).unwrap();
            subdfit::convert::convert_in_memory(&m, &opts, Default::default(), &mut |_, _| true)
                .unwrap()
        })
        .collect()
}

/// Issue 22: any uniform scale gives the same result up to that scale,
/// decimal factors included. Every conversion runs in the input's working
/// frame (`mesh::Frame`: centred, unit diagonal, snapped to 2^-30 of it),
/// so spot at 1e20 and 1e-20 (Embree's f32 squares over- and underflow
/// there) has the same working mesh as spot, bit for bit unless one of its
/// 8.8k coordinates sits within a few ulps of a grid mid-point (~1e-7
/// each). Its control mesh is then unit spot's times the factor, to the
/// round-off of mapping back (~1e-16); the tolerance 1e-9 of the diagonal
/// is the issue's, and a length left unscaled anywhere breaks it by 40
/// orders of magnitude.
#[test]
fn spot_at_1e20_and_1e_minus_20_gives_the_scaled_result() {
    let factors = [1.0, 1e20, 1e-20];
    let runs = convert_spot_scaled(&factors);
    let unit = &runs[0];
    let diag = unit.report.input.bbox_diagonal;
    for (&f, scaled) in factors.iter().zip(&runs).skip(1) {
        let (a, b) = (unit.control.positions(), scaled.control.positions());
        assert_eq!(a.len(), b.len(), "{f:e}: vertex count");
        assert_eq!(unit.control.num_faces(), scaled.control.num_faces());
        let worst = a
            .iter()
            .zip(b)
            .map(|(p, q)| (*q / f - *p).length() / diag)
            .fold(0.0, f64::max);
        assert!(
            worst <= 1e-9,
            "{f:e}: control points differ by {worst:e} of the diagonal"
        );
        // Everything else that has a length scales too, and report.json
        // (‰ of the diagonal) is unchanged to round-off.
        let du = |c: &subdfit::convert::Converted| c.surfaces.displacement.offsets.clone();
        for (o, p) in du(unit).iter().zip(du(scaled)) {
            assert!((p / f - o).abs() <= 1e-9 * diag);
        }
        let rel = |x: f64, y: f64| (x - y).abs() / x.abs().max(y.abs()).max(f64::MIN_POSITIVE);
        let (l0, l1) = (
            unit.report.accuracy.limit.rms_permille,
            scaled.report.accuracy.limit.rms_permille,
        );
        assert!(rel(l0, l1) <= 1e-9, "{f:e}: RMS L {l1} vs {l0}");
        let sd = scaled.report.input.bbox_diagonal;
        assert!(rel(sd, diag * f) <= 1e-15, "{f:e}: diagonal {sd:e}");
        assert!(rel(scaled.surfaces.metrics.bbox_diagonal, sd) <= 1e-15);
        let (r0, r1) = (
            unit.fitmap.as_ref().unwrap().radii[0],
            scaled.fitmap.as_ref().unwrap().radii[0],
        );
        assert!(rel(r1, r0 * f) <= 1e-9, "{f:e}: r_0 {r1:e} vs {r0:e}");
    }
}
