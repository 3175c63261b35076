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
//! the edges). Even faces of six or more sides are then cut into quads,
//! shortest chord first.

use std::collections::{HashMap, HashSet, VecDeque};

use crate::DVec3;

fn key(a: u32, b: u32) -> (u32, u32) {
    (a.min(b), a.max(b))
}

/// The pure-quad mesh of `polys` (oriented polygons on the points `pos`):
/// new points appended to `pos`; `None` when an odd face finds no partner
/// (no path of faces to another odd face or to a boundary).
pub fn to_quads(pos: &mut Vec<DVec3>, polys: Vec<Vec<u32>>) -> Option<Vec<[u32; 4]>> {
    let first_new = pos.len() as u32;
    let polys = make_even(pos, polys)?;
    let mut edges: HashSet<(u32, u32)> = HashSet::new();
    for p in &polys {
        for i in 0..p.len() {
            edges.insert(key(p[i], p[(i + 1) % p.len()]));
        }
    }
    let mut quads = Vec::with_capacity(polys.len());
    for p in polys {
        split_even(pos, p, first_new, &mut edges, &mut quads)?;
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

/// Cuts an even polygon into quads: while it has more than four sides,
/// the quad cut off by the shortest chord `p[i]–p[i+3]` that is not
/// already an edge (a second edge between two points would not be a
/// manifold).
fn split_even(
    pos: &[DVec3],
    mut p: Vec<u32>,
    first_new: u32,
    edges: &mut HashSet<(u32, u32)>,
    quads: &mut Vec<[u32; 4]>,
) -> Option<()> {
    while p.len() > 4 {
        let k = p.len();
        let best = (0..k)
            .filter(|&i| !edges.contains(&key(p[i], p[(i + 3) % k])))
            .min_by(|&a, &b| {
                // Worst corner of the quad cut off and of the rest (when it
                // is a quad too) at the chord's ends, in degrees from 90; a
                // chord ending at a path's new point is preferred by
                // NEW_POINT_BONUS degrees: without one that point keeps
                // valence 2.
                let cost = |i: usize| {
                    let (u, v) = (p[i], p[(i + 3) % k]);
                    let cut = [u, p[(i + 1) % k], p[(i + 2) % k], v];
                    let mut worst = (0..4)
                        .map(|c| corner_deviation(pos, cut[(c + 3) % 4], cut[c], cut[(c + 1) % 4]))
                        .fold(0.0, f64::max);
                    worst = worst
                        .max(corner_deviation(pos, v, u, p[(i + k - 1) % k]))
                        .max(corner_deviation(pos, p[(i + 4) % k], v, u));
                    worst
                        - if u >= first_new || v >= first_new {
                            NEW_POINT_BONUS
                        } else {
                            0.0
                        }
                };
                cost(a).total_cmp(&cost(b)).then(a.cmp(&b))
            })?;
        quads.push([
            p[best],
            p[(best + 1) % k],
            p[(best + 2) % k],
            p[(best + 3) % k],
        ]);
        edges.insert(key(p[best], p[(best + 3) % k]));
        let (a, b) = ((best + 1) % k, (best + 2) % k);
        p = (0..k).filter(|&i| i != a && i != b).map(|i| p[i]).collect();
    }
    (p.len() == 4).then(|| quads.push([p[0], p[1], p[2], p[3]]))
}

/// Degrees a chord at a path's new point may be worse than another (see
/// [`split_even`]).
const NEW_POINT_BONUS: f64 = 30.0;

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
