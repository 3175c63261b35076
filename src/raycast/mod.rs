//! Ray casting against a triangle mesh behind one trait, two
//! implementations: [`bvh::BvhCaster`] (pure Rust, SAH BVH built in
//! parallel) and [`embree::EmbreeCaster`] (Embree 3, robust mode).
//!
//! All queries are batched and run on all cores; results are in input order
//! and do not depend on the thread count.

pub mod bvh;
pub mod embree;

use serde::Serialize;

use crate::error::Result;
use crate::mesh::TriMesh;
use crate::DVec3;

/// A ray `origin + t * dir`, `t` in `[tmin, tmax]`. `dir` need not be unit;
/// `t` is in units of `dir`.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct Ray {
    pub origin: DVec3,
    pub dir: DVec3,
    pub tmin: f64,
    pub tmax: f64,
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

pub trait RayCaster: Send + Sync {
    fn name(&self) -> &'static str;
    /// First hit along each ray within `[tmin, tmax]`.
    fn first_hits(&self, rays: &[Ray]) -> Vec<Option<Hit>>;
    /// Nearest hit on the *line* through `origins[i]` along `dirs[i]`, in
    /// either direction, with `|t| <= max_t` (the normal projection that
    /// fitting needs); `t` is signed.
    fn line_hits(&self, origins: &[DVec3], dirs: &[DVec3], max_t: f64) -> Vec<Option<Hit>>;
    /// Closest point of the mesh to each point, within `max_dist`.
    fn closest_points(&self, points: &[DVec3], max_dist: f64) -> Vec<Option<ClosestPoint>>;
}

/// Builds the chosen ray caster over `mesh`.
pub fn make_raycaster(backend: RayBackend, mesh: &TriMesh) -> Result<Box<dyn RayCaster>> {
    Ok(match backend {
        RayBackend::Embree => Box::new(embree::EmbreeCaster::new(mesh)?),
        RayBackend::Rust => Box::new(bvh::BvhCaster::new(mesh)?),
    })
}
