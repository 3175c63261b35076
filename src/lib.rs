//! subdfit: dense triangle meshes to adaptive Catmull-Clark subdivision surfaces.
//!
//! Layers, data flowing one way: [`io`] → [`mesh`] → (later: analysis, quad,
//! fit, displace, report). [`subdiv`] (limit evaluation) and [`raycast`] are
//! services behind traits, each with a pure-Rust and a C++ implementation so
//! that tests can cross-check them. [`solve`] wraps Eigen's sparse solvers.

pub mod analysis;
pub mod displace;
pub mod embed;
pub mod error;
pub mod fit;
pub mod fixtures;
pub mod io;
pub mod mechanical;
pub mod mesh;
pub mod pipeline;
pub mod project;
pub mod quad;
pub mod raycast;
pub mod render;
pub mod report;
pub mod solve;
pub mod subdiv;

pub(crate) mod ffi;

pub use error::{Error, Result};

/// Vector types used across the crate: double precision everywhere (only
/// Embree's copy of the triangles is `f32`; hits are recomputed in `f64`).
pub use glam::{DVec2, DVec3};

/// Versions of the C++ libraries linked in, as `(name, version)`.
pub fn linked_library_versions() -> Vec<(&'static str, String)> {
    let v = |r: std::result::Result<String, cxx::Exception>| {
        r.unwrap_or_else(|e| format!("error: {e}"))
    };
    vec![
        ("OpenSubdiv", v(ffi::osd::bridge::library_version())),
        ("Embree", v(ffi::embree::bridge::library_version())),
        ("Eigen", v(ffi::eigen::bridge::library_version())),
        ("OpenMesh", v(ffi::openmesh::bridge::library_version())),
    ]
}
