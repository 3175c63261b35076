//! Mesh input and output. Pure-Rust readers for OBJ and PLY, OpenMesh (C++)
//! for OBJ, PLY, OFF and STL; writers for OBJ and binary PLY.
//! (Temporary stubs: the real module lands with the mesh I/O work.)

use std::io::Write;
use std::path::Path;

use crate::error::{Error, Result};
use crate::mesh::{ControlMesh, PolySoup, ValidatedMesh};

/// Reads a polygon soup from `path`, picking the reader from the extension.
pub fn read_soup(path: &Path) -> Result<PolySoup> {
    Err(Error::InvalidArgument(format!(
        "{}: reading is not implemented yet",
        path.display()
    )))
}

pub fn read_mesh(path: &Path) -> Result<ValidatedMesh> {
    crate::mesh::validate_soup(read_soup(path)?, path)
}

pub fn read_control_mesh(path: &Path) -> Result<ControlMesh> {
    ControlMesh::from_soup(&read_soup(path)?)
}

pub fn write_atomically(path: &Path, f: impl FnOnce(&mut dyn Write) -> Result<()>) -> Result<()> {
    let mut w = std::fs::File::create(path).map_err(|e| Error::io(path, e))?;
    f(&mut w)
}
