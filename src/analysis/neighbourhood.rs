//! Neighbourhoods `B(p, r)` of Fitmaps §3.1.2: the vertices reached by a
//! breadth-first traversal of M from `p` that only steps onto vertices within
//! Euclidean distance `r` of `p`.
//!
//! Two ways to gather them:
//! - [`bfs_ball`]: the literal traversal, one per radius (exact mode);
//! - [`nested_balls`]: one best-first traversal that yields every radius at
//!   once. The key of a vertex `q` is the smallest `r` for which the literal
//!   BFS reaches it, i.e. the minimum over paths from `p` to `q` of the
//!   largest `|x - p|` along the path (a bottleneck shortest path, computed by
//!   Dijkstra with `max` instead of `+`). Hence `B(p, r) = {q : key(q) <= r}`
//!   *exactly*, for every `r`, and the balls are prefixes of one list sorted
//!   by key.

use std::cmp::Ordering;
use std::collections::{BinaryHeap, HashMap};

use crate::mesh::{prefetch, TriMesh};
use crate::DVec3;

/// Compressed adjacency `offsets[i]..offsets[i + 1]` into `items`.
#[derive(Clone, Debug, Default)]
pub struct Csr {
    pub offsets: Vec<u32>,
    pub items: Vec<u32>,
}

impl Csr {
    #[inline]
    pub fn row(&self, i: usize) -> &[u32] {
        &self.items[self.offsets[i] as usize..self.offsets[i + 1] as usize]
    }

    /// From `(row, item)` pairs; rows sorted and deduplicated.
    pub fn from_pairs(n: usize, mut pairs: Vec<(u32, u32)>) -> Csr {
        pairs.sort_unstable();
        pairs.dedup();
        let mut offsets = vec![0u32; n + 1];
        for &(r, _) in &pairs {
            offsets[r as usize + 1] += 1;
        }
        for i in 0..n {
            offsets[i + 1] += offsets[i];
        }
        Csr {
            offsets,
            items: pairs.into_iter().map(|(_, x)| x).collect(),
        }
    }
}

/// Vertex–vertex and vertex–triangle adjacency of a triangle mesh.
#[derive(Clone, Debug, Default)]
pub struct Adjacency {
    pub vv: Csr,
    pub vt: Csr,
}

impl Adjacency {
    pub fn new(mesh: &TriMesh) -> Adjacency {
        let n = mesh.positions.len();
        let mut e = Vec::with_capacity(mesh.triangles.len() * 6);
        let mut vt = Vec::with_capacity(mesh.triangles.len() * 3);
        for (t, tri) in mesh.triangles.iter().enumerate() {
            for k in 0..3 {
                let (a, b) = (tri[k], tri[(k + 1) % 3]);
                if a != b {
                    e.push((a, b));
                    e.push((b, a));
                }
                vt.push((tri[k], t as u32));
            }
        }
        Adjacency {
            vv: Csr::from_pairs(n, e),
            vt: Csr::from_pairs(n, vt),
        }
    }
}

/// Literal §3.1.2 traversal: breadth-first from `p`, entering only vertices
/// within distance `r` of `positions[p]`. Appends the ball to `out` (cleared
/// first), `p` first. `mark` is scratch of `positions.len()` entries, all
/// different from `stamp` on entry; visited vertices are set to `stamp`.
pub fn bfs_ball(
    adj: &Csr,
    positions: &[DVec3],
    p: u32,
    r: f64,
    mark: &mut [u32],
    stamp: u32,
    out: &mut Vec<u32>,
) {
    out.clear();
    let c = positions[p as usize];
    let r2 = r * r;
    mark[p as usize] = stamp;
    out.push(p);
    let mut head = 0;
    while head < out.len() {
        let v = out[head] as usize;
        head += 1;
        for &w in adj.row(v) {
            if mark[w as usize] != stamp && (positions[w as usize] - c).length_squared() <= r2 {
                mark[w as usize] = stamp;
                out.push(w);
            }
        }
    }
}

/// Heap entry of [`nested_balls`] (public so that callers can keep the heap
/// allocation between calls).
#[derive(Copy, Clone, PartialEq)]
pub struct Entry(f64, u32);
impl Eq for Entry {}
impl Ord for Entry {
    fn cmp(&self, o: &Self) -> Ordering {
        // Min-heap on key, ties by index for determinism.
        o.0.total_cmp(&self.0).then(o.1.cmp(&self.1))
    }
}
impl PartialOrd for Entry {
    fn partial_cmp(&self, o: &Self) -> Option<Ordering> {
        Some(self.cmp(o))
    }
}

/// Every ball `B(p, r)` with `r <= r_max` at once (see the module docs):
/// fills `out` with `(key, vertex)` sorted by key, so that the ball of
/// radius `r` is the prefix with `key <= r`. `centre` is the point distances
/// are measured from (the position of `p`). `key_of` is scratch of
/// `positions.len()` entries, all `f64::INFINITY` on entry and on exit.
#[allow(clippy::too_many_arguments)] // scratch buffers kept by the caller
pub fn nested_balls(
    adj: &Csr,
    positions: &[DVec3],
    start: u32,
    centre: DVec3,
    r_max: f64,
    key_of: &mut [f64],
    heap: &mut BinaryHeap<Entry>,
    out: &mut Vec<(f64, u32)>,
) {
    out.clear();
    heap.clear();
    // The start (p itself, or the cluster holding p) always belongs to its
    // own ball: key 0.
    key_of[start as usize] = 0.0;
    heap.push(Entry(0.0, start));
    while let Some(Entry(k, v)) = heap.pop() {
        if k > key_of[v as usize] || k > r_max {
            continue;
        }
        out.push((k, v));
        // Settled: NEG_INFINITY makes every later pop and relaxation skip it.
        key_of[v as usize] = f64::NEG_INFINITY;
        for &w in adj.row(v as usize) {
            let kw = k.max((positions[w as usize] - centre).length());
            if kw <= r_max && kw < key_of[w as usize] {
                key_of[w as usize] = kw;
                heap.push(Entry(kw, w));
            }
        }
    }
    // Reset scratch: every touched vertex is either settled (in `out`) or
    // was pushed with a key <= r_max and later settled or left in the heap.
    for &(_, v) in out.iter() {
        key_of[v as usize] = f64::INFINITY;
    }
    for &(_, v) in out.iter() {
        for &w in adj.row(v as usize) {
            key_of[w as usize] = f64::INFINITY;
        }
    }
}

/// The balls `B(p, r)` of several increasing radii at once, each *exactly*
/// the literal [`bfs_ball`] of its radius (see the module docs), without
/// the heap of [`nested_balls`]: the traversal of radius `radii[i]` goes on
/// from the ball of `radii[i - 1]`, seeded by the vertices that the
/// previous traversal reached but left outside (`pending`). A vertex is
/// reachable within `r_i` iff it is reachable from `B(p, r_{i-1})` through
/// vertices within `r_i`, and every such path leaves `B(p, r_{i-1})`
/// through a pending vertex, so the union is the literal ball.
///
/// Fills `out` with `(radii[i], v)` for every vertex `v` of `B(p, radii[i])`
/// not in the previous ball: sorted by key, so that the ball of `radii[i]`
/// is the prefix with `key <= radii[i]`, as [`nested_balls`] gives it.
/// `centre` is the point distances are measured from; `mark` is scratch
/// of `positions.len()` entries, all different from `stamp` on entry; on
/// return it is `stamp` at every vertex seen (in the last ball, or pending
/// just outside it).
#[allow(clippy::too_many_arguments)] // scratch buffers kept by the caller
pub fn layered_balls(
    adj: &Csr,
    positions: &[DVec3],
    start: u32,
    centre: DVec3,
    radii: &[f64],
    mark: &mut [u32],
    stamp: u32,
    pending: &mut Vec<(f64, u32)>,
    out: &mut Vec<(f64, u32)>,
) {
    out.clear();
    pending.clear();
    let Some(&first) = radii.first() else {
        return;
    };
    // The start (p itself, or the cluster holding p) always belongs to its
    // own ball.
    mark[start as usize] = stamp;
    out.push((first, start));
    let mut head = 0;
    for &r in radii {
        let r2 = r * r;
        // A pending vertex carries its squared distance, computed once when
        // it was first seen: each later radius compares the same f64 again
        // instead of reading the vertex's position back (a scattered load
        // per pending vertex and radius) and recomputing it. Same values,
        // same order (`retain` keeps it), hence the same ball.
        pending.retain(|&(d2, v)| {
            if d2 <= r2 {
                out.push((r, v));
                false
            } else {
                true
            }
        });
        while head < out.len() {
            let v = out[head].1 as usize;
            head += 1;
            // The walk is a chain of scattered reads (a vertex's row, then
            // its neighbours' marks and positions); asking for the rows of
            // the vertices a few places down the queue, and for this row's
            // marks and positions before testing any, lets those misses
            // overlap. Hints only ([`prefetch`]): the ball is the same.
            if let Some(&(_, a)) = out.get(head + BFS_PREFETCH_AHEAD) {
                prefetch(adj.offsets.as_ptr().wrapping_add(a as usize));
            }
            if let Some(&(_, a)) = out.get(head + BFS_PREFETCH_AHEAD / 2) {
                prefetch(
                    adj.items
                        .as_ptr()
                        .wrapping_add(adj.offsets[a as usize] as usize),
                );
            }
            let row = adj.row(v);
            for &w in row {
                prefetch(mark.as_ptr().wrapping_add(w as usize));
                prefetch(positions.as_ptr().wrapping_add(w as usize));
            }
            for &w in row {
                let wi = w as usize;
                // Visited, or pending: a pending vertex is outside the
                // current radius (every pending vertex inside it was moved
                // into the ball when this radius started, and the others
                // were found outside it), so its distance need not be
                // computed again. One mark for both (seen), where there
                // were two (in the ball, pending): the traversal only asks
                // "seen?", and one array is one memory access per edge.
                if mark[wi] == stamp {
                    continue;
                }
                mark[wi] = stamp;
                let d2 = (positions[wi] - centre).length_squared();
                if d2 <= r2 {
                    out.push((r, w));
                } else {
                    pending.push((d2, w));
                }
            }
        }
    }
}

/// How far down the queue [`layered_balls`] asks for a vertex's adjacency
/// row (its offsets; the row itself at half this distance): a few vertices,
/// i.e. a few dozen edges of work, about one memory latency.
const BFS_PREFETCH_AHEAD: usize = 4;

/// A coarse proxy of M used by the fast mode for large radii: vertices are
/// clustered by a grid of cell size `cell`, split into the connected pieces
/// of M inside each cell (so that two sheets crossing one cell stay apart),
/// each cluster represented by its member nearest to the members' centroid
/// (a true vertex of M, so residuals measure M itself, not a smoothed copy)
/// and weighted by its member count (so that a weighted fit over clusters
/// estimates the unweighted fit over all vertices of §3.1.2).
#[derive(Clone, Debug)]
pub struct ProxyLevel {
    pub cell: f64,
    pub cluster_of: Vec<u32>,
    pub rep: Vec<DVec3>,
    pub weight: Vec<f64>,
    /// Total area of the triangles assigned to the cluster.
    pub area: Vec<f64>,
    pub adj: Csr,
    /// Triangles assigned to each cluster (by their first vertex).
    pub tris: Csr,
    /// Cumulative areas of `tris`, row by row (area-proportional draws of a
    /// triangle of a cluster in O(log) without rebuilding a table).
    pub tri_cum: Vec<f64>,
}

impl ProxyLevel {
    #[allow(clippy::needless_range_loop)] // several arrays indexed by vertex
    pub fn new(mesh: &TriMesh, areas: &[f64], vv: &Csr, cell: f64) -> ProxyLevel {
        let n = mesh.positions.len();
        let (lo, _) = mesh.bbox();
        let mut cell_id: HashMap<(i64, i64, i64), u32> = HashMap::new();
        let cells: Vec<u32> = mesh
            .positions
            .iter()
            .map(|p| {
                let q = (*p - lo) / cell;
                let key = (q.x.floor() as i64, q.y.floor() as i64, q.z.floor() as i64);
                let next = cell_id.len() as u32;
                *cell_id.entry(key).or_insert(next)
            })
            .collect();
        // Union-find of edges inside one cell.
        let mut parent: Vec<u32> = (0..n as u32).collect();
        fn find(p: &mut [u32], mut x: u32) -> u32 {
            while p[x as usize] != x {
                p[x as usize] = p[p[x as usize] as usize];
                x = p[x as usize];
            }
            x
        }
        for v in 0..n {
            for &w in vv.row(v) {
                if cells[v] == cells[w as usize] {
                    let (a, b) = (find(&mut parent, v as u32), find(&mut parent, w));
                    if a != b {
                        let (a, b) = (a.min(b), a.max(b));
                        parent[b as usize] = a;
                    }
                }
            }
        }
        let mut id = vec![u32::MAX; n];
        let mut cluster_of = vec![0u32; n];
        let mut count = 0u32;
        for v in 0..n {
            let r = find(&mut parent, v as u32) as usize;
            if id[r] == u32::MAX {
                id[r] = count;
                count += 1;
            }
            cluster_of[v] = id[r];
        }
        let m = count as usize;
        let mut centroid = vec![DVec3::ZERO; m];
        let mut weight = vec![0.0; m];
        for v in 0..n {
            centroid[cluster_of[v] as usize] += mesh.positions[v];
            weight[cluster_of[v] as usize] += 1.0;
        }
        for c in 0..m {
            centroid[c] /= weight[c];
        }
        let mut best = vec![(f64::INFINITY, 0u32); m];
        for v in 0..n {
            let c = cluster_of[v] as usize;
            let d = (mesh.positions[v] - centroid[c]).length_squared();
            if d < best[c].0 {
                best[c] = (d, v as u32);
            }
        }
        let rep = best
            .iter()
            .map(|&(_, v)| mesh.positions[v as usize])
            .collect();
        let mut pairs = Vec::new();
        for v in 0..n {
            for &w in vv.row(v) {
                let (a, b) = (cluster_of[v], cluster_of[w as usize]);
                if a != b {
                    pairs.push((a, b));
                }
            }
        }
        let adj = Csr::from_pairs(m, pairs);
        let mut area = vec![0.0; m];
        let mut tp = Vec::with_capacity(mesh.triangles.len());
        for (t, tri) in mesh.triangles.iter().enumerate() {
            let c = cluster_of[tri[0] as usize];
            area[c as usize] += areas[t];
            tp.push((c, t as u32));
        }
        let tris = Csr::from_pairs(m, tp);
        let mut tri_cum = vec![0.0; tris.items.len()];
        for c in 0..m {
            let mut acc = 0.0;
            for k in tris.offsets[c] as usize..tris.offsets[c + 1] as usize {
                acc += areas[tris.items[k] as usize];
                tri_cum[k] = acc;
            }
        }
        ProxyLevel {
            cell,
            cluster_of,
            rep,
            weight,
            area,
            adj,
            tris,
            tri_cum,
        }
    }

    /// The cumulative areas of the triangles of cluster `c`.
    pub fn tri_cum_row(&self, c: usize) -> &[f64] {
        &self.tri_cum[self.tris.offsets[c] as usize..self.tris.offsets[c + 1] as usize]
    }

    pub fn len(&self) -> usize {
        self.rep.len()
    }

    pub fn is_empty(&self) -> bool {
        self.rep.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A wavy, unevenly spaced grid folded over itself along x, so that a
    /// Euclidean ball reaches vertices that the traversal cannot (the other
    /// sheet) and radii cut through the middle of rows.
    fn folded_grid(n: u32) -> TriMesh {
        let pos = |i: u32, j: u32| {
            let (u, v) = (i as f64 / n as f64, j as f64 / n as f64);
            let a = std::f64::consts::PI * 1.8 * u * u;
            DVec3::new(0.3 * a.sin(), v + 0.02 * (7.0 * u).sin(), 0.3 * a.cos())
        };
        crate::fixtures::tri_grid(n, pos, |_, _| true)
    }

    #[test]
    fn layered_balls_are_the_literal_balls() {
        let m = folded_grid(24);
        let adj = Adjacency::new(&m);
        let n = m.positions.len();
        let radii = [0.03, 0.07, 0.15, 0.22, 0.4, 0.9];
        let (mut mark, mut mark2) = (vec![0u32; n], vec![0u32; n]);
        let (mut pending, mut out, mut ball) = (Vec::new(), Vec::new(), Vec::new());
        let mut stamp = 0;
        let mut strict_subset_seen = false;
        for p in (0..n as u32).step_by(37) {
            stamp += 1;
            let c = m.positions[p as usize];
            layered_balls(
                &adj.vv,
                &m.positions,
                p,
                c,
                &radii,
                &mut mark,
                stamp,
                &mut pending,
                &mut out,
            );
            assert!(out.windows(2).all(|w| w[0].0 <= w[1].0), "sorted by key");
            for (i, &r) in radii.iter().enumerate() {
                bfs_ball(
                    &adj.vv,
                    &m.positions,
                    p,
                    r,
                    &mut mark2,
                    stamp * 8 + i as u32,
                    &mut ball,
                );
                let mut a: Vec<u32> = out.iter().filter(|e| e.0 <= r).map(|e| e.1).collect();
                a.sort_unstable();
                ball.sort_unstable();
                assert_eq!(a, ball, "p = {p}, r = {r}");
                // The fold puts vertices within r that the traversal
                // cannot reach: the test sees the difference from a plain
                // Euclidean ball.
                let euclid = m
                    .positions
                    .iter()
                    .filter(|q| (**q - c).length() <= r)
                    .count();
                strict_subset_seen |= euclid > ball.len();
            }
        }
        assert!(strict_subset_seen);
    }

    /// The walk as it was before pending vertices carried their squared
    /// distance: each radius reads a pending vertex's position back and
    /// recomputes it. A plain restatement, kept to check the order.
    fn layered_balls_recomputing(
        adj: &Csr,
        positions: &[DVec3],
        start: u32,
        centre: DVec3,
        radii: &[f64],
    ) -> (Vec<(f64, u32)>, Vec<u32>) {
        let mut seen = vec![false; positions.len()];
        let (mut out, mut pending) = (vec![(radii[0], start)], Vec::new());
        seen[start as usize] = true;
        let mut head = 0;
        for &r in radii {
            let mut keep = Vec::new();
            for &v in &pending {
                if (positions[v as usize] - centre).length_squared() <= r * r {
                    out.push((r, v));
                } else {
                    keep.push(v);
                }
            }
            pending = keep;
            while head < out.len() {
                let v = out[head].1;
                head += 1;
                for &w in adj.row(v as usize) {
                    if std::mem::replace(&mut seen[w as usize], true) {
                        continue;
                    }
                    if (positions[w as usize] - centre).length_squared() <= r * r {
                        out.push((r, w));
                    } else {
                        pending.push(w);
                    }
                }
            }
        }
        (out, pending)
    }

    /// The fits sum a ball's points in `layered_balls`' order, so the
    /// order, not only the set, is part of the Fitmap's bytes: the walk
    /// with cached squared distances gives the recomputing walk's list
    /// (keys and vertices, in order) and leaves the same vertices pending,
    /// in the same order, with their exact squared distances. Centres on a
    /// vertex (level 0) and off it (a proxy level's cluster centre), and
    /// one radius (the proxies' call).
    #[test]
    fn cached_distances_keep_the_walk_order() {
        let m = folded_grid(24);
        let adj = Adjacency::new(&m);
        let n = m.positions.len();
        let (mut mark, mut pending, mut out) = (vec![0u32; n], Vec::new(), Vec::new());
        let mut stamp = 0;
        let mut pending_checked = 0;
        let many = [0.03, 0.07, 0.15, 0.22, 0.4, 0.9];
        for p in (0..n as u32).step_by(23) {
            for (radii, shift) in [(&many[..], 0.0), (&many[..], 0.011), (&[0.15][..], 0.007)] {
                stamp += 1;
                let c = m.positions[p as usize] + DVec3::new(shift, -shift, 0.5 * shift);
                layered_balls(
                    &adj.vv,
                    &m.positions,
                    p,
                    c,
                    radii,
                    &mut mark,
                    stamp,
                    &mut pending,
                    &mut out,
                );
                let (want, want_pending) =
                    layered_balls_recomputing(&adj.vv, &m.positions, p, c, radii);
                assert_eq!(out.len(), want.len(), "p = {p}");
                for (a, b) in out.iter().zip(&want) {
                    assert_eq!((a.0.to_bits(), a.1), (b.0.to_bits(), b.1), "p = {p}");
                }
                let got: Vec<u32> = pending.iter().map(|e| e.1).collect();
                assert_eq!(got, want_pending, "p = {p}");
                for &(d2, v) in &pending {
                    let exact = (m.positions[v as usize] - c).length_squared();
                    assert_eq!(d2.to_bits(), exact.to_bits());
                    assert!(d2 > radii[radii.len() - 1].powi(2));
                }
                pending_checked += pending.len();
            }
        }
        assert!(
            pending_checked > 100,
            "the walks must leave vertices pending ({pending_checked})"
        );
    }
}
