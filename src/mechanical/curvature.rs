//! Per-vertex curvature tensors of M (Lavoué et al. §3.1) with the
//! normal-cycle estimator of Cohen-Steiner and Morvan (2003):
//!
//! `T(v) = 1/|B| Σ_{e ⊂ B} β(e) |e| ē ēᵀ`
//!
//! over the edges e of a geodesic neighbourhood B of v (its
//! [`CurvatureOptions::rings`]-ring), β(e) the signed dihedral angle at e
//! (positive where convex), ē the unit edge direction and |B| the area of
//! the triangles of B. Bending around an edge means curvature *across* it,
//! so the eigenvector of the larger eigenvalue is the direction of *minimum*
//! curvature and vice versa (the paper's "switched order"). The tensor is
//! restricted to the tangent plane of the area-weighted vertex normal before
//! its 2×2 eigen-decomposition: on a flat region all three eigenvalues of
//! the 3×3 tensor vanish and the "smallest |λ|" normal would be arbitrary.
//!
//! Sharp feature edges (see [`super::topology::SHARP_DIHEDRAL_DEG`]) are
//! left out of the sum: their β is a feature, not curvature, and would make
//! every vertex near a crease look like a tight cylinder; they become region
//! boundaries anyway (§4).

use crate::mesh::TriMesh;
use crate::DVec3;

use super::topology::Topology;

/// Options of [`vertex_curvatures`].
#[derive(Clone, Debug)]
pub struct CurvatureOptions {
    /// Radius of the neighbourhood B in edge rings: 2 (a 1-ring estimate is
    /// noisy on irregular CAD tessellations, CSM03 §6).
    pub rings: usize,
    /// A vertex is isotropic (umbilic or planar, §3.1) when
    /// `|k_max − k_min| ≤ iso_relative · max(|k_max|, |k_min|)`: 0.25.
    pub iso_relative: f64,
    /// … or when both `|k| · diagonal ≤ flat_curvature`: 0.5 (a radius of
    /// twice the model's size is flat at the model's scale).
    pub flat_curvature: f64,
}

impl Default for CurvatureOptions {
    fn default() -> Self {
        CurvatureOptions {
            rings: 2,
            iso_relative: 0.25,
            flat_curvature: 0.5,
        }
    }
}

/// Principal curvatures and directions at one vertex.
#[derive(Copy, Clone, Debug, Default, PartialEq)]
pub struct VertexCurvature {
    /// `k_max ≥ k_min` (algebraic; positive convex).
    pub k_max: f64,
    pub k_min: f64,
    /// Unit tangent directions of `k_max` and `k_min`.
    pub d_max: DVec3,
    pub d_min: DVec3,
    pub normal: DVec3,
    /// Umbilic or planar: the directions carry no information.
    pub isotropic: bool,
}

/// Curvature of every vertex of `mesh` (`topo` built over it).
pub fn vertex_curvatures(
    mesh: &TriMesh,
    topo: &Topology,
    opts: &CurvatureOptions,
) -> Vec<VertexCurvature> {
    use rayon::prelude::*;
    let normals = topo.vertex_normals(mesh);
    let sharp = topo.sharp_edges();
    let diag = mesh.bbox_diagonal().max(f64::MIN_POSITIVE);
    // Vertex → triangles, for |B|.
    let nv = mesh.positions.len();
    let mut vt: Vec<Vec<u32>> = vec![Vec::new(); nv];
    for (t, tri) in mesh.triangles.iter().enumerate() {
        for &v in tri {
            vt[v as usize].push(t as u32);
        }
    }
    (0..nv)
        .into_par_iter()
        .map(|v| {
            // Vertices within `rings` edge hops.
            let mut ring: Vec<u32> = vec![v as u32];
            let mut start = 0;
            for _ in 0..opts.rings {
                let end = ring.len();
                for i in start..end {
                    for &e in topo.vertex_edges(ring[i]) {
                        let ed = &topo.edges[e as usize];
                        let w = if ed.v[0] == ring[i] { ed.v[1] } else { ed.v[0] };
                        if !ring.contains(&w) {
                            ring.push(w);
                        }
                    }
                }
                start = end;
            }
            let inner = &ring[..start.max(1)];
            let mut t = [[0.0f64; 3]; 3];
            let mut area = 0.0;
            let mut seen_t: Vec<u32> = Vec::new();
            let mut seen_e: Vec<u32> = Vec::new();
            // Triangles and edges touching a vertex strictly inside B.
            for &u in inner {
                for &tr in &vt[u as usize] {
                    if !seen_t.contains(&tr) {
                        seen_t.push(tr);
                        area += topo.face_areas[tr as usize];
                    }
                }
            }
            // Edges of B's triangles, weighted by the share of their two
            // triangles inside B: |e ∩ B| for B the union of the triangles.
            let mut half: Vec<(u32, f64)> = Vec::new();
            for &tr in &seen_t {
                for &e in &topo.tri_edges[tr as usize] {
                    match half.iter_mut().find(|x| x.0 == e) {
                        Some(x) => x.1 += 0.5,
                        None => half.push((e, 0.5)),
                    }
                }
            }
            seen_e.extend(half.iter().map(|x| x.0));
            for (&e, &(_, share)) in seen_e.iter().zip(&half) {
                let ed = &topo.edges[e as usize];
                if !ed.is_interior() || sharp[e as usize] {
                    continue;
                }
                let d = mesh.positions[ed.v[1] as usize] - mesh.positions[ed.v[0] as usize];
                let len = d.length();
                if len == 0.0 {
                    continue;
                }
                let u = d / len;
                let w = ed.beta * len * share;
                for (r, row) in t.iter_mut().enumerate() {
                    for (c, x) in row.iter_mut().enumerate() {
                        *x += w * u[r] * u[c];
                    }
                }
            }
            let n = normals[v];
            let t1 = n.any_orthonormal_vector();
            let t2 = n.cross(t1);
            let q = |a: DVec3, b: DVec3| -> f64 {
                let mut s = 0.0;
                for r in 0..3 {
                    for c in 0..3 {
                        s += a[r] * t[r][c] * b[c];
                    }
                }
                s / area.max(f64::MIN_POSITIVE)
            };
            let (a, b, c) = (q(t1, t1), q(t1, t2), q(t2, t2));
            // Symmetric 2×2 eigen-decomposition.
            let mean = 0.5 * (a + c);
            let rad = (0.25 * (a - c) * (a - c) + b * b).sqrt();
            let (l1, l2) = (mean + rad, mean - rad);
            let theta = 0.5 * (2.0 * b).atan2(a - c);
            let e1 = t1 * theta.cos() + t2 * theta.sin();
            let e2 = n.cross(e1);
            // l1's eigenvector e1 is the min-curvature direction, its value
            // the curvature across it (the max); see the module docs.
            let (k_max, k_min, d_max, d_min) = (l1, l2, e2, e1);
            let big = k_max.abs().max(k_min.abs());
            let isotropic = (k_max - k_min).abs() <= opts.iso_relative * big
                || big * diag <= opts.flat_curvature;
            VertexCurvature {
                k_max,
                k_min,
                d_max,
                d_min,
                normal: n,
                isotropic,
            }
        })
        .collect()
}
