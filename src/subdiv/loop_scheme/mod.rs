//! Pure-Rust exact Loop limit evaluation (`Sdc::SCHEME_LOOP`), with
//! OpenSubdiv 3.5's rules (`sdc/loopScheme.h`, and the scheme-independent
//! `Sdc::Crease` logic shared with Catmark in `subdiv::catmark::topo`):
//! Loop's (1987) smooth masks with Sdc's weights for every valence,
//! crease masks (3/4, 1/8, 1/8) and edge midpoints at boundaries and
//! infinitely sharp creases, corners, semi-sharp creases and corners decaying
//! uniformly or by Chaikin's rule, boundary interpolation "edge only" or
//! "edge and corner". The design mirrors [`crate::subdiv::catmark`]:
//!
//! - A triangle whose three vertices are regular (six faces, smooth; or on
//!   a boundary/crease with three faces on its side) is a quartic box-spline
//!   patch over 12 control points (Stam 1998), see the `patch` module.
//! - Every other triangle is evaluated by local subdivision: its 1-ring is
//!   refined, the child triangle containing the location is kept with its
//!   own 1-ring, and so on until the child is regular (each level halves the
//!   distance to the irregular corner). A location exactly at an irregular
//!   corner (or within 2^-[`MAX_DEPTH`] of it) gets that vertex's limit.
//! - Vertex limits are the left eigenvectors of the vertex's one-ring
//!   subdivision matrix, after local subdivision has settled semi-sharp
//!   features: the dominant one (position) and the two subdominant ones
//!   (tangents), which makes darts and creases exact as well.
//!
//! Parametrisation (OpenSubdiv's triangular ptex face): triangle
//! `(v0 v1 v2)` has `(0,0)` at v0, `(1,0)` at v1, `(0,1)` at v2. Its four
//! children are `(v0, e01, e20)`, `(e01, v1, e12)`, `(e20, e12, v2)` (the
//! parent's parametrisation halved and translated) and the middle one
//! `(e12, e20, e01)` (turned by a half turn).

pub(crate) mod patch;

use rayon::prelude::*;

use crate::error::Result;
use crate::mesh::{check_loop_triangles, ControlMesh, FaceId};
use crate::subdiv::catmark::topo::{
    comb, face_ring, key, merge3, topo_from_mesh, vertex_rule, Adj, Pt, Rule, Rules, Sparse, Topo,
    INF,
};
use crate::subdiv::{
    check_locations_for, check_not_holes, check_positions, checked_holes, EvalOptions,
    LimitEvaluator, LimitPoint, LimitStencils, SubdivScheme, SurfaceLocation,
};
use crate::DVec3;

use patch::{box_spline_weights, corner_is_regular, regular_patch, Slot};

/// The deepest local subdivision used to approach an irregular corner; the
/// surface near a Loop vertex shrinks by at most ~0.6 per level (the
/// subdominant eigenvalue 3/8 + cos(2π/n)/4 < 5/8), so below that depth it
/// moves by less than 1e-17 of the 1-ring size.
pub const MAX_DEPTH: usize = 80;

/// Sdc's smooth Loop vertex weights `(vertex, each neighbour)` for `n`
/// faces (`Scheme<SCHEME_LOOP>::assignSmoothMaskForVertex`, after Loop
/// 1987): 5/8 and 1/16 at n = 6, else β = 3/8 + cos(2π/n)/4 and
/// `(5/8 - β²)/n` per neighbour.
fn smooth_weights(n: usize) -> (f64, f64) {
    if n == 6 {
        return (0.625, 0.0625);
    }
    let nf = n as f64;
    let beta = 0.25 * (std::f64::consts::PI * 2.0 / nf).cos() + 0.375;
    let e = (0.625 - beta * beta) / nf;
    (1.0 - e * nf, e)
}

impl<P: Pt> Topo<P> {
    /// Loop mask of the child of vertex `v` under `rule`.
    fn loop_vertex_mask(&self, adj: &Adj, v: u32, rule: Rule, sharp: &[f64]) -> P {
        if let Some(r) = self.sharp_vertex_mask(adj, v, rule, sharp) {
            return r;
        }
        let vi = v as usize;
        let (wv, we) = smooth_weights(adj.vfaces[vi].len());
        let mut r = P::zero();
        r.axpy(wv, &self.pts[vi]);
        for &e in &adj.vedges[vi] {
            r.axpy(we, &self.pts[self.other(adj, e, v) as usize]);
        }
        r
    }

    /// Loop edge point: smooth 3/8 of each end and 1/8 of each opposite
    /// vertex, the midpoint when its child vertex is a crease
    /// (`Topo::edge_child_is_crease`), otherwise for a sharp edge the blend
    /// of the two by its sharpness (Sdc `ComputeEdgeVertexMask`).
    fn loop_edge_point(&self, adj: &Adj, e: u32) -> P {
        let (a, b) = adj.edges[e as usize];
        let s = self.edge_sharp(adj, e);
        let (pa, pb) = (&self.pts[a as usize], &self.pts[b as usize]);
        let mid = comb(&[(0.5, pa), (0.5, pb)]);
        if adj.edge_nfaces[e as usize] != 2 || self.edge_child_is_crease(adj, e) {
            return mid;
        }
        let opposite = |f: u32| {
            let fv = self.face(f);
            let o = fv.iter().copied().find(|&x| x != a && x != b);
            &self.pts[o.expect("a triangle has a third vertex") as usize]
        };
        let [f0, f1] = adj.edge_faces[e as usize];
        let smooth = comb(&[
            (0.375, pa),
            (0.375, pb),
            (0.125, opposite(f0)),
            (0.125, opposite(f1)),
        ]);
        if s > 0.0 {
            comb(&[(s, &mid), (1.0 - s, &smooth)])
        } else {
            smooth
        }
    }

    /// One level of Loop refinement of an all-triangle `Topo`. Child
    /// vertices: vertex points, then edge points (by edge id); child faces
    /// `4f..4f+4` of face `f` as in the module doc.
    pub(crate) fn refine_loop(&self, adj: &Adj) -> Topo<P> {
        let nv = self.pts.len();
        let ne = adj.edges.len();
        let mut pts = Vec::with_capacity(nv + ne);
        for v in 0..nv as u32 {
            pts.push(self.vertex_point(adj, v, |rule, sharp| {
                self.loop_vertex_mask(adj, v, rule, sharp)
            }));
        }
        for e in 0..ne as u32 {
            pts.push(self.loop_edge_point(adj, e));
        }
        let mut fv = Vec::with_capacity(4 * self.fv.len());
        let mut fe = Vec::with_capacity(4 * self.fv.len());
        let mut foff = Vec::with_capacity(4 * self.num_faces() + 1);
        foff.push(0u32);
        for f in 0..self.num_faces() as u32 {
            let c = self.face(f);
            let base = self.foff[f as usize] as usize;
            let pe = [0, 1, 2].map(|k| adj.corner_edge[base + k]);
            let [e01, e12, e20] = pe.map(|e| nv as u32 + e);
            // The child edges by identity, not by their ends: parent edge
            // e's half at its first vertex is 2e, at its second 2e + 1; the
            // three inside face f are 2ne + 3f + 0..3.
            let half = |k: usize, at: u32| 2 * pe[k] + u32::from(adj.edges[pe[k] as usize].0 != at);
            let inner = |j: u32| 2 * ne as u32 + 3 * f + j;
            for (tri, edges) in [
                ([c[0], e01, e20], [half(0, c[0]), inner(0), half(2, c[0])]),
                ([e01, c[1], e12], [half(0, c[1]), half(1, c[1]), inner(1)]),
                ([e20, e12, c[2]], [inner(2), half(1, c[2]), half(2, c[2])]),
                ([e12, e20, e01], [inner(2), inner(0), inner(1)]),
            ] {
                fv.extend_from_slice(&tri);
                fe.extend_from_slice(&edges);
                foff.push(fv.len() as u32);
            }
        }
        let esharp = self.child_edge_sharpness(adj);
        let mut vsharp: Vec<f64> = self
            .vsharp
            .iter()
            .map(|&s| crate::subdiv::catmark::topo::decrement(s))
            .collect();
        vsharp.resize(nv + ne, 0.0);
        Topo {
            pts,
            vsharp,
            foff,
            fv,
            esharp,
            rules: self.rules,
            fe,
        }
    }
}

/// Exact Loop limit evaluator; see the module doc.
pub struct LoopEvaluator {
    mesh: ControlMesh,
    sdc: Rules,
    holes: Vec<bool>,
    /// Per face: its 12 patch control points (global ids) when regular.
    patches: Vec<Option<[Slot; 12]>>,
    /// Vertex limit masks (position, tangent 1, tangent 2) per vertex.
    masks: Vec<Vec<(u32, [f64; 3])>>,
}

/// Applies patch weights to the slots of `pts`.
fn apply_patch<P: Pt>(slots: &[Slot; 12], w: &[[f64; 12]; 3], pts: &[P]) -> [P; 3] {
    let mut out = [P::zero(), P::zero(), P::zero()];
    for (m, s) in slots.iter().enumerate() {
        for k in 0..3 {
            match *s {
                Slot::Real(i) => out[k].axpy(w[k][m], &pts[i as usize]),
                Slot::Phantom(a, b, c) => {
                    out[k].axpy(w[k][m], &pts[a as usize]);
                    out[k].axpy(w[k][m], &pts[b as usize]);
                    out[k].axpy(-w[k][m], &pts[c as usize]);
                }
            }
        }
    }
    out
}

/// The child triangle of `(u, v)` and its parameters there, with the
/// derivative factor `∂s/∂u = ∂t/∂v` (±2).
fn child_of(u: f64, v: f64) -> (u32, f64, f64, f64) {
    if u >= 0.5 {
        (1, 2.0 * u - 1.0, 2.0 * v, 2.0)
    } else if v >= 0.5 {
        (2, 2.0 * u, 2.0 * v - 1.0, 2.0)
    } else if u + v <= 0.5 {
        (0, 2.0 * u, 2.0 * v, 2.0)
    } else {
        (3, 1.0 - 2.0 * u, 1.0 - 2.0 * v, -2.0)
    }
}

/// Exact limit at `(u, v)` of face 0 of `t` (the 1-ring of that face), by
/// local Loop subdivision until the location lies in a regular patch.
/// Returns position and derivatives with respect to `(u, v)`.
fn eval_local<P: Pt>(mut t: Topo<P>, u: f64, v: f64) -> (P, P, P) {
    let mut adj = t.adjacency();
    // Points are kept relative to a point of the current face: near an
    // irregular vertex the neighbourhood shrinks geometrically while its
    // coordinates do not, and the derivatives would be lost to cancellation
    // (the same reason as in `catmark::eval_local`). The rules are affine,
    // so subdividing translated points is exact.
    let mut offset = P::zero();
    let recenter = |t: &mut Topo<P>, offset: &mut P| {
        let o = t.pts[t.face(0)[0] as usize].clone();
        for p in t.pts.iter_mut() {
            p.axpy(-1.0, &o);
        }
        offset.axpy(1.0, &o);
    };
    recenter(&mut t, &mut offset);
    let (mut s, mut tt, mut scale) = (u, v, 1.0);
    for depth in 0..=MAX_DEPTH {
        if let Some(slots) = regular_patch(&t, &adj, 0) {
            let w = box_spline_weights(s, tt);
            let [mut p, ds, dt] = apply_patch(&slots, &w, &t.pts);
            p.axpy(1.0, &offset);
            return (p, comb(&[(scale, &ds)]), comb(&[(scale, &dt)]));
        }
        let at_corner = match (s, tt) {
            (x, y) if x == 0.0 && y == 0.0 => Some(0),
            (x, y) if x == 1.0 && y == 0.0 => Some(1),
            (x, y) if x == 0.0 && y == 1.0 => Some(2),
            _ => None,
        };
        // A regular corner's child is regular one level down; an irregular
        // one never is, its limit is the vertex's.
        let corner = match at_corner {
            Some(k) if !corner_is_regular(&t, &adj, 0, k) => Some(k),
            Some(_) => None,
            _ if depth == MAX_DEPTH => Some(if s >= tt && s >= 1.0 - s - tt {
                1
            } else if tt >= 1.0 - s - tt {
                2
            } else {
                0
            }),
            _ => None,
        };
        if let Some(k) = corner {
            // The limit at an irregular corner: its vertex limit, with the
            // tangents of the limit masks (oriented like the faces).
            let c = t.face(0)[k];
            let (mut p, t1, t2) = vertex_limit(&t, &adj, c);
            p.axpy(1.0, &offset);
            return (p, t1, t2);
        }
        let (child, ns, nt, d) = child_of(s, tt);
        let r = t.refine_loop(&adj);
        let radj = r.adjacency();
        let cf = child; // face 0's children are faces 0..4
        let cv = r.face(cf).to_vec();
        t = r.ring(&radj, &cv, Some(cf)).0;
        recenter(&mut t, &mut offset);
        adj = t.adjacency();
        s = ns.clamp(0.0, 1.0);
        tt = nt.clamp(0.0, 1.0 - s);
        scale *= d;
    }
    unreachable!("the loop returns at MAX_DEPTH")
}

/// The 1-ring of `c0` in `t0`, locally subdivided until every sharpness at
/// the vertex is 0 or infinite (semi-sharp features run out after at most
/// `ceil(sharpness)` levels, or 10 under Chaikin's rule at the latest): the
/// one-ring matrix of [`ring_matrix`] assumes it. Returns the ring, its
/// adjacency and `c0` in it.
fn settled_ring<P: Pt>(t0: &Topo<P>, adj0: &Adj, c0: u32) -> (Topo<P>, Adj, u32) {
    let (mut t, map) = t0.ring(adj0, &[c0], None);
    let mut c = map[c0 as usize];
    let mut adj = t.adjacency();
    let settled = |s: f64| s == 0.0 || s >= INF;
    for _ in 0..(INF as usize + 2) {
        let ok = settled(t.vert_sharp(&adj, c))
            && adj.vedges[c as usize]
                .iter()
                .all(|&e| settled(t.edge_sharp(&adj, e)));
        if ok {
            break;
        }
        let r = t.refine_loop(&adj);
        let radj = r.adjacency();
        let (nt, map) = r.ring(&radj, &[c], None);
        c = map[c as usize];
        t = nt;
        adj = t.adjacency();
    }
    (t, adj, c)
}

/// The neighbours of `c` counter-clockwise, from the leading boundary edge
/// when there is one; `closed` when the fan goes all the way round.
fn loop_fan<P>(t: &Topo<P>, adj: &Adj, c: u32) -> (Vec<u32>, bool) {
    // Face to face across edges (`Adj::corner_edge`), not by vertex pairs:
    // two edges can join one pair of vertices (`Topo::fe`).
    let at = |f: u32| t.face(f).iter().position(|&x| x == c);
    // The face of edge `e` that runs c → x along it.
    let leaving = |e: u32| -> Option<u32> {
        let n = adj.edge_nfaces[e as usize].min(2) as usize;
        adj.edge_faces[e as usize][..n]
            .iter()
            .copied()
            .find(|&f| at(f).is_some_and(|p| adj.corner_edge[t.foff[f as usize] as usize + p] == e))
    };
    let ci = c as usize;
    let bstart = adj.vedges[ci]
        .iter()
        .copied()
        .find(|&e| adj.edge_nfaces[e as usize] == 1 && leaving(e).is_some());
    let Some(&e0) = adj.vedges[ci].first() else {
        return (Vec::new(), false);
    };
    let e_first = bstart.unwrap_or(e0);
    let first = t.other(adj, e_first, c);
    let mut fan = Vec::new();
    let (mut cur, mut g) = (first, leaving(e_first));
    for _ in 0..=adj.vedges[ci].len() {
        fan.push(cur);
        let Some(f) = g else {
            return (fan, false);
        };
        let p = at(f).unwrap_or(0);
        let next = t.face(f)[(p + 2) % 3];
        if next == first {
            return (fan, true);
        }
        g = t.across(adj, f, (p + 2) % 3);
        cur = next;
    }
    (fan, true)
}

/// The one-level subdivision matrix of the settled one-ring of `c` (points
/// `c, e_0..e_{n-1}`, rows = their children in the same order): Loop's
/// one-ring is closed under refinement, the vertex under its rule and each
/// `e_i` becoming the point of edge `(c, e_i)`.
fn ring_matrix<P>(t: &Topo<P>, adj: &Adj, c: u32, e: &[u32], closed: bool) -> Vec<Vec<f64>> {
    let n = e.len();
    let mut s = vec![vec![0.0; n + 1]; n + 1];
    let sharp: Vec<f64> = e
        .iter()
        .map(|&x| t.edge_sharp(adj, adj.edge_id[&key(c, x)]))
        .collect();
    match vertex_rule(t.vert_sharp(adj, c), &sharp) {
        Rule::Corner => s[0][0] = 1.0,
        Rule::Crease => {
            s[0][0] = 0.75;
            for i in (0..n).filter(|&i| sharp[i] > 0.0) {
                s[0][1 + i] = 0.125;
            }
        }
        Rule::Smooth => {
            let (wv, we) = smooth_weights(adj.vfaces[c as usize].len());
            s[0][0] = wv;
            (0..n).for_each(|i| s[0][1 + i] = we);
        }
    }
    for i in 0..n {
        let row = &mut s[1 + i];
        if sharp[i] > 0.0 {
            row[0] = 0.5;
            row[1 + i] = 0.5;
        } else {
            // Interior smooth edge: its opposite vertices are the fan
            // neighbours on either side.
            let (prev, next) = ((i + n - 1) % n, (i + 1) % n);
            debug_assert!(closed || (i > 0 && i + 1 < n));
            row[0] = 0.375;
            row[1 + i] += 0.375;
            row[1 + prev] += 0.125;
            row[1 + next] += 0.125;
        }
    }
    s
}

/// `w <- w S` (a left multiplication: masks are rows).
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

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// Limit masks over `c, e_0..` from the ring matrix `s`: the dominant left
/// eigenvector (the limit of the vertex's own stencil under repeated
/// subdivision) and a basis of the dominant zero-sum left invariant
/// subspace of dimension two (subspace iteration), oriented like the
/// reference pair `(ra, rb)`.
fn eigen_masks(s: &[Vec<f64>], ra: &[f64], rb: &[f64]) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let m = s.len();
    let mut p = vec![0.0; m];
    p[0] = 1.0;
    for _ in 0..5000 {
        let np = left_apply(s, &p);
        let d = np
            .iter()
            .zip(&p)
            .fold(0.0f64, |a, (x, y)| a.max((x - y).abs()));
        p = np;
        if d < 1e-18 {
            break;
        }
    }
    let (mut a, mut b) = (ra.to_vec(), rb.to_vec());
    let deflate = |x: &mut Vec<f64>| {
        let sum: f64 = x.iter().sum();
        x.iter_mut().zip(&p).for_each(|(v, l)| *v -= sum * l);
    };
    let normalize = |x: &mut Vec<f64>| {
        let n = dot(x, x).sqrt();
        x.iter_mut().for_each(|v| *v /= n);
    };
    for _ in 0..5000 {
        let (mut na, mut nb) = (left_apply(s, &a), left_apply(s, &b));
        deflate(&mut na);
        deflate(&mut nb);
        normalize(&mut na);
        let proj = dot(&nb, &na);
        nb.iter_mut().zip(&na).for_each(|(y, x)| *y -= proj * x);
        normalize(&mut nb);
        let d = na
            .iter()
            .zip(&a)
            .chain(nb.iter().zip(&b))
            .fold(0.0f64, |acc, (x, y)| acc.max((x - y).abs()));
        a = na;
        b = nb;
        if d < 1e-15 {
            break;
        }
    }
    // Orientation: the determinant of the projection onto the reference.
    let det = dot(&a, ra) * dot(&b, rb) - dot(&a, rb) * dot(&b, ra);
    if det < 0.0 {
        b.iter_mut().for_each(|v| *v = -*v);
    }
    (p, a, b)
}

/// Exact limit position and two tangents at vertex `c` of `t` (its fan must
/// be complete in `t`); `t1 × t2` is the outward normal for outward-
/// oriented faces. At an infinitely sharp corner (or crease vertex with
/// more than one sector) the tangents are those of the first sector.
pub(crate) fn vertex_limit<P: Pt>(t0: &Topo<P>, adj0: &Adj, c0: u32) -> (P, P, P) {
    let (t, adj, c) = settled_ring(t0, adj0, c0);
    let (mut e, closed) = loop_fan(&t, &adj, c);
    let sharp_at = |x: u32| t.edge_sharp(&adj, adj.edge_id[&key(c, x)]) > 0.0;
    let nsharp = e.iter().filter(|&&x| sharp_at(x)).count();
    if closed && nsharp > 1 {
        // An interior crease: rotate to start at a sharp edge, so the first
        // sector runs from e_0 to the next sharp edge.
        let i0 = e.iter().position(|&x| sharp_at(x)).unwrap_or(0);
        e.rotate_left(i0);
    }
    let n = e.len();
    let s = ring_matrix(&t, &adj, c, &e, closed);
    // Reference tangents: Loop's smooth cosine/sine masks for a closed fan;
    // for a sector from e_0 to e_k, the chord e_0 - e_k and the direction
    // from c into the sector (positively oriented for CCW faces).
    let (mut ra, mut rb) = (vec![0.0; n + 1], vec![0.0; n + 1]);
    let k = if closed && nsharp > 1 {
        (1..n).find(|&i| sharp_at(e[i])).unwrap_or(n - 1)
    } else if closed {
        0
    } else {
        n - 1
    };
    if k == 0 {
        let th = 2.0 * std::f64::consts::PI / n as f64;
        for i in 0..n {
            ra[1 + i] = (th * i as f64).cos();
            rb[1 + i] = (th * i as f64).sin();
        }
    } else {
        ra[1] = 1.0;
        ra[1 + k] = -1.0;
        rb[0] = -1.0;
        if k == 1 {
            rb[1] = 0.5;
            rb[2] = 0.5;
        } else {
            for i in 1..k {
                rb[1 + i] = 1.0 / (k - 1) as f64;
            }
        }
    }
    let rule = vertex_rule(
        t.vert_sharp(&adj, c),
        &e.iter()
            .map(|&x| t.edge_sharp(&adj, adj.edge_id[&key(c, x)]))
            .collect::<Vec<_>>(),
    );
    let apply = |w: &[f64]| {
        let mut r = P::zero();
        r.axpy(w[0], &t.pts[c as usize]);
        for i in 0..n {
            r.axpy(w[1 + i], &t.pts[e[i] as usize]);
        }
        r
    };
    if rule == Rule::Corner {
        // The corner interpolates; its tangents are the edges of its first
        // sector, like Sdc's corner tangent masks.
        return (t.pts[c as usize].clone(), apply(&ra), apply(&rb));
    }
    let (p, a, b) = if k == 0 {
        // Restricting to the sector keeps the other side's modes out.
        eigen_masks(&s, &ra, &rb)
    } else {
        let sub: Vec<Vec<f64>> = s[..k + 2].iter().map(|r| r[..k + 2].to_vec()).collect();
        let (p, a, b) = eigen_masks(&sub, &ra[..k + 2], &rb[..k + 2]);
        let pad = |mut x: Vec<f64>| {
            x.resize(n + 1, 0.0);
            x
        };
        (pad(p), pad(a), pad(b))
    };
    (apply(&p), apply(&a), apply(&b))
}

impl LoopEvaluator {
    /// Prepares the evaluator: the mesh must be all triangles
    /// ([`check_loop_triangles`]) and valid.
    pub fn new(mesh: &ControlMesh, options: &EvalOptions) -> Result<Self> {
        mesh.validate()?;
        check_loop_triangles(mesh)?;
        let holes = checked_holes(mesh, &options.scheme)?;
        let sdc = Rules {
            f32_sharpness: !options.exact_sharpness,
            ..Rules::from_scheme(&options.scheme)
        };
        let faces: Vec<FaceId> = mesh.faces().collect();
        let patches = faces
            .par_iter()
            .map(|&f| {
                let t = topo_from_mesh(mesh, Some(&face_ring(mesh, f)), sdc);
                let adj = t.adjacency();
                regular_patch(&t, &adj, 0).map(|slots| {
                    slots.map(|s| match s {
                        Slot::Real(i) => Slot::Real(t.pts[i as usize]),
                        Slot::Phantom(a, b, c) => {
                            Slot::Phantom(t.pts[a as usize], t.pts[b as usize], t.pts[c as usize])
                        }
                    })
                })
            })
            .collect();
        let masks = mesh
            .vertices()
            .collect::<Vec<_>>()
            .par_iter()
            .map(|&v| {
                let faces: Vec<FaceId> = mesh.vertex_faces(v).collect();
                let t = topo_from_mesh(mesh, Some(&faces), sdc);
                let local = t
                    .pts
                    .iter()
                    .position(|&g| g == v.0)
                    .expect("v is in its ring") as u32;
                let t = t.with_points(Sparse::unit);
                let adj = t.adjacency();
                let (mut p, a, b) = vertex_limit(&t, &adj, local);
                if let Some((bv, delta)) = options.broken_mask.filter(|m| m.0 == v.0) {
                    p.axpy(delta, &Sparse::unit(bv));
                }
                merge3([&p, &a, &b])
            })
            .collect();
        Ok(LoopEvaluator {
            mesh: mesh.clone(),
            sdc,
            holes,
            patches,
            masks,
        })
    }

    /// Whether face `f` is a regular (box-spline) patch.
    pub fn is_regular_face(&self, f: FaceId) -> bool {
        matches!(self.patches.get(f.idx()), Some(Some(_)))
    }

    fn local(&self, f: FaceId) -> Topo<u32> {
        topo_from_mesh(&self.mesh, Some(&face_ring(&self.mesh, f)), self.sdc)
    }

    fn eval_one(&self, positions: &[DVec3], l: &SurfaceLocation) -> LimitPoint {
        if let Some(slots) = &self.patches[l.face.idx()] {
            let w = box_spline_weights(l.u, l.v);
            let [position, du, dv] = apply_patch(slots, &w, positions);
            return LimitPoint { position, du, dv };
        }
        let t = self.local(l.face).with_points(|g| positions[g as usize]);
        let (position, du, dv) = eval_local(t, l.u, l.v);
        LimitPoint { position, du, dv }
    }

    fn stencil_one(&self, l: &SurfaceLocation) -> Vec<(u32, [f64; 3])> {
        let t = self.local(l.face).with_points(Sparse::unit);
        let (p, du, dv) = eval_local(t, l.u, l.v);
        merge3([&p, &du, &dv])
    }

    fn check(&self, locations: &[SurfaceLocation]) -> Result<()> {
        check_locations_for(SubdivScheme::Loop, &self.mesh.face_sizes(), locations)?;
        check_not_holes(&self.holes, locations)
    }
}

impl LimitEvaluator for LoopEvaluator {
    fn name(&self) -> &'static str {
        "rust-loop"
    }
    fn num_control_vertices(&self) -> usize {
        self.mesh.num_vertices()
    }
    fn vertex_limits(&self, positions: &[DVec3]) -> Result<Vec<LimitPoint>> {
        check_positions(self.mesh.num_vertices(), positions)?;
        Ok(self
            .masks
            .iter()
            .map(|m| LimitPoint::from_row(m.iter().copied(), positions))
            .collect())
    }
    fn evaluate(
        &self,
        positions: &[DVec3],
        locations: &[SurfaceLocation],
    ) -> Result<Vec<LimitPoint>> {
        check_positions(self.mesh.num_vertices(), positions)?;
        self.check(locations)?;
        Ok(locations
            .par_iter()
            .with_min_len(32)
            .map(|l| self.eval_one(positions, l))
            .collect())
    }
    fn stencils(&self, locations: &[SurfaceLocation]) -> Result<LimitStencils> {
        self.check(locations)?;
        let rows: Vec<_> = locations
            .par_iter()
            .with_min_len(16)
            .map(|l| self.stencil_one(l))
            .collect();
        Ok(LimitStencils::from_rows(rows))
    }
}

fn loop_rules(mesh: &ControlMesh, scheme: &crate::mesh::SchemeOptions) -> Result<Rules> {
    mesh.validate()?;
    check_loop_triangles(mesh)?;
    Ok(Rules::from_scheme(scheme))
}

/// Uniform Loop refinement of the whole of `mesh` to `levels` under
/// `scheme`'s rules: the positions of the last level (vertex points of the
/// previous level's vertices first, then its edge points by edge). The
/// reference of the rules against OpenSubdiv's uniform refinement.
pub fn refine_uniform_loop(
    mesh: &ControlMesh,
    scheme: &crate::mesh::SchemeOptions,
    levels: u32,
) -> Result<Vec<DVec3>> {
    let rules = loop_rules(mesh, scheme)?;
    let mut t = topo_from_mesh(mesh, None, rules).with_points(|g| mesh.positions()[g as usize]);
    for _ in 0..levels {
        let adj = t.adjacency();
        t = t.refine_loop(&adj);
    }
    Ok(t.pts)
}

/// Sdc's closed-form limit position mask of vertex `c` of `t` (complete fan,
/// settled sharpness): corner: itself; crease: 1/6, 2/3, 1/6 along the
/// crease (`assignCreaseLimitMask`); smooth: `1 - nχ` and `χ` per neighbour
/// with `χ = 1 / (3 / (8β) + n)` (Loop 1987; `assignSmoothLimitMask`).
fn closed_form_limit(t: &Topo<DVec3>, adj: &Adj, c: u32) -> DVec3 {
    let x = t.pts[c as usize];
    let sharp: Vec<f64> = adj.vedges[c as usize]
        .iter()
        .map(|&e| t.edge_sharp(adj, e))
        .collect();
    let others = adj.vedges[c as usize]
        .iter()
        .map(|&e| t.pts[t.other(adj, e, c) as usize]);
    match vertex_rule(t.vert_sharp(adj, c), &sharp) {
        Rule::Corner => x,
        Rule::Crease => {
            let ends: DVec3 = others
                .zip(&sharp)
                .filter(|(_, &s)| s > 0.0)
                .map(|(p, _)| p)
                .sum();
            (4.0 * x + ends) / 6.0
        }
        Rule::Smooth => {
            let n = adj.vfaces[c as usize].len() as f64;
            let (_, beta) = smooth_weights(n as usize);
            let chi = 1.0 / (3.0 / (8.0 * beta) + n);
            (1.0 - n * chi) * x + chi * others.sum::<DVec3>()
        }
    }
}

/// The unit normal of Loop's closed-form tangent masks
/// `Σ cos(2πi/n) e_i`, `Σ sin(2πi/n) e_i` (Loop 1987; exact eigenvectors of
/// the smooth one-ring matrix) at a smooth interior vertex without sharp
/// edges; `None` elsewhere (creases, corners, darts).
fn closed_form_normal(t: &Topo<DVec3>, adj: &Adj, c: u32) -> Option<DVec3> {
    let sharp = adj.vedges[c as usize]
        .iter()
        .any(|&e| t.edge_sharp(adj, e) > 0.0);
    if sharp || t.vert_sharp(adj, c) > 0.0 {
        return None;
    }
    let (e, closed) = loop_fan(t, adj, c);
    if !closed {
        return None;
    }
    let th = std::f64::consts::TAU / e.len() as f64;
    let (mut a, mut b) = (DVec3::ZERO, DVec3::ZERO);
    for (i, &x) in e.iter().enumerate() {
        a += (th * i as f64).cos() * t.pts[x as usize];
        b += (th * i as f64).sin() * t.pts[x as usize];
    }
    Some(a.cross(b).normalize())
}

/// Brute-force reference of the limit at a dyadic location `(u, v)` of
/// triangle `face` (`u·2^levels` and `v·2^levels` integers): `levels` of
/// uniform Loop refinement (restricted at each level to the 1-ring of the
/// child triangle containing the location, which leaves the points there
/// unchanged), then the closed-form limit mask of the vertex that the
/// location has become. With `levels` at least the largest semi-sharpness
/// this involves no patch, eigenvector or box spline at all; it is how the
/// tests check the exact evaluator near irregular vertices, where
/// OpenSubdiv only approximates. Also returns the unit normal of the
/// closed-form tangent masks (Loop's cosine and sine masks) where that
/// vertex is smooth, `None` at creases, corners and darts. `levels` is at
/// most 62.
pub fn limit_by_refinement(
    mesh: &ControlMesh,
    scheme: &crate::mesh::SchemeOptions,
    face: FaceId,
    u: f64,
    v: f64,
    levels: u32,
) -> Result<(DVec3, Option<DVec3>)> {
    let rules = loop_rules(mesh, scheme)?;
    let scale = (1u64 << levels.min(62)) as f64;
    let dyadic = |x: f64| (x * scale).fract() == 0.0 && (0.0..=1.0).contains(&x);
    if levels > 62 || face.idx() >= mesh.num_faces() || !dyadic(u) || !dyadic(v) || u + v > 1.0 {
        return Err(crate::error::Error::InvalidArgument(format!(
            "limit_by_refinement: ({u}, {v}) on face {} is not a dyadic location of level {levels}",
            face.0
        )));
    }
    let mut t = topo_from_mesh(mesh, Some(&face_ring(mesh, face)), rules)
        .with_points(|g| mesh.positions()[g as usize]);
    let (mut s, mut tt) = (u, v);
    for _ in 0..levels {
        let adj = t.adjacency();
        let (child, ns, nt, _) = child_of(s, tt);
        let r = t.refine_loop(&adj);
        let radj = r.adjacency();
        let cv = r.face(child).to_vec();
        t = r.ring(&radj, &cv, Some(child)).0;
        (s, tt) = (ns, nt);
    }
    let k = if s == 0.0 && tt == 0.0 {
        0
    } else if s == 1.0 {
        1
    } else {
        2
    };
    let adj = t.adjacency();
    let c = t.face(0)[k];
    Ok((
        closed_form_limit(&t, &adj, c),
        closed_form_normal(&t, &adj, c),
    ))
}
