//! Meshes as people have them: non-manifold vertices and edges split into
//! manifold pieces, so that a real scan (several parts, bow-tie vertices
//! where two parts touch, edges shared by three faces) is converted rather
//! than refused.
//!
//! Every later stage (the Fitmap's neighbourhoods, §3.1; the control mesh's
//! half-edges, §3.2–3.3) needs each vertex's triangles to form one fan. A
//! vertex whose triangles form several fans (joined only through *manifold*
//! edges: exactly two triangles traversing the edge in opposite directions)
//! gets one copy per fan, at the same position. An edge used by three or
//! more triangles, or by two with the same direction, joins nothing, so
//! its triangles come apart along it: it becomes boundary on each side.
//! The surface's geometry is untouched; only connectivity changes.

use std::collections::HashMap;
use std::path::Path;

use super::report::validate_soup_unwelded;
use super::{MeshReport, PolySoup, TriMesh, ValidatedMesh};
use crate::error::Result;
use crate::DVec3;

/// What [`split_non_manifold`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SplitStats {
    /// Vertices whose triangles formed more than one fan.
    pub vertices_split: usize,
    /// Copies added (one per fan beyond the first).
    pub vertices_added: usize,
}

fn find(parent: &mut [u32], mut x: u32) -> u32 {
    while parent[x as usize] != x {
        let p = parent[x as usize];
        parent[x as usize] = parent[p as usize];
        x = p;
    }
    x
}

fn union(parent: &mut [u32], a: u32, b: u32) {
    let (ra, rb) = (find(parent, a), find(parent, b));
    // The smaller root wins, so the result does not depend on the order of
    // the unions (deterministic numbering below).
    if ra != rb {
        let (lo, hi) = (ra.min(rb), ra.max(rb));
        parent[hi as usize] = lo;
    }
}

/// `mesh` with every vertex's triangles in one fan (module docs); copies
/// are appended after the original vertices in order of first use, so a
/// manifold mesh comes back unchanged.
pub fn split_non_manifold(mesh: &TriMesh) -> (TriMesh, SplitStats) {
    let corners: Vec<u32> = mesh.triangles.iter().flatten().copied().collect();
    let next = |c: u32| c - c % 3 + (c % 3 + 1) % 3;
    let split = split_corners(&mesh.positions, &corners, next);
    let triangles = split
        .corner_vertex
        .chunks_exact(3)
        .map(|t| [t[0], t[1], t[2]])
        .collect();
    (
        TriMesh {
            positions: split.positions,
            triangles,
        },
        split.stats,
    )
}

/// [`split_non_manifold`] for polygons of any size (control meshes as
/// other tools write them, issue 17): the same rule, a vertex's faces
/// joined only through manifold edges. Returns the split soup, the counts
/// and, per vertex of the result, the input vertex it copies.
pub fn split_non_manifold_polygons(soup: &PolySoup) -> (PolySoup, SplitStats, Vec<u32>) {
    let mut next = vec![0u32; soup.face_indices.len()];
    for w in soup.face_offsets.windows(2) {
        let (lo, hi) = (w[0], w[1]);
        for c in lo..hi {
            next[c as usize] = if c + 1 == hi { lo } else { c + 1 };
        }
    }
    let split = split_corners(&soup.positions, &soup.face_indices, |c| next[c as usize]);
    let n = soup.positions.len() as u32;
    let origin = (0..n).chain(split.copy_of.iter().copied()).collect();
    (
        PolySoup {
            positions: split.positions,
            face_offsets: soup.face_offsets.clone(),
            face_indices: split.corner_vertex,
        },
        split.stats,
        origin,
    )
}

/// Whether corners `a` and `b` belong to one face.
fn same_face(a: u32, b: u32, next: impl Fn(u32) -> u32) -> bool {
    let mut c = next(a);
    while c != a {
        if c == b {
            return true;
        }
        c = next(c);
    }
    false
}

/// What [`split_corners`] makes: per corner its (new) vertex, the
/// positions with the copies appended, and each copy's original.
struct CornerSplit {
    corner_vertex: Vec<u32>,
    positions: Vec<DVec3>,
    copy_of: Vec<u32>,
    stats: SplitStats,
}

/// The fan split over face corners (`corners[c]` the vertex of corner `c`,
/// `next(c)` the next corner of its face): corners of one vertex joined
/// across manifold edges (exactly two uses, opposite directions) keep one
/// vertex; each further fan gets a copy.
fn split_corners(positions: &[DVec3], corners: &[u32], next: impl Fn(u32) -> u32) -> CornerSplit {
    let nc = corners.len();
    let mut parent: Vec<u32> = (0..nc as u32).collect();
    // Undirected edge → the corners (at its first vertex in the face's
    // order) that traverse it, with their direction.
    let mut edges: HashMap<(u32, u32), Vec<(u32, bool)>> = HashMap::with_capacity(nc / 2);
    for c in 0..nc as u32 {
        let (a, b) = (corners[c as usize], corners[next(c) as usize]);
        edges
            .entry((a.min(b), a.max(b)))
            .or_default()
            .push((c, a < b));
    }
    for uses in edges.values() {
        if let [(c0, d0), (c1, d1)] = uses[..] {
            // One face running along an edge both ways (a face that visits a
            // vertex twice) is not joined to itself: OpenSubdiv gives the
            // second run its own edge (`vtr/level.cpp`,
            // `completeTopologyFromFaceVertices`), non-manifold.
            if d0 != d1 && !same_face(c0, c1, &next) {
                // c0 runs a→b, c1 runs b→a: a's corners are c0 and next(c1),
                // b's are next(c0) and c1.
                union(&mut parent, c0, next(c1));
                union(&mut parent, next(c0), c1);
            }
        }
    }
    let mut out = CornerSplit {
        corner_vertex: corners.to_vec(),
        positions: positions.to_vec(),
        copy_of: Vec::new(),
        stats: SplitStats::default(),
    };
    // Per vertex, the fan root that keeps the vertex's own index.
    let mut owner: Vec<u32> = vec![u32::MAX; positions.len()];
    let mut copy_of_root: HashMap<u32, u32> = HashMap::new();
    let mut split = vec![false; positions.len()];
    for c in 0..nc as u32 {
        let v = corners[c as usize];
        let root = find(&mut parent, c);
        let o = &mut owner[v as usize];
        if *o == u32::MAX {
            *o = root;
        } else if *o != root {
            let id = *copy_of_root.entry(root).or_insert_with(|| {
                out.positions.push(positions[v as usize]);
                out.copy_of.push(v);
                out.stats.vertices_added += 1;
                if !split[v as usize] {
                    split[v as usize] = true;
                    out.stats.vertices_split += 1;
                }
                (out.positions.len() - 1) as u32
            });
            out.corner_vertex[c as usize] = id;
        }
    }
    out
}

impl ValidatedMesh {
    /// This mesh with its non-manifold vertices and edges split
    /// ([`split_non_manifold`]), its report recomputed on the result (the
    /// file's own counts and notes kept) with a note saying what was split;
    /// a manifold mesh is returned as it is. `path` names the file in
    /// messages.
    pub fn into_manifold(self, path: &Path) -> Result<ValidatedMesh> {
        if self.report.manifold {
            return Ok(self);
        }
        let (mesh, stats) = split_non_manifold(&self.mesh);
        if stats.vertices_added == 0 {
            return Ok(self);
        }
        let old = self.report;
        let soup = PolySoup {
            positions: mesh.positions,
            face_offsets: (0..=mesh.triangles.len() as u32).map(|f| 3 * f).collect(),
            face_indices: mesh.triangles.iter().flatten().copied().collect(),
        };
        // Unwelded: the copies sit at their vertex's position on purpose.
        let ValidatedMesh { mesh, report: new } = validate_soup_unwelded(soup, path)?;
        let mut report = MeshReport {
            input_vertices: old.input_vertices,
            input_faces: old.input_faces,
            face_sizes: old.face_sizes.clone(),
            unreferenced_vertices: old.unreferenced_vertices,
            welded_vertices: old.welded_vertices,
            repeated_index_faces: old.repeated_index_faces,
            duplicate_faces: old.duplicate_faces,
            notes: old.notes.clone(),
            ..new
        };
        report.notes.push(format!(
            "split {} non-manifold vertex(es) into {} more manifold cop(ies) ({} non-manifold edge(s), {} vertex(es) on load): each fan of triangles is its own piece",
            stats.vertices_split, stats.vertices_added, old.non_manifold_edges, old.non_manifold_vertices
        ));
        Ok(ValidatedMesh { mesh, report })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::DVec3;

    fn tri_mesh(n: usize, triangles: Vec<[u32; 3]>) -> TriMesh {
        TriMesh {
            positions: (0..n)
                .map(|i| DVec3::new(i as f64, (i * i) as f64, 0.0))
                .collect(),
            triangles,
        }
    }

    #[test]
    fn a_bow_tie_vertex_gets_one_copy_per_fan() {
        // Two triangles touching at vertex 0 only.
        let m = tri_mesh(5, vec![[0, 1, 2], [0, 3, 4]]);
        let (s, st) = split_non_manifold(&m);
        assert_eq!(
            st,
            SplitStats {
                vertices_split: 1,
                vertices_added: 1
            }
        );
        assert_eq!(s.triangles, vec![[0, 1, 2], [5, 3, 4]]);
        assert_eq!(s.positions[5], m.positions[0]);
    }

    #[test]
    fn a_manifold_fan_is_left_alone() {
        // A closed umbrella of 4 triangles around vertex 0 and an open one.
        let m = tri_mesh(5, vec![[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 1]]);
        let (s, st) = split_non_manifold(&m);
        assert_eq!(st, SplitStats::default());
        assert_eq!(s.triangles, m.triangles);
    }

    #[test]
    fn an_edge_of_three_triangles_comes_apart() {
        // Edge 0–1 shared by three triangles: each becomes its own piece
        // along it (one keeps 0 and 1, the others get copies).
        let m = tri_mesh(5, vec![[0, 1, 2], [1, 0, 3], [0, 1, 4]]);
        let (s, st) = split_non_manifold(&m);
        assert_eq!(st.vertices_split, 2);
        assert_eq!(st.vertices_added, 4);
        let mut edge_use: HashMap<(u32, u32), usize> = HashMap::new();
        for t in &s.triangles {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                *edge_use.entry((a.min(b), a.max(b))).or_default() += 1;
            }
        }
        assert!(edge_use.values().all(|&n| n <= 2), "{edge_use:?}");
    }
}
