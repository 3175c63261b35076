//! cxx bridges only. The real C++ lives in `cpp/`; nothing here is public.
//! Every C++ call is declared `-> Result<T>` so that a C++ exception becomes
//! a Rust `Err` instead of crossing the boundary.

pub(crate) mod eigen;
pub(crate) mod embed;
pub(crate) mod embree;
pub(crate) mod openmesh;
pub(crate) mod osd;
