//! One conversion, end to end: `subdfit convert`, `fit` and `metrics`, and
//! the same calls of every host ([`crate::embed`], C++, Python).
//!
//! A conversion runs in the input's working frame ([`Run`]) through
//! - the mode choice ([`crate::mechanical::choose_mode`] for `--mode auto`),
//! - a layout ([`layout`]): the Fitmaps pipeline's (Panozzo et al. 2011,
//!   §3.1–3.3), Lavoué et al. 2007's for mechanical parts, or the input's
//!   own faces when it is coarser than the Fitmap's radii,
//! - the tail ([`tail`]): the global fit (§3.4–3.5; the `--max-error`
//!   search of [`search`] in organic mode), displacement and metrics (§4),
//! - for `--mode auto`, a second opinion ([`auto`]): a mechanical result
//!   that misses its target is converted organically too, the better kept.
//!
//! [`crate::report`] measures and writes; nothing there fits. What the run
//! was given and did goes to `report.json` as a typed [`RunOptions`]
//! ([`record`]).

use std::path::{Path, PathBuf};

use crate::analysis::FitmapOptions;
use crate::error::{Error, Result};
use crate::fit::FitOptions;
use crate::mesh::{Frame, ValidatedMesh};
use crate::raycast::{make_raycaster, RayBackend};
use crate::report::{MetricsOptions, StageTimer, TargetCheck};

/// `report.json` of a conversion (or of `fit`): the measurements and the
/// run's typed record.
pub type Report = crate::report::Report<RunOptions>;

mod adapt;
pub mod auto;
mod faces_local;
mod faces_proj;
pub mod field;
pub mod layout;
mod options;
pub mod record;
pub mod run;
pub mod search;
pub mod tail;
pub mod thin;

pub use auto::{Candidate, SecondOpinion};
pub use layout::{
    adaptive_lsq_rounds, adaptive_proxy_size, fm_patch_integral, AdaptiveRecord, FieldRelayout,
    Laid, Layout, LayoutRecord, ProxyAttempt, ProxyRecord,
};
pub use options::{
    adaptive_proxy_triangles, ConvertOptions, LayoutKind, Mode, Proxy, DEFAULT_ORGANIC_MAX_ERROR,
    FIELD_ADAPT_ENV, PROXY_ADAPTIVE_FLOOR, PROXY_AUTO_ABOVE, PROXY_AUTO_TRIANGLES,
    PROXY_PATCHES_PER_FM_INTEGRAL, PROXY_PROBE_TRIANGLES, PROXY_TRIANGLES_PER_PATCH,
};
pub use record::{
    BranchLayout, BranchRecord, FitInputs, FittedRun, HostRecord, MechanicalRecord, ModeRecord,
    RunOptions, SecondOpinionNote,
};
pub use run::Run;
pub use search::{ErrorSearch, LIMIT_CHECK_STAGE};
pub use tail::{
    fit_and_measure, fit_and_write, measure_fitted, write_converted, Converted, PipelineOptions,
};

/// Converts `input` and writes every output into `dir` (all or nothing).
/// `progress(stage, fraction)` is called per stage (`"fitmap"`,
/// `"simplify"`, then the fitting stages of [`fit_and_measure`] and
/// `"write"`); returning `false` cancels with [`Error::Cancelled`] and
/// writes nothing.
pub fn convert(
    input: &ValidatedMesh,
    opts: &ConvertOptions,
    host: HostRecord,
    dir: &Path,
    progress: &mut crate::watch::Progress<'_>,
) -> Result<(Report, Vec<PathBuf>)> {
    let c = convert_in_memory(input, opts, host, progress)?;
    let written = write_converted(input, &c, dir, None, progress)?;
    Ok((c.report, written))
}

/// [`convert`] without writing anything: the fitted control mesh, the
/// surfaces, the report and the Fitmap, for hosts that keep results in
/// memory (the C++ API).
pub fn convert_in_memory(
    input: &ValidatedMesh,
    opts: &ConvertOptions,
    host: HostRecord,
    progress: &mut crate::watch::Progress<'_>,
) -> Result<Converted> {
    let converted = at_unit_scale(input, |m, frame| {
        convert_at_unit_scale(m, *frame, opts, host, progress)
    });
    // The BVHs shared within the run (M, M′) are this run's only.
    crate::raycast::bvh::BvhCaster::clear_shared();
    converted
}

/// `subdfit fit` and the C++ API's fit: fits a given `control` to `input`
/// and measures it ([`fit_and_measure`] over an Embree caster), at the same
/// working frame as [`convert_in_memory`], so a mesh and its control mesh at
/// 1e20 fit as they do at unit scale.
pub fn fit_in_memory(
    input: &ValidatedMesh,
    mut control: crate::mesh::ControlMesh,
    opts: &PipelineOptions,
    timer: StageTimer,
    mut host: HostRecord,
    progress: &mut crate::watch::Progress<'_>,
) -> Result<Converted> {
    at_unit_scale(input, |m, frame| {
        frame.points_to_unit(control.positions_mut());
        let mut run = Run::start(m, *frame, timer, progress)?;
        let fitmap = match &opts.fitmap {
            Some(fo) => {
                let (fitmap, tried) = proxied_fitmap(run.mesh(), fo, &mut run.timer, run.progress)?;
                host.fitmap_proxy = tried.map(Box::new);
                fitmap
            }
            None => None,
        };
        let timer = run.take_timer();
        fit_and_measure(
            m,
            control,
            run.caster.as_ref(),
            opts,
            timer,
            FittedRun::Host(host),
            fitmap,
            run.progress,
        )
    })
}

/// `fitmap.ply`'s Fitmap for `fit` on a mesh above [`PROXY_AUTO_ABOVE`]
/// triangles: computed on the layout proxy M′ and carried to M's vertices,
/// as `convert` does (a full-resolution Fitmap of a 1.1M-triangle scan
/// took 47 s, twice the whole fit); `None` below the bound or when no
/// proxy keeps M's topology (the Fitmap is then computed on M after the
/// fit). What was tried is returned beside it, for `report.json`'s
/// `options.run.fitmap_proxy`.
fn proxied_fitmap(
    mesh: &crate::mesh::TriMesh,
    fo: &FitmapOptions,
    timer: &mut StageTimer,
    progress: &mut crate::watch::Progress<'_>,
) -> Result<(Option<crate::analysis::Fitmap>, Option<layout::ProxyRecord>)> {
    let (proxy, tried) = layout::layout_proxy(mesh, Proxy::Auto, fo, timer, progress)?;
    let Some((m, c)) = proxy else {
        return Ok((None, tried));
    };
    let stage = crate::fit::report_progress;
    stage(progress, "fitmap", 0.0)?;
    let fitmap = timer.run("fitmap", || {
        layout::fitmap_reporting(&m, c.as_ref(), fo, &mut *progress)
    })?;
    stage(progress, "fitmap", 1.0)?;
    let fitmap = timer.run("fitmap transfer", || {
        fitmap.transferred(&m, c.as_ref(), mesh)
    })?;
    Ok((Some(fitmap), tried))
}

/// `subdfit metrics`: Table 1's figures for a given `control` against
/// `input`, in the working frame of [`convert_in_memory`] (all of them are in
/// ‰ of the diagonal or counts; the diagonal is the input's).
pub fn measure(
    input: &ValidatedMesh,
    mut control: crate::mesh::ControlMesh,
    opts: &MetricsOptions,
) -> Result<crate::report::Metrics> {
    let frame = working_frame(&input.mesh);
    let mut mesh = input.mesh.clone();
    frame.points_to_unit(&mut mesh.positions);
    frame.points_to_unit(control.positions_mut());
    // Triangles and n-gons are measured on the refinement by one level:
    // the same limit surface, all quads (the displacement's patches).
    if tail::displaced_on_refinement(&control, &mesh, opts) {
        control = crate::subdiv::refine::refine_once_keeping_infinite(&control)?;
    }
    let caster = make_raycaster(RayBackend::Embree, &mesh)?;
    let mut m = crate::report::metrics(&mesh, &control, caster.as_ref(), opts)?;
    m.bbox_diagonal = input.mesh.bbox_diagonal();
    Ok(m)
}

/// Runs `body` on `input` in its working frame ([`Frame`]: centred, unit
/// diagonal, snapped; `body` gets the mesh and the frame, to map whatever
/// else it measures against it), then maps the result back.
fn at_unit_scale(
    input: &ValidatedMesh,
    body: impl FnOnce(&ValidatedMesh, &Frame) -> Result<Converted>,
) -> Result<Converted> {
    let frame = working_frame(&input.mesh);
    let mut unit = input.clone();
    frame.points_to_unit(&mut unit.mesh.positions);
    let mut c = body(&unit, &frame)?;
    c.map_from_unit(&frame);
    // The input's own diagonal, not the snapped working mesh's times the
    // scale (they differ by ~1e-9 relative); the ‰ figures were taken
    // against the latter and differ by as little.
    c.surfaces.metrics.bbox_diagonal = input.mesh.bbox_diagonal();
    c.report.input = input.report.clone();
    Ok(c)
}

/// The working frame of `mesh` (see [`Frame`] for why every conversion
/// runs in one).
fn working_frame(mesh: &crate::mesh::TriMesh) -> Frame {
    let (lo, hi) = mesh.bbox();
    Frame::of_bbox(lo, hi)
}

/// [`convert_in_memory`] on a mesh in its working `frame`.
fn convert_at_unit_scale(
    input: &ValidatedMesh,
    frame: Frame,
    opts: &ConvertOptions,
    host: HostRecord,
    progress: &mut crate::watch::Progress<'_>,
) -> Result<Converted> {
    let choice = mode_choice(&input.mesh, opts.mode);
    let mut run = Run::start(input, frame, StageTimer::default(), progress)?;
    if choice.mode == "organic" {
        if adapt::checks(opts) {
            return adapt::with_switch_off_beside(&mut run, opts, |run, opts| {
                convert_as(run, opts, choice.clone(), host.clone())
            });
        }
        return convert_as(&mut run, opts, choice, host);
    }
    // `--mode auto` ends with the pipeline that fits: a CAD-looking mesh
    // whose mechanical result misses its own target (an isotropically
    // remeshed statue with flat parts and a few sharp edges) is converted
    // by the organic pipeline too, and the lower RMS distance is kept. An
    // explicit `--mode mechanical` gets the same second opinion only when
    // its result is far over its target (see [`auto::Doubt`]).
    let doubt = if choice.how == "auto" {
        auto::Doubt::Missed
    } else {
        auto::Doubt::FarOver {
            max_error: opts
                .max_error
                .unwrap_or(crate::mechanical::DEFAULT_MAX_ERROR),
        }
    };
    auto::with_second_opinion(
        &mut run,
        doubt,
        |run| convert_as(run, opts, choice.clone(), host.clone()),
        |run, why| {
            let mut organic = choice.clone();
            organic.mode = "organic";
            organic.reason = format!("{}; {why}", choice.reason);
            convert_as(run, opts, organic, host.clone())
        },
    )
}

/// `--mode`'s choice for `mesh`: [`crate::mechanical::choose_mode`]'s rule,
/// or the mode given, with the rule's figures kept for the report.
fn mode_choice(mesh: &crate::mesh::TriMesh, mode: Mode) -> crate::mechanical::ModeChoice {
    match mode {
        Mode::Auto => crate::mechanical::choose_mode(mesh),
        forced => {
            let mut c = crate::mechanical::choose_mode(mesh);
            c.how = "forced";
            c.mode = if forced == Mode::Mechanical {
                "mechanical"
            } else {
                "organic"
            };
            c.reason = format!("--mode {} given; {}", c.mode, c.reason);
            c
        }
    }
}

/// Organic mode's RMS L bound: `--max-error` (infinity: none, the natural
/// end), else [`DEFAULT_ORGANIC_MAX_ERROR`] unless `--faces` is given.
fn organic_max_error(opts: &ConvertOptions) -> Option<f64> {
    match (opts.max_error, opts.target_faces) {
        (Some(e), _) => Some(e).filter(|e| e.is_finite()),
        (None, None) => Some(DEFAULT_ORGANIC_MAX_ERROR),
        (None, Some(_)) => None,
    }
}

/// The τ of `opts` as Fitmap options.
fn fitmap_options(opts: &ConvertOptions) -> FitmapOptions {
    let mut fo = FitmapOptions::default();
    if let Some(t) = opts.tolerance {
        fo = fo.with_tolerance(t);
    }
    fo
}

/// The layout `choice` calls for: mechanical, or organic (the coarse
/// layout when the input is coarser than the Fitmap's radii, where §3.1's
/// analysis is undefined).
fn layout_for(
    mesh: &crate::mesh::TriMesh,
    opts: &ConvertOptions,
    choice: &crate::mechanical::ModeChoice,
) -> Layout {
    if choice.mode != "organic" {
        return Layout::Mechanical(
            crate::mechanical::MechanicalOptions::default().with_max_error(
                opts.max_error
                    .unwrap_or(crate::mechanical::DEFAULT_MAX_ERROR),
            ),
        );
    }
    match crate::analysis::fitmap::fitmap_radii(mesh) {
        Err(why) => Layout::Coarse { why },
        Ok(_) if opts.layout == LayoutKind::Field => Layout::OrganicField {
            fitmap: fitmap_options(opts),
        },
        Ok(_) => Layout::OrganicGreedy {
            fitmap: fitmap_options(opts),
            checkpoints: organic_max_error(opts).is_some(),
        },
    }
}

/// One branch of a conversion: `choice`'s layout, then its tail.
/// `host` (the host's `"run"` record) goes into `report.json`.
fn convert_as(
    run: &mut Run<'_, '_>,
    opts: &ConvertOptions,
    choice: crate::mechanical::ModeChoice,
    host: HostRecord,
) -> Result<Converted> {
    let laid = layout_for(run.mesh(), opts, &choice).lay(run, opts)?;
    let Laid {
        control,
        checkpoints,
        fitmap,
        record,
    } = laid;
    let fit = field::fit_iterations(
        FitOptions::default().with_objective(opts.objective),
        opts.layout == options::LayoutKind::Field,
    );
    let metrics = MetricsOptions::default()
        .with_displacement_res(opts.displacement_res)
        .with_displacement_samples(opts.displacement_samples)
        .with_displacement_allocation(opts.displacement_allocation)
        .with_reconstruction(opts.displacement_reconstruction)
        .with_output_tessellation(opts.tessellation)
        .with_exact(opts.exact_metrics);
    let branch = |layout: BranchLayout| BranchRecord {
        mode: ModeRecord {
            choice: choice.clone(),
            second_opinion: None,
        },
        convert: opts.clone(),
        run: host.clone(),
        layout,
    };
    let fitted = |layout: BranchLayout| FittedRun::Convert(Box::new(branch(layout)));
    match record {
        LayoutRecord::Mechanical { options: mo, stats } => {
            let target = max_error_target(&mo, &stats);
            let options = RunOptions::Mechanical(Box::new(branch(BranchLayout::Mechanical {
                mechanical: MechanicalRecord { options: mo, stats },
            })));
            let mut c = tail::measure_as_fitted(run, control, &metrics, options)?;
            c.report.add_target(target);
            Ok(c)
        }
        LayoutRecord::Coarse { why } => {
            let options = fitted(BranchLayout::Coarse {
                coarse_input: format!(
                    "no Fitmap ({why}): the input's own faces, refined once into quads, are the control mesh, its sharp edges (dihedral > {}°) infinitely sharp creases",
                    crate::mechanical::SHARP_DIHEDRAL_DEG
                ),
            });
            let po = PipelineOptions::default()
                .with_fit(fit)
                .with_metrics(metrics);
            let timer = run.take_timer();
            fit_and_measure(
                run.input,
                control,
                run.caster.as_ref(),
                &po,
                timer,
                options,
                None,
                run.progress,
            )
        }
        LayoutRecord::OrganicField {
            proxy,
            field,
            relayout,
        } => {
            let (fitmap, po) = organic_tail(fitmap, opts, fit, metrics)?;
            let record = |rounds: &[field::FieldRound]| {
                fitted(BranchLayout::OrganicField {
                    layout_proxy: proxy.clone(),
                    field_layout: field::FieldRecord {
                        first: field.clone(),
                        rounds: rounds.to_vec(),
                        adapt_check: None,
                    },
                })
            };
            field::fit_field(
                run,
                opts,
                control,
                &relayout,
                &po,
                fitmap,
                organic_max_error(opts),
                record,
            )
        }
        LayoutRecord::OrganicGreedy {
            proxy,
            simplification,
        } => {
            let metrics = metrics.with_host_lsq_rounds(layout::adaptive_lsq_rounds(proxy.as_ref()));
            let (fitmap, po) = organic_tail(fitmap, opts, fit, metrics)?;
            let with_search = |search: Option<&ErrorSearch>| {
                fitted(BranchLayout::OrganicGreedy {
                    layout_proxy: proxy.clone(),
                    simplification: simplification.clone(),
                    max_error_search: search.cloned(),
                })
            };
            if let Some(e) = organic_max_error(opts) {
                return search::fit_fewest_within(
                    run,
                    (control, checkpoints),
                    e,
                    &po,
                    &fitmap,
                    with_search,
                );
            }
            let mut timer = run.take_timer();
            let (mesh, caster) = (run.mesh(), run.caster.as_ref());
            let fitted = timer.run("fit", || {
                crate::fit::fit_with_progress(mesh, control, caster, &po.fit, run.progress)
            })?;
            let mut c = measure_fitted(
                run.input,
                fitted,
                caster,
                &po,
                timer,
                with_search(None),
                Some(fitmap),
                run.progress,
            )?;
            if let Some(n) = opts.target_faces {
                c.report
                    .add_target(faces_target(n, &simplification, &c.report));
            }
            Ok(c)
        }
    }
}

/// The Fitmap an organic layout computed and the tail's options for it.
fn organic_tail(
    fitmap: Option<crate::analysis::Fitmap>,
    opts: &ConvertOptions,
    fit: FitOptions,
    metrics: MetricsOptions,
) -> Result<(crate::analysis::Fitmap, PipelineOptions)> {
    let fitmap = fitmap.ok_or_else(|| Error::internal("organic layout without a Fitmap"))?;
    let po = PipelineOptions::default()
        .with_fit(fit)
        .with_metrics(metrics)
        .with_fitmap(Some(fitmap_options(opts)));
    Ok((fitmap, po))
}

/// `--faces N`'s target: within ±2 % of `n` (issue 17), with what
/// relaxing the halting tests to get there cost in projectability.
fn faces_target(n: usize, stats: &crate::quad::SimplifyStats, report: &Report) -> TargetCheck {
    let got = report.control.faces;
    let (lo, hi) = (0.98 * n as f64, 1.02 * n as f64);
    let relaxed = if stats.relax_steps > 0 {
        format!(
            "below the natural end: M-fitmap radius, S-fitmap bound and guard relaxed ×{:.3} ({} steps of ×{})",
            stats.relaxation,
            stats.relax_steps,
            crate::quad::simplify::RELAX_STEP
        )
    } else {
        "the halting tests as they are".to_string()
    };
    TargetCheck {
        option: "faces",
        target: format!("{n} faces ±2 % (--faces {n})"),
        met: (lo..=hi).contains(&(got as f64)),
        outcome: format!(
            "{got} faces; {relaxed}; unprojectable area {:.3} %",
            report.projectability.unprojectable_area_percent
        ),
    }
}

/// Mechanical mode's stated target (Lavoué et al. §7.2's `E_limit`): every
/// control face within RMS `max_error` of M, on the control mesh written.
fn max_error_target(
    mo: &crate::mechanical::MechanicalOptions,
    stats: &crate::mechanical::MechanicalStats,
) -> TargetCheck {
    let e = 1e3 * mo.max_error;
    // The written control mesh, measured after the last geometry pass (a
    // round's figures precede the restore of each region's best state and
    // that pass).
    let r = &stats.output;
    let (over, faces, rms) = (r.faces_over_limit, r.faces, r.rms_permille);
    TargetCheck {
        option: "max_error",
        target: format!(
            "every control face within RMS {e:.3}‰ of the input (--max-error {})",
            mo.max_error
        ),
        met: over == 0 && rms.is_finite(),
        outcome: format!(
            "{over} of {faces} faces above it; RMS over all faces {rms:.3}‰ ({:.1}× the limit)",
            rms / e
        ),
    }
}
