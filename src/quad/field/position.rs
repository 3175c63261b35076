//! Step 3: the position field (Jakob, Tarini, Panozzo, Sorkine-Hornung,
//! "Instant field-aligned meshes", SIGGRAPH Asia 2015, §5): per vertex a
//! point o_i of a local square lattice with axes (q_i, n_i × q_i) and
//! spacing s_i (the per-vertex scale of QuadriFlow's adaptive mode; an edge
//! compares its two lattices at the mean of their spacings). Smoothing
//! moves o_i to the average of its neighbours' nearest lattice points
//! (the extrinsic 4-PoSy rule of §5.2: lattice points compared near the
//! point of the two tangent planes closest to the edge's midpoint), then
//! rounds it to the lattice point nearest p_i.
//!
//! Convergence over many rings needs a hierarchy (§5.3, "multi-resolution
//! hierarchy"): vertices are merged in pairs along edges until few are
//! left, the coarsest level is smoothed first and each level starts from
//! its parent's lattice. Sweeps are sequential Gauss–Seidel in vertex
//! order: the result does not depend on the thread count.
//!
//! Boundary vertices keep a lattice line on M's boundary (Instant Meshes'
//! position constraint): after each update, o_i is moved across the
//! boundary tangent onto the line through p_i, so the extracted boundary
//! follows M's.

use crate::error::Result;
use crate::DVec3;

use super::cross::match_arm;
use super::Surface;

/// One level of the hierarchy (also the cross field's, [`super::cross`]).
pub(super) struct Level {
    pub(super) p: Vec<DVec3>,
    pub(super) n: Vec<DVec3>,
    pub(super) area: Vec<f64>,
    pub(super) q: Vec<DVec3>,
    pub(super) s: Vec<f64>,
    /// A point and tangent of M's boundary the lattice keeps a line on.
    pub(super) constraint: Vec<Option<(DVec3, DVec3)>>,
    pub(super) start: Vec<usize>,
    pub(super) nbr: Vec<u32>,
    /// Index of the parent in the next coarser level.
    pub(super) parent: Vec<u32>,
}

impl Level {
    pub(super) fn neighbours(&self, i: usize) -> &[u32] {
        &self.nbr[self.start[i]..self.start[i + 1]]
    }

    /// M's vertices as the finest level, with cross field `dirs` and
    /// spacing `scale`.
    pub(super) fn finest(surf: &Surface, dirs: &[DVec3], scale: &[f64]) -> Level {
        Level {
            p: surf.positions.clone(),
            n: surf.normals.clone(),
            area: surf.areas.clone(),
            q: dirs.to_vec(),
            s: scale.to_vec(),
            constraint: (0..surf.len())
                .map(|i| surf.boundary_tangent[i].map(|t| (surf.positions[i], t)))
                .collect(),
            start: surf.start.clone(),
            nbr: surf.nbr.clone(),
            parent: Vec::new(),
        }
    }
}

/// The pairwise-merge hierarchy above `finest` (§5.3), finest first:
/// merged until at most 64 vertices are left or a level no longer
/// shrinks by 10 %.
pub(super) fn hierarchy(finest: Level) -> Vec<Level> {
    let mut levels = vec![finest];
    while levels.last().map_or(0, |l| l.p.len()) > 64 {
        let (parent, coarse) = coarsen(levels.last().expect("one level"));
        if coarse.p.len() as f64 > 0.9 * levels.last().expect("one level").p.len() as f64 {
            break;
        }
        levels.last_mut().expect("one level").parent = parent;
        levels.push(coarse);
    }
    levels
}

/// The point nearest the midpoint of `p0`, `p1` on both tangent planes
/// (minimum-norm correction of the midpoint, a 2×2 system; nearly
/// parallel planes are regularised toward the midpoint).
#[inline]
pub fn middle(p0: DVec3, n0: DVec3, p1: DVec3, n1: DVec3) -> DVec3 {
    let m = 0.5 * (p0 + p1);
    let d = n0.dot(n1);
    let (r0, r1) = (n0.dot(m - p0), n1.dot(m - p1));
    let det = 1.0 - d * d + 1e-4;
    let l0 = (r0 - d * r1) / det;
    let l1 = (r1 - d * r0) / det;
    m - l0 * n0 - l1 * n1
}

/// The nearest pair of lattice points of two vertices (`q1` already the
/// arm matching `q0`), compared at spacing `s`: `(P0, P1, c0, c1)` with
/// `P = o + s (c.x q + c.y (n × q))`. The candidates are the corners of
/// each lattice's cell around [`middle`] (§5.2).
#[allow(clippy::too_many_arguments)]
#[inline]
pub fn compat_position(
    p0: DVec3,
    n0: DVec3,
    q0: DVec3,
    o0: DVec3,
    p1: DVec3,
    n1: DVec3,
    q1: DVec3,
    o1: DVec3,
    s: f64,
) -> (DVec3, DVec3, [i64; 2], [i64; 2]) {
    let (t0, t1) = (n0.cross(q0), n1.cross(q1));
    let m = middle(p0, n0, p1, n1);
    compat_at(m, [q0, t0, o0], [q1, t1, o1], [s, s])
}

/// [`compat_position`] with the edge's [`middle`] `m` and each side's
/// lattice `[q, n × q, o]` given (the first two and `m` do not change
/// between sweeps, [`sweep`] computes them once per level).
#[inline]
fn compat_at(
    m: DVec3,
    [q0, t0, o0]: [DVec3; 3],
    [q1, t1, o1]: [DVec3; 3],
    [s0, s1]: [f64; 2],
) -> (DVec3, DVec3, [i64; 2], [i64; 2]) {
    let floor = |o: DVec3, q: DVec3, t: DVec3, s: f64| {
        let d = m - o;
        [floor_i64(q.dot(d) / s), floor_i64(t.dot(d) / s)]
    };
    let (b0, b1) = (floor(o0, q0, t0, s0), floor(o1, q1, t1, s1));
    // Each side's four cell corners once (the same expressions as
    // evaluated per pair before: the same bits), then the 16 pairs in
    // the same order, so the same first-found least distance.
    let corners = |b: [i64; 2], o: DVec3, q: DVec3, t: DVec3, s: f64| {
        std::array::from_fn::<_, 4, _>(|k| {
            let c = [b[0] + (k as i64 & 1), b[1] + (k as i64 >> 1)];
            (c, o + s * (c[0] as f64 * q + c[1] as f64 * t))
        })
    };
    let (x0s, x1s) = (corners(b0, o0, q0, t0, s0), corners(b1, o1, q1, t1, s1));
    let mut best = (f64::INFINITY, DVec3::ZERO, DVec3::ZERO, b0, b1);
    for &(c0, x0) in &x0s {
        for &(c1, x1) in &x1s {
            let d = (x0 - x1).length_squared();
            if d < best.0 {
                best = (d, x0, x1, c0, c1);
            }
        }
    }
    (best.1, best.2, best.3, best.4)
}

/// `x.floor() as i64` without the call: the default x86-64 target has
/// no rounding instruction (SSE4.1), so `f64::floor` is a libm call, and
/// the position field's cell search floors four times per edge and sweep
/// (issue 40's speed point, session 24: ~1.7 % of gargoyle 402's CPU
/// under `SUBDFIT_FIELD_BEST=lean`, docs/status.md). The truncation
/// `x as i64` is exact for |x| < 2⁶³ and rounds toward zero, so one less
/// where it lies above `x`; NaN gives 0 and values beyond the range
/// saturate, as the cast of `floor` does (`tests::floor_i64_is_floor`).
#[inline]
pub(super) fn floor_i64(x: f64) -> i64 {
    let t = x as i64;
    if (t as f64) > x {
        t.saturating_sub(1)
    } else {
        t
    }
}

/// The lattice point of (o, q, n, s) nearest `p` (§5.2's rounding).
#[inline]
pub fn round_to(o: DVec3, q: DVec3, n: DVec3, s: f64, p: DVec3) -> DVec3 {
    let t = n.cross(q);
    let d = p - o;
    o + s * ((q.dot(d) / s).round() * q + (t.dot(d) / s).round() * t)
}

/// The position field: per vertex of M a lattice point near it.
pub fn position_field(
    surf: &Surface,
    dirs: &[DVec3],
    scale: &[f64],
    sweeps: usize,
) -> Result<Vec<DVec3>> {
    let levels = hierarchy(Level::finest(surf, dirs, scale));
    let top = levels.len() - 1;
    let mut o = levels[top].p.clone();
    for l in (0..=top).rev() {
        if l < top {
            let fine = &levels[l];
            let coarse_o = o;
            o = (0..fine.p.len())
                .map(|i| {
                    let po = coarse_o[fine.parent[i] as usize];
                    let po = po - fine.n[i] * fine.n[i].dot(po - fine.p[i]);
                    round_to(po, fine.q[i], fine.n[i], fine.s[i], fine.p[i])
                })
                .collect();
        }
        let edges = EdgeTerms::new(&levels[l]);
        for _ in 0..sweeps.max(1) {
            sweep(&levels[l], &edges, &mut o);
        }
    }
    Ok(o)
}

/// What the position rule reads of each directed edge (i, j) of a level
/// that no sweep changes, in `nbr` order: j's arm matched to i's, its
/// `n × q`, the edge's [`middle`] and mean spacing. Computed once per
/// level instead of once per sweep (the same values, so the same sweeps).
struct EdgeTerms {
    q: Vec<DVec3>,
    t: Vec<DVec3>,
    m: Vec<DVec3>,
    s: Vec<[f64; 2]>,
}

/// `FIELD_POSITION_OWN_SCALE` (off by default; issue 40's adaptivity):
/// each side of an edge compares its own lattice at its own spacing (as
/// QuadriFlow's extrinsic position rule takes a scale per side) instead
/// of both at the edge's mean spacing.
fn own_scale() -> bool {
    crate::switches::set("FIELD_POSITION_OWN_SCALE")
}

impl EdgeTerms {
    fn new(l: &Level) -> EdgeTerms {
        let k = l.nbr.len();
        let mut e = EdgeTerms {
            q: Vec::with_capacity(k),
            t: Vec::with_capacity(k),
            m: Vec::with_capacity(k),
            s: Vec::with_capacity(k),
        };
        let own = own_scale();
        for i in 0..l.p.len() {
            for &j in l.neighbours(i) {
                let j = j as usize;
                let (qj, _) = match_arm(l.q[i], l.q[j], l.n[j]);
                e.q.push(qj);
                e.t.push(l.n[j].cross(qj));
                e.m.push(middle(l.p[i], l.n[i], l.p[j], l.n[j]));
                e.s.push(if own {
                    [l.s[i], l.s[j]]
                } else {
                    [0.5 * (l.s[i] + l.s[j]); 2]
                });
            }
        }
        e
    }
}

/// One Gauss–Seidel sweep of the position rule over a level.
///
/// Sequential (issue 39): each update reads its neighbours' updated
/// lattices. A bit-exact parallel schedule (steps of updates no two of
/// which are neighbours) was measured in session 24 (branch
/// `s24-fieldpar`): the steps hold ~350 updates each on bunny, too few for
/// the hand-over between two threads to pay (no wall saved on a quiet
/// host, +15–27 % CPU).
fn sweep(l: &Level, e: &EdgeTerms, o: &mut [DVec3]) {
    for i in 0..l.p.len() {
        let (pi, ni, qi) = (l.p[i], l.n[i], l.q[i]);
        let ti = ni.cross(qi);
        let mut sum = o[i];
        let mut weight = 0.0;
        for k in l.start[i]..l.start[i + 1] {
            let j = l.nbr[k] as usize;
            let (xi, xj, _, _) = compat_at(e.m[k], [qi, ti, sum], [e.q[k], e.t[k], o[j]], e.s[k]);
            // Running mean in i's shifted lattice (Instant Meshes §5.2).
            sum = (xi * weight + xj) / (weight + 1.0);
            weight += 1.0;
            sum -= ni * ni.dot(sum - pi);
        }
        if let Some((c, t)) = l.constraint[i] {
            let side = ni.cross(t);
            sum -= side * side.dot(sum - c);
        }
        o[i] = round_to(sum, qi, ni, l.s[i], pi);
    }
}

/// Pairs of neighbours merged into one coarse vertex (greedy matching by
/// normal agreement, then smaller combined area; deterministic order),
/// unmatched vertices copied. Returns the parent map and the coarse level.
fn coarsen(l: &Level) -> (Vec<u32>, Level) {
    let n = l.p.len();
    let mut cand: Vec<(f64, u32, u32)> = Vec::new();
    for i in 0..n {
        for &j in l.neighbours(i) {
            if (j as usize) > i {
                let score = l.n[i].dot(l.n[j as usize]) / (l.area[i] + l.area[j as usize] + 1e-300);
                cand.push((score, i as u32, j));
            }
        }
    }
    cand.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
    let mut parent = vec![u32::MAX; n];
    let mut groups: Vec<Vec<u32>> = Vec::new();
    for &(_, i, j) in &cand {
        if parent[i as usize] == u32::MAX && parent[j as usize] == u32::MAX {
            parent[i as usize] = groups.len() as u32;
            parent[j as usize] = groups.len() as u32;
            groups.push(vec![i, j]);
        }
    }
    for (i, p) in parent.iter_mut().enumerate() {
        if *p == u32::MAX {
            *p = groups.len() as u32;
            groups.push(vec![i as u32]);
        }
    }
    let mut c = Level {
        p: Vec::with_capacity(groups.len()),
        n: Vec::with_capacity(groups.len()),
        area: Vec::with_capacity(groups.len()),
        q: Vec::with_capacity(groups.len()),
        s: Vec::with_capacity(groups.len()),
        constraint: Vec::with_capacity(groups.len()),
        start: Vec::new(),
        nbr: Vec::new(),
        parent: Vec::new(),
    };
    for g in &groups {
        let (mut a, mut p, mut nn, mut s) = (0.0, DVec3::ZERO, DVec3::ZERO, 0.0);
        for &v in g {
            let v = v as usize;
            let w = l.area[v].max(1e-300);
            a += w;
            p += w * l.p[v];
            nn += w * l.n[v];
            s += w * l.s[v];
        }
        let nn = nn.normalize_or(l.n[g[0] as usize]);
        let q0 = l.q[g[0] as usize];
        let mut q = q0;
        for &v in &g[1..] {
            q += match_arm(q0, l.q[v as usize], l.n[v as usize]).0;
        }
        let q = (q - nn * nn.dot(q)).normalize_or(nn.any_orthonormal_vector());
        c.p.push(p / a);
        c.n.push(nn);
        c.area.push(a);
        c.q.push(q);
        c.s.push(s / a);
        c.constraint
            .push(g.iter().find_map(|&v| l.constraint[v as usize]));
    }
    let mut pairs: Vec<(u32, u32)> = Vec::new();
    for i in 0..n {
        for &j in l.neighbours(i) {
            let (a, b) = (parent[i], parent[j as usize]);
            if a != b {
                pairs.push((a, b));
            }
        }
    }
    pairs.sort_unstable();
    pairs.dedup();
    c.start = vec![0; groups.len() + 1];
    for &(a, _) in &pairs {
        c.start[a as usize + 1] += 1;
    }
    for k in 0..groups.len() {
        c.start[k + 1] += c.start[k];
    }
    c.nbr = pairs.iter().map(|&(_, b)| b).collect();
    (parent, c)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Deterministic values in `[-s, s]` (a 64-bit LCG).
    fn values(n: usize, s: f64, mut x: u64) -> Vec<f64> {
        (0..n)
            .map(|_| {
                x = x
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                ((x >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0) * s
            })
            .collect()
    }

    /// [`floor_i64`] is `floor` then the saturating cast, for every kind
    /// of value: integers and their neighbours one ulp away, halves,
    /// signed zeros, the ends of the i64 range and beyond, infinities,
    /// NaN, and scattered values at several magnitudes.
    #[test]
    fn floor_i64_is_floor() {
        let mut xs = vec![
            0.0,
            -0.0,
            0.5,
            -0.5,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
            i64::MAX as f64,
            i64::MIN as f64,
            1e300,
            -1e300,
            (1u64 << 52) as f64 + 0.5,
            -((1u64 << 52) as f64) - 0.5,
            f64::MIN_POSITIVE,
            -f64::MIN_POSITIVE,
        ];
        for k in -40i64..=40 {
            let x = k as f64;
            xs.extend([x, x.next_up(), x.next_down(), x + 0.5]);
        }
        for s in [1.0, 1e3, 1e9, 1e17, 1e20] {
            xs.extend(values(2000, s, 7));
        }
        for x in xs {
            assert_eq!(floor_i64(x), x.floor() as i64, "{x:e}");
        }
    }

    /// The cell search as it was before issue 40's session 24 cut (each
    /// pair's corners evaluated inside the loop, `f64::floor`).
    fn compat_at_reference(
        m: DVec3,
        [q0, t0, o0]: [DVec3; 3],
        [q1, t1, o1]: [DVec3; 3],
        [s0, s1]: [f64; 2],
    ) -> (DVec3, DVec3, [i64; 2], [i64; 2]) {
        let floor = |o: DVec3, q: DVec3, t: DVec3, s: f64| {
            let d = m - o;
            [(q.dot(d) / s).floor() as i64, (t.dot(d) / s).floor() as i64]
        };
        let (b0, b1) = (floor(o0, q0, t0, s0), floor(o1, q1, t1, s1));
        let mut best = (f64::INFINITY, DVec3::ZERO, DVec3::ZERO, b0, b1);
        for k0 in 0..4 {
            let c0 = [b0[0] + (k0 & 1), b0[1] + (k0 >> 1)];
            let x0 = o0 + s0 * (c0[0] as f64 * q0 + c0[1] as f64 * t0);
            for k1 in 0..4 {
                let c1 = [b1[0] + (k1 & 1), b1[1] + (k1 >> 1)];
                let x1 = o1 + s1 * (c1[0] as f64 * q1 + c1[1] as f64 * t1);
                let d = (x0 - x1).length_squared();
                if d < best.0 {
                    best = (d, x0, x1, c0, c1);
                }
            }
        }
        (best.1, best.2, best.3, best.4)
    }

    /// The cell search gives the reference's pair bit for bit: for
    /// scattered edges with unit or arbitrary arms (ties between equally
    /// near pairs go to the first, both ways), at spacings from far below
    /// to far above the edge length, and with the lattice origins on cell
    /// corners (where the floors sit on integers).
    #[test]
    fn compat_at_matches_the_per_pair_search() {
        let v = values(9 * 4000, 2.0, 11);
        let bits = |x: DVec3| x.to_array().map(f64::to_bits);
        let mut distinct = std::collections::HashSet::new();
        for (i, w) in v.chunks(9).enumerate() {
            let p = |k: usize| DVec3::new(w[k], w[k + 1], w[k + 2]);
            let (n0, n1) = (p(0).normalize_or(DVec3::Z), p(3).normalize_or(DVec3::X));
            let q0 = n0.any_orthonormal_vector();
            let q1 = if i % 3 == 0 {
                q0
            } else {
                n1.any_orthonormal_vector()
            };
            let (t0, t1) = (n0.cross(q0), n1.cross(q1));
            let m = p(6);
            let s = [0.01, 0.3, 1.0, 7.0][i % 4];
            let (o0, o1) = if i % 5 == 0 {
                (m + s * q0, m - 2.0 * s * t1)
            } else {
                (p(3) * 0.5, p(0) * 0.25)
            };
            let ss = if i % 7 == 0 { [s, 1.5 * s] } else { [s, s] };
            let a = compat_at(m, [q0, t0, o0], [q1, t1, o1], ss);
            let b = compat_at_reference(m, [q0, t0, o0], [q1, t1, o1], ss);
            assert_eq!(
                (bits(a.0), bits(a.1), a.2, a.3),
                (bits(b.0), bits(b.1), b.2, b.3)
            );
            distinct.insert((a.2, a.3));
        }
        // Not one cell for every query: the search does move.
        assert!(distinct.len() > 100, "{}", distinct.len());
    }
}
