//! At a fixed patch count (`--faces N`), a second field layout that moves
//! lattice size to the patches whose fitted limit surface stands off M′
//! (issue 40, session 10).
//!
//! Measured last session (docs/status.md, "Where the field layout's RMS D
//! gap at the peers' counts lies", `examples/thin_diag.rs`): on spot at 80
//! patches and cheburashka at 458 one patch held ~74 % of the displaced
//! surface's squared distance to M: its limit spans a thin part and passes
//! 6–27‰ from M, where no displacement along its normal reaches M. At a
//! fixed count with `--max-error inf` no round refines it.
//!
//! So after the first layout's fit, the limit surface is sampled (a grid
//! of cells per patch, as [`super::field`] measures M′ → limit) and each
//! sample's distance to M′ is taken, the direction in which D → M misses:
//! the RMS over the limit's area is the round's criterion ([`off_m`]).
//! A patch whose own RMS is above [`FAR`] times the whole surface's is
//! "far"; h is lowered under it by the Fitmap's error model E(r) = a r⁴
//! (Fitmaps §3.1.2: `(rms / rms_p)^¼`, at most [`MAX_REFINE`]), on the
//! vertices of M′ nearest to it and under its samples; the sizing is
//! regraded and scaled back to the first layout's predicted count
//! ([`lowered_sizing`]), laid out at N again with the same count passes
//! as the first ([`crate::quad::field::field_layout_counted`]) and fitted.
//! The round with the lower criterion is kept, so the second round never
//! raises the kept result's measured limit → M′ RMS.
//!
//! Session 11 (issue 40, spot and cheburashka): an estimate of RMS D
//! after the displacement, the limit's distance to M′ where the
//! displacement cannot carry it onto M′ ([`carried`], both directions:
//! [`OffM::uncarried`]); patches holding [`SHARE`] of it are marked too,
//! and, with `SUBDFIT_THIN_DROUNDS=N` (session 11: off by default, [`D_ROUNDS`]),
//! up to N more layouts lower h under the marks accumulated round by
//! round, one kept when its limit → M′ and fit RMS stay within [`L_CAP`]
//! of the first's and its estimate is lower ([`Judged::beats`]). The far
//! patches' round keeps session 10's rule.
//!
//! Session 12: that estimate misjudged gargoyle τ 10 % at 402 (every
//! round it preferred had a higher RMS D). Taken against M itself
//! ([`on_m`]) it is the same figure there (M′ is M at these counts: no
//! proxy), so the chain is now judged by the pipeline's own displacement
//! and metrics on each round ([`Judge::Displaced`]): a later round is kept
//! when its measured RMS D is lower and its measured RMS L within
//! [`L_CAP_REAL`] of the first's (and the M′ caps hold); one chain round
//! ([`D_ROUNDS`]) is on by default.
//!
//! On by default ([`THIN_ROUND_DEFAULT`]; `SUBDFIT_THIN_ROUND=0` turns it
//! off): measured at the peers' counts (docs/status.md, Field-aligned
//! layout, session 10) it was kept on homer at 272 (RMS D 1.09 → 0.45‰)
//! and not kept, or not run, on spot, cheburashka and gargoyle (their
//! outputs byte-identical). A variant that judged the rounds by the
//! samples the displacement cannot carry onto M′ only was measured worse
//! there (cheburashka: RMS L 1.84 → 4.71‰) and is not kept.

use crate::error::Result;
use crate::fit::Fitted;
use crate::mesh::{ControlMesh, TriMesh};
use crate::quad::field::draws::{self, Final};
use crate::quad::field::{field_layout_counted, sizing, FieldOptions, Surface};
use crate::raycast::bvh::BvhCaster;
use crate::raycast::RayCaster;
use crate::report::{MetricsOptions, StageTimer};
use crate::DVec3;
use rayon::prelude::*;

use super::field::{FieldRound, Sizes};
use super::layout::FieldRelayout;

/// Whether the second round runs without [`THIN_ROUND_ENV`].
pub const THIN_ROUND_DEFAULT: bool = true;

/// The environment switch: `1` runs the second round, `0` does not
/// (unset: [`THIN_ROUND_DEFAULT`]).
pub const THIN_ROUND_ENV: &str = "SUBDFIT_THIN_ROUND";

/// A patch is far when its RMS distance to M′ is above this many times
/// the whole limit surface's (the test is meant to pick a few patches,
/// not a tail: on gargoyle no patch is far at 1357 or 1391 patches).
pub const FAR: f64 = 3.0;

/// The smallest factor on h under a far patch (a quarter of its area:
/// the lattice then lays about four patches where it laid one).
pub const MAX_REFINE: f64 = 0.5;

/// The displacement's same-sheet factor ([`crate::displace`]): a hit
/// farther than this many times the sample's distance to M lies on
/// another sheet.
pub const SAME_SHEET: f64 = 3.0;

/// A patch holding at least this share of the limit's uncarried squared
/// distance ([`OffM::uncarried`]) has its lattice size lowered.
pub const SHARE: f64 = 0.10;

/// The factor on h under such a patch.
pub const D_FACTOR: f64 = 0.5;

/// How many more layouts at most the uncarried share may ask for
/// (`SUBDFIT_THIN_DROUNDS`). Judged on M′'s estimate this was off by
/// default (gargoyle τ 10 % at 402: RMS D 0.375 → 0.943‰, session 11);
/// judged by the displacement pass ([`Judge::Displaced`]) it keeps
/// cheburashka at 460's first chain round (RMS D 0.671 → 0.253‰) and no
/// round elsewhere, and the second chain round was never kept in the
/// six peers' cases (docs/status.md session 12): one.
pub const D_ROUNDS: usize = 1;

/// The chain runs only when the first round's uncarried estimate
/// ([`OffM::uncarried`]) is at least this, ‰ of the diagonal: the chain
/// moves size to where the displacement cannot carry the limit onto M,
/// and below a fifth of the D bars' scale (0.2–0.3‰) there is nothing for
/// it to move. It costs a displacement pass on the first round plus a
/// layout, a fit and a pass per chain round (gargoyle at 1391: +11 CPU s
/// for an estimate of 0.018‰, no round kept; cheburashka at 460, where it
/// pays, 0.275‰; spot, homer, gargoyle τ 10 %: 0.60–1.36‰; session 12).
pub const CHAIN_MIN_UNCARRIED_PERMILLE: f64 = 0.05;

/// How many of the worst patches [`Concentration::share`] counts.
pub const CHAIN_TOP_PATCHES: usize = 1;

/// The chain runs only when the worst [`CHAIN_TOP_PATCHES`] patches hold
/// at least this share of the first round's uncarried squared distance
/// (`SUBDFIT_THIN_TOP_SHARE`; session 13): the chain lowers h under the
/// few patches holding it, which pays where one thin part holds the error
/// (cheburashka at 460) and not where it is spread over many (gargoyle
/// τ 10 %, where no chain round was ever kept).
pub const CHAIN_MIN_TOP_SHARE: f64 = 0.6;

fn min_top_share() -> f64 {
    crate::switches::number("SUBDFIT_THIN_TOP_SHARE", CHAIN_MIN_TOP_SHARE)
}

/// Whether the uncarried chain runs after a first round that measured
/// `m0` (`permille`: ‰ of the diagonal per unit of M′): its estimate is at
/// least [`CHAIN_MIN_UNCARRIED_PERMILLE`] and the worst
/// [`CHAIN_TOP_PATCHES`] patches hold at least [`CHAIN_MIN_TOP_SHARE`] of
/// it.
pub fn chain_runs(m0: &OffM, permille: f64) -> bool {
    permille * m0.uncarried >= CHAIN_MIN_UNCARRIED_PERMILLE
        && m0.concentration.share() >= min_top_share()
}

/// Whether the split round runs (`SUBDFIT_THIN_SPLIT=1`; off by default,
/// session 13: [`split_round`]).
fn split_enabled() -> bool {
    crate::switches::on("SUBDFIT_THIN_SPLIT")
}

/// The split round is kept only within this share of N (issue 40's
/// count window for a local refinement).
pub const SPLIT_COUNT_WINDOW: f64 = 0.05;

/// A later round is kept only when its limit → M′ RMS and its fit's RMS
/// are within this factor of the first round's (RMS L may not rise more
/// than a few % for a lower D).
pub const L_CAP: f64 = 1.07;

fn share() -> f64 {
    crate::switches::number("SUBDFIT_THIN_SHARE", SHARE)
}

fn d_factor() -> f64 {
    crate::switches::number("SUBDFIT_THIN_DFACTOR", D_FACTOR)
}

fn d_rounds() -> usize {
    crate::switches::number("SUBDFIT_THIN_DROUNDS", D_ROUNDS as f64) as usize
}

fn l_cap() -> f64 {
    crate::switches::number("SUBDFIT_THIN_LCAP", L_CAP)
}

/// With [`Judge::Displaced`], a later round is kept only when its
/// measured RMS L is within this factor of the first round's
/// (`SUBDFIT_THIN_LCAP_REAL`).
pub const L_CAP_REAL: f64 = 1.15;

fn l_cap_real() -> f64 {
    crate::switches::number("SUBDFIT_THIN_LCAP_REAL", L_CAP_REAL)
}

/// What the uncarried chain's rounds are judged by (the estimate of RMS
/// D after the displacement).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Judge {
    /// [`OffM::uncarried`], on M′ (session 11: misjudged gargoyle τ 10 %
    /// at 402, RMS D 0.375 → 0.943‰).
    OnLayoutMesh,
    /// The same rule cast against M itself ([`on_m`]).
    OnM,
    /// The pipeline's own displacement and metrics on each round
    /// ([`crate::report::evaluate_surfaces`]): RMS D and RMS L as the
    /// report measures them.
    Displaced,
}

/// The judge without `SUBDFIT_THIN_JUDGE` (`mprime`, `m`, `displaced`).
pub const JUDGE: Judge = Judge::Displaced;

fn judge() -> Judge {
    match crate::switches::text("SUBDFIT_THIN_JUDGE").as_deref() {
        Some("mprime") => Judge::OnLayoutMesh,
        Some("m") => Judge::OnM,
        Some("displaced") => Judge::Displaced,
        _ => JUDGE,
    }
}

/// M itself, the caster over it and the pipeline's metric options: what
/// the chain's rounds are judged against.
pub struct OnM<'a> {
    pub mesh: &'a TriMesh,
    pub caster: &'a dyn RayCaster,
    pub metrics: &'a MetricsOptions,
    /// Where the evaluations ([`evaluated`]) are kept, when given.
    pub memo: Option<&'a Evaluations>,
}

/// The pipeline's displacement and metrics ([`crate::report::evaluate_surfaces`])
/// of the control meshes judged so far, by control mesh (the same
/// topology, creases and positions bit for bit), against one `OnM`'s M,
/// caster and options. Session 18: under `SUBDFIT_FIELD_BEST=1` the same
/// mesh was evaluated up to three times — by the thin round's chain, as a
/// candidate's final figures, as the projectability rounds' incoming
/// result — and once more by the tail ([`super::tail`]) when it is the
/// one kept. An evaluation is a function of those inputs (deterministic
/// whatever the thread count), so a kept one is the recomputation's bits.
///
/// Only the latest evaluation keeps its surfaces (the displacement and the
/// tessellations); the others keep their metrics, which is all a judgement
/// reads. Session 20: keeping every candidate's surfaces until
/// [`Evaluations::keep_only`] took gargoyle τ 1 % under
/// `SUBDFIT_DISP_LEVEL0` to a 1.37 GB peak (the refined cage's
/// tessellations). [`Evaluations::take`] of a mesh whose surfaces were
/// dropped gives `None` and the tail evaluates it again: the same bits.
///
/// Session 25 (tailcost): a chain whose later round loses had dropped the
/// kept first round's surfaces when it evaluated the later one, and the
/// tail evaluated the first again (spot at 81 under the single draw: 0.4–0.5
/// of 2.9 CPU s). [`Evaluations::pin`] keeps the best round's surfaces
/// instead of the latest's: one set is still all that is held while a
/// round is evaluated.
#[derive(Default)]
pub struct Evaluations {
    kept: std::sync::Mutex<Vec<Evaluation>>,
}

/// One judged control mesh: its metrics, and its surfaces while it is the
/// latest evaluated ([`Evaluations`]).
struct Evaluation {
    control: ControlMesh,
    metrics: crate::report::Metrics,
    surfaces: Option<crate::report::Surfaces>,
    /// Kept through [`Evaluations::insert`] ([`Evaluations::pin`]).
    pinned: bool,
}

/// Whether `a` and `b` are the same control mesh bit for bit (`==` alone
/// takes -0.0 for 0.0).
fn same_control(a: &ControlMesh, b: &ControlMesh) -> bool {
    let bits = |p: &DVec3| p.to_array().map(f64::to_bits);
    a == b
        && a.positions()
            .iter()
            .zip(b.positions())
            .all(|(x, y)| bits(x) == bits(y))
}

impl Evaluations {
    fn lock(&self) -> std::sync::MutexGuard<'_, Vec<Evaluation>> {
        // A panic while holding the lock leaves the list as it was.
        self.kept.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The metrics kept for `control`.
    fn metrics(&self, control: &ControlMesh) -> Option<crate::report::Metrics> {
        let kept = self.lock();
        let hit = kept.iter().find(|e| same_control(&e.control, control));
        hit.map(|e| e.metrics.clone())
    }

    /// Keeps `surfaces` for `control`, dropping the surfaces kept before
    /// but the pinned one's ([`Evaluations::pin`]).
    fn insert(&self, control: &ControlMesh, surfaces: crate::report::Surfaces) {
        let mut kept = self.lock();
        for e in kept.iter_mut().filter(|e| !e.pinned) {
            e.surfaces = None;
        }
        kept.push(Evaluation {
            control: control.clone(),
            metrics: surfaces.metrics.clone(),
            surfaces: Some(surfaces),
            pinned: false,
        });
    }

    /// When `control` is evaluated: its surfaces are kept through later
    /// [`Evaluations::insert`]s (until another is pinned), and every other
    /// evaluation's dropped now (a round judged and not kept), so that
    /// only the pinned set is held while the next round is evaluated.
    /// Nothing changes when `control` is not evaluated.
    pub fn pin(&self, control: &ControlMesh) {
        let mut kept = self.lock();
        if !kept.iter().any(|e| same_control(&e.control, control)) {
            return;
        }
        for e in kept.iter_mut() {
            e.pinned = same_control(&e.control, control);
            if !e.pinned {
                e.surfaces = None;
            }
        }
    }

    /// The evaluation of `control`, taken out (the tail's), when its
    /// surfaces are still kept.
    pub fn take(&self, control: &ControlMesh) -> Option<crate::report::Surfaces> {
        let mut kept = self.lock();
        let i = kept
            .iter()
            .position(|e| same_control(&e.control, control))?;
        kept.swap_remove(i).surfaces
    }

    /// Drops every evaluation but `control`'s (after a judgement, the
    /// candidates not kept).
    pub fn keep_only(&self, control: &ControlMesh) {
        self.lock().retain(|e| same_control(&e.control, control));
    }

    /// Keeps `control`'s surfaces through later [`Evaluations::insert`]s
    /// beside those held already, while the held tessellations total at
    /// most [`HELD_VERTICES`] vertices (else, or when `control` has no
    /// surfaces kept, nothing changes). [`final_draws`]' candidates are
    /// judged side by side on one memo, so the chosen draw's evaluation
    /// had been dropped by a later candidate's and the tail evaluated it
    /// again (session 25: cheburashka at 460 under `SUBDFIT_FIELD_BEST=1`,
    /// 1.9 of 24 CPU s); its `keep_only` drops the others.
    pub fn hold(&self, control: &ControlMesh) {
        self.hold_within(control, HELD_VERTICES);
    }

    /// `old` let go (its surfaces dropped unless it is `control`), then
    /// `control` held ([`Evaluations::hold`]): a chain's best beside other
    /// draws.
    pub fn hold_instead(&self, old: Option<&ControlMesh>, control: &ControlMesh) {
        if let Some(old) = old.filter(|o| !same_control(o, control)) {
            let mut kept = self.lock();
            for e in kept.iter_mut().filter(|e| same_control(&e.control, old)) {
                e.pinned = false;
                e.surfaces = None;
            }
        }
        self.hold(control);
    }

    /// [`Evaluations::hold`] with at most `most` vertices held.
    fn hold_within(&self, control: &ControlMesh, most: usize) {
        let mut kept = self.lock();
        let size = |e: &Evaluation| e.surfaces.as_ref().map_or(0, |s| s.limit.positions.len());
        let held: usize = kept.iter().filter(|e| e.pinned).map(size).sum();
        let Some(e) = kept.iter_mut().find(|e| same_control(&e.control, control)) else {
            return;
        };
        let n = size(e);
        if n > 0 && held + n <= most {
            e.pinned = true;
        }
    }

    /// How many evaluations are kept.
    pub fn len(&self) -> usize {
        self.lock().len()
    }

    /// Whether none is kept.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// The most tessellation vertices [`Evaluations::hold`] keeps (each
/// ~100 bytes with both tessellations, plus the atlas): ~200 MB at most
/// beside the one set the memo held before (session 20's gargoyle τ 1 %
/// peak came from keeping every candidate's, unbounded).
pub const HELD_VERTICES: usize = 2_000_000;

/// [`Evaluations::hold`] on `on`'s memo, when it has one.
fn hold(on: &OnM<'_>, control: &ControlMesh) {
    if let Some(memo) = on.memo {
        memo.hold(control);
    }
}

/// Whether the second round is on (module docs).
pub fn enabled() -> bool {
    crate::switches::on_off(THIN_ROUND_ENV).unwrap_or(THIN_ROUND_DEFAULT)
}

/// [`off_m`]'s measurement of a fitted control mesh.
#[derive(Clone, Debug)]
pub struct OffM {
    /// RMS distance from the limit surface to M′ over the limit's area
    /// (units of M′): the round's criterion.
    pub rms: f64,
    /// The far patches (control faces).
    pub far: Vec<u32>,
    /// Per vertex of M′, the factor on h its far patch asks for (1 where
    /// none does).
    pub far_factor: Vec<f64>,
    /// The same with the patches holding the uncarried share too.
    pub factor: Vec<f64>,
    /// RMS over the limit's area of the distance to M′ at the samples the
    /// displacement cannot carry onto M′ (0 at the others), or over M′ of
    /// its vertices' distance to the limit where their nearest limit
    /// point is not carried, the larger: an estimate of RMS D after the
    /// displacement, D → M and M → D ([`carried`]).
    pub uncarried: f64,
    /// The patches holding at least [`SHARE`] of either uncarried squared
    /// distance (some may also be in `far`).
    pub d_far: Vec<u32>,
    /// How the uncarried squared distance is spread over the patches
    /// ([`Concentration`]).
    pub concentration: Concentration,
}

/// The share of the uncarried squared distance held by the worst patches
/// ([`OffM::uncarried`], session 13): the chain's gate
/// ([`CHAIN_MIN_TOP_SHARE`]) and the patches a split round splits.
#[derive(Clone, Debug, Default)]
pub struct Concentration {
    /// The shares of the worst one, two and three patches (cumulative, 0
    /// to 1), D → M then M → D.
    pub top: [[f64; 3]; 2],
    /// Which direction's RMS is the estimate (0: D → M, 1: M → D).
    pub direction: usize,
    /// The patches by their share of that direction's uncarried squared
    /// distance, highest first (only those holding any).
    pub order: Vec<u32>,
}

impl Concentration {
    /// `per_face`'s squared distances (two directions, totals `total`):
    /// the worst patches' cumulative shares and the order of `direction`.
    fn of(per_face: [&[f64]; 2], total: [f64; 2], direction: usize) -> Self {
        let sorted = |e: &[f64]| -> Vec<u32> {
            let mut order: Vec<u32> = (0..e.len() as u32)
                .filter(|&f| e[f as usize] > 0.0)
                .collect();
            order.sort_by(|&a, &b| e[b as usize].total_cmp(&e[a as usize]).then(a.cmp(&b)));
            order
        };
        let mut top = [[0.0; 3]; 2];
        for d in 0..2 {
            let order = sorted(per_face[d]);
            let mut acc = 0.0;
            for (k, t) in top[d].iter_mut().enumerate() {
                acc += order.get(k).map_or(0.0, |&f| per_face[d][f as usize]);
                *t = if total[d] > 0.0 { acc / total[d] } else { 0.0 };
            }
        }
        Self {
            top,
            direction,
            order: sorted(per_face[direction]),
        }
    }

    /// The share the worst [`CHAIN_TOP_PATCHES`] patches hold of either
    /// direction's uncarried squared distance, the larger.
    pub fn share(&self) -> f64 {
        f64::max(
            self.top[0][CHAIN_TOP_PATCHES - 1],
            self.top[1][CHAIN_TOP_PATCHES - 1],
        )
    }
}

/// Which samples the displacement can carry onto M′ (`caster` over it):
/// a sample is carried when its normal line meets M′ within `max_dist`
/// and no farther than [`SAME_SHEET`] × its distance to M′ plus `slack`
/// (the displacement's same-sheet rule, [`crate::displace`]); elsewhere
/// the displaced surface keeps an inpainted offset and stays about that
/// distance off M (issue 40's D error, docs/status.md session 9). A
/// sample on M′ itself (within 10⁻³ × `slack`) counts as carried: a line
/// from the surface may graze past it. A floor of the whole `slack`
/// hid the thin parts it is meant to find (cheburashka at 460 marked 3
/// patches instead of 5 and kept no round: docs/status.md session 11).
pub fn carried(
    caster: &dyn RayCaster,
    points: &[crate::subdiv::LimitPoint],
    distance: &[f64],
    max_dist: f64,
    slack: f64,
) -> Result<Vec<bool>> {
    let origins: Vec<DVec3> = points.iter().map(|p| p.position).collect();
    let dirs: Vec<DVec3> = points.iter().map(|p| p.normal()).collect();
    let (hits, _) = crate::project::project_along(caster, &origins, &dirs, max_dist)?;
    Ok(hits
        .iter()
        .zip(distance)
        .map(|(h, &d)| {
            d <= 1e-3 * slack || h.is_some_and(|h| h.offset.abs() <= SAME_SHEET * d + slack)
        })
        .collect())
}

/// The limit grid of `control` (as many cells per patch as on `layout`,
/// M′) against a mesh (`caster` over it): what [`off_m`] and [`on_m`]
/// both measure, so that the two estimates follow one rule.
struct Carried {
    /// The limit grid and the control face of each of its triangles.
    surface: TriMesh,
    tri_face: Vec<u32>,
    locs: Vec<crate::subdiv::SurfaceLocation>,
    /// The grid vertices' areas and their nearest points on the mesh.
    weights: Vec<f64>,
    near: Vec<Option<crate::raycast::ClosestPoint>>,
    /// Whether the displacement carries each grid vertex onto the mesh
    /// ([`carried`], slack half the mesh's mean edge, as the pipeline's).
    carry: Vec<bool>,
    /// The mesh's vertices' areas and their nearest points on the grid.
    m_areas: Vec<f64>,
    nearest: Vec<Option<crate::raycast::ClosestPoint>>,
}

/// Squared distances over the limit (D → M) per control face and in
/// total, area-weighted: all samples, and those not carried.
struct LimitSums {
    /// Per face: (all, area, not carried).
    per_face: Vec<(f64, f64, f64)>,
    all: f64,
    lost: f64,
    area: f64,
}

/// Squared distances over the mesh (M → D), area-weighted: at its
/// vertices whose nearest limit point is not carried (two of its grid
/// triangle's three), per control face and in total.
struct MeshSums {
    lost: Vec<f64>,
    all: f64,
    area: f64,
}

/// [`Carried`]'s limit side: the grid, its triangles' faces, locations,
/// vertex areas, nearest points on the mesh and carry flags.
type CarryGrid = (
    TriMesh,
    Vec<u32>,
    Vec<crate::subdiv::SurfaceLocation>,
    Vec<f64>,
    Vec<Option<crate::raycast::ClosestPoint>>,
    Vec<bool>,
);

/// The limit grid of `control` (as many cells per patch as on `layout`)
/// and which of its vertices the displacement carries onto `mesh`
/// ([`carried`], slack half the mesh's mean edge, as the pipeline's).
fn carry_grid(
    layout: &TriMesh,
    mesh: &TriMesh,
    caster: &dyn RayCaster,
    control: &ControlMesh,
) -> Result<CarryGrid> {
    let k = super::field::grid_cells(layout, control);
    let (surface, tri_face, locs, evaluator) = super::field::limit_grid(control, k)?;
    let weights = crate::report::vertex_areas(&surface);
    let near = caster.closest_points(&surface.positions, f64::INFINITY)?;
    let dist: Vec<f64> = near
        .iter()
        .map(|c| c.as_ref().map_or(0.0, |c| c.distance))
        .collect();
    let points = evaluator.evaluate(control.positions(), &locs)?;
    let slack = 0.5 * mesh.mean_edge_length();
    let max_dist = crate::project::default_max_dist(mesh);
    let carry = carried(caster, &points, &dist, max_dist, slack)?;
    Ok((surface, tri_face, locs, weights, near, carry))
}

/// [`uncarried_area`]'s result: per control face the limit area whose
/// samples the displacement cannot carry onto the mesh, and that area's
/// share of the whole limit, %.
#[derive(Clone, Debug)]
pub struct UncarriedArea {
    pub per_face: Vec<f64>,
    pub percent: f64,
}

/// The limit area of `control` whose samples the displacement cannot
/// carry onto `mesh` (`caster` over it; [`carried`]: the normal line
/// meets the mesh only on another sheet or nowhere), per control face and
/// as a share of the limit's area. Such samples are inpainted and the
/// displaced surface stands off M there (docs/status.md session 20,
/// adapt2: homer τ 10 % under ADAPT 74 of 6000 against 23 off).
pub fn uncarried_area(
    mesh: &TriMesh,
    caster: &dyn RayCaster,
    control: &ControlMesh,
) -> Result<UncarriedArea> {
    let (_, _, locs, weights, near, carry) = carry_grid(mesh, mesh, caster, control)?;
    let mut per_face = vec![0.0; control.num_faces()];
    let (mut lost, mut area) = (0.0, 0.0);
    for (((c, &a), loc), &ok) in near.iter().zip(&weights).zip(&locs).zip(&carry) {
        if c.is_none() {
            continue;
        }
        area += a;
        if !ok {
            per_face[loc.face.0 as usize] += a;
            lost += a;
        }
    }
    let percent = if area > 0.0 { 100.0 * lost / area } else { 0.0 };
    Ok(UncarriedArea { per_face, percent })
}

impl Carried {
    fn new(
        layout: &TriMesh,
        mesh: &TriMesh,
        caster: &dyn RayCaster,
        control: &ControlMesh,
    ) -> Result<Self> {
        let (surface, tri_face, locs, weights, near, carry) =
            carry_grid(layout, mesh, caster, control)?;
        let grid = BvhCaster::new(&surface)?;
        let nearest = grid.closest_points(&mesh.positions, f64::INFINITY)?;
        let m_areas = crate::report::vertex_areas(mesh);
        Ok(Self {
            surface,
            tri_face,
            locs,
            weights,
            near,
            carry,
            m_areas,
            nearest,
        })
    }

    fn limit_sums(&self, faces: usize) -> LimitSums {
        let mut s = LimitSums {
            per_face: vec![(0.0, 0.0, 0.0); faces],
            all: 0.0,
            lost: 0.0,
            area: 0.0,
        };
        let samples = self.near.iter().zip(&self.weights).zip(&self.locs);
        for (((c, &a), loc), &ok) in samples.zip(&self.carry) {
            let Some(c) = c else { continue };
            let d2 = c.distance * c.distance;
            let f = &mut s.per_face[loc.face.0 as usize];
            f.0 += a * d2;
            f.1 += a;
            s.all += a * d2;
            s.area += a;
            if !ok {
                f.2 += a * d2;
                s.lost += a * d2;
            }
        }
        s
    }

    fn mesh_sums(&self, faces: usize) -> MeshSums {
        let mut s = MeshSums {
            lost: vec![0.0; faces],
            all: 0.0,
            area: 0.0,
        };
        for (c, &a) in self.nearest.iter().zip(&self.m_areas) {
            let Some(c) = c else { continue };
            s.area += a;
            let t = self.surface.triangles[c.triangle as usize];
            if t.iter().filter(|&&v| !self.carry[v as usize]).count() >= 2 {
                let e = a * c.distance * c.distance;
                s.lost[self.tri_face[c.triangle as usize] as usize] += e;
                s.all += e;
            }
        }
        s
    }
}

/// `e / a`'s root, 0 for no area.
fn rms_of(e: f64, a: f64) -> f64 {
    (e / f64::max(a, f64::MIN_POSITIVE)).sqrt()
}

/// The limit surface of `control` against `mesh` (M′, `caster` over it):
/// the area-weighted RMS distance of its samples to M′, its far patches,
/// the uncarried RMS and the patches holding its share, and the factors
/// on h they ask for (module docs).
pub fn off_m(mesh: &TriMesh, caster: &BvhCaster, control: &ControlMesh) -> Result<OffM> {
    let g = Carried::new(mesh, mesh, caster, control)?;
    let faces = control.num_faces();
    let on_limit = g.limit_sums(faces);
    let rms = rms_of(on_limit.all, on_limit.area);
    // M → D: a vertex of M′ whose nearest limit point lies where the
    // samples are not carried (two of its grid triangle's three) is left
    // about that distance from the displaced surface.
    let on_mesh = g.mesh_sums(faces);
    let (lost, m_all) = (on_limit.lost, on_mesh.all);
    let uncarried = f64::max(rms_of(lost, on_limit.area), rms_of(m_all, on_mesh.area));
    let sum = &on_limit.per_face;
    let m_lost = &on_mesh.lost;
    let d_lost: Vec<f64> = sum.iter().map(|s| s.2).collect();
    let direction = usize::from(rms_of(m_all, on_mesh.area) > rms_of(lost, on_limit.area));
    let concentration = Concentration::of([&d_lost, m_lost], [lost, m_all], direction);
    let patch_rms: Vec<f64> = sum
        .iter()
        .map(|&(e, a, _)| if a > 0.0 { (e / a).sqrt() } else { 0.0 })
        .collect();
    let is_far: Vec<bool> = patch_rms.iter().map(|&r| r > FAR * rms).collect();
    let share = share();
    let holds = |e: f64, total: f64| total > 0.0 && e >= share * total;
    let is_d_far: Vec<bool> = sum
        .iter()
        .zip(m_lost)
        .map(|(s, &m)| holds(s.2, lost) || holds(m, m_all))
        .collect();
    let pick =
        |v: &[bool]| -> Vec<u32> { (0..faces).filter(|&f| v[f]).map(|f| f as u32).collect() };
    let (far, d_far) = (pick(&is_far), pick(&is_d_far));
    // E(r) = a r⁴ (Fitmaps §3.1.2): h × (rms / rms_p)^¼ brings a far
    // patch's error to the surface's; a patch holding the uncarried share
    // is halved in size ([`D_FACTOR`]).
    let far_of: Vec<f64> = (0..faces)
        .map(|f| match is_far[f] {
            true => (rms / patch_rms[f]).powf(0.25).max(MAX_REFINE),
            false => 1.0,
        })
        .collect();
    let d_of: Vec<f64> = (0..faces)
        .map(|f| match is_d_far[f] {
            true => far_of[f].min(d_factor()),
            false => far_of[f],
        })
        .collect();
    let spread = |of: &[f64]| -> Vec<f64> {
        let mut factor = vec![1.0; mesh.positions.len()];
        // The vertices of M′ whose nearest limit point lies on a marked
        // patch (the part of M′ it stands for) ...
        for (v, c) in g.nearest.iter().enumerate() {
            let Some(c) = c else { continue };
            let f = g.tri_face[c.triangle as usize] as usize;
            factor[v] = f64::min(factor[v], of[f]);
        }
        // ... and those under its samples (across a thin part the
        // samples' nearest points lie on both sheets, some nearer to other
        // patches).
        for (c, loc) in g.near.iter().zip(&g.locs) {
            let Some(c) = c else { continue };
            let x = of[loc.face.0 as usize];
            if x < 1.0 {
                for v in mesh.triangles[c.triangle as usize] {
                    factor[v as usize] = f64::min(factor[v as usize], x);
                }
            }
        }
        factor
    };
    Ok(OffM {
        rms,
        far_factor: spread(&far_of),
        factor: spread(&d_of),
        far,
        uncarried,
        d_far,
        concentration,
    })
}

/// [`OffM::uncarried`]'s estimate of RMS D taken against M itself: the
/// limit grid of `control` (as dense as on `layout`, M′) cast along its
/// normals against M with the displacement's same-sheet rule (slack half
/// M's mean edge, as the pipeline's); the larger of the RMS over the
/// limit of the distance to M at the samples not carried and the RMS over
/// M of its vertices' distance to the limit where their nearest limit
/// point is not carried. M′ at τ 10 % is too coarse a stand-in for M
/// (gargoyle at 402, docs/status.md session 11).
pub fn on_m(on: &OnM<'_>, layout: &TriMesh, control: &ControlMesh) -> Result<f64> {
    let g = Carried::new(layout, on.mesh, on.caster, control)?;
    let faces = control.num_faces();
    let (on_limit, on_mesh) = (g.limit_sums(faces), g.mesh_sums(faces));
    Ok(f64::max(
        rms_of(on_limit.lost, on_limit.area),
        rms_of(on_mesh.all, on_mesh.area),
    ))
}

/// The pipeline's displacement and metrics on `control` (refined once
/// when not all quads or under `SUBDFIT_DISP_REFINE`, as the tail does:
/// [`super::tail::displaced_on_refinement`]).
fn evaluated(on: &OnM<'_>, control: &ControlMesh) -> Result<crate::report::Metrics> {
    if let Some(m) = on.memo.and_then(|memo| memo.metrics(control)) {
        return Ok(m);
    }
    let quads = match !super::tail::displaced_on_refinement(control, on.mesh, on.metrics) {
        true => None,
        false => Some(crate::subdiv::refine::refine_once_keeping_infinite(
            control,
        )?),
    };
    let c = quads.as_ref().unwrap_or(control);
    let mut quiet = |_: &str, _: f64| true;
    let s = crate::report::evaluate_surfaces(on.mesh, c, on.caster, on.metrics, &mut quiet)?;
    let metrics = s.metrics.clone();
    if let Some(memo) = on.memo {
        memo.insert(control, s);
    }
    Ok(metrics)
}

/// [`evaluated`]'s RMS D and RMS L, ‰.
fn displaced(on: &OnM<'_>, control: &ControlMesh) -> Result<(f64, f64)> {
    let m = evaluated(on, control)?;
    Ok((m.displaced.rms_permille, m.limit.rms_permille))
}

/// `h0` lowered by `factor`, graded at `gamma`, at least M′'s mean edge,
/// and scaled so that it predicts as many patches as `h0` (the patches
/// added under the far ones taken from everywhere else:
/// [`sizing::predicted_faces`], `∫ dA / h²`).
pub fn lowered_sizing(surf: &Surface, h0: &[f64], factor: &[f64], gamma: f64) -> Vec<f64> {
    let target = sizing::predicted_faces(surf, h0);
    let at = |c: f64| -> Vec<f64> {
        let mut h: Vec<f64> = h0.iter().zip(factor).map(|(h, f)| c * h * f).collect();
        sizing::grade(surf, &mut h, gamma);
        for x in &mut h {
            *x = x.max(surf.mean_edge);
        }
        h
    };
    // The count falls monotonically with c; the lowered sizing predicts
    // more than `h0` at c = 1, so c ≥ 1 (bisection on ln c up to 4).
    let (mut lo, mut hi) = (0.0f64, 4.0f64.ln());
    for _ in 0..40 {
        let mid = 0.5 * (lo + hi);
        if sizing::predicted_faces(surf, &at(mid.exp())) > target {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    at(hi.exp())
}

/// The plan of the rounds that re-lay the field at N from a fit's errors,
/// stated once for [`second_round`], [`second_round_drawn`] and the
/// projectability rounds ([`super::faces_proj::rounds_at_count`]). Every
/// round lays the first layout's sizing (the sizes of
/// [`Sizes::new`], Fitmaps §3.1.3) lowered by a factor per vertex of M′
/// ([`lowered_sizing`]: regraded and scaled back to the first layout's
/// predicted count): first, when given, the far patches' factor (one
/// round, session 10's rule), then up to `chain` rounds whose factor is
/// the product of the marks so far, never below [`MIN_FACTOR`] — the
/// first chain round's marks are the incoming result's, each later one's
/// those its predecessor's result gave ([`RoundPlan::mark`]); the chain
/// stops early when a round gives none.
pub(super) struct RoundPlan {
    surf: Surface,
    /// The first layout's sizing, per vertex of M′.
    h0: Vec<f64>,
    /// The grading's slope bound ([`FieldOptions::gradation`]).
    gamma: f64,
    /// The far patches' factor, until its round is planned.
    far: Option<Vec<f64>>,
    /// Chain rounds left.
    chain: usize,
    /// The chain's factor accumulated so far.
    acc: Vec<f64>,
    /// The marks the next chain round multiplies in; `None` ends the chain.
    marks: Option<Vec<f64>>,
}

/// One planned round: its factor on the first layout's sizing per vertex
/// of M′, and whether it is a chain round (not the far patches' round).
pub(super) struct PlannedRound {
    pub(super) factor: Vec<f64>,
    pub(super) chain: bool,
}

impl RoundPlan {
    /// The plan on the first layout's sizing `h0` over `surf` (graded at
    /// `gamma`), the far patches' round first when `far` is given, then up
    /// to `chain` rounds starting from `marks`.
    pub(super) fn new(
        (surf, h0): (Surface, Vec<f64>),
        gamma: f64,
        far: Option<Vec<f64>>,
        marks: Vec<f64>,
        chain: usize,
    ) -> Self {
        let acc = vec![1.0; h0.len()];
        Self {
            surf,
            h0,
            gamma,
            far,
            chain,
            acc,
            marks: Some(marks),
        }
    }

    /// [`RoundPlan::new`] on the first layout's sizing on `relayout`'s M′
    /// at `fo` (timed as the field layout).
    pub(super) fn laid(
        timer: &mut StageTimer,
        relayout: &FieldRelayout,
        fo: &FieldOptions,
        far: Option<Vec<f64>>,
        marks: Vec<f64>,
        chain: usize,
    ) -> Result<Self> {
        let sizes = timer.run("field layout", || {
            Sizes::new(&relayout.mesh, &relayout.fitmap, fo).map(|s| (s.surf, s.h))
        })?;
        Ok(Self::new(sizes, fo.gradation, far, marks, chain))
    }

    /// The next round, `None` when the plan is done.
    pub(super) fn next_round(&mut self) -> Option<PlannedRound> {
        if let Some(factor) = self.far.take() {
            return Some(PlannedRound {
                factor,
                chain: false,
            });
        }
        if self.chain == 0 {
            return None;
        }
        let marks = self.marks.take()?;
        self.chain -= 1;
        for (a, f) in self.acc.iter_mut().zip(&marks) {
            *a = (*a * f).max(MIN_FACTOR);
        }
        Some(PlannedRound {
            factor: self.acc.clone(),
            chain: true,
        })
    }

    /// After a chain round: the marks its result gives the next one
    /// (`None` ends the chain).
    pub(super) fn mark(&mut self, marks: Option<Vec<f64>>) {
        self.marks = marks;
    }

    /// The sizing a round with `factor` lays ([`lowered_sizing`]).
    pub(super) fn sizing(&self, factor: &[f64]) -> Vec<f64> {
        lowered_sizing(&self.surf, &self.h0, factor, self.gamma)
    }

    /// The first layout's sizing.
    pub(super) fn first_sizing(&self) -> &[f64] {
        &self.h0
    }
}

/// The smallest accumulated factor on h over several rounds.
pub const MIN_FACTOR: f64 = 0.25;

/// A fitted round's measures the rounds are judged by.
struct Judged {
    off_m: f64,
    /// The estimate of RMS D the chain is judged by ([`Judge`]), units of
    /// M′ or ‰ (compared only with itself).
    d: f64,
    fit_rms: f64,
    /// With [`Judge::Displaced`], the measured RMS L (‰).
    limit: Option<f64>,
}

/// What one round measured for the chain (recorded on its round).
#[derive(Clone, Copy, Default)]
struct Measured {
    on_m: Option<f64>,
    displaced: Option<(f64, f64)>,
}

impl Measured {
    /// The chain's measures of `control` by `judge` (none when there is no
    /// chain: the far round alone keeps session 10's rule and cost).
    fn of(
        timer: &mut StageTimer,
        on: &OnM<'_>,
        layout: &TriMesh,
        control: &ControlMesh,
        judge: Option<Judge>,
    ) -> Result<Self> {
        // The estimate against M only when it judges: M′ is M itself at
        // the peers' counts (no proxy), and it equalled M′'s there.
        let on_m = match judge {
            Some(Judge::OnM) => Some(timer.run("thin round", || on_m(on, layout, control))?),
            _ => None,
        };
        let displaced = match judge {
            Some(Judge::Displaced) => Some(timer.run("thin round", || displaced(on, control))?),
            _ => None,
        };
        Ok(Self { on_m, displaced })
    }

    fn record(&self, round: &mut FieldRound, permille: f64) {
        round.uncarried_m_permille = self.on_m.map(|x| permille * x);
        round.displaced_permille = self.displaced.map(|x| x.0);
        round.limit_permille = self.displaced.map(|x| x.1);
    }
}

impl Judged {
    fn of(m: &OffM, f: &Fitted, x: &Measured) -> Self {
        let d = match (x.displaced, x.on_m) {
            (Some((d, _)), _) => d,
            (None, Some(d)) => d,
            (None, None) => m.uncarried,
        };
        Self {
            off_m: m.rms,
            d,
            fit_rms: f.report.final_rms_permille,
            limit: x.displaced.map(|x| x.1),
        }
    }

    /// Whether `self` (a later round) beats `best`, `first` being the
    /// first round: its limit may stand no farther from M′ and its fit be
    /// no worse than [`L_CAP`] × the first's (RMS L may not rise much;
    /// measured, no more than [`L_CAP_REAL`] × the first's), and then the
    /// lower estimate of RMS D wins ([`Judge`]), on a tie the lower limit
    /// → M′ RMS.
    fn beats(&self, best: &Judged, first: &Judged) -> bool {
        let cap = l_cap();
        if self.off_m > cap * first.off_m || self.fit_rms > cap * first.fit_rms {
            return false;
        }
        if let (Some(l), Some(l0)) = (self.limit, first.limit) {
            if l > l_cap_real() * l0 {
                return false;
            }
        }
        if self.d != best.d {
            return self.d < best.d;
        }
        self.off_m < best.off_m
    }
}

/// A fit of a control mesh, timed on the run's timer: what the rounds
/// after the first layout's fit call for each layout they lay.
pub(super) trait FitFn: FnMut(&mut StageTimer, ControlMesh) -> Result<Fitted> {}
impl<F: FnMut(&mut StageTimer, ControlMesh) -> Result<Fitted>> FitFn for F {}

/// What the rounds after the first layout's fit work with
/// ([`second_round`], [`final_draws`],
/// [`super::faces_proj::rounds_at_count`]): the run's timer, the re-layout's
/// inputs, the layout options (the face target), the rounds' records each
/// layout is pushed on, the fit and M to measure the final figures on.
pub(super) struct RoundCtx<'a, F> {
    pub timer: &'a mut StageTimer,
    pub relayout: &'a FieldRelayout,
    pub fo: &'a FieldOptions,
    pub rounds: &'a mut Vec<FieldRound>,
    pub fit: F,
    pub on: &'a OnM<'a>,
}

impl<F: FitFn> RoundCtx<'_, F> {
    /// The same context for a nested call, borrowing this one.
    pub(super) fn reborrow(&mut self) -> RoundCtx<'_, &mut F> {
        RoundCtx {
            timer: &mut *self.timer,
            relayout: self.relayout,
            fo: self.fo,
            rounds: &mut *self.rounds,
            fit: &mut self.fit,
            on: self.on,
        }
    }

    /// `control` fitted on the run's timer.
    pub(super) fn fit(&mut self, control: ControlMesh) -> Result<Fitted> {
        (self.fit)(self.timer, control)
    }
}

/// The later rounds (module docs) after the first round's fit `first`,
/// each fitted by `fit` on a layout at `fo`'s count and pushed on
/// `rounds`: one whose sizing is lowered under the far patches only (when
/// there are), then up to [`D_ROUNDS`] whose sizing is lowered under the
/// patches the previous one marked (far, or holding the uncarried share),
/// accumulated, judged against M (`on`, [`Judge`]). The round kept is the
/// best by [`Judged::beats`], so never one worse than `first` by it;
/// `first` unchanged when no patch is marked.
pub(super) fn second_round<F: FitFn>(cx: RoundCtx<'_, F>, first: Fitted) -> Result<Fitted> {
    let RoundCtx {
        timer,
        relayout,
        fo,
        rounds,
        mut fit,
        on,
    } = cx;
    let mesh = &relayout.mesh;
    let permille = 1000.0 / mesh.bbox_diagonal();
    let caster = BvhCaster::shared(mesh)?;
    let m0 = timer.run("thin round", || off_m(mesh, &caster, &first.control))?;
    if let Some(r) = rounds.last_mut() {
        r.off_m_permille = Some(permille * m0.rms);
        r.patches_off_m = Some(m0.far.len() + m0.d_far.len());
        r.uncarried_permille = Some(permille * m0.uncarried);
        r.uncarried_top_percent = Some(
            m0.concentration
                .top
                .concat()
                .iter()
                .map(|x| 100.0 * x)
                .collect(),
        );
    }
    let chain = match chain_runs(&m0, permille) {
        true => d_rounds(),
        false => 0,
    };
    if m0.far.is_empty() && (chain == 0 || m0.d_far.is_empty()) {
        return Ok(first);
    }
    let k = draws::thin_relayout_draws_from_env();
    if k > 1 {
        let cx = DrawnCtx {
            relayout,
            fo,
            on,
            k,
            chain,
        };
        return second_round_drawn(timer, &cx, first, &m0, rounds, fit);
    }
    let judge = (chain > 0).then(judge);
    let x0 = Measured::of(timer, on, mesh, &first.control, judge)?;
    if let Some(r) = rounds.last_mut() {
        x0.record(r, permille);
    }
    let j0 = Judged::of(&m0, &first, &x0);
    // The best round's surfaces are the tail's ([`Evaluations::pin`]);
    // not beside other draws, which share the memo and would each hold one.
    // Beside other draws, which share the memo, the best is held instead
    // (within the cap) and the one it replaces let go.
    let pin = |old: Option<&ControlMesh>, c: &ControlMesh| match on.memo {
        Some(memo) if relayout.alternatives.is_empty() => memo.pin(c),
        Some(memo) => memo.hold_instead(old, c),
        None => {}
    };
    pin(None, &first.control);
    // Kept only at the count asked for (`--faces`' ±2 % window, or no
    // farther from N than the first round).
    let first_faces = first.control.num_faces();
    let n = fo.target_faces.map_or(first_faces, |n| n) as f64;
    let off = |f: usize| (f as f64 - n).abs();
    let far = (!m0.far.is_empty()).then(|| m0.far_factor.clone());
    let mut plan = RoundPlan::laid(timer, relayout, fo, far, m0.factor.clone(), chain)?;
    let split_from = (chain > 0 && split_enabled()).then(|| first.control.clone());
    let mut best = (Judged::of(&m0, &first, &x0), first, None::<usize>);
    while let Some(planned) = plan.next_round() {
        let laid = timer.run("field layout", || {
            let h = plan.sizing(&planned.factor);
            field_layout_counted(&relayout.prepared, mesh, &relayout.fitmap, h, fo)
        })?;
        let (faces, irregular) = (laid.control.num_faces(), laid.stats.irregular_vertices);
        let next = fit(timer, laid.control)?;
        let m1 = timer.run("thin round", || off_m(mesh, &caster, &next.control))?;
        let x1 = Measured::of(timer, on, mesh, &next.control, judge)?;
        let j1 = Judged::of(&m1, &next, &x1);
        let at_count = off(faces) <= f64::max(0.02 * n, off(first_faces));
        let fitted = (next.report.final_rms_permille, laid.stats.size_factor);
        let mut round = measured_round(fo.target_faces, (faces, irregular), fitted, &m1, permille);
        x1.record(&mut round, permille);
        rounds.push(round);
        // The far patches' round by session 10's rule (a lower limit → M′
        // RMS: on homer at 272 it took RMS D 1.09 → 0.45‰ while the
        // uncarried estimate stayed level), the chain by [`Judged::beats`].
        let better = match planned.chain {
            false => j1.off_m < best.0.off_m,
            true => j1.beats(&best.0, &j0),
        };
        if at_count && better {
            let old = std::mem::replace(&mut best, (j1, next, Some(rounds.len() - 1)));
            pin(Some(&old.1.control), &best.1.control);
        } else {
            pin(None, &best.1.control);
        }
        if planned.chain {
            // The next chain round adds this one's marks (none: the chain ends).
            let marked = !(m1.far.is_empty() && m1.d_far.is_empty());
            plan.mark(marked.then_some(m1.factor));
        }
    }
    if let Some(c) = split_from {
        let cx = SplitCtx {
            relayout,
            fo,
            h: plan.first_sizing(),
            caster: &caster,
            on,
            judge,
        };
        if let Some((j1, next, round)) = split_fitted(timer, &cx, &c, &m0.concentration, &mut fit)?
        {
            rounds.push(round);
            let at_count = off(next.control.num_faces()) <= SPLIT_COUNT_WINDOW * n;
            if at_count && j1.beats(&best.0, &j0) {
                let old = std::mem::replace(&mut best, (j1, next, Some(rounds.len() - 1)));
                pin(Some(&old.1.control), &best.1.control);
            } else {
                pin(None, &best.1.control);
            }
        }
    }
    if let Some(i) = best.2 {
        rounds[i].kept = Some(true);
    }
    Ok(best.1)
}

/// [`second_round`] on the first layout's fit `first` and on each of the
/// first layout's other draws (`relayout.alternatives`,
/// `SUBDFIT_FIELD_THIN_DRAWS`, session 15), each fitted by `fit` and
/// given its own thin round; the result kept is the one
/// [`draws::choose_final`] ranks first on the pipeline's own final figures
/// (RMS L, RMS D, irregular vertices, the unprojectable share over the
/// bar), ties to the lower draw. Session 14 ranked the draws by their
/// first fit, which the final result follows only loosely (the thin
/// round re-lays the field from that fit's errors: spot at 81's worst
/// first layout ended best in RMS D). Without alternatives, [`second_round`].
pub(super) fn final_draws<F: FitFn, S: SideFit>(
    mut cx: RoundCtx<'_, F>,
    first: Fitted,
    side: &S,
) -> Result<Fitted> {
    let relayout = cx.relayout;
    if relayout.alternatives.is_empty() {
        return second_round(cx, first);
    }
    let (fo, on) = (cx.fo, cx.on);
    // The first layout's thin round with its own guard (main's candidate
    // under `SUBDFIT_FIELD_BEST`: unguarded, as main lays it).
    let fo_first = FieldOptions {
        cleanup_guarded: relayout.first_guarded.or(fo.cleanup_guarded),
        ..fo.clone()
    };
    // The candidates read nothing of one another (each lays, fits and
    // judges its own meshes; the shared memo is keyed by mesh), so the
    // other draws are carried on beside the first layout's round (session
    // 19) and their records appended in draw order after its rounds: the
    // rounds and the choice are those of carrying them one after the other.
    let mut alts: Result<Vec<CarriedDraw>> = Ok(Vec::new());
    let main_run = |cx: &mut RoundCtx<'_, F>| -> Result<(Final, Fitted)> {
        let mut c0 = cx.reborrow();
        c0.fo = &fo_first;
        let main = second_round(c0, first)?;
        let f = cx
            .timer
            .run("thin round", || final_figures(on, &main.control))?;
        hold(on, &main.control);
        Ok((f, main))
    };
    let main = if rayon::current_num_threads() > 1 {
        let slot = &mut alts;
        rayon::in_place_scope(|s| {
            s.spawn(move |_| *slot = carry_alternatives(relayout, fo, on, side));
            main_run(&mut cx)
        })
    } else {
        let m = main_run(&mut cx);
        alts = carry_alternatives(relayout, fo, on, side);
        m
    };
    let (f, main) = main?;
    // Each candidate with the index of its first round on `rounds`.
    let mut cands = vec![(f, main, 0usize)];
    for (c, timer, rounds) in alts? {
        let start = cx.rounds.len() + c.2;
        cx.timer.stages.extend(timer.stages);
        cx.rounds.extend(rounds);
        cands.push((c.0, c.1, start));
    }
    let mut figures: Vec<Final> = cands.iter().map(|c| c.0).collect();
    let (mut best, mut scores) =
        draws::choose_final_with(&figures, fo.target_faces, 0.02, draws::Score::from_env());
    if guard_kept() {
        // The guarded cancellation on the kept draw only: its sizing laid
        // again with the guard on (the thin round's layouts too), carried
        // on as the other draws are, kept if the final figures rank it
        // first.
        let scale = match best {
            0 => relayout.first_scale,
            i => relayout.alternatives[i - 1].0,
        };
        let fo_g = FieldOptions {
            cleanup_guarded: Some(true),
            ..fo.clone()
        };
        let laid = cx.timer.run("field layout", || {
            let r = relayout;
            crate::quad::field::field_layout_at_scale(&r.prepared, &r.mesh, &r.fitmap, &fo_g, scale)
        })?;
        let mut g = cx.reborrow();
        g.fo = &fo_g;
        let c = carry_draw(g, scale, laid.control)?;
        figures.push(c.0);
        cands.push(c);
        (best, scores) =
            draws::choose_final_with(&figures, fo.target_faces, 0.02, draws::Score::from_env());
    }
    log_candidates("first draw", &figures, &scores, best);
    let (_, fitted, start) = cands.swap_remove(best);
    if best > 0 {
        cx.rounds[start].kept = Some(true);
    }
    if let Some(memo) = on.memo {
        memo.keep_only(&fitted.control);
    }
    Ok(fitted)
}

/// A fit of a control mesh that can run beside the run's own
/// ([`final_draws`]' other draws): the same fit without the run's
/// progress callback, which is not `Send`.
pub(super) trait SideFit: Fn(&mut StageTimer, ControlMesh) -> Result<Fitted> + Sync {}
impl<F: Fn(&mut StageTimer, ControlMesh) -> Result<Fitted> + Sync> SideFit for F {}

/// A carried draw ([`carry_draw`]) with its own timer and rounds.
type CarriedDraw = ((Final, Fitted, usize), StageTimer, Vec<FieldRound>);

/// `relayout.alternatives` each carried on ([`carry_draw`]) with `fit`,
/// side by side, on a timer and rounds of its own, in draw order; the
/// first error in draw order.
fn carry_alternatives<S: SideFit>(
    relayout: &FieldRelayout,
    fo: &FieldOptions,
    on: &OnM<'_>,
    fit: &S,
) -> Result<Vec<CarriedDraw>> {
    relayout
        .alternatives
        .par_iter()
        .map(|(scale, control)| {
            let (mut timer, mut rounds) = (StageTimer::default(), Vec::new());
            let cx = RoundCtx {
                timer: &mut timer,
                relayout,
                fo,
                rounds: &mut rounds,
                fit: |t: &mut StageTimer, c: ControlMesh| fit(t, c),
                on,
            };
            let c = carry_draw(cx, *scale, control.clone())?;
            Ok((c, timer, rounds))
        })
        .collect()
}

/// One of the first layout's draws (`control`, laid at `scale` × h)
/// carried on by [`final_draws`]: fitted, recorded as a round, given its
/// own thin round ([`second_round`]) and measured by the pipeline's final
/// figures, which its first round records. Returns those figures, the
/// result and the index of its first round on `rounds`.
fn carry_draw<F: FitFn>(
    mut cx: RoundCtx<'_, F>,
    scale: f64,
    control: ControlMesh,
) -> Result<(Final, Fitted, usize)> {
    let start = cx.rounds.len();
    let (faces, irregular) = (
        control.num_faces(),
        crate::quad::field::irregular_vertices(&control),
    );
    let fitted = cx.fit(control)?;
    cx.rounds.push(FieldRound {
        target_faces: cx.fo.target_faces,
        faces,
        irregular_vertices: irregular,
        fit_rms_permille: fitted.report.final_rms_permille,
        thin_draw_scale: Some(scale),
        ..Default::default()
    });
    let on = cx.on;
    let done = second_round(cx.reborrow(), fitted)?;
    let f = cx
        .timer
        .run("thin round", || final_figures(on, &done.control))?;
    hold(on, &done.control);
    let r = &mut cx.rounds[start];
    r.displaced_permille = Some(f.displaced_permille);
    r.limit_permille = Some(f.limit_permille);
    r.unprojectable_percent = Some(f.unprojectable_percent);
    Ok((f, done, start))
}

/// `SUBDFIT_FIELD_THIN_GUARD_KEPT=1`: [`final_draws`] runs the guarded
/// cancellation on the kept draw only (session 15's measurement; off).
fn guard_kept() -> bool {
    crate::switches::on("SUBDFIT_FIELD_THIN_GUARD_KEPT")
}

/// With `SUBDFIT_FIELD_DRAW_LOG` set, each candidate's final figures and
/// score on stderr.
fn log_candidates(what: &str, figures: &[Final], scores: &[Option<f64>], best: usize) {
    if !crate::switches::set("SUBDFIT_FIELD_DRAW_LOG") {
        return;
    }
    for (j, (f, s)) in figures.iter().zip(scores).enumerate() {
        eprintln!(
            "{what} {j}: faces {} irregular {} L {:.4} D {:.4} unprojectable {:.4} % score {s:?}{}",
            f.faces,
            f.irregular_vertices,
            f.limit_permille,
            f.displaced_permille,
            f.unprojectable_percent,
            if j == best { " kept" } else { "" }
        );
    }
}

/// What the drawn thin round ([`second_round_drawn`]) takes of the run.
struct DrawnCtx<'a> {
    relayout: &'a FieldRelayout,
    fo: &'a FieldOptions,
    on: &'a OnM<'a>,
    /// Draws per re-layout.
    k: usize,
    /// Chain rounds after the far patches' round ([`D_ROUNDS`] or none).
    chain: usize,
}

/// [`evaluated`]'s figures as a candidate's final ones.
pub(super) fn final_figures(on: &OnM<'_>, control: &ControlMesh) -> Result<Final> {
    let metrics = evaluated(on, control)?;
    Ok(Final {
        faces: control.num_faces(),
        irregular_vertices: crate::quad::field::irregular_vertices(control),
        limit_permille: metrics.limit.rms_permille,
        displaced_permille: metrics.displaced.rms_permille,
        unprojectable_percent: metrics.unprojectable_area_percent,
    })
}

/// [`second_round`] with each re-layout drawn `cx.k` times
/// (`SUBDFIT_FIELD_THIN_DRAWS`, session 15): the thin round re-lays the
/// field from the first fit's errors and is itself another draw of the
/// chaotic lattice (docs/status.md, session 14: spot at 81 ended at RMS D
/// 0.42–1.01‰ and homer at 272 at 0.38–0.96 % unprojectable by the draw),
/// so its sizing is laid with h × each of [`draws::SCALES`] (side by
/// side, [`draws::lay`]), every draw fitted and measured by the pipeline's
/// own displacement and metrics, and the candidate kept is the first
/// round or a draw, whichever [`draws::choose_final`] ranks first on those
/// final figures. The plan is [`second_round`]'s: the far patches' round,
/// then the chain's rounds, each chain round lowering h under the marks of
/// the previous round's draw 0 (h × 1, the round [`second_round`] lays).
fn second_round_drawn(
    timer: &mut StageTimer,
    cx: &DrawnCtx<'_>,
    first: Fitted,
    m0: &OffM,
    rounds: &mut Vec<FieldRound>,
    mut fit: impl FnMut(&mut StageTimer, ControlMesh) -> Result<Fitted>,
) -> Result<Fitted> {
    let (relayout, fo, on) = (cx.relayout, cx.fo, cx.on);
    let mesh = &relayout.mesh;
    let caster = BvhCaster::shared(mesh)?;
    let f0 = timer.run("thin round", || final_figures(on, &first.control))?;
    if let Some(r) = rounds.last_mut() {
        r.displaced_permille = Some(f0.displaced_permille);
        r.limit_permille = Some(f0.limit_permille);
        r.unprojectable_percent = Some(f0.unprojectable_percent);
    }
    let first_round = rounds.len().saturating_sub(1);
    let far = (!m0.far.is_empty()).then(|| m0.far_factor.clone());
    let mut plan = RoundPlan::laid(timer, relayout, fo, far, m0.factor.clone(), cx.chain)?;
    // Candidate 0 is the first round; each later one a fitted draw, with
    // the index of its round on `rounds`.
    let mut cands: Vec<(Final, Fitted, usize)> = vec![(f0, first, first_round)];
    while let Some(planned) = plan.next_round() {
        let laid = timer.run("field layout", || {
            let h = plan.sizing(&planned.factor);
            Ok(draws::lay(cx.k, |s| {
                let h: Vec<f64> = h.iter().map(|x| x * s).collect();
                field_layout_counted(&relayout.prepared, mesh, &relayout.fitmap, h, fo)
            }))
        })?;
        let mut next_marks = None;
        for (d, laid) in laid.into_iter().enumerate() {
            // A draw that failed is left out (draw 0's error is the
            // round's when every draw failed: [`second_round`] fails
            // there too).
            let laid = match laid {
                Ok(l) => l,
                Err(e) if d == 0 => return Err(e),
                Err(_) => continue,
            };
            let size_factor = laid.stats.size_factor;
            let next = fit(timer, laid.control)?;
            let f1 = timer.run("thin round", || final_figures(on, &next.control))?;
            if d == 0 && planned.chain {
                let m1 = timer.run("thin round", || off_m(mesh, &caster, &next.control))?;
                if !(m1.far.is_empty() && m1.d_far.is_empty()) {
                    next_marks = Some(m1.factor);
                }
            }
            rounds.push(FieldRound {
                target_faces: fo.target_faces,
                faces: f1.faces,
                irregular_vertices: f1.irregular_vertices,
                fit_rms_permille: next.report.final_rms_permille,
                size_factor: Some(size_factor),
                displaced_permille: Some(f1.displaced_permille),
                limit_permille: Some(f1.limit_permille),
                unprojectable_percent: Some(f1.unprojectable_percent),
                thin_draw_scale: Some(draws::SCALES[d]),
                kept: Some(false),
                ..Default::default()
            });
            cands.push((f1, next, rounds.len() - 1));
        }
        if planned.chain {
            plan.mark(next_marks);
        }
    }
    let figures: Vec<Final> = cands.iter().map(|c| c.0).collect();
    let (best, scores) =
        draws::choose_final_with(&figures, fo.target_faces, 0.02, draws::Score::from_env());
    log_candidates("thin draw", &figures, &scores, best);
    let (_, fitted, r) = cands.swap_remove(best);
    if best > 0 {
        rounds[r].kept = Some(true);
    }
    Ok(fitted)
}

/// What the split round ([`split_fitted`]) takes of the run.
struct SplitCtx<'a> {
    relayout: &'a FieldRelayout,
    fo: &'a FieldOptions,
    /// The first layout's sizing.
    h: &'a [f64],
    caster: &'a BvhCaster,
    on: &'a OnM<'a>,
    judge: Option<Judge>,
}

/// The split round (`SUBDFIT_THIN_SPLIT=1`, session 13): splitting the
/// first round's worst patch ([`split_round`]) adds patches (spot at 80:
/// 93), so the lattice is laid again at N less that growth on the first
/// layout's sizing, fitted, and its own worst patch split
/// ([`Concentration::order`]); that mesh fitted and measured as the
/// chain's rounds are. `None` when nothing could be split.
fn split_fitted<F>(
    timer: &mut StageTimer,
    cx: &SplitCtx<'_>,
    first: &ControlMesh,
    concentration: &Concentration,
    fit: &mut F,
) -> Result<Option<(Judged, Fitted, FieldRound)>>
where
    F: FnMut(&mut StageTimer, ControlMesh) -> Result<Fitted>,
{
    let mesh = &cx.relayout.mesh;
    let permille = 1000.0 / mesh.bbox_diagonal();
    let grown = timer.run("field refinement", || {
        split_round(cx.caster, first, concentration)
    })?;
    let Some(grown) = grown else {
        return Ok(None);
    };
    let added = grown.num_faces().saturating_sub(first.num_faces());
    let n = cx.fo.target_faces.unwrap_or(first.num_faces());
    let fo = FieldOptions {
        target_faces: Some(n.saturating_sub(added).max(1)),
        ..cx.fo.clone()
    };
    let r = &cx.relayout;
    let laid = timer.run("field layout", || {
        field_layout_counted(&r.prepared, mesh, &r.fitmap, cx.h.to_vec(), &fo)
    })?;
    let base = fit(timer, laid.control)?;
    let m = timer.run("thin round", || off_m(mesh, cx.caster, &base.control))?;
    let split = timer.run("field refinement", || {
        split_round(cx.caster, &base.control, &m.concentration)
    })?;
    let Some(c) = split else {
        return Ok(None);
    };
    let (faces, irregular) = (c.num_faces(), crate::quad::field::irregular_vertices(&c));
    let next = fit(timer, c)?;
    let m1 = timer.run("thin round", || off_m(mesh, cx.caster, &next.control))?;
    let x1 = Measured::of(timer, cx.on, mesh, &next.control, cx.judge)?;
    let j1 = Judged::of(&m1, &next, &x1);
    let fitted = (next.report.final_rms_permille, laid.stats.size_factor);
    let mut round = FieldRound {
        patches_split: Some(1),
        ..measured_round(
            cx.fo.target_faces,
            (faces, irregular),
            fitted,
            &m1,
            permille,
        )
    };
    x1.record(&mut round, permille);
    Ok(Some((j1, next, round)))
}

/// A thin round's record before its displacement pass: its count, its
/// fit (RMS L ‰, size factor) and its distances off M (`m1`), not kept
/// yet.
fn measured_round(
    target_faces: Option<usize>,
    (faces, irregular): (usize, usize),
    (fit_rms_permille, size_factor): (f64, f64),
    m1: &OffM,
    permille: f64,
) -> FieldRound {
    FieldRound {
        target_faces,
        faces,
        irregular_vertices: irregular,
        fit_rms_permille,
        size_factor: Some(size_factor),
        off_m_permille: Some(permille * m1.rms),
        patches_off_m: Some(m1.far.len() + m1.d_far.len()),
        uncarried_permille: Some(permille * m1.uncarried),
        kept: Some(false),
        ..Default::default()
    }
}

/// Session 13, off by default (`SUBDFIT_THIN_SPLIT=1`): a local
/// refinement where the uncarried distance concentrates, instead of a new
/// lattice (spot at 81: every re-laid round moved the whole lattice, RMS
/// L 10.8–18.7‰ against 9.18). The first round's control mesh with the
/// patch holding the largest share split 1 → 4, conforming transitions
/// around it ([`crate::quad::field::refine`], every other quad kept), and
/// every vertex moved onto M′ (the refit then starts as a layout's does;
/// a fitted start set the fit's outlier rule too tight, see
/// `refine_locally` in [`super::field`]). `None` when the mesh is not pure
/// quad or no patch holds any uncarried distance.
fn split_round(
    caster: &BvhCaster,
    control: &ControlMesh,
    c: &Concentration,
) -> Result<Option<ControlMesh>> {
    use crate::quad::field::refine;
    let Some(&worst) = c.order.first() else {
        return Ok(None);
    };
    if !refine::refinable(control) {
        return Ok(None);
    }
    let mut marked = vec![false; control.num_faces()];
    marked[worst as usize] = true;
    let mut split = refine::split(control, &refine::split_edges(control, &marked)?)?;
    let near = caster.closest_points(split.positions(), f64::INFINITY)?;
    let positions = split
        .positions()
        .iter()
        .zip(near)
        .map(|(p, c)| c.map_or(*p, |c| c.point))
        .collect();
    split.set_positions(positions)?;
    Ok(Some(split))
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;

    /// A mesh's positions as bits (the memo's surfaces must be a fresh
    /// evaluation's bit for bit).
    fn position_bits(m: &TriMesh) -> Vec<[u64; 3]> {
        m.positions
            .iter()
            .map(|p| p.to_array().map(f64::to_bits))
            .collect()
    }

    /// Values as bits.
    fn value_bits(o: &[f64]) -> Vec<u64> {
        o.iter().map(|x| x.to_bits()).collect()
    }

    /// The square [0, n]² as a triangle mesh of `m` × `m` cells per
    /// unit.
    fn plane(n: usize, m: usize) -> TriMesh {
        rectangle(n, n, m, DVec3::ZERO)
    }

    /// The rectangle `origin` + [0, w] × [0, n] as a triangle mesh of
    /// `m` × `m` cells per unit.
    pub(in crate::convert) fn rectangle(w: usize, n: usize, m: usize, origin: DVec3) -> TriMesh {
        let (sx, sy) = (w * m, n * m);
        let positions = (0..=sy)
            .flat_map(|j| {
                (0..=sx).map(move |i| DVec3::new(i as f64, j as f64, 0.0) / m as f64 + origin)
            })
            .collect();
        let at = |i: usize, j: usize| (j * (sx + 1) + i) as u32;
        let triangles = (0..sy)
            .flat_map(|j| (0..sx).map(move |i| (i, j)))
            .flat_map(|(i, j)| {
                [
                    [at(i, j), at(i + 1, j), at(i + 1, j + 1)],
                    [at(i, j), at(i + 1, j + 1), at(i, j + 1)],
                ]
            })
            .collect();
        TriMesh {
            positions,
            triangles,
        }
    }

    /// An `n` × `n` quad grid on the same square, its vertex at `(5, 5)`
    /// lifted by `lift`: the limit stands off the plane around it only.
    fn grid(n: usize, lift: f64) -> ControlMesh {
        let positions = (0..=n)
            .flat_map(|j| {
                (0..=n).map(move |i| {
                    let z = if (i, j) == (5, 5) { lift } else { 0.0 };
                    DVec3::new(i as f64, j as f64, z)
                })
            })
            .collect();
        let at = |i: usize, j: usize| (j * (n + 1) + i) as u32;
        let quads: Vec<[u32; 4]> = (0..n)
            .flat_map(|j| (0..n).map(move |i| (i, j)))
            .map(|(i, j)| [at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1)])
            .collect();
        ControlMesh::from_polygons(positions, &quads).expect("grid")
    }

    /// A limit lifted around one control vertex: the four patches at it
    /// are far (their RMS is several times the surface's), a corner patch
    /// is not; h is lowered on the plane's vertices under them by the r⁴
    /// model (never below [`MAX_REFINE`]) and left alone at the corner.
    /// On a flat grid nothing is far and the criterion is ~0.
    #[test]
    fn a_patch_standing_off_the_mesh_is_far_and_lowers_h_under_it() {
        let mesh = plane(10, 3);
        let caster = BvhCaster::new(&mesh).expect("caster");
        let flat = off_m(&mesh, &caster, &grid(10, 0.0)).expect("flat");
        assert!(flat.far.is_empty(), "{:?}", flat.far);
        assert!(flat.rms < 1e-9, "{}", flat.rms);
        assert!(flat.factor.iter().all(|&f| f == 1.0));
        let lifted = off_m(&mesh, &caster, &grid(10, 2.0)).expect("lifted");
        assert!(lifted.rms > 0.05, "{}", lifted.rms);
        // Faces are numbered row by row: (i, j) is face 10 j + i.
        let face = |i: u32, j: u32| 10 * j + i;
        for f in [face(4, 4), face(5, 4), face(4, 5), face(5, 5)] {
            assert!(lifted.far.contains(&f), "{f} not in {:?}", lifted.far);
        }
        assert!(!lifted.far.contains(&face(0, 0)));
        assert!(lifted.far.len() <= 16, "{:?}", lifted.far);
        // The plane's vertex under (5, 5) and at the corner (0, 0).
        let centre = (5 * 3) * (10 * 3 + 1) + 5 * 3;
        assert!(lifted.factor[centre] < 1.0 && lifted.factor[centre] >= MAX_REFINE);
        assert_eq!(lifted.factor[0], 1.0);
    }

    /// The lowered sizing predicts the first sizing's patch count (the
    /// added patches taken from elsewhere, to the bisection's 1e-6), is
    /// lower where the factor is and higher than before elsewhere, and
    /// keeps the grading slope γ.
    #[test]
    fn the_lowered_sizing_keeps_the_predicted_count() {
        let mesh = plane(10, 3);
        let surf = Surface::new(&mesh).expect("surface");
        let h0 = vec![0.5; mesh.positions.len()];
        let factor: Vec<f64> = mesh
            .positions
            .iter()
            .map(|p| {
                if (*p - DVec3::new(5.0, 5.0, 0.0)).length() < 1.0 {
                    0.5
                } else {
                    1.0
                }
            })
            .collect();
        let gamma = 0.5;
        let h = lowered_sizing(&surf, &h0, &factor, gamma);
        let (n0, n) = (
            sizing::predicted_faces(&surf, &h0),
            sizing::predicted_faces(&surf, &h),
        );
        assert!((n / n0 - 1.0).abs() < 1e-4, "{n} vs {n0}");
        let centre = (5 * 3) * (10 * 3 + 1) + 5 * 3;
        assert!(h[centre] < 0.5 && h[0] > 0.5, "{} {}", h[centre], h[0]);
        for &[a, b] in &surf.edges {
            let d = (mesh.positions[a as usize] - mesh.positions[b as usize]).length();
            assert!((h[a as usize] - h[b as usize]).abs() <= gamma * d + 1e-12);
        }
    }

    /// The round plan on a plane: the far patches' round first, on their
    /// factor as given; then the chain, whose first round's factor is the
    /// incoming marks and each later one's the product of every mark so
    /// far, clamped at [`MIN_FACTOR`]; `chain` rounds at most, fewer when
    /// a round gives no marks. Every round lays the first sizing lowered
    /// by its factor (so the chain's sizing is lowest where both rounds
    /// marked), and none compounds the previous round's sizing.
    #[test]
    fn the_round_plan_lays_the_far_round_then_the_accumulated_chain() {
        let mesh = plane(6, 2);
        let nv = mesh.positions.len();
        let surf = Surface::new(&mesh).expect("surface");
        let h0 = vec![2.0; nv];
        let gamma = 0.5;
        // Far: every third vertex; the first marks every even one, the
        // second every fourth at 0.4 (so 0.16 below MIN_FACTOR) and 0.9
        // elsewhere.
        let far: Vec<f64> = (0..nv).map(|v| [0.5, 1.0, 1.0][v % 3]).collect();
        let m0: Vec<f64> = (0..nv).map(|v| [0.4, 1.0][v % 2]).collect();
        let m1: Vec<f64> = (0..nv).map(|v| [0.4, 0.9, 0.9, 0.9][v % 4]).collect();
        let expected = |factors: &[&[f64]]| -> Vec<f64> {
            (0..nv)
                .map(|v| {
                    factors
                        .iter()
                        .map(|f| f[v])
                        .product::<f64>()
                        .max(MIN_FACTOR)
                })
                .collect()
        };
        let lays = |plan: &RoundPlan, factor: &[f64]| {
            let h = plan.sizing(factor);
            assert_eq!(h, lowered_sizing(&surf, &h0, factor, gamma));
            h
        };
        let sizes = (Surface::new(&mesh).expect("surface"), h0.clone());
        let mut plan = RoundPlan::new(sizes, gamma, Some(far.clone()), m0.clone(), 3);
        let r = plan.next_round().expect("far round");
        assert!(!r.chain);
        assert_eq!(r.factor, far);
        lays(&plan, &r.factor);
        let r = plan.next_round().expect("first chain round");
        assert!(r.chain);
        assert_eq!(r.factor, expected(&[&m0]));
        lays(&plan, &r.factor);
        plan.mark(Some(m1.clone()));
        let r = plan.next_round().expect("second chain round");
        assert!(r.chain);
        let want = expected(&[&m0, &m1]);
        assert_eq!(r.factor, want);
        assert_eq!((want[0], want[2], want[1]), (MIN_FACTOR, 0.4 * 0.9, 0.9));
        let h = lays(&plan, &r.factor);
        // Vertex 0 (factor 1/4) lays a smaller size than its neighbour,
        // vertex 1 (0.9), the grading keeping the larger above it.
        assert!(h[0] < h[1], "{} {}", h[0], h[1]);
        // A round that gives no marks ends the chain before its third.
        plan.mark(None);
        assert!(plan.next_round().is_none());
        // Without a far round the chain opens, and `chain` bounds it.
        let sizes = (Surface::new(&mesh).expect("surface"), h0.clone());
        let mut plan = RoundPlan::new(sizes, gamma, None, m0.clone(), 2);
        let mut seen = Vec::new();
        while let Some(r) = plan.next_round() {
            assert!(r.chain);
            seen.push(r.factor);
            plan.mark(Some(m1.clone()));
        }
        assert_eq!(seen, vec![expected(&[&m0]), expected(&[&m0, &m1])]);
        assert_eq!(plan.first_sizing(), &h0[..]);
    }

    /// The rectangle [-1, w - 1] × [-1, n - 1] as a triangle mesh of
    /// `m` × `m` cells per unit.
    fn strip(w: usize, n: usize, m: usize) -> TriMesh {
        rectangle(w, n, m, DVec3::new(-1.0, -1.0, 0.0))
    }

    /// The displacement's same-sheet rule: a point above a plane whose
    /// line meets it at its own distance is carried, one whose line runs
    /// along the plane (misses) or meets it far beyond 3× its distance
    /// (80° off the normal) is not.
    #[test]
    fn carried_follows_the_same_sheet_rule() {
        use crate::subdiv::LimitPoint;
        let mesh = plane(4, 2);
        let caster = BvhCaster::new(&mesh).expect("caster");
        let at = |du: DVec3, dv: DVec3| LimitPoint {
            position: DVec3::new(2.0, 2.0, 0.2),
            du,
            dv,
        };
        let tilt = 80f64.to_radians();
        let points = [
            at(DVec3::X, DVec3::Y),
            at(DVec3::X, DVec3::Z),
            at(DVec3::Y, DVec3::new(-tilt.cos(), 0.0, tilt.sin())),
        ];
        let d = [0.2; 3];
        let c = carried(&caster, &points, &d, 10.0, 0.01).expect("carried");
        assert_eq!(c, vec![true, false, false]);
    }

    /// A limit surface (the grid [0, 4]², 0.5 above M′, which spans
    /// [-1, 3] × [-1, 5]) whose last column of patches overhangs M′'s border:
    /// the samples there have no hit along their normal, so the uncarried
    /// estimate is their distance, those patches hold its share and h is
    /// halved under them (at M′'s border), while the patches over M′ (at
    /// 0.5 above it, carried) are not marked and keep h. The whole limit
    /// stands about as far off M′ everywhere, so no patch is far: the
    /// session-10 rule alone would mark nothing (spot's case).
    #[test]
    fn an_overhanging_column_holds_the_uncarried_share() {
        let mesh = strip(4, 6, 3);
        let caster = BvhCaster::new(&mesh).expect("caster");
        let mut control = grid(4, 0.0);
        let lifted: Vec<DVec3> = control
            .positions()
            .iter()
            .map(|p| *p + DVec3::new(0.0, 0.0, 0.5))
            .collect();
        control.set_positions(lifted).expect("positions");
        let m = off_m(&mesh, &caster, &control).expect("off_m");
        assert!(m.far.is_empty(), "{:?}", m.far);
        assert!(m.uncarried > 0.1, "{}", m.uncarried);
        let face = |i: u32, j: u32| 4 * j + i;
        for j in 0..4 {
            assert!(m.d_far.contains(&face(3, j)), "{:?}", m.d_far);
        }
        assert!(m.d_far.iter().all(|&f| f % 4 >= 2), "{:?}", m.d_far);
        // M′'s vertex at (3, 2) (its border, under the column) and at
        // (-1, -1).
        let border = (3 * 3) * (4 * 3 + 1) + 4 * 3;
        assert_eq!(m.factor[border], D_FACTOR);
        assert_eq!(m.far_factor[border], 1.0);
        assert_eq!(m.factor[0], 1.0);
    }

    /// The session-11 estimate on M′ misjudges where M′ is a poor
    /// stand-in for M: here M′ (the square [-1, 5]²) reaches under the
    /// whole limit (the grid [0, 4]², 0.5 above), so every sample is
    /// carried onto M′ and its estimate is ~0, while M (the strip
    /// [-1, 3] × [-1, 5]) ends under the last column of patches: against
    /// M those samples' lines miss and [`on_m`] sees their distance
    /// (≥ 0.5 over about a quarter of the limit's area: above 0.2).
    #[test]
    fn the_estimate_against_m_sees_what_m_prime_hides() {
        let layout = rectangle(6, 6, 3, DVec3::new(-1.0, -1.0, 0.0));
        let m = strip(4, 6, 3);
        let mut control = grid(4, 0.0);
        let lifted: Vec<DVec3> = control
            .positions()
            .iter()
            .map(|p| *p + DVec3::new(0.0, 0.0, 0.5))
            .collect();
        control.set_positions(lifted).expect("positions");
        let on_layout = off_m(&layout, &BvhCaster::new(&layout).expect("caster"), &control);
        let on_layout = on_layout.expect("off_m");
        assert!(on_layout.uncarried < 1e-9, "{}", on_layout.uncarried);
        let caster = BvhCaster::new(&m).expect("caster");
        let metrics = MetricsOptions::default();
        let on = OnM {
            mesh: &m,
            caster: &caster,
            metrics: &metrics,
            memo: None,
        };
        let d = on_m(&on, &layout, &control).expect("on_m");
        assert!(d > 0.2, "{d}");
        // The same limit over the whole of M is carried against M too.
        let d = on_m(&on, &layout, &control_over(&m)).expect("on_m");
        assert!(d < 1e-9, "{d}");
    }

    /// A 4 × 4 quad grid 0.5 above the middle of `m`'s strip
    /// ([-1, 3] × [-1, 5]): its limit lies over M everywhere.
    fn control_over(_m: &TriMesh) -> ControlMesh {
        let mut c = grid(4, 0.0);
        let p: Vec<DVec3> = c
            .positions()
            .iter()
            .map(|p| DVec3::new(-0.5 + 0.75 * p.x, -0.5 + 1.25 * p.y, 0.5))
            .collect();
        c.set_positions(p).expect("positions");
        c
    }

    /// `n` × `n` unit quads lifted to z = `z`.
    fn lifted_grid(n: usize, z: f64) -> ControlMesh {
        let mut control = grid(n, 0.0);
        let p: Vec<DVec3> = control
            .positions()
            .iter()
            .map(|p| *p + DVec3::new(0.0, 0.0, z))
            .collect();
        control.set_positions(p).expect("positions");
        control
    }

    /// Two triangle meshes as one (their vertices apart).
    fn union(a: TriMesh, b: TriMesh) -> TriMesh {
        let base = a.positions.len() as u32;
        let mut positions = a.positions;
        positions.extend(b.positions);
        let mut triangles = a.triangles;
        triangles.extend(b.triangles.iter().map(|t| t.map(|v| v + base)));
        TriMesh {
            positions,
            triangles,
        }
    }

    /// The worst patches' cumulative shares and their order, per
    /// direction; no share without any uncarried distance.
    #[test]
    fn the_concentration_counts_the_worst_patches() {
        let d = [0.0, 6.0, 1.0, 3.0];
        let m = [1.0, 1.0, 1.0, 1.0];
        let c = Concentration::of([&d, &m], [10.0, 4.0], 0);
        assert_eq!(c.top[0], [0.6, 0.9, 1.0]);
        assert_eq!(c.top[1], [0.25, 0.5, 0.75]);
        assert_eq!(c.order, vec![1, 3, 2]);
        assert_eq!(c.share(), c.top[0][CHAIN_TOP_PATCHES - 1]);
        let none = Concentration::of([&[0.0; 4], &[0.0; 4]], [0.0, 0.0], 1);
        assert_eq!(none.top, [[0.0; 3]; 2]);
        assert!(none.order.is_empty());
    }

    /// The chain's gate on two limits 0.5 above M′ (a 4 × 4 grid over
    /// [0, 4]²) that both leave patches uncarried (well above the 0.05‰
    /// floor): where M′ lacks the corner [3, 5]² only the corner patch
    /// overhangs, it holds most of the uncarried distance and the chain
    /// runs; where M′ ends at x = 2 the two right columns (8 patches)
    /// overhang alike, no patch holds [`CHAIN_MIN_TOP_SHARE`] and the
    /// chain is skipped (gargoyle τ 10 %'s spread error, session 13).
    /// Before session 13 only the floor gated it: both would run.
    #[test]
    fn the_chain_runs_only_where_the_uncarried_distance_concentrates() {
        let control = lifted_grid(4, 0.5);
        let corner = union(
            rectangle(6, 4, 3, DVec3::new(-1.0, -1.0, 0.0)),
            rectangle(4, 2, 3, DVec3::new(-1.0, 3.0, 0.0)),
        );
        let spread = rectangle(3, 6, 3, DVec3::new(-1.0, -1.0, 0.0));
        for (mesh, runs) in [(corner, true), (spread, false)] {
            let caster = BvhCaster::new(&mesh).expect("caster");
            let m = off_m(&mesh, &caster, &control).expect("off_m");
            let permille = 1000.0 / mesh.bbox_diagonal();
            assert!(permille * m.uncarried > 10.0, "{}", m.uncarried);
            let share = m.concentration.share();
            assert_eq!(chain_runs(&m, permille), runs, "share {share}");
            // The corner patch (3, 3) is face 15 and holds the most.
            if runs {
                assert!(share > 0.7, "{share}");
                assert_eq!(m.concentration.order[0], 15);
            }
        }
    }

    /// [`Evaluations`]: a control mesh judged twice is evaluated once, and
    /// what the memo hands back (the figures, and the surfaces the tail
    /// writes) are a fresh [`crate::report::evaluate_surfaces`]'s bits; a
    /// mesh that differs in one coordinate's last bit is not taken for it;
    /// [`Evaluations::keep_only`] drops the others.
    #[test]
    fn the_memo_hands_back_a_fresh_evaluation_bit_for_bit() {
        let mesh = plane(4, 3);
        let caster = BvhCaster::new(&mesh).expect("caster");
        let metrics = MetricsOptions::default();
        let memo = Evaluations::default();
        let on = OnM {
            mesh: &mesh,
            caster: &caster,
            metrics: &metrics,
            memo: Some(&memo),
        };
        let control = control_over(&mesh);
        let f1 = final_figures(&on, &control).expect("figures");
        assert_eq!(memo.len(), 1);
        let f2 = final_figures(&on, &control).expect("figures again");
        assert_eq!(memo.len(), 1, "the second judgement is the memo's");
        let mut quiet = |_: &str, _: f64| true;
        let fresh =
            crate::report::evaluate_surfaces(&mesh, &control, &caster, &metrics, &mut quiet)
                .expect("fresh");
        let bits = |x: f64| x.to_bits();
        for f in [f1, f2] {
            assert_eq!(
                bits(f.limit_permille),
                bits(fresh.metrics.limit.rms_permille)
            );
            assert_eq!(
                bits(f.displaced_permille),
                bits(fresh.metrics.displaced.rms_permille)
            );
            assert_eq!(
                bits(f.unprojectable_percent),
                bits(fresh.metrics.unprojectable_area_percent)
            );
        }
        // A last-bit change is another mesh: evaluated afresh.
        let mut nudged = control.clone();
        let mut p = nudged.positions().to_vec();
        p[0].z = f64::from_bits(p[0].z.to_bits() + 1);
        nudged.set_positions(p).expect("positions");
        final_figures(&on, &nudged).expect("nudged");
        assert_eq!(memo.len(), 2);
        // Only the latest evaluation keeps its surfaces: `control`'s were
        // dropped (its metrics stay), so the tail would evaluate it again.
        memo.keep_only(&control);
        assert_eq!(memo.len(), 1);
        assert!(memo.take(&control).is_none(), "surfaces dropped");
        assert!(memo.is_empty());
        // Evaluated again it is the latest: its surfaces are kept, with
        // the fresh evaluation's bits.
        final_figures(&on, &control).expect("figures once more");
        final_figures(&on, &control).expect("the memo's");
        assert_eq!(memo.len(), 1);
        let kept = memo.take(&control).expect("kept");
        assert!(memo.is_empty());
        assert_eq!(kept.metrics, fresh.metrics);
        assert_eq!(position_bits(&kept.limit), position_bits(&fresh.limit));
        assert_eq!(
            position_bits(&kept.displaced),
            position_bits(&fresh.displaced)
        );
        assert_eq!(kept.limit.triangles, fresh.limit.triangles);
        assert_eq!(
            value_bits(&kept.displaced_offsets),
            value_bits(&fresh.displaced_offsets)
        );
        assert_eq!(kept.displaced_projected, fresh.displaced_projected);
    }

    /// [`Evaluations::pin`] (session 25): the pinned first round keeps its
    /// surfaces through a later round's evaluation, and what the tail takes
    /// for it is a fresh evaluation's bits; pinning it again after the
    /// later round loses drops the loser's surfaces (one set held while the
    /// next round is evaluated); pinning a mesh never evaluated changes
    /// nothing. Without the pin the later evaluation drops the first's.
    #[test]
    fn a_pinned_round_keeps_its_surfaces_through_a_later_evaluation() {
        let mesh = plane(4, 3);
        let caster = BvhCaster::new(&mesh).expect("caster");
        let metrics = MetricsOptions::default();
        let first = control_over(&mesh);
        let mut later = first.clone();
        let mut p = later.positions().to_vec();
        p[0].z += 0.05;
        later.set_positions(p).expect("same count");
        let mut quiet = |_: &str, _: f64| true;
        let fresh = crate::report::evaluate_surfaces(&mesh, &first, &caster, &metrics, &mut quiet)
            .expect("fresh");
        for pinned in [false, true] {
            let memo = Evaluations::default();
            let on = OnM {
                mesh: &mesh,
                caster: &caster,
                metrics: &metrics,
                memo: Some(&memo),
            };
            final_figures(&on, &first).expect("first");
            if pinned {
                memo.pin(&later);
                memo.pin(&first);
            }
            final_figures(&on, &later).expect("later");
            assert_eq!(memo.len(), 2);
            if pinned {
                memo.pin(&first);
                assert!(memo.take(&later).is_none(), "the loser's surfaces dropped");
            }
            let kept = memo.take(&first);
            assert_eq!(kept.is_some(), pinned);
            let Some(kept) = kept else { continue };
            assert_eq!(kept.metrics, fresh.metrics);
            assert_eq!(position_bits(&kept.limit), position_bits(&fresh.limit));
            assert_eq!(
                position_bits(&kept.displaced),
                position_bits(&fresh.displaced)
            );
            assert_eq!(
                value_bits(&kept.displaced_offsets),
                value_bits(&fresh.displaced_offsets)
            );
            assert_eq!(
                value_bits(&kept.displacement.offsets),
                value_bits(&fresh.displacement.offsets)
            );
        }
    }

    /// [`Evaluations::hold`] (session 25): draws' final evaluations held
    /// side by side survive a later candidate's evaluation, the one kept
    /// by `keep_only` is a fresh evaluation's bits; a hold past the cap,
    /// or of a mesh never evaluated, keeps nothing. Without a hold only
    /// the latest keeps its surfaces.
    #[test]
    fn held_draws_keep_their_surfaces_within_the_cap() {
        let mesh = plane(4, 3);
        let caster = BvhCaster::new(&mesh).expect("caster");
        let metrics = MetricsOptions::default();
        let a = control_over(&mesh);
        let moved = |dz: f64| {
            let mut c = a.clone();
            let mut p = c.positions().to_vec();
            p[0].z += dz;
            c.set_positions(p).expect("same count");
            c
        };
        let (b, c) = (moved(0.05), moved(-0.05));
        let mut quiet = |_: &str, _: f64| true;
        let fresh = crate::report::evaluate_surfaces(&mesh, &a, &caster, &metrics, &mut quiet)
            .expect("fresh");
        let per_set = fresh.limit.positions.len();
        // (cap, whether a and b are still kept after c's evaluation)
        for (cap, kept) in [
            (2 * per_set, (true, true)),
            (per_set, (true, false)),
            (0, (false, false)),
        ] {
            let memo = Evaluations::default();
            let on = OnM {
                mesh: &mesh,
                caster: &caster,
                metrics: &metrics,
                memo: Some(&memo),
            };
            memo.hold_within(&b, cap);
            final_figures(&on, &a).expect("a");
            memo.hold_within(&a, cap);
            final_figures(&on, &b).expect("b");
            memo.hold_within(&b, cap);
            final_figures(&on, &c).expect("c");
            assert_eq!(memo.len(), 3);
            let has = |x: &ControlMesh| {
                let kept = memo.lock();
                let e = kept.iter().find(|e| same_control(&e.control, x));
                e.is_some_and(|e| e.surfaces.is_some())
            };
            assert_eq!((has(&a), has(&b)), kept, "cap {cap}");
            assert!(has(&c), "the latest keeps its surfaces");
            if cap == 2 * per_set {
                // A chain's best replaced: b let go, a still held.
                memo.hold_instead(Some(&b), &c);
                assert!(!has(&b) && has(&a));
            }
            memo.keep_only(&a);
            assert_eq!(memo.len(), 1);
            let Some(s) = memo.take(&a) else {
                assert!(!kept.0);
                continue;
            };
            assert_eq!(s.metrics, fresh.metrics);
            assert_eq!(position_bits(&s.displaced), position_bits(&fresh.displaced));
            assert_eq!(
                value_bits(&s.displacement.offsets),
                value_bits(&fresh.displacement.offsets)
            );
        }
    }

    /// With a measured RMS L, a later round whose D is lower is still not
    /// kept when its RMS L rose more than [`L_CAP_REAL`] over the first
    /// round's; within the cap the lower D wins.
    #[test]
    fn a_lower_d_is_not_kept_for_a_much_higher_l() {
        let at = |d: f64, l: f64| Judged {
            off_m: 1.0,
            d,
            fit_rms: 1.0,
            limit: Some(l),
        };
        let first = at(1.0, 2.0);
        assert!(!at(0.5, 2.0 * L_CAP_REAL * 1.01).beats(&first, &first));
        assert!(at(0.5, 2.0 * L_CAP_REAL * 0.99).beats(&first, &first));
        assert!(!at(1.1, 2.0).beats(&first, &first));
    }
}
