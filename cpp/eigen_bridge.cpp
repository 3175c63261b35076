#include "subdfit/cpp/eigen_bridge.h"
#include <Eigen/Core>
#include <string>
namespace subdfit::eigen {
rust::String library_version() {
  return rust::String(std::to_string(EIGEN_WORLD_VERSION) + "." + std::to_string(EIGEN_MAJOR_VERSION) + "." +
                      std::to_string(EIGEN_MINOR_VERSION));
}
}
