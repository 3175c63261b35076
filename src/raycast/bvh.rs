use crate::error::Result;
use crate::mesh::TriMesh;
use crate::raycast::{ClosestPoint, Hit, Ray, RayCaster};
use crate::DVec3;

pub struct BvhCaster {}

impl BvhCaster {
    pub fn new(_mesh: &TriMesh) -> Result<Self> {
        Ok(BvhCaster {})
    }
}

impl RayCaster for BvhCaster {
    fn name(&self) -> &'static str {
        "rust"
    }
    fn first_hits(&self, rays: &[Ray]) -> Vec<Option<Hit>> {
        vec![None; rays.len()]
    }
    fn line_hits(&self, origins: &[DVec3], _dirs: &[DVec3], _max_t: f64) -> Vec<Option<Hit>> {
        vec![None; origins.len()]
    }
    fn closest_points(&self, points: &[DVec3], _max_dist: f64) -> Vec<Option<ClosestPoint>> {
        vec![None; points.len()]
    }
}
