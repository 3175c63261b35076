#pragma once
#include "rust/cxx.h"

namespace subdfit::embree {
rust::String library_version();
}
