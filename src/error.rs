//! Typed errors of the library. Every message names the file and the element
//! at fault, and, where there is one, how to fix it.

use std::path::PathBuf;

/// Result alias used throughout the library.
pub type Result<T, E = Error> = std::result::Result<T, E>;

#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// The file could not be opened, read or written.
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// The file is not a well-formed mesh file of its format.
    #[error("{}: {location}: {msg}", path.display())]
    Parse {
        path: PathBuf,
        /// Where in the file: `line 12`, `byte 4096`, `face 17`, ...
        location: String,
        msg: String,
    },
    /// The mesh was read but cannot be used: NaN coordinates, out-of-range
    /// indices, empty, non-manifold where a manifold is required, ...
    #[error("{}: {element}: {msg}", path.display())]
    InvalidMesh {
        path: PathBuf,
        /// The offending element: `vertex 12`, `face 7`, `edge (3, 9)`, ...
        element: String,
        msg: String,
    },
    /// A control mesh built in memory violates an invariant.
    #[error("control mesh: {element}: {msg}")]
    Topology { element: String, msg: String },
    /// A C++ backend (OpenSubdiv, Embree, Eigen, OpenMesh) reported an error.
    #[error("{backend}: {msg}")]
    Backend { backend: &'static str, msg: String },
    /// A least-squares system has no unique solution.
    #[error("least squares: the system is rank deficient ({msg}); add a regularisation term or more rows")]
    RankDeficient { msg: String },
    /// A caller passed an argument out of its domain.
    #[error("{0}")]
    InvalidArgument(String),
    /// The caller's progress callback asked to stop (CLI, library, C++
    /// embedding); nothing was written and no state is left behind.
    #[error("cancelled by the caller during stage '{stage}'")]
    Cancelled { stage: String },
    /// An error about one of several meshes of a call, with the role of
    /// that mesh (`"input mesh"`, `"control mesh"`), as the CLI says it.
    #[error("{role}: {source}")]
    Role {
        role: &'static str,
        #[source]
        source: Box<Error>,
    },
}

impl Error {
    /// This error, said of the mesh in `role` (see [`Error::Role`]).
    pub fn in_role(self, role: &'static str) -> Self {
        Error::Role {
            role,
            source: Box::new(self),
        }
    }

    pub(crate) fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.into(),
            source,
        }
    }

    pub(crate) fn parse(
        path: impl Into<PathBuf>,
        location: impl Into<String>,
        msg: impl Into<String>,
    ) -> Self {
        Error::Parse {
            path: path.into(),
            location: location.into(),
            msg: msg.into(),
        }
    }

    pub(crate) fn invalid_mesh(
        path: impl Into<PathBuf>,
        element: impl Into<String>,
        msg: impl Into<String>,
    ) -> Self {
        Error::InvalidMesh {
            path: path.into(),
            element: element.into(),
            msg: msg.into(),
        }
    }

    pub(crate) fn topology(element: impl Into<String>, msg: impl Into<String>) -> Self {
        Error::Topology {
            element: element.into(),
            msg: msg.into(),
        }
    }

    pub(crate) fn backend(backend: &'static str, msg: impl Into<String>) -> Self {
        Error::Backend {
            backend,
            msg: msg.into(),
        }
    }
}
