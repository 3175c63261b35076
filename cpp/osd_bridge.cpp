#include "subdfit/cpp/osd_bridge.h"
#include <opensubdiv/version.h>
#include <string>
namespace subdfit::osd {
rust::String library_version() {
  return rust::String(std::to_string(OPENSUBDIV_VERSION_MAJOR) + "." + std::to_string(OPENSUBDIV_VERSION_MINOR) + "." +
                      std::to_string(OPENSUBDIV_VERSION_PATCH));
}
}  // namespace subdfit::osd
