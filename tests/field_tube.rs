//! The field layout's tube cap (`quad::field::tube`,
//! `SUBDFIT_FIELD_TUBE_CAP`, session 25): a ball with a thin finger, which
//! a lattice coarser than the finger skips (homer's fingertips at
//! `--faces 272`, docs/status.md "Field-aligned layout"), and a thin disc,
//! a sheet the cap must leave alone.

mod common;

use std::f64::consts::PI;

use subdfit::mesh::TriMesh;
use subdfit::quad::field::{control_topology, field_layout_sized, tube, FieldOptions, Surface};
use subdfit::raycast::bvh::BvhCaster;
use subdfit::subdiv::{make_evaluator, Backend, EvalOptions};
use subdfit::DVec3;

/// A closed surface of revolution about z from a profile (ρ, z) sampled
/// from pole to pole (ρ = 0 at both ends, dropped for one pole vertex
/// each), `nu` vertices per ring, outward oriented.
fn revolution(profile: &[(f64, f64)], nu: usize) -> TriMesh {
    let rings = &profile[1..profile.len() - 1];
    let mut positions = vec![DVec3::new(0.0, 0.0, profile[0].1)];
    for &(r, z) in rings {
        for i in 0..nu {
            let a = 2.0 * PI * i as f64 / nu as f64;
            positions.push(DVec3::new(r * a.cos(), r * a.sin(), z));
        }
    }
    let top = positions.len() as u32;
    positions.push(DVec3::new(0.0, 0.0, profile[profile.len() - 1].1));
    let id = |j: usize, i: usize| (1 + j * nu + i % nu) as u32;
    let mut triangles = Vec::new();
    for i in 0..nu {
        triangles.push([0, id(0, i + 1), id(0, i)]);
        triangles.push([top, id(rings.len() - 1, i), id(rings.len() - 1, i + 1)]);
    }
    for j in 0..rings.len() - 1 {
        for i in 0..nu {
            let (a, b, c, d) = (id(j, i), id(j, i + 1), id(j + 1, i + 1), id(j + 1, i));
            triangles.push([a, b, c]);
            triangles.push([a, c, d]);
        }
    }
    TriMesh {
        positions,
        triangles,
    }
}

/// Samples of a polyline profile at about `step` apart (the corners kept).
fn resampled(corners: &[(f64, f64)], step: impl Fn(f64) -> f64) -> Vec<(f64, f64)> {
    let mut out = vec![corners[0]];
    for w in corners.windows(2) {
        let (a, b) = (w[0], w[1]);
        let len = ((b.0 - a.0).powi(2) + (b.1 - a.1).powi(2)).sqrt();
        let k = (len / step(a.1.max(b.1))).ceil().max(1.0) as usize;
        for s in 1..=k {
            let t = s as f64 / k as f64;
            out.push((a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1)));
        }
    }
    out
}

/// Finger radius and the height of its tip's top.
const A: f64 = 0.08;
const TIP: f64 = 1.6 + A;

/// The unit ball with a finger of radius [`A`] along +z up to [`TIP`]
/// (a cylinder and a hemispherical tip).
fn ball_with_finger() -> TriMesh {
    let phi1 = PI - A.asin();
    let mut corners: Vec<(f64, f64)> = (0..=60)
        .map(|k| {
            let p = phi1 * k as f64 / 60.0;
            (p.sin(), -p.cos())
        })
        .collect();
    corners.push((A, 1.6));
    for k in 1..=8 {
        let psi = 0.5 * PI * k as f64 / 8.0;
        corners.push((A * psi.cos(), 1.6 + A * psi.sin()));
    }
    let profile = resampled(&corners, |z| if z > 0.99 { 0.02 } else { 0.06 });
    revolution(&profile, 40)
}

/// A disc of radius 1 and thickness 0.06 (a sheet: thin across, wide
/// along), its rim rounded.
fn thin_disc() -> TriMesh {
    let h = 0.03;
    let mut corners = vec![(0.0, -h), (1.0 - h, -h)];
    for k in 1..8 {
        let psi = -0.5 * PI + PI * k as f64 / 8.0;
        corners.push((1.0 - h + h * psi.cos(), h * psi.sin()));
    }
    corners.push((1.0 - h, h));
    corners.push((0.0, h));
    let profile = resampled(&corners, |_| 0.05);
    revolution(&profile, 48)
}

/// Tangent directions for the cap's across rays (any tangent frame: the
/// test of a tube takes either axis).
fn tangents(s: &Surface) -> Vec<DVec3> {
    s.normals
        .iter()
        .map(|n| {
            let t = DVec3::Z - n.dot(DVec3::Z) * *n;
            if t.length() > 1e-3 {
                t.normalize()
            } else {
                n.any_orthonormal_vector()
            }
        })
        .collect()
}

/// The cap finds the finger: on its cylinder the cap is k times its
/// thickness 2A (the chord along −n is the diameter), on the ball away
/// from the finger k times the ball's own diameter or none, and on the
/// faces of a thin disc (a sheet, thinner still than the finger) none.
#[test]
fn caps_the_finger_not_the_ball_nor_a_sheet() {
    let k = std::f64::consts::FRAC_PI_4;
    let m = ball_with_finger();
    let s = Surface::new(&m).unwrap();
    let c = BvhCaster::new(&m).unwrap();
    let caps = tube::tube_caps(&s, &tangents(&s), &c, k).unwrap();
    let (mut finger, mut ball) = (0, 0);
    for (p, cap) in s.positions.iter().zip(&caps) {
        if p.z > 1.1 && p.z < 1.5 {
            finger += 1;
            // The chord along −n is 2A within the tessellation's sagitta.
            let want = (k * 2.0 * A).max(s.mean_edge);
            assert!(
                (cap - want).abs() < 0.05 * want,
                "finger at {p}: cap {cap}, want {want}"
            );
        }
        if p.z < 0.8 {
            ball += 1;
            // The ball is round across too (a chord along −n through
            // its centre, half-chords of its radius across): its cap is
            // k times its own diameter or more, which binds no lattice
            // the ball would not hold anyway.
            assert!(*cap >= k * 1.9, "ball at {p}: cap {cap}");
        }
    }
    assert!(
        finger > 100 && ball > 1000,
        "{finger} finger, {ball} ball vertices"
    );
    let m = thin_disc();
    let s = Surface::new(&m).unwrap();
    let c = BvhCaster::new(&m).unwrap();
    let caps = tube::tube_caps(&s, &tangents(&s), &c, k).unwrap();
    // The faces are no tube (the chords across run the disc's width);
    // the rounded rim is half a tube, and its shoulders read as one, at
    // no less than k times the sheet's thickness 0.06.
    let mut rim = 0;
    for ((n, p), cap) in s.normals.iter().zip(&s.positions).zip(&caps) {
        if n.z.abs() > 0.9 {
            assert!(cap.is_infinite(), "disc face at {p}: cap {cap}");
        } else if cap.is_finite() {
            rim += 1;
            assert!(*cap >= k * 0.06, "disc rim at {p}: cap {cap}");
        }
    }
    assert!(rim < caps.len() / 10, "{rim} of {} capped", caps.len());
}

/// The highest point of the limit surface of the layout of `m` at the
/// uniform size `h` (at the control vertices' limits), and whether the
/// layout keeps M's topology.
fn limit_top(m: &TriMesh, h: f64, cap: Option<f64>) -> (f64, usize, bool) {
    let opts = FieldOptions::default().with_tube_cap(cap);
    let out = field_layout_sized(m, &vec![h; m.positions.len()], &opts).unwrap();
    let k = &out.control;
    let same = control_topology(k) == Surface::new(m).unwrap().topology;
    let e = make_evaluator(Backend::Rust, k, &EvalOptions::default()).unwrap();
    let limits = e.vertex_limits(k.positions()).unwrap();
    let top = limits.iter().map(|l| l.position.z).fold(f64::MIN, f64::max);
    (top, k.num_faces(), same)
}

/// A lattice at 0.5 (three times the finger's width) leaves the finger
/// under a patch or two whose limit surface stops far below its tip
/// (the limit is a convex combination of control points, so the tip is
/// lost whatever the fit does); with the cap the lattice steps down to
/// rings of quads around the finger and the limit reaches the tip within
/// its radius, M's topology kept.
#[test]
fn capped_lattice_reaches_the_fingertip() {
    let m = ball_with_finger();
    let (top0, n0, same0) = limit_top(&m, 0.5, None);
    let (top1, n1, same1) = limit_top(&m, 0.5, Some(std::f64::consts::FRAC_PI_4));
    eprintln!("uncapped: top {top0:.3} of {TIP:.3}, {n0} quads; capped: top {top1:.3}, {n1} quads");
    assert!(same0 && same1, "topology kept: {same0} {same1}");
    assert!(
        top0 < TIP - 0.3,
        "uncapped limit top {top0}: the finger is not skipped"
    );
    // Within 2A: the closing quads of a ring of edge k · 2A ≈ 1.6 A sit
    // their limit inside their control points by a fraction of an edge
    // (measured 1.5 A).
    assert!(top1 > TIP - 2.0 * A, "capped limit top {top1}, tip {TIP}");
    assert!(n1 > n0, "the cap adds the finger's patches: {n0} → {n1}");
}

/// The unit ball without the finger (the same profile's sphere part).
fn plain_ball() -> TriMesh {
    let corners: Vec<(f64, f64)> = (0..=60)
        .map(|k| {
            let p = PI * k as f64 / 60.0;
            (p.sin(), -p.cos())
        })
        .collect();
    revolution(&resampled(&corners, |_| 0.06), 40)
}

/// `m` as OBJ text.
fn obj(m: &TriMesh) -> String {
    let mut s = String::new();
    for p in &m.positions {
        s += &format!("v {:.9} {:.9} {:.9}\n", p.x, p.y, p.z);
    }
    for [a, b, c] in &m.triangles {
        s += &format!("f {} {} {}\n", a + 1, b + 1, c + 1);
    }
    s
}

/// `convert` at `--faces n` with the field layout, `SUBDFIT_FACES_PROJ_TUBE`
/// at `k` (unset: `None`; the other projectability rounds off): the patch
/// count, the report's RMS L (‰) and unprojectable share of M's area (%).
fn convert_tube(
    mesh: &std::path::Path,
    out: &std::path::Path,
    n: usize,
    k: Option<&str>,
) -> (usize, f64, f64) {
    let mut cmd = common::field_convert_at(mesh, out, n);
    cmd.args(["--max-error", "inf"])
        .env("SUBDFIT_FACES_PROJ", "0")
        .env_remove("SUBDFIT_FIELD_TUBE_CAP");
    match k {
        Some(k) => cmd.env("SUBDFIT_FACES_PROJ_TUBE", k),
        None => cmd.env_remove("SUBDFIT_FACES_PROJ_TUBE"),
    };
    let status = cmd.status().unwrap();
    assert!(status.success(), "tube {k:?}: {status}");
    let (faces, report) = common::faces_and_report(out);
    let unprojectable = report["projectability"]["unprojectable_area_percent"]
        .as_f64()
        .unwrap();
    let l = report["accuracy"]["limit"]["rms_permille"]
        .as_f64()
        .unwrap();
    (faces, l, unprojectable)
}

/// The gated tube round (`SUBDFIT_FACES_PROJ_TUBE`, session 26): at
/// `--faces 40` (edges ≈ 0.56, 3.5 finger widths) the first fit leaves the
/// finger under a patch whose limit misses its tip (measured 0.56 %
/// unprojectable, RMS L 15.5‰: the tip's 0.6 of the ball's radius); one
/// round capped at k · 2A on the tubes under the unprojectable patches
/// reaches it (0.00 %, RMS L 1.7‰) at the same count. Session 15's
/// rounds (`SUBDFIT_FACES_PROJ=1`, a factor on h) stay at 0.38 % and
/// 15.4‰ after six. A ball without the finger leaves nothing
/// unprojectable, so no round runs: the same bytes as without the switch.
#[test]
fn the_gated_tube_round_reaches_the_fingertip_and_leaves_a_plain_ball_alone() {
    let dir = tempfile::tempdir().unwrap();
    let finger = dir.path().join("finger.obj");
    std::fs::write(&finger, obj(&ball_with_finger())).unwrap();
    let n = 40;
    let (f0, l0, u0) = convert_tube(&finger, &dir.path().join("off"), n, None);
    let (f1, l1, u1) = convert_tube(&finger, &dir.path().join("on"), n, Some("1.0"));
    eprintln!("finger: off {f0} / {l0:.3}‰ / {u0:.3} %, on {f1} / {l1:.3}‰ / {u1:.3} %");
    // The fixture must miss issue 40's 0.1 % without the round.
    assert!(u0 > 0.1, "without the round: {u0} %");
    assert!(u1 <= 0.1, "with the round: {u1} % (without: {u0} %)");
    // The tip (0.68 above the ball, 17 % of the diagonal's span) was the
    // RMS: reached, RMS L falls by far more than a redraw's noise.
    assert!(l1 < 0.5 * l0, "RMS L {l0}‰ → {l1}‰");
    assert!(
        (f1 as f64 - n as f64).abs() <= 0.02 * n as f64,
        "{f1} patches for --faces {n}"
    );
    let ball = dir.path().join("ball.obj");
    std::fs::write(&ball, obj(&plain_ball())).unwrap();
    let (off, on) = (dir.path().join("ball-off"), dir.path().join("ball-on"));
    let (_, _, u) = convert_tube(&ball, &off, n, None);
    convert_tube(&ball, &on, n, Some("1.0"));
    assert!(u <= 0.1, "the plain ball: {u} %");
    for file in ["control.obj", "displacement.exr", "limit.ply"] {
        let (a, b) = (
            std::fs::read(off.join(file)).unwrap(),
            std::fs::read(on.join(file)).unwrap(),
        );
        assert!(a == b, "{file} differs with the switch on a plain ball");
    }
}
