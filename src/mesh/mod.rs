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
