//! An idealised floor for the displaced surface's accuracy (Fitmaps §4,
//! Table 1, "RMS D").
//!
//! The displaced surface D is a piecewise-linear surface whose vertices (the
//! displacement samples) lie on M, about as many as M has vertices, at
//! places unrelated to M's own vertices. Even with a perfect limit surface
//! it cannot be closer to M than any other such resampling: between its
//! vertices it cuts across M's facets, by about the sagitta of M's local
//! curvature over one edge. [`resampling_floor`] measures that floor on M
//! itself: every vertex of M slides to a random point of M within the half
//! of its one-ring nearest to it (the ring scaled by ½ about the vertex),
//! M's connectivity is kept (and its boundary vertices, so that
//! the border is covered), and the result is measured against M exactly as
//! D is (both directions, 3-point quadrature, [`super::quadrature_points`]).
//! The half rings of two neighbours meet only at their edge's midpoint, so
//! the slid triangles never flip within a flattened ring; the resampling is
//! at M's density, with M's (well-shaped) triangles — a floor, not a
//! typical case: D's grid cells are less regular than M's triangles.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::error::Result;
use crate::mesh::TriMesh;
use crate::raycast::{make_raycaster, RayBackend};
use crate::DVec3;

use super::{distance_stats, quadrature_points, Accuracy};

/// The floor of a same-density resampling of `mesh` (see the module docs),
/// in ‰ of its bounding-box diagonal. `seed` fixes the random slides, so
/// the figure is reproducible; `reach` (in `[0, 0.5]`) scales the slides
/// (0: M itself, error 0; 0.5: anywhere in the half ring).
pub fn resampling_floor(mesh: &TriMesh, reach: f64, seed: u64) -> Result<Accuracy> {
    let reach = reach.clamp(0.0, 0.5);
    let n = mesh.positions.len();
    let mut incident: Vec<Vec<u32>> = vec![Vec::new(); n];
    for (t, tri) in mesh.triangles.iter().enumerate() {
        for &v in tri {
            incident[v as usize].push(t as u32);
        }
    }
    // Boundary vertices stay: sliding them inwards would uncover a strip
    // of M along its border, an error of the boundary, not of the density.
    let mut edge_uses = std::collections::HashMap::new();
    for tri in &mesh.triangles {
        for k in 0..3 {
            let (a, b) = (tri[k], tri[(k + 1) % 3]);
            *edge_uses.entry((a.min(b), a.max(b))).or_insert(0u32) += 1;
        }
    }
    let mut on_boundary = vec![false; n];
    for (&(a, b), &c) in &edge_uses {
        if c == 1 {
            on_boundary[a as usize] = true;
            on_boundary[b as usize] = true;
        }
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let positions: Vec<DVec3> = (0..n)
        .map(|v| {
            let ring = &incident[v];
            if ring.is_empty() || on_boundary[v] {
                return mesh.positions[v];
            }
            let t = ring[rng.gen_range(0..ring.len())] as usize;
            // A uniform point of the triangle, then pulled towards v: a
            // point of the triangle (convex combination), so on M.
            let (mut a, mut b): (f64, f64) = (rng.gen(), rng.gen());
            if a + b > 1.0 {
                (a, b) = (1.0 - a, 1.0 - b);
            }
            let [x, y, z] = mesh.triangle(t);
            let q = x + a * (y - x) + b * (z - x);
            let s: f64 = reach * rng.gen::<f64>().sqrt();
            let p = mesh.positions[v];
            p + s * (q - p)
        })
        .collect();
    let resampled = TriMesh {
        positions,
        triangles: mesh.triangles.clone(),
    };
    let diag = mesh.bbox_diagonal();
    let mesh_caster = make_raycaster(RayBackend::Embree, mesh)?;
    let resampled_caster = make_raycaster(RayBackend::Embree, &resampled)?;
    let (rp, rw) = quadrature_points(&resampled);
    let (mp, mw) = quadrature_points(mesh);
    Ok(Accuracy::from_directions(
        distance_stats(&rp, &rw, mesh_caster.as_ref(), diag)?,
        distance_stats(&mp, &mw, resampled_caster.as_ref(), diag)?,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `k × k` triangulated grid over `[-1, 1]²` with heights `z(x, y)`.
    fn height_field(k: u32, z: impl Fn(f64, f64) -> f64) -> TriMesh {
        let c = |i: u32| -1.0 + 2.0 * i as f64 / k as f64;
        crate::fixtures::tri_grid(k, |i, j| DVec3::new(c(i), c(j), z(c(i), c(j))), |_, _| true)
    }

    #[test]
    fn floor_is_zero_on_a_plane_and_a_sagitta_on_a_paraboloid() {
        // Every resampling of a plane lies in it.
        let plane = height_field(10, |_, _| 0.0);
        let f = resampling_floor(&plane, 0.5, 1).unwrap();
        assert!(f.rms_permille < 1e-6, "{f:?}");
        // reach 0 is M itself.
        let bowl = height_field(20, |x, y| 0.5 * (x * x + y * y));
        assert!(resampling_floor(&bowl, 0.0, 1).unwrap().rms_permille < 1e-6);
        // z = (x² + y²)/2 has curvature ≤ 1. M and its resampling are
        // both piecewise-linear interpolants of it, each within ℓ²/8 of it
        // (ℓ the longest edge: M's diagonals 0.14, plus two slides of at
        // most half an edge, 0.21 in all): 5.5e-3 each, so they differ by
        // at most 1.1e-2, 3.7‰ of the diagonal (3). Measured: 0.49‰ RMS;
        // clearly positive, below the bound.
        let f = resampling_floor(&bowl, 0.5, 1).unwrap();
        assert!(
            f.rms_permille > 0.05 && f.surface_to_mesh.max_permille < 3.7,
            "{f:?}"
        );
        // Deterministic for a seed.
        assert_eq!(resampling_floor(&bowl, 0.5, 1).unwrap(), f);
    }
}
