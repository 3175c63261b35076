//! Decomposition of M into patches (Lavoué et al. §4).
//!
//! The paper uses the curvature-based segmentation of Lavoué, Dupont and
//! Baskurt (2005): region growing into near-constant-curvature regions,
//! then boundary rectification along the curvature directions. What the
//! fitting needs from it, and what this module guarantees:
//!
//! 1. *Sharp edges on boundaries.* Regions are grown over triangles and may
//!    never cross a sharp edge (dihedral above
//!    [`super::topology::SHARP_DIHEDRAL_DEG`]) nor a boundary or
//!    non-manifold edge of M. On CAD parts these edges *are* the rectified
//!    boundaries of the paper: a polyline of M's own edges along the
//!    feature, so no rectification is needed there.
//! 2. *Near-constant curvature.* Inside a sharp-bounded component, growing
//!    also stops across an edge whose two triangles have different
//!    curvature classes (planar / parabolic / elliptic / hyperbolic, from
//!    the vertex tensors of §3.1), provided both sides are large: the
//!    paper's clustering of curvature values, restricted to the class
//!    (what decides the control-polygon layout of §6), since the values
//!    themselves vary along every fillet.
//! 3. *Small regions merged* ([`SegmentOptions::min_region_share`]) into
//!    the neighbour they share the longest non-sharp boundary with; a
//!    region bounded by sharp edges only is kept whatever its size (merging
//!    it would lose a feature).
//!    Then regions of one sharp-bounded component are *merged across
//!    their smooth boundaries* while the union stays a disc (step 3a):
//!    every region boundary becomes an infinitely sharp crease, which
//!    belongs on a feature, not on a tangent-continuous blend; the
//!    curvature-class splits survive only where a disc needs them. Two
//!    regions that also share a *fading* feature
//!    (a sharp chain that ends inside a face of the part, see
//!    [`fading_edges`]) merge too: where such a feature runs is decided
//!    by step 4, not by where two curvature classes happened to meet.
//! 4. *Dangling features continued.* A sharp chain that fades out inside
//!    a region is continued from its free end along the straightest path
//!    to the region boundary or to another feature chain anchored on it
//!    (a T-junction), or joined to another fading tip when that path is
//!    shorter than both continuations; the region is cut there, so that
//!    every sharp edge ends up on a boundary (a crease of the output) with
//!    the least new boundary.
//! 5. *Discs.* §6.3.1 cuts a region with holes into a disc with its
//!    Topological Contour; here a region that is not a topological disc
//!    (one boundary loop, Euler characteristic 1) is split in two by a
//!    geodesic Voronoi partition from its two mutually farthest triangles,
//!    recursively ([`SegmentOptions::max_splits`] in all). The cut becomes a
//!    region boundary (a crease), which is the price of this simplification
//!    (rarely paid: docs/status.md, "Measurements behind the code").

use std::cmp::Reverse;
use std::collections::{BinaryHeap, HashMap, HashSet, VecDeque};

use super::curvature::VertexCurvature;
use super::topology::Topology;
use super::OrdF;
use crate::mesh::TriMesh;
use crate::DVec3;

/// Options of [`segment`].
#[derive(Clone, Debug)]
pub struct SegmentOptions {
    /// A region smaller than this share of M's area, not bounded by sharp
    /// edges only, is merged into a neighbour: 0.2 %.
    pub min_region_share: f64,
    /// Split curvature classes only where both sides have at least this
    /// share of the component's triangles: 10 % (avoids slivers along the
    /// edges of fillets, where the estimate mixes both sides).
    pub min_class_share: f64,
    /// Most disc-making splits over the whole mesh: 256. Past it a
    /// non-disc region is kept and the polyhedron stage falls back to a
    /// star layout for it.
    pub max_splits: usize,
    /// Merge regions across smooth boundaries while the union stays a
    /// disc (step 3a of [`segment`]): true.
    pub merge_smooth: bool,
    /// Leave a sharp chain that fades out inside a region as a slit of
    /// that region when the chain hangs from the region's boundary (steps
    /// 3b/4b then skip it): false. The crease then ends at the chain's
    /// tip, as on M, instead of going on as a smooth boundary to the far
    /// side of the region, which costs that continuation's control points
    /// and a corner where it lands (see `build_control`, which falls back to
    /// the continuation when a slit region's polyhedron cannot be built).
    pub slits: bool,
}

impl Default for SegmentOptions {
    fn default() -> Self {
        SegmentOptions {
            min_region_share: 0.002,
            min_class_share: 0.1,
            max_splits: 256,
            merge_smooth: true,
            slits: false,
        }
    }
}

/// Region per triangle and what the segmentation did.
#[derive(Clone, Debug)]
pub struct Segmentation {
    pub region: Vec<u32>,
    pub num_regions: usize,
    pub sharp_edges: usize,
    /// Sharp edges with the same region on both sides (a feature line that
    /// fades out inside a face; kept smooth).
    pub sharp_edges_inside: usize,
    /// Whether the sharp edges left inside regions are slits (see
    /// [`SegmentOptions::slits`]): every chain of them hangs from its
    /// region's boundary.
    pub slits: bool,
    pub splits: usize,
    pub merged: usize,
    /// Pairs of regions merged across a smooth boundary (step 3a).
    pub merged_smooth: usize,
}

fn class_of(c: &VertexCurvature, diag: f64) -> u8 {
    let flat = 0.5 / diag;
    let (a, b) = (c.k_max, c.k_min);
    let big = a.abs().max(b.abs());
    if big <= flat {
        0 // planar
    } else if a.abs() <= 0.2 * big || b.abs() <= 0.2 * big {
        1 // parabolic (cylinder, cone)
    } else if a * b > 0.0 {
        2 // elliptic
    } else {
        3 // hyperbolic
    }
}

/// Segments `mesh` (see the module docs): one named step per stage of
/// §4 as this module implements it, in order.
pub fn segment(
    mesh: &TriMesh,
    topo: &Topology,
    curv: &[VertexCurvature],
    opts: &SegmentOptions,
) -> Segmentation {
    let sharp = topo.sharp_edges();
    let blocked = |e: usize| sharp[e] || !topo.edges[e].is_interior();
    // 1–2. Sharp-bounded components cut into curvature classes.
    let mut region = class_regions(mesh, topo, curv, opts, &blocked);
    // 3. Merge small regions, smallest first; one without a non-sharp
    // neighbour is kept (skipped).
    let merged = merge_small(mesh, topo, &blocked, opts.min_region_share, &mut region);
    // 3a. Smooth merges: two regions of one sharp-bounded component meet
    // along a tangent-continuous (non-sharp) boundary, and every region
    // boundary becomes an infinitely sharp crease of the output (§8 step
    // 3): such a boundary would put a crease where M has none, and costs
    // a curve, its control points and the corners at its ends. A
    // Catmull-Clark patch group represents the blend across it (the
    // enrichment of §7.2 adds points where the fit asks), so the two are
    // merged whenever the union is still a topological disc, the one shape
    // §6's Topological Contour is built for here (step 4). Class splits
    // survive only where they make discs (a fillet band around a hole).
    let merged_smooth = if opts.merge_smooth {
        merge_smooth(mesh, topo, &blocked, &sharp, &mut region)
    } else {
        0
    };
    // 3b. Dangling features: a sharp chain that fades out inside a region
    // (fandisk: the cone's side crease and the top crease) would be
    // rounded off, since only region boundaries become creases. The chain
    // is continued from each free end along the straightest path (a
    // smooth boundary, the "rectified" boundary of §4 following the
    // feature's direction) to the region's boundary or to another chain
    // anchored on it, or two tips are joined (see `extend_dangling`), and
    // the region is cut along chain + continuation: the feature then lies
    // on a boundary. With slits (every such chain hanging from its
    // region's boundary) the chains stay where they are instead.
    let slits = opts.slits && inside_chains_hang(topo, &sharp, &region);
    if !slits {
        extend_dangling(mesh, topo, &sharp, &mut region);
    }
    // 4. Disc-making splits.
    let splits = disc_splits(mesh, topo, opts.max_splits, &mut region);
    // 4b. Dangling features again, now that every region is a disc. Step
    // 3b's cut of a region that is not yet a disc need not separate it
    // along every chain: on block.ply a two-edge chain (30.5°) dangling
    // inside an annular region had both ends continued, one to each
    // boundary loop, so its cut did not separate (another chain's did) and
    // the chain stayed inside, rounded off 26‰ away from any crease. In a
    // disc a cut from boundary to boundary always separates, and every
    // part stays a disc (the cut graph touches the boundary). A no-op
    // when no sharp edge is left inside a region (fandisk, joint). A region
    // whose parts would not all be discs (two continuations meeting the
    // boundary at one vertex pinch it: spot forced through this mode) is
    // left as it is.
    if !slits {
        extend_dangling_in_discs(mesh, topo, &sharp, &mut region);
    }
    let num_regions = renumber(&mut region) as usize;
    let sharp_edges = sharp.iter().filter(|&&s| s).count();
    let sharp_edges_inside = topo
        .edges
        .iter()
        .enumerate()
        .filter(|(e, ed)| sharp[*e] && region[ed.faces[0] as usize] == region[ed.faces[1] as usize])
        .count();
    Segmentation {
        region,
        num_regions,
        sharp_edges,
        sharp_edges_inside,
        slits: slits && sharp_edges_inside > 0,
        splits,
        merged,
        merged_smooth,
    }
}

/// Steps 1–2 of [`segment`]: components over non-sharp edges (a region
/// never crosses a feature), cut where two curvature classes meet when
/// both class pieces are large ([`SegmentOptions::min_class_share`]):
/// §4's near-constant curvature, by class. Smaller pieces grow back into
/// their neighbours; a component without a large piece is one region.
fn class_regions(
    mesh: &TriMesh,
    topo: &Topology,
    curv: &[VertexCurvature],
    opts: &SegmentOptions,
    blocked: &dyn Fn(usize) -> bool,
) -> Vec<u32> {
    let nt = mesh.triangles.len();
    let diag = mesh.bbox_diagonal().max(f64::MIN_POSITIVE);
    // 1. Components over non-sharp edges.
    let comp = flood(nt, topo, |e| !blocked(e), None);
    let ncomp = comp.iter().copied().max().map_or(0, |m| m + 1) as usize;
    // 2. Curvature classes per triangle (majority of its vertices).
    let tclass: Vec<u8> = mesh
        .triangles
        .iter()
        .map(|t| {
            let mut votes = [0u8; 4];
            for &v in t {
                votes[class_of(&curv[v as usize], diag) as usize] += 1;
            }
            (0..4).max_by_key(|&k| (votes[k], 3 - k)).unwrap_or(0) as u8
        })
        .collect();
    let mut comp_size = vec![0usize; ncomp];
    for &c in &comp {
        comp_size[c as usize] += 1;
    }
    let sub = flood(
        nt,
        topo,
        |e| {
            let [f0, f1] = topo.edges[e].faces;
            !blocked(e) && tclass[f0 as usize] == tclass[f1 as usize]
        },
        Some(&comp),
    );
    let nsub = sub.iter().copied().max().map_or(0, |m| m + 1) as usize;
    let mut sub_size = vec![0usize; nsub];
    for &s in &sub {
        sub_size[s as usize] += 1;
    }
    // A class piece smaller than min_class_share of its component dissolves
    // into the component: regions are class pieces large enough, and the
    // rest of each component grows back over them.
    let mut region: Vec<u32> = (0..nt)
        .map(|t| {
            let s = sub[t] as usize;
            let c = comp[t] as usize;
            if (sub_size[s] as f64) >= opts.min_class_share * comp_size[c] as f64
                && sub_size[s] != comp_size[c]
            {
                s as u32
            } else {
                u32::MAX
            }
        })
        .collect();
    // Unassigned triangles: nearest assigned piece of the same component
    // (BFS over non-blocked edges); whole components without a large piece
    // become one region.
    grow_unassigned(&mut region, topo, blocked);
    let mut next = renumber(&mut region);
    for t in 0..nt {
        if region[t] == u32::MAX {
            let c = comp[t];
            // Flood this component's unassigned triangles into a new region.
            let mut q = VecDeque::from([t as u32]);
            region[t] = next;
            while let Some(f) = q.pop_front() {
                for &e in &topo.tri_edges[f as usize] {
                    if let Some(g) = topo.edges[e as usize].other_face(f) {
                        if region[g as usize] == u32::MAX && comp[g as usize] == c {
                            region[g as usize] = next;
                            q.push_back(g);
                        }
                    }
                }
            }
            next += 1;
        }
    }
    region
}

/// Step 3 of [`segment`]: a region smaller than `min_share` of M's area
/// merges into the neighbour it shares the longest non-blocked boundary
/// with, smallest first, one merge per pass; a region with no non-blocked
/// boundary (bounded by features only) is kept whatever its size, since
/// merging it would lose a feature. Returns the number of merges.
fn merge_small(
    mesh: &TriMesh,
    topo: &Topology,
    blocked: &dyn Fn(usize) -> bool,
    min_share: f64,
    region: &mut [u32],
) -> usize {
    let nt = region.len();
    let total_area: f64 = topo.face_areas.iter().sum();
    let mut merged = 0;
    loop {
        let nr = renumber(region) as usize;
        let mut area = vec![0.0; nr];
        for t in 0..nt {
            area[region[t] as usize] += topo.face_areas[t];
        }
        let mut order: Vec<usize> = (0..nr)
            .filter(|&r| area[r] < min_share * total_area)
            .collect();
        order.sort_by(|&a, &b| area[a].total_cmp(&area[b]).then(a.cmp(&b)));
        let mut done = true;
        for small in order {
            let mut shared: Vec<(u32, f64)> = Vec::new();
            for (e, ed) in topo.edges.iter().enumerate() {
                if blocked(e) {
                    continue;
                }
                let (r0, r1) = (region[ed.faces[0] as usize], region[ed.faces[1] as usize]);
                let other = if r0 as usize == small && r1 as usize != small {
                    r1
                } else if r1 as usize == small && r0 as usize != small {
                    r0
                } else {
                    continue;
                };
                let len =
                    (mesh.positions[ed.v[0] as usize] - mesh.positions[ed.v[1] as usize]).length();
                match shared.iter_mut().find(|s| s.0 == other) {
                    Some(s) => s.1 += len,
                    None => shared.push((other, len)),
                }
            }
            if let Some(o) = shared
                .iter()
                .max_by(|a, b| a.1.total_cmp(&b.1).then(b.0.cmp(&a.0)))
                .map(|s| s.0)
            {
                for r in region.iter_mut() {
                    if *r as usize == small {
                        *r = o;
                    }
                }
                merged += 1;
                done = false;
                break;
            }
        }
        if done {
            return merged;
        }
    }
}

/// Step 4 of [`segment`]: splits every region that is not a topological
/// disc in two ([`split_region`]) and tries the halves again, up to
/// `max_splits` splits over the whole mesh (§6.3.1 cuts a region with
/// holes into a disc; see the module docs). Returns the number of splits.
fn disc_splits(mesh: &TriMesh, topo: &Topology, max_splits: usize, region: &mut [u32]) -> usize {
    let nt = region.len();
    let mut splits = 0;
    let mut queue: Vec<u32> = (0..renumber(region)).collect();
    while let Some(r) = queue.pop() {
        let tris: Vec<u32> = (0..nt as u32)
            .filter(|&t| region[t as usize] == r)
            .collect();
        if tris.len() < 2 || is_disc(mesh, topo, region, r, &tris) || splits >= max_splits {
            continue;
        }
        let new = region.iter().copied().max().unwrap_or(0) + 1;
        if split_region(topo, region, r, new, &tris) {
            splits += 1;
            queue.push(r);
            queue.push(new);
        }
    }
    splits
}

/// Step 3a of [`segment`]: repeatedly merges the pair of regions with the
/// longest shared non-blocked boundary whose union is a disc; returns the
/// number of merges. Deterministic: pairs in (length, labels) order.
fn merge_smooth(
    mesh: &TriMesh,
    topo: &Topology,
    blocked: &dyn Fn(usize) -> bool,
    sharp: &[bool],
    region: &mut [u32],
) -> usize {
    let nt = region.len();
    let fading = fading_edges(topo, sharp);
    let mut merges = 0;
    loop {
        let nr = renumber(region) as usize;
        let mut tris: Vec<Vec<u32>> = vec![Vec::new(); nr];
        for t in 0..nt {
            tris[region[t] as usize].push(t as u32);
        }
        // Shared length per pair; a pair that also shares a blocked edge
        // (a feature) is never merged.
        let mut shared: std::collections::BTreeMap<(u32, u32), f64> = Default::default();
        let mut featured: std::collections::BTreeSet<(u32, u32)> = Default::default();
        for (e, ed) in topo.edges.iter().enumerate() {
            if !ed.is_interior() {
                continue;
            }
            let (a, b) = (region[ed.faces[0] as usize], region[ed.faces[1] as usize]);
            if a == b {
                continue;
            }
            let k = (a.min(b), a.max(b));
            if blocked(e) {
                if !fading[e] {
                    featured.insert(k);
                }
                continue;
            }
            let len =
                (mesh.positions[ed.v[0] as usize] - mesh.positions[ed.v[1] as usize]).length();
            *shared.entry(k).or_default() += len;
        }
        let mut pairs: Vec<((u32, u32), f64)> = shared
            .into_iter()
            .filter(|(k, _)| !featured.contains(k))
            .collect();
        pairs.sort_by(|x, y| y.1.total_cmp(&x.1).then(x.0.cmp(&y.0)));
        let mut done = true;
        for ((a, b), _) in pairs {
            let mut trial = region.to_vec();
            for &t in &tris[b as usize] {
                trial[t as usize] = a;
            }
            let mut union = tris[a as usize].clone();
            union.extend_from_slice(&tris[b as usize]);
            union.sort_unstable();
            if is_disc(mesh, topo, &trial, a, &union) {
                region.copy_from_slice(&trial);
                merges += 1;
                done = false;
                break;
            }
        }
        if done {
            return merges;
        }
    }
}

/// Sharp edges on a *fading* feature chain: followed through vertices with
/// exactly two sharp edges, the chain reaches a vertex with one (the
/// feature fades out inside a face of the part). Two regions meeting only
/// along such chains (and smooth boundaries) are merged by step 3a; step
/// 3b then cuts the union again along the features and their continuation,
/// which joins two fading tips when that is the shorter cut.
fn fading_edges(topo: &Topology, sharp: &[bool]) -> Vec<bool> {
    let sdeg = topo.sharp_degree(sharp);
    let mut out = vec![false; topo.edges.len()];
    let mut seen = vec![false; topo.edges.len()];
    for e0 in 0..topo.edges.len() {
        if !sharp[e0] || seen[e0] || !topo.edges[e0].is_interior() {
            continue;
        }
        // Walk the chain both ways from e0.
        let mut chain = vec![e0];
        seen[e0] = true;
        let mut free = false;
        for &start in &topo.edges[e0].v {
            let (mut v, mut e) = (start, e0);
            loop {
                if sdeg[v as usize] == 1 {
                    free = true;
                    break;
                }
                if sdeg[v as usize] != 2 {
                    break;
                }
                let Some(&n) = topo
                    .vertex_edges(v)
                    .iter()
                    .find(|&&f| f as usize != e && sharp[f as usize])
                else {
                    break;
                };
                let n = n as usize;
                if seen[n] || !topo.edges[n].is_interior() {
                    break;
                }
                seen[n] = true;
                chain.push(n);
                let ed = &topo.edges[n];
                v = if ed.v[0] == v { ed.v[1] } else { ed.v[0] };
                e = n;
            }
        }
        if free {
            for e in chain {
                out[e] = true;
            }
        }
    }
    out
}

/// See step 3b of [`segment`]. Each region with sharp edges inside is cut
/// at most once per chain end; a cut that does not separate the region
/// (the continuation could not reach the boundary) changes nothing.
fn extend_dangling(mesh: &TriMesh, topo: &Topology, sharp: &[bool], region: &mut [u32]) {
    let mut done_regions: HashSet<u32> = HashSet::new();
    loop {
        let Some(e0) = (0..topo.edges.len()).find(|&e| {
            inside_sharp(topo, sharp, region, e)
                && !done_regions.contains(&region[topo.edges[e].faces[0] as usize])
        }) else {
            return;
        };
        let r = region[topo.edges[e0].faces[0] as usize];
        done_regions.insert(r);
        let cut = Dangling::new(mesh, topo, sharp, region, r).cut();
        split_along(topo, region, r, &cut, &mut done_regions);
    }
}

/// A sharp edge of M with the same region on both sides: a feature that
/// the segmentation left inside a region, which would be rounded off.
fn inside_sharp(topo: &Topology, sharp: &[bool], region: &[u32], e: usize) -> bool {
    let ed = &topo.edges[e];
    sharp[e] && ed.is_interior() && region[ed.faces[0] as usize] == region[ed.faces[1] as usize]
}

/// The result of [`Dangling::search`]: the vertex reached (`None`: all of them, or
/// past the bound), path lengths and predecessors (vertex, edge).
type Search = (Option<u32>, HashMap<u32, f64>, HashMap<u32, (u32, usize)>);

/// The sharp chains inside one region `r` (step 3b of [`segment`]) and
/// the searches that cut `r` along them and their continuations.
struct Dangling<'a> {
    mesh: &'a TriMesh,
    topo: &'a Topology,
    region: &'a [u32],
    r: u32,
    /// The sharp edges inside `r`.
    chain: Vec<usize>,
    /// Those edges by vertex.
    deg: HashMap<u32, Vec<usize>>,
    chain_verts: HashSet<u32>,
    /// Free ends: chain vertices with one chain edge, not on `r`'s
    /// boundary, sorted.
    ends: Vec<u32>,
    ends_set: HashSet<u32>,
    /// Chain (connected component of the chain edges) of each chain vertex.
    chain_of: HashMap<u32, usize>,
    /// Per chain, whether it touches `r`'s boundary.
    anchored_chain: Vec<bool>,
}

impl<'a> Dangling<'a> {
    fn new(
        mesh: &'a TriMesh,
        topo: &'a Topology,
        sharp: &[bool],
        region: &'a [u32],
        r: u32,
    ) -> Self {
        let mut d = Dangling {
            mesh,
            topo,
            region,
            r,
            chain: Vec::new(),
            deg: HashMap::new(),
            chain_verts: HashSet::new(),
            ends: Vec::new(),
            ends_set: HashSet::new(),
            chain_of: HashMap::new(),
            anchored_chain: Vec::new(),
        };
        d.chain = (0..topo.edges.len())
            .filter(|&e| inside_sharp(topo, sharp, region, e) && d.in_r(topo.edges[e].faces[0]))
            .collect();
        for &e in &d.chain {
            for &v in &topo.edges[e].v {
                d.deg.entry(v).or_default().push(e);
            }
        }
        d.chain_verts = d.deg.keys().copied().collect();
        let mut ends: Vec<u32> = d
            .deg
            .iter()
            .filter(|(&v, es)| es.len() == 1 && !d.on_boundary(v))
            .map(|(&v, _)| v)
            .collect();
        ends.sort_unstable();
        d.ends_set = ends.iter().copied().collect();
        d.ends = ends;
        d.label_chains();
        d
    }

    fn in_r(&self, f: u32) -> bool {
        f != u32::MAX && self.region[f as usize] == self.r
    }

    /// Vertex on `r`'s boundary: an edge of `r` with another region (or no
    /// face) on its other side.
    fn on_boundary(&self, v: u32) -> bool {
        self.topo.vertex_edges(v).iter().any(|&e| {
            let [f0, f1] = self.topo.edges[e as usize].faces;
            (self.in_r(f0) || self.in_r(f1)) && !(self.in_r(f0) && self.in_r(f1))
        })
    }

    /// Chains: connected components of the inside-sharp edges, and
    /// whether each is anchored on the region boundary (a cut that
    /// reaches an anchored chain, a T-junction or a join of two anchored
    /// tips, reaches the boundary through it, so the region still falls
    /// apart).
    fn label_chains(&mut self) {
        let mut starts: Vec<u32> = self.deg.keys().copied().collect();
        starts.sort_unstable();
        for s0 in starts {
            if self.chain_of.contains_key(&s0) {
                continue;
            }
            let c = self.anchored_chain.len();
            let mut anchored = false;
            self.chain_of.insert(s0, c);
            let mut stack = vec![s0];
            while let Some(v) = stack.pop() {
                anchored |= self.on_boundary(v);
                for &e in &self.deg[&v] {
                    for &w in &self.topo.edges[e].v {
                        if let std::collections::hash_map::Entry::Vacant(x) = self.chain_of.entry(w)
                        {
                            x.insert(c);
                            stack.push(w);
                        }
                    }
                }
            }
            self.anchored_chain.push(anchored);
        }
    }

    fn anchored(&self, v: u32) -> bool {
        self.chain_of
            .get(&v)
            .is_some_and(|&c| self.anchored_chain[c])
    }

    /// The cut of `r`: its chains, joins of two anchored tips where they
    /// are shorter, and the straightest continuation of every other free
    /// end.
    fn cut(&self) -> HashSet<usize> {
        let mut cut: HashSet<usize> = self.chain.iter().copied().collect();
        let exts = self.continuations(&cut);
        let ext_len = |i: usize| exts[i].as_ref().map_or(f64::INFINITY, |x| x.0);
        let mut open = vec![true; self.ends.len()];
        for (l, i, j, p) in self.joins(&exts, &cut) {
            if open[i] && open[j] && l < ext_len(i) + ext_len(j) {
                cut.extend(p);
                open[i] = false;
                open[j] = false;
            }
        }
        for (i, x) in exts.iter().enumerate() {
            if let (true, Some((_, p))) = (open[i], x) {
                cut.extend(p.iter().copied());
            }
        }
        cut
    }

    /// Each free end's straightest continuation to the boundary (or to
    /// another anchored chain): its length and edges, `None` if the search
    /// reaches neither.
    fn continuations(&self, cut: &HashSet<usize>) -> Vec<Option<(f64, Vec<usize>)>> {
        self.ends
            .iter()
            .map(|&end| {
                let e = self.deg[&end][0];
                let ed = &self.topo.edges[e];
                let prev = if ed.v[0] == end { ed.v[1] } else { ed.v[0] };
                let p = &self.mesh.positions;
                let d = (p[end as usize] - p[prev as usize]).normalize_or_zero();
                let (reached, length, pred) = self.search(end, Some(d), f64::INFINITY, cut);
                reached.map(|v| (length[&v], path(&pred, end, v)))
            })
            .collect()
    }

    /// Two anchored features fading out towards each other are joined by
    /// their shortest path when it is shorter than the two continuations
    /// together: one cut closes the region the features bound, with the
    /// least new boundary (a curve and its control points) instead of
    /// two cuts running on to the boundary. The candidates, shortest
    /// first: `(length, end i, end j, edges)`. The search stops past the
    /// longest join that could still win.
    fn joins(
        &self,
        exts: &[Option<(f64, Vec<usize>)>],
        cut: &HashSet<usize>,
    ) -> Vec<(f64, usize, usize, Vec<usize>)> {
        let ext_len = |i: usize| exts[i].as_ref().map_or(f64::INFINITY, |x| x.0);
        let longest = (0..self.ends.len()).map(ext_len).fold(0.0, f64::max);
        let mut joins: Vec<(f64, usize, usize, Vec<usize>)> = Vec::new();
        for (i, &a) in self.ends.iter().enumerate() {
            if !self.anchored(a) {
                continue;
            }
            let (_, length, pred) = self.search(a, None, ext_len(i) + longest, cut);
            for (j, &b) in self.ends.iter().enumerate().skip(i + 1) {
                if self.chain_of.get(&a) == self.chain_of.get(&b) || !self.anchored(b) {
                    continue;
                }
                if let Some(&l) = length.get(&b) {
                    joins.push((l, i, j, path(&pred, a, b)));
                }
            }
        }
        joins.sort_by(|x, y| x.0.total_cmp(&y.0).then((x.1, x.2).cmp(&(y.1, y.2))));
        joins
    }

    /// Dijkstra over r's edges from `start`, through no chain vertex but
    /// the free ends. With a direction `d` (the straightest
    /// continuation): cost = length × (2 − cos)², so going straight on
    /// costs 1 per unit, sideways 4, backwards 9, and the search stops at
    /// the first vertex on the boundary or on another anchored chain.
    /// Without (joins): plain length, never through the boundary.
    fn search(&self, start: u32, d: Option<DVec3>, bound: f64, cut: &HashSet<usize>) -> Search {
        let (topo, mesh) = (self.topo, self.mesh);
        let own = self.chain_of.get(&start).copied();
        let is_target_chain = |w: u32| {
            self.chain_of
                .get(&w)
                .is_some_and(|&c| Some(c) != own && self.anchored_chain[c])
                && !self.ends_set.contains(&w)
        };
        let mut cost: HashMap<u32, f64> = HashMap::new();
        let mut length: HashMap<u32, f64> = HashMap::new();
        let mut pred: HashMap<u32, (u32, usize)> = HashMap::new();
        let mut heap = BinaryHeap::new();
        cost.insert(start, 0.0);
        length.insert(start, 0.0);
        heap.push((Reverse(OrdF(0.0)), start));
        while let Some((Reverse(OrdF(du)), u)) = heap.pop() {
            if du > cost.get(&u).copied().unwrap_or(f64::INFINITY) {
                continue;
            }
            if du > bound {
                break;
            }
            // A continuation ends on the region boundary or on another
            // feature chain (a T-junction: the cut closes there).
            if u != start && (self.on_boundary(u) || (d.is_some() && is_target_chain(u))) {
                if d.is_some() {
                    return (Some(u), length, pred);
                }
                continue;
            }
            if u != start && self.ends_set.contains(&u) {
                continue;
            }
            for &e in topo.vertex_edges(u) {
                let ed = &topo.edges[e as usize];
                if !(self.in_r(ed.faces[0]) || self.in_r(ed.faces[1]))
                    || cut.contains(&(e as usize))
                {
                    continue;
                }
                let w = if ed.v[0] == u { ed.v[1] } else { ed.v[0] };
                if self.chain_verts.contains(&w)
                    && !(d.is_none() && self.ends_set.contains(&w))
                    && !(d.is_some() && is_target_chain(w))
                {
                    continue;
                }
                let step = mesh.positions[w as usize] - mesh.positions[u as usize];
                let len = step.length();
                let nd = du
                    + match d {
                        Some(d) => len * (2.0 - step.normalize_or_zero().dot(d)).powi(2),
                        None => len,
                    };
                if nd < cost.get(&w).copied().unwrap_or(f64::INFINITY) {
                    cost.insert(w, nd);
                    length.insert(w, length[&u] + len);
                    pred.insert(w, (u, e as usize));
                    heap.push((Reverse(OrdF(nd)), w));
                }
            }
        }
        (None, length, pred)
    }
}

/// The edges of the search path from `from` to `v` (`pred`: predecessor
/// vertex and edge of each vertex reached).
fn path(pred: &HashMap<u32, (u32, usize)>, from: u32, mut v: u32) -> Vec<usize> {
    let mut edges = Vec::new();
    while v != from {
        let (u, e) = pred[&v];
        edges.push(e);
        v = u;
    }
    edges
}

/// Splits region `r` along `cut` (step 3b): its triangles connected
/// across no cut edge; the first part keeps `r`, the others get new
/// labels, marked done (each was cut already). Nothing changes if the cut
/// does not separate `r`.
fn split_along(
    topo: &Topology,
    region: &mut [u32],
    r: u32,
    cut: &HashSet<usize>,
    done_regions: &mut HashSet<u32>,
) {
    let nt = region.len();
    let tris: Vec<usize> = (0..nt).filter(|&t| region[t] == r).collect();
    let mut label: HashMap<usize, u32> = HashMap::new();
    let mut ncomp = 0u32;
    for &s in &tris {
        if label.contains_key(&s) {
            continue;
        }
        let mut q = vec![s];
        label.insert(s, ncomp);
        while let Some(f) = q.pop() {
            for &e in &topo.tri_edges[f] {
                if cut.contains(&(e as usize)) {
                    continue;
                }
                if let Some(g) = topo.edges[e as usize].other_face(f as u32) {
                    let g = g as usize;
                    if region[g] == r && !label.contains_key(&g) {
                        label.insert(g, ncomp);
                        q.push(g);
                    }
                }
            }
        }
        ncomp += 1;
    }
    if ncomp < 2 {
        return;
    }
    let base = region
        .iter()
        .filter(|&&x| x != u32::MAX)
        .copied()
        .max()
        .unwrap_or(0)
        + 1;
    for &t in &tris {
        let c = label[&t];
        if c > 0 {
            region[t] = base + c - 1;
            done_regions.insert(base + c - 1);
        }
    }
}

/// Whether every connected chain of sharp edges inside a region touches
/// that region's boundary ([`SegmentOptions::slits`]): such a chain is a
/// slit of its region's boundary loop, where a chain floating inside would
/// be a second loop (a hole), which the polyhedron stage does not build.
fn inside_chains_hang(topo: &Topology, sharp: &[bool], region: &[u32]) -> bool {
    let side = |f: u32| {
        if f == u32::MAX {
            u32::MAX
        } else {
            region[f as usize]
        }
    };
    let inside = |e: usize| {
        let ed = &topo.edges[e];
        sharp[e] && ed.is_interior() && side(ed.faces[0]) == side(ed.faces[1])
    };
    let on_boundary = |v: u32| {
        topo.vertex_edges(v).iter().any(|&e| {
            let [f0, f1] = topo.edges[e as usize].faces;
            side(f0) != side(f1)
        })
    };
    let mut seen = vec![false; topo.edges.len()];
    for e0 in 0..topo.edges.len() {
        if seen[e0] || !inside(e0) {
            continue;
        }
        seen[e0] = true;
        let mut stack = vec![e0];
        let mut anchored = false;
        while let Some(e) = stack.pop() {
            for &v in &topo.edges[e].v {
                anchored |= on_boundary(v);
                for &f in topo.vertex_edges(v) {
                    let f = f as usize;
                    if !seen[f] && inside(f) {
                        seen[f] = true;
                        stack.push(f);
                    }
                }
            }
        }
        if !anchored {
            return false;
        }
    }
    true
}

/// Step 4b of [`segment`]: [`extend_dangling`] on the (disc) regions, each
/// region's cut kept only if every part it makes is a disc.
fn extend_dangling_in_discs(mesh: &TriMesh, topo: &Topology, sharp: &[bool], region: &mut [u32]) {
    let mut trial = region.to_vec();
    extend_dangling(mesh, topo, sharp, &mut trial);
    if trial == region {
        return;
    }
    // Parts of each old region (the labels a cut gives are new, so parts
    // of different regions never share one).
    let mut parts: std::collections::BTreeMap<u32, std::collections::BTreeMap<u32, Vec<u32>>> =
        Default::default();
    for (t, (&old, &new)) in region.iter().zip(&trial).enumerate() {
        parts
            .entry(old)
            .or_default()
            .entry(new)
            .or_default()
            .push(t as u32);
    }
    for (_, ps) in parts {
        if ps.len() < 2 || !ps.iter().all(|(&l, ts)| is_disc(mesh, topo, &trial, l, ts)) {
            continue;
        }
        for (&l, ts) in &ps {
            for &t in ts {
                region[t as usize] = l;
            }
        }
    }
}

/// Connected components of triangles over edges where `pass(e)`, within
/// the same `within` label when given.
fn flood(
    nt: usize,
    topo: &Topology,
    pass: impl Fn(usize) -> bool,
    within: Option<&[u32]>,
) -> Vec<u32> {
    let mut label = vec![u32::MAX; nt];
    let mut next = 0;
    let mut q = VecDeque::new();
    for s in 0..nt {
        if label[s] != u32::MAX {
            continue;
        }
        label[s] = next;
        q.push_back(s as u32);
        while let Some(f) = q.pop_front() {
            for &e in &topo.tri_edges[f as usize] {
                if !pass(e as usize) {
                    continue;
                }
                if let Some(g) = topo.edges[e as usize].other_face(f) {
                    if label[g as usize] == u32::MAX
                        && within.map_or(true, |w| w[g as usize] == w[f as usize])
                    {
                        label[g as usize] = next;
                        q.push_back(g);
                    }
                }
            }
        }
        next += 1;
    }
    label
}

fn grow_unassigned(region: &mut [u32], topo: &Topology, blocked: &dyn Fn(usize) -> bool) {
    let mut q: VecDeque<u32> = (0..region.len() as u32)
        .filter(|&t| region[t as usize] != u32::MAX)
        .collect();
    while let Some(f) = q.pop_front() {
        for &e in &topo.tri_edges[f as usize] {
            if blocked(e as usize) {
                continue;
            }
            if let Some(g) = topo.edges[e as usize].other_face(f) {
                if region[g as usize] == u32::MAX {
                    region[g as usize] = region[f as usize];
                    q.push_back(g);
                }
            }
        }
    }
}

/// Renumbers labels densely in order of first appearance (`u32::MAX`
/// kept); returns the count.
fn renumber(region: &mut [u32]) -> u32 {
    let mut map: std::collections::HashMap<u32, u32> = std::collections::HashMap::new();
    let mut next = 0;
    for r in region.iter_mut() {
        if *r == u32::MAX {
            continue;
        }
        *r = *map.entry(*r).or_insert_with(|| {
            next += 1;
            next - 1
        });
    }
    next
}

/// One boundary loop and Euler characteristic 1.
fn is_disc(mesh: &TriMesh, topo: &Topology, region: &[u32], r: u32, tris: &[u32]) -> bool {
    let mut verts: Vec<u32> = tris
        .iter()
        .flat_map(|&t| mesh.triangles[t as usize])
        .collect();
    verts.sort_unstable();
    verts.dedup();
    let mut edges: Vec<u32> = tris
        .iter()
        .flat_map(|&t| topo.tri_edges[t as usize])
        .collect();
    edges.sort_unstable();
    edges.dedup();
    let chi = verts.len() as i64 - edges.len() as i64 + tris.len() as i64;
    if chi != 1 {
        return false;
    }
    // Boundary edges of the region: exactly one side in it. One loop iff
    // every boundary vertex has exactly two boundary edges and they form a
    // single cycle (with χ = 1 and manifold vertices, loops = 1 follows
    // from χ unless a vertex is pinched).
    let on_b: Vec<u32> = edges
        .iter()
        .copied()
        .filter(|&e| {
            let ed = &topo.edges[e as usize];
            let inside = |f: u32| f != u32::MAX && region[f as usize] == r;
            !(ed.is_interior() && inside(ed.faces[0]) && inside(ed.faces[1]))
        })
        .collect();
    let mut deg: std::collections::HashMap<u32, u32> = std::collections::HashMap::new();
    for &e in &on_b {
        for &v in &topo.edges[e as usize].v {
            *deg.entry(v).or_default() += 1;
        }
    }
    !on_b.is_empty() && deg.values().all(|&d| d == 2)
}

/// Geodesic (BFS over the dual graph) Voronoi split of region `r` between
/// its two mutually farthest triangles; the second half gets label `new`.
fn split_region(topo: &Topology, region: &mut [u32], r: u32, new: u32, tris: &[u32]) -> bool {
    let bfs = |seeds: &[u32], region: &[u32]| -> (Vec<u32>, Vec<u32>) {
        let mut dist = std::collections::HashMap::new();
        let mut owner = std::collections::HashMap::new();
        let mut q = VecDeque::new();
        for (i, &s) in seeds.iter().enumerate() {
            dist.insert(s, 0u32);
            owner.insert(s, i as u32);
            q.push_back(s);
        }
        while let Some(f) = q.pop_front() {
            let d = dist[&f];
            let o = owner[&f];
            for &e in &topo.tri_edges[f as usize] {
                if let Some(g) = topo.edges[e as usize].other_face(f) {
                    if region[g as usize] == r && !dist.contains_key(&g) {
                        dist.insert(g, d + 1);
                        owner.insert(g, o);
                        q.push_back(g);
                    }
                }
            }
        }
        let ds = tris
            .iter()
            .map(|t| dist.get(t).copied().unwrap_or(u32::MAX))
            .collect();
        let os = tris
            .iter()
            .map(|t| owner.get(t).copied().unwrap_or(0))
            .collect();
        (ds, os)
    };
    let far = |d: &[u32]| -> u32 {
        let mut best = 0;
        for i in 0..tris.len() {
            if d[i] != u32::MAX && d[i] > d[best] {
                best = i;
            }
        }
        tris[best]
    };
    let (d0, _) = bfs(&[tris[0]], region);
    let a = far(&d0);
    let (d1, _) = bfs(&[a], region);
    let b = far(&d1);
    if a == b {
        return false;
    }
    let (_, own) = bfs(&[a, b], region);
    let mut changed = false;
    for (i, &t) in tris.iter().enumerate() {
        if own[i] == 1 {
            region[t as usize] = new;
            changed = true;
        }
    }
    changed
}
