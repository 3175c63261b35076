//! Edge rotation ("edge swap", Fitmaps §3.3.2): the edge shared by two quads
//! is replaced by one of the two other diagonals of the hexagon they form.

use super::{adjacent, min_valence, ValenceTargets};
use crate::error::{Error, Result};
use crate::mesh::{ControlMesh, HalfedgeId, VertexId};

/// Which way the edge turns inside its hexagon.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Hash)]
pub enum Rotation {
    /// The new edge joins the hexagon vertices after each end of the old
    /// edge in counter-clockwise order (the faces' orientation).
    Ccw,
    /// The other one.
    Cw,
}

/// The hexagon `[u, r, s, w, p, q]` around the edge of `h` (`u → w`), in the
/// faces' orientation: `face(h) = (u, w, p, q)`, `face(twin) = (w, u, r, s)`.
fn hexagon(mesh: &ControlMesh, h: HalfedgeId) -> Option<[VertexId; 6]> {
    let t = h.twin();
    let (f1, f2) = (mesh.face_of(h)?, mesh.face_of(t)?);
    if mesh.face_size(f1) != 4 || mesh.face_size(f2) != 4 {
        return None;
    }
    let u = mesh.tail(h);
    let w = mesh.head(h);
    let p = mesh.head(mesh.next(h));
    let q = mesh.tail(mesh.prev(h));
    let r = mesh.head(mesh.next(t));
    let s = mesh.tail(mesh.prev(t));
    Some([u, r, s, w, p, q])
}

/// The two new quads and the new edge's ends for a rotation of hexagon `x`.
fn rotated(x: [VertexId; 6], dir: Rotation) -> ([[VertexId; 4]; 2], [VertexId; 2]) {
    let k = match dir {
        Rotation::Ccw => 1,
        Rotation::Cw => 2,
    };
    let at = |i: usize| x[(k + i) % 6];
    (
        [[at(0), at(1), at(2), at(3)], [at(3), at(4), at(5), at(0)]],
        [at(0), at(3)],
    )
}

/// Checks a rotation of the edge of `h`: both sides quads, six distinct
/// hexagon vertices, the new edge not already present, and both ends of the
/// old edge keep enough edges (no doublet, no new boundary corner).
/// Returns the hexagon.
pub fn can_rotate_edge(
    mesh: &ControlMesh,
    h: HalfedgeId,
    dir: Rotation,
) -> Result<[VertexId; 6], &'static str> {
    if mesh.is_halfedge_deleted(h) {
        return Err("deleted edge");
    }
    let x = hexagon(mesh, h).ok_or("not an edge between two quads")?;
    for i in 0..6 {
        if x[..i].contains(&x[i]) {
            return Err("the hexagon repeats a vertex");
        }
    }
    let (_, [a, b]) = rotated(x, dir);
    if adjacent(mesh, a, b) {
        return Err("the new edge already exists");
    }
    for v in [x[0], x[3]] {
        // A boundary end needs 4 edges: rotations never make new corners.
        let need = min_valence(mesh, v) + 1 + usize::from(mesh.is_boundary_vertex(v));
        if mesh.valence(v) < need {
            return Err("an end of the edge would lose too many edges");
        }
    }
    Ok(x)
}

/// Change of the valence energy `Σ |D(v_i) − ideal(v_i)|` over the hexagon
/// if the edge of `h` is rotated (`> 0`: the energy drops by that much).
pub fn rotation_energy_gain(
    mesh: &ControlMesh,
    targets: &ValenceTargets,
    x: &[VertexId; 6],
    dir: Rotation,
) -> i64 {
    let (_, [a, b]) = rotated(*x, dir);
    let mut gain = 0i64;
    for &v in x {
        let d = mesh.valence(v);
        let nd = if v == x[0] || v == x[3] {
            d - 1
        } else if v == a || v == b {
            d + 1
        } else {
            d
        };
        gain += targets.penalty(mesh, v, d) as i64 - targets.penalty(mesh, v, nd) as i64;
    }
    gain
}

/// Rotates the edge of `h`; returns the hexagon's vertices.
pub fn rotate_edge(mesh: &mut ControlMesh, h: HalfedgeId, dir: Rotation) -> Result<[VertexId; 6]> {
    rotate_edge_logged(mesh, h, dir, None)
}

/// [`rotate_edge`], written to `log` when there is one.
pub(crate) fn rotate_edge_logged(
    mesh: &mut ControlMesh,
    h: HalfedgeId,
    dir: Rotation,
    log: Option<&mut super::FaceLog>,
) -> Result<[VertexId; 6]> {
    let x = can_rotate_edge(mesh, h, dir)
        .map_err(|why| Error::topology(h.to_string(), format!("cannot rotate: {why}")))?;
    let (faces, _) = rotated(x, dir);
    let f1 = mesh.face_of(h).expect("checked");
    let f2 = mesh.face_of(h.twin()).expect("checked");
    super::replace_logged(mesh, &[f1, f2], &[&faces[0], &faces[1]], &[], log)?;
    Ok(x)
}
