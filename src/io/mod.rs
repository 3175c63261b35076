//! Mesh input and output. Pure-Rust readers for OBJ and PLY, OpenMesh (C++)
//! for OBJ, PLY, OFF and STL; writers for OBJ and binary PLY.
//!
//! Readers return the raw [`PolySoup`]; [`read_mesh`] adds validation
//! ([`crate::mesh::validate_soup`]) and [`read_control_mesh`] builds a
//! [`ControlMesh`] with the sharpness tags of an OBJ shape file.

mod obj;
mod obj_uv;
mod openmesh;
mod ply;
pub mod usd;
mod write;

use std::path::Path;

use crate::error::{Error, Result};
use crate::mesh::{validate_soup, ControlMesh, PolySoup, ValidatedMesh, VertexId};

pub use obj::{parse_obj, read_obj, ObjMesh};
pub use obj_uv::{control_obj_with_uvs, write_control_obj_with_uvs};
pub use openmesh::read_openmesh;
pub use ply::{parse_ply, read_ply};
pub use usd::write_usda;
pub use write::{write_atomically, write_control_obj, write_obj, write_ply};

/// Which implementation parses a file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Reader {
    /// Pure-Rust readers: OBJ and PLY.
    Rust,
    /// OpenMesh's readers: OBJ, PLY, OFF, STL.
    OpenMesh,
}

/// Mesh file formats, recognised by extension (case-insensitive).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    Obj,
    Ply,
    Off,
    Stl,
}

impl Format {
    pub fn from_path(path: &Path) -> Result<Format> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(|e| e.to_ascii_lowercase());
        match ext.as_deref() {
            Some("obj") => Ok(Format::Obj),
            Some("ply") => Ok(Format::Ply),
            Some("off") => Ok(Format::Off),
            Some("stl") => Ok(Format::Stl),
            _ => Err(Error::InvalidArgument(format!(
                "{}: unknown mesh format; use .obj, .ply, .off or .stl",
                path.display()
            ))),
        }
    }

    /// The reader used by default: pure Rust where there is one.
    pub fn default_reader(self) -> Reader {
        match self {
            Format::Obj | Format::Ply => Reader::Rust,
            Format::Off | Format::Stl => Reader::OpenMesh,
        }
    }
}

/// Reads a polygon soup from `path`, picking the reader from the extension:
/// OBJ and PLY in pure Rust, OFF and STL through OpenMesh.
pub fn read_soup(path: &Path) -> Result<PolySoup> {
    read_soup_with(path, Format::from_path(path)?.default_reader())
}

/// Reads a polygon soup with the given reader.
pub fn read_soup_with(path: &Path, reader: Reader) -> Result<PolySoup> {
    let format = Format::from_path(path)?;
    match (reader, format) {
        (Reader::Rust, Format::Obj) => Ok(read_obj(path)?.soup),
        (Reader::Rust, Format::Ply) => read_ply(path),
        (Reader::Rust, f) => Err(Error::InvalidArgument(format!(
            "{}: the pure-Rust readers do not handle {f:?}; use the OpenMesh reader",
            path.display()
        ))),
        (Reader::OpenMesh, _) => read_openmesh(path),
    }
}

/// Reads and validates a mesh: the triangle mesh the pipeline works on, and
/// the report of what was found and cleaned up.
pub fn read_mesh(path: &Path) -> Result<ValidatedMesh> {
    validate_soup(read_soup(path)?, path)
}

/// Reads a control mesh: polygons plus, for OBJ, the `t crease` / `t corner`
/// tags. The mesh must be a manifold, consistently oriented polygon mesh
/// without unreferenced vertices; violations name the file and the element.
pub fn read_control_mesh(path: &Path) -> Result<ControlMesh> {
    let (soup, creases, corners) = match Format::from_path(path)? {
        Format::Obj => {
            let o = read_obj(path)?;
            (o.soup, o.creases, o.corners)
        }
        _ => (read_soup(path)?, Vec::new(), Vec::new()),
    };
    let in_file = |e: Error| match e {
        Error::Topology { element, msg } => Error::invalid_mesh(path, element, msg),
        e => e,
    };
    let mut mesh = ControlMesh::from_soup(&soup).map_err(in_file)?;
    for (a, b, s) in creases {
        mesh.set_crease(VertexId(a), VertexId(b), s)
            .map_err(in_file)?;
    }
    for (v, s) in corners {
        mesh.set_corner(VertexId(v), s).map_err(in_file)?;
    }
    Ok(mesh)
}
