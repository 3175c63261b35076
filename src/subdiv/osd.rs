//! OpenSubdiv (Far) limit evaluation through the cxx bridge.
//!
//! The topology is handed to OpenSubdiv once, as the plain arrays of
//! `Far::TopologyDescriptor` (holes as its `holeIndices`), with the scheme
//! (Catmark, Loop or bilinear) and the `Sdc::Options` of
//! [`EvalOptions::scheme`]; Loop's patches are quartic box splines with
//! Gregory-triangle end caps, its ptex faces the triangles themselves. It
//! is refined feature-adaptively to [`EvalOptions::isolation_level`] and
//! turned into a double-precision `Far::PatchTable` (Gregory basis end caps)
//! with a `Far::PatchMap`; all of that lives in one immutable C++ object.
//! Positions are passed per call:
//!
//! - [`LimitEvaluator::evaluate`]: the control positions are refined through
//!   the adaptive levels and the end-cap local points once per call, then the
//!   locations are evaluated in parallel chunks (`PatchMap::FindPatch` +
//!   `PatchTable::EvaluateBasis`).
//! - [`LimitEvaluator::vertex_limits`]: `Far::PrimvarRefiner::Limit` on a
//!   uniform level-1 refinement (the limit of a level-1 child of a control
//!   vertex is the limit of that vertex).
//! - [`LimitEvaluator::stencils`]: `Far::LimitStencilTableFactory` with a
//!   control-vertex stencil table built once (lazily), so rows are over the
//!   control vertices.
//!
//! Exactness: regular patches are exact bicubic B-splines; near extraordinary
//! vertices the deepest level is covered by Gregory end caps, which deviate
//! from the limit by an amount that shrinks with the isolation level
//! (STACK-NOTES: ~2e-3 of the size at level 2, ~2e-4 at level 6); the default
//! level 10 is OpenSubdiv's maximum. Semi-sharp features are exact only when
//! the isolation level is at least their sharpness.
//!
//! Ptex faces: a quad is one ptex face (index `ptex_base[face]`); an n-gon is
//! split into n ptex faces `ptex_base[face] + k`, the k-th with `(0, 0)` at
//! corner k, `u` towards the midpoint of edge `(k, k+1)` and `v` towards the
//! midpoint of edge `(k-1, k)`, `(1, 1)` at the face centroid (OpenSubdiv's
//! and Ptex's convention).

use cxx::UniquePtr;
use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::ffi::osd::bridge;
use crate::mesh::{ControlMesh, SplitControl, INFINITELY_SHARP};
use crate::subdiv::{
    checked_holes, BoundaryInterpolation, CreaseMethod, EvalOptions, FVarLinear, LimitEvaluator,
    LimitPoint, LimitStencils, SchemeOptions, SubdivScheme, SurfaceLocation, TriangleSubdivision,
};
use crate::{DVec2, DVec3};

/// Locations per parallel chunk of [`LimitEvaluator::evaluate`]: large enough
/// to amortise the bridge call, small enough to balance across threads.
const EVAL_CHUNK: usize = 2048;
/// Minimum locations per chunk of [`LimitEvaluator::stencils`]: every factory
/// call rebuilds a `PatchMap`, so chunks must be large.
const STENCIL_CHUNK_MIN: usize = 4096;

/// The bridge's form of the scheme options (OpenSubdiv's enum order).
pub(crate) fn scheme_desc(s: &SchemeOptions) -> bridge::SchemeDesc {
    bridge::SchemeDesc {
        scheme_type: match s.scheme {
            SubdivScheme::Bilinear => 0,
            SubdivScheme::Catmark => 1,
            SubdivScheme::Loop => 2,
        },
        boundary: match s.boundary {
            BoundaryInterpolation::None => 0,
            BoundaryInterpolation::EdgeOnly => 1,
            BoundaryInterpolation::EdgeAndCorner => 2,
        },
        fvar: match s.fvar {
            FVarLinear::None => 0,
            FVarLinear::CornersOnly => 1,
            FVarLinear::CornersPlus1 => 2,
            FVarLinear::CornersPlus2 => 3,
            FVarLinear::Boundaries => 4,
            FVarLinear::All => 5,
        },
        creasing: match s.crease_method {
            CreaseMethod::Uniform => 0,
            CreaseMethod::Chaikin => 1,
        },
        triangles: match s.triangles {
            TriangleSubdivision::Catmark => 0,
            TriangleSubdivision::Smooth => 1,
        },
        holes: s.holes.iter().map(|f| f.0).collect(),
    }
}

/// Per vertex: whether [`OsdEvaluator`]'s `vertex_limits` evaluates it on
/// the patch table rather than with `PrimvarRefiner::Limit` — where a
/// semi-sharp feature at it is still sharp at level 1 (sharpness > 1; under
/// Chaikin creasing any semi-sharp edge, whose child adds its neighbours'
/// average). Where the vertex is extraordinary once the features run out,
/// that is a Gregory end cap, whose tangent plane only approximates the
/// limit (see `diff::DiffReport::approximations`).
pub fn patch_evaluated_vertices(mesh: &ControlMesh, scheme: &SchemeOptions) -> Vec<bool> {
    if scheme.scheme == SubdivScheme::Bilinear {
        // Bilinear limit masks ignore sharpness: `Limit` is exact.
        return vec![false; mesh.num_vertices()];
    }
    let min = if scheme.crease_method == CreaseMethod::Chaikin {
        0.0
    } else {
        1.0
    };
    let semi_sharp = |s: f64| s > min && s < INFINITELY_SHARP;
    mesh.vertices()
        .map(|v| {
            semi_sharp(mesh.vertex_sharpness(v))
                || mesh
                    .outgoing(v)
                    .any(|h| semi_sharp(mesh.edge_sharpness(h.edge())))
        })
        .collect()
}

/// OpenSubdiv's `Far::TopologyDescriptor`: the arrays it is given.
#[derive(Clone, Debug, Default)]
pub struct OsdDescriptor {
    pub num_vertices: usize,
    pub face_sizes: Vec<u32>,
    pub face_indices: Vec<u32>,
    /// `(a, b, sharpness)`.
    pub creases: Vec<(u32, u32, f64)>,
    /// `(v, sharpness)`.
    pub corners: Vec<(u32, f64)>,
}

impl OsdDescriptor {
    pub fn of_mesh(mesh: &ControlMesh) -> Self {
        OsdDescriptor {
            num_vertices: mesh.num_vertices(),
            face_sizes: mesh.face_sizes(),
            face_indices: mesh.face_indices_flat(),
            creases: mesh
                .creases()
                .iter()
                .map(|c| (c.0 .0, c.1 .0, c.2))
                .collect(),
            corners: mesh.corners().iter().map(|c| (c.0 .0, c.1)).collect(),
        }
    }

    /// The file's topology of a non-manifold mesh, untouched: OpenSubdiv
    /// applies its own non-manifold rules.
    pub fn of_split(sc: &SplitControl) -> Self {
        OsdDescriptor {
            num_vertices: sc.positions.len(),
            face_sizes: sc.face_sizes.clone(),
            face_indices: sc.face_indices.clone(),
            creases: sc.creases.clone(),
            corners: sc.corners.clone(),
        }
    }

    fn tag_arrays(&self) -> (Vec<u32>, Vec<f64>, Vec<u32>, Vec<f64>) {
        (
            self.creases.iter().flat_map(|c| [c.0, c.1]).collect(),
            self.creases.iter().map(|c| c.2).collect(),
            self.corners.iter().map(|c| c.0).collect(),
            self.corners.iter().map(|c| c.1).collect(),
        )
    }
}

/// The vertices [`OsdEvaluator`]'s `vertex_limits` evaluates on the patch
/// table ([`patch_evaluated_vertices`]), each with a corner of one of its
/// faces with a surface: the corner of that face's ptex face at the vertex
/// (a vertex with only holes around keeps `Limit`'s value).
pub fn patch_routes(
    mesh: &ControlMesh,
    options: &EvalOptions,
) -> Result<Vec<(u32, SurfaceLocation)>> {
    let loop_scheme = options.scheme.scheme == SubdivScheme::Loop;
    let holes = checked_holes(mesh, &options.scheme)?;
    let routed = patch_evaluated_vertices(mesh, &options.scheme);
    Ok(mesh
        .vertices()
        .filter(|&v| routed[v.idx()])
        .filter_map(|v| {
            let h = mesh
                .outgoing(v)
                .find(|&h| mesh.face_of(h).is_some_and(|f| !holes[f.idx()]))?;
            let f = mesh.face_of(h)?;
            let k = mesh.face_halfedges(f).position(|g| g == h)?;
            let loc = if loop_scheme {
                let (u, w) = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0)][k];
                SurfaceLocation::quad(f, u, w)
            } else if mesh.face_size(f) == 4 {
                let (u, w) = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)][k];
                SurfaceLocation::quad(f, u, w)
            } else {
                SurfaceLocation {
                    face: f,
                    sub: k as u16,
                    u: 0.0,
                    v: 0.0,
                }
            };
            Some((v.0, loc))
        })
        .collect())
}

fn backend(e: cxx::Exception) -> Error {
    Error::backend("OpenSubdiv", e.what())
}

/// OpenSubdiv's Catmull-Clark limit evaluator for one control-mesh topology.
///
/// `Send + Sync`: the C++ object is immutable after construction (see the
/// SAFETY notes in `src/ffi/osd.rs`), so one evaluator can serve many
/// threads, e.g. the rayon workers of a fitting loop.
pub struct OsdEvaluator {
    topo: UniquePtr<bridge::OsdTopology>,
    num_vertices: usize,
    face_sizes: Vec<u32>,
    /// First ptex face of each face (`Far::PtexIndices`).
    ptex_base: Vec<u32>,
    num_patch_points: usize,
    isolation_level: u8,
    max_level: u32,
    /// Vertices whose level-1 `PrimvarRefiner::Limit` is not their limit
    /// (a semi-sharp vertex or incident edge of sharpness > 1 is still sharp
    /// at level 1, so `Limit` would apply a crease/corner mask), with a face
    /// corner at which the patch table gives their limit instead.
    patch_route_vertices: Vec<(u32, SurfaceLocation)>,
    /// Loop scheme: triangular ptex faces.
    loop_scheme: bool,
}

impl OsdEvaluator {
    /// Builds the OpenSubdiv topology, adaptive refinement, patch table and
    /// patch map of `mesh` (its positions are not used). Fails with
    /// [`Error::InvalidArgument`] on an isolation level outside `1..=10`, and
    /// with [`Error::Backend`] carrying OpenSubdiv's message if it refuses
    /// the topology.
    pub fn new(mesh: &ControlMesh, options: &EvalOptions) -> Result<Self> {
        if options.scheme.scheme == SubdivScheme::Loop {
            crate::mesh::check_loop_triangles(mesh)?;
        }
        let routes = patch_routes(mesh, options)?;
        Self::from_descriptor(&OsdDescriptor::of_mesh(mesh), routes, options)
    }

    /// [`Self::new`] on OpenSubdiv's arrays as they are (a non-manifold
    /// mesh, `crate::mesh::SplitControl`), with the vertices whose limit
    /// [`LimitEvaluator::vertex_limits`] takes from the patch table instead
    /// of `Limit` and where (see [`patch_routes`]).
    pub fn from_descriptor(
        desc: &OsdDescriptor,
        patch_route_vertices: Vec<(u32, SurfaceLocation)>,
        options: &EvalOptions,
    ) -> Result<Self> {
        let level = options.isolation_level;
        if !(1..=10).contains(&level) {
            return Err(Error::option(
                "isolation_level",
                format!("OpenSubdiv isolation level {level} outside 1..=10 (10 is OpenSubdiv's maximum)"),
            ));
        }
        let loop_scheme = options.scheme.scheme == SubdivScheme::Loop;
        if let Some(f) = desc.face_sizes.iter().position(|&n| loop_scheme && n != 3) {
            return Err(Error::topology(
                format!("face {f}"),
                format!(
                    "has {} corners: Loop subdivision needs triangles",
                    desc.face_sizes[f]
                ),
            ));
        }
        let num_vertices = desc.num_vertices;
        let nv = u32::try_from(num_vertices).map_err(|_| {
            Error::topology(
                "mesh",
                format!("{num_vertices} control vertices are too many"),
            )
        })?;
        let face_sizes = desc.face_sizes.clone();
        let (crease_vertices, crease_weights, corner_vertices, corner_weights) = desc.tag_arrays();
        let topo = bridge::new_osd_topology(
            nv,
            &face_sizes,
            &desc.face_indices,
            &crease_vertices,
            &crease_weights,
            &corner_vertices,
            &corner_weights,
            &scheme_desc(&options.scheme),
            level as u32,
        )
        .map_err(backend)?;
        let ptex_base = topo.ptex_base_indices().map_err(backend)?;
        let num_patch_points = topo.num_patch_points().map_err(backend)?;
        let max_level = topo.max_level().map_err(backend)?;
        if topo.num_control_vertices().map_err(backend)? != nv
            || ptex_base.len() != face_sizes.len()
        {
            return Err(Error::backend(
                "OpenSubdiv",
                "refined topology does not match the control mesh's vertex/face counts",
            ));
        }
        Ok(OsdEvaluator {
            topo,
            num_vertices,
            face_sizes,
            ptex_base,
            num_patch_points,
            isolation_level: level,
            max_level,
            patch_route_vertices,
            loop_scheme,
        })
    }

    /// The adaptive isolation level this evaluator was built with.
    pub fn isolation_level(&self) -> u8 {
        self.isolation_level
    }

    /// The deepest level the adaptive refinement reached (0 if every patch
    /// is regular at the base level, at most the isolation level).
    pub fn max_refinement_level(&self) -> u32 {
        self.max_level
    }

    /// OpenSubdiv's ptex face index of `loc` (see the module doc), checked.
    pub fn ptex_index(&self, loc: &SurfaceLocation) -> Result<u32> {
        self.check_location(0, loc)
    }

    fn topo(&self) -> &bridge::OsdTopology {
        // Never null: `new` returns an error instead.
        self.topo
            .as_ref()
            .expect("OsdTopology is created non-null by new()")
    }

    /// Checks a location (face in range, sub-face valid for the face size,
    /// u/v finite and in [0, 1]) and returns its ptex index. `i` is the index
    /// in the caller's batch, named in the error.
    fn check_location(&self, i: usize, loc: &SurfaceLocation) -> Result<u32> {
        let bad = |msg: String| Error::InvalidArgument(format!("surface location {i}: {msg}"));
        let f = loc.face;
        let Some(&n) = self.face_sizes.get(f.idx()) else {
            return Err(bad(format!(
                "{f} out of range (the mesh has {} faces)",
                self.face_sizes.len()
            )));
        };
        // Loop: every triangle is one triangular ptex face.
        let subs = if n == 4 || self.loop_scheme { 1 } else { n };
        if u32::from(loc.sub) >= subs {
            return Err(bad(format!(
                "sub-face {} of {f}, which has {n} corners ({subs} ptex face(s))",
                loc.sub
            )));
        }
        for (name, x) in [("u", loc.u), ("v", loc.v)] {
            if !(0.0..=1.0).contains(&x) {
                return Err(bad(format!("{name} = {x} is not in [0, 1]")));
            }
        }
        if self.loop_scheme && loc.u + loc.v > 1.0 {
            return Err(bad(format!(
                "(u, v) = ({}, {}) is outside the triangle (u + v > 1)",
                loc.u, loc.v
            )));
        }
        Ok(self.ptex_base[f.idx()] + u32::from(loc.sub))
    }

    /// Splits a batch into the flat arrays of the bridge, validating it.
    fn flatten_locations(
        &self,
        locations: &[SurfaceLocation],
    ) -> Result<(Vec<u32>, Vec<f64>, Vec<f64>)> {
        let mut ptex = Vec::with_capacity(locations.len());
        let mut u = Vec::with_capacity(locations.len());
        let mut v = Vec::with_capacity(locations.len());
        for (i, loc) in locations.iter().enumerate() {
            ptex.push(self.check_location(i, loc)?);
            u.push(loc.u);
            v.push(loc.v);
        }
        Ok((ptex, u, v))
    }

    fn flatten_positions(&self, positions: &[DVec3]) -> Result<Vec<f64>> {
        if positions.len() != self.num_vertices {
            return Err(Error::InvalidArgument(format!(
                "expected {} control positions, got {}",
                self.num_vertices,
                positions.len()
            )));
        }
        if let Some(i) = positions.iter().position(|p| !p.is_finite()) {
            return Err(Error::InvalidArgument(format!(
                "control position of vertex {i} is not finite: {}",
                positions[i]
            )));
        }
        Ok(positions.iter().flat_map(|p| p.to_array()).collect())
    }

    /// Evaluates validated flat locations (parallel over chunks, results in
    /// input order whatever the thread count).
    fn evaluate_flat(
        &self,
        positions: &[DVec3],
        ptex: &[u32],
        u: &[f64],
        v: &[f64],
    ) -> Result<Vec<LimitPoint>> {
        let flat = self.flatten_positions(positions)?;
        let topo = self.topo();
        let mut points = vec![0.0; 3 * self.num_patch_points];
        topo.compute_patch_points(&flat, &mut points)
            .map_err(backend)?;
        let mut out = vec![0.0; 9 * ptex.len()];
        out.par_chunks_mut(9 * EVAL_CHUNK)
            .enumerate()
            .try_for_each(|(c, out)| {
                let r = c * EVAL_CHUNK..(c * EVAL_CHUNK + out.len() / 9);
                topo.evaluate_patches(&points, &ptex[r.clone()], &u[r.clone()], &v[r], out)
                    .map_err(backend)
            })?;
        Ok(out.chunks_exact(9).map(limit_point).collect())
    }
}

fn limit_point(x: &[f64]) -> LimitPoint {
    LimitPoint {
        position: DVec3::new(x[0], x[1], x[2]),
        du: DVec3::new(x[3], x[4], x[5]),
        dv: DVec3::new(x[6], x[7], x[8]),
    }
}

impl LimitEvaluator for OsdEvaluator {
    fn name(&self) -> &'static str {
        "osd"
    }

    fn num_control_vertices(&self) -> usize {
        self.num_vertices
    }

    /// `PrimvarRefiner::Limit` (exact OpenSubdiv limit masks; interior
    /// valence-2 vertices get its corner mask, see
    /// [`crate::subdiv::known_differences`]). `du`/`dv` are its two limit
    /// tangents, whose scale is OpenSubdiv's. Vertices on or at a semi-sharp
    /// feature of sharpness > 1 are evaluated on the patch table at a corner
    /// of one of their faces instead (exact up to the isolation level);
    /// their `du`/`dv` are that face's parametric derivatives.
    fn vertex_limits(&self, positions: &[DVec3]) -> Result<Vec<LimitPoint>> {
        let flat = self.flatten_positions(positions)?;
        let mut out = vec![0.0; 9 * self.num_vertices];
        self.topo()
            .vertex_limits(&flat, &mut out)
            .map_err(backend)?;
        let mut limits: Vec<LimitPoint> = out.chunks_exact(9).map(limit_point).collect();
        if !self.patch_route_vertices.is_empty() {
            let locs: Vec<SurfaceLocation> =
                self.patch_route_vertices.iter().map(|&(_, l)| l).collect();
            let (ptex, u, v) = self.flatten_locations(&locs)?;
            let exact = self.evaluate_flat(positions, &ptex, &u, &v)?;
            for (&(vert, _), p) in self.patch_route_vertices.iter().zip(exact) {
                limits[vert as usize] = p;
            }
        }
        Ok(limits)
    }

    fn evaluate(
        &self,
        positions: &[DVec3],
        locations: &[SurfaceLocation],
    ) -> Result<Vec<LimitPoint>> {
        let (ptex, u, v) = self.flatten_locations(locations)?;
        self.evaluate_flat(positions, &ptex, &u, &v)
    }

    /// Rows over the control vertices, from `LimitStencilTableFactory` with
    /// first derivatives. Duplicate indices do not occur within a row
    /// (OpenSubdiv's stencil builder merges them).
    fn stencils(&self, locations: &[SurfaceLocation]) -> Result<LimitStencils> {
        let (ptex, u, v) = self.flatten_locations(locations)?;
        let n = ptex.len();
        let chunk = n
            .div_ceil(rayon::current_num_threads().max(1))
            .max(STENCIL_CHUNK_MIN);
        let topo = self.topo();
        let parts: Vec<bridge::StencilRows> = (0..n.div_ceil(chunk))
            .into_par_iter()
            .map(|c| {
                let r = c * chunk..((c + 1) * chunk).min(n);
                topo.limit_stencils(&ptex[r.clone()], &u[r.clone()], &v[r])
                    .map_err(backend)
            })
            .collect::<Result<_>>()?;
        let mut s = LimitStencils {
            offsets: vec![0],
            ..Default::default()
        };
        for p in parts {
            let base = *s.offsets.last().expect("offsets start with 0");
            s.offsets.extend(p.offsets[1..].iter().map(|&o| base + o));
            s.indices.extend(p.indices);
            s.weights.extend(p.weights);
            s.du_weights.extend(p.du_weights);
            s.dv_weights.extend(p.dv_weights);
        }
        Ok(s)
    }
}

/// OpenSubdiv's subdivision scheme for [`osd_refine_uniform`].
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum OsdScheme {
    /// `Sdc::SCHEME_CATMARK` (any polygons).
    Catmark,
    /// `Sdc::SCHEME_LOOP` (triangles only; OpenSubdiv refuses other faces).
    Loop,
}

/// The parent component of a vertex refined by OpenSubdiv, named by its
/// vertices at the parent level (OpenSubdiv's numbering of that level).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum OsdParent {
    Vertex(u32),
    Edge(u32, u32),
    /// The face's vertices in order.
    Face(Vec<u32>),
}

/// Result of [`osd_refine_uniform`].
#[derive(Clone, Debug)]
pub struct OsdUniformRefinement {
    /// Vertex positions of levels `0..=levels` in OpenSubdiv's order.
    pub levels: Vec<Vec<DVec3>>,
    /// `parents[l - 1][i]`: the parent component of vertex `i` of level `l`.
    pub parents: Vec<Vec<OsdParent>>,
    /// `PrimvarRefiner::Limit` positions of the last level's vertices, when
    /// asked for.
    pub limits: Option<Vec<DVec3>>,
}

/// Uniform refinement of `mesh`'s positions by OpenSubdiv to `levels`
/// (1..=10): `Far::TopologyRefiner::RefineUniform` and
/// `PrimvarRefiner::Interpolate`, with the conventions of the module doc
/// (boundary "edge and corner", uniform creasing). OpenSubdiv orders refined
/// vertices its own way; [`OsdUniformRefinement::parents`] names each one's
/// parent component so callers can match them with another refiner's. With
/// `limits`, `PrimvarRefiner::Limit` of the last level too. This is the
/// reference of the quad/triangle scheme's differential test (Catmark on
/// all-quad meshes, Loop on all-triangle meshes).
pub fn osd_refine_uniform(
    mesh: &ControlMesh,
    scheme: OsdScheme,
    levels: u32,
    limits: bool,
) -> Result<OsdUniformRefinement> {
    osd_refine_uniform_with(mesh, scheme, &SchemeOptions::default(), levels, limits)
}

/// [`osd_refine_uniform`] with explicit scheme options (holes included:
/// OpenSubdiv still refines hole faces uniformly).
pub fn osd_refine_uniform_with(
    mesh: &ControlMesh,
    scheme: OsdScheme,
    options: &SchemeOptions,
    levels: u32,
    limits: bool,
) -> Result<OsdUniformRefinement> {
    osd_refine_uniform_desc(
        &OsdDescriptor::of_mesh(mesh),
        mesh.positions(),
        scheme,
        options,
        levels,
        limits,
    )
}

/// [`osd_refine_uniform_with`] on OpenSubdiv's arrays as they are (a
/// non-manifold mesh's, [`OsdDescriptor::of_split`]) with `positions` over
/// their vertices: the reference of `tests/nonmanifold_limit.rs`.
pub fn osd_refine_uniform_desc(
    desc: &OsdDescriptor,
    positions: &[DVec3],
    scheme: OsdScheme,
    options: &SchemeOptions,
    levels: u32,
    limits: bool,
) -> Result<OsdUniformRefinement> {
    if !(1..=10).contains(&levels) {
        return Err(Error::InvalidArgument(format!(
            "OpenSubdiv uniform refinement: {levels} levels requested, 1..=10 supported"
        )));
    }
    let num_vertices = desc.num_vertices;
    let nv = u32::try_from(num_vertices).map_err(|_| {
        Error::topology(
            "mesh",
            format!("{num_vertices} control vertices are too many"),
        )
    })?;
    if positions.len() != num_vertices {
        return Err(Error::InvalidArgument(format!(
            "expected {num_vertices} control positions, got {}",
            positions.len()
        )));
    }
    if let Some(i) = positions.iter().position(|p| !p.is_finite()) {
        return Err(Error::InvalidArgument(format!(
            "control position of vertex {i} is not finite"
        )));
    }
    let (crease_vertices, crease_weights, corner_vertices, corner_weights) = desc.tag_arrays();
    let flat: Vec<f64> = positions.iter().flat_map(|p| p.to_array()).collect();
    let r = bridge::uniform_refine(
        match scheme {
            OsdScheme::Catmark => 0,
            OsdScheme::Loop => 1,
        },
        nv,
        &desc.face_sizes,
        &desc.face_indices,
        &crease_vertices,
        &crease_weights,
        &corner_vertices,
        &corner_weights,
        &scheme_desc(options),
        &flat,
        levels,
        limits,
    )
    .map_err(backend)?;
    let broken = |what: &str| Error::backend("OpenSubdiv", format!("uniform refinement: {what}"));
    let offs: Vec<usize> = r.level_offsets.iter().map(|&o| o as usize).collect();
    if offs.len() != levels as usize + 2 || r.positions.len() != 3 * offs[offs.len() - 1] {
        return Err(broken("level offsets do not match the positions"));
    }
    let pts: Vec<DVec3> = r
        .positions
        .chunks_exact(3)
        .map(|x| DVec3::new(x[0], x[1], x[2]))
        .collect();
    let level_pts: Vec<Vec<DVec3>> = offs.windows(2).map(|w| pts[w[0]..w[1]].to_vec()).collect();
    let refined = offs[offs.len() - 1] - offs[1];
    if r.kinds.len() != refined || r.parent_offsets.len() != refined + 1 {
        return Err(broken("parent arrays do not match the refined vertices"));
    }
    let mut all = Vec::with_capacity(refined);
    for (i, &k) in r.kinds.iter().enumerate() {
        let p = &r.parents[r.parent_offsets[i] as usize..r.parent_offsets[i + 1] as usize];
        all.push(match (k, p) {
            (0, &[v]) => OsdParent::Vertex(v),
            (1, &[a, b]) => OsdParent::Edge(a, b),
            (2, f) if f.len() >= 3 => OsdParent::Face(f.to_vec()),
            _ => return Err(broken("malformed parent component")),
        });
    }
    let mut parents = Vec::with_capacity(levels as usize);
    let mut at = 0;
    for l in 1..=levels as usize {
        let n = offs[l + 1] - offs[l];
        parents.push(all[at..at + n].to_vec());
        at += n;
    }
    let limits = limits.then(|| {
        r.limits
            .chunks_exact(3)
            .map(|x| DVec3::new(x[0], x[1], x[2]))
            .collect::<Vec<_>>()
    });
    if let Some(l) = &limits {
        if l.len() != level_pts[levels as usize].len() {
            return Err(broken("limit positions do not match the last level"));
        }
    }
    Ok(OsdUniformRefinement {
        levels: level_pts,
        parents,
        limits,
    })
}

/// OpenSubdiv's face-varying patches for one channel of a control mesh
/// (`OsdFVarTopology`): the reference of the face-varying columns of
/// `subdfit limit --backend osd` and `diff-limit`.
pub struct OsdFVarEvaluator {
    /// Locates the ptex faces (the same ptex numbering as the channel's
    /// patch table: both come from the same control topology).
    vertex: OsdEvaluator,
    topo: UniquePtr<bridge::OsdFVarTopology>,
    values: Vec<f64>,
}

impl OsdFVarEvaluator {
    pub fn new(
        mesh: &ControlMesh,
        options: &EvalOptions,
        channel: &crate::mesh::FVarChannel,
    ) -> Result<Self> {
        channel.check(mesh)?;
        Self::from_descriptor(&OsdDescriptor::of_mesh(mesh), options, channel)
    }

    /// On the arrays OpenSubdiv is given (a non-manifold file's own
    /// topology, [`OsdDescriptor::of_split`]): `channel` has one index per
    /// face corner of `desc`, in its order.
    pub fn from_descriptor(
        desc: &OsdDescriptor,
        options: &EvalOptions,
        channel: &crate::mesh::FVarChannel,
    ) -> Result<Self> {
        if channel.indices.len() != desc.face_indices.len() {
            return Err(Error::invalid_data(
                "face-varying channel",
                "indices",
                format!(
                    "{} indices for {} face corners",
                    channel.indices.len(),
                    desc.face_indices.len()
                ),
            ));
        }
        if let Some(i) = channel
            .indices
            .iter()
            .find(|&&i| i as usize >= channel.values.len())
        {
            return Err(Error::InvalidArgument(format!(
                "face-varying index {i} out of range ({} values)",
                channel.values.len()
            )));
        }
        let vertex = OsdEvaluator::from_descriptor(desc, Vec::new(), options)?;
        let (crease_vertices, crease_weights, corner_vertices, corner_weights) = desc.tag_arrays();
        let topo = bridge::new_osd_fvar_topology(
            desc.num_vertices as u32,
            &desc.face_sizes,
            &desc.face_indices,
            &crease_vertices,
            &crease_weights,
            &corner_vertices,
            &corner_weights,
            &scheme_desc(&options.scheme),
            &channel.indices,
            channel.values.len() as u32,
            options.isolation_level as u32,
        )
        .map_err(backend)?;
        let values = channel.values.iter().flat_map(|v| v.to_array()).collect();
        Ok(OsdFVarEvaluator {
            vertex,
            topo,
            values,
        })
    }
}

impl crate::subdiv::fvar::FVarEvaluator for OsdFVarEvaluator {
    fn evaluate(&self, locations: &[SurfaceLocation]) -> Result<Vec<LimitPoint>> {
        let ptex = locations
            .iter()
            .map(|l| self.vertex.ptex_index(l))
            .collect::<Result<Vec<u32>>>()?;
        let u: Vec<f64> = locations.iter().map(|l| l.u).collect();
        let v: Vec<f64> = locations.iter().map(|l| l.v).collect();
        let mut out = vec![0.0; 6 * locations.len()];
        let topo = self
            .topo
            .as_ref()
            .ok_or_else(|| Error::backend("OpenSubdiv", "null face-varying topology"))?;
        topo.evaluate(&self.values, &ptex, &u, &v, &mut out)
            .map_err(backend)?;
        let p2 = |x: &[f64]| DVec3::new(x[0], x[1], 0.0);
        Ok(out
            .chunks_exact(6)
            .map(|c| LimitPoint {
                position: p2(&c[0..2]),
                du: p2(&c[2..4]),
                dv: p2(&c[4..6]),
            })
            .collect())
    }
}

/// Result of [`osd_refine_uniform_fvar`]: a face-varying channel refined
/// by OpenSubdiv.
#[derive(Clone, Debug)]
pub struct OsdFVarRefinement {
    /// The last level's values (`PrimvarRefiner::InterpolateFaceVarying`).
    pub values: Vec<DVec2>,
    /// Their limits (`PrimvarRefiner::LimitFaceVarying`).
    pub limits: Vec<DVec2>,
    /// The last level's faces as value indices.
    pub faces: Vec<Vec<u32>>,
}

/// Uniform refinement of the face-varying `channel` of `mesh` by
/// OpenSubdiv to `levels` (1..=10), under every option of `options`
/// (its scheme type included: Catmark, Loop or bilinear, and its
/// face-varying linear interpolation): the reference of the face-varying
/// differential tests.
pub fn osd_refine_uniform_fvar(
    mesh: &ControlMesh,
    options: &SchemeOptions,
    channel: &crate::mesh::FVarChannel,
    levels: u32,
) -> Result<OsdFVarRefinement> {
    channel.check(mesh)?;
    let nv = u32::try_from(mesh.num_vertices())
        .map_err(|_| Error::topology("mesh", "too many control vertices"))?;
    let desc = OsdDescriptor::of_mesh(mesh);
    let (crease_vertices, crease_weights, corner_vertices, corner_weights) = desc.tag_arrays();
    let values: Vec<f64> = channel.values.iter().flat_map(|v| v.to_array()).collect();
    let r = bridge::uniform_refine_fvar(
        match options.scheme {
            SubdivScheme::Catmark => 0,
            SubdivScheme::Loop => 1,
            SubdivScheme::Bilinear => 2,
        },
        nv,
        &desc.face_sizes,
        &desc.face_indices,
        &crease_vertices,
        &crease_weights,
        &corner_vertices,
        &corner_weights,
        &scheme_desc(options),
        &channel.indices,
        &values,
        levels,
    )
    .map_err(backend)?;
    let pts =
        |x: &[f64]| -> Vec<DVec2> { x.chunks_exact(2).map(|c| DVec2::new(c[0], c[1])).collect() };
    let faces = r
        .face_offsets
        .windows(2)
        .map(|w| r.face_values[w[0] as usize..w[1] as usize].to_vec())
        .collect();
    Ok(OsdFVarRefinement {
        values: pts(&r.values),
        limits: pts(&r.limits),
        faces,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// OpenSubdiv's own refusal surfaces as a backend error with its
    /// message (the control mesh rejects everything else earlier, so the
    /// bridge is called directly: a descriptor without vertices).
    #[test]
    fn opensubdiv_refusal_is_a_backend_error() {
        let e = bridge::new_osd_topology(
            0,
            &[],
            &[],
            &[],
            &[],
            &[],
            &[],
            &scheme_desc(&SchemeOptions::default()),
            4,
        )
        .err()
        .expect("OpenSubdiv must refuse an empty descriptor");
        let msg = e.what().to_string();
        assert!(msg.contains("TopologyRefinerFactory"), "{msg}");
        // The message came from OpenSubdiv's error callback, not our default.
        assert!(!msg.contains("without a message"), "{msg}");
    }

    #[test]
    fn descriptor_is_checked_before_opensubdiv_sees_it() {
        let e = bridge::new_osd_topology(
            3,
            &[3],
            &[0, 1, 7],
            &[],
            &[],
            &[],
            &[],
            &scheme_desc(&SchemeOptions::default()),
            4,
        )
        .err()
        .expect("out-of-range index must be refused");
        assert!(e.what().contains("out of range"), "{}", e.what());
    }
}
