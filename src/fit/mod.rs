//! Global fit of a control mesh to M (Fitmaps §3.5).
//!
//! Each patch (ptex face: a quad, or one of the n quads of an n-gon) is
//! sampled on a `k × k` grid of cell centres, `k = ⌊√(n·|P|/|Σ P|)⌋` with n
//! the vertex count of M and |P| the patch area measured on the control
//! polygon, so that the total number of samples roughly matches n as in the
//! paper (which uses |M| in the denominator; Σ|P| makes the total exact
//! however well the control polygon's area matches M's). `k` is at least
//! [`FitOptions::min_samples_per_side`] (3 by default: 9 samples in a patch
//! whose surface depends on 16 control points in the regular case, so no
//! patch is left to the fairness term alone).
//!
//! The rows of the system are the limit stencils of the samples (OpenSubdiv
//! at isolation level [`FitOptions::isolation_level`]), plus one *vertex
//! equation* per control vertex (its limit point → its projection). The
//! targets are φ(s(p)): the intersection of M with the limit normal line at
//! the current limit point; unprojectable samples are dropped from the
//! system and counted. The system is solved for the *update* δ of the
//! control points,
//!
//! `min |A δ − (φ(s) − s)|² + λ |L δ|² + λ ε² |δ|²`,
//!
//! `L` the umbrella Laplacian of the control mesh: the fairness term keeps
//! neighbouring control points moving together, so a sparsely sampled
//! patch follows its neighbours instead of folding, while the fitted shape
//! itself is not pulled towards a flat one (the penalty is on the update,
//! not the positions). λ = `fairness · rows / vertices` makes `fairness`
//! the weight of one vertex's fairness against one vertex's share of the
//! data; ε keeps the system definite on vertices no sample reaches.
//!
//! Samples projected further than [`FitOptions::outlier_factor`] times the
//! first round's median distance are left out too (counted per round in
//! [`FitIteration::outliers`]): near holes and thin parts the normal line
//! can meet another sheet of M, and a few such rows pull spikes.
//!
//! Boundary fit: where M is open (holes, borders), φ is undefined beyond
//! its rim, and a sample there would be dropped, leaving the border patches
//! of the limit surface to the fairness term: they drift past the rim,
//! and the displacement samples there miss M. So the
//! border curves of the limit surface are sampled too (k points per
//! boundary edge of the control mesh, k its patch's), and these samples,
//! the limit points of the boundary vertices, and any lost sample whose
//! closest point of M lies on a boundary edge of M take the closest point
//! of M's rim as their target, as a point-distance row whatever the
//! objective (the tangent plane at a rim extends past M's end). On a closed
//! M none of this applies and the system is unchanged.
//!
//! Parameter correction: the limit points move, so the samples are
//! re-projected and the system re-solved while the error keeps falling (by
//! more than [`FitOptions::min_improvement`], relative), at most
//! [`FitOptions::max_iterations`] times; the best iterate is kept, so the
//! fit never returns a control mesh worse than its input. The error compared
//! is [`FitIteration::score_permille`]: the RMS over *all* samples with the
//! lost ones (unprojectable, outliers, feet on another sheet — see
//! [`FitOptions::min_normal_cos`]) counted at the outlier bound, so that an
//! update cannot look better by pushing samples out of reach.
//!
//! Objectives ([`Objective`]):
//! - `Point`: point distance `|s − φ(s)|²`, x, y and z separate (three
//!   right-hand sides, one factorisation).
//! - `Sdm`: the squared-distance minimisation of Pottmann and Leopoldseder
//!   as used by Lavoué and Dupont (§7.1, eq. 4): in the frame
//!   `(e1, e2, n)` of principal directions and normal of M at the foot point,
//!   `F = w1 x1² + w2 x2² + x3²` with `w_i = d / (d + ρ_i) = dκ_i / (1 + dκ_i)`,
//!   d the signed distance of the sample to the foot point along n. The
//!   normal is the interpolated vertex normal at the foot point and the
//!   curvatures those of the foot triangle ([`curvature`]). Where `1 + dκ_i
//!   ≤ 0` (the sample is beyond the centre of curvature, where eq. 4 is not
//!   an approximation of anything) and where `w_i` falls below
//!   [`FitOptions::sdm_tangent_floor`], `w_i` is that floor: with `d → 0`
//!   eq. 4 becomes pure point-to-plane, which leaves tangential sliding
//!   undetermined; the floor keeps a trace of the point distance
//!   (Pottmann–Leopoldseder's own remedy is the same blend of TDM and PDM).
//!   The coordinates are coupled, so the system has 3·nv unknowns and one
//!   right-hand side, and three rows per sample: each round costs about
//!   ten times a `Point` round, and it fits better (measured:
//!   docs/status.md, "Measurements behind the code").
//!   [`FitOptions::final_sdm_rounds`] runs only the last rounds with it.
//!
//! Both objectives hand Eigen each patch's rows compressed to a square
//! triangular block with the same normal equations ([`compress`]): about
//! five times fewer rows, which makes an SDM round cheaper. Each round's
//! solve runs beside the score's back-distance queries (see the loop).

mod compress;
pub mod curvature;
mod rim;

use std::sync::Arc;
use std::time::Instant;

use serde::Serialize;

use crate::analysis::normals::vertex_normals;
use crate::error::{Error, Result};
use crate::mesh::{ControlMesh, FaceId, TriMesh, VertexId};
use crate::project::{default_max_dist, project_along_normals, Projected};
use crate::raycast::RayCaster;
use crate::solve::{least_squares, LsqOptions, Triplets};
use crate::subdiv::{make_evaluator, Backend, EvalOptions, LimitStencils, SurfaceLocation};
use crate::DVec3;

pub use crate::watch::{report_progress, Progress};

/// The distance a fit minimises: the one fit-objective type of the crate,
/// for the global fit, the mechanical geometry step
/// ([`crate::mechanical::optimize`]) and every host (the CLI's `--fit` by
/// clap's derive, [`crate::embed`], C++, Python).
#[derive(
    Copy, Clone, Debug, PartialEq, Eq, Default, Serialize, serde::Deserialize, clap::ValueEnum,
)]
#[serde(rename_all = "lowercase")]
pub enum Objective {
    /// Point distance to the normal projection φ(s) (Fitmaps §3.5).
    #[default]
    Point,
    /// Squared-distance minimisation (Pottmann–Leopoldseder, Lavoué §7.1).
    Sdm,
}

/// The CLI's words (`point`, `sdm`), for hosts that take the objective as
/// a string.
impl std::str::FromStr for Objective {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Objective, String> {
        <Objective as clap::ValueEnum>::from_str(s, false)
    }
}

impl Objective {
    /// Serialises as the variant's name (`"Point"`, `"Sdm"`): the form
    /// `report.json`'s mechanical options have always had.
    pub fn serialize_variant_name<S: serde::Serializer>(
        o: &Objective,
        s: S,
    ) -> std::result::Result<S::Ok, S::Error> {
        s.serialize_str(match o {
            Objective::Point => "Point",
            Objective::Sdm => "Sdm",
        })
    }
}

/// Options of [`fit`]; defaults documented on each field.
#[derive(Clone, Debug, PartialEq, Serialize, serde::Deserialize)]
#[non_exhaustive]
pub struct FitOptions {
    pub objective: Objective,
    /// OpenSubdiv isolation level of the stencils: 6. Its end caps are
    /// ~2e-4 of the size off the limit near extraordinary vertices
    /// (STACK-NOTES), far below the ‰-level errors being fitted, at a
    /// fraction of level 10's cost.
    pub isolation_level: u8,
    /// Smallest `k` of the per-patch `k × k` sample grid: 3.
    pub min_samples_per_side: usize,
    /// Most solves (parameter-correction rounds): 8.
    pub max_iterations: usize,
    /// Relative decrease of the RMS distance below which the parameter
    /// correction stops: 1e-3.
    pub min_improvement: f64,
    /// Weight of the Laplacian fairness term relative to the data term: 0.01.
    pub fairness: f64,
    /// φ's search distance; `None`: [`default_max_dist`] (a quarter of M's
    /// bounding-box diagonal).
    pub max_dist: Option<f64>,
    /// Smallest tangential weight of the SDM approximant: 0.05.
    pub sdm_tangent_floor: f64,
    /// With the `Point` objective, how many of the last solves (of
    /// [`FitOptions::max_iterations`]) use the SDM instead: 0.
    ///
    /// The point distance to φ's targets holds every sample at its
    /// parameter location, so the surface can only slide tangentially as
    /// fast as re-projection moves the targets, and the error keeps
    /// falling by a few percent a round after eight rounds. The SDM's
    /// tangential weights free that sliding (measured: docs/status.md,
    /// "Measurements behind the code"). Off by default:
    /// it costs the conversion's time budget and worsens D and the
    /// projectability on some meshes.
    pub final_sdm_rounds: usize,
    /// Outlier rejection: a sample whose projection is further than this
    /// many times the median projection distance of the first round is left
    /// out of the system (and counted): 10. φ takes the nearest hit on the
    /// normal line within [`FitOptions::max_dist`], which near holes and
    /// thin parts can be another sheet of M far away; a handful of such
    /// rows is enough to pull control points into spikes.
    pub outlier_factor: f64,
    /// A sample whose foot point's normal on M (interpolated vertex
    /// normals) makes a cosine below this with the limit normal is left out
    /// like an outlier: 0.3 (beyond ~73°). Such a foot is on another sheet
    /// (the inside of a fold, the far side of a thin part), and pulling the
    /// surface there folds it.
    pub min_normal_cos: f64,
}

impl Default for FitOptions {
    fn default() -> Self {
        FitOptions {
            objective: Objective::Point,
            isolation_level: 6,
            min_samples_per_side: 3,
            max_iterations: 8,
            min_improvement: 1e-3,
            fairness: 0.01,
            max_dist: None,
            sdm_tangent_floor: 0.05,
            final_sdm_rounds: 0,
            outlier_factor: 10.0,
            min_normal_cos: 0.3,
        }
    }
}

impl FitOptions {
    pub fn with_objective(mut self, o: Objective) -> Self {
        self.objective = o;
        self
    }
    pub fn with_max_iterations(mut self, n: usize) -> Self {
        self.max_iterations = n;
        self
    }
    pub fn with_fairness(mut self, f: f64) -> Self {
        self.fairness = f;
        self
    }
    pub fn with_isolation_level(mut self, l: u8) -> Self {
        self.isolation_level = l;
        self
    }
    pub fn with_min_samples_per_side(mut self, k: usize) -> Self {
        self.min_samples_per_side = k;
        self
    }
    pub fn with_final_sdm_rounds(mut self, n: usize) -> Self {
        self.final_sdm_rounds = n;
        self
    }
    pub fn with_max_dist(mut self, d: Option<f64>) -> Self {
        self.max_dist = d;
        self
    }

    fn check(&self) -> Result<()> {
        let bad = |m: String| Err(Error::option("fit", format!("fit: {m}")));
        if !(1..=10).contains(&self.isolation_level) {
            return bad(format!(
                "isolation level {} not in 1..=10",
                self.isolation_level
            ));
        }
        if self.min_samples_per_side == 0 || self.min_samples_per_side > 64 {
            return bad(format!(
                "min_samples_per_side {} not in 1..=64",
                self.min_samples_per_side
            ));
        }
        if !(self.fairness.is_finite() && self.fairness > 0.0) {
            return bad(format!("fairness {} must be finite and > 0", self.fairness));
        }
        if !(self.min_improvement.is_finite() && self.min_improvement >= 0.0) {
            return bad(format!(
                "min_improvement {} must be >= 0",
                self.min_improvement
            ));
        }
        if !(self.sdm_tangent_floor > 0.0 && self.sdm_tangent_floor <= 1.0) {
            return bad(format!(
                "sdm_tangent_floor {} not in (0, 1]",
                self.sdm_tangent_floor
            ));
        }
        if !(self.outlier_factor.is_finite() && self.outlier_factor > 1.0) {
            return bad(format!(
                "outlier_factor {} must be > 1",
                self.outlier_factor
            ));
        }
        if let Some(d) = self.max_dist {
            if !(d.is_finite() && d > 0.0) {
                return bad(format!("max_dist {d} must be finite and > 0"));
            }
        }
        Ok(())
    }
}

/// One parameter-correction round, measured before its solve.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FitIteration {
    /// RMS of `|s − φ(s)|` over the samples used, ‰ of M's diagonal.
    pub rms_permille: f64,
    /// RMS over all samples with the lost ones (unprojectable, outliers)
    /// at the outlier bound, ‰: what the best iterate minimises.
    pub score_permille: f64,
    pub unprojectable: usize,
    /// Projected samples left out as outliers.
    pub outliers: usize,
}

/// What [`fit`] did.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FitReport {
    pub objective: Objective,
    pub patches: usize,
    /// Smallest and largest k of the per-patch k × k grids.
    pub samples_per_side: (usize, usize),
    pub data_samples: usize,
    pub vertex_equations: usize,
    /// Rounds in order; the last one measures the final control mesh when
    /// the loop ran out of iterations.
    pub iterations: Vec<FitIteration>,
    /// Index into `iterations` of the kept iterate.
    pub best_iteration: usize,
    pub initial_rms_permille: f64,
    pub final_rms_permille: f64,
    pub seconds: f64,
}

/// The fitted control mesh and the report.
#[derive(Clone, Debug)]
pub struct Fitted {
    pub control: ControlMesh,
    pub report: FitReport,
}

/// Global fit of `control` to `mesh` (`caster` built over `mesh`); see the
/// module docs.
pub fn fit(
    mesh: &TriMesh,
    control: ControlMesh,
    caster: &dyn RayCaster,
    opts: &FitOptions,
) -> Result<Fitted> {
    fit_with_progress(mesh, control, caster, opts, &mut |_, _| true)
}

/// [`fit`] with a progress callback (stage `"fit"`).
///
/// On an open mesh the control mesh's boundary loops are first fitted to
/// M's rim ([`rim`]). That start wins where the loops have enough control
/// points to follow their rims but can shear large border patches that the
/// rounds do not repair (see `src/fit/rim.rs` in docs/status.md,
/// "Measurements behind the code"). So both starts are fitted and the one
/// with the lower score of the fit's own kept iterate wins (ties keep the
/// rim start): one more fit, on open meshes whose loops moved only.
pub fn fit_with_progress(
    mesh: &TriMesh,
    control: ControlMesh,
    caster: &dyn RayCaster,
    opts: &FitOptions,
    progress: &mut Progress<'_>,
) -> Result<Fitted> {
    // Watched (`crate::watch`): the ray queries of every round are chunked,
    // so a cancellation ends the fit within one chunk, not one round.
    fit_deciding(mesh, control, caster, opts, progress, (None, None)).map(|(f, _)| f)
}

/// A fit asked only whether its RMS ends within `bound_permille` (‰ of the
/// diagonal; the `--max-error` search, `convert::search`): it may stop as
/// soon as the answer is plain, and then says so (see [`fit_deciding`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Decide {
    pub bound_permille: f64,
}

/// The least ratio of a fit's final RMS to its RMS after round 1 or later
/// that [`fit_deciding`] assumes: a fit whose RMS times this is still
/// above the bound ends above it. Measured 0.74–0.78 after round 1,
/// 0.79–0.84 after round 2 and 0.85–0.87 after round 3 (bunny at τ = 5 %,
/// default and `--max-error 2e-3`, gargoyle at 2e-3; the ratio grows with
/// the round), so 0.65 leaves a margin.
pub const DECIDE_MISS_FLOOR: f64 = 0.65;

/// [`fit_with_progress`], with `decide`: each start pauses once its kept
/// iterate's RMS is within the bound (a pass: the rounds after only lower
/// the score they keep) or, from round 1 on, once that RMS times
/// [`DECIDE_MISS_FLOOR`] is still above it (a miss). The state is `None`
/// when every start ran its whole course, i.e. the result is the one
/// [`fit_with_progress`] gives; else passing it back as `resume` (same
/// mesh, control mesh and options) runs on from where each start paused,
/// to the same result as one uninterrupted fit.
pub fn fit_deciding(
    mesh: &TriMesh,
    control: ControlMesh,
    caster: &dyn RayCaster,
    opts: &FitOptions,
    progress: &mut Progress<'_>,
    (decide, resume): (Option<Decide>, Option<FitState>),
) -> Result<(Fitted, Option<FitState>)> {
    let facts = MeshFacts::of(mesh);
    fit_deciding_with(
        mesh,
        &facts,
        control,
        caster,
        opts,
        progress,
        (decide, resume),
    )
}

/// [`fit_deciding`] with `facts` = [`MeshFacts::of`] `mesh` computed once
/// by the caller: what a series of fits to one M (the `--max-error`
/// search's candidates) would otherwise recompute for each.
pub fn fit_deciding_with(
    mesh: &TriMesh,
    facts: &Arc<MeshFacts>,
    control: ControlMesh,
    caster: &dyn RayCaster,
    opts: &FitOptions,
    progress: &mut Progress<'_>,
    (decide, resume): (Option<Decide>, Option<FitState>),
) -> Result<(Fitted, Option<FitState>)> {
    crate::watch::watched(progress, |w| {
        let caster = crate::raycast::Watched::new(caster, w);
        fit_both_starts(
            mesh,
            facts,
            control,
            &caster,
            opts,
            &mut |s: &str, f: f64| w.report(s, f).is_ok(),
            (decide, resume, start_pick()),
        )
    })
}

/// [`fit_with_progress`] on the calling thread; `pick`: [`start_pick`].
fn fit_both_starts(
    mesh: &TriMesh,
    facts: &Arc<MeshFacts>,
    control: ControlMesh,
    caster: &dyn RayCaster,
    opts: &FitOptions,
    progress: &mut Progress<'_>,
    (decide, resume, pick): (Option<Decide>, Option<FitState>, Option<(usize, f64)>),
) -> Result<(Fitted, Option<FitState>)> {
    let t0 = Instant::now();
    opts.check()?;
    // A resumed fit goes on with the rim fit and the system it paused with
    // (the same ones a rebuild from the same inputs would give).
    // A released system ([`FitState::release_system`]) is rebuilt.
    let build = || FitSystem::build(mesh, facts, &control, opts).map(Arc::new);
    let (rim_moves, sys, mut states) = match resume {
        Some(s) => {
            let sys = s.sys.map_or_else(build, Ok)?;
            (s.rim_moves, sys, s.starts.into_iter())
        }
        None => {
            checked_diagonal(mesh)?;
            // The rim fit and the system read the same control mesh and
            // neither reads the other (the moves are applied by each start,
            // [`fit_from`]): side by side, each a pure function of its
            // inputs, the same result at any thread count. The rim fit is
            // serial (a chain solve per loop), as is most of the system's
            // OpenSubdiv setup.
            let (rim, sys) = rayon::join(|| rim::fit_rims(mesh, &facts.rim, &control), build);
            (rim.moved, sys?, Vec::new().into_iter())
        }
    };
    // One start from its state (a finished one is its result), paused
    // after round `stop` at the latest when asked.
    let run = |control: ControlMesh,
               moves: &[(VertexId, DVec3)],
               state: Option<StartState>,
               stop: Option<usize>,
               progress: &mut Progress<'_>| {
        let paused = match state {
            Some(StartState::Done(f)) => return Ok((*f, None)),
            Some(StartState::Paused(p)) => Some(p),
            None => None,
        };
        fit_from(
            mesh,
            &sys,
            control,
            caster,
            opts,
            progress,
            moves,
            t0,
            (decide, paused, stop),
        )
    };
    // What a start leaves for a resumption.
    let state = |(f, p): (Fitted, Option<Paused>)| match p {
        Some(p) => (f.clone(), StartState::Paused(p), false),
        None => (f.clone(), StartState::Done(Box::new(f)), true),
    };
    let paused_state = |starts: Vec<StartState>| FitState {
        starts,
        rim_moves: rim_moves.clone(),
        sys: Some(sys.clone()),
    };
    if rim_moves.is_empty() {
        let (f, s, done) = state(run(control, &[], states.next(), None, progress)?);
        return Ok((f, (!done).then(|| paused_state(vec![s]))));
    }
    // The two starts side by side: each round's Eigen solve is serial
    // (~40 % of a round on a million triangles), so one start's solve
    // overlaps the other's ray queries. Each is a pure function of its
    // inputs: the same result whatever the thread count. The rim start
    // reports the progress (the other's cancellation is still checked by
    // the watched caster's chunks). They share one system: the samples'
    // locations, stencils and operators depend on the control mesh's
    // topology and its positions before the rim fit, not on the moves.
    let for_rim = control.clone();
    let (s_with, s_without) = (states.next(), states.next());
    // `SUBDFIT_FIT_START_PICK` (off by default): both starts stop after
    // round k, and one whose kept score is plainly the lower goes on alone.
    let pick = pick.filter(|&(k, _)| {
        [&s_with, &s_without].iter().all(|s| match s {
            None => true,
            Some(StartState::Paused(p)) => p.next_round <= k,
            Some(StartState::Done(_)) => false,
        })
    });
    let stop = pick.map(|(k, _)| k);
    let for_plain = control.clone();
    let (with, without) = rayon::join(
        || run(for_rim, &rim_moves, s_with, stop, progress),
        || run(for_plain, &[], s_without, stop, &mut |_: &str, _: f64| true),
    );
    let (with, without) = (with?, without?);
    let (with, without) = match pick {
        None => (with, without),
        Some((k, margin)) => pick_start(
            (with, without),
            (k, margin),
            &mut |r: StartRun, moves: &[(VertexId, DVec3)], progress: &mut Progress<'_>| {
                let st = r.1.map(StartState::Paused);
                run(control.clone(), moves, st, None, progress)
            },
            &rim_moves,
            progress,
        )?,
    };
    let score = |f: &Fitted| f.report.iterations[f.report.best_iteration].score_permille;
    let ((with, st_with, done_with), (without, st_without, done_without)) =
        (state(with), state(without));
    if crate::switches::set("SUBDFIT_FITTRACE") {
        let it = |f: &Fitted| {
            let v: Vec<String> = f
                .report
                .iterations
                .iter()
                .map(|i| format!("{:.4}", i.score_permille))
                .collect();
            v.join(" ")
        };
        eprintln!("fit rim:   {}\nfit plain: {}", it(&with), it(&without));
    }
    let mut best = if score(&without) < score(&with) {
        without
    } else {
        with
    };
    best.report.seconds = t0.elapsed().as_secs_f64();
    let paused = !(done_with && done_without);
    Ok((
        best,
        paused.then(|| paused_state(vec![st_with, st_without])),
    ))
}

/// One start's result and where it paused ([`fit_from`]).
type StartRun = (Fitted, Option<Paused>);

/// Resumes a paused start (with its rim moves) to its end.
type ResumeStart<'a> =
    dyn FnMut(StartRun, &[(VertexId, DVec3)], &mut Progress<'_>) -> Result<StartRun> + 'a;

/// `SUBDFIT_FIT_START_PICK=k[:m]` (off by default; an experiment, not a
/// proof): on an open mesh both starts of a fit stop after round k, and
/// the one whose kept score is below the other's by more than the factor
/// `1 + m` (default 0) goes on alone (ties keep the rim start, as the
/// whole fit does).
fn start_pick() -> Option<(usize, f64)> {
    let v = crate::switches::text("SUBDFIT_FIT_START_PICK")?;
    let mut it = v.splitn(2, ':');
    let k = it.next()?.trim().parse().ok()?;
    let m = it.next().map_or(Some(0.0), |m| m.trim().parse().ok())?;
    Some((k, m))
}

/// [`start_pick`]'s decision on the two starts (rim start first), both
/// run until round k at the latest: the kept start is resumed to its
/// end (the other keeps its score so far, which the kept start's only
/// undercuts further, so the final comparison keeps the kept one); when
/// neither is plainly lower, each start stopped at round k (by the pick
/// or by `decide`) is resumed, and one paused earlier by `decide` stays
/// paused, as without the pick.
fn pick_start(
    (with, without): (StartRun, StartRun),
    (k, margin): (usize, f64),
    resume: &mut ResumeStart<'_>,
    rim_moves: &[(VertexId, DVec3)],
    progress: &mut Progress<'_>,
) -> Result<(StartRun, StartRun)> {
    let score = |f: &Fitted| f.report.iterations[f.report.best_iteration].score_permille;
    let at_k = |r: &StartRun| r.1.as_ref().is_some_and(|p| p.next_round == k + 1);
    let both = at_k(&with) && at_k(&without);
    let (sw, so) = (score(&with.0), score(&without.0));
    if crate::switches::set("SUBDFIT_FITTRACE") {
        eprintln!("fit starts after round {k}: rim {sw:.5}, plain {so:.5} (both there: {both})");
    }
    let done = |(f, _): StartRun| (f, None);
    if both && so * (1.0 + margin) < sw {
        return Ok((done(with), resume(without, &[], progress)?));
    }
    if both && sw * (1.0 + margin) <= so {
        return Ok((resume(with, rim_moves, progress)?, done(without)));
    }
    // Serially here (a rare case: the starts' scores within the margin).
    let with = match at_k(&with) {
        true => resume(with, rim_moves, progress)?,
        false => with,
    };
    let without = match at_k(&without) {
        true => resume(without, &[], &mut |_: &str, _: f64| true)?,
        false => without,
    };
    Ok((with, without))
}

/// What every fit to M asks of it whatever the control mesh: computed once
/// per fit by [`fit_deciding`], or once for a series of fits to the same M
/// by the caller of [`fit_deciding_with`] (on a 4.4M-triangle input each
/// part took about a second).
pub struct MeshFacts {
    /// [`TriMesh::boundary_edge_masks`].
    rim: Vec<u8>,
    /// Area-weighted vertex normals of M.
    normals: Vec<DVec3>,
    /// The boundary edges of M (from `rim`).
    rim_segments: Vec<RimSegment>,
    /// The SDM's curvatures of M's triangles (from `normals`), made by the
    /// first fit that needs them.
    curvatures: std::sync::OnceLock<Vec<curvature::TriCurvature>>,
}

impl MeshFacts {
    /// The facts of `mesh`.
    pub fn of(mesh: &TriMesh) -> Arc<MeshFacts> {
        let (rim, normals) = rayon::join(|| mesh.boundary_edge_masks(), || vertex_normals(mesh));
        let rim_segments = rim_segments(mesh, &rim);
        Arc::new(MeshFacts {
            rim,
            normals,
            rim_segments,
            curvatures: std::sync::OnceLock::new(),
        })
    }
}

/// One global fit from `control` with the boundary vertices of
/// `rim_moves` first moved to their rim-fitted positions (Fitmaps §3.5,
/// final fitting, with the parameter correction of its last paragraph).
///
/// This is the round loop only: the sample set and the fixed operators
/// come from [`FitSystem::build`], the targets of a round from
/// [`FitSystem::targets`], its error from [`FitSystem::round_error`] and
/// its update from [`FitSystem::solve`], so that each step can be read
/// against the module docs on its own.
#[allow(clippy::too_many_arguments)]
fn fit_from(
    mesh: &TriMesh,
    sys: &FitSystem,
    mut control: ControlMesh,
    caster: &dyn RayCaster,
    opts: &FitOptions,
    progress: &mut Progress<'_>,
    rim_moves: &[(VertexId, DVec3)],
    t0: Instant,
    (decide, resume, stop): (Option<Decide>, Option<Paused>, Option<usize>),
) -> Result<(Fitted, Option<Paused>)> {
    let diag = checked_diagonal(mesh)?;
    let max_dist = opts.max_dist.unwrap_or_else(|| default_max_dist(mesh));
    report_progress(progress, "fit", 0.0)?;
    if !sys.facts.rim_segments.is_empty() {
        // The rim-fitted loops ([`rim`]), where M has a rim.
        let pos = control.positions_mut();
        for &(v, p) in rim_moves {
            pos[v.idx()] = p;
        }
    }

    let nv = control.num_vertices();
    let mut positions = control.positions().to_vec();
    let mut iterations: Vec<FitIteration> = Vec::new();
    // (positions, rms, round, score) of the best iterate so far.
    let mut best = (positions.clone(), f64::INFINITY, 0usize, f64::INFINITY);
    let permille = 1000.0 / diag;
    let mut outlier_bound = f64::INFINITY;
    let mut first_back: Option<f64> = None;
    let mut first_round = 0;
    if let Some(p) = resume {
        // Where the paused fit stood: the rounds from here are the ones an
        // uninterrupted fit runs (`sys` is the one the paused fit ran on).
        (positions, best, outlier_bound, first_back) =
            (p.positions, p.best, p.outlier_bound, p.first_back);
        (iterations, first_round) = (p.iterations, p.next_round);
    }
    let mut paused = None;
    // The patch factors of this start's point solves: the samples' stencils
    // are the system's, so a patch whose samples all keep a target reuses
    // the last round's factor (the same rows, bit for bit). Off with
    // `SUBDFIT_FIT_FACTOR_REUSE=0` (a measurement switch).
    let reuse = crate::switches::not_zero("SUBDFIT_FIT_FACTOR_REUSE") != Some(false);
    let cache = compress::FactorCache::default();
    let factors = reuse.then_some(&cache);
    for round in first_round..=opts.max_iterations {
        let limit = sys.stencils.apply(&positions);
        let (mut hits, stats) = project_along_normals(caster, &limit, max_dist)?;
        if round == 0 {
            outlier_bound = first_outlier_bound(&hits, opts, diag);
        }
        let outliers = sys.drop_outliers(mesh, &limit, &mut hits, outlier_bound, opts);
        let targets = sys.targets(caster, &limit, hits)?;
        let (rms, one_way) = targets.round_error(&limit, outlier_bound, max_dist)?;
        // The other direction: φ only looks from the surface, so a surface
        // that leaves part of M uncovered (a patch flown off to another
        // sheet) can still score well one way. The RMS distance from M's
        // vertices to the tessellated sample grids catches it; that measure
        // is biased by the gaps between the grids (dominant on a dense
        // control mesh), so only its rise over the first round counts.
        //
        // The next round's update does not depend on this score, only
        // whether it is kept does: the (serial) Eigen solve runs beside the
        // (parallel) back-distance queries and is dropped when the round
        // ends the loop. Both are pure functions of this round's data, so
        // the result is the same whatever the thread count.
        let last = round == opts.max_iterations;
        let (back, delta) = rayon::join(
            || mesh_to_samples_rms(mesh, &limit[..sys.data_samples], &sys.ks),
            || {
                if last {
                    return Ok(None);
                }
                let use_sdm = opts.objective == Objective::Sdm
                    || round + opts.final_sdm_rounds >= opts.max_iterations;
                sys.solve(mesh, &limit, &targets, use_sdm, nv, opts, factors)
                    .map(Some)
            },
        );
        let back = back?;
        let back0 = *first_back.get_or_insert(back);
        let score = one_way + (back - back0).max(0.0);
        iterations.push(FitIteration {
            rms_permille: rms * permille,
            score_permille: score * permille,
            unprojectable: stats.unprojectable,
            outliers,
        });
        let improved = score < best.3 * (1.0 - opts.min_improvement);
        if score < best.3 {
            best = (positions.clone(), rms, round, score);
        }
        if !improved || last {
            break;
        }
        report_progress(
            progress,
            "fit",
            (round as f64 + 0.5) / (opts.max_iterations as f64 + 1.0),
        )?;
        let Some(delta) = delta? else { break };
        apply_update(&mut positions, &delta)?;
        report_progress(
            progress,
            "fit",
            (round as f64 + 1.0) / (opts.max_iterations as f64 + 1.0),
        )?;
        let decided = decide.is_some_and(|d| {
            let kept = best.1 * permille;
            kept <= d.bound_permille || (round >= 1 && kept * DECIDE_MISS_FLOOR > d.bound_permille)
        });
        if decided || stop == Some(round) {
            paused = Some(Paused {
                positions,
                best: best.clone(),
                outlier_bound,
                first_back,
                iterations: iterations.clone(),
                next_round: round + 1,
            });
            break;
        }
    }
    let (positions, rms, best_iteration, _) = best;
    control.set_positions(positions)?;
    report_progress(progress, "fit", 1.0)?;
    let fitted = Fitted {
        control,
        report: sys.report(opts, iterations, best_iteration, rms * permille, t0),
    };
    Ok((fitted, paused))
}

/// One start of a fit stopped once decided ([`fit_deciding`]): what its
/// round loop carries from one round to the next, so that resuming it
/// runs exactly the rounds an uninterrupted fit would have.
#[derive(Clone, Debug)]
struct Paused {
    positions: Vec<DVec3>,
    /// (positions, rms, round, score) of the best iterate so far.
    best: (Vec<DVec3>, f64, usize, f64),
    outlier_bound: f64,
    first_back: Option<f64>,
    iterations: Vec<FitIteration>,
    next_round: usize,
}

/// Where each start of a fit stands ([`fit_deciding`]): finished (its
/// result) or paused.
#[derive(Clone, Debug)]
enum StartState {
    Done(Box<Fitted>),
    Paused(Paused),
}

/// A fit stopped once decided, to be resumed with [`fit_deciding`] on
/// the same inputs: its starts in order (the rim start first, on open
/// meshes whose loops move), with the rim fit's moves and the system they
/// share, so that the resumption rebuilds neither.
#[derive(Clone)]
pub struct FitState {
    starts: Vec<StartState>,
    rim_moves: Vec<(VertexId, DVec3)>,
    /// `None` once released.
    sys: Option<Arc<FitSystem>>,
}

impl FitState {
    /// Frees the system (the samples' stencils: tens of MB on a dense
    /// control mesh) while the fit is unlikely to be resumed; a resumption
    /// rebuilds it, to the same result.
    pub fn release_system(&mut self) {
        self.sys = None;
    }
}

impl std::fmt::Debug for FitState {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FitState")
            .field("starts", &self.starts)
            .field("rim_moves", &self.rim_moves.len())
            .finish_non_exhaustive()
    }
}

/// The bounding-box diagonal of `mesh`, or the error that makes a fit to
/// it meaningless (no triangles, or a degenerate box: the permille figures
/// of the report are relative to this diagonal).
fn checked_diagonal(mesh: &TriMesh) -> Result<f64> {
    if mesh.positions.is_empty() || mesh.triangles.is_empty() {
        return Err(Error::invalid_data(
            "input mesh",
            "mesh",
            "is empty; the fit needs triangles",
        ));
    }
    let diag = mesh.bbox_diagonal();
    if !(diag.is_finite() && diag > 0.0) {
        return Err(Error::invalid_data(
            "input mesh",
            "mesh",
            format!("has a degenerate bounding box (diagonal {diag}); the fit needs a surface"),
        ));
    }
    Ok(diag)
}

/// The outlier bound of the whole fit, set from the first round's
/// projections: [`FitOptions::outlier_factor`] times their median
/// distance (see the module docs); infinite when nothing projected.
fn first_outlier_bound(hits: &[Option<Projected>], opts: &FitOptions, diag: f64) -> f64 {
    let mut d: Vec<f64> = hits.iter().flatten().map(|h| h.offset.abs()).collect();
    if d.is_empty() {
        return f64::INFINITY;
    }
    let mid = d.len() / 2;
    let median = *d.select_nth_unstable_by(mid, f64::total_cmp).1;
    // A zero median (a control mesh already on M) must not
    // reject everything else: floor at 1e-6 of the diagonal.
    opts.outlier_factor * median.max(1e-6 * diag)
}

/// Adds the solved update `delta` to the control points, refusing a
/// non-finite one (a singular solve) before it reaches the positions.
fn apply_update(positions: &mut [DVec3], delta: &[DVec3]) -> Result<()> {
    if delta.iter().any(|d| !d.is_finite()) {
        return Err(Error::backend(
            "Eigen",
            "the fit produced non-finite control points",
        ));
    }
    for (p, d) in positions.iter_mut().zip(delta) {
        *p += *d;
    }
    Ok(())
}

/// What stays fixed over the rounds of one global fit (Fitmaps §3.5): the
/// sample locations' limit stencils, the rim of M and which samples aim
/// at it, the fairness Laplacian and M's normals and curvatures. Built
/// once so that a round only re-evaluates and re-projects.
struct FitSystem {
    /// Sample side of each patch, in patch order.
    ks: Vec<usize>,
    /// Patch samples come first in the rows; then the vertex equations,
    /// then the border-curve samples (open M only).
    data_samples: usize,
    vertex_equations: usize,
    /// M's rim masks, rim segments, normals and curvatures.
    facts: Arc<MeshFacts>,
    /// Per sample: its target is the closest point of M's rim.
    rim_sample: Vec<bool>,
    /// The face of each sample, for the row compression of the solves.
    face: Vec<u32>,
    stencils: LimitStencils,
    laplacian: Vec<Vec<(u32, f64)>>,
    /// Whether the SDM's curvatures were made (`facts.curvatures`), also
    /// for the final SDM rounds of the point objective
    /// (`FitOptions::final_sdm_rounds`).
    sdm: bool,
}

/// One round's targets: `hits` after the outlier screen and the boundary
/// fit, which of them are rim targets (point rows whatever the objective),
/// and the lost samples with their closest points of M, for the score.
struct RoundTargets {
    hits: Vec<Option<Projected>>,
    on_rim: Vec<bool>,
    lost_idx: Vec<usize>,
    lost_closest: Vec<Option<crate::raycast::ClosestPoint>>,
}

impl FitSystem {
    /// The report of a fit over this system: its rounds, the kept one
    /// (`best_iteration`, final RMS `final_rms_permille`) and the time
    /// since `t0`.
    fn report(
        &self,
        opts: &FitOptions,
        iterations: Vec<FitIteration>,
        best_iteration: usize,
        final_rms_permille: f64,
        t0: Instant,
    ) -> FitReport {
        FitReport {
            objective: opts.objective,
            patches: self.ks.len(),
            samples_per_side: (
                self.ks.iter().copied().min().unwrap_or(0),
                self.ks.iter().copied().max().unwrap_or(0),
            ),
            data_samples: self.data_samples,
            vertex_equations: self.vertex_equations,
            initial_rms_permille: iterations[0].rms_permille,
            final_rms_permille,
            iterations,
            best_iteration,
            seconds: t0.elapsed().as_secs_f64(),
        }
    }

    /// Samples the patches ([`patch_samples`]) and the vertex equations,
    /// and on an open M adds the border-curve samples; then builds the
    /// stencils and operators. None of it depends on where the rim fit
    /// moves the loops (only on the topology, and on `control`'s positions
    /// for the patches' sample counts), so both starts share it.
    fn build(
        mesh: &TriMesh,
        facts: &Arc<MeshFacts>,
        control: &ControlMesh,
        opts: &FitOptions,
    ) -> Result<Self> {
        let (mut locations, ks) = patch_samples(
            control,
            mesh.positions.len().min(FIT_SAMPLE_BUDGET),
            opts.min_samples_per_side,
        );
        let data_samples = locations.len();
        locations.extend(vertex_locations(control));
        let vertex_equations = locations.len() - data_samples;
        // Boundary fit (see the module docs): samples on the border curves of
        // the limit surface and the limit points of the boundary vertices take
        // the closest point of M's rim as their target.
        let mut rim_sample = vec![false; locations.len()];
        if !facts.rim_segments.is_empty() {
            // Boundary-curve fit (see [`rim`]): each boundary loop of the
            // control mesh is first fitted to its rim as a curve (rim → curve,
            // so the border covers the whole rim instead of hugging part of
            // it); the surface fit then starts from there, its border rows
            // keeping the border on the rim. Holding the fitted loops fixed
            // instead was measured worse (bunny τ = 1 %: RMS D 0.48‰ held vs
            // 0.28‰ free; τ = 10 %: 1.54‰ both): the border patches need the
            // loop to follow the interior's parameter correction. (The
            // moves themselves are the start's: [`fit_from`].)
            for (v, flag) in control.vertices().zip(&mut rim_sample[data_samples..]) {
                *flag = control.is_boundary_vertex(v);
            }
            let border = border_locations(control, &ks);
            rim_sample.resize(rim_sample.len() + border.len(), true);
            locations.extend(border);
        }
        let evaluator = make_evaluator(
            Backend::Osd,
            control,
            &EvalOptions::default().with_isolation_level(opts.isolation_level),
        )?;
        let face: Vec<u32> = locations.iter().map(|l| l.face.0).collect();
        let stencils = evaluator.stencils(&locations)?;
        let laplacian = umbrella(control);
        let sdm = !matches!(
            (opts.objective, opts.final_sdm_rounds),
            (Objective::Point, 0)
        );
        if sdm {
            facts
                .curvatures
                .get_or_init(|| curvature::triangle_curvatures(mesh, &facts.normals));
        }
        Ok(FitSystem {
            ks,
            data_samples,
            vertex_equations,
            facts: facts.clone(),
            rim_sample,
            face,
            stencils,
            laplacian,
            sdm,
        })
    }

    /// Drops the projections of `hits` that landed on another sheet of M
    /// (further than `outlier_bound`, or M's interpolated normal at the
    /// foot facing away from the limit normal); returns how many.
    fn drop_outliers(
        &self,
        mesh: &TriMesh,
        limit: &[crate::subdiv::LimitPoint],
        hits: &mut [Option<Projected>],
        outlier_bound: f64,
        opts: &FitOptions,
    ) -> usize {
        let m_normals = &self.facts.normals;
        let mut outliers = 0;
        for (h, s) in hits.iter_mut().zip(limit) {
            let Some(p) = h else { continue };
            // Another sheet: too far, or facing away from the limit normal
            // (M's interpolated normal at the foot against the sample's).
            let t = mesh.triangles[p.triangle as usize];
            let nm = (1.0 - p.u - p.v) * m_normals[t[0] as usize]
                + p.u * m_normals[t[1] as usize]
                + p.v * m_normals[t[2] as usize];
            let facing = nm.normalize_or_zero().dot(s.normal()) >= opts.min_normal_cos;
            if p.offset.abs() > outlier_bound || !facing {
                *h = None;
                outliers += 1;
            }
        }
        outliers
    }

    /// The boundary fit of one round (module docs): rim samples take the
    /// closest point of M's rim, and a lost sample whose closest point of
    /// M lies on a rim edge takes that point.
    fn targets(
        &self,
        caster: &dyn RayCaster,
        limit: &[crate::subdiv::LimitPoint],
        mut hits: Vec<Option<Projected>>,
    ) -> Result<RoundTargets> {
        // Boundary fit: a lost sample whose closest point of M lies on a
        // boundary edge of M (a hole's rim, an open border) is beyond the
        // end of M, where φ is undefined. Dropped, nothing would hold the
        // limit surface there and it drifts past the rim (bunny τ = 1 %:
        // the 149 patches along its holes overhung them by 3.5‰ median, a
        // seventh of the displacement samples missed M). Its target is that
        // closest point, a point-distance row whatever the objective, which
        // pulls the limit surface's border onto the rim.
        let mut on_rim = vec![false; hits.len()];
        let border_idx: Vec<usize> = (0..hits.len()).filter(|&i| self.rim_sample[i]).collect();
        let border_pts: Vec<DVec3> = border_idx.iter().map(|&i| limit[i].position).collect();
        for (&i, target) in border_idx
            .iter()
            .zip(closest_on_segments(&self.facts.rim_segments, &border_pts))
        {
            hits[i] = target;
            on_rim[i] = target.is_some();
        }
        let lost_idx: Vec<usize> = (0..hits.len()).filter(|&i| hits[i].is_none()).collect();
        let lost_pts: Vec<DVec3> = lost_idx.iter().map(|&i| limit[i].position).collect();
        let lost_closest = caster.closest_points(&lost_pts, f64::INFINITY)?;
        for (&i, c) in lost_idx.iter().zip(&lost_closest) {
            if let Some(c) = c {
                if on_rim_edge(self.facts.rim[c.triangle as usize], c.u, c.v) {
                    hits[i] = Some(Projected {
                        point: c.point,
                        offset: c.distance,
                        triangle: c.triangle,
                        u: c.u,
                        v: c.v,
                    });
                    on_rim[i] = true;
                }
            }
        }
        Ok(RoundTargets {
            hits,
            on_rim,
            lost_idx,
            lost_closest,
        })
    }

    /// The update δ of one round: the SDM system when `use_sdm` (and the
    /// curvatures were built), the point-distance one otherwise (its patch
    /// factors from and into `factors`, the start's).
    #[allow(clippy::too_many_arguments)]
    fn solve(
        &self,
        mesh: &TriMesh,
        limit: &[crate::subdiv::LimitPoint],
        targets: &RoundTargets,
        use_sdm: bool,
        nv: usize,
        opts: &FitOptions,
        factors: Option<&compress::FactorCache>,
    ) -> Result<Vec<DVec3>> {
        let (stencils, hits, face, laplacian) =
            (&self.stencils, &targets.hits, &self.face, &self.laplacian);
        let curvatures = self.facts.curvatures.get().filter(|_| self.sdm && use_sdm);
        match curvatures {
            None => solve_point(stencils, limit, hits, face, laplacian, nv, opts, factors),
            Some(curv) => solve_sdm(
                mesh,
                &self.facts.normals,
                curv,
                stencils,
                limit,
                hits,
                &targets.on_rim,
                face,
                laplacian,
                nv,
                opts,
            ),
        }
    }
}

impl RoundTargets {
    /// The round's RMS over the samples with a target, and its one-way
    /// score over all samples (the module docs; Fitmaps §3.5 compares
    /// iterates by their error, this makes a lost sample count).
    fn round_error(
        &self,
        limit: &[crate::subdiv::LimitPoint],
        outlier_bound: f64,
        max_dist: f64,
    ) -> Result<(f64, f64)> {
        let (sum2, count) = self
            .hits
            .iter()
            .zip(limit)
            .filter_map(|(h, s)| h.map(|h| (h.point - s.position).length_squared()))
            .fold((0.0, 0usize), |(a, c), d2| (a + d2, c + 1));
        if count == 0 {
            return Err(Error::numerical(
                "fit",
                "no sample of the limit surface projects onto the mesh along its normal; \
                 the control mesh does not approximate this mesh",
            ));
        }
        let rms = (sum2 / count as f64).sqrt();
        // The iterate's score: every sample counts, a lost one (no hit,
        // outlier, other sheet) too, so an update that "improves" by losing
        // samples does not look better.
        // A lost sample counts at its distance to the closest point of M
        // (at least the outlier bound when there is one): a spike whose
        // samples φ cannot follow must weigh what it is, not vanish. A
        // sample past a rim counts at its distance to the rim (in `sum2`),
        // the distance the metrics measure there.
        let floor = if outlier_bound.is_finite() {
            outlier_bound
        } else {
            0.0
        };
        let lost2: f64 = self
            .lost_idx
            .iter()
            .zip(&self.lost_closest)
            .filter(|(&i, _)| !self.on_rim[i])
            .map(|(_, c)| c.map_or(max_dist, |c| c.distance).max(floor).powi(2))
            .sum();
        let one_way = ((sum2 + lost2) / limit.len() as f64).sqrt();
        Ok((rms, one_way))
    }
}

/// RMS distance from (up to 20,000, evenly strided) vertices of `mesh` to
/// the triangulated `k × k` sample grids of the patches (`samples` in
/// patch order, `ks` their sides): a cheap stand-in for the mesh-to-limit
/// half of RMS L, biased upwards by the half-cell gaps between patches but
/// the same bias for every iterate, which is all the comparison needs.
fn mesh_to_samples_rms(
    mesh: &TriMesh,
    samples: &[crate::subdiv::LimitPoint],
    ks: &[usize],
) -> Result<f64> {
    let mut tm = TriMesh {
        positions: samples.iter().map(|s| s.position).collect(),
        triangles: Vec::new(),
    };
    let mut base = 0u32;
    for &k in ks {
        let k32 = k as u32;
        for j in 0..k32.saturating_sub(1) {
            for i in 0..k32 - 1 {
                let a = base + j * k32 + i;
                let (b, c, d) = (a + 1, a + k32 + 1, a + k32);
                tm.triangles.push([a, b, c]);
                tm.triangles.push([a, c, d]);
            }
        }
        base += k32 * k32;
    }
    if tm.triangles.is_empty() {
        return Ok(0.0);
    }
    // Embree's build is several times faster than the Rust BVH's SAH build
    // (this runs every round); the distances come from the same
    // point-to-triangle code either way. Points only: the cheaper build
    // (`make_point_caster`, same answers).
    let caster = crate::raycast::make_point_caster(&tm)?;
    let stride = mesh.positions.len().div_ceil(20_000).max(1);
    let pts: Vec<DVec3> = mesh.positions.iter().step_by(stride).copied().collect();
    let hits = caster.closest_points(&pts, f64::INFINITY)?;
    let (sum2, n) = hits.iter().flatten().fold((0.0, 0usize), |(s, n), h| {
        (s + h.distance * h.distance, n + 1)
    });
    Ok(if n == 0 {
        0.0
    } else {
        (sum2 / n as f64).sqrt()
    })
}

/// The corners of ptex patch `sub` of face `f` (a quad: its corners; an
/// n-gon: corner, edge midpoint, centroid, edge midpoint, as Catmull-Clark
/// splits it).
fn patch_corners(control: &ControlMesh, f: FaceId) -> Vec<[DVec3; 4]> {
    let p: Vec<DVec3> = control
        .face_vertices(f)
        .map(|v| control.position(v))
        .collect();
    let n = p.len();
    if n == 4 {
        return vec![[p[0], p[1], p[2], p[3]]];
    }
    let c = p.iter().copied().sum::<DVec3>() / n as f64;
    (0..n)
        .map(|k| {
            let next = 0.5 * (p[k] + p[(k + 1) % n]);
            let prev = 0.5 * (p[k] + p[(k + n - 1) % n]);
            [p[k], next, c, prev]
        })
        .collect()
}

/// The `k × k` cell-centre samples of every patch (see the module docs),
/// and each patch's k.
pub fn patch_samples(
    control: &ControlMesh,
    mesh_vertices: usize,
    min_k: usize,
) -> (Vec<SurfaceLocation>, Vec<usize>) {
    let mut patches = Vec::new();
    for f in control.faces() {
        for (sub, q) in patch_corners(control, f).into_iter().enumerate() {
            let area = 0.5 * (q[2] - q[0]).cross(q[3] - q[1]).length();
            patches.push((f, sub as u16, area));
        }
    }
    let total: f64 = patches.iter().map(|p| p.2).sum();
    let mut locs = Vec::new();
    let mut ks = Vec::with_capacity(patches.len());
    for &(face, sub, area) in &patches {
        let share = if total > 0.0 {
            area / total
        } else {
            1.0 / patches.len() as f64
        };
        // Capped at 64 per side: a patch that would need more is one of a
        // control mesh as dense as M, where 64² samples are plenty.
        let k = ((mesh_vertices as f64 * share).sqrt().floor() as usize).clamp(min_k, 64);
        ks.push(k);
        for j in 0..k {
            for i in 0..k {
                locs.push(SurfaceLocation {
                    face,
                    sub,
                    u: (i as f64 + 0.5) / k as f64,
                    v: (j as f64 + 0.5) / k as f64,
                });
            }
        }
    }
    (locs, ks)
}

/// One location per control vertex, at a corner of its first face.
pub fn vertex_locations(control: &ControlMesh) -> Vec<SurfaceLocation> {
    const QUAD_CORNERS: [(f64, f64); 4] = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)];
    control
        .vertices()
        .map(|v| {
            let f = control
                .vertex_faces(v)
                .next()
                .expect("ControlMesh has no unreferenced vertices");
            let c = control
                .face_vertices(f)
                .position(|w| w == v)
                .expect("vertex of its own face");
            if control.face_size(f) == 4 {
                let (u, w) = QUAD_CORNERS[c];
                SurfaceLocation::quad(f, u, w)
            } else {
                SurfaceLocation {
                    face: f,
                    sub: c as u16,
                    u: 0.0,
                    v: 0.0,
                }
            }
        })
        .collect()
}

/// The most data samples a fit spreads over the patches (as many as M has
/// vertices below that). A bicubic patch has 16 degrees of freedom and
/// ~10² samples pin it; 100k samples are ≥ 50 per patch for every control
/// mesh of the paper's τ range (≤ 2 000 patches), while on a million-vertex
/// scan one sample per M vertex made every round (stencils, projection,
/// solve) cost in proportion to M (issue 16). Detail finer than the
/// patches is the displacement's job (§3.5), sampled at M's density.
pub const FIT_SAMPLE_BUDGET: usize = 100_000;

/// A boundary edge of M: its end points, its triangle and which edge of it
/// (0: (a, b), 1: (b, c), 2: (c, a)).
#[derive(Copy, Clone, Debug)]
struct RimSegment {
    a: DVec3,
    b: DVec3,
    triangle: u32,
    edge: u8,
}

fn rim_segments(mesh: &TriMesh, rim: &[u8]) -> Vec<RimSegment> {
    let mut out = Vec::new();
    for (t, &mask) in rim.iter().enumerate() {
        let p = mesh.triangle(t);
        for k in 0..3u8 {
            if mask & (1 << k) != 0 {
                out.push(RimSegment {
                    a: p[k as usize],
                    b: p[(k as usize + 1) % 3],
                    triangle: t as u32,
                    edge: k,
                });
            }
        }
    }
    out
}

/// The closest point of the rim (all boundary edges of M) to each point,
/// as a [`Projected`] on the edge's triangle. Brute force over the
/// segments, in parallel over the points (order kept): rims are short next
/// to M (a few hundred edges for 10⁵ triangles) and only border samples ask.
fn closest_on_segments(segs: &[RimSegment], pts: &[DVec3]) -> Vec<Option<Projected>> {
    use rayon::prelude::*;
    pts.par_iter()
        .map(|&p| {
            let mut best: Option<(f64, &RimSegment, f64)> = None;
            for s in segs {
                let ab = s.b - s.a;
                let l2 = ab.length_squared();
                let t = if l2 > 0.0 {
                    ((p - s.a).dot(ab) / l2).clamp(0.0, 1.0)
                } else {
                    0.0
                };
                let d2 = (s.a + t * ab - p).length_squared();
                if best.map_or(true, |b| d2 < b.0) {
                    best = Some((d2, s, t));
                }
            }
            best.map(|(d2, s, t)| {
                // Barycentrics of a + t (b − a) on the triangle's edge.
                let (u, v) = match s.edge {
                    0 => (t, 0.0),
                    1 => (1.0 - t, t),
                    _ => (0.0, 1.0 - t),
                };
                Projected {
                    point: s.a + t * (s.b - s.a),
                    offset: d2.sqrt(),
                    triangle: s.triangle,
                    u,
                    v,
                }
            })
        })
        .collect()
}

/// Samples on the border curves of the limit surface: for every boundary
/// edge of a quad face, its patch's `k` points at `(i + ½)/k` along the
/// edge (`ks` as from [`patch_samples`]). Borders of n-gon faces are left
/// to their vertex equations (the pipeline's control meshes are quads).
fn border_locations(control: &ControlMesh, ks: &[usize]) -> Vec<SurfaceLocation> {
    let mut out = Vec::new();
    let mut patch = 0;
    for f in control.faces() {
        let n = control.face_size(f);
        if n != 4 {
            patch += n;
            continue;
        }
        let k = ks[patch];
        patch += 1;
        for (c, h) in control.face_halfedges(f).enumerate() {
            if !control.is_boundary_halfedge(h.twin()) {
                continue;
            }
            for i in 0..k {
                let t = (i as f64 + 0.5) / k as f64;
                // h_c runs from corner c to corner c+1: (0,0)→(1,0)→(1,1)→(0,1).
                let (u, v) = match c {
                    0 => (t, 0.0),
                    1 => (1.0, t),
                    2 => (1.0 - t, 1.0),
                    _ => (0.0, 1.0 - t),
                };
                out.push(SurfaceLocation::quad(f, u, v));
            }
        }
    }
    out
}

/// Whether the point with Embree barycentrics `(u, v)` (`(1-u-v) a + u b +
/// v c`) lies on one of the boundary edges in `mask` ([`rim_edges`]). A
/// closest point off the triangle's interior has an exactly zero
/// barycentric (Ericson's clamping); the tolerance only absorbs rounding.
fn on_rim_edge(mask: u8, u: f64, v: f64) -> bool {
    const EPS: f64 = 1e-9;
    (mask & 1 != 0 && v <= EPS)
        || (mask & 2 != 0 && 1.0 - u - v <= EPS)
        || (mask & 4 != 0 && u <= EPS)
}

/// Rows of the umbrella Laplacian `δ_v − mean(δ_neighbours)`, one per vertex.
fn umbrella(control: &ControlMesh) -> Vec<Vec<(u32, f64)>> {
    control
        .vertices()
        .map(|v| {
            let nb: Vec<u32> = control.outgoing(v).map(|h| control.head(h).0).collect();
            let w = 1.0 / nb.len().max(1) as f64;
            std::iter::once((v.0, 1.0))
                .chain(nb.into_iter().map(|u| (u, -w)))
                .collect()
        })
        .collect()
}

/// ε of the module docs: the identity rows' weight relative to the
/// Laplacian's (ε² = 1e-4).
const RIDGE: f64 = 1e-2;

/// `L` (per coordinate block of size `stride`) stacked on `ε I`.
fn regulariser(laplacian: &[Vec<(u32, f64)>], nv: usize, stride: usize) -> Triplets {
    let n = nv * stride;
    let mut r = Triplets::new(2 * n, n);
    for (v, row) in laplacian.iter().enumerate() {
        for c in 0..stride {
            let ri = v * stride + c;
            for &(u, w) in row {
                r.push(ri, u as usize * stride + c, w);
            }
            r.push(n + ri, ri, RIDGE);
        }
    }
    r
}

fn lambda(opts: &FitOptions, rows: usize, unknowns: usize) -> f64 {
    opts.fairness * rows as f64 / unknowns.max(1) as f64
}

/// Splits the rows of the projected samples into runs of consecutive
/// samples on the same face (`face[i]` of sample `i`), the groups
/// [`compress::compress_groups`] compresses: a patch's `k²` samples are
/// consecutive, so each patch is one group.
fn grouped_rows(
    hits: &[Option<Projected>],
    face: &[u32],
    mut rows_of: impl FnMut(usize, &Projected, &mut Vec<compress::Row>),
) -> Vec<Vec<compress::Row>> {
    let mut groups: Vec<Vec<compress::Row>> = Vec::new();
    let mut last = None;
    for (i, h) in hits.iter().enumerate() {
        let Some(h) = h else { continue };
        if last != Some(face[i]) {
            groups.push(Vec::new());
            last = Some(face[i]);
        }
        let g = groups.last_mut().expect("a group was just pushed");
        rows_of(i, h, g);
    }
    groups
}

/// The samples of [`grouped_rows`]' groups (in order): each group's name
/// for [`compress::compress_groups_cached`].
fn grouped_samples(hits: &[Option<Projected>], face: &[u32]) -> Vec<Vec<u32>> {
    let mut names: Vec<Vec<u32>> = Vec::new();
    let mut last = None;
    for (i, h) in hits.iter().enumerate() {
        if h.is_none() {
            continue;
        }
        if last != Some(face[i]) {
            names.push(Vec::new());
            last = Some(face[i]);
        }
        names
            .last_mut()
            .expect("a name was just pushed")
            .push(i as u32);
    }
    names
}

/// Stacks compressed rows into `A` and the right-hand sides.
fn stack_rows(rows: Vec<compress::Row>, cols: usize, nrhs: usize) -> (Triplets, Vec<Vec<f64>>) {
    let mut a = Triplets::new(rows.len(), cols);
    let mut b: Vec<Vec<f64>> = (0..nrhs).map(|_| Vec::with_capacity(rows.len())).collect();
    for (r, (entries, rhs)) in rows.into_iter().enumerate() {
        for (col, v) in entries {
            a.push(r, col as usize, v);
        }
        for (bc, v) in b.iter_mut().zip(rhs) {
            bc.push(v);
        }
    }
    (a, b)
}

/// The point objective's update; `factors`: the start's patch factors
/// ([`compress::FactorCache`]), reused where a patch keeps its samples.
#[allow(clippy::too_many_arguments)]
fn solve_point(
    stencils: &LimitStencils,
    limit: &[crate::subdiv::LimitPoint],
    hits: &[Option<Projected>],
    face: &[u32],
    laplacian: &[Vec<(u32, f64)>],
    nv: usize,
    opts: &FitOptions,
    factors: Option<&compress::FactorCache>,
) -> Result<Vec<DVec3>> {
    let samples = hits.iter().filter(|h| h.is_some()).count();
    // A sample's row: its limit stencil (fixed for the system, so a
    // group's factor depends only on which samples it holds) and its
    // residual to its target.
    let entries = |i: usize| -> Vec<(u32, f64)> {
        stencils
            .row(i)
            .map(|k| (stencils.indices[k], stencils.weights[k]))
            .collect()
    };
    let rhs = |i: usize, h: &Projected| {
        let d = h.point - limit[i].position;
        vec![d.x, d.y, d.z]
    };
    let rows = match factors {
        Some(cache) => compress::compress_groups_cached(
            grouped_samples(hits, face),
            |i| entries(i as usize),
            |i| {
                rhs(
                    i as usize,
                    hits[i as usize]
                        .as_ref()
                        .expect("a grouped sample has a hit"),
                )
            },
            3,
            cache,
        ),
        None => compress::compress_groups(
            grouped_rows(hits, face, |i, h, g| g.push((entries(i), rhs(i, h)))),
            3,
        ),
    };
    let (a, b) = stack_rows(rows, nv, 3);
    let reg = regulariser(laplacian, nv, 1);
    // λ counts the samples, not the compressed rows: the normal equations
    // are those of the uncompressed system.
    let x = least_squares(
        &a,
        &b,
        Some((&reg, lambda(opts, samples, nv))),
        &LsqOptions::default(),
    )?;
    Ok((0..nv)
        .map(|v| DVec3::new(x[0][v], x[1][v], x[2][v]))
        .collect())
}

/// Weight of a principal-direction row of the squared-distance
/// minimisation (Pottmann–Leopoldseder, as Lavoué et al. §7.1 use it): a
/// point at signed distance `d` from M, where M's principal curvature in
/// that direction is `k`, weighs `d·k / (1 + d·k)` (the osculating
/// circle's second-order distance), clamped to `[floor, 1]` so the row
/// neither vanishes nor outweighs the normal row; `floor` where the point
/// lies beyond the centre of curvature (`1 + d·k ≤ 0`), and 1 (a point
/// row) where the curvature is undefined.
pub(crate) fn sdm_tangent_weight(d: f64, k: f64, floor: f64) -> f64 {
    if !k.is_finite() {
        return 1.0;
    }
    let q = 1.0 + d * k;
    if q > 0.0 {
        (d * k / q).clamp(floor, 1.0)
    } else {
        floor
    }
}

/// Appends the rows of one sample to an SDM system: for each axis `e` of
/// `frame` (with weight `w`), `√w · e · Σ s_j x_j = −√w · e · res`, where
/// `entries` are the sample's limit-stencil pairs (unknown vertex `j`,
/// weight `s_j`) and `res` is the sample's residual to its foot point
/// (the unknowns are corrections, three columns per vertex).
pub(crate) fn push_frame_rows(
    a: &mut Triplets,
    b: &mut Vec<f64>,
    r: &mut usize,
    frame: &[(DVec3, f64); 3],
    entries: impl Iterator<Item = (usize, f64)> + Clone,
    res: DVec3,
) {
    for &(e, w) in frame {
        let sw = w.sqrt();
        for (v, s) in entries.clone() {
            let col = 3 * v;
            let s = sw * s;
            a.push(*r, col, s * e.x);
            a.push(*r, col + 1, s * e.y);
            a.push(*r, col + 2, s * e.z);
        }
        b.push(-sw * e.dot(res));
        *r += 1;
    }
}

#[allow(clippy::too_many_arguments)]
fn solve_sdm(
    mesh: &TriMesh,
    normals: &[DVec3],
    curv: &[curvature::TriCurvature],
    stencils: &LimitStencils,
    limit: &[crate::subdiv::LimitPoint],
    hits: &[Option<Projected>],
    point_rows: &[bool],
    face: &[u32],
    laplacian: &[Vec<(u32, f64)>],
    nv: usize,
    opts: &FitOptions,
) -> Result<Vec<DVec3>> {
    let samples = hits.iter().filter(|h| h.is_some()).count();
    let floor = opts.sdm_tangent_floor;
    let groups = grouped_rows(hits, face, |i, h, g| {
        let t = mesh.triangles[h.triangle as usize];
        let interp = (1.0 - h.u - h.v) * normals[t[0] as usize]
            + h.u * normals[t[1] as usize]
            + h.v * normals[t[2] as usize];
        let [p0, p1, p2] = mesh.triangle(h.triangle as usize);
        let n = interp
            .try_normalize()
            .or_else(|| (p1 - p0).cross(p2 - p0).try_normalize())
            .unwrap_or(limit[i].normal());
        let c = curv[h.triangle as usize];
        let e1 = (c.dir1 - c.dir1.dot(n) * n)
            .try_normalize()
            .unwrap_or_else(|| n.any_orthonormal_vector());
        let e2 = n.cross(e1);
        let res = limit[i].position - h.point;
        let d = res.dot(n);
        let weight = |k: f64| sdm_tangent_weight(d, k, floor);
        // Rim targets (see the boundary fit in `fit_with_progress`) are
        // point rows: the tangent plane at a rim extends past M's end.
        let frame = if point_rows[i] {
            [(DVec3::X, 1.0), (DVec3::Y, 1.0), (DVec3::Z, 1.0)]
        } else {
            [(n, 1.0), (e1, weight(c.k1)), (e2, weight(c.k2))]
        };
        // The rows of `push_frame_rows`, kept apart for the compression.
        for &(e, w) in &frame {
            let sw = w.sqrt();
            let mut entries = Vec::with_capacity(3 * stencils.row(i).len());
            for k in stencils.row(i) {
                let (v, s) = (stencils.indices[k], sw * stencils.weights[k]);
                entries.push((3 * v, s * e.x));
                entries.push((3 * v + 1, s * e.y));
                entries.push((3 * v + 2, s * e.z));
            }
            g.push((entries, vec![-sw * e.dot(res)]));
        }
    });
    let (a, b) = stack_rows(compress::compress_groups(groups, 1), 3 * nv, 1);
    let reg = regulariser(laplacian, nv, 3);
    // λ per unknown as in the point objective: `samples` data rows per
    // coordinate against nv vertices.
    let x = least_squares(
        &a,
        &b,
        Some((&reg, lambda(opts, samples, nv))),
        &LsqOptions::default(),
    )?;
    let x = &x[0];
    Ok((0..nv)
        .map(|v| DVec3::new(x[3 * v], x[3 * v + 1], x[3 * v + 2]))
        .collect())
}

#[cfg(test)]
mod start_pick_tests {
    use super::*;
    use crate::raycast::{make_raycaster, RayBackend};

    /// An open M (a bumpy square) and a control grid overhanging it, so
    /// that its border loops move onto M's rim and both starts run (the
    /// fixture of `tests/fit_deciding.rs`).
    fn open_case() -> (TriMesh, ControlMesh) {
        let mesh = crate::fixtures::tri_grid(
            16,
            |i, j| {
                let (x, y) = (0.25 * i as f64, 0.25 * j as f64);
                DVec3::new(x, y, 0.1 * (x * 1.3).sin() * (y * 0.9).cos())
            },
            |_, _| true,
        );
        let mut control = crate::fixtures::flat_grid(4, 4);
        for p in control.positions_mut() {
            *p = DVec3::new(1.25 * p.x - 0.5, 1.25 * p.y - 0.5, 0.05);
        }
        (mesh, control)
    }

    /// Both starts stopped after round k and resumed (neither plainly
    /// lower: an infinite margin) give the whole fit bit for bit. A pick
    /// (margin 0) gives it too when it keeps the start that wins the whole
    /// fit, as it does on this fixture (its rim start leads from round 0):
    /// the dropped start's score so far is above the kept one's, whose
    /// score only falls, so the final comparison keeps the kept start.
    #[test]
    fn a_pick_that_keeps_the_whole_fit_s_start_gives_its_bits() {
        let (mesh, control) = open_case();
        let caster = make_raycaster(RayBackend::Embree, &mesh).unwrap();
        let facts = MeshFacts::of(&mesh);
        let opts = FitOptions::default();
        let fit_with = |pick| {
            let quiet = &mut |_: &str, _: f64| true;
            let c = control.clone();
            fit_both_starts(
                &mesh,
                &facts,
                c,
                caster.as_ref(),
                &opts,
                quiet,
                (None, None, pick),
            )
            .unwrap()
        };
        let (whole, rest) = fit_with(None);
        assert!(rest.is_none());
        assert!(whole.report.iterations.len() > 3, "{:?}", whole.report);
        for pick in [(0, f64::INFINITY), (2, f64::INFINITY), (1, 0.0), (2, 0.0)] {
            let (picked, rest) = fit_with(Some(pick));
            assert!(rest.is_none(), "{pick:?}");
            assert_eq!(
                picked.control.positions(),
                whole.control.positions(),
                "{pick:?}"
            );
            assert_eq!(
                picked.report.iterations, whole.report.iterations,
                "{pick:?}"
            );
        }
    }
}
