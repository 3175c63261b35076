#pragma once
#include "rust/cxx.h"

namespace subdfit::eigen {
rust::String library_version();
}
