//! Pure-Rust exact Catmull-Clark limit evaluation, with OpenSubdiv 3.5's
//! rules (see [`crate::subdiv`] for the conventions and [`topo`] for the
//! subdivision rules).
//!
//! - Faces whose neighbourhood is a regular grid (with OpenSubdiv's boundary
//!   and corner variants) are bicubic uniform B-spline patches; their 16
//!   control indices are cached at preparation.
//! - Every other face is evaluated exactly by local subdivision: its 1-ring
//!   is subdivided, the child quad containing the location is kept with its
//!   own 1-ring, and so on until the child is a regular patch (each level
//!   halves the distance to the irregular corner, so a location at
//!   parameter distance d from it needs about `log2(1/d)` levels). No
//!   Gregory or ACC approximation is involved. A location exactly at an
//!   irregular corner (or within 2^-[`MAX_DEPTH`] of it) gets that vertex's
//!   limit masks.
//! - Vertex limits use the exact limit masks after local subdivision has
//!   made every incident face a quad and settled semi-sharp features.
//!
//! Parametrisation of a non-quad face with n corners: Catmull-Clark's first
//! step splits it into n quads; `sub = k` is the quad
//! `(v_k, m(k, k+1), centre, m(k-1, k))` (`m` = edge midpoints) with
//! `(0,0)` at corner `v_k`, u running towards the midpoint of edge
//! `(k, k+1)`, v towards the midpoint of edge `(k-1, k)`, and `(1,1)` at the
//! face centre. This is OpenSubdiv's convention for the sub-faces of a
//! non-quad face (ptex faces in corner order), checked against
//! `Bfr::Parameterization::GetEdgeCoord` (OpenSubdiv 3.5, `QUAD_SUBFACES`):
//! along edge (k, k+1), the first half runs in sub-face k with u increasing
//! from corner k, the second half in sub-face k+1 with v decreasing to its
//! corner. The differential tests against OpenSubdiv remain the arbiter.

pub mod closed_form;
pub(crate) mod patch;
pub(crate) mod topo;

use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::mesh::{ControlMesh, FaceId, VertexId};
use crate::subdiv::{
    check_not_holes, checked_holes, EvalOptions, LimitEvaluator, LimitPoint, LimitStencils,
    SurfaceLocation,
};
use crate::DVec3;

use patch::{corner_is_regular, patch_weights, phantom_rules, regular_grid};
use topo::{
    comb, face_ring, key, merge3, topo_from_mesh, vertex_rule, Adj, Pt, Rule, Rules, Sparse, Topo,
    INF,
};

/// The deepest local subdivision used to approach an irregular corner; the
/// limit surface moves by less than `0.66^MAX_DEPTH` (≈ 4e-15) of the
/// 1-ring size below that.
pub const MAX_DEPTH: usize = 80;

#[derive(Copy, Clone, Debug)]
enum FaceKind {
    /// Index into `RustEvaluator::patches`.
    Regular(u32),
    Irregular,
}

#[derive(Clone, Debug)]
struct RegularPatch {
    /// Global control vertex per grid slot, `u32::MAX` for phantoms.
    cv: [u32; 16],
    mask: u8,
}

/// Exact limit evaluator; see the module doc.
pub struct RustEvaluator {
    mesh: ControlMesh,
    /// The Sdc options of the refinement rules.
    sdc: Rules,
    /// Faces without limit surface (`SchemeOptions::effective_holes`).
    holes: Vec<bool>,
    kinds: Vec<FaceKind>,
    patches: Vec<RegularPatch>,
    /// Phantom rules per sharp-edge mask.
    rules: Vec<Vec<(u8, u8, u8)>>,
    /// Vertex limit masks (position, tangent 1, tangent 2) as CSR rows.
    vm_off: Vec<u32>,
    vm_idx: Vec<u32>,
    vm_w: Vec<[f64; 3]>,
}

impl RustEvaluator {
    pub fn new(mesh: &ControlMesh, options: &EvalOptions) -> Result<Self> {
        mesh.validate()?;
        let holes = checked_holes(mesh, &options.scheme)?;
        let sdc = Rules {
            f32_sharpness: !options.exact_sharpness,
            ..Rules::from_scheme(&options.scheme)
        };
        let rules: Vec<_> = (0..16u8).map(phantom_rules).collect();
        let grids: Vec<Option<RegularPatch>> = mesh
            .faces()
            .collect::<Vec<_>>()
            .par_iter()
            .map(|&f| {
                if mesh.face_size(f) != 4 {
                    return None;
                }
                let t = topo_from_mesh(mesh, Some(&face_ring(mesh, f)), sdc);
                let adj = t.adjacency();
                regular_grid(&t, &adj, 0).map(|(g, mask)| RegularPatch {
                    cv: g.map(|l| if l == u32::MAX { l } else { t.pts[l as usize] }),
                    mask,
                })
            })
            .collect();
        let mut kinds = Vec::with_capacity(grids.len());
        let mut patches = Vec::new();
        for g in grids {
            match g {
                Some(p) => {
                    kinds.push(FaceKind::Regular(patches.len() as u32));
                    patches.push(p);
                }
                None => kinds.push(FaceKind::Irregular),
            }
        }
        let masks: Vec<Vec<(u32, [f64; 3])>> = mesh
            .vertices()
            .collect::<Vec<_>>()
            .par_iter()
            .map(|&v| {
                let (mut p, a, b) = vertex_masks(mesh, v, sdc);
                if let Some((bv, delta)) = options.broken_mask.filter(|m| m.0 == v.0) {
                    p.axpy(delta, &Sparse::unit(bv));
                }
                merge3([&p, &a, &b])
            })
            .collect();
        let mut vm_off = vec![0u32];
        let mut vm_idx = Vec::new();
        let mut vm_w = Vec::new();
        for m in masks {
            for (i, w) in m {
                vm_idx.push(i);
                vm_w.push(w);
            }
            vm_off.push(vm_idx.len() as u32);
        }
        Ok(RustEvaluator {
            mesh: mesh.clone(),
            sdc,
            holes,
            kinds,
            patches,
            rules,
            vm_off,
            vm_idx,
            vm_w,
        })
    }

    /// Number of faces evaluated as regular B-spline patches.
    pub fn num_regular_faces(&self) -> usize {
        self.patches.len()
    }

    /// Whether face `f` is a regular (B-spline) patch.
    pub fn is_regular_face(&self, f: FaceId) -> bool {
        matches!(self.kinds.get(f.idx()), Some(FaceKind::Regular(_)))
    }

    fn check_positions(&self, positions: &[DVec3]) -> Result<()> {
        if positions.len() != self.mesh.num_vertices() {
            return Err(Error::InvalidArgument(format!(
                "rust evaluator: {} positions given, the control mesh has {} vertices",
                positions.len(),
                self.mesh.num_vertices()
            )));
        }
        Ok(())
    }

    fn check_locations(&self, locs: &[SurfaceLocation]) -> Result<()> {
        for (i, l) in locs.iter().enumerate() {
            if l.face.idx() >= self.mesh.num_faces() {
                return Err(Error::InvalidArgument(format!(
                    "location {i}: {} out of range (the mesh has {} faces)",
                    l.face,
                    self.mesh.num_faces()
                )));
            }
            let n = self.mesh.face_size(l.face);
            let nsub = if n == 4 { 1 } else { n };
            if l.sub as usize >= nsub {
                return Err(Error::InvalidArgument(format!(
                    "location {i}: sub-face {} of {} which has {nsub} sub-face(s)",
                    l.sub, l.face
                )));
            }
            if !(0.0..=1.0).contains(&l.u) || !(0.0..=1.0).contains(&l.v) {
                return Err(Error::InvalidArgument(format!(
                    "location {i}: (u, v) = ({}, {}) outside [0, 1]²",
                    l.u, l.v
                )));
            }
        }
        // Holes have no limit surface (as in OpenSubdiv, which builds no
        // patches there); their neighbours are evaluated as usual.
        check_not_holes(&self.holes, locs)
    }

    fn eval_one(&self, positions: &[DVec3], l: &SurfaceLocation) -> LimitPoint {
        match self.kinds[l.face.idx()] {
            FaceKind::Regular(pi) => {
                let p = &self.patches[pi as usize];
                let w = patch_weights(l.u, l.v, &self.rules[p.mask as usize]);
                let mut r = LimitPoint::default();
                for (s, &c) in p.cv.iter().enumerate() {
                    if c != u32::MAX {
                        let x = positions[c as usize];
                        r.position += w[0][s] * x;
                        r.du += w[1][s] * x;
                        r.dv += w[2][s] * x;
                    }
                }
                r
            }
            FaceKind::Irregular => {
                let t = topo_from_mesh(&self.mesh, Some(&face_ring(&self.mesh, l.face)), self.sdc);
                let t = t.with_points(|g| positions[g as usize]);
                let (p, du, dv) = eval_local(t, l.sub as usize, l.u, l.v, &self.rules);
                LimitPoint {
                    position: p,
                    du,
                    dv,
                }
            }
        }
    }

    fn stencil_one(&self, l: &SurfaceLocation) -> Vec<(u32, [f64; 3])> {
        match self.kinds[l.face.idx()] {
            FaceKind::Regular(pi) => {
                let p = &self.patches[pi as usize];
                let w = patch_weights(l.u, l.v, &self.rules[p.mask as usize]);
                let mut row: Vec<(u32, [f64; 3])> = (0..16)
                    .filter(|&s| p.cv[s] != u32::MAX)
                    .map(|s| (p.cv[s], [w[0][s], w[1][s], w[2][s]]))
                    .collect();
                row.sort_by_key(|e| e.0);
                row.dedup_by(|b, a| {
                    if a.0 == b.0 {
                        for k in 0..3 {
                            a.1[k] += b.1[k];
                        }
                        true
                    } else {
                        false
                    }
                });
                row
            }
            FaceKind::Irregular => {
                let t = topo_from_mesh(&self.mesh, Some(&face_ring(&self.mesh, l.face)), self.sdc);
                let t = t.with_points(Sparse::unit);
                let (p, du, dv) = eval_local(t, l.sub as usize, l.u, l.v, &self.rules);
                merge3([&p, &du, &dv])
            }
        }
    }
}

/// Which child quad of a quad contains `(s, t)`, and the map to its own
/// parameters: `(s', t') = D (s, t) + o` (child `k` has `(0,0)` at corner k,
/// see [`topo::Topo::refine`]).
fn child_of(s: f64, t: f64) -> (usize, [[f64; 2]; 2], [f64; 2]) {
    match (s >= 0.5, t >= 0.5) {
        (false, false) => (0, [[2.0, 0.0], [0.0, 2.0]], [0.0, 0.0]),
        (true, false) => (1, [[0.0, 2.0], [-2.0, 0.0]], [0.0, 2.0]),
        (true, true) => (2, [[-2.0, 0.0], [0.0, -2.0]], [2.0, 2.0]),
        (false, true) => (3, [[0.0, -2.0], [2.0, 0.0]], [2.0, 0.0]),
    }
}

/// Translates all points of `t` by minus its first point, adding that
/// point to `offset`.
fn recenter<P: Pt>(t: &mut Topo<P>, offset: &mut P) {
    let o = t.pts[t.face(0)[0] as usize].clone();
    for p in t.pts.iter_mut() {
        p.axpy(-1.0, &o);
    }
    offset.axpy(1.0, &o);
}

/// Exact limit at `(u, v)` of sub-face `sub` of face 0 of `t` (the 1-ring
/// of that face), by local subdivision until the location lies in a
/// regular patch. Returns position and derivatives w.r.t. `(u, v)`.
pub(crate) fn eval_local<P: Pt>(
    mut t: Topo<P>,
    sub: usize,
    u: f64,
    v: f64,
    rules: &[Vec<(u8, u8, u8)>],
) -> (P, P, P) {
    let mut adj = t.adjacency();
    if t.face(0).len() != 4 {
        let r = t.refine(&adj);
        let child = sub as u32;
        let cv = r.face(child).to_vec();
        let radj = r.adjacency();
        t = r.ring(&radj, &cv, Some(child)).0;
        adj = t.adjacency();
    }
    // Points are kept relative to `offset` (a point of the current face):
    // near an extraordinary vertex the neighbourhood shrinks like λ^level
    // while its coordinates do not, and differences of nearby absolute
    // coordinates would lose the derivatives to cancellation (a relative
    // error ~1e-16/λ^level, 1e-4 at 1e-9 from a valence-3 vertex). The rules
    // are affine, so subdividing the translated points is exact; for
    // stencils the same holds with weight vectors (the centred weights are
    // the small differences themselves).
    let mut offset = P::zero();
    recenter(&mut t, &mut offset);
    let (mut s, mut tt) = (u, v);
    // J = ∂(s, t)/∂(u, v).
    let mut jac = [[1.0, 0.0], [0.0, 1.0]];
    let chain = |ds: &P, dt: &P, jac: &[[f64; 2]; 2]| -> (P, P) {
        (
            comb(&[(jac[0][0], ds), (jac[1][0], dt)]),
            comb(&[(jac[0][1], ds), (jac[1][1], dt)]),
        )
    };
    for depth in 0..=MAX_DEPTH {
        if let Some((g, mask)) = regular_grid(&t, &adj, 0) {
            let w = patch_weights(s, tt, &rules[mask as usize]);
            let mut out = [P::zero(), P::zero(), P::zero()];
            for slot in 0..16 {
                let c = g[slot];
                if c != u32::MAX {
                    for k in 0..3 {
                        out[k].axpy(w[k][slot], &t.pts[c as usize]);
                    }
                }
            }
            let [mut p, ds, dt] = out;
            p.axpy(1.0, &offset);
            let (du, dv) = chain(&ds, &dt, &jac);
            return (p, du, dv);
        }
        let corner = match (s, tt) {
            (0.0, 0.0) => Some(0),
            (1.0, 0.0) => Some(1),
            (1.0, 1.0) => Some(2),
            (0.0, 1.0) => Some(3),
            _ => None,
        };
        let stop = match corner {
            Some(k) => (!corner_is_regular(&t, &adj, 0, k)).then_some(k),
            None if depth == MAX_DEPTH => {
                Some(child_of(s, tt).0) // nearest corner
            }
            None => None,
        };
        if let Some(k) = stop {
            let fv = t.face(0);
            let (c, n) = (fv[k], fv[(k + 1) % 4]);
            let (mut p, a, b) = vertex_limit(&t, &adj, c, Some(n));
            p.axpy(1.0, &offset);
            // a points along the edge to corner k+1, b a quarter turn
            // (2π/valence) on; express them along s and t.
            let neg = |x: &P| comb(&[(-1.0, x)]);
            let (ds, dt) = match k {
                0 => (a, b),
                1 => (neg(&b), a),
                2 => (neg(&a), neg(&b)),
                _ => (b, neg(&a)),
            };
            let (du, dv) = chain(&ds, &dt, &jac);
            return (p, du, dv);
        }
        let (k, d, o) = child_of(s, tt);
        let r = t.refine(&adj);
        let child = k as u32;
        let (ns, nt) = (
            d[0][0] * s + d[0][1] * tt + o[0],
            d[1][0] * s + d[1][1] * tt + o[1],
        );
        s = ns.clamp(0.0, 1.0);
        tt = nt.clamp(0.0, 1.0);
        jac = [
            [
                d[0][0] * jac[0][0] + d[0][1] * jac[1][0],
                d[0][0] * jac[0][1] + d[0][1] * jac[1][1],
            ],
            [
                d[1][0] * jac[0][0] + d[1][1] * jac[1][0],
                d[1][0] * jac[0][1] + d[1][1] * jac[1][1],
            ],
        ];
        let cv = r.face(child).to_vec();
        let radj = r.adjacency();
        t = r.ring(&radj, &cv, Some(child)).0;
        recenter(&mut t, &mut offset);
        adj = t.adjacency();
    }
    unreachable!("the loop returns at MAX_DEPTH")
}

/// The CCW fan of vertex `c` (complete in `t`, all incident faces quads):
/// edge neighbours `e` and face-opposite vertices `f` (`f[i]` between
/// `e[i]` and `e[i+1]`), starting at the leading boundary edge, else at
/// `start`, else anywhere. `closed` is false on the boundary, where `e` has
/// one more entry than `f`.
fn fan<P>(t: &Topo<P>, adj: &Adj, c: u32, start: Option<u32>) -> (Vec<u32>, Vec<u32>, bool) {
    let ci = c as usize;
    let bstart = adj.vedges[ci].iter().find_map(|&e| {
        let x = t.other(adj, e, c);
        (adj.edge_nfaces[e as usize] == 1 && adj.directed.contains_key(&(c, x))).then_some(x)
    });
    let first = bstart
        .or(start)
        .unwrap_or_else(|| t.other(adj, adj.vedges[ci][0], c));
    let (mut e, mut f) = (Vec::new(), Vec::new());
    let mut cur = first;
    for _ in 0..=adj.vedges[ci].len() {
        e.push(cur);
        let Some(&g) = adj.directed.get(&(c, cur)) else {
            return (e, f, false);
        };
        let gv = t.face(g);
        let p = gv.iter().position(|&x| x == c).unwrap_or(0);
        f.push(gv[(p + 2) % 4]);
        let next = gv[(p + 3) % 4];
        if next == first {
            return (e, f, true);
        }
        cur = next;
    }
    (e, f, true)
}

/// Left eigenvector of the across-crease tangent for a crease side with `k`
/// faces: local points `v, e_0..e_k, f_0..f_{k-1}`. Power iteration of the
/// transposed one-level subdivision matrix of that side, restricted to masks
/// symmetric under the side's reflection (the along-crease tangent is
/// antisymmetric) and summing to zero (which removes the eigenvalue 1).
fn crease_cross_mask(k: usize) -> Vec<f64> {
    let m = 2 * k + 2;
    let ve = |i: usize| 1 + i;
    let vf = |i: usize| 2 + k + i;
    // Rows of S.
    let mut s = vec![vec![0.0; m]; m];
    s[0][0] = 0.75;
    s[0][ve(0)] += 0.125;
    s[0][ve(k)] += 0.125;
    s[ve(0)][0] = 0.5;
    s[ve(0)][ve(0)] = 0.5;
    s[ve(k)][0] = 0.5;
    s[ve(k)][ve(k)] = 0.5;
    let face = |j: usize| -> Vec<(usize, f64)> {
        vec![(0, 0.25), (ve(j), 0.25), (vf(j), 0.25), (ve(j + 1), 0.25)]
    };
    for i in 1..k {
        s[ve(i)][0] += 0.25;
        s[ve(i)][ve(i)] += 0.25;
        for j in [i - 1, i] {
            for (c, w) in face(j) {
                s[ve(i)][c] += 0.25 * w;
            }
        }
    }
    for j in 0..k {
        for (c, w) in face(j) {
            s[vf(j)][c] += w;
        }
    }
    let mut w = vec![0.0; m];
    w[0] = -1.0;
    let nint = (2 * k - 1) as f64;
    for i in 1..k {
        w[ve(i)] = 1.0 / nint;
    }
    for j in 0..k {
        w[vf(j)] = 1.0 / nint;
    }
    // The position mask (e_0 + 4v + e_k)/6, to project out eigenvalue 1.
    let mut l0 = vec![0.0; m];
    l0[0] = 4.0 / 6.0;
    l0[ve(0)] += 1.0 / 6.0;
    l0[ve(k)] += 1.0 / 6.0;
    for _ in 0..4000 {
        let x = left_apply(&s, &w);
        // Symmetrise (e_i <-> e_k-i, f_j <-> f_k-1-j) and remove the
        // eigenvalue-1 component, both of which round-off would seed.
        let mut nw = x.clone();
        for i in 0..=k {
            nw[ve(i)] = 0.5 * (x[ve(i)] + x[ve(k - i)]);
        }
        for j in 0..k {
            nw[vf(j)] = 0.5 * (x[vf(j)] + x[vf(k - 1 - j)]);
        }
        let sum: f64 = nw.iter().sum();
        nw.iter_mut().zip(&l0).for_each(|(v, l)| *v -= sum * l);
        let norm = nw.iter().fold(0.0f64, |a, x| a.max(x.abs()));
        for x in nw.iter_mut() {
            *x /= norm;
        }
        let diff = nw
            .iter()
            .zip(&w)
            .fold(0.0f64, |a, (x, y)| a.max((x - y).abs()));
        w = nw;
        if diff < 1e-16 {
            break;
        }
    }
    w
}

/// The one-level subdivision matrix of the closed all-quad fan of `c`
/// (points `c, e_0..e_n-1, f_0..f_n-1`), rows = new points in the same order.
fn fan_matrix<P: Clone>(t: &Topo<P>, adj: &Adj, c: u32, e: &[u32], f: &[u32]) -> Vec<Vec<f64>> {
    let n = e.len();
    let m = 2 * n + 1;
    let mut idx = vec![u32::MAX; t.pts.len()];
    idx[c as usize] = 0;
    for i in 0..n {
        idx[e[i] as usize] = 1 + i as u32;
        idx[f[i] as usize] = (1 + n + i) as u32;
    }
    let local = Topo {
        pts: idx.iter().map(|&i| Sparse::unit(i)).collect::<Vec<_>>(),
        vsharp: t.vsharp.clone(),
        foff: t.foff.clone(),
        fv: t.fv.clone(),
        esharp: t.esharp.clone(),
        rules: t.rules,
        fe: Vec::new(),
    };
    let r = local.refine(adj);
    let radj = r.adjacency();
    let e0 = local.edge_child(adj.edge_id[&key(c, e[0])]);
    let (ne, nf, _) = fan(&r, &radj, c, Some(e0));
    let mut s = vec![vec![0.0; m]; m];
    let rows = std::iter::once(c).chain(ne).chain(nf);
    for (row, p) in rows.enumerate().take(m) {
        for &(j, w) in &r.pts[p as usize].0 {
            if (j as usize) < m {
                s[row][j as usize] += w;
            }
        }
    }
    s
}

/// `w <- S^T w`.
fn left_apply(s: &[Vec<f64>], w: &[f64]) -> Vec<f64> {
    let mut out = vec![0.0; w.len()];
    for (row, &wr) in s.iter().zip(w) {
        if wr != 0.0 {
            for (o, x) in out.iter_mut().zip(row) {
                *o += wr * x;
            }
        }
    }
    out
}

/// Exact limit masks of a dart (a smooth vertex with one infinitely sharp
/// edge, `e[0]`) over `c, e_i, f_i`: the dominant left eigenvector of the
/// fan's subdivision matrix (power iteration from the vertex itself, i.e.
/// the stencil of its descendant after many levels), and the two tangent
/// masks. The matrix commutes with the reflection through the dart edge, so
/// the tangent along the dart is the dominant zero-sum symmetric left
/// eigenvector and the one across it the dominant antisymmetric one; each is
/// found by power iteration inside its symmetry class (started from the
/// smooth masks, projected back every step so round-off cannot leak into a
/// mode of the other class).
fn dart_masks<P: Clone>(
    t: &Topo<P>,
    adj: &Adj,
    c: u32,
    e: &[u32],
    f: &[u32],
) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let n = e.len();
    let s = fan_matrix(t, adj, c, e, f);
    let m = s.len();
    let maxdiff = |x: &[f64], y: &[f64]| {
        x.iter()
            .zip(y)
            .fold(0.0f64, |a, (p, q)| a.max((p - q).abs()))
    };
    let mut p = vec![0.0; m];
    p[0] = 1.0;
    for _ in 0..2000 {
        let np = left_apply(&s, &p);
        let d = maxdiff(&np, &p);
        p = np;
        if d < 1e-17 {
            break;
        }
    }
    // Reflection: e_i <-> e_-i, f_i <-> f_-i-1.
    let refl = |w: &[f64]| -> Vec<f64> {
        let mut r = vec![0.0; m];
        r[0] = w[0];
        for i in 0..n {
            r[1 + (n - i) % n] = w[1 + i];
            r[1 + n + (2 * n - i - 1) % n] = w[1 + n + i];
        }
        r
    };
    let th = 2.0 * std::f64::consts::PI / n as f64;
    let mut a = vec![0.0; m];
    let mut b = vec![0.0; m];
    for i in 0..n {
        let (a0, a1) = (th * i as f64, th * (i + 1) as f64);
        a[1 + i] = 4.0 * a0.cos();
        a[1 + n + i] = a0.cos() + a1.cos();
        b[1 + i] = 4.0 * a0.sin();
        b[1 + n + i] = a0.sin() + a1.sin();
    }
    for (w, sign) in [(&mut a, 1.0), (&mut b, -1.0)] {
        for _ in 0..4000 {
            let x = left_apply(&s, w);
            let rx = refl(&x);
            let mut x: Vec<f64> = x
                .iter()
                .zip(&rx)
                .map(|(p, q)| 0.5 * (p + sign * q))
                .collect();
            // Remove the eigenvalue-1 component that round-off seeds (it
            // would grow by 1/λ per step): the masks must sum to zero.
            let sum: f64 = x.iter().sum();
            x.iter_mut().zip(&p).for_each(|(v, l)| *v -= sum * l);
            let norm = x.iter().fold(0.0f64, |acc, v| acc.max(v.abs()));
            x.iter_mut().for_each(|v| *v *= 1.0 / norm);
            let d = maxdiff(&x, w);
            *w = x;
            if d < 1e-16 {
                break;
            }
        }
    }
    // Scale like the smooth masks (the tangents' scale is conventional).
    for w in [&mut a, &mut b] {
        w.iter_mut().for_each(|v| *v /= 3.0);
    }
    (p, a, b)
}

/// The exact limit masks (position, tangent 1, tangent 2) of the control
/// vertex `v` of `mesh` under `sdc`, over control vertex ids (sorted):
/// [`vertex_limit`] on `v`'s 1-ring.
fn vertex_masks(mesh: &ControlMesh, v: VertexId, sdc: Rules) -> (Sparse, Sparse, Sparse) {
    let faces: Vec<FaceId> = mesh.vertex_faces(v).collect();
    let t = topo_from_mesh(mesh, Some(&faces), sdc);
    let local = t
        .pts
        .iter()
        .position(|&g| g == v.0)
        .expect("v is in its ring") as u32;
    let t = t.with_points(Sparse::unit);
    let adj = t.adjacency();
    vertex_limit(&t, &adj, local, None)
}

/// The Catmull-Clark limit position mask of the control vertex `v` under
/// `scheme`: weights over control vertices (sorted by id, summing to 1)
/// whose combination is the limit position of `v`. It is the position row
/// of [`RustEvaluator`]'s vertex masks, for callers that need rows of the
/// limit matrix `L` without building a whole evaluator (the limit
/// interpolation of Fitmaps §3.2, `quad::interpolate`).
///
/// A vertex without sharpness whose faces are all quads, the case of every
/// vertex of the layouts' pure-quad meshes, reads its weights
/// ([`smooth_position_weights`], [`CREASE_POSITION_WEIGHTS`], a corner's
/// own point) off its 1-ring directly: the same weights summed in the same
/// (sorted) order as [`vertex_limit`]'s, without building the ring's
/// topology, which made the greedy layout's loop three times slower.
pub fn vertex_limit_mask(
    mesh: &ControlMesh,
    v: VertexId,
    scheme: &crate::mesh::SchemeOptions,
) -> Vec<(VertexId, f64)> {
    let mut out = Vec::new();
    vertex_limit_mask_into(mesh, v, scheme, &mut out);
    out
}

/// [`vertex_limit_mask`] written into `out` (cleared first), the same
/// weights bit for bit: for callers that take many masks in a row (the
/// greedy layout's refits take a few dozen per collapse) and reuse one
/// buffer instead of allocating one per mask.
pub fn vertex_limit_mask_into(
    mesh: &ControlMesh,
    v: VertexId,
    scheme: &crate::mesh::SchemeOptions,
    out: &mut Vec<(VertexId, f64)>,
) {
    out.clear();
    let rules = Rules::from_scheme(scheme);
    let plain = rules.sharpen_corners
        && mesh.vertex_sharpness(v) == 0.0
        && mesh
            .outgoing(v)
            .all(|h| mesh.edge_sharpness(h.edge()) == 0.0);
    if plain && plain_quad_mask_into(mesh, v, out) {
        return;
    }
    let (p, _, _) = vertex_masks(mesh, v, rules);
    out.extend(p.0.into_iter().map(|(i, w)| (VertexId(i), w)));
}

/// [`vertex_limit_mask`] of a vertex with no sharpness on it or its edges
/// (the caller has checked) under boundary "edge and corner", written into
/// the empty `out`, if the faces around it are all quads; `false` (and
/// `out` empty) otherwise (the general route handles it).
fn plain_quad_mask_into(mesh: &ControlMesh, v: VertexId, out: &mut Vec<(VertexId, f64)>) -> bool {
    let h0 = mesh.vertex_halfedge(v);
    if mesh.is_boundary_halfedge(h0) {
        if !mesh.vertex_faces(v).all(|f| mesh.face_size(f) == 4) {
            return false;
        }
        if mesh.valence(v) == 2 {
            // One face: a corner, which interpolates.
            out.push((v, 1.0));
            return true;
        }
        // The boundary is a crease whose neighbours are the heads of the
        // boundary half-edges into and out of `v`.
        let [w0, wv, wk] = CREASE_POSITION_WEIGHTS;
        out.extend([(mesh.head(h0), w0), (v, wv), (mesh.tail(mesh.prev(h0)), wk)]);
    } else {
        // One walk around the fan: the valence, the quad test and the
        // neighbours (edge heads and the quads' opposite corners), whose
        // weights follow from the valence once it is known.
        out.push((v, 0.0));
        for h in mesh.outgoing(v) {
            // h: v → e inside the quad (v, e, f, ·).
            if mesh.face_of(h).map_or(true, |f| mesh.face_size(f) != 4) {
                out.clear();
                return false;
            }
            out.push((mesh.head(h), 0.0));
            out.push((mesh.head(mesh.next(h)), 0.0));
        }
        let [wv, we, wf] = smooth_position_weights((out.len() - 1) / 2);
        out[0].1 = wv;
        for (i, x) in out[1..].iter_mut().enumerate() {
            x.1 = if i % 2 == 0 { we } else { wf };
        }
    }
    // Sorted by id (stable: repeated vertices summed in the order they
    // came), as Sparse sums them.
    out.sort_by_key(|&(u, _)| u);
    let mut n = 0;
    for i in 0..out.len() {
        if n > 0 && out[n - 1].0 == out[i].0 {
            out[n - 1].1 += out[i].1;
        } else {
            out[n] = out[i];
            n += 1;
        }
    }
    out.truncate(n);
    true
}

/// Exact limit position and two tangents at vertex `c` of `t` (its fan must
/// be complete in `t`). The first tangent points along the edge to `start`
/// when `c` is smooth and `start` given; `t1 × t2` is the outward normal
/// for outward-oriented faces.
///
/// The ring is first settled ([`settled_ring`]); then each rule of
/// [`vertex_rule`] has its exact masks: [`dart_limit`], [`smooth_limit`],
/// [`crease_limit`], and the corner's below.
pub(crate) fn vertex_limit<P: Pt>(
    t0: &Topo<P>,
    adj0: &Adj,
    c0: u32,
    start: Option<u32>,
) -> (P, P, P) {
    let (t, adj, c, start) = settled_ring(t0, adj0, c0, start);
    let (mut e, mut f, closed) = fan(&t, &adj, c, start);
    let sharp: Vec<f64> = e
        .iter()
        .map(|&x| t.edge_sharp(&adj, adj.edge_id[&key(c, x)]))
        .collect();
    let rule = vertex_rule(t.vert_sharp(&adj, c), &sharp);
    let nsharp = sharp.iter().filter(|&&s| s > 0.0).count();
    match rule {
        Rule::Smooth if nsharp == 1 && closed => {
            // Dart: the sharp edge's midpoint rule changes the subdivision
            // matrix, so the smooth masks are not its eigenvectors (they are
            // off by ~5e-3 of the size on `fixtures::creased_cube`). Sdc uses
            // the smooth masks anyway; we stay exact, see
            // `subdiv::known_differences`.
            let i0 = sharp.iter().position(|&s| s > 0.0).unwrap_or(0);
            e.rotate_left(i0);
            f.rotate_left(i0);
            dart_limit(&t, &adj, c, &e, &f)
        }
        Rule::Smooth => smooth_limit(&t, c, &e, &f),
        Rule::Crease => {
            // Rotate a closed fan to start at a sharp edge; an open one
            // starts at its leading boundary edge already.
            if closed {
                let i0 = sharp.iter().position(|&s| s > 0.0).unwrap_or(0);
                e.rotate_left(i0);
                f.rotate_left(i0);
            }
            crease_limit(&t, &adj, c, &e, &f)
        }
        Rule::Corner => {
            // The corner interpolates; the tangents are the edges of the
            // first sector (of the whole boundary sector when open), like
            // Sdc's corner tangent masks.
            let v = &t.pts[c as usize];
            let last = if closed {
                e[1 % e.len()]
            } else {
                e[e.len() - 1]
            };
            let t1 = comb(&[(1.0, &t.pts[e[0] as usize]), (-1.0, v)]);
            let t2 = comb(&[(1.0, &t.pts[last as usize]), (-1.0, v)]);
            (v.clone(), t1, t2)
        }
    }
}

/// The 1-ring of `c0` in `t0`, locally subdivided until every incident
/// face is a quad and every sharpness at the vertex is 0 or infinite
/// (semi-sharp features run out after at most ceil(sharpness) levels): the
/// limit masks of [`vertex_limit`] assume both. Returns the ring, its
/// adjacency, and `c0` and `start` in it.
fn settled_ring<P: Pt>(
    t0: &Topo<P>,
    adj0: &Adj,
    c0: u32,
    start: Option<u32>,
) -> (Topo<P>, Adj, u32, Option<u32>) {
    let (mut t, map) = t0.ring(adj0, &[c0], None);
    let mut c = map[c0 as usize];
    let mut start = start.map(|s| map[s as usize]);
    let mut adj = t.adjacency();
    let settled = |s: f64| s == 0.0 || s >= INF;
    for _ in 0..(INF as usize + 2) {
        let ok = adj.vfaces[c as usize].iter().all(|&f| t.face(f).len() == 4)
            && settled(t.vert_sharp(&adj, c))
            && adj.vedges[c as usize]
                .iter()
                .all(|&e| settled(t.edge_sharp(&adj, e)));
        if ok {
            break;
        }
        let r = t.refine(&adj);
        let s_child = start.map(|s| t.edge_child(adj.edge_id[&key(c, s)]));
        let radj = r.adjacency();
        let (nt, map) = r.ring(&radj, &[c], None);
        start = s_child.map(|s| map[s as usize]);
        c = map[c as usize];
        t = nt;
        adj = t.adjacency();
    }
    (t, adj, c, start)
}

/// Dart limit (`e`, `f` rotated to start at the sharp edge): the exact
/// eigenvector masks of [`dart_masks`] applied to the fan.
fn dart_limit<P: Pt>(t: &Topo<P>, adj: &Adj, c: u32, e: &[u32], f: &[u32]) -> (P, P, P) {
    let pt = |i: u32| &t.pts[i as usize];
    let v = pt(c);
    let (p, t1, t2) = dart_masks(t, adj, c, e, f);
    let apply = |w: &[f64]| {
        let mut r = P::zero();
        r.axpy(w[0], v);
        for i in 0..e.len() {
            r.axpy(w[1 + i], pt(e[i]));
            r.axpy(w[1 + e.len() + i], pt(f[i]));
        }
        r
    };
    (apply(&p), apply(&t1), apply(&t2))
}

/// The smooth rule's limit position weights at an interior vertex of
/// valence `n` whose faces are quads: `[vertex, each edge neighbour, each
/// diagonal]`, the dominant left eigenvector `(n² v + 4 Σ e_i + Σ f_i) /
/// (n (n + 5))` of [`smooth_limit`].
fn smooth_position_weights(n: usize) -> [f64; 3] {
    let nf = n as f64;
    let d = nf * (nf + 5.0);
    [nf * nf / d, 4.0 / d, 1.0 / d]
}

/// A crease vertex's limit position weights `[e_0, vertex, e_k]` over its
/// two crease neighbours: the cubic B-spline's (1, 4, 1) / 6 of
/// [`crease_limit`].
const CREASE_POSITION_WEIGHTS: [f64; 3] = [1.0 / 6.0, 4.0 / 6.0, 1.0 / 6.0];

/// Interior (closed) fan of quads. Position: the dominant left
/// eigenvector (n²v + 4Σe + Σf)/(n(n+5)), exact for every n ≥ 2
/// (OpenSubdiv uses the corner mask at n = 2 on purpose, see
/// `known_differences`). Darts use the smooth masks like Sdc.
fn smooth_limit<P: Pt>(t: &Topo<P>, c: u32, e: &[u32], f: &[u32]) -> (P, P, P) {
    let pt = |i: u32| &t.pts[i as usize];
    let v = pt(c);
    let n = e.len();
    let nf = n as f64;
    let [wv, we, wf] = smooth_position_weights(n);
    let mut p = P::zero();
    p.axpy(wv, v);
    for i in 0..n {
        p.axpy(we, pt(e[i]));
        p.axpy(wf, pt(f[i]));
    }
    let (mut t1, mut t2) = (P::zero(), P::zero());
    if n == 2 {
        t1 = comb(&[(1.0, pt(e[0])), (-1.0, pt(e[1]))]);
        t2 = comb(&[(1.0, pt(f[0])), (-1.0, pt(f[1]))]);
    } else {
        // Subdominant eigenvectors (Halstead, Kass & DeRose 1993,
        // appendix): e_i weighted A_n cos(2πi/n), f_i weighted
        // cos(2πi/n) + cos(2π(i+1)/n); the sine version is the
        // second one, a quarter period on.
        let th = 2.0 * std::f64::consts::PI / nf;
        let an = 1.0 + th.cos() + (th / 2.0).cos() * (2.0 * (9.0 + th.cos())).sqrt();
        for i in 0..n {
            let (a0, a1) = (th * i as f64, th * (i + 1) as f64);
            t1.axpy(an * a0.cos(), pt(e[i]));
            t1.axpy(a0.cos() + a1.cos(), pt(f[i]));
            t2.axpy(an * a0.sin(), pt(e[i]));
            t2.axpy(a0.sin() + a1.sin(), pt(f[i]));
        }
        // The masks sum to zero; scale like a B-spline derivative
        // at a regular vertex (A_4 = 4: divide by 12).
        t1 = comb(&[(1.0 / 12.0, &t1)]);
        t2 = comb(&[(1.0 / 12.0, &t2)]);
    }
    (p, t1, t2)
}

/// Crease limit (`e`, `f` starting at a sharp edge `e_0`; the other sharp
/// edge is `e_k`): the crease is a cubic B-spline curve.
fn crease_limit<P: Pt>(t: &Topo<P>, adj: &Adj, c: u32, e: &[u32], f: &[u32]) -> (P, P, P) {
    let pt = |i: u32| &t.pts[i as usize];
    let v = pt(c);
    let k = e
        .iter()
        .skip(1)
        .position(|&x| t.edge_sharp(adj, adj.edge_id[&key(c, x)]) > 0.0)
        .map_or(e.len() - 1, |i| i + 1);
    // The crease is a cubic B-spline curve: 1-4-1 limit mask.
    let [w0, wv, wk] = CREASE_POSITION_WEIGHTS;
    let p = comb(&[(w0, pt(e[0])), (wv, v), (wk, pt(e[k]))]);
    let t1 = comb(&[(0.5, pt(e[0])), (-0.5, pt(e[k]))]);
    // Across: on the side between e_0 and e_k (k faces). For k = 2
    // the regular boundary B-spline derivative; otherwise the exact
    // eigenvector.
    let t2 = if k == 1 {
        // One face between the two sharp edges (a boundary corner without
        // corner sharpening, "edge only"): on the symmetric modes, 1/4 is
        // a defective eigenvalue (the crease curve's second difference and
        // the face point share it in a Jordan block), whose only left
        // eigenvector is `2v - e_0 - e_1`. The face point's share of the
        // surface decays faster by a factor of the level, so the tangent
        // plane is the osculating plane of the crease curve; a power
        // iteration would converge like 1/iterations (9e-5 rad off after
        // 4000). Sdc's crease limit tangent gives the same plane.
        comb(&[(0.5, pt(e[0])), (0.5, pt(e[1])), (-1.0, v)])
    } else if k == 2 {
        comb(&[
            (1.0 / 6.0, pt(f[0])),
            (4.0 / 6.0, pt(e[1])),
            (1.0 / 6.0, pt(f[1])),
            (-1.0 / 6.0, pt(e[0])),
            (-4.0 / 6.0, v),
            (-1.0 / 6.0, pt(e[2])),
        ])
    } else {
        let w = crease_cross_mask(k);
        let mut r = P::zero();
        r.axpy(w[0], v);
        for i in 0..=k {
            r.axpy(w[1 + i], pt(e[i]));
        }
        for j in 0..k {
            r.axpy(w[2 + k + j], pt(f[j]));
        }
        r
    };
    (p, t1, t2)
}

impl LimitEvaluator for RustEvaluator {
    fn name(&self) -> &'static str {
        "rust"
    }
    fn num_control_vertices(&self) -> usize {
        self.mesh.num_vertices()
    }
    fn vertex_limits(&self, positions: &[DVec3]) -> Result<Vec<LimitPoint>> {
        self.check_positions(positions)?;
        Ok((0..self.mesh.num_vertices())
            .into_par_iter()
            .map(|v| {
                let mut r = LimitPoint::default();
                for k in self.vm_off[v] as usize..self.vm_off[v + 1] as usize {
                    let x = positions[self.vm_idx[k] as usize];
                    let w = self.vm_w[k];
                    r.position += w[0] * x;
                    r.du += w[1] * x;
                    r.dv += w[2] * x;
                }
                r
            })
            .collect())
    }
    fn evaluate(
        &self,
        positions: &[DVec3],
        locations: &[SurfaceLocation],
    ) -> Result<Vec<LimitPoint>> {
        self.check_positions(positions)?;
        self.check_locations(locations)?;
        Ok(locations
            .par_iter()
            .with_min_len(64)
            .map(|l| self.eval_one(positions, l))
            .collect())
    }
    fn stencils(&self, locations: &[SurfaceLocation]) -> Result<LimitStencils> {
        self.check_locations(locations)?;
        let rows: Vec<Vec<(u32, [f64; 3])>> = locations
            .par_iter()
            .with_min_len(16)
            .map(|l| self.stencil_one(l))
            .collect();
        let mut st = LimitStencils {
            offsets: vec![0],
            ..Default::default()
        };
        for r in rows {
            for (i, w) in r {
                st.indices.push(i);
                st.weights.push(w[0]);
                st.du_weights.push(w[1]);
                st.dv_weights.push(w[2]);
            }
            st.offsets.push(st.indices.len() as u32);
        }
        Ok(st)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The direct read of a plain quad vertex's mask is the general
    /// route's, bit for bit (interior, boundary and corner vertices), and
    /// so is [`vertex_limit_mask_into`] on every vertex (the plain ones and
    /// those around triangles, which fall back) with one buffer reused
    /// from vertex to vertex.
    #[test]
    fn plain_quad_masks_are_the_general_routes() {
        let scheme = crate::mesh::SchemeOptions::default();
        let rules = Rules::from_scheme(&scheme);
        let mut checked = 0;
        let mut fallbacks = 0;
        let mut fast = Vec::new();
        let mut reused = vec![(VertexId(7), 0.5)];
        for (name, m) in [
            ("grid", crate::fixtures::grid(5, 4, 3)),
            ("flat grid", crate::fixtures::flat_grid(3, 2)),
            ("polar sphere", crate::fixtures::polar_sphere(7, 3)),
            ("cube", crate::fixtures::cube()),
            ("valence 2", crate::fixtures::valence2(1)),
            ("prism", crate::fixtures::prism(5)),
            ("mixed n-gons", crate::fixtures::mixed_ngons(1)),
            ("creased cube", crate::fixtures::creased_cube(1)),
        ] {
            for v in m.vertices() {
                let (p, _, _) = vertex_masks(&m, v, rules);
                let general: Vec<(VertexId, f64)> =
                    p.0.into_iter().map(|(i, w)| (VertexId(i), w)).collect();
                vertex_limit_mask_into(&m, v, &scheme, &mut reused);
                assert_eq!(reused, general, "{name} {v} (reused buffer)");
                fast.clear();
                // The direct read assumes no sharpness (its caller checks).
                let sharp = m.vertex_sharpness(v) != 0.0
                    || m.outgoing(v).any(|h| m.edge_sharpness(h.edge()) != 0.0);
                if sharp || !plain_quad_mask_into(&m, v, &mut fast) {
                    assert!(fast.is_empty(), "{name} {v}: a refused mask left entries");
                    fallbacks += 1;
                    continue;
                }
                assert_eq!(fast, general, "{name} {v}");
                checked += 1;
            }
        }
        assert!(checked > 50, "{checked} vertices checked");
        // The n-gon caps and the creases take the general route.
        assert!(
            fallbacks > 10,
            "{fallbacks} vertices took the general route"
        );
    }
}
