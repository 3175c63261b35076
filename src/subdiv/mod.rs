//! Subdivision limit evaluation behind one trait, two implementations:
//! pure Rust and exact ([`catmark::RustEvaluator`] for Catmull-Clark,
//! [`loop_scheme::LoopEvaluator`] for Loop, [`bilinear::BilinearEvaluator`])
//! and [`osd::OsdEvaluator`] (OpenSubdiv Far, the reference of every DCC
//! tool).
//!
//! Conventions, fixed once here:
//! - The subdivision rules are OpenSubdiv's `Sdc::Options` of
//!   [`EvalOptions::scheme`] ([`SchemeOptions`]), honoured by both
//!   evaluators: boundary interpolation (default "edge and corner", USD's:
//!   boundary edges are infinitely sharp creases, valence-2 boundary
//!   vertices corners), creasing method, triangle rule, holes (faces
//!   without limit surface; evaluating there is an error). Sharpness is
//!   OpenSubdiv's 32-bit float (see `catmark::topo`).
//! - A surface location is `(face, sub, u, v)`. On a quad `(v0 v1 v2 v3)` in
//!   file order, `(0,0)` is at v0, `(1,0)` at v1, `(1,1)` at v2, `(0,1)` at v3
//!   and `sub` is 0. A non-quad face with n corners is split as Catmull-Clark
//!   splits it into n quads (OpenSubdiv's ptex faces), `sub = k` being the
//!   one at corner k with `(0,0)` at that corner.
//! - Loop scheme (all-triangle meshes): a triangle `(v0 v1 v2)` is one
//!   ptex face (`sub` 0) with `(0,0)` at v0, `(1,0)` at v1, `(0,1)` at v2
//!   and `u + v <= 1` (OpenSubdiv's triangular ptex convention).
//! - Derivatives are with respect to that `(u, v)`. At a control vertex the
//!   two tangents are those of the limit tangent masks (their scale is not
//!   comparable between backends); only the unit normal is.

pub mod bilinear;
pub mod catmark;
pub mod diff;
pub mod fvar;
pub mod loop_scheme;
pub mod nonmanifold;
pub mod osd;
pub mod quadtri;
pub mod refine;

pub use nonmanifold::{
    file_vertex_limits, make_split_evaluator, make_split_fvar_evaluator, rust_split_fvar_evaluator,
    split_fvar_sharpened, split_known_differences,
};
pub use quadtri::{QuadTriEvaluator, QuadTriRefiner};

use serde::Serialize;

use crate::error::{Error, Result};
pub use crate::mesh::{
    BoundaryInterpolation, CreaseMethod, FVarLinear, SchemeOptions, SubdivScheme,
    TriangleSubdivision,
};
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

    /// The point of one weight row over `points`: `Σ w · x` for the
    /// position, `du` and `dv` weights `w` of each `(index, w)`.
    pub(crate) fn from_row(
        row: impl IntoIterator<Item = (u32, [f64; 3])>,
        points: &[DVec3],
    ) -> Self {
        let mut p = LimitPoint::default();
        for (i, w) in row {
            let x = points[i as usize];
            p.position += w[0] * x;
            p.du += w[1] * x;
            p.dv += w[2] * x;
        }
        p
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
    /// The stencils of one weight row (`(index, [w, w_u, w_v])`) per
    /// location.
    pub(crate) fn from_rows<R: IntoIterator<Item = (u32, [f64; 3])>>(
        rows: impl IntoIterator<Item = R>,
    ) -> Self {
        let mut st = LimitStencils {
            offsets: vec![0],
            ..Default::default()
        };
        for row in rows {
            for (i, w) in row {
                st.indices.push(i);
                st.weights.push(w[0]);
                st.du_weights.push(w[1]);
                st.dv_weights.push(w[2]);
            }
            st.offsets.push(st.indices.len() as u32);
        }
        st
    }

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
    /// The subdivision rules (Sdc options) and holes; both evaluators
    /// honour every one of them.
    pub scheme: SchemeOptions,
    /// Test hook: adds `.1` to the weight of vertex `.0` in its own limit
    /// position mask in the Rust evaluator — a deliberately broken mask, so
    /// tests can check that `diff-limit` catches a real defect.
    #[doc(hidden)]
    pub broken_mask: Option<(u32, f64)>,
    /// Rust evaluator only: follow the sharpness as written (f64) instead
    /// of OpenSubdiv's f32 rounding — to measure what that rounding does
    /// (`diff::f32_sharpness_effect`); it then departs from OpenSubdiv.
    pub exact_sharpness: bool,
}

impl Default for EvalOptions {
    fn default() -> Self {
        EvalOptions {
            isolation_level: 10,
            scheme: SchemeOptions::default(),
            broken_mask: None,
            exact_sharpness: false,
        }
    }
}

impl EvalOptions {
    pub fn with_isolation_level(mut self, level: u8) -> Self {
        self.isolation_level = level;
        self
    }
    pub fn with_scheme(mut self, scheme: SchemeOptions) -> Self {
        self.scheme = scheme;
        self
    }
    pub fn with_exact_sharpness(mut self, exact: bool) -> Self {
        self.exact_sharpness = exact;
        self
    }
    #[doc(hidden)]
    pub fn with_broken_mask(mut self, vertex: u32, delta: f64) -> Self {
        self.broken_mask = Some((vertex, delta));
        self
    }
}

/// Checks the scheme options against `mesh` (hole faces in range) and
/// returns its per-face hole flags ([`SchemeOptions::effective_holes`]).
pub fn checked_holes(mesh: &ControlMesh, scheme: &SchemeOptions) -> Result<Vec<bool>> {
    if let Some(f) = scheme.holes.iter().find(|f| f.idx() >= mesh.num_faces()) {
        return Err(Error::InvalidArgument(format!(
            "hole face {} out of range (the mesh has {} faces)",
            f.0,
            mesh.num_faces()
        )));
    }
    Ok(scheme.effective_holes(mesh))
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

/// Prepares the chosen evaluator for `mesh`. Its inputs are checked before
/// they reach either implementation, so both report bad positions and
/// locations with the same message.
pub fn make_evaluator(
    backend: Backend,
    mesh: &ControlMesh,
    options: &EvalOptions,
) -> Result<Box<dyn LimitEvaluator>> {
    let face_sizes = mesh.face_sizes();
    let holes = checked_holes(mesh, &options.scheme)?;
    let scheme = options.scheme.scheme;
    if scheme == SubdivScheme::Loop {
        crate::mesh::check_loop_triangles(mesh)?;
    }
    Ok(match backend {
        Backend::Osd => Box::new(Checked {
            inner: osd::OsdEvaluator::new(mesh, options)?,
            face_sizes,
            holes,
            scheme,
        }),
        Backend::Rust if scheme == SubdivScheme::Bilinear => Box::new(Checked {
            inner: bilinear::BilinearEvaluator::new(mesh, options)?,
            face_sizes,
            holes,
            scheme,
        }),
        Backend::Rust if scheme == SubdivScheme::Loop => Box::new(Checked {
            inner: loop_scheme::LoopEvaluator::new(mesh, options)?,
            face_sizes,
            holes,
            scheme,
        }),
        Backend::Rust => Box::new(Checked {
            inner: catmark::RustEvaluator::new(mesh, options)?,
            face_sizes,
            holes,
            scheme,
        }),
    })
}

/// Fails on the first location on a face without limit surface.
pub fn check_not_holes(holes: &[bool], locations: &[SurfaceLocation]) -> Result<()> {
    match locations
        .iter()
        .position(|l| holes.get(l.face.idx()).copied().unwrap_or(false))
    {
        Some(i) => Err(Error::InvalidArgument(format!(
            "location {i}: face {} is a hole (tagged `hole`, or a boundary face under \
             boundary interpolation \"none\"): it has no limit surface",
            locations[i].face.0
        ))),
        None => Ok(()),
    }
}

/// Checks `locations` against a mesh with these face sizes: face in range,
/// `sub` a corner of a non-quad face (0 on quads), `u`, `v` in `[0, 1]`.
pub fn check_locations(face_sizes: &[u32], locations: &[SurfaceLocation]) -> Result<()> {
    check_locations_for(SubdivScheme::Catmark, face_sizes, locations)
}

/// [`check_locations`] under `scheme`: with Loop every face is one
/// triangular ptex face (`sub` 0, `u + v <= 1`), see the module doc.
pub fn check_locations_for(
    scheme: SubdivScheme,
    face_sizes: &[u32],
    locations: &[SurfaceLocation],
) -> Result<()> {
    if scheme == SubdivScheme::Loop {
        return check_triangle_locations(face_sizes, locations);
    }
    for (i, l) in locations.iter().enumerate() {
        let bad = |msg: String| Err(Error::InvalidArgument(format!("location {i}: {msg}")));
        let Some(&n) = face_sizes.get(l.face.idx()) else {
            return bad(format!(
                "face {} out of range (the mesh has {} faces)",
                l.face.0,
                face_sizes.len()
            ));
        };
        let subs = if n == 4 { 1 } else { n };
        if u32::from(l.sub) >= subs {
            return bad(format!(
                "sub-face {} out of range for face {} with {n} corners",
                l.sub, l.face.0
            ));
        }
        if !((0.0..=1.0).contains(&l.u) && (0.0..=1.0).contains(&l.v)) {
            return bad(format!(
                "(u, v) = ({}, {}) outside [0, 1]² on face {}",
                l.u, l.v, l.face.0
            ));
        }
    }
    Ok(())
}

fn check_triangle_locations(face_sizes: &[u32], locations: &[SurfaceLocation]) -> Result<()> {
    for (i, l) in locations.iter().enumerate() {
        let bad = |msg: String| Err(Error::InvalidArgument(format!("location {i}: {msg}")));
        if l.face.idx() >= face_sizes.len() {
            return bad(format!(
                "face {} out of range (the mesh has {} faces)",
                l.face.0,
                face_sizes.len()
            ));
        }
        if l.sub != 0 {
            return bad(format!(
                "sub-face {} out of range: a Loop triangle is one ptex face (sub 0)",
                l.sub
            ));
        }
        let inside = l.u >= 0.0 && l.v >= 0.0 && l.u + l.v <= 1.0;
        if !inside {
            return bad(format!(
                "(u, v) = ({}, {}) outside the triangle u, v >= 0, u + v <= 1 of face {}",
                l.u, l.v, l.face.0
            ));
        }
    }
    Ok(())
}

pub(crate) fn check_positions(n: usize, positions: &[DVec3]) -> Result<()> {
    if positions.len() != n {
        return Err(Error::InvalidArgument(format!(
            "expected {n} control positions, got {}",
            positions.len()
        )));
    }
    if let Some(i) = positions.iter().position(|p| !p.is_finite()) {
        return Err(Error::InvalidArgument(format!(
            "control vertex {i}: non-finite position"
        )));
    }
    Ok(())
}

/// Input checks in front of an implementation.
struct Checked<E> {
    inner: E,
    face_sizes: Vec<u32>,
    holes: Vec<bool>,
    scheme: SubdivScheme,
}

impl<E: LimitEvaluator> LimitEvaluator for Checked<E> {
    fn name(&self) -> &'static str {
        self.inner.name()
    }
    fn num_control_vertices(&self) -> usize {
        self.inner.num_control_vertices()
    }
    fn vertex_limits(&self, positions: &[DVec3]) -> Result<Vec<LimitPoint>> {
        check_positions(self.num_control_vertices(), positions)?;
        self.inner.vertex_limits(positions)
    }
    fn evaluate(
        &self,
        positions: &[DVec3],
        locations: &[SurfaceLocation],
    ) -> Result<Vec<LimitPoint>> {
        check_positions(self.num_control_vertices(), positions)?;
        check_locations_for(self.scheme, &self.face_sizes, locations)?;
        check_not_holes(&self.holes, locations)?;
        self.inner.evaluate(positions, locations)
    }
    fn stencils(&self, locations: &[SurfaceLocation]) -> Result<LimitStencils> {
        check_locations_for(self.scheme, &self.face_sizes, locations)?;
        check_not_holes(&self.holes, locations)?;
        self.inner.stencils(locations)
    }
}

/// A place where OpenSubdiv departs from the exact limit on purpose.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct KnownDifference {
    pub vertex: u32,
    /// Only the normal differs; the limit positions agree.
    pub normal_only: bool,
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
    known_differences_with(mesh, &SchemeOptions::default())
}

/// [`known_differences`] under `scheme`: vertices whose faces are all holes
/// have no surface and are left out. Loop: the darts (Sdc's Loop scheme
/// also gives them the smooth masks; the exact limit, checked against
/// brute-force refinement, is 1e-3 of the size away on the test meshes),
/// and the boundary tangent at boundary vertices without three faces.
pub fn known_differences_with(mesh: &ControlMesh, scheme: &SchemeOptions) -> Vec<KnownDifference> {
    use crate::mesh::INFINITELY_SHARP;
    if scheme.scheme == SubdivScheme::Bilinear {
        return Vec::new(); // both evaluators use the exact bilinear masks
    }
    let holes = scheme.effective_holes(mesh);
    mesh.vertices()
        .filter(|&v| mesh.vertex_faces(v).any(|f| !holes[f.idx()]))
        .filter_map(|v: VertexId| {
            if mesh.is_boundary_vertex(v) {
                // OpenSubdiv's limit tangent mask across the boundary is not
                // the tangent plane of its own limit surface at a smooth
                // boundary vertex of irregular valence.
                // - Catmark (edge-and-corner: one face is a corner, two are
                //   regular): with more faces its patches at the corner and
                //   the exact evaluator agree to 1e-7 rad, its `Limit()`
                //   normal is 2.8e-4 rad away on `fixtures::open_fan3`.
                // - Loop: exact at regular boundary vertices (three faces;
                //   both agree to round-off on `tests/loop_differential.rs`'s
                //   open grid); on OpenSubdiv's loop_xord_boundary a vertex
                //   of four faces gets a `Limit()` normal 0.197 rad away from
                //   the normal both evaluators' surfaces converge to there.
                let faces = mesh.vertex_faces(v).count();
                let smooth = mesh.vertex_sharpness(v) == 0.0
                    && mesh
                        .outgoing(v)
                        .all(|h| mesh.is_boundary_edge(h.edge()) || mesh.edge_sharpness(h.edge()) == 0.0);
                let (irregular, reason) = if scheme.scheme == SubdivScheme::Loop {
                    let corner = faces == 1 && scheme.boundary == BoundaryInterpolation::EdgeAndCorner;
                    (
                        faces != 3 && !corner,
                        "Loop boundary vertex without three faces: OpenSubdiv's limit tangent mask \
                         across the boundary departs from its own limit surface's normal",
                    )
                } else {
                    (
                        faces > 2,
                        "boundary vertex with more than two faces: OpenSubdiv's limit tangent mask \
                         across the boundary departs from its own limit surface's normal",
                    )
                };
                return (irregular && smooth).then_some(KnownDifference {
                    vertex: v.0,
                    normal_only: true,
                    reason,
                });
            }
            if mesh.vertex_sharpness(v) >= INFINITELY_SHARP {
                return None;
            }
            let sharp: Vec<f64> = mesh
                .outgoing(v)
                .map(|h| mesh.edge_sharpness(h.edge()))
                .filter(|&s| s > 0.0)
                .collect();
            let infinite = sharp.iter().filter(|&&s| s >= INFINITELY_SHARP).count();
            let reason = if sharp.is_empty() && mesh.vertex_sharpness(v) == 0.0 && mesh.valence(v) == 2 {
                "interior valence-2 vertex: OpenSubdiv uses the corner limit mask, the exact limit differs"
            } else if infinite == 0 && mesh.valence(v) == 2 {
                // (Where the features outlast level 1 OpenSubdiv evaluates
                // the vertex on its patches instead: `diff` reports that.)
                "interior valence-2 vertex once its semi-sharp features run out: OpenSubdiv uses the corner limit mask, the exact limit differs"
            } else if infinite == 1 && sharp.len() == 1 && mesh.vertex_sharpness(v) == 0.0 {
                "dart: OpenSubdiv uses the smooth limit masks, the exact limit differs"
            } else if infinite == 1 {
                // Semi-sharp edges and corner sharpness run out after a few
                // levels, leaving a dart: same story one level down.
                "becomes a dart once its semi-sharp features run out: OpenSubdiv then uses the smooth limit masks, the exact limit differs"
            } else {
                return None;
            };
            Some(KnownDifference {
                vertex: v.0,
                normal_only: false,
                reason,
            })
        })
        .collect()
}
