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
#[derive(Copy, Clone, Debug, PartialEq, Eq, Default)]
pub enum LsqMethod {
    /// Cholesky (LDLᵀ) of the normal equations: fast; accurate enough once
    /// a fairness term keeps the system well conditioned.
    #[default]
    NormalEquations,
    /// Sparse QR of the stacked system: slower, does not square the
    /// condition number.
    Qr,
}

/// Options of [`least_squares`].
#[derive(Clone, Debug)]
#[non_exhaustive]
pub struct LsqOptions {
    pub method: LsqMethod,
    /// Relative pivot below which an unknown counts as undetermined
    /// (a rank-deficient system is an error, never a silent garbage answer).
    pub rank_tolerance: f64,
}

impl Default for LsqOptions {
    fn default() -> Self {
        // 1e-12 on the normal equations ≈ 1e-6 on singular values of A.
        LsqOptions {
            method: LsqMethod::NormalEquations,
            rank_tolerance: 1e-12,
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
        options.rank_tolerance,
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

#[cfg(test)]
mod tests {
    use super::*;

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
        for method in [LsqMethod::NormalEquations, LsqMethod::Qr] {
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
        for method in [LsqMethod::NormalEquations, LsqMethod::Qr] {
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
