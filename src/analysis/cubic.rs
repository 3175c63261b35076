//! The cubic height function of Fitmaps §3.1.2: a neighbourhood expressed as
//! the graph `h = g(u, v)` over the tangent frame of its centre, fitted by
//! linear least squares with the 10 monomials of degree <= 3.

use crate::{DVec2, DVec3};

/// Number of coefficients of a bivariate cubic (Fitmaps §3.1.2).
pub const CUBIC_COEFFICIENTS: usize = 10;

/// An orthonormal frame `(t1, t2, n)` centred at `origin`.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct Frame {
    pub origin: DVec3,
    pub t1: DVec3,
    pub t2: DVec3,
    pub n: DVec3,
}

impl Frame {
    /// A frame with normal `n` (unit). The tangent directions are arbitrary:
    /// the space of cubics is closed under rotations of `(u, v)` (§3.1.2:
    /// cubics "are independent of the orientation of the local frame"), so
    /// the fit, its residual and its normals do not depend on the choice.
    pub fn from_normal(origin: DVec3, n: DVec3) -> Frame {
        // Cross with the axis least aligned with n: never near-parallel.
        let a = n.abs();
        let axis = if a.x <= a.y && a.x <= a.z {
            DVec3::X
        } else if a.y <= a.z {
            DVec3::Y
        } else {
            DVec3::Z
        };
        let t1 = n.cross(axis).normalize();
        let t2 = n.cross(t1);
        Frame { origin, t1, t2, n }
    }

    /// World point to local `(u, v, h)`.
    #[inline]
    pub fn to_local(&self, p: DVec3) -> DVec3 {
        let d = p - self.origin;
        DVec3::new(d.dot(self.t1), d.dot(self.t2), d.dot(self.n))
    }

    /// Local `(u, v, h)` to world point.
    #[inline]
    pub fn to_world(&self, l: DVec3) -> DVec3 {
        self.origin + l.x * self.t1 + l.y * self.t2 + l.z * self.n
    }

    /// Local direction to world direction.
    #[inline]
    pub fn dir_to_world(&self, l: DVec3) -> DVec3 {
        l.x * self.t1 + l.y * self.t2 + l.z * self.n
    }
}

/// `g(u, v) = scale * P(u / scale, v / scale)` with `P` a cubic in the
/// monomials `[1, x, y, x², xy, y², x³, x²y, xy², y³]`. Coordinates are
/// scaled by the neighbourhood radius so that the normal equations stay
/// well conditioned whatever the units of the mesh.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct Cubic {
    pub coef: [f64; CUBIC_COEFFICIENTS],
    pub scale: f64,
}

#[inline]
fn monomials(x: f64, y: f64) -> [f64; CUBIC_COEFFICIENTS] {
    [
        1.0,
        x,
        y,
        x * x,
        x * y,
        y * y,
        x * x * x,
        x * x * y,
        x * y * y,
        y * y * y,
    ]
}

impl Cubic {
    #[inline]
    pub fn eval(&self, u: f64, v: f64) -> f64 {
        let m = monomials(u / self.scale, v / self.scale);
        self.scale * m.iter().zip(&self.coef).map(|(a, b)| a * b).sum::<f64>()
    }

    /// `|q.z - eval(q.x, q.y)| <= eps`, the same answer bit for bit, mostly
    /// without `eval`'s two divisions (`u / scale`, `v / scale`): the
    /// M-test asks this of every sample it looks at (§3.1.3, a sample
    /// within `eps` of the cubic is reached without a line), and those
    /// divisions were a tenth of the Fitmap's verdict time (perf, bunny).
    ///
    /// `inv` is `1 / scale` as the caller computed it. The graph is first
    /// evaluated at `(q.x inv, q.y inv)`: each scaled coordinate is within
    /// a few units in the last place of the divided one, so every monomial
    /// of degree <= 3 moves by ~1e-15 of itself, and with both sums'
    /// rounding the two heights differ by well under `1e-14 (scale Σ|c_i
    /// m_i| + |q.z|)`. The answer is taken from this estimate only when
    /// it clears `eps` by a hundred times that bound (`NEAR_SLACK`);
    /// otherwise (or for a non-finite estimate: every comparison with NaN
    /// fails) `eval` itself decides.
    #[inline]
    pub fn near_height(&self, q: DVec3, inv: f64, eps: f64) -> bool {
        let m = monomials(q.x * inv, q.y * inv);
        let (mut g, mut mag) = (0.0f64, 0.0f64);
        for (a, b) in m.iter().zip(&self.coef) {
            let t = a * b;
            g += t;
            mag += t.abs();
        }
        let d = (q.z - self.scale * g).abs();
        let slack = NEAR_SLACK * (self.scale * mag + q.z.abs());
        if d + slack <= eps {
            return true;
        }
        if d - slack > eps {
            return false;
        }
        (q.z - self.eval(q.x, q.y)).abs() <= eps
    }

    /// `(dg/du, dg/dv)`; the scale cancels (g and u share it).
    #[inline]
    pub fn grad(&self, u: f64, v: f64) -> DVec2 {
        let (x, y) = (u / self.scale, v / self.scale);
        let c = &self.coef;
        DVec2::new(
            c[1] + 2.0 * c[3] * x
                + c[4] * y
                + 3.0 * c[6] * x * x
                + 2.0 * c[7] * x * y
                + c[8] * y * y,
            c[2] + c[4] * x
                + 2.0 * c[5] * y
                + c[7] * x * x
                + 2.0 * c[8] * x * y
                + 3.0 * c[9] * y * y,
        )
    }

    /// Second derivatives `(g_uu, g_uv, g_vv)`.
    #[inline]
    fn hessian(&self, u: f64, v: f64) -> (f64, f64, f64) {
        let (x, y) = (u / self.scale, v / self.scale);
        let c = &self.coef;
        let s = self.scale;
        (
            (2.0 * c[3] + 6.0 * c[6] * x + 2.0 * c[7] * y) / s,
            (c[4] + 2.0 * c[7] * x + 2.0 * c[8] * y) / s,
            (2.0 * c[5] + 2.0 * c[8] * x + 6.0 * c[9] * y) / s,
        )
    }

    /// Unit normal of the graph at `(u, v)` in local coordinates, computed
    /// analytically as §3.1.3 asks: `(-g_u, -g_v, 1) / |.|`.
    #[inline]
    pub fn normal(&self, u: f64, v: f64) -> DVec3 {
        let g = self.grad(u, v);
        DVec3::new(-g.x, -g.y, 1.0).normalize()
    }

    /// The point `(u, v)` of the graph closest to the local point `q`
    /// (Newton on the squared distance, started below `q`). At that point
    /// `q - graph(u, v)` is parallel to the graph's normal, so the normal
    /// line through it passes through `q`. Steps are clamped to `max_step`;
    /// the iteration stops after a few steps: the caller only needs a foot
    /// point good to a small fraction of the radius.
    pub fn foot_point(&self, q: DVec3, max_step: f64) -> DVec2 {
        let mut p = DVec2::new(q.x, q.y);
        for _ in 0..FOOT_POINT_ITERATIONS {
            let (next, done) = self.foot_point_step(p, q, max_step);
            p = next;
            if done {
                break;
            }
        }
        p
    }

    /// [`Cubic::foot_point`] of every point of `qs` into `out` (cleared),
    /// each the same value, bit for bit, as `foot_point(q, max_step)`.
    /// Newton's iterations are a chain of dependent divisions and square
    /// roots, so one foot point at a time leaves the CPU waiting on
    /// latencies; here [`FOOT_POINT_LANES`] independent points advance in
    /// lockstep (each lane runs the scalar step, stopping exactly where the
    /// scalar loop would), and their chains overlap.
    pub fn foot_points(&self, qs: &[DVec3], max_step: f64, out: &mut Vec<DVec2>) {
        const L: usize = FOOT_POINT_LANES;
        out.clear();
        out.reserve(qs.len());
        let mut chunks = qs.chunks_exact(L);
        for q in &mut chunks {
            out.extend_from_slice(&self.foot_point_lanes(std::array::from_fn(|l| q[l]), max_step));
        }
        let rest = chunks.remainder();
        if let Some(&last) = rest.last() {
            // The last partial group, padded with copies of its last point
            // (lanes are independent; the copies are dropped).
            let q = std::array::from_fn(|l| rest.get(l).copied().unwrap_or(last));
            out.extend_from_slice(&self.foot_point_lanes(q, max_step)[..rest.len()]);
        }
    }

    /// [`Cubic::foot_point`] of [`FOOT_POINT_LANES`] points in lockstep.
    #[allow(clippy::needless_range_loop)] // one lane index over three arrays
    #[inline(always)]
    fn foot_point_lanes(
        &self,
        q: [DVec3; FOOT_POINT_LANES],
        max_step: f64,
    ) -> [DVec2; FOOT_POINT_LANES] {
        let mut p = q.map(|q| DVec2::new(q.x, q.y));
        let mut live = [true; FOOT_POINT_LANES];
        for _ in 0..FOOT_POINT_ITERATIONS {
            for l in 0..FOOT_POINT_LANES {
                if live[l] {
                    let (next, done) = self.foot_point_step(p[l], q[l], max_step);
                    p[l] = next;
                    live[l] = !done;
                }
            }
            if !live.iter().any(|&a| a) {
                break;
            }
        }
        p
    }

    /// One Newton step of [`Cubic::foot_point`] from `p`: the new point and
    /// whether the iteration stops there (converged, or a non-finite step,
    /// which leaves `p` as it is).
    #[inline(always)]
    fn foot_point_step(&self, p: DVec2, q: DVec3, max_step: f64) -> (DVec2, bool) {
        let h = self.eval(p.x, p.y);
        let g = self.grad(p.x, p.y);
        let (huu, huv, hvv) = self.hessian(p.x, p.y);
        let dz = h - q.z;
        // Gradient and Hessian of 1/2 |(u, v, h) - q|^2.
        let f = DVec2::new(p.x - q.x + dz * g.x, p.y - q.y + dz * g.y);
        let a = 1.0 + g.x * g.x + dz * huu;
        let b = g.x * g.y + dz * huv;
        let d = 1.0 + g.y * g.y + dz * hvv;
        let det = a * d - b * b;
        let step = if det > 1e-12 && a > 0.0 {
            DVec2::new((d * f.x - b * f.y) / det, (a * f.y - b * f.x) / det)
        } else {
            // Not locally convex: fall back to Gauss-Newton.
            let (a, d) = (1.0 + g.x * g.x, 1.0 + g.y * g.y);
            let b = g.x * g.y;
            let det = a * d - b * b;
            DVec2::new((d * f.x - b * f.y) / det, (a * f.y - b * f.x) / det)
        };
        // 1e-9 of the radius: far below the grazing tolerance the
        // M-test compares distances with (a tenth of an edge).
        let tol = 1e-9 * self.scale;
        // The length is needed only near its two thresholds: a step clearly
        // inside (max_step, tol) is neither clamped nor the last, and the
        // square root (a divider operation on every Newton step's
        // dependency chain) is skipped. `len = √s2` correctly rounded is
        // monotone in s2, so s2 ≤ ½ max_step² gives len < max_step and
        // s2 > 2 tol² gives len > tol, whatever the rounding of the squared
        // bounds (relative 2⁻⁵², while the factors leave ~30 % of margin);
        // the bounds are used only when they are normal numbers (no
        // underflow), and a NaN s2 fails both and takes the full path.
        // The same decisions and values as always computing the length.
        let s2 = step.length_squared();
        let (hi2, lo2) = (0.5 * max_step * max_step, 2.0 * tol * tol);
        if s2 <= hi2 && s2 > lo2 && hi2.is_normal() && lo2.is_normal() {
            return (p - step, false);
        }
        let len = s2.sqrt();
        let step = if len > max_step {
            step * (max_step / len)
        } else {
            step
        };
        if !step.is_finite() {
            return (p, true);
        }
        (p - step, len <= tol)
    }
}

/// Relative margin of [`Cubic::near_height`]'s estimate: a hundred times
/// the largest difference between the height evaluated with `u · (1 /
/// scale)` and with `u / scale` (~1e-14 of the terms' magnitude, see
/// there), so an answer taken from the estimate is always `eval`'s.
const NEAR_SLACK: f64 = 1e-12;

/// The most Newton steps of [`Cubic::foot_point`].
const FOOT_POINT_ITERATIONS: usize = 8;

/// Foot points computed in lockstep by [`Cubic::foot_points`]: enough
/// independent chains to cover the latency of a division.
pub const FOOT_POINT_LANES: usize = 4;

/// Result of a least-squares cubic fit.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct CubicFit {
    pub cubic: Cubic,
    /// Weighted RMS residual `sqrt(Σ w (g - h)² / Σ w)`: the usual RMS, not
    /// the `1/n` outside the root printed in §3.1.2 (a known slip, see the
    /// seeds' README).
    pub rms: f64,
}

/// Fits `h = g(u, v)` to local points `pts` (weights `w`, all 1 when
/// `None`) by linear least squares (§3.1.2). `scale` > 0 is the
/// neighbourhood radius. Returns `None` when the system is rank deficient
/// (points on a line or a conic, too few points): such a neighbourhood has
/// no well-posed cubic and the caller skips it.
pub fn fit_cubic(pts: &[DVec3], w: Option<&[f64]>, scale: f64) -> Option<CubicFit> {
    if pts.len() < CUBIC_COEFFICIENTS || scale.is_nan() || scale <= 0.0 || !scale.is_finite() {
        return None;
    }
    // One copy per weighting: with unit weights the `1.0 *` products fold
    // away (the same values: multiplying by 1 is exact).
    match w {
        None => fit_cubic_weighted(pts, |_| 1.0, scale),
        Some(w) => fit_cubic_weighted(pts, |k| w[k], scale),
    }
}

/// One point of a fit: its monomials, weight and height, scaled.
#[derive(Copy, Clone)]
struct FitRow {
    m: [f64; CUBIC_COEFFICIENTS],
    w: f64,
    h: f64,
}

thread_local! {
    /// [`fit_cubic`]'s per-thread point rows (it runs tens of thousands
    /// of times per Fitmap inside rayon jobs).
    static FIT_ROWS: std::cell::RefCell<Vec<FitRow>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// Rows `$i` and `$j` of the lower triangle of the normal equations
/// (entries `$a`, `$b` = 0..=row, the only ones the Cholesky reads) and of
/// the right side: `Σ_k (w_k m_i) m_a` and `Σ_k (w_k m_i) h_k`, each summed
/// over the points in order, so every entry gets the same products added
/// in the same order as a single pass that updates the whole system per
/// point — the same system bit for bit. Why by rows: the whole system
/// (100 entries, 55 of them read) does not fit in registers, so the
/// per-point pass loaded and stored every entry once per point (the
/// accumulation was ~7 % of the Fitmap's CPU time, perf on bunny); a pair
/// of rows (11 entries and 2 sums, `$i + $j = 9`) stays in registers over
/// the points, whose rows are read from L1. A macro with literal indices,
/// not a loop: a loop `0..=I` over a local array was compiled to a
/// counted loop over a stack array (a load and a store per entry again).
macro_rules! normal_rows {
    ($rows:expr, $ata:expr, $atb:expr,
     $i:literal: [$($a:literal),*], $j:literal: [$($b:literal),*]) => {{
        let (mut ai, mut aj) = ([0.0f64; CUBIC_COEFFICIENTS], [0.0f64; CUBIC_COEFFICIENTS]);
        let (mut bi, mut bj) = (0.0f64, 0.0f64);
        for r in $rows.iter() {
            let (wi, wj) = (r.w * r.m[$i], r.w * r.m[$j]);
            bi += wi * r.h;
            bj += wj * r.h;
            $(ai[$a] += wi * r.m[$a];)*
            $(aj[$b] += wj * r.m[$b];)*
        }
        $($ata[$i][$a] = ai[$a];)*
        $($ata[$j][$b] = aj[$b];)*
        $atb[$i] = bi;
        $atb[$j] = bj;
    }};
}

/// The normal equations of the fit in scaled coordinates (|x|, |y| <=
/// ~1): the lower triangle of `AᵀWA` (the upper one is left 0; the
/// Cholesky reads `j <= i` only) and `AᵀWh`. Each point's monomials,
/// weight and height are taken once, then the sums are made row by row
/// (`normal_rows!`), two rows per pass over the points.
#[inline(always)]
fn normal_equations(
    pts: &[DVec3],
    w: &impl Fn(usize) -> f64,
    inv: f64,
) -> (
    [[f64; CUBIC_COEFFICIENTS]; CUBIC_COEFFICIENTS],
    [f64; CUBIC_COEFFICIENTS],
) {
    let mut ata = [[0.0f64; CUBIC_COEFFICIENTS]; CUBIC_COEFFICIENTS];
    let mut atb = [0.0f64; CUBIC_COEFFICIENTS];
    // Taken out of the cell, not borrowed (as the Fitmap's other scratch).
    let mut rows = FIT_ROWS.with(|c| c.take());
    rows.clear();
    rows.extend(pts.iter().enumerate().map(|(k, p)| FitRow {
        m: monomials(p.x * inv, p.y * inv),
        w: w(k),
        h: p.z * inv,
    }));
    normal_rows!(rows, ata, atb, 0: [0], 9: [0, 1, 2, 3, 4, 5, 6, 7, 8, 9]);
    normal_rows!(rows, ata, atb, 1: [0, 1], 8: [0, 1, 2, 3, 4, 5, 6, 7, 8]);
    normal_rows!(rows, ata, atb, 2: [0, 1, 2], 7: [0, 1, 2, 3, 4, 5, 6, 7]);
    normal_rows!(rows, ata, atb, 3: [0, 1, 2, 3], 6: [0, 1, 2, 3, 4, 5, 6]);
    normal_rows!(rows, ata, atb, 4: [0, 1, 2, 3, 4], 5: [0, 1, 2, 3, 4, 5]);
    FIT_ROWS.with(|c| c.replace(rows));
    (ata, atb)
}

#[allow(clippy::needless_range_loop)] // index loops mirror the Cholesky formulas
#[inline(always)]
fn fit_cubic_weighted(pts: &[DVec3], w: impl Fn(usize) -> f64, scale: f64) -> Option<CubicFit> {
    const N: usize = CUBIC_COEFFICIENTS;
    let inv = 1.0 / scale;
    let (ata, atb) = normal_equations(pts, &w, inv);
    // Cholesky (lower), with a relative pivot test as the rank check: a pivot
    // below 1e-11 of its diagonal entry means cond(A) ≳ 3e5 in the scaled
    // monomials, i.e. the samples do not determine a cubic.
    let mut l = [[0.0f64; N]; N];
    for j in 0..N {
        let mut d = ata[j][j];
        for k in 0..j {
            d -= l[j][k] * l[j][k];
        }
        if d.is_nan() || d <= 1e-11 * ata[j][j].max(f64::MIN_POSITIVE) {
            return None;
        }
        let d = d.sqrt();
        l[j][j] = d;
        for i in j + 1..N {
            let mut s = ata[i][j];
            for k in 0..j {
                s -= l[i][k] * l[j][k];
            }
            l[i][j] = s / d;
        }
    }
    let mut y = [0.0f64; N];
    for i in 0..N {
        let mut s = atb[i];
        for k in 0..i {
            s -= l[i][k] * y[k];
        }
        y[i] = s / l[i][i];
    }
    let mut c = [0.0f64; N];
    for i in (0..N).rev() {
        let mut s = y[i];
        for k in i + 1..N {
            s -= l[k][i] * c[k];
        }
        c[i] = s / l[i][i];
    }
    if c.iter().any(|x| !x.is_finite()) {
        return None;
    }
    let cubic = Cubic { coef: c, scale };
    // Residual from the points themselves (not from the normal equations,
    // which would cancel catastrophically on near-exact fits).
    let (mut sr, mut sw) = (0.0, 0.0);
    for (k, p) in pts.iter().enumerate() {
        let wk = w(k);
        let r = cubic.eval(p.x, p.y) - p.z;
        sr += wk * r * r;
        sw += wk;
    }
    let rms = if sw > 0.0 { (sr / sw).sqrt() } else { 0.0 };
    Some(CubicFit { cubic, rms })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reproduces_a_cubic_exactly() {
        let truth =
            |u: f64, v: f64| 0.3 + 0.1 * u - 0.2 * v + u * u - 0.5 * u * v * v + 0.7 * v * v * v;
        let pts: Vec<DVec3> = (0..49)
            .map(|k| {
                let (u, v) = ((k % 7) as f64 * 0.3 - 0.9, (k / 7) as f64 * 0.3 - 0.9);
                DVec3::new(u, v, truth(u, v))
            })
            .collect();
        let fit = fit_cubic(&pts, None, 1.0).unwrap();
        assert!(fit.rms < 1e-12, "rms {}", fit.rms);
        assert!((fit.cubic.eval(0.45, -0.2) - truth(0.45, -0.2)).abs() < 1e-10);
        // Collinear points: no cubic.
        let line: Vec<DVec3> = (0..30)
            .map(|k| DVec3::new(k as f64, 2.0 * k as f64, 0.0))
            .collect();
        assert!(fit_cubic(&line, None, 30.0).is_none());
    }

    /// The lockstep foot points are the scalar ones, bit for bit, whatever
    /// the number of iterations each lane needs (points near and far from
    /// the graph, a remainder after the last full group of lanes).
    #[test]
    fn foot_points_match_foot_point_bitwise() {
        let c = Cubic {
            coef: [0.01, 0.1, -0.05, 0.5, 0.2, -0.3, 0.1, -0.4, 0.2, 0.3],
            scale: 2.0,
        };
        let qs: Vec<DVec3> = (0..4 * FOOT_POINT_LANES + 3)
            .map(|k| {
                let t = k as f64;
                DVec3::new(
                    (1.7 * t).sin() * 1.5,
                    (0.9 * t).cos() * 1.2,
                    (0.3 * t).sin() * 10f64.powi(k as i32 % 4 - 2),
                )
            })
            .collect();
        let mut out = Vec::new();
        c.foot_points(&qs, 0.5, &mut out);
        assert_eq!(out.len(), qs.len());
        for (q, f) in qs.iter().zip(&out) {
            let g = c.foot_point(*q, 0.5);
            assert_eq!(
                (g.x.to_bits(), g.y.to_bits()),
                (f.x.to_bits(), f.y.to_bits())
            );
        }
    }

    /// The row-pair sums are the per-point pass over the whole system
    /// (the accumulation `fit_cubic` used before), bit for bit, on every
    /// entry the Cholesky reads, weighted and not.
    #[test]
    #[allow(clippy::needless_range_loop)] // the reference loop as it was
    fn normal_equations_match_the_per_point_pass_bitwise() {
        const N: usize = CUBIC_COEFFICIENTS;
        let pts: Vec<DVec3> = (0..613)
            .map(|k| {
                let t = k as f64;
                DVec3::new(
                    (1.3 * t).sin() * 0.7,
                    (0.7 * t).cos() * 0.9,
                    (0.37 * t).sin() * 0.1,
                )
            })
            .collect();
        let ws: Vec<f64> = (0..pts.len())
            .map(|k| 1.0 + (k % 7) as f64 * 0.37)
            .collect();
        let inv = 1.0 / 0.83;
        for weighted in [false, true] {
            let w = |k: usize| if weighted { ws[k] } else { 1.0 };
            let (mut ref_a, mut ref_b) = ([[0.0f64; N]; N], [0.0f64; N]);
            for (k, p) in pts.iter().enumerate() {
                let m = monomials(p.x * inv, p.y * inv);
                let h = p.z * inv;
                for i in 0..N {
                    let wi = w(k) * m[i];
                    ref_b[i] += wi * h;
                    for j in 0..N {
                        ref_a[i][j] += wi * m[j];
                    }
                }
            }
            let (a, b) = normal_equations(&pts, &w, inv);
            for i in 0..N {
                assert_eq!(a[i][..=i], ref_a[i][..=i], "row {i}");
            }
            assert_eq!(b, ref_b);
        }
    }

    /// The Newton step without the square root where the length is far
    /// from both thresholds takes the same decisions and values as the
    /// step that always computes it: the foot points of many points,
    /// near and far, against a loop that always takes the root.
    #[test]
    fn foot_point_matches_the_always_rooted_step() {
        let c = Cubic {
            coef: [0.02, 0.3, -0.1, 0.8, -0.4, 0.6, 0.3, -0.9, 0.5, 0.2],
            scale: 0.7,
        };
        let reference = |q: DVec3, max_step: f64| {
            let mut p = DVec2::new(q.x, q.y);
            for _ in 0..FOOT_POINT_ITERATIONS {
                let h = c.eval(p.x, p.y);
                let g = c.grad(p.x, p.y);
                let (huu, huv, hvv) = c.hessian(p.x, p.y);
                let dz = h - q.z;
                let f = DVec2::new(p.x - q.x + dz * g.x, p.y - q.y + dz * g.y);
                let a = 1.0 + g.x * g.x + dz * huu;
                let b = g.x * g.y + dz * huv;
                let d = 1.0 + g.y * g.y + dz * hvv;
                let det = a * d - b * b;
                let step = if det > 1e-12 && a > 0.0 {
                    DVec2::new((d * f.x - b * f.y) / det, (a * f.y - b * f.x) / det)
                } else {
                    let (a, d) = (1.0 + g.x * g.x, 1.0 + g.y * g.y);
                    let b = g.x * g.y;
                    let det = a * d - b * b;
                    DVec2::new((d * f.x - b * f.y) / det, (a * f.y - b * f.x) / det)
                };
                let len = step.length();
                let step = if len > max_step {
                    step * (max_step / len)
                } else {
                    step
                };
                if !step.is_finite() {
                    break;
                }
                p -= step;
                if len <= 1e-9 * c.scale {
                    break;
                }
            }
            p
        };
        let mut clamped = 0;
        for k in 0..4000 {
            let t = k as f64;
            let q = DVec3::new(
                (1.7 * t).sin() * 0.9,
                (0.9 * t).cos() * 0.8,
                (0.3 * t).sin() * 10f64.powi(k % 5 - 3),
            );
            let max_step = [0.35, 0.05, 1e-3][k as usize % 3];
            let (a, b) = (c.foot_point(q, max_step), reference(q, max_step));
            assert_eq!(
                (a.x.to_bits(), a.y.to_bits()),
                (b.x.to_bits(), b.y.to_bits()),
                "{k}"
            );
            let first = c.foot_point_step(DVec2::new(q.x, q.y), q, max_step).0;
            clamped += ((first - DVec2::new(q.x, q.y)).length() >= 0.999 * max_step) as usize;
        }
        assert!(
            clamped > 100,
            "the clamped path must be exercised ({clamped})"
        );
    }

    /// `near_height` answers as the divided evaluation does, including at
    /// the threshold itself and one unit in the last place either side of
    /// it (where the estimate must hand over to `eval`), for cubics of
    /// several scales and points near and far from the graph.
    #[test]
    fn near_height_is_the_divided_test() {
        for (j, scale) in [0.7, 3.1e-3, 2.9e4].into_iter().enumerate() {
            let c = Cubic {
                coef: [0.02, 0.3, -0.1, 0.8, -0.4, 0.6, 0.3, -0.9, 0.5, 0.2],
                scale,
            };
            let inv = 1.0 / scale;
            for k in 0..3000 {
                let t = (k + 7 * j) as f64;
                let (u, v) = ((1.7 * t).sin() * scale, (0.9 * t).cos() * scale);
                let q = DVec3::new(u, v, c.eval(u, v) + (0.3 * t).sin() * 1e-3 * scale);
                let d = (q.z - c.eval(q.x, q.y)).abs();
                for eps in [
                    d,
                    f64::from_bits(d.to_bits() + 1),
                    f64::from_bits(d.to_bits().saturating_sub(1)),
                    0.5 * d,
                    2.0 * d,
                    1e-4 * scale,
                ] {
                    assert_eq!(c.near_height(q, inv, eps), d <= eps, "{scale} {k} {eps}");
                }
            }
        }
        // A non-finite point takes `eval`'s answer (false) too.
        let c = Cubic {
            coef: [0.0; CUBIC_COEFFICIENTS],
            scale: 1.0,
        };
        assert!(!c.near_height(DVec3::new(f64::NAN, 0.0, 0.0), 1.0, 1.0));
    }

    #[test]
    fn foot_point_is_orthogonal() {
        let c = Cubic {
            coef: [0.0, 0.1, 0.0, 0.5, 0.2, -0.3, 0.1, 0.0, 0.2, 0.0],
            scale: 1.0,
        };
        let q = DVec3::new(0.3, -0.2, 0.4);
        let f = c.foot_point(q, 1.0);
        let p = DVec3::new(f.x, f.y, c.eval(f.x, f.y));
        let d = q - p;
        let g = c.grad(f.x, f.y);
        // d is orthogonal to both tangents (1, 0, g_u) and (0, 1, g_v).
        assert!(d.dot(DVec3::new(1.0, 0.0, g.x)).abs() < 1e-9);
        assert!(d.dot(DVec3::new(0.0, 1.0, g.y)).abs() < 1e-9);
    }
}
