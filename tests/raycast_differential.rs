//! Differential and analytic tests of the two [`RayCaster`] implementations
//! (pure-Rust BVH and Embree), generic over `&dyn RayCaster`.
//!
//! Tolerance: `1e-6` of the bounding-box diagonal on distances (the unit of
//! every error in subdfit). Embree works on f32 vertices translated to the
//! bbox centre, so its edge decisions are off by up to ~1e-7 of the diagonal;
//! rays whose hit lies within the tolerance of a triangle edge may therefore
//! legitimately hit the neighbouring triangle (or, at an open boundary or a
//! silhouette, miss): there the hit *points* are compared, not the ids.

mod common;

use std::fmt::Write as _;

use common::*;
use rand::Rng;
use subdfit::mesh::TriMesh;
use subdfit::raycast::{make_raycaster, ClosestPoint, Hit, Ray, RayBackend, RayCaster};
use subdfit::DVec3;

const REL_TOL: f64 = 1e-6;

fn both(mesh: &TriMesh) -> [Box<dyn RayCaster>; 2] {
    [
        make_raycaster(RayBackend::Rust, mesh).expect("BVH build"),
        make_raycaster(RayBackend::Embree, mesh).expect("Embree build"),
    ]
}

fn seg_dist(p: DVec3, a: DVec3, b: DVec3) -> f64 {
    let ab = b - a;
    let s = ((p - a).dot(ab) / ab.length_squared()).clamp(0.0, 1.0);
    (p - (a + s * ab)).length()
}

/// Distance from `p` to the nearest edge of triangle `t`.
fn edge_dist(mesh: &TriMesh, t: u32, p: DVec3) -> f64 {
    let [a, b, c] = mesh.triangle(t as usize);
    seg_dist(p, a, b)
        .min(seg_dist(p, b, c))
        .min(seg_dist(p, c, a))
}

fn bary_point(mesh: &TriMesh, t: u32, u: f64, v: f64) -> DVec3 {
    let [a, b, c] = mesh.triangle(t as usize);
    (1.0 - u - v) * a + u * b + v * c
}

/// Collects failures with context, prints a summary and dumps the failing
/// cases to `target/tmp/` for replay.
struct Report {
    label: String,
    failures: Vec<String>,
    worst: f64,
    worst_case: String,
    edge_cases: usize,
    edge_misses: usize,
    n: usize,
}

impl Report {
    fn new(label: &str, n: usize) -> Self {
        Report {
            label: label.into(),
            failures: vec![],
            worst: 0.0,
            worst_case: String::new(),
            edge_cases: 0,
            edge_misses: 0,
            n,
        }
    }
    fn diff(&mut self, d: f64, case: impl FnOnce() -> String) {
        if d > self.worst {
            self.worst = d;
            self.worst_case = case();
        }
    }
    fn fail(&mut self, msg: String) {
        self.failures.push(msg);
    }
    fn finish(self, diag: f64) {
        eprintln!(
            "{}: {} queries, worst distance difference {:.3e} of the diagonal ({}), \
             {} near-edge hits compared by point, {} near-edge hit/miss disagreements",
            self.label,
            self.n,
            self.worst / diag,
            self.worst_case,
            self.edge_cases,
            self.edge_misses
        );
        if !self.failures.is_empty() {
            let path = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!(
                "raycast_failures_{}.txt",
                self.label.replace(' ', "_")
            ));
            let mut s = String::new();
            for f in &self.failures {
                writeln!(s, "{f}").unwrap();
            }
            let _ = std::fs::write(&path, s);
            panic!(
                "{}: {} failures (dumped to {}); first: {}",
                self.label,
                self.failures.len(),
                path.display(),
                self.failures[0]
            );
        }
        // Near-edge hit/miss disagreements need a ray within ~1e-7 of the
        // diagonal of an open boundary or silhouette: a handful at most.
        assert!(
            self.edge_misses <= 2 + self.n / 20_000,
            "{}: too many near-edge hit/miss disagreements: {}",
            self.label,
            self.edge_misses
        );
    }
}

/// Checks one backend's hit for internal consistency: the barycentrics
/// reproduce the ray point at `t` and lie in the triangle.
fn check_hit_consistent(
    mesh: &TriMesh,
    name: &str,
    ray: &Ray,
    h: &Hit,
    tol: f64,
) -> Option<String> {
    let on_ray = ray.at(h.t);
    let from_bary = bary_point(mesh, h.triangle, h.u, h.v);
    let bad_bary = !(h.u >= 0.0 && h.v >= 0.0 && h.u + h.v <= 1.0 + 1e-12);
    if (on_ray - from_bary).length() > tol || bad_bary {
        Some(format!(
            "{name}: inconsistent hit {h:?} for {ray:?}: ray point {on_ray}, barycentric point {from_bary}"
        ))
    } else {
        None
    }
}

/// Compares two backends' hits of the same rays (`rays[i]` is the query; for
/// line hits the ray spans `[-max_t, max_t]` and `t` is signed).
fn compare_hits(
    label: &str,
    mesh: &TriMesh,
    names: [&str; 2],
    rays: &[Ray],
    ha: &[Option<Hit>],
    hb: &[Option<Hit>],
) {
    let diag = mesh.bbox_diagonal();
    let tol = REL_TOL * diag;
    let mut rep = Report::new(label, rays.len());
    let mut hits = 0;
    for (i, ((ray, a), b)) in rays.iter().zip(ha).zip(hb).enumerate() {
        let dl = ray.dir.length();
        // Distance of a hit to where the ray segment ends (tmin/tmax, or
        // ±max_t for line queries): a hit there may be in or out in either.
        let near_end = |h: &Hit| {
            let t = h.t.abs();
            ((t - ray.tmax).abs() * dl <= tol) || ((t - ray.tmin).abs() * dl <= tol)
        };
        let near_edge = |h: &Hit| edge_dist(mesh, h.triangle, ray.at(h.t)) <= tol;
        match (a, b) {
            (None, None) => {}
            (Some(h), None) | (None, Some(h)) => {
                if near_edge(h) || near_end(h) {
                    rep.edge_misses += 1;
                } else {
                    let who = if a.is_some() { names[0] } else { names[1] };
                    rep.fail(format!("ray {i}: only {who} hits: {h:?}, {ray:?}"));
                }
            }
            (Some(x), Some(y)) => {
                hits += 1;
                for (n, h) in [(names[0], x), (names[1], y)] {
                    if let Some(m) = check_hit_consistent(mesh, n, ray, h, tol) {
                        rep.fail(format!("ray {i}: {m}"));
                    }
                }
                let d = (x.t - y.t).abs() * dl;
                rep.diff(d, || format!("ray {i}: {x:?} vs {y:?}"));
                if x.triangle != y.triangle {
                    if near_edge(x) || near_edge(y) {
                        rep.edge_cases += 1;
                        let dp = (ray.at(x.t) - ray.at(y.t)).length();
                        if dp > tol {
                            rep.fail(format!(
                                "ray {i}: near-edge hit points differ by {dp:e}: {x:?} vs {y:?}, {ray:?}"
                            ));
                        }
                    } else {
                        rep.fail(format!(
                            "ray {i}: different triangles away from edges: {x:?} vs {y:?}, {ray:?}"
                        ));
                    }
                } else if d > tol {
                    rep.fail(format!(
                        "ray {i}: distances differ by {d:e}: {x:?} vs {y:?}, {ray:?}"
                    ));
                }
            }
        }
    }
    // A differential test where nothing hits proves nothing.
    assert!(
        hits * 5 >= rays.len(),
        "{label}: only {hits} of {} rays hit",
        rays.len()
    );
    rep.finish(diag);
}

fn compare_closest(
    label: &str,
    mesh: &TriMesh,
    names: [&str; 2],
    points: &[DVec3],
    max_dist: f64,
    ca: &[Option<ClosestPoint>],
    cb: &[Option<ClosestPoint>],
) {
    let diag = mesh.bbox_diagonal();
    let tol = REL_TOL * diag;
    let mut rep = Report::new(label, points.len());
    for (i, ((&p, a), b)) in points.iter().zip(ca).zip(cb).enumerate() {
        match (a, b) {
            (None, None) => {}
            (Some(c), None) | (None, Some(c)) => {
                if (c.distance - max_dist).abs() <= tol {
                    rep.edge_misses += 1;
                } else {
                    rep.fail(format!("point {i} {p}: only one backend finds {c:?}"));
                }
            }
            (Some(x), Some(y)) => {
                for (n, c) in [(names[0], x), (names[1], y)] {
                    let from_bary = bary_point(mesh, c.triangle, c.u, c.v);
                    if (from_bary - c.point).length() > tol
                        || ((p - c.point).length() - c.distance).abs() > 1e-12 * diag
                        || c.distance > max_dist
                    {
                        rep.fail(format!("point {i} {p}: {n}: inconsistent {c:?}"));
                    }
                }
                let d = (x.distance - y.distance).abs();
                rep.diff(d, || format!("point {i}: {x:?} vs {y:?}"));
                if d > tol {
                    rep.fail(format!(
                        "point {i} {p}: distances differ by {d:e}: {x:?} vs {y:?}"
                    ));
                }
            }
        }
    }
    rep.finish(diag);
}

/// Reference first hit by brute force over all triangles (Möller–Trumbore
/// in f64), to check the BVH itself and not only its agreement with Embree.
fn brute_first_hit(mesh: &TriMesh, ray: &Ray) -> Option<(f64, u32)> {
    let mut best: Option<(f64, u32)> = None;
    for t in 0..mesh.triangles.len() {
        let [a, b, c] = mesh.triangle(t);
        let (e1, e2) = (b - a, c - a);
        let pv = ray.dir.cross(e2);
        let det = e1.dot(pv);
        if det == 0.0 {
            continue;
        }
        let s = ray.origin - a;
        let u = s.dot(pv) / det;
        let q = s.cross(e1);
        let v = ray.dir.dot(q) / det;
        let tt = e2.dot(q) / det;
        if u >= 0.0
            && v >= 0.0
            && u + v <= 1.0
            && tt >= ray.tmin
            && tt <= ray.tmax
            && best.map_or(true, |(bt, _)| tt < bt)
        {
            best = Some((tt, t as u32));
        }
    }
    best
}

fn random_rays(mesh: &TriMesh, n: usize, seed: u64) -> Vec<Ray> {
    let mut rng = seeded_rng(seed);
    let diag = mesh.bbox_diagonal();
    (0..n)
        .map(|k| {
            if k % 2 == 0 {
                // Incoherent: anywhere in (and around) the box, any direction,
                // non-unit directions and some finite tmax.
                let scale = rng.gen_range(0.5..2.0);
                let tmax = if k % 6 == 0 {
                    rng.gen_range(0.1..1.0) * diag / scale
                } else {
                    f64::INFINITY
                };
                Ray {
                    origin: random_point_in_bbox(&mut rng, mesh, 0.2),
                    dir: random_dir(&mut rng) * scale,
                    tmin: 0.0,
                    tmax,
                }
            } else {
                // Fitting-like: from near the surface, along a perturbed normal.
                let (p, nrm) = random_surface_point(&mut rng, mesh);
                let off = rng.gen_range(-0.01..0.01) * diag;
                let dir = (nrm + 0.3 * random_dir(&mut rng)).normalize();
                let dir = if rng.gen::<bool>() { dir } else { -dir };
                Ray::new(p + off * nrm, dir)
            }
        })
        .collect()
}

fn run_differential(label: &str, mesh: &TriMesh, n_rays: usize) {
    let diag = mesh.bbox_diagonal();
    let tol = REL_TOL * diag;
    let casters = both(mesh);
    let names = [casters[0].name(), casters[1].name()];

    // --- first hits
    let rays = random_rays(mesh, n_rays, 0x5eed_0001);
    let ha = casters[0].first_hits(&rays).unwrap();
    let hb = casters[1].first_hits(&rays).unwrap();
    compare_hits(&format!("{label} first hits"), mesh, names, &rays, &ha, &hb);

    // --- brute-force reference on a subset
    let mut bad = 0;
    for (i, r) in rays.iter().enumerate().step_by(n_rays / 300) {
        let reference = brute_first_hit(mesh, r);
        for h in [&ha[i], &hb[i]] {
            let ok = match (reference, h) {
                (None, None) => true,
                (Some((t, _)), Some(h)) => (t - h.t).abs() * r.dir.length() <= tol,
                (Some((t, tri)), None) => edge_dist(mesh, tri, r.at(t)) <= tol,
                (None, Some(h)) => edge_dist(mesh, h.triangle, r.at(h.t)) <= tol,
            };
            if !ok {
                bad += 1;
                eprintln!("ray {i}: brute force {reference:?} vs {h:?}");
            }
        }
    }
    assert_eq!(bad, 0, "{label}: disagreements with brute force");

    // --- line hits: fitting-style normal projection with a finite range,
    // plus incoherent lines with an unbounded one.
    let mut rng = seeded_rng(0x5eed_0002);
    let n_lines = n_rays / 2;
    let mut origins = Vec::with_capacity(n_lines);
    let mut dirs = Vec::with_capacity(n_lines);
    for _ in 0..n_lines {
        let (p, nrm) = random_surface_point(&mut rng, mesh);
        origins.push(p + rng.gen_range(-0.02..0.02) * diag * nrm);
        dirs.push((nrm + 0.2 * random_dir(&mut rng)).normalize());
    }
    let max_t = 0.03 * diag;
    let la = casters[0].line_hits(&origins, &dirs, max_t).unwrap();
    let lb = casters[1].line_hits(&origins, &dirs, max_t).unwrap();
    let line_rays: Vec<Ray> = origins
        .iter()
        .zip(&dirs)
        .map(|(&o, &d)| Ray {
            origin: o,
            dir: d,
            tmin: 0.0,
            tmax: max_t,
        })
        .collect();
    compare_hits(
        &format!("{label} line hits"),
        mesh,
        names,
        &line_rays,
        &la,
        &lb,
    );
    // Signed t really is the nearest on the line: no hit of either half-ray
    // is nearer than the reported one.
    let fwd = casters[0].first_hits(&line_rays).unwrap();
    for (i, h) in la.iter().enumerate() {
        if let (Some(h), Some(f)) = (h, fwd[i]) {
            assert!(
                h.t.abs() <= f.t + 1e-12 * diag,
                "line {i}: {h:?} farther than +dir hit {f:?}"
            );
        }
    }
    assert!(
        la.iter().flatten().any(|h| h.t < 0.0),
        "{label}: no line hit behind the origin"
    );

    // --- closest points: around the mesh (unbounded) and near the surface
    // with a finite search radius.
    let mut rng = seeded_rng(0x5eed_0003);
    let n_pts = n_rays / 2;
    let far: Vec<DVec3> = (0..n_pts / 2)
        .map(|_| random_point_in_bbox(&mut rng, mesh, 0.5))
        .collect();
    let near: Vec<DVec3> = (0..n_pts / 2)
        .map(|_| {
            let (p, nrm) = random_surface_point(&mut rng, mesh);
            p + rng.gen_range(-0.01..0.01) * diag * nrm
        })
        .collect();
    for (what, pts, max_dist) in [("far", &far, f64::INFINITY), ("near", &near, 0.005 * diag)] {
        let ca = casters[0].closest_points(pts, max_dist).unwrap();
        let cb = casters[1].closest_points(pts, max_dist).unwrap();
        compare_closest(
            &format!("{label} closest {what}"),
            mesh,
            names,
            pts,
            max_dist,
            &ca,
            &cb,
        );
        // Brute-force reference on a subset.
        for (i, &p) in pts.iter().enumerate().step_by(pts.len() / 100) {
            let reference = (0..mesh.triangles.len())
                .filter_map(|t| {
                    let [a, b, c] = mesh.triangle(t);
                    ((b - a).cross(c - a) != DVec3::ZERO)
                        .then(|| common::point_triangle_distance(p, a, b, c))
                })
                .fold(f64::INFINITY, f64::min);
            for c in [&ca[i], &cb[i]] {
                match c {
                    Some(c) => assert!(
                        (c.distance - reference).abs() <= tol,
                        "point {i}: {c:?} vs {reference}"
                    ),
                    None => assert!(
                        reference >= max_dist - tol,
                        "point {i}: missed at {reference}"
                    ),
                }
            }
        }
    }
}

#[test]
fn differential_perturbed_torus() {
    // 2 * 240 * 100 = 48,000 triangles.
    let mesh = perturbed_torus(240, 100, 1.0, 0.35, 0.05);
    run_differential("torus", &mesh, 100_000);
}

#[test]
fn differential_bunny() {
    let Some(mesh) = load_data_mesh("bunny.ply") else {
        return; // data absent: data_dir() printed why
    };
    assert_eq!(
        mesh.triangles.len(),
        69_451,
        "bunny.ply as documented in its README"
    );
    run_differential("bunny", &mesh, 100_000);
}

#[test]
fn analytic_plane() {
    let mesh = flat_grid(8);
    for rc in both(&mesh) {
        let name = rc.name();
        let rays = [
            Ray::new(DVec3::new(2.3, 4.6, 1.5), DVec3::new(0.0, 0.0, -1.0)),
            // Non-unit direction: t is in units of dir.
            Ray::new(DVec3::new(2.3, 4.6, 1.5), DVec3::new(0.0, 0.0, -2.0)),
            // Oblique from below: hits at z = 0 after t = 3.
            Ray::new(DVec3::new(1.0, 1.0, -3.0), DVec3::new(0.5, 0.25, 1.0)),
            // Pointing away, too short, outside the grid, invalid.
            Ray::new(DVec3::new(2.3, 4.6, 1.5), DVec3::new(0.0, 0.0, 1.0)),
            Ray {
                tmax: 1.5 * (1.0 - 1e-3),
                ..Ray::new(DVec3::new(2.3, 4.6, 1.5), DVec3::new(0.0, 0.0, -1.0))
            },
            Ray::new(DVec3::new(9.5, 4.6, 1.5), DVec3::new(0.0, 0.0, -1.0)),
            Ray::new(DVec3::new(f64::NAN, 4.6, 1.5), DVec3::new(0.0, 0.0, -1.0)),
            Ray::new(DVec3::new(2.3, 4.6, 1.5), DVec3::ZERO),
        ];
        let h = rc.first_hits(&rays).unwrap();
        let expect = [
            Some(1.5),
            Some(0.75),
            Some(3.0),
            None,
            None,
            None,
            None,
            None,
        ];
        for (i, (h, e)) in h.iter().zip(expect).enumerate() {
            match (h, e) {
                (Some(h), Some(t)) => {
                    assert!(
                        (h.t - t).abs() < 1e-12,
                        "{name} ray {i}: {h:?}, expected t = {t}"
                    );
                    let p = bary_point(&mesh, h.triangle, h.u, h.v);
                    assert!((p - rays[i].at(t)).length() < 1e-12, "{name} ray {i}: {p}");
                }
                (None, None) => {}
                _ => panic!("{name} ray {i}: got {h:?}, expected {e:?}"),
            }
        }
        // Line query from below the plane, dir pointing down: the hit is
        // behind the origin, t signed negative.
        let l = rc
            .line_hits(
                &[DVec3::new(3.2, 3.3, -0.25)],
                &[DVec3::new(0.0, 0.0, -1.0)],
                1.0,
            )
            .unwrap();
        assert!((l[0].unwrap().t + 0.25).abs() < 1e-12, "{name}: {:?}", l[0]);
        // Closest point from above: straight down.
        let c = rc
            .closest_points(&[DVec3::new(3.2, 3.3, 0.7)], f64::INFINITY)
            .unwrap()[0]
            .unwrap();
        assert!(
            (c.distance - 0.7).abs() < 1e-12
                && (c.point - DVec3::new(3.2, 3.3, 0.0)).length() < 1e-12,
            "{name}: {c:?}"
        );
        // Outside the search radius.
        assert!(
            rc.closest_points(&[DVec3::new(3.2, 3.3, 0.7)], 0.69)
                .unwrap()[0]
                .is_none(),
            "{name}"
        );
        // Bad batch arguments are errors, not panics.
        assert!(rc.line_hits(&[DVec3::ZERO], &[], 1.0).is_err(), "{name}");
        assert!(
            rc.line_hits(&[DVec3::ZERO], &[DVec3::Z], -1.0).is_err(),
            "{name}"
        );
        assert!(
            rc.closest_points(&[DVec3::ZERO], f64::NAN).is_err(),
            "{name}"
        );
    }
}

/// Rays aimed exactly at shared vertices and edge midpoints of a flat grid
/// (exact in binary) must not slip through: the watertightness that
/// `RTC_SCENE_FLAG_ROBUST` and Woop et al. 2013 provide.
#[test]
fn watertight_at_shared_edges_and_vertices() {
    let n = 16;
    let mesh = flat_grid(n);
    let mut rays = Vec::new();
    let mut targets = Vec::new();
    for j in 1..n {
        for i in 1..n {
            for off in [(0.0, 0.0), (0.5, 0.0), (0.0, 0.5), (0.5, 0.5)] {
                let target = DVec3::new(i as f64 + off.0, j as f64 + off.1, 0.0);
                for d in [
                    DVec3::new(0.3, 0.7, -1.0),
                    DVec3::new(-0.5, 0.5, -1.0),
                    DVec3::new(0.0, 0.0, -1.0),
                    DVec3::new(1.0, 1.0, 1.0),
                ] {
                    rays.push(Ray::new(target - 2.0 * d, d));
                    targets.push(target);
                }
            }
        }
    }
    for rc in both(&mesh) {
        let hits = rc.first_hits(&rays).unwrap();
        for (k, (h, t)) in hits.iter().zip(&targets).enumerate() {
            let h = h.unwrap_or_else(|| panic!("{}: ray {k} at {t} slipped through", rc.name()));
            assert!((h.t - 2.0).abs() < 1e-12, "{}: ray {k}: {h:?}", rc.name());
        }
    }
}

#[test]
fn analytic_sphere() {
    // Level 5: 20,480 faces, vertices on the sphere. The polyhedron is
    // convex and contains the centre, so a ray from the centre leaves it at a
    // t between the smallest face-plane distance `h` and `r`.
    let (c, r) = (DVec3::new(0.3, -1.2, 2.0), 2.5);
    let mesh = icosphere(5, c, r);
    let h = (0..mesh.triangles.len())
        .map(|t| {
            let [a, b, d] = mesh.triangle(t);
            (b - a).cross(d - a).normalize().dot(a - c).abs()
        })
        .fold(f64::INFINITY, f64::min);
    assert!(h > r * (1.0 - 1e-3) && h < r, "inscribed sphere radius {h}");
    let lo = h / r;
    let mut rng = seeded_rng(7);
    let dirs: Vec<DVec3> = (0..2000).map(|_| random_dir(&mut rng)).collect();
    for rc in both(&mesh) {
        let name = rc.name();
        let rays: Vec<Ray> = dirs.iter().map(|&d| Ray::new(c, d)).collect();
        for (h, d) in rc.first_hits(&rays).unwrap().iter().zip(&dirs) {
            let h = h.unwrap_or_else(|| panic!("{name}: ray from the centre along {d} missed"));
            assert!(
                h.t <= r * (1.0 + 1e-12) && h.t >= h_lo(lo, r),
                "{name}: {h:?}"
            );
        }
        // From outside at 2r, aimed at the centre: enters at t in [r, 2r - h].
        let rays: Vec<Ray> = dirs
            .iter()
            .map(|&d| Ray::new(c + 2.0 * r * d, -d))
            .collect();
        for h in rc.first_hits(&rays).unwrap() {
            let h = h.unwrap();
            assert!(
                h.t >= r * (1.0 - 1e-12) && h.t <= 2.0 * r - h_lo(lo, r),
                "{name}: {h:?}"
            );
        }
        // Lines through the centre: nearest hit in either direction at ~r.
        let l = rc.line_hits(&vec![c; dirs.len()], &dirs, 10.0).unwrap();
        for h in l {
            let h = h.unwrap();
            assert!(
                h.t.abs() <= r * (1.0 + 1e-12) && h.t.abs() >= h_lo(lo, r),
                "{name}: {h:?}"
            );
        }
        // Closest point from outside at distance 3r from the centre.
        let pts: Vec<DVec3> = dirs.iter().map(|&d| c + 3.0 * r * d).collect();
        for cp in rc.closest_points(&pts, f64::INFINITY).unwrap() {
            let cp = cp.unwrap();
            assert!(
                cp.distance >= 2.0 * r * (1.0 - 1e-12) && cp.distance <= 3.0 * r - h_lo(lo, r),
                "{name}: {cp:?}"
            );
        }
    }
}

/// The inscribed radius `lo * r` less a rounding margin.
fn h_lo(lo: f64, r: f64) -> f64 {
    lo * r * (1.0 - 1e-12)
}

#[test]
fn zero_area_triangles_are_never_hit() {
    // Triangle 0 is a proper one, 1 is a segment (collinear), 2 a point.
    let mesh = TriMesh {
        positions: vec![
            DVec3::new(0.0, 0.0, 0.0),
            DVec3::new(1.0, 0.0, 0.0),
            DVec3::new(0.0, 1.0, 0.0),
            DVec3::new(5.0, 0.0, 0.0),
            DVec3::new(6.0, 0.0, 0.0),
            DVec3::new(7.0, 0.0, 0.0),
            DVec3::new(9.0, 9.0, 9.0),
        ],
        triangles: vec![[0, 1, 2], [3, 4, 5], [6, 6, 6]],
    };
    for rc in both(&mesh) {
        let name = rc.name();
        let rays = [
            Ray::new(DVec3::new(6.0, 0.0, 1.0), DVec3::new(0.0, 0.0, -1.0)),
            Ray::new(DVec3::new(5.5, -1.0, 0.0), DVec3::new(0.0, 1.0, 0.0)),
            Ray::new(DVec3::new(9.0, 9.0, 10.0), DVec3::new(0.0, 0.0, -1.0)),
            Ray::new(DVec3::new(0.25, 0.25, 1.0), DVec3::new(0.0, 0.0, -1.0)),
        ];
        let h = rc.first_hits(&rays).unwrap();
        assert!(h[..3].iter().all(Option::is_none), "{name}: {h:?}");
        assert_eq!(h[3].unwrap().triangle, 0, "{name}");
        // The closest point to the segment's middle is on triangle 0.
        let c = rc
            .closest_points(&[DVec3::new(6.0, 0.0, 0.0)], f64::INFINITY)
            .unwrap()[0]
            .unwrap();
        assert_eq!(c.triangle, 0, "{name}: {c:?}");
        assert!((c.distance - 5.0).abs() < 1e-12, "{name}: {c:?}");
    }
}

#[test]
fn results_do_not_depend_on_thread_count() {
    let mesh = perturbed_torus(120, 50, 1.0, 0.35, 0.05);
    let rays = random_rays(&mesh, 20_000, 11);
    let pts: Vec<DVec3> = rays.iter().map(|r| r.origin).collect();
    let run = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| {
                both(&mesh)
                    .iter()
                    .map(|rc| {
                        (
                            rc.first_hits(&rays).unwrap(),
                            rc.closest_points(&pts, f64::INFINITY).unwrap(),
                        )
                    })
                    .collect::<Vec<_>>()
            })
    };
    assert_eq!(run(1), run(3));
}

#[test]
fn closest_within_a_limit_per_point_is_the_unbounded_answer() {
    // `closest_points_within` (the displacement's same-sheet test asks for
    // M's closest point only within a radius of its own per sample) must
    // give, wherever the closest point lies within the point's limit, the
    // very answer of the unbounded query: the same triangle and the same
    // distance bits (the outputs' byte identity rests on it). Beyond the
    // limit it may say nothing. Limits at the distance times 0, ½, 1 ± 10⁻⁹,
    // 2 and ∞, so that both sides and the boundary are visited.
    let mesh = perturbed_torus(120, 50, 1.0, 0.35, 0.05);
    let mut rng = seeded_rng(39);
    let points: Vec<DVec3> = (0..20_000)
        .map(|_| {
            DVec3::new(
                rng.gen_range(-1.6..1.6),
                rng.gen_range(-1.6..1.6),
                rng.gen_range(-0.6..0.6),
            )
        })
        .collect();
    for caster in both(&mesh) {
        let all = caster.closest_points(&points, f64::INFINITY).unwrap();
        let factors = [0.0, 0.5, 1.0 - 1e-9, 1.0 + 1e-9, 2.0, f64::INFINITY];
        let limits: Vec<f64> = all
            .iter()
            .enumerate()
            .map(|(i, c)| c.as_ref().unwrap().distance * factors[i % factors.len()])
            .map(|l| if l.is_nan() { f64::INFINITY } else { l })
            .collect();
        let within = caster.closest_points_within(&points, &limits).unwrap();
        let (mut inside, mut outside) = (0, 0);
        for (i, (a, w)) in all.iter().zip(&within).enumerate() {
            let a = a.as_ref().unwrap();
            if a.distance < limits[i] {
                inside += 1;
                let w = w
                    .as_ref()
                    .unwrap_or_else(|| panic!("point {i}: none within"));
                assert_eq!(w.triangle, a.triangle, "{}: point {i}", caster.name());
                assert_eq!(w.distance.to_bits(), a.distance.to_bits());
            } else {
                outside += 1;
                if let Some(w) = w {
                    assert_eq!(w.triangle, a.triangle, "{}: point {i}", caster.name());
                }
            }
        }
        assert!(inside > 5_000 && outside > 5_000, "{inside} {outside}");
        assert!(caster.closest_points_within(&points, &limits[1..]).is_err());
    }
}
