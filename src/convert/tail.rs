//! The tail of every conversion, shared by `subdfit fit` and `convert`:
//! global fit of a given control mesh (Fitmaps §3.4–3.5), displacement and
//! metrics ([`crate::report::evaluate_surfaces`], §4), the Fitmap for
//! `fitmap.ply`, and the all-or-nothing write of the outputs
//! ([`crate::report::write_outputs_with`]).

use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::analysis::{compute_fitmap, Fitmap, FitmapOptions};
use crate::error::Result;
use crate::fit::{fit_with_progress, FitOptions, Progress};
use crate::mesh::{ControlMesh, Frame, ValidatedMesh};
use crate::raycast::RayCaster;

use crate::report::{
    evaluate_surfaces, evaluate_surfaces_after, write_outputs_with, ExtraFiles, LimitCheck,
    MetricsOptions, OutputFiles, OutputOptions, StageTimer, Surfaces,
};

use super::record::{FittedRun, RunOptions};
use super::Report;

/// Options of [`fit_and_write`].
#[derive(Clone, Debug, Default, Serialize, serde::Deserialize)]
#[non_exhaustive]
pub struct PipelineOptions {
    pub fit: FitOptions,
    pub metrics: MetricsOptions,
    /// `fitmap.ply` is computed and written when set.
    pub fitmap: Option<FitmapOptions>,
}

impl PipelineOptions {
    pub fn with_fit(mut self, f: FitOptions) -> Self {
        self.fit = f;
        self
    }
    pub fn with_metrics(mut self, m: MetricsOptions) -> Self {
        self.metrics = m;
        self
    }
    pub fn with_fitmap(mut self, f: Option<FitmapOptions>) -> Self {
        self.fitmap = f;
        self
    }
}

/// `SUBDFIT_DISP_REFINE=1` (issue 40, session 18; off): an all-quad
/// layout's displacement atlas carried on its refinement by one level, as
/// a layout with triangles or n-gons always is (the same limit surface,
/// the same sample budget, four tiles per patch).
pub const DISP_REFINE_ENV: &str = "SUBDFIT_DISP_REFINE";

/// Whether the displacement atlas (and the metrics) of `control` are laid
/// out on its refinement by one level: always when it is not all quads,
/// and under [`DISP_REFINE_ENV`]. Why the switch: issue 40's peers are
/// measured by `subdfit fit`, which carries Instant Meshes' quad-dominant
/// layouts (every RMS D bar the field layout misses is Instant Meshes')
/// on their refinement, where the allocation's tiles of 2^k + 1 samples
/// per side (`displace::alloc`) come four to a patch: a finer grain for
/// the same budget. Spot's field cage at 81 patches (2930 samples, tiles
/// 3 / 5 / 9 / 17 on 8 / 42 / 29 / 2 patches) gives RMS D 0.493‰ on its
/// own patches and 0.432‰ on its refinement (session 18), against the
/// 0.441‰ bar. It helps only where the budget is large against the
/// patches ([`DISP_REFINE_MIN_SAMPLES`]), so the switch refines only there.
pub fn displaced_on_refinement(
    control: &ControlMesh,
    mesh: &crate::mesh::TriMesh,
    metrics: &MetricsOptions,
) -> bool {
    if !control.is_all_quads() {
        return true;
    }
    // The adaptive allocation's budget, as `report::metrics` sets it.
    let budget = (metrics.displacement_res.is_none()
        && metrics.displacement_allocation == crate::displace::SampleAllocation::Adaptive)
        .then(|| metrics.displacement_samples.unwrap_or(mesh.positions.len()));
    crate::switches::on(DISP_REFINE_ENV)
        && budget.is_some_and(|b| {
            b >= DISP_REFINE_MIN_SAMPLES * control.num_faces()
                || refines_for_level0(crate::switches::on(crate::displace::LEVEL0_ENV), control, b)
        })
}

/// Whether [`DISP_REFINE_ENV`] refines all-quad `control` below
/// [`DISP_REFINE_MIN_SAMPLES`] for an allocation from level 0
/// (`displace::LEVEL0_ENV`, `level0`): when the refined cage's level-1
/// floor would eat most of `budget` (`displace::first_level_for` on the
/// refinement's vertices + edges + faces), so that its allocation starts
/// at level 0, and its level-0 floor (the refinement's vertices, which
/// are `control`'s level-1 samples) is at most half the budget, so that
/// the rest is the greedy's to place at the quarters' finer grain. Between
/// (the level-1 floor at most 4/5 of the budget once refined, e.g. homer
/// at 272: 72 %) the cage stays as it is, as on main.
pub fn refines_for_level0(level0: bool, control: &ControlMesh, budget: usize) -> bool {
    // One Catmull-Clark step on an all-quad cage: a vertex per vertex,
    // edge and face; two edges per edge and four per face; four faces per
    // face.
    let (v, e, f) = (
        control.num_vertices(),
        control.num_edges(),
        control.num_faces(),
    );
    let floor0 = v + e + f;
    let floor1 = floor0 + (2 * e + 4 * f) + 4 * f;
    crate::displace::first_level_for(level0, floor1, budget) == 0 && 2 * floor0 <= budget
}

/// The displacement budget per patch from which [`DISP_REFINE_ENV`]
/// refines: 8 per refined patch, twice the 4 a refined patch's smallest
/// tile (3 × 3, its edges shared) holds, so that the allocation can still
/// raise about half of them a level. Session 18: at 34–62 samples per
/// patch the refinement lowered RMS D 9–12 % (spot at 81 and 85, gargoyle
/// τ 10 % at 402); at 18 (gargoyle τ 1 % at 1391) nearly every refined
/// patch got the smallest tile and D rose 0.222 → 0.226‰; at 11
/// (QuadriFlow's 269 patches on spot) the smallest tiles alone took 4306
/// samples of 2930 and D rose 0.292 → 0.353‰.
pub const DISP_REFINE_MIN_SAMPLES: usize = 32;

/// Everything a conversion produces, before anything is written: what
/// [`write_converted`] puts on disk and what the C++ API hands to a host.
pub struct Converted {
    /// The fitted control mesh.
    pub control: ControlMesh,
    /// When `control` is not all quads (mechanical mode): its Catmull-Clark
    /// refinement by one level, which has the same limit surface and is the
    /// mesh the displacement atlas (and `surfaces`) are laid out on, and
    /// the one `control.obj` / `control.usda` carry.
    pub quad_control: Option<ControlMesh>,
    pub surfaces: Surfaces,
    pub report: Report,
    /// The Fitmap written as `fitmap.ply`, when one was computed or given.
    pub fitmap: Option<Fitmap>,
    /// How [`write_converted`] writes the files (units, atlas layout,
    /// texel type); the defaults unless the caller sets them.
    pub outputs: OutputOptions,
    /// `--mode auto`: what its second opinion compared and kept, when it
    /// ran one.
    pub second_opinion: Option<super::auto::SecondOpinion>,
}

impl Converted {
    /// The control mesh the files carry, with the atlas UVs: `quad_control`
    /// when there is one (mechanical mode), else `control`.
    pub fn written_control(&self) -> &ControlMesh {
        self.quad_control.as_ref().unwrap_or(&self.control)
    }
}

impl Converted {
    /// Maps the result from the working `frame` the conversion ran in (see
    /// [`Frame`]) back to the input's coordinates: positions by
    /// [`Frame::from_unit`]; derivatives, displacement offsets, the
    /// diagonal and the Fitmap's radii by the frame's scale `f`; F_S (units
    /// 1 / length^(3/4)) by `f^(-3/4)`. Everything in `report.json` is in ‰
    /// of the diagonal or a count, and stays.
    pub fn map_from_unit(&mut self, frame: &Frame) {
        if *frame == Frame::IDENTITY {
            return;
        }
        let f = frame.scale;
        frame.points_from_unit(self.control.positions_mut());
        if let Some(q) = self.quad_control.as_mut() {
            frame.points_from_unit(q.positions_mut());
        }
        let s = &mut self.surfaces;
        for l in &mut s.displacement.limit {
            l.position = frame.from_unit(l.position);
            l.du *= f;
            l.dv *= f;
        }
        s.displacement.offsets.iter_mut().for_each(|o| *o *= f);
        // (`directions` are unit vectors; the tessellation figures are ‰.)
        s.displaced_offsets.iter_mut().for_each(|o| *o *= f);
        for t in [&mut s.limit, &mut s.displaced] {
            frame.points_from_unit(&mut t.positions);
        }
        s.metrics.bbox_diagonal *= f;
        if let Some(fm) = self.fitmap.as_mut() {
            fm.radii.iter_mut().for_each(|r| *r *= f);
            fm.m.iter_mut().for_each(|r| *r *= f);
            let fs = f.powf(-0.75);
            fm.s.iter_mut().for_each(|x| *x *= fs);
        }
    }
}

/// Fits `control` to `input.mesh` (`caster` built over it) and measures the
/// result. `timer` carries the stages run before (reading, simplification
/// …) into the report; `run` is stored in `report.json` beside the
/// pipeline's own options. `precomputed_fitmap` (e.g. the one the
/// simplification used) is kept for `fitmap.ply` instead of computing one.
/// Stages for `progress`: `"fit"`, `"displacement"`, `"metrics"`,
/// `"fitmap"`.
#[allow(clippy::too_many_arguments)]
pub fn fit_and_measure(
    input: &ValidatedMesh,
    control: ControlMesh,
    caster: &dyn RayCaster,
    opts: &PipelineOptions,
    mut timer: StageTimer,
    run: FittedRun,
    precomputed_fitmap: Option<Fitmap>,
    progress: &mut Progress<'_>,
) -> Result<Converted> {
    let fitted = timer.run("fit", || {
        fit_with_progress(&input.mesh, control, caster, &opts.fit, progress)
    })?;
    measure_fitted(
        input,
        fitted,
        caster,
        opts,
        timer,
        run,
        precomputed_fitmap,
        progress,
    )
}

/// The tail of [`fit_and_measure`] for a control mesh fitted already:
/// displacement, metrics, Fitmap and the report.
#[allow(clippy::too_many_arguments)]
pub fn measure_fitted(
    input: &ValidatedMesh,
    fitted: crate::fit::Fitted,
    caster: &dyn RayCaster,
    opts: &PipelineOptions,
    timer: StageTimer,
    run: FittedRun,
    precomputed_fitmap: Option<Fitmap>,
    progress: &mut Progress<'_>,
) -> Result<Converted> {
    let at = (timer, run, precomputed_fitmap);
    let measured = Known::Check(None);
    measure_fitted_after(input, fitted, caster, opts, at, measured, progress)
}

/// What the tail has of the displacement and metrics before it runs.
// One value per conversion, moved once into the tail: the size of the
// unboxed check costs nothing worth an allocation.
#[allow(clippy::large_enum_variant)]
pub(super) enum Known {
    /// L's accuracy (of `fitted.control`: the `--max-error` search's; not
    /// measured again), or nothing.
    Check(Option<LimitCheck>),
    /// All of it: the displacement and metrics of `fitted.control` against
    /// the input's mesh with the tail's caster and `opts.metrics`
    /// ([`evaluate_surfaces`] on it, refined once when not all quads),
    /// computed already by the fixed-count field rounds
    /// (`super::thin::Evaluations`), the same bits.
    Surfaces(Box<Surfaces>),
}

impl Known {
    /// `evaluated` when there is one, else nothing measured.
    pub(super) fn evaluated(evaluated: Option<Surfaces>) -> Self {
        match evaluated {
            Some(s) => Known::Surfaces(Box::new(s)),
            None => Known::Check(None),
        }
    }
}

/// [`measure_fitted`] with what is `measured` already handed in.
pub(super) fn measure_fitted_after(
    input: &ValidatedMesh,
    fitted: crate::fit::Fitted,
    caster: &dyn RayCaster,
    opts: &PipelineOptions,
    (mut timer, run, precomputed_fitmap): (StageTimer, FittedRun, Option<Fitmap>),
    measured: Known,
    progress: &mut Progress<'_>,
) -> Result<Converted> {
    let mesh = &input.mesh;
    // A layout with triangles or n-gons (another tool's, or mechanical
    // mode's) carries its displacement atlas on its refinement by one
    // level: all quads, the same limit surface.
    let quads = if !displaced_on_refinement(&fitted.control, mesh, &opts.metrics) {
        None
    } else {
        Some(timer.run("refine", || {
            crate::subdiv::refine::refine_once_keeping_infinite(&fitted.control)
        })?)
    };
    let surfaces = timer.run("displacement+metrics", || {
        let on = quads.as_ref().unwrap_or(&fitted.control);
        match measured {
            Known::Surfaces(s) => Ok(*s),
            Known::Check(check) => {
                // L's check was measured on the unrefined patches: not
                // reused on the refinement's.
                let check = check.filter(|_| quads.is_none());
                evaluate_surfaces_after(mesh, on, caster, &opts.metrics, check, progress)
            }
        }
    })?;
    let fitmap = match (&opts.fitmap, precomputed_fitmap) {
        (_, Some(f)) => Some(f),
        (Some(fo), None) => Some(timer.run("fitmap", || {
            crate::fit::report_progress(progress, "fitmap", 0.0)?;
            let f = compute_fitmap(mesh, caster, fo)?;
            crate::fit::report_progress(progress, "fitmap", 1.0)?;
            Ok(f)
        })?),
        (None, None) => None,
    };
    let options = RunOptions::Fitted {
        pipeline: Box::new(opts.clone()),
        run,
        mode: None,
    };
    let mut report = Report::new(
        input.report.clone(),
        &fitted.control,
        Some(fitted.report.clone()),
        &surfaces.metrics,
        timer.stages,
        options,
    );
    report.control_written = quads.as_ref().map(crate::report::control_stats);
    Ok(Converted {
        control: fitted.control,
        quad_control: quads,
        surfaces,
        report,
        fitmap,
        outputs: OutputOptions::default(),
        second_opinion: None,
    })
}

/// Writes a conversion into `dir` as one set with `extra`'s files (all or
/// nothing, see [`crate::report::write_outputs`]). Stage for `progress`: `"write"`.
pub fn write_converted(
    input: &ValidatedMesh,
    c: &Converted,
    dir: &Path,
    extra: Option<ExtraFiles<'_>>,
    progress: &mut Progress<'_>,
) -> Result<Vec<PathBuf>> {
    crate::fit::report_progress(progress, "write", 0.0)?;
    let written = write_outputs_with(
        dir,
        &OutputFiles {
            mesh: &input.mesh,
            control: c.written_control(),
            surfaces: &c.surfaces,
            fitmap: c.fitmap.as_ref(),
            report: &c.report,
            options: &c.outputs,
        },
        extra,
    )?;
    crate::fit::report_progress(progress, "write", 1.0)?;
    Ok(written)
}

/// [`fit_and_measure`] then [`write_converted`]: every output into `dir`.
#[allow(clippy::too_many_arguments)]
pub fn fit_and_write(
    input: &ValidatedMesh,
    control: ControlMesh,
    caster: &dyn RayCaster,
    opts: &PipelineOptions,
    timer: StageTimer,
    run: FittedRun,
    precomputed_fitmap: Option<Fitmap>,
    dir: &Path,
    progress: &mut Progress<'_>,
) -> Result<(Report, Vec<PathBuf>)> {
    let c = fit_and_measure(
        input,
        control,
        caster,
        opts,
        timer,
        run,
        precomputed_fitmap,
        progress,
    )?;
    let written = write_converted(input, &c, dir, None, progress)?;
    Ok((c.report, written))
}

/// The tail of a layout that fitted its control mesh itself (mechanical
/// mode, Lavoué et al. §7.1): displacement and metrics, no fit.
///
/// The mechanical control mesh mixes triangles, quads and larger faces,
/// while the displacement atlas and the tessellations need quads: they are
/// computed on its Catmull-Clark refinement by one level (infinitely sharp
/// creases and corners re-tagged as infinitely sharp), which has *exactly*
/// the same limit surface. That refined mesh is the one written
/// (`control.obj`, `control.usda`, with the atlas UVs and the creases and
/// corners), so that a USD or Blender pipeline can apply the displacement;
/// `report.json`'s `control` counts the compact mesh (Lavoué et al.'s
/// Table 2 figures) and `control_written` the refined one. `options` is
/// `report.json`'s `options` as it stands.
pub(super) fn measure_as_fitted(
    run: &mut super::Run<'_, '_>,
    control: ControlMesh,
    metrics: &MetricsOptions,
    options: RunOptions,
) -> Result<Converted> {
    let mut timer = run.take_timer();
    let (input, caster) = (run.input, run.caster.as_ref());
    let refined = displaced_on_refinement(&control, &input.mesh, metrics);
    let quads = timer.run("refine", || {
        if !refined {
            return Ok(control.clone());
        }
        crate::subdiv::refine::refine_once_keeping_infinite(&control)
    })?;
    let surfaces = timer.run("displacement+metrics", || {
        evaluate_surfaces(&input.mesh, &quads, caster, metrics, run.progress)
    })?;
    let mut report = Report::new(
        input.report.clone(),
        &control,
        None,
        &surfaces.metrics,
        timer.stages,
        options,
    );
    if refined {
        report.control_written = Some(crate::report::control_stats(&quads));
    }
    Ok(Converted {
        quad_control: refined.then_some(quads),
        control,
        surfaces,
        report,
        fitmap: None,
        outputs: Default::default(),
        second_opinion: None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `refines_for_level0`'s counts are the refinement's own (its
    /// vertices, and its level-1 floor through `displace::level1_floor`),
    /// and it refines exactly where the refined cage's allocation then
    /// starts at level 0 with its corners taking at most half the budget:
    /// never without the level-0 switch, never where the level-1 floor
    /// leaves the greedy a fifth of the budget once refined.
    #[test]
    fn refines_below_main_only_where_the_refinement_starts_at_level_0() {
        let cage = crate::fixtures::cube();
        let r = crate::subdiv::refine::refine_once_keeping_infinite(&cage).unwrap();
        let floor1 = crate::displace::level1_floor(&r);
        let mut refined = 0;
        for budget in 0..4 * floor1 {
            assert!(!refines_for_level0(false, &cage, budget));
            let at0 = crate::displace::first_level_for(true, floor1, budget) == 0;
            let want = at0 && 2 * r.num_vertices() <= budget;
            assert_eq!(refines_for_level0(true, &cage, budget), want, "{budget}");
            if want {
                assert!(5 * floor1 > 4 * budget && 2 * r.num_vertices() <= budget);
                refined += 1;
            }
        }
        assert!(refined > 0);
    }
}
