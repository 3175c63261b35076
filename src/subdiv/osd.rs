//! OpenSubdiv (Far) limit evaluation through the cxx bridge.

use crate::error::{Error, Result};
use crate::mesh::ControlMesh;
use crate::subdiv::{EvalOptions, LimitEvaluator, LimitPoint, LimitStencils, SurfaceLocation};
use crate::DVec3;

pub struct OsdEvaluator {
    num_vertices: usize,
}

impl OsdEvaluator {
    pub fn new(mesh: &ControlMesh, _options: &EvalOptions) -> Result<Self> {
        Ok(OsdEvaluator {
            num_vertices: mesh.num_vertices(),
        })
    }
}

impl LimitEvaluator for OsdEvaluator {
    fn name(&self) -> &'static str {
        "osd"
    }
    fn num_control_vertices(&self) -> usize {
        self.num_vertices
    }
    fn vertex_limits(&self, _positions: &[DVec3]) -> Result<Vec<LimitPoint>> {
        Err(Error::InvalidArgument(
            "osd evaluator: not implemented yet".into(),
        ))
    }
    fn evaluate(
        &self,
        _positions: &[DVec3],
        _locations: &[SurfaceLocation],
    ) -> Result<Vec<LimitPoint>> {
        Err(Error::InvalidArgument(
            "osd evaluator: not implemented yet".into(),
        ))
    }
    fn stencils(&self, _locations: &[SurfaceLocation]) -> Result<LimitStencils> {
        Err(Error::InvalidArgument(
            "osd evaluator: not implemented yet".into(),
        ))
    }
}
