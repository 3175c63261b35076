//! Step 3¾: folds of the flow-repaired lattice removed (Huang et al.,
//! "QuadriFlow", SGP 2018, §5.3, "flip removal"; the published source's
//! `Hierarchy::FixFlip`, read, not copied).
//!
//! After [`super::flow`] every non-singular triangle of M has integer
//! offsets that sum to zero, so the offsets are the differences of a
//! lattice map: each vertex sits on a lattice point. Where that map turns
//! a triangle clockwise (negative area in the lattice frame) the lattice
//! folds over itself; where three distinct lattice points of a triangle
//! are collinear it tears along a long edge. The extraction's faces walk
//! such places twice or not at all and the control mesh gets a
//! non-manifold vertex (measured before this step: bunny 123 folded
//! triangles after the flow, the repaired lattice rejected).
//!
//! QuadriFlow removes them with moves that keep every triangle's sum
//! zero: a lattice point is moved ("shrinking" a directed edge moves its
//! origin onto its end), which changes the offsets of all its edges
//! together, a gradient, so it is curl-free by construction. A move is
//! kept only if it lowers the number of bad triangles around it and no
//! edge becomes longer than one lattice step per axis. Here a move is
//! either one vertex of M (it changes which lattice point it samples) or
//! a whole lattice point (the vertices joined by zero offsets, moved
//! together in their own frames), onto a corner of the bad triangle or by
//! one unit step; among the moves that remove most bad triangles the one
//! whose offsets stay closest to the position field's real-valued ones
//! wins (the least change to what the field asked for). Vertices of the
//! cross field's singular triangles stay put: their offsets are 0 by the
//! flow's construction.

use std::collections::VecDeque;

use crate::DVec3;

use super::flow::{rot, triangle_sides, turn, Side};
use super::Surface;

/// What [`remove_flips`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct FlipReport {
    /// Triangles folded (negative area in the lattice) before and after.
    pub folded_before: usize,
    pub folded_after: usize,
    /// Triangles whose three distinct lattice points are collinear (a
    /// tear along an edge longer than one step), before and after.
    pub collinear_before: usize,
    pub collinear_after: usize,
    /// Moves kept, and edge offsets they changed.
    pub moves: usize,
    pub changed: usize,
}

/// Largest lattice point moved as a whole, in vertices of M (a lattice
/// point of a coarse layout on a dense M holds a few hundred; the bound
/// only keeps one move's cost local).
const MAX_CLUSTER: usize = 4096;

/// Passes over the bad triangles (each kept move removes at least one bad
/// triangle, so this only bounds the work where none can be removed).
const PASSES: usize = 8;

/// Removes folded and collinear triangles of the lattice given by
/// `offsets` (per edge of `s.edges`, after [`super::flow::repair_offsets`])
/// where a curl-free move can; `real` are the field's real-valued offsets
/// from [`super::flow::edge_offsets`].
pub fn remove_flips(
    s: &Surface,
    dirs: &[DVec3],
    offsets: &mut [[i64; 2]],
    real: &[[f64; 2]],
) -> FlipReport {
    let (sides, singular) = triangle_sides(s, dirs);
    remove_flips_on(s, dirs, &sides, &singular, offsets, real)
}

/// [`remove_flips`] on [`triangle_sides`]' result for `s` and `dirs`
/// (the offset repair's, [`super::flow::repair_offsets_on`]).
pub(super) fn remove_flips_on(
    s: &Surface,
    dirs: &[DVec3],
    sides: &[[Side; 3]],
    singular: &[bool],
    offsets: &mut [[i64; 2]],
    real: &[[f64; 2]],
) -> FlipReport {
    let net = Net::new(s, dirs, sides, singular);
    let mut report = FlipReport::default();
    let count = |offsets: &[[i64; 2]]| {
        let (mut folded, mut collinear) = (0, 0);
        for f in 0..sides.len() {
            match net.state(f, offsets) {
                Bad::Folded => folded += 1,
                Bad::Collinear => collinear += 1,
                Bad::No => {}
            }
        }
        (folded, collinear)
    };
    (report.folded_before, report.collinear_before) = count(offsets);
    let before = offsets.to_vec();
    for _ in 0..PASSES {
        let bad: Vec<usize> = (0..sides.len())
            .filter(|&f| net.state(f, offsets) != Bad::No)
            .collect();
        let mut progress = false;
        for f in bad {
            if net.state(f, offsets) == Bad::No {
                continue;
            }
            if let Some(mv) = net.best_move(f, offsets, real) {
                net.apply(&mv, offsets);
                report.moves += 1;
                progress = true;
            }
        }
        if !progress {
            break;
        }
    }
    (report.folded_after, report.collinear_after) = count(offsets);
    report.changed = before
        .iter()
        .zip(offsets.iter())
        .filter(|(a, b)| a != b)
        .count();
    report
}

/// How a triangle sits in the lattice.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Bad {
    No,
    Folded,
    Collinear,
}

/// A candidate move: vertices with their displacement, each in its own
/// lattice frame.
struct Move {
    shift: Vec<(u32, [i64; 2])>,
}

/// The mesh's incidences and frames the moves need.
struct Net<'a> {
    s: &'a Surface,
    sides: &'a [[Side; 3]],
    singular: &'a [bool],
    /// Per edge: the quarter turns k from its smaller vertex's frame to
    /// its larger one's (b's coordinates are a's turned by k).
    k: Vec<u8>,
    /// Per vertex: its edges and its triangles (CSR).
    vstart: Vec<usize>,
    vedges: Vec<u32>,
    tstart: Vec<usize>,
    vtris: Vec<u32>,
    /// Vertices of a singular triangle (their offsets are fixed at 0).
    frozen: Vec<bool>,
}

impl<'a> Net<'a> {
    fn new(s: &'a Surface, dirs: &[DVec3], sides: &'a [[Side; 3]], singular: &'a [bool]) -> Self {
        let n = s.len();
        let k = s
            .edges
            .iter()
            .map(|&[a, b]| turn(dirs, s, a as usize, b as usize))
            .collect();
        let csr = |pairs: Vec<(u32, u32)>| -> (Vec<usize>, Vec<u32>) {
            let mut start = vec![0usize; n + 1];
            for &(v, _) in &pairs {
                start[v as usize + 1] += 1;
            }
            for i in 0..n {
                start[i + 1] += start[i];
            }
            let mut fill = start.clone();
            let mut out = vec![0u32; pairs.len()];
            for (v, x) in pairs {
                out[fill[v as usize]] = x;
                fill[v as usize] += 1;
            }
            (start, out)
        };
        let (vstart, vedges) = csr(s
            .edges
            .iter()
            .enumerate()
            .flat_map(|(e, &[a, b])| [(a, e as u32), (b, e as u32)])
            .collect());
        let (tstart, vtris) = csr(s
            .triangles
            .iter()
            .enumerate()
            .flat_map(|(f, t)| t.map(|v| (v, f as u32)))
            .collect());
        let mut frozen = vec![false; n];
        for (f, t) in s.triangles.iter().enumerate() {
            if singular[f] {
                for &v in t {
                    frozen[v as usize] = true;
                }
            }
        }
        Net {
            s,
            sides,
            singular,
            k,
            vstart,
            vedges,
            tstart,
            vtris,
            frozen,
        }
    }

    /// A side's offset in its triangle's frame.
    fn side(&self, sd: &Side, offsets: &[[i64; 2]]) -> [i64; 2] {
        let x = rot(offsets[sd.edge as usize], sd.turn);
        [sd.sign * x[0], sd.sign * x[1]]
    }

    fn state(&self, f: usize, offsets: &[[i64; 2]]) -> Bad {
        if self.singular[f] {
            return Bad::No;
        }
        let [e0, e1, e2] = self.sides[f].map(|sd| self.side(&sd, offsets));
        // v0 → v1 is e0, v0 → v2 is −e2 (as flow::signed_area).
        let area = -(e0[0] * e2[1] - e0[1] * e2[0]);
        let zero = |e: [i64; 2]| e == [0, 0];
        if area < 0 {
            Bad::Folded
        } else if area == 0 && !zero(e0) && !zero(e1) && !zero(e2) {
            Bad::Collinear
        } else {
            Bad::No
        }
    }

    /// The triangle's offset sums (per axis, its frame).
    fn sum(&self, f: usize, offsets: &[[i64; 2]]) -> [i64; 2] {
        let mut s = [0, 0];
        for sd in &self.sides[f] {
            let x = self.side(sd, offsets);
            s[0] += x[0];
            s[1] += x[1];
        }
        s
    }

    /// `c` (coordinates in v's frame) in the frame of the other end of edge `e`.
    fn across(&self, e: usize, v: u32, c: [i64; 2]) -> [i64; 2] {
        if self.s.edges[e][0] == v {
            rot(c, self.k[e])
        } else {
            rot(c, (4 - self.k[e]) % 4)
        }
    }

    /// v's lattice point to w's (edge `e` joins them), in v's frame.
    fn toward(&self, e: usize, v: u32, offsets: &[[i64; 2]]) -> [i64; 2] {
        let x = offsets[e];
        if self.s.edges[e][0] == v {
            x
        } else {
            let y = rot(x, self.k[e]);
            [-y[0], -y[1]]
        }
    }

    /// The lattice point of `v`: the vertices joined to it by zero offsets,
    /// each with `d` (given in v's frame) turned into its own frame;
    /// `None` when it holds a frozen vertex, disagrees with itself around
    /// a loop, or is larger than [`MAX_CLUSTER`].
    fn cluster(&self, v: u32, d: [i64; 2], offsets: &[[i64; 2]]) -> Option<Vec<(u32, [i64; 2])>> {
        let mut out = vec![(v, d)];
        let mut seen = std::collections::HashMap::from([(v, d)]);
        let mut queue = VecDeque::from([(v, d)]);
        while let Some((u, du)) = queue.pop_front() {
            if self.frozen[u as usize] {
                return None;
            }
            for &e in &self.vedges[self.vstart[u as usize]..self.vstart[u as usize + 1]] {
                let e = e as usize;
                if offsets[e] != [0, 0] {
                    continue;
                }
                let [a, b] = self.s.edges[e];
                let w = if a == u { b } else { a };
                let dw = self.across(e, u, du);
                match seen.get(&w) {
                    Some(&x) if x != dw => return None,
                    Some(_) => {}
                    None => {
                        if out.len() >= MAX_CLUSTER {
                            return None;
                        }
                        seen.insert(w, dw);
                        out.push((w, dw));
                        queue.push_back((w, dw));
                    }
                }
            }
        }
        Some(out)
    }

    /// The edges a move changes, with their new offsets.
    fn changes(&self, mv: &Move, offsets: &[[i64; 2]]) -> Vec<(usize, [i64; 2])> {
        let mut shift: Vec<(u32, [i64; 2])> = mv.shift.clone();
        shift.sort_unstable_by_key(|x| x.0);
        let of = |v: u32| {
            shift
                .binary_search_by_key(&v, |x| x.0)
                .ok()
                .map(|i| shift[i].1)
        };
        let mut edges: Vec<usize> = shift
            .iter()
            .flat_map(|&(v, _)| {
                self.vedges[self.vstart[v as usize]..self.vstart[v as usize + 1]]
                    .iter()
                    .map(|&e| e as usize)
            })
            .collect();
        edges.sort_unstable();
        edges.dedup();
        edges
            .into_iter()
            .filter_map(|e| {
                let [a, b] = self.s.edges[e];
                let mut x = offsets[e];
                if let Some(d) = of(a) {
                    x = [x[0] - d[0], x[1] - d[1]];
                }
                if let Some(d) = of(b) {
                    let d = rot(d, (4 - self.k[e]) % 4);
                    x = [x[0] + d[0], x[1] + d[1]];
                }
                (x != offsets[e]).then_some((e, x))
            })
            .collect()
    }

    fn apply(&self, mv: &Move, offsets: &mut [[i64; 2]]) {
        for (e, x) in self.changes(mv, offsets) {
            offsets[e] = x;
        }
    }

    /// What a move does around it: (bad triangles removed, squared
    /// distance to the real offsets added), or `None` when it breaks a
    /// triangle's sum or stretches an edge beyond one step per axis.
    fn score(&self, mv: &Move, offsets: &mut [[i64; 2]], real: &[[f64; 2]]) -> Option<(i64, f64)> {
        let changes = self.changes(mv, offsets);
        if changes.is_empty() {
            return None;
        }
        let mut tris: Vec<u32> = mv
            .shift
            .iter()
            .flat_map(|&(v, _)| {
                self.vtris[self.tstart[v as usize]..self.tstart[v as usize + 1]]
                    .iter()
                    .copied()
            })
            .collect();
        tris.sort_unstable();
        tris.dedup();
        let bad = |offsets: &[[i64; 2]]| {
            tris.iter()
                .filter(|&&f| self.state(f as usize, offsets) != Bad::No)
                .count() as i64
        };
        let sums: Vec<[i64; 2]> = tris
            .iter()
            .map(|&f| self.sum(f as usize, offsets))
            .collect();
        let bad0 = bad(offsets);
        let mut dist = 0.0;
        let mut ok = true;
        let old: Vec<[i64; 2]> = changes.iter().map(|&(e, _)| offsets[e]).collect();
        for (&(e, x), o) in changes.iter().zip(&old) {
            let long = |x: [i64; 2]| x[0].abs().max(x[1].abs());
            ok &= long(x) <= long(*o).max(1);
            let d2 = |x: [i64; 2]| {
                (x[0] as f64 - real[e][0]).powi(2) + (x[1] as f64 - real[e][1]).powi(2)
            };
            dist += d2(x) - d2(*o);
            offsets[e] = x;
        }
        ok &= tris
            .iter()
            .zip(&sums)
            .all(|(&f, s0)| self.singular[f as usize] || self.sum(f as usize, offsets) == *s0);
        let bad1 = bad(offsets);
        for (&(e, _), o) in changes.iter().zip(&old) {
            offsets[e] = *o;
        }
        (ok && bad1 < bad0).then_some((bad0 - bad1, dist))
    }

    /// The best move that removes bad triangles around `f`, if any.
    fn best_move(&self, f: usize, offsets: &mut [[i64; 2]], real: &[[f64; 2]]) -> Option<Move> {
        let tri = self.s.triangles[f];
        let mut best: Option<((i64, f64), Move)> = None;
        for &v in &tri {
            if self.frozen[v as usize] {
                continue;
            }
            // Onto the other corners' lattice points, or one unit step.
            let mut steps: Vec<[i64; 2]> = vec![[1, 0], [-1, 0], [0, 1], [0, -1]];
            for &w in &tri {
                if w == v {
                    continue;
                }
                let e = self
                    .s
                    .edges
                    .binary_search(&[v.min(w), v.max(w)])
                    .expect("a triangle edge is an edge");
                let d = self.toward(e, v, offsets);
                if d != [0, 0] && !steps.contains(&d) {
                    steps.push(d);
                }
            }
            for d in steps {
                let single = Move {
                    shift: vec![(v, d)],
                };
                let whole = self.cluster(v, d, offsets).map(|shift| Move { shift });
                for mv in std::iter::once(single).chain(whole) {
                    let Some(sc) = self.score(&mv, offsets, real) else {
                        continue;
                    };
                    let better = match &best {
                        None => true,
                        Some((b, _)) => sc.0 > b.0 || (sc.0 == b.0 && sc.1 < b.1),
                    };
                    if better {
                        best = Some((sc, mv));
                    }
                }
            }
        }
        best.map(|(_, mv)| mv)
    }
}
