//! Limit interpolation (Fitmaps §3.2, system (1) `L V_K = V_M`): place the
//! control vertices so that the Catmull-Clark limit position of every
//! control vertex equals its target.
//!
//! `L` holds one vertex limit mask per row ([`vertex_limit_mask`]),
//! boundaries with OpenSubdiv's "edge and corner" rule: boundary edges are
//! infinitely sharp creases, so a boundary vertex lies on the cubic B-spline
//! of its boundary polygon, and a boundary vertex with a single face is a
//! corner that stays where it is.
//!
//! Solvers: the paper's fixed-point iteration `V_K += V_M − L V_K` (default;
//! on a regular grid `L` is the tensor product of the B-spline mask
//! `(1, 4, 1)/6`, whose eigenvalues lie in `[1/9, 1]`, so the iteration
//! matrix `I − L` has spectral radius ≤ 8/9 and ~180 sweeps reach 1e-9), or
//! a direct sparse solve through Eigen ([`crate::solve::least_squares`]).

use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::mesh::{ControlMesh, VertexId};
use crate::solve::{least_squares, LsqOptions, Triplets};
use crate::DVec3;

/// Catmull-Clark limit mask of the control vertex `v`: weights over control
/// vertices (sorted by id, summing to 1) whose combination is the limit
/// position of `v`.
///
/// - interior vertex of valence `n` (any `n ≥ 2`, valence 2 included: the
///   limit of the subdivision process, *not* OpenSubdiv 3.5's corner mask
///   for that case, see STACK-NOTES), all faces quads:
///   `(n² v + 4 Σ e_i + Σ d_i) / (n (n + 5))`, `e_i` the edge neighbours and
///   `d_i` the vertices diagonally opposite in each quad;
/// - interior vertex with non-quad faces: one Catmull-Clark step makes its
///   faces quads, so the same mask applied to the refined vertex, edge and
///   face points (expressed back on the control vertices) is exact;
/// - boundary vertex with two or more faces: the cubic B-spline curve limit
///   `(e_prev + 4 v + e_next) / 6` over its two boundary neighbours;
/// - boundary vertex with one face (boundary valence 2): a corner, mask `v`.
///
/// Creases and corner sharpness other than the boundary are not supported
/// and give [`Error::Topology`] rather than a wrong mask.
///
/// The masks are the exact limit evaluator's own
/// ([`crate::subdiv::catmark::vertex_limit_mask`], the position row of
/// [`crate::subdiv::catmark::RustEvaluator`]'s vertex masks), so `L` and the
/// surface every later stage evaluates agree.
pub fn vertex_limit_mask(mesh: &ControlMesh, v: VertexId) -> Result<Vec<(VertexId, f64)>> {
    let mut out = Vec::new();
    vertex_limit_mask_into(mesh, v, &mut out)?;
    Ok(out)
}

/// [`vertex_limit_mask`] written into `out` (cleared first; on error left
/// empty): the greedy layout's refits take a few dozen masks per collapse,
/// and one reused buffer saves an allocation and its growth per mask.
pub fn vertex_limit_mask_into(
    mesh: &ControlMesh,
    v: VertexId,
    out: &mut Vec<(VertexId, f64)>,
) -> Result<()> {
    out.clear();
    if v.idx() >= mesh.num_vertices() {
        return Err(Error::InvalidArgument(format!(
            "vertex_limit_mask: {v} out of range ({} vertices)",
            mesh.num_vertices()
        )));
    }
    if mesh.vertex_sharpness(v) != 0.0
        || mesh
            .outgoing(v)
            .any(|h| mesh.edge_sharpness(h.edge()) != 0.0)
    {
        return Err(Error::topology(
            format!("{v}"),
            "has crease or corner sharpness; limit interpolation supports only the \
             boundary (edge-and-corner) rule",
        ));
    }
    crate::subdiv::catmark::vertex_limit_mask_into(
        mesh,
        v,
        &crate::mesh::SchemeOptions::default(),
        out,
    );
    Ok(())
}

/// The limit matrix `L` in compressed rows (row `v` = mask of `v`).
struct LimitMatrix {
    off: Vec<usize>,
    col: Vec<u32>,
    val: Vec<f64>,
}

impl LimitMatrix {
    fn rows(mesh: &ControlMesh, rows: &[VertexId]) -> Result<Self> {
        let masks: Vec<Vec<(VertexId, f64)>> = rows
            .par_iter()
            .map(|&v| vertex_limit_mask(mesh, v))
            .collect::<Result<_>>()?;
        let mut off = Vec::with_capacity(rows.len() + 1);
        off.push(0);
        let nnz = masks.iter().map(Vec::len).sum();
        let mut col = Vec::with_capacity(nnz);
        let mut val = Vec::with_capacity(nnz);
        for m in masks {
            for (u, x) in m {
                col.push(u.0);
                val.push(x);
            }
            off.push(col.len());
        }
        Ok(LimitMatrix { off, col, val })
    }

    #[inline]
    fn apply_row(&self, r: usize, p: &[DVec3]) -> DVec3 {
        (self.off[r]..self.off[r + 1]).fold(DVec3::ZERO, |acc, k| {
            acc + self.val[k] * p[self.col[k] as usize]
        })
    }
}

/// Limit positions of all control vertices (`L V_K`).
pub fn limit_positions(mesh: &ControlMesh) -> Result<Vec<DVec3>> {
    let rows: Vec<VertexId> = mesh.vertices().collect();
    let l = LimitMatrix::rows(mesh, &rows)?;
    let p = mesh.positions();
    Ok((0..rows.len())
        .into_par_iter()
        .map(|r| l.apply_row(r, p))
        .collect())
}

/// Which solver [`interpolate_limit`] uses.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Default)]
pub enum InterpolationSolver {
    /// Fitmaps §3.2: `V_K += V_M − L V_K` until converged. Falls back to
    /// [`InterpolationSolver::Direct`] if it does not converge.
    #[default]
    FixedPoint,
    /// Sparse direct solve of `L V_K = V_M` through Eigen, polished by
    /// fixed-point sweeps.
    Direct,
}

/// Options of [`interpolate_limit`].
#[derive(Clone, Debug)]
#[non_exhaustive]
pub struct InterpolationOptions {
    pub solver: InterpolationSolver,
    /// Largest residual `|L V_K − V_M|` allowed, relative to the bounding-box
    /// diagonal of the targets (issue 4: 1e-9).
    pub tolerance: f64,
    /// Fixed-point sweeps before giving up (and falling back to Direct).
    pub max_iterations: usize,
}

impl Default for InterpolationOptions {
    fn default() -> Self {
        InterpolationOptions {
            solver: InterpolationSolver::FixedPoint,
            tolerance: 1e-9,
            max_iterations: 5000,
        }
    }
}

impl InterpolationOptions {
    pub fn with_solver(mut self, solver: InterpolationSolver) -> Self {
        self.solver = solver;
        self
    }
    pub fn with_tolerance(mut self, tolerance: f64) -> Self {
        self.tolerance = tolerance;
        self
    }
    pub fn with_max_iterations(mut self, max_iterations: usize) -> Self {
        self.max_iterations = max_iterations;
        self
    }
}

/// What [`interpolate_limit`] / [`interpolate_limit_local`] did.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct InterpolationReport {
    /// The solver that produced the result (Direct after a fallback).
    #[serde(skip)]
    pub solver: InterpolationSolver,
    /// Fixed-point sweeps done (polishing sweeps included).
    pub iterations: usize,
    /// Largest `|L V_K − V_M|` over the solved vertices, relative to the
    /// bounding-box diagonal of the targets.
    pub max_residual_relative: f64,
    pub converged: bool,
    /// The fixed-point iteration did not converge and the direct solver
    /// took over.
    pub fell_back_to_direct: bool,
}

fn check_targets(control: &ControlMesh, targets: &[DVec3]) -> Result<f64> {
    if targets.len() != control.num_vertices() {
        return Err(Error::InvalidArgument(format!(
            "limit interpolation: {} targets for {} control vertices",
            targets.len(),
            control.num_vertices()
        )));
    }
    if let Some(i) = targets.iter().position(|p| !p.is_finite()) {
        return Err(Error::invalid_data(
            "limit interpolation targets",
            format!("target {i}"),
            "is not finite",
        ));
    }
    let (lo, hi) = targets.iter().fold(
        (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
        |(lo, hi), &q| (lo.min(q), hi.max(q)),
    );
    Ok((hi - lo).length().max(f64::MIN_POSITIVE))
}

/// Fixed-point sweeps over `rows` (Jacobi style: all rows read the previous
/// positions), stopping when the largest residual is ≤ `tol` (absolute).
/// Returns (sweeps, final residual); the residual is that of the returned
/// positions.
fn sweep(
    l: &LimitMatrix,
    rows: &[VertexId],
    targets: &[DVec3],
    p: &mut [DVec3],
    tol: f64,
    max_sweeps: usize,
    poll: &mut dyn FnMut() -> Result<()>,
) -> Result<(usize, f64)> {
    let residuals = |p: &[DVec3]| -> Vec<DVec3> {
        rows.par_iter()
            .enumerate()
            .map(|(r, &v)| targets[v.idx()] - l.apply_row(r, p))
            .collect()
    };
    // Euclidean length: the tolerance is a distance (a fraction of the diagonal).
    let max_norm = |r: &[DVec3]| r.iter().map(|x| x.length()).fold(0.0, f64::max);
    let mut r = residuals(p);
    let mut res = max_norm(&r);
    let first = res;
    let mut k = 0;
    while k < max_sweeps && res > tol {
        for (i, &v) in rows.iter().enumerate() {
            p[v.idx()] += r[i];
        }
        k += 1;
        poll()?;
        r = residuals(p);
        res = max_norm(&r);
        // Diverging (an irregular configuration where I − L is not a
        // contraction): stop early, the caller decides what to do.
        if !res.is_finite() || res > 1e3 * first.max(tol) {
            break;
        }
    }
    Ok((k, res))
}

/// Places all control vertices so that the limit position of vertex `i` is
/// `targets[i]`, to `opts.tolerance` of the targets' bounding-box diagonal.
/// On success the control positions are replaced; on error they are left
/// untouched.
pub fn interpolate_limit(
    control: &mut ControlMesh,
    targets: &[DVec3],
    opts: &InterpolationOptions,
) -> Result<InterpolationReport> {
    interpolate_limit_polled(control, targets, opts, &mut || Ok(()))
}

/// [`interpolate_limit`], calling `poll` after each sweep (an `Err` from
/// it, a cancellation, ends the call with the positions untouched).
pub(crate) fn interpolate_limit_polled(
    control: &mut ControlMesh,
    targets: &[DVec3],
    opts: &InterpolationOptions,
    poll: &mut dyn FnMut() -> Result<()>,
) -> Result<InterpolationReport> {
    let diag = check_targets(control, targets)?;
    let tol = opts.tolerance * diag;
    let rows: Vec<VertexId> = control.vertices().collect();
    let l = LimitMatrix::rows(control, &rows)?;
    poll()?;
    // The paper starts from V_K = V_M: the limit of a dense mesh is close to
    // its control points, so few sweeps are needed.
    let mut p = targets.to_vec();
    let mut iterations = 0;
    let mut fell_back = false;
    let mut solver = opts.solver;
    let mut res = f64::INFINITY;
    if solver == InterpolationSolver::FixedPoint {
        let (k, r) = sweep(&l, &rows, targets, &mut p, tol, opts.max_iterations, poll)?;
        iterations = k;
        res = r;
        if res.is_nan() || res > tol {
            fell_back = true;
            solver = InterpolationSolver::Direct;
        }
    }
    if solver == InterpolationSolver::Direct {
        let n = rows.len();
        let mut a = Triplets::new(n, n);
        for r in 0..n {
            for k in l.off[r]..l.off[r + 1] {
                a.push(r, l.col[k] as usize, l.val[k]);
            }
        }
        let rhs: Vec<Vec<f64>> = (0..3)
            .map(|c| targets.iter().map(|t| t[c]).collect())
            .collect();
        let x = least_squares(&a, &rhs, None, &LsqOptions::default())?;
        p = (0..n)
            .map(|i| DVec3::new(x[0][i], x[1][i], x[2][i]))
            .collect();
        // The normal equations square the condition number: a few sweeps
        // remove the rounding left over.
        let (k, r) = sweep(&l, &rows, targets, &mut p, tol, 50, poll)?;
        iterations += k;
        res = r;
    }
    let converged = res <= tol;
    if !converged {
        return Err(Error::numerical(
            "limit interpolation",
            format!(
                "did not converge: residual {:.3e} of the diagonal after {iterations} sweeps",
                res / diag
            ),
        ));
    }
    control.set_positions(p)?;
    Ok(InterpolationReport {
        solver,
        iterations,
        max_residual_relative: res / diag,
        converged,
        fell_back_to_direct: fell_back,
    })
}

/// Local version (Fitmaps §3.4): `iterations` fixed-point sweeps that move
/// only `vertices`, all others held fixed. `targets` is indexed by control
/// vertex, like the positions. The report's residual is over `vertices`;
/// `converged` says whether it is within the default 1e-9 of the diagonal.
pub fn interpolate_limit_local(
    control: &mut ControlMesh,
    targets: &[DVec3],
    vertices: &[VertexId],
    iterations: usize,
) -> Result<InterpolationReport> {
    let diag = check_targets(control, targets)?;
    if let Some(v) = vertices.iter().find(|v| v.idx() >= control.num_vertices()) {
        return Err(Error::InvalidArgument(format!(
            "interpolate_limit_local: {v} out of range"
        )));
    }
    let mut rows = vertices.to_vec();
    rows.sort_unstable();
    rows.dedup();
    let l = LimitMatrix::rows(control, &rows)?;
    let mut p = control.positions().to_vec();
    let (k, res) = sweep(&l, &rows, targets, &mut p, 0.0, iterations, &mut || Ok(()))?;
    let tol = InterpolationOptions::default().tolerance;
    control.set_positions(p)?;
    Ok(InterpolationReport {
        solver: InterpolationSolver::FixedPoint,
        iterations: k,
        max_residual_relative: res / diag,
        converged: res / diag <= tol,
        fell_back_to_direct: false,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cube_corner_limit_is_half() {
        // STACK-NOTES: the limit of a corner of the cube [-1, 1]^3 is ±1/2.
        let m = crate::fixtures::cube();
        let lim = limit_positions(&m).unwrap();
        for (p, q) in m.positions().iter().zip(&lim) {
            assert!((*q - *p * 0.5).length() < 1e-15, "{p} -> {q}");
        }
    }

    #[test]
    fn quad_masks_are_the_closed_form() {
        // An interior vertex of valence n with quads only: the dominant
        // left eigenvector (n² v + 4 Σ e_i + Σ d_i) / (n (n + 5)); a
        // boundary vertex with two or more faces: the cubic B-spline's
        // (1, 4, 1) / 6; one face: the corner itself.
        let m = crate::fixtures::flat_grid(4, 3);
        for v in m.vertices() {
            let w = vertex_limit_mask(&m, v).unwrap();
            let of = |u: VertexId| w.iter().find(|x| x.0 == u).map_or(0.0, |x| x.1);
            let s: f64 = w.iter().map(|x| x.1).sum();
            assert!((s - 1.0).abs() < 1e-14, "{v}: {w:?}");
            if !m.is_boundary_vertex(v) {
                let n = m.valence(v) as f64;
                let den = n * (n + 5.0);
                assert!((of(v) - n * n / den).abs() < 1e-15, "{v}: {w:?}");
                for h in m.outgoing(v) {
                    assert!((of(m.head(h)) - 4.0 / den).abs() < 1e-15, "{v}: {w:?}");
                    assert!((of(m.head(m.next(h))) - 1.0 / den).abs() < 1e-15);
                }
            } else if m.valence(v) == 2 {
                assert_eq!(w, vec![(v, 1.0)]);
            } else {
                assert!((of(v) - 4.0 / 6.0).abs() < 1e-15, "{v}: {w:?}");
                assert_eq!(w.len(), 3, "{v}: {w:?}");
            }
        }
    }

    #[test]
    fn tetrahedron_mask_sums_to_one_and_is_symmetric() {
        // Triangles only: the general route; by symmetry the limit of a
        // regular tetrahedron vertex lies on the ray from the centre.
        let p = vec![
            DVec3::new(1.0, 1.0, 1.0),
            DVec3::new(1.0, -1.0, -1.0),
            DVec3::new(-1.0, 1.0, -1.0),
            DVec3::new(-1.0, -1.0, 1.0),
        ];
        let m =
            ControlMesh::from_polygons(p, &[[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]]).unwrap();
        for v in m.vertices() {
            let w = vertex_limit_mask(&m, v).unwrap();
            let s: f64 = w.iter().map(|x| x.1).sum();
            assert!((s - 1.0).abs() < 1e-14);
            let others: Vec<f64> = w.iter().filter(|x| x.0 != v).map(|x| x.1).collect();
            assert!(others.iter().all(|&x| (x - others[0]).abs() < 1e-15));
        }
    }
}
