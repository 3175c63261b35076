//! Control meshes as other tools write them (issue 17, "fit any layout"):
//! Instant Meshes leaves unreferenced vertices and quad-dominant faces
//! (triangles, pentagons), remeshers put two fans on one vertex where
//! sheets touch, hand edits repeat a corner. `subdfit fit` takes such a
//! layout as it is, repaired the least that makes it a manifold control
//! mesh, and says what it changed; the surface's geometry is untouched.
//!
//! 1. In each face, a corner that repeats the previous one (cyclically) is
//!    dropped; a face left with fewer than three corners, or that still
//!    visits a vertex twice (a face folded through a vertex), is dropped.
//! 2. Vertices no face uses are dropped (the rest keep their order).
//! 3. Non-manifold vertices and edges are split as on input meshes
//!    ([`super::split_non_manifold_polygons`]: one copy per fan; an edge
//!    of three or more faces comes apart).
//! 4. Creases and corners go to every copy of their vertices (a crease to
//!    every copy of its edge).

use std::collections::HashMap;

use super::{split_non_manifold_polygons, ControlMesh, PolySoup, SplitStats, VertexId};
use crate::error::Result;
use crate::DVec3;

/// What [`control_from_foreign_soup`] changed.
#[derive(Clone, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct ForeignRepairs {
    /// Corners dropped because they repeated the previous corner.
    pub repeated_corners: usize,
    /// Faces dropped (fewer than three distinct corners, or folded).
    pub degenerate_faces: usize,
    pub unreferenced_vertices: usize,
    pub vertices_split: usize,
    pub vertices_added: usize,
}

impl ForeignRepairs {
    /// One sentence per kind of change, for reports and warnings.
    pub fn notes(&self) -> Vec<String> {
        let mut n = Vec::new();
        if self.repeated_corners > 0 {
            n.push(format!(
                "dropped {} repeated corner(s) (a face listing the same vertex twice in a row)",
                self.repeated_corners
            ));
        }
        if self.degenerate_faces > 0 {
            n.push(format!(
                "dropped {} degenerate face(s) (fewer than 3 distinct corners, or a vertex visited twice)",
                self.degenerate_faces
            ));
        }
        if self.unreferenced_vertices > 0 {
            n.push(format!(
                "dropped {} vertex(es) used by no face",
                self.unreferenced_vertices
            ));
        }
        if self.vertices_split > 0 {
            n.push(format!(
                "split {} non-manifold vertex(es) into {} more manifold cop(ies): each fan of faces is its own piece",
                self.vertices_split, self.vertices_added
            ));
        }
        n
    }
}

/// The control mesh of `soup` (with `creases` `(a, b, sharpness)` and
/// `corners` `(v, sharpness)` on its vertex ids) after the repairs of the
/// module docs, and what they changed. A mesh that needs none comes back
/// as [`ControlMesh::from_soup`] builds it.
pub fn control_from_foreign_soup(
    soup: &PolySoup,
    creases: &[(u32, u32, f64)],
    corners: &[(u32, f64)],
) -> Result<(ControlMesh, ForeignRepairs)> {
    let mut r = ForeignRepairs::default();
    // 1. Faces.
    let mut faces: Vec<Vec<u32>> = Vec::with_capacity(soup.num_faces());
    for f in soup.faces() {
        let mut g: Vec<u32> = Vec::with_capacity(f.len());
        for &v in f {
            if g.last() == Some(&v) {
                r.repeated_corners += 1;
            } else {
                g.push(v);
            }
        }
        while g.len() > 1 && g.first() == g.last() {
            g.pop();
            r.repeated_corners += 1;
        }
        let mut sorted = g.clone();
        sorted.sort_unstable();
        sorted.dedup();
        if g.len() < 3 || sorted.len() != g.len() {
            r.degenerate_faces += 1;
            continue;
        }
        faces.push(g);
    }
    let copy = manifold_copy(&soup.positions, &faces, creases, corners)?;
    r.unreferenced_vertices = copy.unreferenced_vertices;
    (r.vertices_split, r.vertices_added) = (copy.stats.vertices_split, copy.stats.vertices_added);
    let mesh = copy.mesh;
    Ok((mesh, r))
}

/// A manifold control mesh made from polygons by steps 2–4 of the module
/// docs, with the way back to the input's vertices.
pub(crate) struct ManifoldCopy {
    pub mesh: ControlMesh,
    /// Per vertex of `mesh`: the input vertex it is (a copy of).
    pub origin: Vec<u32>,
    pub unreferenced_vertices: usize,
    pub stats: SplitStats,
}

/// Steps 2–4 of the module docs on `faces` (each with three or more
/// distinct corners, indices into `positions`): unreferenced vertices
/// dropped, fans split, creases `(a, b, s)` and corners `(v, s)` (on input
/// vertex ids) given to every copy. Face ids and each face's corner order
/// are kept. Shared by `subdfit fit`'s repairs and by
/// [`super::SplitControl`], OpenSubdiv's non-manifold input for the Rust
/// evaluators.
pub(crate) fn manifold_copy(
    positions: &[DVec3],
    faces: &[Vec<u32>],
    creases: &[(u32, u32, f64)],
    corners: &[(u32, f64)],
) -> Result<ManifoldCopy> {
    // 2. Unreferenced vertices.
    let n = positions.len();
    let mut new_id = vec![u32::MAX; n];
    for f in faces {
        for &v in f {
            new_id[v as usize] = 0;
        }
    }
    let mut kept = Vec::with_capacity(n);
    let mut kept_of = Vec::with_capacity(n);
    for (v, id) in new_id.iter_mut().enumerate() {
        if *id == 0 {
            *id = kept.len() as u32;
            kept.push(positions[v]);
            kept_of.push(v as u32);
        }
    }
    let unreferenced_vertices = n - kept.len();
    let mut compact = PolySoup {
        positions: kept,
        face_offsets: vec![0],
        face_indices: Vec::new(),
    };
    for f in faces {
        compact
            .face_indices
            .extend(f.iter().map(|&v| new_id[v as usize]));
        compact.face_offsets.push(compact.face_indices.len() as u32);
    }
    // 3. Fans.
    let (split, stats, split_origin) = split_non_manifold_polygons(&compact);
    let mut mesh = ControlMesh::from_soup(&split)?;
    // 4. Sharpness on every copy: input vertex → its vertices in `mesh`.
    let origin: Vec<u32> = split_origin.iter().map(|&c| kept_of[c as usize]).collect();
    let mut copies: HashMap<u32, Vec<u32>> = HashMap::new();
    for (v, &o) in origin.iter().enumerate() {
        copies.entry(o).or_default().push(v as u32);
    }
    let of = |v: u32| -> &[u32] { copies.get(&v).map_or(&[], |c| c.as_slice()) };
    // (A crease whose edge was only in dropped faces has nothing to
    // crease.)
    for &(a, b, s) in creases {
        for &x in of(a) {
            for &y in of(b) {
                if mesh.find_halfedge(VertexId(x), VertexId(y)).is_some() {
                    mesh.set_crease(VertexId(x), VertexId(y), s)?;
                }
            }
        }
    }
    for &(v, s) in corners {
        for &x in of(v) {
            mesh.set_corner(VertexId(x), s)?;
        }
    }
    Ok(ManifoldCopy {
        mesh,
        origin,
        unreferenced_vertices,
        stats,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::DVec3;

    fn soup(n: usize, faces: &[&[u32]]) -> PolySoup {
        let mut s = PolySoup {
            positions: (0..n)
                .map(|i| DVec3::new(i as f64, (i * i % 7) as f64, (i % 3) as f64))
                .collect(),
            face_offsets: vec![0],
            face_indices: Vec::new(),
        };
        for f in faces {
            s.face_indices.extend_from_slice(f);
            s.face_offsets.push(s.face_indices.len() as u32);
        }
        s
    }

    #[test]
    fn instant_meshes_style_layouts_are_repaired_and_reported() {
        // Two quads sharing edge 1–2, a triangle and a pentagon touching
        // the first quad at vertex 0 only (two fans), vertex 9 unused, a
        // repeated corner, and a face collapsed to two corners.
        let s = soup(
            13,
            &[
                &[0, 1, 2, 3],
                &[1, 4, 5, 2, 2],
                &[0, 6, 7],
                &[0, 8, 10, 11, 12],
                &[3, 3, 0],
            ],
        );
        let (m, r) = control_from_foreign_soup(&s, &[(1, 2, 2.0)], &[(0, 1.0)]).unwrap();
        assert_eq!(r.repeated_corners, 2);
        assert_eq!(r.degenerate_faces, 1);
        assert_eq!(r.unreferenced_vertices, 1);
        // Vertex 0's faces: the first quad, the triangle, the pentagon:
        // three fans, two copies.
        assert_eq!((r.vertices_split, r.vertices_added), (1, 2));
        assert_eq!(m.num_faces(), 4);
        assert_eq!(m.num_vertices(), 12 + 2);
        // The crease on 1–2 survives, the corner on all three copies of 0.
        assert_eq!(m.creases().len(), 1);
        assert_eq!(m.corners().len(), 3);
        assert_eq!(r.notes().len(), 4);
    }

    #[test]
    fn a_clean_mesh_is_left_as_it_is() {
        let s = soup(6, &[&[0, 1, 2, 3], &[1, 4, 5, 2]]);
        let (m, r) = control_from_foreign_soup(&s, &[], &[]).unwrap();
        assert_eq!(r, ForeignRepairs::default());
        assert!(r.notes().is_empty());
        let plain = ControlMesh::from_soup(&s).unwrap();
        assert_eq!(m.positions(), plain.positions());
        assert_eq!(m.num_faces(), plain.num_faces());
    }
}
