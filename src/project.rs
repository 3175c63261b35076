//! The projection φ of the Fitmaps paper (§2, §3.3): from a point of the
//! limit surface, the nearest intersection with the input mesh M along the
//! limit normal, in either direction. A point with no valid hit is
//! *unprojectable*: it is counted and reported, never silently dropped.

use serde::Serialize;

use crate::error::{Error, Result};
use crate::mesh::TriMesh;
use crate::raycast::RayCaster;
use crate::subdiv::LimitPoint;
use crate::DVec3;

/// A point of M reached by φ.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct Projected {
    /// The point of M.
    pub point: DVec3,
    /// Signed distance along the unit limit normal (positive: outside).
    pub offset: f64,
    pub triangle: u32,
    /// Barycentrics, `p = (1-u-v) a + u b + v c`.
    pub u: f64,
    pub v: f64,
}

/// Counts of a batch of projections.
#[derive(Copy, Clone, Debug, Default, PartialEq, Serialize)]
pub struct ProjectionStats {
    pub points: usize,
    pub unprojectable: usize,
}

impl ProjectionStats {
    pub fn unprojectable_fraction(&self) -> f64 {
        if self.points == 0 {
            0.0
        } else {
            self.unprojectable as f64 / self.points as f64
        }
    }
}

/// φ for a batch of limit points: the nearest hit of M on the line through
/// each point along its unit normal, within `max_dist` (absolute units).
/// A point whose normal is undefined (zero derivatives) or whose line meets
/// M nowhere within `max_dist` is unprojectable (`None`).
pub fn project_along_normals(
    caster: &dyn RayCaster,
    points: &[LimitPoint],
    max_dist: f64,
) -> Result<(Vec<Option<Projected>>, ProjectionStats)> {
    if !(max_dist.is_finite() && max_dist > 0.0) {
        return Err(Error::InvalidArgument(format!(
            "projection: max_dist {max_dist} must be finite and > 0"
        )));
    }
    let origins: Vec<DVec3> = points.iter().map(|p| p.position).collect();
    let dirs: Vec<DVec3> = points.iter().map(|p| p.normal()).collect();
    project_along(caster, &origins, &dirs, max_dist)
}

/// [`project_along_normals`] from `origins` along given unit directions
/// `dirs` (the displacement's, [`crate::displace`]'s rule at creases).
pub fn project_along(
    caster: &dyn RayCaster,
    origins: &[DVec3],
    dirs: &[DVec3],
    max_dist: f64,
) -> Result<(Vec<Option<Projected>>, ProjectionStats)> {
    if !(max_dist.is_finite() && max_dist > 0.0) {
        return Err(Error::InvalidArgument(format!(
            "projection: max_dist {max_dist} must be finite and > 0"
        )));
    }
    let points = origins;
    let hits = caster.line_hits(origins, dirs, max_dist)?;
    let mut stats = ProjectionStats {
        points: points.len(),
        unprojectable: 0,
    };
    let out = hits
        .iter()
        .zip(origins.iter().zip(dirs))
        .map(|(h, (&o, &d))| match h {
            Some(h) if d != DVec3::ZERO => Some(Projected {
                point: o + h.t * d,
                offset: h.t,
                triangle: h.triangle,
                u: h.u,
                v: h.v,
            }),
            _ => {
                stats.unprojectable += 1;
                None
            }
        })
        .collect();
    Ok((out, stats))
}

/// The default search distance of φ: a quarter of M's bounding-box diagonal
/// (the largest Fitmap radius r_h, §3.1.2): no patch is larger, so a hit
/// further away belongs to another part of the model.
pub fn default_max_dist(mesh: &TriMesh) -> f64 {
    0.25 * mesh.bbox_diagonal()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::raycast::{make_raycaster, RayBackend};

    #[test]
    fn projects_onto_a_plane_both_ways_and_counts_misses() {
        let mesh = TriMesh {
            positions: vec![
                DVec3::new(-1.0, -1.0, 0.0),
                DVec3::new(1.0, -1.0, 0.0),
                DVec3::new(1.0, 1.0, 0.0),
                DVec3::new(-1.0, 1.0, 0.0),
            ],
            triangles: vec![[0, 1, 2], [0, 2, 3]],
        };
        let caster = make_raycaster(RayBackend::Rust, &mesh).unwrap();
        let lp = |p: DVec3| LimitPoint {
            position: p,
            du: DVec3::X,
            dv: DVec3::Y,
        };
        let pts = [
            lp(DVec3::new(0.2, 0.3, 0.5)),
            lp(DVec3::new(-0.4, 0.1, -0.25)),
            lp(DVec3::new(5.0, 5.0, 0.1)),
            LimitPoint::default(),
        ];
        let (p, stats) = project_along_normals(caster.as_ref(), &pts, 1.0).unwrap();
        let a = p[0].unwrap();
        assert!(
            (a.offset + 0.5).abs() < 1e-12
                && (a.point - DVec3::new(0.2, 0.3, 0.0)).length() < 1e-12
        );
        let b = p[1].unwrap();
        assert!((b.offset - 0.25).abs() < 1e-12);
        assert!(p[2].is_none() && p[3].is_none());
        assert_eq!(
            stats,
            ProjectionStats {
                points: 4,
                unprojectable: 2
            }
        );
        assert!(project_along_normals(caster.as_ref(), &pts, f64::NAN).is_err());
    }
}
