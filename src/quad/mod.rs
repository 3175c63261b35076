//! Quad control meshes (Fitmaps §3.2): turning the input triangle mesh M into
//! a pure quad mesh on the same vertex set ([`quadrangulate`], after Tarini et
//! al. 2010, "Practical quad mesh simplification"), and placing its vertices
//! so that the Catmull-Clark limit surface interpolates M's vertices
//! ([`interpolate_limit`], system (1) `L V_K = V_M`).

pub mod field;
mod interpolate;
mod matching;
pub mod ops;
mod quadrangulate;
pub mod simplify;

pub use crate::subdiv::catmark::closed_form::face_centre_limit;
pub use interpolate::{
    interpolate_limit, interpolate_limit_local, limit_positions, vertex_limit_mask,
    vertex_limit_mask_into, InterpolationOptions, InterpolationReport, InterpolationSolver,
};
pub use quadrangulate::{
    quad_quality, quadrangulate, ParityFix, ParityFixKind, QuadQuality, QuadSource,
    QuadrangulateOptions, Quadrangulation, QuadrangulationReport, QualityStats,
};
pub use simplify::{
    prepare, s_fitmap_kappa, simplify, simplify_control, simplify_prepared, simplify_with_progress,
    Prepared, Progress, Simplified, SimplifyOptions, SimplifyStats, StopReason,
};
