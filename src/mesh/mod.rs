//! Meshes: the polygon soup a reader produces ([`PolySoup`]), its validation
//! report ([`MeshReport`]), the triangle mesh the pipeline analyses
//! ([`TriMesh`]), the control mesh that owns its connectivity
//! ([`ControlMesh`]) and the working frame conversions run in ([`Frame`]).

mod control;
mod decimate;
mod foreign;
mod frame;
mod fvar;
mod manifold;
mod nonmanifold;
mod report;
mod scheme;
mod soup;

pub use control::{
    Compaction, ControlMesh, EdgeId, FaceId, HalfedgeId, LivePolygons, VertexId, INFINITELY_SHARP,
};
pub use decimate::{decimate, DecimateStats, Topology};
pub use foreign::{control_from_foreign_soup, ForeignRepairs};
pub use frame::Frame;
pub use fvar::FVarChannel;
pub use manifold::{split_non_manifold, split_non_manifold_polygons, SplitStats};
pub use nonmanifold::{SplitControl, VertexKind};
pub(crate) use report::non_finite;
pub use report::{validate_soup, MeshReport, ValidatedMesh};
pub use scheme::{
    check_loop_triangles, BoundaryInterpolation, CreaseMethod, FVarLinear, SchemeOptions,
    SubdivScheme, TriangleSubdivision,
};
pub use soup::{edge_key, weld_identical, PolySoup, TriMesh, Weld};

/// A hint to load the cache line holding `p`: memory-level parallelism for
/// scattered reads of a mesh's arrays (the Fitmap's ball walks over M, the
/// M-test's samples and draws; the BVH's deferred nodes; the
/// simplification's hits on M), which otherwise wait for one miss after
/// another. One definition for every floor above this one. It changes
/// no value (the pointer is never dereferenced, and a prefetch cannot
/// fault), so results stay bit for bit the same.
#[inline(always)]
pub(crate) fn prefetch<T>(p: *const T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: `_mm_prefetch` only hints the cache; it reads nothing the
    // program sees and cannot fault, whatever the address. SSE is part of
    // the x86_64 baseline.
    unsafe {
        std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(p as *const i8);
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = p;
}
