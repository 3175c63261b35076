//! Exact row compression of the fit's least-squares systems.
//!
//! Every sample of one patch depends on the same few control points (the
//! 16 of a regular patch's stencil, a few more next to an extraordinary
//! vertex), so the `m` rows a patch contributes (`k²` samples, three rows
//! each for the squared-distance objective) span only `c ≪ m` columns. Any
//! rows `C`, `d` with `CᵀC = AᵀA` and `Cᵀd = Aᵀb` give the same normal
//! equations, hence the same least-squares solution (whatever the
//! regulariser added to them): here `C = Lᵀ` with `G = AᵀA = L Lᵀ` the
//! patch's `c × c` Gram matrix and `d = L⁻¹ Aᵀb`. A patch then hands Eigen
//! `c` triangular rows instead of `m` full ones, and Eigen's sparse
//! `AᵀA` product, the main cost of a round (it grows with the square of
//! the entries per row: 48 per row for the squared-distance objective),
//! shrinks by `m / c` (about 5 for both objectives at the pipeline's
//! sample density). The Gram matrices are formed patch by patch in
//! parallel, each in a fixed order, so the result does not depend on the
//! thread count.
//!
//! `G` is positive semi-definite; a pivot below [`PIVOT_FLOOR`] times the
//! largest diagonal entry marks a direction the patch's rows do not
//! constrain (up to rounding): that row of `Lᵀ` is left out, which changes
//! the normal equations by no more than the rounding already in them.

use rayon::prelude::*;

/// Relative pivot below which a direction counts as unconstrained.
const PIVOT_FLOOR: f64 = 1e-13;

/// One sparse row: `(column, value)` entries (any order, duplicates add
/// up) and its right-hand sides.
pub(crate) type Row = (Vec<(u32, f64)>, Vec<f64>);

/// The rows of `groups` (each a list of rows sharing, mostly, the same
/// columns), each group replaced by its compressed equivalent when that is
/// shorter; groups are processed in parallel and returned in order.
/// `nrhs` is the number of right-hand sides of every row.
pub(crate) fn compress_groups(groups: Vec<Vec<Row>>, nrhs: usize) -> Vec<Row> {
    groups
        .into_par_iter()
        .map(|g| compress(g, nrhs))
        .collect::<Vec<_>>()
        .into_iter()
        .flatten()
        .collect()
}

/// One group (module docs).
fn compress(rows: Vec<Row>, nrhs: usize) -> Vec<Row> {
    let mut cols: Vec<u32> = rows.iter().flat_map(|r| r.0.iter().map(|e| e.0)).collect();
    cols.sort_unstable();
    cols.dedup();
    let c = cols.len();
    if rows.len() <= c {
        return rows;
    }
    let local = |col: u32| cols.binary_search(&col).expect("column of the group");
    // Gram matrix G = AᵀA (upper triangle, row-major c × c) and Aᵀb.
    let mut g = vec![0.0; c * c];
    let mut atb = vec![0.0; c * nrhs];
    let mut dense = vec![0.0; c];
    let mut seen = vec![false; c];
    let mut nz: Vec<usize> = Vec::with_capacity(c);
    for (entries, rhs) in &rows {
        nz.clear();
        for &(col, v) in entries {
            let j = local(col);
            if !seen[j] {
                seen[j] = true;
                nz.push(j);
            }
            dense[j] += v;
        }
        nz.sort_unstable();
        for (a, &i) in nz.iter().enumerate() {
            let vi = dense[i];
            for &j in &nz[a..] {
                g[i * c + j] += vi * dense[j];
            }
            for (k, &b) in rhs.iter().enumerate() {
                atb[i * nrhs + k] += vi * b;
            }
        }
        for &j in &nz {
            dense[j] = 0.0;
            seen[j] = false;
        }
    }
    // Cholesky G = L Lᵀ in place (upper triangle holds Lᵀ, row by row).
    let max_diag = (0..c).map(|i| g[i * c + i]).fold(0.0f64, f64::max);
    let floor = PIVOT_FLOOR * max_diag;
    let mut kept = vec![false; c];
    for i in 0..c {
        let mut d = g[i * c + i];
        for k in 0..i {
            if kept[k] {
                d -= g[k * c + i] * g[k * c + i];
            }
        }
        if d.is_nan() || d <= floor {
            continue;
        }
        kept[i] = true;
        let l = d.sqrt();
        g[i * c + i] = l;
        for j in i + 1..c {
            let mut s = g[i * c + j];
            for k in 0..i {
                if kept[k] {
                    s -= g[k * c + i] * g[k * c + j];
                }
            }
            g[i * c + j] = s / l;
        }
        // d_i = (Aᵀb_i − Σ_k L_ik d_k) / L_ii, forward substitution.
        for r in 0..nrhs {
            let mut s = atb[i * nrhs + r];
            for k in 0..i {
                if kept[k] {
                    s -= g[k * c + i] * atb[k * nrhs + r];
                }
            }
            atb[i * nrhs + r] = s / l;
        }
    }
    (0..c)
        .filter(|&i| kept[i])
        .map(|i| {
            let entries = (i..c)
                // Columns whose own pivot was dropped keep their entries:
                // they are part of the earlier rows of Lᵀ.
                .filter(|&j| j == i || g[i * c + j] != 0.0)
                .map(|j| (cols[j], g[i * c + j]))
                .collect();
            (entries, atb[i * nrhs..(i + 1) * nrhs].to_vec())
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solve::{least_squares, LsqOptions, Triplets};

    /// A deterministic pseudo-random value in [-1, 1) (LCG).
    fn rng(state: &mut u64) -> f64 {
        *state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((*state >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
    }

    fn stack(rows: &[Row], cols: usize, nrhs: usize) -> (Triplets, Vec<Vec<f64>>) {
        let mut a = Triplets::new(rows.len(), cols);
        let mut b = vec![Vec::new(); nrhs];
        for (r, (e, rhs)) in rows.iter().enumerate() {
            for &(c, v) in e {
                a.push(r, c as usize, v);
            }
            for (k, &v) in rhs.iter().enumerate() {
                b[k].push(v);
            }
        }
        (a, b)
    }

    /// Groups of tall rows over overlapping column windows, like patches
    /// sharing control points; column `dead` appears in no row (only the
    /// regulariser determines it) and, in the first group, column 0 and 1
    /// always carry the same value (a rank-deficient group).
    fn system(groups: usize, per: usize, width: usize, nrhs: usize) -> Vec<Vec<Row>> {
        let mut s = 7u64;
        (0..groups)
            .map(|g| {
                (0..per)
                    .map(|_| {
                        let mut e: Vec<(u32, f64)> = Vec::new();
                        for k in 0..width {
                            if rng(&mut s) > -0.6 {
                                e.push(((g * width / 2 + k) as u32 + 2, rng(&mut s)));
                            }
                        }
                        if g == 0 {
                            let v = rng(&mut s);
                            e.push((0, v));
                            e.push((1, v));
                            // A duplicate entry adds up.
                            e.push((1, 0.0));
                        }
                        (e, (0..nrhs).map(|_| rng(&mut s)).collect())
                    })
                    .collect()
            })
            .collect()
    }

    #[test]
    fn compressed_rows_give_the_same_least_squares_solution() {
        let (groups, per, width, nrhs) = (6, 60, 12, 3);
        let cols = 2 + (groups + 1) * width / 2 + width + 1;
        let full: Vec<Row> = system(groups, per, width, nrhs)
            .into_iter()
            .flatten()
            .collect();
        let compressed = compress_groups(system(groups, per, width, nrhs), nrhs);
        // Each group of 60 rows over at most 14 columns becomes ≤ 14 rows.
        assert!(
            compressed.len() <= groups * (width + 2),
            "{} rows",
            compressed.len()
        );
        let mut reg = Triplets::new(cols, cols);
        for c in 0..cols {
            reg.push(c, c, 1.0);
        }
        let solve = |rows: &[Row]| {
            let (a, b) = stack(rows, cols, nrhs);
            least_squares(&a, &b, Some((&reg, 1e-3)), &LsqOptions::default()).unwrap()
        };
        let (x0, x1) = (solve(&full), solve(&compressed));
        for k in 0..nrhs {
            for c in 0..cols {
                // Same normal equations up to rounding: agreement to ~1e-12
                // of the solution's scale (≈ 1); 1e-9 leaves room for the
                // condition number of the regularised system.
                assert!(
                    (x0[k][c] - x1[k][c]).abs() < 1e-9,
                    "rhs {k} col {c}: {} vs {}",
                    x0[k][c],
                    x1[k][c]
                );
            }
        }
        // The tied columns 0 and 1 get the same value, by symmetry.
        assert!((x1[0][0] - x1[0][1]).abs() < 1e-9);
    }

    #[test]
    fn short_groups_are_passed_through() {
        let rows: Vec<Row> = vec![
            (vec![(3, 1.0), (5, 2.0)], vec![1.0]),
            (vec![(5, -1.0)], vec![2.0]),
        ];
        assert_eq!(compress_groups(vec![rows.clone()], 1), rows);
    }
}
