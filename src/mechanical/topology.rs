//! Edge structure of the input triangle mesh M shared by every stage of the
//! mechanical pipeline: undirected edges with their (up to two) triangles,
//! signed dihedral angles and the sharp-edge classification.

use std::collections::HashMap;

use crate::mesh::TriMesh;
use crate::DVec3;

/// Dihedral angle (degrees, between the two face normals) above which an
/// edge of M is a *sharp feature edge*. 30° is the acceptance bar of the
/// issue (features kept) and the usual CAD feature threshold: fillets of a
/// tessellated CAD part turn by a few degrees per edge, true creases by
/// 45°–90°.
pub const SHARP_DIHEDRAL_DEG: f64 = 30.0;

/// One undirected edge of M.
#[derive(Copy, Clone, Debug)]
pub struct Edge {
    /// Endpoints, `v[0] < v[1]`.
    pub v: [u32; 2],
    /// Incident triangles; `faces[1] == u32::MAX` on a boundary edge.
    /// Non-manifold edges (three or more triangles) keep the first two and
    /// are flagged by [`Edge::nonmanifold`].
    pub faces: [u32; 2],
    pub nonmanifold: bool,
    /// Signed angle between the face normals, radians: positive where the
    /// surface is convex (the β of Cohen-Steiner & Morvan), 0 on boundary
    /// and non-manifold edges.
    pub beta: f64,
}

impl Edge {
    pub fn is_interior(&self) -> bool {
        self.faces[1] != u32::MAX && !self.nonmanifold
    }
    pub fn other_face(&self, f: u32) -> Option<u32> {
        if !self.is_interior() {
            return None;
        }
        Some(if self.faces[0] == f {
            self.faces[1]
        } else {
            self.faces[0]
        })
    }
}

/// Edges of M, triangle → edge incidence, vertex → edge incidence.
#[derive(Clone, Debug)]
pub struct Topology {
    pub edges: Vec<Edge>,
    /// Edge ids of triangle t's sides `(v0 v1), (v1 v2), (v2 v0)`.
    pub tri_edges: Vec<[u32; 3]>,
    /// Edges incident to each vertex (CSR: `vert_edge_off[v]..[v+1]`).
    pub vert_edge_off: Vec<u32>,
    pub vert_edges: Vec<u32>,
    pub face_normals: Vec<DVec3>,
    pub face_areas: Vec<f64>,
}

impl Topology {
    pub fn new(mesh: &TriMesh) -> Topology {
        let nt = mesh.triangles.len();
        let mut map: HashMap<(u32, u32), u32> = HashMap::with_capacity(nt * 2);
        let mut edges: Vec<Edge> = Vec::with_capacity(nt * 3 / 2 + 8);
        let mut tri_edges = vec![[0u32; 3]; nt];
        for (t, tri) in mesh.triangles.iter().enumerate() {
            for k in 0..3 {
                let (a, b) = (tri[k], tri[(k + 1) % 3]);
                let key = (a.min(b), a.max(b));
                let id = *map.entry(key).or_insert_with(|| {
                    edges.push(Edge {
                        v: [key.0, key.1],
                        faces: [u32::MAX, u32::MAX],
                        nonmanifold: false,
                        beta: 0.0,
                    });
                    edges.len() as u32 - 1
                });
                let e = &mut edges[id as usize];
                if e.faces[0] == u32::MAX {
                    e.faces[0] = t as u32;
                } else if e.faces[1] == u32::MAX {
                    e.faces[1] = t as u32;
                } else {
                    e.nonmanifold = true;
                }
                tri_edges[t][k] = id;
            }
        }
        let mut face_normals = Vec::with_capacity(nt);
        let mut face_areas = Vec::with_capacity(nt);
        for t in 0..nt {
            let [a, b, c] = mesh.triangle(t);
            let n = (b - a).cross(c - a);
            face_areas.push(0.5 * n.length());
            face_normals.push(n.normalize_or_zero());
        }
        for e in edges.iter_mut() {
            if !e.is_interior() {
                continue;
            }
            let (f0, f1) = (e.faces[0] as usize, e.faces[1] as usize);
            let (n0, n1) = (face_normals[f0], face_normals[f1]);
            let angle = n0.dot(n1).clamp(-1.0, 1.0).acos();
            // Convex where f1's opposite vertex lies below f0's plane.
            let opp = mesh.triangles[f1]
                .iter()
                .copied()
                .find(|&v| v != e.v[0] && v != e.v[1])
                .unwrap_or(e.v[0]);
            let p0 = mesh.positions[e.v[0] as usize];
            let side = (mesh.positions[opp as usize] - p0).dot(n0);
            e.beta = if side > 0.0 { -angle } else { angle };
        }
        let nv = mesh.positions.len();
        let mut count = vec![0u32; nv + 1];
        for e in &edges {
            count[e.v[0] as usize + 1] += 1;
            count[e.v[1] as usize + 1] += 1;
        }
        for i in 0..nv {
            count[i + 1] += count[i];
        }
        let mut fill = count.clone();
        let mut vert_edges = vec![0u32; count[nv] as usize];
        for (i, e) in edges.iter().enumerate() {
            for &v in &e.v {
                vert_edges[fill[v as usize] as usize] = i as u32;
                fill[v as usize] += 1;
            }
        }
        Topology {
            edges,
            tri_edges,
            vert_edge_off: count,
            vert_edges,
            face_normals,
            face_areas,
        }
    }

    pub fn vertex_edges(&self, v: u32) -> &[u32] {
        let v = v as usize;
        &self.vert_edges[self.vert_edge_off[v] as usize..self.vert_edge_off[v + 1] as usize]
    }

    /// Per vertex, how many of its edges are flagged in `sharp`: 1 at the
    /// tip of a feature chain, 2 along it, more where chains branch.
    pub fn sharp_degree(&self, sharp: &[bool]) -> Vec<usize> {
        let nv = self.vert_edge_off.len().saturating_sub(1);
        (0..nv as u32)
            .map(|v| {
                self.vertex_edges(v)
                    .iter()
                    .filter(|&&e| sharp[e as usize])
                    .count()
            })
            .collect()
    }

    /// Sharp per edge: interior with |dihedral| above [`SHARP_DIHEDRAL_DEG`].
    pub fn sharp_edges(&self) -> Vec<bool> {
        let t = SHARP_DIHEDRAL_DEG.to_radians();
        self.edges
            .iter()
            .map(|e| e.is_interior() && e.beta.abs() > t)
            .collect()
    }

    /// Area-weighted vertex normals.
    pub fn vertex_normals(&self, mesh: &TriMesh) -> Vec<DVec3> {
        let mut n = vec![DVec3::ZERO; mesh.positions.len()];
        for (t, tri) in mesh.triangles.iter().enumerate() {
            for &v in tri {
                n[v as usize] += self.face_normals[t] * self.face_areas[t];
            }
        }
        n.iter().map(|x| x.normalize_or_zero()).collect()
    }
}
