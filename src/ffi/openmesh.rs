//! Bridge to OpenMesh's file readers (`cpp/openmesh_bridge.cpp`).
//!
//! Only flat arrays cross: OpenMesh parses the file into a raw-collecting
//! importer (no mesh kernel, so nothing is repaired), and the Rust side turns
//! the arrays into a [`crate::mesh::PolySoup`].

#[cxx::bridge(namespace = "subdfit::openmesh")]
pub(crate) mod bridge {
    /// A polygon soup as OpenMesh's reader saw it.
    struct RawSoup {
        /// `x0 y0 z0 x1 ...`, in the order the reader added the vertices.
        positions: Vec<f64>,
        /// Number of corners of each face, in reading order.
        face_sizes: Vec<u32>,
        /// Vertex indices of all faces, concatenated.
        face_indices: Vec<u32>,
        /// What OpenMesh wrote to its log streams (`omerr`, `omlog`) while
        /// reading; captured instead of going to the console.
        log: String,
    }

    unsafe extern "C++" {
        include!("subdfit/cpp/openmesh_bridge.h");
        /// Version string of the wrapped library (smoke test of the bridge).
        fn library_version() -> Result<String>;
        /// Reads `path` (OBJ, PLY, OFF, STL ascii or binary; OpenMesh picks
        /// the reader from the extension). Throws, i.e. returns `Err`, with
        /// OpenMesh's own message when the reader fails.
        fn read_raw_soup(path: &str) -> Result<RawSoup>;
    }
}
