//! Displacement (Fitmaps §1.2, §4): per patch of the control mesh an
//! `R × R` grid of scalar offsets along the limit normal, from the limit
//! surface S_K to M through the projection φ ([`crate::project`]). Samples
//! live on a welded [`PatchGrid`], so a sample on a patch edge is computed
//! once and stored identically in both tiles of the atlas.
//!
//! Misses (the normal line meets M nowhere within the search distance) are
//! *unprojectable*: their offset is 0 (the displaced surface falls back to
//! the limit there) and they are counted in [`DisplacementStats`].

mod atlas;
mod grid;

pub use atlas::{read_exr, Atlas, DEFAULT_GUTTER};
pub use grid::PatchGrid;

use serde::Serialize;

use crate::error::Result;
use crate::mesh::ControlMesh;
use crate::project::{project_along_normals, ProjectionStats};
use crate::raycast::RayCaster;
use crate::subdiv::{LimitEvaluator, LimitPoint};
use crate::DVec3;

/// The per-patch resolution R that makes the total number of samples
/// (`faces · R²`) roughly match M's vertex count (Fitmaps §4, Table 1),
/// at least 2 (the patch corners) and at most 64 (a 64² tile already
/// exceeds any input density this pipeline produces patches for).
pub fn auto_resolution(mesh_vertices: usize, patches: usize) -> usize {
    if patches == 0 {
        return 2;
    }
    let r = (mesh_vertices as f64 / patches as f64).sqrt().round() as usize;
    r.clamp(2, 64)
}

/// Counts of a displacement computation.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct DisplacementStats {
    pub resolution: usize,
    pub patches: usize,
    /// Distinct (welded) samples.
    pub samples: usize,
    pub unprojectable: usize,
    /// Percentage of samples with no projection.
    pub unprojectable_percent: f64,
    /// Largest |offset|, in ‰ of M's bounding-box diagonal.
    pub max_abs_offset_permille: f64,
}

/// Displacement samples on a welded grid: limit point, offset along the
/// unit limit normal, and whether φ reached M.
#[derive(Clone, Debug)]
pub struct Displacement {
    pub grid: PatchGrid,
    /// Limit point (with derivatives) at each global sample.
    pub limit: Vec<LimitPoint>,
    /// Signed offset along the unit limit normal (0 where unprojectable).
    pub offsets: Vec<f64>,
    pub projected: Vec<bool>,
    pub stats: DisplacementStats,
}

impl Displacement {
    /// Positions of the limit surface at the samples.
    pub fn limit_positions(&self) -> Vec<DVec3> {
        self.limit.iter().map(|p| p.position).collect()
    }

    /// Positions of the displaced surface `s + d·n` at the samples.
    pub fn displaced_positions(&self) -> Vec<DVec3> {
        self.limit
            .iter()
            .zip(&self.offsets)
            .map(|(p, &d)| p.position + d * p.normal())
            .collect()
    }
}

/// Samples the limit surface of `control` on an `res × res` welded grid per
/// patch and measures the offset to M (`caster` is built over M) along the
/// limit normal, within `max_dist`. `diag` is M's bounding-box diagonal
/// (the unit of the reported figures).
///
/// With `limit_surface` (a ray caster over a tessellation of the same limit
/// surface), a hit is kept only if the sample is (about) the closest point
/// of L to it: the closest point of L to φ(s) must be at least half as far
/// as s. Otherwise the normal line went past M here and met another sheet
/// of M (across a hole, a thin part, a fold) — a correct φ but a useless
/// displacement, which would raise a spike across the model; such samples
/// count as unprojectable.
pub fn compute_displacement(
    control: &ControlMesh,
    evaluator: &dyn LimitEvaluator,
    caster: &dyn RayCaster,
    limit_surface: Option<&dyn RayCaster>,
    res: usize,
    max_dist: f64,
    diag: f64,
) -> Result<Displacement> {
    let grid = PatchGrid::new(control, res)?;
    let limit = evaluator.evaluate(control.positions(), grid.locations())?;
    let (mut hits, mut pstats): (_, ProjectionStats) =
        project_along_normals(caster, &limit, max_dist)?;
    if let Some(l) = limit_surface {
        let feet: Vec<DVec3> = hits
            .iter()
            .map(|h| h.map_or(DVec3::NAN, |h| h.point))
            .collect();
        let back = l.closest_points(&feet, f64::INFINITY)?;
        for (h, b) in hits.iter_mut().zip(back) {
            let (Some(hit), Some(b)) = (*h, b) else {
                continue;
            };
            // Below 1e-9 of the diagonal the sample is on M: nothing to test.
            if hit.offset.abs() > 1e-9 * diag && b.distance < 0.5 * hit.offset.abs() {
                *h = None;
                pstats.unprojectable += 1;
            }
        }
    }
    let offsets: Vec<f64> = hits.iter().map(|h| h.map_or(0.0, |h| h.offset)).collect();
    let projected: Vec<bool> = hits.iter().map(Option::is_some).collect();
    let max_abs = offsets.iter().fold(0.0f64, |m, d| m.max(d.abs()));
    let stats = DisplacementStats {
        resolution: res,
        patches: grid.num_patches(),
        samples: grid.num_samples(),
        unprojectable: pstats.unprojectable,
        unprojectable_percent: 100.0 * pstats.unprojectable_fraction(),
        max_abs_offset_permille: 1000.0 * max_abs / diag.max(f64::MIN_POSITIVE),
    };
    Ok(Displacement {
        grid,
        limit,
        offsets,
        projected,
        stats,
    })
}
