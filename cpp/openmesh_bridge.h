#pragma once
#include "rust/cxx.h"

namespace subdfit::openmesh {
struct RawSoup;

rust::String library_version();

/// Reads a polygon soup with OpenMesh's IOManager. Throws std::runtime_error
/// (turned into a Rust Err by cxx) on failure, with OpenMesh's log attached.
RawSoup read_raw_soup(rust::Str path);
}  // namespace subdfit::openmesh
