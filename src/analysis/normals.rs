//! Per-triangle areas and per-vertex normals of the input mesh.

use crate::mesh::TriMesh;
use crate::DVec3;

/// Area of every triangle (0 for degenerate ones; never NaN for finite input).
pub fn triangle_areas(mesh: &TriMesh) -> Vec<f64> {
    (0..mesh.triangles.len())
        .map(|t| {
            let [a, b, c] = mesh.triangle(t);
            let x = 0.5 * (b - a).cross(c - a).length();
            if x.is_finite() {
                x
            } else {
                0.0
            }
        })
        .collect()
}

/// Area-weighted vertex normals: the sum of the incident triangles'
/// un-normalised cross products (whose length is twice the area), then
/// normalised. Area weighting lets sliver and zero-area triangles contribute
/// nothing instead of a random direction. A vertex whose incident triangles
/// all have zero area gets the normalised sum of its neighbours' normals; if
/// that is zero too, `DVec3::ZERO` (the caller treats the vertex as
/// undefined).
pub fn vertex_normals(mesh: &TriMesh) -> Vec<DVec3> {
    let n = mesh.positions.len();
    let mut acc = vec![DVec3::ZERO; n];
    for (t, tri) in mesh.triangles.iter().enumerate() {
        let [a, b, c] = mesh.triangle(t);
        let x = (b - a).cross(c - a);
        if !x.is_finite() {
            continue;
        }
        for &v in tri {
            acc[v as usize] += x;
        }
    }
    let mut out: Vec<DVec3> = acc.iter().map(|x| x.normalize_or_zero()).collect();
    // Fallback through the 1-ring for vertices with no area around them.
    let missing: Vec<usize> = (0..n).filter(|&v| out[v] == DVec3::ZERO).collect();
    if !missing.is_empty() {
        let mut ring = vec![DVec3::ZERO; n];
        for tri in &mesh.triangles {
            for k in 0..3 {
                let (v, w) = (tri[k] as usize, tri[(k + 1) % 3] as usize);
                ring[v] += out[w];
                ring[w] += out[v];
            }
        }
        for v in missing {
            out[v] = ring[v].normalize_or_zero();
        }
    }
    out
}
