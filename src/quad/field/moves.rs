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

use crate::error::Result;
use crate::mesh::{ControlMesh, FaceId, TriMesh, VertexId};
use crate::quad::ops::{Rotation, ValenceTargets};
use crate::DVec3;

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
    /// With [`plan_ordered`]'s `geometric`: the control points, by local
    /// index, which order the options ([`Self::options`]).
    pos: Option<Vec<DVec3>>,
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
    /// irregular complete vertex that also have a vertex of `focus` (the
    /// seed for the first step, the last step's hexagon after it: a
    /// dislocation glides through the quads next to it, so a move is one
    /// connected chain), each undirected edge once (from its face with
    /// `u < w`), both directions, in face and corner order.
    fn options(&self, focus: &[u32]) -> Vec<(usize, usize, [u32; 6], Rotation, i64)> {
        let mut out = Vec::new();
        for i in 0..self.faces.len() {
            let f = self.faces[i];
            if !f.iter().any(|v| focus.contains(v))
                || !f
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
        if let Some(pos) = &self.pos {
            // By the new edge's length, then its midpoint's and the old
            // edge's midpoint's lexicographic order (the cleanup's
            // `GeoKey`): the search meets equal moves, and runs out of
            // budget, in an order of the geometry, not of the local
            // numbering (which follows the half-edge ids around each
            // vertex).
            let key = |x: &[u32; 6], dir: Rotation| {
                let (_, [a, b]) = Self::rotated(*x, dir);
                let (pa, pb) = (pos[a as usize], pos[b as usize]);
                let mid = 0.5 * (pos[x[0] as usize] + pos[x[3] as usize]);
                let m = 0.5 * (pa + pb);
                [(pa - pb).length(), m.x, m.y, m.z, mid.x, mid.y, mid.z]
            };
            out.sort_by(|p, q| {
                let (kp, kq) = (key(&p.2, p.3), key(&q.2, q.3));
                kp.iter()
                    .zip(&kq)
                    .map(|(a, b)| a.total_cmp(b))
                    .find(|o| o.is_ne())
                    .unwrap_or(std::cmp::Ordering::Equal)
            });
        }
        out
    }

    /// Depth-first search; `path` holds the steps so far, `sum` their gain,
    /// `focus` where the next step must touch ([`Self::options`]).
    fn search(
        &mut self,
        path: &mut Vec<Step>,
        sum: i64,
        last: Option<[u32; 2]>,
        focus: &[u32],
        best: &mut Option<Move>,
    ) {
        if self.expanded >= BUDGET || path.len() >= MAX_STEPS {
            return;
        }
        self.expanded += 1;
        for (i, j, x, dir, g) in self.options(focus) {
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
            self.search(path, total, Some([a.min(b), a.max(b)]), &x, best);
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
    plan_ordered(k, vt, seed, false)
}

/// [`plan`]; with `geometric` the search tries each state's rotations in
/// an order of the control points (the cleanup's
/// [`super::cleanup::CleanupOptions::geometric_ties`]), so the first found
/// among equal moves, and what the budget reaches, do not depend on ids.
pub fn plan_ordered(
    k: &ControlMesh,
    vt: &ValenceTargets,
    seed: VertexId,
    geometric: bool,
) -> Option<Move> {
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
        pos: geometric.then(|| global.iter().map(|&v| k.position(v)).collect()),
        global,
        complete,
        faces,
        edge,
        expanded: 0,
    };
    let mut best = None;
    l.search(&mut Vec::new(), 0, None, &[0], &mut best);
    best
}

// ---- the fit guard -------------------------------------------------------------

/// How much a move may raise Σ d² over its region's samples of M (d: a
/// sample's distance to the limit surface, [`FitProbe::measure`]): 2 %.
/// The moves were kept under the fitmap tests alone before, and RMS L of
/// the fitted result rose by up to 19 % (cheburashka): the M → limit
/// distance, the one the S-/M-fitmap ratios do not see, is where a sheared
/// layout loses the surface.
pub const FIT_RISE: f64 = 1.02;

/// Refined levels of the limit surface the guard measures against: 4 × 4
/// cells per patch, exact limit points at their corners. Its chord error
/// (≈ (h/4)²/8R for patch size h and radius of curvature R) is far below
/// the fit's RMS distance on the shared meshes, and the same on both sides
/// of the comparison.
const GUARD_LEVELS: u32 = 2;

/// M's vertices bucketed in a uniform grid: the
/// samples a move's guard reads around its region.
#[derive(Clone)]
pub struct FitProbe<'a> {
    points: &'a [DVec3],
    cell: f64,
    grid: HashMap<[i64; 3], Vec<u32>>,
    /// A distance too small to count (the floor of the test: a region
    /// M already fits to round-off must not block on noise).
    floor: f64,
    /// Every `stride`-th vertex of M is a sample (M′ has tens of vertices
    /// per patch; a few per cell of the guard's tessellation suffice).
    stride: u32,
    /// The region fit run before each measure ([`Self::measure_fitted`]):
    /// `None` measures the layout as it is.
    fit: Option<RegionFit<'a>>,
    /// The projectability test of each sample ([`Self::with_projectability`]):
    /// M's caster, the search distance of φ and the reach tolerance.
    proj: Option<(&'a dyn crate::raycast::RayCaster, f64, f64)>,
}

/// What [`FitProbe::measure`] found: per sample (M's vertex index) its
/// squared distance to the limit over the region, and whether its closest
/// point lies on a patch the move changes.
pub struct FitMeasure {
    pub samples: Vec<(u32, f64, bool)>,
    /// With [`FitProbe::with_projectability`]: per sample (same order),
    /// whether φ from its foot on the limit misses it (module
    /// [`crate::report`]'s projectability test, on the guard's
    /// tessellation); empty without.
    pub unreached: Vec<bool>,
}

/// The box bound's allowance in units of the largest coordinate
/// ([`Tess::with_boxes`]): a million ulps.
const SLACK_ULPS: f64 = 1e6 * f64::EPSILON;

/// The limit surface over a set of patches as triangles (patch `i`'s are
/// `16 · 2` consecutive ones), with a bounding sphere per patch.
struct Tess {
    tris: Vec<[DVec3; 3]>,
    /// Per patch: centre, radius, and whether it changes with the move.
    patches: Vec<(DVec3, f64, bool)>,
    /// Per triangle (same order as `tris`): its axis-aligned box, a lower
    /// bound on a query's distance to it ([`Self::closest_foot`]).
    boxes: Vec<(DVec3, DVec3)>,
    /// The rounding allowance of that bound ([`Self::with_boxes`]).
    slack: f64,
}

impl Tess {
    const PER_PATCH: usize = 2 << (2 * GUARD_LEVELS);

    /// `tris` and `patches` with the triangles' boxes and their slack: the
    /// box bound skips a triangle only when it lies farther than the best
    /// distance so far by the slack, [`SLACK_ULPS`] of the largest
    /// coordinate, where the closest point's own rounding (Ericson's
    /// barycentric sums) is a few ulps of it; so a skipped triangle's
    /// computed distance could never have been below the best, and the
    /// answers are those of testing every triangle the sphere bound leaves
    /// (`tests::the_box_bound_changes_no_foot`).
    fn with_boxes(tris: Vec<[DVec3; 3]>, patches: Vec<(DVec3, f64, bool)>) -> Tess {
        let boxes: Vec<(DVec3, DVec3)> = tris
            .iter()
            .map(|t| (t[0].min(t[1]).min(t[2]), t[0].max(t[1]).max(t[2])))
            .collect();
        let scale = tris
            .iter()
            .flatten()
            .map(|x| x.abs().max_element())
            .fold(0.0, f64::max);
        Tess {
            tris,
            patches,
            boxes,
            slack: SLACK_ULPS * scale,
        }
    }

    /// The patch whose bounding sphere's centre is nearest to `p` (the
    /// lower index on a tie; 0 when there is none): the first patch
    /// [`Self::closest_foot`] visits.
    fn nearest_centre(&self, p: DVec3) -> usize {
        (0..self.patches.len())
            .min_by(|&a, &b| {
                let da = (p - self.patches[a].0).length_squared();
                let db = (p - self.patches[b].0).length_squared();
                da.total_cmp(&db).then(a.cmp(&b))
            })
            .unwrap_or(0)
    }

    /// The closest point's squared distance and its patch: the patch with
    /// the nearest centre first, then every patch whose bounding sphere
    /// comes closer than the best so far, in patch order; within a patch,
    /// the triangles in order, each but those whose box lies farther than
    /// the best so far (plus the slack, [`Self::with_boxes`]: issue 40's
    /// speed point, session 23, the guard's closest feet were ~9 % of
    /// gargoyle 402's CPU under `SUBDFIT_FIELD_BEST`, most of it in
    /// triangles the box rules out). Ties go to the first found.
    /// Also the closest point itself and the unit normal of the triangle
    /// it lies on (zero for a degenerate one).
    fn closest_foot(&self, p: DVec3) -> (f64, usize, DVec3, DVec3) {
        let mut best = (f64::INFINITY, usize::MAX, p, DVec3::ZERO);
        if self.patches.is_empty() {
            return best;
        }
        let first = self.nearest_centre(p);
        // The query's own coordinates round too.
        let slack = self.slack.max(SLACK_ULPS * p.abs().max_element());
        // A box farther than this (squared) holds no triangle whose
        // computed distance could beat `d` (infinite before any is found).
        let beyond = |d: f64| {
            let r = d.sqrt() + slack;
            r * r
        };
        let visit = |i: usize, best: &mut (f64, usize, DVec3, DVec3)| {
            let mut far = beyond(best.0);
            let range = i * Self::PER_PATCH..(i + 1) * Self::PER_PATCH;
            for (t, &(lo, hi)) in self.tris[range.clone()].iter().zip(&self.boxes[range]) {
                let out = (lo - p).max(p - hi).max(DVec3::ZERO);
                if out.length_squared() > far {
                    continue;
                }
                let (q, _, _) = crate::raycast::closest_point_triangle(p, t[0], t[1], t[2]);
                let d = (q - p).length_squared();
                if d < best.0 {
                    let n = (t[1] - t[0]).cross(t[2] - t[0]).normalize_or_zero();
                    *best = (d, i, q, n);
                    far = beyond(d);
                }
            }
        };
        visit(first, &mut best);
        for (i, &(c, r, _)) in self.patches.iter().enumerate() {
            let l = ((p - c).length() - r).max(0.0);
            if i != first && l * l < best.0 {
                visit(i, &mut best);
            }
        }
        best
    }

    /// [`Self::closest_foot`] as it was before the box bound (every
    /// triangle of each patch the sphere bound leaves): the reference of
    /// `tests::the_box_bound_changes_no_foot`.
    #[cfg(test)]
    fn closest_foot_unboxed(&self, p: DVec3) -> (f64, usize, DVec3, DVec3) {
        let lb: Vec<f64> = self
            .patches
            .iter()
            .map(|&(c, r, _)| ((p - c).length() - r).max(0.0))
            .collect();
        let first = self.nearest_centre(p);
        let mut best = (f64::INFINITY, usize::MAX, p, DVec3::ZERO);
        let visit = |i: usize, best: &mut (f64, usize, DVec3, DVec3)| {
            for t in &self.tris[i * Self::PER_PATCH..(i + 1) * Self::PER_PATCH] {
                let (q, _, _) = crate::raycast::closest_point_triangle(p, t[0], t[1], t[2]);
                let d = (q - p).length_squared();
                if d < best.0 {
                    let n = (t[1] - t[0]).cross(t[2] - t[0]).normalize_or_zero();
                    *best = (d, i, q, n);
                }
            }
        };
        if self.patches.is_empty() {
            return best;
        }
        visit(first, &mut best);
        for (i, &l) in lb.iter().enumerate() {
            if i != first && l * l < best.0 {
                visit(i, &mut best);
            }
        }
        best
    }
}

/// The faces around a set of changed control vertices: `inner` those with
/// a corner in it, `free` their corners, `region` the faces at `free`
/// (every patch a move of `free` changes most), `all` the region and one
/// ring of faces more (the support of the region's limit patches). Sorted;
/// `all` starts with `region`.
struct Region {
    inner: Vec<FaceId>,
    free: Vec<VertexId>,
    region: Vec<FaceId>,
    all: Vec<FaceId>,
}

impl Region {
    fn of(k: &ControlMesh, changed: &[VertexId]) -> Region {
        let faces_at = |vs: &[VertexId]| -> Vec<FaceId> {
            let mut out: Vec<FaceId> = vs
                .iter()
                .filter(|&&v| !k.is_vertex_deleted(v))
                .flat_map(|&v| k.vertex_faces(v))
                .collect();
            out.sort_unstable();
            out.dedup();
            out
        };
        let corners_of = |fs: &[FaceId]| -> Vec<VertexId> {
            let mut c: Vec<VertexId> = fs.iter().flat_map(|&f| k.face_vertices(f)).collect();
            c.sort_unstable();
            c.dedup();
            c
        };
        let inner = faces_at(changed);
        let free = corners_of(&inner);
        let region = faces_at(&free);
        let mut all = region.clone();
        all.extend(
            faces_at(&corners_of(&region))
                .into_iter()
                .filter(|f| region.binary_search(f).is_err()),
        );
        Region {
            inner,
            free,
            region,
            all,
        }
    }
}

/// The faces `all` of `k` as a control mesh of their own (face `i` is
/// `all[i]`), with its vertices' ids in `k`; `None` when they are not a
/// manifold piece (a vertex whose faces there form two fans).
fn submesh(k: &ControlMesh, all: &[FaceId]) -> Option<(ControlMesh, Vec<VertexId>)> {
    let mut local: HashMap<VertexId, u32> = HashMap::new();
    let mut global = Vec::new();
    let polys: Vec<[u32; 4]> = all
        .iter()
        .map(|&f| {
            crate::quad::ops::quad(k, f).map(|v| {
                *local.entry(v).or_insert_with(|| {
                    global.push(v);
                    global.len() as u32 - 1
                })
            })
        })
        .collect();
    let pos = global.iter().map(|&v| k.position(v)).collect();
    let sub = ControlMesh::from_polygons(pos, &polys).ok()?;
    Some((sub, global))
}

/// The global fit's objective on a region ([`FitProbe::settle`]): what
/// `crate::fit` solves on the whole control mesh (Fitmaps §3.5, the
/// `Point` objective: `min |A δ − (φ(s) − s)|² + λ |L δ|² + λ ε² |δ|²`,
/// samples on a `k × k` grid per patch with k from the patch's share of
/// M's vertices, one vertex equation per control vertex, outliers beyond
/// 10 × the first round's median and feet facing away (cos < 0.3) left
/// out, the best of the rounds kept), with the same sample density and
/// the same λ, on the region's control vertices only (the ring around
/// them held). The cleanup's own local refit (Fitmaps §3.4's smoothing and
/// fixed-point sweeps) ends elsewhere than the global fit does, and a
/// guard that measured after it let moves through whose regions the
/// global fit then fitted worse (homer RMS L +15 %, docs/status.md).
#[derive(Clone)]
pub struct RegionFit<'a> {
    caster: &'a dyn crate::raycast::RayCaster,
    mesh: &'a TriMesh,
    /// M's interpolated vertex normals (the fit's facing test).
    normals: Vec<DVec3>,
    /// Samples per unit of control-polygon area: the global fit's `k² ≈
    /// n · |P| / Σ|P|`.
    density: f64,
    /// The global fit's λ = fairness · samples / control vertices.
    lambda: f64,
    max_dist: f64,
}

/// The fit's own constants ([`crate::fit::FitOptions`]' defaults; the
/// fit module is above this one, so they are repeated here).
const FIT_FAIRNESS: f64 = 0.01;
const FIT_RIDGE: f64 = 1e-2;
const FIT_OUTLIER: f64 = 10.0;
const FIT_NORMAL_COS: f64 = 0.3;
const FIT_ISOLATION: u8 = 6;

/// Parameter-correction rounds of the region fit (the global fit stops
/// after at most 8, most of its gain in the first three).
const REGION_ROUNDS: usize = 3;

/// Samples per patch side at most in the region fit; a patch the global
/// fit samples more densely gets its rows weighted by the ratio, so the
/// data term weighs the same against λ (the cost of a guard is its ray
/// casts).
const REGION_K: usize = 5;

impl<'a> RegionFit<'a> {
    /// For the layout `k` on `mesh` (ray caster `caster`).
    pub fn new(
        mesh: &'a TriMesh,
        caster: &'a dyn crate::raycast::RayCaster,
        k: &ControlMesh,
    ) -> Self {
        let area: f64 = k
            .live_faces()
            .map(|f| {
                let q = crate::quad::ops::quad_positions(k, f);
                0.5 * (q[2] - q[0]).cross(q[3] - q[1]).length()
            })
            .sum();
        let n = mesh.positions.len() as f64;
        RegionFit {
            caster,
            mesh,
            normals: crate::analysis::normals::vertex_normals(mesh),
            density: n / area.max(1e-300),
            lambda: FIT_FAIRNESS * n / k.num_live_vertices().max(1) as f64,
            max_dist: crate::project::default_max_dist(mesh),
        }
    }
}

impl RegionFit<'_> {
    /// Fits the region of `changed` ([`Region`]: its `free` control
    /// vertices unknown, the ring around them held) by the global fit's
    /// objective (the type's docs) and writes the result into `k`;
    /// returns the old positions of the vertices it moved (for
    /// [`restore`]), `None` when the region is not a manifold piece.
    pub fn settle(
        &self,
        k: &mut ControlMesh,
        changed: &[VertexId],
    ) -> Result<Option<Vec<(VertexId, DVec3)>>> {
        use crate::subdiv::{make_evaluator, Backend, EvalOptions, SurfaceLocation};
        let Region {
            free, region, all, ..
        } = Region::of(k, changed);
        let Some((sub, global)) = submesh(k, &all) else {
            return Ok(None);
        };
        // Unknown index of each sub-mesh vertex (`free` ones only).
        let col: Vec<Option<usize>> = global.iter().map(|v| free.binary_search(v).ok()).collect();
        // Samples: the global fit's k × k cell centres on the region's
        // patches (capped at REGION_K, weighted up to the same data mass),
        // then one vertex equation per free vertex (a corner of one of its
        // faces, all of which are in the sub-mesh).
        let mut locs = Vec::new();
        let mut weight = Vec::new();
        for i in 0..region.len() {
            let q: Vec<DVec3> = sub
                .face_vertices(FaceId(i as u32))
                .map(|v| sub.position(v))
                .collect();
            let area = 0.5 * (q[2] - q[0]).cross(q[3] - q[1]).length();
            let kk = ((self.density * area).sqrt().floor() as usize).clamp(3, 64);
            let ku = kk.min(REGION_K);
            let w = ((kk * kk) as f64 / (ku * ku) as f64).sqrt();
            for j in 0..ku {
                for c in 0..ku {
                    let (u, v) = ((c as f64 + 0.5) / ku as f64, (j as f64 + 0.5) / ku as f64);
                    locs.push(SurfaceLocation::quad(FaceId(i as u32), u, v));
                    weight.push(w);
                }
            }
        }
        const CORNERS: [(f64, f64); 4] = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)];
        for (l, c) in col.iter().enumerate() {
            if c.is_none() {
                continue;
            }
            let v = VertexId(l as u32);
            let f = sub.vertex_faces(v).next().expect("a vertex of a face");
            let at = sub.face_vertices(f).position(|w| w == v).expect("its face");
            let (u, w) = CORNERS[at];
            locs.push(SurfaceLocation::quad(f, u, w));
            weight.push(1.0);
        }
        let ev = make_evaluator(
            Backend::Osd,
            &sub,
            &EvalOptions::default().with_isolation_level(FIT_ISOLATION),
        )?;
        let stencils = ev.stencils(&locs)?;
        let reg = self.regulariser(k, &free);
        let mut pos = sub.positions().to_vec();
        let (mut best, mut bound) = ((f64::INFINITY, pos.clone()), f64::INFINITY);
        for round in 0..=REGION_ROUNDS {
            let lp = stencils.apply(&pos);
            let (mut hits, _) =
                crate::project::project_along_normals(self.caster, &lp, self.max_dist)?;
            if round == 0 {
                let mut d: Vec<f64> = hits.iter().flatten().map(|h| h.offset.abs()).collect();
                d.sort_unstable_by(f64::total_cmp);
                bound = d
                    .get(d.len() / 2)
                    .map_or(f64::INFINITY, |m| FIT_OUTLIER * m);
            }
            for (h, s) in hits.iter_mut().zip(&lp) {
                let Some(p) = h else { continue };
                let t = self.mesh.triangles[p.triangle as usize];
                let nm = (1.0 - p.u - p.v) * self.normals[t[0] as usize]
                    + p.u * self.normals[t[1] as usize]
                    + p.v * self.normals[t[2] as usize];
                if p.offset.abs() > bound || nm.normalize_or_zero().dot(s.normal()) < FIT_NORMAL_COS
                {
                    *h = None;
                }
            }
            // The fit's score: lost samples count at the outlier bound.
            let lost = if bound.is_finite() {
                bound * bound
            } else {
                0.0
            };
            let score: f64 = hits
                .iter()
                .zip(&weight)
                .map(|(h, w)| w * w * h.as_ref().map_or(lost, |p| p.offset * p.offset))
                .sum();
            if score < best.0 {
                best = (score, pos.clone());
            }
            if round == REGION_ROUNDS {
                break;
            }
            let mut a = crate::solve::Triplets::new(hits.len(), free.len());
            let mut b: Vec<Vec<f64>> = (0..3).map(|_| Vec::with_capacity(hits.len())).collect();
            for (i, h) in hits.iter().enumerate() {
                let d = h.as_ref().map_or(DVec3::ZERO, |p| p.point - lp[i].position);
                if h.is_some() {
                    for r in stencils.row(i) {
                        if let Some(c) = col[stencils.indices[r] as usize] {
                            a.push(i, c, weight[i] * stencils.weights[r]);
                        }
                    }
                }
                let d = weight[i] * d;
                b[0].push(d.x);
                b[1].push(d.y);
                b[2].push(d.z);
            }
            let x = crate::solve::least_squares(
                &a,
                &b,
                Some((&reg, self.lambda)),
                &crate::solve::LsqOptions::default(),
            )?;
            for (l, c) in col.iter().enumerate() {
                if let Some(c) = *c {
                    pos[l] += DVec3::new(x[0][c], x[1][c], x[2][c]);
                }
            }
        }
        let mut old = Vec::with_capacity(free.len());
        for (l, c) in col.iter().enumerate() {
            if c.is_some() {
                let v = global[l];
                old.push((v, k.position(v)));
                k.positions_mut()[v.idx()] = best.1[l];
            }
        }
        Ok(Some(old))
    }

    /// The fit's umbrella Laplacian rows `δ_v − mean(δ_neighbours)` of
    /// every vertex with a free one among itself and its neighbours (the
    /// others' rows do not depend on the unknowns), held vertices' δ = 0,
    /// stacked on ε I.
    fn regulariser(&self, k: &ControlMesh, free: &[VertexId]) -> crate::solve::Triplets {
        let mut rows: Vec<VertexId> = free
            .iter()
            .flat_map(|&v| std::iter::once(v).chain(k.outgoing(v).map(|h| k.head(h))))
            .collect();
        rows.sort_unstable();
        rows.dedup();
        let n = free.len();
        let mut r = crate::solve::Triplets::new(rows.len() + n, n);
        for (i, &v) in rows.iter().enumerate() {
            if let Ok(c) = free.binary_search(&v) {
                r.push(i, c, 1.0);
            }
            let nb: Vec<VertexId> = k.outgoing(v).map(|h| k.head(h)).collect();
            let w = 1.0 / nb.len().max(1) as f64;
            for u in nb {
                if let Ok(c) = free.binary_search(&u) {
                    r.push(i, c, -w);
                }
            }
        }
        for c in 0..n {
            r.push(rows.len() + c, c, FIT_RIDGE);
        }
        r
    }
}

/// Puts back the positions [`RegionFit::settle`] returned.
pub fn restore(k: &mut ControlMesh, old: &[(VertexId, DVec3)]) {
    for &(v, p) in old {
        k.positions_mut()[v.idx()] = p;
    }
}

impl<'a> FitProbe<'a> {
    /// `cell`: the grid's cell size (about a patch); `floor`, `stride`: see
    /// the fields.
    pub fn new(mesh: &'a TriMesh, cell: f64, floor: f64, stride: usize) -> Self {
        let cell = cell.max(1e-12);
        let mut grid: HashMap<[i64; 3], Vec<u32>> = HashMap::new();
        for (i, p) in mesh.positions.iter().enumerate() {
            grid.entry(Self::key(*p, cell)).or_default().push(i as u32);
        }
        FitProbe {
            points: &mesh.positions,
            cell,
            grid,
            floor,
            stride: stride.clamp(1, u32::MAX as usize) as u32,
            fit: None,
            proj: None,
        }
    }

    /// Measures projectability too: a sample is unreached when the line
    /// through its closest point on the limit, along that point's normal,
    /// meets M (`caster`, within `max_dist`) farther than `tol` from it, or
    /// nowhere: the report's test (`report::unprojectable_percent`: M's
    /// point mapped to its closest limit point, φ cast back, reached
    /// within one mean edge of M) on the guard's tessellation.
    pub fn with_projectability(
        mut self,
        caster: &'a dyn crate::raycast::RayCaster,
        max_dist: f64,
        tol: f64,
    ) -> Self {
        self.proj = Some((caster, max_dist, tol));
        self
    }

    /// How many of M's vertices are samples (every `stride`-th): the
    /// whole surface's count, against which a region's is a share.
    pub fn num_samples(&self) -> usize {
        self.points.len().div_ceil(self.stride as usize)
    }

    /// Measures after the global fit's objective on the region
    /// ([`RegionFit`]) from now on.
    pub fn with_region_fit(mut self, fit: RegionFit<'a>) -> Self {
        self.fit = Some(fit);
        self
    }

    /// [`Self::measure`] of the layout the region fit makes of `k` (the
    /// prediction of what the global fit does there; `k` is left as it
    /// was), or of `k` itself without a region fit.
    pub fn measure_fitted(
        &self,
        k: &mut ControlMesh,
        changed: &[VertexId],
        extra: &[u32],
    ) -> Result<Option<FitMeasure>> {
        let old = match &self.fit {
            Some(f) => match f.settle(k, changed)? {
                Some(old) => old,
                None => return Ok(None),
            },
            None => Vec::new(),
        };
        let m = self.measure(k, changed, extra);
        restore(k, &old);
        m
    }

    fn key(p: DVec3, cell: f64) -> [i64; 3] {
        let q = p / cell;
        [q.x.floor() as i64, q.y.floor() as i64, q.z.floor() as i64]
    }

    /// M's vertices in the box `[lo, hi]`, ascending.
    fn candidates(&self, lo: DVec3, hi: DVec3) -> Vec<u32> {
        let (a, b) = (Self::key(lo, self.cell), Self::key(hi, self.cell));
        let mut out = Vec::new();
        for x in a[0]..=b[0] {
            for y in a[1]..=b[1] {
                for z in a[2]..=b[2] {
                    if let Some(v) = self.grid.get(&[x, y, z]) {
                        out.extend(v.iter().copied().filter(|&i| {
                            let p = self.points[i as usize];
                            i % self.stride == 0 && p.cmpge(lo).all() && p.cmple(hi).all()
                        }));
                    }
                }
            }
        }
        out.sort_unstable();
        out
    }

    /// The limit over the faces with a corner in `changed` (the patches a
    /// change of those control points moves most; the refit's 1-ring is in
    /// `changed`, so its own patches are) and one ring of faces more (so a
    /// sample's closest point is found where it is),
    /// by [`GUARD_LEVELS`] of uniform Catmull-Clark refinement of that
    /// region and its own 1-ring, every refined vertex at its limit.
    /// `None` when the region is not a manifold piece (a vertex of the
    /// outer ring whose faces there form two fans).
    fn tessellate(k: &ControlMesh, changed: &[VertexId]) -> Result<Option<Tess>> {
        let Region {
            inner, region, all, ..
        } = Region::of(k, changed);
        let Some((sub, _)) = submesh(k, &all) else {
            return Ok(None);
        };
        let r = crate::subdiv::refine::refine_uniform(&sub, GUARD_LEVELS)?;
        let scheme = crate::mesh::SchemeOptions::default();
        let mut lim: Vec<Option<DVec3>> = vec![None; r.num_vertices()];
        let mut limit = |v: VertexId| -> DVec3 {
            *lim[v.idx()].get_or_insert_with(|| {
                crate::subdiv::catmark::vertex_limit_mask(&r, v, &scheme)
                    .into_iter()
                    .map(|(u, w)| w * r.position(u))
                    .sum()
            })
        };
        let per = 1usize << (2 * GUARD_LEVELS);
        let mut tris = Vec::with_capacity(region.len() * Tess::PER_PATCH);
        let mut patches = Vec::with_capacity(region.len());
        for (p, f) in region.iter().enumerate() {
            let start = tris.len();
            for c in p * per..(p + 1) * per {
                let q: Vec<DVec3> = r.face_vertices(FaceId(c as u32)).map(&mut limit).collect();
                tris.push([q[0], q[1], q[2]]);
                tris.push([q[0], q[2], q[3]]);
            }
            let pts = tris[start..].iter().flatten();
            let n = (2 * 3 * per) as f64;
            let ctr = pts.clone().sum::<DVec3>() / n;
            let rad = pts.map(|x| (*x - ctr).length()).fold(0.0, f64::max);
            patches.push((ctr, rad, inner.binary_search(f).is_ok()));
        }
        Ok(Some(Tess::with_boxes(tris, patches)))
    }

    /// Squared distances to the limit over the region of `changed` (the
    /// control vertices a move rotated around or refitted): of `extra`
    /// (M's vertex indices, ascending) and of every sample of M whose
    /// closest point on that region lies on a patch the move changes.
    /// (No test of the normals: the samples the limit misses, on both
    /// sides of a thin part it cuts through, are the ones that count.)
    /// `None`: see [`Self::tessellate`].
    pub fn measure(
        &self,
        k: &ControlMesh,
        changed: &[VertexId],
        extra: &[u32],
    ) -> Result<Option<FitMeasure>> {
        let Some(tess) = Self::tessellate(k, changed)? else {
            return Ok(None);
        };
        let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        let mut reach = 0.0f64;
        for &(c, r, inner) in &tess.patches {
            if inner {
                lo = lo.min(c - DVec3::splat(r));
                hi = hi.max(c + DVec3::splat(r));
                reach = reach.max(r);
            }
        }
        let mut cand = self.candidates(lo - DVec3::splat(reach), hi + DVec3::splat(reach));
        cand.extend_from_slice(extra);
        cand.sort_unstable();
        cand.dedup();
        let mut samples = Vec::new();
        let (mut feet, mut normals) = (Vec::new(), Vec::new());
        for i in cand {
            let (d2, patch, q, n) = tess.closest_foot(self.points[i as usize]);
            let inner = patch != usize::MAX && tess.patches[patch].2;
            if inner || extra.binary_search(&i).is_ok() {
                samples.push((i, d2, inner));
                feet.push(q);
                normals.push(n);
            }
        }
        let mut unreached = Vec::new();
        if let Some((caster, max_dist, tol)) = self.proj {
            // A degenerate normal cannot be cast: such a foot is unreached
            // (φ is undefined there), the report's rule too.
            let dirs: Vec<DVec3> = normals
                .iter()
                .map(|&n| if n == DVec3::ZERO { DVec3::Z } else { n })
                .collect();
            let hits = caster.line_hits(&feet, &dirs, max_dist)?;
            unreached = hits
                .iter()
                .zip(&samples)
                .zip(feet.iter().zip(&normals))
                .map(|((h, s), (&q, &n))| match h {
                    Some(h) if n != DVec3::ZERO => {
                        (q + h.t * n - self.points[s.0 as usize]).length() > tol
                    }
                    _ => true,
                })
                .collect();
        }
        Ok(Some(FitMeasure { samples, unreached }))
    }

    /// Whether `after` leaves no more of the samples both measured
    /// unreached than `before` ([`Self::with_projectability`]), plus
    /// `slack` of them; always true without the test.
    pub fn reach_holds(&self, before: &FitMeasure, after: &FitMeasure, slack: usize) -> bool {
        if self.proj.is_none() {
            return true;
        }
        let (mut n0, mut n1) = (0usize, 0usize);
        for (k, &(i, _, _)) in before.samples.iter().enumerate() {
            if let Ok(j) = after.samples.binary_search_by_key(&i, |s| s.0) {
                n0 += before.unreached.get(k).copied().unwrap_or(false) as usize;
                n1 += after.unreached.get(j).copied().unwrap_or(false) as usize;
            }
        }
        n1 <= n0 + slack
    }

    /// Whether the fit after a move (`after`) is within `rise` of the one
    /// before (`before`): Σ d² over the samples both measured (the caller
    /// passes each state's samples to the other's [`Self::measure`] as
    /// `extra`), plus the floor per sample.
    pub fn holds(&self, before: &FitMeasure, after: &FitMeasure, rise: f64) -> bool {
        let (mut s0, mut s1, mut n) = (0.0, 0.0, 0.0);
        for &(i, d0, _) in &before.samples {
            if let Ok(j) = after.samples.binary_search_by_key(&i, |s| s.0) {
                s0 += d0;
                s1 += after.samples[j].1;
                n += 1.0;
            }
        }
        // The largest distance too: M → limit RMS L is carried by the few
        // places the limit misses (a thin part cut through), and there a
        // move must not make it worse either.
        let top = |m: &FitMeasure| m.samples.iter().map(|s| s.1).fold(0.0, f64::max);
        let f2 = self.floor * self.floor;
        s1 <= rise * s0 + n * f2 && top(after) <= rise * top(before) + f2
    }
}

impl FitMeasure {
    /// The sample indices, ascending.
    pub fn ids(&self) -> Vec<u32> {
        self.samples.iter().map(|s| s.0).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Deterministic points in `[-s, s]³` (a 64-bit LCG: no test depends on
    /// a seed's luck, the assertions hold for every point).
    fn points(n: usize, s: f64, mut x: u64) -> Vec<DVec3> {
        let mut next = || {
            x = x
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((x >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0) * s
        };
        (0..n).map(|_| DVec3::new(next(), next(), next())).collect()
    }

    /// The box bound (issue 40's speed point, session 23) changes no
    /// answer of [`Tess::closest_foot`]: on the guard's tessellation of a
    /// perturbed sphere's region, for points scattered around it, for the
    /// tessellation's own vertices and edge midpoints (equal distances on
    /// the triangles and patches that share them: the ties, which go to
    /// the first found) and for points just off the surface, the foot,
    /// its distance, patch and normal are the unbounded search's bit for
    /// bit, and the distance is the least over every triangle.
    #[test]
    fn the_box_bound_changes_no_foot() {
        let k = crate::fixtures::polar_sphere(6, 7);
        let v = k.live_vertices().nth(9).expect("a vertex");
        let tess = FitProbe::tessellate(&k, &[v])
            .unwrap()
            .expect("a manifold region");
        assert!(tess.patches.len() >= 9, "{}", tess.patches.len());
        let mut queries = points(3000, 1.3, 23);
        for t in &tess.tris {
            queries.extend_from_slice(t);
            queries.push(0.5 * (t[0] + t[1]));
            queries.push(0.5 * (t[1] + t[2]));
            let c = (t[0] + t[1] + t[2]) / 3.0;
            queries.push(c * 1.001);
            queries.push(c * 0.999);
        }
        let mut skipped = 0usize;
        for p in queries {
            let a = tess.closest_foot(p);
            let b = tess.closest_foot_unboxed(p);
            assert_eq!(a.0.to_bits(), b.0.to_bits(), "{p}");
            assert_eq!(a.1, b.1, "{p}");
            assert_eq!(
                a.2.to_array().map(f64::to_bits),
                b.2.to_array().map(f64::to_bits)
            );
            assert_eq!(
                a.3.to_array().map(f64::to_bits),
                b.3.to_array().map(f64::to_bits)
            );
            let all = tess
                .tris
                .iter()
                .map(|t| {
                    let (q, _, _) = crate::raycast::closest_point_triangle(p, t[0], t[1], t[2]);
                    (q - p).length_squared()
                })
                .fold(f64::INFINITY, f64::min);
            assert_eq!(a.0, all, "{p}");
            // The bound is not vacuous: count the triangles it rules out
            // for this query once the best is known.
            let far = (a.0.sqrt() + tess.slack).powi(2);
            skipped += tess
                .boxes
                .iter()
                .filter(|(lo, hi)| (*lo - p).max(p - *hi).max(DVec3::ZERO).length_squared() > far)
                .count();
        }
        assert!(skipped > 0);
    }
}
