//! The organic `--max-error E` search: the fewest patches, among the
//! meshes the simplification passed through (§3.3; its natural end and
//! checkpoints 1.06× apart, [`crate::quad::simplify`]), whose fitted limit
//! surface (§3.5) is within RMS `E` of M.

use serde::Serialize;

use crate::analysis::Fitmap;
use crate::error::{Error, Result};
use crate::fit::FitOptions;
use crate::mesh::ControlMesh;
use crate::report::TargetCheck;

use super::run::Run;
use super::tail::{measure_fitted_after, Converted, Known, PipelineOptions};

/// How many intermediate meshes the simplification keeps for the organic
/// `max_error` search: 40 at ratio 1.06 reach 10× the natural end's count.
pub(super) const ERROR_SEARCH_CHECKPOINTS: usize = 40;

/// The fit and measurement of the fewest-faces candidate within
/// `max_error` (a fraction of the diagonal): `end` is the simplification's
/// natural end, `checkpoints` its larger intermediate meshes, `extra(search)`
/// the run's options for `report.json` with the search's record.
pub(super) fn fit_fewest_within(
    run: &mut Run<'_, '_>,
    (end, checkpoints): (ControlMesh, Vec<ControlMesh>),
    max_error: f64,
    po: &PipelineOptions,
    fitmap: &Fitmap,
    extra: impl Fn(Option<&ErrorSearch>) -> super::FittedRun,
) -> Result<Converted> {
    let (input, caster, timer) = (run.input, run.caster.as_ref(), &mut run.timer);
    let progress = &mut *run.progress;
    let mesh = &input.mesh;
    let e = max_error;
    // The search judges candidates by the fit's own RMS distance; the
    // metrics (M's quadrature points both ways) can read a few % higher
    // (spot: 4.93 vs 5.26‰), so a miss there recalibrates the bound by
    // that ratio and searches on among the larger candidates (at most
    // `ROUNDS` measurements).
    const ROUNDS: usize = 3;
    let mut search = ErrorSearcher::new(end, checkpoints, e);
    let mut bound = search.record.max_error_permille;
    let mut round = 0;
    loop {
        round += 1;
        let (i, fitted) = timer.run("fit", || {
            search.fewest_within(bound, mesh, caster, &po.fit, progress)
        })?;
        let fit_rms = fitted.report.final_rms_permille;
        let e = search.record.max_error_permille;
        let last = round == ROUNDS || i + 1 == search.len();
        // RMS L alone first (the only figure the decision reads, the
        // metrics' own: `report::limit_check`): a candidate it rejects
        // never runs the displacement, D's accuracy and the tessellations;
        // the kept one's measurement reuses it. (A candidate that is not all
        // quads, measured on its refinement, takes the whole measurement.)
        let check = if !super::tail::displaced_on_refinement(&fitted.control, mesh, &po.metrics)
            && !full_measure_each()
        {
            Some(timer.run(LIMIT_CHECK_STAGE, || {
                crate::report::limit_check(mesh, &fitted.control, caster, &po.metrics, progress)
            })?)
        } else {
            None
        };
        if let Some(rms) = check.as_ref().map(|c| c.accuracy().rms_permille) {
            if rms > e && !last {
                bound = next_bound(bound, e, rms, fit_rms);
                continue;
            }
        }
        let at = (
            timer.clone(),
            extra(Some(&search.record)),
            Some(fitmap.clone()),
        );
        let mut c =
            measure_fitted_after(input, fitted, caster, po, at, Known::Check(check), progress)?;
        let rms = c.report.accuracy.limit.rms_permille;
        if rms <= e || last {
            c.report.add_target(search.record.target(rms));
            return Ok(c);
        }
        // The discarded measurement's time stays in the report.
        if let Some(last) = c.report.stages.last() {
            timer.stages.push(crate::report::StageStat {
                stage: "displacement+metrics (max_error check)".into(),
                ..last.clone()
            });
        }
        bound = next_bound(bound, e, rms, fit_rms);
    }
}

/// `SUBDFIT_SEARCH_FULL_MEASURE=1`: every candidate measured in full, as
/// before the L-only check (an experiment switch for measuring the check's
/// saving in one binary; the outputs are the same bytes either way).
fn full_measure_each() -> bool {
    crate::switches::on("SUBDFIT_SEARCH_FULL_MEASURE")
}

/// `report.json`'s stage of each `--max-error` candidate's RMS L check
/// (the kept one's included; its `displacement+metrics` stage then does
/// not measure L again).
pub const LIMIT_CHECK_STAGE: &str = "limit check (max_error)";

/// The next round's bound after a miss by the metrics' RMS L `rms` (‰) of
/// a candidate whose fit RMS was `fit_rms`: below the fit RMS by the
/// metrics' ratio, so that it (and every smaller one) misses.
fn next_bound(bound: f64, e: f64, rms: f64, fit_rms: f64) -> f64 {
    (bound * e / rms).min(fit_rms * (1.0 - 1e-9))
}

/// A whole fit's final RMS over its RMS after round r (r = 0..8; the
/// default nine rounds), measured on bunny at τ = 5 % (default and
/// `--max-error 2e-3`) and gargoyle at 2e-3, where the three agree within
/// 0.05: the count a fit stopped early predicts is taken from its estimated
/// final RMS, as a whole fit's would be.
const FINAL_OVER_ROUND: [f64; 9] = [0.60, 0.76, 0.81, 0.86, 0.90, 0.93, 0.96, 0.98, 1.0];

/// What the organic `max_error` search tried and kept (`report.json`'s
/// `options.run.max_error_search`).
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
pub struct ErrorSearch {
    pub max_error_permille: f64,
    /// `(faces, RMS L ‰ by the fit's own samples)` of every candidate
    /// fitted, in the order tried. A candidate whose fit stopped as soon as
    /// its side of the bound was plain ([`crate::fit::fit_deciding`]) has
    /// the RMS it stopped at: above its final one.
    pub tried: Vec<(usize, f64)>,
    /// Fit rounds run over the whole search (of each fit's kept start; the
    /// kept candidate's full fit included): nine per candidate before fits
    /// stopped once decided.
    pub fit_rounds: usize,
    pub kept_faces: usize,
    /// Faces at the natural end and of the largest candidate.
    pub natural_end_faces: usize,
    pub largest_candidate_faces: usize,
}

impl ErrorSearch {
    /// The target of `report.json`, judged on the metrics' RMS L.
    fn target(&self, rms_l_permille: f64) -> TargetCheck {
        let e = self.max_error_permille;
        TargetCheck {
            option: "max_error",
            target: format!(
                "RMS L within {e:.3}‰ of the diagonal with the fewest patches the simplification passed through"
            ),
            met: rms_l_permille <= e,
            outcome: format!(
                "{} patches (natural end {}, largest candidate {}, {} fitted), RMS L {rms_l_permille:.3}‰",
                self.kept_faces,
                self.natural_end_faces,
                self.largest_candidate_faces,
                self.tried.len()
            ),
        }
    }
}

/// The candidates of the organic `--max-error E` search and their fits:
/// the simplification's natural end and its checkpoints (fewest faces
/// first, each 1.06× the previous; [`crate::quad::simplify`]), each
/// fitted (§3.5) only as far as it takes to tell which side of the bound
/// it ends on ([`crate::fit::fit_deciding`]: most candidates are plain
/// misses or passes after one or two rounds of the nine), a paused fit
/// resumed where a later bound or the keeping needs more (the kept one
/// runs to the end: the fit `fit_with_progress` gives). The meshes are
/// kept (they are small: the search never goes past 10× the natural end's
/// count).
struct ErrorSearcher {
    candidates: Vec<ControlMesh>,
    faces: Vec<usize>,
    /// Each fit, and where it paused (`None`: it ran its whole course).
    fits: Vec<Option<(crate::fit::Fitted, Option<crate::fit::FitState>)>>,
    /// What every candidate's fit asks of M, made by the first one.
    facts: Option<std::sync::Arc<crate::fit::MeshFacts>>,
    record: ErrorSearch,
}

impl ErrorSearcher {
    fn new(end: ControlMesh, checkpoints: Vec<ControlMesh>, max_error: f64) -> ErrorSearcher {
        let candidates: Vec<_> = std::iter::once(end).chain(checkpoints).collect();
        let faces: Vec<usize> = candidates.iter().map(|c| c.num_faces()).collect();
        ErrorSearcher {
            fits: vec![None; faces.len()],
            facts: None,
            record: ErrorSearch {
                max_error_permille: 1e3 * max_error,
                tried: Vec::new(),
                fit_rounds: 0,
                kept_faces: faces[0],
                natural_end_faces: faces[0],
                largest_candidate_faces: *faces.last().unwrap_or(&0),
            },
            candidates,
            faces,
        }
    }
}

impl ErrorSearcher {
    fn len(&self) -> usize {
        self.faces.len()
    }

    /// What candidate `i`'s fit RMS `rms` (‰) would end at in full: itself
    /// for a whole fit, else scaled by [`FINAL_OVER_ROUND`] at the round
    /// of the iterate it kept.
    fn final_estimate(&self, i: usize, rms: f64) -> f64 {
        match &self.fits[i] {
            Some((f, Some(_))) => {
                let r = f.report.best_iteration.min(FINAL_OVER_ROUND.len() - 1);
                rms * FINAL_OVER_ROUND[r]
            }
            _ => rms,
        }
    }

    /// The fit RMS (‰) of candidate `i` as far as `bound` needs it
    /// (`None`: in full), fitting it when no fit so far tells.
    fn rms(
        &mut self,
        i: usize,
        bound: Option<f64>,
        mesh: &crate::mesh::TriMesh,
        caster: &dyn crate::raycast::RayCaster,
        fo: &FitOptions,
        progress: &mut crate::watch::Progress<'_>,
    ) -> Result<f64> {
        if let Some((f, paused)) = &self.fits[i] {
            let rms = f.report.final_rms_permille;
            // A fit that stopped early tells a bound it was not asked
            // about only when it is plainly on one side of it.
            let plain = |b: f64| {
                rms <= b
                    || (f.report.iterations.len() > 1 && rms * crate::fit::DECIDE_MISS_FLOOR > b)
            };
            if paused.is_none() || bound.is_some_and(plain) {
                return Ok(rms);
            }
        }
        let decide = bound.map(|bound_permille| crate::fit::Decide { bound_permille });
        let (resume, before) = match self.fits[i].take() {
            Some((f, p)) => (p, f.report.iterations.len()),
            None => (None, 0),
        };
        let c = self.candidates[i].clone();
        let facts = self
            .facts
            .get_or_insert_with(|| crate::fit::MeshFacts::of(mesh));
        let (f, paused) =
            crate::fit::fit_deciding_with(mesh, facts, c, caster, fo, progress, (decide, resume))?;
        let rms = f.report.final_rms_permille;
        // The kept start's rounds (an open mesh whose loops move runs two).
        self.record.fit_rounds += f.report.iterations.len().saturating_sub(before);
        if before == 0 {
            self.record.tried.push((self.faces[i], rms));
        }
        self.fits[i] = Some((f, paused));
        Ok(rms)
    }

    /// The fewest-faces candidate whose fit RMS is within `bound` ‰ (the
    /// error taken to fall with the count), and its fit. Above the largest
    /// known miss, the count predicted by an error falling as 1 / faces
    /// (between the Fitmap's r⁴ for smooth patches and r² where detail
    /// remains; measured ≈ faces^-0.9 on spot and bunny) is tried first,
    /// then the bracket is bisected: typically 2–4 fits. When the largest
    /// candidate misses too, it is returned (the target reports the miss).
    fn fewest_within(
        &mut self,
        bound: f64,
        mesh: &crate::mesh::TriMesh,
        caster: &dyn crate::raycast::RayCaster,
        fo: &FitOptions,
        progress: &mut crate::watch::Progress<'_>,
    ) -> Result<(usize, crate::fit::Fitted)> {
        let last = self.len() - 1;
        let known = |s: &Self, pass: bool| -> Vec<usize> {
            (0..=last)
                .filter(|&i| {
                    s.fits[i]
                        .as_ref()
                        .is_some_and(|(f, _)| (f.report.final_rms_permille <= bound) == pass)
                })
                .collect()
        };
        let mut lo = known(self, false).into_iter().max();
        let mut best = known(self, true)
            .into_iter()
            .filter(|&i| lo.map_or(true, |l| i > l))
            .min();
        if lo.is_none() && best != Some(0) {
            if self.rms(0, Some(bound), mesh, caster, fo, progress)? <= bound {
                best = Some(0);
            } else {
                lo = Some(0);
            }
        }
        if let Some(mut l) = lo {
            let r = self.rms(l, Some(bound), mesh, caster, fo, progress)?;
            let predicted = self.faces[l] as f64 * self.final_estimate(l, r) / bound;
            let mut next = self
                .faces
                .partition_point(|&n| (n as f64) < predicted)
                .clamp((l + 1).min(last), last);
            while best.map_or(last + 1, |b| b) - l > 1 {
                if self.rms(next, Some(bound), mesh, caster, fo, progress)? <= bound {
                    best = Some(next);
                } else {
                    l = next;
                }
                // Still missing: double the index towards the largest;
                // else bisect the bracket.
                next = match best {
                    None => (2 * l + 1).min(last),
                    Some(b) => (l + b) / 2,
                };
            }
            lo = Some(l);
        }
        let i = best.or(lo).unwrap_or(0);
        self.record.kept_faces = self.faces[i];
        // The kept candidate in full: the fit `fit_with_progress` gives.
        self.rms(i, None, mesh, caster, fo, progress)?;
        // The paused fits are resumed only by a later round (a miss by the
        // metrics): their systems would stay in memory through the
        // measurement, the run's peak, for that rare case.
        for (_, state) in self.fits.iter_mut().flatten() {
            if let Some(s) = state {
                s.release_system();
            }
        }
        let f = self.fits[i]
            .clone()
            .map(|(f, _)| f)
            .ok_or_else(|| Error::internal(format!("max_error search: {i} unfitted")))?;
        Ok((i, f))
    }
}
