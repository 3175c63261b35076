//! Limit positions and a [`LimitEvaluator`] for the quad/triangle scheme.
//!
//! Vertex limits are exact (to rounding):
//! - corners stay; a vertex with two sharp edges has the cubic B-spline
//!   curve's limit `(a + 4v + b)/6` (the 1-6-1 rule's limit mask, whatever
//!   the faces);
//! - a smooth vertex with only quads and no sharp edge has Catmull-Clark's
//!   mask `(n² v + 4Σe + Σd)/(n(n+5))`, one with only triangles Loop's
//!   (OpenSubdiv's `assignSmoothLimitMask`): their 1-rings are refined by
//!   the pure Catmull-Clark / Loop rules, because every new edge and face
//!   vertex around them has `γ = 1`;
//! - any other vertex (mixed, dart) by the dominant left eigenvector of the
//!   subdivision matrix of its 1-ring (the vertex, its edge neighbours, the
//!   far corners of its quads), which is invariant under the scheme; found
//!   by power iteration to 1e-15.
//!
//! [`QuadTriEvaluator`] refines to a level `L` and pushes every vertex of
//! level `L` to its limit; a location is then interpolated from the limit
//! points of the level-`L` face containing it (bilinear on quads, linear on
//! triangles), derivatives by the chain rule of that interpolation. Exact at
//! the level-`L` vertices; in between the error is the interpolation's,
//! `O(h²)` with `h ~ 2^-L` of the control edge length (measured in
//! tests/quadtri_differential.rs: at `L = 4` on a unit-size closed mesh,
//! ~1e-3 of the diagonal in position). Normals are those of the piecewise
//! interpolant (`O(h)`).

use crate::error::{Error, Result};
use crate::mesh::ControlMesh;
use crate::subdiv::catmark::topo::{Pt, Sparse};
use crate::subdiv::{LimitEvaluator, LimitPoint, LimitStencils, SurfaceLocation};
use crate::DVec3;

use super::{refine_step, Level, QuadTriRefiner, SparseRows};

/// Default refinement level of [`QuadTriEvaluator`].
pub const DEFAULT_EVAL_LEVEL: u32 = 4;

/// Iterations cap of the power iteration (the subdominant eigenvalue of
/// these schemes is below 0.7, so 0.7^200 is far below rounding).
const MAX_POWER_ITERATIONS: usize = 400;

/// The limit mask of vertex `w` of level `l`, over `l`'s vertices.
pub(crate) fn limit_row(l: &Level, w: u32) -> Result<Sparse> {
    if l.is_corner(w) {
        return Ok(Sparse::unit(w));
    }
    let sharp = l.sharp_neighbours(w);
    if sharp.len() >= 3 {
        return Ok(Sparse::unit(w));
    }
    if sharp.len() == 2 {
        let mut r = Sparse::unit(w);
        r.0[0].1 = 4.0 / 6.0;
        r.axpy(1.0 / 6.0, &Sparse::unit(sharp[0]));
        r.axpy(1.0 / 6.0, &Sparse::unit(sharp[1]));
        return Ok(r);
    }
    let (nq, nt) = l.face_counts(w);
    let (t, adj) = (&l.topo, &l.adj);
    if sharp.is_empty() && nt == 0 {
        // Catmull-Clark: (n² v + 4 Σe + Σd) / (n (n + 5)).
        let n = nq as f64;
        let s = 1.0 / (n * (n + 5.0));
        let mut r = Sparse::zero();
        r.axpy(n * n * s, &Sparse::unit(w));
        for &e in &adj.vedges[w as usize] {
            r.axpy(4.0 * s, &Sparse::unit(t.other(adj, e, w)));
        }
        for &f in &adj.vfaces[w as usize] {
            let c = t.face(f);
            let k = c.iter().position(|&x| x == w).expect("w is in its face");
            r.axpy(s, &Sparse::unit(c[(k + 2) % 4]));
        }
        return Ok(r);
    }
    if sharp.is_empty() && nq == 0 {
        // Loop (Sdc `assignSmoothLimitMask`).
        let n = nt as f64;
        let ew = if nt == 6 {
            1.0 / 12.0
        } else {
            let b = 0.25 * (2.0 * std::f64::consts::PI / n).cos() + 0.375;
            let g = (0.625 - b * b) / n;
            1.0 / (n + 3.0 / (8.0 * g))
        };
        let mut r = Sparse::zero();
        r.axpy(1.0 - n * ew, &Sparse::unit(w));
        for &e in &adj.vedges[w as usize] {
            r.axpy(ew, &Sparse::unit(t.other(adj, e, w)));
        }
        return Ok(r);
    }
    power_limit_row(l, w)
}

/// Limit mask by power iteration on the 1-ring's subdivision matrix.
fn power_limit_row(l: &Level, w: u32) -> Result<Sparse> {
    let (ring, map) = l.topo.ring(&l.adj, &[w], None);
    let lw = map[w as usize];
    let local = Level::new(ring);
    let step = refine_step(&local);
    let (t, adj) = (&local.topo, &local.adj);
    // State slots: w, its edge neighbours, the far corners of its quads;
    // with the child of each slot in the refined ring.
    let mut slot_vertex = vec![lw];
    let mut slot_child = vec![lw];
    for &e in &adj.vedges[lw as usize] {
        slot_vertex.push(t.other(adj, e, lw));
        slot_child.push(t.pts.len() as u32 + e);
    }
    for &f in &adj.vfaces[lw as usize] {
        let c = t.face(f);
        if c.len() == 4 {
            let k = c.iter().position(|&x| x == lw).expect("w is in its face");
            slot_vertex.push(c[(k + 2) % 4]);
            let fc = step
                .parents
                .iter()
                .position(|p| *p == super::Parent::Face(f))
                .ok_or_else(|| {
                    Error::topology(format!("vertex {w}"), "quad without a child vertex")
                })? as u32;
            slot_child.push(fc);
        }
    }
    let ns = slot_vertex.len();
    let mut slot_of = vec![usize::MAX; t.pts.len()];
    for (s, &v) in slot_vertex.iter().enumerate().rev() {
        slot_of[v as usize] = s;
    }
    // Dense ns × ns matrix: state' = S state.
    let mut m = vec![0.0; ns * ns];
    for (i, &c) in slot_child.iter().enumerate() {
        for &(p, wgt) in &step.rows[c as usize].0 {
            let j = slot_of[p as usize];
            if j == usize::MAX {
                if wgt.abs() > 1e-14 {
                    return Err(Error::topology(
                        format!("vertex {w}"),
                        "quad/triangle limit mask: the 1-ring is not invariant under subdivision",
                    ));
                }
                continue;
            }
            m[i * ns + j] += wgt;
        }
    }
    let mut x = vec![0.0; ns];
    x[0] = 1.0;
    let mut y = vec![0.0; ns];
    let mut converged = false;
    for _ in 0..MAX_POWER_ITERATIONS {
        y.iter_mut().for_each(|v| *v = 0.0);
        for i in 0..ns {
            if x[i] != 0.0 {
                for j in 0..ns {
                    y[j] += x[i] * m[i * ns + j];
                }
            }
        }
        let d = x
            .iter()
            .zip(&y)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        std::mem::swap(&mut x, &mut y);
        if d < 1e-16 {
            converged = true;
            break;
        }
    }
    if !converged {
        return Err(Error::topology(
            format!("vertex {w}"),
            "quad/triangle limit mask: power iteration did not converge",
        ));
    }
    // Back to the level's vertex ids.
    let mut inv = vec![u32::MAX; t.pts.len()];
    for (g, &lv) in map.iter().enumerate() {
        if lv != u32::MAX {
            inv[lv as usize] = g as u32;
        }
    }
    let mut r = Sparse::zero();
    for (s, &v) in slot_vertex.iter().enumerate() {
        r.axpy(x[s], &Sparse::unit(inv[v as usize]));
    }
    Ok(r)
}

/// Limit stencils over the control vertices of every control vertex of
/// `mesh` (exact, see the module doc).
pub fn vertex_limit_stencils(mesh: &ControlMesh) -> Result<SparseRows> {
    let r = QuadTriRefiner::new(mesh, 0)?;
    let rows = (0..mesh.num_vertices() as u32)
        .map(|v| limit_row(&r.levels[0], v))
        .collect::<Result<Vec<_>>>()?;
    Ok(SparseRows::from_sparse(&rows))
}

/// Quad/triangle limit evaluation by refinement to a fixed level, see the
/// module doc. Locations follow [`crate::subdiv`]: a quad `(face, 0, u, v)`;
/// a triangle is split into 3 quads `sub = k` at its corners (corner,
/// edge midpoint, centroid, edge midpoint), mapped bilinearly into the
/// triangle's barycentric domain.
pub struct QuadTriEvaluator {
    refiner: QuadTriRefiner,
    face_sizes: Vec<u32>,
    /// Limit stencils (over control vertices) of the finest level's vertices.
    limits: SparseRows,
    level: u32,
}

impl QuadTriEvaluator {
    /// Prepares `mesh` at refinement level `level` (1..=MAX_LEVELS; 4 is a
    /// good default, [`DEFAULT_EVAL_LEVEL`]).
    pub fn new(mesh: &ControlMesh, level: u32) -> Result<Self> {
        if level == 0 {
            return Err(Error::InvalidArgument(
                "quad/triangle evaluator: level must be at least 1".into(),
            ));
        }
        let refiner = QuadTriRefiner::new(mesh, level)?;
        let fine = &refiner.levels[level as usize];
        let rows = (0..fine.num_vertices() as u32)
            .map(|v| limit_row(fine, v))
            .collect::<Result<Vec<_>>>()?;
        let limits =
            SparseRows::from_sparse(&rows).compose(&refiner.stencils(level), mesh.num_vertices());
        Ok(QuadTriEvaluator {
            refiner,
            face_sizes: mesh.face_sizes(),
            limits,
            level,
        })
    }

    pub fn level(&self) -> u32 {
        self.level
    }

    /// The finest-level face containing `loc` and the interpolation weights
    /// (value, d/du, d/dv) of its vertices.
    fn locate(&self, loc: &SurfaceLocation) -> Vec<(u32, [f64; 3])> {
        let mut f = loc.face.0;
        if self.face_sizes[loc.face.idx()] == 4 {
            const C: [(f64, f64); 4] = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)];
            let (mut s, mut t) = (loc.u, loc.v);
            // Jacobian d(s, t)/d(u, v), rows s and t.
            let mut j = [[1.0, 0.0], [0.0, 1.0]];
            for l in 0..self.level {
                let k = match (s < 0.5, t < 0.5) {
                    (true, true) => 0,
                    (false, true) => 1,
                    (false, false) => 2,
                    (true, false) => 3,
                };
                let c = C[k];
                let a = (C[(k + 1) % 4].0 - c.0, C[(k + 1) % 4].1 - c.1);
                let b = (C[(k + 3) % 4].0 - c.0, C[(k + 3) % 4].1 - c.1);
                let d = (s - c.0, t - c.1);
                s = 2.0 * (d.0 * a.0 + d.1 * a.1);
                t = 2.0 * (d.0 * b.0 + d.1 * b.1);
                j = [
                    [
                        2.0 * (a.0 * j[0][0] + a.1 * j[1][0]),
                        2.0 * (a.0 * j[0][1] + a.1 * j[1][1]),
                    ],
                    [
                        2.0 * (b.0 * j[0][0] + b.1 * j[1][0]),
                        2.0 * (b.0 * j[0][1] + b.1 * j[1][1]),
                    ],
                ];
                f = self.refiner.face_base[l as usize][f as usize] + k as u32;
            }
            let (s, t) = (s.clamp(0.0, 1.0), t.clamp(0.0, 1.0));
            let w = [(1.0 - s) * (1.0 - t), s * (1.0 - t), s * t, (1.0 - s) * t];
            let ws = [-(1.0 - t), 1.0 - t, t, -t];
            let wt = [-(1.0 - s), -s, s, 1.0 - s];
            let fv = self.refiner.face(self.level, f);
            (0..4)
                .map(|i| {
                    let du = ws[i] * j[0][0] + wt[i] * j[1][0];
                    let dv = ws[i] * j[0][1] + wt[i] * j[1][1];
                    (fv[i], [w[i], du, dv])
                })
                .collect()
        } else {
            // Sub-quad k of the triangle in barycentric coordinates.
            let k = loc.sub as usize % 3;
            let e = |i: usize| {
                let mut x = [0.0; 3];
                x[i % 3] = 1.0;
                x
            };
            let p0 = e(k);
            let p1 = std::array::from_fn::<f64, 3, _>(|i| 0.5 * (e(k)[i] + e(k + 1)[i]));
            let p2 = [1.0 / 3.0; 3];
            let p3 = std::array::from_fn::<f64, 3, _>(|i| 0.5 * (e(k)[i] + e(k + 2)[i]));
            let (u, v) = (loc.u, loc.v);
            let mut b: [f64; 3] = std::array::from_fn(|i| {
                (1.0 - u) * (1.0 - v) * p0[i]
                    + u * (1.0 - v) * p1[i]
                    + u * v * p2[i]
                    + (1.0 - u) * v * p3[i]
            });
            let mut bu: [f64; 3] = std::array::from_fn(|i| {
                -(1.0 - v) * p0[i] + (1.0 - v) * p1[i] + v * p2[i] - v * p3[i]
            });
            let mut bv: [f64; 3] = std::array::from_fn(|i| {
                -(1.0 - u) * p0[i] - u * p1[i] + u * p2[i] + (1.0 - u) * p3[i]
            });
            for l in 0..self.level {
                let child = (0..3).find(|&i| b[i] >= 0.5);
                let (c, perm, off, sc): (u32, [usize; 3], [f64; 3], f64) = match child {
                    // Corner child (v_k, e(k,k+1), e(k-1,k)): (2b_k - 1, 2b_k+1, 2b_k-1).
                    Some(i) => (
                        i as u32,
                        [i, (i + 1) % 3, (i + 2) % 3],
                        [-1.0, 0.0, 0.0],
                        2.0,
                    ),
                    // Centre (e01, e12, e20): (1 - 2b2, 1 - 2b0, 1 - 2b1).
                    None => (3, [2, 0, 1], [1.0, 1.0, 1.0], -2.0),
                };
                b = std::array::from_fn(|i| off[i] + sc * b[perm[i]]);
                bu = std::array::from_fn(|i| sc * bu[perm[i]]);
                bv = std::array::from_fn(|i| sc * bv[perm[i]]);
                f = self.refiner.face_base[l as usize][f as usize] + c;
            }
            let fv = self.refiner.face(self.level, f);
            (0..3)
                .map(|i| (fv[i], [b[i].clamp(0.0, 1.0), bu[i], bv[i]]))
                .collect()
        }
    }

    fn stencil_rows(&self, loc: &SurfaceLocation) -> Vec<(u32, [f64; 3])> {
        let mut out: Vec<(u32, [f64; 3])> = Vec::new();
        for (v, w) in self.locate(loc) {
            for (c, x) in self.limits.row(v as usize) {
                match out.iter_mut().find(|e| e.0 == c) {
                    Some(e) => {
                        for (acc, wk) in e.1.iter_mut().zip(w) {
                            *acc += wk * x;
                        }
                    }
                    None => out.push((c, [w[0] * x, w[1] * x, w[2] * x])),
                }
            }
        }
        out.sort_by_key(|e| e.0);
        out
    }
}

impl LimitEvaluator for QuadTriEvaluator {
    fn name(&self) -> &'static str {
        "quadtri"
    }
    fn num_control_vertices(&self) -> usize {
        self.refiner.num_vertices(0)
    }
    /// Exact limit positions; `du`/`dv` span the tangent plane of the
    /// level-`L` limit points around the vertex (scale ~ `2^-L`, not
    /// comparable with other backends; the normal is accurate to `O(2^-L)`).
    fn vertex_limits(&self, positions: &[DVec3]) -> Result<Vec<LimitPoint>> {
        crate::subdiv::check_positions(self.num_control_vertices(), positions)?;
        let lim = self.limits.apply(positions);
        let fine = &self.refiner.levels[self.level as usize];
        Ok((0..self.num_control_vertices())
            .map(|v| {
                let p = lim[v];
                let mut n = DVec3::ZERO;
                let mut du = DVec3::ZERO;
                for &f in &fine.adj.vfaces[v] {
                    let c = fine.topo.face(f);
                    let k = c
                        .iter()
                        .position(|&x| x as usize == v)
                        .expect("v in its face");
                    let next = lim[c[(k + 1) % c.len()] as usize] - p;
                    let prev = lim[c[(k + c.len() - 1) % c.len()] as usize] - p;
                    n += next.cross(prev);
                    if du == DVec3::ZERO {
                        du = next;
                    }
                }
                let n = n.normalize_or_zero();
                let du = du - du.dot(n) * n;
                LimitPoint {
                    position: p,
                    du,
                    dv: n.cross(du),
                }
            })
            .collect())
    }
    fn evaluate(
        &self,
        positions: &[DVec3],
        locations: &[SurfaceLocation],
    ) -> Result<Vec<LimitPoint>> {
        crate::subdiv::check_positions(self.num_control_vertices(), positions)?;
        crate::subdiv::check_locations(&self.face_sizes, locations)?;
        let lim = self.limits.apply(positions);
        Ok(locations
            .iter()
            .map(|l| LimitPoint::from_row(self.locate(l), &lim))
            .collect())
    }
    fn stencils(&self, locations: &[SurfaceLocation]) -> Result<LimitStencils> {
        crate::subdiv::check_locations(&self.face_sizes, locations)?;
        Ok(LimitStencils::from_rows(
            locations.iter().map(|l| self.stencil_rows(l)),
        ))
    }
}
