#[cxx::bridge(namespace = "subdfit::embree")]
pub(crate) mod bridge {
    unsafe extern "C++" {
        include!("subdfit/cpp/embree_bridge.h");
        /// Version string of the wrapped library (smoke test of the bridge).
        fn library_version() -> Result<String>;
    }
}
