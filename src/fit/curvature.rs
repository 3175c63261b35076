//! Per-triangle principal curvatures of M for the squared-distance
//! objective: the shape operator fitted to the change of the vertex normals
//! across each triangle (Rusinkiewicz 2004, "Estimating curvatures and their
//! derivatives on triangle meshes", the per-face step, without the
//! per-vertex averaging). Lavoué §7.1 interpolates per-vertex tensors at the
//! foot point; one tensor per triangle is the same estimate one step
//! earlier, and enough for the weights of the approximant.

use glam::{DMat3, DVec3};

use crate::mesh::TriMesh;

/// Principal curvatures (κ1 ≥ κ2) and the direction of κ1 on one triangle.
/// Sign: positive where the surface bends away from its normal (convex,
/// for outward normals), i.e. `dN = S dX`.
#[derive(Copy, Clone, Debug, Default, PartialEq)]
pub struct TriCurvature {
    pub k1: f64,
    pub k2: f64,
    /// Unit direction of κ1, in the triangle's plane.
    pub dir1: DVec3,
}

/// Curvature of every triangle from the vertex normals `normals` (unit, one
/// per vertex of `mesh`). Degenerate triangles get zero curvature.
pub fn triangle_curvatures(mesh: &TriMesh, normals: &[DVec3]) -> Vec<TriCurvature> {
    mesh.triangles
        .iter()
        .map(|t| {
            let p = t.map(|i| mesh.positions[i as usize]);
            let n = t.map(|i| normals[i as usize]);
            shape_operator(p, n).unwrap_or_default()
        })
        .collect()
}

fn shape_operator(p: [DVec3; 3], n: [DVec3; 3]) -> Option<TriCurvature> {
    let nf = (p[1] - p[0]).cross(p[2] - p[0]).try_normalize()?;
    let t1 = (p[1] - p[0]).try_normalize()?;
    let t2 = nf.cross(t1);
    // Least squares for S = [[a, b], [b, c]] from S·dp = dn on the three
    // edges, in the (t1, t2) frame: rows (ex, ey, 0) and (0, ex, ey).
    let mut m = DMat3::ZERO;
    let mut rhs = DVec3::ZERO;
    for (a, b) in [(0, 1), (1, 2), (2, 0)] {
        let dp = p[b] - p[a];
        let dn = n[b] - n[a];
        let (ex, ey) = (dp.dot(t1), dp.dot(t2));
        let (nx, ny) = (dn.dot(t1), dn.dot(t2));
        let r1 = DVec3::new(ex, ey, 0.0);
        let r2 = DVec3::new(0.0, ex, ey);
        m += outer(r1, r1) + outer(r2, r2);
        rhs += r1 * nx + r2 * ny;
    }
    let det = m.determinant();
    let scale = m.x_axis.x + m.y_axis.y + m.z_axis.z;
    // Also rejects NaN (from degenerate normals).
    let well_posed = det.abs() > 1e-12 * scale.powi(3);
    if !well_posed {
        return None;
    }
    let s = m.inverse() * rhs;
    let (a, b, c) = (s.x, s.y, s.z);
    let mean = 0.5 * (a + c);
    let dev = (0.25 * (a - c) * (a - c) + b * b).sqrt();
    let (k1, k2) = (mean + dev, mean - dev);
    let (dx, dy) = if b.abs() > 1e-300 {
        (k1 - c, b)
    } else if a >= c {
        (1.0, 0.0)
    } else {
        (0.0, 1.0)
    };
    let dir1 = (dx * t1 + dy * t2).try_normalize().unwrap_or(t1);
    (k1.is_finite() && k2.is_finite()).then_some(TriCurvature { k1, k2, dir1 })
}

fn outer(a: DVec3, b: DVec3) -> DMat3 {
    DMat3::from_cols(a * b.x, a * b.y, a * b.z)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sphere_triangle_has_curvature_one_over_radius() {
        let r = 2.0;
        let dirs = [
            DVec3::new(1.0, 0.05, 0.02).normalize(),
            DVec3::new(1.0, -0.03, 0.06).normalize(),
            DVec3::new(1.0, 0.01, -0.05).normalize(),
        ];
        let p = dirs.map(|d| d * r);
        let c = shape_operator(p, dirs).unwrap();
        assert!(
            (c.k1 - 0.5).abs() < 1e-9 && (c.k2 - 0.5).abs() < 1e-9,
            "{c:?}"
        );
    }

    #[test]
    fn cylinder_triangle_has_one_zero_curvature() {
        // Cylinder of radius 1 around the z axis: κ1 = 1 across, κ2 = 0 along.
        let at = |t: f64, z: f64| {
            (
                DVec3::new(t.cos(), t.sin(), z),
                DVec3::new(t.cos(), t.sin(), 0.0),
            )
        };
        let (p0, n0) = at(0.0, 0.0);
        let (p1, n1) = at(0.1, 0.0);
        let (p2, n2) = at(0.05, 0.1);
        let c = shape_operator([p0, p1, p2], [n0, n1, n2]).unwrap();
        assert!((c.k1 - 1.0).abs() < 5e-3 && c.k2.abs() < 5e-3, "{c:?}");
        assert!(c.dir1.z.abs() < 0.05, "κ1 runs around the cylinder: {c:?}");
    }
}
