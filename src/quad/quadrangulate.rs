//! Triangles to quads on the same vertex set (Fitmaps §3.2, after Tarini et
//! al. 2010, "Practical quad mesh simplification", §4).
//!
//! Pairs of triangles that share an edge become one quad whose diagonal is
//! the removed edge. The pairing is a matching in the dual graph:
//!
//! 1. **greedy** — candidate pairs sorted by a shape cost (largest deviation
//!    of a corner angle from 90° plus a weighted dihedral angle between the
//!    two triangles), taken while both triangles are free;
//! 2. **augmenting paths** — Edmonds' blossom search from every triangle the
//!    greedy pass left over, until the matching is maximum. On a closed
//!    manifold triangle mesh the dual graph is cubic and bridgeless (every
//!    dual edge lies on the cycle of faces around a vertex), so a perfect
//!    matching exists (Petersen 1891): no triangle is left over;
//! 3. **parity fixes** — on open meshes a maximum matching can leave
//!    triangles over. A pure quad mesh with the same boundary cannot exist
//!    when the number of boundary edges is odd (4F = 2E_int + E_bnd), so each
//!    leftover is moved along an alternating path (the matching keeps its
//!    size) to the nearest triangle with a boundary edge, which is then split
//!    into quads by inserting a vertex on that boundary edge (see
//!    [`ParityFixKind`]).
//!
//! Vertex numbering: the input vertices keep their order; vertices used by no
//! triangle are dropped (a control mesh cannot hold them) and
//! [`Quadrangulation::vertex_map`] says where every input vertex went; the
//! vertices created by parity fixes are appended after them.

use std::ops::Range;

use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::mesh::{ControlMesh, EdgeId, HalfedgeId, TriMesh, VertexId};
use crate::quad::matching::{shift_hole, Graph, Matcher, NONE};
use crate::DVec3;

/// Options of [`quadrangulate`].
#[derive(Clone, Debug)]
#[non_exhaustive]
pub struct QuadrangulateOptions {
    /// Weight of the dihedral angle (radians) against the angle deviation
    /// (radians) in the greedy pairing cost. Tarini et al. rate quads by
    /// both squareness and planarity; 0.5 keeps squareness the main term.
    pub planarity_weight: f64,
    /// Leave non-convex pairs (an angle ≥ 180° at an end of the diagonal)
    /// out of the greedy pass. The augmenting pass may still use them where
    /// a perfect matching needs them; the report counts them.
    pub greedy_convex_only: bool,
}

impl Default for QuadrangulateOptions {
    fn default() -> Self {
        QuadrangulateOptions {
            planarity_weight: 0.5,
            greedy_convex_only: true,
        }
    }
}

impl QuadrangulateOptions {
    pub fn with_planarity_weight(mut self, w: f64) -> Self {
        self.planarity_weight = w;
        self
    }
    pub fn with_greedy_convex_only(mut self, on: bool) -> Self {
        self.greedy_convex_only = on;
        self
    }
}

/// Shape of one quad `(q0, q1, q2, q3)` seen as the two triangles
/// `(q0, q1, q2)` and `(q0, q2, q3)` sharing the diagonal `q0–q2`.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct QuadQuality {
    /// Largest |corner angle − 90°|, degrees. The angles at the diagonal ends
    /// are *developed* (sum of the two triangle angles), so a folded quad is
    /// not mistaken for a square one.
    pub max_angle_deviation_deg: f64,
    /// Angle between the normals of the two triangles, degrees (0 = planar).
    pub dihedral_deg: f64,
    /// Both developed angles at the diagonal ends are below 180°.
    pub convex: bool,
}

/// Quality of the quad `q`, see [`QuadQuality`].
pub fn quad_quality(q: [DVec3; 4]) -> QuadQuality {
    let ang = |o: DVec3, a: DVec3, b: DVec3| {
        let (u, v) = (a - o, b - o);
        u.cross(v).length().atan2(u.dot(v))
    };
    let [q0, q1, q2, q3] = q;
    let a0 = ang(q0, q1, q2) + ang(q0, q2, q3);
    let a2 = ang(q2, q3, q0) + ang(q2, q0, q1);
    let a1 = ang(q1, q2, q0);
    let a3 = ang(q3, q0, q2);
    let half_pi = std::f64::consts::FRAC_PI_2;
    let dev = [a0, a1, a2, a3]
        .iter()
        .map(|a| (a - half_pi).abs())
        .fold(0.0, f64::max);
    let n1 = (q1 - q0).cross(q2 - q0);
    let n2 = (q2 - q0).cross(q3 - q0);
    let dihedral = n1.cross(n2).length().atan2(n1.dot(n2));
    // 1e-9 rad of slack: a pair of coplanar right triangles has exactly 180°
    // nowhere, but rounding must not flip a genuinely convex quad.
    let straight = std::f64::consts::PI - 1e-9;
    QuadQuality {
        max_angle_deviation_deg: dev.to_degrees(),
        dihedral_deg: dihedral.to_degrees(),
        convex: a0 < straight && a2 < straight,
    }
}

/// Where a quad of the output comes from; triangle indices are those of the
/// input [`TriMesh`].
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum QuadSource {
    /// The union of two triangles; the quad's diagonal `q0–q2` is their
    /// shared edge, and `q0 → q1 → q2` runs along the first triangle.
    Pair([u32; 2]),
    /// One of the quads a parity fix cut the triangle into.
    Split { triangle: u32 },
}

/// How a leftover triangle was turned into quads.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum ParityFixKind {
    /// The triangle `(a, b, c)` has the boundary edge `a–b`: insert its
    /// midpoint `m` (a new boundary vertex) and cut the quad `(a, m, b, c)`
    /// Catmull-Clark style into an inner quad and four ring quads (four new
    /// interior vertices, all of valence 3; `m` gets valence 3 like any
    /// regular boundary vertex). Five new vertices, five quads. A two-quad
    /// cut would do with fewer vertices but needs an interior vertex of
    /// valence 2, which the simplification must then remove again.
    BoundaryEdgeSplit {
        /// The split boundary edge, as input vertex indices.
        edge: [u32; 2],
    },
    /// A triangle whose three edges are all on the boundary (an isolated
    /// triangle): the Catmull-Clark 1→3 split, four new vertices (three
    /// boundary midpoints and the centroid), three quads.
    IsolatedTriangleSplit,
}

/// One parity fix, see [`ParityFixKind`].
#[derive(Clone, Debug, PartialEq)]
pub struct ParityFix {
    /// The input triangle that was split.
    pub triangle: u32,
    /// The triangle that was left over by the maximum matching, before it
    /// was moved to the boundary.
    pub leftover: u32,
    /// Matched pairs swapped to bring the leftover to the boundary.
    pub path_length: usize,
    pub kind: ParityFixKind,
    /// Appended control vertices.
    pub new_vertices: Vec<VertexId>,
    /// The output quads that replace the triangle.
    pub quads: Range<usize>,
}

/// Summary statistics of one quality measure over all quads, degrees.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct QualityStats {
    pub mean: f64,
    pub p50: f64,
    pub p90: f64,
    pub p99: f64,
    pub max: f64,
    /// Counts per 10° bin: `[0, 10)`, `[10, 20)`, …, the last bin `≥ 80`.
    pub histogram_10deg: [usize; 9],
}

impl QualityStats {
    fn from_values(mut v: Vec<f64>) -> Self {
        let mut histogram_10deg = [0; 9];
        for &x in &v {
            histogram_10deg[((x / 10.0).floor().max(0.0) as usize).min(8)] += 1;
        }
        if v.is_empty() {
            return QualityStats {
                mean: 0.0,
                p50: 0.0,
                p90: 0.0,
                p99: 0.0,
                max: 0.0,
                histogram_10deg,
            };
        }
        v.sort_by(f64::total_cmp);
        let pct = |p: f64| v[((p * (v.len() - 1) as f64).round() as usize).min(v.len() - 1)];
        QualityStats {
            mean: v.iter().sum::<f64>() / v.len() as f64,
            p50: pct(0.5),
            p90: pct(0.9),
            p99: pct(0.99),
            max: v[v.len() - 1],
            histogram_10deg,
        }
    }
}

impl std::fmt::Display for QualityStats {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "mean {:.1}° p50 {:.1}° p90 {:.1}° p99 {:.1}° max {:.1}° hist/10° {:?}",
            self.mean, self.p50, self.p90, self.p99, self.max, self.histogram_10deg
        )
    }
}

/// What [`quadrangulate`] did.
#[derive(Clone, Debug, PartialEq)]
pub struct QuadrangulationReport {
    pub num_triangles: usize,
    /// Quads made from two triangles.
    pub num_pairs: usize,
    /// Pairs taken by the greedy pass (before augmentation).
    pub greedy_pairs: usize,
    /// Augmenting paths applied after the greedy pass.
    pub augmentations: usize,
    /// Triangles left over by the maximum matching (each got a parity fix).
    pub leftover_triangles: usize,
    pub parity_fixes: Vec<ParityFix>,
    /// Input vertices used by no triangle, dropped from the control mesh.
    pub unreferenced_vertices_removed: usize,
    /// Per-quad largest |angle − 90°|.
    pub angle_deviation: QualityStats,
    /// Per-quad dihedral between its two triangles.
    pub dihedral: QualityStats,
    pub non_convex_quads: usize,
}

/// The result of [`quadrangulate`].
#[derive(Clone, Debug)]
pub struct Quadrangulation {
    /// Pure quad mesh, orientation of the input triangles.
    pub mesh: ControlMesh,
    /// Per output quad: where it comes from.
    pub sources: Vec<QuadSource>,
    /// Per output quad: its shape.
    pub quality: Vec<QuadQuality>,
    /// Per input vertex: its control vertex (`None`: used by no triangle).
    pub vertex_map: Vec<Option<VertexId>>,
    pub report: QuadrangulationReport,
}

/// Turns a manifold, consistently oriented triangle mesh into a pure quad
/// control mesh on the same vertices (plus the few parity-fix vertices on
/// open meshes, appended). Deterministic. Fails with the offending element
/// on out-of-range indices, degenerate (repeated-vertex) triangles,
/// non-manifold edges or vertices, inconsistent orientation, and non-finite
/// coordinates.
///
/// The steps are those of the module docs (Fitmaps §3.2): candidate pairs
/// ([`pair_candidates`]), greedy pairing ([`greedy_pairing`]), augmenting
/// paths over the candidate graph ([`candidate_graph`]), the leftovers
/// moved to the boundary ([`shift_leftovers`]) and split there
/// ([`parity_fix`]).
pub fn quadrangulate(mesh: &TriMesh, opts: &QuadrangulateOptions) -> Result<Quadrangulation> {
    quadrangulate_polled(mesh, opts, &mut || Ok(()))
}

/// [`quadrangulate`], calling `poll` between its steps (an `Err` from it,
/// a cancellation, ends the call): the simplifier's set-up stays
/// cancellable on a million triangles.
pub(crate) fn quadrangulate_polled(
    mesh: &TriMesh,
    opts: &QuadrangulateOptions,
    poll: &mut dyn FnMut() -> Result<()>,
) -> Result<Quadrangulation> {
    if mesh.triangles.is_empty() {
        return Err(Error::invalid_data(
            "input mesh",
            "mesh",
            "has no triangles to quadrangulate",
        ));
    }
    let (vertex_map, mut positions, tris) = compact_vertices(mesh)?;
    let unreferenced = mesh.positions.len() - positions.len();
    // The triangle mesh as a half-edge mesh: validates manifoldness and
    // orientation, and gives the dual graph (face ids = triangle indices).
    poll()?;
    let tm = ControlMesh::from_polygons(positions.clone(), &tris)?;
    poll()?;
    let nt = tris.len();

    let cands = pair_candidates(&tm, opts);
    poll()?;
    let (order, mate, greedy_pairs) = greedy_pairing(&cands, nt, opts);
    poll()?;
    let graph = candidate_graph(&cands, &order, nt);
    poll()?;
    let mut matcher = Matcher::new(&graph, mate);
    let augmentations = matcher.maximise();
    poll()?;
    let mut mate = matcher.mate;
    let (leftovers, holes) = shift_leftovers(&tm, &graph, &mut mate)?;
    poll()?;

    // Output: pair quads in the order of their lower triangle, then the
    // parity-fix quads.
    let mut quads: Vec<[u32; 4]> = Vec::with_capacity(nt / 2 + 5 * holes.len());
    let mut sources = Vec::with_capacity(quads.capacity());
    for t in 0..nt as u32 {
        let m = mate[t as usize];
        if m == NONE || m < t {
            continue;
        }
        let h = tm
            .face_halfedges(crate::mesh::FaceId(t))
            .find(|&h| tm.face_of(h.twin()).map(|f| f.0) == Some(m))
            .expect("matched triangles share an edge");
        quads.push(pair_quad(&tm, h).map(|v| v.0));
        sources.push(QuadSource::Pair([t, m]));
    }
    let num_pairs = quads.len();
    let mut parity_fixes = Vec::with_capacity(holes.len());
    for (leftover, t, path_length) in holes {
        let first = quads.len();
        let (kind, new_vertices) =
            parity_fix(&tm, mesh, &vertex_map, &mut positions, &mut quads, t);
        for _ in first..quads.len() {
            sources.push(QuadSource::Split { triangle: t });
        }
        parity_fixes.push(ParityFix {
            triangle: t,
            leftover,
            path_length,
            kind,
            new_vertices,
            quads: first..quads.len(),
        });
    }

    let quality: Vec<QuadQuality> = quads
        .par_iter()
        .map(|q| quad_quality(q.map(|v| positions[v as usize])))
        .collect();
    poll()?;
    let out = ControlMesh::from_polygons(positions, &quads)?;
    let report = QuadrangulationReport {
        num_triangles: nt,
        num_pairs,
        greedy_pairs,
        augmentations,
        leftover_triangles: leftovers.len(),
        parity_fixes,
        unreferenced_vertices_removed: unreferenced,
        angle_deviation: QualityStats::from_values(
            quality.iter().map(|q| q.max_angle_deviation_deg).collect(),
        ),
        dihedral: QualityStats::from_values(quality.iter().map(|q| q.dihedral_deg).collect()),
        non_convex_quads: quality.iter().filter(|q| !q.convex).count(),
    };
    Ok(Quadrangulation {
        mesh: out,
        sources,
        quality,
        vertex_map,
        report,
    })
}

/// A candidate pair (Fitmaps §3.2): the shared edge, the two triangles,
/// the quad's shape and its cost.
type Candidate = (EdgeId, u32, u32, QuadQuality, f64);

/// A leftover triangle moved to a boundary triangle: (leftover, target,
/// alternating-path length).
type Hole = (u32, u32, usize);

/// Compacts away the vertices no triangle uses, keeping the order of the
/// others (a control mesh cannot hold an isolated vertex): the map from
/// input vertices, the kept positions and the renumbered triangles. Fails
/// on an out-of-range index.
#[allow(clippy::type_complexity)]
fn compact_vertices(mesh: &TriMesh) -> Result<(Vec<Option<VertexId>>, Vec<DVec3>, Vec<[u32; 3]>)> {
    let nv_in = mesh.positions.len();
    let mut used = vec![false; nv_in];
    for (t, tri) in mesh.triangles.iter().enumerate() {
        for &v in tri {
            if v as usize >= nv_in {
                return Err(Error::topology(
                    format!("triangle {t}"),
                    format!("vertex index {v} out of range (the mesh has {nv_in} vertices)"),
                ));
            }
            used[v as usize] = true;
        }
    }
    let mut vertex_map = vec![None; nv_in];
    let mut positions = Vec::with_capacity(nv_in);
    for v in 0..nv_in {
        if used[v] {
            vertex_map[v] = Some(VertexId(positions.len() as u32));
            positions.push(mesh.positions[v]);
        }
    }
    let tris: Vec<[u32; 3]> = mesh
        .triangles
        .iter()
        .map(|t| t.map(|v| vertex_map[v as usize].expect("referenced").0))
        .collect();
    Ok((vertex_map, positions, tris))
}

/// Candidate pairs: interior edges whose two triangles form a quad with
/// four distinct corners (two triangles sharing all three vertices would
/// not), with the shape cost of the module docs. In edge order.
fn pair_candidates(tm: &ControlMesh, opts: &QuadrangulateOptions) -> Vec<Candidate> {
    (0..tm.num_edges() as u32)
        .into_par_iter()
        .filter_map(|e| {
            let e = EdgeId(e);
            let h = e.halfedge();
            let (f1, f2) = (tm.face_of(h)?, tm.face_of(h.twin())?);
            let q = pair_quad(tm, h);
            if q[1] == q[3] {
                return None;
            }
            let qual = quad_quality(q.map(|v| tm.position(v)));
            let cost = qual.max_angle_deviation_deg.to_radians()
                + opts.planarity_weight * qual.dihedral_deg.to_radians();
            Some((e, f1.0, f2.0, qual, cost))
        })
        .collect()
}

/// Step 1, greedy pairing by increasing cost (ties by edge id:
/// deterministic): the candidates in cost order, the matching
/// (`mate[t]`, [`NONE`] when free) and how many pairs it took.
fn greedy_pairing(
    cands: &[Candidate],
    nt: usize,
    opts: &QuadrangulateOptions,
) -> (Vec<usize>, Vec<u32>, usize) {
    let mut order: Vec<usize> = (0..cands.len()).collect();
    order.sort_by(|&i, &j| cands[i].4.total_cmp(&cands[j].4).then(i.cmp(&j)));
    let mut mate = vec![NONE; nt];
    let mut greedy_pairs = 0;
    for &i in &order {
        let (_, a, b, q, _) = cands[i];
        if (opts.greedy_convex_only && !q.convex)
            || mate[a as usize] != NONE
            || mate[b as usize] != NONE
        {
            continue;
        }
        mate[a as usize] = b;
        mate[b as usize] = a;
        greedy_pairs += 1;
    }
    (order, mate, greedy_pairs)
}

/// Step 2's graph: the dual graph restricted to the candidates, each
/// neighbour list sorted by cost (`order`), so that the breadth-first
/// searches of the augmenting paths try the better-shaped pairs first.
fn candidate_graph(cands: &[Candidate], order: &[usize], nt: usize) -> Graph {
    let mut rank = vec![0u32; cands.len()];
    for (r, &i) in order.iter().enumerate() {
        rank[i] = r as u32;
    }
    let mut lists: Vec<Vec<(u32, u32)>> = vec![Vec::new(); nt];
    for (i, &(_, a, b, _, _)) in cands.iter().enumerate() {
        lists[a as usize].push((rank[i], b));
        lists[b as usize].push((rank[i], a));
    }
    let mut off = Vec::with_capacity(nt + 1);
    let mut adj = Vec::with_capacity(2 * cands.len());
    off.push(0u32);
    for l in &mut lists {
        l.sort_unstable();
        adj.extend(l.iter().map(|&(_, n)| n));
        off.push(adj.len() as u32);
    }
    Graph { off, adj }
}

/// Step 3, first half: each triangle a maximum matching leaves over is
/// moved along an alternating path to a triangle with a boundary edge
/// (the matching keeps its size). Returns the leftovers and, per
/// leftover, where it went; fails where no path reaches the boundary.
fn shift_leftovers(
    tm: &ControlMesh,
    graph: &Graph,
    mate: &mut [u32],
) -> Result<(Vec<u32>, Vec<Hole>)> {
    let leftovers: Vec<u32> = (0..mate.len() as u32)
        .filter(|&t| mate[t as usize] == NONE)
        .collect();
    let mut holes = Vec::with_capacity(leftovers.len());
    for &t in &leftovers {
        let (target, steps) = shift_hole(graph, mate, t, |x| {
            tm.face_halfedges(crate::mesh::FaceId(x))
                .any(|h| tm.is_boundary_halfedge(h.twin()))
        })
        .ok_or_else(|| {
            Error::topology(
                format!("triangle {t}"),
                "cannot be paired into a quad and no alternating path reaches a boundary \
                 triangle where the parity could be fixed",
            )
        })?;
        holes.push((t, target, steps));
    }
    Ok((leftovers, holes))
}

/// Step 3, second half: splits the boundary triangle `t` into quads (see
/// [`ParityFixKind`]), appending the new vertices to `positions` and the
/// quads to `quads`; returns the kind of split and the new vertices.
fn parity_fix(
    tm: &ControlMesh,
    mesh: &TriMesh,
    vertex_map: &[Option<VertexId>],
    positions: &mut Vec<DVec3>,
    quads: &mut Vec<[u32; 4]>,
    t: u32,
) -> (ParityFixKind, Vec<VertexId>) {
    let bnd: Vec<HalfedgeId> = tm
        .face_halfedges(crate::mesh::FaceId(t))
        .filter(|&h| tm.is_boundary_halfedge(h.twin()))
        .collect();
    let mut new_vertices = Vec::new();
    let mut add = |p: DVec3, positions: &mut Vec<DVec3>| {
        let id = positions.len() as u32;
        positions.push(p);
        new_vertices.push(VertexId(id));
        id
    };
    let kind = if bnd.len() == 3 {
        let h0 = tm.face_halfedge(crate::mesh::FaceId(t));
        let [a, b, c] = [h0, tm.next(h0), tm.prev(h0)].map(|h| tm.tail(h).0);
        let [pa, pb, pc] = [a, b, c].map(|v| positions[v as usize]);
        let g = add((pa + pb + pc) / 3.0, positions);
        let mab = add((pa + pb) / 2.0, positions);
        let mbc = add((pb + pc) / 2.0, positions);
        let mca = add((pc + pa) / 2.0, positions);
        quads.push([a, mab, g, mca]);
        quads.push([b, mbc, g, mab]);
        quads.push([c, mca, g, mbc]);
        ParityFixKind::IsolatedTriangleSplit
    } else {
        // Longest boundary edge: the new vertex lands where the boundary
        // is coarsest (ties: first in face order).
        let h = bnd
            .iter()
            .copied()
            .max_by(|&x, &y| {
                let l =
                    |h: HalfedgeId| (tm.position(tm.head(h)) - tm.position(tm.tail(h))).length();
                l(x).total_cmp(&l(y)).then(y.cmp(&x))
            })
            .expect("the target has a boundary edge");
        let (a, b, c) = (tm.tail(h).0, tm.head(h).0, tm.head(tm.next(h)).0);
        let p = |v: u32| positions[v as usize];
        let (pa, pb, pc) = (p(a), p(b), p(c));
        let pm = (pa + pb) / 2.0;
        let g = (pa + pb + pc) / 3.0;
        let m = add(pm, positions);
        let ia = add((pa + g) / 2.0, positions);
        let im = add((pm + g) / 2.0, positions);
        let ib = add((pb + g) / 2.0, positions);
        let ic = add((pc + g) / 2.0, positions);
        // Ring quads (u, w, inner(w), inner(u)) over the polygon
        // (a, m, b, c), then the inner quad; all oriented like (a, b, c).
        quads.push([a, m, im, ia]);
        quads.push([m, b, ib, im]);
        quads.push([b, c, ic, ib]);
        quads.push([c, a, ia, ic]);
        quads.push([ia, im, ib, ic]);
        let orig = |v: u32| {
            mesh.triangles[t as usize]
                .iter()
                .copied()
                .find(|&w| vertex_map[w as usize] == Some(VertexId(v)))
                .expect("vertex of the triangle")
        };
        ParityFixKind::BoundaryEdgeSplit {
            edge: [orig(a), orig(b)],
        }
    };
    (kind, new_vertices)
}

/// The quad made by removing the edge of `h` (from `a` to `b`, inside the
/// triangle `(a, b, c)`, the twin inside `(b, a, d)`): `(b, c, a, d)`,
/// oriented like the triangles, with the removed edge as diagonal `q0–q2`.
fn pair_quad(tm: &ControlMesh, h: HalfedgeId) -> [VertexId; 4] {
    let (a, b) = (tm.tail(h), tm.head(h));
    let c = tm.head(tm.next(h));
    let d = tm.head(tm.next(h.twin()));
    [b, c, a, d]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn square_quality() {
        let q = quad_quality([
            DVec3::new(0.0, 0.0, 0.0),
            DVec3::new(1.0, 0.0, 0.0),
            DVec3::new(1.0, 1.0, 0.0),
            DVec3::new(0.0, 1.0, 0.0),
        ]);
        assert!(q.max_angle_deviation_deg < 1e-9 && q.dihedral_deg < 1e-9 && q.convex);
        // A dart (arrowhead) is non-convex at q2.
        let q = quad_quality([
            DVec3::new(0.0, 0.0, 0.0),
            DVec3::new(2.0, -1.0, 0.0),
            DVec3::new(0.5, 0.0, 0.0),
            DVec3::new(2.0, 1.0, 0.0),
        ]);
        assert!(!q.convex);
        // Folded square: 90° dihedral.
        let q = quad_quality([
            DVec3::new(0.0, 0.0, 0.0),
            DVec3::new(1.0, 0.0, 0.0),
            DVec3::new(1.0, 1.0, 0.0),
            DVec3::new(0.0, 1.0, 1.0),
        ]);
        assert!(q.dihedral_deg > 1.0, "{q:?}");
    }
}
