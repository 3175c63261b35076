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

/// One group's factor `Lᵀ` ([`compress`]), a function of the group's rows'
/// entries only, not of their right-hand sides: `samples` names the rows
/// (the fit's sample indices), whose entries the caller guarantees are the
/// same whenever the names are.
pub(crate) struct Factor {
    samples: Vec<u32>,
    cols: Vec<u32>,
    /// Row-major `c × c`, `Lᵀ` in the upper triangle of the kept rows.
    lt: Vec<f64>,
    kept: Vec<bool>,
    /// Each row's entries summed per local column, in column order
    /// (`local[at[r]..at[r + 1]]`, `value[..]`): `Aᵀb` of a later round
    /// from them is the sum [`right_sides`] forms, term for term.
    at: Vec<u32>,
    local: Vec<u32>,
    value: Vec<f64>,
}

/// The factors of one series of solves over the same rows' entries (one
/// start of the point objective's fit: its stencils are the system's,
/// only the targets move), keyed by each group's first sample. A round
/// whose group has the same samples as the last round that factored it
/// reuses the factor and only forms `Aᵀb` and its forward substitution:
/// the Gram products and the Cholesky factorisation are pure functions of
/// the entries, so the rows returned are the same bits as a fresh
/// [`compress`] (measured: ~0.95 of rung 1's ~5 CPU s of fit are the
/// compression, docs/status.md, session 24).
#[derive(Default)]
pub(crate) struct FactorCache {
    by_first: std::sync::Mutex<std::collections::HashMap<u32, std::sync::Arc<Factor>>>,
}

/// [`compress_groups`] of the groups named by `samples` (group `g` holds
/// one row per sample of `samples[g]`, in order: `entries(i)` and
/// `rhs(i)`, `nrhs` values), the factors taken from and left in `cache`:
/// the same rows, bit for bit. A reused factor's group never forms its
/// rows' entries.
pub(crate) fn compress_groups_cached(
    samples: Vec<Vec<u32>>,
    entries: impl Fn(u32) -> Vec<(u32, f64)> + Sync,
    rhs: impl Fn(u32) -> Vec<f64> + Sync,
    nrhs: usize,
    cache: &FactorCache,
) -> Vec<Row> {
    use std::sync::Arc;
    let old = std::mem::take(&mut *cache.by_first.lock().unwrap_or_else(|e| e.into_inner()));
    let done: Vec<(Vec<Row>, Option<Arc<Factor>>)> = samples
        .into_par_iter()
        .map(|names| {
            let reuse = names
                .first()
                .and_then(|f| old.get(f))
                .filter(|f| f.samples == names)
                .cloned();
            let f = match reuse {
                Some(f) => f,
                None => {
                    let rows: Vec<Row> = names.iter().map(|&i| (entries(i), rhs(i))).collect();
                    match factor(&rows, names) {
                        None => return (rows, None),
                        Some(f) => Arc::new(f),
                    }
                }
            };
            let atb = stored_right_sides(&f, &rhs, nrhs);
            (factored_rows(&f, atb, nrhs), Some(f))
        })
        .collect();
    drop(old);
    let mut next = std::collections::HashMap::with_capacity(done.len());
    let mut out = Vec::new();
    for (rows, f) in done {
        if let Some(f) = f {
            if let Some(&first) = f.samples.first() {
                next.insert(first, f);
            }
        }
        out.extend(rows);
    }
    *cache.by_first.lock().unwrap_or_else(|e| e.into_inner()) = next;
    out
}

/// [`right_sides`] from a factor's stored rows and `rhs` of its samples.
fn stored_right_sides(f: &Factor, rhs: &impl Fn(u32) -> Vec<f64>, nrhs: usize) -> Vec<f64> {
    let mut atb = vec![0.0; f.cols.len() * nrhs];
    for (r, &s) in f.samples.iter().enumerate() {
        let b = rhs(s);
        let span = f.at[r] as usize..f.at[r + 1] as usize;
        for (&i, &vi) in f.local[span.clone()].iter().zip(&f.value[span]) {
            let i = i as usize;
            for (k, &b) in b.iter().enumerate() {
                atb[i * nrhs + k] += vi * b;
            }
        }
    }
    atb
}

/// One group (module docs).
fn compress(rows: Vec<Row>, nrhs: usize) -> Vec<Row> {
    match factor(&rows, Vec::new()) {
        None => rows,
        Some(f) => {
            let atb = right_sides(&rows, &f.cols, nrhs);
            factored_rows(&f, atb, nrhs)
        }
    }
}

/// The group's columns, and whether it has more rows than columns (else
/// it is passed through as it is).
fn group_columns(rows: &[Row]) -> Option<Vec<u32>> {
    let mut cols: Vec<u32> = rows.iter().flat_map(|r| r.0.iter().map(|e| e.0)).collect();
    cols.sort_unstable();
    cols.dedup();
    (rows.len() > cols.len()).then_some(cols)
}

/// Visits each row's entries summed per local column (duplicates add up,
/// in the row's order), as `(local column, value)` in column order.
fn each_dense_row(rows: &[Row], cols: &[u32], mut visit: impl FnMut(&[usize], &[f64], &[f64])) {
    let c = cols.len();
    let local = |col: u32| cols.binary_search(&col).expect("column of the group");
    let mut dense = vec![0.0; c];
    let mut seen = vec![false; c];
    let mut nz: Vec<usize> = Vec::with_capacity(c);
    for (entries, rhs) in rows {
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
        visit(&nz, &dense, rhs);
        for &j in &nz {
            dense[j] = 0.0;
            seen[j] = false;
        }
    }
}

/// `Aᵀb` of the group over its columns `cols`, row after row.
fn right_sides(rows: &[Row], cols: &[u32], nrhs: usize) -> Vec<f64> {
    let mut atb = vec![0.0; cols.len() * nrhs];
    each_dense_row(rows, cols, |nz, dense, rhs| {
        for &i in nz {
            let vi = dense[i];
            for (k, &b) in rhs.iter().enumerate() {
                atb[i * nrhs + k] += vi * b;
            }
        }
    });
    atb
}

/// The Gram matrix `G = AᵀA` of the group and its Cholesky factor (module
/// docs); `None` when the group is passed through.
fn factor(rows: &[Row], samples: Vec<u32>) -> Option<Factor> {
    let cols = group_columns(rows)?;
    let c = cols.len();
    // Gram matrix G = AᵀA (upper triangle, row-major c × c).
    let mut g = vec![0.0; c * c];
    // The dense rows, kept only for a named group (a cached one).
    let keep = !samples.is_empty();
    let (mut at, mut local, mut value) = (vec![0u32], Vec::new(), Vec::new());
    each_dense_row(rows, &cols, |nz, dense, _| {
        for (a, &i) in nz.iter().enumerate() {
            let vi = dense[i];
            for &j in &nz[a..] {
                g[i * c + j] += vi * dense[j];
            }
            if keep {
                local.push(i as u32);
                value.push(vi);
            }
        }
        if keep {
            at.push(local.len() as u32);
        }
    });
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
    }
    Some(Factor {
        samples,
        cols,
        lt: g,
        kept,
        at,
        local,
        value,
    })
}

/// The compressed rows `Lᵀ`, `d = L⁻¹ Aᵀb` of a factored group.
fn factored_rows(f: &Factor, mut atb: Vec<f64>, nrhs: usize) -> Vec<Row> {
    let (c, g, kept) = (f.cols.len(), &f.lt, &f.kept);
    // d_i = (Aᵀb_i − Σ_k L_ik d_k) / L_ii, forward substitution.
    for i in (0..c).filter(|&i| kept[i]) {
        let l = g[i * c + i];
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
                .map(|j| (f.cols[j], g[i * c + j]))
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

    /// A row's bit patterns: entries (column, value bits), right-hand sides.
    type RowBits = (Vec<(u32, u64)>, Vec<u64>);

    /// Bit patterns of rows, for exact comparisons.
    fn bits(rows: &[Row]) -> Vec<RowBits> {
        rows.iter()
            .map(|(e, b)| {
                (
                    e.iter().map(|&(c, v)| (c, v.to_bits())).collect(),
                    b.iter().map(|v| v.to_bits()).collect(),
                )
            })
            .collect()
    }

    /// Each group named by its rows' indices (one row a sample).
    fn names(groups: &[Vec<Row>]) -> Vec<Vec<u32>> {
        let mut next = 0u32;
        groups
            .iter()
            .map(|g| {
                let n: Vec<u32> = (next..next + g.len() as u32).collect();
                next += g.len() as u32;
                n
            })
            .collect()
    }

    /// [`compress_groups_cached`] over `groups` named by `names` (row `p`
    /// of group `g` is named `names[g][p]`).
    fn cached(groups: &[Vec<Row>], names: &[Vec<u32>], nrhs: usize, c: &FactorCache) -> Vec<Row> {
        let by_name = |i: u32| -> &Row {
            let (g, p) = names
                .iter()
                .enumerate()
                .find_map(|(g, n)| n.iter().position(|&x| x == i).map(|p| (g, p)))
                .expect("a named row");
            &groups[g][p]
        };
        compress_groups_cached(
            names.to_vec(),
            |i| by_name(i).0.clone(),
            |i| by_name(i).1.clone(),
            nrhs,
            c,
        )
    }

    #[test]
    fn cached_factors_give_the_fresh_rows_bit_for_bit() {
        let (groups, per, width, nrhs) = (6, 60, 12, 3);
        let cache = FactorCache::default();
        let first = system(groups, per, width, nrhs);
        let n0 = names(&first);
        let got = cached(&first, &n0, nrhs, &cache);
        assert_eq!(bits(&got), bits(&compress_groups(first.clone(), nrhs)));
        // The next round: the same entries, new right-hand sides; group 2
        // loses its last sample (a new name: factored afresh).
        let mut s = 99u64;
        let mut second = first.clone();
        for g in &mut second {
            for r in g.iter_mut() {
                r.1 = (0..nrhs).map(|_| rng(&mut s)).collect();
            }
        }
        second[2].pop();
        let mut n1 = n0.clone();
        n1[2].pop();
        let fresh = compress_groups(second.clone(), nrhs);
        let got = cached(&second, &n1, nrhs, &cache);
        assert_eq!(bits(&got), bits(&fresh));
        // The right-hand sides did change the rows (the comparison is not
        // between two copies of the first round).
        assert_ne!(bits(&fresh), bits(&compress_groups(first, nrhs)));
        // The factors are reused, not recomputed: entries changed under an
        // unchanged name (which the fit never does) keep the old factor's
        // rows' entries, while a fresh compression sees the new ones.
        let mut third = second.clone();
        for r in third[0].iter_mut() {
            for e in r.0.iter_mut() {
                e.1 *= 2.0;
            }
        }
        let got = cached(&third, &n1, nrhs, &cache);
        let fresh = compress_groups(third, nrhs);
        let k = fresh.len().min(got.len());
        assert_ne!(bits(&got[..k]), bits(&fresh[..k]));
        // A group passed through (fewer rows than columns) stays as it is.
        let short: Vec<Row> = vec![(vec![(3, 1.0), (5, 2.0)], vec![1.0])];
        let got = cached(std::slice::from_ref(&short), &[vec![0]], 1, &cache);
        assert_eq!(got, short);
    }
}
