//! cxx bridge over `cpp/embree_bridge.{h,cpp}`: an Embree 3 scene behind an
//! opaque handle, queried in batches through flat slices (one call per chunk,
//! never one per ray). The safe wrapper is `crate::raycast::embree`.

#[cxx::bridge(namespace = "subdfit::embree")]
pub(crate) mod bridge {
    unsafe extern "C++" {
        include!("subdfit/cpp/embree_bridge.h");

        /// Version string of the wrapped library (smoke test of the bridge).
        fn library_version() -> Result<String>;

        /// A committed Embree scene (device + one triangle geometry).
        type EmbreeScene;

        /// Builds a robust scene. `vertices`: 3 f32 per vertex
        /// (translated frame); `triangles`: 3 indices per triangle;
        /// `positions_f64`: the untranslated f64 positions, for the exact
        /// distances of point queries; `quality`: Embree's build quality,
        /// 0 low, 1 medium, 2 (or more) high.
        fn new_scene(
            vertices: &[f32],
            triangles: &[u32],
            positions_f64: &[f64],
            quality: u8,
        ) -> Result<UniquePtr<EmbreeScene>>;

        /// `rays`: 8 f32 per ray (ox oy oz tnear dx dy dz tfar); writes
        /// 3 f32 (t u v) and the triangle (or `u32::MAX`) per ray.
        fn intersect(
            self: &EmbreeScene,
            rays: &[f32],
            out_tuv: &mut [f32],
            out_prim: &mut [u32],
        ) -> Result<()>;

        /// `rays` as for `intersect`; `out_blocked[i]` = 1 when the ray or
        /// its reverse (same `[tnear, tfar]`) hits anything (rtcOccluded1).
        fn occluded_lines(self: &EmbreeScene, rays: &[f32], out_blocked: &mut [u8]) -> Result<()>;

        /// Closest triangle within `max_dist` of each point (`u32::MAX` if
        /// none); `points_f32` translated, `points_f64` untranslated.
        fn closest_points(
            self: &EmbreeScene,
            points_f32: &[f32],
            points_f64: &[f64],
            max_dist: f64,
            out_prim: &mut [u32],
        ) -> Result<()>;

        /// As `closest_points`, with point `i`'s own `max_dists[i]`.
        fn closest_points_within(
            self: &EmbreeScene,
            points_f32: &[f32],
            points_f64: &[f64],
            max_dists: &[f64],
            out_prim: &mut [u32],
        ) -> Result<()>;
    }
}

// SAFETY: an `EmbreeScene` is immutable after `new_scene` returns (committed
// scene, no mutable state; its const methods only read). Embree 3 documents
// rtcIntersect1 and rtcPointQuery on a committed scene as thread-safe, and
// the device error code they may set is per thread.
unsafe impl Send for bridge::EmbreeScene {}
unsafe impl Sync for bridge::EmbreeScene {}
