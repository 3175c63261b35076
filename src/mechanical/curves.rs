//! Boundary curves (Lavoué et al. §5): the network of region boundaries cut
//! into pieces between *corners*, each piece approximated by a subdivision
//! curve with as few control points as the tolerance allows.
//!
//! The curve rule is the sharp-edge rule of Hoppe et al. (eq. 1): new
//! points at edge midpoints, old points `P' = (P₋ + 6P + P₊)/8`, and the
//! corner rule `P' = P` (eq. 2) at the ends. Its limit is the uniform cubic
//! B-spline of the control polygon, with phantom points `2P₀ − P₁` at
//! corner ends (the point that makes the 1-6-1 mask fix `P₀`), and the
//! periodic B-spline on a closed piece without corners. This is exactly the
//! limit of a Catmull-Clark crease, so a piece fitted here is the crease
//! curve of the output surface once its control points are joined by
//! infinitely sharp edges and its ends tagged as corners.
//!
//! Fitting (the active-curve approach of Pottmann–Leopoldseder / Lavoué,
//! Dupont & Baskurt 2005b): start from the fewest control points (two for
//! an open piece: the corners; four for a closed one), fit with
//! chord-length parameters, then alternate foot points of the polyline's
//! samples on the curve with the tangent-distance step (the curve may
//! slide along the polyline) under Lawson's minimax reweighting (the
//! tolerance bounds the *largest* distance), and while the largest
//! distance still exceeds the tolerance add one control point and refit
//! ([`fit_feature`] / [`fit_samples_until`], used by
//! [`super::build_control`]). The distance measured is the one the
//! features-kept bar measures: from points *along* the polyline (vertices
//! and chord points) to the curve, through foot points, not through a
//! parameter correspondence. Against least squares on the polyline
//! vertices with parameter correction (the fitter this crate used first)
//! this reaches the same tolerance with fewer points (figures in
//! docs/status.md, "Measurements behind the code").

use crate::DVec3;

/// A boundary piece: a polyline of M's vertices between two corners (open)
/// or a corner-free loop (closed, first vertex not repeated).
#[derive(Clone, Debug)]
pub struct Piece {
    pub verts: Vec<u32>,
    pub closed: bool,
    /// The regions on either side (`u32::MAX`: outside M, an open boundary).
    pub regions: [u32; 2],
}

/// A fitted subdivision curve.
#[derive(Clone, Debug)]
pub struct Curve {
    /// Control points; on an open curve the first and last are the corners.
    pub control: Vec<DVec3>,
    pub closed: bool,
    /// Curve parameter of each polyline vertex (non-decreasing on open
    /// curves), in `[0, n−1]` (open) or `[0, n)` (closed).
    pub params: Vec<f64>,
    /// Largest distance from the polyline (its vertices and chord points,
    /// see [`fit_samples_until`]) to the curve.
    pub max_error: f64,
}

/// Basis of the uniform cubic B-spline on one segment.
fn basis(u: f64) -> [f64; 4] {
    let u2 = u * u;
    let u3 = u2 * u;
    [
        (1.0 - u).powi(3) / 6.0,
        (3.0 * u3 - 6.0 * u2 + 4.0) / 6.0,
        (-3.0 * u3 + 3.0 * u2 + 3.0 * u + 1.0) / 6.0,
        u3 / 6.0,
    ]
}

fn dbasis(u: f64) -> [f64; 4] {
    let u2 = u * u;
    [
        -0.5 * (1.0 - u).powi(2),
        (9.0 * u2 - 12.0 * u) / 6.0,
        (-9.0 * u2 + 6.0 * u + 3.0) / 6.0,
        0.5 * u2,
    ]
}

/// Weights of `C(t)` (or `C'(t)` with `derivative`) over the control
/// points, phantoms folded in: up to 6 `(index, weight)` pairs.
pub fn weights(n: usize, closed: bool, t: f64, derivative: bool) -> Vec<(usize, f64)> {
    let segs = if closed { n } else { n - 1 };
    let t = if closed {
        t.rem_euclid(n as f64)
    } else {
        t.clamp(0.0, segs as f64)
    };
    let s = (t.floor() as usize).min(segs - 1);
    let u = t - s as f64;
    let b = if derivative { dbasis(u) } else { basis(u) };
    let mut out: Vec<(usize, f64)> = Vec::with_capacity(6);
    let mut add = |i: usize, w: f64| match out.iter_mut().find(|p| p.0 == i) {
        Some(p) => p.1 += w,
        None => out.push((i, w)),
    };
    for (k, &w) in b.iter().enumerate() {
        let j = s as i64 + k as i64 - 1;
        if closed {
            add(j.rem_euclid(n as i64) as usize, w);
        } else if j < 0 {
            add(0, 2.0 * w);
            add(1, -w);
        } else if j as usize >= n {
            add(n - 1, 2.0 * w);
            add(n - 2, -w);
        } else {
            add(j as usize, w);
        }
    }
    out
}

pub fn eval(control: &[DVec3], closed: bool, t: f64) -> DVec3 {
    weights(control.len(), closed, t, false)
        .into_iter()
        .map(|(i, w)| w * control[i])
        .sum()
}

fn eval_d(control: &[DVec3], closed: bool, t: f64) -> DVec3 {
    weights(control.len(), closed, t, true)
        .into_iter()
        .map(|(i, w)| w * control[i])
        .sum()
}

/// Chord-length parameters scaled to the curve's parameter range.
fn chord_params(points: &[DVec3], n: usize, closed: bool) -> Vec<f64> {
    let m = points.len();
    let mut acc = vec![0.0; m];
    for i in 1..m {
        acc[i] = acc[i - 1] + (points[i] - points[i - 1]).length();
    }
    let total = if closed {
        acc[m - 1] + (points[0] - points[m - 1]).length()
    } else {
        acc[m - 1]
    };
    let range = if closed { n as f64 } else { (n - 1) as f64 };
    if total <= 0.0 {
        return (0..m).map(|i| range * i as f64 / m.max(2) as f64).collect();
    }
    acc.iter().map(|a| range * a / total).collect()
}

/// Fallback: control points sampled on the polyline.
fn linear(points: &[DVec3], n: usize, closed: bool) -> Vec<DVec3> {
    let m = points.len();
    let den = if closed { n } else { n - 1 }.max(1);
    (0..n)
        .map(|i| {
            let k = (i * (if closed { m } else { m - 1 })) / den;
            points[k.min(m - 1)]
        })
        .collect()
}

/// Samples per polyline edge for [`fit_feature`]: its vertices and the
/// points at ¼, ½ and ¾ of each edge, which is where the features-kept
/// measure (issue 6) looks — a crease must lie near the whole feature
/// line, not only near its vertices.
pub const FEATURE_SAMPLES_PER_EDGE: usize = 4;

/// Weight of the control polygon's fairness in [`fit_feature`], relative
/// to the mean data term.
const FEATURE_FAIRNESS: f64 = 1e-3;

/// Geometry iterations per control-point count in [`fit_feature`] at most.
const FEATURE_ITERATIONS: usize = 30;

/// Points at `k` even steps along every edge of the polyline (and its last
/// vertex when open): sample `j·k` is vertex `j`.
pub fn densify(points: &[DVec3], closed: bool, k: usize) -> Vec<DVec3> {
    let m = points.len();
    let segs = if closed { m } else { m.saturating_sub(1) };
    let mut out = Vec::with_capacity(segs * k + 1);
    for s in 0..segs {
        let (a, b) = (points[s], points[(s + 1) % m]);
        for i in 0..k {
            out.push(a + (b - a) * (i as f64 / k as f64));
        }
    }
    if !closed || segs == 0 {
        out.push(points[m - 1]);
    }
    out
}

/// Newton steps for the foot point of `p` on the curve from parameter `t`.
fn newton_foot(control: &[DVec3], closed: bool, p: DVec3, t: &mut f64) {
    let n = control.len();
    let (lo, hi) = if closed {
        (f64::NEG_INFINITY, f64::INFINITY)
    } else {
        (0.0, (n - 1) as f64)
    };
    for _ in 0..6 {
        let d = eval_d(control, closed, *t);
        let dd = d.length_squared();
        if dd <= 0.0 {
            break;
        }
        let step = (eval(control, closed, *t) - p).dot(d) / dd;
        *t = (*t - step.clamp(-0.5, 0.5)).clamp(lo, hi);
        if step.abs() < 1e-12 {
            break;
        }
    }
}

/// The foot point of `p` on the whole curve (a search over 16 points per
/// control segment, then Newton): `(parameter, distance)`.
pub fn foot_point(control: &[DVec3], closed: bool, p: DVec3) -> (f64, f64) {
    let n = control.len();
    let segs = if closed { n } else { n - 1 };
    let mut best = (0.0, f64::INFINITY);
    for i in 0..=16 * segs {
        let t = i as f64 / 16.0;
        let d = (eval(control, closed, t) - p).length_squared();
        if d < best.1 {
            best = (t, d);
        }
    }
    let mut t = best.0;
    newton_foot(control, closed, p, &mut t);
    (t, (eval(control, closed, t) - p).length())
}

/// Control points minimising `Σ w_j |A_j (C(t_j) − p_j)|²` with
/// `A_j = I − (1 − λ) T_j T_jᵀ`: the squared distance along the normal
/// plane of the curve at the foot point in full and the tangential
/// residual damped by `λ` (the tangent-distance minimisation of Wang,
/// Pottmann & Liu 2006, "Fitting B-spline curves to point clouds by
/// curvature-based squared distance minimization", §4, with a small
/// tangential term for stability; `λ = 1` is the point distance). Ends of
/// an open curve stay fixed. `None` if the system is singular.
fn solve_tdm(
    samples: &[DVec3],
    params: &[f64],
    tangents: &[DVec3],
    wts: &[f64],
    control: &[DVec3],
    closed: bool,
    lambda: f64,
) -> Option<Vec<DVec3>> {
    let n = control.len();
    let col = |i: usize| free_column(i, n, closed);
    let nf = if closed { n } else { n - 2 };
    if nf == 0 {
        return Some(control.to_vec());
    }
    let dim = 3 * nf;
    let mut a = vec![0.0; dim * dim];
    let mut b = vec![0.0; dim];
    // AᵀA = I − (1 − λ²) T Tᵀ.
    let f = 1.0 - lambda * lambda;
    for (j, &p) in samples.iter().enumerate() {
        let ws = weights(n, closed, params[j], false);
        let tv = tangents[j].to_array();
        let mut m = [[0.0; 3]; 3];
        for (r, row) in m.iter_mut().enumerate() {
            for (s, x) in row.iter_mut().enumerate() {
                *x = f64::from(u8::from(r == s)) - f * tv[r] * tv[s];
            }
        }
        let mut rhs = p;
        for &(i, x) in &ws {
            if col(i).is_none() {
                rhs -= x * control[i];
            }
        }
        let rv = rhs.to_array();
        let mr: [f64; 3] = std::array::from_fn(|r| (0..3).map(|s| m[r][s] * rv[s]).sum());
        for &(i, xi) in &ws {
            let Some(ci) = col(i) else { continue };
            for r in 0..3 {
                b[3 * ci + r] += wts[j] * xi * mr[r];
            }
            for &(k, xk) in &ws {
                let Some(ck) = col(k) else { continue };
                let w = wts[j] * xi * xk;
                for r in 0..3 {
                    for s in 0..3 {
                        a[(3 * ci + r) * dim + 3 * ck + s] += w * m[r][s];
                    }
                }
            }
        }
    }
    // The same tiny ridge as `solve`: a control point no sample reaches
    // stays determined.
    let trace = (0..dim).map(|i| a[i * dim + i]).sum::<f64>() / dim as f64;
    for i in 0..dim {
        a[i * dim + i] += 1e-9 * trace.max(1e-300);
    }
    // Fairness of the control polygon: second differences, weighted
    // FEATURE_FAIRNESS of the mean data term. The tangent-distance step
    // leaves the control points free to slide along the curve; a little
    // fairness keeps them evenly spread (the polygon becomes facet edges
    // of §6), and it finds fits as small or smaller than without.
    let lam = FEATURE_FAIRNESS * trace.max(1e-300);
    for k in 1..n.saturating_sub(1) + usize::from(closed) * 2 {
        if lam <= 0.0 {
            break;
        }
        let idx = [((k + n - 1) % n, 1.0), (k % n, -2.0), ((k + 1) % n, 1.0)];
        let mut rhs = DVec3::ZERO;
        for &(i, w) in &idx {
            if col(i).is_none() {
                rhs -= w * control[i];
            }
        }
        let rv = rhs.to_array();
        for &(i, wi) in &idx {
            let Some(ci) = col(i) else { continue };
            for r in 0..3 {
                b[3 * ci + r] += lam * wi * rv[r];
            }
            for &(j, wj) in &idx {
                if let Some(cj) = col(j) {
                    for r in 0..3 {
                        a[(3 * ci + r) * dim + 3 * cj + r] += lam * wi * wj;
                    }
                }
            }
        }
    }
    let x = crate::solve::dense_cholesky_solve(a, dim, b)?;
    let mut out = control.to_vec();
    for (i, c) in out.iter_mut().enumerate() {
        if let Some(ci) = col(i) {
            *c = DVec3::new(x[3 * ci], x[3 * ci + 1], x[3 * ci + 2]);
        }
    }
    Some(out)
}

/// The curve with `n` control points whose largest ratio of distance to
/// tolerance over `samples` (`tol[j]` for sample `j`) is smallest, as far
/// as the iteration finds: `(control, params of the samples, largest
/// ratio)`. Starts from the point-distance fit with chord-length
/// parameters, then alternates foot points (Newton from the previous
/// parameters) with the tangent-distance step under Lawson's minimax
/// reweighting (weights times the ratios, from the fourth iteration on);
/// keeps the best iterate, and stops once every ratio is below 0.9 or the
/// largest has not improved by 1 % in 5 iterations.
fn fit_feature_n(
    samples: &[DVec3],
    tol: &[f64],
    closed: bool,
    n: usize,
) -> (Vec<DVec3>, Vec<f64>, f64) {
    let s = samples.len();
    let mut t = chord_params(samples, n, closed);
    let mut c = linear(samples, n, closed);
    let ones = vec![1.0; s];
    let no_tangent = vec![DVec3::ZERO; s];
    if let Some(x) = solve_tdm(samples, &t, &no_tangent, &ones, &c, closed, 1.0) {
        c = x;
    }
    let mut w = ones;
    let mut best = (c.clone(), t.clone(), f64::INFINITY);
    let mut last_gain = 0;
    for it in 0..FEATURE_ITERATIONS {
        // Newton from the previous parameters (the chord-length ones the
        // first fit was made with, at first): the curve moves little per
        // step, and the global search is left to the final check.
        for (tj, &q) in t.iter_mut().zip(samples) {
            newton_foot(&c, closed, q, tj);
        }
        let r: Vec<f64> = samples
            .iter()
            .zip(&t)
            .zip(tol)
            .map(|((&q, &tj), &e)| (eval(&c, closed, tj) - q).length() / e)
            .collect();
        let rmax = r.iter().copied().fold(0.0, f64::max);
        if rmax < best.2 {
            if rmax < 0.99 * best.2 {
                last_gain = it;
            }
            best = (c.clone(), t.clone(), rmax);
        }
        // (A NaN distance stops too.)
        if rmax.is_nan() || rmax <= 0.9 || it > last_gain + 4 {
            break;
        }
        if it >= 3 {
            let mut sum = 0.0;
            for (wj, rj) in w.iter_mut().zip(&r) {
                *wj *= (rj / rmax).max(1e-3);
                sum += *wj;
            }
            for wj in w.iter_mut() {
                *wj *= s as f64 / sum;
            }
        }
        // Tolerances scale the weights: a sample with twice the room
        // counts a quarter as much.
        let wt: Vec<f64> = w.iter().zip(tol).map(|(&wj, &e)| wj / (e * e)).collect();
        let tg: Vec<DVec3> = t
            .iter()
            .map(|&tj| eval_d(&c, closed, tj).normalize_or_zero())
            .collect();
        match solve_tdm(samples, &t, &tg, &wt, &c, closed, 0.1) {
            Some(x) => c = x,
            None => break,
        }
    }
    // The largest ratio measured from scratch (global foot points), so a
    // Newton step caught on the wrong branch cannot understate it; only
    // for a curve that seems to pass (a global foot is never farther than a
    // local one, so a rejection here at worst costs one control point).
    let (c, mut t, local) = best;
    if local > 1.0 {
        return (c, t, local);
    }
    let mut rmax = 0.0f64;
    for ((tj, &q), &e) in t.iter_mut().zip(samples).zip(tol) {
        let (ft, fd) = foot_point(&c, closed, q);
        *tj = ft;
        rmax = rmax.max(fd / e);
    }
    (c, t, rmax)
}

/// Fits a feature line (§5): the fewest control points (from `min_n`,
/// one at a time) whose curve passes within `tol` of every point of the
/// polyline — its vertices and [`FEATURE_SAMPLES_PER_EDGE`] points per
/// edge, measured as the distance to the curve (foot points), not to a
/// parameter correspondence; falls back to one control point per vertex.
///
/// Against a least-squares fit of the vertices with a parameter
/// correspondence (the fitter this one replaced) it reaches the same
/// tolerance with fewer points: the tangent-distance step lets the curve
/// slide along the polyline, and the minimax weights spend the error
/// budget evenly, so the count found is near the floor (with one point
/// fewer, most lines miss by a few per cent under 200 iterations).
pub fn fit_feature(points: &[DVec3], closed: bool, min_n: usize, tol: f64) -> Curve {
    let edges = if closed {
        points.len()
    } else {
        points.len().saturating_sub(1)
    };
    fit_samples_until(points, closed, min_n, &vec![tol; edges], &|_| true)
}

/// [`fit_feature`] with a tolerance per polyline edge (`edge_tol[k]` for
/// edge `k → k+1`; a vertex takes the smaller of its edges') and a further
/// condition `accept` on the curve (checked once the tolerances hold).
/// `Curve::max_error` is the largest distance over the samples.
pub fn fit_samples_until(
    points: &[DVec3],
    closed: bool,
    min_n: usize,
    edge_tol: &[f64],
    accept: &dyn Fn(&Curve) -> bool,
) -> Curve {
    let m = points.len();
    let k = FEATURE_SAMPLES_PER_EDGE;
    let samples = densify(points, closed, k);
    let segs = edge_tol.len();
    let tol: Vec<f64> = (0..samples.len())
        .map(|j| {
            let e = j / k;
            let here = edge_tol.get(e.min(segs.saturating_sub(1))).copied();
            let before = if j % k == 0 && (e > 0 || closed) {
                edge_tol.get((e + segs - 1) % segs.max(1)).copied()
            } else {
                None
            };
            match (here, before) {
                (Some(a), Some(b)) => a.min(b),
                (Some(a), None) | (None, Some(a)) => a,
                (None, None) => f64::INFINITY,
            }
            .max(f64::MIN_POSITIVE)
        })
        .collect();
    let lo = if closed { min_n.max(3) } else { min_n.max(2) };
    let cap = lo.max(m);
    let mut n = lo;
    loop {
        let (control, sp, ratio) = fit_feature_n(&samples, &tol, closed, n);
        let mut params: Vec<f64> = (0..m).map(|j| sp[(j * k).min(sp.len() - 1)]).collect();
        if closed {
            for t in params.iter_mut() {
                *t = t.rem_euclid(n as f64);
            }
        } else {
            params[0] = 0.0;
            params[m - 1] = (n - 1) as f64;
        }
        let max_error = samples
            .iter()
            .zip(&sp)
            .map(|(&q, &t)| (eval(&control, closed, t) - q).length())
            .fold(0.0, f64::max);
        let curve = Curve {
            control,
            closed,
            params,
            max_error,
        };
        if n >= cap || (ratio <= 1.0 && accept(&curve)) {
            return curve;
        }
        n += 1;
    }
}

/// Column of control point `i` among the unknowns of a curve solve: every
/// point of a closed curve, the inner points of an open one (its ends are
/// fixed on the corners, the 1-6-1 rule's end condition).
fn free_column(i: usize, n: usize, closed: bool) -> Option<usize> {
    if closed {
        Some(i)
    } else if i == 0 || i == n - 1 {
        None
    } else {
        Some(i - 1)
    }
}
