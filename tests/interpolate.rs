//! Limit interpolation (Fitmaps §3.2, system (1)): the Catmull-Clark limit
//! of every control vertex lands on its target.

mod common;

use subdfit::mesh::{ControlMesh, TriMesh, VertexId};
use subdfit::quad::{
    interpolate_limit, interpolate_limit_local, limit_positions, quadrangulate, vertex_limit_mask,
    InterpolationOptions, InterpolationSolver, QuadrangulateOptions,
};
use subdfit::DVec3;

/// Limit positions recomputed row by row from the public masks.
fn limits_by_mask(m: &ControlMesh) -> Vec<DVec3> {
    m.vertices()
        .map(|v| {
            vertex_limit_mask(m, v)
                .unwrap()
                .iter()
                .map(|&(u, w)| w * m.position(u))
                .sum()
        })
        .collect()
}

fn max_err(a: &[DVec3], b: &[DVec3]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (*x - *y).length())
        .fold(0.0, f64::max)
}

#[test]
fn quadrangulated_shared_meshes_interpolate() {
    let Some(dir) = common::data_dir() else {
        return;
    };
    for name in ["spot", "bunny"] {
        let m = common::load_ply(&dir.join(format!("{name}.ply")));
        let q = quadrangulate(&m, &QuadrangulateOptions::default()).unwrap();
        let mut k = q.mesh.clone();
        let targets = k.positions().to_vec();
        let diag = m.bbox_diagonal();
        let t0 = std::time::Instant::now();
        let r = interpolate_limit(&mut k, &targets, &InterpolationOptions::default()).unwrap();
        println!(
            "{name}: {} control vertices, {} sweeps, residual {:.2e} of the diagonal, {:.3}s, fallback {}",
            k.num_vertices(),
            r.iterations,
            r.max_residual_relative,
            t0.elapsed().as_secs_f64(),
            r.fell_back_to_direct
        );
        assert!(r.converged && r.max_residual_relative <= 1e-9);
        // Independent check through the per-vertex masks. The limit of every
        // original vertex is the input vertex (bunny: through vertex_map).
        let lim = limits_by_mask(&k);
        let e = max_err(&lim, &targets) / diag;
        assert!(
            e <= 1e-9,
            "{name}: limit off its target by {e:.2e} of the diagonal"
        );
        for (i, v) in q.vertex_map.iter().enumerate() {
            if let Some(v) = v {
                assert!((lim[v.idx()] - m.positions[i]).length() <= 1e-9 * diag);
            }
        }
        // The control points did move (a dense mesh is not its own limit):
        // the test would not notice a solver that returned the targets.
        assert!(max_err(k.positions(), &targets) > 1e-4 * diag);
        // Same answer from the direct solver (Eigen), to the tolerance.
        if name == "spot" {
            let mut k2 = q.mesh.clone();
            let opts = InterpolationOptions::default().with_solver(InterpolationSolver::Direct);
            let r2 = interpolate_limit(&mut k2, &targets, &opts).unwrap();
            assert_eq!(r2.solver, InterpolationSolver::Direct);
            // Both residuals ≤ 1e-9·diag; ‖L⁻¹‖ ≤ 9-ish on such meshes.
            let d = max_err(k.positions(), k2.positions()) / diag;
            assert!(d < 1e-7, "fixed point vs direct differ by {d:.2e}");
        }
    }
}

/// Triangulated `n × n` grid on the tilted plane z = 0.3 x − 0.2 y + 1, with
/// jittered vertices.
fn plane(n: usize) -> TriMesh {
    let mut positions = Vec::new();
    let mut s = 12345u64;
    let mut rnd = || {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (s >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    };
    for j in 0..=n {
        for i in 0..=n {
            let (x, y) = (i as f64 + 0.3 * rnd(), j as f64 + 0.3 * rnd());
            positions.push(DVec3::new(x, y, 0.3 * x - 0.2 * y + 1.0));
        }
    }
    let id = |i: usize, j: usize| (j * (n + 1) + i) as u32;
    let mut triangles = Vec::new();
    for j in 0..n {
        for i in 0..n {
            triangles.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
            triangles.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    // One extra triangle makes the count odd: a parity fix is involved too.
    positions.push(DVec3::new(
        n as f64 + 1.0,
        0.5,
        0.3 * (n as f64 + 1.0) - 0.1 + 1.0,
    ));
    triangles.push([id(n, 0), positions.len() as u32 - 1, id(n, 1)]);
    TriMesh {
        positions,
        triangles,
    }
}

#[test]
fn plane_stays_plane() {
    let m = plane(12);
    let q = quadrangulate(&m, &QuadrangulateOptions::default()).unwrap();
    assert_eq!(q.report.parity_fixes.len(), 1);
    let mut k = q.mesh.clone();
    let targets = k.positions().to_vec();
    let r = interpolate_limit(&mut k, &targets, &InterpolationOptions::default()).unwrap();
    assert!(r.max_residual_relative <= 1e-9);
    // Masks are affine (weights sum to 1), so the solution stays on the
    // plane up to rounding.
    let off = k
        .positions()
        .iter()
        .map(|p| (p.z - (0.3 * p.x - 0.2 * p.y + 1.0)).abs())
        .fold(0.0, f64::max);
    assert!(off < 1e-10, "control point off the plane by {off:.2e}");
    assert!(max_err(&limits_by_mask(&k), &targets) <= 1e-9 * m.bbox_diagonal());
}

/// Solves the 1-D system of the boundary rule: ends fixed, (1, 4, 1)/6 inside
/// (Thomas algorithm, independent of the crate's solvers).
fn bspline_interp_1d(f: &[f64]) -> Vec<f64> {
    let n = f.len();
    let (mut a, mut b, mut c, mut d) = (vec![0.0; n], vec![1.0; n], vec![0.0; n], f.to_vec());
    for i in 1..n - 1 {
        a[i] = 1.0 / 6.0;
        b[i] = 4.0 / 6.0;
        c[i] = 1.0 / 6.0;
    }
    for i in 1..n {
        let w = a[i] / b[i - 1];
        b[i] -= w * c[i - 1];
        d[i] -= w * d[i - 1];
    }
    let mut x = vec![0.0; n];
    x[n - 1] = d[n - 1] / b[n - 1];
    for i in (0..n - 1).rev() {
        x[i] = (d[i] - c[i] * x[i + 1]) / b[i];
    }
    x
}

#[test]
fn regular_grid_matches_tensor_bspline_interpolation() {
    // On a regular open quad grid with the edge-and-corner rule, L = A ⊗ A
    // with A the 1-D matrix above, so targets z_ij = f_i g_j are interpolated
    // by control heights (A⁻¹f)_i (A⁻¹g)_j; x and y (linear) are reproduced.
    let (nx, ny) = (9usize, 7usize);
    let f: Vec<f64> = (0..nx).map(|i| (i as f64 * 0.9).sin() + 0.2).collect();
    let g: Vec<f64> = (0..ny).map(|j| (j as f64 * 0.6).cos()).collect();
    let mut pos = Vec::new();
    for (j, gj) in g.iter().enumerate() {
        for (i, fi) in f.iter().enumerate() {
            pos.push(DVec3::new(i as f64, j as f64, fi * gj));
        }
    }
    let id = |i: usize, j: usize| (j * nx + i) as u32;
    let faces: Vec<[u32; 4]> = (0..ny - 1)
        .flat_map(|j| {
            (0..nx - 1).map(move |i| [id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1)])
        })
        .collect();
    let mut k = ControlMesh::from_polygons(pos.clone(), &faces).unwrap();
    let r = interpolate_limit(&mut k, &pos, &InterpolationOptions::default()).unwrap();
    let (cf, cg) = (bspline_interp_1d(&f), bspline_interp_1d(&g));
    let mut worst = 0.0f64;
    for (j, cgj) in cg.iter().enumerate() {
        for (i, cfi) in cf.iter().enumerate() {
            let p = k.position(VertexId(id(i, j)));
            let want = DVec3::new(i as f64, j as f64, cfi * cgj);
            worst = worst.max((p - want).length());
        }
    }
    println!(
        "grid: {} sweeps, worst deviation from closed form {worst:.2e}",
        r.iterations
    );
    // Residual ≤ 1e-9·diag and ‖L⁻¹‖ ≤ ‖A⁻¹‖² ≤ 9 (A's smallest eigenvalue
    // is ≥ 1/3): the solution error is below 1e-8·diag.
    assert!(worst < 1e-8 * k.bbox_diagonal().max(1.0), "{worst:.2e}");
}

#[test]
fn interior_valence_two_uses_the_exact_mask() {
    // Two quads (a, m, g, c), (m, b, c, g) glued along m–g and g–c inside a
    // bigger patch make g an interior vertex of valence 2 only if g is
    // surrounded; build a closed example: two quads sharing all four edges
    // is a "pillow", whose vertices are all of valence 2.
    let p = vec![
        DVec3::new(0.0, 0.0, 0.0),
        DVec3::new(1.0, 0.0, 0.0),
        DVec3::new(1.0, 1.0, 0.0),
        DVec3::new(0.0, 1.0, 0.0),
    ];
    let m = ControlMesh::from_polygons(p, &[[0, 1, 2, 3], [3, 2, 1, 0]]).unwrap();
    let w = vertex_limit_mask(&m, VertexId(0)).unwrap();
    // n = 2: v 4/14, each edge neighbour (appearing twice) 2·4/14, the
    // diagonal (opposite in both quads) 2·1/14.
    let get = |v: u32| w.iter().find(|x| x.0 == VertexId(v)).unwrap().1;
    assert!((get(0) - 4.0 / 14.0).abs() < 1e-15);
    assert!((get(1) - 4.0 / 14.0).abs() < 1e-15);
    assert!((get(3) - 4.0 / 14.0).abs() < 1e-15);
    assert!((get(2) - 2.0 / 14.0).abs() < 1e-15);
}

#[test]
fn local_interpolation_moves_only_the_given_vertices() {
    let m = plane(10);
    let q = quadrangulate(&m, &QuadrangulateOptions::default()).unwrap();
    let mut k = q.mesh.clone();
    let mut targets = k.positions().to_vec();
    interpolate_limit(&mut k, &targets, &InterpolationOptions::default()).unwrap();
    // Lift a few interior targets and refit only their neighbourhood.
    let moved: Vec<VertexId> = k
        .vertices()
        .filter(|&v| !k.is_boundary_vertex(v))
        .step_by(17)
        .collect();
    for v in &moved {
        targets[v.idx()].z += 0.05;
    }
    let mut region: Vec<VertexId> = moved.clone();
    for &v in &moved {
        region.extend(
            k.outgoing(v)
                .map(|h| k.head(h))
                .filter(|&w| !k.is_boundary_vertex(w)),
        );
    }
    let before = k.positions().to_vec();
    let r = interpolate_limit_local(&mut k, &targets, &region, 300).unwrap();
    assert!(r.iterations == 300 || r.converged);
    for v in k.vertices() {
        if !region.contains(&v) {
            assert_eq!(k.position(v), before[v.idx()], "{v} moved");
        }
    }
    let lim = limit_positions(&k).unwrap();
    for &v in &moved {
        let e = (lim[v.idx()] - targets[v.idx()]).length();
        assert!(e < 1e-6, "{v}: limit {e:.2e} away after local refit");
    }
    assert!(r.max_residual_relative < 1e-6);
}

#[test]
fn bad_arguments_are_errors() {
    let mut k = subdfit::fixtures::cube();
    assert!(
        interpolate_limit(&mut k, &[DVec3::ZERO; 3], &InterpolationOptions::default()).is_err()
    );
    let mut t = k.positions().to_vec();
    t[0].x = f64::NAN;
    assert!(interpolate_limit(&mut k, &t, &InterpolationOptions::default()).is_err());
    k.set_crease(VertexId(0), VertexId(1), 2.0).unwrap();
    let t = k.positions().to_vec();
    let e = interpolate_limit(&mut k, &t, &InterpolationOptions::default()).unwrap_err();
    assert!(e.to_string().contains("sharpness"), "{e}");
}

#[test]
fn cube_interpolation_inverts_the_corner_mask() {
    // The limit of the cube [-1, 1]^3 corners is ±1/2, so interpolating the
    // half-size cube must give back the unit cube.
    let mut k = subdfit::fixtures::cube();
    let want = k.positions().to_vec();
    let targets: Vec<DVec3> = want.iter().map(|p| *p * 0.5).collect();
    interpolate_limit(&mut k, &targets, &InterpolationOptions::default()).unwrap();
    assert!(max_err(k.positions(), &want) < 1e-8);
}
