//! `convert`: the whole organic pipeline of the Fitmaps paper in one call —
//! Fitmap analysis (§3.1), quadrangulation and limit interpolation (§3.2),
//! simplification with local fitting (§3.3–3.4), global fit and
//! displacement (§3.5), outputs and metrics (§4).

use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::analysis::FitmapOptions;
use crate::error::{Error, Result};
use crate::fit::{FitOptions, Objective};
use crate::mesh::{Frame, ValidatedMesh};
use crate::quad::{simplify_with_progress, Simplified, SimplifyOptions};
use crate::raycast::{make_raycaster, RayBackend};
use crate::report::{
    fit_and_measure, measure_fitted, write_converted, Converted, MetricsOptions, PipelineOptions,
    Report, StageTimer, TargetCheck,
};

/// Options of [`convert`], mirroring `subdfit convert`.
#[derive(Clone, Debug, Serialize)]
#[non_exhaustive]
pub struct ConvertOptions {
    /// τ of the M-fitmap (§3.1.3), a fraction: the only parameter of the
    /// method. `None`: the Fitmap's default.
    pub tolerance: Option<f64>,
    /// Stop the simplification at this many faces (the paper's "*" rows).
    pub target_faces: Option<usize>,
    /// Lift the projectability test (the paper's Fig. 7 experiment).
    pub no_m_fitmap: bool,
    pub objective: Objective,
    /// Displacement samples per patch side; `None`: total ≈ M's vertices.
    pub displacement_res: Option<usize>,
    /// Per-patch displacement resolution under this many samples in all
    /// (`--displacement-samples`); `None`: the uniform grid.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub displacement_samples: Option<usize>,
    /// Which pipeline: Fitmaps (organic), Lavoué et al. (mechanical), or
    /// chosen from the share of sharp edges (auto, the default).
    pub mode: Mode,
    /// An RMS distance bound, fraction of the diagonal. Mechanical mode:
    /// Lavoué et al.'s `E_limit` per control face; `None`:
    /// [`crate::mechanical::DEFAULT_MAX_ERROR`]. Organic mode: RMS L of
    /// the whole surface, met with the fewest patches the simplification
    /// passed through (see [`DEFAULT_ORGANIC_MAX_ERROR`]); `None`: that
    /// default, unless `target_faces` is given; infinity: the natural end.
    pub max_error: Option<f64>,
    /// Cells per patch side of `limit.ply` / `displaced.ply`; `None`: the
    /// default of [`crate::report::tessellate`].
    pub tessellation: Option<usize>,
    /// The mesh the layout stages (Fitmap, quadrangulation,
    /// simplification) run on; see [`Proxy`].
    pub proxy: Proxy,
}

/// `convert --proxy`: the layout proxy M′ of the Fitmaps paper's §4 (its
/// Armadillo runs compute the control mesh from a simplified copy of the
/// input while every fit, projection and measurement refers to M). The
/// Fitmap, the quadrangulation and the simplification cost ~50 and ~150 µs
/// per vertex they see, the fit and the metrics scale with M's size
/// only through ray casting; so the layout runs on M′ (meshoptimizer's quadric
/// simplification, [`crate::mesh::decimate`]) and the rest on M.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Default, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Proxy {
    /// M′ of [`PROXY_AUTO_TRIANGLES`] triangles when M has more than
    /// [`PROXY_AUTO_ABOVE`].
    #[default]
    Auto,
    /// The layout runs on M itself.
    None,
    /// M′ of about this many triangles when M has more.
    Triangles(usize),
}

/// The size of [`Proxy::Auto`]'s M′, in triangles: the final control
/// meshes of the paper's τ range have 10²–10³ patches, and 50k triangles
/// still give every patch dozens of M′ vertices to choose its corners from,
/// while the layout stages (Fitmap, quadrangulation, simplification: ~200
/// µs per triangle they see on this 2-core machine) then cost ~10 s
/// whatever the size of M.
pub const PROXY_AUTO_TRIANGLES: usize = 50_000;

/// [`Proxy::Auto`] decimates only inputs above this many triangles: below
/// it the full-resolution layout costs under ~20 s and stays the reference
/// (the papers' meshes, 50–70k triangles, convert as before).
pub const PROXY_AUTO_ABOVE: usize = 100_000;

impl Proxy {
    /// The triangle count M′ should have for a mesh of `triangles`, or
    /// `None` when the layout runs on M.
    pub fn target(self, triangles: usize) -> Option<usize> {
        let (above, size) = match self {
            Proxy::Auto => (PROXY_AUTO_ABOVE, PROXY_AUTO_TRIANGLES),
            Proxy::None => return None,
            Proxy::Triangles(n) => (n, n),
        };
        (triangles > above).then_some(size)
    }
}

/// Organic mode's default RMS L bound (5‰ of the diagonal; issue 17: "no
/// input ends above RMS L 5‰ unless asked"). The simplification's natural
/// end is set by projectability and the Fitmap's predicted error
/// (§3.3.1), which ends small, smooth inputs coarser than that (spot at
/// τ = 5 %: 79 patches, 6.7‰); the bound then takes the fewest patches
/// along the simplification's own path that meet it (module docs of
/// [`fewest_within`]).
pub const DEFAULT_ORGANIC_MAX_ERROR: f64 = 5e-3;

/// How many intermediate meshes the simplification keeps for the organic
/// `max_error` search: 40 at ratio 1.06 reach 10× the natural end's count.
const ERROR_SEARCH_CHECKPOINTS: usize = 40;

/// `convert --mode`.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Default, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Mode {
    #[default]
    Auto,
    Organic,
    Mechanical,
}

impl Default for ConvertOptions {
    fn default() -> Self {
        ConvertOptions {
            tolerance: None,
            target_faces: None,
            no_m_fitmap: false,
            objective: Objective::Point,
            displacement_res: None,
            displacement_samples: None,
            mode: Mode::Auto,
            max_error: None,
            tessellation: None,
            proxy: Proxy::Auto,
        }
    }
}

impl ConvertOptions {
    pub fn with_tolerance(mut self, t: Option<f64>) -> Self {
        self.tolerance = t;
        self
    }
    pub fn with_target_faces(mut self, n: Option<usize>) -> Self {
        self.target_faces = n;
        self
    }
    pub fn with_m_fitmap(mut self, on: bool) -> Self {
        self.no_m_fitmap = !on;
        self
    }
    pub fn with_objective(mut self, o: Objective) -> Self {
        self.objective = o;
        self
    }
    pub fn with_displacement_res(mut self, r: Option<usize>) -> Self {
        self.displacement_res = r;
        self
    }
    pub fn with_displacement_samples(mut self, n: Option<usize>) -> Self {
        self.displacement_samples = n;
        self
    }
    pub fn with_mode(mut self, m: Mode) -> Self {
        self.mode = m;
        self
    }
    pub fn with_tessellation(mut self, n: Option<usize>) -> Self {
        self.tessellation = n;
        self
    }
    pub fn with_max_error(mut self, e: Option<f64>) -> Self {
        self.max_error = e;
        self
    }
    pub fn with_proxy(mut self, p: Proxy) -> Self {
        self.proxy = p;
        self
    }
}

/// Converts `input` and writes every output into `dir` (all or nothing).
/// `progress(stage, fraction)` is called per stage (`"fitmap"`,
/// `"simplify"`, then the fitting stages of [`fit_and_measure`] and
/// `"write"`); returning `false` cancels with [`Error::Cancelled`] and
/// writes nothing.
pub fn convert(
    input: &ValidatedMesh,
    opts: &ConvertOptions,
    extra_options: serde_json::Value,
    dir: &Path,
    progress: &mut crate::watch::Progress<'_>,
) -> Result<(Report, Vec<PathBuf>)> {
    let c = convert_in_memory(input, opts, extra_options, progress)?;
    let written = write_converted(input, &c, dir, None, progress)?;
    Ok((c.report, written))
}

/// [`convert`] without writing anything: the fitted control mesh, the
/// surfaces, the report and the Fitmap, for hosts that keep results in
/// memory (the C++ API).
pub fn convert_in_memory(
    input: &ValidatedMesh,
    opts: &ConvertOptions,
    extra_options: serde_json::Value,
    progress: &mut crate::watch::Progress<'_>,
) -> Result<Converted> {
    at_unit_scale(input, |m, _| {
        convert_at_unit_scale(m, opts, extra_options, progress)
    })
}

/// `subdfit fit` and the C++ API's fit: fits a given `control` to `input`
/// and measures it ([`fit_and_measure`] over an Embree caster), at the same
/// working frame as [`convert_in_memory`], so a mesh and its control mesh at
/// 1e20 fit as they do at unit scale.
pub fn fit_in_memory(
    input: &ValidatedMesh,
    mut control: crate::mesh::ControlMesh,
    opts: &PipelineOptions,
    mut timer: StageTimer,
    extra_options: serde_json::Value,
    progress: &mut crate::watch::Progress<'_>,
) -> Result<Converted> {
    at_unit_scale(input, |m, frame| {
        frame.points_to_unit(control.positions_mut());
        let caster = timer.run("raycaster", || make_raycaster(RayBackend::Embree, &m.mesh))?;
        let mut extra_options = extra_options;
        let fitmap = match &opts.fitmap {
            Some(fo) => proxied_fitmap(&m.mesh, fo, &mut timer, &mut extra_options, progress)?,
            None => None,
        };
        fit_and_measure(
            m,
            control,
            caster.as_ref(),
            opts,
            timer,
            extra_options,
            fitmap,
            progress,
        )
    })
}

/// `fitmap.ply`'s Fitmap for `fit` on a mesh above [`PROXY_AUTO_ABOVE`]
/// triangles: computed on the layout proxy M′ and carried to M's vertices,
/// as `convert` does (a full-resolution Fitmap of a 1.1M-triangle scan
/// took 47 s, twice the whole fit); `None` below the bound or when no
/// proxy keeps M's topology (the Fitmap is then computed on M after the
/// fit). What was tried goes to `report.json` as `options.run.fitmap_proxy`.
fn proxied_fitmap(
    mesh: &crate::mesh::TriMesh,
    fo: &FitmapOptions,
    timer: &mut StageTimer,
    extra_options: &mut serde_json::Value,
    progress: &mut crate::watch::Progress<'_>,
) -> Result<Option<crate::analysis::Fitmap>> {
    let (proxy, stats) = layout_proxy(mesh, Proxy::Auto, timer, progress)?;
    if let (Some(stats), Some(obj)) = (stats, extra_options.as_object_mut()) {
        obj.insert("fitmap_proxy".into(), stats);
    }
    let Some((m, c)) = proxy else {
        return Ok(None);
    };
    let stage = crate::fit::report_progress;
    stage(progress, "fitmap", 0.0)?;
    let fitmap = timer.run("fitmap", || {
        fitmap_reporting(&m, c.as_ref(), fo, &mut *progress)
    })?;
    stage(progress, "fitmap", 1.0)?;
    let fitmap = timer.run("fitmap transfer", || {
        fitmap.transferred(&m, c.as_ref(), mesh)
    })?;
    Ok(Some(fitmap))
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
    if !control.is_all_quads() {
        control = crate::subdiv::refine::refine_once_keeping_infinite(&control)?;
    }
    let caster = make_raycaster(RayBackend::Embree, &mesh)?;
    let mut m = crate::report::metrics(&mesh, &control, caster.as_ref(), opts)?;
    m.bbox_diagonal = input.mesh.bbox_diagonal();
    Ok(m)
}

/// Runs `run` on `input` in its working frame ([`Frame`]: centred, unit
/// diagonal, snapped; `run` gets the mesh and the frame, to map whatever
/// else it measures against it), then maps the result back.
fn at_unit_scale(
    input: &ValidatedMesh,
    run: impl FnOnce(&ValidatedMesh, &Frame) -> Result<Converted>,
) -> Result<Converted> {
    let frame = working_frame(&input.mesh);
    let mut unit = input.clone();
    frame.points_to_unit(&mut unit.mesh.positions);
    let mut c = run(&unit, &frame)?;
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

/// [`convert_in_memory`] on a mesh in its working frame.
fn convert_at_unit_scale(
    input: &ValidatedMesh,
    opts: &ConvertOptions,
    extra_options: serde_json::Value,
    progress: &mut crate::watch::Progress<'_>,
) -> Result<Converted> {
    let mut timer = StageTimer::default();
    let mesh = &input.mesh;
    let choice = match opts.mode {
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
    };
    let caster = timer.run("raycaster", || make_raycaster(RayBackend::Embree, mesh))?;
    if choice.mode == "organic" {
        return convert_organic(
            input,
            opts,
            choice,
            caster.as_ref(),
            timer,
            extra_options,
            progress,
        );
    }
    let auto = choice.how == "auto";
    let mechanical = convert_mechanical(
        input,
        opts,
        choice.clone(),
        caster.as_ref(),
        timer,
        extra_options.clone(),
        progress,
    )?;
    let doubt = second_opinion_reason(&mechanical.report);
    let Some(why) = doubt.filter(|_| auto) else {
        return Ok(mechanical);
    };
    // `--mode auto` ends with the pipeline that fits: a CAD-looking mesh
    // whose mechanical result misses its own target (an isotropically
    // remeshed statue with flat parts and a few sharp edges) is converted
    // by the organic pipeline too, and the lower RMS distance is kept.
    let mut organic_choice = choice.clone();
    organic_choice.mode = "organic";
    organic_choice.reason = format!("{}; {why}", choice.reason);
    let organic = convert_organic(
        input,
        opts,
        organic_choice,
        caster.as_ref(),
        StageTimer::default(),
        extra_options,
        progress,
    )?;
    Ok(keep_better(mechanical, organic, &why))
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

/// The one of two conversions of the same mesh with the lower RMS distance
/// from its limit surface to M (ties: mechanical, the smaller control
/// mesh); its report says what was compared and why.
fn keep_better(mechanical: Converted, organic: Converted, why: &str) -> Converted {
    let rms = |c: &Converted| c.report.accuracy.limit.rms_permille;
    let summary = |c: &Converted| {
        serde_json::json!({
            "rms_limit_permille": rms(c),
            "unprojectable_area_percent": c.report.projectability.unprojectable_area_percent,
            "faces": c.report.control.faces,
            "seconds": c.report.stages.iter().map(|s| s.seconds).sum::<f64>(),
        })
    };
    let organic_wins = rms(&organic) < rms(&mechanical);
    let note = serde_json::json!({
        "why": why,
        "mechanical": summary(&mechanical),
        "organic": summary(&organic),
        "kept": if organic_wins { "organic" } else { "mechanical" },
    });
    let mut kept = if organic_wins { organic } else { mechanical };
    kept.report.options["mode"]["second_opinion"] = note;
    kept
}

/// The organic branch of [`convert`]: the Fitmaps pipeline, §3.1–3.5.
#[allow(clippy::too_many_arguments)]
fn convert_organic(
    input: &ValidatedMesh,
    opts: &ConvertOptions,
    choice: crate::mechanical::ModeChoice,
    caster: &dyn crate::raycast::RayCaster,
    mut timer: StageTimer,
    extra_options: serde_json::Value,
    progress: &mut crate::watch::Progress<'_>,
) -> Result<Converted> {
    let mesh = &input.mesh;
    if let Err(why) = crate::analysis::fitmap::fitmap_radii(mesh) {
        return convert_coarse(
            input,
            opts,
            choice,
            caster,
            timer,
            extra_options,
            why,
            progress,
        );
    }
    let extra_options = serde_json::json!({ "mode": choice, "options": extra_options });
    let mut fo = FitmapOptions::default();
    if let Some(t) = opts.tolerance {
        fo = fo.with_tolerance(t);
    }
    let max_error = match (opts.max_error, opts.target_faces) {
        (Some(e), _) => Some(e).filter(|e| e.is_finite()),
        (None, None) => Some(DEFAULT_ORGANIC_MAX_ERROR),
        (None, Some(_)) => None,
    };
    let (simplified, fitmap, proxy_stats) = organic_layout(
        mesh,
        caster,
        opts,
        &fo,
        max_error.is_some(),
        &mut timer,
        progress,
    )?;
    let po = PipelineOptions::default()
        .with_fit(FitOptions::default().with_objective(opts.objective))
        .with_metrics(
            MetricsOptions::default()
                .with_displacement_res(opts.displacement_res)
                .with_displacement_samples(opts.displacement_samples)
                .with_output_tessellation(opts.tessellation),
        )
        .with_fitmap(Some(fo));
    let Simplified {
        mesh: end,
        stats,
        checkpoints,
    } = simplified;
    let extra = |search: Option<&ErrorSearch>| {
        serde_json::json!({
            "mode": extra_options["mode"],
            "convert": opts,
            "layout_proxy": proxy_stats,
            "simplification": stats,
            "max_error_search": search,
            "run": extra_options["options"],
        })
    };
    let Some(e) = max_error else {
        let fitted = timer.run("fit", || {
            crate::fit::fit_with_progress(mesh, end, caster, &po.fit, progress)
        })?;
        let mut c = measure_fitted(
            input,
            fitted,
            caster,
            &po,
            timer,
            extra(None),
            Some(fitmap),
            progress,
        )?;
        if let Some(n) = opts.target_faces {
            c.report.add_target(faces_target(n, &stats, &c.report));
        }
        return Ok(c);
    };
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
        let mut c = measure_fitted(
            input,
            fitted,
            caster,
            &po,
            timer.clone(),
            extra(Some(&search.record)),
            Some(fitmap.clone()),
            progress,
        )?;
        let rms = c.report.accuracy.limit.rms_permille;
        let e = search.record.max_error_permille;
        if rms <= e || round == ROUNDS || i + 1 == search.len() {
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
        // Next round: a bound below this candidate's fit RMS by the
        // metrics' ratio, so that it (and every smaller one) misses.
        bound = (bound * e / rms).min(fit_rms * (1.0 - 1e-9));
    }
}

/// The organic layout (Fitmaps §3.1–3.3): the Fitmap and the simplified
/// control mesh, on the layout proxy M′ when there is one (§4; the Fitmap
/// then transferred to M's vertices for fitmap.ply and the pictures), with
/// the proxy's record for the report.
fn organic_layout(
    mesh: &crate::mesh::TriMesh,
    caster: &dyn crate::raycast::RayCaster,
    opts: &ConvertOptions,
    fo: &FitmapOptions,
    checkpoints: bool,
    timer: &mut StageTimer,
    progress: &mut crate::watch::Progress<'_>,
) -> Result<(
    Simplified,
    crate::analysis::Fitmap,
    Option<serde_json::Value>,
)> {
    let stage = crate::fit::report_progress;
    let (proxy, proxy_stats) = layout_proxy(mesh, opts.proxy, timer, progress)?;
    let (layout, layout_caster) = match &proxy {
        Some((m, c)) => (m, c.as_ref()),
        None => (mesh, caster),
    };
    stage(progress, "fitmap", 0.0)?;
    let fitmap = timer.run("fitmap", || {
        fitmap_reporting(layout, layout_caster, fo, &mut *progress)
    })?;
    stage(progress, "fitmap", 1.0)?;
    let so = SimplifyOptions::default()
        .with_target_faces(opts.target_faces)
        .with_m_fitmap(!opts.no_m_fitmap)
        .with_checkpoints(if checkpoints {
            ERROR_SEARCH_CHECKPOINTS
        } else {
            0
        });
    stage(progress, "simplify", 0.0)?;
    let simplified = timer.run("simplify", || {
        simplify_with_progress(layout, &fitmap, layout_caster, &so, &mut |p| {
            let goal = p
                .initial_faces
                .saturating_sub(opts.target_faces.unwrap_or(0))
                .max(1);
            let done = p.initial_faces.saturating_sub(p.faces) as f64 / goal as f64;
            progress("simplify", done.min(0.99))
        })
    })?;
    stage(progress, "simplify", 1.0)?;
    // fitmap.ply and the pictures show the Fitmap on M's own vertices.
    let fitmap = match &proxy {
        Some((m, c)) => timer.run("fitmap transfer", || {
            fitmap.transferred(m, c.as_ref(), mesh)
        })?,
        None => fitmap,
    };
    Ok((simplified, fitmap, proxy_stats))
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

/// What the organic `max_error` search tried and kept (`report.json`'s
/// `options.run.max_error_search`).
#[derive(Clone, Debug, Serialize)]
pub struct ErrorSearch {
    pub max_error_permille: f64,
    /// `(faces, RMS L ‰ by the fit's own samples)` of every candidate
    /// fitted, in the order tried.
    pub tried: Vec<(usize, f64)>,
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
/// fitted (§3.5) at most once and kept (they are small: the search never
/// goes past 10× the natural end's count).
struct ErrorSearcher {
    candidates: Vec<Option<crate::mesh::ControlMesh>>,
    faces: Vec<usize>,
    fits: Vec<Option<crate::fit::Fitted>>,
    record: ErrorSearch,
}

impl ErrorSearcher {
    fn new(
        end: crate::mesh::ControlMesh,
        checkpoints: Vec<crate::mesh::ControlMesh>,
        max_error: f64,
    ) -> ErrorSearcher {
        let candidates: Vec<_> = std::iter::once(end).chain(checkpoints).map(Some).collect();
        let faces: Vec<usize> = candidates
            .iter()
            .map(|c| c.as_ref().map_or(0, |c| c.num_faces()))
            .collect();
        ErrorSearcher {
            fits: vec![None; faces.len()],
            record: ErrorSearch {
                max_error_permille: 1e3 * max_error,
                tried: Vec::new(),
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

    /// The fit RMS (‰) of candidate `i`, fitting it the first time.
    fn rms(
        &mut self,
        i: usize,
        mesh: &crate::mesh::TriMesh,
        caster: &dyn crate::raycast::RayCaster,
        fo: &FitOptions,
        progress: &mut crate::watch::Progress<'_>,
    ) -> Result<f64> {
        if let Some(f) = &self.fits[i] {
            return Ok(f.report.final_rms_permille);
        }
        let c = self.candidates[i].take().ok_or_else(|| {
            Error::InvalidArgument(format!("max_error search: candidate {i} lost"))
        })?;
        let f = crate::fit::fit_with_progress(mesh, c, caster, fo, progress)?;
        let rms = f.report.final_rms_permille;
        self.record.tried.push((self.faces[i], rms));
        self.fits[i] = Some(f);
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
                        .is_some_and(|f| (f.report.final_rms_permille <= bound) == pass)
                })
                .collect()
        };
        let mut lo = known(self, false).into_iter().max();
        let mut best = known(self, true)
            .into_iter()
            .filter(|&i| lo.map_or(true, |l| i > l))
            .min();
        if lo.is_none() && best != Some(0) {
            if self.rms(0, mesh, caster, fo, progress)? <= bound {
                best = Some(0);
            } else {
                lo = Some(0);
            }
        }
        if let Some(mut l) = lo {
            let r = self.rms(l, mesh, caster, fo, progress)?;
            let predicted = self.faces[l] as f64 * r / bound;
            let mut next = self
                .faces
                .partition_point(|&n| (n as f64) < predicted)
                .clamp((l + 1).min(last), last);
            while best.map_or(last + 1, |b| b) - l > 1 {
                if self.rms(next, mesh, caster, fo, progress)? <= bound {
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
        let f = self.fits[i]
            .clone()
            .ok_or_else(|| Error::InvalidArgument(format!("max_error search: {i} unfitted")))?;
        Ok((i, f))
    }
}

/// The layout proxy M′ for `proxy` (see [`Proxy`]) with an Embree caster
/// over it, or `None` when the layout runs on M; and what was done, for
/// the report. M′ is used only when it has M's [`Topology`] (components,
/// boundary loops, Euler characteristic): the control mesh inherits the
/// layout mesh's topology, so a decimation that closed a handle or pinched
/// a part off would give a wrong surface, not just a coarser one. A failed
/// check retries at twice the triangles, up to [`PROXY_ATTEMPTS`] times,
/// then falls back to M (the report says why).
fn layout_proxy(
    mesh: &crate::mesh::TriMesh,
    proxy: Proxy,
    timer: &mut StageTimer,
    progress: &mut crate::watch::Progress<'_>,
) -> Result<(Option<LayoutProxy>, Option<serde_json::Value>)> {
    use crate::mesh::Topology;
    let Some(mut triangles) = proxy.target(mesh.triangles.len()) else {
        return Ok((None, None));
    };
    crate::fit::report_progress(progress, "proxy", 0.0)?;
    let found = timer.run("proxy", || -> Result<_> {
        let want = Topology::of(mesh);
        let mut tried = Vec::new();
        for _ in 0..PROXY_ATTEMPTS {
            if 2 * triangles > mesh.triangles.len() {
                break;
            }
            let (m, stats) = crate::mesh::decimate(mesh, triangles)?;
            let got = Topology::of(&m);
            tried.push(serde_json::json!({
                "target_triangles": triangles,
                "triangles": m.triangles.len(),
                "topology": got,
                "decimation": stats,
            }));
            if got == want {
                let c = make_raycaster(RayBackend::Embree, &m)?;
                return Ok((Some((m, c)), tried, want));
            }
            triangles *= 2;
        }
        Ok((None, tried, want))
    })?;
    crate::fit::report_progress(progress, "proxy", 1.0)?;
    let (m, tried, want) = found;
    let stats = serde_json::json!({
        "used": m.is_some(),
        "input_triangles": mesh.triangles.len(),
        "input_topology": want,
        "attempts": tried,
    });
    Ok((m, Some(stats)))
}

/// M′ and a ray caster over it.
type LayoutProxy = (crate::mesh::TriMesh, Box<dyn crate::raycast::RayCaster>);

/// Decimations tried for a layout proxy with M's topology (targets 1×, 2×,
/// 4× the bound) before the layout runs on M.
const PROXY_ATTEMPTS: usize = 3;

/// The organic branch for a mesh coarser than the Fitmap's radii (its mean
/// edge is longer than a quarter of its diagonal: a tetrahedron, a box of
/// a few triangles), where §3.1's analysis is undefined and there is
/// nothing to simplify: its own faces, refined once so that every face is
/// a quad (the same limit surface's domain, §3.2's all-quad requirement),
/// are the control mesh, fitted as any other (§3.4).
#[allow(clippy::too_many_arguments)]
fn convert_coarse(
    input: &ValidatedMesh,
    opts: &ConvertOptions,
    choice: crate::mechanical::ModeChoice,
    caster: &dyn crate::raycast::RayCaster,
    mut timer: StageTimer,
    extra_options: serde_json::Value,
    why: Error,
    progress: &mut crate::watch::Progress<'_>,
) -> Result<Converted> {
    let mesh = &input.mesh;
    if !(mesh.bbox_diagonal().is_finite() && mesh.bbox_diagonal() > 0.0) {
        return Err(why);
    }
    let control = timer.run("control", || coarse_control(mesh))?;
    let po = PipelineOptions::default()
        .with_fit(FitOptions::default().with_objective(opts.objective))
        .with_metrics(
            MetricsOptions::default()
                .with_displacement_res(opts.displacement_res)
                .with_displacement_samples(opts.displacement_samples)
                .with_output_tessellation(opts.tessellation),
        );
    let extra = serde_json::json!({
        "mode": choice,
        "convert": opts,
        "coarse_input": format!(
            "no Fitmap ({why}): the input's own faces, refined once into quads, are the control mesh, its sharp edges (dihedral > {}°) infinitely sharp creases",
            crate::mechanical::SHARP_DIHEDRAL_DEG
        ),
        "run": extra_options,
    });
    fit_and_measure(input, control, caster, &po, timer, extra, None, progress)
}

/// [`convert_coarse`]'s control mesh: M's triangles with its sharp edges
/// as infinitely sharp creases and the vertices where three or more meet
/// as corners (so a tetrahedron or a box is reproduced exactly: each face's
/// limit patch is the planar face), refined once into quads.
fn coarse_control(mesh: &crate::mesh::TriMesh) -> Result<crate::mesh::ControlMesh> {
    use crate::mesh::{ControlMesh, VertexId, INFINITELY_SHARP};
    let mut base = ControlMesh::from_polygons(mesh.positions.clone(), &mesh.triangles)?;
    let topo = crate::mechanical::Topology::new(mesh);
    let mut sharp_degree = vec![0u32; mesh.positions.len()];
    for (e, sharp) in topo.edges.iter().zip(topo.sharp_edges()) {
        if sharp {
            base.set_crease(VertexId(e.v[0]), VertexId(e.v[1]), INFINITELY_SHARP)?;
            for v in e.v {
                sharp_degree[v as usize] += 1;
            }
        }
    }
    for (v, &d) in sharp_degree.iter().enumerate() {
        if d >= 3 {
            base.set_corner(VertexId(v as u32), INFINITELY_SHARP)?;
        }
    }
    crate::subdiv::refine::refine_once_keeping_infinite(&base)
}

/// The Fitmap (§3.1) with progress and cancellation, watched
/// ([`crate::watch::watched`]): the workers count their analysed vertices
/// and stop within one vertex each once the host said stop.
fn fitmap_reporting(
    mesh: &crate::mesh::TriMesh,
    caster: &dyn crate::raycast::RayCaster,
    fo: &FitmapOptions,
    progress: &mut crate::watch::Progress<'_>,
) -> Result<crate::analysis::Fitmap> {
    use std::sync::atomic::{AtomicUsize, Ordering};
    let done = AtomicUsize::new(0);
    let total = mesh.positions.len().max(1) as f64;
    crate::watch::watched(progress, |w| {
        w.report("fitmap", 0.0)?;
        crate::analysis::compute_fitmap_cancellable(mesh, caster, fo, &|k| {
            let d = done.fetch_add(k, Ordering::Relaxed) + k;
            w.report("fitmap", (d as f64 / total).min(0.99)).is_ok()
        })
    })
}

/// The mechanical branch of [`convert`] (Lavoué et al. 2007, see
/// [`crate::mechanical`]): the control mesh is built and fitted there, then
/// measured and written with the shared code.
///
/// The mechanical control mesh mixes triangles, quads and larger faces,
/// while the displacement atlas and the tessellations need quads: they are
/// computed on its Catmull-Clark refinement by one level (infinitely sharp
/// creases and corners re-tagged as infinitely sharp), which has *exactly*
/// the same limit surface. That refined mesh is the one written
/// (`control.obj`, `control.usda`, with the atlas UVs and the creases and
/// corners), so that a USD or Blender pipeline can apply the displacement;
/// `report.json`'s `control` counts the compact mesh (Lavoué et al.'s
/// Table 2 figures) and `control_written` the refined one.
#[allow(clippy::too_many_arguments)]
fn convert_mechanical(
    input: &ValidatedMesh,
    opts: &ConvertOptions,
    choice: crate::mechanical::ModeChoice,
    caster: &dyn crate::raycast::RayCaster,
    mut timer: StageTimer,
    extra_options: serde_json::Value,
    progress: &mut crate::watch::Progress<'_>,
) -> Result<Converted> {
    let mo = crate::mechanical::MechanicalOptions::default().with_max_error(
        opts.max_error
            .unwrap_or(crate::mechanical::DEFAULT_MAX_ERROR),
    );
    crate::fit::report_progress(progress, "mechanical", 0.0)?;
    let built = timer.run("mechanical", || {
        crate::mechanical::build_control(&input.mesh, caster, &mo)
    })?;
    crate::fit::report_progress(progress, "mechanical", 1.0)?;
    let control = built.control;
    let quads = timer.run("refine", || {
        if control.is_all_quads() {
            return Ok(control.clone());
        }
        crate::subdiv::refine::refine_once_keeping_infinite(&control)
    })?;
    let mopts = MetricsOptions::default()
        .with_displacement_res(opts.displacement_res)
        .with_displacement_samples(opts.displacement_samples)
        .with_output_tessellation(opts.tessellation);
    let surfaces = timer.run("displacement+metrics", || {
        crate::report::evaluate_surfaces(&input.mesh, &quads, caster, &mopts, progress)
    })?;
    let extra = serde_json::json!({
        "mode": choice,
        "convert": opts,
        "mechanical": { "options": mo, "stats": built.stats },
        "run": extra_options,
    });
    let mut report = Report::new(
        input.report.clone(),
        &control,
        None,
        &surfaces.metrics,
        timer.stages,
        extra,
    );
    report.add_target(max_error_target(&mo, &built.stats));
    if !control.is_all_quads() {
        report.control_written = Some(crate::report::control_stats(&quads));
    }
    Ok(Converted {
        quad_control: (!control.is_all_quads()).then_some(quads),
        control,
        surfaces,
        report,
        fitmap: None,
        outputs: Default::default(),
    })
}

/// Mechanical mode's stated target (Lavoué et al. §7.2's `E_limit`): every
/// control face within RMS `max_error` of M at the end of enrichment.
fn max_error_target(
    mo: &crate::mechanical::MechanicalOptions,
    stats: &crate::mechanical::MechanicalStats,
) -> TargetCheck {
    let e = 1e3 * mo.max_error;
    let (over, faces, rms) = stats.rounds.last().map_or((0, 0, f64::NAN), |r| {
        (r.faces_over_limit, r.faces, r.rms_permille)
    });
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
