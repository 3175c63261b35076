//! Mechanical mode (Lavoué et al. 2007): curvature, segmentation, curves
//! and the end-to-end figures on fandisk.

mod common;

use subdfit::mechanical::{self, curves, CurvatureOptions, Topology};
use subdfit::mesh::TriMesh;
use subdfit::DVec3;

/// An open cylinder of radius `r` along z, `n` around, `m` along, height h.
fn cylinder(r: f64, h: f64, n: u32, m: u32) -> TriMesh {
    let mut positions = Vec::new();
    for j in 0..=m {
        for i in 0..n {
            let a = std::f64::consts::TAU * i as f64 / n as f64;
            positions.push(DVec3::new(
                r * a.cos(),
                r * a.sin(),
                h * j as f64 / m as f64,
            ));
        }
    }
    let mut triangles = Vec::new();
    for j in 0..m {
        for i in 0..n {
            let a = j * n + i;
            let b = j * n + (i + 1) % n;
            let c = a + n;
            let d = b + n;
            triangles.push([a, b, d]);
            triangles.push([a, d, c]);
        }
    }
    TriMesh {
        positions,
        triangles,
    }
}

/// Sphere: the normal cycle converges linearly in the edge length h (CSM03
/// Thm. 3 on a Delaunay-like mesh): on a level-4 icosphere, h ≈ 0.08 r, so
/// 10 % is a margin of about one h/r over the estimator's error.
#[test]
fn sphere_curvature_is_one_over_r() {
    let r = 2.0;
    let mesh = common::icosphere(4, DVec3::ZERO, r);
    let topo = Topology::new(&mesh);
    let c = mechanical::vertex_curvatures(&mesh, &topo, &CurvatureOptions::default());
    for (v, k) in c.iter().enumerate() {
        assert!(
            (k.k_max - 1.0 / r).abs() < 0.1 / r,
            "vertex {v}: k_max {}",
            k.k_max
        );
        assert!(
            (k.k_min - 1.0 / r).abs() < 0.1 / r,
            "vertex {v}: k_min {}",
            k.k_min
        );
        assert!(k.isotropic, "vertex {v}: a sphere is umbilic");
    }
}

/// Cylinder: k_max = 1/r across the axis, k_min = 0, d_min along the axis.
/// Interior vertices only (the 2-ring must be complete). 64 around: the
/// inscribed polygon's dihedral sum is exact (2π per turn), so the error is
/// the area normalisation, O((h/r)²) ≈ 1 %; 5 % and 5° are margins.
#[test]
fn cylinder_curvature_and_direction() {
    let r = 1.0;
    let mesh = cylinder(r, 2.0, 64, 20);
    let topo = Topology::new(&mesh);
    let c = mechanical::vertex_curvatures(&mesh, &topo, &CurvatureOptions::default());
    for (v, k) in c.iter().enumerate() {
        let j = v / 64;
        if j < 2 || j > 18 {
            continue;
        }
        assert!(
            (k.k_max - 1.0 / r).abs() < 0.05,
            "vertex {v}: k_max {}",
            k.k_max
        );
        assert!(k.k_min.abs() < 0.05, "vertex {v}: k_min {}", k.k_min);
        assert!(
            k.d_min.z.abs() > 5f64.to_radians().cos(),
            "vertex {v}: d_min {}",
            k.d_min
        );
        assert!(!k.isotropic);
    }
}

/// Curve fitting: a quarter circle of radius 1 sampled at 50 points is
/// approximated within the requested tolerance, with few control points.
#[test]
fn curve_fit_meets_tolerance() {
    let pts: Vec<DVec3> = (0..=50)
        .map(|i| {
            let a = std::f64::consts::FRAC_PI_2 * i as f64 / 50.0;
            DVec3::new(a.cos(), a.sin(), 0.0)
        })
        .collect();
    for tol in [1e-2, 1e-3, 1e-4] {
        let c = curves::fit_curve(&pts, false, tol, 2);
        assert!(c.max_error <= tol, "tol {tol}: error {}", c.max_error);
        assert_eq!(c.control[0], pts[0]);
        assert_eq!(*c.control.last().unwrap(), pts[50]);
        // Independent check of the error: dense samples of the curve.
        for (p, &t) in pts.iter().zip(&c.params) {
            assert!((curves::eval(&c.control, false, t) - *p).length() <= tol * 1.0001);
        }
        if tol >= 1e-3 {
            assert!(
                c.control.len() <= 12,
                "tol {tol}: {} control points",
                c.control.len()
            );
        }
    }
    // A straight line needs only its two ends.
    let line: Vec<DVec3> = (0..10).map(|i| DVec3::new(i as f64, 0.0, 0.0)).collect();
    assert_eq!(curves::fit_curve(&line, false, 1e-6, 2).control.len(), 2);
}

/// Segmentation of fandisk: every sharp edge separates two regions except
/// feature lines that fade out inside a face (counted; at most a handful).
#[test]
fn fandisk_sharp_edges_on_boundaries() {
    let mesh = subdfit::io::read_mesh(
        &std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data/fandisk.ply"),
    )
    .unwrap()
    .mesh;
    let topo = Topology::new(&mesh);
    let c = mechanical::vertex_curvatures(&mesh, &topo, &CurvatureOptions::default());
    let seg = mechanical::segment(&mesh, &topo, &c, &Default::default());
    assert!(
        seg.sharp_edges > 500,
        "fandisk has its feature lines: {}",
        seg.sharp_edges
    );
    assert!(
        seg.sharp_edges_inside * 100 <= seg.sharp_edges,
        "{} of {} sharp edges inside a region",
        seg.sharp_edges_inside,
        seg.sharp_edges
    );
    assert!(
        seg.num_regions >= 10 && seg.num_regions <= 40,
        "{} regions",
        seg.num_regions
    );
}

/// Auto mode: fandisk is mechanical, spot organic.
#[test]
fn auto_mode_choice() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data");
    let fan = subdfit::io::read_mesh(&dir.join("fandisk.ply"))
        .unwrap()
        .mesh;
    let spot = subdfit::io::read_mesh(&dir.join("spot.ply")).unwrap().mesh;
    assert_eq!(mechanical::choose_mode(&fan).mode, "mechanical");
    let s = mechanical::choose_mode(&spot);
    assert_eq!(s.mode, "organic", "{}", s.reason);
}

/// Bad input: spot forced through mechanical mode terminates with figures.
#[test]
fn spot_in_mechanical_mode_terminates() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data");
    let spot = subdfit::io::read_mesh(&dir.join("spot.ply")).unwrap().mesh;
    let caster =
        subdfit::raycast::make_raycaster(subdfit::raycast::RayBackend::Embree, &spot).unwrap();
    let opts = mechanical::MechanicalOptions::default().with_max_rounds(2);
    let built = mechanical::build_control(&spot, caster.as_ref(), &opts).unwrap();
    built.control.validate().unwrap();
    let last = built.stats.rounds.last().unwrap();
    assert!(last.rms_permille.is_finite());
    assert!(built.stats.rounds.len() <= 3);
}

/// Diagnostic: prints fandisk's rounds (`cargo test --release --test
/// mechanical fandisk_rounds -- --ignored --nocapture`).
#[test]
#[ignore]
fn fandisk_rounds() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data");
    let fan = subdfit::io::read_mesh(&dir.join("fandisk.ply"))
        .unwrap()
        .mesh;
    let caster =
        subdfit::raycast::make_raycaster(subdfit::raycast::RayBackend::Embree, &fan).unwrap();
    let t = std::time::Instant::now();
    let built =
        mechanical::build_control(&fan, caster.as_ref(), &Default::default()).unwrap();
    println!("total {:.3}s {:?}", t.elapsed().as_secs_f64(), built.stats.seconds);
    println!("initial {} faces {} verts", built.stats.initial_faces, built.stats.initial_vertices);
    for r in &built.stats.rounds {
        println!("{r:?}");
    }
    println!("final {} verts {} faces", built.control.num_vertices(), built.control.num_faces());
}
