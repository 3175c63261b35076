// limit CONTROL.obj OSD.csv [RUST.csv]
// Limit points of a control mesh with the OpenSubdiv backend (and the Rust
// one), as CSV in the format of `subdfit limit CONTROL -o OUT.csv`.

#include <cstdio>
#include <string>

#include "mesh_io.h"

static void write_csv(const std::string& path, const std::vector<subdfit::LimitSample>& pts) {
  std::string text = "vertex,x,y,z,nx,ny,nz\n";
  for (std::size_t i = 0; i < pts.size(); ++i) {
    text += std::to_string(i);
    const auto& p = pts[i];
    for (double x : {p.position.x, p.position.y, p.position.z, p.normal.x, p.normal.y, p.normal.z}) {
      text += ',';
      example::append_display(text, x);
    }
    text += '\n';
  }
  std::FILE* f = std::fopen(path.c_str(), "wb");
  if (!f || std::fwrite(text.data(), 1, text.size(), f) != text.size() || std::fclose(f) != 0)
    throw std::runtime_error(path + ": write failed");
}

int main(int argc, char** argv) {
  if (argc < 3 || argc > 4) {
    std::fprintf(stderr, "usage: %s CONTROL.obj OSD.csv [RUST.csv]\n", argv[0]);
    return 2;
  }
  try {
    const example::FlatMesh mesh = example::read_mesh(argv[1]);
    const subdfit::ControlMeshView control{mesh.view(), {}, {}};
    write_csv(argv[2], subdfit::limit_points(control, subdfit::Backend::OpenSubdiv));
    if (argc == 4) write_csv(argv[3], subdfit::limit_points(control, subdfit::Backend::Rust));
  } catch (const std::exception& e) {
    std::fprintf(stderr, "limit: error: %s\n", e.what());
    return 1;
  }
  return 0;
}
