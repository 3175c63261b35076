// The C++ API (include/subdfit/subdfit.hpp) over the cxx bridge
// src/embed/bridge.rs. This file is the only place where the public types meet
// cxx's: views become rust::Slice (no copy), rust::Vec results are moved
// into std::vector (one copy), and rust::Error becomes subdfit::Error.

#include "subdfit/subdfit.hpp"

#include <algorithm>
#include <cstdlib>
#include <exception>
#include <string>
#include <utility>

#include "subdfit/cpp/api/progress_sink.h"
#include "subdfit/src/embed/bridge.rs.h"

namespace subdfit {
namespace ffi {

bool ProgressSink::report(rust::Str stage, double fraction) const {
  if (!callback_) return true;
  // The public callback takes a NUL-terminated name; rust::Str is not.
  const std::string name(stage.data(), stage.size());
  return callback_(name.c_str(), fraction);
}

}  // namespace ffi

namespace {

template <class T>
rust::Slice<const T> slice(const T* data, std::size_t size) {
  // A Rust slice needs a non-null pointer even when empty; the default
  // rust::Slice is a well-aligned dangling one.
  if (size == 0) return rust::Slice<const T>();
  if (data == nullptr) throw Error("a view has a null pointer but " + std::to_string(size) + " elements");
  return rust::Slice<const T>(data, size);
}
template <class T>
rust::Slice<const T> slice(View<T> v) {
  return slice(v.data, v.size);
}

template <class T>
std::vector<T> to_vector(const rust::Vec<T>& v) {
  return std::vector<T>(v.begin(), v.end());
}

std::string to_string(const rust::String& s) { return std::string(s.data(), s.size()); }

// Flat creases/corners as the bridge takes them (they are few: a copy).
struct Sharpness {
  std::vector<std::uint32_t> crease_vertices;
  std::vector<double> crease_weights;
  std::vector<std::uint32_t> corner_vertices;
  std::vector<double> corner_weights;

  explicit Sharpness(const ControlMeshView& c) {
    if (c.creases.size > 0 && c.creases.data == nullptr) throw Error("creases: null pointer");
    if (c.corners.size > 0 && c.corners.data == nullptr) throw Error("corners: null pointer");
    crease_vertices.reserve(2 * c.creases.size);
    crease_weights.reserve(c.creases.size);
    for (const Crease& k : c.creases) {
      crease_vertices.push_back(k.i);
      crease_vertices.push_back(k.j);
      crease_weights.push_back(k.sharpness);
    }
    for (const Corner& k : c.corners) {
      corner_vertices.push_back(k.i);
      corner_weights.push_back(k.sharpness);
    }
  }
};

std::uint8_t backend_code(Backend b) {
  switch (b) {
    case Backend::OpenSubdiv:
      return 0;
    case Backend::Rust:
      return 1;
  }
  throw Error("unknown backend", ErrorKind::Option);
}

ffi::FfiOptions ffi_options(const Options& o) {
  ffi::FfiOptions r;
  r.tolerance = o.tolerance;
  r.target_faces = o.target_faces;
  r.mode = o.mode == Mode::Organic ? 0 : o.mode == Mode::Mechanical ? 1 : 2;
  r.fit_method = o.fit_method == FitMethod::Sdm ? 1 : 0;
  r.displacement_resolution = o.displacement_resolution;
  r.displacement_samples = o.displacement_samples;
  r.displacement_allocation = o.displacement_allocation == DisplacementAllocation::Uniform ? 1 : 0;
  r.displacement_reconstruction =
      o.displacement_reconstruction == DisplacementReconstruction::BSpline ? 1 : 0;
  r.layout = o.layout == Layout::Field ? 1 : 0;
  r.max_error = o.max_error;
  r.m_fitmap = o.m_fitmap;
  r.tessellation = o.tessellation;
  r.proxy = o.proxy;
  r.exact_metrics = o.exact_metrics;
  r.threads = o.threads;
  // Lossy: a name that is not UTF-8 must not make the call fail.
  r.source_name = rust::String::lossy(o.source_name);
  return r;
}

std::vector<LimitSample> samples(const rust::Vec<double>& flat) {
  std::vector<LimitSample> out(flat.size() / 12);
  for (std::size_t i = 0; i < out.size(); ++i) {
    const double* p = flat.data() + 12 * i;
    out[i] = LimitSample{{p[0], p[1], p[2]}, {p[3], p[4], p[5]}, {p[6], p[7], p[8]},
                         {p[9], p[10], p[11]}};
  }
  return out;
}

Result result(ffi::FfiConversion&& c) {
  Result r;
  const ffi::FfiControlMesh& m = c.control;
  r.control.face_sizes = to_vector(m.face_sizes);
  r.control.face_indices = to_vector(m.face_indices);
  r.control.positions = to_vector(m.positions);
  for (std::size_t k = 0; k < m.crease_weights.size(); ++k)
    r.control.creases.push_back(
        Crease{m.crease_vertices[2 * k], m.crease_vertices[2 * k + 1], m.crease_weights[k]});
  for (std::size_t k = 0; k < m.corner_weights.size(); ++k)
    r.control.corners.push_back(Corner{m.corner_vertices[k], m.corner_weights[k]});
  r.control.uvs = to_vector(m.uvs);
  r.control.uv_indices = to_vector(m.uv_indices);
  r.tiles.reserve(c.tiles.size());
  for (const ffi::FfiTile& t : c.tiles)
    r.tiles.push_back(DisplacementTile{t.face, t.resolution, to_vector(t.values)});
  r.metrics.reserve(c.metrics.size());
  for (const ffi::FfiMetric& x : c.metrics) r.metrics.push_back(Metric{to_string(x.name), x.value});
  r.report_json = to_string(c.report_json);
  r.control_obj.assign(reinterpret_cast<const char*>(c.control_obj.data()), c.control_obj.size());
  return r;
}

// The message of a bridge error and its kind: `guard` in
// src/embed/bridge.rs sends "subdfit-error-kind:N:" ahead of the message.
Error bridge_error(const char* what) {
  static constexpr char tag[] = "subdfit-error-kind:";
  const std::string s = what;
  constexpr std::size_t n = sizeof(tag) - 1;
  if (s.compare(0, n, tag) != 0) return Error(s, ErrorKind::Internal);
  const std::size_t colon = s.find(':', n);
  if (colon == std::string::npos) return Error(s, ErrorKind::Internal);
  const int code = std::atoi(s.substr(n, colon - n).c_str());
  const ErrorKind kind =
      code >= 1 && code <= 5 ? static_cast<ErrorKind>(code) : ErrorKind::Internal;
  return Error(s.substr(colon + 1), kind);
}

// Every bridge call goes through here: rust::Error (an Err from Rust, panics
// included, see `guard` in embed.rs) becomes subdfit::Error with the same
// message and its kind.
template <class F>
auto call(F&& f) -> decltype(f()) {
  try {
    return f();
  } catch (const rust::Error& e) {
    throw bridge_error(e.what());
  }
}

}  // namespace

std::vector<LimitSample> limit_points(const ControlMeshView& control, Backend backend) {
  const Sharpness s(control);
  const MeshView& m = control.mesh;
  return call([&] {
    return samples(ffi::embed_limit_points(
        slice(m.positions), slice(m.face_sizes), slice(m.face_indices),
        slice(s.crease_vertices.data(), s.crease_vertices.size()),
        slice(s.crease_weights.data(), s.crease_weights.size()),
        slice(s.corner_vertices.data(), s.corner_vertices.size()),
        slice(s.corner_weights.data(), s.corner_weights.size()), backend_code(backend)));
  });
}

std::vector<LimitSample> evaluate(const ControlMeshView& control, View<Location> locations,
                                  Backend backend) {
  const Sharpness s(control);
  const MeshView& m = control.mesh;
  if (locations.size > 0 && locations.data == nullptr) throw Error("locations: null pointer");
  // Structure of arrays for the bridge.
  std::vector<std::uint32_t> faces(locations.size);
  std::vector<std::uint16_t> subs(locations.size);
  std::vector<double> us(locations.size), vs(locations.size);
  for (std::size_t i = 0; i < locations.size; ++i) {
    faces[i] = locations[i].face;
    subs[i] = locations[i].sub;
    us[i] = locations[i].u;
    vs[i] = locations[i].v;
  }
  return call([&] {
    return samples(ffi::embed_evaluate(
        slice(m.positions), slice(m.face_sizes), slice(m.face_indices),
        slice(s.crease_vertices.data(), s.crease_vertices.size()),
        slice(s.crease_weights.data(), s.crease_weights.size()),
        slice(s.corner_vertices.data(), s.corner_vertices.size()),
        slice(s.corner_weights.data(), s.corner_weights.size()), slice(faces.data(), faces.size()),
        slice(subs.data(), subs.size()), slice(us.data(), us.size()), slice(vs.data(), vs.size()),
        backend_code(backend)));
  });
}

Result convert(const MeshView& mesh, const Options& options, const Progress& progress) {
  const ffi::ProgressSink sink(progress);
  return call([&] {
    return result(ffi::embed_convert(slice(mesh.positions), slice(mesh.face_sizes),
                                     slice(mesh.face_indices), ffi_options(options), sink));
  });
}

Result fit(const MeshView& mesh, const ControlMeshView& control, const Options& options,
           const Progress& progress) {
  const Sharpness s(control);
  const MeshView& c = control.mesh;
  const ffi::ProgressSink sink(progress);
  return call([&] {
    return result(ffi::embed_fit(
        slice(mesh.positions), slice(mesh.face_sizes), slice(mesh.face_indices),
        slice(c.positions), slice(c.face_sizes), slice(c.face_indices),
        slice(s.crease_vertices.data(), s.crease_vertices.size()),
        slice(s.crease_weights.data(), s.crease_weights.size()),
        slice(s.corner_vertices.data(), s.corner_vertices.size()),
        slice(s.corner_weights.data(), s.corner_weights.size()), ffi_options(options), sink));
  });
}

namespace detail {
void self_test(const char* what, const Progress& progress) {
  const ffi::ProgressSink sink(progress);
  const std::string w = what ? what : "";
  call([&] { ffi::embed_self_test(rust::Str(w), sink); });
}
}  // namespace detail

}  // namespace subdfit
