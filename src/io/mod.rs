//! Mesh input and output. Pure-Rust readers for OBJ and PLY, OpenMesh (C++)
//! for OBJ, PLY, OFF and STL; writers for OBJ and binary PLY.

use std::path::Path;

use crate::error::{Error, Result};
use crate::mesh::PolySoup;

/// Reads a polygon soup from `path`, picking the reader from the extension.
pub fn read_soup(path: &Path) -> Result<PolySoup> {
    Err(Error::InvalidArgument(format!(
        "{}: reading is not implemented yet",
        path.display()
    )))
}
