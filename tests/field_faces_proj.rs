//! The projectability rounds at a fixed count (`SUBDFIT_FACES_PROJ=1`,
//! `subdfit::convert`'s `faces_proj`, issue 40, session 15) on a sphere
//! with a flat fin narrower than the patches across it: at `--faces 60`
//! the field layout leaves the fin's sides unprojectable (Fitmaps §3.1.3:
//! the limit's normal lines miss them), and the rounds, which move lattice
//! size there from everywhere else, bring the unprojectable share of M's
//! area under issue 40's 0.1 % at the same count ±2 %.

use std::path::Path;

mod common;

use subdfit::DVec3;

/// An icosphere of unit radius subdivided `sub` times, its radius raised
/// on the upper half by a fin `a · exp(−(x/sx)² − (y/sy)²)` (thin in x,
/// long in y), as OBJ text.
fn finned_sphere(sub: u32, a: f64, sx: f64, sy: f64) -> String {
    let sphere = common::icosphere(sub, DVec3::ZERO, 1.0);
    let mut obj = String::new();
    for p in &sphere.positions {
        let r = 1.0
            + if p.z > 0.0 {
                a * (-(p.x / sx).powi(2) - (p.y / sy).powi(2)).exp()
            } else {
                0.0
            };
        let q = r * *p;
        obj += &format!("v {:.9} {:.9} {:.9}\n", q.x, q.y, q.z);
    }
    for [a, b, c] in &sphere.triangles {
        obj += &format!("f {} {} {}\n", a + 1, b + 1, c + 1);
    }
    obj
}

/// `convert` at `--faces n` with the field layout, the rounds on or off:
/// the patch count and the report's unprojectable share of M's area, %.
fn convert(mesh: &Path, out: &Path, n: usize, rounds: bool) -> (usize, f64) {
    let status = common::field_convert_at(mesh, out, n)
        .args(["--max-error", "inf"])
        .env("SUBDFIT_FACES_PROJ", if rounds { "1" } else { "0" })
        .status()
        .unwrap();
    assert!(status.success(), "rounds {rounds}: {status}");
    let (faces, report) = common::faces_and_report(out);
    let unprojectable = report["projectability"]["unprojectable_area_percent"]
        .as_f64()
        .unwrap();
    (faces, unprojectable)
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
