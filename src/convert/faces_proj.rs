//! At a fixed patch count (`--faces N`, `--max-error inf`), rounds that
//! spend patches where the fitted limit surface leaves M′ unprojectable
//! and take them from everywhere else (issue 40, session 15).
//!
//! The Fitmaps guarantee is projectability: every point of M reached by
//! the limit surface's normal lines (Fitmaps §3.1.3, §4). With `--faces N`
//! and `--max-error inf` the `--max-error` rounds of [`super::field`] do not
//! run, so a feature narrower than the patches across it (homer at 272:
//! the two hands and a bump on the head, 0.381 % of the area) stays
//! unprojectable, and no move at the same lattice fixes it.
//!
//! So after the layout's fit (and the thin rounds, [`super::thin`]), when
//! more than [`super::field::UNPROJECTABLE_PERCENT`] of M′'s area is
//! unprojectable ([`super::field::patch_errors`], the M-fitmap's test on
//! M′'s vertices), h is lowered by [`PROJ_REFINE`] on the vertices of M′
//! nearest the patches with unprojectable vertices and, by its square
//! root, on those nearest the patches around them (the ring: the feature
//! is narrower than the patch, and the patch next to it shares its
//! lattice lines). The factors accumulate round by round (at least
//! [`super::thin::MIN_FACTOR`]); each sizing is regraded and scaled back to
//! the first layout's predicted count ([`super::thin::lowered_sizing`]:
//! the patches added there are taken from everywhere else, `∫ dA / h²`),
//! laid out at N with the layout's own count passes, and fitted. At most
//! [`PROJ_ROUNDS`] rounds; a round is kept only within [`COUNT_WINDOW`] of
//! N, when it leaves less unprojectable area than the best so far, and
//! its RMS (the larger of the fit's and M′ → limit) stays within
//! [`L_CAP`] × the incoming result's; the same lattice topology family
//! (the field layout's) is laid every round.
//!
//! Off by default (`SUBDFIT_FACES_PROJ=1` turns it on): measured on the
//! peers' counts, docs/status.md, Field-aligned layout, session 15.

use crate::error::Result;
use crate::fit::Fitted;
use crate::mesh::ControlMesh;
use crate::quad::field::draws;

use super::faces_local::Source;
use super::field::{patch_errors, FieldRound, Measured, UNPROJECTABLE_PERCENT};
use super::thin::{FitFn, RoundCtx, RoundPlan};

/// The switch's environment variable (`1` on).
pub const FACES_PROJ_ENV: &str = "SUBDFIT_FACES_PROJ";

/// Layouts laid and fitted at most after the incoming result. Six, not
/// three: homer 272 (the one table case that runs past round 3) reaches
/// 0.12 % unprojectable on the plain field and 0.04 % with four draws and the
/// guarded cancellation after six rounds, against 0.19 % / no kept round after
/// three; the other cases stop earlier (docs/status.md, session 15).
pub const PROJ_ROUNDS: usize = 6;

/// The factor on h per round on the vertices of M′ nearest a patch with
/// unprojectable vertices (the ring gets its square root). Fitmaps
/// §3.1.3's sizes step by about 1.4 in area; the feature is narrower than
/// the patch across it, so a round takes a larger step than the
/// `--max-error` rounds' [`super::field::UNPROJECTABLE_REFINE`].
pub const PROJ_REFINE: f64 = 0.6;

/// A round is kept only within this share of N (`--faces`' own window).
pub const COUNT_WINDOW: f64 = 0.02;

/// A round is kept only when its RMS (the larger of the fit's and M′ →
/// limit) is within this factor of the incoming result's: projectability
/// first, but not at any cost in RMS L.
pub const L_CAP: f64 = 1.1;

/// The gated tube round's switch: `k > 0` lays one round whose sizes are
/// capped at `k` × the tube thickness ([`crate::quad::field::tube`]) on
/// the M′ vertices under and around the patches a first fit left
/// unprojectable (off by default; [`tube_round_marks`]).
pub const FACES_PROJ_TUBE_ENV: &str = "SUBDFIT_FACES_PROJ_TUBE";

/// Tube rounds laid at most ([`FACES_PROJ_TUBE_ROUNDS_ENV`] sets it).
pub const TUBE_ROUNDS: usize = 1;

/// The tube rounds' count switch.
pub const FACES_PROJ_TUBE_ROUNDS_ENV: &str = "SUBDFIT_FACES_PROJ_TUBE_ROUNDS";

/// The gated tube round's factor k ([`FACES_PROJ_TUBE_ENV`]), `None` off.
pub fn tube_k() -> Option<f64> {
    crate::switches::parsed::<f64>(FACES_PROJ_TUBE_ENV).filter(|x| x.is_finite() && *x > 0.0)
}

/// Whether the projectability rounds run at all: [`enabled`] or the gated
/// tube round ([`tube_k`]).
pub fn any_enabled() -> bool {
    enabled() || tube_k().is_some()
}

/// Whether the rounds run (`SUBDFIT_FACES_PROJ=1`, or
/// `SUBDFIT_FIELD_BEST=1` with `SUBDFIT_FACES_PROJ` unset).
pub fn enabled() -> bool {
    match crate::switches::text(FACES_PROJ_ENV) {
        Some(v) => v == "1",
        None => crate::quad::field::draws::best_enabled(),
    }
}

/// The switch of the judged chain's stop at the bar ([`stop_at_bar`]):
/// `0` lays all [`PROJ_ROUNDS`] (session 16's chain).
pub const FACES_PROJ_STOP_ENV: &str = "SUBDFIT_FACES_PROJ_STOP";

/// Whether the judged rounds (`SUBDFIT_FIELD_BEST`) stop once the round
/// [`draws::choose_final_with`] would keep among those laid so far meets
/// issue 40's unprojectable bar on its final figures: on unless
/// [`FACES_PROJ_STOP_ENV`] is `0`.
///
/// The rounds trade RMS L, RMS D and the irregular count for
/// projectability (module docs), and the incoming result skips them when
/// it meets the bar already; this stops the chain on the same test, taken
/// on the choice so far. Session 21 (issue 40's speed point): homer at
/// 272 laid six rounds and kept the third, the first at the bar
/// (0.096 %, with the lowest RMS L and RMS D of all seven candidates); the
/// three after it (0.46 / 0.28 / 0.94 %) cost 10.5 of its 37.6 CPU s.
pub fn stop_at_bar() -> bool {
    crate::switches::on_off(FACES_PROJ_STOP_ENV).unwrap_or(true)
}

/// Whether the candidate [`draws::choose_final_with`] keeps among
/// `finals` (the incoming result first) meets the unprojectable bar.
pub(super) fn choice_meets_bar(finals: &[draws::Final], n: Option<usize>) -> bool {
    let (i, _) = draws::choose_final_with(finals, n, COUNT_WINDOW, draws::Score::BarsUnguarded);
    finals
        .get(i)
        .is_some_and(|f| f.unprojectable_percent <= draws::UNPROJECTABLE_BAR)
}

/// A fitted round's figures the rounds are judged by.
#[derive(Clone, Copy, Debug)]
struct Judged {
    unprojectable: f64,
    /// The larger of the fit's RMS and M′ → limit, ‰.
    rms: f64,
}

impl Judged {
    fn of(m: &Measured, f: &Fitted, permille: f64) -> Self {
        Self {
            unprojectable: m.unprojectable_percent,
            rms: f.report.final_rms_permille.max(permille * m.rms),
        }
    }

    /// Lower unprojectable share first, then lower RMS; never above
    /// [`L_CAP`] × the incoming result's RMS.
    fn beats(&self, best: &Judged, first: &Judged) -> bool {
        if self.rms > crate::switches::number("SUBDFIT_FACES_PROJ_LCAP", L_CAP) * first.rms {
            return false;
        }
        if self.unprojectable != best.unprojectable {
            return self.unprojectable < best.unprojectable;
        }
        self.rms < best.rms
    }
}

/// Per vertex of M′ (`nv` of them), the factor on h this round asks for:
/// `f` under the patches of `control` with unprojectable vertices, `√f`
/// under the patches sharing a vertex with them, 1 elsewhere.
pub(super) fn marks(control: &ControlMesh, m: &Measured, nv: usize, f: f64) -> (Vec<f64>, usize) {
    let nf = control.num_faces();
    let mut bad = vec![false; nf];
    for p in &m.per_patch {
        if p.unprojectable > 0.0 && (p.face as usize) < nf {
            bad[p.face as usize] = true;
        }
    }
    let mut ring = vec![false; nf];
    for fc in control.faces() {
        if !bad[fc.idx()] {
            continue;
        }
        for v in control.face_vertices(fc) {
            for g in control.vertex_faces(v) {
                ring[g.idx()] = true;
            }
        }
    }
    let mut factor = vec![1.0; nv];
    for p in &m.per_patch {
        let face = p.face as usize;
        let x = match (bad.get(face), ring.get(face)) {
            (Some(true), _) => f,
            (_, Some(true)) => f.sqrt(),
            _ => continue,
        };
        for &v in &p.vertices {
            factor[v as usize] = x;
        }
    }
    (factor, bad.iter().filter(|b| **b).count())
}

/// The gated tube round's sizing inputs (session 26, issue 40: homer's
/// fingers at `--faces 272`): per vertex of M′ (`nv`) the factor on the
/// first layout's h and the cap on h. Session 25's tube cap on every tube
/// reached homer's fingers but spent patches on every tube of every shape
/// (22/32 bars): here it is applied only where the first fit leaves M′
/// unprojectable — the vertices under a patch with unprojectable vertices
/// and under its ring ([`marks`]) — as `caps[v]` = `k · t` where a tube
/// is found there (`tube_caps`, [`crate::quad::field::tube::tube_caps`]),
/// factor 1; the marked vertices with no tube (homer's mouth cavity) get
/// [`marks`]' factor (`f` under the patch, `√f` on its ring) and no cap.
pub(super) fn tube_round_marks(
    control: &ControlMesh,
    m: &Measured,
    tube_caps: &[f64],
    f: f64,
) -> (Vec<f64>, Vec<f64>) {
    let nv = tube_caps.len();
    let (mut factor, _) = marks(control, m, nv, f);
    let mut caps = vec![f64::INFINITY; nv];
    for (v, x) in factor.iter_mut().enumerate() {
        if *x < 1.0 && tube_caps[v].is_finite() {
            caps[v] = tube_caps[v];
            *x = 1.0;
        }
    }
    (factor, caps)
}

/// The rounds (module docs) after the kept fit `first`, each fitted by
/// `fit` and pushed on `rounds`; the best by [`Judged::beats`] is returned
/// (`first` when none beats it or nothing is unprojectable). With `judge`
/// (`SUBDFIT_FIELD_BEST=1`, session 16) the incoming result and every
/// round are measured by the pipeline's own displacement and metrics
/// ([`super::thin::final_figures`]) and the one kept is the one
/// [`draws::choose_final_with`] ranks first by [`draws::Score::BarsUnguarded`]: the
/// M′ test and the RMS cap see neither RMS D nor the irregular count
/// (gargoyle τ 10 % at 421 went from 99 / 3.59‰ / 0.294‰ / 0.105 % to
/// 99 / 3.97‰ / 0.326‰ / 0.069 %, at 402 the irregular count rose 89 → 102).
pub(super) fn rounds_at_count<F: FitFn>(
    cx: RoundCtx<'_, F>,
    first: Fitted,
    judged: bool,
) -> Result<Fitted> {
    let memo = cx.on.memo;
    let kept = rounds_judged(cx, first, judged)?;
    // The rounds not kept hold their evaluations' tessellations.
    if let Some(memo) = memo {
        memo.keep_only(&kept.control);
    }
    Ok(kept)
}

/// Where the rounds' control meshes come from: the thin rounds' plan
/// without the far patches' round (a chain of `max_rounds`, each lowering
/// h under the marks accumulated so far), or, under
/// `SUBDFIT_FACES_PROJ_LOCAL` when the incoming result (`control`, measured
/// `m0`) misses the bar narrowly, first up to
/// [`super::faces_local::ROUNDS`] rounds that move it locally
/// ([`super::faces_local`]), then the plan's rounds left.
fn source(
    timer: &mut crate::report::StageTimer,
    relayout: &super::layout::FieldRelayout,
    fo: &crate::quad::field::FieldOptions,
    (control, m0): (&ControlMesh, Measured),
    max_rounds: usize,
    f: f64,
) -> Result<Source> {
    let nv = relayout.mesh.positions.len();
    let (marked, _) = marks(control, &m0, nv, f);
    Ok(
        match super::faces_local::rounds(m0.unprojectable_percent, max_rounds) {
            Some(local) => Source::Local {
                last: control.clone(),
                m: m0,
                left: local,
                base: None,
                then: Some((marked, max_rounds - local)),
            },
            None => Source::Plan(RoundPlan::laid(
                timer, relayout, fo, None, marked, max_rounds,
            )?),
        },
    )
}

/// The tube caps and the caps so far of the tube rounds.
type TubeCaps = (Vec<f64>, Vec<f64>);

/// The rounds' source, the tube rounds' caps and the incoming result's
/// final figures ([`sources`]).
type Sources = (Source, Option<TubeCaps>, Vec<draws::Final>);

/// The rounds' source after the incoming result (`control`, measured `m0`
/// on M′), with the tube caps under `SUBDFIT_FACES_PROJ_TUBE` and, with
/// `judge`, the incoming result's final figures; `None` when those meet
/// the unprojectable bar (no round).
fn sources(
    timer: &mut crate::report::StageTimer,
    (relayout, fo, judge): (
        &super::layout::FieldRelayout,
        &crate::quad::field::FieldOptions,
        Option<&super::thin::OnM<'_>>,
    ),
    (control, m0): (&ControlMesh, Measured),
    max_rounds: usize,
    f: f64,
) -> Result<Option<Sources>> {
    let final_of = |timer: &mut crate::report::StageTimer, on: &super::thin::OnM<'_>| {
        timer.run("projectability round", || {
            super::thin::final_figures(on, control)
        })
    };
    let meets = |finals: &[draws::Final]| {
        finals
            .first()
            .is_some_and(|f| f.unprojectable_percent <= draws::UNPROJECTABLE_BAR)
    };
    // The gated tube round (`SUBDFIT_FACES_PROJ_TUBE`): re-laid rounds
    // (one unless `_TUBE_ROUNDS`), their sizes capped at the tubes under
    // the spots; its gate before its caps are cast.
    if let Some(k) = tube_k() {
        let finals = match judge {
            Some(on) => vec![final_of(timer, on)?],
            None => Vec::new(),
        };
        if meets(&finals) {
            return Ok(None);
        }
        let (src, t) = tube_source(timer, relayout, fo, (control, &m0), k, f)?;
        return Ok(Some((src, Some(t), finals)));
    }
    let src = source(timer, relayout, fo, (control, m0), max_rounds, f)?;
    let finals = match judge {
        Some(on) => vec![final_of(timer, on)?],
        None => Vec::new(),
    };
    // Judged on the final figures, the rounds run only when the incoming
    // result misses issue 40's unprojectable bar there: they trade L, D
    // and the irregular count for projectability (session 17: gargoyle
    // τ 10 % at 402 came in at 0.043 % on M's final figures, over the bar
    // by M′'s test, and laid, fitted and measured five rounds, none kept;
    // docs/status.md, field-aligned layout).
    if meets(&finals) {
        return Ok(None);
    }
    Ok(Some((src, None, finals)))
}

/// The tube rounds' source (`SUBDFIT_FACES_PROJ_TUBE` at `k`): the
/// tube caps of M′, and a plan of [`TUBE_ROUNDS`] rounds (or
/// `_TUBE_ROUNDS`) on the incoming result's (`control`, measured `m0`)
/// factor ([`tube_round_marks`]); returns the plan with the tube caps and
/// the caps the first round lays.
fn tube_source(
    timer: &mut crate::report::StageTimer,
    relayout: &super::layout::FieldRelayout,
    fo: &crate::quad::field::FieldOptions,
    (control, m0): (&ControlMesh, &Measured),
    k: f64,
    f: f64,
) -> Result<(Source, TubeCaps)> {
    let tubes = timer.run("projectability round", || {
        relayout.prepared.tube_caps(&relayout.mesh, k)
    })?;
    let (factor, caps) = tube_round_marks(control, m0, &tubes, f);
    if crate::switches::set("SUBDFIT_FACES_PROJ_LOG") {
        let capped = caps.iter().filter(|c| c.is_finite()).count();
        let lowered = factor.iter().filter(|x| **x < 1.0).count();
        eprintln!(
            "projectability tube round: {capped} vertices capped, {lowered} lowered by the factor"
        );
    }
    let rounds = crate::switches::number(FACES_PROJ_TUBE_ROUNDS_ENV, TUBE_ROUNDS as f64) as usize;
    let plan = RoundPlan::laid(timer, relayout, fo, None, factor, rounds)?;
    Ok((Source::Plan(plan), (tubes, caps)))
}

/// `fo` with the tube rounds' `caps` ([`crate::quad::field::FieldOptions::local_caps`]).
fn capped_options(
    fo: &crate::quad::field::FieldOptions,
    caps: &[f64],
) -> crate::quad::field::FieldOptions {
    fo.clone()
        .with_local_caps(Some(std::sync::Arc::new(caps.to_vec())))
}

/// After a tube round (`control`, measured `m1`): the next round's factor
/// and the patches with unprojectable vertices; the tubes its spots are
/// on are capped too, the caps so far kept (`caps`, in place).
fn tube_marks_after(
    control: &ControlMesh,
    m1: &Measured,
    tubes: &[f64],
    caps: &mut [f64],
    f: f64,
) -> (Vec<f64>, usize) {
    let (factor, more) = tube_round_marks(control, m1, tubes, f);
    for (c, x) in caps.iter_mut().zip(more) {
        *c = c.min(x);
    }
    let patches = marks(control, m1, tubes.len(), f).1;
    (factor, patches)
}

/// [`rounds_at_count`] before the evaluations of the rounds not kept are
/// dropped.
fn rounds_judged<F: FitFn>(cx: RoundCtx<'_, F>, first: Fitted, judged: bool) -> Result<Fitted> {
    let RoundCtx {
        timer,
        relayout,
        fo,
        rounds,
        mut fit,
        on,
    } = cx;
    // The tube rounds are judged on the final figures too: on M′'s test
    // alone gargoyle 421 (0.050 % on M, 0.157 % on M′) laid one and kept
    // it for 0.154 % on M′, at 0.142 % on M, 72 irregular against 63 and
    // RMS D 0.380‰ against 0.263 (docs/status.md, session 26, reach).
    let judge = (judged || tube_k().is_some()).then_some(on);
    let mesh = &relayout.mesh;
    let permille = 1000.0 / mesh.bbox_diagonal();
    let m0 = timer.run("projectability round", || {
        patch_errors(mesh, &first.control)
    })?;
    if m0.unprojectable_percent <= UNPROJECTABLE_PERCENT {
        return Ok(first);
    }
    let j0 = Judged::of(&m0, &first, permille);
    let log = crate::switches::set("SUBDFIT_FACES_PROJ_LOG");
    if log {
        eprintln!(
            "projectability rounds: incoming faces {} rms {:.4} unprojectable {:.4} %",
            first.control.num_faces(),
            j0.rms,
            j0.unprojectable
        );
    }
    let first_faces = first.control.num_faces();
    let n = fo.target_faces.unwrap_or(first_faces) as f64;
    let f = crate::switches::number("SUBDFIT_FACES_PROJ_F", PROJ_REFINE);
    let max_rounds =
        crate::switches::number("SUBDFIT_FACES_PROJ_ROUNDS", PROJ_ROUNDS as f64) as usize;
    let nv = mesh.positions.len();
    let Some((mut source, mut tube, mut finals)) = sources(
        timer,
        (relayout, fo, judge),
        (&first.control, m0),
        max_rounds,
        f,
    )?
    else {
        return Ok(first);
    };
    // Under `judge`, every round's fit with its index on `rounds`.
    let mut judged: Vec<(Fitted, usize)> = Vec::new();
    let mut best = (j0, first, None::<usize>);
    loop {
        let laid = match &tube {
            Some((_, caps)) => source.next(timer, relayout, &capped_options(fo, caps))?,
            None => source.next(timer, relayout, fo)?,
        };
        let Some((control, irregular, size_factor)) = laid else {
            break;
        };
        let faces = control.num_faces();
        let next = fit(timer, control)?;
        let m1 = timer.run("projectability round", || patch_errors(mesh, &next.control))?;
        let j1 = Judged::of(&m1, &next, permille);
        let (m, patches) = match &mut tube {
            Some((tubes, caps)) => tube_marks_after(&next.control, &m1, tubes, caps, f),
            None => marks(&next.control, &m1, nv, f),
        };
        let (m1_rms, m1_unprojectable, m1_thin) =
            (m1.rms, m1.unprojectable_percent, m1.thin_percent);
        source.mark(m, &next.control, m1);
        rounds.push(FieldRound {
            target_faces: fo.target_faces,
            faces,
            irregular_vertices: irregular,
            fit_rms_permille: next.report.final_rms_permille,
            layout_rms_permille: Some(permille * m1_rms),
            layout_unprojectable_percent: Some(m1_unprojectable),
            layout_thin_percent: Some(m1_thin),
            patches_unprojectable: patches,
            size_factor: Some(size_factor),
            kept: Some(false),
            ..Default::default()
        });
        if log {
            eprintln!(
                "projectability round: faces {faces} irregular {irregular} rms {:.4} unprojectable {:.4} % ({patches} patches)",
                j1.rms, j1.unprojectable
            );
        }
        let at_count =
            (faces as f64 - n).abs() <= f64::max(COUNT_WINDOW * n, (first_faces as f64 - n).abs());
        let stop = m1_unprojectable <= UNPROJECTABLE_PERCENT || patches == 0;
        if let Some(on) = judge {
            let f1 = timer.run("projectability round", || {
                super::thin::final_figures(on, &next.control)
            })?;
            let r = rounds.len() - 1;
            rounds[r].limit_permille = Some(f1.limit_permille);
            rounds[r].displaced_permille = Some(f1.displaced_permille);
            rounds[r].unprojectable_percent = Some(f1.unprojectable_percent);
            finals.push(f1);
            judged.push((next, r));
        } else if at_count && j1.beats(&best.0, &j0) {
            best = (j1, next, Some(rounds.len() - 1));
        }
        // Judged, the chain stops once the choice so far meets the bar
        // ([`stop_at_bar`]).
        let at_bar = judge.is_some() && stop_at_bar() && choice_meets_bar(&finals, fo.target_faces);
        if log && at_bar {
            eprintln!("projectability rounds: the choice meets the bar, stop");
        }
        if stop || at_bar {
            break;
        }
    }
    if judge.is_some() {
        let (i, scores) = draws::choose_final_with(
            &finals,
            fo.target_faces,
            COUNT_WINDOW,
            draws::Score::BarsUnguarded,
        );
        if log {
            for (j, (f, s)) in finals.iter().zip(&scores).enumerate() {
                eprintln!(
                    "projectability judged {j}: faces {} irregular {} L {:.4} D {:.4} unprojectable {:.4} % score {s:?}{}",
                    f.faces, f.irregular_vertices, f.limit_permille, f.displaced_permille,
                    f.unprojectable_percent, if j == i { " kept" } else { "" }
                );
            }
        }
        if i == 0 {
            return Ok(best.1);
        }
        let (fitted, r) = judged.swap_remove(i - 1);
        rounds[r].kept = Some(true);
        return Ok(fitted);
    }
    if let Some(i) = best.2 {
        rounds[i].kept = Some(true);
    }
    Ok(best.1)
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use crate::convert::field::PatchError;
    use crate::DVec3;

    /// A flat `n × n` grid of unit quads, vertex (i, j) at i + (n + 1) j.
    pub(in crate::convert) fn grid(n: usize) -> ControlMesh {
        let positions = (0..=n)
            .flat_map(|j| (0..=n).map(move |i| DVec3::new(i as f64, j as f64, 0.0)))
            .collect();
        let at = |i: usize, j: usize| (j * (n + 1) + i) as u32;
        let faces: Vec<[u32; 4]> = (0..n)
            .flat_map(|j| (0..n).map(move |i| (i, j)))
            .map(|(i, j)| [at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1)])
            .collect();
        ControlMesh::from_polygons(positions, &faces).unwrap()
    }

    /// What the rounds measured on a grid of `faces` unit patches, face f
    /// with one vertex of M′ (its own index) and the unprojectable area and
    /// centroid `bad(f)`; `percent` of M′ unprojectable in all.
    pub(in crate::convert) fn measured(
        faces: u32,
        percent: f64,
        bad: impl Fn(u32) -> (f64, DVec3),
    ) -> Measured {
        let per_patch = (0..faces)
            .map(|f| {
                let (unprojectable, unprojectable_at) = bad(f);
                PatchError {
                    face: f,
                    area: 1.0,
                    unprojectable,
                    unprojectable_at,
                    vertices: vec![f],
                    ..Default::default()
                }
            })
            .collect();
        Measured {
            per_patch,
            rms: 0.0,
            unprojectable_percent: percent,
            thin_percent: 0.0,
        }
    }

    /// On a 4 × 4 grid with face 0 (a corner) unprojectable and one
    /// vertex of M′ per face: that face's vertex gets f, the three faces
    /// sharing a vertex with it √f, the twelve others 1.
    #[test]
    fn marks_lower_the_unprojectable_patch_and_its_ring() {
        let c = grid(4);
        let m = measured(16, 0.5 / 16.0 * 100.0, |f| {
            (if f == 0 { 0.5 } else { 0.0 }, DVec3::ZERO)
        });
        let (factor, bad) = marks(&c, &m, 16, 0.64);
        assert_eq!(bad, 1);
        // Face (i, j) is i + 4 j: the ring of face 0 is faces 1, 4 and 5.
        for (f, x) in factor.iter().enumerate() {
            let want = match f {
                0 => 0.64,
                1 | 4 | 5 => 0.8,
                _ => 1.0,
            };
            assert!((x - want).abs() < 1e-12, "face {f}: {x}, want {want}");
        }
    }

    /// A candidate's final figures: faces, irregular, L ‰, D ‰, unprojectable %.
    fn fin(faces: usize, irregular: usize, l: f64, d: f64, u: f64) -> draws::Final {
        draws::Final {
            faces,
            irregular_vertices: irregular,
            limit_permille: l,
            displaced_permille: d,
            unprojectable_percent: u,
        }
    }

    /// Homer at 272 under `SUBDFIT_FIELD_BEST` (session 21's log): the
    /// incoming result (1.10 %) and round 1 (0.64 %) miss the bar, and the
    /// choice among them is round 1, so the chain goes on; round 3 (0.096 %,
    /// the lowest L and D) is the choice once laid, and it stops there.
    #[test]
    fn the_chain_stops_once_the_choice_meets_the_bar() {
        let incoming = fin(271, 45, 3.5201, 0.7916, 1.1011);
        let r1 = fin(271, 48, 3.6993, 0.5149, 0.6402);
        let r2 = fin(271, 53, 4.3231, 0.8301, 0.4332);
        let r3 = fin(271, 47, 2.5705, 0.2696, 0.0964);
        assert!(!choice_meets_bar(&[incoming], Some(272)));
        assert!(!choice_meets_bar(&[incoming, r1], Some(272)));
        assert!(!choice_meets_bar(&[incoming, r1, r2], Some(272)));
        assert!(choice_meets_bar(&[incoming, r1, r2, r3], Some(272)));
    }

    /// A round at the bar that the score would not keep (RMS L twice the
    /// lowest: 33 units of L's tolerance against round 1's 7.4 in all), or
    /// that is outside the count window, does not stop the chain: the stop
    /// is the choice's, not any round's.
    #[test]
    fn a_round_at_the_bar_not_chosen_does_not_stop_the_chain() {
        let incoming = fin(271, 45, 3.5201, 0.7916, 1.1011);
        let r1 = fin(271, 48, 3.6993, 0.5149, 0.6402);
        let far_l = fin(271, 48, 7.04, 0.5149, 0.09);
        assert!(!choice_meets_bar(&[incoming, r1, far_l], Some(272)));
        // 250 patches is 8 % off 272, outside the 2 % window.
        let off_count = fin(250, 40, 2.0, 0.2, 0.0);
        assert!(!choice_meets_bar(&[incoming, r1, off_count], Some(272)));
    }

    /// On a 4 × 4 grid with face 0 unprojectable: of its mark and its
    /// ring's, the vertices on a tube (finite tube cap) take the cap and
    /// factor 1, the others keep `marks`' factor and no cap; unmarked
    /// vertices get neither, tube or not.
    #[test]
    fn the_tube_round_caps_marked_tubes_and_lowers_the_rest() {
        let c = grid(4);
        let m = measured(16, 0.5 / 16.0 * 100.0, |f| {
            (if f == 0 { 0.5 } else { 0.0 }, DVec3::ZERO)
        });
        // Tubes under face 0, face 5 (ring) and face 15 (far).
        let tubes: Vec<f64> = (0..16)
            .map(|v| match v {
                0 => 0.2,
                5 => 0.3,
                15 => 0.1,
                _ => f64::INFINITY,
            })
            .collect();
        let (factor, caps) = tube_round_marks(&c, &m, &tubes, 0.64);
        for v in 0..16 {
            let (want_f, want_c) = match v {
                0 => (1.0, 0.2),
                5 => (1.0, 0.3),
                1 | 4 => (0.8, f64::INFINITY),
                _ => (1.0, f64::INFINITY),
            };
            assert!(
                (factor[v] - want_f).abs() < 1e-12,
                "vertex {v}: factor {}",
                factor[v]
            );
            assert_eq!(caps[v], want_c, "vertex {v}");
        }
    }

    /// Nothing unprojectable marks nothing.
    #[test]
    fn no_unprojectable_patch_marks_nothing() {
        let c = grid(2);
        let per_patch = (0..4u32)
            .map(|f| PatchError {
                face: f,
                vertices: vec![f],
                ..Default::default()
            })
            .collect();
        let m = Measured {
            per_patch,
            rms: 0.0,
            unprojectable_percent: 0.0,
            thin_percent: 0.0,
        };
        let (factor, bad) = marks(&c, &m, 4, 0.6);
        assert_eq!(bad, 0);
        assert!(factor.iter().all(|x| *x == 1.0));
    }
}
