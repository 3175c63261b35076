//! Step 4: the control mesh from the position field, after Instant Meshes
//! §6 ("mesh extraction"): every edge of M is classified by the integer
//! lattice offset between its two vertices' lattice points. Offset 0: the
//! two vertices sample the same lattice point and are merged (union-find);
//! a unit offset: the two lattice points are joined by an edge of the
//! output; anything else (diagonals, jumps across a defect) is dropped.
//! The faces are walked in the graph of lattice points, each directed edge
//! once, turning to the next edge clockwise at every vertex (the face on
//! the left, counter-clockwise about the normal as M's triangles are).
//!
//! M's boundary is kept, never filled: a lattice edge produced by a
//! boundary edge of M has the surface on one side only, and a walked face
//! that uses its other side is the hole, not a face. Adjacent non-quads
//! are merged where that saves irregular vertices, then the faces are
//! made pure quad: at the target size by [`super::purequad`] (only faces
//! near non-quads change) and a few steps of tangential relaxation; or,
//! the fallback, by one Catmull-Clark split (each n-gon into n quads; the
//! lattice was solved at twice the target length for this). The points
//! are put on M's closest points, and the result must have M's
//! components, boundary loops and Euler characteristic, else an error.

use crate::error::{Error, Result};
use crate::mesh::{ControlMesh, TriMesh};
use crate::raycast::bvh::BvhCaster;
use crate::raycast::RayCaster;
use crate::DVec3;

use super::purequad::{irregularity, valences};
use super::{control_topology, Surface, UnionFind};

/// Longest walk followed: every walk closes (each directed edge has one
/// successor), this only bounds the work on a torn lattice.
const MAX_FACE: usize = 1 << 16;

/// The lattice graph: points and their neighbour rings (sorted by angle),
/// and the directed edges that face a hole of M.
struct Graph {
    pos: Vec<DVec3>,
    ring: Vec<Vec<u32>>,
    hole_side: std::collections::HashSet<(u32, u32)>,
}

/// Extracts the pure-quad control mesh; also returns the number of raw
/// faces that were not quads. The lattice's offsets are first repaired by
/// [`super::flow`]; if that lattice does not have M's topology, the
/// position field's own offsets are tried before giving up.
pub fn extract(
    s: &Surface,
    mesh: &TriMesh,
    dirs: &[DVec3],
    o: &[DVec3],
    scale: &[f64],
    at_size: bool,
) -> Result<(ControlMesh, usize, LatticeInfo)> {
    match extract_once(s, mesh, dirs, o, scale, at_size, true) {
        Err(Failure {
            error: e @ Error::Topology { .. },
            ..
        }) => {
            if crate::switches::set("FIELD_DEBUG") {
                eprintln!("repaired lattice rejected: {e}");
            }
            extract_once(s, mesh, dirs, o, scale, at_size, false).map_err(|f| f.error)
        }
        r => r.map_err(|f| f.error),
    }
}

/// A failed extraction: the error, and for a lattice at the target size
/// that missed M's topology the vertices of M where it went wrong
/// ([`super::local::failure_seeds`]; empty when none were found).
pub struct Failure {
    pub error: Error,
    pub seeds: Vec<u32>,
}

impl From<Error> for Failure {
    fn from(error: Error) -> Self {
        Failure {
            error,
            seeds: Vec::new(),
        }
    }
}

/// The lattice at the target size, flow-repaired (`repair`) or the
/// position field's own offsets, with the seeds of a topology failure
/// ([`super::local`]).
pub fn extract_at_size(
    s: &Surface,
    mesh: &TriMesh,
    dirs: &[DVec3],
    o: &[DVec3],
    scale: &[f64],
    repair: bool,
) -> std::result::Result<(ControlMesh, usize, LatticeInfo), Failure> {
    extract_once(s, mesh, dirs, o, scale, true, repair)
}

/// How the extracted lattice was made.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct LatticeInfo {
    /// The flow-repaired offsets were extracted (`false`: the position
    /// field's own, after the repaired lattice failed M's topology).
    pub repaired: bool,
    /// What the flip removal did on the repaired offsets.
    pub flips: super::flip::FlipReport,
    /// Control vertices where separate fans of quads met, split into one
    /// vertex per fan ([`split_pinches`]).
    pub pinches_split: usize,
    /// Rounds of local refinement the kept repaired lattice needed (0:
    /// none, the lattice at the first sizes kept M's topology), and the
    /// vertices of M whose lattice step they lowered ([`super::local`]).
    #[serde(default)]
    pub local_rounds: usize,
    #[serde(default)]
    pub local_vertices: usize,
}

/// [`extract`] with or without the flow's repair.
fn extract_once(
    s: &Surface,
    mesh: &TriMesh,
    dirs: &[DVec3],
    o: &[DVec3],
    scale: &[f64],
    at_size: bool,
    repair: bool,
) -> std::result::Result<(ControlMesh, usize, LatticeInfo), Failure> {
    let (mut g, flips) = lattice_graph(s, dirs, o, scale, repair);
    let faces = clean_faces(&mut g);
    let non_quads = faces.iter().filter(|f| f.len() != 4).count();
    let debug = crate::switches::set("FIELD_DEBUG");
    let raw = if debug { faces.clone() } else { Vec::new() };
    let faces = merge_non_quad_pairs(faces, g.pos.len(), at_size);
    let (positions, quads) = if at_size {
        let mut pos = g.pos.clone();
        let merged = if debug { faces.clone() } else { Vec::new() };
        let quads = super::purequad::to_quads(&mut pos, faces).ok_or_else(|| Error::Topology {
            element: "field layout".into(),
            msg: "an odd face of the lattice has no partner to pair with".into(),
        })?;
        if debug {
            eprintln!("{}", sources(&raw, &merged, &quads, g.pos.len()));
        }
        compact(pos, quads)
    } else {
        split_to_quads(&g, &faces)
    };
    let (positions, quads, pinches_split) = split_pinches(positions, quads);
    let info = LatticeInfo {
        repaired: repair,
        flips,
        pinches_split,
        ..LatticeInfo::default()
    };
    let caster = BvhCaster::shared(mesh)?;
    let project = |positions: &[DVec3]| -> Result<Vec<DVec3>> {
        let hits = caster.closest_points(positions, f64::INFINITY)?;
        Ok(positions
            .iter()
            .zip(&hits)
            .map(|(p, h)| h.as_ref().map_or(*p, |h| h.point))
            .collect())
    };
    let mut positions = project(&positions)?;
    if at_size {
        let mode = RelaxMode::from_env();
        for _ in 0..mode.steps {
            let sizes = if mode.sized {
                Some(sizes_at(&caster, mesh, scale, &positions)?)
            } else {
                None
            };
            positions = project(&relax(&positions, &quads, sizes.as_deref(), mode.power))?;
        }
    }
    // Where the kept lattice went wrong, for the local refinement (only
    // the repaired lattice at the target size is refined, [`super::local`]).
    let seeds = |positions: &[DVec3]| -> Vec<u32> {
        if at_size && repair {
            super::local::failure_seeds(s, &caster, positions, &quads, scale).unwrap_or_default()
        } else {
            Vec::new()
        }
    };
    let control = match ControlMesh::from_polygons(positions.clone(), &quads) {
        Ok(c) => c,
        Err(e) => {
            return Err(Failure {
                error: Error::Topology {
                    element: "field layout".into(),
                    msg: format!("the extracted quads are not a manifold mesh ({e})"),
                },
                seeds: seeds(&positions),
            })
        }
    };
    if let Some(dir) = dump_dir() {
        dump_quads(&dir, &positions, &quads);
    }
    let got = control_topology(&control);
    if got != s.topology && crate::switches::set("FIELD_DEBUG") {
        eprintln!("pinched vertices split: {pinches_split}");
    }
    if got != s.topology {
        return Err(Failure {
            error: Error::Topology {
                element: "field layout".into(),
                msg: format!(
                    "the extracted mesh has {} components, {} boundary loops, Euler characteristic {}; \
                     M has {}, {}, {}",
                    got.components,
                    got.boundary_loops,
                    got.euler,
                    s.topology.components,
                    s.topology.boundary_loops,
                    s.topology.euler
                ),
            },
            seeds: seeds(&positions),
        });
    }
    Ok((control, non_quads, info))
}

/// Merges zero-offset edges, joins unit-offset ones (see the module docs).
fn lattice_graph(
    s: &Surface,
    dirs: &[DVec3],
    o: &[DVec3],
    scale: &[f64],
    repair: bool,
) -> (Graph, super::flip::FlipReport) {
    let n = s.len();
    let mut uf = UnionFind::new(n);
    let mut unit: Vec<(u32, u32)> = Vec::new();
    let mut zero: Vec<(u32, u32)> = Vec::new();
    // The position field's offsets, made consistent per triangle by
    // QuadriFlow's flow (super::flow) so that the lattice has no
    // dislocation the cross field does not ask for.
    let (mut offsets, real) = super::flow::edge_offsets(s, dirs, o, scale);
    let raw_offsets = dump_dir().map(|_| offsets.clone());
    let mut flips = super::flip::FlipReport::default();
    if repair {
        // Sequential (issue 39): the flow augments one path after another
        // on one network (each path's reduced costs are the last one's
        // result), and the flip removal reads the flow's offsets. The
        // triangles' frames once for both (they depend on the cross field
        // only).
        let (sides, singular) = super::flow::triangle_sides(s, dirs);
        let report = super::flow::repair_offsets_on(s, &sides, &singular, &mut offsets, &real);
        // The flow zeroes the sums but may fold the lattice (QuadriFlow
        // §5.3): folds removed by curl-free moves before extraction.
        flips = super::flip::remove_flips_on(s, dirs, &sides, &singular, &mut offsets, &real);
        if crate::switches::set("FIELD_DEBUG") {
            eprintln!("integer flow: {report:?}");
            eprintln!("flip removal: {flips:?}");
        }
    }
    for (&[a, b], d) in s.edges.iter().zip(&offsets) {
        match d[0].abs() + d[1].abs() {
            0 => {
                uf.union(a as usize, b as usize);
                zero.push((a, b));
            }
            1 => unit.push((a, b)),
            _ => {}
        }
    }
    let key = split_across_loops(s, &mut uf, &zero);
    // Clusters numbered by their smallest vertex (deterministic).
    let mut id = vec![u32::MAX; n];
    let mut count = 0u32;
    let mut cluster = vec![0u32; n];
    for (v, cl) in cluster.iter_mut().enumerate() {
        let r = key[v];
        if id[r] == u32::MAX {
            id[r] = count;
            count += 1;
        }
        *cl = id[r];
    }
    if let (Some(dir), Some(raw)) = (dump_dir(), raw_offsets) {
        dump_clusters(&dir, s, o, &raw, &cluster);
    }
    let c = count as usize;
    let (mut pos, mut nrm, mut w) = (vec![DVec3::ZERO; c], vec![DVec3::ZERO; c], vec![0.0; c]);
    for v in 0..n {
        let k = cluster[v] as usize;
        let a = s.areas[v].max(1e-300);
        pos[k] += a * o[v];
        nrm[k] += a * s.normals[v];
        w[k] += a;
    }
    for k in 0..c {
        pos[k] /= w[k];
        nrm[k] = nrm[k].normalize_or(DVec3::Z);
    }
    let mut pairs: Vec<(u32, u32)> = unit
        .iter()
        .map(|&(a, b)| (cluster[a as usize], cluster[b as usize]))
        .filter(|(a, b)| a != b)
        .flat_map(|(a, b)| [(a, b), (b, a)])
        .collect();
    pairs.sort_unstable();
    pairs.dedup();
    let mut ring: Vec<Vec<u32>> = vec![Vec::new(); c];
    for &(a, b) in &pairs {
        ring[a as usize].push(b);
    }
    for (k, r) in ring.iter_mut().enumerate() {
        let nk = nrm[k];
        let e1 = nk.any_orthonormal_vector();
        let e2 = nk.cross(e1);
        let angle = |b: u32| {
            let d = pos[b as usize] - pos[k];
            d.dot(e2).atan2(d.dot(e1))
        };
        r.sort_by(|&x, &y| angle(x).total_cmp(&angle(y)).then(x.cmp(&y)));
    }
    let mut hole_side = std::collections::HashSet::new();
    for &[a, b] in &s.boundary_edges {
        let (ca, cb) = (cluster[a as usize], cluster[b as usize]);
        if ca != cb {
            hole_side.insert((cb, ca));
        }
    }
    (
        Graph {
            pos,
            ring,
            hole_side,
        },
        flips,
    )
}

/// Per vertex of M, the key of its lattice point: the root of its cluster
/// of zero offsets, except where one cluster holds boundary vertices of
/// two or more of M's boundary loops. There two holes of M come within
/// one lattice step and the one lattice point would join them (the
/// extracted boundary touches itself; measured on bunny at τ 1 %: two of
/// its five holes each share a point with a third, the extraction has 3
/// loops, 4 after this cut, so bunny still falls back; a plate with two
/// holes two grid cells apart keeps the repaired lattice at a lattice
/// step of 0.13 only with it, `tests/field_layout.rs`). QuadriFlow keeps
/// the boundary on lattice lines of its own
/// (Huang et al. 2018, §5.1, boundary constraints); locally the same
/// end is reached by cutting such a cluster: each vertex goes with the
/// loop whose boundary vertex is nearest along the zero-offset edges
/// (breadth first, sources in vertex order, so deterministic), each part
/// a lattice point of its own at the same lattice coordinates.
fn split_across_loops(s: &Surface, uf: &mut UnionFind, zero: &[(u32, u32)]) -> Vec<usize> {
    let n = s.len();
    let mut key: Vec<usize> = (0..n).map(|v| uf.find(v)).collect();
    if s.boundary_edges.is_empty() {
        return key;
    }
    let mut loops = UnionFind::new(n);
    for &[a, b] in &s.boundary_edges {
        loops.union(a as usize, b as usize);
    }
    let mut on_boundary = vec![false; n];
    for &[a, _] in &s.boundary_edges {
        on_boundary[a as usize] = true;
    }
    // The first loop seen per cluster, and whether a second one is there.
    let mut first = vec![usize::MAX; n];
    let mut mixed = vec![false; n];
    for v in (0..n).filter(|&v| on_boundary[v]) {
        let (k, l) = (key[v], loops.find(v));
        if first[k] == usize::MAX {
            first[k] = l;
        } else if first[k] != l {
            mixed[k] = true;
        }
    }
    if !mixed.iter().any(|&m| m) {
        return key;
    }
    let mut adj: Vec<Vec<u32>> = vec![Vec::new(); n];
    for &(a, b) in zero {
        if mixed[key[a as usize]] {
            adj[a as usize].push(b);
            adj[b as usize].push(a);
        }
    }
    // Multi-source BFS: the label is the smallest boundary vertex of the
    // source's loop within the cluster (a vertex of this cluster, so it
    // cannot be another cluster's key).
    let mut label = vec![usize::MAX; n];
    let mut loop_label: std::collections::HashMap<(usize, usize), usize> = Default::default();
    let mut queue = std::collections::VecDeque::new();
    for v in (0..n).filter(|&v| on_boundary[v] && mixed[key[v]]) {
        let l = *loop_label.entry((key[v], loops.find(v))).or_insert(v);
        label[v] = l;
        queue.push_back(v);
    }
    while let Some(v) = queue.pop_front() {
        for &w in &adj[v] {
            let w = w as usize;
            if label[w] == usize::MAX {
                label[w] = label[v];
                queue.push_back(w);
            }
        }
    }
    for v in 0..n {
        if mixed[key[v]] && label[v] != usize::MAX {
            key[v] = label[v];
        }
    }
    key
}

/// Each control vertex whose quads form more than one fan (quads around
/// it joined through the edges they share at it) split into one vertex
/// per fan, each moved a quarter of the way towards its fan's quads'
/// centre so the copies do not coincide (the caller projects them onto
/// M). On a lattice this happens where the zero offsets chain two lattice
/// points into one cluster, two sheets of the lattice then touch at a
/// point (measured on gargoyle: two closed fans of two quads each, the
/// split gives M's topology); where instead two holes of M come within
/// one step, the split joins them (bunny) and the topology check after
/// rejects the lattice as before. Returns the new points and quads and
/// how many vertices were split.
fn split_pinches(
    mut pos: Vec<DVec3>,
    mut quads: Vec<[u32; 4]>,
) -> (Vec<DVec3>, Vec<[u32; 4]>, usize) {
    let n = pos.len();
    // Corners of each vertex, (quad, corner), in quad order.
    let mut corners: Vec<Vec<(usize, usize)>> = vec![Vec::new(); n];
    for (q, quad) in quads.iter().enumerate() {
        for (c, &v) in quad.iter().enumerate() {
            corners[v as usize].push((q, c));
        }
    }
    let mut split = 0;
    for (v, cs) in corners.iter().enumerate() {
        if cs.len() < 2 {
            continue;
        }
        // Two corners are in one fan when their quads share an edge at v.
        let mut uf = UnionFind::new(cs.len());
        let ends = |&(q, c): &(usize, usize)| [quads[q][(c + 1) % 4], quads[q][(c + 3) % 4]];
        for i in 0..cs.len() {
            for j in i + 1..cs.len() {
                let (a, b) = (ends(&cs[i]), ends(&cs[j]));
                if a.iter().any(|x| b.contains(x)) {
                    uf.union(i, j);
                }
            }
        }
        let roots: Vec<usize> = (0..cs.len()).map(|i| uf.find(i)).collect();
        let mut fans: Vec<usize> = roots.clone();
        fans.sort_unstable();
        fans.dedup();
        if fans.len() < 2 {
            continue;
        }
        split += 1;
        let p = pos[v];
        for (k, &root) in fans.iter().enumerate() {
            let members: Vec<(usize, usize)> = (0..cs.len())
                .filter(|&i| roots[i] == root)
                .map(|i| cs[i])
                .collect();
            let centre = members
                .iter()
                .map(|&(q, _)| quads[q].iter().map(|&w| pos[w as usize]).sum::<DVec3>() / 4.0)
                .sum::<DVec3>()
                / members.len() as f64;
            let id = if k == 0 {
                v
            } else {
                pos.push(p);
                pos.len() - 1
            };
            pos[id] = p + 0.25 * (centre - p);
            for (q, c) in members {
                quads[q][c] = id as u32;
            }
        }
    }
    (pos, quads, split)
}

/// The faces of the lattice graph after removing what cannot bound a
/// face: dangling edges (a lattice point with one neighbour, pruned
/// repeatedly) and bridges (an edge a face walks both ways), then each
/// walk that still visits a point twice cut there into simple loops.
fn clean_faces(g: &mut Graph) -> Vec<Vec<u32>> {
    let mut faces = Vec::new();
    for _ in 0..16 {
        prune_dangling(g);
        faces = walk_faces(g);
        let mut bridges = Vec::new();
        for f in &faces {
            let k = f.len();
            let mut seen = std::collections::HashSet::new();
            for i in 0..k {
                seen.insert((f[i], f[(i + 1) % k]));
            }
            for i in 0..k {
                let (a, b) = (f[i], f[(i + 1) % k]);
                if a < b && seen.contains(&(b, a)) {
                    bridges.push((a, b));
                }
            }
        }
        if bridges.is_empty() {
            break;
        }
        for (a, b) in bridges {
            g.ring[a as usize].retain(|&x| x != b);
            g.ring[b as usize].retain(|&x| x != a);
        }
    }
    faces.into_iter().flat_map(simple_loops).collect()
}

/// Removes lattice points with fewer than two neighbours until none is left.
fn prune_dangling(g: &mut Graph) {
    let mut stack: Vec<usize> = (0..g.ring.len())
        .filter(|&v| g.ring[v].len() == 1)
        .collect();
    while let Some(v) = stack.pop() {
        if g.ring[v].len() != 1 {
            continue;
        }
        let w = g.ring[v][0] as usize;
        g.ring[v].clear();
        g.ring[w].retain(|&x| x as usize != v);
        if g.ring[w].len() == 1 {
            stack.push(w);
        }
    }
}

/// A closed walk cut at its repeated points into simple loops (each of at
/// least 3 points; shorter pieces are dropped).
fn simple_loops(face: Vec<u32>) -> Vec<Vec<u32>> {
    let mut out = Vec::new();
    let mut stack: Vec<u32> = Vec::new();
    for &v in face.iter().chain(face.first()) {
        if let Some(p) = stack.iter().position(|&x| x == v) {
            let piece: Vec<u32> = stack.drain(p..).collect();
            if piece.len() >= 3 {
                out.push(piece);
            }
        }
        stack.push(v);
    }
    out
}

/// Faces of the lattice graph: each directed edge walked once, the face on
/// its left; walks shorter than 3 or along a hole of M are dropped. Long
/// walks are kept: they are where the lattice has a defect (a pair of
/// singularities the position field did not resolve), and dropping them
/// would open a hole M does not have.
fn walk_faces(g: &Graph) -> Vec<Vec<u32>> {
    let c = g.ring.len();
    let mut used: Vec<Vec<bool>> = g.ring.iter().map(|r| vec![false; r.len()]).collect();
    let mut faces = Vec::new();
    for a0 in 0..c {
        for k0 in 0..g.ring[a0].len() {
            if used[a0][k0] {
                continue;
            }
            let mut face = Vec::new();
            let (mut a, mut k) = (a0, k0);
            let mut hole = false;
            let closed = loop {
                if used[a][k] {
                    break a == a0 && k == k0;
                }
                used[a][k] = true;
                face.push(a as u32);
                let b = g.ring[a][k] as usize;
                hole |= g.hole_side.contains(&(a as u32, b as u32));
                // At b, the edge just clockwise of b → a.
                let back = g.ring[b]
                    .iter()
                    .position(|&x| x as usize == a)
                    .expect("the lattice graph is symmetric");
                let deg = g.ring[b].len();
                (a, k) = (b, (back + deg - 1) % deg);
                if face.len() > MAX_FACE {
                    break false;
                }
            };
            if crate::switches::set("FIELD_DEBUG") && (!closed || hole || face.len() < 3) {
                eprintln!(
                    "dropped face closed {closed} hole {hole} len {}",
                    face.len()
                );
            }
            if closed && !hole && face.len() >= 3 {
                faces.push(face);
            }
        }
    }
    faces
}

/// Where the pure-quad mesh's irregular vertices come from (a
/// `FIELD_DEBUG` diagnostic): the raw lattice's non-quads by size and
/// after merging, and the irregular vertices of `quads` split into raw
/// lattice points whose raw faces were all quads (the lattice's own
/// singularities), raw points at a corner of a non-quad, and the points
/// the pairing added (index ≥ `n_raw`).
fn sources(raw: &[Vec<u32>], merged: &[Vec<u32>], quads: &[[u32; 4]], n_raw: usize) -> String {
    let sizes = |faces: &[Vec<u32>]| {
        let mut h = std::collections::BTreeMap::new();
        for f in faces.iter().filter(|f| f.len() != 4) {
            *h.entry(f.len()).or_insert(0usize) += 1;
        }
        h
    };
    let mut near_non_quad = vec![false; n_raw];
    for f in raw.iter().filter(|f| f.len() != 4) {
        for &v in f {
            near_non_quad[v as usize] = true;
        }
    }
    let (rv, rb) = valences(raw, n_raw);
    let raw_singular = (0..n_raw)
        .filter(|&v| rv[v] > 0 && !near_non_quad[v] && irregularity(rv[v], rb[v]) != 0)
        .count();
    let polys: Vec<Vec<u32>> = quads.iter().map(|q| q.to_vec()).collect();
    let n = quads
        .iter()
        .flatten()
        .map(|&v| v as usize + 1)
        .max()
        .unwrap_or(0);
    let (val, bnd) = valences(&polys, n);
    let (mut singular, mut corner, mut added) = (0, 0, 0);
    for v in (0..n).filter(|&v| val[v] > 0 && irregularity(val[v], bnd[v]) != 0) {
        if v >= n_raw {
            added += 1;
        } else if near_non_quad[v] {
            corner += 1;
        } else {
            singular += 1;
        }
    }
    // Each non-quad's corners as 4 − valence (what an interior lattice
    // point lacks; negative: too many edges; 'b' on M's boundary).
    let (mv, mb) = valences(merged, n_raw);
    let mut shapes = std::collections::BTreeMap::new();
    for f in merged.iter().filter(|f| f.len() != 4) {
        let s: String = f
            .iter()
            .map(|&v| {
                let v = v as usize;
                if mb[v] {
                    "b".to_string()
                } else {
                    (4 - mv[v] as i64).to_string()
                }
            })
            .collect::<Vec<_>>()
            .join(",");
        *shapes.entry(s).or_insert(0usize) += 1;
    }
    format!(
        "extraction sources: shapes {shapes:?}\n non-quads raw {:?} merged {:?}; raw singular points {raw_singular}; \
         irregular after pairing {} = lattice singular {singular} + non-quad corners {corner} + \
         added points {added}",
        sizes(raw),
        sizes(merged),
        singular + corner + added
    )
}

fn key(a: u32, b: u32) -> (u32, u32) {
    (a.min(b), a.max(b))
}

/// Each undirected edge of a polygon list and the faces using it.
fn edge_faces(polys: &[Vec<u32>]) -> std::collections::HashMap<(u32, u32), Vec<usize>> {
    let mut ef: std::collections::HashMap<(u32, u32), Vec<usize>> = Default::default();
    for (f, p) in polys.iter().enumerate() {
        let k = p.len();
        for i in 0..k {
            ef.entry(key(p[i], p[(i + 1) % k])).or_default().push(f);
        }
    }
    ef
}

/// Most sides of a merged face: merging into hexagons too lowers the
/// irregular vertices a little at no cost in accuracy, while merges of
/// any size leave larger faces that can fit worse (measured:
/// docs/status.md, "Measurements behind the code").
const MAX_MERGED: usize = 6;

/// Adjacent non-quads merged across their shared edge before the split,
/// where that lowers the irregular vertices of the result: the split
/// keeps every raw vertex's valence and gives each raw face a centre of
/// valence n, so merging two non-quads removes one or two irregular
/// centres (a triangle pair, the usual trace of a diagonal lattice edge,
/// becomes a quad) at the price of one less valence at the edge's ends.
/// Only pairs sharing exactly that edge (the union is a simple polygon)
/// into at most [`MAX_MERGED`] sides, best gain first (ties in face order), each face once, the gain recomputed
/// from the valences as they change.
///
/// With `at_size` (no split follows, [`super::purequad`] cuts even faces by
/// chords and pairs odd ones by paths) the gain is that of the pure-quad
/// conversion instead: two odd faces merged need no path between them (a
/// path ends in two new valence-3 points), two even ones gain nothing.
fn merge_non_quad_pairs(polys: Vec<Vec<u32>>, n: usize, at_size: bool) -> Vec<Vec<u32>> {
    let ef = edge_faces(&polys);
    let (mut val, bnd) = valences(&polys, n);
    let gain = |val: &[usize], f: usize, h: usize, a: u32, b: u32| -> Option<i64> {
        let (pf, pg) = (&polys[f], &polys[h]);
        let low = |v: u32| val[v as usize] < if bnd[v as usize] { 3 } else { 4 };
        if pf.iter().filter(|v| pg.contains(v)).count() != 2 || low(a) || low(b) {
            return None;
        }
        let cost = |v: u32| {
            let v = v as usize;
            irregularity(val[v] - 1, bnd[v]) - irregularity(val[v], bnd[v])
        };
        let merged = pf.len() + pg.len() - 2;
        if merged > MAX_MERGED {
            return None;
        }
        let base = if at_size {
            2 * i64::from(pf.len() % 2 == 1 && pg.len() % 2 == 1)
        } else {
            2 - i64::from(merged != 4)
        };
        Some(base - cost(a) - cost(b))
    };
    let mut cand: Vec<(i64, usize, usize, usize)> = Vec::new();
    for (f, pf) in polys.iter().enumerate() {
        let k = pf.len();
        if k == 4 {
            continue;
        }
        for i in 0..k {
            let (a, b) = (pf[i], pf[(i + 1) % k]);
            let fs = &ef[&key(a, b)];
            if fs.len() != 2 {
                continue;
            }
            let h = if fs[0] == f { fs[1] } else { fs[0] };
            if h <= f || polys[h].len() == 4 {
                continue;
            }
            if let Some(c) = gain(&val, f, h, a, b).filter(|&c| c > 0) {
                cand.push((-c, f, h, i));
            }
        }
    }
    cand.sort_unstable();
    let mut alive = vec![true; polys.len()];
    let mut out = Vec::with_capacity(polys.len());
    for (_, f, h, i) in cand {
        let pf = &polys[f];
        let k = pf.len();
        let (a, b) = (pf[i], pf[(i + 1) % k]);
        if !alive[f] || !alive[h] || !gain(&val, f, h, a, b).is_some_and(|c| c > 0) {
            continue;
        }
        let pg = &polys[h];
        let j = pg.iter().position(|&v| v == b).expect("shared edge");
        // f from b around to a, then h from a around to b, inner part.
        let mut m: Vec<u32> = (0..k).map(|t| pf[(i + 1 + t) % k]).collect();
        let kg = pg.len();
        m.extend((2..kg).map(|t| pg[(j + t) % kg]));
        alive[f] = false;
        alive[h] = false;
        val[a as usize] -= 1;
        val[b as usize] -= 1;
        out.push(m);
    }
    for (f, p) in polys.into_iter().enumerate() {
        if alive[f] {
            out.push(p);
        }
    }
    out
}
/// Tangential relaxation steps of the extracted points (each followed by
/// the projection onto M), as Instant Meshes' extraction ends (Jakob et
/// al. 2015, §6: "a few iterations of tangential smoothing"): the lattice
/// points are cluster means and the chords' quads have whatever corners
/// the raw lattice left, down to a fraction of a degree.
const RELAX_STEPS: usize = 3;

/// How the extracted points are relaxed: `FIELD_RELAX` =
/// `uniform[:STEPS]` (the default, [`RELAX_STEPS`] steps), `none`, or
/// `sized[:STEPS[:POWER]]` (neighbours weighted by the lattice spacing,
/// see [`relax`]; power 1 by default). An off-by-default switch for
/// measuring issue 40's adaptivity (docs/status.md, "Field-aligned layout",
/// 2026-12-06): the sized relaxation raises the gargoyle's ρ but moves the
/// small layouts' errors both ways by more than the noise.
#[derive(Clone, Copy, Debug, PartialEq)]
struct RelaxMode {
    steps: usize,
    sized: bool,
    power: f64,
}

impl RelaxMode {
    fn from_env() -> RelaxMode {
        RelaxMode::parse(&crate::switches::text("FIELD_RELAX").unwrap_or_default())
    }

    /// Anything unparsable is the default.
    fn parse(v: &str) -> RelaxMode {
        let mut it = v.split(':');
        let kind = it.next().unwrap_or("");
        let steps = it.next().and_then(|x| x.parse().ok());
        let power = it
            .next()
            .and_then(|x| x.parse::<f64>().ok())
            .filter(|p| p.is_finite())
            .unwrap_or(1.0);
        RelaxMode {
            steps: if kind == "none" {
                0
            } else {
                steps.unwrap_or(RELAX_STEPS)
            },
            sized: kind == "sized",
            power,
        }
    }
}

/// The lattice spacing `scale` (per vertex of M) at each point's closest
/// point on M, interpolated over its triangle.
fn sizes_at(caster: &BvhCaster, mesh: &TriMesh, scale: &[f64], pos: &[DVec3]) -> Result<Vec<f64>> {
    let hits = caster.closest_points(pos, f64::INFINITY)?;
    let mean = scale.iter().sum::<f64>() / scale.len().max(1) as f64;
    Ok(hits
        .iter()
        .map(|h| {
            h.as_ref().map_or(mean, |h| {
                let t = mesh.triangles[h.triangle as usize];
                let w = [1.0 - h.u - h.v, h.u, h.v];
                (0..3).map(|k| w[k] * scale[t[k] as usize]).sum::<f64>()
            })
        })
        .collect())
}

/// Each interior point moved halfway to the mean of its edge neighbours
/// (halfway, so that the projection onto M stays on the point's own sheet
/// of a thin part); points on a boundary edge stay. With `sizes`, each
/// neighbour weighs `L^-power`, `L` the edge's mean size: along a chain the
/// weighted mean's fixed point has edge lengths ∝ L (at power 1, equal
/// tension e/L on every edge), so the relaxation keeps the sizing's
/// grading instead of equalising the patches.
fn relax(pos: &[DVec3], quads: &[[u32; 4]], sizes: Option<&[f64]>, power: f64) -> Vec<DVec3> {
    let n = pos.len();
    let mut count: std::collections::HashMap<(u32, u32), u8> = Default::default();
    for q in quads {
        for i in 0..4 {
            *count.entry(key(q[i], q[(i + 1) % 4])).or_default() += 1;
        }
    }
    let (mut sum, mut deg, mut fixed) = (vec![DVec3::ZERO; n], vec![0.0; n], vec![false; n]);
    let mut edges: Vec<(&(u32, u32), &u8)> = count.iter().collect();
    edges.sort_unstable();
    for (&(a, b), &c) in edges {
        let (a, b) = (a as usize, b as usize);
        let w = sizes.map_or(1.0, |h| (0.5 * (h[a] + h[b])).max(1e-300).powf(-power));
        sum[a] += w * pos[b];
        sum[b] += w * pos[a];
        deg[a] += w;
        deg[b] += w;
        if c == 1 {
            fixed[a] = true;
            fixed[b] = true;
        }
    }
    (0..n)
        .map(|v| {
            if fixed[v] || deg[v] == 0.0 {
                pos[v]
            } else {
                0.5 * (pos[v] + sum[v] / deg[v])
            }
        })
        .collect()
}

/// The sized relaxation after the extraction (issue 40's adaptivity,
/// `FIELD_SIZED_RELAX=STEPS:POWER[:GAMMA]`, off by default): [`relax`]'s
/// weighted steps towards sizes of its own ([`super::sizing::relaxation_sizes`],
/// the S- and M-fitmap limits graded at GAMMA, without the holes' caps),
/// not the lattice's step. The lattice keeps its count and topology from
/// the graded, capped sizing; the points then slide towards where the
/// Fitmap asks for smaller patches.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SizedRelax {
    pub steps: usize,
    pub power: f64,
    /// γ of the relaxation's sizes (infinite: ungraded).
    pub gamma: f64,
    /// Undo the moves of a step that lengthen an edge or a quad's diagonal
    /// past the Fitmap's own limit there (`g` in the fourth field): the
    /// relaxation may only grow patches the Fitmap allows to grow.
    pub guard: bool,
    /// Undo the move of a point whose projection lands on a sheet of M
    /// facing away from the one it left (`s` in the fourth field): across
    /// a thin part the closest point can be on the other side.
    pub sheet: bool,
    /// Undo the moves of a step on every quad it leaves with a corner
    /// sharper than [`SHAPE_GUARD_MIN_SINE`] (and sharper than before;
    /// `q` in the fourth field): the fit pays for distorted patches more
    /// than it gains from their sizes.
    pub shape: bool,
    /// Relax towards the S-fitmap's sizes alone (`f` in the fourth field;
    /// [`super::sizing::relaxation_sizes`] with `s_only`): F_M then bounds only through
    /// the growth guard's limits, so where it caps h_S (7 % of the
    /// gargoyle's vertices at τ 1 %) it does not set the ranks the
    /// relaxation aims at.
    pub s_only: bool,
}

/// The shape guard's bound on a corner's sine (45°).
pub const SHAPE_GUARD_MIN_SINE: f64 = std::f64::consts::FRAC_1_SQRT_2;

impl SizedRelax {
    pub fn from_env() -> Option<SizedRelax> {
        SizedRelax::parse(&crate::switches::text("FIELD_SIZED_RELAX")?)
    }

    /// `None` for anything unparsable or zero steps.
    pub fn parse(v: &str) -> Option<SizedRelax> {
        let mut it = v.split(':');
        let steps: usize = it.next()?.parse().ok()?;
        let power: f64 = it.next()?.parse().ok().filter(|p: &f64| p.is_finite())?;
        let gamma = match it.next() {
            Some(g) => g.parse().ok().filter(|g: &f64| *g > 0.0)?,
            None => f64::INFINITY,
        };
        let guards = it.next().unwrap_or("");
        if it.next().is_some() || !guards.chars().all(|c| "gsqf".contains(c)) {
            return None;
        }
        (steps > 0).then_some(SizedRelax {
            steps,
            power,
            gamma,
            guard: guards.contains('g'),
            sheet: guards.contains('s'),
            shape: guards.contains('q'),
            s_only: guards.contains('f'),
        })
    }
}

/// A [`SizedRelax`] ready for the layouts of one sizing: its sizes and,
/// with the guard, its limits ([`super::sizing::relaxation_sizes`] at the
/// layout's α and μ, graded at the mode's γ and not graded).
pub struct SizedRelaxPlan {
    mode: SizedRelax,
    sizes: Vec<f64>,
    limits: Option<Vec<f64>>,
}

impl SizedRelaxPlan {
    /// `None` unless [`super::FieldOptions::sized_relax`] asks for it.
    pub fn new(
        s: &Surface,
        mesh: &TriMesh,
        fitmap: &crate::analysis::Fitmap,
        opts: &super::FieldOptions,
        alpha: f64,
        mu: f64,
    ) -> Result<Option<SizedRelaxPlan>> {
        let Some(mode) = opts.sized_relax else {
            return Ok(None);
        };
        let sizes_at = |g: f64, s_only: bool| {
            super::sizing::relaxation_sizes(s, mesh, fitmap, opts, alpha, mu, g, s_only)
        };
        let sizes = sizes_at(mode.gamma, mode.s_only)?;
        let limits = if mode.guard {
            Some(sizes_at(f64::INFINITY, false)?)
        } else {
            None
        };
        Ok(Some(SizedRelaxPlan {
            mode,
            sizes,
            limits,
        }))
    }

    /// This plan for a layout laid at the sizing `h` instead of `base`
    /// (both per vertex of M′; `base` is the sizing the plan's α belongs
    /// to): its sizes and limits times `h / base` per vertex. A
    /// `--max-error` round's sizing is the first one times local factors
    /// (and a count's global scale), so the relaxation keeps the F_S
    /// ranks of the first layout's aim and the round's refinements
    /// (issue 40's adaptivity after the rounds), and the growth guard
    /// follows the size the lattice was laid at instead of freezing a
    /// coarser lattice. `None` when the lengths differ.
    pub fn following(&self, base: &[f64], h: &[f64]) -> Option<SizedRelaxPlan> {
        if base.len() != h.len() || base.len() != self.sizes.len() {
            return None;
        }
        let scale = |v: &[f64]| -> Vec<f64> {
            v.iter()
                .zip(base.iter().zip(h))
                .map(|(x, (b, h))| if *b > 0.0 { x * (h / b) } else { *x })
                .collect()
        };
        Some(SizedRelaxPlan {
            mode: self.mode,
            sizes: scale(&self.sizes),
            limits: self.limits.as_deref().map(scale),
        })
    }

    /// [`relax_to_sizes`] with this plan.
    pub fn apply(
        &self,
        control: &mut ControlMesh,
        mesh: &TriMesh,
        caster: &BvhCaster,
    ) -> Result<()> {
        let limits = self.limits.as_deref();
        relax_to_sizes(control, mesh, caster, &self.sizes, limits, self.mode)
    }
}

/// [`relax`] `steps` times on a pure-quad `control` with per-vertex
/// `sizes` of `mesh` (each step followed by the projection onto M); a mesh
/// with a non-quad face is left as it is. With `limits` (per vertex of
/// `mesh`, the longest edge the Fitmap allows), the points of an edge that
/// a step lengthens past its limit at its midpoint, or of a quad whose
/// diagonal it lengthens past √2 times that, keep their places.
pub fn relax_to_sizes(
    control: &mut ControlMesh,
    mesh: &TriMesh,
    caster: &BvhCaster,
    sizes: &[f64],
    limits: Option<&[f64]>,
    mode: SizedRelax,
) -> Result<()> {
    let mut quads = Vec::with_capacity(control.num_faces());
    for f in control.faces() {
        let v: Vec<u32> = control.face_vertices(f).map(|v| v.idx() as u32).collect();
        match v[..] {
            [a, b, c, d] => quads.push([a, b, c, d]),
            _ => return Ok(()),
        }
    }
    let mut pos = control.positions().to_vec();
    for _ in 0..mode.steps {
        let at = sizes_at(caster, mesh, sizes, &pos)?;
        let mut moved = relax(&pos, &quads, Some(&at), mode.power);
        if let Some(limits) = limits {
            guard_growth(caster, mesh, limits, &quads, &pos, &mut moved)?;
        }
        let hits = caster.closest_points(&moved, f64::INFINITY)?;
        let mut next: Vec<DVec3> = moved
            .iter()
            .zip(&hits)
            .map(|(p, h)| h.as_ref().map_or(*p, |h| h.point))
            .collect();
        if mode.sheet {
            let before = caster.closest_points(&pos, f64::INFINITY)?;
            let normal = |t: u32| {
                let [a, b, c] = mesh.triangles[t as usize].map(|v| mesh.positions[v as usize]);
                (b - a).cross(c - a).normalize_or_zero()
            };
            for (k, (a, b)) in before.iter().zip(&hits).enumerate() {
                if let (Some(a), Some(b)) = (a, b) {
                    if normal(a.triangle).dot(normal(b.triangle)) < 0.0 {
                        next[k] = pos[k];
                    }
                }
            }
        }
        if mode.shape {
            guard_shape(&quads, &pos, &mut next);
        }
        pos = next;
    }
    control.set_positions(pos)
}

/// Puts back (in `moved`) the corners of every quad with a side or a
/// diagonal that is longer in `moved` than in `pos` and longer than its
/// limit (`limits` at the side's midpoint, √2 times it for a diagonal).
fn guard_growth(
    caster: &BvhCaster,
    mesh: &TriMesh,
    limits: &[f64],
    quads: &[[u32; 4]],
    pos: &[DVec3],
    moved: &mut [DVec3],
) -> Result<()> {
    // Each quad's four sides and two diagonals, as (a, b, factor).
    let pairs = |q: &[u32; 4]| {
        let s2 = std::f64::consts::SQRT_2;
        [
            (q[0], q[1], 1.0),
            (q[1], q[2], 1.0),
            (q[2], q[3], 1.0),
            (q[3], q[0], 1.0),
            (q[0], q[2], s2),
            (q[1], q[3], s2),
        ]
    };
    // Putting a quad's corners back can lengthen its neighbours' sides, so
    // until none is left (at worst every point is put back).
    loop {
        let mids: Vec<DVec3> = quads
            .iter()
            .flat_map(|q| pairs(q).map(|(a, b, _)| 0.5 * (moved[a as usize] + moved[b as usize])))
            .collect();
        let lim = sizes_at(caster, mesh, limits, &mids)?;
        let mut changed = false;
        for (k, q) in quads.iter().enumerate() {
            let grew_past = pairs(q).iter().enumerate().any(|(e, &(a, b, f))| {
                let (a, b) = (a as usize, b as usize);
                let after = (moved[a] - moved[b]).length();
                after > (pos[a] - pos[b]).length() && after > f * lim[6 * k + e]
            });
            if grew_past {
                for &v in q {
                    changed |= moved[v as usize] != pos[v as usize];
                    moved[v as usize] = pos[v as usize];
                }
            }
        }
        if !changed {
            return Ok(());
        }
    }
}

/// The smallest sine of a quad's four corners (0 for a degenerate one).
fn min_corner_sine(q: &[u32; 4], p: &[DVec3]) -> f64 {
    (0..4)
        .map(|k| {
            let c = p[q[k] as usize];
            let a = p[q[(k + 3) % 4] as usize] - c;
            let b = p[q[(k + 1) % 4] as usize] - c;
            let d = a.length() * b.length();
            if d > 0.0 && a.dot(b) < d {
                a.cross(b).length() / d
            } else {
                0.0
            }
        })
        .fold(f64::INFINITY, f64::min)
}

/// Puts back (in `moved`) the corners of every quad whose sharpest corner
/// is sharper in `moved` than in `pos` and below [`SHAPE_GUARD_MIN_SINE`],
/// until no quad is (at worst every point is put back).
fn guard_shape(quads: &[[u32; 4]], pos: &[DVec3], moved: &mut [DVec3]) {
    let was: Vec<f64> = quads.iter().map(|q| min_corner_sine(q, pos)).collect();
    loop {
        let mut changed = false;
        for (q, &w) in quads.iter().zip(&was) {
            let now = min_corner_sine(q, moved);
            if now < w && now < SHAPE_GUARD_MIN_SINE {
                for &v in q {
                    changed |= moved[v as usize] != pos[v as usize];
                    moved[v as usize] = pos[v as usize];
                }
            }
        }
        if !changed {
            return;
        }
    }
}

/// The points used by `quads`, renumbered in order of first use.
fn compact(pos: Vec<DVec3>, quads: Vec<[u32; 4]>) -> (Vec<DVec3>, Vec<[u32; 4]>) {
    let mut index = vec![u32::MAX; pos.len()];
    let mut out = Vec::new();
    let quads = quads
        .into_iter()
        .map(|q| {
            q.map(|v| {
                if index[v as usize] == u32::MAX {
                    index[v as usize] = out.len() as u32;
                    out.push(pos[v as usize]);
                }
                index[v as usize]
            })
        })
        .collect();
    (out, quads)
}

/// One Catmull-Clark split of the raw faces, topologically (face points
/// at the corners' mean, edge points at midpoints; both projected onto M
/// by the caller). Lattice points used by no face are dropped.
fn split_to_quads(g: &Graph, faces: &[Vec<u32>]) -> (Vec<DVec3>, Vec<[u32; 4]>) {
    let mut index = vec![u32::MAX; g.pos.len()];
    let mut positions = Vec::new();
    for f in faces {
        for &v in f {
            if index[v as usize] == u32::MAX {
                index[v as usize] = positions.len() as u32;
                positions.push(g.pos[v as usize]);
            }
        }
    }
    let mut edge_point = std::collections::HashMap::new();
    let mut quads = Vec::new();
    for f in faces {
        let fp = positions.len() as u32;
        let centre = f.iter().map(|&v| g.pos[v as usize]).sum::<DVec3>() / f.len() as f64;
        positions.push(centre);
        let k = f.len();
        let mut mids = Vec::with_capacity(k);
        for i in 0..k {
            let (a, b) = (f[i], f[(i + 1) % k]);
            let key = (a.min(b), a.max(b));
            let m = *edge_point.entry(key).or_insert_with(|| {
                positions.push(0.5 * (g.pos[a as usize] + g.pos[b as usize]));
                positions.len() as u32 - 1
            });
            mids.push(m);
        }
        for i in 0..k {
            quads.push([index[f[i] as usize], mids[i], fp, mids[(i + k - 1) % k]]);
        }
    }
    (positions, quads)
}

/// `FIELD_DUMP=DIR` (a trace, session 25's per-stage measurement of
/// homer's fingers): each lattice's stages written to `DIR` as numbered
/// files, in the order laid (one draw: sequential).
fn dump_dir() -> Option<String> {
    crate::switches::text("FIELD_DUMP").filter(|d| !d.is_empty())
}

static DUMPED: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);

/// Per vertex of M: its position, its lattice point o, and its cluster
/// (the lattice vertex it merges into) from the position field's own
/// offsets and after the flow and flip removal (`lattice-N.txt`).
fn dump_clusters(dir: &str, s: &Surface, o: &[DVec3], raw: &[[i64; 2]], after: &[u32]) {
    let n = s.len();
    let mut uf = UnionFind::new(n);
    for (&[a, b], d) in s.edges.iter().zip(raw) {
        if d[0] == 0 && d[1] == 0 {
            uf.union(a as usize, b as usize);
        }
    }
    let mut text = String::new();
    for v in 0..n {
        let (p, q) = (s.positions[v], o[v]);
        text.push_str(&format!(
            "{} {} {} {} {} {} {} {}\n",
            p.x,
            p.y,
            p.z,
            q.x,
            q.y,
            q.z,
            uf.find(v),
            after[v]
        ));
    }
    let k = DUMPED.load(std::sync::atomic::Ordering::Relaxed);
    let _ = std::fs::write(format!("{dir}/lattice-{k}.txt"), text);
}

/// The extracted quads before the cleanup (`extract-N.obj`).
fn dump_quads(dir: &str, positions: &[DVec3], quads: &[[u32; 4]]) {
    let mut text = String::new();
    for p in positions {
        text.push_str(&format!("v {} {} {}\n", p.x, p.y, p.z));
    }
    for q in quads {
        text.push_str(&format!(
            "f {} {} {} {}\n",
            q[0] + 1,
            q[1] + 1,
            q[2] + 1,
            q[3] + 1
        ));
    }
    let k = DUMPED.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let _ = std::fs::write(format!("{dir}/extract-{k}.obj"), text);
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 3 × 3 grid of quads whose centre cell is cut by a diagonal into
    /// two triangles (the trace of a diagonal lattice edge): the merge
    /// restores the centre quad (both diagonal ends back to valence 4)
    /// and leaves the eight quads as they were.
    #[test]
    fn triangle_pair_on_a_diagonal_is_merged_into_the_quad() {
        let id = |i: u32, j: u32| j * 4 + i;
        let mut polys = Vec::new();
        for j in 0..3 {
            for i in 0..3 {
                let q = vec![id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1)];
                if (i, j) == (1, 1) {
                    polys.push(vec![q[0], q[1], q[2]]);
                    polys.push(vec![q[0], q[2], q[3]]);
                } else {
                    polys.push(q);
                }
            }
        }
        let out = merge_non_quad_pairs(polys.clone(), 16, false);
        assert_eq!(out.len(), 9);
        assert!(out.iter().all(|p| p.len() == 4));
        let centre = out.iter().find(|p| p.contains(&id(1, 1))).unwrap();
        let mut c = centre.clone();
        c.sort_unstable();
        assert_eq!(c, vec![id(1, 1), id(2, 1), id(1, 2), id(2, 2)]);
        let (val, _) = valences(&out, 16);
        assert_eq!((val[id(1, 1) as usize], val[id(2, 2) as usize]), (4, 4));
        // Orientation kept: every directed edge is used once.
        let mut directed = std::collections::HashSet::new();
        for p in &out {
            for i in 0..4 {
                assert!(directed.insert((p[i], p[(i + 1) % 4])));
            }
        }
    }

    /// A plane grid of `nx` × `ny` quads with unit spacing.
    fn grid(nx: usize, ny: usize) -> (Vec<DVec3>, Vec<[u32; 4]>) {
        let id = |i: usize, j: usize| (j * (nx + 1) + i) as u32;
        let mut pos = Vec::new();
        for j in 0..=ny {
            for i in 0..=nx {
                pos.push(DVec3::new(i as f64, j as f64, 0.0));
            }
        }
        let mut quads = Vec::new();
        for j in 0..ny {
            for i in 0..nx {
                quads.push([id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1)]);
            }
        }
        (pos, quads)
    }

    #[test]
    fn relax_mode_parses_the_switch() {
        let d = RelaxMode::parse("");
        assert_eq!((d.steps, d.sized), (RELAX_STEPS, false));
        assert_eq!(RelaxMode::parse("none").steps, 0);
        let s = RelaxMode::parse("sized:5:8");
        assert_eq!((s.steps, s.sized, s.power), (5, true, 8.0));
        assert_eq!(RelaxMode::parse("sized").power, 1.0);
        assert_eq!(RelaxMode::parse("sized:x:inf").steps, RELAX_STEPS);
    }

    /// Equal sizes weigh every neighbour alike: the sized relaxation is
    /// the uniform one (to rounding), on a jittered grid.
    #[test]
    fn equal_sizes_relax_as_the_uniform_relaxation() {
        let (mut pos, quads) = grid(6, 5);
        for (k, p) in pos.iter_mut().enumerate() {
            p.x += 0.2 * ((k * 37 % 11) as f64 / 11.0 - 0.5);
            p.y += 0.2 * ((k * 53 % 13) as f64 / 13.0 - 0.5);
        }
        let uniform = relax(&pos, &quads, None, 1.0);
        let sized = relax(&pos, &quads, Some(&vec![0.3; pos.len()]), 4.0);
        for (a, b) in uniform.iter().zip(&sized) {
            assert!((*a - *b).length() < 1e-12);
        }
        // The boundary stays, the interior moves.
        assert_eq!(uniform[0], pos[0]);
        assert!(uniform
            .iter()
            .zip(&pos)
            .any(|(a, b)| (*a - *b).length() > 1e-3));
    }

    /// Sizes growing 3× from left to right: relaxed to its fixed point
    /// (the boundary held), the uniform relaxation keeps the grid's equal
    /// spacing, the sized one grades it. Along a chain the fixed point has
    /// edges ∝ L^power, here 2.92 / 1.08 = 2.7 between the rightmost and
    /// the leftmost edge; the fixed top and bottom rows pull the middle row
    /// back towards equal spacing (measured 2.51), so the bar is 2.
    #[test]
    fn sized_relaxation_grades_the_spacing() {
        let (nx, ny) = (12, 24);
        let (pos, quads) = grid(nx, ny);
        let sizes: Vec<f64> = pos.iter().map(|p| 1.0 + 2.0 * p.x / nx as f64).collect();
        let run = |sized: Option<&[f64]>| {
            let mut p = pos.clone();
            for _ in 0..2000 {
                p = relax(&p, &quads, sized, 1.0);
            }
            let row = ny / 2 * (nx + 1);
            let first = p[row + 1].x - p[row].x;
            let last = p[row + nx].x - p[row + nx - 1].x;
            let monotone = (1..nx)
                .all(|i| p[row + i + 1].x - p[row + i].x >= p[row + i].x - p[row + i - 1].x - 1e-9);
            (last / first, monotone)
        };
        let (uniform, _) = run(None);
        assert!((uniform - 1.0).abs() < 1e-6, "uniform ratio {uniform}");
        let (graded, monotone) = run(Some(&sizes));
        assert!(
            graded > 2.0 && monotone,
            "graded ratio {graded}, monotone {monotone}"
        );
    }

    #[test]
    fn sized_relax_parses_its_switch() {
        let m = SizedRelax::parse("6:12").unwrap();
        assert_eq!((m.steps, m.power, m.gamma), (6, 12.0, f64::INFINITY));
        assert_eq!(SizedRelax::parse("3:8:1").unwrap().gamma, 1.0);
        assert!(SizedRelax::parse("3:8:1:g").unwrap().guard);
        assert!(!SizedRelax::parse("3:8:1").unwrap().guard);
        let m = SizedRelax::parse("3:8:inf:sq").unwrap();
        assert!(m.sheet && m.shape && !m.guard);
        for bad in [
            "",
            "0:8",
            "x:8",
            "3",
            "3:inf",
            "3:8:-1",
            "3:8:y",
            "3:8:1:x",
            "3:8:1:g:s",
        ] {
            assert_eq!(SizedRelax::parse(bad), None, "{bad:?}");
        }
    }

    /// The plane of `pos` and `quads`, each quad split along its first
    /// diagonal: the M the relaxation tests project onto.
    fn split_quads(pos: &[DVec3], quads: &[[u32; 4]]) -> TriMesh {
        TriMesh {
            positions: pos.to_vec(),
            triangles: quads
                .iter()
                .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
                .collect(),
        }
    }

    /// A flat 8×8 control grid over a triangulated plane, sizes growing 3×
    /// from left to right: every step keeps the points on the plane and
    /// the boundary where it was, and the interior slides towards the
    /// small sizes (each point's weighted mean lies left of the uniform
    /// one), so the leftmost column of cells ends narrower than the
    /// rightmost.
    #[test]
    fn relax_to_sizes_slides_the_interior_towards_small_sizes() {
        let n = 8;
        let (pos, quads) = grid(n, n);
        let mesh = split_quads(&pos, &quads);
        let sizes: Vec<f64> = pos.iter().map(|p| 1.0 + 2.0 * p.x / n as f64).collect();
        let caster = BvhCaster::new(&mesh).unwrap();
        let mut control = ControlMesh::from_polygons(pos.clone(), &quads).unwrap();
        let mode = SizedRelax::parse("20:1").unwrap();
        relax_to_sizes(&mut control, &mesh, &caster, &sizes, None, mode).unwrap();
        let p = control.positions();
        let row = n / 2 * (n + 1);
        for (k, (a, b)) in p.iter().zip(&pos).enumerate() {
            assert!(a.z.abs() < 1e-12, "point {k} left the plane");
            let (i, j) = (k % (n + 1), k / (n + 1));
            if i == 0 || j == 0 || i == n || j == n {
                assert!((*a - *b).length() < 1e-12, "boundary point {k} moved");
            }
        }
        let first = p[row + 1].x - p[row].x;
        let last = p[row + n].x - p[row + n - 1].x;
        assert!(last > 1.2 * first, "first cell {first}, last {last}");
    }

    /// The shape guard leaves no quad with a corner sharper than both its
    /// own start and 45°, where the same steps without it do (the sizes
    /// grow 30× across the grid, so power 12 pulls the cells far out of
    /// square).
    #[test]
    fn shape_guard_keeps_corners_from_sharpening() {
        let n = 8;
        let (pos, quads) = grid(n, n);
        let mesh = split_quads(&pos, &quads);
        let sizes: Vec<f64> = pos
            .iter()
            .map(|p| 1.0 + 29.0 * (p.x * p.y) / (n * n) as f64)
            .collect();
        let caster = BvhCaster::new(&mesh).unwrap();
        let worst = |guards: &str| {
            let mut control = ControlMesh::from_polygons(pos.clone(), &quads).unwrap();
            let mode = SizedRelax::parse(&format!("10:12:inf{guards}")).unwrap();
            relax_to_sizes(&mut control, &mesh, &caster, &sizes, None, mode).unwrap();
            let p = control.positions();
            quads
                .iter()
                .map(|q| min_corner_sine(q, p))
                .fold(f64::INFINITY, f64::min)
        };
        // The start is the unit grid: every corner square (sine 1).
        let (free, guarded) = (worst(""), worst(":q"));
        assert!(
            free < SHAPE_GUARD_MIN_SINE,
            "unguarded sharpest sine {free}"
        );
        assert!(
            guarded >= SHAPE_GUARD_MIN_SINE - 1e-12,
            "guarded sharpest sine {guarded}"
        );
    }

    /// With limits below every edge the guard lets no step lengthen a
    /// side or a diagonal of any quad.
    #[test]
    fn guarded_relaxation_grows_nothing_past_its_limits() {
        let n = 8;
        let (pos, quads) = grid(n, n);
        let mesh = split_quads(&pos, &quads);
        let mut jittered = pos.clone();
        for (k, p) in jittered.iter_mut().enumerate() {
            let (i, j) = (k % (n + 1), k / (n + 1));
            if i > 0 && j > 0 && i < n && j < n {
                p.x += 0.3 * ((k * 37 % 11) as f64 / 11.0 - 0.5);
                p.y += 0.3 * ((k * 53 % 13) as f64 / 13.0 - 0.5);
            }
        }
        let sizes: Vec<f64> = pos.iter().map(|p| 1.0 + 2.0 * p.x / n as f64).collect();
        let caster = BvhCaster::new(&mesh).unwrap();
        let mut control = ControlMesh::from_polygons(jittered.clone(), &quads).unwrap();
        let mode = SizedRelax::parse("5:4:inf:g").unwrap();
        let limits = vec![1e-3; pos.len()];
        relax_to_sizes(&mut control, &mesh, &caster, &sizes, Some(&limits), mode).unwrap();
        let p = control.positions();
        for q in &quads {
            for (a, b) in [(0, 1), (1, 2), (2, 3), (3, 0), (0, 2), (1, 3)] {
                let (a, b) = (q[a] as usize, q[b] as usize);
                let (before, after) =
                    ((jittered[a] - jittered[b]).length(), (p[a] - p[b]).length());
                assert!(after <= before + 1e-12, "{a}-{b}: {before} -> {after}");
            }
        }
    }
}
