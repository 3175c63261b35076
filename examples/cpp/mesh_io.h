#pragma once
// Reading and writing meshes for the example hosts: OpenMesh reads any format
// it knows into flat arrays (double precision points), and the writers format
// numbers exactly as the Rust library does, so outputs compare byte for byte
// with the `subdfit` CLI's.

#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <stdexcept>
#include <string>
#include <vector>

#include <OpenMesh/Core/IO/MeshIO.hh>
#include <OpenMesh/Core/Mesh/PolyMesh_ArrayKernelT.hh>

#include <subdfit/subdfit.hpp>

namespace example {

struct Traits : OpenMesh::DefaultTraits {
  using Point = OpenMesh::Vec3d;
  using Normal = OpenMesh::Vec3d;
};
using PolyMesh = OpenMesh::PolyMesh_ArrayKernelT<Traits>;

// A mesh as the API takes it; `view()` borrows these arrays.
struct FlatMesh {
  std::vector<double> positions;
  std::vector<std::uint32_t> face_sizes;
  std::vector<std::uint32_t> face_indices;

  subdfit::MeshView view() const { return {positions, face_sizes, face_indices}; }
};

inline FlatMesh read_mesh(const std::string& path) {
  PolyMesh mesh;
  OpenMesh::IO::Options opt;
  if (!OpenMesh::IO::read_mesh(mesh, path, opt))
    throw std::runtime_error(path + ": OpenMesh cannot read this file");
  FlatMesh out;
  out.positions.reserve(3 * mesh.n_vertices());
  for (auto v : mesh.vertices()) {
    const auto& p = mesh.point(v);
    for (int k = 0; k < 3; ++k) out.positions.push_back(p[k]);
  }
  out.face_sizes.reserve(mesh.n_faces());
  for (auto f : mesh.faces()) {
    std::uint32_t n = 0;
    for (auto v : mesh.fv_range(f)) {
      out.face_indices.push_back(static_cast<std::uint32_t>(v.idx()));
      ++n;
    }
    out.face_sizes.push_back(n);
  }
  return out;
}

// Rust's `{}` for f64: the shortest digits that round-trip, never an exponent
// (std::to_chars in fixed format without a precision is exactly that).
inline void append_display(std::string& out, double x) {
  if (std::isnan(x)) {
    out += "NaN";
    return;
  }
  char buf[512];
  auto r = std::to_chars(buf, buf + sizeof buf, x, std::chars_format::fixed);
  out.append(buf, r.ptr);
}

// Rust's `{:e}` for f64: shortest round-trip digits, exponent without '+' or
// leading zeros ("1.5e-7", "1e20").
inline void append_exp(std::string& out, double x) {
  char buf[64];
  auto r = std::to_chars(buf, buf + sizeof buf, x, std::chars_format::scientific);
  std::string s(buf, r.ptr);
  auto e = s.find('e');
  std::string mant = s.substr(0, e);
  int exp = std::stoi(s.substr(e + 1));
  out += mant;
  out += 'e';
  out += std::to_string(exp);
}

// The number format of subdfit's OBJ writer (src/io/write.rs, fmt_f64).
inline void append_obj_number(std::string& out, double x) {
  double a = std::fabs(x);
  if (x == 0.0 || (a >= 1e-5 && a < 1e16) || !std::isfinite(x))
    append_display(out, x);
  else
    append_exp(out, x);
}

inline void write_file(const std::string& path, const std::string& text);

// Writes the control mesh as subdfit's OBJ writer does: positions, UVs when
// there are any, faces (1-based), then OpenSubdiv's crease/corner tags.
inline void write_control_obj(const std::string& path, const subdfit::ControlMesh& m) {
  std::string text = "# subdfit 0.1.0\n# " + std::to_string(m.num_vertices()) + " vertices, " +
                     std::to_string(m.num_faces()) + " faces, " + std::to_string(m.creases.size()) +
                     " creases, " + std::to_string(m.corners.size()) + " corners" +
                     (m.uvs.empty() ? "" : "; vt: displacement.exr atlas") + "\n";
  for (std::size_t i = 0; i < m.num_vertices(); ++i) {
    text += 'v';
    for (int k = 0; k < 3; ++k) {
      text += ' ';
      append_obj_number(text, m.positions[3 * i + k]);
    }
    text += '\n';
  }
  for (std::size_t i = 0; i + 1 < m.uvs.size(); i += 2) {
    text += "vt ";
    append_obj_number(text, m.uvs[i]);
    text += ' ';
    append_obj_number(text, m.uvs[i + 1]);
    text += '\n';
  }
  const bool uv = m.uv_indices.size() == m.face_indices.size() && !m.uvs.empty();
  std::size_t k = 0;
  for (std::uint32_t n : m.face_sizes) {
    text += 'f';
    for (std::uint32_t c = 0; c < n; ++c, ++k) {
      text += ' ' + std::to_string(std::uint64_t(m.face_indices[k]) + 1);
      if (uv) text += '/' + std::to_string(std::uint64_t(m.uv_indices[k]) + 1);
    }
    text += '\n';
  }
  for (const auto& c : m.creases) {
    text += "t crease 2/1/0 " + std::to_string(c.i) + ' ' + std::to_string(c.j) + ' ';
    append_obj_number(text, c.sharpness);
    text += '\n';
  }
  for (const auto& c : m.corners) {
    text += "t corner 1/1/0 " + std::to_string(c.i) + ' ';
    append_obj_number(text, c.sharpness);
    text += '\n';
  }
  write_file(path, text);
}

// Writes `text` under a temporary name, then renames: never a half-written
// file.
inline void write_file(const std::string& path, const std::string& text) {
  const std::string tmp = path + ".tmp";
  std::FILE* f = std::fopen(tmp.c_str(), "wb");
  if (!f) throw std::runtime_error(path + ": cannot open for writing");
  bool ok = std::fwrite(text.data(), 1, text.size(), f) == text.size();
  ok = (std::fclose(f) == 0) && ok;
  if (!ok || std::rename(tmp.c_str(), path.c_str()) != 0) {
    std::remove(tmp.c_str());
    throw std::runtime_error(path + ": write failed");
  }
}

}  // namespace example
