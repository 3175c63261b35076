//! Sparse linear least squares through Eigen: minimise `|A x - b|² + λ|R x|²`
//! for several right-hand sides at once (x, y and z of control points share
//! one factorisation). The global fit (Fitmaps §3.5) and the local refits of
//! the simplification (§3.4) build `A` from limit stencils and `R` from a
//! fairness term.

use crate::error::{Error, Result};
use crate::ffi::eigen::bridge;

/// A sparse matrix given as `(row, col, value)` triplets; duplicates add up.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Triplets {
    pub rows: usize,
    pub cols: usize,
    pub row_idx: Vec<u32>,
    pub col_idx: Vec<u32>,
    pub values: Vec<f64>,
}

impl Triplets {
    pub fn new(rows: usize, cols: usize) -> Self {
        Triplets {
            rows,
            cols,
            ..Default::default()
        }
    }
    #[inline]
    pub fn push(&mut self, row: usize, col: usize, value: f64) {
        self.row_idx.push(row as u32);
        self.col_idx.push(col as u32);
        self.values.push(value);
    }
    pub fn nnz(&self) -> usize {
        self.values.len()
    }
    /// `A x` for a dense `x` (used by tests and residual reports).
    pub fn mul_vec(&self, x: &[f64]) -> Vec<f64> {
        let mut y = vec![0.0; self.rows];
        for k in 0..self.values.len() {
            y[self.row_idx[k] as usize] += self.values[k] * x[self.col_idx[k] as usize];
        }
        y
    }
}

/// How the system is factorised.
/// The normal equations `N x = Aᵀ b` of a least-squares problem too large
/// to hold `A` (tens of millions of rows, each touching two or three
/// unknowns that are neighbours in a mesh): `N = Σ w a aᵀ` and `Aᵀ b` are
/// accumulated row by row into a sparsity pattern fixed in advance, so the
/// memory is that of `N` (the pattern's entries), not of the rows, and
/// `A` is never built. Rows are added in the caller's order; the sums (and
/// so the solution) depend on that order only, not on the thread count.
#[derive(Clone, Debug)]
pub struct NormalEquations {
    /// Compressed rows of `N` (both triangles, columns sorted, diagonal
    /// included): row `i` is `inner[outer[i]..outer[i + 1]]`.
    outer: Vec<i32>,
    inner: Vec<i32>,
    values: Vec<f64>,
    rhs: Vec<f64>,
    /// Rows added.
    pub rows: usize,
    /// [`Self::add_row`]'s scratch: a long row's entries in column order.
    sorted: Vec<(u32, f64)>,
}

impl NormalEquations {
    /// `n` unknowns whose rows only couple the pairs in `pairs` (either
    /// order, repeats allowed) and each unknown with itself.
    pub fn with_pairs(n: usize, pairs: impl Iterator<Item = [u32; 2]> + Clone) -> Result<Self> {
        if n >= i32::MAX as usize {
            return Err(Error::numerical(
                "normal equations",
                format!("{n} unknowns is more than the solver indexes"),
            ));
        }
        let mut count = vec![1i64; n];
        for [a, b] in pairs.clone() {
            if a != b {
                count[a as usize] += 1;
                count[b as usize] += 1;
            }
        }
        let mut start = Vec::with_capacity(n + 1);
        let mut total = 0i64;
        for &c in &count {
            start.push(total);
            total += c;
        }
        start.push(total);
        let mut inner = vec![0i32; total as usize];
        let mut fill = start.clone();
        for i in 0..n {
            inner[fill[i] as usize] = i as i32;
            fill[i] += 1;
        }
        for [a, b] in pairs {
            if a != b {
                inner[fill[a as usize] as usize] = b as i32;
                fill[a as usize] += 1;
                inner[fill[b as usize] as usize] = a as i32;
                fill[b as usize] += 1;
            }
        }
        // Sort and dedupe each row in place, compacting as we go.
        let mut outer = Vec::with_capacity(n + 1);
        let mut w = 0usize;
        outer.push(0i32);
        for i in 0..n {
            let row = &mut inner[start[i] as usize..start[i + 1] as usize];
            row.sort_unstable();
            let mut last = -1;
            for k in start[i] as usize..start[i + 1] as usize {
                let c = inner[k];
                if c != last {
                    inner[w] = c;
                    w += 1;
                    last = c;
                }
            }
            if w > i32::MAX as usize {
                return Err(Error::numerical(
                    "normal equations",
                    "more entries than the solver indexes",
                ));
            }
            outer.push(w as i32);
        }
        inner.truncate(w);
        inner.shrink_to_fit();
        Ok(NormalEquations {
            outer,
            values: vec![0.0; w],
            inner,
            rhs: vec![0.0; n],
            rows: 0,
            sorted: Vec::new(),
        })
    }

    /// Unknowns.
    pub fn len(&self) -> usize {
        self.rhs.len()
    }

    /// Whether there are no unknowns.
    pub fn is_empty(&self) -> bool {
        self.rhs.is_empty()
    }

    fn entry(&self, i: u32, j: u32) -> Result<usize> {
        let missing = || {
            Error::internal(format!(
                "normal equations: ({i}, {j}) is not in the sparsity pattern"
            ))
        };
        let i = i as usize;
        if i + 1 >= self.outer.len() {
            return Err(missing());
        }
        let lo = self.outer[i] as usize;
        let row = &self.inner[lo..self.outer[i + 1] as usize];
        // Rows are short (a mesh vertex's neighbours): a scan beats a search.
        row.iter()
            .position(|&c| c == j as i32)
            .map(|k| lo + k)
            .ok_or_else(missing)
    }

    /// Adds the row `Σ a_k x_{c_k} = b` (`entries` = `(c_k, a_k)`, columns
    /// distinct and coupled in the pattern; else an error, `N` unchanged
    /// only if the first column is the one missing).
    pub fn add_row(&mut self, entries: &[(u32, f64)], b: f64) -> Result<()> {
        // Short rows (the bilinear reconstruction's 4 samples): a scan of
        // pattern row i per pair. Long ones (the B-spline's 16 and more,
        // whose pattern rows hold ~50 columns) would scan k² times; with the
        // entries in column order, one merge walk of each pattern row finds
        // all k of its columns. The same (i, j) sums in the same order.
        if entries.len() <= 6 {
            for &(i, ai) in entries {
                for &(j, aj) in entries {
                    let k = self.entry(i, j)?;
                    self.values[k] += ai * aj;
                }
                self.rhs[i as usize] += ai * b;
            }
            self.rows += 1;
            return Ok(());
        }
        let mut sorted = std::mem::take(&mut self.sorted);
        sorted.clear();
        sorted.extend_from_slice(entries);
        sorted.sort_unstable_by_key(|e| e.0);
        let r = self.add_sorted_row(entries, &sorted, b);
        self.sorted = sorted;
        r
    }

    /// [`Self::add_row`] of `entries`, `sorted` the same in column order.
    fn add_sorted_row(
        &mut self,
        entries: &[(u32, f64)],
        sorted: &[(u32, f64)],
        b: f64,
    ) -> Result<()> {
        for &(i, ai) in entries {
            let iu = i as usize;
            if iu + 1 >= self.outer.len() {
                return Err(self.entry(i, sorted[0].0).unwrap_err());
            }
            let (lo, hi) = (self.outer[iu] as usize, self.outer[iu + 1] as usize);
            let mut k = lo;
            for &(j, aj) in sorted {
                while k < hi && self.inner[k] < j as i32 {
                    k += 1;
                }
                if k == hi || self.inner[k] != j as i32 {
                    return Err(Error::internal(format!(
                        "normal equations: ({i}, {j}) is not in the sparsity pattern"
                    )));
                }
                self.values[k] += ai * aj;
            }
            self.rhs[iu] += ai * b;
        }
        self.rows += 1;
        Ok(())
    }

    /// Adds `v` to `N[i][i]` (a ridge).
    pub fn add_diagonal(&mut self, i: usize, v: f64) -> Result<()> {
        let k = self.entry(i as u32, i as u32)?;
        self.values[k] += v;
        Ok(())
    }

    /// `x` with `N x = Aᵀ b`, by Jacobi-preconditioned conjugate gradients
    /// to a relative residual of `tolerance` (Eigen; an error when they do
    /// not converge). `N` must be definite (a ridge on every unknown that
    /// no row reaches).
    pub fn solve_cg(&self, tolerance: f64) -> Result<Vec<f64>> {
        self.solve_cg_for(&self.rhs, tolerance)
    }

    /// [`Self::solve_cg`] with `rhs` in place of the rows' `Aᵀ b` (one
    /// assembled `N` for several right-hand sides; `rhs.len()` must be
    /// [`Self::len`]).
    pub fn solve_cg_for(&self, rhs: &[f64], tolerance: f64) -> Result<Vec<f64>> {
        if rhs.len() != self.rhs.len() {
            return Err(Error::internal(format!(
                "normal equations: {} right-hand side values for {} unknowns",
                rhs.len(),
                self.rhs.len()
            )));
        }
        if rhs.is_empty() {
            return Ok(Vec::new());
        }
        bridge::spd_conjugate_gradients(
            rhs.len(),
            &self.outer,
            &self.inner,
            &self.values,
            rhs,
            tolerance,
        )
        .map_err(|e| Error::backend("Eigen", e.what().to_string()))
    }
}

#[derive(Copy, Clone, Debug, PartialEq, Eq, Default)]
pub enum LsqMethod {
    /// Cholesky (LDLᵀ) of the normal equations: fast; accurate enough once
    /// a fairness term keeps the system well conditioned.
    #[default]
    NormalEquations,
    /// Sparse QR of the stacked system: slower, does not square the
    /// condition number.
    Qr,
    /// Jacobi-preconditioned conjugate gradients on the normal equations,
    /// to a relative residual of [`LsqOptions::cg_tolerance`]: for large,
    /// well-conditioned systems (close to a mass matrix), where a
    /// factorisation's fill-in costs more than tens of iterations. A system
    /// that does not converge is an error, not a rough answer. It does not
    /// detect rank deficiency (the component of x along a null direction
    /// stays 0): use it with a ridge that makes the system definite.
    ConjugateGradient,
}

/// Options of [`least_squares`].
#[derive(Clone, Debug)]
#[non_exhaustive]
pub struct LsqOptions {
    pub method: LsqMethod,
    /// Relative pivot below which an unknown counts as undetermined
    /// (a rank-deficient system is an error, never a silent garbage answer).
    pub rank_tolerance: f64,
    /// Relative residual `|N x - Aᵀb| / |Aᵀb|` at which
    /// [`LsqMethod::ConjugateGradient`] stops.
    pub cg_tolerance: f64,
}

impl Default for LsqOptions {
    fn default() -> Self {
        // 1e-12 on the normal equations ≈ 1e-6 on singular values of A.
        LsqOptions {
            method: LsqMethod::NormalEquations,
            rank_tolerance: 1e-12,
            cg_tolerance: 1e-10,
        }
    }
}

/// Minimises `|A x - b_k|² + λ|R x|²` for every right-hand side `b_k`
/// (each of length `A.rows`); returns one `x_k` (length `A.cols`) per `b_k`.
pub fn least_squares(
    a: &Triplets,
    rhs: &[Vec<f64>],
    regularisation: Option<(&Triplets, f64)>,
    options: &LsqOptions,
) -> Result<Vec<Vec<f64>>> {
    let bad = |m: String| Err(Error::InvalidArgument(format!("least squares: {m}")));
    if rhs.is_empty() {
        return bad("no right-hand side".into());
    }
    if let Some(k) = rhs.iter().position(|b| b.len() != a.rows) {
        return bad(format!(
            "right-hand side {k} has length {}, A has {} rows",
            rhs[k].len(),
            a.rows
        ));
    }
    let empty = Triplets::new(0, a.cols);
    let (r, lambda) = regularisation.unwrap_or((&empty, 0.0));
    if r.cols != a.cols {
        return bad(format!("R has {} columns, A has {}", r.cols, a.cols));
    }
    if !(lambda.is_finite() && lambda >= 0.0) {
        return bad(format!("λ = {lambda} must be finite and >= 0"));
    }
    if a.rows + if lambda > 0.0 { r.rows } else { 0 } < a.cols {
        return Err(Error::RankDeficient {
            msg: format!("{} equations for {} unknowns", a.rows + r.rows, a.cols),
        });
    }
    let b: Vec<f64> = rhs.iter().flatten().copied().collect();
    let method = match options.method {
        LsqMethod::NormalEquations => 0,
        LsqMethod::Qr => 1,
        LsqMethod::ConjugateGradient => 2,
    };
    let x = bridge::sparse_least_squares(
        a.rows,
        a.cols,
        &a.row_idx,
        &a.col_idx,
        &a.values,
        r.rows,
        &r.row_idx,
        &r.col_idx,
        &r.values,
        lambda,
        &b,
        rhs.len(),
        method,
        // The factorisations' pivot threshold, or CG's stopping residual.
        match options.method {
            LsqMethod::ConjugateGradient => options.cg_tolerance,
            _ => options.rank_tolerance,
        },
    )
    .map_err(|e| {
        let msg = e.what().to_string();
        match msg.strip_prefix("rank deficient: ") {
            Some(m) => Error::RankDeficient { msg: m.to_string() },
            None => Error::backend("Eigen", msg),
        }
    })?;
    Ok(x.chunks(a.cols).map(|c| c.to_vec()).collect())
}

/// `x * y` for two `f64`: inside [`dense_cholesky_solve`] the bound
/// `f64: Mul<T>` hides `f64: Mul<f64>` from type inference.
#[inline]
fn scalar_mul(x: f64, y: f64) -> f64 {
    x * y
}

/// Solves the small dense SPD system `a x = b` (`a` row-major `n × n`) by
/// Cholesky, for right-hand sides of any vector type (`f64`, `DVec3`). The
/// curve fits (rim loops of the global fit, mechanical boundary curves,
/// Lavoué §5) have a few dozen unknowns: Eigen's sparse path would cost more
/// than it saves. `None` when `a` is not positive definite (a pivot that is
/// not a finite positive number, NaN included).
pub(crate) fn dense_cholesky_solve<T>(mut a: Vec<f64>, n: usize, mut b: Vec<T>) -> Option<Vec<T>>
where
    T: Copy + std::ops::Sub<Output = T> + std::ops::Div<f64, Output = T>,
    f64: std::ops::Mul<T, Output = T>,
{
    debug_assert!(a.len() == n * n && b.len() == n);
    for j in 0..n {
        let mut d = a[j * n + j];
        for k in 0..j {
            d -= scalar_mul(a[j * n + k], a[j * n + k]);
        }
        if d <= 0.0 || !d.is_finite() {
            return None;
        }
        let d = d.sqrt();
        a[j * n + j] = d;
        for i in j + 1..n {
            let mut s = a[i * n + j];
            for k in 0..j {
                s -= scalar_mul(a[i * n + k], a[j * n + k]);
            }
            a[i * n + j] = s / d;
        }
    }
    for i in 0..n {
        let mut s = b[i];
        for k in 0..i {
            s = s - a[i * n + k] * b[k];
        }
        b[i] = s / a[i * n + i];
    }
    for i in (0..n).rev() {
        let mut s = b[i];
        for k in i + 1..n {
            s = s - a[k * n + i] * b[k];
        }
        b[i] = s / a[i * n + i];
    }
    Some(b)
}

#[cfg(test)]
mod tests {
    use super::*;

    const ALL: [LsqMethod; 3] = [
        LsqMethod::NormalEquations,
        LsqMethod::Qr,
        LsqMethod::ConjugateGradient,
    ];

    /// A displacement-like system: 2000 unknowns on a closed chain, each
    /// row interpolating two neighbours at a fraction `t`, plus a ridge. CG
    /// agrees with LDLᵀ to its tolerance; asked for a residual of exactly 0
    /// it cannot converge and says so.
    #[test]
    fn conjugate_gradients_agree_with_ldlt_and_report_non_convergence() {
        let n = 2000;
        let mut a = Triplets::new(0, n);
        let mut b = Vec::new();
        for i in 0..n {
            for k in 0..3 {
                let t = (k as f64 + 0.5) / 3.0;
                a.push(a.rows, i, 1.0 - t);
                a.push(a.rows, (i + 1) % n, t);
                a.rows += 1;
                b.push(((i * 7 + k * 3) % 11) as f64 - 5.0 + (i as f64 * 0.01).sin());
            }
        }
        let mut r = Triplets::new(n, n);
        for i in 0..n {
            r.push(i, i, 1.0);
        }
        let solve = |method, cg_tolerance| {
            let opts = LsqOptions {
                method,
                cg_tolerance,
                ..Default::default()
            };
            least_squares(&a, std::slice::from_ref(&b), Some((&r, 1e-3)), &opts)
        };
        let ldlt = solve(LsqMethod::NormalEquations, 0.0).unwrap().remove(0);
        let cg = solve(LsqMethod::ConjugateGradient, 1e-10)
            .unwrap()
            .remove(0);
        let scale = ldlt.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        let worst = ldlt
            .iter()
            .zip(&cg)
            .fold(0.0f64, |m, (p, q)| m.max((p - q).abs()));
        // Residual 1e-10 and a condition number of ~10 (the ridge and the
        // interpolation weights bound it): 1e-8 of the solution's size.
        assert!(
            worst < 1e-8 * scale,
            "CG off LDLT by {worst} (scale {scale})"
        );
        let e = solve(LsqMethod::ConjugateGradient, 0.0).unwrap_err();
        assert!(e.to_string().contains("did not converge"), "{e}");
    }

    #[test]
    fn normal_equations_row_by_row_solve_the_stacked_problem() {
        // A path of 40 unknowns, rows on pairs and triples of neighbours
        // with pseudo-random coefficients, plus a ridge: the accumulated
        // normal equations give the least-squares solution of the stacked
        // rows (Eigen's own normal equations of the triplets) to CG's
        // tolerance.
        let n = 40;
        let mut seed = 7u64;
        let mut rnd = move || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((seed >> 11) as f64 / (1u64 << 53) as f64) - 0.5
        };
        let pairs = (0..n as u32 - 1)
            .map(|i| [i, i + 1])
            .chain((0..n as u32 - 2).map(|i| [i + 2, i]));
        let mut ne = NormalEquations::with_pairs(n, pairs).unwrap();
        let mut a = Triplets::new(0, n);
        let mut b = Vec::new();
        for r in 0..3 * n {
            let i = (r % (n - 2)) as u32;
            let cols: Vec<u32> = if r % 2 == 0 {
                vec![i, i + 1]
            } else {
                vec![i, i + 1, i + 2]
            };
            let entries: Vec<(u32, f64)> = cols.iter().map(|&c| (c, 1.0 + rnd())).collect();
            let rhs = rnd();
            ne.add_row(&entries, rhs).unwrap();
            for &(c, v) in &entries {
                a.push(a.rows, c as usize, v);
            }
            a.rows += 1;
            b.push(rhs);
        }
        let mut ridge = Triplets::new(n, n);
        for i in 0..n {
            ridge.push(i, i, 1.0);
            ne.add_diagonal(i, 1e-2).unwrap();
        }
        let x = ne.solve_cg(1e-12).unwrap();
        let opts = LsqOptions::default();
        let y = least_squares(&a, &[b], Some((&ridge, 1e-2)), &opts).unwrap();
        for (i, (p, q)) in x.iter().zip(&y[0]).enumerate() {
            assert!(
                (p - q).abs() < 1e-8 * (1.0 + q.abs()),
                "unknown {i}: {p} vs {q}"
            );
        }
        // A row outside the pattern is an error, not a panic.
        assert!(ne.add_row(&[(0, 1.0), (5, 1.0)], 0.0).is_err());
        assert!(ne.add_diagonal(n, 1.0).is_err());
    }

    #[test]
    fn long_rows_sum_the_same_entries_as_short_ones() {
        // Rows of 16 unknowns out of column order (the B-spline's 4 × 4
        // knots) take the merge walk; the same rows split into the
        // pattern's scan, entry by entry, must give bit-identical sums
        // (each (i, j) gets one product per row, in row order either way).
        let n = 24u32;
        let window = |r: u32| -> Vec<u32> { (0..16).map(|k| (r + 5 * k) % n).collect() };
        let mut pairs: Vec<[u32; 2]> = Vec::new();
        for r in 0..8 {
            let w = window(r);
            for &a in &w {
                pairs.extend(w.iter().map(|&b| [a, b]));
            }
        }
        let mut long = NormalEquations::with_pairs(n as usize, pairs.iter().copied()).unwrap();
        let mut short = long.clone();
        for r in 0..8u32 {
            let entries: Vec<(u32, f64)> = window(r)
                .into_iter()
                .map(|c| (c, 1.0 + (c * 7 + r) as f64 / 13.0))
                .collect();
            long.add_row(&entries, r as f64).unwrap();
            for &(i, ai) in &entries {
                for &(j, aj) in &entries {
                    let k = short.entry(i, j).unwrap();
                    short.values[k] += ai * aj;
                }
                short.rhs[i as usize] += ai * r as f64;
            }
        }
        assert_eq!(long.values, short.values);
        assert_eq!(long.rhs, short.rhs);
        // A long row outside the pattern is an error too.
        let mut sparse =
            NormalEquations::with_pairs(n as usize, (0..n - 1).map(|i| [i, i + 1])).unwrap();
        let row: Vec<(u32, f64)> = (0..8).map(|c| (c, 1.0)).collect();
        assert!(sparse.add_row(&row, 0.0).is_err());
    }

    #[test]
    fn dense_cholesky_solves_spd_systems_and_refuses_the_rest() {
        // A = M Mᵀ + I is SPD; check A x = b for f64 and vector right-hand sides.
        let a = vec![4.0, 2.0, 0.5, 2.0, 5.0, 1.0, 0.5, 1.0, 3.0];
        let x = [1.0, -2.0, 0.25];
        let b: Vec<f64> = (0..3)
            .map(|i| (0..3).map(|k| a[i * 3 + k] * x[k]).sum())
            .collect();
        let got = dense_cholesky_solve(a.clone(), 3, b.clone()).unwrap();
        for (g, w) in got.iter().zip(x) {
            assert!((g - w).abs() < 1e-12, "{g} vs {w}");
        }
        let bv: Vec<glam::DVec3> = b
            .iter()
            .map(|&v| glam::DVec3::new(v, 2.0 * v, -v))
            .collect();
        let gv = dense_cholesky_solve(a, 3, bv).unwrap();
        for (g, w) in gv.iter().zip(x) {
            assert!((*g - glam::DVec3::new(w, 2.0 * w, -w)).length() < 1e-12);
        }
        // Indefinite (eigenvalues 3 and -1) and NaN matrices are refused.
        assert!(dense_cholesky_solve(vec![1.0, 2.0, 2.0, 1.0], 2, vec![1.0, 1.0]).is_none());
        assert!(dense_cholesky_solve(vec![f64::NAN, 0.0, 0.0, 1.0], 2, vec![1.0, 1.0]).is_none());
    }

    /// Line fit y = c0 + c1 t through noisy-free points: exact recovery.
    #[test]
    fn recovers_exact_solution_both_methods() {
        let ts = [0.0, 1.0, 2.0, 3.5, 5.0];
        let mut a = Triplets::new(ts.len(), 2);
        for (i, &t) in ts.iter().enumerate() {
            a.push(i, 0, 1.0);
            a.push(i, 1, t);
        }
        let b1: Vec<f64> = ts.iter().map(|t| 2.0 - 3.0 * t).collect();
        let b2: Vec<f64> = ts.iter().map(|t| 0.5 + 0.25 * t).collect();
        for method in ALL {
            let opts = LsqOptions {
                method,
                ..Default::default()
            };
            let x = least_squares(&a, &[b1.clone(), b2.clone()], None, &opts).unwrap();
            assert!(
                (x[0][0] - 2.0).abs() < 1e-12 && (x[0][1] + 3.0).abs() < 1e-12,
                "{method:?} {x:?}"
            );
            assert!(
                (x[1][0] - 0.5).abs() < 1e-12 && (x[1][1] - 0.25).abs() < 1e-12,
                "{method:?} {x:?}"
            );
        }
    }

    /// Overdetermined inconsistent system: the answer satisfies the normal
    /// equations Aᵀ(Ax - b) = 0.
    #[test]
    fn residual_is_orthogonal_to_columns() {
        let mut a = Triplets::new(6, 3);
        let vals = [
            [1.0, 2.0, 0.0],
            [0.0, 1.0, 1.0],
            [1.0, 0.0, 1.0],
            [2.0, 1.0, 0.5],
            [0.0, 0.0, 3.0],
            [1.0, 1.0, 1.0],
        ];
        for (i, row) in vals.iter().enumerate() {
            for (j, &v) in row.iter().enumerate() {
                if v != 0.0 {
                    a.push(i, j, v);
                }
            }
        }
        let b = vec![1.0, -2.0, 0.5, 3.0, 1.0, -1.0];
        for method in ALL {
            let opts = LsqOptions {
                method,
                ..Default::default()
            };
            let x = least_squares(&a, std::slice::from_ref(&b), None, &opts)
                .unwrap()
                .remove(0);
            let r: Vec<f64> = a.mul_vec(&x).iter().zip(&b).map(|(p, q)| p - q).collect();
            for (j, col) in (0..3).map(|j| (j, vals.iter().map(move |row| row[j]))) {
                let dot: f64 = col.zip(&r).map(|(c, r)| c * r).sum();
                assert!(dot.abs() < 1e-10, "{method:?} column {j}: {dot}");
            }
        }
    }

    #[test]
    fn rank_deficiency_is_an_error_and_regularisation_fixes_it() {
        // Unknown 2 appears in no equation.
        let mut a = Triplets::new(3, 3);
        a.push(0, 0, 1.0);
        a.push(1, 1, 1.0);
        a.push(2, 0, 1.0);
        a.push(2, 1, 1.0);
        let b = vec![1.0, 2.0, 3.0];
        for method in [LsqMethod::NormalEquations, LsqMethod::Qr] {
            let opts = LsqOptions {
                method,
                ..Default::default()
            };
            let e = least_squares(&a, std::slice::from_ref(&b), None, &opts).unwrap_err();
            assert!(matches!(e, Error::RankDeficient { .. }), "{method:?}: {e}");
            let mut r = Triplets::new(3, 3);
            for j in 0..3 {
                r.push(j, j, 1.0);
            }
            let x = least_squares(&a, std::slice::from_ref(&b), Some((&r, 1e-8)), &opts).unwrap();
            assert!(
                (x[0][0] - 1.0).abs() < 1e-6 && x[0][2].abs() < 1e-6,
                "{method:?} {x:?}"
            );
        }
    }

    #[test]
    fn bad_arguments_are_errors() {
        let mut a = Triplets::new(2, 2);
        a.push(0, 0, f64::NAN);
        a.push(1, 1, 1.0);
        let e = least_squares(&a, &[vec![1.0, 1.0]], None, &LsqOptions::default()).unwrap_err();
        assert!(e.to_string().contains("not finite"), "{e}");
        let mut a = Triplets::new(2, 2);
        a.push(5, 0, 1.0);
        let e = least_squares(&a, &[vec![1.0, 1.0]], None, &LsqOptions::default()).unwrap_err();
        assert!(e.to_string().contains("outside"), "{e}");
        let e = least_squares(&a, &[vec![1.0]], None, &LsqOptions::default()).unwrap_err();
        assert!(e.to_string().contains("length"), "{e}");
    }
}
