//! Diagonal collapse (Fitmaps §3.3.1): the two opposite vertices `a`, `c` of
//! a quad merge into one; the quad, two edges and a vertex disappear. The
//! doublets the collapse may create at the quad's other two corners are
//! removed at once (§3.3.3), so the operator never leaves a valence-2
//! interior vertex.

use super::remove_doublet::remove_doublets_logged;
use super::{adjacent, min_valence, quad};
use crate::error::{Error, Result};
use crate::mesh::{ControlMesh, FaceId, VertexId};
use crate::DVec3;

/// What a collapse will do: `remove` merges into `keep`, at `position`.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct CollapsePlan {
    pub face: FaceId,
    pub keep: VertexId,
    pub remove: VertexId,
    /// The quad's other two corners (they lose an edge each; in a collapse
    /// along the boundary, one of them is `corner` and disappears).
    pub sides: [VertexId; 2],
    /// Collapse along the boundary: the boundary corner (valence 2, both
    /// edges on the boundary) between the two boundary ends, removed with
    /// the quad. `None` for an ordinary collapse.
    pub corner: Option<VertexId>,
    /// Midpoint of the diagonal (§3.3.1); the boundary end's position when
    /// one end is on the boundary, the removed corner's when both are (the
    /// boundary must not move inwards: see [`can_collapse_diagonal`]).
    pub position: DVec3,
}

/// The outcome of [`collapse_diagonal`].
#[derive(Clone, Debug, PartialEq)]
pub struct Collapsed {
    pub keep: VertexId,
    pub removed: VertexId,
    /// The boundary corner removed by a collapse along the boundary.
    pub corner: Option<VertexId>,
    /// Doublet vertices removed afterwards.
    pub doublets: Vec<VertexId>,
}

/// Checks the collapse of diagonal `k` (0: corners 0–2, 1: corners 1–3) of
/// the quad `f`. Boundary vertices collapse only along the boundary (issue
/// 4: holes are never closed or opened): when both ends `a`, `c` are on the
/// boundary, the collapse is allowed only if they are neighbours along it
/// through one of the quad's other corners `b` — a boundary corner of
/// valence 2 (the quad is its only face, `a b` and `b c` are boundary
/// edges) without corner sharpness — and the fourth corner `d` is interior.
/// The quad, `b`, `c` and the edges `a b`, `b c`, `c d` go (V − 2, E − 3,
/// F − 1: the Euler characteristic is kept), the boundary loop loses two
/// vertices and stays a loop. This is how the boundary coarsens: a collapse
/// of an interior vertex into the boundary leaves its boundary side corner
/// with valence 2, and the next collapse along the boundary absorbs it.
/// Refused when:
/// - both ends are on the boundary and are not neighbours along it as
///   above (joining them would pinch the boundary or join two holes);
/// - the ends are joined by an edge, share a neighbour other than the
///   quad's two other corners, or share another face (the result would have
///   a doubled edge, a handle change or a face with a repeated vertex: the
///   quad form of the link condition, which keeps the Euler characteristic
///   at V − 1, E − 2, F − 1);
/// - a side corner would drop below its minimum valence, or becomes a
///   doublet whose removal would cascade (its third neighbour would become a
///   doublet too) or would leave the merged vertex below its minimum.
pub fn can_collapse_diagonal(
    mesh: &ControlMesh,
    f: FaceId,
    k: usize,
) -> Result<CollapsePlan, &'static str> {
    if f.idx() >= mesh.num_faces() || mesh.is_face_deleted(f) || mesh.face_size(f) != 4 || k > 1 {
        return Err("not a live quad diagonal");
    }
    let q = quad(mesh, f);
    let (a, b, c, d) = (q[k], q[k + 1], q[k + 2], q[(k + 3) % 4]);
    let (ba, bc) = (mesh.is_boundary_vertex(a), mesh.is_boundary_vertex(c));
    let mut corner = None;
    if ba && bc {
        // A boundary vertex of valence 2 has one face (this quad) and its
        // two edges, to a and c, on the boundary.
        let along = |s: VertexId| {
            mesh.is_boundary_vertex(s) && mesh.valence(s) == 2 && mesh.vertex_sharpness(s) == 0.0
        };
        let other = if along(b) {
            corner = Some(b);
            d
        } else if along(d) {
            corner = Some(d);
            b
        } else {
            return Err("both ends on the boundary, not neighbours along it");
        };
        if mesh.is_boundary_vertex(other) {
            return Err("collapse along the boundary with a boundary fourth corner");
        }
    }
    if adjacent(mesh, a, c) {
        return Err("the ends are joined by an edge");
    }
    for h in mesh.outgoing(c) {
        let x = mesh.head(h);
        if x != b && x != d && adjacent(mesh, a, x) {
            return Err("the ends share a neighbour outside the quad");
        }
    }
    for g in mesh.vertex_faces(c) {
        if g != f && mesh.face_vertices(g).any(|x| x == a) {
            return Err("the ends share another face");
        }
    }
    // The merged vertex: every edge of a and c, the two pairs (a b, c b) and
    // (a d, c d) counted once (the edge to a removed corner not at all),
    // less one per doublet removed at b or d.
    let mut merged = mesh.valence(a) + mesh.valence(c) - 2 - usize::from(corner.is_some());
    let mut third = [VertexId::INVALID; 2];
    for (i, &s) in [b, d].iter().enumerate() {
        if corner == Some(s) {
            continue;
        }
        let vs = mesh.valence(s);
        if vs - 1 < min_valence(mesh, s) {
            if mesh.is_boundary_vertex(s) {
                return Err("a boundary side corner would be left with one edge");
            }
            // s becomes a doublet between the faces at its edges to a and c;
            // removing it takes the edge (s, a) and the edge to its third
            // neighbour y.
            let y = mesh
                .outgoing(s)
                .map(|h| mesh.head(h))
                .find(|&x| x != a && x != c)
                .ok_or("degenerate side corner")?;
            if y == b || y == d || mesh.valence(y) - 1 < min_valence(mesh, y) {
                return Err("the doublet removal would cascade");
            }
            third[i] = y;
            merged -= 1;
        }
    }
    if third[0].is_valid() && third[0] == third[1] {
        return Err("both doublets would share their third neighbour");
    }
    if merged < if ba || bc { 2 } else { 3 } {
        return Err("the merged vertex would have too few edges");
    }
    let (keep, remove) = if bc { (c, a) } else { (a, c) };
    let position = if let Some(s) = corner {
        // The corner lies on the boundary curve (a valence-2 boundary vertex
        // is a corner under the edge-and-corner rule: its limit is itself);
        // the midpoint of a c would cut the curve's chord, inside M.
        mesh.position(s)
    } else if ba || bc {
        mesh.position(keep)
    } else {
        0.5 * (mesh.position(a) + mesh.position(c))
    };
    Ok(CollapsePlan {
        face: f,
        keep,
        remove,
        sides: [b, d],
        corner,
        position,
    })
}

/// Collapses diagonal `k` of quad `f` (see [`can_collapse_diagonal`]),
/// places the merged vertex at `position` (`None`: the plan's position), and
/// removes the doublets it creates.
pub fn collapse_diagonal(
    mesh: &mut ControlMesh,
    f: FaceId,
    k: usize,
    position: Option<DVec3>,
) -> Result<Collapsed> {
    collapse_diagonal_logged(mesh, f, k, position, None)
}

/// [`collapse_diagonal`], written to `log` when there is one.
pub(crate) fn collapse_diagonal_logged(
    mesh: &mut ControlMesh,
    f: FaceId,
    k: usize,
    position: Option<DVec3>,
    mut log: Option<&mut super::FaceLog>,
) -> Result<Collapsed> {
    let plan = can_collapse_diagonal(mesh, f, k)
        .map_err(|why| Error::topology(f.to_string(), format!("cannot collapse: {why}")))?;
    let (keep, remove) = (plan.keep, plan.remove);
    let mut removed_faces: Vec<FaceId> = mesh.vertex_faces(remove).collect();
    let added: Vec<Vec<VertexId>> = removed_faces
        .iter()
        .filter(|&&g| g != f)
        .map(|&g| {
            mesh.face_vertices(g)
                .map(|x| if x == remove { keep } else { x })
                .collect()
        })
        .collect();
    if !removed_faces.contains(&f) {
        removed_faces.push(f);
    }
    let add: Vec<&[VertexId]> = added.iter().map(|p| p.as_slice()).collect();
    let mut delete = vec![remove];
    delete.extend(plan.corner);
    super::replace_logged(mesh, &removed_faces, &add, &delete, log.as_deref_mut())?;
    mesh.positions_mut()[keep.idx()] = position.unwrap_or(plan.position);
    let sides: Vec<VertexId> = plan
        .sides
        .into_iter()
        .filter(|&s| Some(s) != plan.corner)
        .collect();
    let (doublets, _) = remove_doublets_logged(mesh, &sides, log)?;
    Ok(Collapsed {
        keep,
        removed: remove,
        corner: plan.corner,
        doublets,
    })
}
