#include "subdfit/cpp/embree_bridge.h"
#include <embree3/rtcore.h>
namespace subdfit::embree {
rust::String library_version() { return rust::String(RTC_VERSION_STRING); }
}
