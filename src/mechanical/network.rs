//! The boundary network of a segmentation (§5, Fig. 7.b): pieces of region
//! boundary between corners, and each region's oriented boundary loop as a
//! sequence of (piece, direction).

use std::collections::HashMap;

use super::curves::Piece;
use super::topology::Topology;
use crate::mesh::TriMesh;

/// A boundary turning by more than this (degrees, between consecutive
/// edges) at a vertex where both edges are sharp edges of M makes the
/// vertex a corner, so the crease curve keeps the kink (eq. 2's corner
/// rule) instead of rounding it. Only along sharp edges: a boundary between
/// curvature classes zigzags along triangle edges and is not a feature.
pub const CORNER_TURN_DEG: f64 = 40.0;

/// Pieces, corner flags per vertex of M, and for each region its boundary
/// loops as `(piece, forward)` sequences.
#[derive(Clone, Debug)]
pub struct Network {
    pub pieces: Vec<Piece>,
    pub corner: Vec<bool>,
    /// Per region: loops, each a sequence of `(piece index, forward)` in the
    /// region's orientation (M's triangle orientation).
    pub loops: Vec<Vec<Vec<(usize, bool)>>>,
    /// Whether each vertex of M lies on a region boundary.
    pub on_boundary: Vec<bool>,
}

/// The network of `region`'s boundaries. `extra_corner` (indexed by vertex
/// of M, may be shorter) adds corners on boundaries, where §5's fit found
/// that a feature kinks. With `slits`, a sharp edge with one region on
/// both sides is a boundary edge too (a slit: a feature that fades out
/// inside its region, see `SegmentOptions::slits`); the region's loop then
/// runs along it on both sides.
///
/// Three steps, as in Fig. 7.b: the corners (`find_corners`), the pieces
/// between them (`walk_pieces`), and each region's boundary loop as a
/// sequence of pieces (`region_loops`).
pub fn build_network(
    mesh: &TriMesh,
    topo: &Topology,
    region: &[u32],
    num_regions: usize,
    sharp: &[bool],
    extra_corner: &[bool],
    slits: bool,
) -> Network {
    let is_b: Vec<bool> = topo
        .edges
        .iter()
        .enumerate()
        .map(|(i, e)| {
            !e.is_interior()
                || side(region, e.faces[0]) != side(region, e.faces[1])
                || (slits && sharp[i])
        })
        .collect();
    let (corner, on_boundary) = find_corners(mesh, topo, region, sharp, &is_b, extra_corner);
    let pieces = walk_pieces(topo, region, &is_b, &corner);
    let loops = region_loops(
        mesh,
        topo,
        region,
        num_regions,
        &is_b,
        &corner,
        &pieces,
        slits,
    );
    Network {
        pieces,
        corner,
        loops,
        on_boundary,
    }
}

/// The region on one side of an edge (`u32::MAX`: no face, outside M).
fn side(region: &[u32], f: u32) -> u32 {
    if f == u32::MAX {
        u32::MAX
    } else {
        region[f as usize]
    }
}

/// The corners of the network, and which vertices lie on a boundary
/// (`is_b`: per edge of M, whether it is a boundary edge). §5's pieces
/// run between corners, and eq. 2's corner rule keeps a curve end fixed
/// there: a vertex where the boundary branches (not two boundary edges),
/// where three or more regions (M's outside counting as one) meet, an
/// `extra_corner` (feature tips and kinks, see `super::tip_corners` and
/// `super::CurveFit::with_kink_corners`), or a turn of more
/// than [`CORNER_TURN_DEG`] between two sharp edges (a feature's kink).
fn find_corners(
    mesh: &TriMesh,
    topo: &Topology,
    region: &[u32],
    sharp: &[bool],
    is_b: &[bool],
    extra_corner: &[bool],
) -> (Vec<bool>, Vec<bool>) {
    let nv = mesh.positions.len();
    let mut deg = vec![0u32; nv];
    let mut on_boundary = vec![false; nv];
    for (e, ed) in topo.edges.iter().enumerate() {
        if is_b[e] {
            for &v in &ed.v {
                deg[v as usize] += 1;
                on_boundary[v as usize] = true;
            }
        }
    }
    let mut corner = vec![false; nv];
    let cos_turn = CORNER_TURN_DEG.to_radians().cos();
    for v in 0..nv {
        if deg[v] == 0 {
            continue;
        }
        if deg[v] != 2 || extra_corner.get(v).copied().unwrap_or(false) {
            corner[v] = true;
            continue;
        }
        let mut sides: Vec<u32> = Vec::new();
        let mut bedges: Vec<u32> = Vec::new();
        for &e in topo.vertex_edges(v as u32) {
            let ed = &topo.edges[e as usize];
            for &f in &ed.faces {
                let s = side(region, f);
                if !sides.contains(&s) {
                    sides.push(s);
                }
            }
            if is_b[e as usize] {
                bedges.push(e);
            }
        }
        if sides.len() >= 3 {
            corner[v] = true;
            continue;
        }
        if bedges.len() == 2 && bedges.iter().all(|&e| sharp[e as usize]) {
            let other = |e: u32| {
                let ed = &topo.edges[e as usize];
                if ed.v[0] as usize == v {
                    ed.v[1]
                } else {
                    ed.v[0]
                }
            };
            let p = mesh.positions[v];
            let a = (p - mesh.positions[other(bedges[0]) as usize]).normalize_or_zero();
            let b = (mesh.positions[other(bedges[1]) as usize] - p).normalize_or_zero();
            if a.dot(b) < cos_turn {
                corner[v] = true;
            }
        }
    }
    (corner, on_boundary)
}

/// The boundary pieces: from every corner along each of its boundary
/// edges not walked yet, to the next corner (open pieces; a loop through
/// one corner comes back to it), then the loops left with no corner on
/// them (closed pieces).
fn walk_pieces(topo: &Topology, region: &[u32], is_b: &[bool], corner: &[bool]) -> Vec<Piece> {
    let mut edge_piece: Vec<u32> = vec![u32::MAX; topo.edges.len()];
    let mut pieces: Vec<Piece> = Vec::new();
    let regions_of = |e: u32| {
        let ed = &topo.edges[e as usize];
        let mut r = [side(region, ed.faces[0]), side(region, ed.faces[1])];
        r.sort_unstable();
        r
    };
    for v in 0..corner.len() as u32 {
        if !corner[v as usize] {
            continue;
        }
        for &e in topo.vertex_edges(v) {
            if is_b[e as usize] && edge_piece[e as usize] == u32::MAX {
                let pid = pieces.len() as u32;
                let (mut verts, closed) = walk(topo, is_b, corner, v, e, &mut edge_piece, pid);
                if !closed && verts.first() == verts.last() && verts.len() > 1 {
                    // A loop through one corner: the last vertex repeats
                    // the corner, which is how an open piece is stored.
                } else if closed {
                    verts.dedup();
                }
                pieces.push(Piece {
                    verts,
                    closed: false,
                    regions: regions_of(e),
                });
            }
        }
    }
    for e in 0..topo.edges.len() as u32 {
        if is_b[e as usize] && edge_piece[e as usize] == u32::MAX {
            let pid = pieces.len() as u32;
            let v = topo.edges[e as usize].v[0];
            let (verts, _) = walk(topo, is_b, corner, v, e, &mut edge_piece, pid);
            pieces.push(Piece {
                verts,
                closed: true,
                regions: regions_of(e),
            });
        }
    }
    pieces
}

/// Walks one piece from `start_v` along boundary edge `start_e` until a
/// corner, a dead end or back at the start, marking its edges with `pid`
/// in `edge_piece`: its vertices, and whether it closed without a corner.
fn walk(
    topo: &Topology,
    is_b: &[bool],
    corner: &[bool],
    start_v: u32,
    start_e: u32,
    edge_piece: &mut [u32],
    pid: u32,
) -> (Vec<u32>, bool) {
    let mut verts = vec![start_v];
    let mut v = start_v;
    let mut e = start_e;
    loop {
        edge_piece[e as usize] = pid;
        let ed = &topo.edges[e as usize];
        let w = if ed.v[0] == v { ed.v[1] } else { ed.v[0] };
        if w == start_v {
            if corner[w as usize] {
                // A loop through one corner is stored as an open
                // piece from the corner back to it, so both ends
                // resolve to the corner's control vertex.
                verts.push(w);
                return (verts, false);
            }
            return (verts, true);
        }
        verts.push(w);
        if corner[w as usize] {
            return (verts, false);
        }
        let next = topo
            .vertex_edges(w)
            .iter()
            .copied()
            .find(|&f| is_b[f as usize] && edge_piece[f as usize] == u32::MAX);
        match next {
            Some(f) => {
                v = w;
                e = f;
            }
            None => return (verts, false),
        }
    }
}

/// Directed boundary half-edges per region (a → b as in its triangle, so
/// loops follow M's orientation): heads by tail vertex.
type OutHalves = Vec<HashMap<u32, Vec<u32>>>;

/// Each region's directed boundary half-edges ([`OutHalves`]), and the
/// triangle holding each half-edge.
fn boundary_halves(
    mesh: &TriMesh,
    topo: &Topology,
    region: &[u32],
    num_regions: usize,
    is_b: &[bool],
) -> (OutHalves, HashMap<(u32, u32), u32>) {
    let mut out: OutHalves = vec![HashMap::new(); num_regions];
    for (t, tri) in mesh.triangles.iter().enumerate() {
        for k in 0..3 {
            let e = topo.tri_edges[t][k];
            if is_b[e as usize] {
                out[region[t] as usize]
                    .entry(tri[k])
                    .or_default()
                    .push(tri[(k + 1) % 3]);
            }
        }
    }
    let mut half_tri: HashMap<(u32, u32), u32> = HashMap::new();
    for (t, tri) in mesh.triangles.iter().enumerate() {
        for k in 0..3 {
            if is_b[topo.tri_edges[t][k] as usize] {
                half_tri.insert((tri[k], tri[(k + 1) % 3]), t as u32);
            }
        }
    }
    (out, half_tri)
}

/// The head of the boundary half-edge after `a → b` in rotation about `b`
/// through the region's triangles (`half_tri`: the triangle of each
/// boundary half-edge): the next one of the same loop, to take at a vertex
/// with several outgoing boundary half-edges (a slit's root).
fn next_in_rotation(
    mesh: &TriMesh,
    topo: &Topology,
    is_b: &[bool],
    half_tri: &HashMap<(u32, u32), u32>,
    a: u32,
    b: u32,
) -> Option<u32> {
    let mut t = *half_tri.get(&(a, b))?;
    for _ in 0..64 {
        let tri = mesh.triangles[t as usize];
        let k = (0..3).find(|&k| tri[k] == b)?;
        let e = topo.tri_edges[t as usize][k];
        if is_b[e as usize] {
            return Some(tri[(k + 1) % 3]);
        }
        let ed = &topo.edges[e as usize];
        t = if ed.faces[0] == t {
            ed.faces[1]
        } else {
            ed.faces[0]
        };
        if t == u32::MAX {
            return None;
        }
    }
    None
}

/// Per region, its boundary loops as `(piece, forward)` sequences:
/// directed boundary half-edges chained head to tail, each mapped to the
/// piece it lies on. Loops start at corners where they have one, so that
/// a loop's first piece begins there; with `slits`, a vertex with several
/// outgoing half-edges continues with the next one in rotation
/// ([`next_in_rotation`]), so a loop runs down one side of a
/// slit and back up the other.
#[allow(clippy::too_many_arguments)]
fn region_loops(
    mesh: &TriMesh,
    topo: &Topology,
    region: &[u32],
    num_regions: usize,
    is_b: &[bool],
    corner: &[bool],
    pieces: &[Piece],
    slits: bool,
) -> Vec<Vec<Vec<(usize, bool)>>> {
    let mut piece_pos: HashMap<(u32, u32), (usize, bool)> = HashMap::new();
    for (pi, p) in pieces.iter().enumerate() {
        let m = p.verts.len();
        let segs = if p.closed { m } else { m - 1 };
        for k in 0..segs {
            let (a, b) = (p.verts[k], p.verts[(k + 1) % m]);
            piece_pos.insert((a, b), (pi, true));
            piece_pos.insert((b, a), (pi, false));
        }
    }
    let mut loops: Vec<Vec<Vec<(usize, bool)>>> = vec![Vec::new(); num_regions];
    let (mut out, half_tri) = boundary_halves(mesh, topo, region, num_regions, is_b);
    for (r, outr) in out.iter_mut().enumerate() {
        let mut starts: Vec<u32> = outr.keys().copied().collect();
        starts.sort_unstable();
        // Start loops at corners so that a loop's first piece begins there.
        starts.sort_by_key(|&v| !corner[v as usize]);
        for s in starts {
            while let Some(b) = outr.get_mut(&s).and_then(|l| l.pop()) {
                let mut seq: Vec<(usize, bool)> = Vec::new();
                let (mut a, mut b) = (s, b);
                let mut guard = 0;
                loop {
                    if let Some(&(pi, fwd)) = piece_pos.get(&(a, b)) {
                        // Each piece once per traversal; a slit's piece
                        // comes back at once the other way round.
                        if seq.last() != Some(&(pi, fwd)) {
                            seq.push((pi, fwd));
                        }
                    }
                    if b == s {
                        break;
                    }
                    let rotated = slits
                        .then(|| next_in_rotation(mesh, topo, is_b, &half_tri, a, b))
                        .flatten()
                        .and_then(|n| {
                            let l = outr.get_mut(&b)?;
                            let i = l.iter().position(|&x| x == n)?;
                            Some(l.swap_remove(i))
                        });
                    a = b;
                    match rotated.or_else(|| outr.get_mut(&a).and_then(|l| l.pop())) {
                        Some(n) => b = n,
                        None => break,
                    }
                    guard += 1;
                    if guard > 10_000_000 {
                        break;
                    }
                }
                // A loop may start in the middle of its first piece (no
                // corner on it): merge a split first/last occurrence.
                if seq.len() > 1 && seq.first() == seq.last() {
                    seq.pop();
                }
                loops[r].push(seq);
            }
        }
    }
    loops
}
