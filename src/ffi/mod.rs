//! cxx bridges to C++ only (OpenSubdiv, Embree, Eigen, OpenMesh), used by
//! the lowest layers; they import nothing from the rest of the crate. (The
//! C++ API's bridge the other way, `extern "Rust"`, is `embed::bridge`.) The real C++ lives in `cpp/`; nothing here is public
//! but [`linked_library_versions`].
//! Every C++ call is declared `-> Result<T>` so that a C++ exception becomes
//! a Rust `Err` instead of crossing the boundary.

pub(crate) mod eigen;
pub(crate) mod embree;
pub(crate) mod openmesh;
pub(crate) mod osd;

/// Versions of the C++ libraries linked in, as `(name, version)`.
pub fn linked_library_versions() -> Vec<(&'static str, String)> {
    let v = |r: std::result::Result<String, cxx::Exception>| {
        r.unwrap_or_else(|e| format!("error: {e}"))
    };
    vec![
        ("OpenSubdiv", v(osd::bridge::library_version())),
        ("Embree", v(embree::bridge::library_version())),
        ("Eigen", v(eigen::bridge::library_version())),
        ("OpenMesh", v(openmesh::bridge::library_version())),
    ]
}
