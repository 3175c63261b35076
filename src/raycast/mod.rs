//! Ray casting against a triangle mesh behind one trait, two
//! implementations: [`bvh::BvhCaster`] (pure Rust, SAH BVH built in
//! parallel) and [`embree::EmbreeCaster`] (Embree 3, robust mode).
//!
//! All queries are batched and run on all cores; results are in input order
//! and do not depend on the thread count.
//!
//! Conventions shared by both implementations (and checked against each
//! other by `tests/raycast_differential.rs`):
//! - barycentrics are Embree's: the point is `(1 - u - v) a + u b + v c` for
//!   the triangle `(a, b, c)`, with `u, v >= 0`, `u + v <= 1`;
//! - triangles of zero area (exactly, in f64) are part of the mesh but are
//!   never hit and never returned as closest triangle;
//! - a ray with a non-finite origin or direction, a zero direction, NaN
//!   bounds, `tmin < 0` or `tmax < tmin` is a miss (the fitting pipeline
//!   feeds degenerate normals through unchanged rather than failing a batch);
//! - ties: a line query equidistant in both directions takes the `+dir`
//!   hit; closest points equidistant from several triangles take the smallest
//!   triangle id.

pub mod bvh;
pub mod embree;
pub mod watched;
pub use watched::Watched;

use serde::Serialize;

use crate::error::{Error, Result};
use crate::mesh::TriMesh;
use crate::DVec3;

/// A ray `origin + t * dir`, `t` in `[tmin, tmax]`. `dir` need not be unit;
/// `t` is in units of `dir`. `tmin` must be `>= 0` (see the module docs).
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct Ray {
    pub origin: DVec3,
    pub dir: DVec3,
    pub tmin: f64,
    pub tmax: f64,
}

impl Ray {
    /// The ray over `[0, +inf)`.
    pub fn new(origin: DVec3, dir: DVec3) -> Self {
        Ray {
            origin,
            dir,
            tmin: 0.0,
            tmax: f64::INFINITY,
        }
    }

    /// Whether the ray can hit anything (the module docs list the rest as
    /// misses).
    pub fn is_valid(&self) -> bool {
        self.origin.is_finite()
            && self.dir.is_finite()
            && self.dir != DVec3::ZERO
            && self.tmin >= 0.0
            && self.tmin <= self.tmax // false for NaN
    }

    pub fn at(&self, t: f64) -> DVec3 {
        self.origin + t * self.dir
    }
}

/// A hit: ray parameter, triangle and barycentric coordinates, the hit point
/// being `(1 - u - v) a + u b + v c` for the triangle `(a, b, c)`.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct Hit {
    /// Ray parameter; for line queries signed (negative: behind the origin).
    pub t: f64,
    pub triangle: u32,
    pub u: f64,
    pub v: f64,
}

/// The closest point of the mesh to a query point.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct ClosestPoint {
    pub point: DVec3,
    pub distance: f64,
    pub triangle: u32,
    pub u: f64,
    pub v: f64,
}

/// Which implementation of [`RayCaster`].
#[derive(Copy, Clone, Debug, PartialEq, Eq, Serialize)]
pub enum RayBackend {
    Embree,
    Rust,
}

/// Batched ray and closest-point queries against one triangle mesh.
///
/// Object safe; every query takes and returns whole batches so that an
/// implementation can parallelise and (for Embree) cross the FFI once per
/// chunk. Queries return `Result` because a C++ backend may report an error
/// at query time; bad *per-query* input is a miss, not an error, while bad
/// *batch* arguments (mismatched lengths, negative `max_t`) are
/// [`Error::InvalidArgument`].
pub trait RayCaster: Send + Sync {
    fn name(&self) -> &'static str;

    /// First hit along each ray within `[tmin, tmax]`.
    fn first_hits(&self, rays: &[Ray]) -> Result<Vec<Option<Hit>>>;

    /// Nearest hit on the *line* through `origins[i]` along `dirs[i]`, in
    /// either direction, with `|t| <= max_t` (the normal projection that
    /// fitting needs); `t` is signed, and a tie between both directions goes
    /// to `+dir`.
    ///
    /// The default casts two rays per line (`+dir` and `-dir` over
    /// `[0, max_t]`) through [`RayCaster::first_hits`] and keeps the nearer,
    /// so both backends share these semantics exactly.
    fn line_hits(&self, origins: &[DVec3], dirs: &[DVec3], max_t: f64) -> Result<Vec<Option<Hit>>> {
        check_lines(origins, dirs, max_t)?;
        let mut rays = Vec::with_capacity(2 * origins.len());
        for (&o, &d) in origins.iter().zip(dirs) {
            rays.push(Ray {
                origin: o,
                dir: d,
                tmin: 0.0,
                tmax: max_t,
            });
            rays.push(Ray {
                origin: o,
                dir: -d,
                tmin: 0.0,
                tmax: max_t,
            });
        }
        let hits = self.first_hits(&rays)?;
        Ok(hits
            .chunks_exact(2)
            .map(|p| nearer_on_line(p[0], p[1]))
            .collect())
    }

    /// Whether anything lies on the segment of each line: `out[i]` is true
    /// when `rays[i]` or the same ray with its direction negated (same
    /// `[tmin, tmax]`) hits the mesh — exactly `first_hits` of both rays,
    /// `is_some()` of either — without the closest hit's position. `out` is
    /// cleared and refilled (a caller's reusable buffer).
    ///
    /// The default goes through [`RayCaster::first_hits`]; Embree overrides
    /// it with any-hit queries (rtcOccluded1) that also skip the reversed
    /// ray once the forward one is blocked.
    fn lines_blocked(&self, rays: &[Ray], out: &mut Vec<bool>) -> Result<()> {
        let mut both = Vec::with_capacity(2 * rays.len());
        for r in rays {
            both.push(*r);
            both.push(Ray { dir: -r.dir, ..*r });
        }
        let hits = self.first_hits(&both)?;
        out.clear();
        out.extend(
            hits.chunks_exact(2)
                .map(|h| h[0].is_some() || h[1].is_some()),
        );
        Ok(())
    }

    /// Closest point of the mesh to each point, within `max_dist`
    /// (inclusive; `f64::INFINITY` for no limit). Non-finite points get `None`.
    fn closest_points(&self, points: &[DVec3], max_dist: f64) -> Result<Vec<Option<ClosestPoint>>>;

    /// [`RayCaster::closest_points`] with point `i`'s own limit
    /// `max_dists[i]`, for a caller that reads a closest point only where
    /// it lies within that limit (the displacement's same-sheet test,
    /// [`crate::displace::compute_displacement`]): there the answer is
    /// `closest_points(points, f64::INFINITY)`'s; elsewhere it is `None` or
    /// that same answer. A search bounded by its point's limit opens fewer
    /// boxes of the hierarchy. The default answers every point unbounded.
    fn closest_points_within(
        &self,
        points: &[DVec3],
        max_dists: &[f64],
    ) -> Result<Vec<Option<ClosestPoint>>> {
        check_max_dists(points, max_dists)?;
        self.closest_points(points, f64::INFINITY)
    }
}

/// [`RayCaster::closest_points_within`] for a caster that orders its
/// batches ([`in_spatial_order`]): the limits checked (one per point),
/// then `answer` takes sub-batches of (point, limit) pairs in Z-order.
pub(crate) fn within_in_spatial_order<A: Copy + Default + Send>(
    points: &[DVec3],
    max_dists: &[f64],
    answer: impl FnMut(&[(DVec3, f64)]) -> Result<Vec<A>>,
) -> Result<Vec<A>> {
    check_max_dists(points, max_dists)?;
    let queries: Vec<(DVec3, f64)> = points
        .iter()
        .copied()
        .zip(max_dists.iter().copied())
        .collect();
    in_spatial_order(&queries, |q| q.0, answer)
}

/// Answers `queries` (located at `at(query)`) in the Z-order (Morton
/// order) of their locations, `answer` taking sub-batches of at most
/// [`SUB_BATCH`] in that order, and returns the answers in input order.
///
/// Why: on a mesh of a million triangles the BVH and the triangles it
/// visits no longer fit in the caches, and the batches the pipeline makes
/// (quadrature points in triangle order, grid samples patch by patch) jump
/// across the mesh; neighbouring queries in Z-order visit the same nodes
/// and leaves (1.1M-triangle ladder rung: 15 % less CPU time). The answers
/// do not change: each query is answered on its own (module docs), so only
/// the time does. Memory: 8 bytes per query for the order, and one
/// sub-batch of copies (the answers go straight to their place). A batch
/// of at most one sub-batch is answered as it comes: it is too small to
/// gain, and a sub-batch handed on to a caster that orders its own
/// batches again (the watched wrapper around Embree, a caller ordering
/// before either) is not sorted twice.
pub(crate) fn in_spatial_order<Q: Copy + Send + Sync, A: Copy + Default + Send>(
    queries: &[Q],
    at: impl Fn(&Q) -> DVec3 + Sync,
    mut answer: impl FnMut(&[Q]) -> Result<Vec<A>>,
) -> Result<Vec<A>> {
    if queries.len() <= SUB_BATCH || queries.len() > u32::MAX as usize {
        return answer(queries);
    }
    let Some(order) = spatial_order(queries.len(), |i| at(&queries[i])) else {
        return answer(queries);
    };
    let mut out = vec![A::default(); queries.len()];
    let mut batch = Vec::with_capacity(SUB_BATCH);
    for part in order.chunks(SUB_BATCH) {
        batch.clear();
        batch.extend(part.iter().map(|&k| queries[(k & 0xffff_ffff) as usize]));
        let answers = answer(&batch)?;
        if answers.len() != part.len() {
            return Err(Error::backend(
                "ray caster",
                "a batch returned too few answers",
            ));
        }
        for (&k, a) in part.iter().zip(answers) {
            out[(k & 0xffff_ffff) as usize] = a;
        }
    }
    Ok(out)
}

/// The Z-order (Morton order) of `n` points (`at(i)`), as `(key << 32) |
/// i` sorted (the index is the low 32 bits): keys tie-broken by index, so
/// the order is the same on every run. `None` when no point is finite or
/// `n` does not fit 32 bits. Non-finite points come last.
pub(crate) fn spatial_order(n: usize, at: impl Fn(usize) -> DVec3 + Sync) -> Option<Vec<u64>> {
    use rayon::prelude::*;
    if n > u32::MAX as usize {
        return None;
    }
    let (lo, hi) = (0..n)
        .into_par_iter()
        .with_min_len(1 << 12)
        .map(&at)
        .filter(|p| p.is_finite())
        .fold(
            || (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
            |(lo, hi), p| (lo.min(p), hi.max(p)),
        )
        .reduce(
            || (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
            |a, b| (a.0.min(b.0), a.1.max(b.1)),
        );
    if !(lo.cmple(hi).all()) {
        return None;
    }
    // 10 bits per axis: cells of a thousandth of the extent, finer than
    // the cache can tell apart, and a 30-bit key that packs with the index.
    let scale = DVec3::splat(1023.0) / (hi - lo).max(DVec3::splat(f64::MIN_POSITIVE));
    let mut order: Vec<u64> = (0..n)
        .into_par_iter()
        .map(|i| {
            let p = at(i);
            let key = if p.is_finite() {
                let c = ((p - lo) * scale).as_uvec3().min(glam::UVec3::splat(1023));
                morton3(c.x) | (morton3(c.y) << 1) | (morton3(c.z) << 2)
            } else {
                1 << 30
            };
            (key << 32) | i as u64
        })
        .collect();
    order.par_sort_unstable();
    Some(order)
}

/// Queries per call of [`in_spatial_order`]'s `answer`: enough for both
/// cores (16 chunks of Embree's 1024), little memory.
pub(crate) const SUB_BATCH: usize = 1 << 14;

/// The 10 low bits of `x` spread to every third bit (Morton code).
fn morton3(x: u32) -> u64 {
    let mut x = u64::from(x) & 0x3ff;
    x = (x | x << 16) & 0x30000ff;
    x = (x | x << 8) & 0x300f00f;
    x = (x | x << 4) & 0x30c30c3;
    (x | x << 2) & 0x9249249
}

/// Builds the chosen ray caster over `mesh`.
pub fn make_raycaster(backend: RayBackend, mesh: &TriMesh) -> Result<Box<dyn RayCaster>> {
    Ok(match backend {
        RayBackend::Embree => Box::new(embree::EmbreeCaster::new(mesh)?),
        RayBackend::Rust => Box::new(bvh::BvhCaster::new(mesh)?),
    })
}

/// An Embree caster over `mesh` for closest-point queries only
/// ([`embree::EmbreeCaster::for_points`]: a cheaper build, the same
/// answers bit for bit). Its rays are those of another tree than
/// [`make_raycaster`]'s: ask it for none.
pub fn make_point_caster(mesh: &TriMesh) -> Result<Box<dyn RayCaster>> {
    Ok(Box::new(embree::EmbreeCaster::for_points(mesh)?))
}

/// Name used for in-memory meshes in [`Error::InvalidMesh`].
const MESH_NAME: &str = "<ray caster mesh>";

/// Checks `mesh` for the ray casters and returns the ids of its triangles of
/// non-zero area (the only ones queries can return), in increasing order.
///
/// Errors: a vertex index out of range, or a triangle with a non-finite
/// coordinate (named by triangle and vertex).
pub(crate) fn surface_triangles(mesh: &TriMesh) -> Result<Vec<u32>> {
    if mesh.triangles.len() > u32::MAX as usize - 1 {
        return Err(Error::invalid_mesh(
            MESH_NAME,
            "triangles",
            "more than 2^32 - 2 triangles; split the mesh",
        ));
    }
    let mut ids = Vec::with_capacity(mesh.triangles.len());
    for (t, tri) in mesh.triangles.iter().enumerate() {
        for &i in tri {
            let Some(p) = mesh.positions.get(i as usize) else {
                return Err(Error::invalid_mesh(
                    MESH_NAME,
                    format!("triangle {t}"),
                    format!(
                        "vertex index {i} out of range ({} vertices)",
                        mesh.positions.len()
                    ),
                ));
            };
            if !p.is_finite() {
                return Err(Error::invalid_mesh(
                    MESH_NAME,
                    format!("triangle {t}"),
                    format!("vertex {i} has a non-finite coordinate {p}; remove or repair it"),
                ));
            }
        }
        let [a, b, c] = mesh.triangle(t);
        if (b - a).cross(c - a) != DVec3::ZERO {
            ids.push(t as u32);
        }
    }
    Ok(ids)
}

fn check_lines(origins: &[DVec3], dirs: &[DVec3], max_t: f64) -> Result<()> {
    if origins.len() != dirs.len() {
        return Err(Error::InvalidArgument(format!(
            "line_hits: {} origins but {} directions",
            origins.len(),
            dirs.len()
        )));
    }
    if max_t.is_nan() || max_t < 0.0 {
        return Err(Error::InvalidArgument(format!(
            "line_hits: max_t must be >= 0, got {max_t}"
        )));
    }
    Ok(())
}

/// [`check_max_dist`] of every limit of [`RayCaster::closest_points_within`],
/// one per point.
pub(crate) fn check_max_dists(points: &[DVec3], max_dists: &[f64]) -> Result<()> {
    if points.len() != max_dists.len() {
        return Err(Error::InvalidArgument(format!(
            "closest_points_within: {} points but {} limits",
            points.len(),
            max_dists.len()
        )));
    }
    max_dists.iter().try_for_each(|&d| check_max_dist(d))
}

pub(crate) fn check_max_dist(max_dist: f64) -> Result<()> {
    if max_dist.is_nan() || max_dist < 0.0 {
        return Err(Error::InvalidArgument(format!(
            "closest_points: max_dist must be >= 0, got {max_dist}"
        )));
    }
    Ok(())
}

/// The nearer of a `+dir` and a `-dir` hit, `t` signed; the `+dir` hit wins
/// ties (both backends share this through [`RayCaster::line_hits`]).
pub(crate) fn nearer_on_line(fwd: Option<Hit>, bwd: Option<Hit>) -> Option<Hit> {
    match (fwd, bwd) {
        (Some(f), Some(b)) if b.t < f.t => Some(Hit { t: -b.t, ..b }),
        (Some(f), _) => Some(f),
        (None, Some(b)) => Some(Hit { t: -b.t, ..b }),
        (None, None) => None,
    }
}

/// Closest point of triangle `(a, b, c)` to `p`: Ericson, *Real-Time
/// Collision Detection*, §5.1.5 (`ClosestPtPointTriangle`), classifying `p`
/// against the Voronoi regions by barycentric dot products. Returns the point
/// and Embree-convention `(u, v)`. Mirrored in C++ (`point_triangle_dist2` in
/// `cpp/embree_bridge.cpp`) for Embree's point-query callback.
pub(crate) fn closest_point_triangle(p: DVec3, a: DVec3, b: DVec3, c: DVec3) -> (DVec3, f64, f64) {
    let ab = b - a;
    let ac = c - a;
    let ap = p - a;
    let d1 = ab.dot(ap);
    let d2 = ac.dot(ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return (a, 0.0, 0.0); // vertex region a
    }
    let bp = p - b;
    let d3 = ab.dot(bp);
    let d4 = ac.dot(bp);
    if d3 >= 0.0 && d4 <= d3 {
        return (b, 1.0, 0.0); // vertex region b
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return (a + v * ab, v, 0.0); // edge ab
    }
    let cp = p - c;
    let d5 = ab.dot(cp);
    let d6 = ac.dot(cp);
    if d6 >= 0.0 && d5 <= d6 {
        return (c, 0.0, 1.0); // vertex region c
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return (a + w * ac, 0.0, w); // edge ac
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return (b + w * (c - b), 1.0 - w, w); // edge bc
    }
    let denom = 1.0 / (va + vb + vc);
    let v = vb * denom;
    let w = vc * denom;
    (a + ab * v + ac * w, v, w) // interior
}

/// Builds the [`ClosestPoint`] of `mesh` triangle `tri` to `p` in f64.
pub(crate) fn closest_on_triangle(mesh_tri: [DVec3; 3], tri: u32, p: DVec3) -> ClosestPoint {
    let [a, b, c] = mesh_tri;
    let (q, u, v) = closest_point_triangle(p, a, b, c);
    ClosestPoint {
        point: q,
        distance: (p - q).length(),
        triangle: tri,
        u,
        v,
    }
}

#[cfg(test)]
pub(crate) mod tests_support {
    use super::*;

    /// An `n` x `n` grid of unit squares in the plane z = 0, split into
    /// triangles, with a deterministic bump in z (for build tests).
    pub(crate) fn noisy_grid(n: u32) -> TriMesh {
        crate::fixtures::tri_grid(
            n,
            |i, j| DVec3::new(i as f64, j as f64, ((i * 7 + j * 13) % 11) as f64 * 0.01),
            |_, _| true,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spatial_order_answers_every_query_in_input_order() {
        // Large enough to be sorted, with duplicates and non-finite points.
        let n = 3 * SUB_BATCH + 7;
        let q: Vec<DVec3> = (0..n)
            .map(|i| match i % 1000 {
                0 => DVec3::splat(f64::NAN),
                1 => DVec3::new(f64::INFINITY, 0.0, 0.0),
                _ => DVec3::new(
                    ((i * 7919) % 1013) as f64,
                    ((i * 104729) % 997) as f64 * 1e-3,
                    (i % 5) as f64,
                ),
            })
            .collect();
        let mut seen_sorted = false;
        let out = in_spatial_order(
            &q,
            |p| *p,
            |s| {
                assert!(s.len() <= SUB_BATCH, "sub-batches of at most SUB_BATCH");
                seen_sorted |= s.iter().zip(&q).any(|(a, b)| a.to_array() != b.to_array());
                Ok(s.to_vec())
            },
        )
        .unwrap();
        assert!(
            seen_sorted,
            "a batch this large is answered in another order"
        );
        assert_eq!(out.len(), n);
        for (a, b) in out.iter().zip(&q) {
            assert_eq!(
                a.to_array().map(f64::to_bits),
                b.to_array().map(f64::to_bits)
            );
        }
        // An answer missing is an error, not a short result.
        assert!(in_spatial_order(&q, |p| *p, |s| Ok(s[1..].to_vec())).is_err());
    }

    #[test]
    fn nan_vertex_is_rejected_naming_the_triangle() {
        let mut m = tests_support::noisy_grid(2);
        m.positions[4].y = f64::NAN;
        let t = m.triangles.iter().position(|t| t.contains(&4)).unwrap();
        for backend in [RayBackend::Rust, RayBackend::Embree] {
            let err = make_raycaster(backend, &m)
                .err()
                .expect("NaN must be rejected");
            let msg = err.to_string();
            assert!(msg.contains(&format!("triangle {t}:")), "{msg}");
            assert!(msg.contains("vertex 4"), "{msg}");
        }
    }

    #[test]
    fn out_of_range_index_is_rejected() {
        let mut m = tests_support::noisy_grid(1);
        m.triangles[1][2] = 99;
        let err = surface_triangles(&m).unwrap_err().to_string();
        assert!(err.contains("triangle 1") && err.contains("99"), "{err}");
    }

    #[test]
    fn closest_point_regions() {
        let (a, b, c) = (DVec3::ZERO, DVec3::X, DVec3::Y);
        let cases = [
            (
                DVec3::new(0.2, 0.3, 1.0),
                DVec3::new(0.2, 0.3, 0.0),
                0.2,
                0.3,
            ),
            (DVec3::new(-1.0, -1.0, 0.0), a, 0.0, 0.0),
            (DVec3::new(2.0, -0.1, 0.0), b, 1.0, 0.0),
            (
                DVec3::new(0.5, -1.0, 0.0),
                DVec3::new(0.5, 0.0, 0.0),
                0.5,
                0.0,
            ),
            (
                DVec3::new(1.0, 1.0, 0.5),
                DVec3::new(0.5, 0.5, 0.0),
                0.5,
                0.5,
            ),
            (
                DVec3::new(-1.0, 0.25, 0.0),
                DVec3::new(0.0, 0.25, 0.0),
                0.0,
                0.25,
            ),
        ];
        for (p, q, u, v) in cases {
            let (got, gu, gv) = closest_point_triangle(p, a, b, c);
            assert!((got - q).length() < 1e-15, "{p}: {got} != {q}");
            assert!((gu - u).abs() < 1e-15 && (gv - v).abs() < 1e-15, "{p}");
            // The barycentrics reproduce the point (Embree convention).
            assert!(((1.0 - gu - gv) * a + gu * b + gv * c - got).length() < 1e-15);
        }
    }

    #[test]
    fn line_hit_tie_prefers_plus_dir() {
        let h = |t| Hit {
            t,
            triangle: 0,
            u: 0.0,
            v: 0.0,
        };
        let f = Hit {
            triangle: 1,
            ..h(2.0)
        };
        let b = Hit {
            triangle: 2,
            ..h(2.0)
        };
        assert_eq!(nearer_on_line(Some(f), Some(b)).unwrap().triangle, 1);
        let b = Hit {
            triangle: 2,
            ..h(1.0)
        };
        let got = nearer_on_line(Some(f), Some(b)).unwrap();
        assert_eq!((got.triangle, got.t), (2, -1.0));
    }
}
