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
    /// Data handed to the library in memory, with no file behind it (a
    /// mesh, a Fitmap, a face-varying channel, control positions), that
    /// cannot be used: the in-memory counterpart of [`Error::InvalidMesh`].
    /// `what` names the data (`input mesh`, `Fitmap`, …), `element` the
    /// offending element (`vertex 12`, `face 7`, `mesh`); a host that read
    /// it from a file names the file with [`Error::context`].
    #[error("{what}: {element}: {msg}")]
    InvalidData {
        what: String,
        element: String,
        msg: String,
    },
    /// A library function was called against its contract: arguments that
    /// disagree with each other or with the mesh they go with (a list of
    /// the wrong length, an id out of range, a surface location off its
    /// face). Neither a bad option nor a bad mesh: the calling code is at
    /// fault, and a host that builds these arguments itself (the CLI)
    /// never produces one. Its kind is `Input`, the caller's side; inside
    /// the library, a call that can only fail by a bug of subdfit's own
    /// says so with [`Error::Internal`] instead.
    #[error("{0}")]
    InvalidArgument(String),
    /// An option out of its domain: `option` names it as the CLI spells
    /// it (`tolerance`, `max_error`, …); the message says the valid range.
    #[error("{msg}")]
    InvalidOption { option: String, msg: String },
    /// A numerical stage did not produce a usable result on a valid input
    /// (a solve that diverged, a field with no consistent sizing, …).
    #[error("{stage}: {msg}")]
    Numerical { stage: String, msg: String },
    /// An invariant of the library itself broke: a bug in subdfit, never
    /// the caller's fault.
    #[error(
        "internal error (a bug in subdfit, please report it with the input and the command): {msg}"
    )]
    Internal { msg: String },
    /// The caller's progress callback asked to stop (CLI, library, C++
    /// embedding); nothing was written and no state is left behind.
    #[error("cancelled by the caller during stage '{stage}'")]
    Cancelled { stage: String },
    /// An error with what the host was doing when it happened (the input's
    /// name, the output folder), as the CLI prefixes it; its kind is its
    /// source's.
    #[error("{context}: {source}")]
    Context {
        context: String,
        #[source]
        source: Box<Error>,
    },
    /// An error about one of several meshes of a call, with the role of
    /// that mesh (`"input mesh"`, `"control mesh"`), as the CLI says it.
    #[error("{role}: {source}")]
    Role {
        role: &'static str,
        #[source]
        source: Box<Error>,
    },
}

/// What kind of failure an [`Error`] is, for hosts that act on it: the
/// CLI's exit code, the C++ API's `subdfit::Error::kind()`, the Python
/// exception class.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum ErrorKind {
    /// Bad input: a file that cannot be read or parsed, a mesh that cannot
    /// be used, an argument out of its domain.
    Input,
    /// An option out of its domain.
    Option,
    /// A numerical stage failed on a valid input (or a backend did).
    Numerical,
    /// A bug in subdfit.
    Internal,
    /// The caller's progress callback cancelled the run.
    Cancelled,
}

impl ErrorKind {
    /// The kind's stable code across the C++ bridge (`subdfit::ErrorKind`
    /// in `include/subdfit/subdfit.hpp` spells the same numbers).
    pub fn code(self) -> u8 {
        match self {
            ErrorKind::Input => 1,
            ErrorKind::Option => 2,
            ErrorKind::Numerical => 3,
            ErrorKind::Internal => 4,
            ErrorKind::Cancelled => 5,
        }
    }

    /// The kind of [`ErrorKind::code`] `c` (`Internal` for an unknown one).
    pub fn from_code(c: u8) -> Self {
        match c {
            1 => ErrorKind::Input,
            2 => ErrorKind::Option,
            3 => ErrorKind::Numerical,
            5 => ErrorKind::Cancelled,
            _ => ErrorKind::Internal,
        }
    }
}

impl Error {
    /// What kind of failure this is (a [`Error::Role`] is its source's).
    pub fn kind(&self) -> ErrorKind {
        match self {
            Error::Io { .. }
            | Error::Parse { .. }
            | Error::InvalidMesh { .. }
            | Error::Topology { .. }
            | Error::InvalidData { .. }
            | Error::InvalidArgument(_) => ErrorKind::Input,
            Error::InvalidOption { .. } => ErrorKind::Option,
            Error::Backend { .. } | Error::RankDeficient { .. } | Error::Numerical { .. } => {
                ErrorKind::Numerical
            }
            Error::Internal { .. } => ErrorKind::Internal,
            Error::Cancelled { .. } => ErrorKind::Cancelled,
            Error::Role { source, .. } | Error::Context { source, .. } => source.kind(),
        }
    }

    /// An option out of its domain (see [`Error::InvalidOption`]).
    pub fn option(option: impl Into<String>, msg: impl Into<String>) -> Self {
        Error::InvalidOption {
            option: option.into(),
            msg: msg.into(),
        }
    }

    /// Unusable in-memory data (see [`Error::InvalidData`]).
    pub fn invalid_data(
        what: impl Into<String>,
        element: impl Into<String>,
        msg: impl Into<String>,
    ) -> Self {
        Error::InvalidData {
            what: what.into(),
            element: element.into(),
            msg: msg.into(),
        }
    }

    /// A numerical failure of `stage` (see [`Error::Numerical`]).
    pub fn numerical(stage: impl Into<String>, msg: impl Into<String>) -> Self {
        Error::Numerical {
            stage: stage.into(),
            msg: msg.into(),
        }
    }

    /// A broken invariant of the library (see [`Error::Internal`]).
    pub fn internal(msg: impl Into<String>) -> Self {
        Error::Internal { msg: msg.into() }
    }

    /// The same error with its message prefixed by `context` (`"{context}:
    /// {msg}"`, see [`Error::Context`]), keeping its kind: what a host adds
    /// to say which of its calls failed (e.g. the output folder a write
    /// went to). A cancel stays as it is.
    pub fn context(self, context: impl std::fmt::Display) -> Self {
        match self {
            Error::Cancelled { .. } => self,
            e => Error::Context {
                context: context.to_string(),
                source: Box::new(e),
            },
        }
    }

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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kinds_survive_roles_and_context() {
        let option = Error::option("tolerance", "tolerance τ = 5 must be in (0, 1]");
        let input = Error::invalid_mesh("m.obj", "face 3", "index 9 out of range");
        let numerical = Error::backend("Eigen", "not positive definite");
        let bug = Error::internal("candidate 3 lost");
        for (e, kind) in [
            (option, ErrorKind::Option),
            (input, ErrorKind::Input),
            (numerical, ErrorKind::Numerical),
            (bug, ErrorKind::Internal),
        ] {
            let text = e.to_string();
            assert_eq!(e.kind(), kind, "{text}");
            let e = e.in_role("input mesh");
            assert_eq!(e.kind(), kind, "{e}");
            // A host's prefix (embed's input name) keeps the kind and the text.
            let e = e.context("bunny.ply");
            assert_eq!(e.kind(), kind, "{e}");
            assert!(e.to_string().starts_with("bunny.ply: "), "{e}");
            assert!(e.to_string().contains(&text), "{e} lost {text}");
            assert_eq!(ErrorKind::from_code(kind.code()), kind);
        }
        let bug = Error::internal("x").to_string();
        assert!(
            bug.contains("a bug in subdfit") && bug.contains("report"),
            "{bug}"
        );
        let cancelled = Error::Cancelled {
            stage: "fit".into(),
        }
        .context("m.obj");
        assert!(matches!(cancelled, Error::Cancelled { .. }));
    }
}
