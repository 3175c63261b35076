//! Pure quads from a quad-dominant lattice extracted at the target size,
//! changing only the faces near its non-quads (instead of one
//! Catmull-Clark split of every face, which makes the lattice's structure
//! twice as coarse as the patches).
//!
//! Every polygon with an even number of sides splits into quads by chords;
//! an odd one cannot, so odd faces are made even in pairs: a shortest
//! path of faces joins two odd faces (or one odd face and M's boundary),
//! and a new point in the middle of every edge the path crosses adds one
//! side to each end face and two to each face on the way (the parity
//! argument of quad-dominant to pure-quad conversion, e.g. Bommes et al.,
//! "Quad-mesh generation and processing: a survey", CGF 2013, §5; on a
//! closed mesh the odd faces come in pairs since the sides sum to twice
//! the edges). Even faces of six or more sides are then filled by the
//! lattice's grid where they are a rectangular hole of it, else cut into
//! quads by chords chosen first by the valences their ends get, then by
//! their corners' angles ([`Cut`]).

use std::collections::{HashMap, HashSet, VecDeque};

use crate::DVec3;

fn key(a: u32, b: u32) -> (u32, u32) {
    (a.min(b), a.max(b))
}

/// The pure-quad mesh of `polys` (oriented polygons on the points `pos`):
/// new points appended to `pos`; `None` when an odd face finds no partner
/// (no path of faces to another odd face or to a boundary).
pub fn to_quads(pos: &mut Vec<DVec3>, polys: Vec<Vec<u32>>) -> Option<Vec<[u32; 4]>> {
    let polys = make_even(pos, polys)?;
    let mut edges: HashSet<(u32, u32)> = HashSet::new();
    for p in &polys {
        for i in 0..p.len() {
            edges.insert(key(p[i], p[(i + 1) % p.len()]));
        }
    }
    let (mut val, bnd) = valences(&polys, pos.len());
    let mut quads = Vec::with_capacity(polys.len());
    let mut cut = Cut {
        pos,
        edges: &mut edges,
        val: &mut val,
        bnd: &bnd,
    };
    for p in polys {
        if p.len() > 4 && cut.fill_rectangle(&p, &mut quads) {
            continue;
        }
        cut.split_even(p, &mut quads)?;
    }
    Some(remove_doublets(quads))
}

/// Removes interior points of valence 2 (a doublet: two quads sharing two
/// consecutive sides), merging their two quads into one, until none is
/// left. A path's end point can be left so when no chord of its face
/// reaches it; a doublet is a flat pinch of the limit surface.
fn remove_doublets(mut quads: Vec<[u32; 4]>) -> Vec<[u32; 4]> {
    loop {
        let mut around: HashMap<u32, Vec<usize>> = HashMap::new();
        let mut ef: HashMap<(u32, u32), usize> = HashMap::new();
        for (f, q) in quads.iter().enumerate() {
            for i in 0..4 {
                around.entry(q[i]).or_default().push(f);
                *ef.entry(key(q[i], q[(i + 1) % 4])).or_default() += 1;
            }
        }
        let mut doublets: Vec<(u32, usize, usize)> = around
            .iter()
            .filter(|(_, fs)| fs.len() == 2)
            .map(|(&v, fs)| (v, fs[0], fs[1]))
            .filter(|&(v, f, _)| {
                let q = quads[f];
                let i = q.iter().position(|&x| x == v).expect("corner");
                ef[&key(v, q[(i + 1) % 4])] == 2 && ef[&key(v, q[(i + 3) % 4])] == 2
            })
            .collect();
        doublets.sort_unstable();
        let mut dead = vec![false; quads.len()];
        let mut merged = Vec::new();
        for (v, f, g) in doublets {
            if dead[f] || dead[g] {
                continue;
            }
            // f = (v, a, x, b), g = (v, b, y, a): the merged quad (a, x, b, y).
            let (qf, qg) = (quads[f], quads[g]);
            let i = qf.iter().position(|&x| x == v).expect("corner");
            let j = qg.iter().position(|&x| x == v).expect("corner");
            let (a, x, b) = (qf[(i + 1) % 4], qf[(i + 2) % 4], qf[(i + 3) % 4]);
            let y = qg[(j + 2) % 4];
            if qg[(j + 1) % 4] != b || qg[(j + 3) % 4] != a || x == y {
                continue;
            }
            dead[f] = true;
            dead[g] = true;
            merged.push([a, x, b, y]);
        }
        if merged.is_empty() {
            return quads;
        }
        quads = quads
            .into_iter()
            .zip(dead)
            .filter(|(_, d)| !d)
            .map(|(q, _)| q)
            .chain(merged)
            .collect();
    }
}

/// Pairs the odd faces by shortest dual paths and puts a middle point on
/// every edge crossed (each edge at most once, so paths never cancel).
fn make_even(pos: &mut Vec<DVec3>, polys: Vec<Vec<u32>>) -> Option<Vec<Vec<u32>>> {
    let mut ef: HashMap<(u32, u32), Vec<usize>> = HashMap::new();
    for (f, p) in polys.iter().enumerate() {
        for i in 0..p.len() {
            ef.entry(key(p[i], p[(i + 1) % p.len()]))
                .or_default()
                .push(f);
        }
    }
    let mut odd: Vec<bool> = polys.iter().map(|p| p.len() % 2 == 1).collect();
    let mut split: HashMap<(u32, u32), u32> = HashMap::new();
    let nf = polys.len();
    for f0 in 0..nf {
        if !odd[f0] {
            continue;
        }
        // Breadth-first over faces through edges not yet split; stop at the
        // first other odd face, or a face with a free boundary edge.
        let mut from: Vec<Option<(usize, (u32, u32))>> = vec![None; nf];
        let mut seen = vec![false; nf];
        seen[f0] = true;
        let mut queue = VecDeque::from([f0]);
        let mut end: Option<(usize, Option<(u32, u32)>)> = None;
        'bfs: while let Some(f) = queue.pop_front() {
            let p = &polys[f];
            for i in 0..p.len() {
                let e = key(p[i], p[(i + 1) % p.len()]);
                if split.contains_key(&e) {
                    continue;
                }
                let fs = &ef[&e];
                if fs.len() == 1 {
                    end = Some((f, Some(e)));
                    break 'bfs;
                }
                for &g in fs {
                    if g == f || seen[g] {
                        continue;
                    }
                    seen[g] = true;
                    from[g] = Some((f, e));
                    if odd[g] {
                        end = Some((g, None));
                        break 'bfs;
                    }
                    queue.push_back(g);
                }
            }
        }
        let (mut f, boundary) = end?;
        let mut crossed: Vec<(u32, u32)> = boundary.into_iter().collect();
        odd[f] = false;
        odd[f0] = false;
        while let Some((g, e)) = from[f] {
            crossed.push(e);
            f = g;
        }
        for e in crossed {
            let m = pos.len() as u32;
            pos.push(0.5 * (pos[e.0 as usize] + pos[e.1 as usize]));
            split.insert(e, m);
        }
    }
    let out = polys
        .into_iter()
        .map(|p| {
            let k = p.len();
            let mut q = Vec::with_capacity(k + 2);
            for i in 0..k {
                q.push(p[i]);
                if let Some(&m) = split.get(&key(p[i], p[(i + 1) % k])) {
                    q.push(m);
                }
            }
            q
        })
        .collect();
    Some(out)
}

/// Valence per point (edges at it) and whether it is on the boundary (has
/// an edge used by one polygon).
pub(super) fn valences(polys: &[Vec<u32>], n: usize) -> (Vec<usize>, Vec<bool>) {
    let mut count: HashMap<(u32, u32), u8> = HashMap::new();
    for p in polys {
        for i in 0..p.len() {
            *count.entry(key(p[i], p[(i + 1) % p.len()])).or_default() += 1;
        }
    }
    let (mut val, mut bnd) = (vec![0usize; n], vec![false; n]);
    for (&(a, b), &c) in &count {
        for v in [a, b] {
            val[v as usize] += 1;
            bnd[v as usize] |= c == 1;
        }
    }
    (val, bnd)
}

/// How far a valence is from regular: 4 inside, 2 (a corner of the
/// boundary) or 3 (a straight stretch of it) on the boundary.
pub(super) fn irregularity(val: usize, boundary: bool) -> i64 {
    let v = val as i64;
    if boundary {
        (2 - v).max(v - 3).max(0)
    } else {
        (v - 4).abs()
    }
}

/// The state of cutting even polygons into quads: the points, the edges
/// made so far (a chord must not repeat one: a second edge between two
/// points would not be a manifold) and every point's valence as the
/// chords raise it.
struct Cut<'a> {
    pos: &'a mut Vec<DVec3>,
    edges: &'a mut HashSet<(u32, u32)>,
    val: &'a mut Vec<usize>,
    bnd: &'a [bool],
}

impl Cut<'_> {
    /// Cuts an even polygon into quads: while it has more than four sides,
    /// the quad cut off by the best chord `p[i]–p[i+3]` that is not
    /// already an edge. A chord raises its two ends' valences by one, so
    /// it decides whether they end regular: a hexagon left where one
    /// lattice edge is missing becomes two quads with no irregular vertex
    /// only when the chord joins the two points that lack it, and a path's
    /// new point (valence 2) needs a chord from each side. The cost is the
    /// change in irregularity of the chord's ends, [`VALENCE_DEGREES`] per
    /// unit, plus the worst corner of the quad cut off and of the rest at
    /// the chord's ends in degrees from 90.
    fn split_even(&mut self, mut p: Vec<u32>, quads: &mut Vec<[u32; 4]>) -> Option<()> {
        while p.len() > 4 {
            let k = p.len();
            let pos = &self.pos[..];
            let (val, bnd) = (&self.val[..], self.bnd);
            let cost = |i: usize| {
                let (u, v) = (p[i], p[(i + 3) % k]);
                let cut = [u, p[(i + 1) % k], p[(i + 2) % k], v];
                let worst = (0..4)
                    .map(|c| corner_deviation(pos, cut[(c + 3) % 4], cut[c], cut[(c + 1) % 4]))
                    .fold(0.0, f64::max)
                    .max(corner_deviation(pos, v, u, p[(i + k - 1) % k]))
                    .max(corner_deviation(pos, p[(i + 4) % k], v, u));
                let rise = |x: u32| {
                    let (n, b) = (val[x as usize], bnd[x as usize]);
                    irregularity(n + 1, b) - irregularity(n, b)
                };
                worst + VALENCE_DEGREES * (rise(u) + rise(v)) as f64
            };
            let best = (0..k)
                .filter(|&i| !self.edges.contains(&key(p[i], p[(i + 3) % k])))
                .min_by(|&a, &b| cost(a).total_cmp(&cost(b)).then(a.cmp(&b)))?;
            quads.push([
                p[best],
                p[(best + 1) % k],
                p[(best + 2) % k],
                p[(best + 3) % k],
            ]);
            self.add_edge(p[best], p[(best + 3) % k]);
            let (a, b) = ((best + 1) % k, (best + 2) % k);
            p = (0..k).filter(|&i| i != a && i != b).map(|i| p[i]).collect();
        }
        (p.len() == 4).then(|| quads.push([p[0], p[1], p[2], p[3]]))
    }

    fn add_edge(&mut self, u: u32, v: u32) {
        self.edges.insert(key(u, v));
        for x in [u, v] {
            if let Some(n) = self.val.get_mut(x as usize) {
                *n += 1;
            }
        }
    }

    /// Fills an even polygon that is a hole of a regular lattice by that
    /// lattice: where every corner lacks 0 (a convex corner of the hole) or
    /// 1 (a straight side) of the 4 edges an interior lattice point has,
    /// with exactly four convex corners and opposite sides of equal length
    /// a, b, the hole is an a × b block of cells whose inner points the
    /// extraction lost (a lattice point whose cluster was dropped, or edges
    /// the flow left longer than one step). Filling it with the a × b grid
    /// (new inner points on the Coons patch of its sides) leaves every
    /// corner at valence 4 and the new points too, where cutting it by
    /// chords cannot: a chord `p[i]–p[i+3]` joins points of both parities,
    /// so on an octagon round one lost point it always raises a convex
    /// corner to 5 (QuadriFlow fills its extraction's holes by quads too,
    /// `Parametrizer::FixHoles`). Returns `false` (nothing changed) when
    /// the polygon is not such a block, touches M's boundary, or a grid
    /// edge between two of its corners would repeat an existing edge.
    fn fill_rectangle(&mut self, p: &[u32], quads: &mut Vec<[u32; 4]>) -> bool {
        let k = p.len();
        if p.iter().any(|&v| self.bnd[v as usize]) {
            return false;
        }
        let lack: Vec<usize> = p
            .iter()
            .map(|&v| 4usize.saturating_sub(self.val[v as usize]))
            .collect();
        if lack.iter().any(|&l| l > 1) {
            return false;
        }
        let corners: Vec<usize> = (0..k).filter(|&i| lack[i] == 0).collect();
        if corners.len() != 4 || p.iter().any(|&v| self.val[v as usize] > 4) {
            return false;
        }
        let side = |s: usize| (corners[(s + 1) % 4] + k - corners[s]) % k;
        let (a, b) = (side(0), side(1));
        if side(2) != a || side(3) != b {
            return false;
        }
        // Grid point (i, j), 0 ≤ i ≤ a, 0 ≤ j ≤ b: the sides walk
        // (0,0) → (a,0) → (a,b) → (0,b) → (0,0), the polygon's order.
        let c0 = corners[0];
        let at = |t: usize| p[(c0 + t) % k];
        let boundary = |i: usize, j: usize| -> Option<u32> {
            if j == 0 {
                Some(at(i))
            } else if i == a {
                Some(at(a + j))
            } else if j == b {
                Some(at(a + b + (a - i)))
            } else if i == 0 {
                Some(at(2 * a + b + (b - j)))
            } else {
                None
            }
        };
        // Edges between two boundary points (a or b of 1) must be new.
        let mut inner_edges = Vec::new();
        for i in 0..=a {
            for j in 0..=b {
                for (di, dj) in [(1, 0), (0, 1)] {
                    let (i2, j2) = (i + di, j + dj);
                    if i2 > a || j2 > b {
                        continue;
                    }
                    let on_side = (j == 0 && j2 == 0)
                        || (j == b && j2 == b)
                        || (i == 0 && i2 == 0)
                        || (i == a && i2 == a);
                    if !on_side {
                        inner_edges.push(((i, j), (i2, j2)));
                    }
                }
            }
        }
        for &(x, y) in &inner_edges {
            if let (Some(u), Some(v)) = (boundary(x.0, x.1), boundary(y.0, y.1)) {
                if self.edges.contains(&key(u, v)) {
                    return false;
                }
            }
        }
        let mut id = vec![u32::MAX; (a + 1) * (b + 1)];
        for j in 0..=b {
            for i in 0..=a {
                id[j * (a + 1) + i] = match boundary(i, j) {
                    Some(v) => v,
                    None => {
                        // Coons patch of the four sides.
                        let (u, w) = (i as f64 / a as f64, j as f64 / b as f64);
                        let q =
                            |x: usize, y: usize| self.pos[boundary(x, y).expect("side") as usize];
                        let point =
                            (1.0 - w) * q(i, 0) + w * q(i, b) + (1.0 - u) * q(0, j) + u * q(a, j)
                                - ((1.0 - u) * (1.0 - w) * q(0, 0)
                                    + u * (1.0 - w) * q(a, 0)
                                    + u * w * q(a, b)
                                    + (1.0 - u) * w * q(0, b));
                        self.pos.push(point);
                        self.val.push(0);
                        self.pos.len() as u32 - 1
                    }
                };
            }
        }
        let g = |i: usize, j: usize| id[j * (a + 1) + i];
        for ((i, j), (i2, j2)) in inner_edges {
            self.add_edge(g(i, j), g(i2, j2));
        }
        for j in 0..b {
            for i in 0..a {
                quads.push([g(i, j), g(i + 1, j), g(i + 1, j + 1), g(i, j + 1)]);
            }
        }
        true
    }
}

/// Degrees of corner deviation one unit of irregularity at a chord's end
/// is worth (see [`Cut::split_even`]): one irregular vertex outweighs
/// any corner but a near-degenerate one.
const VALENCE_DEGREES: f64 = 45.0;

/// |angle at `b` between `a` and `c` − 90°|, in degrees.
fn corner_deviation(pos: &[DVec3], a: u32, b: u32, c: u32) -> f64 {
    let (u, v) = (
        pos[a as usize] - pos[b as usize],
        pos[c as usize] - pos[b as usize],
    );
    (u.angle_between(v).to_degrees() - 90.0).abs()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 3 × 3 grid with a triangle at the centre cell's place in one
    /// corner and a pentagon in another: one path between them, every
    /// result a quad, each directed edge used once.
    #[test]
    fn odd_pair_becomes_quads() {
        let mut pos: Vec<DVec3> = (0..16)
            .map(|i| DVec3::new((i % 4) as f64, (i / 4) as f64, 0.0))
            .collect();
        let id = |i: u32, j: u32| j * 4 + i;
        let mut polys = Vec::new();
        for j in 0..3 {
            for i in 0..3 {
                polys.push(vec![id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1)]);
            }
        }
        // Cell (0,0) as triangle + cell (1,0) as pentagon (move the shared
        // vertex (1,0) to the pentagon only).
        polys[0] = vec![id(0, 0), id(1, 1), id(0, 1)];
        polys[1] = vec![id(0, 0), id(1, 0), id(2, 0), id(2, 1), id(1, 1)];
        let quads = to_quads(&mut pos, polys).unwrap();
        let mut directed = HashSet::new();
        for q in &quads {
            for i in 0..4 {
                assert!(directed.insert((q[i], q[(i + 1) % 4])));
            }
        }
        // The triangle becomes a quad, the pentagon a hexagon cut in two.
        assert_eq!(quads.len(), 10);
    }
}
