//! Maximum matching in a general graph (Edmonds' blossom algorithm), used on
//! the dual graph of a triangle mesh to pair triangles into quads.
//!
//! The search is the classic BFS from one free vertex with blossom
//! contraction, written so that its cost is proportional to the part of the
//! graph it explores rather than to the graph size: the per-vertex state is
//! reset only where it was touched, and blossom bases live in a union-find
//! structure (no scan of all vertices per contraction). After a greedy pass
//! the free vertices are few and their augmenting paths short, so the whole
//! pass is close to linear on mesh dual graphs.

use std::collections::VecDeque;

pub(crate) const NONE: u32 = u32::MAX;

/// Undirected graph in compressed adjacency form.
pub(crate) struct Graph {
    pub off: Vec<u32>,
    pub adj: Vec<u32>,
}

impl Graph {
    pub fn num_vertices(&self) -> usize {
        self.off.len() - 1
    }
    #[inline]
    pub fn neighbours(&self, v: u32) -> &[u32] {
        &self.adj[self.off[v as usize] as usize..self.off[v as usize + 1] as usize]
    }
}

pub(crate) struct Matcher<'g> {
    g: &'g Graph,
    pub mate: Vec<u32>,
    parent: Vec<u32>,
    /// Even (outer) vertices of the current alternating tree.
    even: Vec<bool>,
    in_tree: Vec<bool>,
    uf: Vec<u32>,
    /// Blossom base stored at each union-find root.
    uf_base: Vec<u32>,
    mark: Vec<u32>,
    stamp: u32,
    touched: Vec<u32>,
    queue: VecDeque<u32>,
    merge: Vec<u32>,
}

impl<'g> Matcher<'g> {
    pub fn new(g: &'g Graph, mate: Vec<u32>) -> Self {
        let n = g.num_vertices();
        debug_assert_eq!(mate.len(), n);
        Matcher {
            g,
            mate,
            parent: vec![NONE; n],
            even: vec![false; n],
            in_tree: vec![false; n],
            uf: (0..n as u32).collect(),
            uf_base: (0..n as u32).collect(),
            mark: vec![0; n],
            stamp: 0,
            touched: Vec::new(),
            queue: VecDeque::new(),
            merge: Vec::new(),
        }
    }

    /// Augments from every free vertex in index order; returns the number of
    /// augmentations. A free vertex with no augmenting path never gets one
    /// later (Edmonds), so one pass yields a maximum matching.
    pub fn maximise(&mut self) -> usize {
        let mut augmentations = 0;
        for root in 0..self.g.num_vertices() as u32 {
            if self.mate[root as usize] != NONE {
                continue;
            }
            if let Some(end) = self.search(root) {
                self.augment(end);
                augmentations += 1;
            }
            self.reset();
        }
        augmentations
    }

    fn touch(&mut self, v: u32) {
        if !self.in_tree[v as usize] {
            self.in_tree[v as usize] = true;
            self.touched.push(v);
        }
    }

    fn reset(&mut self) {
        for &v in &self.touched {
            let i = v as usize;
            self.parent[i] = NONE;
            self.even[i] = false;
            self.in_tree[i] = false;
            self.uf[i] = v;
            self.uf_base[i] = v;
        }
        self.touched.clear();
        self.queue.clear();
    }

    fn find(&mut self, mut v: u32) -> u32 {
        while self.uf[v as usize] != v {
            let p = self.uf[v as usize];
            self.uf[v as usize] = self.uf[p as usize];
            v = p;
        }
        v
    }

    fn base(&mut self, v: u32) -> u32 {
        let r = self.find(v);
        self.uf_base[r as usize]
    }

    fn lca(&mut self, mut a: u32, mut b: u32) -> u32 {
        self.stamp = self.stamp.wrapping_add(1);
        if self.stamp == 0 {
            self.mark.iter_mut().for_each(|m| *m = 0);
            self.stamp = 1;
        }
        loop {
            a = self.base(a);
            self.mark[a as usize] = self.stamp;
            let m = self.mate[a as usize];
            if m == NONE {
                break;
            }
            a = self.parent[m as usize];
        }
        loop {
            b = self.base(b);
            if self.mark[b as usize] == self.stamp {
                return b;
            }
            b = self.parent[self.mate[b as usize] as usize];
        }
    }

    fn mark_path(&mut self, mut v: u32, b: u32, mut child: u32) {
        while self.base(v) != b {
            let m = self.mate[v as usize];
            self.merge.push(v);
            self.merge.push(m);
            self.parent[v as usize] = child;
            child = m;
            // The odd vertex becomes part of an outer blossom: scan it too.
            if !self.even[m as usize] {
                self.even[m as usize] = true;
                self.queue.push_back(m);
            }
            v = self.parent[m as usize];
        }
    }

    /// Alternating BFS from `root`; returns the free vertex that ends an
    /// augmenting path, the path being recorded in `parent`/`mate`.
    fn search(&mut self, root: u32) -> Option<u32> {
        self.touch(root);
        self.even[root as usize] = true;
        self.queue.push_back(root);
        let g = self.g;
        while let Some(v) = self.queue.pop_front() {
            for &to in g.neighbours(v) {
                if self.mate[v as usize] == to {
                    continue;
                }
                let bv = self.base(v);
                let bt = self.base(to);
                if bv == bt {
                    continue;
                }
                let to_is_outer = to == root
                    || (self.mate[to as usize] != NONE
                        && self.parent[self.mate[to as usize] as usize] != NONE);
                if to_is_outer {
                    let b = self.lca(v, to);
                    self.merge.clear();
                    self.mark_path(v, b, to);
                    self.mark_path(to, b, v);
                    let merge = std::mem::take(&mut self.merge);
                    for &x in &merge {
                        let rx = self.find(x);
                        let rb = self.find(b);
                        if rx != rb {
                            self.uf[rx as usize] = rb;
                        }
                        self.uf_base[rb as usize] = b;
                    }
                    self.merge = merge;
                } else if self.parent[to as usize] == NONE {
                    self.touch(to);
                    self.parent[to as usize] = v;
                    let m = self.mate[to as usize];
                    if m == NONE {
                        return Some(to);
                    }
                    self.touch(m);
                    self.even[m as usize] = true;
                    self.queue.push_back(m);
                }
            }
        }
        None
    }

    fn augment(&mut self, end: u32) {
        let mut v = end;
        while v != NONE {
            let pv = self.parent[v as usize];
            let ppv = self.mate[pv as usize];
            self.mate[v as usize] = pv;
            self.mate[pv as usize] = v;
            v = ppv;
        }
    }
}

/// Moves the unmatched vertex `hole` along an even alternating path to the
/// nearest vertex accepted by `is_target` (BFS over matched edges, so the
/// matching keeps its size). Returns the new hole and the number of matched
/// pairs that were swapped, or `None` when no target is reachable.
pub(crate) fn shift_hole(
    g: &Graph,
    mate: &mut [u32],
    hole: u32,
    is_target: impl Fn(u32) -> bool,
) -> Option<(u32, usize)> {
    if is_target(hole) {
        return Some((hole, 0));
    }
    // from[p] = the even vertex we came from, via[p] = the odd vertex between.
    let mut from: std::collections::HashMap<u32, (u32, u32)> = Default::default();
    from.insert(hole, (NONE, NONE));
    let mut queue = VecDeque::from([hole]);
    let mut found = None;
    'bfs: while let Some(v) = queue.pop_front() {
        for &n in g.neighbours(v) {
            let p = mate[n as usize];
            if p == NONE || p == v || from.contains_key(&p) {
                continue;
            }
            from.insert(p, (v, n));
            if is_target(p) {
                found = Some(p);
                break 'bfs;
            }
            queue.push_back(p);
        }
    }
    let target = found?;
    let mut cur = target;
    let mut steps = 0;
    mate[target as usize] = NONE;
    while cur != hole {
        let (prev, n) = from[&cur];
        mate[n as usize] = prev;
        mate[prev as usize] = n;
        cur = prev;
        steps += 1;
    }
    Some((target, steps))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn graph(n: usize, edges: &[(u32, u32)]) -> Graph {
        let mut lists = vec![Vec::new(); n];
        for &(a, b) in edges {
            lists[a as usize].push(b);
            lists[b as usize].push(a);
        }
        let mut off = vec![0u32];
        let mut adj = Vec::new();
        for l in lists {
            adj.extend(l);
            off.push(adj.len() as u32);
        }
        Graph { off, adj }
    }

    fn check(g: &Graph, mate: &[u32]) -> usize {
        let mut n = 0;
        for v in 0..mate.len() {
            let m = mate[v];
            if m != NONE {
                assert_eq!(mate[m as usize], v as u32);
                assert!(g.neighbours(v as u32).contains(&m));
                n += 1;
            }
        }
        n / 2
    }

    #[test]
    fn blossom_needed() {
        // A 5-cycle 0..4 with a pendant 5 on vertex 4 and 6 on vertex 2; the
        // greedy matching (0-1), (2-3) blocks; the perfect matching needs an
        // augmenting path through the odd cycle.
        let g = graph(
            8,
            &[
                (0, 1),
                (1, 2),
                (2, 3),
                (3, 4),
                (4, 0),
                (4, 5),
                (2, 6),
                (6, 7),
            ],
        );
        let mut mate = vec![NONE; 8];
        for (a, b) in [(0, 1), (2, 3), (6, 7)] {
            mate[a] = b as u32;
            mate[b] = a as u32;
        }
        let mut m = Matcher::new(&g, mate);
        m.maximise();
        assert_eq!(check(&g, &m.mate), 4);
    }

    #[test]
    fn petersen_graph_perfect() {
        let mut e = Vec::new();
        for i in 0..5u32 {
            e.push((i, (i + 1) % 5));
            e.push((i, i + 5));
            e.push((i + 5, (i + 2) % 5 + 5));
        }
        let g = graph(10, &e);
        let mut m = Matcher::new(&g, vec![NONE; 10]);
        m.maximise();
        assert_eq!(check(&g, &m.mate), 5);
    }

    #[test]
    fn odd_path_leaves_one_and_shifts() {
        let g = graph(5, &[(0, 1), (1, 2), (2, 3), (3, 4)]);
        let mut m = Matcher::new(&g, vec![NONE; 5]);
        m.maximise();
        assert_eq!(check(&g, &m.mate), 2);
        let mut mate = m.mate.clone();
        let hole = (0..5).find(|&v| mate[v] == NONE).unwrap() as u32;
        let (t, _) = shift_hole(&g, &mut mate, hole, |v| v == 4).unwrap();
        assert_eq!(t, 4);
        assert_eq!(mate[4], NONE);
        assert_eq!(check(&g, &mate), 2);
    }
}
