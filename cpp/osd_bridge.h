#pragma once
#include "rust/cxx.h"

namespace subdfit::osd {
rust::String library_version();
}
