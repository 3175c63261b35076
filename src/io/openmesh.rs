//! OpenMesh (C++) reader: OBJ, PLY, OFF and STL (ascii and binary).
//!
//! Not the default for any format: an independent cross-check of the
//! pure-Rust readers, which agree with it on valid files (its OFF and STL
//! readers mishandle hostile ones, see `off.rs` and `stl.rs`). OpenMesh parses into a
//! collecting importer (see `cpp/openmesh_bridge.cpp`), so non-manifold input
//! reaches [`crate::mesh::validate_soup`] unrepaired. One deliberate
//! difference: OpenMesh's STL reader merges coincident corners into shared
//! vertices (STL stores none) and skips faces that become degenerate by it.

use std::path::Path;

use crate::error::{Error, Result};
use crate::ffi::openmesh::bridge;
use crate::mesh::PolySoup;
use crate::DVec3;

/// Reads `path` with OpenMesh; the format follows the extension.
pub fn read_openmesh(path: &Path) -> Result<PolySoup> {
    // OpenMesh reports a missing file only through its log; check first so
    // that the error is a proper `Error::Io` with the OS reason.
    std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    let name = path.to_str().ok_or_else(|| {
        Error::backend(
            "OpenMesh",
            format!("{}: the path is not valid UTF-8", path.display()),
        )
    })?;
    let raw = bridge::read_raw_soup(name)
        .map_err(|e| Error::backend("OpenMesh", format!("{}: {}", path.display(), e.what())))?;
    let positions = raw
        .positions
        .chunks_exact(3)
        .map(|c| DVec3::new(c[0], c[1], c[2]))
        .collect();
    let mut face_offsets = Vec::with_capacity(raw.face_sizes.len() + 1);
    face_offsets.push(0u32);
    let mut end = 0u64;
    for &n in &raw.face_sizes {
        end += n as u64;
        face_offsets.push(u32::try_from(end).map_err(|_| {
            Error::backend(
                "OpenMesh",
                format!("{}: too many face corners", path.display()),
            )
        })?);
    }
    if end as usize != raw.face_indices.len() {
        return Err(Error::backend(
            "OpenMesh",
            format!(
                "{}: bridge returned {} face corners for face sizes summing to {end}",
                path.display(),
                raw.face_indices.len()
            ),
        ));
    }
    Ok(PolySoup {
        positions,
        face_offsets,
        face_indices: raw.face_indices,
    })
}
