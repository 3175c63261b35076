//! Step 3½: integer lattice offsets made consistent by a flow (Huang, Zhou,
//! Zhang, Tang, Ye, Guibas, Nießner, "QuadriFlow: a scalable and robust
//! method for quadrangulation", SGP 2018, §5).
//!
//! The position field gives every edge (a, b) of M an integer offset
//! x_ab ∈ ℤ²: where b's lattice point lies from a's, in a's lattice
//! ([`edge_offsets`], the same nearest-pair rule the extraction uses).
//! A lattice that tiles the surface has, in every triangle, offsets that
//! sum to zero per axis once written in one frame; where a sum is not
//! zero the rounded field has a dislocation there, and the extracted
//! lattice gets a pair of non-quads (an irregular pair after the pure-quad
//! repair). QuadriFlow's remedy: the sums are the excesses of a network
//! whose nodes are (triangle, axis) equations and whose arcs are the
//! interior edges' offset components (a unit change of an edge moves one
//! unit from one of its triangles' equations to the other's), and a
//! maximum flow from the positive sums to the negative ones changes the
//! fewest-hop set of offsets that zeroes them ([`repair_offsets`]).
//!
//! Writing every triangle in one frame: each triangle's frame is its first
//! vertex's lattice turned by t_f quarter turns, with t_f propagated over
//! a spanning tree of the triangles that avoids the cross field's singular
//! triangles (QuadriFlow's `BuildIntegerConstraints` does the same with a
//! disjoint-set tree), so that an edge between two triangles of the tree
//! enters both equations along the same axis with opposite signs: an arc.
//! Edges where the frames disagree (the cuts around singularities) and
//! M's boundary edges keep their offsets.
//!
//! The maximum flow is Dinic's (shortest augmenting paths first: each
//! dislocation is fixed by the offsets between it and its nearest partner),
//! with arcs in a fixed order: the result does not depend on the thread
//! count.

use std::collections::VecDeque;

use crate::watch::thread_cpu_seconds;
use crate::DVec3;

use super::cross::match_arm;
use super::position::compat_position;
use super::Surface;

/// `c` turned by `k` quarter turns counter-clockwise: (x, y) → (−y, x).
#[inline]
pub(super) fn rot(c: [i64; 2], k: u8) -> [i64; 2] {
    match k % 4 {
        0 => c,
        1 => [-c[1], c[0]],
        2 => [-c[0], -c[1]],
        _ => [c[1], -c[0]],
    }
}

/// The quarter turns k with which b's arm k matches a's first arm: a
/// vector's coordinates in a's lattice are those in b's turned by −k.
#[inline]
pub(super) fn turn(dirs: &[DVec3], s: &Surface, a: usize, b: usize) -> u8 {
    if a == b {
        0
    } else {
        match_arm(dirs[a], dirs[b], s.normals[b]).1
    }
}

/// Per edge of `s.edges` (a < b): b's lattice point relative to a's, in
/// a's lattice (units of the edge's mean spacing), and the real-valued
/// offset the field asks for, the integer one plus where b lies in its
/// cell minus where a lies in its (each within ±½ of its lattice point).
pub fn edge_offsets(
    s: &Surface,
    dirs: &[DVec3],
    o: &[DVec3],
    scale: &[f64],
) -> (Vec<[i64; 2]>, Vec<[f64; 2]>) {
    s.edges
        .iter()
        .map(|&[a, b]| {
            let (i, j) = (a as usize, b as usize);
            let (qj, _) = match_arm(dirs[i], dirs[j], s.normals[j]);
            let sc = 0.5 * (scale[i] + scale[j]);
            let (_, _, c0, c1) = compat_position(
                s.positions[i],
                s.normals[i],
                dirs[i],
                o[i],
                s.positions[j],
                s.normals[j],
                qj,
                o[j],
                sc,
            );
            let x = [c0[0] - c1[0], c0[1] - c1[1]];
            let cell = |k: usize, q: DVec3| {
                let d = s.positions[k] - o[k];
                [q.dot(d) / sc, s.normals[k].cross(q).dot(d) / sc]
            };
            let (ua, ub) = (cell(i, dirs[i]), cell(j, qj));
            let r = [x[0] as f64 + ub[0] - ua[0], x[1] as f64 + ub[1] - ua[1]];
            (x, r)
        })
        .unzip()
}

/// What [`repair_offsets`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FlowReport {
    /// Triangle equations (triangle, axis) with a non-zero sum, before and after.
    pub violated_before: usize,
    pub violated_after: usize,
    /// Units of excess to move, and how many were moved.
    pub supply: i64,
    pub moved: i64,
    /// Edge offsets changed.
    pub changed: usize,
    /// Triangles whose offsets turn clockwise (a fold of the lattice
    /// map) and edges longer than one lattice step, after.
    pub folded: usize,
    pub long_edges: usize,
}

/// One triangle edge in its triangle's frame: the edge, the quarter turns
/// from the edge's frame (its smaller vertex's) to the triangle's, and the
/// sign (+1 when the triangle walks it from the smaller vertex).
#[derive(Clone, Copy)]
pub(super) struct Side {
    pub(super) edge: u32,
    pub(super) turn: u8,
    pub(super) sign: i64,
}

/// Largest |offset| the flow may give an edge, first and last try
/// (QuadriFlow starts at 2 and widens while the flow is not full; edges of
/// M are shorter than the lattice spacing, so 1 is tried first).
const BOUND: (i64, i64) = (1, 2);

/// Zeroes the triangles' offset sums where a flow can (see the module
/// docs); `offsets` and the real offsets `real` as from [`edge_offsets`].
pub fn repair_offsets(
    s: &Surface,
    dirs: &[DVec3],
    offsets: &mut [[i64; 2]],
    real: &[[f64; 2]],
) -> FlowReport {
    let (sides, singular) = triangle_sides(s, dirs);
    repair_offsets_on(s, &sides, &singular, offsets, real)
}

/// [`repair_offsets`] on the triangles' sides and singular flags from
/// [`triangle_sides`] (of the same `s` and cross field), which the flip
/// removal after it reads too: computed once per lattice (issue 40's
/// speed point, session 24).
pub(super) fn repair_offsets_on(
    s: &Surface,
    sides: &[[Side; 3]],
    singular: &[bool],
    offsets: &mut [[i64; 2]],
    real: &[[f64; 2]],
) -> FlowReport {
    let mut report = FlowReport::default();
    let before = offsets.to_vec();
    // A singular triangle's corners on one lattice point (QuadriFlow's
    // treatment of singularities): its offsets are 0 and stay 0; the
    // flow then repairs the triangles around it.
    for (side, &sg) in sides.iter().zip(singular) {
        if sg {
            for sd in side {
                offsets[sd.edge as usize] = [0, 0];
            }
        }
    }
    let sums = equation_sums(sides, singular, offsets);
    report.violated_before = sums.iter().filter(|&&x| x != 0).count();
    report.supply = sums.iter().filter(|&&x| x > 0).sum();
    let arcs = arcs(s, sides, singular);
    if report.supply > 0 {
        report.moved += min_cost_flow(&sums, &arcs, offsets, real);
    }
    for bound in BOUND.0..=BOUND.1 {
        let sums = equation_sums(sides, singular, offsets);
        let supply: i64 = sums.iter().filter(|&&x| x > 0).sum();
        if supply == 0 {
            break;
        }
        let moved = push_flow(&sums, &arcs, offsets, bound);
        report.moved += moved;
        if moved == supply {
            break;
        }
    }
    let sums = equation_sums(sides, singular, offsets);
    report.violated_after = sums.iter().filter(|&&x| x != 0).count();
    report.changed = before
        .iter()
        .zip(offsets.iter())
        .filter(|(a, b)| a != b)
        .count();
    report.folded = sides
        .iter()
        .filter(|sd| signed_area(sd, offsets) < 0)
        .count();
    report.long_edges = offsets
        .iter()
        .filter(|x| x[0].abs() + x[1].abs() > 1)
        .count();
    report
}

/// Twice the signed area of a triangle in lattice units (its first two
/// sides' offsets in its frame): > 0 counter-clockwise as on M, < 0 a
/// fold, 0 a triangle inside one lattice cell's edge or point.
fn signed_area(side: &[Side; 3], offsets: &[[i64; 2]]) -> i64 {
    let d = |sd: &Side| {
        let x = rot(offsets[sd.edge as usize], sd.turn);
        [sd.sign * x[0], sd.sign * x[1]]
    };
    let (e0, e2) = (d(&side[0]), d(&side[2]));
    // v0 → v1 is e0, v0 → v2 is −e2.
    -(e0[0] * e2[1] - e0[1] * e2[0])
}

/// Per triangle its three sides in the triangle's frame, the frames
/// turned along a spanning tree that avoids singular triangles, and
/// whether the cross field is singular in it (its arms turn around it).
pub(super) fn triangle_sides(s: &Surface, dirs: &[DVec3]) -> (Vec<[Side; 3]>, Vec<bool>) {
    let edge_index = |a: u32, b: u32| -> u32 {
        let k = [a.min(b), a.max(b)];
        s.edges
            .binary_search(&k)
            .expect("a triangle edge is an edge") as u32
    };
    let nf = s.triangles.len();
    // Sides in the first vertex's frame (turn before t_f).
    let mut sides: Vec<[Side; 3]> = Vec::with_capacity(nf);
    let mut singular = vec![false; nf];
    for (f, tri) in s.triangles.iter().enumerate() {
        let v0 = tri[0] as usize;
        let mut side = [Side {
            edge: 0,
            turn: 0,
            sign: 1,
        }; 3];
        let mut holonomy = 0u32;
        for j in 0..3 {
            let (u, w) = (tri[j], tri[(j + 1) % 3]);
            let a = u.min(w) as usize;
            side[j] = Side {
                edge: edge_index(u, w),
                turn: (4 - turn(dirs, s, v0, a)) % 4,
                sign: if u as usize == a { 1 } else { -1 },
            };
            holonomy += u32::from(turn(dirs, s, u as usize, w as usize));
        }
        singular[f] = holonomy % 4 != 0;
        sides.push(side);
    }
    // Triangles per edge.
    let mut edge_faces = vec![[u32::MAX; 2]; s.edges.len()];
    for (f, side) in sides.iter().enumerate() {
        for sd in side {
            let ef = &mut edge_faces[sd.edge as usize];
            if ef[0] == u32::MAX {
                ef[0] = f as u32;
            } else {
                ef[1] = f as u32;
            }
        }
    }
    let turn_of = |f: usize, e: u32| -> u8 {
        sides[f]
            .iter()
            .find(|sd| sd.edge == e)
            .expect("edge of the triangle")
            .turn
    };
    // t_g chosen so that the shared edge has the same turn in f and g.
    let mut t = vec![u8::MAX; nf];
    let mut queue = VecDeque::new();
    let grow = |t: &mut Vec<u8>, queue: &mut VecDeque<usize>, through_singular: bool| {
        while let Some(f) = queue.pop_front() {
            for sd in &sides[f] {
                let ef = edge_faces[sd.edge as usize];
                let g = if ef[0] as usize == f { ef[1] } else { ef[0] };
                if g == u32::MAX || t[g as usize] != u8::MAX {
                    continue;
                }
                let g = g as usize;
                if !through_singular && singular[g] {
                    continue;
                }
                let want = (t[f] + turn_of(f, sd.edge)) % 4;
                t[g] = (want + 4 - turn_of(g, sd.edge)) % 4;
                queue.push_back(g);
            }
        }
    };
    for seed in 0..nf {
        if t[seed] == u8::MAX && !singular[seed] {
            t[seed] = 0;
            queue.push_back(seed);
            grow(&mut t, &mut queue, false);
        }
    }
    queue.extend((0..nf).filter(|&f| t[f] != u8::MAX));
    grow(&mut t, &mut queue, true);
    for (f, side) in sides.iter_mut().enumerate() {
        let tf = if t[f] == u8::MAX { 0 } else { t[f] };
        for sd in side.iter_mut() {
            sd.turn = (sd.turn + tf) % 4;
        }
    }
    (sides, singular)
}

/// Per (triangle, axis) the sum of its sides' offsets in its frame; 0 in
/// a singular triangle, whose corners are put on one lattice point (it
/// has no frame its sides agree on: the lattice turns there).
fn equation_sums(sides: &[[Side; 3]], singular: &[bool], offsets: &[[i64; 2]]) -> Vec<i64> {
    let mut sums = vec![0i64; 2 * sides.len()];
    for (f, side) in sides.iter().enumerate() {
        if singular[f] {
            continue;
        }
        for sd in side {
            let x = rot(offsets[sd.edge as usize], sd.turn);
            sums[2 * f] += sd.sign * x[0];
            sums[2 * f + 1] += sd.sign * x[1];
        }
    }
    sums
}

/// An offset component shared by two equations with opposite signs:
/// lowering `offsets[edge][axis]` by one moves a unit of excess from
/// equation `plus` (where it enters with +1) to `minus` (with −1).
#[derive(Clone, Copy)]
struct Arc {
    edge: u32,
    axis: u8,
    plus: u32,
    minus: u32,
}

/// Where a unit along `axis` of an edge lands in a triangle's frame:
/// `(axis, sign)`.
fn landing(axis: u8, turn: u8) -> (u32, i64) {
    let mut e = [0i64; 2];
    e[axis as usize] = 1;
    let r = rot(e, turn);
    if r[0] != 0 {
        (0, r[0])
    } else {
        (1, r[1])
    }
}

/// The arcs: interior edges' components that enter their two triangles'
/// equations with opposite signs (edges of singular triangles are kept).
fn arcs(s: &Surface, sides: &[[Side; 3]], singular: &[bool]) -> Vec<Arc> {
    let mut seen: Vec<Option<(u32, i64, u32, i64)>> = vec![None; 2 * s.edges.len()];
    let mut out = Vec::new();
    for (f, side) in sides.iter().enumerate() {
        if singular[f] {
            for sd in side {
                seen[2 * sd.edge as usize] = Some((u32::MAX, 0, 0, 0));
                seen[2 * sd.edge as usize + 1] = Some((u32::MAX, 0, 0, 0));
            }
            continue;
        }
        for sd in side {
            for axis in 0..2u8 {
                let (ax, sg) = landing(axis, sd.turn);
                let eq = 2 * f as u32 + ax;
                let sign = sg * sd.sign;
                let slot = 2 * sd.edge as usize + axis as usize;
                match seen[slot] {
                    None => seen[slot] = Some((eq, sign, 0, 0)),
                    Some((eq0, sign0, _, _)) if sign0 == -sign => {
                        let (plus, minus) = if sign0 > 0 { (eq0, eq) } else { (eq, eq0) };
                        out.push(Arc {
                            edge: sd.edge,
                            axis,
                            plus,
                            minus,
                        });
                    }
                    Some(_) => {}
                }
            }
        }
    }
    out.sort_unstable_by_key(|a| (a.edge, a.axis));
    out
}

/// One maximum flow from the positive sums to the negative ones with
/// every offset component kept within ±`bound`; applies it to `offsets`
/// and returns the units moved.
fn push_flow(sums: &[i64], arcs: &[Arc], offsets: &mut [[i64; 2]], bound: i64) -> i64 {
    let n = sums.len();
    let (source, sink) = (n, n + 1);
    let mut g = MaxFlow::new(n + 2);
    // A unit of flow plus → minus lowers the component by one (the plus
    // equation loses it, the minus one gains it).
    let ids: Vec<usize> = arcs
        .iter()
        .map(|a| {
            let x = offsets[a.edge as usize][a.axis as usize];
            g.add(
                a.plus as usize,
                a.minus as usize,
                (x + bound).max(0),
                (bound - x).max(0),
            )
        })
        .collect();
    for (i, &x) in sums.iter().enumerate() {
        if x > 0 {
            g.add(source, i, x, 0);
        } else if x < 0 {
            g.add(i, sink, -x, 0);
        }
    }
    let moved = g.run(source, sink);
    for (a, &id) in arcs.iter().zip(&ids) {
        offsets[a.edge as usize][a.axis as usize] -= g.flow(id);
    }
    moved
}

/// Cost of one unit of change, in thousandths of a lattice step: how
/// decided the field is about the component, the change in its distance
/// to the real offset either way (near 0 where the real offset is half a
/// step, an ambiguous rounding; near 1 where it is not). Symmetric: a
/// one-sided cost (only moves away from the real offset) makes merging two
/// close lattice points nearly free and the flow then removes whole rows
/// of cells (measured: a uniform torus of 256 cells extracted at 84).
fn change_cost(k: i64, r: f64, step: i64) -> i64 {
    let d = ((k + step) as f64 - r).abs() - (k as f64 - r).abs();
    1 + (1000.0 * d.abs()).round() as i64
}

/// Environment variable that, when set, makes `min_cost_flow` use
/// [`MinCostFlow::run`] (every search restarted from the source) instead
/// of [`MinCostFlow::run_kept`]. Both give the same flow on every arc
/// (the kept search takes the restarted one's path wherever shortest
/// paths tie); the restarted search is the slow reference (bunny's flow
/// 1.7-2.1 CPU s against ~0.3), kept to measure and check against.
pub const RESTARTED_SEARCH: &str = "SUBDFIT_FLOW_RESTARTED";

/// The cheapest flow from the positive sums to the negative ones, each
/// offset component changed by at most one step either way, the cost of a
/// step its [`change_cost`] (QuadriFlow's minimum-cost variant of §5: the
/// changes go where the field's offsets are ambiguous, near half a step,
/// instead of anywhere a path exists). Applies it; returns the units moved.
fn min_cost_flow(sums: &[i64], arcs: &[Arc], offsets: &mut [[i64; 2]], real: &[[f64; 2]]) -> i64 {
    let n = sums.len();
    let (source, sink) = (n, n + 1);
    let ends = sums.iter().filter(|&&x| x != 0).count();
    let mut g = MinCostFlow::with_arcs(n + 2, 2 * arcs.len() + ends);
    let ids: Vec<(usize, usize)> = arcs
        .iter()
        .map(|a| {
            let (e, ax) = (a.edge as usize, a.axis as usize);
            let (x, r) = (offsets[e][ax], real[e][ax]);
            // plus → minus lowers the component, minus → plus raises it.
            let down = g.add(a.plus as usize, a.minus as usize, 1, change_cost(x, r, -1));
            let up = g.add(a.minus as usize, a.plus as usize, 1, change_cost(x, r, 1));
            (down, up)
        })
        .collect();
    for (i, &x) in sums.iter().enumerate() {
        if x > 0 {
            g.add(source, i, x, 0);
        } else if x < 0 {
            g.add(i, sink, -x, 0);
        }
    }
    let cpu = thread_cpu_seconds();
    let (moved, stats) = if crate::switches::set(RESTARTED_SEARCH) {
        (g.run(source, sink), KeptStats::default())
    } else {
        g.run_kept_counted(source, sink)
    };
    if crate::switches::set("FIELD_DEBUG") {
        eprintln!(
            "flow: min-cost search moved {moved} units over {} nodes in {:.3} CPU s \
             ({} paths tied: restarted search, {} differed from the kept tree's)",
            n + 2,
            thread_cpu_seconds() - cpu,
            stats.restarted,
            stats.differed
        );
    }
    for (a, &(down, up)) in arcs.iter().zip(&ids) {
        offsets[a.edge as usize][a.axis as usize] += g.flow(up) - g.flow(down);
    }
    moved
}

/// A minimum-cost flow by successive shortest paths (Dijkstra on reduced
/// costs with Johnson potentials; every cost starts non-negative). Each
/// search stops at the sink, so a unit of excess only explores the
/// neighbourhood up to its nearest partner. Ties broken by node index:
/// deterministic. [`MinCostFlow::run`] restarts the search after each
/// augmentation, [`MinCostFlow::run_kept`] resumes it.
pub struct MinCostFlow {
    head: Vec<u32>,
    next: Vec<u32>,
    to: Vec<u32>,
    cap: Vec<i64>,
    cost: Vec<i64>,
    initial: Vec<i64>,
}

impl MinCostFlow {
    pub fn new(nodes: usize) -> Self {
        MinCostFlow {
            head: vec![NONE; nodes],
            next: Vec::new(),
            to: Vec::new(),
            cap: Vec::new(),
            cost: Vec::new(),
            initial: Vec::new(),
        }
    }

    /// [`Self::new`] with room for `arcs` calls of [`Self::add`] (the
    /// arrays are not grown and copied while the network is built).
    pub fn with_arcs(nodes: usize, arcs: usize) -> Self {
        let m = 2 * arcs;
        MinCostFlow {
            head: vec![NONE; nodes],
            next: Vec::with_capacity(m),
            to: Vec::with_capacity(m),
            cap: Vec::with_capacity(m),
            cost: Vec::with_capacity(m),
            initial: Vec::with_capacity(m),
        }
    }

    /// An arc u → v of capacity `cap` and unit cost `cost` ≥ 0; returns
    /// its id for [`MinCostFlow::flow`].
    pub fn add(&mut self, u: usize, v: usize, cap: i64, cost: i64) -> usize {
        let id = self.to.len();
        for (from, to, c, w) in [(u, v, cap, cost), (v, u, 0, -cost)] {
            self.to.push(to as u32);
            self.cap.push(c);
            self.cost.push(w);
            self.initial.push(c);
            self.next.push(self.head[from]);
            self.head[from] = self.to.len() as u32 - 1;
        }
        id
    }

    /// Flow on arc `id`.
    pub fn flow(&self, id: usize) -> i64 {
        self.initial[id] - self.cap[id]
    }

    /// [`MinCostFlow::run`] with the search kept across augmentations:
    /// the same flow on every arc, in a fraction of the time (the default;
    /// [`RESTARTED_SEARCH`] selects `run`).
    ///
    /// Successive shortest paths as one Dijkstra search that is never
    /// restarted. With Johnson potentials raised by each search's
    /// distances, a restarted search finds every node the last one settled
    /// at reduced distance 0 again (the shortest-path tree's arcs are
    /// tight) and settles them all before going further; on the bunny's
    /// layout mesh that re-settling was 2.2 of the field layout's 3.5 CPU
    /// seconds. Here the search keeps its settled nodes and its heap across
    /// augmentations, in one clock: a settled node u has the potential
    /// `P(u) = base(u) + dist(u)` (dist = the clock when it was settled),
    /// an unsettled one `base(v) + G` (G = the clock when the sink was
    /// last reached), and an arc u → v is relaxed to `P(u) + cost −
    /// base(v)`, which is the restarted search's key plus G. Then only the
    /// nodes an augmentation disconnects need work: the subtree of the
    /// search tree below the path's first saturated arc is unsettled
    /// (its potential kept, re-expressed as `base + G`) and its nodes, and
    /// the heap nodes they had reached, get their keys again from the
    /// settled nodes; the search resumes. Distances are exact at every
    /// augmentation, so each path is a shortest one and the flow is of
    /// least cost.
    ///
    /// Among equal-cost paths the kept tree may hold another one than the
    /// restarted search finds (that search re-settles the zero region in
    /// node-index order, so a node's predecessor can change between
    /// searches). Each path is therefore checked: when every node on it
    /// has a single tight in-arc from a settled node, it is the only
    /// shortest path and the restarted search takes it too; otherwise the
    /// restarted search is run once from the source with the same
    /// potentials ([`Restarted`]) and its path taken (homer's defaults:
    /// 23 of 585 paths, 8 of them other than the kept tree's, which is
    /// what changed homer's layouts before the check). The kept tree then
    /// loses the subtrees below every saturated tree arc of the path
    /// taken, and the sink. Deterministic.
    pub fn run_kept(&mut self, s: usize, t: usize) -> i64 {
        self.run_kept_counted(s, t).0
    }

    /// [`MinCostFlow::run_kept`], also returning how many augmentations
    /// took the restarted search's path because the kept one was not the
    /// only shortest path, and how many of those differed from it.
    fn run_kept_counted(&mut self, s: usize, t: usize) -> (i64, KeptStats) {
        use std::cmp::Reverse;
        use std::collections::BinaryHeap;
        let n = self.head.len();
        let (start, arcs, order) = self.compact();
        let mut arcs = arcs;
        let mut node = vec![
            SearchNode {
                dist: i64::MAX,
                base: 0,
                via: NONE,
                done: false,
            };
            n
        ];
        let mut heap: BinaryHeap<Reverse<(i64, usize)>> = BinaryHeap::new();
        let mut path: Vec<u32> = Vec::new();
        let mut cut: Vec<usize> = Vec::new();
        let mut fringe: Vec<usize> = Vec::new();
        let mut restarted = Restarted::new(n);
        let mut roots: Vec<usize> = Vec::new();
        let mut stats = KeptStats::default();
        // The clock when the sink was last reached (G in the docs above).
        let mut last = 0i64;
        let mut total = 0;
        node[s].dist = 0;
        heap.push(Reverse((0i64, s)));
        loop {
            while let Some(Reverse((d, u))) = heap.pop() {
                if node[u].done || d != node[u].dist {
                    continue;
                }
                node[u].done = true;
                if u == t {
                    break;
                }
                let pu = d + node[u].base;
                for k in start[u]..start[u + 1] {
                    let arc = &arcs[k as usize];
                    let v = arc.to as usize;
                    let nv = &mut node[v];
                    if arc.cap > 0 && !nv.done {
                        let nd = pu + arc.cost - nv.base;
                        if nd < nv.dist {
                            nv.dist = nd;
                            nv.via = k;
                            heap.push(Reverse((nd, v)));
                        }
                    }
                }
            }
            if !node[t].done {
                break;
            }
            let clock = node[t].dist;
            // The path, source first, and its bottleneck.
            path.clear();
            let mut v = t;
            while v != s {
                let k = node[v].via;
                path.push(k);
                v = arcs[arcs[k as usize].rev as usize].to as usize;
            }
            path.reverse();
            if !Self::forced(&start, &arcs, &node, &path) {
                // Several shortest paths: take the one the restarted
                // search takes, found by that search (same potentials).
                let kept = std::mem::take(&mut path);
                restarted.path(&start, &arcs, &node, s, t, last, &mut path);
                stats.restarted += 1;
                stats.differed += usize::from(path != kept);
            }
            let b = path
                .iter()
                .map(|&k| arcs[k as usize].cap)
                .min()
                .expect("a path");
            for &k in &path {
                arcs[k as usize].cap -= b;
                let r = arcs[k as usize].rev as usize;
                arcs[r].cap += b;
            }
            total += b;
            last = clock;
            // The search tree loses the subtrees below the path's saturated
            // tree arcs (on the kept path, the first one's holds the rest),
            // and the sink, which a restarted path may reach by another arc.
            cut.clear();
            fringe.clear();
            roots.clear();
            roots.extend(
                path.iter()
                    .filter(|&&k| arcs[k as usize].cap == 0)
                    .map(|&k| (k, arcs[k as usize].to as usize))
                    .filter(|&(k, v)| node[v].via == k)
                    .map(|(_, v)| v)
                    .chain([t]),
            );
            for &root in &roots {
                Self::unsettle(&start, &arcs, &mut node, root, clock, &mut cut, &mut fringe);
            }
            Self::rekey(&start, &arcs, &mut node, &cut, &mut heap);
            Self::rekey(&start, &arcs, &mut node, &fringe, &mut heap);
        }
        for (arc, &a) in arcs.iter().zip(&order) {
            self.cap[a as usize] = arc.cap;
        }
        (total, stats)
    }

    /// Whether `path` (the kept search's, source first) is the only
    /// shortest path its sink has: every node on it has one tight in-arc
    /// from a settled node (`base + dist` is a settled node's exact
    /// distance label). Then the restarted search, whose path is also
    /// made of tight arcs from nodes it settled first, takes the same.
    fn forced(start: &[u32], arcs: &[CsrArc], node: &[SearchNode], path: &[u32]) -> bool {
        path.iter().all(|&k| {
            let v = arcs[k as usize].to as usize;
            let label = node[v].base + node[v].dist;
            let tight = (start[v]..start[v + 1]).filter(|&j| {
                let r = &arcs[arcs[j as usize].rev as usize];
                let u = &node[arcs[j as usize].to as usize];
                r.cap > 0 && u.done && u.base + u.dist + r.cost == label
            });
            tight.count() == 1
        })
    }

    /// Sends as much flow as possible from `s` to `t` at least cost;
    /// returns its value.
    ///
    /// The search is the same as a textbook one on the arc lists (same
    /// settle order, same arcs relaxed in the same order, so the same
    /// paths and the same flow), laid out for speed: each node's arcs are
    /// copied next to each other in list order ([`CsrArc`]), and the
    /// potentials of the nodes a search did not reach are raised by one
    /// shared offset instead of one by one (only differences of
    /// potentials enter the reduced costs). On the bunny's layout mesh
    /// every search settles again the zero-reduced-cost region of the
    /// ones before, so the per-node work is what the flow costs.
    pub fn run(&mut self, s: usize, t: usize) -> i64 {
        use std::cmp::Reverse;
        use std::collections::BinaryHeap;
        let n = self.head.len();
        let (start, arcs, order) = self.compact();
        let mut arcs = arcs;
        // Per node in one place (a settled node's neighbours are read
        // together): pot = base + (the shared offset, never stored).
        let mut node = vec![
            SearchNode {
                dist: i64::MAX,
                base: 0,
                via: NONE,
                done: false,
            };
            n
        ];
        let mut touched: Vec<usize> = Vec::new();
        let mut heap: BinaryHeap<Reverse<(i64, usize)>> = BinaryHeap::new();
        let mut total = 0;
        loop {
            for &v in &touched {
                let nv = &mut node[v];
                nv.dist = i64::MAX;
                nv.via = NONE;
                nv.done = false;
            }
            touched.clear();
            heap.clear();
            node[s].dist = 0;
            touched.push(s);
            heap.push(Reverse((0i64, s)));
            while let Some(Reverse((d, u))) = heap.pop() {
                if node[u].done || d > node[u].dist {
                    continue;
                }
                node[u].done = true;
                if u == t {
                    break;
                }
                let bu = d + node[u].base;
                for k in start[u]..start[u + 1] {
                    let arc = &arcs[k as usize];
                    let v = arc.to as usize;
                    let nv = &mut node[v];
                    if arc.cap > 0 && !nv.done {
                        let nd = bu + arc.cost - nv.base;
                        if nd < nv.dist {
                            if nv.dist == i64::MAX {
                                touched.push(v);
                            }
                            nv.dist = nd;
                            nv.via = k;
                            heap.push(Reverse((nd, v)));
                        }
                    }
                }
            }
            if !node[t].done {
                break;
            }
            // Potentials: reached nodes by their distance (capped at the
            // sink's), the rest by the sink's: the shared offset rises by
            // dt and the reached ones take back what they did not get.
            let dt = node[t].dist;
            for &v in &touched {
                let nv = &mut node[v];
                nv.base += nv.dist.min(dt) - dt;
            }
            let mut b = i64::MAX;
            let mut v = t;
            while v != s {
                let a = &arcs[node[v].via as usize];
                b = b.min(a.cap);
                v = arcs[a.rev as usize].to as usize;
            }
            let mut v = t;
            while v != s {
                let k = node[v].via as usize;
                arcs[k].cap -= b;
                let r = arcs[k].rev as usize;
                arcs[r].cap += b;
                v = arcs[r].to as usize;
            }
            total += b;
        }
        for (arc, &a) in arcs.iter().zip(&order) {
            self.cap[a as usize] = arc.cap;
        }
        total
    }

    /// Unsettles the search tree's subtree at `root` (children found by
    /// their `via` arcs; nothing if `root` is not settled), keeping each
    /// node's potential: `base + dist` becomes `base + clock`. The nodes
    /// are added to `cut`, and the unsettled nodes whose key came from one
    /// of them (the heap's fringe below the subtree) to `fringe`.
    fn unsettle(
        start: &[u32],
        arcs: &[CsrArc],
        node: &mut [SearchNode],
        root: usize,
        clock: i64,
        cut: &mut Vec<usize>,
        fringe: &mut Vec<usize>,
    ) {
        if !node[root].done {
            return;
        }
        let mut i = cut.len();
        let take = |node: &mut [SearchNode], cut: &mut Vec<usize>, x: usize| {
            let nx = &mut node[x];
            nx.base += nx.dist - clock;
            nx.done = false;
            cut.push(x);
        };
        take(node, cut, root);
        while i < cut.len() {
            let x = cut[i];
            i += 1;
            for k in start[x]..start[x + 1] {
                let y = arcs[k as usize].to as usize;
                if node[y].via == k {
                    if node[y].done {
                        take(node, cut, y);
                    } else {
                        fringe.push(y);
                    }
                }
            }
        }
    }

    /// New keys, from the settled nodes only, for the unsettled nodes
    /// `nodes` (the old heap entries of those already in the heap are
    /// stale: a key that no longer equals the node's `dist` is skipped
    /// when popped).
    fn rekey(
        start: &[u32],
        arcs: &[CsrArc],
        node: &mut [SearchNode],
        nodes: &[usize],
        heap: &mut std::collections::BinaryHeap<std::cmp::Reverse<(i64, usize)>>,
    ) {
        for &y in nodes {
            node[y].dist = i64::MAX;
            node[y].via = NONE;
        }
        for &y in nodes {
            // In-arcs of y: the reverses of its out-arcs, in list order
            // (the first of equal keys wins, as in a relaxation).
            let mut best = (i64::MAX, NONE);
            for k in start[y]..start[y + 1] {
                let r = arcs[k as usize].rev;
                let arc = &arcs[r as usize];
                let u = arcs[k as usize].to as usize;
                if arc.cap > 0 && node[u].done {
                    let nd = node[u].dist + node[u].base + arc.cost - node[y].base;
                    if nd < best.0 {
                        best = (nd, r);
                    }
                }
            }
            let ny = &mut node[y];
            if best.0 < ny.dist {
                ny.dist = best.0;
                ny.via = best.1;
                heap.push(std::cmp::Reverse((best.0, y)));
            }
        }
    }

    /// The arcs grouped by tail node in list order: `(start, arcs, id)`
    /// with node u's arcs at `arcs[start[u]..start[u + 1]]` and `id[k]`
    /// the arc id of `arcs[k]`.
    ///
    /// A node's list holds its arcs newest first (each [`Self::add`]
    /// puts its arc at the head), so its list order is its arcs' ids
    /// descending: the layout is a counting sort of the arcs by tail, the
    /// ids taken from the last, instead of a walk of every list (a chase
    /// of `next` through memory; issue 40's speed point, session 24: the
    /// walk and its first touch of the arrays were ~1 % of gargoyle 402's
    /// CPU under `SUBDFIT_FIELD_BEST=lean`). The same slots
    /// (`tests::counting_sort_layout_is_the_list_walk`).
    fn compact(&self) -> (Vec<u32>, Vec<CsrArc>, Vec<u32>) {
        let n = self.head.len();
        let m = self.to.len();
        // Arc a runs from its reverse's head: a ^ 1 is its reverse.
        let tail = |a: usize| self.to[a ^ 1] as usize;
        let mut start = vec![0u32; n + 1];
        for a in 0..m {
            start[tail(a) + 1] += 1;
        }
        for u in 0..n {
            start[u + 1] += start[u];
        }
        let mut fill = start[..n].to_vec();
        let mut order = vec![0u32; m];
        let mut slot = vec![0u32; m];
        for a in (0..m).rev() {
            let u = tail(a);
            let k = fill[u];
            fill[u] += 1;
            order[k as usize] = a as u32;
            slot[a] = k;
        }
        let arcs = order
            .iter()
            .map(|&a| {
                let a = a as usize;
                CsrArc {
                    to: self.to[a],
                    rev: slot[a ^ 1],
                    cost: self.cost[a],
                    cap: self.cap[a],
                }
            })
            .collect();
        (start, arcs, order)
    }
}

/// What [`MinCostFlow::run_kept`] left to the restarted search: the
/// augmentations whose shortest path was not unique, and of those the
/// ones where the kept search's tree held another path than the
/// restarted search's.
#[derive(Clone, Copy, Debug, Default)]
struct KeptStats {
    restarted: usize,
    differed: usize,
}

/// The search of [`MinCostFlow::run`], run once from the source by
/// [`MinCostFlow::run_kept`] where several shortest paths exist, to take
/// the one the restarted search takes: same potentials (a settled node's
/// from before the current search, `base + min(dist, last)`, any other's
/// `base + last`), same key order (distance, then node index), same
/// relaxation rule (the first arc in list order that lowers a key), so the
/// same settle order and the same path.
struct Restarted {
    /// Per node its key, the arc it was reached by and whether it is
    /// settled, side by side (a relaxation reads all three of the arc's
    /// head; issue 40's speed point, session 24, docs/status.md).
    state: Vec<RestartedNode>,
    touched: Vec<usize>,
    /// The heap, kept between calls for its allocation (empty between).
    heap: std::collections::BinaryHeap<std::cmp::Reverse<(i64, usize)>>,
}

/// A node of [`Restarted`]'s search.
#[derive(Clone, Copy)]
struct RestartedNode {
    dist: i64,
    via: u32,
    done: bool,
}

impl RestartedNode {
    const UNSEEN: RestartedNode = RestartedNode {
        dist: i64::MAX,
        via: NONE,
        done: false,
    };
}

impl Restarted {
    fn new(n: usize) -> Self {
        Restarted {
            state: vec![RestartedNode::UNSEEN; n],
            touched: Vec::new(),
            heap: std::collections::BinaryHeap::new(),
        }
    }

    /// The restarted search's shortest path from `s` to `t` into `path`
    /// (arc slots, source first); `last` is the kept search's clock when
    /// the sink was last reached.
    #[allow(clippy::too_many_arguments)]
    fn path(
        &mut self,
        start: &[u32],
        arcs: &[CsrArc],
        node: &[SearchNode],
        s: usize,
        t: usize,
        last: i64,
        path: &mut Vec<u32>,
    ) {
        use std::cmp::Reverse;
        let pot = |v: usize| {
            let nv = &node[v];
            nv.base + if nv.done { nv.dist.min(last) } else { last }
        };
        let state = &mut self.state;
        for &v in &self.touched {
            state[v] = RestartedNode::UNSEEN;
        }
        self.touched.clear();
        state[s].dist = 0;
        self.touched.push(s);
        let heap = &mut self.heap;
        heap.clear();
        heap.push(Reverse((0i64, s)));
        while let Some(Reverse((d, u))) = heap.pop() {
            if state[u].done || d > state[u].dist {
                continue;
            }
            state[u].done = true;
            if u == t {
                break;
            }
            let pu = d + pot(u);
            for k in start[u]..start[u + 1] {
                let arc = &arcs[k as usize];
                let v = arc.to as usize;
                let sv = &mut state[v];
                if arc.cap > 0 && !sv.done {
                    let nd = pu + arc.cost - pot(v);
                    if nd < sv.dist {
                        if sv.dist == i64::MAX {
                            self.touched.push(v);
                        }
                        sv.dist = nd;
                        sv.via = k;
                        heap.push(Reverse((nd, v)));
                    }
                }
            }
        }
        heap.clear();
        assert!(state[t].done, "the kept search reached the sink");
        path.clear();
        let mut v = t;
        while v != s {
            let k = state[v].via;
            path.push(k);
            v = arcs[arcs[k as usize].rev as usize].to as usize;
        }
        path.reverse();
    }
}

/// A node's state in [`MinCostFlow::run`]'s search.
#[derive(Clone, Copy)]
struct SearchNode {
    dist: i64,
    base: i64,
    via: u32,
    done: bool,
}

/// An arc of [`MinCostFlow::run`]'s compact layout: head node, the slot
/// of its reverse arc, unit cost, residual capacity.
struct CsrArc {
    to: u32,
    rev: u32,
    cost: i64,
    cap: i64,
}

/// A maximum flow by Dinic's algorithm (level graph by breadth-first
/// search, blocking flow by depth-first search with per-node arc
/// pointers; iterative, so paths across the whole mesh do not recurse).
/// Arcs are kept in insertion order: deterministic.
pub struct MaxFlow {
    head: Vec<u32>,
    next: Vec<u32>,
    to: Vec<u32>,
    cap: Vec<i64>,
    initial: Vec<i64>,
}

const NONE: u32 = u32::MAX;

impl MaxFlow {
    pub fn new(nodes: usize) -> Self {
        MaxFlow {
            head: vec![NONE; nodes],
            next: Vec::new(),
            to: Vec::new(),
            cap: Vec::new(),
            initial: Vec::new(),
        }
    }

    /// An arc u → v of capacity `forward` and, the other way, `backward`;
    /// returns its id for [`MaxFlow::flow`].
    pub fn add(&mut self, u: usize, v: usize, forward: i64, backward: i64) -> usize {
        let id = self.to.len();
        for (from, to, c) in [(u, v, forward), (v, u, backward)] {
            self.to.push(to as u32);
            self.cap.push(c);
            self.initial.push(c);
            self.next.push(self.head[from]);
            self.head[from] = self.to.len() as u32 - 1;
        }
        id
    }

    /// Net flow along arc `id` in its forward direction.
    pub fn flow(&self, id: usize) -> i64 {
        self.initial[id] - self.cap[id]
    }

    /// Pushes a maximum flow from `s` to `t`; returns its value.
    pub fn run(&mut self, s: usize, t: usize) -> i64 {
        let n = self.head.len();
        let mut total = 0;
        let mut level = vec![u32::MAX; n];
        loop {
            level.fill(u32::MAX);
            level[s] = 0;
            let mut queue = VecDeque::from([s]);
            while let Some(u) = queue.pop_front() {
                let mut a = self.head[u];
                while a != NONE {
                    let v = self.to[a as usize] as usize;
                    if self.cap[a as usize] > 0 && level[v] == u32::MAX {
                        level[v] = level[u] + 1;
                        queue.push_back(v);
                    }
                    a = self.next[a as usize];
                }
            }
            if level[t] == u32::MAX {
                return total;
            }
            total += self.blocking(s, t, &mut level);
        }
    }

    /// Augments along level-increasing paths until none is left.
    fn blocking(&mut self, s: usize, t: usize, level: &mut [u32]) -> i64 {
        let mut it = self.head.clone();
        let mut path: Vec<u32> = Vec::new();
        let mut total = 0;
        let mut u = s;
        loop {
            if u == t {
                let b = path
                    .iter()
                    .map(|&a| self.cap[a as usize])
                    .min()
                    .expect("a path");
                for &a in &path {
                    self.cap[a as usize] -= b;
                    self.cap[(a ^ 1) as usize] += b;
                }
                total += b;
                let k = path
                    .iter()
                    .position(|&a| self.cap[a as usize] == 0)
                    .expect("a saturated arc");
                path.truncate(k);
                u = path.last().map_or(s, |&a| self.to[a as usize] as usize);
                continue;
            }
            let mut advanced = false;
            while it[u] != NONE {
                let a = it[u] as usize;
                let v = self.to[a] as usize;
                if self.cap[a] > 0 && level[v] == level[u].wrapping_add(1) {
                    path.push(a as u32);
                    u = v;
                    advanced = true;
                    break;
                }
                it[u] = self.next[a];
            }
            if !advanced {
                if u == s {
                    return total;
                }
                level[u] = u32::MAX;
                let a = path.pop().expect("not at the source") as usize;
                u = self.to[a ^ 1] as usize;
                it[u] = self.next[it[u] as usize];
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A small network with a known maximum (the classic two-path example
    /// where the second augmentation must undo part of the first): 0 → 1
    /// (3), 0 → 2 (2), 1 → 2 (1), 1 → 3 (2), 2 → 3 (3): cut {0→1, 0→2}
    /// and {1→3, 2→3} both 5, so the flow is 5.
    #[test]
    fn dinic_reaches_the_minimum_cut() {
        let mut g = MaxFlow::new(4);
        let a = g.add(0, 1, 3, 0);
        let b = g.add(0, 2, 2, 0);
        let c = g.add(1, 2, 1, 0);
        let d = g.add(1, 3, 2, 0);
        let e = g.add(2, 3, 3, 0);
        assert_eq!(g.run(0, 3), 5);
        // Conservation at 1 and 2.
        assert_eq!(g.flow(a), g.flow(c) + g.flow(d));
        assert_eq!(g.flow(b) + g.flow(c), g.flow(e));
    }

    /// The textbook successive-shortest-path search on the arc lists
    /// (potentials raised one node at a time, every search restarted from
    /// the source), as [`MinCostFlow::run`] was first written: the
    /// reference the compact layout must match arc for arc, and whose
    /// flow value and cost the kept search must match.
    fn list_search(g: &mut MinCostFlow, s: usize, t: usize) -> i64 {
        use std::cmp::Reverse;
        use std::collections::BinaryHeap;
        let n = g.head.len();
        let mut pot = vec![0i64; n];
        let mut total = 0;
        loop {
            let mut dist = vec![i64::MAX; n];
            let mut via = vec![NONE; n];
            let mut done = vec![false; n];
            dist[s] = 0;
            let mut heap = BinaryHeap::from([Reverse((0i64, s))]);
            while let Some(Reverse((d, u))) = heap.pop() {
                if done[u] || d > dist[u] {
                    continue;
                }
                done[u] = true;
                if u == t {
                    break;
                }
                let mut a = g.head[u];
                while a != NONE {
                    let ai = a as usize;
                    let v = g.to[ai] as usize;
                    if g.cap[ai] > 0 && !done[v] {
                        let nd = d + g.cost[ai] + pot[u] - pot[v];
                        if nd < dist[v] {
                            dist[v] = nd;
                            via[v] = a;
                            heap.push(Reverse((nd, v)));
                        }
                    }
                    a = g.next[ai];
                }
            }
            if !done[t] {
                return total;
            }
            let dt = dist[t];
            for v in 0..n {
                pot[v] += dist[v].min(dt);
            }
            let (mut b, mut v) = (i64::MAX, t);
            while v != s {
                let a = via[v] as usize;
                b = b.min(g.cap[a]);
                v = g.to[a ^ 1] as usize;
            }
            let mut v = t;
            while v != s {
                let a = via[v] as usize;
                g.cap[a] -= b;
                g.cap[a ^ 1] += b;
                v = g.to[a ^ 1] as usize;
            }
            total += b;
        }
    }

    /// The arcs grouped by tail as [`MinCostFlow::compact`] laid them out
    /// before issue 40's session 24 cut: a walk of each node's list.
    fn compact_by_list_walk(g: &MinCostFlow) -> (Vec<u32>, Vec<u32>) {
        let n = g.head.len();
        let mut start = vec![0u32; n + 1];
        let mut order = Vec::new();
        for u in 0..n {
            let mut a = g.head[u];
            while a != NONE {
                order.push(a);
                a = g.next[a as usize];
            }
            start[u + 1] = order.len() as u32;
        }
        (start, order)
    }

    /// The counting sort lays the arcs out as the list walk did: the same
    /// node ranges, the same arc in every slot, each slot's reverse slot
    /// the reverse arc's, on the grid networks (arcs added node by node)
    /// and on networks whose arcs come in scattered order with repeated
    /// pairs, whichever constructor built them.
    #[test]
    fn counting_sort_layout_is_the_list_walk() {
        let mut next = xorshift(0x9e37_79b9_7f4a_7c15);
        let mut nets = Vec::new();
        for case in 0..6 {
            let (a, _, _, _, _) = grid_networks(5 + case, 4 + case % 3, &mut next);
            nets.push(a);
        }
        for case in 0..6 {
            let n = 20 + 7 * case;
            let m = 5 * n;
            let mut g = if case % 2 == 0 {
                MinCostFlow::new(n)
            } else {
                MinCostFlow::with_arcs(n, m)
            };
            for _ in 0..m {
                let (u, v) = ((next() % n as u64) as usize, (next() % n as u64) as usize);
                g.add(u, v, (next() % 3) as i64, (next() % 5) as i64);
            }
            nets.push(g);
        }
        for g in &nets {
            let (start, arcs, order) = g.compact();
            let (want_start, want_order) = compact_by_list_walk(g);
            assert_eq!(start, want_start);
            assert_eq!(order, want_order);
            assert!(!order.is_empty());
            for (k, (arc, &a)) in arcs.iter().zip(&order).enumerate() {
                let a = a as usize;
                assert_eq!((arc.to, arc.cost, arc.cap), (g.to[a], g.cost[a], g.cap[a]));
                assert_eq!(order[arc.rev as usize] as usize, a ^ 1);
                assert_eq!(arcs[arc.rev as usize].rev as usize, k);
            }
        }
    }

    /// The compact search finds the same flow on every arc as the list
    /// search, on grids shaped like the flow's networks (unit arcs both
    /// ways between neighbouring equations, costs from a few values so
    /// that equal-cost paths tie, excesses scattered), including ones
    /// whose supply cannot all be routed.
    #[test]
    fn compact_search_matches_the_list_search() {
        let mut next = xorshift(0x2545_f491_4f6c_dd1d);
        for case in 0..20 {
            let (w, h) = (6 + case % 5, 5 + case % 7);
            let (mut a, mut b, ids, s, t) = grid_networks(w, h, &mut next);
            let got = a.run(s, t);
            assert_eq!(got, list_search(&mut b, s, t), "case {case}");
            for &id in &ids {
                assert_eq!(a.flow(id), b.flow(id), "case {case}, arc {id}");
            }
        }
    }

    /// Value and cost of `g`'s flow on the arcs `ids`, after checking that
    /// it is a flow: within capacity, conserved at every node but s and t.
    fn value_and_cost(g: &MinCostFlow, ids: &[usize], s: usize, t: usize) -> (i64, i64) {
        let mut net = vec![0i64; g.head.len()];
        let mut cost = 0;
        for &id in ids {
            let f = g.flow(id);
            assert!((0..=g.initial[id]).contains(&f), "arc {id} carries {f}");
            let (u, v) = (g.to[id ^ 1] as usize, g.to[id] as usize);
            net[u] -= f;
            net[v] += f;
            cost += f * g.cost[id];
        }
        for (v, &x) in net.iter().enumerate() {
            if v != s && v != t {
                assert_eq!(x, 0, "node {v} does not conserve the flow");
            }
        }
        assert_eq!(net[s], -net[t]);
        (net[t], cost)
    }

    /// A xorshift generator: the networks are the same on every run.
    fn xorshift(mut seed: u64) -> impl FnMut() -> u64 {
        move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            seed
        }
    }

    /// Builds the same network in `a` (returning its arc ids) and `b`.
    fn add_both(a: &mut MinCostFlow, b: &mut MinCostFlow, ids: &mut Vec<usize>, arc: [usize; 4]) {
        let [u, v, cap, cost] = arc;
        ids.push(a.add(u, v, cap as i64, cost as i64));
        b.add(u, v, cap as i64, cost as i64);
    }

    /// The same network in `a` and `b` (with `a`'s arc ids, the source and
    /// the sink), shaped like the flow's: a `w × h` grid of equations with
    /// arcs both ways between neighbours, costs from a few values so that
    /// equal-cost paths tie, capacities 1..2, and about one equation in
    /// seven fed by the source or draining into the sink. `next` draws
    /// every cost, capacity and excess, so one seed gives one sequence of
    /// networks.
    fn grid_networks(
        w: usize,
        h: usize,
        next: &mut impl FnMut() -> u64,
    ) -> (MinCostFlow, MinCostFlow, Vec<usize>, usize, usize) {
        let n = w * h;
        let (s, t) = (n, n + 1);
        let mut a = MinCostFlow::new(n + 2);
        let mut b = MinCostFlow::new(n + 2);
        let mut ids = Vec::new();
        for y in 0..h {
            for x in 0..w {
                let u = y * w + x;
                for v in [(x + 1 < w).then(|| u + 1), (y + 1 < h).then(|| u + w)]
                    .into_iter()
                    .flatten()
                {
                    for (p, q) in [(u, v), (v, u)] {
                        let cost = [1, 1001, 1001, 500][(next() % 4) as usize];
                        let cap = 1 + (next() % 2) as usize;
                        add_both(&mut a, &mut b, &mut ids, [p, q, cap, cost]);
                    }
                }
            }
        }
        for u in 0..n {
            match next() % 7 {
                0 => add_both(
                    &mut a,
                    &mut b,
                    &mut ids,
                    [s, u, 1 + (next() % 3) as usize, 0],
                ),
                1 => add_both(
                    &mut a,
                    &mut b,
                    &mut ids,
                    [u, t, 1 + (next() % 2) as usize, 0],
                ),
                _ => {}
            }
        }
        (a, b, ids, s, t)
    }

    /// Runs the kept search on `a` and the restarted one on `b` (the same
    /// network) from `st[0]` to `st[1]`, checks that both send the same
    /// value at the same cost and the same flow on every arc, and returns
    /// how many of the kept search's paths tied (see the grid test below).
    fn assert_kept_matches_restarted(
        a: &mut MinCostFlow,
        b: &mut MinCostFlow,
        ids: &[usize],
        [s, t]: [usize; 2],
        case: usize,
    ) -> KeptStats {
        let (got, st) = a.run_kept_counted(s, t);
        let want = list_search(b, s, t);
        assert_eq!(got, want, "case {case}");
        let (va, ca) = value_and_cost(a, ids, s, t);
        let (vb, cb) = value_and_cost(b, ids, s, t);
        assert_eq!((va, ca), (vb, cb), "case {case}");
        assert_eq!(va, got);
        for &id in ids {
            assert_eq!(a.flow(id), b.flow(id), "case {case}, arc {id}");
        }
        st
    }

    /// The kept search sends the same flow on every arc as the textbook
    /// restarted one, on grids shaped like the flow's networks (arcs both
    /// ways between neighbouring equations, costs from a few values so
    /// that equal-cost paths tie and the kept tree holds other shortest
    /// paths than the restarted search finds, excesses scattered),
    /// including ones whose supply cannot all be routed. Value and cost
    /// are checked on their own too (a flow, maximum, of least cost), and
    /// that ties did occur where the kept tree's path was not the
    /// restarted one's (else the arc identity would prove nothing).
    #[test]
    fn kept_search_matches_the_restarted_search_on_grids() {
        let mut next = xorshift(0x2545_f491_4f6c_dd1d);
        let mut tied = KeptStats::default();
        for case in 0..60 {
            let (w, h) = (6 + case % 9, 5 + case % 11);
            let (mut a, mut b, ids, s, t) = grid_networks(w, h, &mut next);
            let st = assert_kept_matches_restarted(&mut a, &mut b, &ids, [s, t], case);
            tied.restarted += st.restarted;
            tied.differed += st.differed;
        }
        // The networks do tie, and the kept tree alone would have taken
        // other paths: the identity above is not vacuous.
        assert!(tied.differed > 10, "{tied:?}");
    }

    /// The same on random sparse networks (any arcs, costs 0..45 with
    /// many ties and zero-cost arcs, capacities 1..4, several sources' and
    /// sinks' arcs), where augmenting paths cross and undo each other's
    /// arcs more than on a grid.
    #[test]
    fn kept_search_matches_the_restarted_search_on_random_networks() {
        let mut next = xorshift(0x9e37_79b9_7f4a_7c15);
        let mut tied = KeptStats::default();
        for case in 0..200 {
            let n = 4 + (next() % 60) as usize;
            let m = n + (next() % (4 * n as u64)) as usize;
            let (s, t) = (n, n + 1);
            let mut a = MinCostFlow::new(n + 2);
            let mut b = MinCostFlow::new(n + 2);
            let mut ids = Vec::new();
            for _ in 0..m {
                let u = (next() % n as u64) as usize;
                let v = (next() % n as u64) as usize;
                if u != v {
                    let cap = 1 + (next() % 4) as usize;
                    let cost = (next() % 6 * (next() % 10)) as usize;
                    add_both(&mut a, &mut b, &mut ids, [u, v, cap, cost]);
                }
            }
            for _ in 0..1 + n / 4 {
                let u = (next() % n as u64) as usize;
                add_both(
                    &mut a,
                    &mut b,
                    &mut ids,
                    [s, u, 1 + (next() % 3) as usize, 0],
                );
                let v = (next() % n as u64) as usize;
                add_both(
                    &mut a,
                    &mut b,
                    &mut ids,
                    [v, t, 1 + (next() % 3) as usize, 0],
                );
            }
            let st = assert_kept_matches_restarted(&mut a, &mut b, &ids, [s, t], case);
            tied.restarted += st.restarted;
            tied.differed += st.differed;
        }
        // The networks do tie, and the kept tree alone would have taken
        // other paths: the identity above is not vacuous.
        assert!(tied.differed > 10, "{tied:?}");
    }

    #[test]
    fn turns_compose() {
        let c = [2, -5];
        for k in 0..4 {
            assert_eq!(rot(rot(c, k), (4 - k) % 4), c);
        }
        assert_eq!(rot([1, 0], 1), [0, 1]);
    }

    /// A torus of `nu × nv` quads split into triangles, its tube's radius
    /// varying around it (so the cross field and the lattice are not
    /// uniform).
    fn bumpy_torus(nu: usize, nv: usize) -> crate::mesh::TriMesh {
        use std::f64::consts::TAU;
        let mut positions = Vec::new();
        for j in 0..nv {
            for i in 0..nu {
                let (u, v) = (TAU * i as f64 / nu as f64, TAU * j as f64 / nv as f64);
                let r = 0.8 + 0.25 * (3.0 * u).sin();
                positions.push(DVec3::new(
                    (2.0 + r * v.cos()) * u.cos(),
                    (2.0 + r * v.cos()) * u.sin(),
                    r * v.sin(),
                ));
            }
        }
        let id = |i: usize, j: usize| ((j % nv) * nu + i % nu) as u32;
        let mut triangles = Vec::new();
        for j in 0..nv {
            for i in 0..nu {
                let (a, b, c, d) = (id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1));
                triangles.extend([[a, b, c], [a, c, d]]);
            }
        }
        crate::mesh::TriMesh {
            positions,
            triangles,
        }
    }

    /// The lattice's offset repair and flip removal on one computation of
    /// the triangles' frames (issue 40's session 24 cut) give the offsets
    /// and reports of the two separate calls, each computing its own, on
    /// a bumpy torus's lattices at three spacings with sizes that vary
    /// over it (the flow moves units and changes offsets there).
    #[test]
    fn shared_frames_repair_as_the_separate_calls() {
        use super::super::{cross, flip, position, FieldOptions};
        let m = bumpy_torus(48, 24);
        let s = Surface::new(&m).unwrap();
        let opts = FieldOptions::default();
        let dirs = cross::cross_field(&s, &opts).unwrap();
        let mut moved = 0;
        for h in [0.18, 0.25, 0.4] {
            let scale: Vec<f64> = s
                .positions
                .iter()
                .map(|p| h * (1.0 + 0.6 * (0.5 + 0.5 * p.z.sin())))
                .collect();
            let o = position::position_field(&s, &dirs, &scale, opts.position_sweeps).unwrap();
            let (start, real) = edge_offsets(&s, &dirs, &o, &scale);
            let mut a = start.clone();
            let ra = repair_offsets(&s, &dirs, &mut a, &real);
            let fa = flip::remove_flips(&s, &dirs, &mut a, &real);
            let mut b = start.clone();
            let (sides, singular) = triangle_sides(&s, &dirs);
            let rb = repair_offsets_on(&s, &sides, &singular, &mut b, &real);
            let fb = flip::remove_flips_on(&s, &dirs, &sides, &singular, &mut b, &real);
            assert_eq!(a, b, "h {h}");
            assert_eq!(ra, rb, "h {h}");
            assert_eq!(fa, fb, "h {h}");
            moved += ra.moved;
        }
        assert!(moved > 0, "no lattice needed the flow");
    }
}
