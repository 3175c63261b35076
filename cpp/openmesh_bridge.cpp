// OpenMesh file reading into flat arrays.
//
// Why a custom importer: OpenMesh's ImporterT<Mesh> feeds a half-edge kernel,
// which refuses or silently splits non-manifold faces ("complex edge" /
// "complex vertex" warnings) and so hides the very defects the validation
// report must show. BaseImporter is the interface OpenMesh's readers talk to
// (OpenMesh/Core/IO/importer/BaseImporter.hh); this one records positions and
// face index lists verbatim and ignores every attribute.

#include "subdfit/cpp/openmesh_bridge.h"
#include "subdfit/src/ffi/openmesh.rs.h"

#include <OpenMesh/Core/IO/IOManager.hh>
#include <OpenMesh/Core/IO/Options.hh>
#include <OpenMesh/Core/IO/importer/BaseImporter.hh>
#include <OpenMesh/Core/System/config.h>
#include <OpenMesh/Core/System/omstream.hh>

#include <iostream>
#include <mutex>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

namespace subdfit::openmesh {

rust::String library_version() {
  return rust::String(std::to_string(OM_VERSION >> 16) + "." + std::to_string((OM_VERSION >> 8) & 0xff));
}

namespace {

using namespace OpenMesh;

class RawImporter final : public IO::BaseImporter {
 public:
  std::vector<double> positions;
  std::vector<uint32_t> face_sizes;
  std::vector<uint32_t> face_indices;

  VertexHandle add_vertex(const Vec3f& p) override { return push(p[0], p[1], p[2]); }
  // Keep double precision where a reader has it (OBJ, ascii OFF/PLY with
  // double properties) instead of the base class's narrowing to Vec3f.
  VertexHandle add_vertex(const Vec3d& p) override { return push(p[0], p[1], p[2]); }
  // PLY reads the properties first and sets the point afterwards.
  VertexHandle add_vertex() override { return push(0.0, 0.0, 0.0); }
  void set_point(VertexHandle vh, const Vec3f& p) override {
    if (!vh.is_valid() || size_t(vh.idx()) >= n_vertices()) return;
    for (int k = 0; k < 3; ++k) positions[3 * size_t(vh.idx()) + k] = p[k];
  }

  FaceHandle add_face(const VHandles& idx) override {
    // Readers pass what the file says; range and size checks happen in Rust
    // (validate_soup) so that both readers report defects the same way.
    for (const auto& vh : idx) face_indices.push_back(uint32_t(vh.idx()));
    face_sizes.push_back(uint32_t(idx.size()));
    return FaceHandle(int(face_sizes.size()) - 1);
  }

  size_t n_vertices() const override { return positions.size() / 3; }
  size_t n_faces() const override { return face_sizes.size(); }
  // No edges are built; readers only use this for statistics.
  size_t n_edges() const override { return 0; }
  void reserve(unsigned int nv, unsigned int, unsigned int nf) override {
    positions.reserve(3 * size_t(nv));
    face_sizes.reserve(nf);
  }

  // ---- everything else is ignored: attributes do not matter here --------
  HalfedgeHandle add_edge(VertexHandle, VertexHandle) override { return HalfedgeHandle(); }
  FaceHandle add_face(HalfedgeHandle) override { return FaceHandle(); }
  void add_face_texcoords(FaceHandle, VertexHandle, const std::vector<Vec2f>&) override {}
  void add_face_texcoords(FaceHandle, VertexHandle, const std::vector<Vec3f>&) override {}
  void set_face_texindex(FaceHandle, int) override {}
  void set_halfedge(VertexHandle, HalfedgeHandle) override {}
  void set_normal(VertexHandle, const Vec3f&) override {}
  void set_normal(VertexHandle, const Vec3d&) override {}
  void set_color(VertexHandle, const Vec3uc&) override {}
  void set_color(VertexHandle, const Vec4uc&) override {}
  void set_color(VertexHandle, const Vec3f&) override {}
  void set_color(VertexHandle, const Vec4f&) override {}
  void set_texcoord(VertexHandle, const Vec2f&) override {}
  void set_status(VertexHandle, const Attributes::StatusInfo&) override {}
  void set_next(HalfedgeHandle, HalfedgeHandle) override {}
  void set_face(HalfedgeHandle, FaceHandle) override {}
  void request_face_texcoords2D() override {}
  void set_texcoord(HalfedgeHandle, const Vec2f&) override {}
  void set_texcoord(VertexHandle, const Vec3f&) override {}
  void set_texcoord(HalfedgeHandle, const Vec3f&) override {}
  void set_status(HalfedgeHandle, const Attributes::StatusInfo&) override {}
  void set_color(EdgeHandle, const Vec3uc&) override {}
  void set_color(EdgeHandle, const Vec4uc&) override {}
  void set_color(EdgeHandle, const Vec3f&) override {}
  void set_color(EdgeHandle, const Vec4f&) override {}
  void set_status(EdgeHandle, const Attributes::StatusInfo&) override {}
  void set_normal(FaceHandle, const Vec3f&) override {}
  void set_normal(FaceHandle, const Vec3d&) override {}
  void set_color(FaceHandle, const Vec3uc&) override {}
  void set_color(FaceHandle, const Vec4uc&) override {}
  void set_color(FaceHandle, const Vec3f&) override {}
  void set_color(FaceHandle, const Vec4f&) override {}
  void set_status(FaceHandle, const Attributes::StatusInfo&) override {}
  void add_texture_information(int, std::string) override {}

 private:
  VertexHandle push(double x, double y, double z) {
    positions.push_back(x);
    positions.push_back(y);
    positions.push_back(z);
    return VertexHandle(int(n_vertices()) - 1);
  }
};

// OpenMesh's IOManager singleton and its log streams are process-wide and not
// thread-safe: one read at a time. The streams (omerr/omlog/omout, see
// OpenMesh/Core/System/omstream.hh) are multiplexers connected to
// std::cerr/clog/cout by default; we detach the console once and attach a
// string buffer whose content becomes part of the error message instead.
std::mutex& io_mutex() {
  static std::mutex m;
  return m;
}

std::ostringstream& captured_log() {
  static std::ostringstream log;
  static bool connected = [] {
    omerr().disconnect(std::cerr);
    omlog().disconnect(std::clog);
    omout().disconnect(std::cout);
    omerr().connect(log);
    omlog().connect(log);
    omout().connect(log);
    return true;
  }();
  (void)connected;
  return log;
}

std::string take_log() {
  omerr().flush();
  omlog().flush();
  omout().flush();
  auto& log = captured_log();
  std::string s = log.str();
  log.str("");
  log.clear();
  // Collapse OpenMesh's multi-line chatter into one line for error messages.
  for (auto& c : s)
    if (c == '\n' || c == '\r') c = ' ';
  while (!s.empty() && s.back() == ' ') s.pop_back();
  return s;
}

}  // namespace

RawSoup read_raw_soup(rust::Str path) {
  const std::string filename(path.data(), path.size());
  std::lock_guard<std::mutex> lock(io_mutex());
  (void)captured_log();
  take_log();  // drop anything left over from earlier calls

  RawImporter importer;
  IO::Options options;  // Default: positions and faces only.
  bool ok = false;
  try {
    ok = IO::IOManager().read(filename, importer, options);
  } catch (const std::exception& e) {
    std::string log = take_log();
    throw std::runtime_error("OpenMesh threw while reading: " + std::string(e.what()) +
                             (log.empty() ? "" : " (" + log + ")"));
  }
  std::string log = take_log();
  if (!ok) {
    throw std::runtime_error("OpenMesh could not read the file" +
                             (log.empty() ? std::string() : ": " + log));
  }

  RawSoup out;
  out.positions.reserve(importer.positions.size());
  for (double x : importer.positions) out.positions.push_back(x);
  out.face_sizes.reserve(importer.face_sizes.size());
  for (uint32_t n : importer.face_sizes) out.face_sizes.push_back(n);
  out.face_indices.reserve(importer.face_indices.size());
  for (uint32_t i : importer.face_indices) out.face_indices.push_back(i);
  out.log = rust::String(log);
  return out;
}

}  // namespace subdfit::openmesh
