#pragma once
// Embree 3 scene behind an opaque handle for the cxx bridge in
// src/ffi/embree.rs. Only the scene build and the batched raw queries live
// here; precision refinement (f64), tie-breaking and line queries are done on
// the Rust side so both ray casters share that logic.
#include <cstdint>
#include <memory>
#include <vector>

#include <embree3/rtcore.h>

#include "rust/cxx.h"

namespace subdfit::embree {

rust::String library_version();

/// A committed Embree scene over one triangle mesh. Immutable after
/// construction; rtcIntersect1 / rtcPointQuery on a committed scene are
/// thread-safe (Embree 3 API docs), so `const` methods may run concurrently.
class EmbreeScene {
public:
  EmbreeScene(rust::Slice<const float> vertices, rust::Slice<const uint32_t> triangles,
              rust::Slice<const double> positions_f64, uint8_t quality);
  ~EmbreeScene();
  EmbreeScene(const EmbreeScene &) = delete;
  EmbreeScene &operator=(const EmbreeScene &) = delete;

  /// rays: 8 floats per ray (ox oy oz tnear dx dy dz tfar), in the scene's
  /// translated frame. out_tuv: 3 floats per ray (t u v); out_prim: hit
  /// triangle or 0xffffffff for a miss.
  void intersect(rust::Slice<const float> rays, rust::Slice<float> out_tuv,
                 rust::Slice<uint32_t> out_prim) const;

  /// rays: as for `intersect`. out_blocked[i] = 1 when anything lies on the
  /// *line* segment of ray i in either direction (the ray, or the ray with
  /// its direction negated, over the same [tnear, tfar]), else 0. Uses
  /// rtcOccluded1 (any hit, no closest-hit search) and skips the reversed
  /// ray once the forward one is blocked.
  void occluded_lines(rust::Slice<const float> rays, rust::Slice<uint8_t> out_blocked) const;

  /// points_f32: 3 floats per point in the translated frame (for Embree's
  /// BVH); points_f64: the same points untranslated, for the exact distance.
  /// out_prim: closest triangle within max_dist, or 0xffffffff.
  void closest_points(rust::Slice<const float> points_f32,
                      rust::Slice<const double> points_f64, double max_dist,
                      rust::Slice<uint32_t> out_prim) const;

  /// As `closest_points`, with point i's own max_dist `max_dists[i]`.
  void closest_points_within(rust::Slice<const float> points_f32,
                             rust::Slice<const double> points_f64,
                             rust::Slice<const double> max_dists,
                             rust::Slice<uint32_t> out_prim) const;

private:
  RTCDevice device_ = nullptr;
  RTCScene scene_ = nullptr;
  // f64 triangle data for the exact point-triangle distance in the point
  // query callback (Embree only has the f32 copy).
  std::vector<double> positions_;
  std::vector<uint32_t> triangles_;
  // Slack added to the shrinking query radius: Embree's boxes enclose the f32
  // (rounded) triangles, which may lie up to this far from the f64 ones.
  float radius_slack_ = 0.0f;

  friend struct PointQueryState;
  friend bool point_query_callback(RTCPointQueryFunctionArguments *args);
};

/// quality: 0 low, 1 medium, 2 high (RTCBuildQuality); anything else is high.
std::unique_ptr<EmbreeScene> new_scene(rust::Slice<const float> vertices,
                                       rust::Slice<const uint32_t> triangles,
                                       rust::Slice<const double> positions_f64, uint8_t quality);

} // namespace subdfit::embree
