//! Multi-step valence moves for [`super::cleanup`]: a sequence of edge
//! rotations that lowers the valence energy only as a whole.
//!
//! A valence-3 / valence-5 pair next to each other is a dislocation of the
//! quad lattice; one rotation beside it moves it one step without changing
//! `E = Σ |valence − ideal|` (the 3 and the 5 become regular, a regular
//! neighbour pair becomes the new 3–5), and two dislocations of opposite
//! sense that meet annihilate (E drops by 4). A single-operation cleanup
//! never takes the energy-neutral steps, so separated pairs stay (the gap
//! to QuadriFlow, whose integer-offset flow removes them globally, Jakob et
//! al. 2015 §6 and Huang et al. 2018 §5; Tarini et al. 2010 §4 combine
//! their local operators in the same way, kept only if the whole
//! combination pays off).
//!
//! [`plan`] searches, around one irregular vertex and on a copy of its
//! neighbourhood only (the control mesh is not touched), the sequences of
//! at most [`MAX_STEPS`] rotations whose every prefix keeps E at most
//! [`SLACK`] above the start and whose end lowers it, each step touching a
//! vertex that is irregular at that point (only such rotations can keep E
//! from rising). The caller applies the best sequence through the
//! simplifier (local refit, fitmap tests, undo) and keeps it only as a
//! whole.

use std::collections::HashMap;

use crate::mesh::{ControlMesh, VertexId};
use crate::quad::ops::{Rotation, ValenceTargets};

/// Rotations in one move at most.
pub const MAX_STEPS: usize = 4;

/// How far E may rise above its start inside a move (0: never).
pub const SLACK: i64 = 0;

/// States a search expands at most (bounds the time per seed).
const BUDGET: usize = 400;

/// One rotation of a move: the edge `u → w` (the half-edge in the face
/// `(u, w, p, q)`, as [`crate::quad::ops::rotate_edge`] reads it) turned
/// `dir`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Step {
    pub u: VertexId,
    pub w: VertexId,
    pub dir: Rotation,
}

/// A move found by [`plan`]: its steps and the drop in E.
#[derive(Clone, Debug)]
pub struct Move {
    pub steps: Vec<Step>,
    pub gain: i64,
}

/// The neighbourhood of a seed as plain quads (local vertex indices),
/// edited in place by the search and restored on the way back.
struct Local {
    /// Local index → control vertex.
    global: Vec<VertexId>,
    /// Every face of the vertex is in `faces` (its valence and edges are
    /// all known here).
    complete: Vec<bool>,
    /// Valence now (the control mesh's, changed by the search's steps).
    valence: Vec<usize>,
    /// Ideal valence ([`ValenceTargets::ideal`]) and whether the vertex
    /// is on the boundary.
    ideal: Vec<usize>,
    boundary: Vec<bool>,
    faces: Vec<[u32; 4]>,
    /// Directed edge → the face that has it.
    edge: HashMap<(u32, u32), usize>,
    expanded: usize,
}

impl Local {
    fn valence(&self, v: u32) -> usize {
        self.valence[v as usize]
    }
    fn penalty(&self, v: u32, d: usize) -> i64 {
        d.abs_diff(self.ideal[v as usize]) as i64
    }
    fn irregular(&self, v: u32) -> bool {
        self.penalty(v, self.valence(v)) != 0
    }
    fn adjacent(&self, a: u32, b: u32) -> bool {
        self.edge.contains_key(&(a, b)) || self.edge.contains_key(&(b, a))
    }

    /// The hexagon `[u, r, s, w, p, q]` of the edge `u → w` in face `i`
    /// (see [`crate::quad::ops::rotate_edge`]) and the twin face.
    fn hexagon(&self, i: usize, c: usize) -> Option<([u32; 6], usize)> {
        let f = self.faces[i];
        let (u, w, p, q) = (f[c], f[(c + 1) % 4], f[(c + 2) % 4], f[(c + 3) % 4]);
        let j = *self.edge.get(&(w, u))?;
        let g = self.faces[j];
        let cw = g.iter().position(|&x| x == w)?;
        let (r, s) = (g[(cw + 2) % 4], g[(cw + 3) % 4]);
        Some(([u, r, s, w, p, q], j))
    }

    /// The rotation's two new quads and new edge, as in `rotate_edge`.
    fn rotated(x: [u32; 6], dir: Rotation) -> ([[u32; 4]; 2], [u32; 2]) {
        let k = if dir == Rotation::Ccw { 1 } else { 2 };
        let at = |i: usize| x[(k + i) % 6];
        (
            [[at(0), at(1), at(2), at(3)], [at(3), at(4), at(5), at(0)]],
            [at(0), at(3)],
        )
    }

    /// `can_rotate_edge`'s checks on the local copy, plus: every hexagon
    /// vertex complete (its valence and edges known). Returns the gain.
    fn check(&self, x: [u32; 6], dir: Rotation) -> Option<i64> {
        for i in 0..6 {
            if x[..i].contains(&x[i]) || !self.complete[x[i] as usize] {
                return None;
            }
        }
        let (_, [a, b]) = Self::rotated(x, dir);
        if self.adjacent(a, b) {
            return None;
        }
        for v in [x[0], x[3]] {
            // `min_valence`: 2 on the boundary, 3 inside.
            let b = self.boundary[v as usize];
            let need = if b { 2 } else { 3 } + 1 + usize::from(b);
            if self.valence(v) < need {
                return None;
            }
        }
        let mut gain = 0;
        for &v in &x {
            let d = self.valence(v);
            let nd = if v == x[0] || v == x[3] {
                d - 1
            } else if v == a || v == b {
                d + 1
            } else {
                d
            };
            gain += self.penalty(v, d) - self.penalty(v, nd);
        }
        Some(gain)
    }

    /// Replaces faces `i` and `j` by `to` (edge map kept).
    fn swap(&mut self, i: usize, j: usize, from: [[u32; 4]; 2], to: [[u32; 4]; 2]) {
        // Remove both first: the new faces reuse some directed edges.
        for f in from {
            for c in 0..4 {
                self.edge.remove(&(f[c], f[(c + 1) % 4]));
            }
        }
        for (idx, f) in [(i, to[0]), (j, to[1])] {
            self.faces[idx] = f;
            for c in 0..4 {
                self.edge.insert((f[c], f[(c + 1) % 4]), idx);
            }
        }
    }

    /// Applies (`sign` 1) or undoes (`sign` −1) a rotation of faces `i`
    /// and `j`, whose faces before it were `old`.
    fn rotate(
        &mut self,
        i: usize,
        j: usize,
        x: [u32; 6],
        dir: Rotation,
        old: [[u32; 4]; 2],
        sign: i64,
    ) {
        let (new, [a, b]) = Self::rotated(x, dir);
        if sign > 0 {
            self.swap(i, j, old, new);
        } else {
            self.swap(i, j, new, old);
        }
        let add = |d: &mut usize, s: i64| *d = (*d as i64 + s) as usize;
        add(&mut self.valence[x[0] as usize], -sign);
        add(&mut self.valence[x[3] as usize], -sign);
        add(&mut self.valence[a as usize], sign);
        add(&mut self.valence[b as usize], sign);
    }

    /// The rotations worth trying now: edges of faces around a currently
    /// irregular complete vertex, each undirected edge once (from its face
    /// with `u < w`), both directions, in face and corner order.
    fn options(&self) -> Vec<(usize, usize, [u32; 6], Rotation, i64)> {
        let mut out = Vec::new();
        for i in 0..self.faces.len() {
            let f = self.faces[i];
            if !f
                .iter()
                .any(|&v| self.complete[v as usize] && self.irregular(v))
            {
                continue;
            }
            for c in 0..4 {
                if f[c] > f[(c + 1) % 4] {
                    continue;
                }
                let Some((x, j)) = self.hexagon(i, c) else {
                    continue;
                };
                for dir in [Rotation::Ccw, Rotation::Cw] {
                    if let Some(g) = self.check(x, dir) {
                        out.push((i, j, x, dir, g));
                    }
                }
            }
        }
        out
    }

    /// Depth-first search; `path` holds the steps so far, `sum` their gain.
    fn search(
        &mut self,
        path: &mut Vec<Step>,
        sum: i64,
        last: Option<[u32; 2]>,
        best: &mut Option<Move>,
    ) {
        if self.expanded >= BUDGET || path.len() >= MAX_STEPS {
            return;
        }
        self.expanded += 1;
        for (i, j, x, dir, g) in self.options() {
            // Never rotate the edge the last step made (that undoes it).
            let e = [x[0].min(x[3]), x[0].max(x[3])];
            if last == Some(e) {
                continue;
            }
            let total = sum + g;
            if total < -SLACK {
                continue;
            }
            path.push(Step {
                u: self.global[x[0] as usize],
                w: self.global[x[3] as usize],
                dir,
            });
            let better = |b: &Option<Move>| {
                b.as_ref().map_or(true, |m| {
                    (total, -(path.len() as i64)) > (m.gain, -(m.steps.len() as i64))
                })
            };
            if total > 0 && better(best) {
                *best = Some(Move {
                    steps: path.clone(),
                    gain: total,
                });
            }
            let old = [self.faces[i], self.faces[j]];
            self.rotate(i, j, x, dir, old, 1);
            let (_, [a, b]) = Self::rotated(x, dir);
            self.search(path, total, Some([a.min(b), a.max(b)]), best);
            self.rotate(i, j, x, dir, old, -1);
            path.pop();
            if self.expanded >= BUDGET {
                return;
            }
        }
    }
}

/// The best move around `seed` (most E removed, then fewest steps; the
/// first found among equals): `None` if no sequence of at most
/// [`MAX_STEPS`] rotations within the search's budget lowers E. `k` is not
/// changed.
pub fn plan(k: &ControlMesh, vt: &ValenceTargets, seed: VertexId) -> Option<Move> {
    // Rings enough for every step to stay among complete vertices.
    let rings = MAX_STEPS + 1;
    let mut local: HashMap<VertexId, u32> = HashMap::new();
    let mut global = vec![seed];
    local.insert(seed, 0);
    let mut start = 0;
    for _ in 0..rings {
        let end = global.len();
        for i in start..end {
            let v = global[i];
            for h in k.outgoing(v) {
                let u = k.head(h);
                if let std::collections::hash_map::Entry::Vacant(e) = local.entry(u) {
                    e.insert(global.len() as u32);
                    global.push(u);
                }
            }
        }
        start = end;
    }
    let inner = global.len();
    let mut faces_seen = std::collections::HashSet::new();
    let mut faces = Vec::new();
    for i in 0..inner {
        for f in k.vertex_faces(global[i]) {
            if !faces_seen.insert(f) {
                continue;
            }
            let q = crate::quad::ops::quad(k, f);
            let mut lq = [0u32; 4];
            for (c, v) in q.into_iter().enumerate() {
                let n = global.len() as u32;
                lq[c] = *local.entry(v).or_insert_with(|| {
                    global.push(v);
                    n
                });
            }
            faces.push(lq);
        }
    }
    let complete = (0..global.len()).map(|i| i < inner).collect();
    let mut edge = HashMap::new();
    for (i, f) in faces.iter().enumerate() {
        for c in 0..4 {
            edge.insert((f[c], f[(c + 1) % 4]), i);
        }
    }
    let mut l = Local {
        valence: global.iter().map(|&v| k.valence(v)).collect(),
        ideal: global.iter().map(|&v| vt.ideal(k, v)).collect(),
        boundary: global.iter().map(|&v| k.is_boundary_vertex(v)).collect(),
        global,
        complete,
        faces,
        edge,
        expanded: 0,
    };
    let mut best = None;
    l.search(&mut Vec::new(), 0, None, &mut best);
    best
}
