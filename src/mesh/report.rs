//! Validation of a freshly read polygon soup (owned by the mesh I/O work).

use std::path::Path;

use serde::Serialize;

use crate::error::Result;
use crate::mesh::{PolySoup, TriMesh};

/// What `subdfit info` prints: counts and defects found on load.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct MeshReport {
    pub vertices: usize,
    pub faces: usize,
}

/// A soup that passed validation, as a triangle mesh, with its report.
#[derive(Clone, Debug)]
pub struct ValidatedMesh {
    pub mesh: TriMesh,
    pub report: MeshReport,
}

/// Validates `soup` read from `path`.
pub fn validate_soup(_soup: PolySoup, _path: &Path) -> Result<ValidatedMesh> {
    Err(crate::Error::InvalidArgument(
        "validate_soup: not implemented yet".into(),
    ))
}

impl std::fmt::Display for MeshReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(f, "vertices {}\nfaces {}", self.vertices, self.faces)
    }
}
