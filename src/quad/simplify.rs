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
//! fit towards φ targets (§3.4). Boundary vertices collapse only along the
//! boundary (see [`super::ops::can_collapse_diagonal`]): without that the
//! boundary loops keep every input vertex and a mesh's holes hold a large
//! share of its final patches.
//!
//! All per-collapse work is local: vertex limit points come from
//! [`vertex_limit_mask`] (cached per vertex, refreshed around each refit),
//! patch centres from the closed-form Catmull-Clark face-centre limit
//! ([`face_centre_limit`]), and φ is one line query at a time on a pure-Rust
//! BVH over M ([`BvhCaster::first_hit`], both directions), with a search
//! distance of twice the local feature size: the per-collapse queries are a
//! few dozen rays, for which a batched call (rayon + FFI chunking) costs
//! more in fixed overhead than the rays themselves. The loop is sequential
//! by default (each step's heap, mesh and refit depend on the previous
//! step's; forking a step's few dozen φ queries was measured slower, see
//! `PHI_PAR_MIN`). [`SimplifyOptions::batch`] above 1 runs it in batches
//! of whole candidates whose regions do not meet (`Simplifier::run`):
//! deterministic, but measured no cheaper and with a different outcome
//! (see [`DEFAULT_BATCH`]). The sweeps over all faces run in parallel, in
//! input order, so the result does not depend on the number of threads.
//! The quadrangulation
//! and interpolation before it need no Fitmap ([`prepare`]), so `convert`
//! runs them beside the Fitmap. Every edit updates the control mesh's
//! free lists locally: a full re-sort per edit made the loop quadratic.
//! (Timings: docs/status.md, "Measurements behind the code".)

use std::cmp::Reverse;
use std::collections::{BTreeMap, BinaryHeap};
use std::time::Instant;

use serde::Serialize;

use super::interpolate::interpolate_limit_polled;
use super::ops::{
    can_collapse_diagonal, can_rotate_edge, collapse_diagonal_logged, remove_doublets,
    rotate_edge_logged, rotation_energy_gain, CollapsePlan, FaceLog, Rotation, ValenceTargets,
};
use super::quadrangulate::quadrangulate_polled;
use super::{vertex_limit_mask, vertex_limit_mask_into, InterpolationOptions};
use super::{QuadrangulateOptions, Quadrangulation};

use crate::analysis::Fitmap;
use crate::error::{Error, Result};
use crate::mesh::{prefetch, ControlMesh, FaceId, TriMesh, VertexId};
use crate::project::{default_max_dist, Projected};
use crate::raycast::bvh::BvhCaster;
use crate::raycast::RayCaster;
use crate::subdiv::catmark::closed_form::{
    centroid, edge_point_with, face_centre_limit, face_centre_limit_from, vertex_normal,
    vertex_point_with,
};
use crate::subdiv::LimitPoint;
use crate::DVec3;

/// Default [`SimplifyOptions::s_fitmap_scale`]: κ = 1.55 κ₀, inside the
/// measured window in which the results meet Fitmaps' Table 1 at τ = 1 %
/// and 10 % (see the option's documentation).
pub const DEFAULT_S_FITMAP_SCALE: f64 = 1.55;

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
    /// The surface guard (see [`Simplifier::guard`]): after the local refit
    /// every patch around the refit region must keep its centre within
    /// `guard_scale · (F_S · r)⁴ + guard_floor · τ^¼ · diag` of M along its
    /// normal (`(F_S r)⁴ = a r⁴` is the S-fitmap's prediction of the RMS
    /// error of one patch of radius r, §3.1.2), and its limit normal must
    /// agree with M's there (`cos > guard_min_cos`); otherwise the collapse
    /// is undone and refused. `guard_scale = 0` turns the guard off.
    pub guard_scale: f64,
    /// See `guard_scale`: times τ^¼, a fraction of M's bounding-box
    /// diagonal. τ, the Fitmap's tolerance to lost projectability, is the
    /// method's one parameter (§3.1.3); the floor grows with it so that a
    /// larger τ buys coarser patches from the guard too (below the floor
    /// the S-fitmap term rules).
    ///
    /// The guard is not in the paper, whose only halting rule is the
    /// M-fitmap test (§3.3.1); it stands in for the accuracy the paper's
    /// Fitmap delivered at the same τ, and its floor is an empirical
    /// calibration against Fitmaps' Table 1 (RMS L after the global fit of
    /// §3.5): a floor ∝ τ^¼ keeps the guard binding at both τ = 1 % and
    /// 10 %, where ∝ √τ stopped binding at 10 %; the default keeps a margin
    /// because the loop's outcome moves by ±5 % with small changes of the
    /// bound. Since the S-fitmap test ([`SimplifyOptions::s_fitmap_scale`])
    /// controls the error, the guard stops few final patches; it was not
    /// recalibrated. (Calibration figures: docs/status.md, "Measurements
    /// behind the code".)
    pub guard_floor: f64,
    /// See `guard_scale`.
    pub guard_min_cos: f64,
    /// The S-fitmap test (§3.1.1's first prescription, "the local radius of
    /// each patch should be inversely proportional to F_S", made a bound
    /// like the M-fitmap test makes the second one): a collapse is allowed
    /// only if every patch it enlarges keeps `radius · F_S ≤ κ` at its
    /// projected centre, so that at the natural end a patch is stopped
    /// either by projectability (F_M) or by its predicted error (F_S·r)⁴
    /// (§3.1.2: "two patches contribute approximately the same error if
    /// r·F_S are equal"). κ = `s_fitmap_scale` · κ₀, κ₀ from the Fitmap
    /// alone (see [`s_fitmap_kappa`]); 0 turns the test off. It runs with
    /// the M-fitmap test (off with it).
    ///
    /// On by default at [`DEFAULT_S_FITMAP_SCALE`] since F_S is fitted in
    /// log space (`analysis::fitmap`, `s_from_errors`): F_S now predicts the
    /// error at patch-size radii and varies over M (more than the former
    /// linear fit did), so the test
    /// stops patches where (F_S·r)⁴ is large and the M-fitmap test stops
    /// the rest. The scale is not from the paper (the paper has no κ: its
    /// prescription is a proportionality, §3.1.1); κ₀ sets the order of
    /// magnitude from the Fitmap, and the factor is the measured window
    /// in which the results meet Table 1 at both τ (count and RMS L); the
    /// outcome moves between neighbouring scales (the order of the
    /// collapses changes), so the default sits inside the window, not at
    /// its edge. With the former linear F_S fit (≈ E(r_h)/r_h⁴, a
    /// near-global quantity) no scale gave adaptivity. (The scale sweep:
    /// docs/status.md, "Measurements behind the code".)
    pub s_fitmap_scale: f64,
    /// Keep the last this many intermediate meshes of the loop, one each
    /// time the face count falls by another factor [`CHECKPOINT_RATIO`]
    /// ([`Simplified::checkpoints`]): the candidates with more patches than
    /// the natural end that `pipeline`'s `--max-error` search fits when the
    /// end itself is not accurate enough. 0: none.
    pub checkpoints: usize,
    /// Collapses the loop evaluates together at most
    /// ([`DEFAULT_BATCH`]): the next ones in the heap's order whose regions
    /// do not meet, their Fitmap tests and refits one per rayon job. 1: the
    /// sequential loop (Fitmaps' order exactly; the default). Any value
    /// gives the same result at any thread count; values above 1 take a
    /// batch's later candidates before the entries its earlier ones push,
    /// a different greedy order with a different outcome.
    pub batch: usize,
    /// From how many lines the sequential loop splits a step's φ batch in
    /// two over the pool when it has two threads or more
    /// ([`DEFAULT_STEP_FORK`]); `Some(0)`: never; `None`: the
    /// `SUBDFIT_SIMPLIFY_FORK` switch, else the default. The same result
    /// whatever the value (not in the report).
    #[serde(skip)]
    pub step_fork: Option<usize>,
    /// The split loop (`SUBDFIT_SIMPLIFY_SPLIT=1` turns it on in
    /// [`Default`]; see [`split`]): the greedy runs first on two halves of
    /// the mesh side by side, with a frozen band between them, then on the
    /// whole as usual. A different greedy order: off by default.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub split: bool,
}

#[path = "simplify_split.rs"]
mod split;

/// Default [`SimplifyOptions::batch`]: the sequential loop. Batches of 16
/// were measured on 2026-12-05 (docs/status.md, "Scale", session 22): the
/// same result at 1 and 2 threads, but 11 % more CPU on one thread and
/// 40 % more on two, and a different greedy order that moved the shared
/// meshes' outcome by more than noise (homer 212 → 233 patches, irregular
/// vertices 60 → 81; bunny's loop 339 → 288 faces).
pub const DEFAULT_BATCH: usize = 1;

/// `--faces N` below the natural end (issue 17: "beyond the natural end
/// the M-fitmap test is relaxed step by step"): each time the loop ends
/// above `1.02·N`, the M-fitmap radius F_M, the S-fitmap bound κ and the
/// guard's distance bound are multiplied by this factor (the guard's
/// normal test stays: a patch whose normal turns away from M's is never
/// accepted) and every face is tried again, at most [`MAX_RELAX_STEPS`]
/// times (1.25^16 ≈ 36: far past any meaningful projectability).
pub const RELAX_STEP: f64 = 1.25;
pub const MAX_RELAX_STEPS: usize = 16;

/// Face-count ratio between consecutive checkpoints
/// ([`SimplifyOptions::checkpoints`]): the `--max-error` search lands
/// within this factor of the fewest patches that meet the bound, and 40
/// checkpoints reach 1.06^40 ≈ 10× the natural end's count.
pub const CHECKPOINT_RATIO: f64 = 1.06;

impl Default for SimplifyOptions {
    fn default() -> Self {
        SimplifyOptions {
            target_faces: None,
            m_fitmap: true,
            refit_rounds: 2,
            fit_sweeps: 3,
            max_dist: None,
            check_every_step: false,
            guard_scale: 8.0,
            guard_floor: 0.026,
            guard_min_cos: 0.3,
            s_fitmap_scale: DEFAULT_S_FITMAP_SCALE,
            checkpoints: 0,
            batch: DEFAULT_BATCH,
            step_fork: None,
            split: split::env_on(),
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
    /// Keep the last `n` checkpoints ([`SimplifyOptions::checkpoints`]).
    pub fn with_checkpoints(mut self, n: usize) -> Self {
        self.checkpoints = n;
        self
    }
    /// The S-fitmap test's κ in units of [`s_fitmap_kappa`] (0: off).
    pub fn with_s_fitmap_scale(mut self, scale: f64) -> Self {
        self.s_fitmap_scale = scale;
        self
    }
    /// Collapses per batch ([`SimplifyOptions::batch`]; 1: sequential).
    pub fn with_batch(mut self, n: usize) -> Self {
        self.batch = n.max(1);
        self
    }
    /// The split loop ([`SimplifyOptions::split`]).
    pub fn with_step_fork(mut self, lines: Option<usize>) -> Self {
        self.step_fork = lines;
        self
    }

    pub fn with_split(mut self, on: bool) -> Self {
        self.split = on;
        self
    }
    /// The surface guard's bound (`scale = 0`: off) and normal test.
    pub fn with_guard(mut self, scale: f64, floor: f64, min_cos: f64) -> Self {
        self.guard_scale = scale;
        self.guard_floor = floor;
        self.guard_min_cos = min_cos;
        self
    }
}

/// Why the loop ended.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StopReason {
    /// `target_faces` reached.
    TargetFaces,
    /// No allowed collapse remains.
    NaturalEnd,
}

impl SimplifyStats {
    /// Counts an undone collapse by its reason ([`Simplifier::refusal`]).
    fn count_refusal(&mut self, why: u8) {
        match why {
            Blocked::GUARD_NORMAL => self.refused_guard_normal += 1,
            Blocked::GUARD_DISTANCE => self.refused_guard_distance += 1,
            _ => self.refused_undershoot += 1,
        }
    }
}

/// Passed to the progress callback every few dozen steps (see `run`);
/// during the set-up (quadrangulation, limit interpolation), before the
/// control mesh exists, `faces` and `initial_faces` are 0.
#[derive(Copy, Clone, Debug, PartialEq, Serialize)]
pub struct Progress {
    pub faces: usize,
    pub initial_faces: usize,
    pub collapses: usize,
    pub seconds: f64,
}

/// Counters and timings of one run.
#[derive(Clone, Debug, Default, PartialEq, Serialize, serde::Deserialize)]
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
    /// The same, by the reason [`can_collapse_diagonal`] gave.
    pub refused_topology_by_reason: BTreeMap<String, usize>,
    /// Heap entries refused by the M-fitmap test.
    pub refused_m_fitmap: usize,
    /// Heap entries refused by the S-fitmap test
    /// ([`SimplifyOptions::s_fitmap_scale`]).
    pub refused_s_fitmap: usize,
    /// κ of the S-fitmap test (0 when off).
    pub s_fitmap_kappa: f64,
    /// At the natural end, what stops the final patches: for each test,
    /// the number of final faces one of whose diagonal collapses it refused
    /// in the last sweep (a face can count under two tests, one per
    /// diagonal).
    pub final_blockers: BTreeMap<String, usize>,
    /// Collapses undone because the refit left a patch centre too far from
    /// M ([`SimplifyOptions::guard_scale`]).
    pub refused_guard_distance: usize,
    /// Collapses undone because a patch's limit normal disagreed with M's.
    pub refused_guard_normal: usize,
    /// Collapses undone because their doublet removals would have left
    /// fewer faces than `target_faces`' 2 % window.
    pub refused_undershoot: usize,
    /// Full re-evaluations of every face after the heap ran dry.
    pub sweeps: usize,
    /// Batches of candidates the loop evaluated together
    /// ([`SimplifyOptions::batch`]); with the candidates in them, the mean
    /// batch.
    #[serde(default)]
    pub batches: usize,
    /// φ batches the loop split in two over the pool
    /// ([`SimplifyOptions::step_fork`]; not in the report: it depends on
    /// the thread count, the result does not).
    #[serde(skip)]
    pub step_forks: usize,
    #[serde(default)]
    pub batched_candidates: usize,
    /// The factor the halting tests were relaxed by to reach
    /// `target_faces` below the natural end (1: not relaxed; see
    /// [`RELAX_STEP`]), and how many steps that took.
    pub relaxation: f64,
    pub relax_steps: usize,
    /// φ queries and those with no hit (counted, then handled by a closest
    /// point look-up for the Fitmap values, or by not moving the vertex).
    pub projections: usize,
    pub unprojectable: usize,
    pub seconds_quadrangulate: f64,
    pub seconds_interpolate: f64,
    pub seconds_simplify: f64,
    pub stop: Option<StopReason>,
    /// Adaptivity of the result (issue 4; see
    /// [`SimplifyOptions::s_fitmap_scale`] for measured values): Spearman
    /// rank correlation, over
    /// the final patches, between the patch radius (largest centre-to-corner
    /// distance of the limit patch) and 1/F_S at its projected centre.
    /// `None` with fewer than two patches or constant values.
    pub adaptivity_spearman: Option<f64>,
    /// The same with F_M instead of 1/F_S: at the natural end with the
    /// M-fitmap test on, F_M (the bound that stopped the collapses) rather
    /// than F_S (the order they came in) sets the patch sizes.
    pub spearman_radius_fm: Option<f64>,
    /// Median over the final patches of radius / F_M at the centre (how
    /// close the patches came to the M-fitmap bound; above 1 where the test
    /// was off or a doublet removal merged two patches).
    pub median_radius_over_fm: f64,
    /// The second adaptivity figure: the mean patch radius over the final
    /// patches in the top quartile of F_S divided by that in the bottom
    /// quartile (patches ranked by F_S at their projected centres). Below 1
    /// when patches are smaller where F_S is large (§3.1.1: "the local
    /// radius of each patch should be inversely proportional to F_S"); 0
    /// with fewer than four patches.
    pub radius_ratio_fs_quartiles: f64,
    /// Standard deviation of ln F_S over the final patches (at their
    /// projected centres) and over M's vertices (F_S > 0): how much the
    /// S-fitmap can order and bound the patches at all.
    pub sd_log_fs_patches: f64,
    /// See `sd_log_fs_patches`.
    pub sd_log_fs_vertices: f64,
    /// The split loop's first phase ([`SimplifyOptions::split`]); `None`
    /// when it did not run.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub split: Option<SplitStats>,
}

/// What the two halves of the split loop did ([`SimplifyOptions::split`]).
#[derive(Clone, Debug, Default, PartialEq, Serialize, serde::Deserialize)]
pub struct SplitStats {
    /// Faces of the start wholly on each side (outside the frozen band),
    /// and those in the band (a corner frozen).
    pub faces: [usize; 2],
    pub band_faces: usize,
    /// Collapses each half kept, and the steps undone because they reached
    /// the band.
    pub collapses: [usize; 2],
    pub refused_band: [usize; 2],
    /// Faces when the halves were joined, and the wall time of the halves.
    pub faces_joined: usize,
    pub seconds: f64,
    /// CPU seconds of each half's loop thread, and of the loop on the
    /// whole after the join (its own thread): on two free cores the loop's
    /// wall time is about the larger of the first two plus the third.
    pub thread_cpu: [f64; 2],
    pub thread_cpu_joined: f64,
}

/// Standard deviation of `ln x` over the positive finite entries (0 with
/// fewer than two).
fn sd_log(x: impl Iterator<Item = f64>) -> f64 {
    let l: Vec<f64> = x
        .filter(|v| *v > 0.0 && v.is_finite())
        .map(f64::ln)
        .collect();
    if l.len() < 2 {
        return 0.0;
    }
    let m = l.iter().sum::<f64>() / l.len() as f64;
    (l.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / l.len() as f64).sqrt()
}

/// Mean radius of the patches in the top quartile of F_S over that in the
/// bottom quartile (`patches`: (F_S, radius); ties broken by radius, then
/// order, for determinism). 0 with fewer than four patches.
pub fn radius_ratio_fs_quartiles(patches: &[(f64, f64)]) -> f64 {
    let n = patches.len();
    if n < 4 {
        return 0.0;
    }
    let mut p = patches.to_vec();
    p.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.total_cmp(&b.1)));
    let q = n / 4;
    let mean = |s: &[(f64, f64)]| s.iter().map(|x| x.1).sum::<f64>() / s.len() as f64;
    let (low, high) = (mean(&p[..q]), mean(&p[n - q..]));
    if low > 0.0 {
        high / low
    } else {
        0.0
    }
}

/// The simplified control mesh (compact) and its statistics.
#[derive(Clone, Debug)]
pub struct Simplified {
    pub mesh: ControlMesh,
    pub stats: SimplifyStats,
    /// Intermediate meshes of the loop (compact), fewest faces first, each
    /// at least [`CHECKPOINT_RATIO`] times the previous one's count (and
    /// the first than `mesh`'s); empty unless
    /// [`SimplifyOptions::checkpoints`] asked for them.
    pub checkpoints: Vec<ControlMesh>,
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
/// `caster` a ray caster over `mesh` (used for the closest-point fallback
/// of centres φ cannot project; φ itself runs on an internal BVH). `progress` is called every few hundred
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
    // Between the set-up steps too, so that a cancellation waits for one
    // step (each well under a second on a million triangles), not all.
    let t_all = Instant::now();
    let mut ask = || {
        let p = Progress {
            faces: 0,
            initial_faces: 0,
            collapses: 0,
            seconds: t_all.elapsed().as_secs_f64(),
        };
        if progress(p) {
            Ok(())
        } else {
            Err(Error::Cancelled {
                stage: "simplification".into(),
            })
        }
    };
    let start = prepare_polled(mesh, &mut ask)?;
    simplify_prepared(mesh, fitmap, caster, opts, start, progress)
}

/// The simplification's start, which does not need the Fitmap: M
/// quadrangulated (§3.2) and interpolated by the limit surface (system
/// (1)). See [`prepare`].
pub struct Prepared {
    mesh: ControlMesh,
    seconds_quadrangulate: f64,
    seconds_interpolate: f64,
}

/// The first half of [`simplify_with_progress`]: quadrangulation and
/// interpolation, which read M only, so a caller can run them beside the
/// Fitmap (`convert` does: that sequential work then shares the Fitmap's
/// cores instead of following it). Deterministic.
pub fn prepare(mesh: &TriMesh) -> Result<Prepared> {
    prepare_polled(mesh, &mut || Ok(()))
}

fn prepare_polled(mesh: &TriMesh, ask: &mut dyn FnMut() -> Result<()>) -> Result<Prepared> {
    let t = Instant::now();
    let Quadrangulation { mesh: mut k, .. } =
        quadrangulate_polled(mesh, &QuadrangulateOptions::default(), ask)?;
    let seconds_quadrangulate = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let targets = k.positions().to_vec();
    interpolate_limit_polled(&mut k, &targets, &InterpolationOptions::default(), ask)?;
    Ok(Prepared {
        mesh: k,
        seconds_quadrangulate,
        seconds_interpolate: t.elapsed().as_secs_f64(),
    })
}

/// The second half of [`simplify_with_progress`]: the greedy loop from a
/// [`prepare`]d start of the same `mesh`.
pub fn simplify_prepared(
    mesh: &TriMesh,
    fitmap: &Fitmap,
    caster: &dyn RayCaster,
    opts: &SimplifyOptions,
    start: Prepared,
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
        seconds_quadrangulate: start.seconds_quadrangulate,
        seconds_interpolate: start.seconds_interpolate,
        ..Default::default()
    };
    let t = Instant::now();
    let mut poll = || {
        let p = Progress {
            faces: 0,
            initial_faces: 0,
            collapses: 0,
            seconds: t.elapsed().as_secs_f64(),
        };
        if progress(p) {
            Ok(())
        } else {
            Err(Error::Cancelled {
                stage: "simplification".into(),
            })
        }
    };
    let mut s = Simplifier::new(mesh, fitmap, caster, opts, start.mesh, &mut poll)?;
    s.run(&mut stats, progress)?;
    s.finish(stats, t)
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
    let mut s = Simplifier::new(mesh, fitmap, caster, opts, k, &mut || Ok(()))?;
    s.run(&mut stats, progress)?;
    s.finish(stats, t)
}

/// κ₀ of the S-fitmap test ([`SimplifyOptions::s_fitmap_scale`]): the
/// proportionality constant of §3.1.1's first prescription, `r = κ/F_S`,
/// chosen so that it asks for as many patches over M as the second one,
/// `r = F_M`. A patch of radius r covers an area ∝ r², so the patch count
/// of a radius field r(p) is ∝ ∫ r⁻² dA; equating ∫ F_S²/κ² dA with
/// ∫ F_M⁻² dA gives
///
/// `κ₀² = ∫ F_S² dA / ∫ F_M⁻² dA`
///
/// (vertex areas a third of the incident triangles'; vertices with F_S or
/// F_M ≤ 0, where the Fitmap has no value, left out). κ₀ comes from the
/// Fitmap alone, with no constant: it follows τ through F_M, and it scales
/// with the mesh as F_S·r does (F_S ∝ length^-¾, so both go as length^¼),
/// which makes the test invariant under scaling. Returns 0 when no vertex
/// has both values.
pub fn s_fitmap_kappa(mesh: &TriMesh, fitmap: &Fitmap) -> f64 {
    let areas = crate::analysis::normals::triangle_areas(mesh);
    let mut va = vec![0.0; mesh.positions.len()];
    for (t, a) in mesh.triangles.iter().zip(&areas) {
        for &v in t {
            va[v as usize] += a / 3.0;
        }
    }
    let (mut num, mut den) = (0.0, 0.0);
    for ((&a, &s), &m) in va.iter().zip(&fitmap.s).zip(&fitmap.m) {
        if s > 0.0 && m > 0.0 && s.is_finite() && m.is_finite() {
            num += a * s * s;
            den += a / (m * m);
        }
    }
    if den > 0.0 && num > 0.0 {
        (num / den).sqrt()
    } else {
        0.0
    }
}

// ---- limit quantities ----------------------------------------------------------

/// The limit position of a [`vertex_limit_mask`]: its weighted sum of the
/// control points.
fn limit_of(k: &ControlMesh, mask: &[(VertexId, f64)]) -> DVec3 {
    mask.iter().map(|&(u, w)| w * k.position(u)).sum()
}

/// The limit point of every vertex of `k` (a deleted one's position), in
/// parallel; the same bits as the loop's per-vertex updates.
fn all_limits(k: &ControlMesh) -> Result<Vec<DVec3>> {
    use rayon::prelude::*;
    (0..k.num_vertices())
        .into_par_iter()
        .map(|i| {
            let v = VertexId(i as u32);
            if k.is_vertex_deleted(v) {
                Ok(k.position(v))
            } else {
                vertex_limit_mask(k, v).map(|m| limit_of(k, &m))
            }
        })
        .collect()
}

// ---- the loop ------------------------------------------------------------------

/// The loop's state; [`super::field::cleanup`] drives the same operators,
/// local fits and tests in its own order.
#[derive(Clone)]
pub(crate) struct Simplifier<'a> {
    pub(crate) m: &'a TriMesh,
    pub(crate) fitmap: &'a Fitmap,
    caster: &'a dyn RayCaster,
    /// Pure-Rust BVH over M for the per-collapse φ queries: one ray at a
    /// time inside the sequential loop, without the fixed cost of a batched
    /// (rayon + FFI) call for a handful of rays.
    bvh: std::sync::Arc<BvhCaster>,
    opts: SimplifyOptions,
    max_dist: f64,
    pub(crate) k: ControlMesh,
    pub(crate) valence_targets: ValenceTargets,
    version: Vec<u32>,
    pub(crate) fs: Vec<f64>,
    pub(crate) fm: Vec<f64>,
    /// Limit position of every live control vertex (kept current in the
    /// refit region; the M-fitmap test reads it).
    pub(crate) lim: Vec<DVec3>,
    heap: BinaryHeap<HeapEntry>,
    projections: usize,
    unprojectable: usize,
    /// Topological invariants of the input, checked per step in tests.
    invariants: (usize, usize, i64),
    /// Unit vertex normals of M (the guard's normal test).
    m_normals: Vec<DVec3>,
    diag: f64,
    /// Collapses the guard undid, by (smaller, larger) end id: not tried
    /// again until the next sweep (their heap entries come back with the
    /// restored faces).
    refused: std::collections::HashMap<(u32, u32), u8>,
    /// BFS stamps over vertices (region snapshots, batch claims).
    stamp: Vec<u32>,
    stamp_now: u32,
    /// The same stamps over faces (a snapshot's faces).
    face_stamp: Vec<u32>,
    /// Face and vertex points shared by the faces of one update.
    memo: PointMemo,
    /// Per vertex, the batch that claimed it ([`Simplifier::claim`]).
    claimed: Vec<u32>,
    batch_now: u32,
    ring_scratch: Vec<VertexId>,
    /// Buffers of [`Simplifier::update_faces_split`], kept between calls.
    face_scratch: FaceScratch,
    /// Old positions and limit points written by the current step, for its
    /// undo.
    pub(crate) pos_log: Vec<(VertexId, DVec3)>,
    pub(crate) lim_log: Vec<(VertexId, DVec3)>,
    /// Per face, the tests that refused its collapses since the last
    /// sweep began ([`Blocked`] bits): at the natural end, what stops each
    /// final patch ([`SimplifyStats::final_blockers`]).
    blocked: std::collections::HashMap<u32, u8>,
    /// κ of the S-fitmap test (0: off).
    pub(crate) kappa: f64,
    /// The last [`SimplifyOptions::checkpoints`] checkpoints, oldest
    /// (most faces) first, and the face count that takes the next one.
    checkpoints: std::collections::VecDeque<Checkpoint>,
    /// Scratch of [`Checkpoint::of`]: the compact id of every vertex.
    checkpoint_map: Vec<u32>,
    next_checkpoint: usize,
    /// The relaxation of the halting tests ([`RELAX_STEP`]), 1 unless
    /// `target_faces` asked for fewer faces than the natural end.
    pub(crate) relax: f64,
    /// One side of the split loop ([`SimplifyOptions::split`]): which
    /// faces may enter the heap and which edits a step may make.
    region: Option<split::Region>,
    /// From how many lines a step's φ batch is split in two halves over
    /// the pool ([`phi_lines_into`]); `usize::MAX`: never (set by
    /// [`Simplifier::run`] when the loop runs as a job of a pool of two
    /// threads or more, see [`DEFAULT_STEP_FORK`]).
    step_fork: usize,
    /// φ batches split so far ([`SimplifyStats::step_forks`]).
    step_forks: usize,
}

/// Buffers of [`Simplifier::update_faces_split`], kept between its calls
/// (a few per collapse, ~100k on bunny): the live faces asked for, their
/// centres' φ lines and φ's answers. Only their allocations carry over;
/// every call clears them first.
#[derive(Clone, Default)]
struct FaceScratch {
    live: Vec<FaceId>,
    lines: Vec<(DVec3, DVec3, f64)>,
    hits: Vec<Option<Projected>>,
}

/// The result of φ at one patch centre, for the guard.
#[derive(Copy, Clone, Debug)]
pub(crate) struct CentreCheck {
    face: FaceId,
    /// |centre − φ(centre)|, or the distance to the closest point of M when
    /// the normal line misses.
    residual: f64,
    /// Cosine between the limit normal and M's interpolated normal at the
    /// hit (1 when the line missed: no normal to compare).
    cos: f64,
}

/// φ lines asked and missed by read-only work (added to the loop's
/// counters in a fixed order afterwards).
#[derive(Copy, Clone, Debug, Default)]
struct PhiCount {
    lines: usize,
    misses: usize,
    /// Batches split in two ([`phi_lines_into`]).
    forks: usize,
}

impl PhiCount {
    fn add(&mut self, lines: usize, misses: usize) {
        self.lines += lines;
        self.misses += misses;
    }
}

/// A heap entry: (cost bits, face, diagonal, version), least cost first.
type HeapEntry = Reverse<(u64, u32, u8, u32)>;

/// One collapse of a batch ([`Simplifier::run_batch`]) and what its undo
/// needs.
struct Candidate {
    entry: HeapEntry,
    plan: CollapsePlan,
    /// The diagonal's ends, (smaller, larger) id: the key of `refused`.
    pair: (u32, u32),
    /// The faces the step changed, for its undo (when it may be undone and
    /// is alone in its batch).
    log: Option<FaceLog>,
    /// The region before the step, for its undo when it shares its batch:
    /// a face id another candidate freed may be reused by this one's
    /// collapse (or the other way round), and only the region tells whose
    /// face it is. Taken beside a log under `check_every_step`, to check
    /// that both give the same undo.
    snap: Option<Snapshot>,
    pos_log: Vec<(VertexId, DVec3)>,
    lim_log: Vec<(VertexId, DVec3)>,
    touched: Vec<VertexId>,
    rotations: usize,
    doublets: usize,
}

impl Candidate {
    fn new(entry: HeapEntry, plan: CollapsePlan, pair: (u32, u32)) -> Self {
        Candidate {
            entry,
            plan,
            pair,
            log: None,
            snap: None,
            pos_log: Vec::new(),
            lim_log: Vec::new(),
            touched: Vec::new(),
            rotations: 0,
            doublets: 0,
        }
    }
    fn face(&self) -> FaceId {
        FaceId((self.entry.0).1)
    }
    fn diagonal(&self) -> usize {
        (self.entry.0).2 as usize
    }
}

/// Catmull-Clark face points (centroids) and vertex points of one
/// [`Simplifier::update_faces`] call, each computed once: the limit at a
/// quad's centre ([`face_centre_limit`]) takes its face point, four edge
/// points (two face points each) and four vertex points (one face point
/// per incident face each), and the faces around a refit region share
/// most of them: about 25 centroids per face, where a region has about one
/// per face. Edge points are not kept: the two faces of an edge sum its
/// terms in opposite orders, and a shared value would change the bits.
#[derive(Clone, Default)]
struct PointMemo {
    now: u32,
    face: Vec<(u32, DVec3)>,
    vertex: Vec<(u32, DVec3)>,
}

impl PointMemo {
    /// Forgets the previous call's points (the mesh has changed since).
    fn begin(&mut self, k: &ControlMesh) {
        self.face
            .resize(k.num_faces().max(self.face.len()), (0, DVec3::ZERO));
        let nv = k.num_vertices().max(self.vertex.len());
        self.vertex.resize(nv, (0, DVec3::ZERO));
        self.now = self.now.wrapping_add(1);
        if self.now == 0 {
            self.face.iter_mut().for_each(|x| x.0 = 0);
            self.vertex.iter_mut().for_each(|x| x.0 = 0);
            self.now = 1;
        }
    }

    fn centroid(&mut self, k: &ControlMesh, f: FaceId) -> DVec3 {
        let e = &mut self.face[f.idx()];
        if e.0 != self.now {
            *e = (self.now, centroid(k, f));
        }
        e.1
    }

    fn vertex_point(&mut self, k: &ControlMesh, v: VertexId) -> DVec3 {
        if self.vertex[v.idx()].0 != self.now {
            let p = vertex_point_with(k, v, |g| self.centroid(k, g));
            self.vertex[v.idx()] = (self.now, p);
        }
        self.vertex[v.idx()].1
    }

    /// [`face_centre_limit`] of the quad `f`, bit for bit.
    fn centre_limit(&mut self, k: &ControlMesh, f: FaceId) -> LimitPoint {
        let mut e = [DVec3::ZERO; 4];
        let mut vp = [DVec3::ZERO; 4];
        for (i, h) in k.face_halfedges(f).enumerate().take(4) {
            e[i] = edge_point_with(k, h, |g| self.centroid(k, g));
            vp[i] = self.vertex_point(k, k.tail(h));
        }
        let fp = self.centroid(k, f);
        face_centre_limit_from(fp, &e, &vp)
    }
}

/// What [`Simplifier::next_batch`] found.
enum NextBatch {
    Ready(Vec<Candidate>),
    /// The heap is empty: a sweep or the natural end.
    Empty,
    /// `target_faces` is reached.
    Target,
}

/// W of a local refit, W's limit masks and the faces around W
/// ([`Simplifier::refit_region`]).
struct RefitRegion {
    w: Vec<VertexId>,
    /// W's masks end to end, `w[i]`'s at `mask_at[i]..mask_at[i + 1]`
    /// (one allocation per region rather than one per vertex).
    masks: Vec<(VertexId, f64)>,
    mask_at: Vec<usize>,
    faces: Vec<FaceId>,
}

impl RefitRegion {
    /// The limit mask of `w[i]`.
    fn mask(&self, i: usize) -> &[(VertexId, f64)] {
        &self.masks[self.mask_at[i]..self.mask_at[i + 1]]
    }
}

/// `f` over `xs` in input order, one item per rayon job when there are
/// several (items are whole candidates' work); the result does not depend
/// on the threads.
fn map_in_order<T: Sync, R: Send>(xs: &[T], f: impl Fn(&T) -> R + Sync + Send) -> Vec<R> {
    if xs.len() > 1 {
        use rayon::prelude::*;
        xs.par_iter().with_max_len(1).map(f).collect()
    } else {
        xs.iter().map(f).collect()
    }
}

/// Edge rings around a candidate quad that no other candidate of its
/// batch may reach. A step writes positions within 4 edges of the quad's
/// corners (W: the rotations' vertices, within 3, plus their 1-ring) and
/// limit points within 6 (the corners of the faces around W), and reads
/// positions within 8 (those corners' limit masks and the face-centre
/// limits around W); two claims of 7 rings that do not meet keep the quads
/// 15 edges apart, more than 8 + 6, with one edge to spare for each of
/// the two collapses shortening paths.
const BATCH_RINGS: usize = 7;

/// Candidates per batch put back (their region met an earlier one's)
/// before a batch is closed short, per place in it: bounds the pops per
/// batch on a coarse mesh, where most regions meet.
const BATCH_DEFER: usize = 2;

/// A checkpoint of the loop ([`SimplifyOptions::checkpoints`]): the live
/// mesh as [`ControlMesh::live_polygons`] gives it, with the polygons in
/// one flat list. A run takes one per 6 % fewer faces, about ninety on
/// bunny, and keeps the last forty; the first ones, the largest, one
/// allocation per polygon each in `LivePolygons`, were ~3 % of the loop.
#[derive(Clone)]
struct Checkpoint {
    positions: Vec<DVec3>,
    vertex_sharpness: Vec<f64>,
    /// The polygons' compact vertex ids, end to end; polygon `i` is
    /// `corners[start[i]..start[i + 1]]`.
    corners: Vec<u32>,
    start: Vec<u32>,
    creases: Vec<(u32, u32, f64)>,
}

impl Checkpoint {
    /// The live part of `k` in `live_polygons`' order (live vertices and
    /// faces by id); `map` is scratch.
    fn of(k: &ControlMesh, map: &mut Vec<u32>) -> Self {
        map.clear();
        map.resize(k.num_vertices(), u32::MAX);
        let nv = k.num_live_vertices();
        let (mut positions, mut vertex_sharpness) =
            (Vec::with_capacity(nv), Vec::with_capacity(nv));
        for v in k.vertices() {
            if !k.is_vertex_deleted(v) {
                map[v.idx()] = positions.len() as u32;
                positions.push(k.position(v));
                vertex_sharpness.push(k.vertex_sharpness(v));
            }
        }
        let nf = k.num_live_faces();
        let mut corners = Vec::with_capacity(4 * nf);
        let mut start = Vec::with_capacity(nf + 1);
        start.push(0);
        for f in k.faces() {
            if !k.is_face_deleted(f) {
                corners.extend(k.face_vertices(f).map(|v| map[v.idx()]));
                start.push(corners.len() as u32);
            }
        }
        let creases = k
            .edges()
            .filter(|&e| !k.is_edge_deleted(e) && k.edge_sharpness(e) > 0.0)
            .map(|e| {
                let (a, b) = k.edge_vertices(e);
                (map[a.idx()], map[b.idx()], k.edge_sharpness(e))
            })
            .collect();
        Checkpoint {
            positions,
            vertex_sharpness,
            corners,
            start,
            creases,
        }
    }

    fn into_polygons(self) -> crate::mesh::LivePolygons {
        let polygons = self
            .start
            .windows(2)
            .map(|w| self.corners[w[0] as usize..w[1] as usize].to_vec())
            .collect();
        crate::mesh::LivePolygons {
            positions: self.positions,
            vertex_sharpness: self.vertex_sharpness,
            polygons,
            creases: self.creases,
        }
    }
}

/// What an undo replaces ([`Simplifier::restore`]): faces to remove,
/// quads to put back (both in face id order) and vertices to revive.
#[derive(Debug, PartialEq)]
struct UndoLists {
    remove: Vec<FaceId>,
    add: Vec<[VertexId; 4]>,
    revive: Vec<VertexId>,
}

/// The faces of a region before a step, for its undo when a log cannot
/// serve (a step that shares its batch, `field::cleanup`'s moves).
pub(crate) struct Snapshot {
    pub(crate) vertices: Vec<VertexId>,
    pub(crate) faces: Vec<(FaceId, [VertexId; 4])>,
}

/// The state a trial step can change, whole ([`Simplifier::save_exact`]):
/// restoring it puts back the same face, edge and vertex ids, so a refused
/// step leaves no trace. [`Simplifier::undo`] restores the region's faces
/// under whichever free slots come first, and every later tie-break by id
/// (candidate order, diagonal index) then differs from a run where the
/// step was never tried (field cleanup's moves: a move refused at spot's
/// 81 faces still changed RMS D 1.010 → 1.362‰, docs/status.md).
/// `version` and the heap are not in it: they only grow (a restored
/// face's entries are stale, and the cleanup never pops).
#[derive(Clone)]
pub(crate) struct Exact {
    k: ControlMesh,
    lim: Vec<DVec3>,
    fs: Vec<f64>,
    fm: Vec<f64>,
    pos_log: Vec<(VertexId, DVec3)>,
    lim_log: Vec<(VertexId, DVec3)>,
}

/// Bits naming the tests that refuse a collapse.
struct Blocked;

impl Blocked {
    const TOPOLOGY: u8 = 1;
    const M_FITMAP: u8 = 2;
    const S_FITMAP: u8 = 4;
    const GUARD_DISTANCE: u8 = 8;
    const GUARD_NORMAL: u8 = 16;
    /// The collapse would leave fewer than `target_faces`' 2 % window.
    const UNDERSHOOT: u8 = 32;
    const NAMES: [(u8, &'static str); 6] = [
        (Self::TOPOLOGY, "topology"),
        (Self::M_FITMAP, "m_fitmap"),
        (Self::S_FITMAP, "s_fitmap"),
        (Self::GUARD_DISTANCE, "guard_distance"),
        (Self::GUARD_NORMAL, "guard_normal"),
        (Self::UNDERSHOOT, "undershoot"),
    ];
}

/// The centre (corners' mean) and radius (farthest corner) of a patch.
fn patch_radius(q: &[DVec3; 4]) -> (DVec3, f64) {
    let ctr = 0.25 * (q[0] + q[1] + q[2] + q[3]);
    let r = q.iter().map(|p| (*p - ctr).length()).fold(0.0, f64::max);
    (ctr, r)
}

/// Rings around a collapsed quad that a step can change (see
/// [`Simplifier::snapshot`]); one more than needed, for safety.
const SNAPSHOT_RINGS: usize = 3;

fn euler(k: &ControlMesh) -> i64 {
    k.num_live_vertices() as i64 - k.num_live_edges() as i64 + k.num_live_faces() as i64
}

/// φ of one point along the unit direction `n` on the BVH: the nearer hit of
/// the line within `max_t` in either direction, `+n` winning ties (the
/// semantics of [`RayCaster::line_hits`]), in one traversal of the line
/// ([`BvhCaster::line_hit`]: the same hit as a forward ray and a backward
/// one up to it, which descended the tree twice).
fn phi_line(bvh: &BvhCaster, o: DVec3, n: DVec3, max_t: f64) -> Option<Projected> {
    if n == DVec3::ZERO || !o.is_finite() || !n.is_finite() {
        return None;
    }
    bvh.line_hit(o, n, max_t).map(|h| Projected {
        point: o + h.t * n,
        offset: h.t,
        triangle: h.triangle,
        u: h.u,
        v: h.v,
    })
}

/// φ of a batch of `(origin, unit direction, search distance)` lines, in
/// order, into `out` (its previous contents dropped, its allocation kept:
/// the loop asks for a few dozen lines per step, ~100k times on bunny).
/// From `par_min` lines on (the sweeps over every face) they
/// are split over the rayon pool; the map keeps input order, so the result
/// does not depend on the threads.
fn phi_batch_into(
    bvh: &BvhCaster,
    lines: &[(DVec3, DVec3, f64)],
    par_min: usize,
    out: &mut Vec<Option<Projected>>,
) {
    let one = |&(o, n, t): &(DVec3, DVec3, f64)| phi_line(bvh, o, n, t);
    if lines.len() >= par_min {
        use rayon::prelude::*;
        lines
            .par_iter()
            .with_min_len((par_min / 2).max(1))
            .map(one)
            .collect_into_vec(out);
    } else {
        out.clear();
        out.extend(lines.iter().map(one));
    }
}

/// Lines from which [`phi_batch_into`] forks. A collapse's refit and face
/// updates ask for a few dozen lines at a time, and those stay on the
/// loop's thread: forking them from 16 lines on was measured slower than
/// sequential (docs/status.md, "Measurements behind the code"). Each fork/join wakes a
/// worker (30k collapses, ~100k wake-ups), and when the OS has preempted
/// the worker that stole half a batch the loop waits for it.
const PHI_PAR_MIN: usize = 512;

/// Default of `SUBDFIT_SIMPLIFY_FORK` (lines; `0` turns it off): from this
/// many lines on, a step's φ batch (its refit's targets, its faces'
/// centres) is split in two halves, one of them a job for the pool's other
/// worker (issue 39: the loop is the pipeline's longest stage on one
/// core). Unlike the forks `PHI_PAR_MIN` measured, these are made from
/// inside the pool ([`Simplifier::run`] runs the loop as a pool job): a
/// fork is a push on the loop's own deque, and a half nobody stole by the
/// time the loop is done with its own is taken back and run by the loop
/// (`rayon::join`), so a preempted or sleeping worker costs no wait. Each
/// line's φ is computed alone and written at its index, so the answers are
/// those of the sequential loop bit for bit, at any thread count.
///
/// Off (0) by default: measured on quiet cores (session 19, bunny defaults,
/// 2 threads, three alternating pairs) the simplify stage's wall was
/// 4.66 / 4.75 / 5.16 s split at 16 lines against 4.72 / 4.93 / 4.12 s
/// unsplit, and the run's system CPU rose 0.5 → 2.3 s (idle workers
/// spinning): the halves are too small for the hand-over to pay.
/// `SUBDFIT_SIMPLIFY_FORK=16` turns it on.
pub const DEFAULT_STEP_FORK: usize = 0;

/// φ of `lines` into `out` as [`phi_batch_into`], and below `par_min`
/// lines, from `fork` lines on, in two halves side by side
/// (`rayon::join`): the same answers in the same order. Whether it split.
fn phi_lines_into(
    bvh: &BvhCaster,
    lines: &[(DVec3, DVec3, f64)],
    (par_min, fork): (usize, usize),
    out: &mut Vec<Option<Projected>>,
) -> bool {
    if lines.len() >= par_min || lines.len() < fork.max(2) {
        phi_batch_into(bvh, lines, par_min, out);
        return false;
    }
    let fill = |out: &mut [Option<Projected>], lines: &[(DVec3, DVec3, f64)]| {
        for (o, &(p, n, t)) in out.iter_mut().zip(lines) {
            *o = phi_line(bvh, p, n, t);
        }
    };
    out.clear();
    out.resize(lines.len(), None);
    let mid = lines.len() / 2;
    let (oa, ob) = out.split_at_mut(mid);
    let (la, lb) = lines.split_at(mid);
    rayon::join(|| fill(oa, la), || fill(ob, lb));
    true
}

/// Search distance of φ around a feature of size `scale` (a ring's or a
/// face's extent): a point of the limit surface further than twice that
/// from M along its normal has no meaningful projection there, and a short
/// ray is what makes the query cheap. Capped by the global `max_dist`.
#[inline]
fn local_reach(scale: f64, max_dist: f64) -> f64 {
    (2.0 * scale).min(max_dist)
}

impl<'a> Simplifier<'a> {
    pub(crate) fn new(
        m: &'a TriMesh,
        fitmap: &'a Fitmap,
        caster: &'a dyn RayCaster,
        opts: &SimplifyOptions,
        mut k: ControlMesh,
        poll: &mut dyn FnMut() -> Result<()>,
    ) -> Result<Self> {
        if !k.is_all_quads() {
            return Err(Error::topology(
                "mesh",
                "the greedy simplification needs a control mesh of quads only",
            ));
        }
        let max_dist = opts.max_dist.unwrap_or_else(|| default_max_dist(m));
        // Doublets of the quadrangulation (a vertex of triangle valence 3
        // whose paired diagonals left it two edges) go first (§3.3.3).
        let all: Vec<VertexId> = k.live_vertices().collect();
        remove_doublets(&mut k, &all)?;
        poll()?;
        let valence_targets = ValenceTargets::new(&k);
        let invariants = (k.num_components(), k.num_boundary_loops(), euler(&k));
        let nf = k.num_faces();
        poll()?;
        let bvh = BvhCaster::shared(m)?;
        poll()?;
        let lim = all_limits(&k)?;
        poll()?;
        Ok(Simplifier {
            m,
            fitmap,
            caster,
            bvh,
            opts: opts.clone(),
            max_dist,
            k,
            valence_targets,
            version: vec![0; nf],
            fs: vec![0.0; nf],
            fm: vec![0.0; nf],
            lim,
            heap: BinaryHeap::new(),
            projections: 0,
            unprojectable: 0,
            invariants,
            m_normals: crate::analysis::normals::vertex_normals(m),
            diag: m.bbox_diagonal(),
            refused: Default::default(),
            stamp: Vec::new(),
            stamp_now: 0,
            face_stamp: Vec::new(),
            memo: PointMemo::default(),
            claimed: Vec::new(),
            batch_now: 0,
            ring_scratch: Vec::new(),
            face_scratch: Default::default(),
            pos_log: Vec::new(),
            lim_log: Vec::new(),
            blocked: Default::default(),
            kappa: if opts.s_fitmap_scale > 0.0 {
                opts.s_fitmap_scale * s_fitmap_kappa(m, fitmap)
            } else {
                0.0
            },
            checkpoints: Default::default(),
            checkpoint_map: Vec::new(),
            next_checkpoint: (nf as f64 / CHECKPOINT_RATIO) as usize,
            relax: 1.0,
            region: None,
            step_fork: usize::MAX,
            step_forks: 0,
        })
    }

    /// φ of one point, counted in `count` (read-only: the batched loop asks
    /// from several candidates at once).
    fn phi_counted(
        &self,
        o: DVec3,
        n: DVec3,
        scale: f64,
        count: &mut PhiCount,
    ) -> Option<Projected> {
        let p = phi_line(&self.bvh, o, n, local_reach(scale, self.max_dist));
        count.add(1, p.is_none() as usize);
        p
    }

    fn add_count(&mut self, count: PhiCount) {
        self.projections += count.lines;
        self.unprojectable += count.misses;
        self.step_forks += count.forks;
    }

    /// Recomputes centre, F_S, F_M and heap entries of `faces` (live ones);
    /// returns what φ found at each centre (for the guard).
    pub(crate) fn update_faces(&mut self, faces: &[FaceId]) -> Result<Vec<CentreCheck>> {
        self.update_faces_split(faces, PHI_PAR_MIN)
    }

    /// [`Simplifier::update_faces`], splitting the centres and their φ
    /// over the pool from `par_min` faces on (any split gives the same
    /// result: the maps keep input order).
    fn update_faces_split(&mut self, faces: &[FaceId], par_min: usize) -> Result<Vec<CentreCheck>> {
        let nf = self.k.num_faces();
        if self.version.len() < nf {
            self.version.resize(nf, 0);
            self.fs.resize(nf, 0.0);
            self.fm.resize(nf, 0.0);
        }
        // The buffers are taken out of `self` for the call (the loop below
        // writes `self` while reading them) and put back at the end.
        let mut scratch = std::mem::take(&mut self.face_scratch);
        let out = self.update_faces_with(faces, par_min, &mut scratch);
        self.face_scratch = scratch;
        out
    }

    /// [`Simplifier::update_faces_split`]'s body, in `scratch`'s buffers.
    fn update_faces_with(
        &mut self,
        faces: &[FaceId],
        par_min: usize,
        scratch: &mut FaceScratch,
    ) -> Result<Vec<CentreCheck>> {
        let FaceScratch { live, lines, hits } = scratch;
        live.clear();
        live.extend(
            faces
                .iter()
                .copied()
                .filter(|&f| !self.k.is_face_deleted(f)),
        );
        let faces = &live[..];
        let (k, max_dist) = (&self.k, self.max_dist);
        let line = |f: FaceId, l: LimitPoint| {
            let q = super::ops::quad_positions(k, f);
            let scale = (q[2] - q[0]).length().max((q[3] - q[1]).length());
            (l.position, l.normal(), local_reach(scale, max_dist))
        };
        // Map order is input order: the same result whatever the threads.
        if faces.len() >= par_min {
            use rayon::prelude::*;
            faces
                .par_iter()
                .with_min_len((par_min / 2).max(1))
                .map(|&f| line(f, face_centre_limit(k, f)))
                .collect_into_vec(lines);
        } else {
            // A step's faces are neighbours: their face and vertex points
            // are shared, taken once each (the same values, so the same
            // bits as `face_centre_limit`).
            let memo = &mut self.memo;
            memo.begin(k);
            lines.clear();
            lines.extend(faces.iter().map(|&f| line(f, memo.centre_limit(k, f))));
        }
        let forked = phi_lines_into(&self.bvh, lines, (par_min, self.step_fork), hits);
        self.step_forks += forked as usize;
        self.projections += hits.len();
        // A centre with no hit along its normal still needs Fitmap values:
        // take them at the closest point of M (the miss is counted).
        let miss: Vec<DVec3> = hits
            .iter()
            .zip(lines.iter())
            .filter(|(p, _)| p.is_none())
            .map(|(_, l)| l.0)
            .collect();
        self.unprojectable += miss.len();
        let mut closest = if miss.is_empty() {
            Vec::new()
        } else {
            self.caster.closest_points(&miss, f64::INFINITY)?
        }
        .into_iter();
        self.prefetch_hits(hits);
        let mut checks = Vec::with_capacity(faces.len());
        for (i, &f) in faces.iter().enumerate() {
            let (hit, (ctr, nrm, _)) = (hits[i], lines[i]);
            let (tri, u, v) = match hit {
                Some(p) => {
                    let t = self.m.triangles[p.triangle as usize];
                    let nm = (1.0 - p.u - p.v) * self.m_normals[t[0] as usize]
                        + p.u * self.m_normals[t[1] as usize]
                        + p.v * self.m_normals[t[2] as usize];
                    checks.push(CentreCheck {
                        face: f,
                        residual: p.offset.abs(),
                        cos: nm.normalize_or_zero().dot(nrm),
                    });
                    (p.triangle, p.u, p.v)
                }
                None => match closest.next().flatten() {
                    Some(c) => {
                        checks.push(CentreCheck {
                            face: f,
                            residual: (c.point - ctr).length(),
                            cos: 1.0,
                        });
                        (c.triangle, c.u, c.v)
                    }
                    None => {
                        checks.push(CentreCheck {
                            face: f,
                            residual: f64::INFINITY,
                            cos: 1.0,
                        });
                        (u32::MAX, 0.0, 0.0)
                    }
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
            if let Some(r) = &self.region {
                if !r.eligible(&self.k, f) {
                    continue;
                }
            }
            let q = super::ops::quad_positions(&self.k, f);
            for d in 0..2 {
                let len = (q[d] - q[d + 2]).length();
                let cost = len * s.max(0.0);
                self.heap
                    .push(Reverse((cost.to_bits(), f.0, d as u8, self.version[fi])));
            }
        }
        Ok(checks)
    }

    /// Asks for what [`Simplifier::update_faces_split`]'s loop reads of M at
    /// each hit: the triangle's corners, then their normals and Fitmap
    /// values. These are scattered over M (the BVH keeps its own copy of
    /// the triangles, so φ touched none of them), and read one hit after
    /// another they were the loop's two hottest loads (session 17's
    /// profile of bunny); asked for all at once, their misses overlap. A
    /// hint only: the values read, and so the result, are unchanged.
    fn prefetch_hits(&self, hits: &[Option<Projected>]) {
        let tris = &self.m.triangles;
        for p in hits.iter().flatten() {
            prefetch(tris.as_ptr().wrapping_add(p.triangle as usize));
        }
        for p in hits.iter().flatten() {
            for c in tris[p.triangle as usize] {
                let c = c as usize;
                prefetch(self.m_normals.as_ptr().wrapping_add(c));
                prefetch(self.fitmap.s.as_ptr().wrapping_add(c));
                prefetch(self.fitmap.m.as_ptr().wrapping_add(c));
            }
        }
    }

    /// The M-fitmap test (§3.1.1 / §3.3.1 with the README's correction):
    /// every patch the collapse enlarges — the faces around both ends of the
    /// diagonal except the collapsed one — must keep `radius <= F_M` at its
    /// projected centre.
    ///
    /// The patch is the limit surface's, not the control polygon's (the
    /// control polygon stands off a curved surface and is larger than its
    /// patch): its corners are the limit points of its control vertices
    /// (cached, [`vertex_limit_mask`]), the merged vertex's limit taken at
    /// the midpoint of the two ends' limits (where the refit will put it,
    /// the collapse placing the control vertex at the diagonal's midpoint;
    /// at the boundary end's limit when one end is on the boundary). The
    /// centre is the corners' mean, projected by φ along the corners'
    /// normal; F_M is interpolated there, linearly over M's triangle
    /// ([`Fitmap::m_at`]). A centre φ cannot project keeps the face's
    /// cached F_M.
    ///
    /// Read-only: the φ lines it asks are counted in `count`.
    fn fitmap_verdict(&self, f: FaceId, plan: &CollapsePlan, count: &mut PhiCount) -> Option<u8> {
        let (a, c) = (plan.keep, plan.remove);
        let boundary = self.k.is_boundary_vertex(a) || self.k.is_boundary_vertex(c);
        let merged = if let Some(s) = plan.corner {
            // Along the boundary: the merged vertex starts at the removed
            // corner, whose limit is itself (see `can_collapse_diagonal`).
            self.lim[s.idx()]
        } else if boundary {
            self.lim[plan.keep.idx()]
        } else {
            0.5 * (self.lim[a.idx()] + self.lim[c.idx()])
        };
        let mut faces: Vec<FaceId> = Vec::with_capacity(12);
        for v in [a, c] {
            faces.extend(self.k.vertex_faces(v).filter(|&g| g != f));
        }
        for g in faces {
            let mut q = [DVec3::ZERO; 4];
            let mut before = [DVec3::ZERO; 4];
            for (i, x) in self.k.face_vertices(g).enumerate() {
                before[i] = self.lim[x.idx()];
                q[i] = if x == a || x == c { merged } else { before[i] };
            }
            // Only a patch the collapse *extends* is tested (§3.3.1): one
            // that does not grow (the merged corner moves towards its
            // centre) cannot lose projectability by it, even if a doublet
            // removal or a rotation already left it above F_M.
            if patch_radius(&q).1 <= patch_radius(&before).1 {
                continue;
            }
            if let Some(why) = self.patch_verdict(g, &q, count) {
                return Some(why);
            }
        }
        None
    }

    /// The radius of one patch whose corners' limit points are `q`, and
    /// F_M, F_S at its centre projected by φ (face `g`'s cached values
    /// where φ misses).
    pub(crate) fn patch_fitmap(&mut self, g: FaceId, q: &[DVec3; 4]) -> (f64, f64, f64) {
        let mut count = PhiCount::default();
        let x = self.patch_fitmap_counted(g, q, &mut count);
        self.add_count(count);
        x
    }

    fn patch_fitmap_counted(
        &self,
        g: FaceId,
        q: &[DVec3; 4],
        count: &mut PhiCount,
    ) -> (f64, f64, f64) {
        let (ctr, r) = patch_radius(q);
        let n = (q[2] - q[0]).cross(q[3] - q[1]).normalize_or_zero();
        let (fm, fs) = match self.phi_counted(ctr, n, 2.0 * r, count) {
            Some(p) => (
                self.fitmap.m_at(self.m, p.triangle, p.u, p.v),
                self.fitmap.s_at(self.m, p.triangle, p.u, p.v),
            ),
            None => (self.fm[g.idx()], self.fs[g.idx()]),
        };
        (r, fm, fs)
    }

    /// The M- and S-fitmap tests of one patch whose corners' limit points
    /// are `q` (face `g`'s cached F_M, F_S where φ misses its centre):
    /// `radius ≤ F_M` and `radius · F_S ≤ κ`, both times the relaxation.
    // The loop itself asks `patch_verdict` (read-only); this counted form
    // is the one `field::cleanup`'s documentation names, kept for it.
    #[allow(dead_code)]
    pub(crate) fn patch_test(&mut self, g: FaceId, q: &[DVec3; 4]) -> Option<u8> {
        let mut count = PhiCount::default();
        let why = self.patch_verdict(g, q, &mut count);
        self.add_count(count);
        why
    }

    fn patch_verdict(&self, g: FaceId, q: &[DVec3; 4], count: &mut PhiCount) -> Option<u8> {
        let (r, fm, fs) = self.patch_fitmap_counted(g, q, count);
        if r > fm * self.relax {
            return Some(Blocked::M_FITMAP);
        }
        if r * fs > self.kappa * self.relax && self.kappa > 0.0 {
            return Some(Blocked::S_FITMAP);
        }
        None
    }

    /// Tells `progress` where the run is; its `false` is a cancellation.
    fn ask(
        &self,
        stats: &SimplifyStats,
        t0: Instant,
        progress: &mut dyn FnMut(Progress) -> bool,
    ) -> Result<()> {
        let p = Progress {
            faces: self.k.num_live_faces(),
            initial_faces: stats.initial_faces,
            collapses: stats.collapses,
            seconds: t0.elapsed().as_secs_f64(),
        };
        if progress(p) {
            Ok(())
        } else {
            Err(Error::Cancelled {
                stage: "simplification".into(),
            })
        }
    }

    /// Re-evaluates every live face, asking `progress` between chunks: the
    /// same heap entries in the same order as one batch (each face's update
    /// is independent of the others').
    fn update_all(
        &mut self,
        stats: &SimplifyStats,
        t0: Instant,
        progress: &mut dyn FnMut(Progress) -> bool,
    ) -> Result<()> {
        const SWEEP_CHUNK: usize = 2048;
        // Every live face gets fresh entries (and a new version), so every
        // entry in the heap now is stale: dropping them changes no pop.
        self.heap.clear();
        let all: Vec<FaceId> = match &self.region {
            Some(r) => self
                .k
                .live_faces()
                .filter(|&f| r.reads(&self.k, f))
                .collect(),
            None => self.k.live_faces().collect(),
        };
        for c in all.chunks(SWEEP_CHUNK) {
            let _ = self.update_faces(c)?;
            self.ask(stats, t0, progress)?;
        }
        Ok(())
    }

    /// The greedy loop (§3.3), in batches of at most
    /// [`SimplifyOptions::batch`] candidates: the next ones in the heap's
    /// order whose regions ([`BATCH_RINGS`]) do not meet. A batch's
    /// read-only work — the Fitmap tests, and each refit round's smoothing,
    /// φ targets and fit sweeps — runs one candidate per rayon job; every
    /// edit (collapse, rotations, positions, limit points, heap, undo) is
    /// made on this thread in the heap's order. Which candidates form a
    /// batch depends on the heap and the mesh only, never on the threads,
    /// so the result is the same at any thread count. A batch of one is the
    /// sequential loop, step for step.
    fn run(
        &mut self,
        stats: &mut SimplifyStats,
        progress: &mut dyn FnMut(Progress) -> bool,
    ) -> Result<()> {
        if self.opts.split && self.region.is_none() {
            return self.run_split(stats, progress);
        }
        // The sequential loop's φ batches fork in two (`DEFAULT_STEP_FORK`)
        // when there is a second thread, and only from inside the pool,
        // where a fork is cheap. What stays sequential, and why: each
        // step's heap pop, collapse, rotations, refit rounds and face
        // updates read the previous step's mesh and heap (Fitmaps' greedy
        // order, §3.3), so only the independent φ lines within a phase are
        // split; the Fitmap test of a candidate stops at its first failing
        // patch (a few lines) and stays on the loop's thread.
        let asked = self.opts.step_fork;
        let asked = asked.or_else(|| crate::switches::parsed("SUBDFIT_SIMPLIFY_FORK"));
        let fork = match asked.unwrap_or(DEFAULT_STEP_FORK) {
            0 => usize::MAX,
            n => n,
        };
        let forks = self.opts.batch <= 1
            && self.region.is_none()
            && rayon::current_num_threads() > 1
            && fork < PHI_PAR_MIN;
        self.step_fork = if forks { fork } else { usize::MAX };
        if rayon::current_thread_index().is_some() || (self.opts.batch <= 1 && !forks) {
            return self.run_loop(stats, progress);
        }
        // A batch forks about fifteen times (its Fitmap tests, and each
        // refit round's phases). From a thread outside the pool every fork
        // is a hand-over to a worker and a futex wait for it (measured: a
        // tenth of the loop's samples in the kernel, and 40 % more CPU than
        // the sequential loop on one thread); from a worker it is a push
        // on its own deque. So the loop runs as one job in the pool, and
        // this thread keeps the progress callback (a host's, which need
        // not be callable from elsewhere), answering the loop's questions
        // over a channel.
        let (to_host, from_loop) = std::sync::mpsc::channel::<Progress>();
        let (to_loop, from_host) = std::sync::mpsc::channel::<bool>();
        let mut result = Ok(());
        rayon::in_place_scope(|scope| {
            let result = &mut result;
            scope.spawn(move |_| {
                let mut ask =
                    |p: Progress| to_host.send(p).is_ok() && from_host.recv().unwrap_or(false);
                *result = self.run_loop(stats, &mut ask);
            });
            // Ends when the loop's end of the channel is dropped.
            for p in from_loop {
                let _ = to_loop.send(progress(p));
            }
        });
        result
    }

    /// The loop of [`Simplifier::run`], on the thread it is called on.
    fn run_loop(
        &mut self,
        stats: &mut SimplifyStats,
        progress: &mut dyn FnMut(Progress) -> bool,
    ) -> Result<()> {
        let t0 = Instant::now();
        stats.initial_faces = self.k.num_live_faces();
        self.update_all(stats, t0, progress)?;
        let target = self.opts.target_faces.unwrap_or(0);
        let mut stop = StopReason::NaturalEnd;
        let mut at_last_sweep = stats.collapses;
        let mut pops = 0usize;
        loop {
            let batch = match self.next_batch(stats, t0, progress, &mut pops, target)? {
                NextBatch::Ready(b) => b,
                NextBatch::Target => {
                    stop = StopReason::TargetFaces;
                    break;
                }
                NextBatch::Empty => {
                    // The heap only re-evaluates faces around a refit region; a
                    // refused collapse whose blocking neighbour changed later
                    // from further away was never looked at again. Before
                    // declaring the natural end, re-evaluate every face once
                    // more, as long as the previous sweep led to collapses.
                    if stats.collapses == at_last_sweep {
                        // The natural end. Above a `target_faces` (by more than
                        // its 2 % window), relax the halting tests one step
                        // and sweep again.
                        let above = self.k.num_live_faces() as f64 > 1.02 * target as f64;
                        if target == 0
                            || !above
                            || stats.relax_steps == MAX_RELAX_STEPS
                            || self.region.is_some()
                        {
                            break;
                        }
                        self.relax *= RELAX_STEP;
                        stats.relax_steps += 1;
                        stats.relaxation = self.relax;
                    }
                    at_last_sweep = stats.collapses;
                    stats.sweeps += 1;
                    // A collapse the guard undid was refused for the geometry of
                    // its region then; collapses since may have changed it (the
                    // refits move vertices, neighbouring collapses change the
                    // patches), so it gets one more try per sweep. The loop
                    // still ends: a sweep with no collapse is the last.
                    self.refused.clear();
                    self.blocked.clear();
                    self.update_all(stats, t0, progress)?;
                    continue;
                }
            };
            self.run_batch(batch, stats, target)?;
        }
        if self.k.num_live_faces() <= target {
            stop = StopReason::TargetFaces;
        }
        stats.stop = Some(stop);
        stats.relaxation = self.relax;
        stats.s_fitmap_kappa = self.kappa;
        stats.projections = self.projections;
        stats.step_forks = self.step_forks;
        stats.unprojectable = self.unprojectable;
        Ok(())
    }

    /// Pops the next batch: live entries in the heap's order, each passing
    /// the topology check and not refused this sweep (those are counted and
    /// dropped, as in a sequential step), whose region meets no earlier
    /// candidate's (those go back to the heap for a later batch). A batch
    /// of one near `target_faces` (its undershoot check counts faces one
    /// collapse at a time).
    fn next_batch(
        &mut self,
        stats: &mut SimplifyStats,
        t0: Instant,
        progress: &mut dyn FnMut(Progress) -> bool,
        pops: &mut usize,
        target: usize,
    ) -> Result<NextBatch> {
        // The progress callback is also how a cancellation arrives: it is
        // asked every ASK_EVERY heap pops (refused ones included: a run of
        // refusals can be long) and between chunks of a full sweep.
        const ASK_EVERY: usize = 64;
        let live = self.k.num_live_faces();
        let size = if target > 0 && live <= target + 8 * self.opts.batch {
            1
        } else {
            self.opts.batch.max(1)
        };
        self.batch_now = self.batch_now.wrapping_add(1);
        if self.batch_now == 0 {
            self.claimed.iter_mut().for_each(|x| *x = 0);
            self.batch_now = 1;
        }
        let mut batch: Vec<Candidate> = Vec::with_capacity(size);
        let mut deferred = Vec::new();
        while batch.len() < size && deferred.len() < BATCH_DEFER * size {
            *pops += 1;
            if *pops % ASK_EVERY == 0 {
                self.ask(stats, t0, progress)?;
            }
            self.compact_heap();
            let Some(entry) = self.heap.pop() else {
                break;
            };
            let Reverse((_, fi, d, ver)) = entry;
            if live <= target {
                if batch.is_empty() {
                    return Ok(NextBatch::Target);
                }
                self.heap.push(entry);
                break;
            }
            let f = FaceId(fi);
            if self.k.is_face_deleted(f) || self.version[f.idx()] != ver {
                continue;
            }
            let plan = match can_collapse_diagonal(&self.k, f, d as usize) {
                Ok(p) => p,
                Err(why) => {
                    stats.refused_topology += 1;
                    self.block(fi, Blocked::TOPOLOGY);
                    *stats
                        .refused_topology_by_reason
                        .entry(why.to_string())
                        .or_default() += 1;
                    continue;
                }
            };
            let pair = (
                plan.keep.0.min(plan.remove.0),
                plan.keep.0.max(plan.remove.0),
            );
            if let Some(&why) = self.refused.get(&pair) {
                self.block(fi, why);
                continue;
            }
            if size > 1 && !self.claim(f) {
                deferred.push(entry);
                continue;
            }
            batch.push(Candidate::new(entry, plan, pair));
        }
        for e in deferred {
            self.heap.push(e);
        }
        Ok(if batch.is_empty() {
            NextBatch::Empty
        } else {
            NextBatch::Ready(batch)
        })
    }

    /// Claims the vertices within [`BATCH_RINGS`] edges of the corners of
    /// `f` for the current batch; `false` (and nothing claimed) if one is
    /// already another candidate's.
    fn claim(&mut self, f: FaceId) -> bool {
        let nv = self.k.num_vertices();
        if self.claimed.len() < nv {
            self.claimed.resize(nv, 0);
        }
        if self.stamp.len() < nv {
            self.stamp.resize(nv, 0);
        }
        self.next_stamp();
        let (now, batch) = (self.stamp_now, self.batch_now);
        let mut ring = std::mem::take(&mut self.ring_scratch);
        ring.clear();
        ring.extend(self.k.face_vertices(f));
        let mut free = true;
        for &v in &ring {
            self.stamp[v.idx()] = now;
            free &= self.claimed[v.idx()] != batch;
        }
        let mut start = 0;
        for _ in 0..BATCH_RINGS {
            if !free {
                break;
            }
            let end = ring.len();
            for i in start..end {
                for h in self.k.outgoing(ring[i]) {
                    let u = self.k.head(h);
                    if self.stamp[u.idx()] != now {
                        self.stamp[u.idx()] = now;
                        free &= self.claimed[u.idx()] != batch;
                        ring.push(u);
                    }
                }
            }
            start = end;
        }
        if free {
            for &v in &ring {
                self.claimed[v.idx()] = batch;
            }
        }
        self.ring_scratch = ring;
        free
    }

    /// One batch: the Fitmap tests (one job per candidate), the collapses
    /// and rotations in order, the refits ([`Simplifier::refit_batch`]),
    /// then the guard of each candidate in order, undoing the refused ones.
    fn run_batch(
        &mut self,
        mut batch: Vec<Candidate>,
        stats: &mut SimplifyStats,
        target: usize,
    ) -> Result<()> {
        stats.batches += 1;
        stats.batched_candidates += batch.len();
        if self.opts.m_fitmap {
            let verdicts = map_in_order(&batch, |c| {
                let mut count = PhiCount::default();
                (self.fitmap_verdict(c.face(), &c.plan, &mut count), count)
            });
            let mut keep = Vec::with_capacity(batch.len());
            for (c, (why, count)) in batch.into_iter().zip(verdicts) {
                self.add_count(count);
                if let Some(why) = why {
                    if why == Blocked::S_FITMAP {
                        stats.refused_s_fitmap += 1;
                    } else {
                        stats.refused_m_fitmap += 1;
                    }
                    self.block(c.face().0, why);
                } else {
                    keep.push(c);
                }
            }
            batch = keep;
        }

        let guard = self.opts.guard_scale > 0.0;
        // One candidate (the sequential loop): nothing but its own step
        // changes the connectivity before its undo, so its log suffices.
        let alone = batch.len() == 1;
        let mut done = Vec::with_capacity(batch.len());
        for mut c in batch {
            let f = c.face();
            let d = c.diagonal();
            if !done.is_empty() {
                // The regions of a batch do not meet, so an earlier
                // candidate's edits leave this face and its plan as they
                // were; checked again all the same (a changed one goes back
                // to the heap, and is the first of a later batch).
                let same = |p: &CollapsePlan| {
                    (p.keep, p.remove, p.sides, p.corner)
                        == (c.plan.keep, c.plan.remove, c.plan.sides, c.plan.corner)
                };
                if self.k.is_face_deleted(f) || self.version[f.idx()] != (c.entry.0).3 {
                    continue;
                }
                match can_collapse_diagonal(&self.k, f, d) {
                    Ok(p) if same(&p) => c.plan = p,
                    _ => {
                        self.heap.push(c.entry);
                        continue;
                    }
                }
            }
            let plan = c.plan;
            let undoable = guard || target > 0 || self.region.is_some();
            c.log = (undoable && alone).then(FaceLog::default);
            c.snap = (undoable && (!alone || self.opts.check_every_step)).then(|| self.snapshot(f));
            c.pos_log.push((plan.keep, self.k.position(plan.keep)));
            let col =
                collapse_diagonal_logged(&mut self.k, f, d, Some(plan.position), c.log.as_mut())?;
            stats.collapses += 1;
            stats.doublets += col.doublets.len();
            c.doublets = col.doublets.len();
            self.check_step("collapse")?;
            let mut touched = vec![col.keep, plan.sides[0], plan.sides[1]];
            touched.retain(|&v| !self.k.is_vertex_deleted(v));
            let centres = touched.clone();
            c.rotations = self.rotate_around(&centres, &mut touched, c.log.as_mut())?;
            stats.rotations += c.rotations;
            c.touched = touched;
            if self.region.is_some() && !self.region_allows(&c) {
                self.undo_outside(c, stats)?;
                continue;
            }
            done.push(c);
        }
        let checks = self.refit_batch(&mut done)?;
        // A collapse whose doublet removals would take the mesh below
        // `target_faces`' 2 % window is undone too (`--faces N` lands
        // within ±2 %; one that removes a single face is always fine).
        let floor = (0.98 * target as f64).ceil() as usize;
        let mut kept = 0;
        for (c, checks) in done.into_iter().zip(checks) {
            let f = c.face();
            if c.log.is_none() && c.snap.is_none() {
                kept += 1;
                continue;
            }
            let Some(why) = self.refusal(guard, &checks, floor) else {
                kept += 1;
                continue;
            };
            self.block(f.0, why);
            stats.count_refusal(why);
            stats.collapses -= 1;
            stats.doublets -= c.doublets;
            stats.rotations -= c.rotations;
            self.pos_log = c.pos_log;
            self.lim_log = c.lim_log;
            let lists = match (&c.log, &c.snap) {
                (Some(log), snap) => {
                    let lists = self.log_lists(log);
                    if let Some(want) = snap.as_ref().map(|s| self.snapshot_lists(s)) {
                        if lists != want {
                            return Err(Error::topology(
                                f.to_string(),
                                format!(
                                    "the undo from the step's log {lists:?} differs from \
                                     the undo from its snapshot {want:?}"
                                ),
                            ));
                        }
                    }
                    lists
                }
                (None, Some(snap)) => self.snapshot_lists(snap),
                (None, None) => continue, // kept above
            };
            self.restore(lists)?;
            self.refused.insert(c.pair, why);
            self.check_step("undo")?;
        }
        if kept > 0 {
            self.checkpoint()?;
        }
        Ok(())
    }

    /// [`Simplifier::refit`] of every candidate of a batch: the regions do
    /// not meet, so each round's smoothing, φ targets and sweeps of one
    /// candidate read nothing another one writes, and they run one
    /// candidate per job (a whole region's work per job: forking a single
    /// refit's few dozen φ lines was measured slower than running them
    /// sequentially); positions, limit points and the logs are written here
    /// in order. Then one update of all their faces, whose centres and φ
    /// are split over the pool. Returns each candidate's centre checks.
    fn refit_batch(&mut self, cands: &mut [Candidate]) -> Result<Vec<Vec<CentreCheck>>> {
        let regions: Vec<RefitRegion> = map_in_order(cands, |c| self.refit_region(&c.touched))
            .into_iter()
            .collect::<Result<_>>()?;
        for (c, r) in cands.iter_mut().zip(&regions) {
            c.pos_log
                .extend(r.w.iter().map(|&v| (v, self.k.position(v))));
        }
        for _ in 0..self.opts.refit_rounds {
            let smooth = map_in_order(&regions, |r| self.smoothed(r));
            for (r, x) in regions.iter().zip(&smooth) {
                self.set_positions(&r.w, x, false);
            }
            let targets = map_in_order(&regions, |r| {
                let mut count = PhiCount::default();
                (self.fit_targets(r, &mut count), count)
            });
            for (_, count) in &targets {
                self.add_count(*count);
            }
            for _ in 0..self.opts.fit_sweeps {
                let pairs: Vec<(&RefitRegion, &Vec<DVec3>)> =
                    regions.iter().zip(targets.iter().map(|t| &t.0)).collect();
                let delta = map_in_order(&pairs, |(r, t)| self.fit_deltas(r, t));
                for (r, x) in regions.iter().zip(&delta) {
                    self.set_positions(&r.w, x, true);
                }
            }
        }
        let limits = map_in_order(&regions, |r| self.refit_limits(r));
        for (c, l) in cands.iter_mut().zip(limits) {
            for (v, l) in l? {
                c.lim_log.push((v, self.lim[v.idx()]));
                self.lim[v.idx()] = l;
            }
        }
        let faces: Vec<FaceId> = regions
            .iter()
            .flat_map(|r| r.faces.iter().copied())
            .collect();
        let par_min = if cands.len() > 1 { 64 } else { PHI_PAR_MIN };
        let all = self.update_faces_split(&faces, par_min)?;
        // The faces around W are live (W's vertices are), so there is one
        // check per face, in order.
        let mut all = all.into_iter();
        Ok(regions
            .iter()
            .map(|r| all.by_ref().take(r.faces.len()).collect())
            .collect())
    }

    /// Why a collapse just made must be undone: the guard (when on) or an
    /// undershoot of `floor` faces (`target_faces`' 2 % window); `None`:
    /// keep it.
    fn refusal(&self, guard: bool, checks: &[CentreCheck], floor: usize) -> Option<u8> {
        match guard.then(|| self.guard(checks)).flatten() {
            Some(true) => Some(Blocked::GUARD_NORMAL),
            Some(false) => Some(Blocked::GUARD_DISTANCE),
            None if self.k.num_live_faces() < floor => Some(Blocked::UNDERSHOOT),
            None => None,
        }
    }

    /// Keeps a compact copy of the mesh when its face count has fallen
    /// below the next checkpoint's ([`SimplifyOptions::checkpoints`]).
    fn checkpoint(&mut self) -> Result<()> {
        if self.region.is_some() {
            self.region_checkpoint();
            return Ok(());
        }
        let n = self.k.num_live_faces();
        if self.opts.checkpoints == 0 || n > self.next_checkpoint {
            return Ok(());
        }
        // Flat polygons: the ring drops the oldest (largest) checkpoints,
        // most of those taken, so the half-edges (and the polygon lists)
        // are built only for the ones kept, at the end.
        let c = Checkpoint::of(&self.k, &mut self.checkpoint_map);
        if self.checkpoints.len() == self.opts.checkpoints {
            self.checkpoints.pop_front();
        }
        self.checkpoints.push_back(c);
        self.next_checkpoint = (n as f64 / CHECKPOINT_RATIO).floor() as usize;
        Ok(())
    }

    /// Drops stale entries (a face updated since, or deleted) once they
    /// outnumber the live ones three to one: each refit re-pushes its
    /// region, and a heap grown with dead entries made `pop` a tenth of
    /// the run. Entries are unique (face, diagonal, version), so the live
    /// ones pop in the same order after.
    pub(crate) fn compact_heap(&mut self) {
        let live = 2 * self.k.num_live_faces();
        if self.heap.len() <= 4 * live + 1024 {
            return;
        }
        let (k, version) = (&self.k, &self.version);
        self.heap.retain(|Reverse((_, fi, _, ver))| {
            !k.is_face_deleted(FaceId(*fi)) && version[*fi as usize] == *ver
        });
    }

    fn block(&mut self, fi: u32, why: u8) {
        *self.blocked.entry(fi).or_default() |= why;
    }

    /// Final counts and the adaptivity figures, then the compact mesh.
    pub(crate) fn finish(self, mut stats: SimplifyStats, t: Instant) -> Result<Simplified> {
        for f in self.k.live_faces() {
            let bits = self.blocked.get(&f.0).copied().unwrap_or(0);
            for (bit, name) in Blocked::NAMES {
                if bits & bit != 0 {
                    *stats.final_blockers.entry(name.to_string()).or_default() += 1;
                }
            }
        }
        let (mut radius, mut inv_fs, mut ratio) = (Vec::new(), Vec::new(), Vec::new());
        let (mut radius_m, mut fms) = (Vec::new(), Vec::new());
        let mut fs_r = Vec::new();
        for f in self.k.live_faces() {
            let q: Vec<DVec3> = self.k.face_vertices(f).map(|v| self.lim[v.idx()]).collect();
            let ctr = q.iter().sum::<DVec3>() / q.len() as f64;
            let r = q.iter().map(|p| (*p - ctr).length()).fold(0.0, f64::max);
            let (fs, fm) = (self.fs[f.idx()], self.fm[f.idx()]);
            if fs > 0.0 {
                radius.push(r);
                inv_fs.push(1.0 / fs);
                fs_r.push((fs, r));
            }
            if fm > 0.0 {
                ratio.push(r / fm);
                radius_m.push(r);
                fms.push(fm);
            }
        }
        stats.adaptivity_spearman = crate::analysis::spearman(&radius, &inv_fs);
        stats.spearman_radius_fm = crate::analysis::spearman(&radius_m, &fms);
        stats.radius_ratio_fs_quartiles = radius_ratio_fs_quartiles(&fs_r);
        stats.sd_log_fs_patches = sd_log(fs_r.iter().map(|x| x.0));
        stats.sd_log_fs_vertices = sd_log(self.fitmap.s.iter().copied());
        ratio.sort_unstable_by(f64::total_cmp);
        stats.median_radius_over_fm = ratio.get(ratio.len() / 2).copied().unwrap_or(0.0);
        let Simplifier {
            mut k,
            valence_targets,
            checkpoints,
            ..
        } = self;
        stats.irregular_vertices = k
            .live_vertices()
            .filter(|&v| valence_targets.is_irregular(&k, v))
            .count();
        k.compact()?;
        stats.faces = k.num_faces();
        stats.vertices = k.num_vertices();
        stats.seconds_simplify = t.elapsed().as_secs_f64();
        // Fewest faces first; the last checkpoints of the loop may be no
        // larger than the end itself by the ratio (taken just before it).
        let floor = k.num_faces() as f64 * CHECKPOINT_RATIO;
        let checkpoints = checkpoints
            .into_iter()
            .rev()
            .filter(|c| (c.start.len() - 1) as f64 >= floor)
            .map(|c| c.into_polygons().build())
            .collect::<Result<_>>()?;
        Ok(Simplified {
            mesh: k,
            stats,
            checkpoints,
        })
    }

    /// A fresh stamp for the per-vertex marks: cleared only when the
    /// counter wraps, so marking a region costs its size, not the mesh's.
    fn next_stamp(&mut self) {
        self.stamp_now = self.stamp_now.wrapping_add(1);
        if self.stamp_now == 0 {
            self.stamp.iter_mut().for_each(|x| *x = 0);
            self.face_stamp.iter_mut().for_each(|x| *x = 0);
            self.stamp_now = 1;
        }
    }

    /// The faces within reach of a step on quad `f` (every face with a
    /// vertex at most [`SNAPSHOT_RINGS`] edges from a corner of `f`): the
    /// collapse changes the faces around its two ends, the doublet removals
    /// those around the side corners' third neighbours, the rotations faces
    /// within two rings of the merged vertex; nothing further.
    pub(crate) fn snapshot(&mut self, f: FaceId) -> Snapshot {
        let nv = self.k.num_vertices();
        if self.stamp.len() < nv {
            self.stamp.resize(nv, 0);
        }
        self.next_stamp();
        let now = self.stamp_now;
        let mut vertices: Vec<VertexId> = self.k.face_vertices(f).collect();
        for &v in &vertices {
            self.stamp[v.idx()] = now;
        }
        let mut start = 0;
        for _ in 0..SNAPSHOT_RINGS {
            let end = vertices.len();
            for i in start..end {
                let v = vertices[i];
                for h in self.k.outgoing(v) {
                    let u = self.k.head(h);
                    if self.stamp[u.idx()] != now {
                        self.stamp[u.idx()] = now;
                        vertices.push(u);
                    }
                }
            }
            start = end;
        }
        // Each face once, marked by the same stamp (a face has up to four
        // corners in the region: collecting them per corner and sorting the
        // duplicates away was a third of the snapshot's time).
        let nf = self.k.num_faces();
        if self.face_stamp.len() < nf {
            self.face_stamp.resize(nf, 0);
        }
        let mut faces: Vec<FaceId> = Vec::with_capacity(vertices.len() + 8);
        for &v in &vertices {
            for g in self.k.vertex_faces(v) {
                if self.face_stamp[g.idx()] != now {
                    self.face_stamp[g.idx()] = now;
                    faces.push(g);
                }
            }
        }
        faces.sort_unstable();
        vertices.sort_unstable();
        let faces = faces
            .into_iter()
            .map(|g| (g, super::ops::quad(&self.k, g)))
            .collect();
        Snapshot { vertices, faces }
    }

    /// The whole state a step can change, for [`Simplifier::restore_exact`]
    /// (a copy of the control mesh and the per-vertex and per-face arrays:
    /// linear in the mesh, small beside a step's local fit on the field
    /// layout's meshes of a few thousand faces).
    pub(crate) fn save_exact(&self) -> Exact {
        Exact {
            k: self.k.clone(),
            lim: self.lim.clone(),
            fs: self.fs.clone(),
            fm: self.fm.clone(),
            pos_log: self.pos_log.clone(),
            lim_log: self.lim_log.clone(),
        }
    }

    /// Back to `x` exactly: same ids, positions, limit points and Fitmap
    /// values per face (the inverse of everything since
    /// [`Simplifier::save_exact`]).
    pub(crate) fn restore_exact(&mut self, x: Exact) {
        let Exact {
            k,
            lim,
            fs,
            fm,
            pos_log,
            lim_log,
        } = x;
        self.k = k;
        self.lim = lim;
        self.fs = fs;
        self.fm = fm;
        // Slots the trial added keep their `version` (it only grows), and
        // `update_faces` resizes the per-face arrays by it.
        let n = self.version.len().max(self.fs.len());
        self.fs.resize(n, 0.0);
        self.fm.resize(n, 0.0);
        self.pos_log = pos_log;
        self.lim_log = lim_log;
    }

    /// Undoes the current step: the region's faces back as in `snap` (the
    /// faces that differ are replaced, deleted vertices revived, through
    /// [`ControlMesh::restore_faces`]), positions and limit points back from
    /// the step's logs, then fresh heap entries for the restored area.
    pub(crate) fn undo(&mut self, snap: Snapshot) -> Result<()> {
        let lists = self.snapshot_lists(&snap);
        self.restore(lists)
    }

    /// What [`Simplifier::undo`] replaces to go back to `snap`: the faces
    /// to remove (live ones that differ from the snapshot's), the quads to
    /// put back (the snapshot's that differ from the live ones), both in
    /// face id order, and the vertices to revive.
    fn snapshot_lists(&self, snap: &Snapshot) -> UndoLists {
        let k = &self.k;
        let mut now: Vec<(FaceId, [VertexId; 4])> = snap
            .vertices
            .iter()
            .filter(|&&v| !k.is_vertex_deleted(v))
            .flat_map(|&v| k.vertex_faces(v))
            .map(|g| (g, super::ops::quad(k, g)))
            .collect();
        now.sort_unstable();
        now.dedup();
        let remove: Vec<FaceId> = now
            .iter()
            .filter(|x| snap.faces.binary_search(x).is_err())
            .map(|x| x.0)
            .collect();
        let add: Vec<[VertexId; 4]> = snap
            .faces
            .iter()
            .filter(|x| now.binary_search(x).is_err())
            .map(|x| x.1)
            .collect();
        let revive: Vec<VertexId> = snap
            .vertices
            .iter()
            .copied()
            .filter(|&v| k.is_vertex_deleted(v))
            .collect();
        UndoLists {
            remove,
            add,
            revive,
        }
    }

    /// The lists of [`Simplifier::snapshot_lists`] from the log of the
    /// step instead of a snapshot taken before it: the faces the step
    /// touched, each compared as it was before its first change (a face id
    /// first added in the step was no face before it) with what it is
    /// now. The same lists, in the same order, whenever the snapshot holds
    /// every face the step changed (the snapshot's rings are chosen so
    /// that it does; `check_every_step` compares the two).
    fn log_lists(&self, log: &FaceLog) -> UndoLists {
        let k = &self.k;
        let mut before: BTreeMap<FaceId, Option<[VertexId; 4]>> = BTreeMap::new();
        let (mut removed, mut added) = (log.removed.iter(), log.added.iter());
        for &removal in &log.order {
            if removal {
                if let Some(&(f, q)) = removed.next() {
                    before.entry(f).or_insert(Some(q));
                }
            } else if let Some(&f) = added.next() {
                before.entry(f).or_insert(None);
            }
        }
        let mut remove = Vec::new();
        let mut add = Vec::new();
        for (f, was) in before {
            let now = (!k.is_face_deleted(f)).then(|| super::ops::quad(k, f));
            if now == was {
                continue;
            }
            if now.is_some() {
                remove.push(f);
            }
            add.extend(was);
        }
        let mut revive: Vec<VertexId> = log
            .deleted
            .iter()
            .copied()
            .filter(|&v| k.is_vertex_deleted(v))
            .collect();
        revive.sort_unstable();
        revive.dedup();
        UndoLists {
            remove,
            add,
            revive,
        }
    }

    /// The undo proper (see [`Simplifier::undo`]) from its lists.
    fn restore(&mut self, lists: UndoLists) -> Result<()> {
        let UndoLists {
            remove,
            add,
            revive,
        } = lists;
        let add: Vec<&[VertexId]> = add.iter().map(|q| q.as_slice()).collect();
        self.k.restore_faces(&remove, &add, &revive)?;
        for &(v, p) in self.pos_log.iter().rev() {
            self.k.positions_mut()[v.idx()] = p;
        }
        for &(v, l) in self.lim_log.iter().rev() {
            self.lim[v.idx()] = l;
        }
        let k = &self.k;
        let mut faces: Vec<FaceId> = self
            .pos_log
            .iter()
            .chain(&self.lim_log)
            .map(|x| x.0)
            .chain(revive.iter().copied())
            .filter(|&v| !k.is_vertex_deleted(v))
            .flat_map(|v| k.vertex_faces(v))
            .collect();
        faces.sort_unstable();
        faces.dedup();
        let _ = self.update_faces(&faces)?;
        Ok(())
    }

    /// The surface guard on the patches around a refit region: `None` if
    /// every centre stays near M with a limit normal that agrees with M's;
    /// `Some(true)` for a normal disagreement, `Some(false)` for a distance
    /// beyond the bound of [`SimplifyOptions::guard_scale`]. The radius in
    /// the bound is the limit patch's (largest distance of a corner's limit
    /// point to their mean).
    pub(crate) fn guard(&self, checks: &[CentreCheck]) -> Option<bool> {
        let floor = self.opts.guard_floor * self.fitmap.tolerance.max(0.0).powf(0.25) * self.diag;
        for c in checks {
            if self.k.is_face_deleted(c.face) {
                continue;
            }
            if c.cos < self.opts.guard_min_cos {
                return Some(true);
            }
            let q: Vec<DVec3> = self
                .k
                .face_vertices(c.face)
                .map(|v| self.lim[v.idx()])
                .collect();
            let ctr = q.iter().sum::<DVec3>() / q.len() as f64;
            let r = q.iter().map(|p| (*p - ctr).length()).fold(0.0, f64::max);
            let e = (self.fs[c.face.idx()] * r).powi(4);
            if c.residual > self.relax * (self.opts.guard_scale * e + floor) {
                return Some(false);
            }
        }
        None
    }

    /// Test hook: the invariants after every step.
    pub(crate) fn check_step(&self, what: &str) -> Result<()> {
        if !self.opts.check_every_step {
            return Ok(());
        }
        self.check_invariants(what)
    }

    /// The invariants [`Simplifier::check_step`] checks, whatever the
    /// options (the split loop's join checks them once).
    pub(crate) fn check_invariants(&self, what: &str) -> Result<()> {
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

    /// Edge rotations (§3.3.2) on the edges of the faces around `centres`
    /// (the merged vertex and the collapsed quad's surviving side corners:
    /// the 1-ring of the collapsed element): each edge turns the way that
    /// lowers the valence energy most, if any does.
    fn rotate_around(
        &mut self,
        centres: &[VertexId],
        touched: &mut Vec<VertexId>,
        mut log: Option<&mut FaceLog>,
    ) -> Result<usize> {
        let k = &self.k;
        let mut edges: Vec<_> = centres
            .iter()
            .filter(|&&v| !k.is_vertex_deleted(v))
            .flat_map(|&v| k.vertex_faces(v))
            .flat_map(|f| k.face_halfedges(f))
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
                let x = rotate_edge_logged(&mut self.k, h, dir, log.as_deref_mut())?;
                touched.extend_from_slice(&x);
                n += 1;
                self.check_step("rotation")?;
            }
        }
        Ok(n)
    }

    /// Local refit (§3.4) of W = the touched vertices plus their 1-ring:
    /// `refit_rounds` times, tangential Laplacian smoothing (each vertex to
    /// the mean of its faces' centroids, within its tangent plane; boundary
    /// vertices midway along the boundary,
    /// corners fixed) then `fit_sweeps` fixed-point sweeps `P += φ − L`
    /// towards the φ targets of the smoothed limit points. Then the faces
    /// around W get new centres, Fitmap values and heap entries.
    pub(crate) fn refit(&mut self, touched: &[VertexId]) -> Result<Vec<CentreCheck>> {
        let r = self.refit_region(touched)?;
        let k = &self.k;
        self.pos_log.extend(r.w.iter().map(|&v| (v, k.position(v))));
        for _ in 0..self.opts.refit_rounds {
            let smooth = self.smoothed(&r);
            self.set_positions(&r.w, &smooth, false);
            let mut count = PhiCount::default();
            let targets = self.fit_targets(&r, &mut count);
            self.add_count(count);
            for _ in 0..self.opts.fit_sweeps {
                let delta = self.fit_deltas(&r, &targets);
                self.set_positions(&r.w, &delta, true);
            }
        }
        for (v, l) in self.refit_limits(&r)? {
            self.lim_log.push((v, self.lim[v.idx()]));
            self.lim[v.idx()] = l;
        }
        self.update_faces(&r.faces)
    }

    /// W = the touched vertices plus their 1-ring (sorted), W's limit masks
    /// and the faces around W (sorted): what [`Simplifier::refit`] moves,
    /// reads and re-evaluates.
    fn refit_region(&self, touched: &[VertexId]) -> Result<RefitRegion> {
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
        let mut masks = Vec::with_capacity(10 * w.len());
        let mut mask_at = Vec::with_capacity(w.len() + 1);
        mask_at.push(0);
        let mut one = Vec::with_capacity(16);
        for &v in &w {
            vertex_limit_mask_into(k, v, &mut one)?;
            masks.extend_from_slice(&one);
            mask_at.push(masks.len());
        }
        // The faces around W (the refit moves vertices, it does not change
        // the connectivity): their centroids are taken once per round, not
        // once per vertex of W that shares them (up to four).
        let mut faces: Vec<FaceId> = w.iter().flat_map(|&v| k.vertex_faces(v)).collect();
        faces.sort_unstable();
        faces.dedup();
        Ok(RefitRegion {
            w,
            masks,
            mask_at,
            faces,
        })
    }

    /// Writes `x` to the positions of `w` (added to them when `add`).
    fn set_positions(&mut self, w: &[VertexId], x: &[DVec3], add: bool) {
        let pos = self.k.positions_mut();
        for (&v, &p) in w.iter().zip(x) {
            if add {
                pos[v.idx()] += p;
            } else {
                pos[v.idx()] = p;
            }
        }
    }

    /// One round's smoothed positions of W (§3.4; read-only).
    fn smoothed(&self, r: &RefitRegion) -> Vec<DVec3> {
        let k = &self.k;
        let centroids: Vec<DVec3> = r.faces.iter().map(|&f| centroid(k, f)).collect();
        r.w.iter()
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
                    c += r
                        .faces
                        .binary_search(&f)
                        .map_or_else(|_| centroid(k, f), |i| centroids[i]);
                    n += 1.0;
                }
                // Tangent-space smoothing (§3.4): the whole step to the
                // mean of the face centroids, less its component along
                // the limit normal, so smoothing evens the patches out
                // without pulling the surface off M (the fit that
                // follows corrects what is left).
                let d = c / n - p;
                let nrm = vertex_normal(k, v);
                p + d - nrm * nrm.dot(d)
            })
            .collect()
    }

    /// The φ targets of W's limit points along W's normals (the limit point
    /// itself where φ misses; read-only).
    fn fit_targets(&self, r: &RefitRegion, count: &mut PhiCount) -> Vec<DVec3> {
        self.fit_targets_split(r, count, PHI_PAR_MIN)
    }

    /// [`Simplifier::fit_targets`], each line's φ taken as it is made below
    /// `par_min` lines, as one batch from there on.
    fn fit_targets_split(
        &self,
        r: &RefitRegion,
        count: &mut PhiCount,
        par_min: usize,
    ) -> Vec<DVec3> {
        let k = &self.k;
        let line = |i: usize, v: VertexId| {
            let m = r.mask(i);
            let p = k.position(v);
            let scale = k
                .outgoing(v)
                .map(|h| (k.position(k.head(h)) - p).length())
                .fold(0.0, f64::max);
            let reach = local_reach(scale, self.max_dist);
            (limit_of(k, m), vertex_normal(k, v), reach)
        };
        let target = |h: Option<Projected>, l: DVec3| h.map_or(l, |p| p.point);
        if r.w.len() < par_min && r.w.len() < self.step_fork {
            // A step's W (a few dozen vertices): each line's φ as it is
            // made, in W's order, without the lines' and the answers' own
            // buffers (this runs ~100k times on bunny); the same lines and
            // the same φ as the batch below, so the same targets.
            let mut misses = 0;
            let out =
                r.w.iter()
                    .enumerate()
                    .map(|(i, &v)| {
                        let (l, n, reach) = line(i, v);
                        let h = phi_line(&self.bvh, l, n, reach);
                        misses += h.is_none() as usize;
                        target(h, l)
                    })
                    .collect();
            count.add(r.w.len(), misses);
            return out;
        }
        let lines: Vec<(DVec3, DVec3, f64)> =
            r.w.iter().enumerate().map(|(i, &v)| line(i, v)).collect();
        let mut hits = Vec::new();
        count.forks +=
            phi_lines_into(&self.bvh, &lines, (par_min, self.step_fork), &mut hits) as usize;
        count.add(hits.len(), hits.iter().filter(|h| h.is_none()).count());
        hits.iter()
            .zip(&lines)
            .map(|(&h, &(l, _, _))| target(h, l))
            .collect()
    }

    /// One fixed-point sweep's moves `φ − L` of W (read-only).
    fn fit_deltas(&self, r: &RefitRegion, targets: &[DVec3]) -> Vec<DVec3> {
        targets
            .iter()
            .enumerate()
            .map(|(i, t)| *t - limit_of(&self.k, r.mask(i)))
            .collect()
    }

    /// New limit points of every corner of the faces around W (their masks
    /// reach into W; read-only).
    fn refit_limits(&self, r: &RefitRegion) -> Result<Vec<(VertexId, DVec3)>> {
        let k = &self.k;
        let mut corners: Vec<VertexId> = r.faces.iter().flat_map(|&f| k.face_vertices(f)).collect();
        corners.sort_unstable();
        corners.dedup();
        let mut one = Vec::with_capacity(16);
        corners
            .into_iter()
            .map(|v| {
                // W's masks still hold: the refit moved vertices, it did not
                // change the connectivity a mask depends on.
                let l = match r.w.binary_search(&v) {
                    Ok(i) => limit_of(k, r.mask(i)),
                    Err(_) => {
                        vertex_limit_mask_into(k, v, &mut one)?;
                        limit_of(k, &one)
                    }
                };
                Ok((v, l))
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fixtures;

    /// The shared face and vertex points give `face_centre_limit`'s bits on
    /// every quad of meshes with extraordinary vertices inside and on the
    /// boundary, in any order of the faces and across calls after a move.
    #[test]
    fn a_checkpoint_is_the_live_polygons() {
        // Meshes with deleted faces and vertices (collapses), so the
        // compact ids differ from the mesh's.
        let tau = 2.0 * std::f64::consts::PI;
        for mut k in [fixtures::grid(6, 5, 3), fixtures::fan(6, 0.75 * tau, 4)] {
            let mut map = vec![7; 3];
            let mut collapsed = 0;
            for step in 0..4 {
                let c = Checkpoint::of(&k, &mut map);
                assert_eq!(c.into_polygons(), k.live_polygons().0, "step {step}");
                let Some((f, d)) = k
                    .live_faces()
                    .flat_map(|f| [(f, 0), (f, 1)])
                    .find(|&(f, d)| can_collapse_diagonal(&k, f, d).is_ok())
                else {
                    break;
                };
                super::super::ops::collapse_diagonal(&mut k, f, d, None).unwrap();
                assert!(k.num_live_faces() < k.num_faces(), "nothing deleted");
                collapsed += 1;
            }
            assert!(collapsed >= 2, "{collapsed}");
        }
    }

    /// M: the unit sphere, triangulated from `polar_sphere` refined twice,
    /// with a cap of triangles removed (a hole, so that some normal lines
    /// of K miss and take the closest-point path); K: `polar_sphere`
    /// blown up by 5 %, so φ travels a real distance to M.
    fn holed_sphere_case() -> (TriMesh, ControlMesh) {
        let fine = crate::subdiv::refine::refine_uniform(&fixtures::polar_sphere(6, 3), 2).unwrap();
        let positions: Vec<DVec3> = fine.positions().iter().map(|p| p.normalize()).collect();
        let mut triangles = Vec::new();
        for f in fine.live_faces() {
            let v: Vec<u32> = fine.face_vertices(f).map(|v| v.0).collect();
            let c = (positions[v[0] as usize] + positions[v[2] as usize]) * 0.5;
            if c.z > 0.8 {
                continue; // the hole around the pole
            }
            triangles.push([v[0], v[1], v[2]]);
            triangles.push([v[0], v[2], v[3]]);
        }
        let m = TriMesh {
            positions,
            triangles,
        };
        let mut k = fixtures::polar_sphere(10, 5);
        for p in k.positions_mut() {
            *p *= 1.05;
        }
        (m, k)
    }

    fn synthetic_fitmap(m: &TriMesh) -> Fitmap {
        let n = m.positions.len();
        Fitmap {
            radii: vec![0.5],
            s: m.positions.iter().map(|p| 1.0 + p.x * p.x).collect(),
            m: m.positions.iter().map(|p| 0.4 + 0.1 * p.y).collect(),
            m_step: vec![0; n],
            tolerance: 0.05,
            stats: Default::default(),
        }
    }

    fn check_bits(c: &[CentreCheck]) -> Vec<(u32, u64, u64)> {
        c.iter()
            .map(|c| (c.face.0, c.residual.to_bits(), c.cos.to_bits()))
            .collect()
    }

    /// `update_faces_split` keeps its buffers between calls: whatever the
    /// previous calls left in them (longer or shorter face lists, split over
    /// the pool or not, dead faces filtered out), a call gives the centre
    /// checks, F_S, F_M and heap entries of a fresh simplifier's first
    /// call, bit for bit; and `fit_targets` gives the same targets and
    /// counts whether its lines are taken one by one or as a batch.
    #[test]
    fn reused_buffers_give_a_fresh_simplifiers_answers() {
        let (m, k) = holed_sphere_case();
        let fitmap = synthetic_fitmap(&m);
        let caster =
            crate::raycast::make_raycaster(crate::raycast::RayBackend::Embree, &m).unwrap();
        let opts = SimplifyOptions::default();
        let fresh = || {
            Simplifier::new(&m, &fitmap, caster.as_ref(), &opts, k.clone(), &mut || {
                Ok(())
            })
            .unwrap()
        };
        let mut reused = fresh();
        let all: Vec<FaceId> = reused.k.live_faces().collect();
        let n = all.len();
        assert!(n >= 40, "{n} faces");
        // Long, short, long again, reversed; split over the pool (par_min
        // 1, 8) or not (usize::MAX).
        let lists: Vec<(Vec<FaceId>, usize)> = vec![
            (all.clone(), 1),
            (all[..5].to_vec(), usize::MAX),
            (all.iter().rev().copied().collect(), usize::MAX),
            (all[n / 2..].to_vec(), 8),
            (all[3..9].to_vec(), usize::MAX),
        ];
        let mut misses = 0;
        for (i, (faces, par_min)) in lists.iter().enumerate() {
            let got = reused.update_faces_split(faces, *par_min).unwrap();
            let mut one = fresh();
            let want = one.update_faces_split(faces, usize::MAX).unwrap();
            assert_eq!(check_bits(&got), check_bits(&want), "list {i}");
            assert_eq!(got.len(), faces.len(), "list {i}");
            for f in faces {
                let fi = f.idx();
                assert_eq!(reused.fs[fi].to_bits(), one.fs[fi].to_bits(), "list {i}");
                assert_eq!(reused.fm[fi].to_bits(), one.fm[fi].to_bits(), "list {i}");
            }
            misses += want.iter().filter(|c| c.cos == 1.0).count();
        }
        // The hole made some lines miss (closest-point path exercised).
        assert!(misses > 0, "no centre line missed M");
        // fit_targets: one by one (par_min above |W|) and batched (0).
        let s = fresh();
        let vs: Vec<VertexId> = s.k.live_vertices().collect();
        let mut regions = 0;
        for chunk in vs.chunks(4) {
            let r = s.refit_region(chunk).unwrap();
            let (mut c1, mut c2) = (PhiCount::default(), PhiCount::default());
            let a = s.fit_targets_split(&r, &mut c1, usize::MAX);
            let b = s.fit_targets_split(&r, &mut c2, 0);
            let bits = |x: &[DVec3]| -> Vec<[u64; 3]> {
                x.iter()
                    .map(|p| [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()])
                    .collect()
            };
            assert_eq!(bits(&a), bits(&b));
            assert_eq!((c1.lines, c1.misses), (c2.lines, c2.misses));
            assert_eq!(a.len(), r.w.len());
            regions += 1;
        }
        assert!(regions > 5);
    }

    #[test]
    fn point_memo_is_face_centre_limit_bit_for_bit() {
        let bits = |l: &LimitPoint| {
            [l.position, l.du, l.dv].map(|p| [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()])
        };
        let tau = 2.0 * std::f64::consts::PI;
        let meshes = [
            fixtures::grid(5, 4, 3),
            fixtures::fan(5, tau, 1),
            fixtures::fan(3, tau, 2),
            fixtures::fan(6, 0.75 * tau, 4),
        ];
        let mut memo = PointMemo::default();
        for mut k in meshes {
            assert!(k.is_all_quads());
            let mut faces: Vec<FaceId> = k.live_faces().collect();
            for round in 0..3 {
                memo.begin(&k);
                let mut compared = 0;
                for &f in &faces {
                    assert_eq!(
                        bits(&memo.centre_limit(&k, f)),
                        bits(&face_centre_limit(&k, f))
                    );
                    compared += 1;
                }
                assert_eq!(compared, k.num_live_faces());
                // Move a vertex and revisit in another order: a new call
                // must not keep the old points.
                let v = VertexId(round as u32);
                k.positions_mut()[v.idx()] += DVec3::new(0.01, -0.02, 0.03);
                faces.reverse();
            }
        }
    }
}
