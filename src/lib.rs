//! subdfit: dense triangle meshes to adaptive Catmull-Clark subdivision surfaces.
//!
//! Two published systems define it: *Fitmaps* (Panozzo et al., TVCG 2011) for
//! organic shapes — [`analysis`] (§3.1), [`quad`] (§3.2–3.3), [`fit`] (§3.4),
//! [`displace`] (§3.5) — and Lavoué et al. (CGF 2007) for mechanical parts,
//! [`mechanical`]. [`convert`] runs either end to end, [`report`] measures
//! and writes the result, [`render`] draws it, [`embed`] is the API of the
//! C++ package.
//!
//! # Layers
//!
//! Data flows one way; a module imports only modules on a lower floor, or
//! earlier on its own floor (`tests/house.rs` checks every `crate::` path
//! outside test code against this list):
//!
//! | floor | modules | what |
//! |---|---|---|
//! | 0 | [`error`], [`switches`], [`watch`], `ffi` | the error type; the experiment switches (`SUBDFIT_*`); progress and cancellation for long stages; cxx bridges *to* C++ |
//! | 1 | [`mesh`], [`io`], [`solve`] | meshes and their validation; readers and writers; Eigen's sparse solvers |
//! | 2 | [`subdiv`], [`raycast`], [`fixtures`] | services behind traits (limit evaluation, ray casting), each in pure Rust and in C++; procedural meshes |
//! | 3 | [`project`], [`analysis`] | projecting a limit surface onto M; the Fitmaps |
//! | 4 | [`quad`], [`fit`], [`displace`] | layout, fitting, displacement |
//! | 5 | [`mechanical`], [`report`] | Lavoué et al.'s pipeline; metrics and outputs |
//! | 6 | [`convert`], [`render`] | conversion end to end; pictures and `report.html` |
//! | 7 | [`embed`] | the library API of the C++ package, with its `extern "Rust"` bridge |
//!
//! The binary (`src/bin/subdfit`) sits on top. [`subdiv`] and [`raycast`]
//! each have a pure-Rust and a C++ implementation so that tests can
//! cross-check them.

pub mod error;
pub(crate) mod ffi;
pub mod switches;
pub mod watch;

pub mod io;
pub mod mesh;
pub mod solve;

pub mod fixtures;
pub mod raycast;
pub mod subdiv;

pub mod analysis;
pub mod project;

pub mod displace;
pub mod fit;
pub mod quad;

pub mod mechanical;
pub mod report;

pub mod convert;
pub mod render;

pub mod embed;

pub use error::{Error, ErrorKind, Result};

/// Vector types used across the crate: double precision everywhere (only
/// Embree's copy of the triangles is `f32`; hits are recomputed in `f64`).
pub use glam::{DVec2, DVec3};

pub use ffi::linked_library_versions;
