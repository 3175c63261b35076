#[cxx::bridge(namespace = "subdfit::eigen")]
pub(crate) mod bridge {
    unsafe extern "C++" {
        include!("subdfit/cpp/eigen_bridge.h");
        /// Version string of the wrapped library (smoke test of the bridge).
        fn library_version() -> Result<String>;
    }
}
