//! The tail of the field-aligned layout (`--layout field`, issue 40): the
//! global fit of [`super::tail`], and organic `--max-error` met by
//! refining the sizing field locally where the fit misses it, instead of
//! fitting a series of simplification checkpoints ([`super::search`]) or
//! laying the whole field out again at a finer global scale.
//!
//! After each fit, every patch's error is measured on its own limit
//! surface: k × k samples per patch ([`crate::fit::patch_samples`], about
//! one per vertex of M′), each sample's distance to M′ (the layout mesh
//! the sizing lives on). A patch whose RMS is above the local target
//! [`LOCAL_TARGET`]·E gets its h scaled by `(t / rms)^¼` on the vertices
//! of M′ under it (the Fitmap's own error model, E(r) = a r⁴, Fitmaps
//! §3.1.2; issue 40's design note, step 4: "patches that fail … or exceed
//! the error target get a smaller h locally"), one far below it
//! ([`COARSEN_BELOW`]) a larger one, capped at the M-fitmap's projectable
//! size and at [`MAX_COARSEN`] per pass; then the field is graded again
//! and steps 3–5 run on it. Projectability drives the same refinement:
//! each vertex of M′ is tested as `report.json` tests M (the normal
//! projection φ from its nearest limit point must land on it, the
//! M-fitmap's criterion, Fitmaps §3.1.3; a vertex reached on a sheet
//! facing against the limit normal, where the limit crossed a thin part,
//! is counted apart and drives nothing unless [`THIN_REFINES`]), the
//! patches it is nearest to
//! carry its area, and a patch with unprojectable vertices gets h ×
//! [`UNPROJECTABLE_REFINE`]; rounds go on while more than
//! [`UNPROJECTABLE_PERCENT`] of M′'s area is unprojectable.
//!
//! With [`LOCAL_REFINEMENT`] (off: its measurements there), a pure-quad
//! layout (the field layout's own output) is refined locally instead
//! ([`refine_locally`]): the same per-patch errors and projectability
//! choose patches of the layout that are split 1 → 4 with conforming
//! transitions ([`crate::quad::field::refine`]), every other quad kept,
//! and the next round fits the split layout. Laying the whole lattice out
//! again on the refined sizing changes every patch, so each round meets new badly fitted or
//! folded patches and the rounds overshot (spot at τ 5 %: 285 patches,
//! 3.03‰ against a 5‰ bound, more than its 135 at τ 1 %), but the local
//! pass measured worse still. At most
//! [`FIELD_ROUNDS`] layouts are fitted, fewer when a refined sizing no
//! longer grows the mesh. A round within the error bound that misses
//! only projectability refines only its unprojectable patches
//! ([`Sizes::refine`]). A round that meets both bounds far under the
//! error bound, after a failing one, may be followed by one round between
//! the two sizings ([`back_off`]). The kept round is the one with the
//! fewest patches among those meeting both bounds, else the lowest RMS
//! among those within projectability, else the least unprojectable
//! ([`Kept`]), and `report.json`'s target says whether it met the bound.

use serde::Serialize;

use crate::analysis::Fitmap;
use crate::error::Result;
use crate::mesh::{ControlMesh, TriMesh};
use crate::quad::field::{
    field_layout_refined_following, sizing, FieldOptions, FieldStats, Follow, Surface,
};
use crate::raycast::RayCaster;
use crate::report::TargetCheck;
use crate::DVec3;

use super::layout::FieldRelayout;
use super::options::ConvertOptions;
use super::run::Run;
use super::tail::{measure_fitted_after, Converted, Known, PipelineOptions};
use crate::report::StageTimer;

/// Whether a pure-quad layout is refined locally ([`refine_locally`])
/// rather than laid out again on a refined sizing ([`lay_out_grown`]).
/// Off: measured at the defaults (`--layout field --mode organic`, τ 5 %)
/// the local pass ended worse than the relayout on every mesh tried
/// (patches / irregular / RMS L ‰, relayout → local: spot 285 / 67 / 3.03
/// → 222 / 69 / 18.96, homer 624 / 173 / 1.16 → 738 / 307 / 2.75,
/// cheburashka 514 / 82 / 1.94 → 527 / 201 / 3.42; docs/status.md, Field-
/// aligned layout): each refined region's transitions add valence-3/5
/// pairs, and the refit of a locally split layout left parts of M′ far
/// from the limit surface (its RMS over M′ rose from round to round).
pub const LOCAL_REFINEMENT: bool = false;

/// Layouts fitted at most for one `--max-error` (the first included).
pub const FIELD_ROUNDS: usize = 6;

/// Extra refinements of one round's sizing when its lattice did not grow
/// the mesh, each at [`REGROW_FACTOR`] times h ([`fit_field`]).
pub const REGROW: usize = 2;
pub const REGROW_FACTOR: f64 = 0.9;

/// [`REGROW_FACTOR`] for a round refined for projectability alone (its
/// error within the bound): such a round refines a few patches, and a
/// lattice that did not grow from them was grown ×0.9 everywhere, which
/// took homer at τ 1 % from 377 patches (0.115 % unprojectable) to 501.
pub const PROJECTION_REGROW_FACTOR: f64 = 0.95;

/// A relaid lattice with more than this times the patches its growth
/// budget allows is laid once more at a larger h ([`lay_out_grown`]).
pub const OVERSHOOT: f64 = 1.25;

/// Layouts an overshooting round lays at most to land near its budget
/// under [`ConvertOptions::field_adapt()`] ([`lay_out_grown`]).
pub const OVERSHOOT_PASSES: usize = 3;

/// The factor on h of another try when a refined sizing's lattice tore
/// ([`fit_field`]): a small change that lays another lattice.
pub const TORN_RETRY_FACTOR: f64 = 0.95;

/// A patch is refined when its RMS is above this share of `--max-error`
/// (the lattice does not land exactly on h, and the patches refined pull
/// the whole surface's RMS down only in their share of the area).
pub const LOCAL_TARGET: f64 = 0.8;

/// A patch is coarsened when its RMS is below this share of the local
/// target (by the h⁴ model, a patch at a sixteenth of it may grow 2×; the
/// cap below keeps the step small because the fitted error of a grown
/// patch is not its model's).
pub const COARSEN_BELOW: f64 = 1.0 / 16.0;

/// Factor on the patch-count growth the h⁴ rule allows per pass
/// ([`Sizes::refine`]): the lattice lands below its predicted count
/// (0.55–0.95 of it measured).
pub const FIELD_MARGIN: f64 = 1.1;

/// Rounds go on while the fitted limit surface leaves more than this share
/// of M′'s area unprojectable, % (issue 40's acceptance: ≤ 0.1 % of M's
/// area, measured by `report.json` on M).
pub const UNPROJECTABLE_PERCENT: f64 = 0.1;

/// The factor on h under a patch with unprojectable vertices (a patch
/// larger than the M-fitmap's radius there folds over M′; Fitmaps §3.1.3:
/// F_M is the largest radius that projects, and the sizes step down the
/// same way, about a factor 1.4 per step in area).
pub const UNPROJECTABLE_REFINE: f64 = 0.7;

/// The growth in predicted patches one pass may take when projectability
/// alone asks for refinement (the error's own budget is below 1.1 then).
pub const UNPROJECTABLE_GROWTH: f64 = 1.3;

/// Whether M′'s vertices reached only on a sheet facing against the limit
/// normal ([`Reach::Thin`], a thin part the limit crossed; issue 37) count
/// as unprojectable, so that they refine their patches by
/// [`UNPROJECTABLE_REFINE`] and keep the rounds going. Off: measured worse
/// at the defaults (docs/status.md, Field-aligned layout, 2026-12-05 thin
/// parts): homer RMS D 0.285 → 0.535‰, cheburashka 0.235 → 1.197‰. With it
/// off the thin area is only measured (`layout_thin_percent`).
pub const THIN_REFINES: bool = false;

/// With [`ConvertOptions::field_adapt()`] and `--max-error` rounds: the
/// share of the limit's area whose samples the displacement cannot carry
/// onto M′ ([`super::thin::uncarried_area`]) above which a round fails
/// projectability, %, its patches' uncarried area counted as unprojectable
/// (so they are refined by [`UNPROJECTABLE_REFINE`]). Off (infinite) by
/// default; `SUBDFIT_FIELD_ADAPT_CARRY` sets it. ADAPT's high-D results
/// had 3–11× the switch-off layout's uncarried displacement samples
/// (docs/status.md session 20, adapt2: homer τ 10 % 1.2 % against 0.38 %,
/// gargoyle τ 10 % 0.72 % against 0.064 %); the bound is measured in
/// session 22 (adaptcure).
pub const ADAPT_CARRY_PERCENT: f64 = f64::INFINITY;

/// The switch that sets [`ADAPT_CARRY_PERCENT`] (e.g. `0.5`).
pub const ADAPT_CARRY_ENV: &str = "SUBDFIT_FIELD_ADAPT_CARRY";

/// The switch that sets the field layout's fits' iterations
/// ([`fit_iterations`]).
pub const FIT_ITERS_ENV: &str = "SUBDFIT_FIELD_FIT_ITERS";

/// `fit` with [`FIT_ITERS_ENV`]'s iterations (at least 1) when `field`
/// (the field layout's pipeline) and the switch is set; `fit` unchanged
/// otherwise. Session 24 (issue 40's single draw): spot at 85's fit was
/// still gaining 2.4 % RMS per iteration at its eighth (7.06 → 6.89‰) and
/// its RMS L missed the bar by 0.05 %.
pub fn fit_iterations(fit: crate::fit::FitOptions, field: bool) -> crate::fit::FitOptions {
    match crate::switches::parsed::<usize>(FIT_ITERS_ENV) {
        Some(n) if field => fit.with_max_iterations(n.max(1)),
        _ => fit,
    }
}

/// The field layout's fit options for `objective` ([`fit_iterations`]).
pub fn field_fit_options(objective: crate::fit::Objective) -> crate::fit::FitOptions {
    fit_iterations(
        crate::fit::FitOptions::default().with_objective(objective),
        true,
    )
}

/// The uncarried-area bound of the rounds (%): with `adapt` (the rounds
/// follow the first sizing, [`following`]) and the switch set; `None`
/// otherwise, and then nothing is measured (the bytes are the switch's
/// off).
fn carry_bound(adapt: bool) -> Option<f64> {
    let b = crate::switches::number(ADAPT_CARRY_ENV, ADAPT_CARRY_PERCENT);
    (adapt && b.is_finite() && b >= 0.0).then_some(b)
}

/// The share a round's judged unprojectable share `u` (%) is ranked by
/// when its uncarried area `carry` (%) is measured against `bound`: the
/// larger of `u` and `carry` scaled so that it crosses
/// [`UNPROJECTABLE_PERCENT`] exactly at the bound ([`Kept`]: a round over
/// either fails projectability and ranks by how far).
fn with_carry(u: Option<f64>, carry: Option<f64>, bound: Option<f64>) -> Option<f64> {
    match (carry, bound) {
        (Some(c), Some(b)) => {
            let scaled = UNPROJECTABLE_PERCENT * c / b.max(f64::MIN_POSITIVE);
            Some(u.unwrap_or(0.0).max(scaled))
        }
        _ => u,
    }
}

/// The uncarried limit area of `control` against the layout mesh (M′)
/// added to `m`'s patches ([`add_uncarried`]); its share of the limit, %.
fn carried_into(
    timer: &mut StageTimer,
    layout_mesh: &TriMesh,
    control: &ControlMesh,
    m: &mut Measured,
) -> Result<f64> {
    let lost = timer.run("field refinement", || {
        let c = crate::raycast::bvh::BvhCaster::shared(layout_mesh)?;
        super::thin::uncarried_area(layout_mesh, &*c, control)
    })?;
    add_uncarried(m, &lost.per_face);
    Ok(lost.percent)
}

/// Adds each patch's uncarried limit area (`per_face`,
/// [`super::thin::uncarried_area`]) to its unprojectable area in `m`.
fn add_uncarried(m: &mut Measured, per_face: &[f64]) {
    for p in &mut m.per_patch {
        p.unprojectable += per_face.get(p.face as usize).copied().unwrap_or(0.0);
    }
}

/// The largest factor on h per pass, down and up.
pub const MAX_REFINE: f64 = 0.5;
pub const MAX_COARSEN: f64 = 1.25;

/// One fitted field layout (`report.json`'s `field_layout.rounds`); the
/// default is the record with nothing measured, which each stage fills in.
#[derive(Clone, Debug, Default, Serialize, serde::Deserialize)]
pub struct FieldRound {
    /// `--faces`-like target the round's sizing aimed at (`None`: the
    /// Fitmap's own sizes).
    pub target_faces: Option<usize>,
    pub faces: usize,
    pub irregular_vertices: usize,
    /// The fit's own RMS distance, ‰ of the diagonal.
    pub fit_rms_permille: f64,
    /// With `--max-error`: the RMS distance of M′'s vertices to the fitted
    /// limit surface, ‰ (the direction RMS L measures; module docs).
    pub layout_rms_permille: Option<f64>,
    /// Spearman's ρ between patch radius and 1/F_S on the layout before
    /// its fit ([`sizing::adaptivity_spearman`]; issue 40 asks ≥ 0.6).
    pub adaptivity_spearman: Option<f64>,
    /// With `--max-error`: the share of M′'s area the fitted limit surface
    /// does not project onto, % ([`unprojectable_vertices`]).
    #[serde(default)]
    pub layout_unprojectable_percent: Option<f64>,
    /// With `--max-error`: the share of M′'s area whose vertices the limit
    /// normal reaches only on a sheet facing against it (a thin part the
    /// limit crossed, [`Reach::Thin`]), % (counted in the unprojectable
    /// share only with [`THIN_REFINES`]).
    #[serde(default)]
    pub layout_thin_percent: Option<f64>,
    /// Patches of this round over / far under the local target (module
    /// docs), whose sizes the next round lowers / raises (0 on the last).
    pub patches_refined: usize,
    pub patches_coarsened: usize,
    /// Patches of this round with unprojectable vertices, whose sizes the
    /// next round lowers by [`UNPROJECTABLE_REFINE`] (0 on the last).
    #[serde(default)]
    pub patches_unprojectable: usize,
    /// The factor on the round's sizing its lattice was solved at (below 1
    /// after a torn lattice's global refinements or a regrowth, 1 on the
    /// first round's own sizing).
    #[serde(default)]
    pub size_factor: Option<f64>,
    /// The patches of this round's control mesh split 1 → 4 for the next
    /// round ([`refine_locally`]; `None` when none were, or the next round
    /// was laid out again).
    #[serde(default)]
    pub patches_split: Option<usize>,
    /// With the thin round ([`super::thin`]): the RMS distance from the
    /// fitted limit surface to M′ over its area, ‰ (the round's criterion).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub off_m_permille: Option<f64>,
    /// With the thin round: the patches whose RMS distance to M′ is above
    /// [`super::thin::FAR`] times the surface's, plus those holding
    /// [`super::thin::SHARE`] of the uncarried squared distance.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub patches_off_m: Option<usize>,
    /// With the thin round, and on the `--max-error` bracket's rounds: the
    /// RMS over the limit's area of the distance to M′ at the samples the
    /// displacement cannot carry onto M′, ‰
    /// ([`super::thin::OffM::uncarried`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub uncarried_permille: Option<f64>,
    /// With the thin round, on the first round: the share of the
    /// uncarried squared distance held by the worst one, two and three
    /// patches, D → M then M → D, % ([`super::thin::Concentration`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub uncarried_top_percent: Option<Vec<f64>>,
    /// With the thin rounds' chain, the same estimate taken against M
    /// itself ([`super::thin::on_m`]), ‰.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub uncarried_m_permille: Option<f64>,
    /// With the thin rounds' chain judged by a displacement pass
    /// ([`super::thin::Judge::Displaced`]): that pass's RMS D and RMS L, ‰.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub displaced_permille: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub limit_permille: Option<f64>,
    /// With the thin round's draws (`SUBDFIT_FIELD_THIN_DRAWS`): the
    /// unprojectable share of M's area the displacement pass measured, %,
    /// and on each draw the factor on the round's sizing it was laid at.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub unprojectable_percent: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub thin_draw_scale: Option<f64>,
    /// With [`ADAPT_CARRY_ENV`] under ADAPT: the share of the limit's area
    /// whose samples the displacement cannot carry onto M′, %
    /// ([`super::thin::uncarried_area`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub uncarried_area_percent: Option<f64>,
    /// With the thin round, on its own round, and on the bracket's rounds:
    /// whether it was kept.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub kept: Option<bool>,
}

/// `report.json`'s record of the field layout: the first layout's figures
/// and every round fitted.
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
pub struct FieldRecord {
    pub first: FieldStats,
    pub rounds: Vec<FieldRound>,
    /// With [`ConvertOptions::field_adapt()`] and a bound: the switch-off layout
    /// laid beside the adaptive one and which was kept
    /// ([`super::adapt`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub adapt_check: Option<super::adapt::AdaptCheck>,
}

/// Fits `control` (the field layout's first mesh) and, with `max_error`,
/// lays the field out again while the fit misses it (module docs).
#[allow(clippy::too_many_arguments)]
pub fn fit_field(
    run: &mut Run<'_, '_>,
    opts: &ConvertOptions,
    control: ControlMesh,
    relayout: &FieldRelayout,
    po: &PipelineOptions,
    fitmap: Fitmap,
    max_error: Option<f64>,
    record: impl Fn(&[FieldRound]) -> super::FittedRun,
) -> Result<Converted> {
    let mut timer = run.take_timer();
    let (mesh, caster) = relayout.fit_target(run.mesh(), run.caster.as_ref());
    let mut rounds: Vec<FieldRound> = Vec::new();
    let (mut control, mut target) = (control, opts.target_faces);
    let fo = FieldOptions::for_convert(opts.target_faces, opts.field_adapt);
    // The sizes the first layout was laid out at (recomputed: the sizing
    // is cheap and deterministic), refined in place round by round.
    let mut sizes: Option<Sizes> = None;
    // The best fit so far by its own RMS: a finer layout that fits worse
    // (or a sizing that did not grow the mesh) is not kept.
    let mut best: Option<(Kept, crate::fit::Fitted)> = None;
    let mut size_factor = None;
    // The sizing, patches and RMS of the last round refined for a relayout,
    // and whether the back-off round was laid.
    let mut last_refined: Option<Refined> = None;
    let mut backed_off = false;
    // The sizing each round was laid at (`None`: the Fitmap's own, or one
    // not kept), for [`Bracket`].
    let mut laid_h: Vec<Option<Vec<f64>>> = vec![None];
    let follow = following(relayout, &fo, opts, max_error)?;
    let how = Lay::new(relayout, &fo, follow.as_ref());
    loop {
        let faces = control.num_faces();
        let irregular = crate::quad::field::irregular_vertices(&control);
        let spearman = sizing::adaptivity_spearman(&relayout.mesh, &relayout.fitmap, &control)?;
        // The layout as laid (on M′): what a local pass refines.
        let laid = (max_error.is_some() && LOCAL_REFINEMENT).then(|| control.clone());
        let fitted = timer.run("fit", || {
            crate::fit::fit_with_progress(mesh, control, caster, &po.fit, run.progress)
        })?;
        let e = max_error.map(|e| 1000.0 * e).filter(|e| e.is_finite());
        let on = super::thin::OnM {
            mesh,
            caster,
            metrics: &po.metrics,
            memo: None,
        };
        let near = follow.as_ref().map(|_| &on);
        let Judged {
            measured,
            layout_rms,
            unprojectable,
            rms,
            on_m,
            carry,
            near_figures,
        } = Judged::of(&mut timer, &relayout.mesh, &fitted, e, near)?;
        let judged = with_carry(on_m.or(unprojectable), carry, carry_bound(follow.is_some()));
        let fails_projection = judged.is_some_and(|u| u > UNPROJECTABLE_PERCENT);
        let diag = relayout.mesh.bbox_diagonal();
        rounds.push(FieldRound {
            target_faces: target,
            faces,
            irregular_vertices: irregular,
            fit_rms_permille: fitted.report.final_rms_permille,
            layout_rms_permille: layout_rms,
            adaptivity_spearman: spearman,
            layout_unprojectable_percent: unprojectable,
            layout_thin_percent: measured.as_ref().map(|m| m.thin_percent),
            size_factor,
            unprojectable_percent: on_m,
            uncarried_area_percent: carry,
            ..near_figures
        });
        let next = match (e, measured) {
            (Some(e), Some(m))
                if (rms > e || fails_projection) && rounds.len() < FIELD_ROUNDS && !backed_off =>
            {
                let e_abs = e * diag / 1000.0;
                let budget = growth_budget(rms / e, fails_projection);
                let last = rounds.last_mut().expect("pushed above");
                let asks = Asks {
                    e: e_abs,
                    budget,
                    projection: fails_projection,
                    error: rms > e,
                };
                let round = Refining {
                    laid: laid.as_ref(),
                    relayout,
                    fo: &fo,
                    faces,
                };
                round.next(&mut timer, &m, asks, &mut sizes, last)?
            }
            _ => Next::Stop,
        };
        let key = Kept::of(e, rms, judged, faces);
        if best.as_ref().map_or(true, |b| key < b.0) {
            best = Some((key, fitted));
        }
        let next = if key.meets() && !backed_off && matches!(next, Next::Stop) {
            backed_off = true;
            backed_off_round(last_refined.as_ref(), (faces, rms), e, &mut sizes)
        } else {
            next
        };
        target = None;
        if let Next::Relayout(_, _, before) = &next {
            let h = before.clone();
            last_refined = Some(Refined { h, faces, rms });
        }
        let regrow = match e {
            Some(e) if rms <= e => PROJECTION_REGROW_FACTOR,
            _ => REGROW_FACTOR,
        };
        match lay_next(&mut timer, &how, next, faces, &mut sizes, regrow)? {
            Some((c, f)) => {
                (control, size_factor) = (c, f);
                laid_h.push(sizes.as_ref().map(|s| s.h.clone()));
            }
            None => break,
        }
    }
    let best = best.ok_or_else(|| crate::Error::internal("field layout: no round was fitted"))?;
    let memo = super::thin::Evaluations::default();
    let ends = Ends {
        opts,
        relayout,
        po,
        fo: &fo,
        max_error,
        follow: follow.as_ref(),
        memo: &memo,
    };
    let fitted = ends.run(run, &mut timer, &mut rounds, &laid_h, best)?;
    // The rounds judged on M itself (no renumbered M, [`FieldRelayout::fit_target`])
    // evaluated the kept mesh as the tail would: its evaluation is the tail's.
    let evaluated = match relayout.fit_caster {
        None => memo.take(&fitted.control),
        Some(_) => None,
    };
    drop(memo);
    let caster = run.caster.as_ref();
    let at = (timer, record(&rounds), Some(fitmap));
    let known = Known::evaluated(evaluated);
    let mut c = measure_fitted_after(run.input, fitted, caster, po, at, known, run.progress)?;
    add_targets(&mut c, opts.target_faces, max_error, &rounds);
    Ok(c)
}

/// How [`crate::quad::field::field_layout_drawn`] ranks the first
/// layout's draws, lower first: a fit of the draw's control mesh to the
/// layout mesh M′, scored as [`fit_field`] scores a round, by the larger of
/// the fit's RMS (limit → M′) and M′'s own RMS distance to the fitted
/// limit ([`patch_errors`], as RMS L measures it), in ‰ of M′'s diagonal.
/// The fit's RMS alone ranks a lattice that cuts across a thin part first
/// (homer 272, session 14: fit 1.91‰ but RMS L 5.65‰ on the draw it
/// preferred). `SUBDFIT_FIELD_DRAW_SCORE`: `fit` the fit's RMS only,
/// `irr` the irregular count, `unproj` adds the unprojectable share (%)
/// to the default.
pub fn draw_score(
    mesh: &TriMesh,
    caster: &dyn RayCaster,
    fit: &crate::fit::FitOptions,
    laid: &crate::quad::field::FieldLayout,
) -> Result<f64> {
    draw_score_fitted(mesh, caster, fit, laid).map(|(s, _)| s)
}

/// [`draw_score`] and the fit it scored (`None` when it fitted none):
/// `src/convert/layout.rs` keeps the chosen draw's for its carried
/// candidate's first fit ([`super::layout::FieldRelayout::scored_fit`]).
pub fn draw_score_fitted(
    mesh: &TriMesh,
    caster: &dyn RayCaster,
    fit: &crate::fit::FitOptions,
    laid: &crate::quad::field::FieldLayout,
) -> Result<(f64, Option<crate::fit::Fitted>)> {
    let how = crate::switches::text("SUBDFIT_FIELD_DRAW_SCORE").unwrap_or_default();
    if how == "irr" {
        return Ok((laid.stats.irregular_vertices as f64, None));
    }
    let fitted = crate::fit::fit(mesh, laid.control.clone(), caster, fit)?;
    let fit_rms = fitted.report.final_rms_permille;
    if how == "fit" {
        return Ok((fit_rms, Some(fitted)));
    }
    let m = patch_errors(mesh, &fitted.control)?;
    let layout_rms = 1000.0 * m.rms / mesh.bbox_diagonal();
    let score = fit_rms.max(layout_rms)
        + if how == "unproj" {
            m.unprojectable_percent
        } else {
            0.0
        };
    if crate::switches::set("SUBDFIT_FIELD_DRAW_LOG") {
        eprintln!(
            "draw: faces {} irregular {} fit {fit_rms:.4} layout {layout_rms:.4} unprojectable {:.4} % score {score:.4}",
            laid.stats.faces, laid.stats.irregular_vertices, m.unprojectable_percent
        );
    }
    Ok((score, Some(fitted)))
}

/// What follows the rounds of [`fit_field`]: the `--max-error` bracket
/// towards fewer patches ([`Bracket`]) or, at a fixed count, the thin
/// rounds ([`super::thin`]).
struct Ends<'a> {
    opts: &'a ConvertOptions,
    relayout: &'a FieldRelayout,
    po: &'a PipelineOptions,
    fo: &'a FieldOptions,
    max_error: Option<f64>,
    follow: Option<&'a Follow>,
    /// The fixed-count rounds' evaluations ([`super::thin::Evaluations`]).
    memo: &'a super::thin::Evaluations,
}

impl Ends<'_> {
    /// The fit kept after them, from the rounds' `best`.
    fn run(
        &self,
        run: &mut Run<'_, '_>,
        timer: &mut StageTimer,
        rounds: &mut Vec<FieldRound>,
        laid_h: &[Option<Vec<f64>>],
        mut best: (Kept, crate::fit::Fitted),
    ) -> Result<crate::fit::Fitted> {
        let (opts, relayout, po, fo, max_error) =
            (self.opts, self.relayout, self.po, self.fo, self.max_error);
        let (mesh, caster) = relayout.fit_target(run.mesh(), run.caster.as_ref());
        // What the fixed-count rounds below, and the bracket's near misses
        // under the switch, are judged against: M and the pipeline's
        // metrics.
        let on_m = super::thin::OnM {
            mesh,
            caster,
            metrics: &po.metrics,
            // The evaluations are kept for the fixed-count rounds only
            // (the tail takes the kept one's); the bracket's near misses
            // are not.
            memo: opts.target_faces.is_some().then_some(self.memo),
        };
        if let Some(e) = max_error.map(|e| 1000.0 * e).filter(|e| e.is_finite()) {
            if opts.target_faces.is_none() && bracket_enabled() {
                let mut fit = |timer: &mut StageTimer, c: ControlMesh| {
                    timer.run("fit", || {
                        crate::fit::fit_with_progress(mesh, c, caster, &po.fit, run.progress)
                    })
                };
                let b = Bracket {
                    relayout,
                    fo,
                    e,
                    follow: self.follow,
                    on: self.follow.map(|_| &on_m),
                };
                b.run(timer, rounds, laid_h, &mut best, &mut fit)?;
            }
        }
        let (_, mut fitted) = best;
        // At a fixed count, one more layout with lattice size moved to the
        // patches whose limit stands off M′ ([`super::thin`]).
        if opts.target_faces.is_some() && rounds.len() == 1 && super::thin::enabled() {
            let progress = &mut *run.progress;
            let fit = |timer: &mut StageTimer, c: ControlMesh| {
                timer.run("fit", || {
                    crate::fit::fit_with_progress(mesh, c, caster, &po.fit, progress)
                })
            };
            let cx = super::thin::RoundCtx {
                timer: &mut *timer,
                relayout,
                fo,
                rounds: &mut *rounds,
                fit,
                on: &on_m,
            };
            let side = |timer: &mut StageTimer, c: ControlMesh| {
                // The chosen draw's scoring fit when it is this one
                // ([`FieldRelayout::scored_fit`]: same mesh, caster, control
                // and options).
                if let Some(f) = relayout.scored_fit(&c, &po.fit) {
                    return Ok(f);
                }
                timer.run("fit", || crate::fit::fit(mesh, c, caster, &po.fit))
            };
            fitted = super::thin::final_draws(cx, fitted, &side)?;
        }
        // At a fixed count, patches moved to where the limit leaves M′
        // unprojectable ([`super::faces_proj`], off by default).
        if opts.target_faces.is_some() && super::faces_proj::any_enabled() {
            let progress = &mut *run.progress;
            let fit = |timer: &mut StageTimer, c: ControlMesh| {
                timer.run("fit", || {
                    crate::fit::fit_with_progress(mesh, c, caster, &po.fit, progress)
                })
            };
            // Under `SUBDFIT_FIELD_BEST` the rounds are judged on their
            // final figures, as the draws are (`faces_proj` module docs).
            let cx = super::thin::RoundCtx {
                timer: &mut *timer,
                relayout,
                fo,
                rounds: &mut *rounds,
                fit,
                on: &on_m,
            };
            let judged = crate::quad::field::draws::best_enabled();
            fitted = super::faces_proj::rounds_at_count(cx, fitted, judged)?;
        }
        Ok(fitted)
    }
}

/// Whether [`Bracket`] runs: on unless `SUBDFIT_FIELD_BRACKET=0`
/// ([`BRACKET_DEFAULT`]).
pub fn bracket_enabled() -> bool {
    crate::switches::on_off(BRACKET_ENV).unwrap_or(BRACKET_DEFAULT)
}

/// Whether [`Bracket`] runs without [`BRACKET_ENV`].
pub const BRACKET_DEFAULT: bool = true;

/// The environment switch of [`Bracket`]: `0` off, `1` on.
pub const BRACKET_ENV: &str = "SUBDFIT_FIELD_BRACKET";

/// Layouts [`Bracket`] fits at most after the refinement rounds.
pub const BRACKET_LAYOUTS: usize = 2;

/// A bracket layout is tried only if it saves at least this share of the
/// kept round's patches (the lattice lands within ±2 % of a count, and
/// its error is noisy from count to count by more than that).
pub const BRACKET_MIN_SAVING: f64 = 0.06;

/// A bracket layout is kept only if its D estimate (the uncarried RMS
/// of [`super::thin::off_m`], ‰) is at most this times the kept one's
/// plus [`BRACKET_D_SLACK`] ‰.
pub const BRACKET_D_CAP: f64 = 1.25;
pub const BRACKET_D_SLACK: f64 = 0.02;

/// Conciseness after the refinement rounds of `--max-error` (Fitmaps'
/// goal: the fewest patches within the bound, as the greedy layout's
/// search keeps, [`super::search`]). The refinement rounds stop at the
/// first round that meets both bounds, and the field lattice's error
/// falls in steps from round to round (spot at τ 5 %: 180 patches at
/// 6.4‰ → 213 at 2.4‰ against 5‰), so the kept round is often far under
/// the bound. While it is under [`BACK_OFF_BELOW`]·E, the whole field is
/// laid out again at a smaller count on the kept round's own sizing (the
/// global scale α the `--faces` count loop solves for, so the local
/// refinement's shape is kept) and fitted:
///
/// - between the largest round below it that missed and it, at the count
///   where the log-log line through the two reaches [`BACK_OFF_AIM`]·E
///   (the geometric mean when the miss was by projectability);
/// - with no such round, at the count the h⁴ model gives for
///   [`BACK_OFF_AIM`]·E (RMS ∝ N⁻², Fitmaps §3.1.2).
///
/// At most [`BRACKET_LAYOUTS`] such layouts; one is kept when it meets
/// both bounds with fewer patches ([`Kept`]) and its D estimate stays
/// within [`BRACKET_D_CAP`] of the kept fit's (`report.json`'s round
/// `uncarried_permille`, `kept`).
struct Bracket<'a> {
    relayout: &'a FieldRelayout,
    fo: &'a FieldOptions,
    /// `--max-error`, ‰.
    e: f64,
    /// With [`ConvertOptions::field_adapt()`]: the first layout's sizing, which
    /// the bracket layouts' sized relaxation follows ([`following`]).
    follow: Option<&'a Follow>,
    /// With the switch, M: a near miss (or pass) of projectability on M′
    /// judged there ([`near_miss_on_m`]), as the rounds judge theirs.
    on: Option<&'a super::thin::OnM<'a>>,
}

impl Bracket<'_> {
    /// With [`carry_bound`]: the bracket layout `control`'s judged share
    /// `u` with its uncarried share on M′ ([`with_carry`]), and that share.
    fn carried(
        &self,
        timer: &mut StageTimer,
        control: &ControlMesh,
        u: Option<f64>,
    ) -> Result<(Option<f64>, Option<f64>)> {
        let Some(bound) = carry_bound(self.follow.is_some()) else {
            return Ok((u, None));
        };
        let mesh = &self.relayout.mesh;
        let lost = timer.run("field refinement", || {
            let c = crate::raycast::bvh::BvhCaster::shared(mesh)?;
            super::thin::uncarried_area(mesh, &*c, control)
        })?;
        let carry = Some(lost.percent);
        Ok((with_carry(u, carry, Some(bound)), carry))
    }

    fn run(
        &self,
        timer: &mut StageTimer,
        rounds: &mut Vec<FieldRound>,
        laid_h: &[Option<Vec<f64>>],
        best: &mut (Kept, crate::fit::Fitted),
        fit: &mut impl FnMut(&mut StageTimer, ControlMesh) -> Result<crate::fit::Fitted>,
    ) -> Result<()> {
        // The sizing of the round a bracket layout scales: the kept one
        // from the refinement rounds (the bracket rounds reuse it).
        let kept = rounds
            .iter()
            .zip(laid_h)
            .filter(|(r, _)| round_meets(self.e, r))
            .min_by_key(|(r, _)| r.faces);
        let kept_faces = kept.map_or(0, |(r, _)| r.faces);
        let mut kept_rho = kept.and_then(|(r, _)| r.adaptivity_spearman);
        let h = match kept.and_then(|(_, h)| h.clone()) {
            Some(h) => h,
            None => Sizes::new(&self.relayout.mesh, &self.relayout.fitmap, self.fo)?.h,
        };
        // The D estimate of the kept fit ([`super::thin::off_m`]): a
        // bracket layout that raises it by more than [`BRACKET_D_CAP`] is
        // not kept (measured: cheburashka at τ 10 %, 486 → 422 patches,
        // RMS D 0.22 → 0.64‰ without this test).
        let mesh = &self.relayout.mesh;
        let permille = 1000.0 / mesh.bbox_diagonal();
        let caster = crate::raycast::bvh::BvhCaster::shared(mesh)?;
        let mut kept_d = timer
            .run("field refinement", || {
                super::thin::off_m(mesh, &caster, &best.1.control)
            })?
            .uncarried
            * permille;
        for _ in 0..BRACKET_LAYOUTS {
            let Some(n) = bracket_count(self.e, rounds) else {
                break;
            };
            // With the switch a bracket layout is deterministic in its
            // count: one not kept would be laid and fitted again as it was
            // (bunny and homer at τ 1 %, session 17).
            let repeat = rounds
                .iter()
                .any(|r| r.kept.is_some() && r.target_faces == Some(n));
            if self.follow.is_some() && repeat {
                break;
            }
            let fo = self.fo.clone().with_target_faces(Some(n));
            let (prep, mesh, fitmap) = (
                &self.relayout.prepared,
                &self.relayout.mesh,
                &self.relayout.fitmap,
            );
            // With the switch, the kept round's sizing × √(kept / n) (the
            // count goes as h⁻², Fitmaps §3.1.2) laid once as the first
            // layout is, without `--faces`' count passes and the
            // cleanup's trimming to the count: measured on the gargoyle
            // at τ 1 %, the counted bracket layouts fell to ρ 0.43–0.53
            // from the first layout's 0.62 (docs/status.md, session 17).
            let laid = timer.run("field layout", || match self.follow {
                Some(f) => {
                    let lay = |s: f64| {
                        crate::quad::field::field_layout_counted_following(
                            prep,
                            mesh,
                            fitmap,
                            scaled(&h, s),
                            self.fo,
                            f,
                        )
                    };
                    let landed = crate::quad::field::lay_near_count(
                        lay,
                        (1.0, kept_faces),
                        n,
                        BRACKET_COUNT_PASSES,
                    )?;
                    landed
                        .map(|(l, _)| l)
                        .ok_or_else(|| crate::Error::internal("field bracket: no layout laid"))
                }
                None => {
                    crate::quad::field::field_layout_counted(prep, mesh, fitmap, h.clone(), &fo)
                }
            })?;
            let control = laid.control;
            let faces = control.num_faces();
            let irregular = crate::quad::field::irregular_vertices(&control);
            let spearman =
                sizing::adaptivity_spearman(&self.relayout.mesh, &self.relayout.fitmap, &control)?;
            let fitted = fit(timer, control)?;
            let m = timer.run("field refinement", || {
                patch_errors(&self.relayout.mesh, &fitted.control)
            })?;
            let diag = self.relayout.mesh.bbox_diagonal();
            let layout_rms = 1000.0 * m.rms / diag;
            let rms = fitted.report.final_rms_permille.max(layout_rms);
            let d = timer
                .run("field refinement", || {
                    super::thin::off_m(mesh, &caster, &fitted.control)
                })?
                .uncarried
                * permille;
            let on_m = match self.on {
                Some(on) if rms <= self.e => {
                    near_miss_on_m(timer, on, m.unprojectable_percent, &fitted.control)?
                        .map(|f| f.unprojectable_percent)
                }
                _ => None,
            };
            let u = Some(on_m.unwrap_or(m.unprojectable_percent));
            let (judged, carry) = self.carried(timer, &fitted.control, u)?;
            let key = Kept::of(Some(self.e), rms, judged, faces);
            // With the switch, a bracket layout that loses the kept
            // round's adaptivity is not kept (issue 40: ρ ≥ 0.6; measured,
            // the gargoyle at τ 1 % landed 782 patches at ρ 0.564 and RMS
            // L 2.58‰ against the first layout's 906 at 0.617 and 2.10‰).
            let rho_kept = self.follow.is_none() || bracket_keeps_rho(spearman, kept_rho);
            let kept = key < best.0 && d <= BRACKET_D_CAP * kept_d + BRACKET_D_SLACK && rho_kept;
            rounds.push(FieldRound {
                target_faces: Some(n),
                faces,
                irregular_vertices: irregular,
                fit_rms_permille: fitted.report.final_rms_permille,
                layout_rms_permille: Some(layout_rms),
                adaptivity_spearman: spearman,
                layout_unprojectable_percent: Some(m.unprojectable_percent),
                layout_thin_percent: Some(m.thin_percent),
                size_factor: Some(laid.stats.size_factor),
                uncarried_permille: Some(d),
                unprojectable_percent: on_m,
                uncarried_area_percent: carry,
                kept: Some(kept),
                ..Default::default()
            });
            if kept {
                *best = (key, fitted);
                kept_d = d;
                kept_rho = spearman;
            }
        }
        Ok(())
    }
}

/// A round's RMS as the rounds judge it (the fit's and M′'s, the larger).
fn round_rms(r: &FieldRound) -> f64 {
    r.fit_rms_permille.max(r.layout_rms_permille.unwrap_or(0.0))
}

/// Whether round `r` meets both bounds (`e` ‰, [`Kept`]); a bracket
/// round not kept for its D estimate counts as a miss.
fn round_meets(e: f64, r: &FieldRound) -> bool {
    // A near miss on M′ judged on M ([`near_miss_on_m`]) by M's share.
    let u = r.unprojectable_percent.or(r.layout_unprojectable_percent);
    let u = with_carry(u, r.uncarried_area_percent, carry_bound(true));
    let key = Kept::of(Some(e), round_rms(r), u, r.faces);
    key.meets() && r.kept != Some(false)
}

/// Whether a bracket layout at ρ `r` may be kept after one at `kept`
/// ([`BRACKET_RHO_SLACK`]); without either ρ, it may.
fn bracket_keeps_rho(r: Option<f64>, kept: Option<f64>) -> bool {
    match (r, kept) {
        (Some(r), Some(k)) => r >= k - BRACKET_RHO_SLACK,
        _ => true,
    }
}

/// A near miss's unprojectable share of M, when its RMS D is at most
/// `share` of its RMS L ([`NEAR_D_SHARE`]; infinite: any); `None`: it is
/// judged on M′.
fn near_judged_on_m(f: &crate::quad::field::draws::Final, share: f64) -> Option<f64> {
    let carried = share.is_infinite() || f.displaced_permille <= share * f.limit_permille;
    carried.then_some(f.unprojectable_percent)
}

/// Under [`ConvertOptions::field_adapt()`], a bracket layout is kept only if its
/// ρ (patch radius against 1/F_S) is at least the kept round's minus this.
pub const BRACKET_RHO_SLACK: f64 = 0.03;

/// Layouts [`crate::quad::field::lay_near_count`] lays at most for one
/// bracket count.
pub const BRACKET_COUNT_PASSES: usize = 4;

/// `h` times `s`.
fn scaled(h: &[f64], s: f64) -> Vec<f64> {
    h.iter().map(|x| x * s).collect()
}

/// The count of the next [`Bracket`] layout (its docs) for the bound `e`
/// ‰, `None` when the fewest-patch round meeting both bounds is near the
/// bound, or no count saves [`BRACKET_MIN_SAVING`] of its patches over
/// the largest miss below it.
fn bracket_count(e: f64, rounds: &[FieldRound]) -> Option<usize> {
    let pass = rounds
        .iter()
        .filter(|r| round_meets(e, r))
        .min_by_key(|r| r.faces)?;
    let (n1, r1) = (pass.faces as f64, round_rms(pass));
    if r1 > BACK_OFF_BELOW * e {
        return None;
    }
    let aim = BACK_OFF_AIM * e;
    let miss = rounds
        .iter()
        .filter(|r| r.faces < pass.faces && !round_meets(e, r))
        .max_by_key(|r| r.faces);
    let (n, floor) = match miss {
        Some(m) => {
            let (n0, r0) = (m.faces as f64, round_rms(m));
            let by_error = m
                .layout_unprojectable_percent
                .map_or(true, |u| u <= UNPROJECTABLE_PERCENT);
            let p = (r1 / r0).ln() / (n1 / n0).ln();
            let n = if by_error && r0 > e && p < -0.5 {
                n0 * (aim / r0).powf(1.0 / p)
            } else {
                (n0 * n1).sqrt()
            };
            (n, n0 * 1.03)
        }
        None => (n1 * (r1 / aim).sqrt(), 0.0),
    };
    let n = n.max(floor);
    (n.is_finite() && n < (1.0 - BRACKET_MIN_SAVING) * n1).then_some(n.round() as usize)
}

/// `report.json`'s targets for a field conversion: `--max-error` when it
/// is finite, else `--faces` when given.
fn add_targets(
    c: &mut Converted,
    target_faces: Option<usize>,
    max_error: Option<f64>,
    rounds: &[FieldRound],
) {
    let rms_l = c.report.accuracy.limit.rms_permille;
    if let Some(e) = max_error.filter(|e| e.is_finite()) {
        let kept = c.report.control.faces;
        c.report
            .add_target(max_error_target(1000.0 * e, rms_l, kept, rounds));
    }
    if let Some(n) = target_faces.filter(|_| max_error.is_none()) {
        c.report.add_target(faces_target(n, c.report.control.faces));
    }
}

/// A round that met both bounds after a failing one, far under the bound
/// and with many more patches, overshot: one round between the two
/// sizings follows ([`back_off`]), kept if it meets them with fewer
/// patches (the rounds stop after it either way). [`Next::Stop`] when
/// there is no such pair; `sizes` is taken either way (no round refines
/// after a meeting one).
fn backed_off_round(
    prev: Option<&Refined>,
    (faces, rms): (usize, f64),
    e: Option<f64>,
    sizes: &mut Option<Sizes>,
) -> Next {
    let (Some(prev), Some(e)) = (prev, e) else {
        return Next::Stop;
    };
    match (sizes.take(), back_off(prev, (faces, rms), e)) {
        (Some(mut s), Some((ratio, allowed))) => {
            s.h = s.interpolate(&prev.h, ratio);
            Next::BackOff(s, prev.faces, allowed)
        }
        _ => Next::Stop,
    }
}

/// The control mesh of the round after one of `faces` patches, and the
/// factor on its sizing it was laid at (`None` for a local pass); `None`
/// when the rounds stop (`next` is [`Next::Stop`], or no grown lattice).
/// A relayout leaves its sizing in `sizes` for the next refinement and
/// regrows by `regrow` ([`lay_out_grown`]); a back-off round must land
/// below `faces`.
fn lay_next(
    timer: &mut StageTimer,
    how: &Lay<'_>,
    next: Next,
    faces: usize,
    sizes: &mut Option<Sizes>,
    regrow: f64,
) -> Result<Option<(ControlMesh, Option<f64>)>> {
    Ok(match next {
        Next::Stop => None,
        Next::Local(c) => Some((c, None)),
        Next::Relayout(mut s, allowed, _) => {
            let grown = lay_out_grown(timer, how, &mut s, (faces, allowed), regrow)?;
            *sizes = Some(s);
            grown.map(|(c, f)| (c, Some(f)))
        }
        Next::BackOff(mut s, floor, allowed) => {
            let counts = (floor, allowed);
            let grown = lay_out_grown(timer, how, &mut s, counts, REGROW_FACTOR)?;
            grown
                .filter(|(c, _)| c.num_faces() < faces)
                .map(|(c, f)| (c, Some(f)))
        }
    })
}

/// How [`lay_next`] lays a round: on the layout mesh with the field's
/// options, and the sizing the sized relaxation follows ([`following`]).
struct Lay<'a> {
    relayout: &'a FieldRelayout,
    fo: &'a FieldOptions,
    follow: Option<&'a Follow>,
}

/// With [`ConvertOptions::field_adapt()`] at the natural size (its sized
/// relaxation on): the first layout's sizing and α, so that the
/// `--max-error` rounds' and bracket's layouts relax towards the first
/// layout's aim times their own local factors
/// ([`crate::quad::field::extract::SizedRelaxPlan::following`]). Without
/// it the rounds' lattices follow only their graded sizings: measured at
/// the default `--max-error` (session 16) the bunny's kept round fell to
/// ρ 0.44 and the gargoyle's bracket layouts to 0.43–0.53, from 0.64 and
/// 0.62 on the first layouts. `None` otherwise (main's layouts).
fn following(
    relayout: &FieldRelayout,
    fo: &FieldOptions,
    opts: &ConvertOptions,
    max_error: Option<f64>,
) -> Result<Option<Follow>> {
    let bound = max_error.is_some_and(|e| e.is_finite());
    if !opts.field_adapt || !bound || opts.target_faces.is_some() || fo.sized_relax.is_none() {
        return Ok(None);
    }
    let surf = Surface::new(&relayout.mesh)?;
    let (base, alpha, ..) = sizing::sizing_for(&surf, &relayout.mesh, &relayout.fitmap, fo)?;
    Ok(Some(Follow { base, alpha }))
}

/// One fitted round's figures against the bounds ([`fit_field`]).
struct Judged {
    /// With a bound, the layout mesh's own distance to the fitted limit
    /// surface too (M′ → limit, as RMS L measures it; the fit's RMS is
    /// limit → M and misses parts of M no patch reaches).
    measured: Option<Measured>,
    /// Its RMS, ‰, and unprojectable share of M′, %.
    layout_rms: Option<f64>,
    unprojectable: Option<f64>,
    /// The larger of the fit's RMS and M′'s, ‰.
    rms: f64,
    /// A near miss of projectability judged on M ([`near_miss_on_m`])
    /// and passing [`NEAR_D_SHARE`].
    on_m: Option<f64>,
    /// The near miss's RMS D and RMS L on M, for the round's record.
    near_figures: FieldRound,
    /// With `near` and [`carry_bound`]: the limit's uncarried share, %,
    /// its area added to the patches of `measured` ([`carried_into`]).
    carry: Option<f64>,
}

impl Judged {
    /// `fitted` measured on `layout_mesh` (M′) under the bound `e` ‰, and
    /// with `near` (the switch's M), a near miss judged on M.
    fn of(
        timer: &mut StageTimer,
        layout_mesh: &TriMesh,
        fitted: &crate::fit::Fitted,
        e: Option<f64>,
        near: Option<&super::thin::OnM<'_>>,
    ) -> Result<Judged> {
        let mut measured = match e {
            Some(_) => Some(timer.run("field refinement", || {
                patch_errors(layout_mesh, &fitted.control)
            })?),
            None => None,
        };
        let carry = match (measured.as_mut(), carry_bound(near.is_some())) {
            (Some(m), Some(_)) => Some(carried_into(timer, layout_mesh, &fitted.control, m)?),
            _ => None,
        };
        let diag = layout_mesh.bbox_diagonal();
        let layout_rms = measured.as_ref().map(|m| 1000.0 * m.rms / diag);
        let unprojectable = measured.as_ref().map(|m| m.unprojectable_percent);
        let rms = fitted
            .report
            .final_rms_permille
            .max(layout_rms.unwrap_or(0.0));
        let f = match (near, e, unprojectable) {
            (Some(on), Some(e), Some(u)) if rms <= e => {
                near_miss_on_m(timer, on, u, &fitted.control)?
            }
            _ => None,
        };
        // A near miss is judged on M only if the displacement carries the
        // limit onto M there ([`NEAR_D_SHARE`]); otherwise on M′, as any
        // round is.
        let share = crate::switches::number(NEAR_D_ENV, NEAR_D_SHARE);
        let on_m = f.as_ref().and_then(|f| near_judged_on_m(f, share));
        let near_figures = FieldRound {
            displaced_permille: f.as_ref().map(|f| f.displaced_permille),
            limit_permille: f.as_ref().map(|f| f.limit_permille),
            ..Default::default()
        };
        Ok(Judged {
            measured,
            layout_rms,
            unprojectable,
            rms,
            on_m,
            near_figures,
            carry,
        })
    }
}

/// A round within the error bound whose limit leaves at most this times
/// [`UNPROJECTABLE_PERCENT`] of M′ unprojectable is judged on M instead
/// ([`near_miss_on_m`]).
pub const NEAR_MISS: f64 = 1.5;

/// ... and one that leaves at least [`UNPROJECTABLE_PERCENT`] / this of
/// M′ unprojectable: M′'s per-vertex proxy errs on both sides
/// (cheburashka at τ 10 % with the switch kept a round at 0.066 % of M′
/// that left 0.105 % of M unprojectable, docs/status.md session 17).
pub const NEAR_PASS: f64 = 2.0;

/// A refinement round's near miss may be judged on M only if its RMS D is
/// at most this share of its RMS L (the pipeline's, [`near_miss_on_m`]):
/// M's unprojectable share alone does not see a limit the displacement
/// does not carry onto M. Off (infinite) by default: measured with the
/// switch at 0.15 (session 19), the gargoyle at τ 10 %'s near miss (757
/// patches, 0.072 % of M, RMS D 0.604 = 0.16 L) was refined to 863 at D
/// 0.454, and cheburashka at τ 1 %'s (546, D 0.528 = 0.28 L) to 650 at D
/// 0.404: 14–19 % more patches, D still above 1.05× the switch-off
/// layout's (0.246, 1.076 at 705 and 446 patches).
pub const NEAR_D_SHARE: f64 = f64::INFINITY;

/// The switch that sets [`NEAR_D_SHARE`] (e.g. `0.15`) for a measurement.
pub const NEAR_D_ENV: &str = "SUBDFIT_FIELD_NEAR_D";

/// With [`ConvertOptions::field_adapt()`]: the pipeline's figures on M (its
/// displacement and metrics, as `report.json` measures them; the
/// unprojectable share of M's area is issue 40's acceptance) of a round whose share of M′ `u` is within
/// [`NEAR_PASS`] and [`NEAR_MISS`] of [`UNPROJECTABLE_PERCENT`]; `None`
/// otherwise.
/// M′'s test is a per-vertex proxy (module docs) and a round that misses
/// it by a hair is refined and laid out again: the bunny at τ 1 %, first
/// layout 445 patches at 0.1013 % of M′ (0.024 % of M), went through four
/// more rounds to 702 patches, ρ 0.64 → 0.44 (session 16).
fn near_miss_on_m(
    timer: &mut StageTimer,
    on: &super::thin::OnM<'_>,
    u: f64,
    control: &ControlMesh,
) -> Result<Option<crate::quad::field::draws::Final>> {
    if !(UNPROJECTABLE_PERCENT / NEAR_PASS..=NEAR_MISS * UNPROJECTABLE_PERCENT).contains(&u) {
        return Ok(None);
    }
    let f = timer.run("field refinement", || {
        super::thin::final_figures(on, control)
    })?;
    Ok(Some(f))
}

impl<'a> Lay<'a> {
    fn new(relayout: &'a FieldRelayout, fo: &'a FieldOptions, follow: Option<&'a Follow>) -> Self {
        Lay {
            relayout,
            fo,
            follow,
        }
    }
}

/// A round of [`fit_field`] that missed the bound, deciding what follows
/// it: the local pass on the layout as laid when it is on
/// ([`LOCAL_REFINEMENT`]), else the sizing refined for a relayout.
struct Refining<'a> {
    laid: Option<&'a ControlMesh>,
    relayout: &'a FieldRelayout,
    fo: &'a FieldOptions,
    faces: usize,
}

impl Refining<'_> {
    fn next(
        &self,
        timer: &mut StageTimer,
        m: &Measured,
        asks: Asks,
        sizes: &mut Option<Sizes>,
        last: &mut FieldRound,
    ) -> Result<Next> {
        let local = match self.laid {
            Some(laid) => timer.run("field refinement", || {
                refine_locally(laid, &self.relayout.mesh, &m.per_patch, asks)
            })?,
            None => Local::NotQuad,
        };
        Ok(match local {
            Local::Split(c, split) => {
                last.patches_refined = split.refined;
                last.patches_unprojectable = split.unprojectable;
                last.patches_split = Some(split.split);
                Next::Local(*c)
            }
            Local::Nothing => Next::Stop,
            Local::NotQuad => {
                let mut s = match sizes.take() {
                    Some(s) => s,
                    None => Sizes::new(&self.relayout.mesh, &self.relayout.fitmap, self.fo)?,
                };
                let before = s.h.clone();
                let (up, down, unproj) = s.refine(&m.per_patch, asks, self.fo.gradation);
                (last.patches_refined, last.patches_coarsened) = (up, down);
                last.patches_unprojectable = unproj;
                let allowed = (asks.budget * self.faces as f64).round() as usize;
                Next::Relayout(s, allowed, before)
            }
        })
    }
}

/// What follows a fitted round in [`fit_field`].
enum Next {
    Stop,
    /// The round's fitted control mesh refined locally ([`refine_locally`]).
    Local(ControlMesh),
    /// The whole lattice laid out again on a refined sizing, with the
    /// patch count its budget allows, and the sizing before the refinement
    /// (the round's own, for a [`back_off`] round).
    Relayout(Sizes, usize, Vec<f64>),
    /// A sizing between a failing round's and the meeting round after it
    /// ([`back_off`]), laid with at least the failing round's patches and
    /// at most about the second count.
    BackOff(Sizes, usize, usize),
}

/// A round refined for a relayout (its sizing before the refinement).
struct Refined {
    h: Vec<f64>,
    faces: usize,
    rms: f64,
}

/// How [`fit_field`] ranks its rounds, lowest kept: first the rounds that
/// meet both the error bound and [`UNPROJECTABLE_PERCENT`], by fewest
/// patches (the rounds are there to meet the bound, and every patch more
/// is an irregular vertex and fit cost more); then those that meet
/// projectability, by RMS; then the rest by their unprojectable share of
/// M′ (by RMS before, homer at τ 1 % kept its 405-patch round at 0.26 %
/// over a 426-patch one at 0.12 %, and ended 0.25 % unprojectable on M).
#[derive(Clone, Copy, Debug, PartialEq, PartialOrd)]
struct Kept(u8, f64);

impl Kept {
    fn of(e: Option<f64>, rms: f64, unprojectable: Option<f64>, faces: usize) -> Kept {
        let fails_projection = unprojectable.is_some_and(|u| u > UNPROJECTABLE_PERCENT);
        match (fails_projection, e.map_or(true, |e| rms <= e)) {
            (false, true) => Kept(0, faces as f64),
            (false, false) => Kept(1, rms),
            (true, _) => Kept(2, unprojectable.unwrap_or(0.0)),
        }
    }

    fn meets(self) -> bool {
        self.0 == 0
    }
}

/// A meeting round far under the bound with many more patches than the
/// failing round refined into it overshot (the lattice's error does not
/// follow the h⁴ model from round to round: spot at τ 5 % went 180
/// patches at 6.4‰ → 213 at 2.4‰ against a 5‰ bound): the patch count
/// where the RMS reaches [`BACK_OFF_AIM`]·E, interpolated log-log between
/// the two rounds (the h⁴ model's RMS ∝ N⁻² when they agree with it), and
/// the factor on the patch count of the meeting round's sizing it asks
/// for. `None` when the meeting round is near the bound or the count would
/// be within [`BACK_OFF_MIN_SAVING`] of its own.
fn back_off(prev: &Refined, (faces, rms): (usize, f64), e: f64) -> Option<(f64, usize)> {
    let (n0, n1) = (prev.faces as f64, faces as f64);
    if rms > BACK_OFF_BELOW * e || n1 <= n0 || prev.rms <= e {
        return None;
    }
    // RMS = a Nᵖ through both rounds; p < 0 when the finer one fits better.
    let p = (rms / prev.rms).ln() / (n1 / n0).ln();
    let n = if p < -0.5 {
        n0 * (BACK_OFF_AIM * e / prev.rms).powf(1.0 / p)
    } else {
        n0 * (prev.rms / e).sqrt()
    };
    let n = n.max(n0 * 1.05);
    (n < (1.0 - BACK_OFF_MIN_SAVING) * n1).then_some((n / n1, n.round() as usize))
}

/// A meeting round is backed off from ([`back_off`]) when its RMS is below
/// this share of the bound.
pub const BACK_OFF_BELOW: f64 = 0.7;

/// The share of the bound a back-off round aims its RMS at (the lattice
/// lands off its predicted count and error by ±20 % measured).
pub const BACK_OFF_AIM: f64 = 0.8;

/// A back-off is tried only if it saves at least this share of patches.
pub const BACK_OFF_MIN_SAVING: f64 = 0.15;

/// What a round that missed the bounds asks of [`refine_locally`].
#[derive(Clone, Copy, Debug)]
struct Asks {
    /// `--max-error` in units of M′.
    e: f64,
    /// [`growth_budget`]'s factor on the patch count.
    budget: f64,
    /// More than [`UNPROJECTABLE_PERCENT`] of M′ is unprojectable.
    projection: bool,
    /// The RMS is above the bound.
    error: bool,
}

/// [`refine_locally`]'s outcome.
enum Local {
    /// The control mesh is not pure quad (or has creases).
    NotQuad,
    /// No patch asked for refinement.
    Nothing,
    Split(Box<ControlMesh>, SplitCounts),
}

/// Patches that asked for refinement by their error and by projectability,
/// and the patches split for them.
#[derive(Clone, Copy, Debug)]
struct SplitCounts {
    refined: usize,
    unprojectable: usize,
    split: usize,
}

/// The local pass of `--max-error` (module docs): the round's layout
/// `control` (on M′, as laid) with its failing patches split 1 → 4 and
/// conforming transitions around them ([`crate::quad::field::refine`]),
/// every other quad and vertex kept, the new vertices moved onto
/// `layout_mesh` (M′).
///
/// A patch above the local target t = [`LOCAL_TARGET`]·E is weighted by
/// its share of the excess squared error, `area (rms² − t²) / t²` (a
/// split halves h, so by the h⁴ model its error falls 16×, Fitmaps
/// §3.1.2); when projectability fails, a patch carrying unprojectable
/// area is weighted by that area. Each kind's weights are normalised to
/// sum to 1, so neither bound crowds the other out. The patches are
/// taken by weight, as many as keep the faces added (bisected on the
/// split itself) within the [`growth_budget`] of the patch count, at
/// least one.
fn refine_locally(
    control: &ControlMesh,
    layout_mesh: &TriMesh,
    per_patch: &[PatchError],
    asks: Asks,
) -> Result<Local> {
    use crate::quad::field::refine;
    if !refine::refinable(control) {
        return Ok(Local::NotQuad);
    }
    let t = LOCAL_TARGET * asks.e;
    let mut weight = vec![0.0; control.num_faces()];
    let (mut refined, mut unprojectable) = (0, 0);
    for (kind, on) in [(0, asks.error), (1, asks.projection)] {
        let w = |p: &PatchError| match kind {
            0 if p.rms > t => p.area * (p.rms * p.rms - t * t) / (t * t),
            1 => p.unprojectable,
            _ => 0.0,
        };
        let sum: f64 = per_patch.iter().map(w).sum();
        if !on || sum <= 0.0 {
            continue;
        }
        for p in per_patch.iter().filter(|p| w(p) > 0.0) {
            weight[p.face as usize] += w(p) / sum;
            if kind == 0 {
                refined += 1;
            } else {
                unprojectable += 1;
            }
        }
    }
    let mut order: Vec<usize> = (0..weight.len()).filter(|&f| weight[f] > 0.0).collect();
    if order.is_empty() {
        return Ok(Local::Nothing);
    }
    order.sort_by(|&a, &b| weight[b].total_cmp(&weight[a]).then(a.cmp(&b)));
    let faces = control.num_faces();
    let max_added = ((asks.budget - 1.0).max(0.0) * faces as f64).round() as usize;
    let refine_first = |n: usize| -> Result<ControlMesh> {
        let mut marked = vec![false; faces];
        order[..n].iter().for_each(|&f| marked[f] = true);
        refine::split(control, &refine::split_edges(control, &marked)?)
    };
    // The most patches (a prefix of `order`) whose split stays in budget.
    let (mut lo, mut hi) = (1, order.len());
    let mut best = refine_first(1)?;
    while lo < hi {
        let mid = (lo + hi).div_ceil(2);
        let c = refine_first(mid)?;
        if c.num_faces() - faces <= max_added {
            (lo, best) = (mid, c);
        } else {
            hi = mid - 1;
        }
    }
    // The new vertices onto M′, where the layout's own vertices are: the
    // refit then starts as every layout's fit does. (Refining the fitted
    // control mesh instead, its new vertices at the control polygon's
    // midpoints, was measured first: the fit's outlier rule, set by the
    // first round's median distance, which a fitted start makes tiny,
    // dropped a fifth of the samples around the new patches, and spot
    // ended at RMS L 13.2‰ with a 106‰ spike.)
    let first_new = control.num_vertices();
    let mut positions = best.positions().to_vec();
    let caster = crate::raycast::bvh::BvhCaster::shared(layout_mesh)?;
    let snapped = caster.closest_points(&positions[first_new..], f64::INFINITY)?;
    for (p, c) in positions[first_new..].iter_mut().zip(snapped) {
        if let Some(c) = c {
            *p = c.point;
        }
    }
    best.set_positions(positions)?;
    let counts = SplitCounts {
        refined,
        unprojectable,
        split: lo,
    };
    Ok(Local::Split(Box::new(best), counts))
}

/// A refined sizing whose lattice did not grow the mesh (measured on
/// spot at 56 patches: the lattice of a coarse field settles on
/// another count by its own rounding) is laid out again at
/// `regrow` times h ([`REGROW_FACTOR`] or [`PROJECTION_REGROW_FACTOR`]),
/// at most [`REGROW`] times, before the
/// rounds give up (refining by the same errors again overshot:
/// spot 56 → 323 patches, 15.5‰ → 1.35‰ against a 5‰ bound).
///
/// A lattice torn by M's topology is refined globally inside the
/// layout (`size_factor` < 1: ×0.8 per retry, measured on homer
/// 230 → 1069 patches at 0.64), which undoes the local refinement:
/// the same sizes are then laid out again at [`TORN_RETRY_FACTOR`]
/// (another lattice of nearly the same sizes), and the first
/// untorn lattice that grew is kept, else the smallest that grew; an
/// untorn one above [`OVERSHOOT`] times the `allowed` count is laid once
/// more at a larger h. Returns the kept layout and the factor on `s.h` it was solved at;
/// `s.h` is left at the scale laid out.
fn lay_out_grown(
    timer: &mut StageTimer,
    how: &Lay<'_>,
    s: &mut Sizes,
    (faces, allowed): (usize, usize),
    regrow: f64,
) -> Result<Option<(ControlMesh, f64)>> {
    let mut grown: Option<(ControlMesh, f64, f64)> = None;
    let mut scale = 1.0;
    let mut lay = |scale: f64| {
        let h: Vec<f64> = s.h.iter().map(|x| x * scale).collect();
        let r = how.relayout;
        timer.run("field layout", || {
            field_layout_refined_following(&r.prepared, &r.mesh, &r.fitmap, &h, how.fo, how.follow)
        })
    };
    for _ in 0..=REGROW {
        let laid = lay(scale)?;
        let n = laid.control.num_faces();
        if n <= faces {
            scale *= regrow;
            continue;
        }
        let torn = laid.stats.size_factor < 1.0;
        let f = laid.stats.size_factor * scale;
        if !torn || grown.as_ref().map_or(true, |g| n < g.0.num_faces()) {
            grown = Some((laid.control, f, scale));
        }
        if !torn {
            break;
        }
        scale *= TORN_RETRY_FACTOR;
    }
    // An untorn lattice far above the growth budget (the lattice's count
    // follows the sizing's prediction loosely, measured: homer at τ 5 %
    // went 275 → 624 patches, 1.75× what its budget of 1.3× allowed) is laid
    // once more at h scaled by √(count / allowed) (the count goes as
    // h⁻²), and kept if it still grew and is untorn and smaller.
    if let Some((c, f, sc)) = &grown {
        let n = c.num_faces();
        if *f >= *sc && n as f64 > OVERSHOOT * allowed as f64 && how.follow.is_some() {
            // With the switch, the count searched for as the bracket's
            // is ([`crate::quad::field::lay_near_count`]): homer at τ 1 %
            // went from 345 patches (predicted 566) to 668 (predicted 608,
            // 1.5× its budget's 449), the one retry at √(668 / 449) = 1.22
            // fell to 276, below the round it grows, and the 668 were
            // kept (190 irregular vertices); the search lands 381 at 1.055.
            let (sc, passes) = (*sc, OVERSHOOT_PASSES);
            let landed = crate::quad::field::lay_near_count(&mut lay, (sc, n), allowed, passes)?;
            if let Some((laid, retry)) = landed {
                let m = laid.control.num_faces();
                if m > faces && m < n && laid.stats.size_factor >= 1.0 {
                    grown = Some((laid.control, retry, retry));
                }
            }
        } else if *f >= *sc && n as f64 > OVERSHOOT * allowed as f64 {
            let retry = sc * (n as f64 / allowed.max(1) as f64).sqrt();
            let laid = lay(retry)?;
            let m = laid.control.num_faces();
            if m > faces && m < n && laid.stats.size_factor >= 1.0 {
                grown = Some((laid.control, retry, retry));
            }
        }
    }
    if let Some((_, _, scale)) = &grown {
        for x in &mut s.h {
            *x *= scale;
        }
    }
    Ok(grown.map(|(c, f, _)| (c, f)))
}

/// The sizing field of the field layout on M′, refined by
/// [`Sizes::refine`] (module docs).
pub(super) struct Sizes {
    pub(super) h: Vec<f64>,
    /// The M-fitmap's cap `β √2 F_M` per vertex: coarsening stops there.
    cap: Vec<f64>,
    pub(super) surf: Surface,
}

impl Sizes {
    pub(super) fn new(mesh: &TriMesh, fitmap: &Fitmap, fo: &FieldOptions) -> Result<Sizes> {
        let surf = Surface::new(mesh)?;
        let (h, ..) = sizing::sizing_for(&surf, mesh, fitmap, fo)?;
        let (_, hm) = sizing::fitmap_limits(mesh, fitmap, fo.s_fitmap_scale)?;
        let cap = hm.iter().map(|x| fo.m_fitmap_scale * x).collect();
        Ok(Sizes { h, cap, surf })
    }

    /// The sizing `prev^(1−s) · h^s` between a coarser round's `prev` and
    /// this one, with s bisected so that its predicted patches are `ratio`
    /// times this one's ([`back_off`]; both graded, so their geometric
    /// mean keeps the slope bound of the grading within their own).
    fn interpolate(&self, prev: &[f64], ratio: f64) -> Vec<f64> {
        let at = |s: f64| -> Vec<f64> {
            self.h
                .iter()
                .zip(prev)
                .map(|(h, p)| p.powf(1.0 - s) * h.powf(s))
                .collect()
        };
        let now = sizing::predicted_faces(&self.surf, &self.h);
        let (mut lo, mut hi) = (0.0, 1.0);
        for _ in 0..30 {
            let mid = 0.5 * (lo + hi);
            if sizing::predicted_faces(&self.surf, &at(mid)) > ratio * now {
                hi = mid;
            } else {
                lo = mid;
            }
        }
        at(lo)
    }

    /// Scales h under each patch by its error (`per_patch` from
    /// [`patch_errors`]) against the bound `asks.e` (units of M′) and by
    /// [`UNPROJECTABLE_REFINE`] where it leaves vertices unprojectable,
    /// within `asks.budget` times the predicted patches ([`growth_budget`]),
    /// grades it with `gamma`; the patches refined and coarsened by the
    /// error, and refined for projectability (module docs).
    ///
    /// A round that met the error bound and missed only projectability
    /// refines only its unprojectable patches: refining the patches above
    /// the local target too (they are there at any RMS) grew cheburashka
    /// at the defaults from 313 patches at 3.0‰ to 545 over three rounds
    /// that projectability alone kept going (107 irregular vertices).
    fn refine(
        &mut self,
        per_patch: &[PatchError],
        asks: Asks,
        gamma: f64,
    ) -> (usize, usize, usize) {
        let (budget, t) = (asks.budget, LOCAL_TARGET * asks.e);
        let mut factor = vec![f64::INFINITY; self.h.len()];
        let (mut up, mut down, mut unprojectable) = (0, 0, 0);
        for p in per_patch {
            let rms = p.rms;
            let mut f = if !asks.error {
                1.0
            } else if rms > t {
                up += 1;
                (t / rms).powf(0.25).max(MAX_REFINE)
            } else if rms < COARSEN_BELOW * t {
                down += 1;
                (t / rms.max(f64::MIN_POSITIVE)).powf(0.25).min(MAX_COARSEN)
            } else {
                1.0
            };
            if p.unprojectable > 0.0 {
                unprojectable += 1;
                f = f.min(UNPROJECTABLE_REFINE);
            }
            for &v in &p.vertices {
                factor[v as usize] = f;
            }
        }
        for f in &mut factor {
            if !f.is_finite() {
                *f = 1.0;
            }
        }
        // The local factors decide where; the h⁴ model's global rule (the
        // whole mesh at RMS `rms` asks for `(rms / e)^½` times the patches)
        // bounds how much, with [`FIELD_MARGIN`]: measured on spot, the
        // local factors alone overshot (80 → 145 → 231 patches, RMS L from
        // 14.7‰ to 1.5‰ against a 5‰ bound) because a few badly fitted
        // lattice patches dominate the RMS and are fixed by any
        // refinement. So the factors are raised to the power s ∈ (0, 1]
        // (bisected) that keeps the predicted count within that budget.
        let before = sizing::predicted_faces(&self.surf, &self.h);
        let sized = |s: f64| -> Vec<f64> {
            let mut h: Vec<f64> = self
                .h
                .iter()
                .zip(&factor)
                .zip(&self.cap)
                .map(|((h, f), cap)| {
                    let f = f.powf(s);
                    if f > 1.0 {
                        (h * f).min(cap.max(*h))
                    } else {
                        h * f
                    }
                })
                .collect();
            sizing::grade(&self.surf, &mut h, gamma);
            for x in &mut h {
                *x = x.max(self.surf.mean_edge);
            }
            h
        };
        let grows = |h: &[f64]| sizing::predicted_faces(&self.surf, h) / before;
        let mut h = sized(1.0);
        if grows(&h) > budget {
            let (mut lo, mut hi) = (0.0, 1.0);
            for _ in 0..20 {
                let mid = 0.5 * (lo + hi);
                if grows(&sized(mid)) > budget {
                    hi = mid;
                } else {
                    lo = mid;
                }
            }
            h = sized(lo);
        }
        self.h = h;
        (up, down, unprojectable)
    }
}

/// The growth in predicted patches one refinement may take: the h⁴ rule's
/// `(rms / E)^½` with [`FIELD_MARGIN`] for a fit `over` = rms / E times
/// the bound (the field's own error model, [`Sizes::refine`]), at least
/// [`UNPROJECTABLE_GROWTH`] when projectability asks for refinement.
fn growth_budget(over: f64, fails_projection: bool) -> f64 {
    let by_error = over.sqrt().max(1.0) * FIELD_MARGIN;
    if fails_projection {
        by_error.max(UNPROJECTABLE_GROWTH)
    } else {
        by_error
    }
}

/// Per patch (control face) of a fitted `control`: the area-weighted RMS
/// distance from the vertices of `mesh` nearest to it to its limit
/// surface, those vertices, and the area of them the patch does not
/// project onto (module docs); also the whole mesh's RMS (units of `mesh`)
/// and unprojectable share of its area. Measured from `mesh` to the limit
/// surface, as RMS L is, so a part of M that no patch reaches (a horn the
/// layout cut across) counts where the fit's own samples, taken on the
/// patches, do not see it. The limit surface is a grid of `k × k` cells
/// per patch (k from [`CELLS_PER_VERTEX`]).
pub(super) fn patch_errors(mesh: &TriMesh, control: &ControlMesh) -> Result<Measured> {
    let k = grid_cells(mesh, control);
    let (surface, tri_face, locs, evaluator) = limit_grid(control, k)?;
    let caster = crate::raycast::bvh::BvhCaster::new(&surface)?;
    let nearest = caster.closest_points(&mesh.positions, f64::INFINITY)?;
    let missed =
        unprojectable_vertices(mesh, control, evaluator.as_ref(), &surface, &locs, &nearest)?;
    let areas = crate::report::vertex_areas(mesh);
    let n = tri_face.iter().map(|&f| f as usize + 1).max().unwrap_or(0);
    let mut sum = vec![PatchError::default(); n];
    for (f, s) in sum.iter_mut().enumerate() {
        s.face = f as u32;
    }
    let (mut all, mut area, mut lost, mut thin) = (0.0, 0.0, 0.0, 0.0);
    for (v, c) in nearest.iter().enumerate() {
        let Some(c) = c else { continue };
        let a = areas[v];
        let s = &mut sum[tri_face[c.triangle as usize] as usize];
        s.rms += a * c.distance * c.distance;
        s.area += a;
        s.vertices.push(v as u32);
        all += a * c.distance * c.distance;
        area += a;
        if missed[v] == Reach::Missed || (missed[v] == Reach::Thin && THIN_REFINES) {
            s.unprojectable += a;
            s.unprojectable_at += a * mesh.positions[v];
            lost += a;
        }
        if missed[v] == Reach::Thin {
            thin += a;
        }
    }
    let per_patch = sum
        .into_iter()
        .filter(|s| s.area > 0.0)
        .map(|mut s| {
            s.rms = (s.rms / s.area).sqrt();
            s
        })
        .collect();
    let area = area.max(f64::MIN_POSITIVE);
    Ok(Measured {
        per_patch,
        rms: (all / area).sqrt(),
        unprojectable_percent: 100.0 * lost / area,
        thin_percent: 100.0 * thin / area,
    })
}

/// The cells per side of each patch's grid on `control`'s limit surface
/// measured against `mesh` (about [`CELLS_PER_VERTEX`] cells per vertex of
/// `mesh`, 4 to 16 per side).
pub(super) fn grid_cells(mesh: &TriMesh, control: &ControlMesh) -> usize {
    let patches = control.num_patches();
    ((CELLS_PER_VERTEX * mesh.positions.len() as f64 / patches.max(1) as f64).sqrt() as usize)
        .clamp(4, 16)
}

/// [`limit_grid`]'s grid mesh, face per triangle, locations and evaluator.
pub(super) type LimitGrid = (
    TriMesh,
    Vec<u32>,
    Vec<crate::subdiv::SurfaceLocation>,
    Box<dyn crate::subdiv::LimitEvaluator>,
);

/// The fitted limit surface of `control` as a grid of `k × k` cells per
/// patch (sub-patches of a non-quad face apart): the grid as a triangle
/// mesh, the control face of each of its triangles, each grid vertex's
/// surface location, and the evaluator ([`patch_errors`],
/// [`super::thin`]).
pub(super) fn limit_grid(control: &ControlMesh, k: usize) -> Result<LimitGrid> {
    use crate::subdiv::{make_evaluator, Backend, EvalOptions, SurfaceLocation};
    let mut locs = Vec::new();
    let mut tri_face = Vec::new();
    let mut tris = Vec::new();
    for f in control.faces() {
        let subs = control.face_patches(f);
        for sub in 0..subs as u16 {
            let base = locs.len() as u32;
            for j in 0..=k {
                for i in 0..=k {
                    let (u, v) = (i as f64 / k as f64, j as f64 / k as f64);
                    locs.push(SurfaceLocation { face: f, sub, u, v });
                }
            }
            let at = |i: usize, j: usize| base + (j * (k + 1) + i) as u32;
            for j in 0..k {
                for i in 0..k {
                    tris.push([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
                    tris.push([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
                    tri_face.extend([f.0, f.0]);
                }
            }
        }
    }
    let evaluator = make_evaluator(Backend::Osd, control, &EvalOptions::default())?;
    let limit = evaluator.evaluate(control.positions(), &locs)?;
    let surface = TriMesh {
        positions: limit.iter().map(|p| p.position).collect(),
        triangles: tris,
    };
    Ok((surface, tri_face, locs, evaluator))
}

/// Projectability of `mesh`'s vertices from the fitted limit surface: the
/// M-fitmap's test (Fitmaps §3.1.3: a point of M is reached when the normal
/// projection φ from the surface lands on it) as `report.json`'s
/// unprojectable area measures it on M (`crate::report`), here on the
/// layout mesh's vertices so that it can be attributed to patches: each
/// vertex's nearest point on the limit grid `surface` (`nearest`, its
/// parameters interpolated from the grid's `locs`) is evaluated exactly,
/// the line along its normal is cast against `mesh`, and the vertex is
/// missed when the nearest hit is farther from it than `mesh`'s mean edge;
/// a hit near it on a sheet facing against the limit normal makes it
/// [`Reach::Thin`] ([`faces_with`]).
fn unprojectable_vertices(
    mesh: &TriMesh,
    control: &ControlMesh,
    evaluator: &dyn crate::subdiv::LimitEvaluator,
    surface: &TriMesh,
    locs: &[crate::subdiv::SurfaceLocation],
    nearest: &[Option<crate::raycast::ClosestPoint>],
) -> Result<Vec<Reach>> {
    let mut at = Vec::with_capacity(nearest.len());
    let mut which = Vec::with_capacity(nearest.len());
    for (v, c) in nearest.iter().enumerate() {
        let Some(c) = c else { continue };
        let [a, b, d] = surface.triangles[c.triangle as usize].map(|i| locs[i as usize]);
        let w = 1.0 - c.u - c.v;
        at.push(crate::subdiv::SurfaceLocation {
            u: (w * a.u + c.u * b.u + c.v * d.u).clamp(0.0, 1.0),
            v: (w * a.v + c.u * b.v + c.v * d.v).clamp(0.0, 1.0),
            ..a
        });
        which.push(v);
    }
    let exact = evaluator.evaluate(control.positions(), &at)?;
    let m_caster = crate::raycast::bvh::BvhCaster::shared(mesh)?;
    let max_dist = crate::project::default_max_dist(mesh);
    let (hits, _) = crate::project::project_along_normals(&*m_caster, &exact, max_dist)?;
    // The report's tolerance (M's mean edge), here over the triangles'
    // sides (interior edges counted twice: the same mean on a closed mesh).
    let sides: f64 = (0..mesh.triangles.len())
        .map(|t| {
            let [a, b, c] = mesh.triangle(t);
            (a - b).length() + (b - c).length() + (c - a).length()
        })
        .sum();
    let tol = sides / (3 * mesh.triangles.len()).max(1) as f64;
    let mut missed = vec![Reach::Projects; mesh.positions.len()];
    for ((h, &v), p) in hits.iter().zip(&which).zip(&exact) {
        missed[v] = match h {
            Some(h) if (h.point - mesh.positions[v]).length() <= tol => {
                if faces_with(mesh, h.triangle, p.normal()) {
                    Reach::Projects
                } else {
                    Reach::Thin
                }
            }
            _ => Reach::Missed,
        };
    }
    Ok(missed)
}

/// Whether triangle `t` of `mesh` faces the same way as the limit normal
/// `n` that reached it. A line that lands on a sheet facing against it
/// has crossed a thin part: the limit surface there lies beyond the far
/// sheet (issue 37, `examples/thin_diag.rs`: homer's patch 53, n·n_M =
/// −0.99), so the vertex passes the distance test while the displacement
/// along that normal can only reach the other sheet. Such a vertex is
/// [`Reach::Thin`].
fn faces_with(mesh: &TriMesh, t: u32, n: DVec3) -> bool {
    let [a, b, c] = mesh.triangle(t as usize);
    (b - a).cross(c - a).dot(n) >= 0.0
}

/// How the normal line from a vertex's nearest limit point meets M′
/// ([`unprojectable_vertices`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Reach {
    /// It lands on the vertex, on a sheet facing with the limit normal.
    Projects,
    /// It misses the vertex (Fitmaps §3.1.3's test fails).
    Missed,
    /// It lands on the vertex, on a sheet facing against the limit normal:
    /// the limit crossed a thin part ([`faces_with`]).
    Thin,
}

/// One patch's figures in [`patch_errors`]: its RMS distance, the area of
/// the vertices of M′ nearest to it (and the part it does not project
/// onto), and those vertices.
#[derive(Clone, Debug, Default)]
pub(super) struct PatchError {
    /// The control face.
    pub(super) face: u32,
    pub(super) rms: f64,
    pub(super) area: f64,
    pub(super) unprojectable: f64,
    /// The area-weighted sum of the unprojectable vertices' positions
    /// (over `unprojectable`, their centroid: where a local round,
    /// [`super::faces_local`], draws the lattice in).
    pub(super) unprojectable_at: DVec3,
    pub(super) vertices: Vec<u32>,
}

/// [`patch_errors`]' result.
pub(super) struct Measured {
    pub(super) per_patch: Vec<PatchError>,
    pub(super) rms: f64,
    pub(super) unprojectable_percent: f64,
    /// The share of M′'s area that is [`Reach::Thin`], %.
    pub(super) thin_percent: f64,
}

/// Limit-grid cells per vertex of M′ in [`patch_errors`] (the grid's chord
/// error then stays well below the patches' distance to M′).
const CELLS_PER_VERTEX: f64 = 4.0;

/// `--max-error`'s target for the field layout, judged on the metrics'
/// RMS L.
fn max_error_target(e: f64, rms_l: f64, kept: usize, rounds: &[FieldRound]) -> TargetCheck {
    let faces: Vec<String> = rounds.iter().map(|r| r.faces.to_string()).collect();
    TargetCheck {
        option: "max_error",
        target: format!(
            "RMS L within {e:.3}‰ of the diagonal, the sizing refined where the fit misses it"
        ),
        met: rms_l <= e,
        outcome: format!(
            "{kept} patches kept of {} layout(s) fitted ({}), RMS L {rms_l:.3}‰",
            rounds.len(),
            faces.join(" → ")
        ),
    }
}

/// `--faces N`'s target for the field layout: within ±2 % of `n`.
fn faces_target(n: usize, got: usize) -> TargetCheck {
    TargetCheck {
        option: "faces",
        target: format!("{n} faces ±2 % (--faces {n})"),
        met: (0.98 * n as f64..=1.02 * n as f64).contains(&(got as f64)),
        outcome: format!("{got} faces from the field layout's sizing scale"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The gargoyle at τ 1 % with the switch (session 18): the bracket's
    /// 782 patches at ρ 0.564 are not kept after the first layout's 906
    /// at 0.617 (issue 40 asks ρ ≥ 0.6); a layout within the slack is.
    #[test]
    fn a_bracket_layout_that_loses_adaptivity_is_not_kept() {
        assert!(!bracket_keeps_rho(Some(0.564), Some(0.617)));
        assert!(bracket_keeps_rho(Some(0.6), Some(0.617)));
        assert!(bracket_keeps_rho(Some(0.7), Some(0.617)));
        assert!(bracket_keeps_rho(None, Some(0.617)));
    }

    /// With the share at 0.15, a near miss whose displacement leaves RMS
    /// D at 0.16 L (the gargoyle at τ 10 %, session 18) is judged on M′,
    /// one at 0.10 L (the bunny at τ 1 %) on M.
    #[test]
    fn a_near_miss_whose_displacement_misses_m_is_judged_on_m_prime() {
        let f = |d: f64, l: f64| crate::quad::field::draws::Final {
            faces: 0,
            irregular_vertices: 0,
            limit_permille: l,
            displaced_permille: d,
            unprojectable_percent: 0.072,
        };
        assert_eq!(near_judged_on_m(&f(0.604, 3.698), 0.15), None);
        assert_eq!(near_judged_on_m(&f(0.204, 2.085), 0.15), Some(0.072));
        // Off by default: any near miss is judged on M.
        assert_eq!(
            near_judged_on_m(&f(0.604, 3.698), NEAR_D_SHARE),
            Some(0.072)
        );
    }

    /// Two rounds on the h⁴ model's curve (RMS ∝ N⁻², Fitmaps §3.1.2):
    /// the back-off count is where that curve reaches [`BACK_OFF_AIM`]·E,
    /// between the two rounds; a meeting round near the bound, or one
    /// after a round that met the error, is not backed off from.
    #[test]
    fn back_off_lands_where_the_error_model_meets_the_aim() {
        let e = 5.0;
        let rms = |n: f64| 8.0 * (100.0 / n).powi(2);
        let prev = Refined {
            h: Vec::new(),
            faces: 100,
            rms: rms(100.0),
        };
        let (ratio, n) = back_off(&prev, (300, rms(300.0)), e).expect("overshot");
        assert!((rms(n as f64) - BACK_OFF_AIM * e).abs() < 0.05 * e, "{n}");
        assert!(n > 100 && n < 300);
        assert!((ratio * 300.0 - n as f64).abs() <= 0.5);
        // Just under the bound: no overshoot to take back.
        assert!(back_off(&prev, (300, 0.9 * e), e).is_none());
        // A previous round within the error (it failed projectability):
        // no count between the two meets the error bound by the model.
        let met = Refined { rms: 4.0, ..prev };
        assert!(back_off(&met, (300, 1.0), e).is_none());
    }

    /// A round as [`bracket_count`] reads it.
    fn round(faces: usize, rms: f64, unprojectable: f64) -> FieldRound {
        FieldRound {
            faces,
            fit_rms_permille: rms,
            layout_rms_permille: Some(rms),
            layout_unprojectable_percent: Some(unprojectable),
            ..Default::default()
        }
    }

    /// The bracket's counts: alone, a meeting round far under the bound
    /// gets the h⁴ model's count for [`BACK_OFF_AIM`]·E (gargoyle at the
    /// defaults: 779 patches at 2.57‰ → 624); after a miss by the error,
    /// the log-log line's count lies between the two rounds and where the
    /// line reaches the aim; after a miss by projectability, the geometric
    /// mean; none near the bound or when it would save < 6 %.
    #[test]
    fn bracket_counts_lie_between_the_miss_and_the_pass() {
        let e = 5.0;
        let n = bracket_count(e, &[round(779, 2.57, 0.03)]).expect("far under");
        assert!(
            (n as f64 - 779.0 * (2.57f64 / 4.0).sqrt()).abs() <= 0.5,
            "{n}"
        );
        // Spot's rounds: 111 at 8.9‰ and 180 at 6.4‰ missed, 213 at
        // 2.4‰ met: the line through (180, 6.4) and (213, 2.4) reaches
        // 4‰ at 195 patches; after 195 met at 3.0‰, the line through
        // (180, 6.4) and (195, 3.0) reaches it at 189, within 6 % of 195.
        let mut spot = vec![
            round(111, 8.9, 0.01),
            round(180, 6.4, 0.0),
            round(213, 2.4, 0.0),
        ];
        assert_eq!(bracket_count(e, &spot), Some(195));
        spot.push(round(195, 3.0, 0.0));
        assert_eq!(bracket_count(e, &spot), None);
        // A flatter line (300 at 6‰ → 400 at 2‰): its count is strictly
        // between and at the aim on the line.
        let two = [round(300, 6.0, 0.0), round(400, 2.0, 0.0)];
        let n = bracket_count(e, &two).expect("saves patches") as f64;
        let p = (2.0f64 / 6.0).ln() / (400.0f64 / 300.0).ln();
        assert!(n > 300.0 && n < 376.0, "{n}");
        assert!((6.0 * (n / 300.0).powf(p) - 4.0).abs() < 0.05, "{n}");
        // A miss by projectability: the geometric mean of the counts.
        let proj = [round(300, 2.0, 0.4), round(400, 2.0, 0.05)];
        assert_eq!(bracket_count(e, &proj), Some(346));
        // The kept round near the bound, or none meeting: nothing to try.
        assert_eq!(bracket_count(e, &[round(300, 3.6, 0.0)]), None);
        assert_eq!(bracket_count(e, &[round(300, 6.0, 0.0)]), None);
        assert_eq!(bracket_count(e, &[round(300, 2.0, 0.2)]), None);
    }

    /// The kept round: meeting both bounds beats everything, and among
    /// those the fewest patches; then projectability by RMS; then the
    /// least unprojectable area.
    #[test]
    fn rounds_are_kept_by_bounds_then_patches() {
        let e = Some(5.0);
        let ok = Some(0.05);
        let k = |rms, u, f| Kept::of(e, rms, u, f);
        assert!(k(4.0, ok, 200) < k(1.0, ok, 250));
        assert!(k(4.9, ok, 900) < k(6.0, ok, 100));
        assert!(k(6.0, ok, 100) < k(1.0, Some(0.2), 100));
        assert!(k(3.0, Some(0.12), 426) < k(2.0, Some(0.26), 405));
        assert!(k(4.0, ok, 200).meets() && !k(1.0, Some(0.2), 10).meets());
    }

    /// A thin slab's two sheets face opposite ways: a limit normal pointing
    /// up faces with the top sheet only, so a line that crossed the slab
    /// and landed on the bottom sheet is told apart (issue 37).
    #[test]
    fn a_line_that_crossed_a_thin_part_lands_on_a_sheet_facing_away() {
        let mesh = TriMesh {
            positions: vec![
                DVec3::new(0.0, 0.0, 0.01),
                DVec3::new(1.0, 0.0, 0.01),
                DVec3::new(0.0, 1.0, 0.01),
                DVec3::new(0.0, 0.0, 0.0),
                DVec3::new(1.0, 0.0, 0.0),
                DVec3::new(0.0, 1.0, 0.0),
            ],
            // Top counter-clockwise seen from above (normal +z), bottom
            // reversed (normal −z): an outward-oriented slab.
            triangles: vec![[0, 1, 2], [3, 5, 4]],
        };
        let up = DVec3::new(0.1, -0.2, 1.0).normalize();
        assert!(faces_with(&mesh, 0, up));
        assert!(!faces_with(&mesh, 1, up));
        assert!(faces_with(&mesh, 1, -up));
    }

    /// The rectangle [0, w] × [0, n] at z = 0, `m` × `m` cells per unit.
    fn sheet(w: usize, n: usize, m: usize) -> TriMesh {
        crate::convert::thin::tests::rectangle(w, n, m, DVec3::ZERO)
    }

    /// The 4 × 4 quad grid on [0, 4]² at height `z` (face 4 j + i is the
    /// patch over [i, i + 1] × [j, j + 1]).
    fn lifted_grid(z: f64) -> ControlMesh {
        let positions = (0..=4)
            .flat_map(|j| (0..=4).map(move |i| DVec3::new(i as f64, j as f64, z)))
            .collect();
        let at = |i: u32, j: u32| j * 5 + i;
        let quads: Vec<[u32; 4]> = (0..4)
            .flat_map(|j| (0..4).map(move |i| (i, j)))
            .map(|(i, j)| [at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1)])
            .collect();
        ControlMesh::from_polygons(positions, &quads).expect("grid")
    }

    /// The faces of `c` whose control polygon's centroid has x below `x`.
    fn faces_left_of(c: &ControlMesh, x: f64) -> usize {
        c.faces()
            .filter(|&f| {
                let xs: Vec<f64> = c
                    .face_vertices(f)
                    .map(|v| c.positions()[v.idx()].x)
                    .collect();
                xs.iter().sum::<f64>() / (xs.len() as f64) < x
            })
            .count()
    }

    /// ADAPT's carry rule (session 22, adaptcure): the limit (the grid
    /// [0, 4]²) 0.1 above M′. Clean: M′ ([-0.5, 4.5]²) lies under the
    /// whole limit, every sample's normal line meets it at its own
    /// distance, the rule adds no area and the local pass is the one
    /// without it. Overhang: M′ ([-0.5, 3.25] × [-0.5, 4.5]) ends under
    /// the last column of patches, whose samples beyond x = 3.25 have no
    /// hit along their normal; the rule puts that uncarried area (about
    /// 3/4 of each patch) on those four patches only, which fails a 0.5 %
    /// bound by itself, and the local pass splits all four while the
    /// patches left of x = 2 are split exactly as without the rule.
    #[test]
    fn the_carry_rule_refines_the_patches_whose_samples_project_nowhere() {
        let control = lifted_grid(0.1);
        let asks = Asks {
            e: 1.0,
            budget: 20.0,
            projection: true,
            error: false,
        };
        let bound = Some(0.5);
        // `w` × 20 cells of 0.25 from (-0.5, -0.5).
        let under = |w: usize| {
            let mut m = sheet(w, 20, 1);
            for p in &mut m.positions {
                *p = DVec3::new(0.25 * p.x - 0.5, 0.25 * p.y - 0.5, 0.0);
            }
            m
        };
        let split = |mesh: &TriMesh, m: &Measured| -> ControlMesh {
            match refine_locally(&control, mesh, &m.per_patch, asks).expect("local") {
                Local::Split(c, _) => *c,
                _ => control.clone(),
            }
        };
        // Clean: M′ reaches past the limit on every side.
        let clean = under(20);
        let caster = crate::raycast::bvh::BvhCaster::new(&clean).expect("caster");
        let lost = super::super::thin::uncarried_area(&clean, &caster, &control).expect("lost");
        assert!(
            lost.per_face.iter().all(|&a| a == 0.0),
            "{:?}",
            lost.per_face
        );
        assert_eq!(lost.percent, 0.0);
        let plain = patch_errors(&clean, &control).expect("measured");
        let mut ruled = patch_errors(&clean, &control).expect("measured");
        add_uncarried(&mut ruled, &lost.per_face);
        let judged = with_carry(Some(ruled.unprojectable_percent), Some(lost.percent), bound);
        assert_eq!(judged, Some(plain.unprojectable_percent));
        let (a, b) = (split(&clean, &plain), split(&clean, &ruled));
        assert_eq!(a.num_faces(), b.num_faces());
        // Overhang: the last column stands past M′'s border.
        let short = under(15);
        let caster = crate::raycast::bvh::BvhCaster::new(&short).expect("caster");
        let lost = super::super::thin::uncarried_area(&short, &caster, &control).expect("lost");
        for j in 0..4 {
            for i in 0..4 {
                let a = lost.per_face[4 * j + i];
                match i {
                    3 => assert!(a > 0.5, "face ({i}, {j}): {a}"),
                    _ => assert_eq!(a, 0.0, "face ({i}, {j})"),
                }
            }
        }
        assert!((15.0..=30.0).contains(&lost.percent), "{}", lost.percent);
        let carry_alone = with_carry(Some(0.0), Some(lost.percent), bound);
        assert!(carry_alone.is_some_and(|u| u > UNPROJECTABLE_PERCENT));
        let plain = patch_errors(&short, &control).expect("measured");
        let on_column = |m: &Measured| -> f64 {
            m.per_patch
                .iter()
                .filter(|p| p.face % 4 == 3)
                .map(|p| p.unprojectable)
                .sum()
        };
        let mut ruled = patch_errors(&short, &control).expect("measured");
        add_uncarried(&mut ruled, &lost.per_face);
        let added = on_column(&ruled) - on_column(&plain);
        assert!(added > 2.0, "{added}");
        let right = |c: &ControlMesh| c.num_faces() - faces_left_of(c, 3.0);
        let (without, with) = (split(&short, &plain), split(&short, &ruled));
        assert!(right(&with) >= 16, "{}", right(&with));
        assert_eq!(faces_left_of(&with, 2.0), faces_left_of(&without, 2.0));
    }

    /// The carry share ranks a round as [`UNPROJECTABLE_PERCENT`] does at
    /// its bound: below it the judged share is unchanged, above it the
    /// round fails projectability; without a bound nothing changes.
    #[test]
    fn the_carry_share_crosses_the_bar_at_its_bound() {
        let u = Some(0.05);
        assert_eq!(with_carry(u, Some(0.2), Some(0.5)), u);
        let over = with_carry(u, Some(0.6), Some(0.5)).expect("judged");
        assert!(over > UNPROJECTABLE_PERCENT, "{over}");
        assert_eq!(with_carry(u, Some(0.6), None), u);
        assert_eq!(with_carry(u, None, Some(0.5)), u);
    }
}
