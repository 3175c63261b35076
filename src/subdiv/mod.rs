//! Catmull-Clark limit evaluation behind one trait, two implementations:
//! [`catmark::RustEvaluator`] (pure Rust, exact) and [`osd::OsdEvaluator`]
//! (OpenSubdiv Far, the reference of every DCC tool).
//!
//! Conventions, fixed once here:
//! - Boundary interpolation "edge and corner" (USD's default): boundary
//!   edges are infinitely sharp creases, valence-2 boundary vertices corners.
//! - A surface location is `(face, sub, u, v)`. On a quad `(v0 v1 v2 v3)` in
//!   file order, `(0,0)` is at v0, `(1,0)` at v1, `(1,1)` at v2, `(0,1)` at v3
//!   and `sub` is 0. A non-quad face with n corners is split as Catmull-Clark
//!   splits it into n quads (OpenSubdiv's ptex faces), `sub = k` being the
//!   one at corner k with `(0,0)` at that corner.
//! - Derivatives are with respect to that `(u, v)`. At a control vertex the
//!   two tangents are those of the limit tangent masks (their scale is not
//!   comparable between backends); only the unit normal is.

pub mod catmark;
pub mod osd;
pub mod refine;

use serde::Serialize;

use crate::error::Result;
use crate::mesh::{ControlMesh, FaceId, VertexId};
use crate::DVec3;

/// A point on the limit surface: `(face, sub, u, v)`, see the module doc.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct SurfaceLocation {
    pub face: FaceId,
    pub sub: u16,
    pub u: f64,
    pub v: f64,
}

impl SurfaceLocation {
    pub fn quad(face: FaceId, u: f64, v: f64) -> Self {
        SurfaceLocation { face, sub: 0, u, v }
    }
}

/// Limit position with its first derivatives.
#[derive(Copy, Clone, Debug, PartialEq, Default)]
pub struct LimitPoint {
    pub position: DVec3,
    pub du: DVec3,
    pub dv: DVec3,
}

impl LimitPoint {
    /// Unit normal `du × dv`; zero where the derivatives are parallel.
    pub fn normal(&self) -> DVec3 {
        self.du.cross(self.dv).normalize_or_zero()
    }
}

/// Limit stencils: for each location, weights over control vertices for the
/// position and both derivatives (compressed rows). These are the rows of a
/// fitting matrix.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LimitStencils {
    /// `offsets[i]..offsets[i + 1]` indexes the other arrays for location i.
    pub offsets: Vec<u32>,
    pub indices: Vec<u32>,
    pub weights: Vec<f64>,
    pub du_weights: Vec<f64>,
    pub dv_weights: Vec<f64>,
}

impl LimitStencils {
    pub fn len(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    pub fn row(&self, i: usize) -> std::ops::Range<usize> {
        self.offsets[i] as usize..self.offsets[i + 1] as usize
    }
    /// Applies the stencils to control positions.
    pub fn apply(&self, positions: &[DVec3]) -> Vec<LimitPoint> {
        (0..self.len())
            .map(|i| {
                let mut p = LimitPoint::default();
                for k in self.row(i) {
                    let x = positions[self.indices[k] as usize];
                    p.position += self.weights[k] * x;
                    p.du += self.du_weights[k] * x;
                    p.dv += self.dv_weights[k] * x;
                }
                p
            })
            .collect()
    }
}

/// Options shared by both evaluators.
#[derive(Clone, Debug)]
#[non_exhaustive]
pub struct EvalOptions {
    /// OpenSubdiv's adaptive isolation level around extraordinary features.
    /// Its end-cap patches only approximate the limit near extraordinary
    /// vertices (STACK-NOTES: ~2e-4 of the size at level 6), so a reference
    /// needs a high level; 10 is OpenSubdiv's maximum.
    pub isolation_level: u8,
}

impl Default for EvalOptions {
    fn default() -> Self {
        EvalOptions {
            isolation_level: 10,
        }
    }
}

impl EvalOptions {
    pub fn with_isolation_level(mut self, level: u8) -> Self {
        self.isolation_level = level;
        self
    }
}

/// Which implementation of [`LimitEvaluator`].
#[derive(Copy, Clone, Debug, PartialEq, Eq, Serialize)]
pub enum Backend {
    /// OpenSubdiv 3.5 (Far).
    Osd,
    /// The pure-Rust exact evaluator.
    Rust,
}

/// Catmull-Clark limit evaluation prepared for one control-mesh topology
/// (connectivity and sharpness); positions are given per call, so a fitting
/// loop moves the control points without re-preparing.
pub trait LimitEvaluator: Send + Sync {
    fn name(&self) -> &'static str;
    fn num_control_vertices(&self) -> usize;
    /// Limit position, tangents and normal at every control vertex, in order.
    fn vertex_limits(&self, positions: &[DVec3]) -> Result<Vec<LimitPoint>>;
    /// Limit position and derivatives at each location.
    fn evaluate(
        &self,
        positions: &[DVec3],
        locations: &[SurfaceLocation],
    ) -> Result<Vec<LimitPoint>>;
    /// Limit stencils (weights over control vertices) at each location.
    fn stencils(&self, locations: &[SurfaceLocation]) -> Result<LimitStencils>;
}

/// Prepares the chosen evaluator for `mesh`.
pub fn make_evaluator(
    backend: Backend,
    mesh: &ControlMesh,
    options: &EvalOptions,
) -> Result<Box<dyn LimitEvaluator>> {
    Ok(match backend {
        Backend::Osd => Box::new(osd::OsdEvaluator::new(mesh, options)?),
        Backend::Rust => Box::new(catmark::RustEvaluator::new(mesh, options)?),
    })
}

/// A place where OpenSubdiv departs from the exact limit on purpose.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct KnownDifference {
    pub vertex: u32,
    pub reason: &'static str,
}

/// Known, deliberate differences between OpenSubdiv and the exact limit:
/// interior valence-2 vertices get OpenSubdiv's corner limit mask
/// (`sdc/catmarkScheme.h`, `assignSmoothLimitMask`), i.e. stay where they
/// are, while the subdivision process converges to the general mask with
/// n = 2 (STACK-NOTES). Smooth, non-sharp vertices only: a sharp one uses
/// the crease/corner rule in both.
///
/// Darts (an interior vertex with exactly one infinitely sharp incident
/// edge and no corner sharpness): Sdc applies the smooth limit masks, which
/// are not eigenvectors of the dart's subdivision matrix (the sharp edge's
/// midpoint rule changes it); the exact limit differs by ~5e-3 of the size
/// on `fixtures::creased_cube`, and so does the normal. (A semi-sharp single
/// edge is not a dart in the limit: it runs out, both agree.)
pub fn known_differences(mesh: &ControlMesh) -> Vec<KnownDifference> {
    mesh.vertices()
        .filter_map(|v: VertexId| {
            if mesh.is_boundary_vertex(v) || mesh.vertex_sharpness(v) != 0.0 {
                return None;
            }
            let sharp: Vec<f64> = mesh
                .outgoing(v)
                .map(|h| mesh.edge_sharpness(h.edge()))
                .filter(|&s| s > 0.0)
                .collect();
            if sharp.is_empty() && mesh.valence(v) == 2 {
                Some(KnownDifference {
                    vertex: v.0,
                    reason: "interior valence-2 vertex: OpenSubdiv uses the corner limit mask, the exact limit differs",
                })
            } else if sharp.len() == 1 && sharp[0] >= crate::mesh::INFINITELY_SHARP {
                Some(KnownDifference {
                    vertex: v.0,
                    reason: "dart: OpenSubdiv uses the smooth limit masks, the exact limit differs",
                })
            } else {
                None
            }
        })
        .collect()
}
