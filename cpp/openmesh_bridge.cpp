#include "subdfit/cpp/openmesh_bridge.h"
#include <OpenMesh/Core/System/config.h>
namespace subdfit::openmesh {
rust::String library_version() { return rust::String(std::to_string(OM_VERSION >> 16) + "." + std::to_string((OM_VERSION >> 8) & 0xff)); }
}
