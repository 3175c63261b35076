//! Regular Loop patches: the quartic three-direction box spline over the 12
//! control points around a triangle whose vertices are all regular (Stam
//! 1998, "Evaluation of Loop subdivision surfaces", §2: the limit surface
//! of a regular triangle is a quartic box-spline patch), with OpenSubdiv's
//! boundary variant: a triangle next to a boundary or an infinitely sharp
//! crease whose vertices there have three faces on its side gets phantom
//! points `a + b - c` (the reflection of the real triangle `(a, b, c)`
//! through the midpoint of the boundary edge `(a, b)`), under which the box
//! spline's own rules reproduce Sdc's crease rules (3/4, 1/8, 1/8 at the
//! vertices, 1/2, 1/2 on the edges) and the phantom row stays a reflection
//! after refinement, so the patch is exact there too.
//!
//! The basis functions are not transcribed from a table: they are derived
//! once from the subdivision rules themselves (see [`basis`]), so they
//! cannot disagree with the rules the rest of the evaluator applies.

use std::sync::OnceLock;

use crate::subdiv::catmark::topo::{key, Adj, Topo, INF};

/// Lattice positions `(i, j)` (the point `i·(v1 - v0) + j·(v2 - v0)` from
/// v0) of the 12 control points of the patch of triangle
/// `(0,0) (1,0) (0,1)`: its corners, then their other neighbours.
pub(crate) const LATTICE: [(i32, i32); 12] = [
    (0, 0),
    (1, 0),
    (0, 1),
    (-1, 0),
    (0, -1),
    (1, -1),
    (-1, 1),
    (2, 0),
    (1, 1),
    (2, -1),
    (0, 2),
    (-1, 2),
];

/// The six lattice directions around a vertex, counter-clockwise.
const DIRS: [(i32, i32); 6] = [(1, 0), (0, 1), (-1, 1), (-1, 0), (0, -1), (1, -1)];

/// A control point of a patch: a vertex of the local mesh, or a phantom
/// `a + b - c` beyond a boundary or crease edge `(a, b)`.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub(crate) enum Slot {
    Real(u32),
    Phantom(u32, u32, u32),
}

/// One step of regular Loop subdivision (Loop 1987: vertex 5/8 and 1/16,
/// edge 3/8 and 1/8) of values on a square array indexed by lattice
/// coordinates; the outermost rim comes out wrong and is never read.
fn refine_grid(g: &[Vec<f64>]) -> Vec<Vec<f64>> {
    let n = g.len();
    let m = 2 * n - 1;
    let at = |i: isize, j: isize| -> f64 {
        if i < 0 || j < 0 || i >= n as isize || j >= n as isize {
            0.0
        } else {
            g[i as usize][j as usize]
        }
    };
    let mut out = vec![vec![0.0; m]; m];
    for (a, row) in out.iter_mut().enumerate() {
        for (b, x) in row.iter_mut().enumerate() {
            let (i, j) = ((a / 2) as isize, (b / 2) as isize);
            *x = match (a % 2, b % 2) {
                (0, 0) => {
                    let ring: f64 = DIRS
                        .iter()
                        .map(|&(di, dj)| at(i + di as isize, j + dj as isize))
                        .sum();
                    0.625 * at(i, j) + 0.0625 * ring
                }
                // Edge (i, j)-(i+1, j): opposite (i, j+1) and (i+1, j-1).
                (1, 0) => {
                    0.375 * (at(i, j) + at(i + 1, j)) + 0.125 * (at(i, j + 1) + at(i + 1, j - 1))
                }
                // Edge (i, j)-(i, j+1): opposite (i+1, j) and (i-1, j+1).
                (0, 1) => {
                    0.375 * (at(i, j) + at(i, j + 1)) + 0.125 * (at(i + 1, j) + at(i - 1, j + 1))
                }
                // Edge (i+1, j)-(i, j+1): opposite (i, j) and (i+1, j+1).
                _ => 0.375 * (at(i + 1, j) + at(i, j + 1)) + 0.125 * (at(i, j) + at(i + 1, j + 1)),
            };
        }
    }
    out
}

/// Per basis function (control point `LATTICE[m]`), its limit at the 15
/// points `(i/4, j/4)` of the triangle (`i + j <= 4`, in [`NODES`] order):
/// two levels of regular subdivision of a unit impulse, then the regular
/// limit mask (1/2 and 1/12 each neighbour, Sdc `assignSmoothLimitMask`).
/// A quartic is determined by its values at these 15 points, so this is the
/// whole basis function on the triangle.
fn limit_values() -> [[f64; 15]; 12] {
    const O: i32 = 4; // lattice offset: coordinates -4..=5
    const N: usize = 10;
    let mut out = [[0.0; 15]; 12];
    for (m, &(li, lj)) in LATTICE.iter().enumerate() {
        let mut g = vec![vec![0.0; N]; N];
        g[(li + O) as usize][(lj + O) as usize] = 1.0;
        let g = refine_grid(&refine_grid(&g));
        let at = |i: i32, j: i32| g[(i + 4 * O) as usize][(j + 4 * O) as usize];
        for (n, &(i, j)) in NODES.iter().enumerate() {
            let ring: f64 = DIRS.iter().map(|&(di, dj)| at(i + di, j + dj)).sum();
            out[m][n] = 0.5 * at(i, j) + ring / 12.0;
        }
    }
    out
}

/// The degree-4 principal lattice of the triangle, `(i, j)` for `(i/4, j/4)`.
const NODES: [(i32, i32); 15] = [
    (0, 0),
    (1, 0),
    (2, 0),
    (3, 0),
    (4, 0),
    (0, 1),
    (1, 1),
    (2, 1),
    (3, 1),
    (0, 2),
    (1, 2),
    (2, 2),
    (0, 3),
    (1, 3),
    (0, 4),
];

/// The limit values of [`limit_values`], computed once.
fn basis() -> &'static [[f64; 15]; 12] {
    static B: OnceLock<[[f64; 15]; 12]> = OnceLock::new();
    B.get_or_init(limit_values)
}

/// `(value, d/du, d/dv)` of `Π_{a < k} (4x - a) / (k - a)` for `x` with
/// derivatives `dx`.
fn lagrange_factor(x: f64, dx: [f64; 2], k: i32) -> [f64; 3] {
    let mut r = [1.0, 0.0, 0.0];
    for a in 0..k {
        let d = (k - a) as f64;
        let f = (4.0 * x - a as f64) / d;
        let df = [4.0 * dx[0] / d, 4.0 * dx[1] / d];
        r = [r[0] * f, r[1] * f + r[0] * df[0], r[2] * f + r[0] * df[1]];
    }
    r
}

fn mul(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[0] * b[0],
        a[1] * b[0] + a[0] * b[1],
        a[2] * b[0] + a[0] * b[2],
    ]
}

/// Weights of the 12 control points ([`LATTICE`] order) at `(u, v)` for the
/// position and both derivatives: the basis functions in Lagrange form on
/// the 15 nodes (barycentric product formula, well conditioned).
pub(crate) fn box_spline_weights(u: f64, v: f64) -> [[f64; 12]; 3] {
    let w = 1.0 - u - v;
    let mut lag = [[0.0; 3]; 15];
    for (n, &(i, j)) in NODES.iter().enumerate() {
        let k = 4 - i - j;
        lag[n] = mul(
            mul(
                lagrange_factor(u, [1.0, 0.0], i),
                lagrange_factor(v, [0.0, 1.0], j),
            ),
            lagrange_factor(w, [-1.0, -1.0], k),
        );
    }
    let b = basis();
    let mut out = [[0.0; 12]; 3];
    for m in 0..12 {
        for n in 0..15 {
            for d in 0..3 {
                out[d][m] += b[m][n] * lag[n][d];
            }
        }
    }
    out
}

/// Neighbours of vertex `c` by lattice direction, starting with `n0` in
/// direction `d0`, or `None` when `c` is not regular: interior with six
/// faces and no sharpness, or on a boundary/infinitely sharp crease (two
/// such edges, every other edge smooth, no corner sharpness) with three
/// faces on this side — the two directions beyond it are phantoms.
fn vertex_dirs<P>(
    t: &Topo<P>,
    adj: &Adj,
    f0: u32,
    c: u32,
    n0: u32,
    d0: usize,
) -> Option<[Slot; 6]> {
    if t.vert_sharp(adj, c) != 0.0 {
        return None;
    }
    let wall = |x: u32| -> Option<bool> {
        let s = t.edge_sharp(adj, *adj.edge_id.get(&key(c, x))?);
        if s == 0.0 {
            Some(false)
        } else if s >= INF {
            Some(true)
        } else {
            None // semi-sharp: not regular
        }
    };
    let mut walls = 0;
    for &e in &adj.vedges[c as usize] {
        walls += wall(t.other(adj, e, c))? as usize;
    }
    if walls != 0 && walls != 2 {
        return None;
    }
    // Six faces all round (a valence dividing six would also walk the six
    // directions back to the start).
    if walls == 0 && (adj.vedges[c as usize].len() != 6 || adj.vfaces[c as usize].len() != 6) {
        return None;
    }
    let mut res: [Option<Slot>; 6] = [None; 6];
    res[d0] = Some(Slot::Real(n0));
    // The walks go from face to face across edges (`Adj::corner_edge`),
    // not by vertex pairs: two edges can join one pair of vertices.
    // Counter-clockwise from n0 to the first wall (or all the way round):
    // `f` holds the edge c → cur.
    let (mut cur, mut d, mut ccw_end, mut f) = (n0, d0, None, f0);
    for step in 0..6 {
        if walls > 0 && wall(cur)? && step > 0 {
            ccw_end = Some(d);
            break;
        }
        if step > 0 {
            // The face across the previous face's edge cur → c.
            let fv = t.face(f);
            let p = fv.iter().position(|&x| x == c)?;
            f = t.across(adj, f, (p + 2) % 3)?;
        }
        let fv = t.face(f);
        let p = fv.iter().position(|&x| x == c)?;
        let next = fv[(p + 2) % 3];
        d = (d + 1) % 6;
        if d == d0 {
            if walls > 0 || next != n0 {
                return None;
            }
            return Some(res.map(|s| s.expect("all six directions seen")));
        }
        res[d] = Some(Slot::Real(next));
        cur = next;
    }
    let a = ccw_end.or_else(|| (walls > 0 && wall(cur) == Some(true)).then_some(d))?;
    // Clockwise from n0 to the other wall (n0 may be it): `g` holds the
    // edge cur → c, the face across `f`'s edge c → cur.
    let (mut cur, mut d, mut f) = (n0, d0, f0);
    while !wall(cur)? {
        let fv = t.face(f);
        let p = fv.iter().position(|&x| x == c)?;
        let g = t.across(adj, f, p)?;
        let fv = t.face(g);
        let p = fv.iter().position(|&x| x == c)?;
        let prev = fv[(p + 1) % 3];
        f = g;
        d = (d + 5) % 6;
        if res[d].is_some() {
            return None;
        }
        res[d] = Some(Slot::Real(prev));
        cur = prev;
    }
    let b = d;
    if (a + 6 - b) % 6 != 3 {
        return None; // not three faces on this side
    }
    let real = |k: usize| match res[k] {
        Some(Slot::Real(i)) => Some(i),
        _ => None,
    };
    let (ra, ra1, rb, rb1) = (real(a)?, real((a + 5) % 6)?, real(b)?, real((b + 1) % 6)?);
    res[(a + 1) % 6] = Some(Slot::Phantom(c, ra, ra1));
    res[(a + 2) % 6] = Some(Slot::Phantom(c, rb, rb1));
    Some(res.map(|s| s.expect("three faces and two phantoms")))
}

/// Whether corner `k` of face `f` is a regular vertex for the patch of
/// that face (see [`regular_patch`]).
pub(crate) fn corner_is_regular<P>(t: &Topo<P>, adj: &Adj, f: u32, k: usize) -> bool {
    let fv = t.face(f);
    vertex_dirs(t, adj, f, fv[k], fv[(k + 1) % 3], 2 * k).is_some()
}

/// The 12 control points of face `f` of `t` (corners in the face's order
/// at `(0,0) (1,0) (0,1)`) when it is a regular patch, else `None`.
pub(crate) fn regular_patch<P>(t: &Topo<P>, adj: &Adj, f: u32) -> Option<[Slot; 12]> {
    let fv = t.face(f);
    if fv.len() != 3 {
        return None;
    }
    let corners = [
        ((0, 0), fv[0], fv[1], 0),
        ((1, 0), fv[1], fv[2], 2),
        ((0, 1), fv[2], fv[0], 4),
    ];
    let mut slots: [Option<Slot>; 12] = [None; 12];
    for ((ci, cj), c, n0, d0) in corners {
        let dirs = vertex_dirs(t, adj, f, c, n0, d0)?;
        let mut put = |pos: (i32, i32), s: Slot| -> Option<()> {
            let k = LATTICE.iter().position(|&l| l == pos)?;
            match (slots[k], s) {
                (None, _) => slots[k] = Some(s),
                (Some(Slot::Real(a)), Slot::Real(b)) if a == b => {}
                (Some(Slot::Phantom(..)), Slot::Phantom(..)) => {}
                _ => return None, // not locally a (half-)lattice
            }
            Some(())
        };
        put((ci, cj), Slot::Real(c))?;
        for (k, &(di, dj)) in DIRS.iter().enumerate() {
            put((ci + di, cj + dj), dirs[k])?;
        }
    }
    slots
        .iter()
        .all(|s| s.is_some())
        .then(|| slots.map(|s| s.expect("checked")))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The box spline is a partition of unity with linear precision, and
    /// at a corner it interpolates the regular limit mask (1/2, 1/12).
    #[test]
    fn basis_is_affine_and_matches_the_limit_mask() {
        for (u, v) in [(0.0, 0.0), (0.2, 0.3), (1.0, 0.0), (0.1, 0.85)] {
            let w = box_spline_weights(u, v);
            assert!((w[0].iter().sum::<f64>() - 1.0).abs() < 1e-14);
            assert!(w[1].iter().sum::<f64>().abs() < 1e-13);
            assert!(w[2].iter().sum::<f64>().abs() < 1e-13);
            let x: f64 = (0..12).map(|m| w[0][m] * LATTICE[m].0 as f64).sum();
            let y: f64 = (0..12).map(|m| w[0][m] * LATTICE[m].1 as f64).sum();
            assert!((x - u).abs() < 1e-14 && (y - v).abs() < 1e-14, "{x} {y}");
            let dx: f64 = (0..12).map(|m| w[1][m] * LATTICE[m].0 as f64).sum();
            assert!((dx - 1.0).abs() < 1e-12, "{dx}");
        }
        let w = box_spline_weights(0.0, 0.0);
        assert!((w[0][0] - 0.5).abs() < 1e-15);
        assert!((w[0][1] - 1.0 / 12.0).abs() < 1e-15);
        assert!(w[0][7].abs() < 1e-15);
    }
}
