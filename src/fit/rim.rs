//! Boundary-curve fit: each boundary loop of the control mesh fitted to
//! the rim (boundary polyline) of M it follows, before the surface fit.
//!
//! Why: under Catmull-Clark with the "edge and corner" boundary rule
//! (OpenSubdiv's `VTX_BOUNDARY_EDGE_AND_CORNER`, the evaluator's setting),
//! the limit surface's border over a boundary loop without corners is the
//! closed uniform cubic B-spline of the loop's control points, and depends
//! on nothing else. The surface fit's border rows target the *closest*
//! point of the rim, a one-sided measure: a border curve lying along part
//! of the rim satisfies them as well as one covering all of it. On a mesh
//! with holes, each border curve hugged one side of its hole and the limit
//! surface capped the rest of it, where the displaced samples have nothing
//! of M below them: most of the displaced error on a small share of the
//! area (figures in docs/status.md, "Measurements behind the code").
//!
//! So each loop is fitted to its rim as a curve least-squares problem in
//! the other direction — rim points to the curve — with foot-point
//! parameter correction (Hoschek's "intrinsic parametrisation"): the data
//! are the rim resampled evenly by arc length, each with a parameter on
//! the curve; the control points solve the (tiny, dense) normal equations;
//! the parameters are then re-projected onto the new curve, a few times.
//! The initial parameters are arc-length proportional, with the phase and
//! orientation that fit well and move the control points least, so a
//! curve that collapsed onto part of its rim does not trap the fit. The
//! surface fit ([`super::fit_with_progress`]) starts from the fitted loops.
//!
//! It helps fine layouts much and can hurt very coarse ones, whose few
//! border patches do not recover from moved loops within the fit's rounds
//! (an open problem; figures in docs/status.md, "Measurements behind the
//! code"). Closed meshes are untouched.

use crate::mesh::{ControlMesh, TriMesh, VertexId};
use crate::DVec3;

/// Boundary vertices of the control mesh moved by the curve fit, with
/// their new positions (in vertex order), and the RMS distance rim → curve
/// of each fitted loop before and after.
#[derive(Clone, Debug, Default)]
pub(crate) struct RimFit {
    pub moved: Vec<(VertexId, DVec3)>,
    /// (rim → curve RMS before, after), per fitted loop, in mesh units.
    pub loops: Vec<(f64, f64)>,
}

/// Closed boundary polylines of M, each as its vertex positions in order
/// (`None` when the boundary is not a set of simple closed loops, e.g. a
/// non-manifold vertex with two outgoing boundary edges: the curve fit is
/// then skipped and the surface fit keeps its closest-point rim rows).
fn rim_loops(mesh: &TriMesh, rim: &[u8]) -> Option<Vec<Vec<DVec3>>> {
    use std::collections::HashMap;
    // The outer half-edge of a boundary edge (a, b) runs b → a, as the
    // control mesh's boundary half-edges run against their face.
    let mut next: HashMap<u32, u32> = HashMap::new();
    let mut starts: Vec<u32> = Vec::new();
    for (t, &m) in mesh.triangles.iter().zip(rim) {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            if m & (1 << k) != 0 {
                if next.insert(b, a).is_some() {
                    return None;
                }
                starts.push(b);
            }
        }
    }
    let mut seen = std::collections::HashSet::new();
    let mut loops = Vec::new();
    for s in starts {
        if seen.contains(&s) {
            continue;
        }
        let mut l = Vec::new();
        let mut c = s;
        loop {
            if !seen.insert(c) {
                return None;
            }
            l.push(mesh.positions[c as usize]);
            c = *next.get(&c)?;
            if c == s {
                break;
            }
        }
        loops.push(l);
    }
    Some(loops)
}

/// Boundary loops of the control mesh as vertex lists (in the direction of
/// the boundary half-edges).
fn control_loops(control: &ControlMesh) -> Vec<Vec<VertexId>> {
    let mut seen = vec![false; control.num_halfedges()];
    let mut loops = Vec::new();
    for h in 0..control.num_halfedges() {
        let hid = crate::mesh::HalfedgeId(h as u32);
        if seen[h] || control.is_halfedge_deleted(hid) || !control.is_boundary_halfedge(hid) {
            continue;
        }
        let mut l = Vec::new();
        let mut c = hid;
        while !seen[c.idx()] {
            seen[c.idx()] = true;
            l.push(control.tail(c));
            c = control.next(c);
        }
        loops.push(l);
    }
    loops
}

/// Uniform cubic B-spline basis at `t ∈ [0, 1)` of a segment.
fn basis(t: f64) -> [f64; 4] {
    let s = 1.0 - t;
    [
        s * s * s / 6.0,
        (3.0 * t * t * t - 6.0 * t * t + 4.0) / 6.0,
        (-3.0 * t * t * t + 3.0 * t * t + 3.0 * t + 1.0) / 6.0,
        t * t * t / 6.0,
    ]
}

/// Control-point indices and weights of the closed curve at parameter
/// `u ∈ [0, m)`: segment `i = ⌊u⌋` spans control points `i − 1 … i + 2`
/// (its ends are the limit points of vertices `i` and `i + 1`).
fn weights(u: f64, m: usize) -> [(usize, f64); 4] {
    let i = (u.floor() as isize).rem_euclid(m as isize) as usize;
    let b = basis(u - u.floor());
    [
        ((i + m - 1) % m, b[0]),
        (i, b[1]),
        ((i + 1) % m, b[2]),
        ((i + 2) % m, b[3]),
    ]
}

fn eval(p: &[DVec3], u: f64) -> DVec3 {
    weights(u, p.len())
        .iter()
        .fold(DVec3::ZERO, |a, &(j, w)| a + w * p[j])
}

/// The rim resampled at `n` points evenly spaced by arc length, with each
/// point's arc-length fraction.
fn resample(rim: &[DVec3], n: usize) -> Vec<(DVec3, f64)> {
    let k = rim.len();
    let seg: Vec<f64> = (0..k)
        .map(|i| (rim[(i + 1) % k] - rim[i]).length())
        .collect();
    let total: f64 = seg.iter().sum();
    let mut out = Vec::with_capacity(n);
    let (mut i, mut acc) = (0usize, 0.0);
    for j in 0..n {
        let s = total * j as f64 / n as f64;
        while i + 1 < k && acc + seg[i] < s {
            acc += seg[i];
            i += 1;
        }
        let t = if seg[i] > 0.0 {
            ((s - acc) / seg[i]).clamp(0.0, 1.0)
        } else {
            0.0
        };
        out.push((
            rim[i] + t * (rim[(i + 1) % k] - rim[i]),
            j as f64 / n as f64,
        ));
    }
    out
}

/// Least-squares control points for data points with given parameters,
/// plus a small second-difference fairness (keeps the normal equations
/// definite on segments no data point reaches). Dense Cholesky: loops have
/// at most a few hundred control points.
fn solve(m: usize, data: &[(DVec3, f64)], fair: f64) -> Option<Vec<DVec3>> {
    let mut a = vec![0.0; m * m];
    let mut b = vec![DVec3::ZERO; m];
    for &(q, u) in data {
        let w = weights(u, m);
        for &(i, wi) in &w {
            b[i] += wi * q;
            for &(j, wj) in &w {
                a[i * m + j] += wi * wj;
            }
        }
    }
    for i in 0..m {
        let r = [((i + m - 1) % m, 1.0), (i, -2.0), ((i + 1) % m, 1.0)];
        for &(p, wp) in &r {
            for &(q, wq) in &r {
                a[p * m + q] += fair * wp * wq;
            }
        }
    }
    crate::solve::dense_cholesky_solve(a, m, b)
}

/// Parameter of the point of the curve closest to `q`: the best of 16
/// samples per segment, refined by golden-section search in its bracket.
fn foot(p: &[DVec3], q: DVec3) -> f64 {
    let m = p.len();
    const S: usize = 16;
    let h = 1.0 / S as f64;
    let d2 = |u: f64| (eval(p, u) - q).length_squared();
    let mut best = (f64::INFINITY, 0.0);
    for k in 0..m * S {
        let u = k as f64 * h;
        let d = d2(u);
        if d < best.0 {
            best = (d, u);
        }
    }
    golden_section(best.1 - h, best.1 + h, d2).rem_euclid(m as f64)
}

fn rms_to_curve(p: &[DVec3], data: &[(DVec3, f64)]) -> f64 {
    let s: f64 = data
        .iter()
        .map(|&(q, _)| (eval(p, foot(p, q)) - q).length_squared())
        .sum();
    (s / data.len().max(1) as f64).sqrt()
}

/// Second-difference fairness weight, relative to one data point's.
const FAIR: f64 = 1e-3;
/// Foot-point parameter-correction rounds (the curve RMS settles in 5–8).
const ROUNDS: usize = 10;
/// Smallest closed loop fitted. A closed uniform cubic B-spline of three
/// control points is a planar oval fixed up to an affine map, and four
/// leave little more: forcing such a curve onto a rim moves its few control
/// points far and distorts the large border patches more than the overhang
/// it removes (the displaced error grew, docs/status.md, "Measurements
/// behind the code"). Those loops keep the surface fit's closest-point rim
/// rows only.
const MIN_LOOP: usize = 5;
/// Largest loop fitted (dense normal equations: m² memory, m³/3 flops).
const MAX_LOOP: usize = 1500;

/// Data points on the rim with their curve parameters.
type Samples = Vec<(DVec3, f64)>;

/// Fits one closed control loop (positions `p`) to one rim polyline;
/// returns the new control points and the (before, after) rim → curve RMS,
/// or `None` when the fit does not improve on the current curve.
fn fit_loop(p: &[DVec3], rim: &[DVec3]) -> Option<(Vec<DVec3>, f64, f64)> {
    let m = p.len();
    if !(MIN_LOOP..=MAX_LOOP).contains(&m) || rim.len() < 3 {
        return None;
    }
    let n = (8 * m).max(2 * rim.len());
    let data = resample(rim, n);
    let before = rms_to_curve(p, &data);
    // Initial parameters: arc length, both orientations, phases in quarter
    // segments. On a roundish rim every phase fits about equally well, and
    // the phase decides where along the rim each control point goes: a
    // wrong one turns the loop against its inner neighbours and twists
    // the border strip of patches over the hole. So among the fits within
    // 1.5× of the best residual (plus a hair for exact ties), the one that
    // moves the control points least wins.
    let mut cands: Vec<(f64, f64, Vec<DVec3>, Samples)> = Vec::new();
    for dir in [1.0, -1.0] {
        for phase in 0..4 * m {
            let off = phase as f64 / 4.0;
            let d: Vec<(DVec3, f64)> = data
                .iter()
                .map(|&(q, s)| (q, (off + dir * s * m as f64).rem_euclid(m as f64)))
                .collect();
            let Some(c) = solve(m, &d, FAIR) else {
                continue;
            };
            let r: f64 = d
                .iter()
                .map(|&(q, u)| (eval(&c, u) - q).length_squared())
                .sum();
            let moved: f64 = c
                .iter()
                .zip(p)
                .map(|(a, b)| (*a - *b).length_squared())
                .sum();
            cands.push((r, moved, c, d));
        }
    }
    let rmin = cands.iter().map(|c| c.0).fold(f64::INFINITY, f64::min);
    let (_, _, mut c, mut d) = cands
        .into_iter()
        .filter(|c| c.0 <= 2.25 * rmin + 1e-12 * (1.0 + rmin))
        .min_by(|a, b| a.1.total_cmp(&b.1))?;
    for _ in 0..ROUNDS {
        for x in d.iter_mut() {
            x.1 = foot(&c, x.0);
        }
        c = solve(m, &d, FAIR)?;
    }
    let after = rms_to_curve(&c, &data);
    (after < before && c.iter().all(|x| x.is_finite())).then_some((c, before, after))
}

/// Control-point weights of an open chain `P_0 … P_q` whose ends are
/// corners, at `u ∈ [0, q]`: the boundary rule with a corner is the cubic
/// B-spline with the phantom points `P_{−1} = 2P_0 − P_1` and `P_{q+1} =
/// 2P_q − P_{q−1}` (the corner is interpolated).
fn chain_weights(u: f64, q: usize) -> Vec<(usize, f64)> {
    let i = (u.floor().max(0.0) as usize).min(q - 1);
    let b = basis((u - i as f64).clamp(0.0, 1.0));
    let mut out = Vec::with_capacity(6);
    for (k, &w) in b.iter().enumerate() {
        let j = i as isize - 1 + k as isize;
        if j < 0 {
            out.push((0, 2.0 * w));
            out.push((1, -w));
        } else if j as usize > q {
            out.push((q, 2.0 * w));
            out.push((q - 1, -w));
        } else {
            out.push((j as usize, w));
        }
    }
    out
}

fn eval_chain(p: &[DVec3], u: f64) -> DVec3 {
    chain_weights(u, p.len() - 1)
        .iter()
        .fold(DVec3::ZERO, |a, &(j, w)| a + w * p[j])
}

/// Parameter of the point of the chain closest to `q` (as [`foot`]).
fn foot_chain(p: &[DVec3], q: DVec3) -> f64 {
    let n = p.len() - 1;
    const S: usize = 16;
    let h = 1.0 / S as f64;
    let d2 = |u: f64| (eval_chain(p, u) - q).length_squared();
    let mut best = (f64::INFINITY, 0.0);
    for k in 0..=n * S {
        let u = k as f64 * h;
        let d = d2(u);
        if d < best.0 {
            best = (d, u);
        }
    }
    golden_section((best.1 - h).max(0.0), (best.1 + h).min(n as f64), d2)
}

/// Least-squares interior points `P_1 … P_{q−1}` of a chain with fixed
/// corner ends, for data points with parameters (second-difference
/// fairness `FAIR` on the chain, phantom-free).
fn solve_chain(p: &[DVec3], data: &[(DVec3, f64)]) -> Option<Vec<DVec3>> {
    let q = p.len() - 1;
    let n = q - 1; // unknowns: P_1 … P_{q−1} at 0 … n−1
    let mut a = vec![0.0; n * n];
    let mut b = vec![DVec3::ZERO; n];
    let mut add = |row: &[(usize, f64)], target: DVec3, scale: f64| {
        let mut rhs = target;
        for &(j, w) in row {
            if j == 0 || j == q {
                rhs -= w * p[j];
            }
        }
        for &(i, wi) in row {
            if i == 0 || i == q {
                continue;
            }
            b[i - 1] += scale * wi * rhs;
            for &(j, wj) in row {
                if j != 0 && j != q {
                    a[(i - 1) * n + (j - 1)] += scale * wi * wj;
                }
            }
        }
    };
    for &(x, u) in data {
        add(&chain_weights(u, q), x, 1.0);
    }
    for i in 1..q {
        add(&[(i - 1, 1.0), (i, -2.0), (i + 1, 1.0)], DVec3::ZERO, FAIR);
    }
    crate::solve::dense_cholesky_solve(a, n, b)
}

/// Arc-length parametrisation of a closed polyline.
struct ArcLength<'a> {
    pts: &'a [DVec3],
    cum: Vec<f64>,
    total: f64,
}

impl<'a> ArcLength<'a> {
    fn new(pts: &'a [DVec3]) -> Self {
        let k = pts.len();
        let mut cum = Vec::with_capacity(k + 1);
        let mut acc = 0.0;
        for i in 0..k {
            cum.push(acc);
            acc += (pts[(i + 1) % k] - pts[i]).length();
        }
        cum.push(acc);
        ArcLength {
            pts,
            cum,
            total: acc,
        }
    }
    fn at(&self, s: f64) -> DVec3 {
        let k = self.pts.len();
        let s = s.rem_euclid(self.total.max(f64::MIN_POSITIVE));
        let i = self
            .cum
            .partition_point(|&c| c <= s)
            .saturating_sub(1)
            .min(k - 1);
        let len = self.cum[i + 1] - self.cum[i];
        let t = if len > 0.0 {
            (s - self.cum[i]) / len
        } else {
            0.0
        };
        self.pts[i] + t * (self.pts[(i + 1) % k] - self.pts[i])
    }
    /// Closest point and its arc-length position.
    fn closest(&self, q: DVec3) -> (DVec3, f64) {
        let k = self.pts.len();
        let mut best = (f64::INFINITY, DVec3::ZERO, 0.0);
        for i in 0..k {
            let (a, b) = (self.pts[i], self.pts[(i + 1) % k]);
            let ab = b - a;
            let l2 = ab.length_squared();
            let t = if l2 > 0.0 {
                ((q - a).dot(ab) / l2).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let x = a + t * ab;
            let d = (x - q).length_squared();
            if d < best.0 {
                best = (d, x, self.cum[i] + t * (self.cum[i + 1] - self.cum[i]));
            }
        }
        (best.1, best.2)
    }
}

/// Fits a loop with corner vertices (`corners`: their indices in `p`, in
/// loop order): each corner goes to its closest rim point (the limit
/// border interpolates it), and each chain between consecutive corners is
/// fitted to the stretch of rim between their positions, with fixed ends.
fn fit_loop_with_corners(
    p: &[DVec3],
    corners: &[usize],
    rim: &[DVec3],
) -> Option<(Vec<DVec3>, f64, f64)> {
    let m = p.len();
    if !(3..=MAX_LOOP).contains(&m) || rim.len() < 3 || corners.is_empty() {
        return None;
    }
    let arc = ArcLength::new(rim);
    if arc.total.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
        return None;
    }
    let proj: Vec<(DVec3, f64)> = corners.iter().map(|&c| arc.closest(p[c])).collect();
    let k = corners.len();
    // Orientation: the corners' rim positions must go once around the rim
    // in loop order, one way or the other.
    let gaps = |dir: f64| -> Vec<f64> {
        (0..k)
            .map(|i| {
                let g = (dir * (proj[(i + 1) % k].1 - proj[i].1)).rem_euclid(arc.total);
                if k == 1 || g == 0.0 {
                    arc.total
                } else {
                    g
                }
            })
            .collect()
    };
    let winds = |g: &[f64]| (g.iter().sum::<f64>() - arc.total).abs() < 1e-9 * arc.total;
    let dirs: Vec<f64> = [1.0, -1.0]
        .into_iter()
        .filter(|&d| winds(&gaps(d)))
        .collect();
    let mut best: Option<(f64, Vec<DVec3>, Samples)> = None;
    for dir in dirs {
        let g = gaps(dir);
        let mut c = p.to_vec();
        for (i, &ci) in corners.iter().enumerate() {
            c[ci] = proj[i].0;
        }
        let mut samples = Vec::new();
        let mut ok = true;
        for i in 0..k {
            let (ca, cb) = (corners[i], corners[(i + 1) % k]);
            let q = if cb > ca { cb - ca } else { cb + m - ca };
            let idx: Vec<usize> = (0..=q).map(|j| (ca + j) % m).collect();
            let n = ((2.0 * rim.len() as f64 * g[i] / arc.total).ceil() as usize).max(8 * q);
            let data: Vec<(DVec3, f64)> = (0..n)
                .map(|j| {
                    let f = (j as f64 + 0.5) / n as f64;
                    (arc.at(proj[i].1 + dir * f * g[i]), f * q as f64)
                })
                .collect();
            samples.extend(data.iter().map(|x| x.0));
            if q < 2 {
                continue;
            }
            let mut chain: Vec<DVec3> = idx.iter().map(|&j| c[j]).collect();
            let mut d = data;
            let Some(x) = solve_chain(&chain, &d) else {
                ok = false;
                break;
            };
            chain[1..q].copy_from_slice(&x);
            for _ in 0..ROUNDS {
                for y in d.iter_mut() {
                    y.1 = foot_chain(&chain, y.0);
                }
                let Some(x) = solve_chain(&chain, &d) else {
                    ok = false;
                    break;
                };
                chain[1..q].copy_from_slice(&x);
            }
            for (j, &v) in idx.iter().enumerate() {
                c[v] = chain[j];
            }
        }
        if !ok {
            continue;
        }
        let moved: f64 = c
            .iter()
            .zip(p)
            .map(|(a, b)| (*a - *b).length_squared())
            .sum();
        let data: Vec<(DVec3, f64)> = samples.into_iter().map(|x| (x, 0.0)).collect();
        if best.as_ref().map_or(true, |b| moved < b.0) {
            best = Some((moved, c, data));
        }
    }
    let (_, c, data) = best?;
    let rms = |pts: &[DVec3]| -> f64 {
        // Distance to the union of the chains' curves.
        let mut chains = Vec::new();
        for i in 0..k {
            let (ca, cb) = (corners[i], corners[(i + 1) % k]);
            let q = if cb > ca { cb - ca } else { cb + m - ca };
            chains.push((0..=q).map(|j| pts[(ca + j) % m]).collect::<Vec<_>>());
        }
        let s: f64 = data
            .iter()
            .map(|&(x, _)| {
                chains
                    .iter()
                    .map(|ch| (eval_chain(ch, foot_chain(ch, x)) - x).length_squared())
                    .fold(f64::INFINITY, f64::min)
            })
            .sum();
        (s / data.len().max(1) as f64).sqrt()
    };
    let (before, after) = (rms(p), rms(&c));
    (after < before && c.iter().all(|x| x.is_finite())).then_some((c, before, after))
}

/// Fits every boundary loop of `control` that follows one rim loop of
/// `mesh` (matched by the rim nearest to most of its control points, one
/// control loop per rim). A corner (tagged, or a boundary vertex of one
/// face, which the "edge and corner" rule sharpens) makes the limit border
/// interpolate it: loops with corners are fitted chain by chain
/// ([`fit_loop_with_corners`]), the others as closed curves ([`fit_loop`]).
/// `rim` is [`TriMesh::boundary_edge_masks`] of `mesh`.
pub(crate) fn fit_rims(mesh: &TriMesh, rim: &[u8], control: &ControlMesh) -> RimFit {
    let mut out = RimFit::default();
    let Some(rims) = rim_loops(mesh, rim) else {
        return out;
    };
    if rims.is_empty() {
        return out;
    }
    let loops = control_loops(control);
    let pos = control.positions();
    // Which rim each control loop follows (majority of its vertices'
    // nearest rim points).
    let nearest_rim = |q: DVec3| -> usize {
        let mut best = (f64::INFINITY, 0);
        for (r, rim) in rims.iter().enumerate() {
            for &x in rim {
                let d = (x - q).length_squared();
                if d < best.0 {
                    best = (d, r);
                }
            }
        }
        best.1
    };
    let matched: Vec<Option<usize>> = loops
        .iter()
        .map(|l| {
            let mut votes = vec![0usize; rims.len()];
            for &v in l {
                votes[nearest_rim(pos[v.idx()])] += 1;
            }
            let (r, &c) = votes
                .iter()
                .enumerate()
                .max_by_key(|&(i, c)| (*c, usize::MAX - i))?;
            (2 * c > l.len()).then_some(r)
        })
        .collect();
    for (li, l) in loops.iter().enumerate() {
        let Some(r) = matched[li] else { continue };
        if matched.iter().filter(|&&x| x == Some(r)).count() != 1 {
            continue;
        }
        let corners: Vec<usize> = (0..l.len())
            .filter(|&i| {
                let v = l[i];
                control.vertex_sharpness(v) > 0.0 || control.vertex_faces(v).count() < 2
            })
            .collect();
        let p: Vec<DVec3> = l.iter().map(|v| pos[v.idx()]).collect();
        let fitted = if corners.is_empty() {
            fit_loop(&p, &rims[r])
        } else {
            fit_loop_with_corners(&p, &corners, &rims[r])
        };
        if let Some((c, before, after)) = fitted {
            out.moved.extend(l.iter().copied().zip(c));
            out.loops.push((before, after));
        }
    }
    out.moved.sort_by_key(|(v, _)| v.0);
    out
}

/// Minimum of `f` in `[lo, hi]` by 30 golden-section steps (the bracket
/// shrinks to 0.618³⁰ ≈ 5e-7 of its width, far below a sample spacing):
/// the foot-point refinement of both loop fitters, from the best of their
/// coarse samples.
fn golden_section(mut lo: f64, mut hi: f64, f: impl Fn(f64) -> f64) -> f64 {
    let g = 0.5 * (5f64.sqrt() - 1.0);
    for _ in 0..30 {
        let (x1, x2) = (hi - g * (hi - lo), lo + g * (hi - lo));
        if f(x1) < f(x2) {
            hi = x2;
        } else {
            lo = x1;
        }
    }
    0.5 * (lo + hi)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A circle of radius 1 sampled at `n` points.
    fn circle(n: usize, r: f64) -> Vec<DVec3> {
        (0..n)
            .map(|i| {
                let a = std::f64::consts::TAU * i as f64 / n as f64;
                DVec3::new(r * a.cos(), r * a.sin(), 0.0)
            })
            .collect()
    }

    #[test]
    fn collapsed_loop_is_spread_over_its_rim() {
        // Twelve control points bunched on a quarter of the unit circle:
        // their curve covers a quarter of the rim. The fit must cover all
        // of it: a 12-point closed cubic B-spline approximates a circle to
        // well under 1 % of its radius (the chord error of a 30° span is
        // 3.4 %, the B-spline's far less after least squares).
        let rim = circle(120, 1.0);
        let p: Vec<DVec3> = (0..12)
            .map(|i| {
                let a = std::f64::consts::FRAC_PI_2 * i as f64 / 12.0;
                DVec3::new(a.cos(), a.sin(), 0.0)
            })
            .collect();
        let (c, before, after) = fit_loop(&p, &rim).expect("the fit improves");
        assert!(before > 0.3, "before {before}");
        assert!(after < 5e-3, "after {after}");
        // Coverage both ways: every rim point is near the curve and every
        // curve point is near the unit circle.
        for k in 0..12 * 16 {
            let q = eval(&c, k as f64 / 16.0);
            assert!(
                (q.length() - 1.0).abs() < 1e-2,
                "curve point off the rim: {q}"
            );
        }
    }
}
