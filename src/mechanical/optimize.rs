//! Local optimisation and enrichment (Lavoué et al. §7), on the assembled
//! control mesh with every curve control point fixed (§7.3: "boundary
//! control points are fixed, to insure that no crack will appear"; here it
//! also keeps the crease curves where §5 fitted them).
//!
//! Geometry (§7.1): samples of the limit surface (the ptex grids of
//! [`crate::fit::patch_samples`], about one per vertex of M), their feet
//! on M (closest point within the sample's region, see [`optimize`]), and
//! a linear least-squares update of the free control points plus a small
//! umbrella fairness on the update (as in [`crate::fit`]). The objective is
//! the paper's: the squared-distance minimisation of Pottmann and
//! Leopoldseder ([`Objective::Sdm`], eq. 4: normal residual in full,
//! tangential residuals weighted by `dκ/(1 + dκ)` in the foot triangle's
//! principal frame, [`tri_frames`]); the point distance `Σ |s − f|²`
//! ([`Objective::Point`]) is kept for comparison (SDM fits closer at the
//! same faces). Up to `m₀` iterations per
//! round, each accepted only if the squared distance to the (new) closest
//! feet falls, stopping early when it falls by less than 1 %.
//!
//! Enrichment (§7.2): faces whose RMS sample distance exceeds the limit form
//! error fields (connected over non-crease edges). A field whose samples
//! above `D_max/2` are mostly below `0.8 D_max` is a *local* error: its
//! faces are merged and one point inserted, connected to the merged
//! polygon's corners (case 1); otherwise (a plateau, or a single face) every
//! face of the field is enriched (case 2): its non-crease edges are cut at
//! their midpoints and it is split into one face per *sector* — from one
//! midpoint, through the corners up to the next midpoint, to a new centre
//! point (Catmull-Clark's split where every edge is cut). Crease edges are
//! never cut, so a face with two cut edges (a quad of a strip between two
//! crease curves, e.g. a fillet spanned by its boundary curves alone) is
//! cut along the chord between their midpoints instead, with no centre:
//! the strip gains the row of points across it that its profile lacks, at
//! one face per face (a face with one cut edge just gains its midpoint).
//! Fanning such a quad into triangles around a centre, as before, gave six
//! faces per quad for the same row, many more faces for no lower error.
//!
//! Regions are independent (their boundaries are creases of fixed curve
//! points), which the loop uses twice: a geometry step is accepted per
//! region (a region whose squared distance it raises keeps its points), and
//! each region's best measured state is kept. A region whose RMS rose by
//! more than 2 % after an enrichment (a case-1 fan folding over a curved
//! region) is put back
//! and, in the same round, enriched by case 2 where its best state was
//! over the limit; it is enriched by case 2 only from then on, and a
//! second regression freezes it at its best state. The others keep their
//! progress; the output is the best state of every region. Before this,
//! one bad region ended the whole loop (the stall test saw the total RMS
//! rise) and stopped far above the limit. A
//! restored region used to wait a round before being enriched, and that
//! idle round could read as a stall and end the loop with faces over the
//! limit and nothing refined.
//!
//! RMS against faces on fandisk, against Lavoué et al.'s Table 2: see
//! docs/status.md, "Measurements behind the code".

use std::collections::{HashMap, HashSet};

use crate::error::{Error, Result};
use crate::fit::{push_frame_rows, sdm_tangent_weight};
use crate::mesh::{ControlMesh, TriMesh, INFINITELY_SHARP};
use crate::raycast::{make_raycaster, RayBackend, RayCaster};
use crate::solve::{least_squares, LsqOptions, Triplets};
use crate::subdiv::{make_evaluator, Backend, EvalOptions};
use crate::DVec3;

/// The control mesh under construction as polygons (rebuilt into a
/// [`ControlMesh`] after each topology change).
#[derive(Clone, Debug)]
pub struct Polys {
    pub positions: Vec<DVec3>,
    pub faces: Vec<Vec<u32>>,
    /// Vertices `0..fixed` are curve control points (never moved).
    pub fixed: usize,
    pub creases: HashSet<(u32, u32)>,
    pub corners: Vec<u32>,
    /// Region (of the segmentation) of each face: the samples of a face
    /// are fitted to that region of M only.
    pub face_region: Vec<u32>,
}

impl Polys {
    /// Number of regions the faces refer to (one past the largest index).
    pub fn region_count(&self) -> usize {
        self.face_region
            .iter()
            .map(|&r| r as usize + 1)
            .max()
            .unwrap_or(0)
    }

    pub fn to_control(&self) -> Result<ControlMesh> {
        let mut c = ControlMesh::from_polygons(self.positions.clone(), &self.faces)?;
        let mut cr: Vec<&(u32, u32)> = self.creases.iter().collect();
        cr.sort_unstable();
        for &&(a, b) in &cr {
            use crate::mesh::VertexId;
            if c.find_halfedge(VertexId(a), VertexId(b)).is_some() {
                c.set_crease(VertexId(a), VertexId(b), INFINITELY_SHARP)?;
            }
        }
        for &v in &self.corners {
            c.set_corner(crate::mesh::VertexId(v), INFINITELY_SHARP)?;
        }
        Ok(c)
    }
}

/// Per-round record.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Round {
    pub faces: usize,
    pub vertices: usize,
    /// Mean and RMS sample distance after the geometry step, ‰ of diagonal.
    pub mean_permille: f64,
    pub rms_permille: f64,
    pub max_permille: f64,
    pub geometry_iterations: usize,
    pub faces_over_limit: usize,
    pub local_fields: usize,
    pub diffuse_fields: usize,
    /// RMS distance per region of the segmentation (to the region's own
    /// part of M, the distance the fit minimises), ‰ of the diagonal.
    pub region_rms_permille: Vec<f64>,
    /// Control faces per region.
    pub region_faces: Vec<usize>,
}

/// Objective of the geometry step (§7.1): the crate's one fit objective.
/// [`Objective::Point`] is the point distance `|s − f|²` (x, y, z
/// separate); [`Objective::Sdm`] the squared-distance minimisation
/// (Pottmann & Leopoldseder, the paper's choice, §7.1 eq. 4):
/// `x₃² + w₁x₁² + w₂x₂²` in the frame of the foot triangle (see
/// [`TriFrame`]).
pub use crate::fit::Objective;

/// Normal, principal directions and curvatures of one triangle of M, for
/// the SDM objective.
#[derive(Copy, Clone, Debug)]
pub struct TriFrame {
    pub normal: DVec3,
    pub e1: DVec3,
    pub k1: f64,
    pub k2: f64,
}

/// Per-triangle SDM frames from the vertex tensors of §3.1: the face
/// normal (a CAD tessellation's faces are exact within a region, where an
/// interpolated vertex normal bends towards the neighbouring region at a
/// feature) and the mean of the tensors `k_max d_max d_maxᵀ + k_min d_min
/// d_minᵀ` of the triangle's vertices that touch no sharp edge, projected
/// onto the face plane. A vertex on a sharp edge carries the feature's
/// dihedral in its normal-cycle tensor, not the region's curvature; a
/// triangle with only such vertices gets `k = ∞`, i.e. `w = 1`: point
/// distance, the safe choice next to a crease.
pub fn tri_frames(
    mesh: &TriMesh,
    curv: &[super::VertexCurvature],
    on_sharp: &[bool],
) -> Vec<TriFrame> {
    mesh.triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|v| mesh.positions[v as usize]);
            let n = (b - a).cross(c - a).normalize_or_zero();
            let e = (b - a).normalize_or_zero();
            let f = n.cross(e);
            // 2×2 tensor in the (e, f) basis.
            let (mut txx, mut txy, mut tyy, mut cnt) = (0.0, 0.0, 0.0, 0);
            for &v in t {
                let v = v as usize;
                if on_sharp[v] {
                    continue;
                }
                let k = &curv[v];
                for (kk, d) in [(k.k_max, k.d_max), (k.k_min, k.d_min)] {
                    let (x, y) = (d.dot(e), d.dot(f));
                    txx += kk * x * x;
                    txy += kk * x * y;
                    tyy += kk * y * y;
                }
                cnt += 1;
            }
            if cnt == 0 || n == DVec3::ZERO {
                return TriFrame {
                    normal: n,
                    e1: e,
                    k1: f64::INFINITY,
                    k2: f64::INFINITY,
                };
            }
            let c = cnt as f64;
            let (txx, txy, tyy) = (txx / c, txy / c, tyy / c);
            let half = 0.5 * (txx + tyy);
            let r = (0.25 * (txx - tyy).powi(2) + txy * txy).sqrt();
            let (k1, k2) = (half + r, half - r);
            let ang = 0.5 * (2.0 * txy).atan2(txx - tyy);
            TriFrame {
                normal: n,
                e1: ang.cos() * e + ang.sin() * f,
                k1,
                k2,
            }
        })
        .collect()
}

pub struct OptimizeOptions {
    pub objective: Objective,
    /// SDM's smallest tangential weight (as `crate::fit`'s): 0.05.
    pub sdm_tangent_floor: f64,
    pub max_error: f64,
    pub m0: usize,
    pub max_rounds: usize,
    pub max_faces: usize,
    pub fairness: f64,
}

/// Runs §7.3's loop; returns the rounds. `polys` ends with every region's
/// best measured state, then one converged geometry pass on it (the
/// rounds' figures are from before that pass).
///
/// Each round: the geometry step (§7.1, `geometry`), the errors per face
/// and region (`SampleErrors`), each region's best state kept
/// (`RegionBook::record`), the stop rules, then enrichment (§7.2,
/// `enrich`) of the faces over the limit and the restore of the regions
/// that regressed (`RegionBook::enrich_restored`).
pub fn optimize(
    mesh: &TriMesh,
    caster: &dyn RayCaster,
    reach: &[Vec<u32>],
    polys: &mut Polys,
    frames: &[TriFrame],
    o: &OptimizeOptions,
) -> Result<Optimized> {
    let diag = mesh.bbox_diagonal();
    let limit = o.max_error * diag;
    let mut rounds = Vec::new();
    let mut book = RegionBook::default();
    // §7.1's foot points: the closest point of M *within the sample's own
    // region*. Along the limit normal (φ) or unrestricted, a sample near a
    // crease lands on the neighbouring face, and the update pulls the
    // surface across the feature: the error rises instead of falling.
    // The restriction is to the region's triangles and the two rings of
    // its neighbours' triangles across *smooth* boundary edges (`reach`,
    // see `super::region_reach`): a crease on a smooth boundary is a
    // smoothed zigzag, and the samples between it and the staircase
    // belong to M all the same. One BVH per region, built once.
    let region_casters = region_casters(mesh, reach)?;
    for round in 0..=o.max_rounds {
        let Geometry {
            locs,
            pts,
            feet,
            iters,
        } = geometry(
            mesh.positions.len(),
            &region_casters,
            polys,
            frames,
            o,
            limit,
            o.m0,
            0.01,
        )?;
        let Measured {
            err,
            dists,
            face_over,
            over_all,
            mut rec,
        } = measure(caster, polys, &locs, &pts, &feet, iters, limit, diag)?;
        let nf = polys.faces.len();
        let nreg = err.rsum.len();
        book.grow(nreg);
        let regressed = book.record(polys, &err, &face_over);
        let any_regressed = regressed.iter().any(|&x| x);
        let over: Vec<usize> = (0..nf)
            .filter(|&f| {
                let r = polys.face_region[f] as usize;
                face_over[f] && !regressed[r] && !book.frozen[r]
            })
            .collect();
        // Progress is judged per region (`RegionBook::record`): a region
        // whose enrichment bought less than 2 % of its RMS is enriched
        // differently, then frozen, while the others go on. A regression
        // is answered by the restore below (and case 2 from then on).
        // Nothing left to enrich: every face over the limit lies in a
        // frozen region.
        let idle = over.is_empty()
            && (0..nreg).all(|r| !regressed[r] || book.frozen[r] || book.best[r].is_none());
        if over_all == 0 || idle || round == o.max_rounds || nf >= o.max_faces {
            rounds.push(rec);
            break;
        }
        book.mark_enriched(polys, &over, &regressed);
        if !over.is_empty() {
            let (local, diffuse) =
                enrich(polys, &over, &locs_faces(&locs), &dists, &book.allow_local);
            rec.local_fields = local;
            rec.diffuse_fields = diffuse;
        }
        if any_regressed && restore_regions(polys, &book.best, &regressed) {
            rec.diffuse_fields += book.enrich_restored(polys, &regressed);
        }
        rounds.push(rec);
    }
    let all: Vec<bool> = book.best.iter().map(|b| b.is_some()).collect();
    // (A shared free vertex, which no layout here has, leaves it as is.)
    let _ = restore_regions(polys, &book.best, &all);
    split_doublets(polys);
    // A last geometry pass on the output, run to convergence: the
    // umbrella damping of each step (λ|Lδ|², on the update, so it does not
    // move the minimum) makes the alternating foot-point iteration converge
    // linearly, and a round's 1 % gain stop leaves a few per cent of RMS on
    // the table. Up to 2·m₀ more steps while a step gains 0.1 % (fandisk,
    // `--max-error 1.1e-3`: RMS 0.312‰ → 0.306‰; at the default 3e-3 it
    // stops after 4 steps, 0.744‰ → 0.733‰). Per-region acceptance as in
    // the rounds: no region's distance rises.
    let g = geometry(
        mesh.positions.len(),
        &region_casters,
        polys,
        frames,
        o,
        limit,
        2 * o.m0,
        1e-3,
    )?;
    // The figures of the surface as written: the restore of each region's
    // best state, the doublet splits and this pass all change it after the
    // last round was measured, so `--max-error`'s verdict is taken here.
    let output = measure(
        caster, polys, &g.locs, &g.pts, &g.feet, g.iters, limit, diag,
    )?
    .rec;
    Ok(Optimized { rounds, output })
}

/// What [`optimize`] measured: each round (before its enrichment) and the
/// control mesh it returns (after the final geometry pass).
pub struct Optimized {
    pub rounds: Vec<Round>,
    pub output: Round,
}

/// One measurement of the fitted samples: per-face and per-region errors
/// of the restricted distances (what enrichment and `--max-error` judge)
/// and the round record (unrestricted distances to M).
struct Measured {
    err: SampleErrors,
    dists: Vec<f64>,
    face_over: Vec<bool>,
    over_all: usize,
    rec: Round,
}

#[allow(clippy::too_many_arguments)]
fn measure(
    caster: &dyn RayCaster,
    polys: &Polys,
    locs: &[crate::subdiv::SurfaceLocation],
    pts: &[DVec3],
    feet: &[Option<DVec3>],
    iters: usize,
    limit: f64,
    diag: f64,
) -> Result<Measured> {
    // Restricted distance drives enrichment; the reported figures are
    // the honest unrestricted distance to M.
    let dists: Vec<f64> = pts
        .iter()
        .zip(feet)
        .map(|(p, f)| f.map_or(f64::NAN, |f| (*p - f).length()))
        .collect();
    let report: Vec<f64> = caster
        .closest_points(pts, f64::INFINITY)?
        .iter()
        .map(|c| c.map_or(f64::NAN, |c| c.distance))
        .collect();
    let err = SampleErrors::new(polys, locs, &dists);
    let face_over: Vec<bool> = err.frms.iter().map(|&e| e > limit).collect();
    let over_all = face_over.iter().filter(|&&x| x).count();
    let rec = round_record(polys, &report, &err, iters, over_all, diag);
    Ok(Measured {
        err,
        dists,
        face_over,
        over_all,
        rec,
    })
}

/// Removes every interior vertex of valence 2 (a *doublet*: two faces
/// sharing two consecutive edges, which Fitmaps §3.3 removes and
/// OpenSubdiv pins in place, so its surface is not the one fitted) by
/// splitting each of its two faces that has four or more corners along
/// the diagonal from the vertex to the corner opposite it. The vertex
/// keeps its place and its creases, so a crease curve through it (§5's
/// control points, fixed) is unchanged: an infinitely sharp crease's limit
/// depends on its crease vertices only. Merging the two faces instead, as
/// §3.3 does on all-quad meshes, would drop the vertex from its crease
/// curve. Valence becomes 4 (3 next to a triangle); the final geometry
/// pass then refits the free vertices around it. Returns the number of
/// vertices fixed.
pub fn split_doublets(p: &mut Polys) -> usize {
    let mut fixed = 0;
    loop {
        let ef = edge_faces(&p.faces);
        let mut nbrs: Vec<Vec<u32>> = vec![Vec::new(); p.positions.len()];
        let mut boundary = vec![false; p.positions.len()];
        for (&(a, b), fs) in &ef {
            nbrs[a as usize].push(b);
            nbrs[b as usize].push(a);
            if fs.len() == 1 {
                boundary[a as usize] = true;
                boundary[b as usize] = true;
            }
        }
        // Lowest vertex first: deterministic whatever the hash order.
        let Some(v) = (0..p.positions.len()).find(|&v| nbrs[v].len() == 2 && !boundary[v]) else {
            return fixed;
        };
        let faces: Vec<usize> = (0..p.faces.len())
            .filter(|&f| p.faces[f].contains(&(v as u32)))
            .collect();
        let mut split_any = false;
        for f in faces {
            let face = p.faces[f].clone();
            let n = face.len();
            if n < 4 {
                continue;
            }
            let k = face.iter().position(|&x| x == v as u32).unwrap_or(0);
            // v, then corners k+1 ..= k+n/2 | k+n/2 .. k+n-1, v.
            let half = n / 2;
            let first: Vec<u32> = (0..=half).map(|i| face[(k + i) % n]).collect();
            let mut second: Vec<u32> = (half..n).map(|i| face[(k + i) % n]).collect();
            second.push(v as u32);
            p.faces[f] = first;
            p.faces.push(second);
            let region = p.face_region[f];
            p.face_region.push(region);
            split_any = true;
        }
        if !split_any {
            // Two triangles: a closed pillow, no mesh of this pipeline.
            return fixed;
        }
        fixed += 1;
    }
}

/// Squared restricted sample distances summed per face and per region
/// (§7.2's error per face is its samples' RMS distance).
struct SampleErrors {
    /// RMS distance per face.
    frms: Vec<f64>,
    /// Sum of squared distances and sample count per region.
    rsum: Vec<f64>,
    rcnt: Vec<usize>,
}

impl SampleErrors {
    fn new(polys: &Polys, locs: &[crate::subdiv::SurfaceLocation], dists: &[f64]) -> Self {
        let nf = polys.faces.len();
        let mut fsum = vec![0.0; nf];
        let mut fcnt = vec![0usize; nf];
        for (l, d) in locs.iter().zip(dists) {
            if d.is_finite() {
                let f = l.face.idx();
                fsum[f] += d * d;
                fcnt[f] += 1;
            }
        }
        let frms: Vec<f64> = (0..nf)
            .map(|f| (fsum[f] / fcnt[f].max(1) as f64).sqrt())
            .collect();
        let nreg = polys.region_count();
        let mut rsum = vec![0.0; nreg];
        let mut rcnt = vec![0usize; nreg];
        for (l, d) in locs.iter().zip(dists) {
            if d.is_finite() {
                let r = polys.face_region[l.face.idx()] as usize;
                rsum[r] += d * d;
                rcnt[r] += 1;
            }
        }
        SampleErrors { frms, rsum, rcnt }
    }

    /// RMS distance of region `r` (`None` without samples).
    fn region_rms(&self, r: usize) -> Option<f64> {
        (self.rcnt[r] > 0).then(|| (self.rsum[r] / self.rcnt[r] as f64).sqrt())
    }
}

/// The best state met per region (by the region's RMS): enrichment is
/// not guaranteed to lower the error (a case-1 fan over a curved region
/// can fold), and the result must never be worse than a state measured.
/// Regions are independent once their boundary control points are fixed
/// (§7.3: "boundary control points are fixed"; every region boundary is
/// a crease, which no enrichment splits), so a region whose error rose is
/// put back as it was, and from then on enriched by case 2 only (§7.2's
/// "lack of degrees of freedom" answer, which only adds points) — the
/// other regions keep their progress.
#[derive(Default)]
struct RegionBook {
    best: Vec<Option<RegionState>>,
    /// Case 1 (merge and insert) still allowed.
    allow_local: Vec<bool>,
    /// Regions that regressed after a case-2 enrichment, or that case 2
    /// failed to improve [`MAX_STRIKES`] − 1 times: left at their best
    /// state, never enriched again.
    frozen: Vec<bool>,
    /// Each region's RMS at the last round and whether that round
    /// enriched it: the per-region progress test of [`RegionBook::record`].
    last_rms: Vec<Option<f64>>,
    enriched: Vec<bool>,
    /// Enrichments of the region that bought less than 2 % of its RMS.
    strikes: Vec<usize>,
    /// Times the region was rebuilt (see [`RegionBook::freeze_or_rebuild`]).
    rebuilt: Vec<usize>,
    /// The region is to be rebuilt this round.
    rebuild_now: Vec<bool>,
}

/// Enrichments without progress after which a region is frozen (see
/// [`RegionBook::record`]): the first bars case 1, the next ones are
/// case 2 refinements of its faces over the limit, which add points
/// everywhere they are cut; past that the error sits where no new point
/// reaches it.
const MAX_STRIKES: usize = 3;

/// Rebuilds of a region before it is frozen (see
/// [`RegionBook::freeze_or_rebuild`]).
const MAX_REBUILDS: usize = 1;

/// The largest valence enrichment may give a new point (case 1's merged
/// fan, a fan around a face closed by creases): a fan point joined to
/// every corner of a long loop is one vertex carrying a whole region (an
/// extraordinary vertex of valence 49 was seen on a casting), which
/// neither fits a curved region (the fan folds) nor evaluates well.
pub const MAX_FAN_VALENCE: usize = 12;

impl RegionBook {
    fn grow(&mut self, nreg: usize) {
        if self.best.len() < nreg {
            self.best.resize(nreg, None);
            self.allow_local.resize(nreg, true);
            self.frozen.resize(nreg, false);
            self.last_rms.resize(nreg, None);
            self.enriched.resize(nreg, false);
            self.strikes.resize(nreg, 0);
            self.rebuilt.resize(nreg, 0);
            self.rebuild_now.resize(nreg, false);
        }
    }

    /// Compares each region's RMS with its best: a better one is recorded
    /// (with its faces over the limit), a worse one by more than 2 % marks
    /// the region regressed (returned per region), which bars case 1 for
    /// it and, the second time, freezes it.
    ///
    /// An enriched region that did not improve by 2 % either is no more a
    /// reason to stop the whole loop (one stuck region used to end it for
    /// all, and a casting ended at 10‰ with 54 faces over the limit): it
    /// takes a strike. The first bars case 1 (a field's merged fan can be
    /// the very fan it was built from, so case 1 may repeat itself
    /// forever); the next ones leave it to case 2, which always adds
    /// points; at [`MAX_STRIKES`] it is frozen at its best state.
    fn record(&mut self, polys: &Polys, err: &SampleErrors, face_over: &[bool]) -> Vec<bool> {
        let nreg = err.rsum.len();
        let mut regressed = vec![false; nreg];
        for (r, worse) in regressed.iter_mut().enumerate() {
            let Some(e) = err.region_rms(r) else {
                continue;
            };
            // 2 %: the stall margin of `optimize`; a region within it of
            // its best is not worse (the SDM steps move it by rounding
            // noise), and keeps its best state on record.
            match &self.best[r] {
                Some(b) if e > 1.02 * b.rms => {
                    *worse = true;
                    // A second regression: case 2 failed too (after the
                    // first one the region is enriched by case 2 only).
                    // Faces added where the error is will not help.
                    if !self.allow_local[r] {
                        self.freeze_or_rebuild(r);
                    }
                    self.allow_local[r] = false;
                }
                Some(b) if e >= b.rms => {}
                _ => self.best[r] = Some(region_state(polys, r as u32, e, face_over)),
            }
            let stuck = self.enriched[r] && self.last_rms[r].is_some_and(|p| e > 0.98 * p);
            if stuck && !*worse {
                self.strikes[r] += 1;
                self.allow_local[r] = false;
                if self.strikes[r] >= MAX_STRIKES {
                    self.freeze_or_rebuild(r);
                }
            }
            self.last_rms[r] = Some(e);
            self.enriched[r] = false;
            // A region rebuilt this round is put back to its best state
            // first, as a regressed one is.
            *worse |= self.rebuild_now[r];
        }
        regressed
    }

    /// A region whose enrichment where the error is failed: the first
    /// time it is *rebuilt*, its best state put back and every one of its
    /// faces split by case 2 (points everywhere, not only where the error
    /// peaks: on a half-pipe between two crease arcs the error of one face
    /// is often the fold of its neighbour), and enriched as before from
    /// there; past [`MAX_REBUILDS`] it is frozen at its best state.
    fn freeze_or_rebuild(&mut self, r: usize) {
        if self.rebuilt[r] >= MAX_REBUILDS {
            self.frozen[r] = true;
        } else {
            self.rebuilt[r] += 1;
            self.rebuild_now[r] = true;
            self.strikes[r] = 0;
        }
    }

    /// Notes which regions the faces `over` (and the restored ones) put
    /// through enrichment this round.
    fn mark_enriched(&mut self, polys: &Polys, over: &[usize], regressed: &[bool]) {
        for &f in over {
            self.enriched[polys.face_region[f] as usize] = true;
        }
        for (r, &x) in regressed.iter().enumerate() {
            if x && !self.frozen[r] {
                self.enriched[r] = true;
            }
        }
    }

    /// A restored region is enriched at once, by case 2, where its best
    /// state had faces over the limit (recorded with it). Waiting a round
    /// to re-measure it left it idle while the others moved on, and the
    /// round after could read as a stall (the total RMS barely moves when
    /// only the restored regions change) and end the loop with faces still
    /// over the limit and nothing refined ("over 25, local 0, diffuse 0"
    /// on fandisk at 1.1 × 10⁻³). Returns the diffuse fields enriched.
    fn enrich_restored(&mut self, polys: &mut Polys, regressed: &[bool]) -> usize {
        let nreg = regressed.len();
        let mut again = Vec::new();
        let mut k = vec![0usize; nreg];
        for (f, &r) in polys.face_region.iter().enumerate() {
            let r = r as usize;
            if regressed[r] && !self.frozen[r] {
                if let Some(Some(b)) = self.best.get(r) {
                    if self.rebuild_now[r] || b.over.get(k[r]).copied().unwrap_or(false) {
                        again.push(f);
                    }
                }
                k[r] += 1;
            }
        }
        self.rebuild_now.iter_mut().for_each(|x| *x = false);
        if again.is_empty() {
            return 0;
        }
        let no_local = vec![false; nreg];
        enrich(polys, &again, &[], &[], &no_local).1
    }
}

/// The round's figures for `report.json`: mean, RMS and max of the
/// unrestricted distances `report`, and the RMS and faces per region.
fn round_record(
    polys: &Polys,
    report: &[f64],
    err: &SampleErrors,
    iters: usize,
    over_all: usize,
    diag: f64,
) -> Round {
    let nreg = err.rsum.len();
    let region_rms_permille: Vec<f64> = (0..nreg)
        .map(|r| 1000.0 * (err.rsum[r] / err.rcnt[r].max(1) as f64).sqrt() / diag)
        .collect();
    let ok: Vec<f64> = report.iter().copied().filter(|d| d.is_finite()).collect();
    let cnt = ok.len().max(1) as f64;
    let mut region_faces = vec![0usize; nreg];
    for &r in &polys.face_region {
        region_faces[r as usize] += 1;
    }
    Round {
        faces: polys.faces.len(),
        vertices: polys.positions.len(),
        mean_permille: 1000.0 * ok.iter().sum::<f64>() / cnt / diag,
        rms_permille: 1000.0 * (ok.iter().map(|d| d * d).sum::<f64>() / cnt).sqrt() / diag,
        max_permille: 1000.0 * ok.iter().copied().fold(0.0, f64::max) / diag,
        geometry_iterations: iters,
        faces_over_limit: over_all,
        local_fields: 0,
        diffuse_fields: 0,
        region_rms_permille,
        region_faces,
    }
}

/// The fitted samples of one topology: sample locations, limit points,
/// their feet on M (restricted to the sample's region) and the geometry
/// iterations taken.
struct Geometry {
    locs: Vec<crate::subdiv::SurfaceLocation>,
    pts: Vec<DVec3>,
    feet: Vec<Option<DVec3>>,
    iters: usize,
}

/// §7.1's geometry step on `polys`' current topology: up to `iterations`
/// least-squares updates of the free control points, each accepted per
/// region only where it lowers the squared distance to the new closest
/// feet, stopping when a step gains less than `min_gain` of the energy.
#[allow(clippy::too_many_arguments)]
fn geometry(
    mesh_vertices: usize,
    region_casters: &[RegionCaster],
    polys: &mut Polys,
    frames: &[TriFrame],
    o: &OptimizeOptions,
    limit: f64,
    iterations: usize,
    min_gain: f64,
) -> Result<Geometry> {
    let control = polys.to_control()?;
    let (locs, _) = crate::fit::patch_samples(&control, mesh_vertices, 3);
    // Stencils once per topology (§7.3: the geometry iterations share it).
    let eval = make_evaluator(
        Backend::Osd,
        &control,
        &EvalOptions::default().with_isolation_level(5),
    )?;
    let st = eval.stencils(&locs)?;
    let sample_region: Vec<u32> = locs
        .iter()
        .map(|l| polys.face_region[l.face.idx()])
        .collect();
    let nfree = polys.positions.len() - polys.fixed;
    let lap = umbrella(&control, polys.fixed);
    let mut iters: usize = 0;
    let mut pts: Vec<DVec3> = st
        .apply(&polys.positions)
        .iter()
        .map(|s| s.position)
        .collect();
    let (mut feet, mut foot_tri) = region_feet(region_casters, &sample_region, &pts)?;
    let mut energy = sq_energy(&pts, &feet);
    let nreg_now = polys.region_count();
    // Region of each free vertex (the faces using it all lie in one
    // region: region boundaries are creases of fixed points).
    let mut vert_region = vec![u32::MAX; nfree];
    for (f, poly) in polys.faces.iter().enumerate() {
        for &v in poly {
            if (v as usize) >= polys.fixed {
                vert_region[v as usize - polys.fixed] = polys.face_region[f];
            }
        }
    }
    for _ in 0..iterations {
        if nfree == 0 || energy.sqrt() <= 0.1 * limit * (pts.len() as f64).sqrt() {
            break;
        }
        let delta = match o.objective {
            Objective::Point => solve_step(&st, &pts, &feet, polys.fixed, nfree, &lap, o.fairness)?,
            Objective::Sdm => solve_step_sdm(
                &st,
                &pts,
                &feet,
                &foot_tri,
                frames,
                polys.fixed,
                nfree,
                &lap,
                o,
            )?,
        };
        let mut trial = polys.positions.clone();
        for (v, d) in delta.iter().enumerate() {
            trial[polys.fixed + v] += *d;
        }
        let mut tpts: Vec<DVec3> = st.apply(&trial).iter().map(|s| s.position).collect();
        let (mut tfeet, mut ttri) = region_feet(region_casters, &sample_region, &tpts)?;
        // Per region: the regions are independent (their free points
        // move only their own samples), so a region whose energy the
        // step raised (the fairness term, or feet jumping) keeps its
        // old points while the others take the step. Each region's
        // error then never rises within a round.
        let e_old = region_energy(&pts, &feet, &sample_region, nreg_now);
        let e_new = region_energy(&tpts, &tfeet, &sample_region, nreg_now);
        let worse: Vec<bool> = (0..nreg_now).map(|r| e_new[r] > e_old[r]).collect();
        if worse.iter().any(|&w| w) {
            for (v, &r) in vert_region.iter().enumerate() {
                if r != u32::MAX && worse[r as usize] {
                    trial[polys.fixed + v] = polys.positions[polys.fixed + v];
                }
            }
            for (k, &r) in sample_region.iter().enumerate() {
                if worse[r as usize] {
                    tpts[k] = pts[k];
                    tfeet[k] = feet[k];
                    ttri[k] = foot_tri[k];
                }
            }
        }
        let e = sq_energy(&tpts, &tfeet);
        // Alternating minimisation: the solve lowers Σ|s − f|² for the
        // old feet (the fairness term only damps it) and the new closest
        // feet lower it again, so `e` falls; a rise can only come from
        // the regularisation and ends the round.
        if e >= energy {
            break;
        }
        let gain = 1.0 - e / energy;
        polys.positions = trial;
        pts = tpts;
        feet = tfeet;
        foot_tri = ttri;
        energy = e;
        iters += 1;
        if gain < min_gain {
            break;
        }
    }
    Ok(Geometry {
        locs,
        pts,
        feet,
        iters,
    })
}

fn locs_faces(locs: &[crate::subdiv::SurfaceLocation]) -> Vec<u32> {
    locs.iter().map(|l| l.face.0).collect()
}

/// Umbrella rows over the free vertices (fixed neighbours have δ = 0).
fn umbrella(control: &ControlMesh, fixed: usize) -> Vec<Vec<(u32, f64)>> {
    control
        .vertices()
        .skip(fixed)
        .map(|v| {
            let nb: Vec<u32> = control.outgoing(v).map(|h| control.head(h).0).collect();
            let w = 1.0 / nb.len().max(1) as f64;
            std::iter::once((v.0 - fixed as u32, 1.0))
                .chain(
                    nb.into_iter()
                        .filter(|&u| u as usize >= fixed)
                        .map(|u| (u - fixed as u32, -w)),
                )
                .collect()
        })
        .collect()
}

/// One region's faces and free vertices (free ids renumbered from
/// `fixed`), with its RMS distance when recorded.
#[derive(Clone, Debug)]
struct RegionState {
    rms: f64,
    /// Per face (in `faces` order): its RMS was over the limit.
    over: Vec<bool>,
    faces: Vec<Vec<u32>>,
    free: Vec<DVec3>,
}

fn region_state(p: &Polys, r: u32, rms: f64, face_over: &[bool]) -> RegionState {
    let mut map: HashMap<u32, u32> = HashMap::new();
    let mut free = Vec::new();
    let mut faces = Vec::new();
    let mut over = Vec::new();
    for (f, poly) in p.faces.iter().enumerate() {
        if p.face_region[f] != r {
            continue;
        }
        over.push(face_over.get(f).copied().unwrap_or(false));
        faces.push(
            poly.iter()
                .map(|&v| {
                    if (v as usize) < p.fixed {
                        v
                    } else {
                        *map.entry(v).or_insert_with(|| {
                            free.push(p.positions[v as usize]);
                            (p.fixed + free.len() - 1) as u32
                        })
                    }
                })
                .collect(),
        );
    }
    RegionState {
        rms,
        over,
        faces,
        free,
    }
}

/// Rebuilds `p` region by region: the regions flagged in `restore` from
/// their recorded states, the others as they are. Faces come out grouped
/// by region (deterministic order); fixed vertices, creases and corners
/// are untouched (they only involve vertices below `fixed`).
///
/// The regions must not share a free vertex (true of every layout built
/// here: region boundaries are creases of fixed points, and enrichment
/// never cuts a crease); if one is shared all the same, nothing is
/// restored rather than crack the mesh. Returns whether it restored.
fn restore_regions(p: &mut Polys, states: &[Option<RegionState>], restore: &[bool]) -> bool {
    let mut owner = vec![u32::MAX; p.positions.len().saturating_sub(p.fixed)];
    for (f, poly) in p.faces.iter().enumerate() {
        for &v in poly {
            if let Some(o) = owner.get_mut((v as usize).wrapping_sub(p.fixed)) {
                if *o != u32::MAX && *o != p.face_region[f] {
                    return false;
                }
                *o = p.face_region[f];
            }
        }
    }
    let nreg = p.region_count().max(restore.len());
    let mut positions = p.positions[..p.fixed].to_vec();
    let mut faces = Vec::with_capacity(p.faces.len());
    let mut face_region = Vec::with_capacity(p.faces.len());
    for r in 0..nreg {
        let s = match states.get(r) {
            Some(Some(s)) if restore.get(r).copied().unwrap_or(false) => s.clone(),
            _ => region_state(p, r as u32, 0.0, &[]),
        };
        let base = positions.len() as u32;
        positions.extend_from_slice(&s.free);
        for f in s.faces {
            faces.push(
                f.into_iter()
                    .map(|v| {
                        if (v as usize) < p.fixed {
                            v
                        } else {
                            v - p.fixed as u32 + base
                        }
                    })
                    .collect(),
            );
            face_region.push(r as u32);
        }
    }
    p.positions = positions;
    p.faces = faces;
    p.face_region = face_region;
    true
}

/// Enriches the faces in `over` (§7.2, see the module docs); returns the
/// number of local and diffuse fields. The steps: error fields
/// ([`error_fields`]), each classed local or diffuse ([`classify_fields`]),
/// case 2's midpoints and splits ([`edge_midpoints`], [`split_faces`]),
/// case 1's merged fans ([`fan_merges`]), and the vertices the merges left
/// unused dropped ([`drop_unused`]). `sample_face` and `dists` give each
/// sample's face and distance, `allow_local` per region whether case 1 is
/// allowed.
fn enrich(
    polys: &mut Polys,
    over: &[usize],
    sample_face: &[u32],
    dists: &[f64],
    allow_local: &[bool],
) -> (usize, usize) {
    let edge_faces = edge_faces(&polys.faces);
    let (field, fields) = error_fields(polys, over, &edge_faces);
    let kinds = classify_fields(
        polys,
        &field,
        &fields,
        sample_face,
        dists,
        allow_local,
        &edge_faces,
    );
    let mut positions = polys.positions.clone();
    let mid = edge_midpoints(polys, &kinds.split, &mut positions);
    let merged_faces: HashSet<usize> = kinds.merges.iter().flatten().copied().collect();
    let (mut faces, mut regions) =
        split_faces(polys, &kinds.split, &merged_faces, &mid, &mut positions);
    fan_merges(
        polys,
        &kinds.merges,
        &edge_faces,
        &mid,
        &mut positions,
        &mut faces,
        &mut regions,
    );
    drop_unused(polys, positions, faces, regions);
    (kinds.local, kinds.diffuse)
}

fn edge_key(a: u32, b: u32) -> (u32, u32) {
    (a.min(b), a.max(b))
}

/// Faces of each (undirected) control edge.
fn edge_faces(faces: &[Vec<u32>]) -> HashMap<(u32, u32), Vec<usize>> {
    let mut edge_faces: HashMap<(u32, u32), Vec<usize>> = HashMap::new();
    for (f, poly) in faces.iter().enumerate() {
        for k in 0..poly.len() {
            edge_faces
                .entry(edge_key(poly[k], poly[(k + 1) % poly.len()]))
                .or_default()
                .push(f);
        }
    }
    edge_faces
}

/// §7.2's error fields: connected components of the over-limit faces
/// across non-crease edges (so a field lies in one region). Returns each
/// face's field (`usize::MAX`: none) and the fields' faces.
fn error_fields(
    polys: &Polys,
    over: &[usize],
    edge_faces: &HashMap<(u32, u32), Vec<usize>>,
) -> (Vec<usize>, Vec<Vec<usize>>) {
    let nf = polys.faces.len();
    let mut is_over = vec![false; nf];
    for &f in over {
        is_over[f] = true;
    }
    let mut field = vec![usize::MAX; nf];
    let mut fields: Vec<Vec<usize>> = Vec::new();
    for &s in over {
        if field[s] != usize::MAX {
            continue;
        }
        let id = fields.len();
        let mut comp = vec![s];
        field[s] = id;
        let mut i = 0;
        while i < comp.len() {
            let f = comp[i];
            i += 1;
            let poly = &polys.faces[f];
            for k in 0..poly.len() {
                let e = edge_key(poly[k], poly[(k + 1) % poly.len()]);
                if polys.creases.contains(&e) {
                    continue;
                }
                for &g in &edge_faces[&e] {
                    if is_over[g] && field[g] == usize::MAX {
                        field[g] = id;
                        comp.push(g);
                    }
                }
            }
        }
        fields.push(comp);
    }
    (field, fields)
}

/// What [`classify_fields`] decided.
struct FieldKinds {
    /// Faces split by case 2.
    split: Vec<bool>,
    /// Fields merged into one polygon with one new point (case 1).
    merges: Vec<Vec<usize>>,
    local: usize,
    diffuse: usize,
}

/// §7.2's test per field: *local* (case 1) when its samples above
/// `D_max/2` are mostly below `0.8 D_max` (one peak, which one new point
/// answers), the field has several faces, its region still allows case 1
/// and its faces merge into one disc ([`merge_loop`]); else *diffuse*
/// (case 2: every face split).
fn classify_fields(
    polys: &Polys,
    field: &[usize],
    fields: &[Vec<usize>],
    sample_face: &[u32],
    dists: &[f64],
    allow_local: &[bool],
    edge_faces: &HashMap<(u32, u32), Vec<usize>>,
) -> FieldKinds {
    let mut out = FieldKinds {
        split: vec![false; polys.faces.len()],
        merges: Vec::new(),
        local: 0,
        diffuse: 0,
    };
    for comp in fields {
        let ds: Vec<f64> = sample_face
            .iter()
            .zip(dists)
            .filter(|(f, d)| {
                d.is_finite() && field[**f as usize] != usize::MAX && comp.contains(&(**f as usize))
            })
            .map(|(_, &d)| d)
            .collect();
        let dmax = ds.iter().copied().fold(0.0, f64::max);
        let set: Vec<f64> = ds.iter().copied().filter(|&d| d >= 0.5 * dmax).collect();
        let high = set.iter().filter(|&&d| d >= 0.8 * dmax).count();
        let local = comp.len() > 1
            && (high as f64) < 0.5 * set.len() as f64
            && allow_local
                .get(polys.face_region[comp[0]] as usize)
                .copied()
                .unwrap_or(true);
        if local
            && merge_loop(&polys.faces, comp, edge_faces)
                .is_some_and(|lp| lp.len() <= MAX_FAN_VALENCE)
        {
            out.merges.push(comp.clone());
            out.local += 1;
        } else {
            for &f in comp {
                out.split[f] = true;
            }
            out.diffuse += 1;
        }
    }
    out
}

/// Case 2's new points: the midpoint of every non-crease edge of a split
/// face (crease edges are never cut: they carry §5's curves), appended to
/// `positions`. Returns the midpoint of each cut edge.
fn edge_midpoints(
    polys: &Polys,
    split: &[bool],
    positions: &mut Vec<DVec3>,
) -> HashMap<(u32, u32), u32> {
    let mut mid: HashMap<(u32, u32), u32> = HashMap::new();
    for (f, poly) in polys.faces.iter().enumerate() {
        if !split[f] {
            continue;
        }
        for k in 0..poly.len() {
            let (a, b) = (poly[k], poly[(k + 1) % poly.len()]);
            let e = edge_key(a, b);
            if polys.creases.contains(&e) || mid.contains_key(&e) {
                continue;
            }
            positions.push(0.5 * (positions[a as usize] + positions[b as usize]));
            mid.insert(e, positions.len() as u32 - 1);
        }
    }
    mid
}

/// Every face not merged by case 1, with the midpoints of its cut edges
/// inserted; the split ones (case 2) cut by the number of cut edges (see
/// the module docs): two, along the chord between them; one, unchanged
/// but for the midpoint; three or more, one face per sector around a new
/// centre; none, a fan of triangles around it. Returns faces and regions.
fn split_faces(
    polys: &Polys,
    split: &[bool],
    merged_faces: &HashSet<usize>,
    mid: &HashMap<(u32, u32), u32>,
    positions: &mut Vec<DVec3>,
) -> (Vec<Vec<u32>>, Vec<u32>) {
    let mut faces: Vec<Vec<u32>> = Vec::new();
    let mut regions: Vec<u32> = Vec::new();
    for (f, poly) in polys.faces.iter().enumerate() {
        if merged_faces.contains(&f) {
            continue;
        }
        let n = poly.len();
        // Boundary sequence with midpoints inserted.
        let mut seq: Vec<(u32, bool)> = Vec::new();
        for k in 0..n {
            seq.push((poly[k], true));
            if let Some(&m) = mid.get(&edge_key(poly[k], poly[(k + 1) % n])) {
                seq.push((m, false));
            }
        }
        let reg = polys.face_region[f];
        if !split[f] {
            faces.push(seq.iter().map(|s| s.0).collect());
            regions.push(reg);
            continue;
        }
        let m = seq.len();
        let mids: Vec<usize> = (0..m).filter(|&i| !seq[i].1).collect();
        if mids.len() == 2 {
            // Two cut edges: one chord between their midpoints, no centre.
            let (i, j) = (mids[0], mids[1]);
            faces.push((i..=j).map(|k| seq[k].0).collect());
            regions.push(reg);
            faces.push((j..i + m + 1).map(|k| seq[k % m].0).collect());
            regions.push(reg);
            continue;
        }
        if mids.len() == 1 {
            // One cut edge (the end quad of such a strip, against the
            // crease closing it): the face keeps its shape and gains the
            // midpoint, which ends the strip's new row. A fan around a
            // centre here added five triangles per end quad; on fandisk
            // (`--max-error 1.1e-3`) keeping it gives 158 faces at RMS
            // 0.312‰ instead of 162 at 0.317‰.
            faces.push(seq.iter().map(|s| s.0).collect());
            regions.push(reg);
            continue;
        }
        let c = poly.iter().map(|&v| positions[v as usize]).sum::<DVec3>() / n as f64;
        positions.push(c);
        let ci = positions.len() as u32 - 1;
        if mids.len() >= 3 {
            // One face per sector: from a midpoint to the next, through
            // the corners between, and the centre (Catmull-Clark's split
            // where every edge is cut; a quad per corner).
            for (a, &i) in mids.iter().enumerate() {
                let j = mids[(a + 1) % mids.len()];
                let j = if j > i { j } else { j + m };
                let mut f: Vec<u32> = (i..=j).map(|k| seq[k % m].0).collect();
                f.push(ci);
                faces.push(f);
                regions.push(reg);
            }
            continue;
        }
        // No cut edge (a face closed by creases): a fan of triangles
        // around the centre, the only split left, while the centre's
        // valence stays bounded; a longer face is cut in two along the
        // chord between opposite corners instead (no new point: the chord
        // is an edge the next round can cut).
        if m > MAX_FAN_VALENCE {
            positions.pop();
            let h = m / 2;
            faces.push((0..=h).map(|k| seq[k].0).collect());
            regions.push(reg);
            faces.push((h..=m).map(|k| seq[k % m].0).collect());
            regions.push(reg);
            continue;
        }
        for i in 0..m {
            faces.push(vec![seq[i].0, seq[(i + 1) % m].0, ci]);
            regions.push(reg);
        }
    }
    (faces, regions)
}

/// Case 1: each merged field's polygon (with the midpoints its
/// neighbours' splits put on its edges) fanned around one new point, its
/// vertices' mean; appended to `faces` / `regions`.
fn fan_merges(
    polys: &Polys,
    merges: &[Vec<usize>],
    edge_faces: &HashMap<(u32, u32), Vec<usize>>,
    mid: &HashMap<(u32, u32), u32>,
    positions: &mut Vec<DVec3>,
    faces: &mut Vec<Vec<u32>>,
    regions: &mut Vec<u32>,
) {
    for comp in merges {
        let Some(lp) = merge_loop(&polys.faces, comp, edge_faces) else {
            continue;
        };
        // The merge loop may gain midpoints of neighbours' split edges.
        let mut seq: Vec<u32> = Vec::new();
        for k in 0..lp.len() {
            seq.push(lp[k]);
            if let Some(&m) = mid.get(&edge_key(lp[k], lp[(k + 1) % lp.len()])) {
                seq.push(m);
            }
        }
        let c = seq.iter().map(|&v| positions[v as usize]).sum::<DVec3>() / seq.len() as f64;
        positions.push(c);
        let ci = positions.len() as u32 - 1;
        // A field never crosses a crease, so it lies in one region.
        let reg = polys.face_region[comp[0]];
        for k in 0..seq.len() {
            faces.push(vec![seq[k], seq[(k + 1) % seq.len()], ci]);
            regions.push(reg);
        }
    }
}

/// Stores the enriched layout in `polys`. Merging leaves the merged
/// faces' inner vertices unused: they are dropped (free vertices only;
/// curve control points lie on creases, which no field crosses) and the
/// rest renumbered.
fn drop_unused(
    polys: &mut Polys,
    positions: Vec<DVec3>,
    mut faces: Vec<Vec<u32>>,
    regions: Vec<u32>,
) {
    let mut used = vec![false; positions.len()];
    for f in &faces {
        for &v in f {
            used[v as usize] = true;
        }
    }
    let mut map = vec![u32::MAX; positions.len()];
    let mut kept = Vec::with_capacity(positions.len());
    for (v, p) in positions.into_iter().enumerate() {
        if used[v] || v < polys.fixed {
            map[v] = kept.len() as u32;
            kept.push(p);
        }
    }
    for f in faces.iter_mut() {
        for v in f.iter_mut() {
            *v = map[*v as usize];
        }
    }
    polys.positions = kept;
    polys.faces = faces;
    polys.face_region = regions;
}

/// The single boundary loop of the union of `comp`'s faces, if it is a
/// disc whose loop visits no vertex twice and has no crease inside.
fn merge_loop(
    faces: &[Vec<u32>],
    comp: &[usize],
    edge_faces: &HashMap<(u32, u32), Vec<usize>>,
) -> Option<Vec<u32>> {
    let set: HashSet<usize> = comp.iter().copied().collect();
    let mut next: HashMap<u32, u32> = HashMap::new();
    let mut nb = 0;
    for &f in comp {
        let p = &faces[f];
        for k in 0..p.len() {
            let (a, b) = (p[k], p[(k + 1) % p.len()]);
            let inner = edge_faces[&(a.min(b), a.max(b))]
                .iter()
                .filter(|g| set.contains(g))
                .count()
                == 2;
            if !inner {
                if next.insert(a, b).is_some() {
                    return None;
                }
                nb += 1;
            }
        }
    }
    let &start = next.keys().min()?;
    let mut lp = vec![start];
    let mut v = next[&start];
    while v != start {
        lp.push(v);
        v = *next.get(&v)?;
        if lp.len() > nb {
            return None;
        }
    }
    // Interior vertices must exist (V − E + F = 1 for a disc).
    (lp.len() == nb && lp.len() >= 3).then_some(lp)
}

/// A region's ray caster and its triangles of M.
type RegionCaster = Option<(Box<dyn RayCaster>, Vec<u32>)>;

/// One ray caster per region over the triangles it may be fitted to
/// (`None` for a region without any).
fn region_casters(mesh: &TriMesh, reach: &[Vec<u32>]) -> Result<Vec<RegionCaster>> {
    use rayon::prelude::*;
    reach
        .to_vec()
        .into_par_iter()
        .map(|ts| {
            if ts.is_empty() {
                return Ok(None);
            }
            let sub = TriMesh {
                positions: mesh.positions.clone(),
                triangles: ts.iter().map(|&t| mesh.triangles[t as usize]).collect(),
            };
            Ok(Some((make_raycaster(RayBackend::Rust, &sub)?, ts)))
        })
        .collect()
}

/// Closest point of each sample's own region of M, and its triangle.
type Feet = (Vec<Option<DVec3>>, Vec<u32>);

fn region_feet(casters: &[RegionCaster], sample_region: &[u32], pts: &[DVec3]) -> Result<Feet> {
    let mut by_region: Vec<Vec<usize>> = vec![Vec::new(); casters.len()];
    for (i, &r) in sample_region.iter().enumerate() {
        if let Some(b) = by_region.get_mut(r as usize) {
            b.push(i);
        }
    }
    let mut feet = vec![None; pts.len()];
    let mut tri = vec![u32::MAX; pts.len()];
    for (r, idx) in by_region.iter().enumerate() {
        let Some((c, ts)) = &casters[r] else { continue };
        if idx.is_empty() {
            continue;
        }
        let q: Vec<DVec3> = idx.iter().map(|&i| pts[i]).collect();
        for (&i, h) in idx.iter().zip(c.closest_points(&q, f64::INFINITY)?) {
            feet[i] = h.map(|h| h.point);
            if let Some(h) = h {
                tri[i] = ts.get(h.triangle as usize).copied().unwrap_or(u32::MAX);
            }
        }
    }
    Ok((feet, tri))
}

/// [`sq_energy`] per region of the samples.
fn region_energy(
    pts: &[DVec3],
    feet: &[Option<DVec3>],
    sample_region: &[u32],
    nreg: usize,
) -> Vec<f64> {
    let mut e = vec![0.0; nreg];
    for ((p, f), &r) in pts.iter().zip(feet).zip(sample_region) {
        if let (Some(f), Some(x)) = (f, e.get_mut(r as usize)) {
            *x += (*p - *f).length_squared();
        }
    }
    e
}

fn sq_energy(pts: &[DVec3], feet: &[Option<DVec3>]) -> f64 {
    pts.iter()
        .zip(feet)
        .filter_map(|(p, f)| f.map(|f| (*p - f).length_squared()))
        .sum()
}

/// One least-squares update of the free control points: minimises
/// `Σ |s_i + A_i δ − f_i|²` (point distance to the fixed feet) plus
/// `λ (|L δ|² + 10⁻⁴ |δ|²)`, the umbrella fairness of [`crate::fit`] and a
/// Tikhonov term that keeps a control point no sample sees where it is.
fn solve_step(
    st: &crate::subdiv::LimitStencils,
    pts: &[DVec3],
    feet: &[Option<DVec3>],
    fixed: usize,
    nfree: usize,
    lap: &[Vec<(u32, f64)>],
    fairness: f64,
) -> Result<Vec<DVec3>> {
    let mut rows: Vec<usize> = Vec::new();
    for (i, f) in feet.iter().enumerate() {
        if f.is_some() && st.row(i).any(|k| st.indices[k] as usize >= fixed) {
            rows.push(i);
        }
    }
    let r = rows.len();
    if r == 0 {
        return Ok(vec![DVec3::ZERO; nfree]);
    }
    let mut a = Triplets::new(r, nfree);
    let mut b: Vec<Vec<f64>> = (0..3).map(|_| Vec::with_capacity(r)).collect();
    for (row, &i) in rows.iter().enumerate() {
        for k in st.row(i) {
            let v = st.indices[k] as usize;
            if v >= fixed {
                a.push(row, v - fixed, st.weights[k]);
            }
        }
        let d = feet[i].unwrap_or(pts[i]) - pts[i];
        for (c, bc) in b.iter_mut().enumerate() {
            bc.push(d[c]);
        }
    }
    let mut reg = Triplets::new(2 * nfree, nfree);
    for (v, row) in lap.iter().enumerate() {
        for &(u, w) in row {
            reg.push(v, u as usize, w);
        }
        reg.push(nfree + v, v, 1e-2);
    }
    let lambda = fairness * r as f64 / nfree as f64;
    let x = least_squares(&a, &b, Some((&reg, lambda)), &LsqOptions::default())?;
    (0..nfree)
        .map(|v| {
            let d = DVec3::new(x[0][v], x[1][v], x[2][v]);
            if d.is_finite() {
                Ok(d)
            } else {
                Err(Error::backend("Eigen", "non-finite control update"))
            }
        })
        .collect()
}

/// One SDM update of the free control points (§7.1, eq. 4 of Lavoué et
/// al., after Pottmann & Leopoldseder): per sample, three rows in the foot
/// triangle's frame `(n, e1, e2)`, `√w` times the residual along each, with
/// `w_i = dκ_i / (1 + dκ_i)` (d the signed distance along n) clamped to
/// `[floor, 1]` and `floor` where `1 + dκ_i ≤ 0` (beyond the centre of
/// curvature eq. 4 approximates nothing), as in [`crate::fit`]. The
/// coordinates are coupled: 3·nfree unknowns, one right-hand side. Same
/// regularisation as [`solve_step`], per coordinate.
#[allow(clippy::too_many_arguments)]
fn solve_step_sdm(
    st: &crate::subdiv::LimitStencils,
    pts: &[DVec3],
    feet: &[Option<DVec3>],
    foot_tri: &[u32],
    frames: &[TriFrame],
    fixed: usize,
    nfree: usize,
    lap: &[Vec<(u32, f64)>],
    o: &OptimizeOptions,
) -> Result<Vec<DVec3>> {
    let floor = o.sdm_tangent_floor;
    let mut rows: Vec<usize> = Vec::new();
    for (i, f) in feet.iter().enumerate() {
        if f.is_some() && st.row(i).any(|k| st.indices[k] as usize >= fixed) {
            rows.push(i);
        }
    }
    let samples = rows.len();
    if samples == 0 {
        return Ok(vec![DVec3::ZERO; nfree]);
    }
    let n3 = 3 * nfree;
    let mut a = Triplets::new(3 * samples, n3);
    let mut b = Vec::with_capacity(3 * samples);
    let mut r = 0;
    for &i in &rows {
        let foot = feet[i].unwrap_or(pts[i]);
        let res = pts[i] - foot;
        let fr = frames.get(foot_tri[i] as usize);
        let frame: [(DVec3, f64); 3] = match fr {
            Some(fr) if fr.normal != DVec3::ZERO => {
                let n = fr.normal;
                let d = res.dot(n);
                let weight = |k: f64| sdm_tangent_weight(d, k, floor);
                let e1 = (fr.e1 - fr.e1.dot(n) * n)
                    .try_normalize()
                    .unwrap_or_else(|| n.any_orthonormal_vector());
                [(n, 1.0), (e1, weight(fr.k1)), (n.cross(e1), weight(fr.k2))]
            }
            _ => [(DVec3::X, 1.0), (DVec3::Y, 1.0), (DVec3::Z, 1.0)],
        };
        // Fixed (curve) vertices are not unknowns: their stencil terms drop.
        let entries = st
            .row(i)
            .map(|k| (st.indices[k] as usize, st.weights[k]))
            .filter(|&(v, _)| v >= fixed)
            .map(|(v, s)| (v - fixed, s));
        push_frame_rows(&mut a, &mut b, &mut r, &frame, entries, res);
    }
    let mut reg = Triplets::new(2 * n3, n3);
    for (v, row) in lap.iter().enumerate() {
        for c in 0..3 {
            for &(u, w) in row {
                reg.push(3 * v + c, 3 * u as usize + c, w);
            }
            reg.push(n3 + 3 * v + c, 3 * v + c, 1e-2);
        }
    }
    // λ as in the point step: `samples` data rows per coordinate.
    let lambda = o.fairness * samples as f64 / nfree as f64;
    let x = least_squares(&a, &[b], Some((&reg, lambda)), &LsqOptions::default())?;
    let x = &x[0];
    (0..nfree)
        .map(|v| {
            let d = DVec3::new(x[3 * v], x[3 * v + 1], x[3 * v + 2]);
            if d.is_finite() {
                Ok(d)
            } else {
                Err(Error::backend("Eigen", "non-finite control update"))
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `w × h` grid of unit quads in the plane z = 0, every vertex fixed
    /// and the outer boundary a crease (one region).
    fn grid(w: u32, h: u32) -> Polys {
        let id = |i: u32, j: u32| j * (w + 1) + i;
        let positions = (0..=h)
            .flat_map(|j| (0..=w).map(move |i| DVec3::new(i as f64, j as f64, 0.0)))
            .collect::<Vec<_>>();
        let faces: Vec<Vec<u32>> = (0..h)
            .flat_map(|j| {
                (0..w).map(move |i| vec![id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1)])
            })
            .collect();
        let mut creases = HashSet::new();
        for i in 0..w {
            creases.insert((id(i, 0), id(i + 1, 0)));
            creases.insert((id(i, h), id(i + 1, h)));
        }
        for j in 0..h {
            creases.insert((id(0, j), id(0, j + 1)));
            creases.insert((id(w, j), id(w, j + 1)));
        }
        Polys {
            fixed: positions.len(),
            face_region: vec![0; faces.len()],
            positions,
            faces,
            creases,
            corners: vec![id(0, 0), id(w, 0), id(0, h), id(w, h)],
        }
    }

    /// A strip of three quads between two creases, all over the limit
    /// (case 2): the inner quad has two cut edges and is cut along the
    /// chord between their midpoints, the end quads have one and only
    /// gain it. One new row across the strip: 2 points, 4 faces.
    #[test]
    fn strip_gains_one_row() {
        let mut p = grid(3, 1);
        let (local, diffuse) = enrich(&mut p, &[0, 1, 2], &[], &[], &[false]);
        assert_eq!((local, diffuse), (0, 1));
        assert_eq!(p.positions.len(), 8 + 2);
        let mut sizes: Vec<usize> = p.faces.iter().map(|f| f.len()).collect();
        sizes.sort_unstable();
        assert_eq!(sizes, vec![4, 4, 5, 5]);
        // The new points are the midpoints of the two inner edges.
        for (k, x) in [(8, 1.0), (9, 2.0)] {
            let q = p.positions[k];
            assert!((q - DVec3::new(x, 0.5, 0.0)).length() < 1e-12, "{q}");
        }
        p.to_control().unwrap().validate().unwrap();
    }

    /// The centre quad of a 3 × 3 grid: four cut edges, Catmull-Clark's
    /// split into four quads around a new centre; its neighbours gain the
    /// midpoints (pentagons), nothing else changes.
    #[test]
    fn interior_face_splits_into_sectors() {
        let mut p = grid(3, 3);
        enrich(&mut p, &[4], &[], &[], &[false]);
        assert_eq!(p.positions.len(), 16 + 4 + 1);
        assert_eq!(p.faces.len(), 8 + 4);
        let quads_at_centre = p.faces.iter().filter(|f| f.contains(&20)).count();
        assert_eq!(quads_at_centre, 4);
        assert!(p.faces.iter().all(|f| f.len() == 4 || f.len() == 5));
        assert!((p.positions[20] - DVec3::new(1.5, 1.5, 0.0)).length() < 1e-12);
        p.to_control().unwrap().validate().unwrap();
    }
}
