//! Build script: generate the cxx bridges, then let the root `CMakeLists.txt`
//! build the C++ side (wrappers + generated shims) into one static library.
//!
//! STACK-NOTES: `cxx_build::bridges` must run before CMake because the C++
//! wrappers include the generated headers under `OUT_DIR/cxxbridge/`.

use std::path::PathBuf;

const BRIDGES: &[&str] = &[
    "src/ffi/osd.rs",
    "src/ffi/embree.rs",
    "src/ffi/eigen.rs",
    "src/ffi/openmesh.rs",
    "src/embed/bridge.rs",
];

fn main() {
    let out_dir = PathBuf::from(std::env::var("OUT_DIR").unwrap());
    // Generate the shims and headers only: CMake compiles them together with
    // the wrappers so the whole C++ side is one archive with one set of flags.
    let _ = cxx_build::bridges(BRIDGES);
    let cxxbridge = out_dir.join("cxxbridge");

    // Debug cargo builds would otherwise compile OpenSubdiv/Embree wrappers at -O0.
    let dst = cmake::Config::new(".")
        .profile("RelWithDebInfo")
        .define("SUBDFIT_CPP_ONLY", "ON")
        .define("SUBDFIT_CXXBRIDGE_DIR", &cxxbridge)
        .build_target("subdfit_cpp")
        .build();

    println!("cargo:rustc-link-search=native={}/build", dst.display());
    println!("cargo:rustc-link-lib=static=subdfit_cpp");
    // STACK-NOTES: a static library built by CMake does not pass its link
    // dependencies on, so name them here.
    for lib in ["osdCPU", "embree3", "tbb", "OpenMeshCore", "gomp", "stdc++"] {
        println!("cargo:rustc-link-lib=dylib={lib}");
    }
    for p in BRIDGES {
        println!("cargo:rerun-if-changed={p}");
    }
    println!("cargo:rerun-if-changed=cpp");
    println!("cargo:rerun-if-changed=include");
    println!("cargo:rerun-if-changed=CMakeLists.txt");
}
