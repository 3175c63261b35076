#pragma once
// OpenSubdiv 3.5 (Far) limit evaluation behind the cxx bridge
// `src/ffi/osd.rs`. One `OsdTopology` is built per control-mesh topology and
// is immutable afterwards (except for two lazily built, mutex-guarded
// caches), so every const method may be called from several threads at once.
//
// Arrays cross the bridge flat: positions as xyz triples, evaluation results
// as 9 doubles per location (position, d/du, d/dv).

#include <cstdint>
#include <memory>
#include <mutex>
#include <vector>

#include <opensubdiv/far/patchMap.h>
#include <opensubdiv/far/patchTable.h>
#include <opensubdiv/far/stencilTable.h>
#include <opensubdiv/far/topologyRefiner.h>
#include <opensubdiv/sdc/options.h>
#include <opensubdiv/sdc/types.h>

#include "rust/cxx.h"

namespace subdfit::osd {

// Defined by the bridge (shared structs), see src/ffi/osd.rs.
struct StencilRows;
struct UniformRefinement;
struct FVarUniform;
struct SchemeDesc;

rust::String library_version();

class OsdTopology {
 public:
  // Use `new_osd_topology`; public only for std::make_unique.
  OsdTopology() = default;
  OsdTopology(const OsdTopology&) = delete;
  OsdTopology& operator=(const OsdTopology&) = delete;

  std::uint32_t num_control_vertices() const;
  // Far::PtexIndices: first ptex face of every base face (a quad has one,
  // an n-gon n consecutive ones).
  rust::Vec<std::uint32_t> ptex_base_indices() const;
  // Refined vertices of every adaptive level followed by the end-cap local
  // points: the index space of the patch table's control vertices.
  std::size_t num_patch_points() const;
  std::uint32_t max_level() const;

  // Control positions (3 per vertex) -> patch points (3 per patch point).
  void compute_patch_points(rust::Slice<const double> positions, rust::Slice<double> points) const;
  // Evaluates the patches at (ptex, u, v), 9 doubles per location into
  // `out`. `points` comes from `compute_patch_points`.
  void evaluate_patches(rust::Slice<const double> points, rust::Slice<const std::uint32_t> ptex,
                        rust::Slice<const double> u, rust::Slice<const double> v,
                        rust::Slice<double> out) const;
  // Far::PrimvarRefiner::Limit at the level-1 children of the control
  // vertices: position, tangent 1, tangent 2 (9 doubles per vertex).
  void vertex_limits(rust::Slice<const double> positions, rust::Slice<double> out) const;
  // Far::LimitStencilTableFactory rows over the control vertices.
  StencilRows limit_stencils(rust::Slice<const std::uint32_t> ptex, rust::Slice<const double> u,
                             rust::Slice<const double> v) const;

 private:
  friend std::unique_ptr<OsdTopology> new_osd_topology(
      std::uint32_t, rust::Slice<const std::uint32_t>, rust::Slice<const std::uint32_t>,
      rust::Slice<const std::uint32_t>, rust::Slice<const double>, rust::Slice<const std::uint32_t>,
      rust::Slice<const double>, const SchemeDesc&, std::uint32_t);

  // A fresh, unrefined refiner from the stored descriptor arrays (null on
  // failure, with OpenSubdiv's message in the error callback).
  OpenSubdiv::Far::TopologyRefiner* make_refiner() const;
  const OpenSubdiv::Far::TopologyRefiner& uniform_refiner() const;
  const OpenSubdiv::Far::StencilTableReal<double>& control_stencils() const;

  // The descriptor's arrays, kept to build the lazy uniform refiner.
  int num_vertices_ = 0;
  std::vector<int> face_sizes_;
  std::vector<int> face_indices_;
  std::vector<int> crease_vertices_;
  std::vector<float> crease_weights_;
  std::vector<int> corner_vertices_;
  std::vector<float> corner_weights_;
  std::vector<int> holes_;
  OpenSubdiv::Sdc::Options sdc_options_;
  OpenSubdiv::Sdc::SchemeType scheme_type_ = OpenSubdiv::Sdc::SCHEME_CATMARK;

  std::unique_ptr<OpenSubdiv::Far::TopologyRefiner> adaptive_;
  std::unique_ptr<const OpenSubdiv::Far::PatchTable> patches_;
  std::unique_ptr<const OpenSubdiv::Far::PatchMap> patch_map_;
  std::vector<std::uint32_t> ptex_base_;
  std::size_t num_refined_ = 0;  // all adaptive levels, control vertices included
  std::size_t num_local_ = 0;    // end-cap local points

  // Lazily built (only `vertex_limits` / `limit_stencils` need them); the
  // mutex makes the const methods that build them thread-safe.
  mutable std::mutex lazy_mutex_;
  mutable std::unique_ptr<OpenSubdiv::Far::TopologyRefiner> uniform_;
  mutable std::unique_ptr<const OpenSubdiv::Far::StencilTableReal<double>> control_stencils_;
};

// Builds the topology (Catmark, with the Sdc options and holes of
// `scheme`), refines it adaptively to
// `isolation_level` and builds a double-precision patch table with Gregory
// basis end caps. Creases are vertex pairs + sharpness, corners vertex +
// sharpness. Throws (-> Rust Err) with OpenSubdiv's own message on failure.
std::unique_ptr<OsdTopology> new_osd_topology(std::uint32_t num_vertices,
                                              rust::Slice<const std::uint32_t> face_sizes,
                                              rust::Slice<const std::uint32_t> face_indices,
                                              rust::Slice<const std::uint32_t> crease_vertices,
                                              rust::Slice<const double> crease_weights,
                                              rust::Slice<const std::uint32_t> corner_vertices,
                                              rust::Slice<const double> corner_weights,
                                              const SchemeDesc& scheme, std::uint32_t isolation_level);

// Uniform refinement of vertex positions with `scheme` 0 = Catmark, 1 = Loop
// (same boundary and creasing options as above; Loop needs an all-triangle
// mesh, which OpenSubdiv itself checks), `levels` in 1..=10:
// Far::TopologyRefiner::RefineUniform + PrimvarRefiner::Interpolate, level by
// level. Every refined vertex also carries its parent component (kind 0 =
// vertex, 1 = edge, 2 = face, with that component's vertices at the parent
// level), so a caller can match OpenSubdiv's vertex order with its own. With
// `limits`, PrimvarRefiner::Limit positions of the last level's vertices
// are added. Independent of OsdTopology (no patch table is built). Throws
// (-> Rust Err) on bad input or OpenSubdiv's refusal.
UniformRefinement uniform_refine(std::uint32_t scheme_type, std::uint32_t num_vertices,
                                 rust::Slice<const std::uint32_t> face_sizes,
                                 rust::Slice<const std::uint32_t> face_indices,
                                 rust::Slice<const std::uint32_t> crease_vertices,
                                 rust::Slice<const double> crease_weights,
                                 rust::Slice<const std::uint32_t> corner_vertices,
                                 rust::Slice<const double> corner_weights, const SchemeDesc& scheme,
                                 rust::Slice<const double> positions, std::uint32_t levels, bool limits);

// Uniform refinement of one face-varying channel (`fvar_indices` one value
// index per face corner, `fvar_values` 2 doubles per value) with `scheme`'s
// face-varying interpolation: PrimvarRefiner::InterpolateFaceVarying level
// by level, then LimitFaceVarying at the last level. `scheme_type` 0
// Catmark, 1 Loop, 2 bilinear. Throws (-> Rust Err) on bad input.
FVarUniform uniform_refine_fvar(std::uint32_t scheme_type, std::uint32_t num_vertices,
                                rust::Slice<const std::uint32_t> face_sizes,
                                rust::Slice<const std::uint32_t> face_indices,
                                rust::Slice<const std::uint32_t> crease_vertices,
                                rust::Slice<const double> crease_weights,
                                rust::Slice<const std::uint32_t> corner_vertices,
                                rust::Slice<const double> corner_weights, const SchemeDesc& scheme,
                                rust::Slice<const std::uint32_t> fvar_indices, rust::Slice<const double> fvar_values,
                                std::uint32_t levels);

// A face-varying channel's limit by OpenSubdiv's patches: the control mesh
// refined adaptively with the channel considered
// (`considerFVarChannels`), face-varying patches in double precision and
// non-linear (`generateFVarLegacyLinearPatches = false`). Immutable after
// construction, so `evaluate` may be called from several threads.
class OsdFVarTopology {
 public:
  OsdFVarTopology() = default;
  OsdFVarTopology(const OsdFVarTopology&) = delete;
  OsdFVarTopology& operator=(const OsdFVarTopology&) = delete;
  // Values (2 doubles each, in the channel's order) at (ptex, u, v): 6
  // doubles per location into `out` (value, d/du, d/dv).
  void evaluate(rust::Slice<const double> values, rust::Slice<const std::uint32_t> ptex,
                rust::Slice<const double> u, rust::Slice<const double> v, rust::Slice<double> out) const;

  std::unique_ptr<OpenSubdiv::Far::TopologyRefiner> refiner_;
  std::unique_ptr<const OpenSubdiv::Far::PatchTable> patches_;
  std::unique_ptr<const OpenSubdiv::Far::PatchMap> patch_map_;
  std::vector<int> face_sizes_, face_indices_, crease_vertices_, corner_vertices_, holes_, fvar_indices_;
  std::vector<float> crease_weights_, corner_weights_;
  std::uint32_t num_values_ = 0;
  std::size_t num_refined_ = 0;  // face-varying values of all levels
  std::size_t num_local_ = 0;    // face-varying end-cap local points
};

// Builds an OsdFVarTopology (arguments as `new_osd_topology`, plus one
// face-varying index per face corner and the number of values).
std::unique_ptr<OsdFVarTopology> new_osd_fvar_topology(
    std::uint32_t num_vertices, rust::Slice<const std::uint32_t> face_sizes,
    rust::Slice<const std::uint32_t> face_indices, rust::Slice<const std::uint32_t> crease_vertices,
    rust::Slice<const double> crease_weights, rust::Slice<const std::uint32_t> corner_vertices,
    rust::Slice<const double> corner_weights, const SchemeDesc& scheme, rust::Slice<const std::uint32_t> fvar_indices,
    std::uint32_t num_values, std::uint32_t isolation_level);

}  // namespace subdfit::osd
