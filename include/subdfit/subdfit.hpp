#pragma once
// subdfit: dense triangle meshes to Catmull-Clark subdivision surfaces with
// displacement — the C++ API.
//
// Plain C++17: no Rust or cxx type appears here. Link the CMake target
// `subdfit::subdfit` (find_package(subdfit CONFIG REQUIRED)); it brings the
// static library and every system library it needs.
//
// Conventions (the same as the Rust library and the `subdfit` CLI):
// - Arrays are flat: positions are x, y, z per vertex; faces are a count per
//   face (`face_sizes`) and the concatenated vertex indices (0-based).
// - Inputs are borrowed views (pointer + size) of the caller's memory: the
//   library reads them during the call and keeps nothing. They are copied
//   once, into the library's own mesh.
// - A surface location is (face, sub, u, v): on a quad (v0 v1 v2 v3), (0,0)
//   is at v0, (1,0) at v1, (1,1) at v2; a face with n != 4 corners is split
//   into n quads as Catmull-Clark splits it, `sub` = k being the one at
//   corner k with (0,0) there (OpenSubdiv's ptex faces); `sub` is 0 on quads.
// - Boundary interpolation "edge and corner" (USD's default).
//
// Errors: every function throws `subdfit::Error` (and only that, besides
// std::bad_alloc), whose what() is the message `subdfit` prints for the same
// input and whose kind() says what failed (`ErrorKind`: bad input, a bad
// option, a numerical failure, a bug, a cancel). A bug inside the library (a
// Rust panic) is also reported as `subdfit::Error` of kind Internal; it never
// terminates the host.
//
// Threads: every function may be called from several host threads at once;
// no state survives a call.

#include <cstddef>
#include <cstdint>
#include <functional>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

namespace subdfit {

// What kind of failure a `subdfit::Error` is (the library's
// `subdfit::ErrorKind`, same numbers; the CLI exits 2 on Input and Option).
enum class ErrorKind : int {
  Input = 1,      // a mesh, an array or a file that cannot be used
  Option = 2,     // an option out of its range (Options' fields)
  Numerical = 3,  // a numerical stage or a C++ backend failed on valid input
  Internal = 4,   // a bug in subdfit: please report it
  Cancelled = 5,  // the progress callback returned false
};

class Error : public std::runtime_error {
 public:
  explicit Error(const std::string& what, ErrorKind kind = ErrorKind::Input)
      : std::runtime_error(what), kind_(kind) {}
  explicit Error(const char* what, ErrorKind kind = ErrorKind::Input)
      : std::runtime_error(what), kind_(kind) {}
  ErrorKind kind() const noexcept { return kind_; }

 private:
  ErrorKind kind_;
};

// A read-only view of `size` contiguous `T`s (what std::span<const T> is in
// C++20). Converts implicitly from a std::vector.
template <class T>
struct View {
  const T* data = nullptr;
  std::size_t size = 0;

  View() = default;
  View(const T* data_, std::size_t size_) : data(data_), size(size_) {}
  View(const std::vector<T>& v) : data(v.data()), size(v.size()) {}  // NOLINT: implicit on purpose

  const T* begin() const { return data; }
  const T* end() const { return data + size; }
  const T& operator[](std::size_t i) const { return data[i]; }
  bool empty() const { return size == 0; }
};

// A polygon (usually triangle) mesh: `positions.size` = 3 × vertices,
// sum(face_sizes) = face_indices.size.
struct MeshView {
  View<double> positions;
  View<std::uint32_t> face_sizes;
  View<std::uint32_t> face_indices;
};

// A crease edge (i, j) and a corner vertex i, with OpenSubdiv's sharpness
// (10 or more = infinitely sharp).
struct Crease {
  std::uint32_t i = 0;
  std::uint32_t j = 0;
  double sharpness = 0.0;
};
struct Corner {
  std::uint32_t i = 0;
  double sharpness = 0.0;
};

// A control mesh given to the library: a manifold, consistently oriented
// polygon mesh without unused vertices, plus its creases and corners.
struct ControlMeshView {
  MeshView mesh;
  View<Crease> creases;
  View<Corner> corners;
};

// A control mesh made by the library. In mechanical mode it is the
// once-refined all-quad mesh (the CLI's control_quads.obj: the same limit
// surface, creases and corners tagged) so that the UVs and tiles apply.
struct ControlMesh {
  std::vector<std::uint32_t> face_sizes;
  std::vector<std::uint32_t> face_indices;
  std::vector<double> positions;  // x, y, z per vertex
  std::vector<Crease> creases;
  std::vector<Corner> corners;
  // Per-corner UVs into the displacement atlas: `uv_indices` runs parallel
  // to `face_indices` and indexes `uvs` (u, v pairs).
  std::vector<double> uvs;
  std::vector<std::uint32_t> uv_indices;

  std::size_t num_vertices() const { return positions.size() / 3; }
  std::size_t num_faces() const { return face_sizes.size(); }
  // A view of this mesh, valid while it lives (e.g. to evaluate its limit).
  ControlMeshView view() const {
    return ControlMeshView{MeshView{positions, face_sizes, face_indices}, creases, corners};
  }
};

// Organic: Fitmaps (Panozzo et al.); Mechanical: sharp features kept as
// creases (Lavoué et al.); Auto: picks one from the share of sharp edges.
enum class Mode { Organic, Mechanical, Auto };
enum class FitMethod { Point, Sdm };
// How the displacement samples are spread over the patches: per patch where
// the detail is, under a total (the default), or the same grid everywhere.
enum class DisplacementAllocation { Adaptive, Uniform };
// How a host reads the displacement maps: Bilinear samples (every host), or
// BSpline coefficients of the uniform bicubic B-spline, read with a cubic
// B-spline filter (Blender/Cycles' "Cubic"; docs/handoff.md).
enum class DisplacementReconstruction { Bilinear, BSpline };
// Organic mode's layout: Greedy (Fitmaps' simplification, the default) or
// Field (a field-aligned layout, experimental).
enum class Layout { Greedy, Field };

// The options of `subdfit convert` / `subdfit fit`, with the CLI's defaults.
struct Options {
  // --tolerance: τ of the M-fitmap (Fitmaps §3.1.3), the share of a
  // neighbourhood allowed to be unreachable by normal projection (the paper
  // uses 0.01 and 0.1); larger τ, fewer patches. Default as the CLI's.
  double tolerance = 0.05;
  // --faces: target number of control faces; 0 lets the tolerance decide.
  std::uint32_t target_faces = 0;
  // --mode
  Mode mode = Mode::Auto;
  // --fit
  FitMethod fit_method = FitMethod::Point;
  // --displacement-res: samples per patch side; 0 = automatic.
  std::uint32_t displacement_resolution = 0;
  // --displacement-samples: displacement samples in all, each shared sample
  // counted once; 0 = the input's vertex count.
  std::uint32_t displacement_samples = 0;
  // --displacement-allocation; a displacement_resolution implies Uniform.
  DisplacementAllocation displacement_allocation = DisplacementAllocation::Adaptive;
  // --displacement-reconstruction
  DisplacementReconstruction displacement_reconstruction = DisplacementReconstruction::Bilinear;
  // --layout
  Layout layout = Layout::Greedy;
  // --max-error, a fraction of the bounding-box diagonal: mechanical mode's
  // RMS bound per control face, organic mode's bound on the limit surface's
  // RMS distance; 0 = the mode's default, infinity = organic mode's natural
  // end of the simplification.
  double max_error = 0.0;
  // false = --no-mfitmap: the projectability test lifted.
  bool m_fitmap = true;
  // --tessellation: cells per patch side of the limit and displaced
  // tessellations (1-1024); 0 = automatic.
  std::uint32_t tessellation = 0;
  // --proxy: the mesh the organic layout runs on. -1 = auto (a 50 000
  // triangle decimation for inputs above 100 000), 0 = none (the input
  // itself), N = about N triangles (at least 100) when the input has more,
  // -2 = adaptive (sized by a probe's predicted patch count).
  std::int64_t proxy = -1;
  // --exact-metrics: measure the metrics on every point (by default the
  // displaced surface's directions are drawn at 100 000 points, the limit
  // surface's and the projectability at 300 000, and report.json gives
  // the 95 % confidence interval of each figure).
  bool exact_metrics = false;
  // Worker threads for this call; 0 = all cores (a shared pool).
  std::uint32_t threads = 0;
  // Name of the input in error messages ("input mesh" if empty); pass the
  // file name to get the CLI's messages verbatim.
  std::string source_name;
};

// One patch's displacement: resolution × resolution offsets along the limit
// normal, row-major in the patch's (u, v) (v rows, u columns).
struct DisplacementTile {
  std::uint32_t face = 0;
  std::uint32_t resolution = 0;
  std::vector<float> values;
};

struct Metric {
  std::string name;  // dotted path into report.json, e.g. "limit.rms_permille"
  double value = 0.0;
};

struct Result {
  ControlMesh control;
  std::vector<DisplacementTile> tiles;
  std::vector<Metric> metrics;  // the numbers of report.json, in its order
  std::string report_json;      // report.json as the CLI writes it (timings vary per run)
  std::string control_obj;      // control.obj, byte for byte as the CLI writes it

  // The metric called `name`, or nullptr.
  const double* metric(std::string_view name) const {
    for (const auto& m : metrics)
      if (m.name == name) return &m.value;
    return nullptr;
  }
};

struct Location {
  std::uint32_t face = 0;
  std::uint16_t sub = 0;
  double u = 0.0;
  double v = 0.0;
};

struct Vec3 {
  double x = 0.0, y = 0.0, z = 0.0;
};

// A limit-surface sample: position, first derivatives with respect to the
// location's (u, v) (at a control vertex: the limit tangent masks, whose
// scale differs between backends) and the unit normal du × dv.
struct LimitSample {
  Vec3 position, du, dv, normal;
};

enum class Backend {
  OpenSubdiv,  // OpenSubdiv 3.5 Far, feature-adaptive patches, isolation 10
  Rust,        // the exact pure-Rust evaluator
};

// Progress callback: the name of the running stage and how much of it is done
// (0 to 1). Return false to cancel: the call then throws `subdfit::Error`
// ("cancelled by the caller") promptly, leaving nothing behind.
// It is called at most every ~20 ms within a stage, never on two threads at
// once, but possibly from a library worker thread rather than the caller's.
// An exception thrown by the callback cancels the call; its message is
// carried by the `subdfit::Error` that the call throws.
using Progress = std::function<bool(const char* stage, double fraction)>;

// Limit position, derivatives and normal at every control vertex, in order
// (what `subdfit limit CONTROL --backend ...` writes).
std::vector<LimitSample> limit_points(const ControlMeshView& control,
                                      Backend backend = Backend::OpenSubdiv);

// Limit position, derivatives and normal at each location.
std::vector<LimitSample> evaluate(const ControlMeshView& control, View<Location> locations,
                                  Backend backend = Backend::OpenSubdiv);

// Dense mesh to control mesh + displacement + metrics (`subdfit convert`).
Result convert(const MeshView& mesh, const Options& options = {},
               const Progress& progress = {});

// Fits a given control mesh to a dense mesh (`subdfit fit`).
Result fit(const MeshView& mesh, const ControlMeshView& control, const Options& options = {},
           const Progress& progress = {});

namespace detail {
// Test hooks, not part of the API: "panic" and "panic-in-worker" make the
// library panic, "error" fail, "progress" run a ten-second fake stage that
// reports progress (for timing cancellation).
void self_test(const char* what, const Progress& progress = {});
}  // namespace detail

}  // namespace subdfit
