#[cxx::bridge(namespace = "subdfit::openmesh")]
pub(crate) mod bridge {
    unsafe extern "C++" {
        include!("subdfit/cpp/openmesh_bridge.h");
        /// Version string of the wrapped library (smoke test of the bridge).
        fn library_version() -> Result<String>;
    }
}
