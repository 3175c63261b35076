//! Fitmap-driven simplification of the quad control mesh (Fitmaps §3.3–3.4).
//!
//! From the triangle mesh M: quadrangulate (§3.2), interpolate M's vertices
//! with the limit surface (system (1)), then collapse diagonals in order of
//! `|d| · F_S(φ(c))` (a heap with version stamps: a face whose geometry
//! changed gets a new version and new entries; older entries are skipped
//! when they surface). After each collapse: edge rotations in the 1-ring
//! that lower the valence energy (§3.3.2), doublet removal (§3.3.3, done by
//! the collapse operator itself), and a local refit of the touched region W
//! plus its 1-ring, twice alternating Laplacian smoothing and a fixed-point
//! fit towards φ targets (§3.4).
//!
//! All per-collapse work is local: vertex limit points come from
//! [`vertex_limit_mask`], patch centres from the closed-form Catmull-Clark
//! face-centre limit ([`face_centre_limit`]), and every φ query of one step
//! goes to the ray caster as one batch. The loop itself is sequential and
//! the batches keep their input order, so the result does not depend on the
//! number of threads.

use std::cmp::Reverse;
use std::collections::BinaryHeap;
use std::time::Instant;

use serde::Serialize;

use super::ops::{
    can_collapse_diagonal, can_rotate_edge, collapse_diagonal, remove_doublets, rotate_edge,
    rotation_energy_gain, Rotation, ValenceTargets,
};
use super::{interpolate_limit, quadrangulate, vertex_limit_mask, InterpolationOptions};
use super::{QuadrangulateOptions, Quadrangulation};
use crate::analysis::Fitmap;
use crate::error::{Error, Result};
use crate::mesh::{ControlMesh, FaceId, TriMesh, VertexId};
use crate::project::{default_max_dist, project_along_normals, Projected};
use crate::raycast::RayCaster;
use crate::subdiv::LimitPoint;
use crate::DVec3;

/// Options of [`simplify`]. τ is not here: it is the Fitmap's.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[non_exhaustive]
pub struct SimplifyOptions {
    /// Stop as soon as the mesh has at most this many faces (the paper's
    /// "*" rows); `None`: run to the natural end.
    pub target_faces: Option<usize>,
    /// The M-fitmap projectability test of §3.3.1 (off: the paper's Fig. 7
    /// experiment).
    pub m_fitmap: bool,
    /// Smoothing + fit rounds of the local refit (§3.4: "twice").
    pub refit_rounds: usize,
    /// Fixed-point sweeps per fit round.
    pub fit_sweeps: usize,
    /// Search distance of φ; `None`: [`default_max_dist`].
    pub max_dist: Option<f64>,
    /// Run `validate()` and the no-doublet check after every step (tests;
    /// O(mesh) per step).
    pub check_every_step: bool,
}

impl Default for SimplifyOptions {
    fn default() -> Self {
        SimplifyOptions {
            target_faces: None,
            m_fitmap: true,
            refit_rounds: 2,
            fit_sweeps: 3,
            max_dist: None,
            check_every_step: false,
        }
    }
}

impl SimplifyOptions {
    pub fn with_target_faces(mut self, n: Option<usize>) -> Self {
        self.target_faces = n;
        self
    }
    pub fn with_m_fitmap(mut self, on: bool) -> Self {
        self.m_fitmap = on;
        self
    }
    pub fn with_check_every_step(mut self, on: bool) -> Self {
        self.check_every_step = on;
        self
    }
}

/// Why the loop ended.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum StopReason {
    /// `target_faces` reached.
    TargetFaces,
    /// No allowed collapse remains.
    NaturalEnd,
}

/// Passed to the progress callback every few hundred collapses.
#[derive(Copy, Clone, Debug, PartialEq, Serialize)]
pub struct Progress {
    pub faces: usize,
    pub initial_faces: usize,
    pub collapses: usize,
    pub seconds: f64,
}

/// Counters and timings of one run.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct SimplifyStats {
    pub input_triangles: usize,
    pub initial_faces: usize,
    pub faces: usize,
    pub vertices: usize,
    /// Vertices whose valence differs from the regular one (4 inside, 3 on
    /// the boundary, 2 at input corners; see [`super::ops`]).
    pub irregular_vertices: usize,
    pub collapses: usize,
    pub rotations: usize,
    pub doublets: usize,
    /// Heap entries refused by the topological checks.
    pub refused_topology: usize,
    /// Heap entries refused by the M-fitmap test.
    pub refused_m_fitmap: usize,
    /// φ queries and those with no hit (counted, then handled by a closest
    /// point look-up for the Fitmap values, or by not moving the vertex).
    pub projections: usize,
    pub unprojectable: usize,
    pub seconds_quadrangulate: f64,
    pub seconds_interpolate: f64,
    pub seconds_simplify: f64,
    pub stop: Option<StopReason>,
}

/// The simplified control mesh (compact) and its statistics.
#[derive(Clone, Debug)]
pub struct Simplified {
    pub mesh: ControlMesh,
    pub stats: SimplifyStats,
}

/// [`simplify_with_progress`] without a progress callback.
pub fn simplify(
    mesh: &TriMesh,
    fitmap: &Fitmap,
    caster: &dyn RayCaster,
    opts: &SimplifyOptions,
) -> Result<Simplified> {
    simplify_with_progress(mesh, fitmap, caster, opts, &mut |_| true)
}

/// Quadrangulates `mesh`, interpolates it with the limit surface and
/// simplifies it (module documentation). `fitmap` is the Fitmap of `mesh`,
/// `caster` a ray caster over `mesh`. `progress` is called every few hundred
/// collapses; returning `false` cancels with [`Error::Cancelled`].
pub fn simplify_with_progress(
    mesh: &TriMesh,
    fitmap: &Fitmap,
    caster: &dyn RayCaster,
    opts: &SimplifyOptions,
    progress: &mut dyn FnMut(Progress) -> bool,
) -> Result<Simplified> {
    let nv = mesh.positions.len();
    if fitmap.s.len() != nv || fitmap.m.len() != nv {
        return Err(Error::InvalidArgument(format!(
            "simplify: the Fitmap has {} values, the mesh {nv} vertices",
            fitmap.s.len()
        )));
    }
    let mut stats = SimplifyStats {
        input_triangles: mesh.triangles.len(),
        ..Default::default()
    };
    let t = Instant::now();
    let Quadrangulation { mesh: mut k, .. } =
        quadrangulate(mesh, &QuadrangulateOptions::default())?;
    stats.seconds_quadrangulate = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let targets = k.positions().to_vec();
    interpolate_limit(&mut k, &targets, &InterpolationOptions::default())?;
    stats.seconds_interpolate = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let mut s = Simplifier::new(mesh, fitmap, caster, opts, k)?;
    s.run(&mut stats, progress)?;
    let Simplifier {
        k, valence_targets, ..
    } = s;
    let mut k = k;
    stats.irregular_vertices = k
        .live_vertices()
        .filter(|&v| valence_targets.is_irregular(&k, v))
        .count();
    k.compact()?;
    stats.faces = k.num_faces();
    stats.vertices = k.num_vertices();
    stats.seconds_simplify = t.elapsed().as_secs_f64();
    Ok(Simplified { mesh: k, stats })
}

/// Simplifies a quad control mesh `k` already fitted to `mesh` (its limit
/// surface on M). Exposed for tests and callers that build the initial
/// control mesh themselves. The result is compact.
pub fn simplify_control(
    mesh: &TriMesh,
    fitmap: &Fitmap,
    caster: &dyn RayCaster,
    opts: &SimplifyOptions,
    k: ControlMesh,
    progress: &mut dyn FnMut(Progress) -> bool,
) -> Result<Simplified> {
    let mut stats = SimplifyStats {
        input_triangles: mesh.triangles.len(),
        ..Default::default()
    };
    let t = Instant::now();
    let mut s = Simplifier::new(mesh, fitmap, caster, opts, k)?;
    s.run(&mut stats, progress)?;
    let Simplifier {
        mut k,
        valence_targets,
        ..
    } = s;
    stats.irregular_vertices = k
        .live_vertices()
        .filter(|&v| valence_targets.is_irregular(&k, v))
        .count();
    k.compact()?;
    stats.faces = k.num_faces();
    stats.vertices = k.num_vertices();
    stats.seconds_simplify = t.elapsed().as_secs_f64();
    Ok(Simplified { mesh: k, stats })
}

// ---- closed-form limit quantities -------------------------------------------

fn centroid(k: &ControlMesh, f: FaceId) -> DVec3 {
    let mut c = DVec3::ZERO;
    let mut n = 0.0;
    for v in k.face_vertices(f) {
        c += k.position(v);
        n += 1.0;
    }
    c / n
}

/// The Catmull-Clark vertex point of `v` after one step (smooth rules;
/// boundary edges are creases: cubic B-spline rule, corners fixed).
fn vertex_point(k: &ControlMesh, v: VertexId) -> DVec3 {
    let p = k.position(v);
    let h0 = k.vertex_halfedge(v);
    if k.is_boundary_halfedge(h0) {
        if k.valence(v) == 2 {
            return p;
        }
        let next = k.position(k.head(h0));
        let prev = k.position(k.tail(k.prev(h0)));
        return (prev + 6.0 * p + next) / 8.0;
    }
    let mut q = DVec3::ZERO;
    let mut r = DVec3::ZERO;
    let mut n = 0.0;
    for h in k.outgoing(v) {
        q += centroid(k, k.face_of(h).expect("interior"));
        r += 0.5 * (p + k.position(k.head(h)));
        n += 1.0;
    }
    (q / n + 2.0 * r / n + (n - 3.0) * p) / n
}

/// The Catmull-Clark edge point of the edge of `h`.
fn edge_point(k: &ControlMesh, h: crate::mesh::HalfedgeId) -> DVec3 {
    let a = k.position(k.tail(h));
    let b = k.position(k.head(h));
    match (k.face_of(h), k.face_of(h.twin())) {
        (Some(f), Some(g)) => (a + b + centroid(k, f) + centroid(k, g)) / 4.0,
        _ => 0.5 * (a + b),
    }
}

/// The limit point and tangents at the centre of the quad `f`, in closed
/// form: one Catmull-Clark step makes the face point a regular (valence 4)
/// vertex whose neighbours are the four edge points `E_i` and whose
/// diagonals are the four vertex points `V_i`, so its limit is
/// `(16 F + 4 Σ E_i + Σ V_i) / 36` and its tangents are those of the
/// bicubic B-spline at a knot. Exact for any valences around the face.
pub fn face_centre_limit(k: &ControlMesh, f: FaceId) -> LimitPoint {
    let hs: Vec<_> = k.face_halfedges(f).collect();
    debug_assert_eq!(hs.len(), 4);
    let fp = centroid(k, f);
    let e: Vec<DVec3> = hs.iter().map(|&h| edge_point(k, h)).collect();
    let vp: Vec<DVec3> = hs.iter().map(|&h| vertex_point(k, k.tail(h))).collect();
    let position =
        (16.0 * fp + 4.0 * (e[0] + e[1] + e[2] + e[3]) + vp[0] + vp[1] + vp[2] + vp[3]) / 36.0;
    // E_0 lies on edge (v0, v1), so E_0 − E_2 runs along "v" and E_1 − E_3
    // along "u" of the face; the B-spline derivative at a knot weighs the
    // middle row 4 and the corner rows 1 (scale irrelevant for the normal).
    let du = 4.0 * (e[1] - e[3]) + (vp[1] + vp[2] - vp[3] - vp[0]);
    let dv = 4.0 * (e[2] - e[0]) + (vp[2] + vp[3] - vp[0] - vp[1]);
    LimitPoint { position, du, dv }
}

/// Unit normal of the limit surface at the control vertex `v`: Halstead et
/// al.'s limit tangents for an interior vertex with quads; for a boundary
/// vertex the area-weighted normal of its control quads (a proxy, used only
/// as the direction of φ).
fn vertex_normal(k: &ControlMesh, v: VertexId) -> DVec3 {
    if !k.is_boundary_vertex(v) {
        let hs: Vec<_> = k.outgoing(v).collect();
        let n = hs.len() as f64;
        let c1 = (2.0 * std::f64::consts::PI / n).cos();
        let a = 1.0 + c1 + (std::f64::consts::PI / n).cos() * (2.0 * (9.0 + c1)).sqrt();
        let (mut t1, mut t2) = (DVec3::ZERO, DVec3::ZERO);
        for (i, &h) in hs.iter().enumerate() {
            let th0 = 2.0 * std::f64::consts::PI * i as f64 / n;
            let th1 = 2.0 * std::f64::consts::PI * (i + 1) as f64 / n;
            let e = k.position(k.head(h));
            let d = k.position(k.head(k.next(h)));
            t1 += a * th0.cos() * e + (th0.cos() + th1.cos()) * d;
            t2 += a * th0.sin() * e + (th0.sin() + th1.sin()) * d;
        }
        let nrm = t1.cross(t2).normalize_or_zero();
        if nrm != DVec3::ZERO {
            return nrm;
        }
    }
    let mut nrm = DVec3::ZERO;
    for f in k.vertex_faces(v) {
        let q = super::ops::quad_positions(k, f);
        nrm += (q[2] - q[0]).cross(q[3] - q[1]);
    }
    nrm.normalize_or_zero()
}

fn limit_of(k: &ControlMesh, mask: &[(VertexId, f64)]) -> DVec3 {
    mask.iter().map(|&(u, w)| w * k.position(u)).sum()
}

// ---- the loop ------------------------------------------------------------------

struct Simplifier<'a> {
    m: &'a TriMesh,
    fitmap: &'a Fitmap,
    caster: &'a dyn RayCaster,
    opts: SimplifyOptions,
    max_dist: f64,
    k: ControlMesh,
    valence_targets: ValenceTargets,
    version: Vec<u32>,
    fs: Vec<f64>,
    fm: Vec<f64>,
    heap: BinaryHeap<Reverse<(u64, u32, u8, u32)>>,
    projections: usize,
    unprojectable: usize,
    /// Topological invariants of the input, checked per step in tests.
    invariants: (usize, usize, i64),
}

fn euler(k: &ControlMesh) -> i64 {
    k.num_live_vertices() as i64 - k.num_live_edges() as i64 + k.num_live_faces() as i64
}

impl<'a> Simplifier<'a> {
    fn new(
        m: &'a TriMesh,
        fitmap: &'a Fitmap,
        caster: &'a dyn RayCaster,
        opts: &SimplifyOptions,
        mut k: ControlMesh,
    ) -> Result<Self> {
        if !k.is_all_quads() {
            return Err(Error::InvalidArgument(
                "simplify: the control mesh must be made of quads only".into(),
            ));
        }
        let max_dist = opts.max_dist.unwrap_or_else(|| default_max_dist(m));
        // Doublets of the quadrangulation (a vertex of triangle valence 3
        // whose paired diagonals left it two edges) go first (§3.3.3).
        let all: Vec<VertexId> = k.live_vertices().collect();
        remove_doublets(&mut k, &all)?;
        let valence_targets = ValenceTargets::new(&k);
        let invariants = (k.num_components(), k.num_boundary_loops(), euler(&k));
        let nf = k.num_faces();
        Ok(Simplifier {
            m,
            fitmap,
            caster,
            opts: opts.clone(),
            max_dist,
            k,
            valence_targets,
            version: vec![0; nf],
            fs: vec![0.0; nf],
            fm: vec![0.0; nf],
            heap: BinaryHeap::new(),
            projections: 0,
            unprojectable: 0,
            invariants,
        })
    }

    /// φ of a batch of limit points; misses fall back to `None`.
    fn project(&mut self, pts: &[LimitPoint]) -> Result<Vec<Option<Projected>>> {
        let (p, st) = project_along_normals(self.caster, pts, self.max_dist)?;
        self.projections += st.points;
        self.unprojectable += st.unprojectable;
        Ok(p)
    }

    /// Recomputes centre, F_S, F_M and heap entries of `faces` (live ones),
    /// with one batch of φ queries.
    fn update_faces(&mut self, faces: &[FaceId]) -> Result<()> {
        let nf = self.k.num_faces();
        if self.version.len() < nf {
            self.version.resize(nf, 0);
            self.fs.resize(nf, 0.0);
            self.fm.resize(nf, 0.0);
        }
        let faces: Vec<FaceId> = faces
            .iter()
            .copied()
            .filter(|&f| !self.k.is_face_deleted(f))
            .collect();
        let k = &self.k;
        let pts: Vec<LimitPoint> = if faces.len() > 512 {
            use rayon::prelude::*;
            faces.par_iter().map(|&f| face_centre_limit(k, f)).collect()
        } else {
            faces.iter().map(|&f| face_centre_limit(k, f)).collect()
        };
        let proj = self.project(&pts)?;
        // A centre with no hit along its normal still needs Fitmap values:
        // take them at the closest point of M (the miss is counted).
        let miss: Vec<DVec3> = proj
            .iter()
            .zip(&pts)
            .filter(|(p, _)| p.is_none())
            .map(|(_, l)| l.position)
            .collect();
        let mut closest = if miss.is_empty() {
            Vec::new()
        } else {
            self.caster.closest_points(&miss, f64::INFINITY)?
        }
        .into_iter();
        for (i, &f) in faces.iter().enumerate() {
            let (tri, u, v) = match proj[i] {
                Some(p) => (p.triangle, p.u, p.v),
                None => match closest.next().flatten() {
                    Some(c) => (c.triangle, c.u, c.v),
                    None => (u32::MAX, 0.0, 0.0),
                },
            };
            let (s, mv) = if tri == u32::MAX {
                (0.0, 0.0)
            } else {
                (
                    self.fitmap.s_at(self.m, tri, u, v),
                    self.fitmap.m_at(self.m, tri, u, v),
                )
            };
            let fi = f.idx();
            self.version[fi] = self.version[fi].wrapping_add(1);
            self.fs[fi] = s;
            self.fm[fi] = mv;
            let q = super::ops::quad_positions(&self.k, f);
            for d in 0..2 {
                let len = (q[d] - q[d + 2]).length();
                let cost = len * s.max(0.0);
                self.heap
                    .push(Reverse((cost.to_bits(), f.0, d as u8, self.version[fi])));
            }
        }
        Ok(())
    }

    /// The M-fitmap test (§3.1.1 / §3.3.1 with the README's correction):
    /// every patch the collapse enlarges — the faces around both ends of the
    /// diagonal except the collapsed one — must keep `radius <= F_M` at its
    /// projected centre. Radius and centre are measured on the control
    /// polygon with the merged vertex at its planned position: that is
    /// known before the collapse in O(ring) (the limit patch after the
    /// collapse depends on the refit that follows it), and after the limit
    /// interpolation the control quad and its limit patch have nearly the
    /// same extent. F_M is the cached value at the face's projected limit
    /// centre, which the collapse moves little.
    fn m_test(&self, f: FaceId, a: VertexId, c: VertexId, pos: DVec3) -> bool {
        let k = &self.k;
        for v in [a, c] {
            for g in k.vertex_faces(v) {
                if g == f {
                    continue;
                }
                let mut q = super::ops::quad_positions(k, g);
                for (i, x) in k.face_vertices(g).enumerate() {
                    if x == a || x == c {
                        q[i] = pos;
                    }
                }
                let ctr = 0.25 * (q[0] + q[1] + q[2] + q[3]);
                let r = q.iter().map(|p| (*p - ctr).length()).fold(0.0, f64::max);
                if r > self.fm[g.idx()] {
                    return false;
                }
            }
        }
        true
    }

    fn run(
        &mut self,
        stats: &mut SimplifyStats,
        progress: &mut dyn FnMut(Progress) -> bool,
    ) -> Result<()> {
        let t0 = Instant::now();
        let all: Vec<FaceId> = self.k.live_faces().collect();
        stats.initial_faces = all.len();
        self.update_faces(&all)?;
        let target = self.opts.target_faces.unwrap_or(0);
        let mut stop = StopReason::NaturalEnd;
        while let Some(Reverse((_, fi, d, ver))) = self.heap.pop() {
            if self.k.num_live_faces() <= target {
                stop = StopReason::TargetFaces;
                break;
            }
            let f = FaceId(fi);
            if self.k.is_face_deleted(f) || self.version[f.idx()] != ver {
                continue;
            }
            let plan = match can_collapse_diagonal(&self.k, f, d as usize) {
                Ok(p) => p,
                Err(_) => {
                    stats.refused_topology += 1;
                    continue;
                }
            };
            if self.opts.m_fitmap && !self.m_test(f, plan.keep, plan.remove, plan.position) {
                stats.refused_m_fitmap += 1;
                continue;
            }
            let done = collapse_diagonal(&mut self.k, f, d as usize, Some(plan.position))?;
            stats.collapses += 1;
            stats.doublets += done.doublets.len();
            self.check_step("collapse")?;
            let mut touched = vec![done.keep, plan.sides[0], plan.sides[1]];
            touched.retain(|&v| !self.k.is_vertex_deleted(v));
            stats.rotations += self.rotate_around(done.keep, &mut touched)?;
            self.refit(&touched)?;
            if stats.collapses % 256 == 0 {
                let p = Progress {
                    faces: self.k.num_live_faces(),
                    initial_faces: stats.initial_faces,
                    collapses: stats.collapses,
                    seconds: t0.elapsed().as_secs_f64(),
                };
                if !progress(p) {
                    return Err(Error::Cancelled {
                        stage: "simplification".into(),
                    });
                }
            }
        }
        if self.k.num_live_faces() <= target {
            stop = StopReason::TargetFaces;
        }
        stats.stop = Some(stop);
        stats.projections = self.projections;
        stats.unprojectable = self.unprojectable;
        Ok(())
    }

    /// Test hook: the invariants after every step.
    fn check_step(&self, what: &str) -> Result<()> {
        if !self.opts.check_every_step {
            return Ok(());
        }
        let k = &self.k;
        k.validate()?;
        if !k.is_all_quads() {
            return Err(Error::topology(
                "mesh",
                format!("non-quad face after {what}"),
            ));
        }
        if let Some(v) = k.live_vertices().find(|&v| super::ops::is_doublet(k, v)) {
            return Err(Error::topology(
                v.to_string(),
                format!("doublet left after {what}"),
            ));
        }
        let now = (k.num_components(), k.num_boundary_loops(), euler(k));
        if now != self.invariants {
            return Err(Error::topology(
                "mesh",
                format!(
                    "{what} changed (components, boundary loops, Euler characteristic) from {:?} to {now:?}",
                    self.invariants
                ),
            ));
        }
        Ok(())
    }

    /// Edge rotations (§3.3.2) on the edges of the faces around `v`: each
    /// edge turns the way that lowers the valence energy most, if any does.
    fn rotate_around(&mut self, v: VertexId, touched: &mut Vec<VertexId>) -> Result<usize> {
        let mut edges: Vec<_> = self
            .k
            .vertex_faces(v)
            .flat_map(|f| self.k.face_halfedges(f).collect::<Vec<_>>())
            .map(|h| h.edge().halfedge())
            .collect();
        edges.sort_unstable();
        edges.dedup();
        let mut n = 0;
        for h in edges {
            let mut best: Option<(i64, Rotation)> = None;
            for dir in [Rotation::Ccw, Rotation::Cw] {
                if let Ok(x) = can_rotate_edge(&self.k, h, dir) {
                    let g = rotation_energy_gain(&self.k, &self.valence_targets, &x, dir);
                    if g > 0 && best.map_or(true, |b| g > b.0) {
                        best = Some((g, dir));
                    }
                }
            }
            if let Some((_, dir)) = best {
                let x = rotate_edge(&mut self.k, h, dir)?;
                touched.extend_from_slice(&x);
                n += 1;
                self.check_step("rotation")?;
            }
        }
        Ok(n)
    }

    /// Local refit (§3.4) of W = the touched vertices plus their 1-ring:
    /// `refit_rounds` times, Laplacian smoothing (each vertex midway to the
    /// mean of its faces' centroids; boundary vertices along the boundary,
    /// corners fixed) then `fit_sweeps` fixed-point sweeps `P += φ − L`
    /// towards the φ targets of the smoothed limit points. Then the faces
    /// around W get new centres, Fitmap values and heap entries.
    fn refit(&mut self, touched: &[VertexId]) -> Result<()> {
        let k = &self.k;
        let mut w: Vec<VertexId> = Vec::new();
        for &v in touched {
            if k.is_vertex_deleted(v) {
                continue;
            }
            w.push(v);
            w.extend(k.outgoing(v).map(|h| k.head(h)));
        }
        w.sort_unstable();
        w.dedup();
        let masks: Vec<Vec<(VertexId, f64)>> = w
            .iter()
            .map(|&v| vertex_limit_mask(k, v))
            .collect::<Result<_>>()?;
        for _ in 0..self.opts.refit_rounds {
            let k = &self.k;
            let smooth: Vec<DVec3> = w
                .iter()
                .map(|&v| {
                    let p = k.position(v);
                    let h0 = k.vertex_halfedge(v);
                    if k.is_boundary_halfedge(h0) {
                        if k.valence(v) == 2 {
                            return p;
                        }
                        let next = k.position(k.head(h0));
                        let prev = k.position(k.tail(k.prev(h0)));
                        return 0.5 * p + 0.25 * (next + prev);
                    }
                    let mut c = DVec3::ZERO;
                    let mut n = 0.0;
                    for f in k.vertex_faces(v) {
                        c += centroid(k, f);
                        n += 1.0;
                    }
                    0.5 * (p + c / n)
                })
                .collect();
            for (&v, p) in w.iter().zip(smooth) {
                self.k.positions_mut()[v.idx()] = p;
            }
            let k = &self.k;
            let pts: Vec<LimitPoint> = w
                .iter()
                .zip(&masks)
                .map(|(&v, m)| {
                    let n = vertex_normal(k, v);
                    // A LimitPoint whose du × dv is the unit normal.
                    let (du, dv) = n.any_orthonormal_pair();
                    LimitPoint {
                        position: limit_of(k, m),
                        du,
                        dv,
                    }
                })
                .collect();
            let proj = self.project(&pts)?;
            let targets: Vec<DVec3> = proj
                .iter()
                .zip(&pts)
                .map(|(p, l)| p.map_or(l.position, |p| p.point))
                .collect();
            for _ in 0..self.opts.fit_sweeps {
                let delta: Vec<DVec3> = masks
                    .iter()
                    .zip(&targets)
                    .map(|(m, t)| *t - limit_of(&self.k, m))
                    .collect();
                for (&v, d) in w.iter().zip(delta) {
                    self.k.positions_mut()[v.idx()] += d;
                }
            }
        }
        let k = &self.k;
        let mut faces: Vec<FaceId> = w.iter().flat_map(|&v| k.vertex_faces(v)).collect();
        faces.sort_unstable();
        faces.dedup();
        self.update_faces(&faces)
    }
}
