//! Random sequences of the simplification operators (Fitmaps §3.3) on the
//! quadrangulated shared meshes: `validate()` and the topological
//! invariants after every single operation.

mod common;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use subdfit::mesh::{ControlMesh, FaceId, HalfedgeId, VertexId};
use subdfit::quad::ops::{
    can_collapse_diagonal, can_remove_doublet, can_rotate_edge, collapse_diagonal, is_doublet,
    remove_doublets, rotate_edge, Rotation,
};
use subdfit::quad::{quadrangulate, QuadrangulateOptions};

fn euler(k: &ControlMesh) -> i64 {
    k.num_live_vertices() as i64 - k.num_live_edges() as i64 + k.num_live_faces() as i64
}

fn invariants(k: &ControlMesh) -> (usize, usize, i64) {
    (k.num_components(), k.num_boundary_loops(), euler(k))
}

/// Everything the operators promise, checked on the whole mesh.
fn check(k: &ControlMesh, inv: (usize, usize, i64), what: &str) {
    k.validate().unwrap_or_else(|e| panic!("after {what}: {e}"));
    assert!(k.is_all_quads(), "after {what}: non-quad face");
    if let Some(v) = k.live_vertices().find(|&v| is_doublet(k, v)) {
        panic!("after {what}: doublet at {v}");
    }
    assert_eq!(invariants(k), inv, "after {what}: topology changed");
}

fn random_sequence(name: &str, ops: usize, seed: u64) {
    let Some(m) = common::load_data_mesh(name) else {
        return;
    };
    let mut k = quadrangulate(&m, &QuadrangulateOptions::default())
        .unwrap()
        .mesh;
    let all: Vec<VertexId> = k.live_vertices().collect();
    remove_doublets(&mut k, &all).unwrap();
    let inv = invariants(&k);
    check(&k, inv, "initial doublet removal");
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let (mut collapses, mut rotations, mut refused) = (0, 0, 0);
    let f0 = k.num_live_faces();
    let mut tries = 0;
    while collapses + rotations < ops && tries < 50 * ops {
        tries += 1;
        if rng.gen_bool(0.7) {
            let f = FaceId(rng.gen_range(0..k.num_faces() as u32));
            if k.is_face_deleted(f) {
                continue;
            }
            let d = rng.gen_range(0..2);
            if can_collapse_diagonal(&k, f, d).is_ok() {
                collapse_diagonal(&mut k, f, d, None).unwrap();
                collapses += 1;
                check(&k, inv, &format!("collapse {collapses} of {f}"));
            } else {
                refused += 1;
                if refused > 10 {
                    continue;
                }
                // A refused operator must fail cleanly and change nothing.
                let before = k.clone();
                assert!(collapse_diagonal(&mut k, f, d, None).is_err());
                assert_eq!(k, before);
            }
        } else {
            let h = HalfedgeId(rng.gen_range(0..k.num_halfedges() as u32));
            if k.is_halfedge_deleted(h) {
                continue;
            }
            let dir = if rng.gen_bool(0.5) {
                Rotation::Ccw
            } else {
                Rotation::Cw
            };
            if can_rotate_edge(&k, h, dir).is_ok() {
                rotate_edge(&mut k, h, dir).unwrap();
                rotations += 1;
                check(&k, inv, &format!("rotation {rotations} of {h}"));
            }
        }
    }
    assert!(
        collapses > ops / 3,
        "{name}: only {collapses} collapses applied"
    );
    assert!(k.num_live_faces() <= f0 - collapses);
    // Compaction keeps the mesh and its invariants.
    let before = k.num_live_faces();
    let map = k.compact().unwrap();
    assert_eq!(k.num_faces(), before);
    assert!(!k.has_deletions());
    assert_eq!(map.face_map.iter().flatten().count(), before);
    check(&k, inv, "compact");
    eprintln!(
        "{name}: {collapses} collapses, {rotations} rotations, {refused} refused, {} -> {} faces",
        f0,
        k.num_faces()
    );
}

#[test]
fn random_operations_keep_invariants_on_spot() {
    random_sequence("spot.ply", 300, 1);
}

#[test]
fn random_operations_keep_invariants_on_genus3_block() {
    random_sequence("block.ply", 120, 2);
}

#[test]
fn random_operations_keep_invariants_on_open_bunny() {
    // Open: 5 holes, checked to survive.
    random_sequence("bunny.ply", 40, 3);
}

/// A 4 × 4 grid: a diagonal joining an interior and a boundary vertex keeps
/// the boundary vertex and its position; one joining two boundary vertices
/// is allowed only along the boundary, through a valence-2 corner, which
/// goes with the quad.
#[test]
fn boundary_rules_on_a_grid() {
    let k = subdfit::fixtures::grid(4, 4, 7);
    let inv = invariants(&k);
    // Face 1 = (1, 2, 7, 6): corners 1, 2 on the boundary, 6, 7 interior.
    let f = FaceId(1);
    let q: Vec<VertexId> = k.face_vertices(f).collect();
    assert_eq!(q.iter().map(|v| v.0).collect::<Vec<_>>(), [1, 2, 7, 6]);
    // Diagonal 0: 1 (boundary) – 7 (interior): allowed, keeps 1 where it is.
    let plan = can_collapse_diagonal(&k, f, 0).unwrap();
    assert_eq!(plan.keep, VertexId(1));
    assert_eq!(plan.corner, None);
    assert_eq!(plan.position, k.position(VertexId(1)));
    let mut k2 = k.clone();
    collapse_diagonal(&mut k2, f, 0, None).unwrap();
    check(&k2, inv, "boundary collapse");
    assert!(k2.is_boundary_vertex(VertexId(1)));
    // Corner quad 0 = (0, 1, 6, 5): diagonal 1 joins boundary vertices 1
    // and 5, neighbours along the boundary through the corner 0 (valence
    // 2): allowed; 0 and one end go, the merged vertex starts at 0.
    let p = can_collapse_diagonal(&k, FaceId(0), 1).unwrap();
    assert_eq!(p.corner, Some(VertexId(0)));
    assert_eq!(p.position, k.position(VertexId(0)));
    let mut k3 = k.clone();
    let nb = |k: &ControlMesh| {
        k.live_vertices()
            .filter(|&v| k.is_boundary_vertex(v))
            .count()
    };
    let done = collapse_diagonal(&mut k3, FaceId(0), 1, None).unwrap();
    check(&k3, inv, "collapse along the boundary");
    assert!(k3.is_vertex_deleted(VertexId(0)));
    assert!(k3.is_boundary_vertex(done.keep));
    assert_eq!(nb(&k3), nb(&k) - 2);
    assert_eq!(k3.num_live_faces(), k.num_live_faces() - 1);
    // Diagonal 0 of the corner quad joins the corner 0 and interior 6: the
    // corner stays.
    let p = can_collapse_diagonal(&k, FaceId(0), 0).unwrap();
    assert_eq!(p.keep, VertexId(0));
    // A 4 × 1 strip: face 1 = (1, 2, 7, 6) has all four corners on the
    // boundary, none of valence 2; 1 – 7 would pinch the strip: refused.
    let s = subdfit::fixtures::grid(4, 1, 7);
    assert_eq!(
        can_collapse_diagonal(&s, FaceId(1), 0).unwrap_err(),
        "both ends on the boundary, not neighbours along it"
    );
    // A sharp corner (mechanical input) is never absorbed.
    let mut k4 = k.clone();
    k4.set_corner(VertexId(0), 1.0).unwrap();
    assert!(can_collapse_diagonal(&k4, FaceId(0), 1).is_err());
}

/// Boundary coarsening: on an 8 × 8 grid, collapses of boundary-adjacent
/// quads, interior-into-boundary and along the boundary, keep every
/// invariant (one component, one boundary loop, Euler characteristic 1)
/// after each one, and the boundary loop gets shorter by two vertices per
/// collapse along it.
#[test]
fn boundary_loop_coarsens_and_survives() {
    let mut k = subdfit::fixtures::grid(8, 8, 11);
    let inv = invariants(&k);
    assert_eq!(inv.1, 1);
    let nb = |k: &ControlMesh| {
        k.live_vertices()
            .filter(|&v| k.is_boundary_vertex(v))
            .count()
    };
    let b0 = nb(&k);
    let (mut along, mut total) = (0, 0);
    loop {
        // First applicable boundary collapse in id order (deterministic).
        let mut step = None;
        'find: for f in k.live_faces() {
            if !k.face_vertices(f).any(|v| k.is_boundary_vertex(v)) {
                continue;
            }
            for d in 0..2 {
                if let Ok(p) = can_collapse_diagonal(&k, f, d) {
                    step = Some((f, d, p.corner.is_some()));
                    break 'find;
                }
            }
        }
        let Some((f, d, corner)) = step else { break };
        collapse_diagonal(&mut k, f, d, None).unwrap();
        total += 1;
        along += usize::from(corner);
        check(&k, inv, &format!("boundary collapse {total}"));
        if total > 200 {
            break;
        }
    }
    eprintln!(
        "8 x 8 grid: {total} boundary collapses ({along} along the boundary), {b0} -> {} \
         boundary vertices, {} faces",
        nb(&k),
        k.num_live_faces()
    );
    assert!(along > 0, "no collapse along the boundary");
    // Only a collapse along the boundary changes the boundary, by two
    // vertices (the corner and one end).
    assert_eq!(nb(&k), b0 - 2 * along);
    assert_eq!(k.num_boundary_loops(), 1);
}

/// Edge rotation on a regular grid raises the valence energy, so its gain
/// is negative; the rotation itself is still valid and reversible by the
/// opposite one.
#[test]
fn rotation_is_undone_by_the_opposite_rotation() {
    let k = subdfit::fixtures::grid(4, 4, 3);
    let inv = invariants(&k);
    let h = k.find_halfedge(VertexId(7), VertexId(12)).unwrap();
    let mut k2 = k.clone();
    let x = rotate_edge(&mut k2, h, Rotation::Ccw).unwrap();
    check(&k2, inv, "rotation");
    let targets = subdfit::quad::ops::ValenceTargets::new(&k);
    assert!(subdfit::quad::ops::rotation_energy_gain(&k, &targets, &x, Rotation::Ccw) < 0);
    // The new edge joins x[1] and x[4]; rotating it clockwise gives back
    // the original faces (as vertex sets).
    let h2 = k2.find_halfedge(x[1], x[4]).unwrap();
    rotate_edge(&mut k2, h2, Rotation::Cw).unwrap();
    check(&k2, inv, "rotation back");
    let mut a: Vec<Vec<u32>> = k
        .to_polygons()
        .into_iter()
        .map(|mut p| {
            p.sort();
            p
        })
        .collect();
    let mut b: Vec<Vec<u32>> = k2
        .live_faces()
        .map(|f| {
            let mut p: Vec<u32> = k2.face_vertices(f).map(|v| v.0).collect();
            p.sort();
            p
        })
        .collect();
    a.sort();
    b.sort();
    assert_eq!(a, b);
}

#[test]
fn doublet_removal_merges_two_quads() {
    // A cube whose top face is split in two by an interior vertex 8 of
    // valence 2: removing it gives back the cube's six quads.
    let mut k = subdfit::fixtures::valence2(1);
    let inv = invariants(&k);
    let v = VertexId(8);
    assert!(is_doublet(&k, v));
    let merged = can_remove_doublet(&k, v).unwrap();
    let mut set: Vec<u32> = merged.iter().map(|x| x.0).collect();
    set.sort();
    assert_eq!(set, [4, 5, 6, 7]);
    let (removed, _) = remove_doublets(&mut k, &[v]).unwrap();
    assert_eq!(removed, [v]);
    check(&k, inv, "doublet removal");
    assert_eq!(k.num_live_faces(), 6);
    assert!(k.live_vertices().all(|x| k.valence(x) == 3));
    // Not a doublet any more (deleted): refused.
    assert!(can_remove_doublet(&k, v).is_err());
}
