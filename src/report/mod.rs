//! Quality figures of a fitted surface (Fitmaps §4, Table 1) and the
//! `report.json` of a run. This module measures and writes; the run that
//! fits the surface is [`crate::convert`]'s.
//!
//! Units: every distance is in ‰ (thousandths) of M's bounding-box
//! diagonal, as in Table 1; percentages are of M's area or of samples, as
//! named.
//!
//! Accuracy of a surface S (the limit L or the displaced surface D) against
//! M is measured in both directions, on triangulations:
//! - S → M: sample points of S to their closest points of M;
//! - M → S: sample points of M to their closest points of S's tessellation.
//!
//! Sample points of a triangulated surface are those of the symmetric
//! 3-point quadrature rule (barycentrics (2/3, 1/6, 1/6) and permutations,
//! weight a third of the triangle's area each; exact for quadratics), not
//! the vertices: the limit surface of the initial control mesh interpolates
//! M's vertices and the displaced surface's vertices lie on M by
//! construction, so vertex samples would report zero error for both
//! whatever the surface does between them. L's tessellation is fine enough
//! (below) that its own vertices, weighted by a third of their triangles'
//! areas, serve as its samples (the 3-point rule there would cost 6× the
//! queries for the same figure).
//! RMS and mean are area-weighted; max is over all samples. `rms_permille`
//! of an [`Accuracy`] is the larger of the two directional RMS (a
//! symmetric figure that neither a surface covering only part of M nor one
//! with a fin sticking out can pass).
//!
//! Tessellations (of the measurements; the files have their own,
//! [`tessellate`]): L is evaluated (OpenSubdiv, isolation level 10, the
//! reference setting of STACK-NOTES) on a welded `t × t` grid per patch,
//! `t` large enough that L has about twice as many samples as M has
//! vertices (at least the displacement resolution, at most 64): its chordal
//! error is then well below M's own. Four times as many (the setting until
//! the scale work of issue 16) moved RMS L by a fraction of a percent for
//! a noticeable share of this stage's time (L's samples, its BVH and its
//! OpenSubdiv evaluation grow with `t²`). D is the displacement grid itself: the
//! limit point plus the measured offset at every `R × R` sample, linear in
//! between, each grid cell split along its shorter displaced diagonal —
//! what `displaced.ply` holds. By default the offsets are least-squares
//! ones ([`crate::displace::refine_offsets`], fitted on M's edge midpoints
//! and D's triangle centroids, not on the quadrature points measured here). Unprojectable samples carry their
//! inpainted offsets ([`crate::displace`]), so D is measured as written.
//! With per-patch resolutions (`--displacement-samples`) a coarse tile's
//! sample grid is far from the limit surface between its samples, so D is
//! instead the host's surface ([`crate::displace::HostSurface`]: the limit
//! point plus the bilinear lookup of the displacement vectors on a
//! tessellation twice as fine as each tile, at least
//! [`crate::displace::FIT_CELLS`] cells per patch side), which is also
//! what the offsets are fitted to; `displaced.ply` holds the same surface
//! at its own tessellation.
//!
//! Projectability (Table 1, "Unp."): the percentage of M's area not reached
//! correctly by the normal projection φ from L. For each triangle of M, its
//! centroid c is mapped to the closest point of L's tessellation, that
//! point's patch location is evaluated exactly, and φ is cast along the
//! exact limit normal; c counts as reached when φ lands within one mean edge
//! length of M from c (a miss, or a hit on another sheet of M, is not).

mod floor;
mod output;
mod sample;
pub mod tessellate;
pub mod written;

pub use floor::resampling_floor;
pub use sample::{DECISION_SAMPLES, METRIC_SAMPLES};
pub use written::WrittenReport;

pub use output::{
    is_known_name, remove_staging_folders, write_outputs, write_outputs_with, ExtraFiles,
    OutputFiles, OutputOptions, KNOWN_NAMES, OUTPUT_NAMES,
};

use std::collections::BTreeMap;
use std::time::Instant;

use serde::Serialize;

use crate::analysis::normals::triangle_areas;
use crate::displace::{
    allocate_resolutions, auto_resolution, compute_displacement, displacement_after,
    refine_offsets_keeping_d, BuiltD, Displacement, DisplacementStats, HostSurface,
    LsqOffsetOptions, OffsetMode, PatchGrid, Pilot, Reconstruction, SampleAllocation, FIT_CELLS,
};
use crate::error::{Error, Result};
use crate::fit::Progress;
use crate::mesh::{ControlMesh, TriMesh};
use crate::project::default_max_dist;
use crate::raycast::RayCaster;
use crate::raycast::Watched;
use crate::subdiv::{make_evaluator, Backend, EvalOptions};
use crate::DVec3;

/// Options of [`metrics`] / [`evaluate_surfaces`].
#[derive(Clone, Debug, Default, Serialize, serde::Deserialize)]
#[non_exhaustive]
pub struct MetricsOptions {
    /// Displacement samples per patch side; `None`: [`auto_resolution`]
    /// (total samples ≈ M's vertex count, Fitmaps §4).
    pub displacement_res: Option<usize>,
    /// Independent displacement samples in all, allocated per patch
    /// ([`crate::displace::allocate_resolutions`]); used when
    /// `displacement_res` is `None` and the allocation is adaptive.
    /// `None`: M's vertex count (Fitmaps §4).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub displacement_samples: Option<usize>,
    /// Per-patch resolutions under the budget (the default) or the
    /// uniform grid; `displacement_res` implies the uniform grid.
    pub displacement_allocation: SampleAllocation,
    /// How hosts read the maps: bilinear samples (the default) or
    /// B-spline coefficients for a cubic lookup
    /// ([`crate::displace::BsplineTiles`]); left out of `report.json`
    /// when bilinear.
    #[serde(default, skip_serializing_if = "Reconstruction::is_bilinear")]
    pub reconstruction: Reconstruction,
    /// Limit tessellation per patch side; `None`: see the module docs.
    pub tessellation_res: Option<usize>,
    /// φ's search distance; `None`: a quarter of M's diagonal.
    pub max_dist: Option<f64>,
    /// φ's hits, or least-squares offsets (the default).
    pub offsets: OffsetMode,
    /// Cells per patch side of `limit.ply` / `displaced.ply`; `None`: the
    /// default of [`tessellate`].
    pub output_tessellation: Option<usize>,
    /// Measure every point of every direction (`--exact-metrics`); off:
    /// D's directions of more than [`METRIC_SAMPLES`] points, and L's and
    /// the projectability's of more than [`DECISION_SAMPLES`], are
    /// measured on a stratified draw of that many (see `report::sample`).
    /// Left out of `report.json` when off.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub exact: bool,
    /// Gauss–Newton rounds of the least-squares offsets on the host
    /// surface (per-patch resolutions); `None`: [`HOST_LSQ_ROUNDS`]. Set
    /// by a caller whose layout makes the later rounds idle (see
    /// `convert`'s adaptive proxy). Left out of `report.json` when `None`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub host_lsq_rounds: Option<usize>,
}

impl MetricsOptions {
    pub fn with_displacement_res(mut self, r: Option<usize>) -> Self {
        self.displacement_res = r;
        self
    }
    pub fn with_displacement_samples(mut self, n: Option<usize>) -> Self {
        self.displacement_samples = n;
        self
    }
    pub fn with_displacement_allocation(mut self, a: SampleAllocation) -> Self {
        self.displacement_allocation = a;
        self
    }
    pub fn with_reconstruction(mut self, r: Reconstruction) -> Self {
        self.reconstruction = r;
        self
    }
    pub fn with_tessellation_res(mut self, r: Option<usize>) -> Self {
        self.tessellation_res = r;
        self
    }
    pub fn with_output_tessellation(mut self, n: Option<usize>) -> Self {
        self.output_tessellation = n;
        self
    }
    pub fn with_offsets(mut self, m: OffsetMode) -> Self {
        self.offsets = m;
        self
    }
    pub fn with_exact(mut self, e: bool) -> Self {
        self.exact = e;
        self
    }
    pub fn with_host_lsq_rounds(mut self, n: Option<usize>) -> Self {
        self.host_lsq_rounds = n;
        self
    }
}

/// Distances in one direction, ‰ of M's bounding-box diagonal.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct DistanceStats {
    pub rms_permille: f64,
    pub mean_permille: f64,
    /// Over the points measured: when they are a draw of the population
    /// (`samples < population`), only a lower bound of the max — a max has
    /// no confidence interval (`report::sample`); `--exact-metrics` gives
    /// the max of every point.
    pub max_permille: f64,
    /// Distinct points measured.
    pub samples: usize,
    /// Points of the direction (`samples` unless it was drawn from, see
    /// [`METRIC_SAMPLES`]).
    pub population: usize,
    /// Half-width of the 95 % confidence interval of `rms_permille`; 0 when
    /// every point was measured.
    pub rms_ci95_permille: f64,
    /// Half-width of the 95 % confidence interval of `mean_permille`; 0
    /// when every point was measured.
    pub mean_ci95_permille: f64,
}

/// Accuracy of one surface against M (see the module docs).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Accuracy {
    pub surface_to_mesh: DistanceStats,
    pub mesh_to_surface: DistanceStats,
    /// max of the two directional RMS.
    pub rms_permille: f64,
}

/// Table 1's figures for one control mesh.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Metrics {
    pub bbox_diagonal: f64,
    /// Limit surface L.
    pub limit: Accuracy,
    /// Displaced surface D.
    pub displaced: Accuracy,
    /// Percentage of M's area not reached by φ from L.
    pub unprojectable_area_percent: f64,
    /// Half-width of its 95 % confidence interval (0: every triangle of M
    /// was tested, see [`METRIC_SAMPLES`]).
    pub unprojectable_ci95_percent: f64,
    pub displacement: DisplacementStats,
    pub tessellation_res: usize,
    /// Where D's surface→mesh error sits (see [`DisplacedBreakdown`]).
    pub displaced_breakdown: DisplacedBreakdown,
    /// The tessellations written as `limit.ply` / `displaced.ply` (the
    /// figures above are measured on grids of their own, module docs).
    pub files: tessellate::TessellationStats,
}

/// Where the displaced surface's S → M error comes from. D's RMS is an
/// area integral dominated by a few regions: the displaced triangles that
/// touch an unprojectable sample (whose offset is inpainted: over a hole of
/// M, or where the limit surface runs past M's boundary, no normal offset
/// can bring the surface onto M), and the patches with the largest squared
/// error. Diagnostic figures next to the honest totals of
/// [`Metrics::displaced`], which include everything.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct DisplacedBreakdown {
    /// Percentage of D's area in triangles with at least one unprojectable
    /// corner sample.
    pub unprojectable_area_percent: f64,
    /// Percentage of D's area-weighted squared S → M distance in those
    /// triangles.
    pub unprojectable_error_share_percent: f64,
    /// S → M over the triangles whose three corners projected.
    pub surface_to_mesh_projected: DistanceStats,
    /// Percentage of D's area in patches with a boundary control vertex
    /// (where the limit surface may run past M's boundary), and their share
    /// of the squared error.
    pub boundary_patch_area_percent: f64,
    pub boundary_patch_error_share_percent: f64,
    /// The patches with the largest share of the squared error, largest
    /// first (at most [`WORST_PATCHES`]).
    pub worst_patches: Vec<PatchError>,
}

/// One patch's part of D's S → M error.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct PatchError {
    /// Face index in the control mesh.
    pub patch: usize,
    /// Percentage of D's area-weighted squared S → M distance.
    pub error_share_percent: f64,
    /// Area-weighted RMS S → M over the patch, ‰ of M's diagonal.
    pub rms_permille: f64,
    /// Unprojectable samples among the patch's R² grid samples.
    pub unprojectable_samples: usize,
    /// Whether a corner of the patch is a boundary vertex of the control mesh.
    pub boundary: bool,
}

/// How many patches [`DisplacedBreakdown::worst_patches`] lists.
pub const WORST_PATCHES: usize = 8;

/// The surfaces the metrics were measured on, for writing out.
#[derive(Clone, Debug)]
pub struct Surfaces {
    pub displacement: Displacement,
    /// `limit.ply`: L's tessellation (welded, watertight where the control
    /// mesh is), [`tessellate`].
    pub limit: TriMesh,
    /// `displaced.ply`: D on the same grid, [`tessellate`].
    pub displaced: TriMesh,
    /// Per vertex of `displaced`: offset and projected flag.
    pub displaced_offsets: Vec<f64>,
    pub displaced_projected: Vec<bool>,
    pub metrics: Metrics,
}

/// Table 1's accuracy and projectability for `control` against `mesh`
/// (`caster` built over `mesh`).
pub fn metrics(
    mesh: &TriMesh,
    control: &ControlMesh,
    caster: &dyn RayCaster,
    opts: &MetricsOptions,
) -> Result<Metrics> {
    Ok(evaluate_surfaces(mesh, control, caster, opts, &mut |_, _| true)?.metrics)
}

/// Displacement, tessellations and metrics in one go (stages
/// `"displacement"` and `"metrics"` for `progress`).
pub fn evaluate_surfaces(
    mesh: &TriMesh,
    control: &ControlMesh,
    caster: &dyn RayCaster,
    opts: &MetricsOptions,
    progress: &mut Progress<'_>,
) -> Result<Surfaces> {
    evaluate_surfaces_after(mesh, control, caster, opts, None, progress)
}

/// L's accuracy alone (RMS L, what the organic `--max-error` search
/// judges a candidate by): the first half of [`evaluate_surfaces`]'s L
/// side, without projectability, displacement, D's accuracy or the
/// tessellations. Handed to [`evaluate_surfaces_after`] for the same
/// `control`, it is not computed again there; the figures are the same
/// bits either way (the same functions on the same inputs, each
/// deterministic whatever the thread count).
pub struct LimitCheck {
    control: ControlMesh,
    evaluator: Box<dyn crate::subdiv::LimitEvaluator>,
    grid: PatchGrid,
    /// Built over `limit` (dropped before it).
    limit_caster: Box<dyn RayCaster>,
    limit: TriMesh,
    accuracy: Accuracy,
}

impl LimitCheck {
    /// L's accuracy against M (`accuracy.limit` of the metrics).
    pub fn accuracy(&self) -> &Accuracy {
        &self.accuracy
    }
}

/// The settings [`evaluate_surfaces`] derives from M and the control mesh.
struct Setup {
    diag: f64,
    max_dist: f64,
    /// The displacement grid's R and the tessellation's T (module docs).
    r: usize,
    t: usize,
}

impl Setup {
    fn of(mesh: &TriMesh, control: &ControlMesh, opts: &MetricsOptions) -> Result<Setup> {
        let diag = mesh.bbox_diagonal();
        if mesh.triangles.is_empty() || !(diag.is_finite() && diag > 0.0) {
            return Err(Error::invalid_data(
                "input mesh",
                "mesh",
                "is empty or has a degenerate bounding box; no metric is defined on it",
            ));
        }
        let max_dist = opts.max_dist.unwrap_or_else(|| default_max_dist(mesh));
        let patches = control.num_faces();
        let n = mesh.positions.len();
        // The uniform grid's R: given, or from the budget (M's vertex count
        // by default).
        let r = opts
            .displacement_res
            .unwrap_or_else(|| auto_resolution(opts.displacement_samples.unwrap_or(n), patches));
        let t = opts.tessellation_res.unwrap_or_else(|| {
            // Twice M's vertex count (module docs).
            let t = (2.0 * n as f64 / patches.max(1) as f64).sqrt().ceil() as usize + 1;
            t.clamp(r.min(64), 64).max(r)
        });
        Ok(Setup {
            diag,
            max_dist,
            r,
            t,
        })
    }
}

/// L's tessellation at `t` cells per patch side and its ray caster.
fn limit_surface(
    control: &ControlMesh,
    evaluator: &dyn crate::subdiv::LimitEvaluator,
    t: usize,
) -> Result<(PatchGrid, Box<dyn RayCaster>, TriMesh)> {
    let grid = PatchGrid::new(control, t)?;
    let limit_pts = evaluator.evaluate(control.positions(), grid.locations())?;
    let limit = TriMesh {
        positions: limit_pts.iter().map(|p| p.position).collect(),
        triangles: grid.triangles(),
    };
    // Asked for closest points only (M → L, `nearest_limit_locations`):
    // the cheaper build, same answers (`make_point_caster`).
    let limit_caster = crate::raycast::make_point_caster(&limit)?;
    Ok((grid, limit_caster, limit))
}

/// [`LimitCheck`] of `control` against `mesh` (`caster` built over it);
/// stage `"metrics"` for `progress`.
pub fn limit_check(
    mesh: &TriMesh,
    control: &ControlMesh,
    caster: &dyn RayCaster,
    opts: &MetricsOptions,
    progress: &mut Progress<'_>,
) -> Result<LimitCheck> {
    let Setup { diag, t, .. } = Setup::of(mesh, control, opts)?;
    let evaluator = make_evaluator(Backend::Osd, control, &EvalOptions::default())?;
    crate::watch::watched(progress, |w| {
        w.report("metrics", 0.0)?;
        let caster = &Watched::new(caster, w);
        let mq = Quadrature::new(mesh);
        let (grid, limit_caster, limit) = limit_surface(control, evaluator.as_ref(), t)?;
        let accuracy = {
            let l = (
                &limit,
                &Watched::new(limit_caster.as_ref(), w) as &dyn RayCaster,
            );
            limit_accuracy(caster, l, &mq, diag, opts.exact)?
        };
        w.report("metrics", 1.0)?;
        Ok(LimitCheck {
            control: control.clone(),
            evaluator,
            grid,
            limit,
            limit_caster,
            accuracy,
        })
    })
}

/// L's accuracy (`known`, else measured on `l`) and the tessellations'
/// density ([`tessellate::density`]: their chord-error grids need only L
/// and RMS L). Run on L's side, beside the displacement, whose serial
/// parts (the least squares' rows and solve, the BVH builds) otherwise
/// left this side's worker idle (session 22's profile of bunny: one worker
/// at about half the other's samples through the stage).
fn accuracy_and_density(
    known: Option<Accuracy>,
    caster: &dyn RayCaster,
    l: (&TriMesh, &dyn RayCaster),
    mq: &Quadrature<'_>,
    (control, evaluator): (&ControlMesh, &dyn crate::subdiv::LimitEvaluator),
    diag: f64,
    opts: &MetricsOptions,
) -> Result<(Accuracy, tessellate::Density)> {
    let acc = match known {
        Some(a) => a,
        None => limit_accuracy(caster, l, mq, diag, opts.exact)?,
    };
    let density = tessellate::density(
        control,
        evaluator,
        diag,
        opts.output_tessellation,
        acc.rms_permille,
    )?;
    Ok((acc, density))
}

/// [`evaluate_surfaces`], reusing `check` when it was made for this
/// `control` (else it is dropped and L measured afresh).
pub fn evaluate_surfaces_after(
    mesh: &TriMesh,
    control: &ControlMesh,
    caster: &dyn RayCaster,
    opts: &MetricsOptions,
    check: Option<LimitCheck>,
    progress: &mut Progress<'_>,
) -> Result<Surfaces> {
    let Setup {
        diag,
        max_dist,
        r,
        t,
    } = Setup::of(mesh, control, opts)?;
    let check = check.filter(|c| c.control == *control);
    let (evaluator, check) = match check {
        Some(c) => {
            let LimitCheck {
                evaluator,
                grid,
                limit,
                limit_caster,
                accuracy,
                ..
            } = c;
            (evaluator, Some((grid, limit_caster, limit, accuracy)))
        }
        None => (
            make_evaluator(Backend::Osd, control, &EvalOptions::default())?,
            None,
        ),
    };
    // Watched (`crate::watch`): every ray query below is chunked and a
    // cancellation ends the stage within one chunk.
    let (
        limit_acc,
        unprojectable_area_percent,
        displacement,
        displaced_acc,
        displaced_breakdown,
        files,
    ) = crate::watch::watched(progress, |w| {
        w.report("displacement", 0.0)?;
        let caster = &Watched::new(caster, w);
        let edge = mesh.mean_edge_length();
        // M's 3-point quadrature, the M → S samples of both L and D, its
        // points computed where drawn (`Quadrature`).
        let mq = Quadrature::new(mesh);
        crate::watch::memtrace("metrics: M quadrature");
        // L (tessellation, accuracy, projectability) and D (displacement,
        // least-squares offsets, accuracy) depend only on the control mesh and
        // M, not on each other: they run side by side, which keeps both cores
        // busy through the serial parts of each (OpenSubdiv's evaluation, the
        // inpainting, Eigen's solve, the BVH builds). Each side is
        // deterministic on its own, so the figures do not depend on the
        // thread count.
        let (limit_side, displaced_side) = rayon::join(
            || -> Result<_> {
                // Projectability, and L's accuracy unless the check
                // measured it, side by side.
                let (grid, limit_caster, limit, acc) = match check {
                    Some((g, c, l, a)) => (g, c, l, Some(a)),
                    None => {
                        let (g, c, l) = limit_surface(control, evaluator.as_ref(), t)?;
                        (g, c, l, None)
                    }
                };
                crate::watch::memtrace("limit: L built");
                let limit_caster = Watched::new(limit_caster.as_ref(), w);
                let (acc, unreached) = rayon::join(
                    || {
                        let l = (&limit, &limit_caster as &dyn RayCaster);
                        let on = (control, evaluator.as_ref());
                        accuracy_and_density(acc, caster, l, &mq, on, diag, opts)
                    },
                    || {
                        unprojectable_percent(
                            mesh,
                            caster,
                            control,
                            evaluator.as_ref(),
                            &grid,
                            &limit_caster,
                            max_dist,
                            edge,
                            opts.exact,
                        )
                    },
                );
                Ok((acc?, unreached?))
            },
            || {
                let at = Sampling {
                    mesh,
                    control,
                    r,
                    max_dist,
                    diag,
                    edge,
                    mq: &mq,
                };
                displaced_side(&at, evaluator.as_ref(), caster, w, opts)
            },
        );
        let ((limit_acc, density), unprojectable_area_percent) = limit_side?;
        let (displacement, displaced_acc, displaced_breakdown) = displaced_side?;
        crate::watch::memtrace("both sides done");
        let files = tessellate::tessellate_at(control, evaluator.as_ref(), &displacement, density)?;
        w.report("displacement", 1.0)?;
        w.report("metrics", 0.0)?;
        w.report("metrics", 1.0)?;
        Ok((
            limit_acc,
            unprojectable_area_percent,
            displacement,
            displaced_acc,
            displaced_breakdown,
            files,
        ))
    })?;
    let (unprojectable_area_percent, unprojectable_ci95_percent) = unprojectable_area_percent;
    let metrics = Metrics {
        bbox_diagonal: diag,
        limit: limit_acc,
        displaced: displaced_acc,
        unprojectable_area_percent,
        unprojectable_ci95_percent,
        displacement: displacement.stats.clone(),
        tessellation_res: t,
        displaced_breakdown,
        files: files.stats,
    };
    Ok(Surfaces {
        displacement,
        limit: files.limit,
        displaced: files.displaced,
        displaced_offsets: files.offsets,
        displaced_projected: files.projected,
        metrics,
    })
}

/// What both sides of [`evaluate_surfaces`] sample: M, its quadrature
/// `mq`, the control mesh and the displacement grid's settings.
struct Sampling<'a> {
    mesh: &'a TriMesh,
    control: &'a ControlMesh,
    r: usize,
    max_dist: f64,
    diag: f64,
    edge: f64,
    mq: &'a Quadrature<'a>,
}

/// M's fitting points in the least squares at most
/// ([`LsqOffsetOptions::m_samples`]): `SUBDFIT_TAIL_SAMPLES`, else every
/// edge midpoint of M.
fn lsq_m_samples() -> Option<usize> {
    crate::switches::parsed("SUBDFIT_TAIL_SAMPLES")
}

/// D's side of [`evaluate_surfaces`]: the displacement (§3.5), its
/// least-squares offsets, and D's accuracy both ways with its breakdown.
fn displaced_side(
    at: &Sampling<'_>,
    evaluator: &dyn crate::subdiv::LimitEvaluator,
    caster: &dyn RayCaster,
    w: &crate::watch::Watch,
    opts: &MetricsOptions,
) -> Result<(Displacement, Accuracy, DisplacedBreakdown)> {
    let Sampling {
        mesh,
        control,
        r,
        max_dist,
        diag,
        edge,
        mq,
    } = *at;
    // Adaptive unless a uniform grid is asked for (explicitly, or by
    // giving its resolution); the budget defaults to M's vertex count,
    // the density Fitmaps §4 (Table 1) states.
    let budget = (opts.displacement_res.is_none()
        && opts.displacement_allocation == SampleAllocation::Adaptive)
        .then(|| opts.displacement_samples.unwrap_or(mesh.positions.len()));
    crate::watch::memtrace("D side start");
    let mut displacement = match budget {
        None => compute_displacement(control, evaluator, caster, r, max_dist, diag, 0.5 * edge)?,
        Some(budget) => adaptive_displacement(at, evaluator, caster, budget)?,
    };
    // `SUBDFIT_DISP_SHEET`: the samples the same-sheet test rejected get
    // an orientation-consistent hit where their line has one nearby
    // (`displace::sheet`; off by default).
    if crate::displace::sheet::enabled() {
        crate::displace::sheet::resolve(
            &mut displacement,
            mesh,
            caster,
            max_dist,
            diag,
            0.5 * edge,
        )?;
    }
    // Per-patch resolutions: D is the surface a host reconstructs (the
    // limit surface plus the bilinear lookup of the vectors), on which the
    // offsets are also fitted; a coarse tile's own sample grid would be a
    // poor stand-in for it (`refine_offsets_on`).
    // The fit runs on a tessellation of at least `FIT_CELLS` cells per
    // patch side (`HostSurface::with_floor`, for the stage's time), and D
    // is measured on the same one (one host surface for both):
    // gargoyle τ 1 %, D → M 0.2557‰ against 0.2580‰ at 16 cells, M → D
    // 0.2243‰ against 0.2258‰, a quarter of the measuring points
    // (docs/status.md, "Adaptive displacement"); displaced.ply keeps its
    // own tessellation.
    // The B-spline reconstruction is always fitted and measured on the
    // host surface: its samples are coefficients, not points of D.
    displacement.reconstruction = opts.reconstruction;
    displacement.stats.reconstruction = opts.reconstruction;
    let adaptive =
        !displacement.grid.is_uniform() || opts.reconstruction == Reconstruction::Bspline;
    crate::watch::memtrace("displacement done");
    let host = match adaptive {
        false => None,
        true => Some(HostSurface::with_floor(
            control,
            evaluator,
            &displacement,
            FIT_CELLS,
        )?),
    };
    // D and its scene as the least squares' last kept round built them, at
    // exactly the offsets returned (the same bits a rebuild would give).
    let mut built = None;
    if opts.offsets == OffsetMode::LeastSquares {
        crate::watch::memtrace("host built");
        let (st, d) = refine_offsets_keeping_d(
            mesh,
            caster,
            &mut displacement,
            host.as_ref(),
            diag,
            &LsqOffsetOptions {
                rounds: if adaptive {
                    opts.host_lsq_rounds.unwrap_or(HOST_LSQ_ROUNDS)
                } else {
                    LsqOffsetOptions::default().rounds
                },
                m_samples: lsq_m_samples(),
                ..LsqOffsetOptions::default()
            },
        )?;
        let max_abs = displacement
            .offsets
            .iter()
            .fold(0.0f64, |m, d| m.max(d.abs()));
        displacement.stats.max_abs_offset_permille = 1000.0 * max_abs / diag;
        displacement.stats.least_squares = Some(st);
        built = d;
    }
    // D: the displacement grid, each cell split along its shorter
    // displaced diagonal (`PatchGrid::triangles_shorter_diagonal`).
    let (displaced, displaced_caster) = match built {
        Some(BuiltD { mesh, caster }) => (mesh, caster),
        None => {
            let displaced = displaced_mesh(&displacement, host.as_ref());
            crate::watch::memtrace("D mesh built");
            // Closest points only (M → D below): the cheaper build.
            let caster = crate::raycast::make_point_caster(&displaced)?;
            (displaced, caster)
        }
    };
    let displaced_caster = Watched::new(displaced_caster.as_ref(), w);
    // D's S → M by the 3-point rule, kept per point for the breakdown.
    // Both of D's directions only report (no decision reads them): drawn
    // at `METRIC_SAMPLES` (`report::sample`).
    let bound = (!opts.exact).then_some(METRIC_SAMPLES);
    let dq = Quadrature::new(&displaced);
    let (d2m, m2d) = rayon::join(
        || measure_direction(&dq, caster, diag, bound, sample::STREAM_D_TO_M),
        || {
            let to = &displaced_caster as &dyn RayCaster;
            sampled_distance_stats(mq, to, diag, bound, sample::STREAM_M_TO_D)
        },
    );
    let d2m = d2m?;
    crate::watch::memtrace("D measured");
    let acc = Accuracy::from_directions(d2m.stats.clone(), m2d?);
    // The triangles of D are the displacement grid's, or the host
    // surface's when there is one; only the patch of a triangle and the
    // projected flags of its points differ.
    let (tri_grid, projected) = match &host {
        None => (&displacement.grid, &displacement.projected[..]),
        Some(h) => (h.grid(), &h.projected[..]),
    };
    let bd = breakdown(
        control,
        &displacement,
        &displaced,
        (tri_grid, projected),
        (&dq.areas, &d2m),
        diag,
    );
    Ok((displacement, acc, bd))
}

/// D: the displacement grid, each cell split along its shorter displaced
/// diagonal, or the host surface's tessellation when there is one (the
/// surface the least squares fitted, `refine_offsets_on`).
fn displaced_mesh(displacement: &Displacement, host: Option<&HostSurface>) -> TriMesh {
    match host {
        None => {
            let displaced_positions = displacement.displaced_positions();
            TriMesh {
                triangles: displacement
                    .grid
                    .triangles_shorter_diagonal(&displaced_positions),
                positions: displaced_positions,
            }
        }
        Some(h) => h.mesh(displacement),
    }
}

/// Gauss–Newton rounds of the least squares on the host surface (per-patch
/// resolutions). Gargoyle τ 1 % at the default budget, RMS M →
/// displaced.ply: 0.250‰ after one round, 0.226‰ after three; bunny
/// 0.0965‰ after one and three. Two, for the stage's time
/// (docs/status.md, "Adaptive displacement").
const HOST_LSQ_ROUNDS: usize = 2;

/// The displacement of per-patch resolutions under `budget` samples
/// ([`allocate_resolutions`]).
fn adaptive_displacement(
    at: &Sampling<'_>,
    evaluator: &dyn crate::subdiv::LimitEvaluator,
    caster: &dyn RayCaster,
    budget: usize,
) -> Result<Displacement> {
    let (control, slack) = (at.control, 0.5 * at.edge);
    let alloc = allocate_resolutions(
        control,
        evaluator,
        caster,
        budget,
        at.max_dist,
        at.diag,
        slack,
    )?;
    let mut d = match alloc.pilot {
        // The final grid is the pilot's: its displacement, as computed.
        Pilot::Final(d) => d,
        Pilot::Probed(pilot) => {
            let grid =
                PatchGrid::with_resolutions_from(control, &alloc.resolutions, alloc.first_level)?;
            // The final grid's samples at or below the pilot's level are
            // the pilot's: their limit points, lines and closest points
            // are taken from it, not evaluated and cast again (the same
            // numbers).
            displacement_after(
                grid,
                &pilot,
                control,
                evaluator,
                caster,
                at.max_dist,
                at.diag,
                slack,
            )?
        }
    };
    d.stats.adaptive = Some(alloc.stats);
    Ok(d)
}

/// A third of the area of each vertex's triangles.
pub fn vertex_areas(mesh: &TriMesh) -> Vec<f64> {
    let mut w = vec![0.0; mesh.positions.len()];
    for (t, a) in mesh.triangles.iter().zip(triangle_areas(mesh)) {
        for &v in t {
            w[v as usize] += a / 3.0;
        }
    }
    w
}

/// Area-weighted distance statistics of `points` (weights `w`) to the
/// surface behind `to`, in ‰ of `diag`.
pub fn distance_stats(
    points: &[DVec3],
    w: &[f64],
    to: &dyn RayCaster,
    diag: f64,
) -> Result<DistanceStats> {
    Ok(stats_of(&closest_distances(points, to)?, w, diag))
}

/// Distance from each point to the surface behind `to`.
///
/// In Z-order sub-batches ([`crate::raycast::in_spatial_order`]), each
/// reduced to its distances at once: the whole batch's closest points (64
/// bytes each, 13M of them for M's quadrature on 4.4M triangles, two such
/// batches at a time) are never held.
fn closest_distances(points: &[DVec3], to: &dyn RayCaster) -> Result<Vec<f64>> {
    crate::raycast::in_spatial_order(
        points,
        |p| *p,
        |sub| {
            to.closest_points(sub, f64::INFINITY)?
                .iter()
                .map(|c| {
                    c.map(|c| c.distance).ok_or_else(|| {
                        Error::backend("ray caster", "closest point query returned nothing")
                    })
                })
                .collect()
        },
    )
}

/// Area-weighted statistics of distances `dist` (weights `w`, samples of
/// weight 0 skipped), in ‰ of `diag`.
fn stats_of(dist: &[f64], w: &[f64], diag: f64) -> DistanceStats {
    stats_of_pairs(dist.iter().copied().zip(w.iter().copied()), diag)
}

/// [`stats_of`] over `(distance, weight)` pairs in order.
fn stats_of_pairs(pairs: impl Iterator<Item = (f64, f64)>, diag: f64) -> DistanceStats {
    let (mut sw, mut s1, mut s2, mut max, mut count) = (0.0, 0.0, 0.0, 0.0f64, 0usize);
    for (d, wi) in pairs {
        if wi <= 0.0 {
            continue;
        }
        sw += wi;
        s1 += wi * d;
        s2 += wi * d * d;
        max = max.max(d);
        count += 1;
    }
    let k = 1000.0 / diag;
    let sw = sw.max(f64::MIN_POSITIVE);
    DistanceStats {
        rms_permille: k * (s2 / sw).sqrt(),
        mean_permille: k * s1 / sw,
        max_permille: k * max,
        samples: count,
        population: count,
        rms_ci95_permille: 0.0,
        mean_ci95_permille: 0.0,
    }
}

/// Points with weights, for one direction of a measure: a given set
/// (`(points, weights)`) or a triangulation's 3-point quadrature computed on
/// demand ([`Quadrature`]).
trait Weighted: Sync {
    fn len(&self) -> usize;
    fn weight(&self, i: usize) -> f64;
    fn point(&self, i: usize) -> DVec3;
}

impl Weighted for (&[DVec3], &[f64]) {
    fn len(&self) -> usize {
        self.0.len()
    }
    fn weight(&self, i: usize) -> f64 {
        self.1[i]
    }
    fn point(&self, i: usize) -> DVec3 {
        self.0[i]
    }
}

/// [`quadrature_points`] of a mesh without the arrays: point `3t + k` and
/// its weight are computed when asked for, from triangle `t`'s corners and
/// area (the same expressions, so the same bits). A direction drawn at
/// [`METRIC_SAMPLES`] reads 100k of them; the arrays of a 10M-triangle M
/// (30M points, 24 + 8 bytes each) were ~1 GB, and D's as many again.
pub(crate) struct Quadrature<'a> {
    mesh: &'a TriMesh,
    /// Per triangle, its area ([`triangle_areas`]).
    areas: Vec<f64>,
}

impl<'a> Quadrature<'a> {
    pub(crate) fn new(mesh: &'a TriMesh) -> Self {
        Quadrature {
            mesh,
            areas: triangle_areas(mesh),
        }
    }
}

impl Weighted for Quadrature<'_> {
    fn len(&self) -> usize {
        3 * self.areas.len()
    }
    fn weight(&self, i: usize) -> f64 {
        self.areas[i / 3] / 3.0
    }
    fn point(&self, i: usize) -> DVec3 {
        let [x, y, z] = self.mesh.triangle(i / 3);
        let (b0, b1, b2) = QUADRATURE[i % 3];
        (b0 * x + b1 * y + b2 * z) / 6.0
    }
}

/// The 3-point rule's barycentrics, times 6 ([`quadrature_points`]).
const QUADRATURE: [(f64, f64, f64); 3] = [(4.0, 1.0, 1.0), (1.0, 4.0, 1.0), (1.0, 1.0, 4.0)];

/// One direction measured ([`measure_direction`]): every measured point
/// of positive weight, by increasing index, with its distance and the
/// weight its figures were taken with (its own when every point was
/// measured; `W / m` per draw when drawn), the draws in stratum order with
/// their distances (`None`: every point), and the figures. Points neither
/// drawn nor weighted count as distance 0 and weight 0, which is what the
/// dense arrays this replaces held for them.
struct Direction {
    measured: Vec<(usize, f64, f64)>,
    draws: Option<Vec<(usize, f64)>>,
    stats: DistanceStats,
}

/// Distances of the points of `src` to the surface behind `to`, on
/// every point or, when there are more than `bound` (`None`: exact), on
/// the stratified draw of `stream` ([`sample::stratified_by`]), with the
/// 95 % intervals of the RMS and mean ([`sample::stratified_ci95`] of the
/// squared and plain distances; the RMS's through the square root by the
/// delta method).
fn measure_direction(
    src: &dyn Weighted,
    to: &dyn RayCaster,
    diag: f64,
    bound: Option<usize>,
    stream: u64,
) -> Result<Direction> {
    let n = src.len();
    let Some(keep) = sample::stratified_by(n, |i| src.weight(i), bound, stream) else {
        let points: Vec<DVec3> = (0..n).map(|i| src.point(i)).collect();
        let dist = closest_distances(&points, to)?;
        drop(points);
        let measured: Vec<(usize, f64, f64)> = dist
            .into_iter()
            .enumerate()
            .map(|(i, d)| (i, d, src.weight(i)))
            .filter(|e| e.2 > 0.0)
            .collect();
        let stats = stats_of_measured(&measured, diag);
        return Ok(Direction {
            measured,
            draws: None,
            stats,
        });
    };
    // A point drawn in several strata (heavier than W / m) is queried once:
    // the draws are non-decreasing, so repeats are adjacent.
    let mut unique = keep.clone();
    unique.dedup();
    let p: Vec<DVec3> = unique.iter().map(|&i| src.point(i)).collect();
    let du = closest_distances(&p, to)?;
    let mut at = 0;
    let d: Vec<f64> = keep
        .iter()
        .map(|&i| {
            while unique[at] != i {
                at += 1;
            }
            du[at]
        })
        .collect();
    let positive = || (0..n).map(|i| src.weight(i)).filter(|&x| x > 0.0);
    let total: f64 = positive().sum();
    let share = total / keep.len() as f64;
    // Each drawn point's weight is `share` once per draw, summed from 0
    // as the dense array's `+=` did.
    let mut measured: Vec<(usize, f64, f64)> = Vec::with_capacity(unique.len());
    for (&i, &di) in keep.iter().zip(&d) {
        match measured.last_mut() {
            Some(e) if e.0 == i => {
                e.1 = di;
                e.2 += share;
            }
            _ => measured.push((i, di, share)),
        }
    }
    measured.retain(|e| e.2 > 0.0);
    let mut stats = stats_of_measured(&measured, diag);
    stats.population = positive().count();
    let k = 1000.0 / diag;
    let d2: Vec<f64> = d.iter().map(|x| x * x).collect();
    stats.rms_ci95_permille =
        k * rms_half_width(stats.rms_permille / k, sample::stratified_ci95(&d2));
    stats.mean_ci95_permille = k * sample::stratified_ci95(&d);
    Ok(Direction {
        measured,
        draws: Some(keep.into_iter().zip(d).collect()),
        stats,
    })
}

/// [`stats_of`] over the measured points of a [`Direction`] (the points
/// of weight 0 it skips are the ones not listed).
fn stats_of_measured(measured: &[(usize, f64, f64)], diag: f64) -> DistanceStats {
    stats_of_pairs(measured.iter().map(|e| (e.1, e.2)), diag)
}

/// The half-width of an RMS's interval from that of its mean square
/// (`half_sq`), by the delta method (`d√x = dx / 2√x`); at an RMS of 0
/// (where the derivative is unbounded) the root of the square's.
fn rms_half_width(rms: f64, half_sq: f64) -> f64 {
    if rms > 0.0 {
        half_sq / (2.0 * rms)
    } else {
        half_sq.sqrt()
    }
}

/// [`measure_direction`]'s figures alone.
fn sampled_distance_stats(
    src: &dyn Weighted,
    to: &dyn RayCaster,
    diag: f64,
    bound: Option<usize>,
    stream: u64,
) -> Result<DistanceStats> {
    Ok(measure_direction(src, to, diag, bound, stream)?.stats)
}

impl Accuracy {
    fn from_directions(s2m: DistanceStats, m2s: DistanceStats) -> Accuracy {
        Accuracy {
            rms_permille: s2m.rms_permille.max(m2s.rms_permille),
            surface_to_mesh: s2m,
            mesh_to_surface: m2s,
        }
    }
}

/// [`DisplacedBreakdown`] from D's S → M direction `d2m` (three points
/// per triangle of `displaced`, D's tessellation, in order, as
/// [`quadrature_points`] makes them; `area`: their own weights). Areas are
/// every point's; error shares are the measured points' (with `d2m`'s
/// weights: estimates when it was drawn from). `of`: the grid whose
/// triangles `displaced` has (the patch of each triangle), and whether
/// each of its vertices reads projected samples only.
fn breakdown(
    control: &ControlMesh,
    displacement: &Displacement,
    displaced: &TriMesh,
    of: (&PatchGrid, &[bool]),
    (tri_areas, d2m): (&[f64], &Direction),
    diag: f64,
) -> DisplacedBreakdown {
    let measured = &d2m.measured[..];
    let grid = &displacement.grid;
    let tris = &displaced.triangles;
    let boundary_patch: Vec<bool> = control
        .faces()
        .map(|f| {
            control
                .face_vertices(f)
                .any(|v| control.is_boundary_vertex(v))
        })
        .collect();
    let (mut area, mut err) = (0.0, 0.0);
    let (mut u_area, mut u_err, mut b_area, mut b_err) = (0.0, 0.0, 0.0, 0.0);
    let mut patch_err = vec![0.0; grid.num_patches()];
    let mut patch_area = vec![0.0; grid.num_patches()];
    let mut proj_population = 0;
    let unprojectable = |t: usize| tris[t].iter().any(|&s| !of.1[s as usize]);
    // `measured` is sorted by point: a cursor walks it beside the points.
    let mut next = 0;
    for (t, &tri_area) in tri_areas.iter().enumerate() {
        let f = of.0.triangle_patch(t);
        // Each of the triangle's three points weighs a third of its area
        // (`quadrature_points`); an unmeasured point adds 0 error.
        let third = tri_area / 3.0;
        let (mut a, mut e) = (0.0, 0.0);
        for k in 3 * t..3 * t + 3 {
            a += third;
            e += match measured.get(next) {
                Some(&(i, d, w)) if i == k => {
                    next += 1;
                    w * d * d
                }
                _ => 0.0,
            };
        }
        area += a;
        err += e;
        patch_area[f] += a;
        patch_err[f] += e;
        if unprojectable(t) {
            u_area += a;
            u_err += e;
        } else if third > 0.0 {
            proj_population += 3;
        }
        if boundary_patch[f] {
            b_area += a;
            b_err += e;
        }
    }
    let pct = |x: f64, of: f64| 100.0 * x / of.max(f64::MIN_POSITIVE);
    let mut order: Vec<usize> = (0..grid.num_patches()).collect();
    // Largest share first; ties by index, so the list is deterministic.
    order.sort_by(|&a, &b| patch_err[b].total_cmp(&patch_err[a]).then(a.cmp(&b)));
    let worst_patches = order
        .into_iter()
        .take(WORST_PATCHES)
        .map(|f| {
            let mut unprojectable = 0;
            for j in 0..grid.patch_res(f) {
                for i in 0..grid.patch_res(f) {
                    if !displacement.projected[grid.sample(f, i, j) as usize] {
                        unprojectable += 1;
                    }
                }
            }
            PatchError {
                patch: f,
                error_share_percent: pct(patch_err[f], err),
                rms_permille: 1000.0 / diag
                    * (patch_err[f] / patch_area[f].max(f64::MIN_POSITIVE)).sqrt(),
                unprojectable_samples: unprojectable,
                boundary: boundary_patch[f],
            }
        })
        .collect();
    let mut projected = stats_of_pairs(
        measured
            .iter()
            .filter(|e| !unprojectable(e.0 / 3))
            .map(|e| (e.1, e.2)),
        diag,
    );
    if let Some(draws) = &d2m.draws {
        projected.population = proj_population;
        let k = 1000.0 / diag;
        let inside = |&(i, _): &(usize, f64)| !unprojectable(i / 3);
        let sq: Vec<(bool, f64)> = draws.iter().map(|x| (inside(x), x.1 * x.1)).collect();
        let plain: Vec<(bool, f64)> = draws.iter().map(|x| (inside(x), x.1)).collect();
        let half_sq = sample::domain_ci95(&sq);
        projected.rms_ci95_permille = k * rms_half_width(projected.rms_permille / k, half_sq);
        projected.mean_ci95_permille = k * sample::domain_ci95(&plain);
    }
    DisplacedBreakdown {
        unprojectable_area_percent: pct(u_area, area),
        unprojectable_error_share_percent: pct(u_err, err),
        surface_to_mesh_projected: projected,
        boundary_patch_area_percent: pct(b_area, area),
        boundary_patch_error_share_percent: pct(b_err, err),
        worst_patches,
    }
}

/// L's accuracy: its vertices (weighted by a third of their triangles'
/// areas) to M (`mesh_caster`), M's quadrature points `mp` (weights `mw`,
/// [`quadrature_points`]) to its tessellation (module docs).
fn limit_accuracy(
    mesh_caster: &dyn RayCaster,
    (surface, surface_caster): (&TriMesh, &dyn RayCaster),
    mq: &Quadrature<'_>,
    diag: f64,
    exact: bool,
) -> Result<Accuracy> {
    // RMS L steers geometry (module `sample`): drawn from only above
    // `DECISION_SAMPLES`.
    let bound = (!exact).then_some(DECISION_SAMPLES);
    let areas = vertex_areas(surface);
    let s2m = sampled_distance_stats(
        &(&surface.positions[..], &areas[..]),
        mesh_caster,
        diag,
        bound,
        sample::STREAM_L_TO_M,
    )?;
    let m2s = sampled_distance_stats(mq, surface_caster, diag, bound, sample::STREAM_M_TO_L)?;
    Ok(Accuracy::from_directions(s2m, m2s))
}

/// Projectability (module docs): the percentage of M's area whose
/// triangle centroids φ does not reach from L. `grid` is L's tessellation
/// grid, `limit_caster` built over it; `tol` is M's mean edge length.
/// Above [`DECISION_SAMPLES`] triangles (unless `exact`) a stratified draw
/// of them by area (`report::sample`), with the half-width of the
/// percentage's 95 % interval (else 0).
#[allow(clippy::too_many_arguments)]
fn unprojectable_percent(
    mesh: &TriMesh,
    caster: &dyn RayCaster,
    control: &ControlMesh,
    evaluator: &dyn crate::subdiv::LimitEvaluator,
    grid: &PatchGrid,
    limit_caster: &dyn RayCaster,
    max_dist: f64,
    tol: f64,
    exact: bool,
) -> Result<(f64, f64)> {
    let (mut areas, mut centroids) = (triangle_areas(mesh), mesh.centroids());
    let bound = (!exact).then_some(DECISION_SAMPLES);
    let keep = sample::stratified(&areas, bound, sample::STREAM_PROJECTABILITY);
    if let Some(keep) = &keep {
        // Drawn by area: each draw stands for the same share of M's area.
        areas = vec![1.0; keep.len()];
        centroids = keep.iter().map(|&t| centroids[t]).collect();
    }
    let locations = nearest_limit_locations(limit_caster, &centroids, |t, u, v| {
        grid.triangle_location(t, u, v)
    })?;
    let exact = evaluator.evaluate(control.positions(), &locations)?;
    let (hits, _) = crate::project::project_along_normals(caster, &exact, max_dist)?;
    let total_area: f64 = areas.iter().sum();
    let missed: Vec<f64> = hits
        .iter()
        .zip(&centroids)
        .map(|(h, c)| match h {
            Some(h) if (h.point - *c).length() <= tol => 0.0,
            _ => 1.0,
        })
        .collect();
    let unreached: f64 = missed
        .iter()
        .zip(&areas)
        .filter(|(m, _)| **m > 0.0)
        // fold from +0.0: `Sum` of no f64 is -0.0.
        .fold(0.0, |acc, (_, a)| acc + a);
    let ci = match keep {
        Some(_) => 100.0 * sample::stratified_ci95(&missed),
        None => 0.0,
    };
    Ok((100.0 * unreached / total_area.max(f64::MIN_POSITIVE), ci))
}

/// The limit-surface locations nearest to `points`, found on a tessellated
/// limit surface: `limit_caster` casts against the tessellation and
/// `location` maps one of its triangles and barycentrics back to the patch
/// parameter (the exact surface is then evaluated there, not the
/// tessellation).
pub(crate) fn nearest_limit_locations(
    limit_caster: &dyn RayCaster,
    points: &[DVec3],
    location: impl Fn(usize, f64, f64) -> crate::subdiv::SurfaceLocation,
) -> Result<Vec<crate::subdiv::SurfaceLocation>> {
    limit_caster
        .closest_points(points, f64::INFINITY)?
        .iter()
        .map(|c| {
            let c = c.ok_or_else(|| {
                Error::backend("ray caster", "closest point query returned nothing")
            })?;
            Ok(location(c.triangle as usize, c.u, c.v))
        })
        .collect()
}

/// The sample points and weights of the 3-point rule (module docs), three
/// per triangle in triangle order.
pub fn quadrature_points(mesh: &TriMesh) -> (Vec<DVec3>, Vec<f64>) {
    let areas = triangle_areas(mesh);
    let mut p = Vec::with_capacity(3 * mesh.triangles.len());
    let mut w = Vec::with_capacity(3 * mesh.triangles.len());
    for (t, &a) in areas.iter().enumerate() {
        let [x, y, z] = mesh.triangle(t);
        for (b0, b1, b2) in [(4.0, 1.0, 1.0), (1.0, 4.0, 1.0), (1.0, 1.0, 4.0)] {
            p.push((b0 * x + b1 * y + b2 * z) / 6.0);
            w.push(a / 3.0);
        }
    }
    (p, w)
}

/// Control-mesh statistics of `report.json`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ControlStats {
    pub faces: usize,
    pub vertices: usize,
    pub edges: usize,
    pub quads: usize,
    pub boundary_vertices: usize,
    pub irregular_vertices: usize,
    pub irregular_convention: &'static str,
    /// Valence (incident edges) → number of vertices.
    pub valence_histogram: BTreeMap<usize, usize>,
    pub creases: usize,
    pub corners: usize,
}

/// The convention of [`ControlStats::irregular_vertices`].
pub const IRREGULAR_CONVENTION: &str = "interior vertex with valence != 4; boundary vertex with \
     a number of incident faces other than 2, except boundary corners with exactly 1 face \
     (regular under edge-and-corner boundary interpolation)";

pub fn control_stats(control: &ControlMesh) -> ControlStats {
    let mut hist = BTreeMap::new();
    let mut irregular = 0;
    let mut boundary = 0;
    for v in control.vertices() {
        let val = control.valence(v);
        *hist.entry(val).or_insert(0) += 1;
        if control.is_boundary_vertex(v) {
            boundary += 1;
            let faces = control.vertex_faces(v).count();
            if faces != 2 && faces != 1 {
                irregular += 1;
            }
        } else if val != 4 {
            irregular += 1;
        }
    }
    ControlStats {
        faces: control.num_faces(),
        vertices: control.num_vertices(),
        edges: control.num_edges(),
        quads: control
            .faces()
            .filter(|&f| control.face_size(f) == 4)
            .count(),
        boundary_vertices: boundary,
        irregular_vertices: irregular,
        irregular_convention: IRREGULAR_CONVENTION,
        valence_histogram: hist,
        creases: control.creases().len(),
        corners: control.corners().len(),
    }
}

/// Peak resident memory of this process so far (`VmHWM` of
/// `/proc/self/status`), in MiB; `None` where there is no procfs.
pub fn peak_memory_mib() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

/// CPU time (user + system, all threads) this process has used so far, in
/// seconds, from `/proc/self/stat` (fields 14 and 15, in clock ticks of
/// 1/100 s, the Linux `USER_HZ` on every architecture it exports to user
/// space); `None` where there is no procfs.
pub fn process_cpu_seconds() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/stat").ok()?;
    // The command name (field 2) may hold spaces: count from its ')'.
    let rest = &s[s.rfind(')')? + 1..];
    let mut f = rest.split_whitespace().skip(11);
    let utime: f64 = f.next()?.parse().ok()?;
    let stime: f64 = f.next()?.parse().ok()?;
    Some((utime + stime) / 100.0)
}

/// Wall time, CPU time and peak memory of one stage. Peak memory is the
/// process-wide high-water mark at the end of the stage (it never
/// decreases: a stage's own peak is the first stage whose figure jumps).
/// CPU time is the whole process's (every thread) during the stage: on a
/// machine shared with other work the wall time grows with the load, the
/// CPU time much less, so it is the figure to compare runs by.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct StageStat {
    pub stage: String,
    pub seconds: f64,
    pub cpu_seconds: Option<f64>,
    pub peak_memory_mib: Option<f64>,
}

/// Collects [`StageStat`]s.
#[derive(Clone, Debug, Default)]
pub struct StageTimer {
    pub stages: Vec<StageStat>,
}

impl StageTimer {
    /// Runs `f` as stage `name`.
    pub fn run<T>(&mut self, name: &str, f: impl FnOnce() -> Result<T>) -> Result<T> {
        let t0 = Instant::now();
        let c0 = process_cpu_seconds();
        let r = f()?;
        self.stages.push(StageStat {
            stage: name.to_string(),
            seconds: t0.elapsed().as_secs_f64(),
            cpu_seconds: c0.zip(process_cpu_seconds()).map(|(a, b)| b - a),
            peak_memory_mib: peak_memory_mib(),
        });
        Ok(r)
    }
}

/// `report.json`: what was measured here, and `options`, the run's own
/// typed record of what it was given and did (`O`, written by the layer
/// that ran it: [`crate::convert::RunOptions`] for every conversion).
#[derive(Clone, Debug, Serialize)]
#[serde(bound(serialize = "O: Serialize"))]
pub struct Report<O> {
    /// `subdfit x.y.z` and the linked C++ libraries.
    pub version: BTreeMap<String, String>,
    pub input: crate::mesh::MeshReport,
    pub control: ControlStats,
    /// The mesh `control.obj` / `control.usda` carry when it is not
    /// `control` (mechanical mode: the compact quad/triangle mesh refined
    /// once into quads, the same limit surface); absent otherwise.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub control_written: Option<ControlStats>,
    pub fit: Option<crate::fit::FitReport>,
    pub accuracy: ReportAccuracy,
    pub projectability: ReportProjectability,
    /// `limit.ply` / `displaced.ply`: cells per patch side, chord error.
    pub tessellation: tessellate::TessellationStats,
    pub stages: Vec<StageStat>,
    /// The options of the run, as given. Written with its keys sorted at
    /// every level (see [`sorted`]), as the file always had them.
    #[serde(serialize_with = "sorted")]
    pub options: O,
    /// Whether every target the run was given (see [`Report::targets`])
    /// was met; `true` when it had none. `subdfit convert` warns when not,
    /// and exits 1 with `--strict`.
    pub targets_met: bool,
    /// The run's own stated targets and how they ended (mechanical
    /// `--max-error`).
    pub targets: Vec<TargetCheck>,
}

/// One stated target of a run and its outcome, for `report.json`.
#[derive(Clone, Debug, Serialize)]
pub struct TargetCheck {
    /// The option that set it, e.g. `"max_error"`.
    pub option: &'static str,
    /// What it promises, in words with the figures.
    pub target: String,
    pub met: bool,
    /// What the result gave, in words with the figures.
    pub outcome: String,
}

#[derive(Clone, Debug, Serialize)]
pub struct ReportAccuracy {
    pub unit: &'static str,
    pub limit: Accuracy,
    pub displaced: Accuracy,
    /// Where D's S → M error sits (diagnostic; `displaced` is the total).
    pub displaced_breakdown: DisplacedBreakdown,
}

#[derive(Clone, Debug, Serialize)]
pub struct ReportProjectability {
    /// % of M's area not reached by φ from the limit surface.
    pub unprojectable_area_percent: f64,
    /// Half-width of its 95 % confidence interval (0: measured on every
    /// triangle of M, see [`METRIC_SAMPLES`]).
    pub unprojectable_ci95_percent: f64,
    pub displacement: DisplacementStats,
}

/// Versions for [`Report::version`].
pub fn versions() -> BTreeMap<String, String> {
    let mut v = BTreeMap::new();
    v.insert("subdfit".to_string(), env!("CARGO_PKG_VERSION").to_string());
    for (name, ver) in crate::ffi::linked_library_versions() {
        v.insert(name.to_string(), ver);
    }
    v
}

/// Serializes `value` with the keys of its maps sorted at every level: a
/// typed record's fields are written in declaration order, `report.json`'s
/// `options` were always in key order (through [`serde_json::Value`],
/// whose maps sort), and stay so byte for byte.
fn sorted<O: Serialize, S: serde::Serializer>(value: &O, s: S) -> Result<S::Ok, S::Error> {
    serde_json::to_value(value)
        .map_err(serde::ser::Error::custom)?
        .serialize(s)
}

impl<O> Report<O> {
    /// Records a target's outcome (and clears [`Report::targets_met`] when
    /// it was missed).
    pub fn add_target(&mut self, t: TargetCheck) {
        self.targets_met &= t.met;
        self.targets.push(t);
    }

    pub fn new(
        input: crate::mesh::MeshReport,
        control: &ControlMesh,
        fit: Option<crate::fit::FitReport>,
        metrics: &Metrics,
        stages: Vec<StageStat>,
        options: O,
    ) -> Report<O> {
        Report {
            version: versions(),
            input,
            control: control_stats(control),
            control_written: None,
            fit,
            accuracy: ReportAccuracy {
                unit: "permille of the input's bounding-box diagonal",
                limit: metrics.limit.clone(),
                displaced: metrics.displaced.clone(),
                displaced_breakdown: metrics.displaced_breakdown.clone(),
            },
            projectability: ReportProjectability {
                unprojectable_area_percent: metrics.unprojectable_area_percent,
                unprojectable_ci95_percent: metrics.unprojectable_ci95_percent,
                displacement: metrics.displacement.clone(),
            },
            tessellation: metrics.files.clone(),
            stages,
            options,
            targets_met: true,
            targets: Vec::new(),
        }
    }
}
