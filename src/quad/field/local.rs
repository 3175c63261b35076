//! Step 4½: M's topology kept by refining the lattice locally (issue 40:
//! "on a topology failure, lower the size locally and redo that region;
//! never return other topology").
//!
//! When the flow-repaired lattice ([`super::extract`]) does not have M's
//! components, boundary loops and Euler characteristic, the places where
//! it went wrong are read off the extracted quads: a piece of the lattice
//! that is a component of its own (homer at τ 1 %: a closed two-quad
//! "pillow" over a thin part, docs/status.md "Field-aligned layout"),
//! one boundary loop of the lattice running along two of M's holes (two
//! holes within a lattice step, bunny), a hole of M that no boundary loop
//! follows, a boundary loop where M has none (a tear), an edge of more
//! than two quads. The vertices of M under those places get 0.7 times the
//! lattice step within one step of them ([`refine`]); the sizing is
//! graded again, so the finer size spreads at slope γ, and the position
//! field and the flow are solved again on the whole mesh (a solve of the
//! refined region alone, with the lattice outside held, is not built: the
//! position field's hierarchy is global; the sizes outside the region
//! are unchanged, so the lattice there lands on the same spacing). At
//! most [`LOCAL_ROUNDS`] rounds, each from the previous round's failure;
//! then the caller falls back as before (the field's own offsets at the
//! first sizes), so a lattice that needs no refinement is the same bytes.
//!
//! QuadriFlow handles the same failures by construction where it can
//! (boundary vertices held on lattice lines, Huang et al. 2018, §5.1) and
//! Instant Meshes not at all; the local refinement is this pipeline's own
//! answer, in the Fitmap's terms: a place where the lattice cannot follow
//! M is a place where the patches must be smaller.

use std::cmp::Reverse;
use std::collections::{BTreeMap, BTreeSet, BinaryHeap};

use crate::error::{Error, Result};
use crate::mesh::{ControlMesh, TriMesh};
use crate::raycast::bvh::BvhCaster;
use crate::raycast::RayCaster;
use crate::DVec3;

use super::extract::{self, LatticeInfo};
use super::{Surface, UnionFind};

/// Rounds of local refinement before falling back (each lowers the step
/// where the last lattice failed by [`LOCAL_FACTOR`], so three rounds
/// reach 0.34 h there).
pub const LOCAL_ROUNDS: usize = 3;

/// The factor on the lattice step under a failure, per round: 0.7 keeps
/// both bunny and homer at one round with fewer patches than 0.5 (bunny
/// 465 against 666, [`LOCAL_SLOPE`]'s figures).
pub const LOCAL_FACTOR: f64 = 0.7;

/// The extraction at the target size with the local refinement of this
/// module: the flow-repaired lattice of `o` (solved at `scale`); where it
/// fails M's topology, up to [`LOCAL_ROUNDS`] locally refined position
/// fields; then the field's own offsets of `o`, as [`extract::extract`].
pub fn extract_refining(
    s: &Surface,
    mesh: &TriMesh,
    dirs: &[DVec3],
    o: &[DVec3],
    scale: &[f64],
    gradation: f64,
    sweeps: usize,
) -> Result<(ControlMesh, usize, LatticeInfo)> {
    let debug = crate::switches::set("FIELD_DEBUG");
    let mut seeds = match extract::extract_at_size(s, mesh, dirs, o, scale, true) {
        Ok(out) => return Ok(out),
        Err(f) if matches!(f.error, Error::Topology { .. }) => {
            if debug {
                eprintln!(
                    "repaired lattice rejected: {} ({} seeds)",
                    f.error,
                    f.seeds.len()
                );
            }
            f.seeds
        }
        Err(f) => return Err(f.error),
    };
    // The rounds stay one after the other (issue 39): each refines where
    // the last one's lattice failed ([`failure_seeds`]), and the unrepaired
    // fallback below runs only when every round failed; the lattice kept at
    // the first try, the defaults' common case, pays for none of them.
    let mut local = scale.to_vec();
    for round in 1..=LOCAL_ROUNDS {
        if seeds.is_empty() {
            break;
        }
        refine(s, &mut local, &seeds, gradation);
        let lowered = local.iter().zip(scale).filter(|(a, b)| a < b).count();
        let o2 = super::position::position_field(s, dirs, &local, sweeps)?;
        match extract::extract_at_size(s, mesh, dirs, &o2, &local, true) {
            Ok((control, non_quads, mut info)) => {
                info.local_rounds = round;
                info.local_vertices = lowered;
                if debug {
                    eprintln!("local refinement round {round}: kept ({lowered} vertices finer)");
                }
                return Ok((control, non_quads, info));
            }
            Err(f) if matches!(f.error, Error::Topology { .. }) => {
                if debug {
                    eprintln!(
                        "local refinement round {round}: {} ({lowered} vertices finer, {} seeds)",
                        f.error,
                        f.seeds.len()
                    );
                }
                seeds = f.seeds;
            }
            Err(f) => return Err(f.error),
        }
    }
    extract::extract_at_size(s, mesh, dirs, o, scale, false).map_err(|f| f.error)
}

/// `scale` × [`LOCAL_FACTOR`] on the vertices of M within one lattice
/// step (the step at the seed, along M's edges) of a seed, spread out
/// graded (`h_i ≤ h_j + γ' |x_i − x_j|`, [`super::sizing::grade`], at γ'
/// = [`LOCAL_SLOPE`] × `gradation`). Returns the vertices lowered.
pub fn refine(s: &Surface, scale: &mut [f64], seeds: &[u32], gradation: f64) -> usize {
    let n = s.len();
    // Dijkstra over M's edges in units of the seed's step: a vertex is in
    // the region when its nearest seed, so measured, is within 1.
    let mut dist = vec![f64::INFINITY; n];
    let mut radius = vec![0.0; n];
    let mut heap = BinaryHeap::new();
    for &v in seeds {
        let v = v as usize;
        if v < n && dist[v] > 0.0 {
            dist[v] = 0.0;
            radius[v] = scale[v];
            heap.push(Reverse((0.0f64.to_bits(), v as u32)));
        }
    }
    let mut region = Vec::new();
    while let Some(Reverse((bits, v))) = heap.pop() {
        let v = v as usize;
        let d = f64::from_bits(bits);
        if d != dist[v] {
            continue;
        }
        region.push(v);
        for &w in s.neighbours(v) {
            let w = w as usize;
            let nd = d + (s.positions[v] - s.positions[w]).length() / radius[v];
            if nd <= 1.0 && nd < dist[w] {
                dist[w] = nd;
                radius[w] = radius[v];
                heap.push(Reverse((nd.to_bits(), w as u32)));
            }
        }
    }
    // The finer step spreads out graded at the sizing's own slope: the
    // cone of sizes hanging off the region moves down with it (on bunny,
    // whose holes' capped sizes set much of the graded field, 21450
    // vertices of the layout mesh get finer at ×0.7). A steeper spread
    // keeps the change near the region but tears the lattice (see
    // [`LOCAL_SLOPE`]).
    let mut finer = vec![f64::INFINITY; n];
    for &v in &region {
        finer[v] = LOCAL_FACTOR * scale[v];
    }
    super::sizing::grade(s, &mut finer, LOCAL_SLOPE * gradation);
    let mut lowered = 0;
    for (h, f) in scale.iter_mut().zip(&finer) {
        if *f < *h {
            *h = *f;
            lowered += 1;
        }
    }
    lowered
}

/// The slope of the refinement's spread in units of the sizing's γ (see
/// [`refine`]). Measured (`convert --layout field --mode organic
/// --tolerance 0.01 --max-error inf`, patches / irregular / RMS L ‰,
/// repaired lattice kept or not), factor / slope: 0.5 / 1 bunny 666 /
/// 123 / 1.88 kept, homer 169 / 35 / 13.5 kept; 0.7 / 1 bunny 465 / 112
/// / 2.29, homer 171 / 39 / 13.7, both kept; 0.5 / 1.5 bunny 561 / 100 /
/// 2.07, homer 185 / 39 / 21.3; 0.5 / 2 bunny falls back after three
/// rounds (its lattice tears further each round: 4, 3, then 26 loops).
pub const LOCAL_SLOPE: f64 = 1.0;

/// Vertices of M under the places where the extracted quads (`pos`, on
/// M; `quads`) miss M's topology, see the module docs; empty when none
/// is found (a genus changed without a component or loop changing).
pub fn failure_seeds(
    s: &Surface,
    caster: &BvhCaster,
    pos: &[DVec3],
    quads: &[[u32; 4]],
    scale: &[f64],
) -> Result<Vec<u32>> {
    let hits = caster.closest_points(pos, f64::INFINITY)?;
    // Each control point's nearest vertex of M: the closest triangle's
    // nearest corner.
    let near: Vec<Option<u32>> = hits
        .iter()
        .zip(pos)
        .map(|(h, &p)| {
            h.as_ref().map(|h| {
                let t = s.triangles[h.triangle as usize];
                *t.iter()
                    .min_by(|&&a, &&b| {
                        let da = (s.positions[a as usize] - p).length_squared();
                        let db = (s.positions[b as usize] - p).length_squared();
                        da.total_cmp(&db).then(a.cmp(&b))
                    })
                    .expect("three corners")
            })
        })
        .collect();
    let mut seeds = BTreeSet::new();
    let mut seed = |v: u32| {
        if let Some(m) = near[v as usize] {
            seeds.insert(m);
        }
    };
    let mut uses: BTreeMap<(u32, u32), usize> = BTreeMap::new();
    for q in quads {
        for i in 0..4 {
            let (a, b) = (q[i], q[(i + 1) % 4]);
            *uses.entry((a.min(b), a.max(b))).or_default() += 1;
        }
    }
    for (&(a, b), &c) in &uses {
        if c > 2 {
            seed(a);
            seed(b);
        }
    }
    // Pieces of the lattice beyond M's count: all but the largest.
    let mut uf = UnionFind::new(pos.len());
    for q in quads {
        for i in 1..4 {
            uf.union(q[0] as usize, q[i] as usize);
        }
    }
    let mut size: BTreeMap<usize, usize> = BTreeMap::new();
    for q in quads {
        *size.entry(uf.find(q[0] as usize)).or_default() += 1;
    }
    if size.len() > s.topology.components {
        let mut pieces: Vec<(usize, usize)> = size.iter().map(|(&r, &c)| (c, r)).collect();
        pieces.sort_by(|a, b| b.0.cmp(&a.0).then(a.1.cmp(&b.1)));
        let small: BTreeSet<usize> = pieces[s.topology.components..]
            .iter()
            .map(|p| p.1)
            .collect();
        for q in quads {
            if small.contains(&uf.find(q[0] as usize)) {
                q.iter().for_each(|&v| seed(v));
            }
        }
    }
    for v in loop_seeds(s, pos, &near, &uses, scale) {
        seeds.insert(v);
    }
    Ok(seeds.into_iter().collect())
}

/// The boundary part of [`failure_seeds`]: each boundary vertex of the
/// quads votes for the boundary loop of M nearest it; a loop of M with no
/// vote, or sharing a lattice loop with another, gives all its boundary
/// vertices; a lattice boundary vertex farther than its step from M's
/// boundary (a tear) gives its nearest vertex of M.
fn loop_seeds(
    s: &Surface,
    pos: &[DVec3],
    near: &[Option<u32>],
    uses: &BTreeMap<(u32, u32), usize>,
    scale: &[f64],
) -> Vec<u32> {
    let mut out = Vec::new();
    let mut m_loops = UnionFind::new(s.len());
    for &[a, b] in &s.boundary_edges {
        m_loops.union(a as usize, b as usize);
    }
    let m_boundary: Vec<u32> = {
        let mut v: Vec<u32> = s.boundary_edges.iter().map(|e| e[0]).collect();
        v.sort_unstable();
        v.dedup();
        v
    };
    let mut k_loops = UnionFind::new(pos.len());
    let mut k_boundary = BTreeSet::new();
    for (&(a, b), &c) in uses {
        if c == 1 {
            k_loops.union(a as usize, b as usize);
            k_boundary.insert(a);
            k_boundary.insert(b);
        }
    }
    // Votes: lattice loop → loops of M.
    let mut votes: BTreeMap<usize, BTreeSet<usize>> = BTreeMap::new();
    let mut voted = BTreeSet::new();
    for &v in &k_boundary {
        let p = pos[v as usize];
        let nearest = m_boundary.iter().min_by(|&&a, &&b| {
            let da = (s.positions[a as usize] - p).length_squared();
            let db = (s.positions[b as usize] - p).length_squared();
            da.total_cmp(&db).then(a.cmp(&b))
        });
        let step = near[v as usize].map_or(0.0, |m| scale[m as usize]);
        match nearest {
            Some(&m) if (s.positions[m as usize] - p).length() <= step => {
                let l = m_loops.find(m as usize);
                votes.entry(k_loops.find(v as usize)).or_default().insert(l);
                voted.insert(l);
            }
            _ => out.extend(near[v as usize]),
        }
    }
    let mut bad: BTreeSet<usize> = BTreeSet::new();
    for ls in votes.values().filter(|ls| ls.len() > 1) {
        bad.extend(ls.iter().copied());
    }
    for &m in &m_boundary {
        let l = m_loops.find(m as usize);
        if !voted.contains(&l) || bad.contains(&l) {
            out.push(m);
        }
    }
    out
}
