#pragma once
#include "rust/cxx.h"

namespace subdfit::openmesh {
rust::String library_version();
}
