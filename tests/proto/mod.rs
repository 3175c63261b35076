//! Prototype feature-curve fitter (distance to the curve, minimax).
#![allow(dead_code)]

use subdfit::mechanical::curves::{eval, weights};
use subdfit::DVec3;

fn eval_d(c: &[DVec3], closed: bool, t: f64) -> DVec3 {
    weights(c.len(), closed, t, true)
        .into_iter()
        .map(|(i, w)| w * c[i])
        .sum()
}

/// Samples at 0, ¼, ½, ¾ of each polyline edge (and the last vertex).
pub fn densify(p: &[DVec3], closed: bool, k: usize) -> Vec<DVec3> {
    let m = p.len();
    let segs = if closed { m } else { m - 1 };
    let mut out = Vec::with_capacity(segs * k + 1);
    for s in 0..segs {
        let (a, b) = (p[s], p[(s + 1) % m]);
        for i in 0..k {
            out.push(a + (b - a) * (i as f64 / k as f64));
        }
    }
    if !closed {
        out.push(p[m - 1]);
    }
    out
}

fn chord(p: &[DVec3], n: usize, closed: bool) -> Vec<f64> {
    let m = p.len();
    let mut acc = vec![0.0; m];
    for i in 1..m {
        acc[i] = acc[i - 1] + (p[i] - p[i - 1]).length();
    }
    let total = if closed {
        acc[m - 1] + (p[0] - p[m - 1]).length()
    } else {
        acc[m - 1]
    };
    let range = if closed { n as f64 } else { (n - 1) as f64 };
    acc.iter().map(|a| range * a / total.max(1e-300)).collect()
}

fn newton(c: &[DVec3], closed: bool, p: DVec3, t: &mut f64) {
    let n = c.len();
    let hi = if closed { f64::INFINITY } else { (n - 1) as f64 };
    let lo = if closed { f64::NEG_INFINITY } else { 0.0 };
    for _ in 0..6 {
        let x = eval(c, closed, *t);
        let d = eval_d(c, closed, *t);
        let dd = d.length_squared();
        if dd <= 0.0 {
            break;
        }
        let step = (x - p).dot(d) / dd;
        *t = (*t - step.clamp(-0.5, 0.5)).clamp(lo, hi);
        if step.abs() < 1e-10 {
            break;
        }
    }
}

/// Global foot point: dense search then Newton.
fn foot(c: &[DVec3], closed: bool, p: DVec3) -> (f64, f64) {
    let n = c.len();
    let segs = if closed { n } else { n - 1 };
    let k = 16 * segs;
    let mut best = (0.0, f64::INFINITY);
    for i in 0..=k {
        let t = i as f64 / 16.0;
        let d = (eval(c, closed, t) - p).length_squared();
        if d < best.1 {
            best = (t, d);
        }
    }
    let mut t = best.0;
    newton(c, closed, p, &mut t);
    (t, (eval(c, closed, t) - p).length())
}

/// Largest distance from `samples` to the curve.
pub fn max_dist(c: &[DVec3], closed: bool, samples: &[DVec3]) -> f64 {
    samples
        .iter()
        .map(|&p| foot(c, closed, p).1)
        .fold(0.0, f64::max)
}

/// Solves `min Σ w_j |A_j (C(t_j) − p_j)|²` (A_j = I − (1−λ) T Tᵀ) over
/// the free control points (open: ends fixed).
fn solve_tdm(
    samples: &[DVec3],
    params: &[f64],
    tangents: &[DVec3],
    w: &[f64],
    control: &[DVec3],
    closed: bool,
    lam_t: f64,
) -> Option<Vec<DVec3>> {
    let n = control.len();
    let col = |i: usize| -> Option<usize> {
        if closed {
            Some(i)
        } else if i == 0 || i == n - 1 {
            None
        } else {
            Some(i - 1)
        }
    };
    let nf = if closed { n } else { n - 2 };
    if nf == 0 {
        return Some(control.to_vec());
    }
    let dim = 3 * nf;
    let mut a = vec![0.0; dim * dim];
    let mut b = vec![0.0; dim];
    for j in 0..samples.len() {
        let ws = weights(n, closed, params[j], false);
        let tg = tangents[j];
        // metric M = I − (1 − λ) T Tᵀ (symmetric, M² = I − (1 − λ²) T Tᵀ).
        let mut m = [[0.0; 3]; 3];
        let tv = [tg.x, tg.y, tg.z];
        let f = 1.0 - lam_t * lam_t;
        for r in 0..3 {
            for s in 0..3 {
                m[r][s] = if r == s { 1.0 } else { 0.0 } - f * tv[r] * tv[s];
            }
        }
        let mut fixed = DVec3::ZERO;
        for &(i, x) in &ws {
            if col(i).is_none() {
                fixed += x * control[i];
            }
        }
        let rhs = samples[j] - fixed;
        let rv = [rhs.x, rhs.y, rhs.z];
        for &(i, xi) in &ws {
            let Some(ci) = col(i) else { continue };
            for r in 0..3 {
                let mut mr = 0.0;
                for s in 0..3 {
                    mr += m[r][s] * rv[s];
                }
                b[3 * ci + r] += w[j] * xi * mr;
            }
            for &(k, xk) in &ws {
                let Some(ck) = col(k) else { continue };
                for r in 0..3 {
                    for s in 0..3 {
                        a[(3 * ci + r) * dim + 3 * ck + s] += w[j] * xi * xk * m[r][s];
                    }
                }
            }
        }
    }
    let tr: f64 = (0..dim).map(|i| a[i * dim + i]).sum::<f64>() / dim as f64;
    for i in 0..dim {
        a[i * dim + i] += 1e-9 * tr.max(1e-300);
    }
    // Cholesky.
    let nn = dim;
    for j in 0..nn {
        let mut d = a[j * nn + j];
        for k in 0..j {
            d -= a[j * nn + k] * a[j * nn + k];
        }
        if d <= 0.0 || !d.is_finite() {
            return None;
        }
        let d = d.sqrt();
        a[j * nn + j] = d;
        for i in j + 1..nn {
            let mut s = a[i * nn + j];
            for k in 0..j {
                s -= a[i * nn + k] * a[j * nn + k];
            }
            a[i * nn + j] = s / d;
        }
    }
    for i in 0..nn {
        let mut s = b[i];
        for k in 0..i {
            s -= a[i * nn + k] * b[k];
        }
        b[i] = s / a[i * nn + i];
    }
    for i in (0..nn).rev() {
        let mut s = b[i];
        for k in i + 1..nn {
            s -= a[k * nn + i] * b[k];
        }
        b[i] = s / a[i * nn + i];
    }
    let mut out = control.to_vec();
    for i in 0..n {
        if let Some(ci) = col(i) {
            out[i] = DVec3::new(b[3 * ci], b[3 * ci + 1], b[3 * ci + 2]);
        }
    }
    Some(out)
}

/// Fits `n` control points to the polyline `p` minimising the largest
/// distance of its samples to the curve; returns (control, max distance).
pub fn fit_n(p: &[DVec3], closed: bool, n: usize, iters: usize, tol: f64) -> (Vec<DVec3>, f64) {
    let s = densify(p, closed, 4);
    let mut t = chord(&s, n, closed);
    // Initial: point-distance LSQ with chord params (TDM with λ = 1).
    let mut c: Vec<DVec3> = (0..n)
        .map(|i| {
            let k = if closed {
                i * s.len() / n
            } else {
                (i * (s.len() - 1)) / (n - 1).max(1)
            };
            s[k.min(s.len() - 1)]
        })
        .collect();
    if !closed {
        c[0] = p[0];
        c[n - 1] = p[p.len() - 1];
    }
    let ones = vec![1.0; s.len()];
    let zero_t = vec![DVec3::ZERO; s.len()];
    if let Some(x) = solve_tdm(&s, &t, &zero_t, &ones, &c, closed, 1.0) {
        c = x;
    }
    let mut w = ones.clone();
    let mut best = (c.clone(), f64::INFINITY);
    let mut last_gain = 0;
    for it in 0..iters {
        // Foot points.
        if it == 0 {
            for (j, &q) in s.iter().enumerate() {
                t[j] = foot(&c, closed, q).0;
            }
        } else {
            for (j, &q) in s.iter().enumerate() {
                newton(&c, closed, q, &mut t[j]);
            }
        }
        let d: Vec<f64> = s
            .iter()
            .zip(&t)
            .map(|(&q, &tt)| (eval(&c, closed, tt) - q).length())
            .collect();
        let dmax = d.iter().copied().fold(0.0, f64::max);
        if dmax < best.1 {
            if dmax < 0.99 * best.1 {
                last_gain = it;
            }
            best = (c.clone(), dmax);
        }
        if dmax <= 0.0 || dmax <= 0.9 * tol || it > last_gain + 4 {
            break;
        }
        // Lawson after a few plain iterations.
        if it >= 3 {
            let mut sum = 0.0;
            for (wj, dj) in w.iter_mut().zip(&d) {
                *wj *= (dj / dmax).max(1e-3);
                sum += *wj;
            }
            for wj in w.iter_mut() {
                *wj *= s.len() as f64 / sum;
            }
        }
        let tg: Vec<DVec3> = t
            .iter()
            .map(|&tt| eval_d(&c, closed, tt).normalize_or_zero())
            .collect();
        match solve_tdm(&s, &t, &tg, &w, &c, closed, 0.1) {
            Some(x) => c = x,
            None => break,
        }
    }
    let md = max_dist(&best.0, closed, &s);
    (best.0, md)
}

/// Fewest control points (from `lo`) with max distance ≤ tol.
pub fn fit_min(p: &[DVec3], closed: bool, lo: usize, tol: f64, iters: usize) -> (usize, f64) {
    let m = p.len();
    let cap = m.max(lo);
    let mut n = lo;
    loop {
        let (_, d) = fit_n(p, closed, n, iters, tol);
        if d <= tol || n >= cap {
            return (n, d);
        }
        n += 1;
    }
}
