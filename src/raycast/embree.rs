//! [`RayCaster`] over Embree 3.13 (robust scene, high build quality).
//!
//! Embree stores `f32` vertices. To keep their precision the mesh is
//! translated so that its bounding-box centre is the origin (query origins
//! are translated the same way, in f64, before rounding). Embree then only
//! *selects* the triangle: every hit is recomputed in f64 against the original
//! triangle ([`refine_hit`]), and closest points are computed in f64 both in
//! the C++ callback and here, so results carry f64 accuracy for the chosen
//! triangle.

use cxx::UniquePtr;
use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::ffi::embree::bridge;
use crate::mesh::TriMesh;
use crate::raycast::{
    check_max_dist, closest_on_triangle, in_spatial_order, surface_triangles, ClosestPoint, Hit,
    Ray, RayCaster,
};
use crate::DVec3;

/// Queries per bridge call: large enough to amortise the FFI call and the
/// FTZ/DAZ switch, small enough to balance across rayon workers.
const CHUNK: usize = 1024;
const MISS: u32 = u32::MAX;

/// Embree's build quality (`RTCBuildQuality`): high builds a tree with
/// spatial splits (slower to build, faster rays), medium and low without.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum BuildQuality {
    Low = 0,
    Medium = 1,
    High = 2,
}

/// The build quality of scenes queried only for closest points
/// ([`EmbreeCaster::for_points`]): `SUBDFIT_EMBREE_POINT_BUILD` (`low`,
/// `medium`, `high`), else [`POINT_BUILD_QUALITY`].
pub fn point_build_quality() -> BuildQuality {
    match crate::switches::text("SUBDFIT_EMBREE_POINT_BUILD").as_deref() {
        Some("low") => BuildQuality::Low,
        Some("medium") => BuildQuality::Medium,
        Some("high") => BuildQuality::High,
        _ => POINT_BUILD_QUALITY,
    }
}

/// The default of [`point_build_quality`]: low (Embree's Morton
/// builder). `subdfit metrics` on bunny rung 1 (278k triangles), five
/// alternating runs each: 7.12 CPU s at low, 7.65 at medium, 7.67 at high,
/// the same JSON (docs/status.md, "Scale", session 23).
pub const POINT_BUILD_QUALITY: BuildQuality = BuildQuality::Low;

pub struct EmbreeCaster {
    scene: UniquePtr<bridge::EmbreeScene>,
    /// Subtracted from every position sent to Embree.
    center: DVec3,
    /// Embree primitive id -> mesh triangle id (zero-area triangles are not
    /// given to Embree).
    prim_to_tri: Vec<u32>,
    positions: Vec<DVec3>,
    triangles: Vec<[u32; 3]>,
}

fn backend_err(e: cxx::Exception) -> Error {
    Error::backend("Embree", e.what().to_string())
}

impl EmbreeCaster {
    /// Builds the Embree scene over `mesh` (high build quality). Errors:
    /// invalid mesh (see [`surface_triangles`]) or an Embree device error.
    pub fn new(mesh: &TriMesh) -> Result<Self> {
        Self::with_quality(mesh, BuildQuality::High)
    }

    /// [`Self::new`] for a scene asked only for closest points
    /// ([`RayCaster::closest_points`] and `_within`), built at
    /// [`point_build_quality`]. A point query keeps the least (distance,
    /// triangle id) over every triangle within a radius that only shrinks
    /// to a conservative bound of the best distance so far (the bridge's
    /// `point_query_callback`), so every tree gives the same answers, bit
    /// for bit; only the build's and the traversal's costs differ. Rays
    /// (a nearest hit among triangles at equal `t`) are not covered by
    /// that argument: use [`Self::new`] for them.
    pub fn for_points(mesh: &TriMesh) -> Result<Self> {
        Self::with_quality(mesh, point_build_quality())
    }

    /// [`Self::new`] at Embree build quality `quality`.
    pub fn with_quality(mesh: &TriMesh, quality: BuildQuality) -> Result<Self> {
        let prim_to_tri = surface_triangles(mesh)?;
        let (lo, hi) = mesh.bbox();
        let center = 0.5 * (lo + hi);
        let vertices: Vec<f32> = mesh
            .positions
            .iter()
            .flat_map(|&p| (p - center).as_vec3().to_array())
            .collect();
        let positions_f64: Vec<f64> = mesh.positions.iter().flat_map(|p| p.to_array()).collect();
        let tris: Vec<u32> = prim_to_tri
            .iter()
            .flat_map(|&t| mesh.triangles[t as usize])
            .collect();
        let scene = bridge::new_scene(&vertices, &tris, &positions_f64, quality as u8)
            .map_err(backend_err)?;
        Ok(EmbreeCaster {
            scene,
            center,
            prim_to_tri,
            positions: mesh.positions.clone(),
            triangles: mesh.triangles.clone(),
        })
    }

    fn tri(&self, t: u32) -> [DVec3; 3] {
        self.triangles[t as usize].map(|i| self.positions[i as usize])
    }

    /// Encodes `rays` as the bridge's 8 f32 per ray into `buf` (cleared);
    /// an invalid ray becomes tnear > tfar, which the bridge reports as a
    /// miss without tracing.
    fn encode_rays(&self, rays: &[Ray], buf: &mut Vec<f32>) {
        buf.clear();
        buf.reserve(8 * rays.len());
        for r in rays {
            if r.is_valid() {
                let o = (r.origin - self.center).as_vec3();
                let d = r.dir.as_vec3();
                buf.extend_from_slice(&[
                    o.x,
                    o.y,
                    o.z,
                    r.tmin as f32,
                    d.x,
                    d.y,
                    d.z,
                    r.tmax as f32,
                ]);
            } else {
                buf.extend_from_slice(&[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0]);
            }
        }
    }

    fn blocked_chunk(&self, rays: &[Ray], out: &mut [bool]) -> Result<()> {
        thread_local! {
            static BUF: std::cell::RefCell<(Vec<f32>, Vec<u8>)> =
                const { std::cell::RefCell::new((Vec::new(), Vec::new())) };
        }
        BUF.with(|b| {
            let (buf, flags) = &mut *b.borrow_mut();
            self.encode_rays(rays, buf);
            flags.clear();
            flags.resize(rays.len(), 0);
            self.scene.occluded_lines(buf, flags).map_err(backend_err)?;
            for (o, &f) in out.iter_mut().zip(flags.iter()) {
                *o = f != 0;
            }
            Ok(())
        })
    }

    fn trace_chunk(&self, rays: &[Ray]) -> Result<Vec<Option<Hit>>> {
        let mut buf = Vec::new();
        self.encode_rays(rays, &mut buf);
        let mut tuv = vec![0f32; 3 * rays.len()];
        let mut prim = vec![MISS; rays.len()];
        self.scene
            .intersect(&buf, &mut tuv, &mut prim)
            .map_err(backend_err)?;
        Ok(rays
            .iter()
            .enumerate()
            .map(|(i, r)| {
                if prim[i] == MISS || !r.is_valid() {
                    return None;
                }
                let tri = self.prim_to_tri[prim[i] as usize];
                let raw = Hit {
                    t: tuv[3 * i] as f64,
                    triangle: tri,
                    u: tuv[3 * i + 1] as f64,
                    v: tuv[3 * i + 2] as f64,
                };
                Some(refine_hit(self.tri(tri), r, raw))
            })
            .collect())
    }

    fn closest_chunk(&self, points: &[DVec3], max_dist: f64) -> Result<Vec<Option<ClosestPoint>>> {
        self.closest_chunk_with(points, |scene, p32, p64, prim| {
            scene.closest_points(p32, p64, max_dist, prim)
        })
    }

    fn closest_chunk_within(
        &self,
        points: &[DVec3],
        max_dists: &[f64],
    ) -> Result<Vec<Option<ClosestPoint>>> {
        self.closest_chunk_with(points, |scene, p32, p64, prim| {
            scene.closest_points_within(p32, p64, max_dists, prim)
        })
    }

    /// The bridge's closest triangles of `points` (by `query`), each
    /// answered in f64 against its triangle.
    fn closest_chunk_with(
        &self,
        points: &[DVec3],
        query: impl FnOnce(
            &bridge::EmbreeScene,
            &[f32],
            &[f64],
            &mut [u32],
        ) -> std::result::Result<(), cxx::Exception>,
    ) -> Result<Vec<Option<ClosestPoint>>> {
        let p32: Vec<f32> = points
            .iter()
            .flat_map(|&p| {
                if p.is_finite() {
                    (p - self.center).as_vec3().to_array()
                } else {
                    [0.0; 3] // skipped by the bridge (it checks the f64 copy)
                }
            })
            .collect();
        let p64: Vec<f64> = points.iter().flat_map(|p| p.to_array()).collect();
        let mut prim = vec![MISS; points.len()];
        query(&self.scene, &p32, &p64, &mut prim).map_err(backend_err)?;
        Ok(points
            .iter()
            .zip(&prim)
            .map(|(&p, &k)| {
                (k != MISS).then(|| {
                    let tri = self.prim_to_tri[k as usize];
                    closest_on_triangle(self.tri(tri), tri, p)
                })
            })
            .collect())
    }
}

/// Recomputes an f32 Embree hit in f64 against the original triangle: `t`
/// from the plane of the triangle, `(u, v)` from the barycentrics of the
/// f64 hit point, clamped to the triangle (Embree picked this triangle, so
/// any excursion is f32 rounding at an edge). Keeps Embree's values for a
/// ray parallel to the plane (grazing hit, where the plane gives no `t`).
pub(crate) fn refine_hit(tri: [DVec3; 3], ray: &Ray, raw: Hit) -> Hit {
    let [a, b, c] = tri;
    let e1 = b - a;
    let e2 = c - a;
    let n = e1.cross(e2);
    let denom = n.dot(ray.dir);
    let t = n.dot(a - ray.origin) / denom;
    if denom == 0.0 || !t.is_finite() {
        return raw;
    }
    let w = ray.at(t) - a;
    let (d00, d01, d11) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
    let (d20, d21) = (w.dot(e1), w.dot(e2));
    let den = d00 * d11 - d01 * d01;
    let mut u = ((d11 * d20 - d01 * d21) / den).max(0.0);
    let mut v = ((d00 * d21 - d01 * d20) / den).max(0.0);
    if u + v > 1.0 {
        let s = u + v;
        u /= s;
        v /= s;
    }
    Hit { t, u, v, ..raw }
}

impl RayCaster for EmbreeCaster {
    fn name(&self) -> &'static str {
        "embree"
    }

    fn first_hits(&self, rays: &[Ray]) -> Result<Vec<Option<Hit>>> {
        in_spatial_order(
            rays,
            |r| r.origin,
            |rays| {
                let chunks: Vec<Vec<Option<Hit>>> = rays
                    .par_chunks(CHUNK)
                    .map(|c| self.trace_chunk(c))
                    .collect::<Result<_>>()?;
                Ok(chunks.into_iter().flatten().collect())
            },
        )
    }

    fn lines_blocked(&self, rays: &[Ray], out: &mut Vec<bool>) -> Result<()> {
        out.clear();
        out.resize(rays.len(), false);
        // Two rays per line, both from the line's origin, as `first_hits`
        // would cast them. Measured and not kept: (a) one ray over the
        // whole segment, from `origin - tmax dir` over [0, 2 tmax], saves
        // ~8 % of the Fitmap's CPU time, but the f32 rounding of that start
        // flips a grazing verdict now and then (gargoyle τ 10 %: 3 of 25k
        // vertices one F_M step apart); (b) rtcOccluded4/8/16 packets of
        // these rays are no faster than rtcOccluded1 (the M-test's rays are
        // short and scattered over a ball).
        // Small batches (the M-test's, one ball at a time inside a rayon
        // job) are traced on the calling thread: no nested fork/join and no
        // per-chunk result vectors.
        if rays.len() <= CHUNK {
            return self.blocked_chunk(rays, out);
        }
        rays.par_chunks(CHUNK)
            .zip(out.par_chunks_mut(CHUNK))
            .try_for_each(|(r, o)| self.blocked_chunk(r, o))
    }

    fn closest_points(&self, points: &[DVec3], max_dist: f64) -> Result<Vec<Option<ClosestPoint>>> {
        check_max_dist(max_dist)?;
        in_spatial_order(
            points,
            |p| *p,
            |points| {
                let chunks: Vec<Vec<Option<ClosestPoint>>> = points
                    .par_chunks(CHUNK)
                    .map(|c| self.closest_chunk(c, max_dist))
                    .collect::<Result<_>>()?;
                Ok(chunks.into_iter().flatten().collect())
            },
        )
    }

    fn closest_points_within(
        &self,
        points: &[DVec3],
        max_dists: &[f64],
    ) -> Result<Vec<Option<ClosestPoint>>> {
        super::within_in_spatial_order(points, max_dists, |queries| {
            let chunks: Vec<Vec<Option<ClosestPoint>>> = queries
                .par_chunks(CHUNK)
                .map(|c| {
                    let (p, d): (Vec<DVec3>, Vec<f64>) = c.iter().copied().unzip();
                    self.closest_chunk_within(&p, &d)
                })
                .collect::<Result<_>>()?;
            Ok(chunks.into_iter().flatten().collect())
        })
    }
}
