#include "subdfit/cpp/osd_bridge.h"
#include "subdfit/cpp/osd_limit.h"

#include <opensubdiv/far/error.h>
#include <opensubdiv/far/patchTableFactory.h>
#include <opensubdiv/far/primvarRefiner.h>
#include <opensubdiv/far/ptexIndices.h>
#include <opensubdiv/far/stencilTableFactory.h>
#include <opensubdiv/far/topologyDescriptor.h>
#include <opensubdiv/version.h>

#include <array>
#include <stdexcept>
#include <string>

#include "subdfit/src/ffi/osd.rs.h"

namespace subdfit::osd {

namespace Far = OpenSubdiv::Far;
namespace Sdc = OpenSubdiv::Sdc;

rust::String library_version() {
  return rust::String(std::to_string(OPENSUBDIV_VERSION_MAJOR) + "." + std::to_string(OPENSUBDIV_VERSION_MINOR) + "." +
                      std::to_string(OPENSUBDIV_VERSION_PATCH));
}

namespace {

// ---- errors ------------------------------------------------------------------
//
// OpenSubdiv reports failures through one process-wide callback and returns
// null (far/error.h). The callback appends to a buffer of the calling thread
// (Far's factories report on the thread that runs them), so concurrent calls
// cannot read each other's messages; construction is in addition serialised
// by a global mutex, which keeps OpenSubdiv's default stdout printing out and
// makes "errors seen during this factory call" well defined.

thread_local std::string t_errors;
thread_local std::string t_warnings;

void append(std::string& buf, const char* msg) {
  if (!buf.empty()) buf += "; ";
  buf += msg ? msg : "(no message)";
}
void on_error(Far::ErrorType, const char* msg) { append(t_errors, msg); }
void on_warning(const char* msg) { append(t_warnings, msg); }

std::mutex g_construction_mutex;

class ErrorScope {
 public:
  ErrorScope() {
    static std::once_flag installed;
    std::call_once(installed, [] {
      Far::SetErrorCallback(on_error);
      Far::SetWarningCallback(on_warning);
    });
    t_errors.clear();
    t_warnings.clear();
  }
  ~ErrorScope() {
    t_errors.clear();
    t_warnings.clear();
  }
  // Throws if OpenSubdiv reported an error since the scope began.
  void check(const char* what) const {
    if (!t_errors.empty()) fail(what);
  }
  [[noreturn]] void fail(const char* what) const {
    std::string m = what;
    m += ": ";
    m += t_errors.empty() ? std::string("failed without a message") : t_errors;
    if (!t_warnings.empty()) m += " (warnings: " + t_warnings + ")";
    throw std::runtime_error(m);
  }
};

// ---- primvar type for Far's templates (Clear / AddWithWeight) -----------------

struct P3 {
  double x = 0, y = 0, z = 0;
  void Clear(void* = nullptr) { x = y = z = 0; }
  void AddWithWeight(const P3& s, double w) {
    x += w * s.x;
    y += w * s.y;
    z += w * s.z;
  }
};

std::vector<P3> to_points(rust::Slice<const double> xyz) {
  std::vector<P3> p(xyz.size() / 3);
  for (std::size_t i = 0; i < p.size(); ++i) p[i] = P3{xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]};
  return p;
}

void put(rust::Slice<double> out, std::size_t at, const P3& p) {
  out[at] = p.x;
  out[at + 1] = p.y;
  out[at + 2] = p.z;
}

// ---- topology ---------------------------------------------------------------

// The Sdc options of `scheme` (integers in the order of OpenSubdiv's enums,
// checked here: a cast of an out-of-range value would be undefined).
Sdc::Options sdc_options(const SchemeDesc& scheme) {
  if (scheme.boundary > Sdc::Options::VTX_BOUNDARY_EDGE_AND_CORNER)
    throw std::invalid_argument("boundary interpolation " + std::to_string(scheme.boundary) + " outside 0..=2");
  if (scheme.fvar > Sdc::Options::FVAR_LINEAR_ALL)
    throw std::invalid_argument("face-varying interpolation " + std::to_string(scheme.fvar) + " outside 0..=5");
  if (scheme.creasing > Sdc::Options::CREASE_CHAIKIN)
    throw std::invalid_argument("creasing method " + std::to_string(scheme.creasing) + " outside 0..=1");
  if (scheme.triangles > Sdc::Options::TRI_SUB_SMOOTH)
    throw std::invalid_argument("triangle subdivision " + std::to_string(scheme.triangles) + " outside 0..=1");
  Sdc::Options o;
  o.SetVtxBoundaryInterpolation(static_cast<Sdc::Options::VtxBoundaryInterpolation>(scheme.boundary));
  o.SetFVarLinearInterpolation(static_cast<Sdc::Options::FVarLinearInterpolation>(scheme.fvar));
  o.SetCreasingMethod(static_cast<Sdc::Options::CreasingMethod>(scheme.creasing));
  o.SetTriangleSubdivision(static_cast<Sdc::Options::TriangleSubdivision>(scheme.triangles));
  return o;
}

// Hole faces as the descriptor's int array, range-checked.
std::vector<int> hole_indices(const SchemeDesc& scheme, std::size_t num_faces) {
  std::vector<int> holes;
  holes.reserve(scheme.holes.size());
  for (auto f : scheme.holes) {
    if (f >= num_faces) throw std::invalid_argument("hole face " + std::to_string(f) + " out of range");
    holes.push_back(static_cast<int>(f));
  }
  return holes;
}

// Largest patch: Gregory basis (20 points); regular B-spline patches have 16.
constexpr int kMaxPatchPoints = 20;

// Factor that makes PatchTable::EvaluateBasis derivatives derivatives with
// respect to the (u, v) of the ptex face. OpenSubdiv 3.5 maps (u, v) into a
// patch with PatchParam::Normalize, which honours the "non-quad root" bit
// (the sub-faces of an n-gon are level-1 faces, their parameter fraction is
// 1/2^(depth-1)), but scales the derivative weights by 2^depth regardless
// (far/patchBasis.cpp), so on the ptex sub-faces of non-quads du/dv come out
// twice too large. Checked against finite differences in tests/osd_eval.rs.
double derivative_correction(const Far::PatchParam& param) {
  // = 2^(depth - nonQuadRoot) / 2^depth
  return param.NonQuadRoot() ? 0.5 : 1.0;
}

// The descriptor checks of `new_osd_topology` and `uniform_refine` (OpenSubdiv trusts its
// descriptor: an out-of-range index is undefined behaviour there).
void check_descriptor(std::uint32_t num_vertices, rust::Slice<const std::uint32_t> face_sizes,
                      rust::Slice<const std::uint32_t> face_indices, rust::Slice<const std::uint32_t> crease_vertices,
                      rust::Slice<const double> crease_weights, rust::Slice<const std::uint32_t> corner_vertices,
                      rust::Slice<const double> corner_weights) {
  if (num_vertices > static_cast<std::uint32_t>(INT32_MAX)) throw std::invalid_argument("too many vertices");
  std::size_t total = 0;
  for (auto n : face_sizes) {
    if (n < 3) throw std::invalid_argument("face with fewer than 3 vertices");
    total += n;
  }
  if (total != face_indices.size())
    throw std::invalid_argument("face sizes sum to " + std::to_string(total) + " but " +
                                std::to_string(face_indices.size()) + " indices were given");
  auto check_index = [&](std::uint32_t i, const char* what) {
    if (i >= num_vertices)
      throw std::invalid_argument(std::string(what) + " vertex index " + std::to_string(i) + " out of range");
  };
  for (auto i : face_indices) check_index(i, "face");
  if (crease_vertices.size() != 2 * crease_weights.size())
    throw std::invalid_argument("creases need two vertices per weight");
  for (auto i : crease_vertices) check_index(i, "crease");
  if (corner_vertices.size() != corner_weights.size())
    throw std::invalid_argument("corners need one vertex per weight");
  for (auto i : corner_vertices) check_index(i, "corner");
}

}  // namespace

std::unique_ptr<OsdTopology> new_osd_topology(std::uint32_t num_vertices,
                                              rust::Slice<const std::uint32_t> face_sizes,
                                              rust::Slice<const std::uint32_t> face_indices,
                                              rust::Slice<const std::uint32_t> crease_vertices,
                                              rust::Slice<const double> crease_weights,
                                              rust::Slice<const std::uint32_t> corner_vertices,
                                              rust::Slice<const double> corner_weights,
                                              const SchemeDesc& scheme, std::uint32_t isolation_level) {
  // OpenSubdiv trusts its descriptor (an out-of-range index is undefined
  // behaviour there), so check the arrays before handing them over.
  if (isolation_level < 1 || isolation_level > 10)
    throw std::invalid_argument("isolation level " + std::to_string(isolation_level) + " outside 1..=10");
  check_descriptor(num_vertices, face_sizes, face_indices, crease_vertices, crease_weights, corner_vertices,
                   corner_weights);

  auto t = std::make_unique<OsdTopology>();
  t->num_vertices_ = static_cast<int>(num_vertices);
  t->face_sizes_.assign(face_sizes.begin(), face_sizes.end());
  t->face_indices_.assign(face_indices.begin(), face_indices.end());
  t->crease_vertices_.assign(crease_vertices.begin(), crease_vertices.end());
  t->crease_weights_.assign(crease_weights.begin(), crease_weights.end());
  t->corner_vertices_.assign(corner_vertices.begin(), corner_vertices.end());
  t->corner_weights_.assign(corner_weights.begin(), corner_weights.end());
  t->holes_ = hole_indices(scheme, face_sizes.size());
  t->sdc_options_ = sdc_options(scheme);
  if (scheme.scheme_type != Sdc::SCHEME_BILINEAR && scheme.scheme_type != Sdc::SCHEME_CATMARK &&
      scheme.scheme_type != Sdc::SCHEME_LOOP)
    throw std::invalid_argument("scheme type " + std::to_string(scheme.scheme_type) +
                                " is neither bilinear (0), Catmark (1) nor Loop (2)");
  t->scheme_type_ = static_cast<Sdc::SchemeType>(scheme.scheme_type);

  std::lock_guard<std::mutex> lock(g_construction_mutex);
  ErrorScope errors;

  t->adaptive_.reset(t->make_refiner());
  if (!t->adaptive_) errors.fail("TopologyRefinerFactory<TopologyDescriptor>::Create");

  // Feature-adaptive refinement isolates extraordinary vertices and
  // semi-sharp features down to `isolation_level`; the remaining irregular
  // patches become Gregory basis end caps (the only approximation left).
  // useInfSharpPatch: infinitely sharp creases/corners are represented exactly
  // by sharp B-spline patches instead of being isolated and end-capped, which
  // only removes approximation (it is also what Bfr and USD/Hydra use).
  Far::PatchTableFactory::Options po(isolation_level);
  po.SetEndCapType(Far::PatchTableFactory::Options::ENDCAP_GREGORY_BASIS);
  po.SetPatchPrecision<double>();
  po.useInfSharpPatch = true;
  po.generateVaryingTables = false;
  po.generateVaryingLocalPoints = false;
  t->adaptive_->RefineAdaptive(po.GetRefineAdaptiveOptions());
  errors.check("TopologyRefiner::RefineAdaptive");

  t->patches_.reset(Far::PatchTableFactory::Create(*t->adaptive_, po));
  if (!t->patches_) errors.fail("PatchTableFactory::Create");
  errors.check("PatchTableFactory::Create");
  t->patch_map_ = std::make_unique<Far::PatchMap>(*t->patches_);

  Far::PtexIndices ptex(*t->adaptive_);
  t->ptex_base_.resize(face_sizes.size());
  for (std::size_t f = 0; f < face_sizes.size(); ++f)
    t->ptex_base_[f] = static_cast<std::uint32_t>(ptex.GetFaceId(static_cast<Far::Index>(f)));

  t->num_refined_ = static_cast<std::size_t>(t->adaptive_->GetNumVerticesTotal());
  t->num_local_ = static_cast<std::size_t>(t->patches_->GetNumLocalPoints());
  // SetPatchPrecision<double>() builds the double local-point table; make
  // sure it is there rather than reading the float one (STACK-NOTES).
  if (t->num_local_ > 0 && !t->patches_->GetLocalPointStencilTable<double>())
    throw std::logic_error("patch table has local points but no double-precision stencils for them");
  return t;
}

Far::TopologyRefiner* OsdTopology::make_refiner() const {
  Far::TopologyDescriptor d;
  d.numVertices = num_vertices_;
  d.numFaces = static_cast<int>(face_sizes_.size());
  d.numVertsPerFace = face_sizes_.data();
  d.vertIndicesPerFace = face_indices_.data();
  d.numCreases = static_cast<int>(crease_weights_.size());
  d.creaseVertexIndexPairs = crease_vertices_.data();
  d.creaseWeights = crease_weights_.data();
  d.numCorners = static_cast<int>(corner_weights_.size());
  d.cornerVertexIndices = corner_vertices_.data();
  d.cornerWeights = corner_weights_.data();
  // Hole faces keep their place in the subdivision rules of their
  // neighbours but get no patches (Far::PatchTableFactory skips them).
  d.numHoles = static_cast<int>(holes_.size());
  d.holeIndices = holes_.data();
  using Factory = Far::TopologyRefinerFactory<Far::TopologyDescriptor>;
  return Factory::Create(d, Factory::Options(scheme_type_, sdc_options_));
}

std::uint32_t OsdTopology::num_control_vertices() const { return static_cast<std::uint32_t>(num_vertices_); }

rust::Vec<std::uint32_t> OsdTopology::ptex_base_indices() const {
  rust::Vec<std::uint32_t> v;
  v.reserve(ptex_base_.size());
  for (auto i : ptex_base_) v.push_back(i);
  return v;
}

std::size_t OsdTopology::num_patch_points() const { return num_refined_ + num_local_; }

std::uint32_t OsdTopology::max_level() const { return static_cast<std::uint32_t>(adaptive_->GetMaxLevel()); }

void OsdTopology::compute_patch_points(rust::Slice<const double> positions, rust::Slice<double> points) const {
  if (positions.size() != 3 * static_cast<std::size_t>(num_vertices_))
    throw std::invalid_argument("expected " + std::to_string(num_vertices_) + " positions");
  if (points.size() != 3 * num_patch_points()) throw std::invalid_argument("patch point buffer has the wrong size");
  // The far tutorials' recipe: interpolate level by level into one buffer
  // (levels are concatenated, which is the index space of the patch table),
  // then the end-cap local points from their stencils over that buffer. The
  // double stencil table is applied directly: ComputeLocalPointValues is
  // float-only (STACK-NOTES).
  std::vector<P3> buf(num_patch_points());
  for (int i = 0; i < num_vertices_; ++i)
    buf[i] = P3{positions[3 * i], positions[3 * i + 1], positions[3 * i + 2]};
  Far::PrimvarRefinerReal<double> primvar(*adaptive_);
  P3* src = buf.data();
  for (int level = 1; level <= adaptive_->GetMaxLevel(); ++level) {
    P3* dst = src + adaptive_->GetLevel(level - 1).GetNumVertices();
    primvar.Interpolate(level, src, dst);
    src = dst;
  }
  if (num_local_ > 0)
    patches_->GetLocalPointStencilTable<double>()->UpdateValues(buf.data(), buf.data() + num_refined_);
  for (std::size_t i = 0; i < buf.size(); ++i) put(points, 3 * i, buf[i]);
}

void OsdTopology::evaluate_patches(rust::Slice<const double> points, rust::Slice<const std::uint32_t> ptex,
                                   rust::Slice<const double> u, rust::Slice<const double> v,
                                   rust::Slice<double> out) const {
  const std::size_t n = ptex.size();
  if (points.size() != 3 * num_patch_points()) throw std::invalid_argument("patch point buffer has the wrong size");
  if (u.size() != n || v.size() != n || out.size() != 9 * n)
    throw std::invalid_argument("location arrays of different lengths");
  std::array<double, kMaxPatchPoints> wP, wDu, wDv;
  for (std::size_t i = 0; i < n; ++i) {
    // PatchMap::FindPatch and PatchTable::EvaluateBasis are const and touch
    // no shared mutable state: safe from several threads.
    const Far::PatchTable::PatchHandle* h = patch_map_->FindPatch(static_cast<int>(ptex[i]), u[i], v[i]);
    // Hole faces (tagged, or boundary faces under boundary interpolation
    // "none") have no patches: no limit surface there.
    if (!h)
      throw std::runtime_error("no patch at ptex face " + std::to_string(ptex[i]) + " (" + std::to_string(u[i]) +
                               ", " + std::to_string(v[i]) + "): a hole, no limit surface there");
    Far::ConstIndexArray cvs = patches_->GetPatchVertices(*h);
    if (cvs.size() > kMaxPatchPoints) throw std::logic_error("patch with more than 20 control points");
    // EvaluateBasis maps (u, v) of the ptex face into the (sub-)patch and
    // scales the derivative weights accordingly, so du/dv are with respect
    // to the ptex face's own parametrisation.
    patches_->EvaluateBasis(*h, u[i], v[i], wP.data(), wDu.data(), wDv.data());
    const double dscale = derivative_correction(patches_->GetPatchParam(*h));
    P3 p, du, dv;
    for (int k = 0; k < cvs.size(); ++k) {
      const std::size_t c = 3 * static_cast<std::size_t>(cvs[k]);
      const P3 x{points[c], points[c + 1], points[c + 2]};
      p.AddWithWeight(x, wP[k]);
      du.AddWithWeight(x, dscale * wDu[k]);
      dv.AddWithWeight(x, dscale * wDv[k]);
    }
    put(out, 9 * i, p);
    put(out, 9 * i + 3, du);
    put(out, 9 * i + 6, dv);
  }
}

const Far::TopologyRefiner& OsdTopology::uniform_refiner() const {
  std::lock_guard<std::mutex> lazy(lazy_mutex_);
  if (uniform_) return *uniform_;
  std::lock_guard<std::mutex> lock(g_construction_mutex);
  ErrorScope errors;
  std::unique_ptr<Far::TopologyRefiner> r(make_refiner());
  if (!r) errors.fail("TopologyRefinerFactory<TopologyDescriptor>::Create");
  // PrimvarRefiner::Limit needs the full topology of its last level
  // (STACK-NOTES). One level suffices: every face is a quad there, and a
  // level-1 child of a control vertex has the same limit as its parent.
  Far::TopologyRefiner::UniformOptions uo(1);
  uo.fullTopologyInLastLevel = true;
  uo.orderVerticesFromFacesFirst = false;  // children of vertices come first
  r->RefineUniform(uo);
  errors.check("TopologyRefiner::RefineUniform");
  // Guard the ordering assumption: child i of control vertex i has its
  // parent's valence.
  const auto& l0 = r->GetLevel(0);
  const auto& l1 = r->GetLevel(1);
  for (int i = 0; i < num_vertices_; ++i)
    if (l0.GetVertexEdges(i).size() != l1.GetVertexEdges(i).size())
      throw std::logic_error("level-1 vertex order is not children-of-vertices first");
  uniform_ = std::move(r);
  return *uniform_;
}

void OsdTopology::vertex_limits(rust::Slice<const double> positions, rust::Slice<double> out) const {
  if (positions.size() != 3 * static_cast<std::size_t>(num_vertices_))
    throw std::invalid_argument("expected " + std::to_string(num_vertices_) + " positions");
  if (out.size() != 9 * static_cast<std::size_t>(num_vertices_))
    throw std::invalid_argument("output buffer has the wrong size");
  const Far::TopologyRefiner& r = uniform_refiner();
  std::vector<P3> base = to_points(positions);
  const std::size_t n1 = static_cast<std::size_t>(r.GetLevel(1).GetNumVertices());
  std::vector<P3> level1(n1), pos(n1), tan1(n1), tan2(n1);
  Far::PrimvarRefinerReal<double> primvar(r);
  // Far's templates take the buffers by (non-const) reference.
  const P3* src = base.data();
  P3* l1 = level1.data();
  P3 *dp = pos.data(), *dt1 = tan1.data(), *dt2 = tan2.data();
  primvar.Interpolate(1, src, l1);
  const P3* l1c = l1;
  if (limit_buffers_fit(r.GetLevel(1))) {
    ErrorScope errors;  // Limit reports a missing full topology via the callback
    primvar.Limit(l1c, dp, dt1, dt2);
    errors.check("PrimvarRefiner::Limit");
  } else {
    limit_with_masks(r, l1c, dp, dt1, dt2);  // Limit would overrun (osd_limit.h)
  }
  for (int i = 0; i < num_vertices_; ++i) {
    put(out, 9 * i, pos[i]);
    put(out, 9 * i + 3, tan1[i]);
    put(out, 9 * i + 6, tan2[i]);
  }
}

const Far::StencilTableReal<double>& OsdTopology::control_stencils() const {
  std::lock_guard<std::mutex> lazy(lazy_mutex_);
  if (control_stencils_) return *control_stencils_;
  std::lock_guard<std::mutex> lock(g_construction_mutex);
  ErrorScope errors;
  // Stencils of every refined vertex (control vertices included, all
  // levels: the patch table's index space) factorised down to the control
  // vertices, then the end-cap local points appended, also factorised. With
  // this table LimitStencilTableFactory writes rows over control vertices.
  using Factory = Far::StencilTableFactoryReal<double>;
  Factory::Options so;
  so.generateControlVerts = true;
  so.generateIntermediateLevels = true;
  so.factorizeIntermediateLevels = true;
  so.generateOffsets = true;
  so.maxLevel = static_cast<unsigned>(adaptive_->GetMaxLevel());
  std::unique_ptr<const Far::StencilTableReal<double>> base(Factory::Create(*adaptive_, so));
  if (!base) errors.fail("StencilTableFactory::Create");
  std::unique_ptr<const Far::StencilTableReal<double>> full;
  if (num_local_ > 0) {
    full.reset(Factory::AppendLocalPointStencilTable(*adaptive_, base.get(),
                                                     patches_->GetLocalPointStencilTable<double>(), true));
    if (!full) errors.fail("StencilTableFactory::AppendLocalPointStencilTable");
  } else {
    full = std::move(base);
  }
  errors.check("StencilTableFactory");
  if (static_cast<std::size_t>(full->GetNumStencils()) != num_patch_points())
    throw std::logic_error("control stencil table has " + std::to_string(full->GetNumStencils()) +
                           " stencils, the patch table needs " + std::to_string(num_patch_points()));
  control_stencils_ = std::move(full);
  return *control_stencils_;
}

StencilRows OsdTopology::limit_stencils(rust::Slice<const std::uint32_t> ptex, rust::Slice<const double> u,
                                        rust::Slice<const double> v) const {
  const std::size_t n = ptex.size();
  if (u.size() != n || v.size() != n) throw std::invalid_argument("location arrays of different lengths");
  StencilRows rows;
  rows.offsets.push_back(0);
  if (n == 0) return rows;  // the factory returns null for no locations
  const Far::StencilTableReal<double>& cv = control_stencils();

  using Factory = Far::LimitStencilTableFactoryReal<double>;
  typename Factory::LocationArrayVec locs(n);
  for (std::size_t i = 0; i < n; ++i) {
    locs[i].ptexIdx = static_cast<int>(ptex[i]);
    locs[i].numLocations = 1;
    locs[i].s = &u[i];
    locs[i].t = &v[i];
  }
  typename Factory::Options lo;
  lo.generate1stDerivatives = true;
  lo.generate2ndDerivatives = false;
  // Given both tables the factory only reads them (no shared state), so
  // calls for different chunks may run concurrently; errors land in this
  // thread's buffer.
  ErrorScope errors;
  std::unique_ptr<const Far::LimitStencilTableReal<double>> t(
      Factory::Create(*adaptive_, locs, &cv, patches_.get(), lo));
  if (!t) errors.fail("LimitStencilTableFactory::Create");
  errors.check("LimitStencilTableFactory::Create");
  // Locations on no patch are dropped silently by the factory.
  if (static_cast<std::size_t>(t->GetNumStencils()) != n)
    throw std::runtime_error("LimitStencilTableFactory found patches for " + std::to_string(t->GetNumStencils()) +
                             " of " + std::to_string(n) + " locations");
  const auto& sizes = t->GetSizes();
  const auto& offsets = t->GetOffsets();
  const auto& idx = t->GetControlIndices();
  const auto& w = t->GetWeights();
  const auto& wu = t->GetDuWeights();
  const auto& wv = t->GetDvWeights();
  const std::size_t nnz = idx.size();
  rows.indices.reserve(nnz);
  rows.weights.reserve(nnz);
  rows.du_weights.reserve(nnz);
  rows.dv_weights.reserve(nnz);
  std::uint32_t at = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const std::size_t o = static_cast<std::size_t>(offsets[i]);
    // The factory found this patch too (it drops locations it cannot place,
    // and the count matched), with the same derivative scaling to undo.
    const Far::PatchTable::PatchHandle* h = patch_map_->FindPatch(static_cast<int>(ptex[i]), u[i], v[i]);
    if (!h) throw std::logic_error("no patch at a location the stencil factory placed");
    const double dscale = derivative_correction(patches_->GetPatchParam(*h));
    for (int k = 0; k < sizes[i]; ++k) {
      rows.indices.push_back(static_cast<std::uint32_t>(idx[o + k]));
      rows.weights.push_back(w[o + k]);
      rows.du_weights.push_back(dscale * wu[o + k]);
      rows.dv_weights.push_back(dscale * wv[o + k]);
    }
    at += static_cast<std::uint32_t>(sizes[i]);
    rows.offsets.push_back(at);
  }
  return rows;
}

}  // namespace subdfit::osd

// ---- uniform refinement (Catmark or Loop) ------------------------------------

namespace subdfit::osd {


namespace {

struct P2 {
  double x = 0, y = 0;
  void Clear(void* = nullptr) { x = y = 0; }
  void AddWithWeight(const P2& s, double w) {
    x += w * s.x;
    y += w * s.y;
  }
};

// The control-mesh descriptor of `uniform_refine` and `uniform_refine_fvar`,
// with its arrays (the descriptor only points at them).
struct UniformDescriptor {
  std::vector<int> sizes, indices, cverts, kverts, holes, fvar_indices;
  std::vector<float> cweights, kweights;
  Far::TopologyDescriptor::FVarChannel channel;
  Far::TopologyDescriptor d;
};

// Checks the arrays and refines them uniformly `levels` times, the last
// level with full topology (PrimvarRefiner::Limit needs it, STACK-NOTES).
// `type` 0 Catmark, 1 Loop, 2 bilinear. A face-varying channel is attached
// when `fvar_indices` is not empty.
std::unique_ptr<Far::TopologyRefiner> refine_uniformly(
    std::uint32_t type, std::uint32_t num_vertices, rust::Slice<const std::uint32_t> face_sizes,
    rust::Slice<const std::uint32_t> face_indices, rust::Slice<const std::uint32_t> crease_vertices,
    rust::Slice<const double> crease_weights, rust::Slice<const std::uint32_t> corner_vertices,
    rust::Slice<const double> corner_weights, const SchemeDesc& scheme, std::uint32_t levels,
    rust::Slice<const std::uint32_t> fvar_indices, std::uint32_t num_fvar_values) {
  if (type > 2) throw std::invalid_argument("scheme " + std::to_string(type) + " is neither Catmark (0), Loop (1) nor bilinear (2)");
  // RefineUniform stores the level in 4 bits; 10 is OpenSubdiv's documented maximum.
  if (levels < 1 || levels > 10)
    throw std::invalid_argument("uniform refinement level " + std::to_string(levels) + " outside 1..=10");
  check_descriptor(num_vertices, face_sizes, face_indices, crease_vertices, crease_weights, corner_vertices,
                   corner_weights);
  if (!fvar_indices.empty()) {
    if (fvar_indices.size() != face_indices.size())
      throw std::invalid_argument("face-varying channel needs one index per face corner");
    for (auto i : fvar_indices)
      if (i >= num_fvar_values) throw std::invalid_argument("face-varying index " + std::to_string(i) + " out of range");
  }
  UniformDescriptor u;
  u.sizes.assign(face_sizes.begin(), face_sizes.end());
  u.indices.assign(face_indices.begin(), face_indices.end());
  u.cverts.assign(crease_vertices.begin(), crease_vertices.end());
  u.cweights.assign(crease_weights.begin(), crease_weights.end());
  u.kverts.assign(corner_vertices.begin(), corner_vertices.end());
  u.kweights.assign(corner_weights.begin(), corner_weights.end());
  u.fvar_indices.assign(fvar_indices.begin(), fvar_indices.end());
  Far::TopologyDescriptor& d = u.d;
  d.numVertices = static_cast<int>(num_vertices);
  d.numFaces = static_cast<int>(u.sizes.size());
  d.numVertsPerFace = u.sizes.data();
  d.vertIndicesPerFace = u.indices.data();
  d.numCreases = static_cast<int>(u.cweights.size());
  d.creaseVertexIndexPairs = u.cverts.data();
  d.creaseWeights = u.cweights.data();
  d.numCorners = static_cast<int>(u.kweights.size());
  d.cornerVertexIndices = u.kverts.data();
  d.cornerWeights = u.kweights.data();
  u.holes = hole_indices(scheme, u.sizes.size());
  d.numHoles = static_cast<int>(u.holes.size());
  d.holeIndices = u.holes.data();
  if (!u.fvar_indices.empty()) {
    u.channel.numValues = static_cast<int>(num_fvar_values);
    u.channel.valueIndices = u.fvar_indices.data();
    d.numFVarChannels = 1;
    d.fvarChannels = &u.channel;
  }
  // `type` chooses the scheme here; `scheme.scheme_type` is not read.
  const Sdc::Options options = sdc_options(scheme);

  std::unique_ptr<Far::TopologyRefiner> r;
  std::lock_guard<std::mutex> lock(g_construction_mutex);
  ErrorScope errors;
  // The triangle subdivision rule only matters to Catmark.
  using Factory = Far::TopologyRefinerFactory<Far::TopologyDescriptor>;
  const Sdc::SchemeType st = type == 0 ? Sdc::SCHEME_CATMARK : type == 1 ? Sdc::SCHEME_LOOP : Sdc::SCHEME_BILINEAR;
  r.reset(Factory::Create(d, Factory::Options(st, options)));
  if (!r) errors.fail("TopologyRefinerFactory<TopologyDescriptor>::Create");
  errors.check("TopologyRefinerFactory<TopologyDescriptor>::Create");
  Far::TopologyRefiner::UniformOptions uo(static_cast<int>(levels));
  uo.fullTopologyInLastLevel = true;
  r->RefineUniform(uo);
  errors.check("TopologyRefiner::RefineUniform");
  return r;
}

}  // namespace

UniformRefinement uniform_refine(std::uint32_t scheme_type, std::uint32_t num_vertices,
                                 rust::Slice<const std::uint32_t> face_sizes,
                                 rust::Slice<const std::uint32_t> face_indices,
                                 rust::Slice<const std::uint32_t> crease_vertices,
                                 rust::Slice<const double> crease_weights,
                                 rust::Slice<const std::uint32_t> corner_vertices,
                                 rust::Slice<const double> corner_weights, const SchemeDesc& scheme,
                                 rust::Slice<const double> positions, std::uint32_t levels, bool limits) {
  if (scheme_type > 1) throw std::invalid_argument("scheme " + std::to_string(scheme_type) + " is neither Catmark (0) nor Loop (1)");
  if (positions.size() != 3 * static_cast<std::size_t>(num_vertices))
    throw std::invalid_argument("expected " + std::to_string(num_vertices) + " positions");
  std::unique_ptr<Far::TopologyRefiner> r =
      refine_uniformly(scheme_type, num_vertices, face_sizes, face_indices, crease_vertices, crease_weights,
                       corner_vertices, corner_weights, scheme, levels, {}, 0);

  UniformRefinement out;
  const int nlevels = r->GetNumLevels();  // levels + 1
  std::vector<std::size_t> first(static_cast<std::size_t>(nlevels) + 1, 0);
  for (int l = 0; l < nlevels; ++l)
    first[l + 1] = first[l] + static_cast<std::size_t>(r->GetLevel(l).GetNumVertices());
  for (auto f : first) out.level_offsets.push_back(static_cast<std::uint32_t>(f));

  // Positions of every level in one buffer (the far tutorials' recipe).
  std::vector<P3> buf(first.back());
  for (std::uint32_t i = 0; i < num_vertices; ++i)
    buf[i] = P3{positions[3 * i], positions[3 * i + 1], positions[3 * i + 2]};
  Far::PrimvarRefinerReal<double> primvar(*r);
  for (int l = 1; l < nlevels; ++l) {
    const P3* src = buf.data() + first[l - 1];
    P3* dst = buf.data() + first[l];
    primvar.Interpolate(l, src, dst);
  }
  out.positions.reserve(3 * buf.size());
  for (const P3& p : buf) {
    out.positions.push_back(p.x);
    out.positions.push_back(p.y);
    out.positions.push_back(p.z);
  }

  // Parent component of every refined vertex, from the parent level's
  // child indices (TopologyLevel::Get*ChildVertex).
  for (int l = 1; l < nlevels; ++l) {
    const Far::TopologyLevel& parent = r->GetLevel(l - 1);
    const std::size_t n = static_cast<std::size_t>(r->GetLevel(l).GetNumVertices());
    std::vector<std::uint8_t> kind(n, 255);
    std::vector<std::vector<std::uint32_t>> comp(n);
    auto assign = [&](Far::Index child, std::uint8_t k, Far::ConstIndexArray verts) {
      if (child == Far::INDEX_INVALID) return;
      if (child < 0 || static_cast<std::size_t>(child) >= n || kind[child] != 255)
        throw std::logic_error("refined vertex with no or several parents");
      kind[child] = k;
      for (int i = 0; i < verts.size(); ++i) comp[child].push_back(static_cast<std::uint32_t>(verts[i]));
    };
    for (int v = 0; v < parent.GetNumVertices(); ++v) {
      const Far::Index one[1] = {v};
      assign(parent.GetVertexChildVertex(v), 0, Far::ConstIndexArray(one, 1));
    }
    for (int e = 0; e < parent.GetNumEdges(); ++e) assign(parent.GetEdgeChildVertex(e), 1, parent.GetEdgeVertices(e));
    // Loop's triangle split creates no face vertices, and its refinement
    // keeps no face-child-vertex table to ask (reading it is out of bounds).
    if (scheme_type == 0)
      for (int f = 0; f < parent.GetNumFaces(); ++f)
        assign(parent.GetFaceChildVertex(f), 2, parent.GetFaceVertices(f));
    for (std::size_t c = 0; c < n; ++c) {
      if (kind[c] == 255) throw std::logic_error("refined vertex without a parent component");
      out.kinds.push_back(kind[c]);
      out.parent_offsets.push_back(static_cast<std::uint32_t>(out.parents.size()));
      for (auto v : comp[c]) out.parents.push_back(v);
    }
  }
  out.parent_offsets.push_back(static_cast<std::uint32_t>(out.parents.size()));

  if (limits) {
    const int last = nlevels - 1;
    const std::size_t n = static_cast<std::size_t>(r->GetLevel(last).GetNumVertices());
    std::vector<P3> lim(n);
    const P3* src = buf.data() + first[last];
    P3* dst = lim.data();
    if (limit_buffers_fit(r->GetLevel(last))) {
      ErrorScope errors;  // Limit reports a missing full topology via the callback
      primvar.Limit(src, dst);
      errors.check("PrimvarRefiner::Limit");
    } else {  // Limit would overrun its buffers (osd_limit.h)
      std::vector<P3> t1(n), t2(n);
      limit_with_masks(*r, src, dst, t1.data(), t2.data());
    }
    out.limits.reserve(3 * n);
    for (const P3& p : lim) {
      out.limits.push_back(p.x);
      out.limits.push_back(p.y);
      out.limits.push_back(p.z);
    }
  }
  return out;
}

FVarUniform uniform_refine_fvar(std::uint32_t scheme_type, std::uint32_t num_vertices,
                                rust::Slice<const std::uint32_t> face_sizes,
                                rust::Slice<const std::uint32_t> face_indices,
                                rust::Slice<const std::uint32_t> crease_vertices,
                                rust::Slice<const double> crease_weights,
                                rust::Slice<const std::uint32_t> corner_vertices,
                                rust::Slice<const double> corner_weights, const SchemeDesc& scheme,
                                rust::Slice<const std::uint32_t> fvar_indices, rust::Slice<const double> fvar_values,
                                std::uint32_t levels) {
  if (fvar_indices.empty()) throw std::invalid_argument("face-varying channel without indices");
  if (fvar_values.size() % 2 != 0) throw std::invalid_argument("face-varying values need 2 doubles each");
  const auto nvalues = static_cast<std::uint32_t>(fvar_values.size() / 2);
  std::unique_ptr<Far::TopologyRefiner> r =
      refine_uniformly(scheme_type, num_vertices, face_sizes, face_indices, crease_vertices, crease_weights,
                       corner_vertices, corner_weights, scheme, levels, fvar_indices, nvalues);
  const int nlevels = r->GetNumLevels();
  std::vector<std::vector<P2>> lv(static_cast<std::size_t>(nlevels));
  lv[0].resize(nvalues);
  for (std::uint32_t i = 0; i < nvalues; ++i) lv[0][i] = P2{fvar_values[2 * i], fvar_values[2 * i + 1]};
  Far::PrimvarRefinerReal<double> primvar(*r);
  for (int l = 1; l < nlevels; ++l) {
    lv[l].resize(static_cast<std::size_t>(r->GetLevel(l).GetNumFVarValues(0)));
    const P2* src = lv[l - 1].data();
    P2* dst = lv[l].data();
    primvar.InterpolateFaceVarying(l, src, dst, 0);
  }
  const std::vector<P2>& last = lv[static_cast<std::size_t>(nlevels - 1)];
  std::vector<P2> lim(last.size());
  {
    const P2* src = last.data();
    P2* dst = lim.data();
    // LimitFaceVarying sizes its buffers as Limit does (osd_limit.h); it is
    // only ever given manifold copies, which cannot overrun them, but a
    // refusal beats heap corruption if that changes.
    if (!limit_buffers_fit(r->GetLevel(nlevels - 1)))
      throw std::invalid_argument(
          "PrimvarRefiner::LimitFaceVarying would overrun its mask buffers here (a vertex with more faces than "
          "OpenSubdiv's recorded max valence)");
    ErrorScope errors;
    primvar.LimitFaceVarying(src, dst, 0);
    errors.check("PrimvarRefiner::LimitFaceVarying");
  }
  FVarUniform out;
  for (std::size_t i = 0; i < last.size(); ++i) {
    out.values.push_back(last[i].x);
    out.values.push_back(last[i].y);
    out.limits.push_back(lim[i].x);
    out.limits.push_back(lim[i].y);
  }
  // The last level's faces by value index, for callers that match values
  // to locations.
  const Far::TopologyLevel& top = r->GetLevel(nlevels - 1);
  for (int f = 0; f < top.GetNumFaces(); ++f) {
    Far::ConstIndexArray fv = top.GetFaceFVarValues(f, 0);
    out.face_offsets.push_back(static_cast<std::uint32_t>(out.face_values.size()));
    for (int k = 0; k < fv.size(); ++k) out.face_values.push_back(static_cast<std::uint32_t>(fv[k]));
  }
  out.face_offsets.push_back(static_cast<std::uint32_t>(out.face_values.size()));
  return out;
}

std::unique_ptr<OsdFVarTopology> new_osd_fvar_topology(
    std::uint32_t num_vertices, rust::Slice<const std::uint32_t> face_sizes,
    rust::Slice<const std::uint32_t> face_indices, rust::Slice<const std::uint32_t> crease_vertices,
    rust::Slice<const double> crease_weights, rust::Slice<const std::uint32_t> corner_vertices,
    rust::Slice<const double> corner_weights, const SchemeDesc& scheme, rust::Slice<const std::uint32_t> fvar_indices,
    std::uint32_t num_values, std::uint32_t isolation_level) {
  if (isolation_level < 1 || isolation_level > 10)
    throw std::invalid_argument("isolation level " + std::to_string(isolation_level) + " outside 1..=10");
  check_descriptor(num_vertices, face_sizes, face_indices, crease_vertices, crease_weights, corner_vertices,
                   corner_weights);
  if (fvar_indices.size() != face_indices.size())
    throw std::invalid_argument("face-varying channel needs one index per face corner");
  for (auto i : fvar_indices)
    if (i >= num_values) throw std::invalid_argument("face-varying index " + std::to_string(i) + " out of range");
  if (scheme.scheme_type > 2) throw std::invalid_argument("unknown scheme type");
  auto t = std::make_unique<OsdFVarTopology>();
  t->face_sizes_.assign(face_sizes.begin(), face_sizes.end());
  t->face_indices_.assign(face_indices.begin(), face_indices.end());
  t->crease_vertices_.assign(crease_vertices.begin(), crease_vertices.end());
  t->crease_weights_.assign(crease_weights.begin(), crease_weights.end());
  t->corner_vertices_.assign(corner_vertices.begin(), corner_vertices.end());
  t->corner_weights_.assign(corner_weights.begin(), corner_weights.end());
  t->fvar_indices_.assign(fvar_indices.begin(), fvar_indices.end());
  t->holes_ = hole_indices(scheme, face_sizes.size());
  t->num_values_ = num_values;

  Far::TopologyDescriptor d;
  d.numVertices = static_cast<int>(num_vertices);
  d.numFaces = static_cast<int>(t->face_sizes_.size());
  d.numVertsPerFace = t->face_sizes_.data();
  d.vertIndicesPerFace = t->face_indices_.data();
  d.numCreases = static_cast<int>(t->crease_weights_.size());
  d.creaseVertexIndexPairs = t->crease_vertices_.data();
  d.creaseWeights = t->crease_weights_.data();
  d.numCorners = static_cast<int>(t->corner_weights_.size());
  d.cornerVertexIndices = t->corner_vertices_.data();
  d.cornerWeights = t->corner_weights_.data();
  d.numHoles = static_cast<int>(t->holes_.size());
  d.holeIndices = t->holes_.data();
  Far::TopologyDescriptor::FVarChannel channel;
  channel.numValues = static_cast<int>(num_values);
  channel.valueIndices = t->fvar_indices_.data();
  d.numFVarChannels = 1;
  d.fvarChannels = &channel;

  std::lock_guard<std::mutex> lock(g_construction_mutex);
  ErrorScope errors;
  using Factory = Far::TopologyRefinerFactory<Far::TopologyDescriptor>;
  t->refiner_.reset(Factory::Create(
      d, Factory::Options(static_cast<Sdc::SchemeType>(scheme.scheme_type), sdc_options(scheme))));
  if (!t->refiner_) errors.fail("TopologyRefinerFactory<TopologyDescriptor>::Create");
  // As `new_osd_topology`, plus face-varying patches that are not the
  // legacy linear ones: then adaptive refinement isolates the channel's
  // own features too (considerFVarChannels).
  Far::PatchTableFactory::Options po(isolation_level);
  po.SetEndCapType(Far::PatchTableFactory::Options::ENDCAP_GREGORY_BASIS);
  po.SetPatchPrecision<double>();
  po.SetFVarPatchPrecision<double>();
  po.useInfSharpPatch = true;
  po.generateVaryingTables = false;
  po.generateFVarTables = true;
  po.generateFVarLegacyLinearPatches = false;
  t->refiner_->RefineAdaptive(po.GetRefineAdaptiveOptions());
  errors.check("TopologyRefiner::RefineAdaptive");
  t->patches_.reset(Far::PatchTableFactory::Create(*t->refiner_, po));
  if (!t->patches_) errors.fail("PatchTableFactory::Create");
  errors.check("PatchTableFactory::Create");
  t->patch_map_ = std::make_unique<Far::PatchMap>(*t->patches_);
  for (int l = 0; l <= t->refiner_->GetMaxLevel(); ++l)
    t->num_refined_ += static_cast<std::size_t>(t->refiner_->GetLevel(l).GetNumFVarValues(0));
  t->num_local_ = static_cast<std::size_t>(t->patches_->GetNumLocalPointsFaceVarying(0));
  if (t->num_local_ > 0 && !t->patches_->GetLocalPointFaceVaryingStencilTable<double>(0))
    throw std::logic_error("face-varying local points without double-precision stencils");
  return t;
}

void OsdFVarTopology::evaluate(rust::Slice<const double> values, rust::Slice<const std::uint32_t> ptex,
                               rust::Slice<const double> u, rust::Slice<const double> v,
                               rust::Slice<double> out) const {
  const std::size_t n = ptex.size();
  if (values.size() != 2 * static_cast<std::size_t>(num_values_))
    throw std::invalid_argument("expected " + std::to_string(num_values_) + " face-varying values");
  if (u.size() != n || v.size() != n || out.size() != 6 * n)
    throw std::invalid_argument("location arrays of different lengths");
  // The values of every level in one buffer, then the end-cap local
  // points: the index space of GetPatchFVarValues.
  std::vector<P2> buf(num_refined_ + num_local_);
  for (std::uint32_t i = 0; i < num_values_; ++i) buf[i] = P2{values[2 * i], values[2 * i + 1]};
  Far::PrimvarRefinerReal<double> primvar(*refiner_);
  P2* src = buf.data();
  for (int level = 1; level <= refiner_->GetMaxLevel(); ++level) {
    P2* dst = src + refiner_->GetLevel(level - 1).GetNumFVarValues(0);
    primvar.InterpolateFaceVarying(level, src, dst, 0);
    src = dst;
  }
  if (num_local_ > 0)
    patches_->GetLocalPointFaceVaryingStencilTable<double>(0)->UpdateValues(buf.data(), buf.data() + num_refined_);
  std::array<double, kMaxPatchPoints> wP, wDu, wDv;
  for (std::size_t i = 0; i < n; ++i) {
    const Far::PatchTable::PatchHandle* h = patch_map_->FindPatch(static_cast<int>(ptex[i]), u[i], v[i]);
    if (!h)
      throw std::runtime_error("no patch at ptex face " + std::to_string(ptex[i]) + ": a hole, no limit surface there");
    Far::ConstIndexArray cvs = patches_->GetPatchFVarValues(*h, 0);
    if (cvs.size() > kMaxPatchPoints) throw std::logic_error("face-varying patch with more than 20 points");
    patches_->EvaluateBasisFaceVarying(*h, u[i], v[i], wP.data(), wDu.data(), wDv.data(), nullptr, nullptr,
                                       nullptr, 0);
    const double dscale = derivative_correction(patches_->GetPatchFVarPatchParam(*h, 0));
    P2 p, du, dv;
    for (int k = 0; k < cvs.size(); ++k) {
      const P2& x = buf[static_cast<std::size_t>(cvs[k])];
      p.AddWithWeight(x, wP[k]);
      du.AddWithWeight(x, dscale * wDu[k]);
      dv.AddWithWeight(x, dscale * wDv[k]);
    }
    out[6 * i] = p.x;
    out[6 * i + 1] = p.y;
    out[6 * i + 2] = du.x;
    out[6 * i + 3] = du.y;
    out[6 * i + 4] = dv.x;
    out[6 * i + 5] = dv.y;
  }
}

}  // namespace subdfit::osd
