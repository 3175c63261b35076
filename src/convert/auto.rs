//! `--mode auto`'s second opinion: a combinator over two branches of a
//! conversion. The first (mechanical, when the share of sharp edges chose
//! it) is kept unless it misses its own target or leaves part of M
//! unprojectable; then the second (organic) runs too and the one with the
//! lower RMS distance is kept.

use serde::Serialize;

use crate::error::Result;
use crate::report::Report;

use super::run::Run;
use super::tail::Converted;

/// Runs `first`; when [`second_opinion_reason`] doubts its result, runs
/// `second` with the reason (on a fresh stage timer: `first` took the
/// stages so far) and keeps the better ([`keep_better`]).
pub fn with_second_opinion<'a, 'p>(
    run: &mut Run<'a, 'p>,
    first: impl FnOnce(&mut Run<'a, 'p>) -> Result<Converted>,
    second: impl FnOnce(&mut Run<'a, 'p>, &str) -> Result<Converted>,
) -> Result<Converted> {
    let first = first(run)?;
    let Some(why) = second_opinion_reason(&first.report) else {
        return Ok(first);
    };
    run.take_timer();
    let second = second(run, &why)?;
    Ok(keep_better(first, second, &why))
}

/// Why `--mode auto`'s mechanical result needs the organic one beside it,
/// or `None`: its own target missed, or more than 1 % of M unprojectable
/// (a surface that does not follow M, whatever the per-face figures).
fn second_opinion_reason(r: &Report) -> Option<String> {
    let missed: Vec<&str> = r
        .targets
        .iter()
        .filter(|t| !t.met)
        .map(|t| t.outcome.as_str())
        .collect();
    let unproj = r.projectability.unprojectable_area_percent;
    if !missed.is_empty() {
        Some(format!(
            "the mechanical result missed its target ({})",
            missed.join("; ")
        ))
    } else if unproj > 1.0 {
        Some(format!(
            "the mechanical result leaves {unproj:.2} % of the input unprojectable"
        ))
    } else {
        None
    }
}

/// What `--mode auto`'s second opinion compared and kept: `report.json`'s
/// `options.mode.second_opinion`, and [`Converted::second_opinion`] for
/// hosts (the CLI's note) without reading the JSON back.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SecondOpinion {
    /// Why the mechanical result was doubted.
    pub why: String,
    pub mechanical: Candidate,
    pub organic: Candidate,
    /// `"organic"` or `"mechanical"`.
    pub kept: &'static str,
}

/// One side of a [`SecondOpinion`].
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Candidate {
    /// RMS distance of the limit surface, ‰ of the diagonal.
    pub rms_limit_permille: f64,
    pub unprojectable_area_percent: f64,
    /// Control faces.
    pub faces: usize,
    /// Wall time of its stages.
    pub seconds: f64,
}

impl Candidate {
    fn of(c: &Converted) -> Candidate {
        Candidate {
            rms_limit_permille: c.report.accuracy.limit.rms_permille,
            unprojectable_area_percent: c.report.projectability.unprojectable_area_percent,
            faces: c.report.control.faces,
            seconds: c.report.stages.iter().map(|s| s.seconds).sum::<f64>(),
        }
    }
}

/// The one of two conversions of the same mesh with the lower RMS distance
/// from its limit surface to M (ties: mechanical, the smaller control
/// mesh); its report says what was compared and why.
fn keep_better(mechanical: Converted, organic: Converted, why: &str) -> Converted {
    let (m, o) = (Candidate::of(&mechanical), Candidate::of(&organic));
    let organic_wins = o.rms_limit_permille < m.rms_limit_permille;
    let note = SecondOpinion {
        why: why.to_string(),
        mechanical: m,
        organic: o,
        kept: if organic_wins {
            "organic"
        } else {
            "mechanical"
        },
    };
    let mut kept = if organic_wins { organic } else { mechanical };
    kept.report.options["mode"]["second_opinion"] = serde_json::json!(note);
    kept.second_opinion = Some(note);
    kept
}
