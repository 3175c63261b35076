// convert_concurrent A B OUT_A.obj OUT_B.obj
// Two conversions at once from two host threads: the library keeps no state
// between or across calls, so each result equals that of a lone call.

#include <cstdio>
#include <string>
#include <thread>

#include "mesh_io.h"

int main(int argc, char** argv) {
  if (argc != 5) {
    std::fprintf(stderr, "usage: %s A B OUT_A.obj OUT_B.obj\n", argv[0]);
    return 2;
  }
  std::string errors[2];
  // OpenMesh's readers share process-wide state (its IOManager singleton and
  // per-format reader objects), so the host reads both inputs first; the
  // two subdfit::convert calls then run at the same time.
  example::FlatMesh meshes[2];
  for (int k = 0; k < 2; ++k) {
    try {
      meshes[k] = example::read_mesh(argv[1 + k]);
    } catch (const std::exception& e) {
      errors[k] = e.what();
    }
  }
  auto job = [&](int k) {
    if (!errors[k].empty()) return;
    try {
      subdfit::Options options;
      options.source_name = argv[1 + k];
      const subdfit::Result r = subdfit::convert(meshes[k].view(), options);
      example::write_control_obj(argv[3 + k], r.control);
    } catch (const std::exception& e) {
      errors[k] = e.what();
    }
  };
  std::thread a(job, 0), b(job, 1);
  a.join();
  b.join();
  int status = 0;
  for (int k = 0; k < 2; ++k)
    if (!errors[k].empty()) {
      std::fprintf(stderr, "convert_concurrent: %s: error: %s\n", argv[1 + k], errors[k].c_str());
      status = 1;
    }
  return status;
}
