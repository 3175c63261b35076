//! `SUBDFIT_CLEANUP_FITMAP_MOVES` (issue 40, session 25): one round of
//! multi-rotation moves before the cleanup's count phase, judged by the
//! fitmap tests without the region-fit guard. Its own test binary, since
//! it sets the process's environment.

mod common;

use subdfit::mesh::{ControlMesh, TriMesh};
use subdfit::quad::field::cleanup::{
    cleanup, CleanupOptions, FITMAP_MOVES_ENV, LOCAL_SHARE, LOCAL_SHARE_ENV,
};
use subdfit::quad::field::{control_topology, irregular_vertices};
use subdfit::raycast::bvh::BvhCaster;

/// `n × n` vertices over the unit square with a gentle bump (height 0.05,
/// so the fitmap and the local fits read a curved surface), quads split
/// along alternating diagonals.
fn bumpy_square(n: usize) -> TriMesh {
    common::alternating_grid(n, |u, v| {
        0.05 * (std::f64::consts::PI * u).sin() * (std::f64::consts::PI * v).sin()
    })
}

/// A regular `n × n` quad grid on [`bumpy_square`]'s surface.
fn quad_grid(n: usize, m: &TriMesh) -> ControlMesh {
    let side = (m.positions.len() as f64).sqrt().round() as usize;
    let id = |i: usize, j: usize| (j * (n + 1) + i) as u32;
    let mut positions = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            // The grid's vertices are M's (n divides side − 1).
            let s = (side - 1) / n;
            positions.push(m.positions[j * s * side + i * s]);
        }
    }
    let mut faces = Vec::new();
    for j in 0..n {
        for i in 0..n {
            faces.push([id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    ControlMesh::from_polygons(positions, &faces).unwrap()
}

/// A spurious pair of singularity pairs on a regular 10 × 10 grid: one
/// rotation plants two 3–5 pairs (E 4), an energy-neutral rotation beside
/// them pulls one pair apart, so no single operation lowers E (the
/// extraction's leftovers on gargoyle 402 are of this kind: 3–5 pairs a
/// cell or two apart).
fn dislocated(m: &TriMesh) -> ControlMesh {
    let mut k = quad_grid(10, m);
    common::dislocate(&mut k);
    k
}

/// Unset (or `0`) the switch leaves the options as they are; set, it asks
/// for one move round without the region-fit guard. On the dislocated
/// grid with a face target of 100 (the count phase runs and keeps the
/// count), the single-operation cleanup (the default) keeps the 4 planted
/// irregular vertices; with the switch the pairs cancel: 0 irregular
/// vertices, valence energy 0, the same 100 pure quads, one component, one
/// boundary loop and Euler characteristic 1 (the disc's), every step
/// validated, at least one move kept and the region-fit guard never run
/// (no time in it, no move refused by it).
#[test]
fn fitmap_moves_cancel_a_separated_pair_without_the_region_fit() {
    std::env::remove_var(FITMAP_MOVES_ENV);
    let base = CleanupOptions::default()
        .with_check_every_step(true)
        .with_target_faces(Some(100));
    assert_eq!(base.clone().with_fitmap_moves_env(), base);
    std::env::set_var(FITMAP_MOVES_ENV, "0");
    assert_eq!(base.clone().with_fitmap_moves_env(), base);
    // `local` and `local-fit`: `shape`'s tests under the locality gate.
    std::env::set_var(FITMAP_MOVES_ENV, "local");
    let local = base.clone().with_fitmap_moves_env();
    assert!(local.move_shape_tests && !local.move_local_fit);
    assert_eq!(local.move_local_share, LOCAL_SHARE);
    std::env::set_var(LOCAL_SHARE_ENV, "0.3");
    std::env::set_var(FITMAP_MOVES_ENV, "local-fit");
    let fit = base.clone().with_fitmap_moves_env();
    std::env::remove_var(LOCAL_SHARE_ENV);
    assert!(fit.move_shape_tests && fit.move_local_fit);
    assert_eq!((fit.move_local_share, fit.move_fit_rise), (0.3, 0.0));
    std::env::set_var(FITMAP_MOVES_ENV, "1");
    let on = base.clone().with_fitmap_moves_env();
    std::env::remove_var(FITMAP_MOVES_ENV);
    assert_eq!((on.move_local_share, on.move_local_fit), (0.0, false));
    assert_eq!((on.move_rounds, on.move_fit_rise), (1, 0.0));
    assert!(!on.guarded && !on.moves_after_count);

    let m = bumpy_square(41);
    let fm = common::flat_fitmap(m.positions.len());
    let caster = BvhCaster::new(&m).unwrap();
    let k = dislocated(&m);
    assert_eq!(irregular_vertices(&k), 4);
    // The grid's own (the rotations' mesh may hold unused slots).
    let before = control_topology(&quad_grid(10, &m));

    let (single, _) = cleanup(&m, &fm, &caster, k.clone(), &base).unwrap();
    assert_eq!(irregular_vertices(&single), 4, "single operations only");

    let (out, stats) = cleanup(&m, &fm, &caster, k, &on).unwrap();
    assert!(out.is_all_quads());
    assert_eq!(out.num_faces(), 100);
    let t = control_topology(&out);
    assert_eq!(
        (t.components, t.boundary_loops, t.euler),
        (before.components, before.boundary_loops, before.euler)
    );
    assert_eq!((t.components, t.boundary_loops, t.euler), (1, 1, 1));
    assert_eq!(irregular_vertices(&out), 0, "{stats:?}");
    assert_eq!(stats.energy_after, 0);
    assert!(stats.moves >= 1, "{stats:?}");
    assert_eq!(stats.moves_undone_fit, 0);
    assert_eq!(stats.move_seconds_guard, 0.0);
    // Every control point is still on the bump (the output goes back to
    // points on M): within M's chord error of the height field.
    for &p in out.positions() {
        let z = 0.05 * (std::f64::consts::PI * p.x).sin() * (std::f64::consts::PI * p.y).sin();
        assert!((p.z - z).abs() < 1e-3, "{p:?} vs {z}");
    }
}

/// The control mesh as data: its positions and its faces' vertex ids.
fn bits(k: &ControlMesh) -> (Vec<[u64; 3]>, Vec<Vec<u32>>) {
    let p = k
        .positions()
        .iter()
        .map(|p| [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()])
        .collect();
    let f = k
        .live_faces()
        .map(|f| k.face_vertices(f).map(|v| v.0).collect())
        .collect();
    (p, f)
}

/// The options of `SUBDFIT_CLEANUP_FITMAP_MOVES=shape` (`local_share` 0),
/// `local` (`local_share` > 0) or `local-fit`, set directly (the
/// environment is the other test's).
fn moves(n: usize, local_share: f64, fit: bool) -> CleanupOptions {
    let mut o = CleanupOptions::default()
        .with_check_every_step(true)
        .with_target_faces(Some(n));
    o.move_rounds = 1;
    o.move_fit_rise = 0.0;
    o.move_shape_tests = true;
    o.move_local_share = local_share;
    o.move_local_fit = fit;
    o
}

/// The locality gate (session 26): the same planted dislocation, the same
/// move, on a coarse grid (10 × 10 quads: the move's faces with their
/// one-ring are about a third of the surface) and on a fine one (20 × 20
/// over the same surface: a twelfth). Fine, `local` takes the move as
/// `shape` does: 0 irregular vertices, bit for bit `shape`'s mesh. Coarse,
/// `shape` takes it but `local` refuses it before applying it: the 4
/// planted irregular vertices stay, no move is counted, and the mesh is
/// bit for bit the single-operation cleanup's (what lets spot at 81–85
/// faces keep main's bytes); `local-fit` judges it by the region fit
/// instead (time spent in the guard). Each keeps the face count, the pure
/// quads and the disc's topology.
#[test]
fn the_locality_gate_refuses_a_move_that_reshapes_a_large_share() {
    let m = bumpy_square(41);
    let fm = common::flat_fitmap(m.positions.len());
    let caster = BvhCaster::new(&m).unwrap();
    let disc = |k: &ControlMesh, n: usize| {
        assert!(k.is_all_quads());
        assert_eq!(k.num_faces(), n);
        let t = control_topology(k);
        assert_eq!((t.components, t.boundary_loops, t.euler), (1, 1, 1));
    };

    // Fine: the move is local.
    let mut k = quad_grid(20, &m);
    common::dislocate_grid(&mut k, 20);
    assert_eq!(irregular_vertices(&k), 4);
    let (shape, _) = cleanup(&m, &fm, &caster, k.clone(), &moves(400, 0.0, false)).unwrap();
    let (local, st) = cleanup(&m, &fm, &caster, k, &moves(400, LOCAL_SHARE, false)).unwrap();
    disc(&local, 400);
    assert_eq!(irregular_vertices(&local), 0, "{st:?}");
    assert!(st.moves >= 1, "{st:?}");
    assert_eq!(bits(&local), bits(&shape));

    // Coarse: the same move reshapes a large share of the surface.
    let k = dislocated(&m);
    let base = CleanupOptions::default()
        .with_check_every_step(true)
        .with_target_faces(Some(100));
    let (single, _) = cleanup(&m, &fm, &caster, k.clone(), &base).unwrap();
    let (shape, st) = cleanup(&m, &fm, &caster, k.clone(), &moves(100, 0.0, false)).unwrap();
    assert_eq!(irregular_vertices(&shape), 0, "shape takes it: {st:?}");
    let (local, st) =
        cleanup(&m, &fm, &caster, k.clone(), &moves(100, LOCAL_SHARE, false)).unwrap();
    disc(&local, 100);
    assert_eq!(irregular_vertices(&local), 4, "{st:?}");
    assert_eq!((st.moves, st.moves_tried), (0, 0), "{st:?}");
    assert_eq!(bits(&local), bits(&single));
    let (fit, st) = cleanup(&m, &fm, &caster, k, &moves(100, LOCAL_SHARE, true)).unwrap();
    disc(&fit, 100);
    assert!(st.moves_tried >= 1 && st.move_seconds_guard > 0.0, "{st:?}");
}
