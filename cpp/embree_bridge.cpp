// Embree 3.13 scene wrapper (see embree_bridge.h). Every Embree error is
// captured by the device error callback and turned into a C++ exception here,
// which cxx turns into a Rust `Err` (never across Embree's C frames).
#include "subdfit/cpp/embree_bridge.h"

#include <pmmintrin.h>
#include <xmmintrin.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

namespace subdfit::embree {

rust::String library_version() { return rust::String(RTC_VERSION_STRING); }

namespace {

constexpr uint32_t kInvalid = 0xffffffffu;

// The error callback runs on the thread that made the failing call; keep the
// message per thread so concurrent queries do not mix their errors.
thread_local std::string t_last_error;

void error_callback(void * /*user*/, RTCError code, const char *str) {
  t_last_error = std::string(str ? str : "") + " (RTCError " + std::to_string(int(code)) + ")";
}

void check(RTCDevice device, const char *what) {
  // rtcGetDeviceError returns and clears the calling thread's error code.
  RTCError e = rtcGetDeviceError(device);
  if (e != RTC_ERROR_NONE) {
    std::string msg = std::string(what) + " failed: " +
                      (t_last_error.empty() ? "RTCError " + std::to_string(int(e)) : t_last_error);
    t_last_error.clear();
    throw std::runtime_error(msg);
  }
}

// STACK-NOTES / Embree docs: tracing threads should flush denormals to zero
// (FTZ/DAZ), otherwise denormal arithmetic in the traversal is very slow.
// The rayon workers also run unrelated f64 code, so restore MXCSR on exit.
class FtzDazGuard {
public:
  FtzDazGuard() : saved_(_mm_getcsr()) {
    _MM_SET_FLUSH_ZERO_MODE(_MM_FLUSH_ZERO_ON);
    _MM_SET_DENORMALS_ZERO_MODE(_MM_DENORMALS_ZERO_ON);
  }
  ~FtzDazGuard() { _mm_setcsr(saved_); }

private:
  unsigned int saved_;
};

struct V3 {
  double x, y, z;
};
inline V3 sub(V3 a, V3 b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
inline double dot(V3 a, V3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }

// Squared distance from p to triangle (a, b, c): Ericson, Real-Time Collision
// Detection, §5.1.5 (ClosestPtPointTriangle), region tests by barycentrics.
// Mirrors `closest_point_triangle` in src/raycast/mod.rs, which recomputes
// the final point in f64 for both backends.
double point_triangle_dist2(V3 p, V3 a, V3 b, V3 c) {
  V3 ab = sub(b, a), ac = sub(c, a), ap = sub(p, a);
  double d1 = dot(ab, ap), d2 = dot(ac, ap);
  V3 q;
  if (d1 <= 0.0 && d2 <= 0.0) {
    q = a;
  } else {
    V3 bp = sub(p, b);
    double d3 = dot(ab, bp), d4 = dot(ac, bp);
    if (d3 >= 0.0 && d4 <= d3) {
      q = b;
    } else {
      double vc = d1 * d4 - d3 * d2;
      if (vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0) {
        double v = d1 / (d1 - d3);
        q = {a.x + v * ab.x, a.y + v * ab.y, a.z + v * ab.z};
      } else {
        V3 cp = sub(p, c);
        double d5 = dot(ab, cp), d6 = dot(ac, cp);
        if (d6 >= 0.0 && d5 <= d6) {
          q = c;
        } else {
          double vb = d5 * d2 - d1 * d6;
          if (vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0) {
            double w = d2 / (d2 - d6);
            q = {a.x + w * ac.x, a.y + w * ac.y, a.z + w * ac.z};
          } else {
            double va = d3 * d6 - d5 * d4;
            if (va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0) {
              double w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
              q = {b.x + w * (c.x - b.x), b.y + w * (c.y - b.y), b.z + w * (c.z - b.z)};
            } else {
              double denom = 1.0 / (va + vb + vc);
              double v = vb * denom, w = vc * denom;
              q = {a.x + ab.x * v + ac.x * w, a.y + ab.y * v + ac.y * w,
                   a.z + ab.z * v + ac.z * w};
            }
          }
        }
      }
    }
  }
  V3 d = sub(p, q);
  return dot(d, d);
}

} // namespace

struct PointQueryState {
  const EmbreeScene *scene;
  V3 p;
  double best_d2;
  uint32_t best_prim;
};

bool point_query_callback(RTCPointQueryFunctionArguments *args) {
  auto *st = static_cast<PointQueryState *>(args->userPtr);
  const EmbreeScene &s = *st->scene;
  const uint32_t prim = args->primID;
  const uint32_t *t = &s.triangles_[3 * size_t(prim)];
  auto vtx = [&](uint32_t i) {
    const double *q = &s.positions_[3 * size_t(i)];
    return V3{q[0], q[1], q[2]};
  };
  const double d2 = point_triangle_dist2(st->p, vtx(t[0]), vtx(t[1]), vtx(t[2]));
  // Equal distances (a vertex shared by several triangles) go to the smallest
  // triangle id, as in the Rust BVH, so both backends agree exactly.
  if (d2 < st->best_d2 || (d2 == st->best_d2 && prim < st->best_prim)) {
    st->best_d2 = d2;
    st->best_prim = prim;
    const float r = float(std::sqrt(d2)) * (1.0f + 4.0f * std::numeric_limits<float>::epsilon()) +
                    s.radius_slack_;
    if (r < args->query->radius) {
      args->query->radius = r;
      return true; // the radius shrank: Embree re-culls the remaining nodes
    }
  }
  return false;
}

EmbreeScene::EmbreeScene(rust::Slice<const float> vertices, rust::Slice<const uint32_t> triangles,
                         rust::Slice<const double> positions_f64, uint8_t quality)
    : positions_(positions_f64.begin(), positions_f64.end()),
      triangles_(triangles.begin(), triangles.end()) {
  if (vertices.size() % 3 != 0 || triangles.size() % 3 != 0 ||
      positions_f64.size() != vertices.size())
    throw std::invalid_argument("embree scene: array sizes are not multiples of 3 or disagree");
  const size_t nv = vertices.size() / 3, nt = triangles.size() / 3;
  for (uint32_t i : triangles_)
    if (size_t(i) >= nv)
      throw std::invalid_argument("embree scene: vertex index out of range");
  float max_abs = 0.0f;
  for (float x : vertices)
    max_abs = std::max(max_abs, std::fabs(x));
  // f32 rounding moves each vertex by at most half an ulp of its largest
  // coordinate; twice that is a safe bound for box/triangle displacement.
  radius_slack_ = 2.0f * std::numeric_limits<float>::epsilon() * max_abs;

  device_ = rtcNewDevice(nullptr);
  if (!device_)
    throw std::runtime_error("rtcNewDevice failed (RTCError " +
                             std::to_string(int(rtcGetDeviceError(nullptr))) + ")");
  try {
    rtcSetDeviceErrorFunction(device_, error_callback, nullptr);
    scene_ = rtcNewScene(device_);
    check(device_, "rtcNewScene");
    // ROBUST: watertight traversal/intersection so rays do not slip through
    // shared edges (STACK-NOTES: ~15% cost).
    rtcSetSceneFlags(scene_, RTC_SCENE_FLAG_ROBUST);
    // High by default. Point queries keep the least (distance, triangle id)
    // over every triangle within a conservative shrinking radius, so their
    // answers do not depend on the tree: a scene queried only for closest
    // points may take a cheaper build (`EmbreeCaster::for_points`).
    const RTCBuildQuality q = quality == 0   ? RTC_BUILD_QUALITY_LOW
                              : quality == 1 ? RTC_BUILD_QUALITY_MEDIUM
                                             : RTC_BUILD_QUALITY_HIGH;
    rtcSetSceneBuildQuality(scene_, q);
    if (nt > 0) {
      RTCGeometry geom = rtcNewGeometry(device_, RTC_GEOMETRY_TYPE_TRIANGLE);
      check(device_, "rtcNewGeometry");
      rtcSetGeometryBuildQuality(geom, q);
      // rtcSetNewGeometryBuffer allocates with the padding Embree needs
      // after the last vertex for its SIMD loads.
      auto *vb = static_cast<float *>(rtcSetNewGeometryBuffer(
          geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float), nv));
      auto *ib = static_cast<uint32_t *>(rtcSetNewGeometryBuffer(
          geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(uint32_t), nt));
      if (!vb || !ib) {
        rtcReleaseGeometry(geom);
        check(device_, "rtcSetNewGeometryBuffer");
        throw std::runtime_error("rtcSetNewGeometryBuffer returned null");
      }
      std::copy(vertices.begin(), vertices.end(), vb);
      std::copy(triangles.begin(), triangles.end(), ib);
      rtcCommitGeometry(geom);
      rtcAttachGeometryByID(scene_, geom, 0);
      rtcReleaseGeometry(geom); // the scene holds its own reference
      check(device_, "geometry setup");
    }
    rtcCommitScene(scene_);
    check(device_, "rtcCommitScene");
  } catch (...) {
    if (scene_)
      rtcReleaseScene(scene_);
    rtcReleaseDevice(device_);
    throw;
  }
}

EmbreeScene::~EmbreeScene() {
  if (scene_)
    rtcReleaseScene(scene_);
  if (device_)
    rtcReleaseDevice(device_);
}

// A ray of the bridge's 8-float layout is traced only when 0 <= tnear <=
// tfar and every component is finite (tfar may be +inf); anything else is a
// miss (the Rust side filters these too).
static bool valid_ray(const float *r) {
  bool ok = r[3] <= r[7] && r[3] >= 0.0f;
  for (int k = 0; k < 8; ++k)
    ok = ok && (k == 7 || std::isfinite(r[k])) && !std::isnan(r[k]);
  return ok;
}

void EmbreeScene::intersect(rust::Slice<const float> rays, rust::Slice<float> out_tuv,
                            rust::Slice<uint32_t> out_prim) const {
  const size_t n = rays.size() / 8;
  if (rays.size() != 8 * n || out_tuv.size() != 3 * n || out_prim.size() != n)
    throw std::invalid_argument("embree intersect: buffer sizes disagree");
  FtzDazGuard ftz;
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  for (size_t i = 0; i < n; ++i) {
    const float *r = &rays[8 * i];
    out_prim[i] = kInvalid;
    out_tuv[3 * i] = out_tuv[3 * i + 1] = out_tuv[3 * i + 2] = 0.0f;
    if (!valid_ray(r))
      continue; // invalid ray: a miss (the Rust side filters these too)
    RTCRayHit rh;
    rh.ray.org_x = r[0];
    rh.ray.org_y = r[1];
    rh.ray.org_z = r[2];
    rh.ray.tnear = r[3];
    rh.ray.dir_x = r[4];
    rh.ray.dir_y = r[5];
    rh.ray.dir_z = r[6];
    rh.ray.tfar = r[7];
    rh.ray.time = 0.0f;
    rh.ray.mask = 0xffffffffu;
    rh.ray.id = 0;
    rh.ray.flags = 0;
    rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
    rh.hit.primID = RTC_INVALID_GEOMETRY_ID;
    rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
    rtcIntersect1(scene_, &ctx, &rh);
    if (rh.hit.geomID != RTC_INVALID_GEOMETRY_ID) {
      out_prim[i] = rh.hit.primID;
      out_tuv[3 * i] = rh.ray.tfar;
      out_tuv[3 * i + 1] = rh.hit.u;
      out_tuv[3 * i + 2] = rh.hit.v;
    }
  }
  check(device_, "rtcIntersect1");
}

void EmbreeScene::occluded_lines(rust::Slice<const float> rays,
                                 rust::Slice<uint8_t> out_blocked) const {
  const size_t n = rays.size() / 8;
  if (rays.size() != 8 * n || out_blocked.size() != n)
    throw std::invalid_argument("embree occluded_lines: buffer sizes disagree");
  FtzDazGuard ftz;
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  for (size_t i = 0; i < n; ++i) {
    const float *r = &rays[8 * i];
    out_blocked[i] = 0;
    // Same validity rule as `intersect`: an invalid ray is a miss.
    if (!valid_ray(r))
      continue;
    // rtcOccluded1 reports a hit iff rtcIntersect1 on the same ray would
    // (same robust triangle test over the same [tnear, tfar]; Embree 3
    // sets tfar = -inf on a hit). Negating an f32 direction is exact, so
    // the reversed ray equals the one the Rust side would encode for -dir.
    for (float sign : {1.0f, -1.0f}) {
      RTCRay ray;
      ray.org_x = r[0];
      ray.org_y = r[1];
      ray.org_z = r[2];
      ray.tnear = r[3];
      ray.dir_x = sign * r[4];
      ray.dir_y = sign * r[5];
      ray.dir_z = sign * r[6];
      ray.tfar = r[7];
      ray.time = 0.0f;
      ray.mask = 0xffffffffu;
      ray.id = 0;
      ray.flags = 0;
      rtcOccluded1(scene_, &ctx, &ray);
      if (ray.tfar < 0.0f) {
        out_blocked[i] = 1;
        break;
      }
    }
  }
  check(device_, "rtcOccluded1");
}

void EmbreeScene::closest_points(rust::Slice<const float> points_f32,
                                 rust::Slice<const double> points_f64, double max_dist,
                                 rust::Slice<uint32_t> out_prim) const {
  // One radius for every point: the per-point query below, same answers.
  if (out_prim.empty()) {
    if (!points_f32.empty() || !points_f64.empty())
      throw std::invalid_argument("embree closest_points: buffer sizes disagree");
    return;
  }
  const std::vector<double> max_dists(out_prim.size(), max_dist);
  closest_points_within(points_f32, points_f64,
                        rust::Slice<const double>(max_dists.data(), max_dists.size()), out_prim);
}

void EmbreeScene::closest_points_within(rust::Slice<const float> points_f32,
                                        rust::Slice<const double> points_f64,
                                        rust::Slice<const double> max_dists,
                                        rust::Slice<uint32_t> out_prim) const {
  const size_t n = points_f32.size() / 3;
  if (points_f32.size() != 3 * n || points_f64.size() != 3 * n || out_prim.size() != n ||
      max_dists.size() != n)
    throw std::invalid_argument("embree closest_points: buffer sizes disagree");
  for (double max_dist : max_dists)
    if (!(max_dist >= 0.0))
      throw std::invalid_argument("embree closest_points: max_dist must be >= 0");
  FtzDazGuard ftz;
  // The previous query's answer, as a start for the next one: the caller
  // sends points in spatial order (`in_spatial_order`), so that triangle is
  // usually near the next point, and its distance bounds the next answer's.
  // Starting from it (best = it, radius from its distance, as the callback
  // shrinks the radius after a hit) culls from the first node the boxes a
  // query from `max_dist` (often infinite) would open before its first
  // leaf. The answer is the same: the callback keeps the least (distance,
  // triangle id) over the triangles it sees plus the start, and every
  // triangle at least as near as the answer is within the radius (the same
  // conservative radius as the callback's), so it is seen either way.
  uint32_t prev = kInvalid;
  auto vtx = [&](uint32_t i) {
    const double *q = &positions_[3 * size_t(i)];
    return V3{q[0], q[1], q[2]};
  };
  for (size_t i = 0; i < n; ++i) {
    out_prim[i] = kInvalid;
    const double *p = &points_f64[3 * i];
    if (!std::isfinite(p[0]) || !std::isfinite(p[1]) || !std::isfinite(p[2]))
      continue;
    const V3 pv{p[0], p[1], p[2]};
    RTCPointQuery q;
    q.x = points_f32[3 * i];
    q.y = points_f32[3 * i + 1];
    q.z = points_f32[3 * i + 2];
    q.time = 0.0f;
    const double max_dist = max_dists[i];
    q.radius = std::isfinite(max_dist)
                   ? float(max_dist) * (1.0f + 4.0f * std::numeric_limits<float>::epsilon()) +
                         radius_slack_
                   : std::numeric_limits<float>::infinity();
    PointQueryState st{this, pv, max_dist * max_dist, kInvalid};
    if (prev != kInvalid) {
      const uint32_t *t = &triangles_[3 * size_t(prev)];
      const double d2 = point_triangle_dist2(pv, vtx(t[0]), vtx(t[1]), vtx(t[2]));
      // Strictly inside max_dist, as the callback's own test.
      if (d2 < st.best_d2) {
        st.best_d2 = d2;
        st.best_prim = prev;
        const float r = float(std::sqrt(d2)) *
                            (1.0f + 4.0f * std::numeric_limits<float>::epsilon()) +
                        radius_slack_;
        q.radius = std::min(q.radius, r);
      }
    }
    RTCPointQueryContext ctx;
    rtcInitPointQueryContext(&ctx);
    rtcPointQuery(scene_, &q, &ctx, point_query_callback, &st);
    out_prim[i] = st.best_prim;
    if (st.best_prim != kInvalid)
      prev = st.best_prim;
  }
  check(device_, "rtcPointQuery");
}

std::unique_ptr<EmbreeScene> new_scene(rust::Slice<const float> vertices,
                                       rust::Slice<const uint32_t> triangles,
                                       rust::Slice<const double> positions_f64, uint8_t quality) {
  return std::make_unique<EmbreeScene>(vertices, triangles, positions_f64, quality);
}

} // namespace subdfit::embree
