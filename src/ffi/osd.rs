//! Bridge to `cpp/osd_bridge.{h,cpp}`: OpenSubdiv Far topology, patch table
//! and stencils behind one opaque, immutable `OsdTopology`.

#[cxx::bridge(namespace = "subdfit::osd")]
pub(crate) mod bridge {
    /// Limit stencils in compressed rows, as `LimitStencilTableFactory`
    /// writes them (see `crate::subdiv::LimitStencils`).
    struct StencilRows {
        offsets: Vec<u32>,
        indices: Vec<u32>,
        weights: Vec<f64>,
        du_weights: Vec<f64>,
        dv_weights: Vec<f64>,
    }

    /// Uniform refinement of positions (`uniform_refine`): every level's
    /// vertices, level `l` at `level_offsets[l]..level_offsets[l + 1]`
    /// (xyz each in `positions`); for every refined vertex (levels 1.., in
    /// that order) its parent component's kind (0 vertex, 1 edge, 2 face)
    /// and vertices at the parent level (`parents[parent_offsets[i]..
    /// parent_offsets[i + 1]]`); `limits` (xyz per last-level vertex) when
    /// asked for.
    struct UniformRefinement {
        level_offsets: Vec<u32>,
        positions: Vec<f64>,
        kinds: Vec<u8>,
        parent_offsets: Vec<u32>,
        parents: Vec<u32>,
        limits: Vec<f64>,
    }

    /// Uniform refinement of a face-varying channel (`uniform_refine_fvar`):
    /// the last level's values and their limits (2 doubles each), and its
    /// faces by value index (`face_values[face_offsets[f]..face_offsets[f +
    /// 1]]`).
    struct FVarUniform {
        values: Vec<f64>,
        limits: Vec<f64>,
        face_offsets: Vec<u32>,
        face_values: Vec<u32>,
    }

    /// `Sdc::Options` as integers in the order of OpenSubdiv's enums
    /// (`VtxBoundaryInterpolation`, `FVarLinearInterpolation`,
    /// `CreasingMethod`, `TriangleSubdivision`) and the hole faces.
    struct SchemeDesc {
        /// `Sdc::SchemeType`: 0 bilinear, 1 Catmark (as OpenSubdiv numbers them).
        scheme_type: u32,
        boundary: u32,
        fvar: u32,
        creasing: u32,
        triangles: u32,
        holes: Vec<u32>,
    }

    unsafe extern "C++" {
        include!("subdfit/cpp/osd_bridge.h");

        /// Version string of the wrapped library (smoke test of the bridge).
        fn library_version() -> Result<String>;

        type OsdTopology;

        /// Topology + adaptive refinement + double patch table + patch map.
        /// Creases are vertex pairs (`2 * crease_weights.len()` indices).
        #[allow(clippy::too_many_arguments)]
        fn new_osd_topology(
            num_vertices: u32,
            face_sizes: &[u32],
            face_indices: &[u32],
            crease_vertices: &[u32],
            crease_weights: &[f64],
            corner_vertices: &[u32],
            corner_weights: &[f64],
            scheme: &SchemeDesc,
            isolation_level: u32,
        ) -> Result<UniquePtr<OsdTopology>>;

        fn num_control_vertices(self: &OsdTopology) -> Result<u32>;
        fn ptex_base_indices(self: &OsdTopology) -> Result<Vec<u32>>;
        fn num_patch_points(self: &OsdTopology) -> Result<usize>;
        fn max_level(self: &OsdTopology) -> Result<u32>;
        /// xyz per control vertex -> xyz per patch point.
        fn compute_patch_points(
            self: &OsdTopology,
            positions: &[f64],
            points: &mut [f64],
        ) -> Result<()>;
        /// 9 doubles per location: position, d/du, d/dv.
        fn evaluate_patches(
            self: &OsdTopology,
            points: &[f64],
            ptex: &[u32],
            u: &[f64],
            v: &[f64],
            out: &mut [f64],
        ) -> Result<()>;
        /// 9 doubles per control vertex: limit position, tangent 1, tangent 2.
        fn vertex_limits(self: &OsdTopology, positions: &[f64], out: &mut [f64]) -> Result<()>;
        fn limit_stencils(
            self: &OsdTopology,
            ptex: &[u32],
            u: &[f64],
            v: &[f64],
        ) -> Result<StencilRows>;

        /// `scheme_type` 0 = Catmark, 1 = Loop; `levels` in 1..=10.
        #[allow(clippy::too_many_arguments)]
        fn uniform_refine(
            scheme_type: u32,
            num_vertices: u32,
            face_sizes: &[u32],
            face_indices: &[u32],
            crease_vertices: &[u32],
            crease_weights: &[f64],
            corner_vertices: &[u32],
            corner_weights: &[f64],
            scheme: &SchemeDesc,
            positions: &[f64],
            levels: u32,
            limits: bool,
        ) -> Result<UniformRefinement>;

        /// `scheme_type` 0 = Catmark, 1 = Loop, 2 = bilinear; `levels` in 1..=10.
        #[allow(clippy::too_many_arguments)]
        fn uniform_refine_fvar(
            scheme_type: u32,
            num_vertices: u32,
            face_sizes: &[u32],
            face_indices: &[u32],
            crease_vertices: &[u32],
            crease_weights: &[f64],
            corner_vertices: &[u32],
            corner_weights: &[f64],
            scheme: &SchemeDesc,
            fvar_indices: &[u32],
            fvar_values: &[f64],
            levels: u32,
        ) -> Result<FVarUniform>;

        type OsdFVarTopology;

        /// Adaptive refinement considering one face-varying channel and its
        /// non-linear double-precision patches.
        #[allow(clippy::too_many_arguments)]
        fn new_osd_fvar_topology(
            num_vertices: u32,
            face_sizes: &[u32],
            face_indices: &[u32],
            crease_vertices: &[u32],
            crease_weights: &[f64],
            corner_vertices: &[u32],
            corner_weights: &[f64],
            scheme: &SchemeDesc,
            fvar_indices: &[u32],
            num_values: u32,
            isolation_level: u32,
        ) -> Result<UniquePtr<OsdFVarTopology>>;
        /// 6 doubles per location: value, d/du, d/dv.
        fn evaluate(
            self: &OsdFVarTopology,
            values: &[f64],
            ptex: &[u32],
            u: &[f64],
            v: &[f64],
            out: &mut [f64],
        ) -> Result<()>;
    }
}

// SAFETY: `OsdTopology` owns its OpenSubdiv objects (refiner, patch table,
// patch map, stencil tables) outright; nothing refers to thread-local or
// thread-affine state, so moving it to another thread is sound.
unsafe impl Send for bridge::OsdTopology {}
// SAFETY: after `new_osd_topology` returns, every method reachable through
// `&OsdTopology` only reads it: `PrimvarRefiner`, `PatchMap::FindPatch`,
// `PatchTable::EvaluateBasis` and `LimitStencilTableFactory::Create` (given
// both tables) are const over their inputs. The two lazily built caches
// (uniform refiner, control stencil table) are created under a mutex inside
// the object and never changed afterwards, and OpenSubdiv's process-wide
// error callback writes to a per-thread buffer.
unsafe impl Sync for bridge::OsdTopology {}
// SAFETY: as `OsdTopology`: it owns its refiner, patch table and patch map;
// `evaluate` only reads them (its buffers are local).
unsafe impl Send for bridge::OsdFVarTopology {}
// SAFETY: see `Send`; nothing is mutated after construction.
unsafe impl Sync for bridge::OsdFVarTopology {}
