//! The projectability rounds at a fixed count (`SUBDFIT_FACES_PROJ=1`,
//! `subdfit::convert`'s `faces_proj`, issue 40, session 15) on a sphere
//! with a flat fin narrower than the patches across it: at `--faces 60`
//! the field layout leaves the fin's sides unprojectable (Fitmaps §3.1.3:
//! the limit's normal lines miss them), and the rounds, which move lattice
//! size there from everywhere else, bring the unprojectable share of M's
//! area under issue 40's 0.1 % at the same count ±2 %.

use std::path::Path;

use subdfit::DVec3;

/// An icosphere of unit radius subdivided `sub` times, its radius raised
/// on the upper half by a fin `a · exp(−(x/sx)² − (y/sy)²)` (thin in x,
/// long in y), as OBJ text.
fn finned_sphere(sub: usize, a: f64, sx: f64, sy: f64) -> String {
    let t = (1.0 + 5f64.sqrt()) / 2.0;
    let mut v: Vec<DVec3> = [
        (-1.0, t, 0.0),
        (1.0, t, 0.0),
        (-1.0, -t, 0.0),
        (1.0, -t, 0.0),
        (0.0, -1.0, t),
        (0.0, 1.0, t),
        (0.0, -1.0, -t),
        (0.0, 1.0, -t),
        (t, 0.0, -1.0),
        (t, 0.0, 1.0),
        (-t, 0.0, -1.0),
        (-t, 0.0, 1.0),
    ]
    .iter()
    .map(|&(x, y, z)| DVec3::new(x, y, z).normalize())
    .collect();
    let mut f: Vec<[usize; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..sub {
        let mut mid = std::collections::HashMap::new();
        let mut m = |a: usize, b: usize, v: &mut Vec<DVec3>| {
            *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                v.push((v[a] + v[b]).normalize());
                v.len() - 1
            })
        };
        let mut next = Vec::with_capacity(4 * f.len());
        for &[a, b, c] in &f {
            let (ab, bc, ca) = (m(a, b, &mut v), m(b, c, &mut v), m(c, a, &mut v));
            next.extend([[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        f = next;
    }
    let mut obj = String::new();
    for p in &v {
        let r = 1.0
            + if p.z > 0.0 {
                a * (-(p.x / sx).powi(2) - (p.y / sy).powi(2)).exp()
            } else {
                0.0
            };
        let q = r * *p;
        obj += &format!("v {:.9} {:.9} {:.9}\n", q.x, q.y, q.z);
    }
    for [a, b, c] in &f {
        obj += &format!("f {} {} {}\n", a + 1, b + 1, c + 1);
    }
    obj
}

/// `convert` at `--faces n` with the field layout, the rounds on or off:
/// the patch count and the report's unprojectable share of M's area, %.
fn convert(mesh: &Path, out: &Path, n: usize, rounds: bool) -> (usize, f64) {
    let status = std::process::Command::new(env!("CARGO_BIN_EXE_subdfit"))
        .args(["convert"])
        .arg(mesh)
        .arg("-o")
        .arg(out)
        .args([
            "--mode",
            "organic",
            "--layout",
            "field",
            "--tolerance",
            "0.01",
        ])
        .args(["--faces", &n.to_string(), "--max-error", "inf", "--quiet"])
        .env("SUBDFIT_FACES_PROJ", if rounds { "1" } else { "0" })
        .status()
        .unwrap();
    assert!(status.success(), "rounds {rounds}: {status}");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    let control = subdfit::io::read_control_mesh(&out.join("control.obj")).unwrap();
    let unprojectable = report["projectability"]["unprojectable_area_percent"]
        .as_f64()
        .unwrap();
    (control.num_faces(), unprojectable)
}

/// Measured (session 15): 59 patches, 0.183 % unprojectable without the
/// rounds; 60, 0.057 % with them. The bounds: the plain layout must miss
/// issue 40's 0.1 % (else the fixture tests nothing), the rounds must meet
/// it at N ± 2 % (`--faces`' own window).
#[test]
fn the_rounds_make_a_narrow_fin_projectable_at_the_same_count() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = dir.path().join("fin.obj");
    std::fs::write(&mesh, finned_sphere(5, 0.6, 0.07, 0.35)).unwrap();
    let n = 60;
    let (f0, u0) = convert(&mesh, &dir.path().join("off"), n, false);
    let (f1, u1) = convert(&mesh, &dir.path().join("on"), n, true);
    assert!(
        u0 > 0.1,
        "without the rounds: {f0} patches, {u0} % unprojectable"
    );
    assert!(
        u1 <= 0.1,
        "with the rounds: {f1} patches, {u1} % (without: {u0} %)"
    );
    assert!(
        (f1 as f64 - n as f64).abs() <= 0.02 * n as f64,
        "with the rounds: {f1} patches for --faces {n}"
    );
}
