//! Local operators on a pure-quad control mesh (Fitmaps §3.3, the subset of
//! Tarini et al. 2010 the paper keeps): diagonal collapse, edge rotation
//! ("swap") and doublet removal. Each operator has its `can_*` check beside
//! it; an operator applied where its check passes keeps the mesh manifold,
//! pure quad, free of valence-2 interior vertices (after the doublet
//! cascade the collapse runs itself), with the same components, boundary
//! loops and genus (every operator keeps the Euler characteristic: collapse
//! and doublet removal take one vertex, two edges and one face, rotation
//! takes nothing). The final word on manifoldness is
//! [`ControlMesh::replace_faces`], which checks before it changes anything.
//!
//! Valence convention (the energy of §3.3.2 and the irregular-vertex
//! count): an interior vertex is regular with 4 edges; a boundary vertex
//! with 3 edges (the boundary counterpart of 4: half of its neighbourhood is
//! missing); a vertex that was a corner of the input boundary (2 edges)
//! stays regular with 2 ([`ValenceTargets`]). So neither regular boundary
//! vertices nor input corners are penalised, while a corner created by the
//! simplification is (by 1).

mod collapse_diagonal;
mod remove_doublet;
mod rotate_edge;

pub(crate) use collapse_diagonal::collapse_diagonal_logged;
pub use collapse_diagonal::{can_collapse_diagonal, collapse_diagonal, CollapsePlan, Collapsed};
pub use remove_doublet::{can_remove_doublet, is_doublet, remove_doublet, remove_doublets};
pub(crate) use rotate_edge::rotate_edge_logged;
pub use rotate_edge::{can_rotate_edge, rotate_edge, rotation_energy_gain, Rotation};

use crate::mesh::{ControlMesh, FaceId, VertexId};

/// The four vertices of a quad, starting at its first half-edge.
#[inline]
pub(crate) fn quad(mesh: &ControlMesh, f: FaceId) -> [VertexId; 4] {
    let h0 = mesh.face_halfedge(f);
    let h1 = mesh.next(h0);
    let h2 = mesh.next(h1);
    let h3 = mesh.next(h2);
    [mesh.tail(h0), mesh.tail(h1), mesh.tail(h2), mesh.tail(h3)]
}

/// What the operators changed in a quad mesh since the log began, in the
/// order they changed it: enough to put the mesh back
/// ([`crate::quad::simplify`]'s undo of a refused collapse) without
/// copying the faces around the edit beforehand, which cost a BFS of
/// three rings per collapse while fewer than one collapse in a hundred is
/// undone.
#[derive(Clone, Debug, Default)]
pub(crate) struct FaceLog {
    /// Faces removed, with their corners as they were (quads: every
    /// operator removes and adds quads only).
    pub(crate) removed: Vec<(FaceId, [VertexId; 4])>,
    /// Faces added. Within one replacement the removals come first, so a
    /// face id both removed and added there was a face before it.
    pub(crate) added: Vec<FaceId>,
    /// The events in order: `true` a removal (the next of `removed`),
    /// `false` an addition (the next of `added`).
    pub(crate) order: Vec<bool>,
    /// Vertices deleted.
    pub(crate) deleted: Vec<VertexId>,
}

/// [`ControlMesh::replace_faces`] of quads, written to `log` when there is
/// one.
pub(crate) fn replace_logged(
    mesh: &mut ControlMesh,
    remove: &[FaceId],
    add: &[&[VertexId]],
    delete: &[VertexId],
    log: Option<&mut FaceLog>,
) -> crate::error::Result<Vec<FaceId>> {
    let Some(log) = log else {
        return mesh.replace_faces(remove, add, delete);
    };
    let before: Vec<(FaceId, [VertexId; 4])> = remove
        .iter()
        .filter(|&&f| f.idx() < mesh.num_faces() && !mesh.is_face_deleted(f))
        .map(|&f| (f, quad(mesh, f)))
        .collect();
    let new = mesh.replace_faces(remove, add, delete)?;
    // Written only once the replacement is made (it checks before it
    // changes anything, so a refused one leaves no trace).
    log.order.extend(std::iter::repeat(true).take(before.len()));
    log.removed.extend(before);
    log.order.extend(std::iter::repeat(false).take(new.len()));
    log.added.extend_from_slice(&new);
    log.deleted.extend_from_slice(delete);
    Ok(new)
}

/// Whether `a` and `b` are joined by an edge.
#[inline]
pub(crate) fn adjacent(mesh: &ControlMesh, a: VertexId, b: VertexId) -> bool {
    mesh.outgoing(a).any(|h| mesh.head(h) == b)
}

/// The smallest valence `v` may have and still be neither a doublet
/// (interior, 2 edges) nor dangling (boundary, 1 edge).
#[inline]
pub(crate) fn min_valence(mesh: &ControlMesh, v: VertexId) -> usize {
    if mesh.is_boundary_vertex(v) {
        2
    } else {
        3
    }
}

/// Ideal valences for the energy `Σ |D(v) − ideal(v)|` of §3.3.2 (see the
/// module documentation for the convention).
#[derive(Clone, Debug)]
pub struct ValenceTargets {
    input_corner: Vec<bool>,
}

impl ValenceTargets {
    /// Records the corners (boundary vertices with 2 edges) of `mesh`.
    pub fn new(mesh: &ControlMesh) -> Self {
        ValenceTargets {
            input_corner: mesh
                .vertices()
                .map(|v| {
                    !mesh.is_vertex_deleted(v) && mesh.is_boundary_vertex(v) && mesh.valence(v) == 2
                })
                .collect(),
        }
    }
    /// The regular valence of `v` in its current position (interior or
    /// boundary).
    pub fn ideal(&self, mesh: &ControlMesh, v: VertexId) -> usize {
        if !mesh.is_boundary_vertex(v) {
            4
        } else if self.input_corner.get(v.idx()).copied().unwrap_or(false) {
            2
        } else {
            3
        }
    }
    /// `|D(v) − ideal(v)|` for a valence `d`.
    pub fn penalty(&self, mesh: &ControlMesh, v: VertexId, d: usize) -> usize {
        d.abs_diff(self.ideal(mesh, v))
    }
    /// Whether `v` is irregular (the paper's Table 1 "regularity").
    pub fn is_irregular(&self, mesh: &ControlMesh, v: VertexId) -> bool {
        self.penalty(mesh, v, mesh.valence(v)) != 0
    }
}

/// Positions of the four corners of a quad, in [`quad`] order.
#[inline]
pub(crate) fn quad_positions(mesh: &ControlMesh, f: FaceId) -> [crate::DVec3; 4] {
    quad(mesh, f).map(|v| mesh.position(v))
}
