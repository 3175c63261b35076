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
        if !(2..=18).contains(&j) {
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

/// Curve fitting ([`curves::fit_feature`], §5's fit): a quarter circle of
/// radius 1 sampled at 50 points is approximated within the requested
/// tolerance, with few control points (measured: 4, 6 and 27 points at
/// 1e-2, 1e-3 and 1e-4, where the vertex fit it replaced needed 4, 10 and
/// 26).
#[test]
fn curve_fit_meets_tolerance() {
    let pts: Vec<DVec3> = (0..=50)
        .map(|i| {
            let a = std::f64::consts::FRAC_PI_2 * i as f64 / 50.0;
            DVec3::new(a.cos(), a.sin(), 0.0)
        })
        .collect();
    for tol in [1e-2, 1e-3, 1e-4] {
        let c = curves::fit_feature(&pts, false, 2, tol);
        assert!(c.max_error <= tol, "tol {tol}: error {}", c.max_error);
        assert_eq!(c.control[0], pts[0]);
        assert_eq!(*c.control.last().unwrap(), pts[50]);
        // Independent check of the error at the vertices, through the
        // curve parameters the fit reports for them.
        assert_eq!(c.params.len(), pts.len());
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
    assert_eq!(curves::fit_feature(&line, false, 2, 1e-6).control.len(), 2);
}

/// The feature fit (§5, distance to the curve): every point of the
/// polyline — vertices and chord points, where the features-kept test
/// looks — lies within the tolerance of the curve, checked independently
/// against the polyline through 2000 points of the curve (its segments
/// are below 4e-3 long on curves of radius about 1, so their sag, below
/// 2e-6, is far below the tolerances); the ends are the corners; and it
/// needs no more control points than the vertex fit it replaced needed at
/// the same tolerance (measured before that fit was removed; measured at
/// the vertices only, it was the weaker requirement). A closed loop and a
/// straight line too. (The polylines' chord sag, 7.7e-4 for both, halved
/// is what even the best curve must leave: the 1e-3 tolerance allows it.)
#[test]
fn feature_fit_bounds_distance_to_curve() {
    let arc = |n: usize, full: bool| -> Vec<DVec3> {
        let span = if full {
            std::f64::consts::TAU
        } else {
            std::f64::consts::FRAC_PI_2
        };
        let k = if full { n } else { n + 1 };
        (0..k)
            .map(|i| {
                let a = span * i as f64 / n as f64;
                DVec3::new(a.cos(), a.sin(), 0.1 * (2.0 * a).sin())
            })
            .collect()
    };
    let dist_to_curve = |c: &curves::Curve, p: DVec3| {
        let n = c.control.len();
        let range = if c.closed { n } else { n - 1 } as f64;
        let q: Vec<DVec3> = (0..=2000)
            .map(|i| curves::eval(&c.control, c.closed, range * i as f64 / 2000.0))
            .collect();
        q.windows(2)
            .map(|w| point_segment(p, w[0], w[1]))
            .fold(f64::INFINITY, f64::min)
    };
    for (pts, closed) in [(arc(20, false), false), (arc(80, true), true)] {
        let m = pts.len();
        let segs = if closed { m } else { m - 1 };
        for tol in [1e-2, 1e-3] {
            let c = curves::fit_feature(&pts, closed, 2, tol);
            let mut worst = 0.0f64;
            for k in 0..segs {
                let (a, b) = (pts[k], pts[(k + 1) % m]);
                for i in 0..=4 {
                    worst = worst.max(dist_to_curve(&c, a + (b - a) * (i as f64 / 4.0)));
                }
            }
            assert!(
                worst <= tol * 1.001,
                "closed {closed} tol {tol}: worst {worst} with {} points",
                c.control.len()
            );
            if !closed {
                assert_eq!(c.control[0], pts[0]);
                assert_eq!(*c.control.last().unwrap(), pts[m - 1]);
                // The vertex fit this one replaced, measured on this arc
                // before its removal: 4 points at 1e-2, 9 at 1e-3.
                let vertex_fit = if tol >= 1e-2 { 4 } else { 9 };
                assert!(
                    c.control.len() <= vertex_fit,
                    "tol {tol}: {} points, vertex fit {vertex_fit}",
                    c.control.len()
                );
            }
            println!(
                "closed {closed} tol {tol}: {} points, worst {worst:.2e}",
                c.control.len()
            );
        }
    }
    let line: Vec<DVec3> = (0..10).map(|i| DVec3::new(i as f64, 0.0, 0.0)).collect();
    assert_eq!(curves::fit_feature(&line, false, 2, 1e-6).control.len(), 2);
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
    let built = mechanical::build_control(&fan, caster.as_ref(), &Default::default()).unwrap();
    println!(
        "total {:.3}s {:?}",
        t.elapsed().as_secs_f64(),
        built.stats.seconds
    );
    println!(
        "initial {} faces {} verts",
        built.stats.initial_faces, built.stats.initial_vertices
    );
    for r in &built.stats.rounds {
        println!("{r:?}");
    }
    println!(
        "final {} verts {} faces",
        built.control.num_vertices(),
        built.control.num_faces()
    );
}

fn fandisk() -> TriMesh {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data");
    subdfit::io::read_mesh(&dir.join("fandisk.ply"))
        .unwrap()
        .mesh
}

fn point_segment(p: DVec3, a: DVec3, b: DVec3) -> f64 {
    let ab = b - a;
    let t = ((p - a).dot(ab) / ab.length_squared().max(1e-300)).clamp(0.0, 1.0);
    (p - (a + t * ab)).length()
}

/// Fandisk through [`mechanical::build_control`] with Embree, the output
/// checked for a valid control mesh.
fn build_fandisk(o: &mechanical::MechanicalOptions) -> (TriMesh, mechanical::Built) {
    let mesh = fandisk();
    let caster =
        subdfit::raycast::make_raycaster(subdfit::raycast::RayBackend::Embree, &mesh).unwrap();
    let built = mechanical::build_control(&mesh, caster.as_ref(), o).unwrap();
    built.control.validate().unwrap();
    (mesh, built)
}

/// The mesh of the ignored diagnostics: `SUBDFIT_MESH` (a PLY path) or
/// fandisk.
fn diagnostic_mesh() -> TriMesh {
    match std::env::var("SUBDFIT_MESH") {
        Ok(p) => common::load_ply(std::path::Path::new(&p)),
        Err(_) => fandisk(),
    }
}

/// Features kept (issue 6's acceptance): points on every input edge with a
/// dihedral angle above 30° lie within 1‰ of the diagonal from a crease
/// curve of the output's limit surface. The crease curves are sampled with
/// the limit evaluator along every crease edge of the control mesh (64
/// points per edge, as a polyline), independently of §5's curve code.
/// The feature curves are fitted to 0.97‰, measured as the distance of
/// the same five points per edge to the curve (`curves::fit_feature`);
/// the 0.03‰ left covers the 64-point tessellation of the crease here
/// (its sag is far below 0.01‰). Measured: worst 0.88‰. No edge may
/// fail, including the fading tail of a feature inside a face (the
/// segmentation continues it to the region boundary).
/// Sharp edges of `mesh` (dihedral > 30°) and how many lie farther than
/// 1‰ of the diagonal from a crease curve of `built`'s limit surface
/// (5 points per edge), with the worst distance in ‰.
fn features_far(mesh: &TriMesh, built: &mechanical::Built) -> (usize, usize, f64) {
    use subdfit::subdiv::{make_evaluator, Backend, EvalOptions, SurfaceLocation};
    let c = &built.control;
    let eval = make_evaluator(Backend::Osd, c, &EvalOptions::default()).unwrap();
    const N: usize = 64;
    let mut locs: Vec<SurfaceLocation> = Vec::new();
    for f in c.faces() {
        let hs: Vec<_> = c.face_halfedges(f).collect();
        let n = hs.len();
        for (k, &h) in hs.iter().enumerate() {
            if c.edge_sharpness(h.edge()) < 10.0 {
                continue;
            }
            for i in 0..=N {
                let t = i as f64 / N as f64;
                if n == 4 {
                    let (u, v) = [(t, 0.0), (1.0, t), (1.0 - t, 1.0), (0.0, 1.0 - t)][k];
                    locs.push(SurfaceLocation::quad(f, u, v));
                } else {
                    // Non-quads: sub-face k runs from corner k to the
                    // edge midpoint along v = 0; sub-face k + 1 from the
                    // midpoint back to corner k + 1 along u = 0.
                    let (sub, u, v) = if t <= 0.5 {
                        (k, 2.0 * t, 0.0)
                    } else {
                        ((k + 1) % n, 0.0, 2.0 - 2.0 * t)
                    };
                    locs.push(SurfaceLocation {
                        face: f,
                        sub: sub as u16,
                        u,
                        v,
                    });
                }
            }
        }
    }
    assert!(!locs.is_empty(), "no crease edges in the output");
    let lp: Vec<DVec3> = eval
        .evaluate(c.positions(), &locs)
        .unwrap()
        .iter()
        .map(|p| p.position)
        .collect();
    let segs: Vec<(DVec3, DVec3)> = lp
        .chunks_exact(N + 1)
        .flat_map(|ch| ch.windows(2).map(|w| (w[0], w[1])).collect::<Vec<_>>())
        .collect();
    let diag = mesh.bbox_diagonal();
    let topo = Topology::new(mesh);
    let sharp = topo.sharp_edges();
    let mut worst = 0.0f64;
    let mut far = 0usize;
    let mut total = 0usize;
    for (e, &s) in topo.edges.iter().zip(&sharp) {
        if !s {
            continue;
        }
        total += 1;
        let (a, b) = (
            mesh.positions[e.v[0] as usize],
            mesh.positions[e.v[1] as usize],
        );
        let d = (0..=4)
            .map(|i| {
                let p = a + (b - a) * (i as f64 / 4.0);
                segs.iter()
                    .map(|&(x, y)| point_segment(p, x, y))
                    .fold(f64::INFINITY, f64::min)
            })
            .fold(0.0, f64::max);
        if d > 1e-3 * diag {
            far += 1;
        }
        worst = worst.max(d);
    }
    (total, far, 1000.0 * worst / diag)
}

#[test]
fn fandisk_features_kept() {
    let mesh = fandisk();
    let caster =
        subdfit::raycast::make_raycaster(subdfit::raycast::RayBackend::Embree, &mesh).unwrap();
    let opts = mechanical::MechanicalOptions::default().with_max_rounds(1);
    let built = mechanical::build_control(&mesh, caster.as_ref(), &opts).unwrap();
    let (total, far, worst) = features_far(&mesh, &built);
    println!("{total} sharp edges, {far} farther than 1‰; worst {worst:.3}‰");
    assert!(
        total > 500 && far == 0,
        "{far} of {total} sharp edges are farther than 1‰ from a crease (worst {worst:.3}‰)"
    );
}

/// Surface-to-mesh distance of `built`'s limit surface (patch samples as
/// in the fit, closest points on M): (mean, RMS, max) in ‰ of the diagonal.
fn output_error(mesh: &TriMesh, built: &mechanical::Built) -> (f64, f64, f64) {
    use subdfit::subdiv::{make_evaluator, Backend, EvalOptions};
    let c = &built.control;
    let (locs, _) = subdfit::fit::patch_samples(c, mesh.positions.len(), 3);
    let eval = make_evaluator(Backend::Osd, c, &EvalOptions::default()).unwrap();
    let pts: Vec<DVec3> = eval
        .evaluate(c.positions(), &locs)
        .unwrap()
        .iter()
        .map(|p| p.position)
        .collect();
    let caster =
        subdfit::raycast::make_raycaster(subdfit::raycast::RayBackend::Embree, mesh).unwrap();
    let d: Vec<f64> = caster
        .closest_points(&pts, f64::INFINITY)
        .unwrap()
        .iter()
        .map(|h| h.unwrap().distance)
        .collect();
    let k = 1000.0 / mesh.bbox_diagonal();
    let n = d.len() as f64;
    (
        k * d.iter().sum::<f64>() / n,
        k * (d.iter().map(|x| x * x).sum::<f64>() / n).sqrt(),
        k * d.iter().copied().fold(0.0, f64::max),
    )
}

/// Fandisk end to end. The paper's bar (Lavoué et al. 2007, Table 2):
/// ≤ 75 control vertices, ≤ 89 faces, mean ≤ 0.78‰, RMS ≤ 1.63‰,
/// max ≤ 10.46‰ of the diagonal. Measured at the default `E_limit`:
/// 77 vertices, 80 faces, mean 0.36‰, RMS 0.69‰, max 5.8‰ (the curve
/// network alone has 72 control points, 26 of them corners, with its
/// feature lines within 1‰; the vertex bar is met at `--max-error 6e-3`,
/// see `fandisk_table2_vertices_with_slits`). The assertions here are the
/// error bar on the output, the improvement over the initial polyhedron
/// and a loose size guard; the tests below hold the tight bars.
#[test]
fn fandisk_figures() {
    let (mesh, built) = build_fandisk(&mechanical::MechanicalOptions::default());
    let r = &built.stats.rounds;
    for x in r {
        println!("{x:?}");
    }
    let (mean, rms, max) = output_error(&mesh, &built);
    println!(
        "{} vertices {} faces: mean {mean:.3}‰ RMS {rms:.3}‰ max {max:.2}‰",
        built.control.num_vertices(),
        built.control.num_faces()
    );
    // The geometry step and the enrichment lower the error: the output
    // beats the initial polyhedron (round 0 has no free control point).
    assert!(r.len() >= 2 && r[1].geometry_iterations > 0);
    assert!(rms < r[0].rms_permille && mean < r[0].mean_permille);
    assert!(mean <= 0.78, "mean {mean}");
    assert!(rms <= 1.63, "rms {rms}");
    assert!(max <= 10.46, "max {max}");
    assert!(
        built.control.num_faces() <= 105,
        "{} faces",
        built.control.num_faces()
    );
    assert!(built.control.num_vertices() <= 88);
    assert!(built.stats.sharp_edges_inside_regions == 0);
    // Smooth boundaries merged away (§4 step 3a): fandisk's class splits
    // that are not needed for discs are gone.
    assert!(built.stats.regions_merged_smooth > 0);
}

/// Per-region rollback of the enrichment (§7.2 with the "never worse than
/// a measured state" rule): the output is no worse than any round
/// measured, region by region, so more rounds never raise the error.
/// With 1 round and with the default 8, on fandisk.
#[test]
fn fandisk_more_rounds_never_worse() {
    let mesh = fandisk();
    let caster =
        subdfit::raycast::make_raycaster(subdfit::raycast::RayBackend::Embree, &mesh).unwrap();
    let run = |n: usize| {
        let o = mechanical::MechanicalOptions::default().with_max_rounds(n);
        mechanical::build_control(&mesh, caster.as_ref(), &o).unwrap()
    };
    let (one, all) = (run(1), run(mechanical::DEFAULT_MAX_ROUNDS));
    let (_, rms1, _) = output_error(&mesh, &one);
    let (_, rms8, _) = output_error(&mesh, &all);
    println!("RMS after 1 round {rms1:.3}‰, after all {rms8:.3}‰");
    // 2 %: the stall margin of `optimize` (a region within it of its best
    // is kept as measured).
    assert!(rms8 <= 1.02 * rms1, "{rms8} vs {rms1}");
}

/// §7.1's objective: the squared-distance minimisation (the default) fits
/// at least as well as the point distance on the same topology. Round 1 is
/// the first round both fit on the *same* control mesh (round 0's
/// polyhedron has only curve control points, all fixed, so its enrichment
/// does not depend on the objective). Measured on fandisk: RMS 0.691‰
/// (SDM) against 1.183‰ (point); the assertion allows no regression past
/// the point objective.
#[test]
fn fandisk_sdm_beats_point_distance() {
    use subdfit::mechanical::optimize::Objective;
    let mesh = fandisk();
    let caster =
        subdfit::raycast::make_raycaster(subdfit::raycast::RayBackend::Embree, &mesh).unwrap();
    let run = |o: Objective| {
        // One curve network for both: §5's fit does not depend on the
        // objective.
        let opts = mechanical::MechanicalOptions::default()
            .with_objective(o)
            .with_max_rounds(1);
        mechanical::build_control(&mesh, caster.as_ref(), &opts)
            .unwrap()
            .stats
            .rounds
    };
    let (sdm, point) = (run(Objective::Sdm), run(Objective::Point));
    assert!(sdm.len() >= 2 && point.len() >= 2);
    assert_eq!(sdm[1].faces, point[1].faces, "same topology in round 1");
    assert!(sdm[1].geometry_iterations > 0);
    println!(
        "round 1 RMS: SDM {:.3}‰, point {:.3}‰",
        sdm[1].rms_permille, point[1].rms_permille
    );
    assert!(
        sdm[1].rms_permille <= point[1].rms_permille,
        "SDM {} vs point {}",
        sdm[1].rms_permille,
        point[1].rms_permille
    );
    assert!(sdm[1].mean_permille <= 1.02 * point[1].mean_permille);
}

/// Diagnostic (`SUBDFIT_CT=1e-3 SUBDFIT_ST=2e-3 SUBDFIT_ME=3e-3 cargo test
/// --release --test mechanical fandisk_sweep -- --ignored --nocapture`):
/// fandisk's size, error, features and per-piece control points under the
/// given curve tolerances and error limit.
#[test]
#[ignore]
fn fandisk_sweep() {
    let mesh = diagnostic_mesh();
    let caster =
        subdfit::raycast::make_raycaster(subdfit::raycast::RayBackend::Embree, &mesh).unwrap();
    let env = |k: &str| std::env::var(k).ok().and_then(|s| s.parse::<f64>().ok());
    let mut o = mechanical::MechanicalOptions::default();
    if let Some(x) = env("SUBDFIT_ME") {
        o = o.with_max_error(x);
    }
    if let Some(x) = env("SUBDFIT_CT") {
        o.curve_tolerance = x;
    }
    if let Some(x) = env("SUBDFIT_ST") {
        o.smooth_curve_tolerance = x;
    }
    if let Some(x) = env("SUBDFIT_FT") {
        o.feature_tolerance = x;
    }
    let t = std::time::Instant::now();
    let built = mechanical::build_control(&mesh, caster.as_ref(), &o).unwrap();
    let secs = t.elapsed().as_secs_f64();
    let s = &built.stats;
    for p in &s.pieces {
        println!(
            "piece {:3} verts {:2} ctrl sharp {} err {:.3}",
            p.polyline_vertices, p.control_points, p.sharp, p.max_error_permille
        );
    }
    for r in &s.rounds {
        println!(
            "round {} F {} V rms {:.3} max {:.2} over {} local {} diffuse {}",
            r.faces,
            r.vertices,
            r.rms_permille,
            r.max_permille,
            r.faces_over_limit,
            r.local_fields,
            r.diffuse_fields
        );
    }
    if let Some(r) = s.rounds.last() {
        let mut v: Vec<(usize, f64)> = r.region_rms_permille.iter().copied().enumerate().collect();
        v.sort_by(|a, b| b.1.total_cmp(&a.1));
        println!("worst regions {:?}", &v[..v.len().min(5)]);
        let init: Vec<usize> = v[..v.len().min(5)]
            .iter()
            .map(|x| s.region_initial_faces.get(x.0).copied().unwrap_or(0))
            .collect();
        println!(
            "their initial faces {init:?}; planar regions {}, star {}",
            s.planar_regions, s.star_fallback
        );
        if std::env::var("SUBDFIT_DUMP").is_ok() {
            let w = std::env::var("SUBDFIT_REGION")
                .ok()
                .and_then(|s| s.parse().ok())
                .unwrap_or(v[0].0 as u32);
            for (f, &r) in built.face_region.iter().enumerate() {
                if r == w {
                    let fv = built.control.face_vertices(subdfit::mesh::FaceId(f as u32));
                    let pts: Vec<String> = fv
                        .map(|x| {
                            let p = built.control.position(x);
                            format!("({:.3},{:.3},{:.3})", p.x, p.y, p.z)
                        })
                        .collect();
                    println!("region {w} face {f}: {}", pts.join(" "));
                }
            }
        }
    }
    let (total, far, worst) = features_far(&mesh, &built);
    let (mean, rms, max) = output_error(&mesh, &built);
    println!(
        "corners {} curves {} curve points {} initial {} F; {:?}",
        s.corners, s.curves, s.curve_control_points, s.initial_faces, s.seconds
    );
    println!(
        "RESULT {} V {} F mean {mean:.3} RMS {rms:.3} max {max:.2}; features {far}/{total} worst {worst:.3}; {secs:.2}s",
        built.control.num_vertices(),
        built.control.num_faces()
    );
}

// ---------------------------------------------------------------------
// Enrichment (Lavoué §7.2–7.3): the RMS-vs-faces curve and Hoppe's line.
// ---------------------------------------------------------------------

/// Diagnostic (`HOP_ME=1.2e-3 cargo test --release --test mechanical
/// hoppe_rounds -- --ignored --nocapture`): fandisk's rounds under one
/// `--max-error`, with the faces and RMS of every region.
#[test]
#[ignore]
fn hoppe_rounds() {
    let mesh = diagnostic_mesh();
    let caster =
        subdfit::raycast::make_raycaster(subdfit::raycast::RayBackend::Embree, &mesh).unwrap();
    let env = |k: &str| std::env::var(k).ok().and_then(|s| s.parse::<f64>().ok());
    let mut o = mechanical::MechanicalOptions::default()
        .with_max_error(env("HOP_ME").unwrap_or(mechanical::DEFAULT_MAX_ERROR));
    if let Some(n) = env("HOP_ROUNDS") {
        o = o.with_max_rounds(n as usize);
    }
    if let Some(n) = env("HOP_M0") {
        o.m0 = n as usize;
    }
    if let Some(x) = env("HOP_FAIR") {
        o.fairness = x;
    }
    let t = std::time::Instant::now();
    let built = mechanical::build_control(&mesh, caster.as_ref(), &o).unwrap();
    let secs = t.elapsed().as_secs_f64();
    let s = &built.stats;
    for r in &s.rounds {
        println!(
            "F {:3} V {:3} rms {:.3} max {:.2} it {} over {:2} local {} diffuse {}",
            r.faces,
            r.vertices,
            r.rms_permille,
            r.max_permille,
            r.geometry_iterations,
            r.faces_over_limit,
            r.local_fields,
            r.diffuse_fields
        );
        if env("HOP_VERBOSE").is_some() {
            let v: Vec<String> = r
                .region_rms_permille
                .iter()
                .zip(&r.region_faces)
                .map(|(e, f)| format!("{f}:{e:.2}"))
                .collect();
            println!("   {}", v.join(" "));
        }
    }
    let (total, far, worst) = features_far(&mesh, &built);
    let (mean, rms, max) = output_error(&mesh, &built);
    println!(
        "RESULT {} V {} F mean {mean:.3} RMS {rms:.3} max {max:.2}; features {far}/{total} worst {worst:.3}; {secs:.2}s opt {:.2}s",
        built.control.num_vertices(),
        built.control.num_faces(),
        s.seconds.iter().find(|x| x.0 == "optimize").map_or(0.0, |x| x.1)
    );
}

/// Hoppe et al. (1994)'s line in Lavoué et al.'s Table 2: at most 170
/// faces at RMS ≤ 0.32‰ of the diagonal, with `--max-error 1e-3` (the
/// curve tolerances follow it, see `MechanicalOptions::with_max_error`).
/// Measured with this file's sampling: 148 vertices, 155 faces, RMS 0.231‰
/// (report.json's figure: 0.214‰); the bar itself is asserted, with the
/// features kept and every face under the limit at the end.
#[test]
fn fandisk_hoppe_line() {
    let (mesh, built) =
        build_fandisk(&mechanical::MechanicalOptions::default().with_max_error(1e-3));
    let (mean, rms, max) = output_error(&mesh, &built);
    let faces = built.control.num_faces();
    println!(
        "{} vertices {faces} faces: mean {mean:.3}‰ RMS {rms:.3}‰ max {max:.2}‰",
        built.control.num_vertices()
    );
    assert!(faces <= 170, "{faces} faces");
    assert!(rms <= 0.32, "RMS {rms}");
    assert!(!built.stats.error_limit_reached);
    let (total, far, worst) = features_far(&mesh, &built);
    assert_eq!(
        far, 0,
        "{far} of {total} sharp edges beyond 1‰ (worst {worst})"
    );
}

// ---------------------------------------------------------------------
// Segmentation and polyhedron structure (issue 6, Table 2's size).
// ---------------------------------------------------------------------

/// Fandisk at the default `E_limit` against Table 2's face bar: fading
/// features merged and re-cut with the least new boundary (§4), corners at
/// fading tips (§5), planar facets kept whole while star-shaped (§6.3.2).
/// Fading features that hang from their region's boundary are slits of it
/// (see `fandisk_table2_vertices_with_slits`). Measured (this test's
/// samples): 77 vertices, 80 faces, mean 0.36‰, RMS 0.69‰, max 5.8‰,
/// every sharp edge within 0.88‰ of a crease (80 V / 83 F before the
/// slits). Asserted: the paper's face bar (≤ 89) and error bars, the
/// features bar, and the vertex count with its measured value as a
/// regression guard (Table 2's ≤ 75 is met at `--max-error 6e-3`, not at
/// the default).
#[test]
fn fandisk_table2_faces_at_default() {
    let (mesh, built) = build_fandisk(&mechanical::MechanicalOptions::default());
    let (mean, rms, max) = output_error(&mesh, &built);
    let (total, far, worst) = features_far(&mesh, &built);
    let (v, f) = (built.control.num_vertices(), built.control.num_faces());
    println!(
        "{v} vertices {f} faces: mean {mean:.3}‰ RMS {rms:.3}‰ max {max:.2}‰; {far} of {total} sharp edges beyond 1‰ (worst {worst:.3}‰)"
    );
    assert!(f <= 89, "{f} faces");
    assert!(v <= 77, "{v} vertices");
    assert!(
        mean <= 0.78 && rms <= 1.63 && max <= 10.46,
        "{mean} {rms} {max}"
    );
    assert!(total > 500 && far == 0, "{far} of {total} (worst {worst})");
    assert_eq!(built.stats.sharp_edges_inside_regions, 0);
}

// ===========================================================================
// Block and joint (issue 6): §5's compact curve network serves every CAD
// mesh, and the features bar holds on them. Skipped without the shared data.
// ===========================================================================

/// Block and joint through the default [`mechanical::build_control`]: the
/// compact curve fit (the only one) must reach the error limit, no face
/// left above it (before the chord-bend rule of
/// `polyhedron::MAX_CHORD_BEND`, half-pipe regions were cut into fans
/// through the air, block ended at RMS 3.6‰ and joint at 3.5‰ with it,
/// and both needed a second build with a conservative fitter since
/// removed).
/// The output's RMS and max distance must stay within the paper's
/// `E_limit` (3‰, RMS per face) and Table 2's max bar (10.46‰); every
/// sharp input edge must lie within 1‰ of a crease curve, as on fandisk
/// (block had 2 edges off before step 4b of `segment`, worst 26.4‰).
/// Measured: block 188 V / 236 F, RMS 0.86‰, worst feature 0.92‰; joint
/// 165 V / 168 F, RMS 0.77‰, worst 0.96‰. (`--nocapture` prints the
/// figures.)
#[test]
fn shared_cad_compact_network_keeps_features() {
    let Some(dir) = common::data_dir() else {
        eprintln!("skipping shared_cad_compact_network_keeps_features: no data directory");
        return;
    };
    for name in ["block.ply", "joint.ply"] {
        let path = dir.join(name);
        if !path.exists() {
            eprintln!("skipping {name}: not in {}", dir.display());
            continue;
        }
        let mesh = common::load_ply(&path);
        let caster =
            subdfit::raycast::make_raycaster(subdfit::raycast::RayBackend::Embree, &mesh).unwrap();
        let built = mechanical::build_control(&mesh, caster.as_ref(), &Default::default()).unwrap();
        built.control.validate().unwrap();
        let s = &built.stats;
        let (total, far, worst) = features_far(&mesh, &built);
        let (mean, rms, max) = output_error(&mesh, &built);
        println!(
            "{name}: {} V {} F, mean {mean:.3} RMS {rms:.3} max {max:.2}‰; {far}/{total} sharp edges beyond 1‰ (worst {worst:.3}‰); {} inside regions",
            built.control.num_vertices(),
            built.control.num_faces(),
            s.sharp_edges_inside_regions
        );
        // The fallback to the second fitter was taken exactly when faces
        // were left above `E_limit`, so this is what it checked.
        assert!(!s.error_limit_reached, "{name}: faces left above E_limit");
        // Step 4b of `segment`: no sharp chain left inside a region, and
        // every region a disc that §6 could build.
        assert_eq!(s.sharp_edges_inside_regions, 0, "{name}");
        assert_eq!(s.regions_skipped, 0, "{name}");
        assert!(rms <= 3.0 && max <= 10.46, "{name}: RMS {rms} max {max}");
        assert!(
            total > 500 && far == 0,
            "{name}: {far} of {total} sharp edges farther than 1‰ from a crease (worst {worst:.3}‰)"
        );
    }
}

/// §6's cut on a half-pipe (radius 1 around z, normals turning 180°, 32
/// steps around and 16 along), with block's configuration: two feature
/// arcs (4 and 5 control points) and one control point in the middle of
/// each straight side. Every control edge of the facets must span at most
/// a quarter turn (`polyhedron::MAX_CHORD_BEND`): one edge cannot carry
/// more of a circle, and a facet spanning the pipe cuts through the air
/// (block's three such regions ended at RMS 6–12‰). Without the rule the
/// cut joins the two side points straight across the pipe (checked: an
/// edge spanning 180°).
/// Runs without the shared data.
#[test]
fn half_pipe_chords_span_at_most_a_quarter_turn() {
    use mechanical::polyhedron::{cut_region, PolyVertex, RegionGeom};
    let (n, m) = (32u32, 16u32);
    let angle = |i: u32| std::f64::consts::PI * i as f64 / n as f64;
    let mut positions = Vec::new();
    for j in 0..=m {
        for i in 0..=n {
            let a = angle(i);
            positions.push(DVec3::new(a.cos(), -a.sin(), 2.0 * j as f64 / m as f64));
        }
    }
    let id = |i: u32, j: u32| j * (n + 1) + i;
    let mut triangles = Vec::new();
    for j in 0..m {
        for i in 0..n {
            let (a, b, c, d) = (id(i, j), id(i + 1, j), id(i, j + 1), id(i + 1, j + 1));
            triangles.push([a, b, d]);
            triangles.push([a, d, c]);
        }
    }
    let mesh = TriMesh {
        positions,
        triangles,
    };
    let topo = Topology::new(&mesh);
    let curv = mechanical::vertex_curvatures(&mesh, &topo, &CurvatureOptions::default());
    let on_boundary: Vec<bool> = (0..=m)
        .flat_map(|j| (0..=n).map(move |i| i == 0 || i == n || j == 0 || j == m))
        .collect();
    // Polygon in boundary order: bottom arc 0°..180° (3 spans), the left
    // side's middle, top arc 180°..0° (4 spans: on block the two ends of a
    // pipe have different counts too), the right side's middle. Anchors are grid
    // vertices; the control points sit on them (only the planar cut reads
    // positions).
    let mut anchors: Vec<u32> = (0..=3).map(|k| id(k * n / 3, 0)).collect();
    anchors.push(id(n, m / 2));
    anchors.extend((0..=4).map(|k| id(n - k * n / 4, m)));
    anchors.push(id(0, m / 2));
    let poly: Vec<PolyVertex> = anchors
        .iter()
        .enumerate()
        .map(|(k, &a)| PolyVertex {
            id: k as u32,
            anchor: a,
        })
        .collect();
    let pos: Vec<DVec3> = anchors
        .iter()
        .map(|&a| mesh.positions[a as usize])
        .collect();
    let tris: Vec<u32> = (0..mesh.triangles.len() as u32).collect();
    let g = RegionGeom::new(&mesh, &curv, &tris, &on_boundary, mesh.bbox_diagonal());
    assert!(g.planar.is_none());
    let mut edges = std::collections::HashSet::new();
    for k in 0..poly.len() as u32 {
        let b = (k + 1) % poly.len() as u32;
        edges.insert((k.min(b), k.max(b)));
    }
    let faces = cut_region(&g, &poly, &pos, &mut edges);
    println!("facets {faces:?}");
    let turn = |v: u32| {
        let p = pos[v as usize];
        (-p.y).atan2(p.x).to_degrees()
    };
    for f in &faces {
        for k in 0..f.len() {
            let (a, b) = (f[k], f[(k + 1) % f.len()]);
            let span = (turn(a) - turn(b)).abs();
            assert!(
                span <= 90.0 + 1e-6,
                "facet {f:?}: edge {a}-{b} spans {span:.0}°"
            );
        }
    }
}

// ===========================================================================
// Table 2's vertex bar (issue 6): fading features as slits of their region.
// ===========================================================================

/// Fandisk at `--max-error 6e-3` against Table 2's full line: ≤ 75
/// control vertices and ≤ 89 faces with mean ≤ 0.78‰, RMS ≤ 1.63‰, max
/// ≤ 10.46‰, and every sharp input edge within 1‰ of a crease. The two
/// features that fade out inside fandisk's top region (the top crease and
/// the cone's side crease) stay slits of that region
/// (`SegmentOptions::slits`): their creases end at their tips, as on M.
/// Continued to the far side of their regions instead (the network before),
/// they cost 5 curve control points (77 against 72: the continuations'
/// interior points, the two corners where they landed and the splits of
/// the lines they landed on) and the line was 78 V / 76 F.
/// Measured (this test's samples): 73 V / 72 F, mean 0.72‰, RMS 1.52‰,
/// max 7.9‰, worst feature edge 0.88‰.
#[test]
fn fandisk_table2_vertices_with_slits() {
    let (mesh, built) =
        build_fandisk(&mechanical::MechanicalOptions::default().with_max_error(6e-3));
    let (mean, rms, max) = output_error(&mesh, &built);
    let (total, far, worst) = features_far(&mesh, &built);
    let (v, f) = (built.control.num_vertices(), built.control.num_faces());
    println!(
        "{v} vertices {f} faces: mean {mean:.3}‰ RMS {rms:.3}‰ max {max:.2}‰; {far} of {total} sharp edges beyond 1‰ (worst {worst:.3}‰); {} slit edges",
        built.stats.slit_edges
    );
    assert!(
        built.stats.slit_edges > 0,
        "no slit: the test measures nothing new"
    );
    assert!(v <= 75 && f <= 89, "{v} vertices {f} faces");
    assert!(
        mean <= 0.78 && rms <= 1.63 && max <= 10.46,
        "{mean} {rms} {max}"
    );
    assert!(total > 500 && far == 0, "{far} of {total} (worst {worst})");
    assert_eq!(built.stats.sharp_edges_inside_regions, 0);
}

// ===========================================================================
// Procedural CAD parts (issue 6): shapes whose right answer is known, so the
// method (not fandisk's tuning) is what is tested.
// ===========================================================================

/// A triangle mesh from quads given by their corners (counter-clockwise
/// seen from outside), vertices welded on exact coordinates: every corner
/// below is computed by one expression per grid point, so shared points
/// are bit-identical.
fn welded_quads(quads: &[[DVec3; 4]]) -> TriMesh {
    let mut ids: std::collections::HashMap<[u64; 3], u32> = Default::default();
    let mut positions: Vec<DVec3> = Vec::new();
    let mut id = |p: DVec3| {
        let key = [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()];
        *ids.entry(key).or_insert_with(|| {
            positions.push(p);
            positions.len() as u32 - 1
        })
    };
    let mut triangles = Vec::new();
    for q in quads {
        let [a, b, c, d] = q.map(&mut id);
        triangles.push([a, b, c]);
        triangles.push([a, c, d]);
    }
    TriMesh {
        positions,
        triangles,
    }
}

/// The faces of the cube [-1, 1]³ as n × n grids, without the faces listed
/// in `skip` (index 2·axis + (0 for −, 1 for +)).
fn grid_box(n: u32, skip: &[usize]) -> TriMesh {
    let mut quads = Vec::new();
    for axis in 0..3 {
        for (s, sign) in [-1.0f64, 1.0].into_iter().enumerate() {
            if skip.contains(&(2 * axis + s)) {
                continue;
            }
            let p = |i: u32, j: u32| {
                let mut v = [0.0; 3];
                v[axis] = sign;
                v[(axis + 1) % 3] = -1.0 + 2.0 * i as f64 / n as f64;
                v[(axis + 2) % 3] = -1.0 + 2.0 * j as f64 / n as f64;
                DVec3::from_array(v)
            };
            for i in 0..n {
                for j in 0..n {
                    let q = [p(i, j), p(i + 1, j), p(i + 1, j + 1), p(i, j + 1)];
                    quads.push(if sign > 0.0 {
                        q
                    } else {
                        [q[0], q[3], q[2], q[1]]
                    });
                }
            }
        }
    }
    welded_quads(&quads)
}

/// A box is exactly representable (Lavoué §6: planar regions bounded by
/// straight feature lines): 8 corners, 6 quads with infinitely sharp edges,
/// whose limit is the box itself. The same with one face removed (an open
/// part: 5 faces, the rim kept). Anything more is wasted control points,
/// any error is a defect of the curve or polyhedron stage.
#[test]
fn boxes_are_reproduced_exactly() {
    for (skip, faces) in [(vec![], 6usize), (vec![5], 5)] {
        let mesh = grid_box(8, &skip);
        let caster =
            subdfit::raycast::make_raycaster(subdfit::raycast::RayBackend::Embree, &mesh).unwrap();
        let built = mechanical::build_control(&mesh, caster.as_ref(), &Default::default()).unwrap();
        built.control.validate().unwrap();
        let (_, rms, max) = output_error(&mesh, &built);
        let (total, far, _) = features_far(&mesh, &built);
        assert_eq!(
            (built.control.num_vertices(), built.control.num_faces()),
            (8, faces),
            "box without faces {skip:?}"
        );
        // Round-off only: the limit of a planar quad with sharp edges is
        // the quad itself.
        assert!(rms < 1e-6 && max < 1e-6, "RMS {rms}‰ max {max}‰");
        assert!(total > 0 && far == 0, "{far} of {total} sharp edges off");
    }
}

/// A washer (annulus extruded; genus 1, four circular feature lines, no
/// corner anywhere on M): the closed crease loops must be fitted without
/// corners, the control mesh keeps the genus, and the fit meets the
/// default `E_limit` (3‰ RMS) and the features bar. Measured (this
/// test's samples): 54 V / 51 F, RMS 0.89‰, max 4.7‰.
#[test]
fn washer_keeps_genus_and_features() {
    let m = 64u32;
    let radii = [0.5, 0.625, 0.75, 0.875, 1.0];
    let heights = [-0.2, -0.1, 0.0, 0.1, 0.2];
    let p = |r: f64, z: f64, i: u32| {
        let t = std::f64::consts::TAU * (i % m) as f64 / m as f64;
        DVec3::new(r * t.cos(), r * t.sin(), z)
    };
    let mut quads = Vec::new();
    for i in 0..m {
        for k in 0..radii.len() - 1 {
            let (r0, r1) = (radii[k], radii[k + 1]);
            let (zb, zt) = (heights[0], heights[heights.len() - 1]);
            quads.push([
                p(r0, zt, i),
                p(r1, zt, i),
                p(r1, zt, i + 1),
                p(r0, zt, i + 1),
            ]);
            quads.push([
                p(r0, zb, i),
                p(r0, zb, i + 1),
                p(r1, zb, i + 1),
                p(r1, zb, i),
            ]);
        }
        for k in 0..heights.len() - 1 {
            let (z0, z1) = (heights[k], heights[k + 1]);
            let (ri, ro) = (radii[0], radii[radii.len() - 1]);
            quads.push([
                p(ro, z0, i),
                p(ro, z0, i + 1),
                p(ro, z1, i + 1),
                p(ro, z1, i),
            ]);
            quads.push([
                p(ri, z0, i),
                p(ri, z1, i),
                p(ri, z1, i + 1),
                p(ri, z0, i + 1),
            ]);
        }
    }
    let mesh = welded_quads(&quads);
    let caster =
        subdfit::raycast::make_raycaster(subdfit::raycast::RayBackend::Embree, &mesh).unwrap();
    let built = mechanical::build_control(&mesh, caster.as_ref(), &Default::default()).unwrap();
    built.control.validate().unwrap();
    let c = &built.control;
    let euler = c.num_vertices() as i64 - c.num_edges() as i64 + c.num_faces() as i64;
    assert_eq!(euler, 0, "genus 1 needs V - E + F = 0");
    let (mean, rms, max) = output_error(&mesh, &built);
    println!(
        "washer: {} V / {} F, mean {mean:.3} RMS {rms:.3} max {max:.2}‰",
        c.num_vertices(),
        c.num_faces()
    );
    assert!(rms <= 3.0 && max <= 10.46, "RMS {rms}‰ max {max}‰");
    let (total, far, worst) = features_far(&mesh, &built);
    assert!(
        total >= 4 * m as usize && far == 0,
        "{far} of {total} off (worst {worst})"
    );
}
