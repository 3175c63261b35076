//! Doublet removal (Fitmaps §3.3.3): an interior vertex with two edges sits
//! between two quads that share two consecutive edges; the quads merge into
//! one and the vertex goes.

use crate::error::{Error, Result};
use crate::mesh::{ControlMesh, VertexId};

/// Whether `v` is a doublet: a live interior vertex with two edges.
pub fn is_doublet(mesh: &ControlMesh, v: VertexId) -> bool {
    !mesh.is_vertex_deleted(v) && !mesh.is_boundary_vertex(v) && mesh.valence(v) == 2
}

/// The merged quad `[x, p, y, q]` of the doublet at `v`, or why it cannot be
/// removed: `v` is not a doublet, a face is not a quad, or the two quads
/// share their far vertex too (`p == q`: a closed two-face component, which
/// has no quad to merge into).
pub fn can_remove_doublet(mesh: &ControlMesh, v: VertexId) -> Result<[VertexId; 4], &'static str> {
    if !is_doublet(mesh, v) {
        return Err("not a doublet");
    }
    let h0 = mesh.vertex_halfedge(v);
    let h1 = mesh.prev(h0).twin();
    let (Some(g1), Some(g2)) = (mesh.face_of(h0), mesh.face_of(h1)) else {
        return Err("not interior");
    };
    if mesh.face_size(g1) != 4 || mesh.face_size(g2) != 4 {
        return Err("a face is not a quad");
    }
    // g1 = (v, x, p, y) from h0; g2 = (v, y, q, x) from h1.
    let x = mesh.head(h0);
    let p = mesh.head(mesh.next(h0));
    let y = mesh.head(h1);
    let q = mesh.head(mesh.next(h1));
    if p == q || x == y {
        return Err("the two quads share three vertices");
    }
    Ok([x, p, y, q])
}

/// Removes the doublet at `v`; returns its two former neighbours `x`, `y`
/// (each lost an edge, so either may now be a doublet itself).
pub fn remove_doublet(mesh: &mut ControlMesh, v: VertexId) -> Result<[VertexId; 2]> {
    remove_doublet_logged(mesh, v, None)
}

/// [`remove_doublet`], written to `log` when there is one.
pub(crate) fn remove_doublet_logged(
    mesh: &mut ControlMesh,
    v: VertexId,
    log: Option<&mut super::FaceLog>,
) -> Result<[VertexId; 2]> {
    let merged = can_remove_doublet(mesh, v)
        .map_err(|why| Error::topology(v.to_string(), format!("cannot remove doublet: {why}")))?;
    let faces: Vec<_> = mesh.vertex_faces(v).collect();
    super::replace_logged(mesh, &faces, &[&merged], &[v], log)?;
    Ok([merged[0], merged[2]])
}

/// Removes doublets among `candidates` and those that removal creates, in
/// a deterministic order (a stack seeded with `candidates` reversed).
/// Returns the removed vertices and the vertices whose faces changed;
/// doublets that cannot be removed are left and reported by the caller's
/// `validate`-style checks.
pub fn remove_doublets(
    mesh: &mut ControlMesh,
    candidates: &[VertexId],
) -> Result<(Vec<VertexId>, Vec<VertexId>)> {
    remove_doublets_logged(mesh, candidates, None)
}

/// [`remove_doublets`], written to `log` when there is one.
pub(crate) fn remove_doublets_logged(
    mesh: &mut ControlMesh,
    candidates: &[VertexId],
    mut log: Option<&mut super::FaceLog>,
) -> Result<(Vec<VertexId>, Vec<VertexId>)> {
    let mut stack: Vec<VertexId> = candidates.iter().rev().copied().collect();
    let mut removed = Vec::new();
    let mut touched = Vec::new();
    while let Some(v) = stack.pop() {
        if can_remove_doublet(mesh, v).is_ok() {
            let [x, y] = remove_doublet_logged(mesh, v, log.as_deref_mut())?;
            removed.push(v);
            touched.extend([x, y]);
            stack.extend([y, x]);
        }
    }
    Ok((removed, touched))
}
