//! Exact bilinear-scheme limit evaluation (`Sdc::SCHEME_BILINEAR`), pure
//! Rust. Bilinear subdivision puts face points at centroids, edge points at
//! midpoints and keeps vertices, so after the first level (which splits an
//! n-gon into n quads, the ptex sub-faces of [`crate::subdiv`]) every quad
//! converges to the bilinear patch of its four corners: the limit is that
//! patch, in closed form. Sharpness, boundary interpolation, creasing and
//! the triangle rule change nothing (Sdc's bilinear masks ignore them).
//!
//! Vertex limits: the vertex itself (`Scheme<SCHEME_BILINEAR>`'s limit
//! mask). Its tangents are ambiguous on a polyhedral surface; like Sdc
//! (which takes "the incident edges of the first face") they are the two
//! edges of one incident face at the vertex, and no normal is defined there.

use crate::error::Result;
use crate::mesh::{ControlMesh, VertexId};
use crate::subdiv::{
    check_locations, check_not_holes, checked_holes, EvalOptions, LimitEvaluator, LimitPoint,
    LimitStencils, SurfaceLocation,
};
use crate::DVec3;

/// Bilinear limit evaluator; see the module doc.
pub struct BilinearEvaluator {
    mesh: ControlMesh,
    face_sizes: Vec<u32>,
    holes: Vec<bool>,
    /// `(vertex, next, prev)` of one face corner at each vertex.
    corner: Vec<(u32, u32, u32)>,
}

/// Weights of the four corners of the patch at `(u, v)` and of its
/// derivatives: corner order `(0,0) (1,0) (1,1) (0,1)`.
fn bilinear_weights(u: f64, v: f64) -> [[f64; 4]; 3] {
    [
        [(1.0 - u) * (1.0 - v), u * (1.0 - v), u * v, (1.0 - u) * v],
        [-(1.0 - v), 1.0 - v, v, -v],
        [-(1.0 - u), -u, u, 1.0 - u],
    ]
}

impl BilinearEvaluator {
    pub fn new(mesh: &ControlMesh, options: &EvalOptions) -> Result<Self> {
        mesh.validate()?;
        let holes = checked_holes(mesh, &options.scheme)?;
        let corner = mesh
            .vertices()
            .map(|v: VertexId| {
                let h = mesh
                    .outgoing(v)
                    .find(|&h| mesh.face_of(h).is_some())
                    .expect("validated meshes have no isolated vertices");
                (v.0, mesh.head(h).0, mesh.tail(mesh.prev(h)).0)
            })
            .collect();
        Ok(BilinearEvaluator {
            face_sizes: mesh.face_sizes(),
            mesh: mesh.clone(),
            holes,
            corner,
        })
    }

    /// The four corners of the (sub-)quad of `l` as weights over control
    /// vertices: a quad's own corners, or for sub-face k of an n-gon
    /// `(v_k, mid(k, k+1), centroid, mid(k-1, k))`.
    fn corners(&self, l: &SurfaceLocation) -> [Vec<(u32, f64)>; 4] {
        let fv: Vec<u32> = self.mesh.face_vertices(l.face).map(|v| v.0).collect();
        let n = fv.len();
        if n == 4 {
            return [0, 1, 2, 3].map(|k| vec![(fv[k], 1.0)]);
        }
        let k = l.sub as usize;
        let (prev, next) = (fv[(k + n - 1) % n], fv[(k + 1) % n]);
        let centroid = fv.iter().map(|&i| (i, 1.0 / n as f64)).collect();
        [
            vec![(fv[k], 1.0)],
            vec![(fv[k], 0.5), (next, 0.5)],
            centroid,
            vec![(prev, 0.5), (fv[k], 0.5)],
        ]
    }

    /// Sparse rows (index, [position, d/du, d/dv] weights) at `l`.
    fn row(&self, l: &SurfaceLocation) -> Vec<(u32, [f64; 3])> {
        let w = bilinear_weights(l.u, l.v);
        let mut row: Vec<(u32, [f64; 3])> = Vec::new();
        for (c, terms) in self.corners(l).iter().enumerate() {
            for &(i, t) in terms {
                let x = [w[0][c] * t, w[1][c] * t, w[2][c] * t];
                match row.iter_mut().find(|r| r.0 == i) {
                    Some(r) => (0..3).for_each(|k| r.1[k] += x[k]),
                    None => row.push((i, x)),
                }
            }
        }
        row.sort_by_key(|r| r.0);
        row
    }
}

impl LimitEvaluator for BilinearEvaluator {
    fn name(&self) -> &'static str {
        "rust-bilinear"
    }
    fn num_control_vertices(&self) -> usize {
        self.mesh.num_vertices()
    }
    fn vertex_limits(&self, positions: &[DVec3]) -> Result<Vec<LimitPoint>> {
        crate::subdiv::check_positions(self.mesh.num_vertices(), positions)?;
        Ok(self
            .corner
            .iter()
            .map(|&(v, next, prev)| {
                let p = positions[v as usize];
                LimitPoint {
                    position: p,
                    du: positions[next as usize] - p,
                    dv: positions[prev as usize] - p,
                }
            })
            .collect())
    }
    fn evaluate(
        &self,
        positions: &[DVec3],
        locations: &[SurfaceLocation],
    ) -> Result<Vec<LimitPoint>> {
        crate::subdiv::check_positions(self.mesh.num_vertices(), positions)?;
        check_locations(&self.face_sizes, locations)?;
        check_not_holes(&self.holes, locations)?;
        Ok(locations
            .iter()
            .map(|l| LimitPoint::from_row(self.row(l), positions))
            .collect())
    }
    fn stencils(&self, locations: &[SurfaceLocation]) -> Result<LimitStencils> {
        check_locations(&self.face_sizes, locations)?;
        check_not_holes(&self.holes, locations)?;
        Ok(LimitStencils::from_rows(
            locations.iter().map(|l| self.row(l)),
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The weights are a partition of unity and their derivatives sum to 0.
    #[test]
    fn weights_are_affine() {
        for (u, v) in [(0.0, 0.0), (0.3, 0.8), (1.0, 0.25)] {
            let w = bilinear_weights(u, v);
            assert!((w[0].iter().sum::<f64>() - 1.0).abs() < 1e-15);
            assert!(w[1].iter().sum::<f64>().abs() < 1e-15);
            assert!(w[2].iter().sum::<f64>().abs() < 1e-15);
        }
    }
}
