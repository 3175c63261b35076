//! Pure-Rust exact Catmull-Clark limit evaluation.

use crate::error::{Error, Result};
use crate::mesh::ControlMesh;
use crate::subdiv::{EvalOptions, LimitEvaluator, LimitPoint, LimitStencils, SurfaceLocation};
use crate::DVec3;

pub struct RustEvaluator {
    num_vertices: usize,
}

impl RustEvaluator {
    pub fn new(mesh: &ControlMesh, _options: &EvalOptions) -> Result<Self> {
        Ok(RustEvaluator {
            num_vertices: mesh.num_vertices(),
        })
    }
}

impl LimitEvaluator for RustEvaluator {
    fn name(&self) -> &'static str {
        "rust"
    }
    fn num_control_vertices(&self) -> usize {
        self.num_vertices
    }
    fn vertex_limits(&self, _positions: &[DVec3]) -> Result<Vec<LimitPoint>> {
        Err(Error::InvalidArgument(
            "rust evaluator: not implemented yet".into(),
        ))
    }
    fn evaluate(
        &self,
        _positions: &[DVec3],
        _locations: &[SurfaceLocation],
    ) -> Result<Vec<LimitPoint>> {
        Err(Error::InvalidArgument(
            "rust evaluator: not implemented yet".into(),
        ))
    }
    fn stencils(&self, _locations: &[SurfaceLocation]) -> Result<LimitStencils> {
        Err(Error::InvalidArgument(
            "rust evaluator: not implemented yet".into(),
        ))
    }
}
