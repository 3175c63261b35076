//! Mesh input and output. Pure-Rust readers for OBJ, PLY, OFF and STL (the
//! default), OpenMesh's (C++) for the same formats as a cross-check; writers
//! for OBJ and binary PLY.
//!
//! The readers never return a mesh that is not what the file says: a BOM is
//! skipped, and truncation, counts that disagree with the data, trailing
//! data, out-of-range indices and NaN/infinite coordinates are errors naming
//! the file and the line, byte, vertex or face.
//!
//! Readers return the raw [`PolySoup`]; [`read_mesh`] adds validation
//! ([`crate::mesh::validate_soup`]) and [`read_control_mesh`] builds a
//! [`ControlMesh`] with the sharpness tags of an OBJ shape file.

mod obj;
mod obj_uv;
mod off;
mod openmesh;
mod ply;
mod stl;
mod text;
pub mod usd;
mod write;

use std::path::Path;

use crate::error::{Error, Result};
use crate::mesh::{
    validate_soup, ControlMesh, FVarChannel, PolySoup, SchemeOptions, ValidatedMesh, VertexId,
};

pub use obj::{parse_obj, read_obj, ObjMesh};
pub use obj_uv::{control_obj_with_uvs, write_control_obj_with_uvs};
pub use off::{parse_off, read_off};
pub use openmesh::read_openmesh;
pub use ply::{parse_ply, read_ply};
pub use stl::{parse_stl, read_stl};

pub use usd::{usda_text_with, write_usda, write_usda_with, UsdOptions};
pub use write::{
    scheme_tags, write_atomically, write_control_file, write_control_obj, write_obj, write_ply,
};

/// Which implementation parses a file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Reader {
    /// Pure-Rust readers: OBJ, PLY, OFF, STL.
    Rust,
    /// OpenMesh's readers: OBJ, PLY, OFF, STL. Kept for cross-checks only:
    /// its OFF reader reads uninitialised memory and its STL reader accepts
    /// truncated files (see the `off` and `stl` module docs).
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
            _ => Err(Error::invalid_mesh(
                path,
                "file name",
                "unknown mesh format; use .obj, .ply, .off or .stl",
            )),
        }
    }

    /// The reader used by default: pure Rust for every format.
    pub fn default_reader(self) -> Reader {
        Reader::Rust
    }
}

/// Reads a polygon soup from `path`, picking the format from the extension.
pub fn read_soup(path: &Path) -> Result<PolySoup> {
    read_soup_with(path, Format::from_path(path)?.default_reader())
}

/// Reads a polygon soup with the given reader.
pub fn read_soup_with(path: &Path, reader: Reader) -> Result<PolySoup> {
    let format = Format::from_path(path)?;
    match reader {
        Reader::Rust => {
            let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
            read_soup_bytes(&bytes, format, path)
        }
        Reader::OpenMesh => read_openmesh(path),
    }
}

/// Parses a polygon soup already in memory with the pure-Rust reader for
/// `format`; `name` only names the file in errors. [`read_soup`] is this on
/// the file's bytes (the fuzz targets call it directly).
pub fn read_soup_bytes(bytes: &[u8], format: Format, name: &Path) -> Result<PolySoup> {
    match format {
        Format::Obj => Ok(parse_obj(bytes, name)?.soup),
        Format::Ply => parse_ply(bytes, name),
        Format::Off => parse_off(bytes, name),
        Format::Stl => parse_stl(bytes, name),
    }
}

/// Reads and validates a mesh: the triangle mesh the pipeline works on, and
/// the report of what was found and cleaned up.
pub fn read_mesh(path: &Path) -> Result<ValidatedMesh> {
    validate_soup(read_soup(path)?, path)
}

/// A control mesh file's polygons, creases `(a, b, s)`, corners `(v, s)`
/// and scheme options (OBJ's shape-file tags; none and the defaults in the
/// other formats).
type ControlParts = (
    PolySoup,
    Vec<(u32, u32, f64)>,
    Vec<(u32, f64)>,
    SchemeOptions,
    Option<FVarChannel>,
    Option<String>,
);

fn read_control_parts(path: &Path) -> Result<ControlParts> {
    Ok(match Format::from_path(path)? {
        Format::Obj => {
            let o = read_obj(path)?;
            (o.soup, o.creases, o.corners, o.scheme, o.uv, o.uv_note)
        }
        _ => (
            read_soup(path)?,
            Vec::new(),
            Vec::new(),
            SchemeOptions::default(),
            None,
            None,
        ),
    })
}

/// The error for a file whose scheme options a reader of the crate's
/// defaults would drop.
fn non_default_scheme(path: &Path, scheme: &SchemeOptions) -> Error {
    // Dropping them would change the surface without a word.
    Error::invalid_mesh(
        path,
        "scheme tags",
        format!(
            "the file asks for {scheme}; this reader keeps only the crate's defaults \
             (use `read_control_file`, or `subdfit limit`/`diff-limit` which honour them)"
        ),
    )
}

/// [`read_control_mesh`] for layouts other tools wrote (`subdfit fit`):
/// unreferenced vertices, repeated corners, degenerate faces and
/// non-manifold vertices and edges are repaired instead of refused
/// ([`crate::mesh::control_from_foreign_soup`]), and the repairs returned.
pub fn read_control_mesh_as_found(
    path: &Path,
) -> Result<(ControlMesh, crate::mesh::ForeignRepairs)> {
    let (soup, creases, corners, scheme, _, _) = read_control_parts(path)?;
    if !scheme.is_default() {
        return Err(non_default_scheme(path, &scheme));
    }
    crate::mesh::control_from_foreign_soup(&soup, &creases, &corners).map_err(|e| match e {
        Error::Topology { element, msg } => Error::invalid_mesh(path, element, msg),
        e => e,
    })
}

/// Reads a control mesh: polygons plus, for OBJ, the `t crease` / `t corner`
/// tags. The mesh must be a manifold, consistently oriented polygon mesh
/// without unreferenced vertices; violations name the file and the element.
pub fn read_control_mesh(path: &Path) -> Result<ControlMesh> {
    let ControlFile { mesh, scheme, .. } = read_control_file(path)?;
    if !scheme.is_default() {
        return Err(non_default_scheme(path, &scheme));
    }
    Ok(mesh)
}

/// A control mesh with the scheme options its file states.
#[derive(Clone, Debug)]
pub struct ControlFile {
    pub mesh: ControlMesh,
    pub scheme: SchemeOptions,
    /// The texture coordinates (`vt`, `f v/vt`) as a face-varying channel.
    pub uv: Option<FVarChannel>,
    /// Why the file's texture coordinates were not kept, if it has some.
    pub uv_note: Option<String>,
}

/// Reads a control mesh and, from an OBJ shape file, its sharpness tags
/// and scheme options (see the `obj` module doc); other formats carry the
/// default options.
pub fn read_control_file(path: &Path) -> Result<ControlFile> {
    let (soup, creases, corners, scheme, uv, uv_note) = read_control_parts(path)?;
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
    if let Some(ch) = &uv {
        ch.check(&mesh)
            .map_err(|e| Error::invalid_mesh(path, "texture coordinates", e.to_string()))?;
    }
    Ok(ControlFile {
        mesh,
        scheme,
        uv,
        uv_note,
    })
}

/// Reads a control mesh as OpenSubdiv takes it (issue 18): non-manifold
/// edges and vertices and unused vertices accepted, with the file's scheme
/// options ([`crate::mesh::SplitControl`]: the file's topology for
/// OpenSubdiv, a manifold copy for the Rust evaluators; what neither can
/// reproduce is refused, naming the element). A manifold file gives the
/// mesh [`read_control_file`] reads.
pub fn read_control_split(path: &Path) -> Result<ControlSplitFile> {
    let (soup, creases, corners, scheme, uv, uv_note) = read_control_parts(path)?;
    let split = crate::mesh::SplitControl::new(&soup, &creases, &corners, path)?;
    if let Some(ch) = &uv {
        ch.check(&split.manifold)
            .map_err(|e| Error::invalid_mesh(path, "texture coordinates", e.to_string()))?;
    }
    Ok(ControlSplitFile {
        split,
        scheme,
        uv,
        uv_note,
    })
}

/// What [`read_control_split`] reads.
#[derive(Clone, Debug)]
pub struct ControlSplitFile {
    pub split: crate::mesh::SplitControl,
    pub scheme: SchemeOptions,
    /// The texture coordinates, one index per face corner (the manifold
    /// copy keeps the file's faces and corner order).
    pub uv: Option<FVarChannel>,
    /// Why the file's texture coordinates were not kept, if it has some.
    pub uv_note: Option<String>,
}
