//! Regular bicubic B-spline patches inside a [`Topo`]: recognising them,
//! gathering their 16 control points, and OpenSubdiv's boundary/corner
//! variants where infinitely sharp edges replace the missing rows with
//! "phantom" points mirrored through the edge (`P_-1 = 2 P_0 - P_1`), which
//! makes the uniform B-spline reproduce the crease rules exactly (the
//! boundary row's limit is the cubic B-spline curve of that row, and
//! `(2P0 - P1 + 6P0 + P1)/8 = ... ` turns the tensor vertex rule into the
//! 1-6-1 crease rule).
//!
//! Grid slots are `j * 4 + i`, `i` along the face's u and `j` along v; the
//! face's corners `c0..c3` sit at `(1,1) (2,1) (2,2) (1,2)`.

use super::topo::{key, Adj, Topo, INF};

/// Rotates grid coordinates by a quarter turn `k` times: `(i, j) -> (3 - j, i)`
/// maps the block of corner 0 onto the block of corner k.
pub(crate) const fn rot(k: usize, i: usize, j: usize) -> usize {
    let (mut i, mut j) = (i, j);
    let mut n = 0;
    while n < k % 4 {
        let ni = 3 - j;
        j = i;
        i = ni;
        n += 1;
    }
    j * 4 + i
}

/// Phantom rules `P[slot] = 2 P[a] - P[b]`, in evaluation order, for a patch
/// whose face edges `k` (from corner k to k+1) with bit k of `mask` set are
/// infinitely sharp.
pub(crate) fn phantom_rules(mask: u8) -> Vec<(u8, u8, u8)> {
    let mut r = Vec::new();
    for k in 0..4 {
        if mask & (1 << k) != 0 {
            r.push((rot(k, 1, 0) as u8, rot(k, 1, 1) as u8, rot(k, 1, 2) as u8));
            r.push((rot(k, 2, 0) as u8, rot(k, 2, 1) as u8, rot(k, 2, 2) as u8));
        }
    }
    for k in 0..4 {
        let next = mask & (1 << k) != 0;
        let prev = mask & (1 << ((k + 3) % 4)) != 0;
        if next {
            r.push((rot(k, 0, 0) as u8, rot(k, 0, 1) as u8, rot(k, 0, 2) as u8));
        } else if prev {
            r.push((rot(k, 0, 0) as u8, rot(k, 1, 0) as u8, rot(k, 2, 0) as u8));
        }
    }
    r
}

/// Uniform cubic B-spline basis and its derivative at `t`.
#[inline]
pub(crate) fn bspline(t: f64) -> ([f64; 4], [f64; 4]) {
    let s = 1.0 - t;
    let t2 = t * t;
    let t3 = t2 * t;
    (
        [
            s * s * s / 6.0,
            (3.0 * t3 - 6.0 * t2 + 4.0) / 6.0,
            (-3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0) / 6.0,
            t3 / 6.0,
        ],
        [
            -0.5 * s * s,
            0.5 * (3.0 * t2 - 4.0 * t),
            0.5 * (-3.0 * t2 + 2.0 * t + 1.0),
            0.5 * t2,
        ],
    )
}

/// Position and derivative weights of the 16 slots at `(s, t)`, phantom
/// slots folded into the real ones (their weight is left at 0).
#[inline]
pub(crate) fn patch_weights(s: f64, t: f64, rules: &[(u8, u8, u8)]) -> [[f64; 16]; 3] {
    let (bs, ds) = bspline(s);
    let (bt, dt) = bspline(t);
    let mut w = [[0.0; 16]; 3];
    for j in 0..4 {
        for i in 0..4 {
            w[0][j * 4 + i] = bs[i] * bt[j];
            w[1][j * 4 + i] = ds[i] * bt[j];
            w[2][j * 4 + i] = bs[i] * dt[j];
        }
    }
    for &(slot, a, b) in rules.iter().rev() {
        for arr in w.iter_mut() {
            let x = arr[slot as usize];
            arr[a as usize] += 2.0 * x;
            arr[b as usize] -= x;
            arr[slot as usize] = 0.0;
        }
    }
    w
}

fn is_inf(s: f64) -> bool {
    s >= INF
}

/// Position of `v` in the face's vertex list.
fn pos_in(face: &[u32], v: u32) -> Option<usize> {
    face.iter().position(|&x| x == v)
}

/// Whether corner `k` of quad `c` lets the patch be a (boundary) B-spline
/// patch, given the face edges' sharp `mask`.
fn corner_ok<P>(t: &Topo<P>, adj: &Adj, c: [u32; 4], k: usize, mask: u8) -> bool {
    let v = c[k];
    let vi = v as usize;
    let sv = t.vert_sharp(adj, v);
    if sv > 0.0 && !is_inf(sv) {
        return false;
    }
    let mut nsharp = 0;
    for &e in &adj.vedges[vi] {
        let s = t.edge_sharp(adj, e);
        if s > 0.0 && !is_inf(s) {
            return false;
        }
        if s > 0.0 {
            nsharp += 1;
        }
    }
    let next = mask & (1 << k) != 0;
    let prev = mask & (1 << ((k + 3) % 4)) != 0;
    let edge_inf = |a: u32, b: u32| {
        adj.edge_id
            .get(&key(a, b))
            .is_some_and(|&e| is_inf(t.edge_sharp(adj, e)))
    };
    match (prev, next) {
        (false, false) => {
            sv == 0.0
                && nsharp == 0
                && adj.vedges[vi].len() == 4
                && adj.vfaces[vi].len() == 4
                && adj.vfaces[vi].iter().all(|&f| t.face(f).len() == 4)
        }
        // Both face edges sharp: the corner must interpolate (corner rule
        // with nothing semi-sharp left), whatever lies on the other side.
        (true, true) => is_inf(sv) || nsharp >= 3,
        // One sharp face edge: a regular crease, the other sharp edge being
        // the continuation through the neighbouring quad on this side.
        (false, true) => {
            if sv != 0.0 || nsharp != 2 {
                return false;
            }
            let p = c[(k + 3) % 4];
            let Some(&g) = adj.directed.get(&(v, p)) else {
                return false;
            };
            let gv = t.face(g);
            if gv.len() != 4 {
                return false;
            }
            let Some(pos) = pos_in(gv, v) else {
                return false;
            };
            edge_inf(v, gv[(pos + 3) % 4])
        }
        (true, false) => {
            if sv != 0.0 || nsharp != 2 {
                return false;
            }
            let n = c[(k + 1) % 4];
            let Some(&h) = adj.directed.get(&(n, v)) else {
                return false;
            };
            let hv = t.face(h);
            if hv.len() != 4 {
                return false;
            }
            let Some(pos) = pos_in(hv, n) else {
                return false;
            };
            edge_inf(v, hv[(pos + 2) % 4])
        }
    }
}

/// Sharp mask of the face edges of quad `c`, `None` if one is semi-sharp.
pub(crate) fn edge_mask<P>(t: &Topo<P>, adj: &Adj, c: [u32; 4]) -> Option<u8> {
    let mut mask = 0u8;
    for k in 0..4 {
        let e = *adj.edge_id.get(&key(c[k], c[(k + 1) % 4]))?;
        let s = t.edge_sharp(adj, e);
        if is_inf(s) {
            mask |= 1 << k;
        } else if s > 0.0 {
            return None;
        }
    }
    Some(mask)
}

/// Whether corner `k` of face `f` (a quad) is regular for that face.
pub(crate) fn corner_is_regular<P>(t: &Topo<P>, adj: &Adj, f: u32, k: usize) -> bool {
    let fv = t.face(f);
    if fv.len() != 4 {
        return false;
    }
    let c = [fv[0], fv[1], fv[2], fv[3]];
    match edge_mask(t, adj, c) {
        Some(mask) => corner_ok(t, adj, c, k, mask),
        None => false,
    }
}

/// The 16 control slots (vertex ids of `t`, `u32::MAX` for phantoms) and
/// the sharp-edge mask of face `f` if it is a regular patch.
pub(crate) fn regular_grid<P>(t: &Topo<P>, adj: &Adj, f: u32) -> Option<([u32; 16], u8)> {
    let fv = t.face(f);
    if fv.len() != 4 {
        return None;
    }
    let c = [fv[0], fv[1], fv[2], fv[3]];
    let mask = edge_mask(t, adj, c)?;
    if !(0..4).all(|k| corner_ok(t, adj, c, k, mask)) {
        return None;
    }
    let mut g = [u32::MAX; 16];
    for k in 0..4 {
        g[rot(k, 1, 1)] = c[k];
    }
    // The quad across each smooth face edge `c_k -> c_k+1`: `(c_k+1, c_k, A, B)`.
    for k in 0..4 {
        if mask & (1 << k) == 0 {
            let n = c[(k + 1) % 4];
            let h = *adj.directed.get(&(n, c[k]))?;
            let hv = t.face(h);
            if hv.len() != 4 {
                return None;
            }
            let p = pos_in(hv, n)?;
            g[rot(k, 1, 0)] = hv[(p + 2) % 4];
            g[rot(k, 2, 0)] = hv[(p + 3) % 4];
        }
    }
    // Diagonal points at smooth corners: the quad `(A, c_k, C, D)`.
    for k in 0..4 {
        let next = mask & (1 << k) != 0;
        let prev = mask & (1 << ((k + 3) % 4)) != 0;
        if !next && !prev {
            let a = g[rot(k, 1, 0)];
            let d = *adj.directed.get(&(a, c[k]))?;
            let dv = t.face(d);
            if dv.len() != 4 {
                return None;
            }
            let p = pos_in(dv, a)?;
            if dv[(p + 2) % 4] != g[rot(k, 0, 1)] {
                return None;
            }
            g[rot(k, 0, 0)] = dv[(p + 3) % 4];
        }
    }
    Some((g, mask))
}
