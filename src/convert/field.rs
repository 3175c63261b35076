//! The tail of the field-aligned layout (`--layout field`, issue 40): the
//! global fit of [`super::tail`], and organic `--max-error` met by laying
//! the field out again at a finer size instead of fitting a series of
//! simplification checkpoints ([`super::search`]).
//!
//! The rule for the next size: a fitted limit surface's distance to M
//! falls as h⁴ with the patch size h (the Fitmap's own model, E(r) = a r⁴,
//! Fitmaps §3.1.2), and the patch count grows as h⁻²; so a fit at RMS
//! `rms` over a bound `e` asks for `faces · (rms / e)^½` patches, with a
//! margin of [`FIELD_MARGIN`] because the lattice lands below its
//! predicted count (issue 40's measurements: 0.55–0.95 of it). At most
//! [`FIELD_ROUNDS`] layouts are fitted, and fewer when a finer sizing no
//! longer grows the mesh; the one with the lowest fitted RMS is kept, and
//! `report.json`'s target says whether it met the bound.

use serde::Serialize;

use crate::analysis::Fitmap;
use crate::error::Result;
use crate::mesh::ControlMesh;
use crate::quad::field::{field_layout, FieldOptions, FieldStats};
use crate::report::TargetCheck;

use super::layout::FieldRelayout;
use super::options::ConvertOptions;
use super::run::Run;
use super::tail::{measure_fitted, Converted, PipelineOptions};

/// Layouts fitted at most for one `--max-error` (the first included).
pub const FIELD_ROUNDS: usize = 4;

/// Factor on the patch count the h⁴ rule predicts (see the module docs).
pub const FIELD_MARGIN: f64 = 1.1;

/// One fitted field layout (`report.json`'s `field_layout.rounds`).
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
pub struct FieldRound {
    /// `--faces`-like target the round's sizing aimed at (`None`: the
    /// Fitmap's own sizes).
    pub target_faces: Option<usize>,
    pub faces: usize,
    pub irregular_vertices: usize,
    /// The fit's own RMS distance, ‰ of the diagonal.
    pub fit_rms_permille: f64,
}

/// `report.json`'s record of the field layout: the first layout's figures
/// and every round fitted.
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
pub struct FieldRecord {
    pub first: FieldStats,
    pub rounds: Vec<FieldRound>,
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
    let (mesh, caster) = (run.mesh(), run.caster.as_ref());
    let mut rounds: Vec<FieldRound> = Vec::new();
    let (mut control, mut target) = (control, opts.target_faces);
    // The best fit so far by its own RMS: a finer layout that fits worse
    // (or a sizing that did not grow the mesh) is not kept.
    let mut best: Option<crate::fit::Fitted> = None;
    loop {
        let faces = control.num_faces();
        let irregular = crate::quad::field::irregular_vertices(&control);
        let fitted = timer.run("fit", || {
            crate::fit::fit_with_progress(mesh, control, caster, &po.fit, run.progress)
        })?;
        let rms = fitted.report.final_rms_permille;
        rounds.push(FieldRound {
            target_faces: target,
            faces,
            irregular_vertices: irregular,
            fit_rms_permille: rms,
        });
        let better = match &best {
            Some(b) => rms < b.report.final_rms_permille,
            None => true,
        };
        if better {
            best = Some(fitted);
        }
        let Some(e) = max_error.map(|e| 1000.0 * e) else {
            break;
        };
        if rms <= e || rounds.len() >= FIELD_ROUNDS {
            break;
        }
        let next = (faces as f64 * (rms / e).sqrt() * FIELD_MARGIN).ceil() as usize;
        target = Some(next.max(faces + 1));
        let fo = FieldOptions::default().with_target_faces(target);
        let laid = timer.run("field layout", || {
            field_layout(&relayout.mesh, &relayout.fitmap, &fo)
        })?;
        if laid.control.num_faces() <= faces {
            // The sizing could not grow the mesh (the lattice settled at
            // or below the last count): more rounds would repeat it.
            break;
        }
        control = laid.control;
    }
    let fitted = best.ok_or_else(|| crate::Error::internal("field layout: no round was fitted"))?;
    let mut c = measure_fitted(
        run.input,
        fitted,
        caster,
        po,
        timer,
        record(&rounds),
        Some(fitmap),
        run.progress,
    )?;
    let rms_l = c.report.accuracy.limit.rms_permille;
    if let Some(e) = max_error.filter(|e| e.is_finite()) {
        let kept = c.report.control.faces;
        c.report
            .add_target(max_error_target(1000.0 * e, rms_l, kept, &rounds));
    }
    if let Some(n) = opts.target_faces.filter(|_| max_error.is_none()) {
        c.report.add_target(faces_target(n, c.report.control.faces));
    }
    Ok(c)
}

/// `--max-error`'s target for the field layout, judged on the metrics'
/// RMS L.
fn max_error_target(e: f64, rms_l: f64, kept: usize, rounds: &[FieldRound]) -> TargetCheck {
    let faces: Vec<String> = rounds.iter().map(|r| r.faces.to_string()).collect();
    TargetCheck {
        option: "max_error",
        target: format!("RMS L within {e:.3}‰ of the diagonal, the field laid out finer while the fit misses it"),
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
