//! Test helpers shared by the integration tests.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

use subdfit::mesh::TriMesh;

/// The shared test meshes: `$SUBDFIT_DATA`, else `../shared/data` beside the
/// repository. `None` (with a message saying so) when absent: tests that need
/// the large meshes skip instead of failing on a machine without them.
pub fn data_dir() -> Option<PathBuf> {
    let d = std::env::var_os("SUBDFIT_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data"));
    if d.is_dir() {
        Some(d)
    } else {
        eprintln!(
            "SKIPPED: test data directory {} is absent (set SUBDFIT_DATA)",
            d.display()
        );
        None
    }
}

/// Reads a triangle mesh as it is in the file (no cleanup: unreferenced
/// vertices are kept, so vertex indices match the file).
pub fn load_ply(path: &Path) -> TriMesh {
    let soup = subdfit::io::read_soup(path).unwrap_or_else(|e| panic!("{e}"));
    let triangles = soup
        .faces()
        .map(|f| {
            assert_eq!(f.len(), 3, "{}: not a triangle mesh", path.display());
            [f[0], f[1], f[2]]
        })
        .collect();
    TriMesh {
        positions: soup.positions,
        triangles,
    }
}
