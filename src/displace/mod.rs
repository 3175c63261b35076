//! Displacement (Fitmaps §1.2, §4): per patch of the control mesh an
//! `R × R` grid of scalar offsets along the limit normal, from the limit
//! surface S_K to M through the projection φ ([`crate::project`]). Samples
//! live on a welded [`PatchGrid`], so a sample on a patch edge is computed
//! once and stored identically in both tiles of the atlas.
//!
//! `R` is the same for every patch (`--displacement-res`, or
//! [`auto_resolution`]), or chosen per patch under a total of samples
//! (`--displacement-samples`, [`allocate_resolutions`]): `R_f = 2^k + 1`,
//! where the displacement has detail, with the in-between samples of an
//! edge between resolutions interpolating the coarser side's (see
//! [`PatchGrid`]), so every host's bilinear lookup reads the same function
//! along the edge from both tiles. The reconstruction is that bilinear
//! lookup in both cases: what `displaced.ply` is built with and what
//! hosts do with the written maps.
//!
//! Every sample gets φ's offset: the nearest intersection of its normal
//! line with M, in either direction. A sample is *unprojectable* when the
//! line meets M nowhere within the search distance, or only on another
//! sheet (see [`compute_displacement`]); it is counted in
//! [`DisplacementStats`] and its offset is *inpainted* from its neighbours
//! on the welded grid (a discrete harmonic fill), so that the displaced
//! surface stays continuous there instead of dropping back onto the limit
//! surface (an offset of 0 leaves the limit surface's whole error at the
//! sample, and a tent of it over the neighbouring triangles).
//!
//! **Direction.** A sample is displaced along the unit limit normal,
//! except on an infinitely sharp crease or at a corner (a control edge of
//! sharpness ≥ [`INFINITELY_SHARP`], a corner vertex, or an end of such an
//! edge), where the patches meeting there have different normals: there
//! the direction is the normalised sum of the unit normals of every patch
//! that contains the sample, each evaluated in its own patch
//! ([`sample_directions`]). The sample is welded (one offset, one
//! direction, whatever patch it is seen from), so the displaced surface
//! stays watertight along creases; displacing each patch along its own
//! normal there opens a gap of |d|·|n₁ − n₂|. Renderers that displace
//! along averaged vertex normals (Blender's Displace modifier) do the same
//! at a welded crease.
//!
//! φ's offsets make D interpolate M at the samples; [`refine_offsets`]
//! then replaces them by the offsets that minimise the integrated squared
//! distance between D and M in both directions (see its module), which
//! the report's pipeline does by default ([`OffsetMode`]).

mod alloc;
mod atlas;
mod bspline;
mod grid;
mod lsq;
pub mod sheet;

pub use alloc::{
    allocate_resolutions, first_level, first_level_for, level1_floor, AdaptiveStats, Allocation,
    Pilot, LEVEL0_ENV,
};

pub use atlas::{
    read_exr, read_exr_channels, Atlas, AtlasLayout, AtlasMap, TexelType, DEFAULT_GUTTER,
    MIP_LEVELS, UDIM_PATCHES,
};
pub use bspline::{refinement, weights as bspline_weights, BsplineTiles};
pub use grid::{Dependent, PatchGrid};
pub use lsq::{
    refine_offsets, refine_offsets_keeping_d, refine_offsets_on, BuiltD, HostSurface,
    LsqOffsetOptions, LsqOffsetStats, FIT_CELLS,
};

use serde::Serialize;

use crate::error::Result;
use crate::mesh::{ControlMesh, INFINITELY_SHARP};
use crate::project::{project_along, ProjectionStats};
use crate::raycast::RayCaster;
use crate::subdiv::{LimitEvaluator, LimitPoint, SurfaceLocation};
use crate::DVec3;

/// The per-patch resolution R that makes the number of distinct samples
/// of the welded grid roughly match M's vertex count (Fitmaps §4, Table 1:
/// the displaced surface resamples M at its own density). A patch owns
/// `(R − 1)²` of the welded samples (its border is shared with its
/// neighbours), so `R = round(√(n / patches)) + 1`; counting `R²` per patch
/// instead, as the tiles of the atlas do, undersamples M by up to half
/// (gargoyle at τ = 1 %: 13.3k distinct samples for 25k vertices, and RMS D
/// 0.64‰ instead of 0.44‰). At least 2 (the patch corners) and at most 64
/// (a 64² tile already exceeds any input density this pipeline produces
/// patches for).
pub fn auto_resolution(mesh_vertices: usize, patches: usize) -> usize {
    if patches == 0 {
        return 2;
    }
    let r = (mesh_vertices as f64 / patches as f64).sqrt().round() as usize + 1;
    r.clamp(2, 64)
}

/// How the displacement samples are spread over the patches (issue 37).
#[derive(
    Copy, Clone, Debug, PartialEq, Eq, Default, Serialize, serde::Deserialize, clap::ValueEnum,
)]
#[serde(rename_all = "snake_case")]
pub enum SampleAllocation {
    /// Per patch, `2^k + 1` per side where the detail is, under a total of
    /// samples (default ≈ M's vertex count, Fitmaps §4, Table 1;
    /// [`allocate_resolutions`]).
    #[default]
    Adaptive,
    /// The same `R × R` grid on every patch ([`auto_resolution`]): the
    /// behaviour before issue 37.
    Uniform,
}

/// The CLI's words (`adaptive`, `uniform`), for hosts that take the
/// allocation as a string.
impl std::str::FromStr for SampleAllocation {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<SampleAllocation, String> {
        <SampleAllocation as clap::ValueEnum>::from_str(s, false)
    }
}

/// How a host reads the displacement maps between texels, and so what
/// the written values are (issue 37 item 2).
#[derive(
    Copy, Clone, Debug, PartialEq, Eq, Default, Serialize, serde::Deserialize, clap::ValueEnum,
)]
#[serde(rename_all = "snake_case")]
pub enum Reconstruction {
    /// Bilinear lookup of samples of the displacement: what every host
    /// does (USD's `UsdUVTexture`, Blender's "Linear").
    #[default]
    Bilinear,
    /// The bicubic uniform B-spline of the texels, Blender/Cycles'
    /// "Cubic" image interpolation: the maps hold B-spline coefficients
    /// and a linear-extrapolation gutter ([`BsplineTiles`]). A host with
    /// only a bilinear lookup must not read these maps.
    Bspline,
}

impl Reconstruction {
    pub fn is_bilinear(&self) -> bool {
        *self == Reconstruction::Bilinear
    }
}

/// The CLI's words (`bilinear`, `bspline`).
impl std::str::FromStr for Reconstruction {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Reconstruction, String> {
        <Reconstruction as clap::ValueEnum>::from_str(s, false)
    }
}

/// How the displacement offsets are chosen.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Default, Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OffsetMode {
    /// φ's hit distances: D interpolates M at the samples (Fitmaps §1.2).
    Hit,
    /// φ's hits refined by least squares ([`refine_offsets`]).
    #[default]
    LeastSquares,
}

/// Counts of a displacement computation.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct DisplacementStats {
    pub resolution: usize,
    pub patches: usize,
    /// Distinct (welded) samples.
    pub samples: usize,
    /// Samples whose normal line misses M within the search distance, or
    /// meets it only on another sheet; their offsets are inpainted.
    pub unprojectable: usize,
    /// Of `unprojectable`, those whose line did hit M, on another sheet.
    pub other_sheet: usize,
    /// Percentage of samples with no projection.
    pub unprojectable_percent: f64,
    /// Largest |offset|, in ‰ of M's bounding-box diagonal.
    pub max_abs_offset_permille: f64,
    /// Set when the offsets were refined by least squares
    /// ([`refine_offsets`]) instead of kept at φ's hits.
    pub least_squares: Option<LsqOffsetStats>,
    /// How hosts must read the maps (bilinear samples, or B-spline
    /// coefficients for a cubic lookup); absent: bilinear, the report as
    /// before the option.
    #[serde(skip_serializing_if = "Reconstruction::is_bilinear")]
    pub reconstruction: Reconstruction,
    /// Set for a per-patch resolution under a sample budget
    /// (`--displacement-samples`); absent for a uniform grid, whose
    /// report is unchanged.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub adaptive: Option<AdaptiveStats>,
    /// With `SUBDFIT_DISP_SHEET`: the rejected samples given an
    /// orientation-consistent hit instead ([`sheet::resolve`]); absent
    /// otherwise, the report as before the switch.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sheet_resolved: Option<usize>,
}

/// Displacement samples on a welded grid: limit point, offset along the
/// unit limit normal, and whether φ reached M.
#[derive(Clone, Debug)]
pub struct Displacement {
    pub grid: PatchGrid,
    /// Limit point (with derivatives) at each global sample.
    pub limit: Vec<LimitPoint>,
    /// Unit displacement direction at each sample: the limit normal, or
    /// the crease rule of the module docs.
    pub directions: Vec<DVec3>,
    /// Signed offset along `directions` (inpainted where unprojectable).
    pub offsets: Vec<f64>,
    pub projected: Vec<bool>,
    pub stats: DisplacementStats,
    /// How the maps are read between samples: with
    /// [`Reconstruction::Bspline`] the offsets are B-spline coefficients
    /// ([`BsplineTiles`]), and [`Self::vectors`] at a sample is a
    /// coefficient, not a point of the displaced surface.
    pub reconstruction: Reconstruction,
}

impl Displacement {
    /// Positions of the limit surface at the samples.
    pub fn limit_positions(&self) -> Vec<DVec3> {
        self.limit.iter().map(|p| p.position).collect()
    }

    /// The displacement vector at each sample: `d·n` at the independent
    /// samples, and at a dependent one (on an edge between resolutions,
    /// [`PatchGrid::dependents`]) the linear interpolation of its coarse
    /// neighbours' vectors, the value the coarser tile's bilinear lookup
    /// gives there (what `displacement_vector.exr` holds in both tiles).
    pub fn vectors(&self) -> Vec<DVec3> {
        let mut v: Vec<DVec3> = self
            .offsets
            .iter()
            .zip(&self.directions)
            .map(|(&d, &n)| d * n)
            .collect();
        self.grid.apply_dependents(&mut v);
        v
    }

    /// Positions of the displaced surface `s + d·n` at the samples (at the
    /// dependent ones, `s` plus their interpolated vector, [`Self::vectors`]).
    pub fn displaced_positions(&self) -> Vec<DVec3> {
        self.limit
            .iter()
            .zip(self.vectors())
            .map(|(p, v)| p.position + v)
            .collect()
    }
}

/// How far beyond the distance to M a hit may lie and still be on the
/// sample's own sheet: the line may make up to acos(1/3) ≈ 71° with M's
/// normal at the closest point (see [`compute_displacement`]).
const SAME_SHEET_FACTOR: f64 = 3.0;

/// The same-sheet test of [`compute_displacement`] with its slack.
#[derive(Clone, Copy, Debug)]
pub(crate) struct SameSheet {
    /// `slack`, at least `1e-9` of the diagonal.
    slack: f64,
}

impl SameSheet {
    pub(crate) fn new(diag: f64, slack: f64) -> SameSheet {
        SameSheet {
            slack: slack.max(1e-9 * diag),
        }
    }

    /// Whether a hit at offset `hit` lies on another sheet than the
    /// sample, `distance` from M.
    fn other_sheet(&self, hit: f64, distance: f64) -> bool {
        hit.abs() > SAME_SHEET_FACTOR * distance + self.slack
    }

    /// How near M's closest point must lie for a line's nearest hit `hit`
    /// to fail [`Self::other_sheet`]; `None` when no distance can (no hit,
    /// or `|hit| ≤ slack`: `3·d + slack` rounds to at least `slack` for
    /// any `d ≥ 0`). A closest point beyond the radius cannot fail it:
    /// `d ≥ (|hit| − slack)/3 + 10⁻⁹|hit|` gives `3·d + slack ≥ |hit|·(1 +
    /// 3·10⁻⁹)`, a margin over the rounding of the sum and of the radius
    /// (relative errors of ~10⁻¹⁶) and over the backends' distance to a
    /// triangle against the one returned (the same formula in f64). So the
    /// test needs the distance only within the radius, where a bounded
    /// search gives the same closest point as an unbounded one
    /// ([`RayCaster::closest_points_within`]).
    fn radius(&self, hit: Option<f64>) -> Option<f64> {
        let h = hit?.abs();
        (h > self.slack).then(|| (h - self.slack) / SAME_SHEET_FACTOR + 1e-9 * h)
    }
}

/// Samples the limit surface of `control` on an `res × res` welded grid per
/// patch and measures the offset to M (`caster` is built over M) along the
/// limit normal, within `max_dist`. `diag` is M's bounding-box diagonal
/// (the unit of the reported figures); `slack` is an absolute tolerance of
/// the same-sheet test, half of M's mean edge length in the pipeline.
///
/// Same-sheet test: with `d_M` the distance from the sample to M (its
/// closest point), a hit at `|offset| > 3·d_M + slack` is on another sheet
/// (the far side of a thin part, across a hole or a fold): the line left
/// the sample's neighbourhood of M without meeting it, so its hit, a
/// correct φ, would make a useless displacement, a spike across the model.
/// A hit on the sample's own sheet lies at `d_M / cos θ`, θ the angle
/// between the line and M's normal, so the factor 3 admits lines up to 71°
/// off M's normal; `slack` covers `d_M ≈ 0` (the limit surface crossing
/// M), where M's faceting can put the hit a fraction of an edge from the
/// closest point. Such samples and those whose line misses M entirely (over
/// a hole, beyond a boundary of M) are unprojectable and inpainted
/// ([`inpaint`]).
pub fn compute_displacement(
    control: &ControlMesh,
    evaluator: &dyn LimitEvaluator,
    caster: &dyn RayCaster,
    res: usize,
    max_dist: f64,
    diag: f64,
    slack: f64,
) -> Result<Displacement> {
    let grid = PatchGrid::new(control, res)?;
    displacement_on(grid, control, evaluator, caster, max_dist, diag, slack)
}

/// [`compute_displacement`] on a given `grid` (uniform or adaptive, see
/// [`allocate_resolutions`]). The offsets of dependent samples are the
/// interpolation of their coarse neighbours' ([`PatchGrid::apply_dependents`]),
/// and they count as projected when both neighbours are.
pub fn displacement_on(
    grid: PatchGrid,
    control: &ControlMesh,
    evaluator: &dyn LimitEvaluator,
    caster: &dyn RayCaster,
    max_dist: f64,
    diag: f64,
    slack: f64,
) -> Result<Displacement> {
    let sheet = SameSheet::new(diag, slack);
    let probe = probe(&grid, control, evaluator, caster, max_dist, sheet, None)?;
    Ok(finish(grid, probe, diag, slack))
}

/// What φ answers at every sample of a grid, before the same-sheet test
/// and the inpainting of [`displacement_on`]: the limit point, the
/// direction, the line's nearest hit (its offset; `None`: the line met M
/// nowhere within the search distance) and the distance to M's closest
/// point where the same-sheet test needs it ([`SameSheet::radius`]; `None`:
/// the hit passes the test whatever the distance). The allocation's pilot
/// keeps its own ([`Allocation`]) so that
/// the final grid does not evaluate and cast again at the samples the
/// two grids share.
#[derive(Clone, Debug)]
pub struct Probe {
    pub limit: Vec<LimitPoint>,
    pub directions: Vec<DVec3>,
    pub hits: Vec<Option<f64>>,
    pub closest: Vec<Option<f64>>,
}

/// A grid's [`Probe`] with the probe it was measured on.
#[derive(Clone, Debug)]
pub struct Probed {
    pub grid: PatchGrid,
    pub probe: Probe,
}

/// The sample of `earlier` at `grid`'s sample `s`'s location, when
/// `earlier` evaluates one at exactly that location (the same patch and
/// the same `(u, v)` bits: a level-`k` grid point `i / 2^k` is the
/// pilot's `i·2^{kp−k} / 2^{kp}`, both exact in binary).
fn same_location(grid: &PatchGrid, s: usize, earlier: &PatchGrid) -> Option<usize> {
    let l = grid.locations()[s];
    let f = l.face.idx();
    if f >= earlier.num_patches() {
        return None;
    }
    let r1 = (earlier.patch_res(f) - 1) as f64;
    let (x, y) = (l.u * r1, l.v * r1);
    if x.fract() != 0.0 || y.fract() != 0.0 || !(0.0..=r1).contains(&x) || !(0.0..=r1).contains(&y)
    {
        return None;
    }
    let e = earlier.sample(f, x as usize, y as usize) as usize;
    let m = earlier.locations()[e];
    let same = m.face == l.face
        && m.sub == l.sub
        && m.u.to_bits() == l.u.to_bits()
        && m.v.to_bits() == l.v.to_bits();
    same.then_some(e)
}

fn same_bits(a: DVec3, b: DVec3) -> bool {
    a.to_array()
        .iter()
        .zip(b.to_array())
        .all(|(x, y)| x.to_bits() == y.to_bits())
}

/// φ at every sample of `grid` ([`Probe`]). With `earlier`, a sample
/// at the same location as one of its samples (and the same direction)
/// takes that sample's limit point, hit and closest distance instead of
/// evaluating and casting again: each is a function of the location (and
/// the line) alone, so the numbers are the ones a fresh query gives.
/// `earlier` must have been probed with the same `sheet`.
pub(crate) fn probe(
    grid: &PatchGrid,
    control: &ControlMesh,
    evaluator: &dyn LimitEvaluator,
    caster: &dyn RayCaster,
    max_dist: f64,
    sheet: SameSheet,
    earlier: Option<&Probed>,
) -> Result<Probe> {
    let n = grid.num_samples();
    let from: Vec<Option<usize>> = match earlier {
        Some(e) => (0..n).map(|s| same_location(grid, s, &e.grid)).collect(),
        None => vec![None; n],
    };
    let fresh: Vec<usize> = (0..n).filter(|&s| from[s].is_none()).collect();
    let limit = if fresh.len() == n {
        evaluator.evaluate(control.positions(), grid.locations())?
    } else {
        let locs: Vec<SurfaceLocation> = fresh.iter().map(|&s| grid.locations()[s]).collect();
        let new = match locs.is_empty() {
            true => Vec::new(),
            false => evaluator.evaluate(control.positions(), &locs)?,
        };
        let mut limit = vec![LimitPoint::default(); n];
        for (&s, p) in fresh.iter().zip(new) {
            limit[s] = p;
        }
        if let Some(e) = earlier {
            for (s, f) in from.iter().enumerate() {
                if let Some(f) = *f {
                    limit[s] = e.probe.limit[f];
                }
            }
        }
        limit
    };
    let directions = sample_directions(control, evaluator, grid, &limit)?;
    // Cast and query only where no earlier sample had the same line.
    let reuse: Vec<Option<usize>> = match earlier {
        Some(e) => from
            .iter()
            .zip(&directions)
            .map(|(f, &d)| f.filter(|&f| same_bits(e.probe.directions[f], d)))
            .collect(),
        None => vec![None; n],
    };
    let cast: Vec<usize> = (0..n).filter(|&s| reuse[s].is_none()).collect();
    let positions: Vec<DVec3> = cast.iter().map(|&s| limit[s].position).collect();
    let dirs: Vec<DVec3> = cast.iter().map(|&s| directions[s]).collect();
    let (cast_hits, _) = project_along(caster, &positions, &dirs, max_dist)?;
    let (mut hits, mut closest) = (vec![None; n], vec![None; n]);
    for (&s, h) in cast.iter().zip(cast_hits) {
        hits[s] = h.map(|h| h.offset);
    }
    // M's closest point is read only by the same-sheet test, and only
    // within the radius it needs ([`SameSheet::radius`]): no query for a
    // line without a hit or with a hit within the slack, a bounded one for
    // the others. A hit on the sample's own sheet lies at `d / cos θ`
    // (θ the line's angle with M's normal), so its closest point is
    // usually beyond the radius, about `|hit|/3`, and the search ends
    // without opening the boxes between.
    let queried: Vec<(usize, f64)> = cast
        .iter()
        .filter_map(|&s| sheet.radius(hits[s]).map(|r| (s, r)))
        .collect();
    // Only the distance of each closest point is read: reduced per
    // sub-batch, so the whole batch's closest points (64 bytes each, 5M
    // samples on a 10M-triangle input) are never held at once.
    let queried_closest: Vec<Option<f64>> = crate::raycast::in_spatial_order(
        &queried,
        |&(s, _)| limit[s].position,
        |sub| {
            let (points, radii): (Vec<DVec3>, Vec<f64>) =
                sub.iter().map(|&(s, r)| (limit[s].position, r)).unzip();
            Ok(caster
                .closest_points_within(&points, &radii)?
                .into_iter()
                .map(|c| c.map(|c| c.distance))
                .collect())
        },
    )?;
    for (&(s, _), c) in queried.iter().zip(queried_closest) {
        closest[s] = c;
    }
    if let Some(e) = earlier {
        for (s, r) in reuse.iter().enumerate() {
            if let Some(r) = *r {
                hits[s] = e.probe.hits[r];
                closest[s] = e.probe.closest[r];
            }
        }
    }
    Ok(Probe {
        limit,
        directions,
        hits,
        closest,
    })
}

/// [`displacement_on`] of `grid` with the samples it shares with the
/// allocation's pilot grid taken from `pilot` ([`probe`]): the same
/// displacement, without evaluating and casting again where the pilot
/// did (every sample of a patch at or below the pilot's level that the
/// pilot evaluates in the same patch).
#[allow(clippy::too_many_arguments)]
pub fn displacement_after(
    grid: PatchGrid,
    pilot: &Probed,
    control: &ControlMesh,
    evaluator: &dyn LimitEvaluator,
    caster: &dyn RayCaster,
    max_dist: f64,
    diag: f64,
    slack: f64,
) -> Result<Displacement> {
    let sheet = SameSheet::new(diag, slack);
    let probe = probe(
        &grid,
        control,
        evaluator,
        caster,
        max_dist,
        sheet,
        Some(pilot),
    )?;
    Ok(finish(grid, probe, diag, slack))
}

/// The same-sheet test, the counts and the inpainting of
/// [`displacement_on`] on a grid's [`Probe`].
pub(crate) fn finish(grid: PatchGrid, probe: Probe, diag: f64, slack: f64) -> Displacement {
    let Probe {
        limit,
        directions,
        mut hits,
        closest,
    } = probe;
    let mut pstats = ProjectionStats {
        points: hits.len(),
        unprojectable: hits.iter().filter(|h| h.is_none()).count(),
    };
    let mut other_sheet = 0;
    let sheet = SameSheet::new(diag, slack);
    for (h, c) in hits.iter_mut().zip(&closest) {
        let (Some(hit), Some(distance)) = (*h, *c) else {
            continue;
        };
        if sheet.other_sheet(hit, distance) {
            *h = None;
            pstats.unprojectable += 1;
            other_sheet += 1;
        }
    }
    let mut projected: Vec<bool> = hits.iter().map(Option::is_some).collect();
    for d in grid.dependents() {
        projected[d.sample as usize] = projected[d.a as usize] && projected[d.b as usize];
    }
    let mut offsets: Vec<f64> = hits.iter().map(|h| h.unwrap_or(0.0)).collect();
    inpaint(&grid, &mut offsets, &projected);
    grid.apply_dependents(&mut offsets);
    let max_abs = offsets.iter().fold(0.0f64, |m, d| m.max(d.abs()));
    let stats = DisplacementStats {
        resolution: grid.res(),
        patches: grid.num_patches(),
        samples: grid.num_independent(),
        unprojectable: pstats.unprojectable,
        other_sheet,
        unprojectable_percent: 100.0 * pstats.unprojectable_fraction(),
        max_abs_offset_permille: 1000.0 * max_abs / diag.max(f64::MIN_POSITIVE),
        least_squares: None,
        reconstruction: Reconstruction::Bilinear,
        adaptive: None,
        sheet_resolved: None,
    };
    Displacement {
        grid,
        limit,
        directions,
        offsets,
        projected,
        stats,
        reconstruction: Reconstruction::Bilinear,
    }
}

/// The displacement direction at every sample of `grid` (`limit` its
/// limit points): the unit limit normal, or on infinitely sharp creases and
/// at corners the normalised sum of the unit normals of the patches that
/// contain the sample (module docs). Deterministic: patches are visited in
/// order.
pub fn sample_directions(
    control: &ControlMesh,
    evaluator: &dyn LimitEvaluator,
    grid: &PatchGrid,
    limit: &[LimitPoint],
) -> Result<Vec<DVec3>> {
    use std::collections::HashSet;
    let mut sharp_edges: HashSet<(u32, u32)> = HashSet::new();
    let mut sharp_vertex = vec![false; control.num_vertices()];
    for (a, b, s) in control.creases() {
        if s >= INFINITELY_SHARP {
            sharp_edges.insert((a.0.min(b.0), a.0.max(b.0)));
            sharp_vertex[a.0 as usize] = true;
            sharp_vertex[b.0 as usize] = true;
        }
    }
    for (v, _) in control.corners() {
        sharp_vertex[v.0 as usize] = true;
    }
    let mut dirs: Vec<DVec3> = limit.iter().map(|p| p.normal()).collect();
    if sharp_edges.is_empty() && !sharp_vertex.iter().any(|&s| s) {
        return Ok(dirs);
    }
    let (mut locs, mut ids) = (Vec::new(), Vec::new());
    for f in 0..grid.num_patches() {
        let r1 = grid.patch_res(f) - 1;
        let vs = grid.patch_vertices(f);
        let on_sharp_edge = |k: usize| {
            let (a, b) = (vs[k], vs[(k + 1) % 4]);
            sharp_edges.contains(&(a.min(b), a.max(b)))
        };
        let mut push = |i: usize, j: usize| {
            locs.push(SurfaceLocation::quad(
                crate::mesh::FaceId(f as u32),
                i as f64 / r1 as f64,
                j as f64 / r1 as f64,
            ));
            ids.push(grid.sample(f, i, j));
        };
        for (k, (i, j)) in [(0, 0), (r1, 0), (r1, r1), (0, r1)].into_iter().enumerate() {
            if sharp_vertex[vs[k] as usize] {
                push(i, j);
            }
        }
        for k in 1..r1 {
            if on_sharp_edge(0) {
                push(k, 0);
            }
            if on_sharp_edge(1) {
                push(r1, k);
            }
            if on_sharp_edge(2) {
                push(k, r1);
            }
            if on_sharp_edge(3) {
                push(0, k);
            }
        }
    }
    if locs.is_empty() {
        return Ok(dirs);
    }
    let pts = evaluator.evaluate(control.positions(), &locs)?;
    let mut sum: std::collections::BTreeMap<u32, DVec3> = Default::default();
    for (p, &s) in pts.iter().zip(&ids) {
        *sum.entry(s).or_insert(DVec3::ZERO) += p.normal();
    }
    for (s, n) in sum {
        let n = n.normalize_or_zero();
        if n != DVec3::ZERO {
            dirs[s as usize] = n;
        }
    }
    Ok(dirs)
}

/// Sweeps of the Gauss–Seidel smoothing in [`inpaint`]: enough for the
/// fill to settle over the holes met in practice (a few grid cells wide);
/// the breadth-first initialisation already makes it continuous.
const INPAINT_SWEEPS: usize = 64;

/// Fills `values` where `known` is false with a discrete harmonic
/// interpolation of the known ones over the welded grid's edges (each
/// unknown the mean of its grid neighbours). Initialised breadth-first from
/// the known samples (each unknown the mean of its neighbours filled
/// before it), then smoothed by Gauss–Seidel sweeps in index order:
/// deterministic whatever the thread count. Samples in a component without
/// any known sample keep their value (0).
pub fn inpaint(grid: &PatchGrid, values: &mut [f64], known: &[bool]) {
    let n = values.len();
    if known.iter().all(|&k| k) || known.iter().all(|&k| !k) {
        return;
    }
    // Neighbours from the grid triangles' edges, deduplicated.
    let mut nbr: Vec<Vec<u32>> = vec![Vec::new(); n];
    for t in grid.triangles() {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            if !known[a as usize] && !nbr[a as usize].contains(&b) {
                nbr[a as usize].push(b);
            }
            if !known[b as usize] && !nbr[b as usize].contains(&a) {
                nbr[b as usize].push(a);
            }
        }
    }
    let mut filled: Vec<bool> = known.to_vec();
    let mut frontier: Vec<usize> = (0..n)
        .filter(|&i| !known[i] && nbr[i].iter().any(|&j| known[j as usize]))
        .collect();
    let mut order = Vec::new();
    while !frontier.is_empty() {
        let vals: Vec<f64> = frontier
            .iter()
            .map(|&i| {
                let (s, c) = nbr[i]
                    .iter()
                    .filter(|&&j| filled[j as usize])
                    .fold((0.0, 0usize), |(s, c), &j| (s + values[j as usize], c + 1));
                s / c.max(1) as f64
            })
            .collect();
        for (&i, v) in frontier.iter().zip(vals) {
            values[i] = v;
            filled[i] = true;
        }
        order.extend_from_slice(&frontier);
        let mut next: Vec<usize> = frontier
            .iter()
            .flat_map(|&i| nbr[i].iter().map(|&j| j as usize))
            .filter(|&j| !filled[j])
            .collect();
        next.sort_unstable();
        next.dedup();
        frontier = next;
    }
    order.sort_unstable();
    for _ in 0..INPAINT_SWEEPS {
        for &i in &order {
            let (s, c) = nbr[i]
                .iter()
                .filter(|&&j| filled[j as usize])
                .fold((0.0, 0usize), |(s, c), &j| (s + values[j as usize], c + 1));
            if c > 0 {
                values[i] = s / c as f64;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fixtures::flat_grid;
    use crate::mesh::TriMesh;
    use crate::raycast::{make_raycaster, RayBackend};
    use crate::subdiv::{make_evaluator, Backend, EvalOptions};

    #[test]
    fn beyond_the_same_sheet_radius_no_distance_fails_the_test() {
        // `SameSheet::radius` lets the probe skip or bound M's closest
        // point: a hit whose closest point lies at or beyond the radius
        // (or that has none) must pass the same-sheet test whatever the
        // distance, and the radius must be tight enough to matter (a
        // distance a little inside it fails). Hits of every magnitude
        // around slacks of several, with the boundary cases `|hit| =
        // slack` and just above it.
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(39);
        for slack in [1e-12, 1e-4, 0.01, 0.5, 3.0] {
            let sheet = SameSheet::new(1.0, slack);
            assert!(sheet.radius(None).is_none());
            let s = sheet.slack;
            let mut hits = vec![s, s * (1.0 + 1e-15), s * (1.0 - 1e-15), 0.0, 2.0 * s];
            hits.extend((0..2000).map(|_| 10f64.powf(rng.gen_range(-13.0..4.0))));
            for h in hits.into_iter().flat_map(|h| [h, -h]) {
                let far = |d: f64| assert!(!sheet.other_sheet(h, d), "hit {h} d {d} slack {s}");
                match sheet.radius(Some(h)) {
                    None => {
                        assert!(h.abs() <= s);
                        for d in [0.0, 1e-300, 0.1 * s, s, 1e6] {
                            far(d);
                        }
                    }
                    Some(r) => {
                        assert!(h.abs() > s && r > 0.0);
                        for d in [r, r * (1.0 + 1e-15), 1.5 * r, 1e6 * r, f64::MAX / 4.0] {
                            far(d);
                        }
                        // Inside the radius by more than its margin: fails.
                        let inner = 0.999 * (h.abs() - s) / SAME_SHEET_FACTOR;
                        if h.abs() - s > 1e-6 * h.abs() {
                            assert!(sheet.other_sheet(h, inner), "hit {h} d {inner}");
                        }
                    }
                }
            }
        }
    }

    /// A triangulated square `[-1, 5]²` at z = 0 (cells of 0.5), without
    /// the cells whose centre lies in `hole`.
    fn plane_with_hole(hole: (f64, f64)) -> TriMesh {
        let inside = |x: f64| x > hole.0 && x < hole.1;
        crate::fixtures::tri_grid(
            12,
            |i, j| DVec3::new(-1.0 + 0.5 * i as f64, -1.0 + 0.5 * j as f64, 0.0),
            // Cell (i, j) has its centre at -0.75 + 0.5 (i, j).
            |i, j| !(inside(-0.75 + 0.5 * i as f64) && inside(-0.75 + 0.5 * j as f64)),
        )
    }

    #[test]
    fn samples_over_a_hole_are_unprojectable_and_inpainted_not_zero() {
        // The limit surface of the flat grid lifted to z = 0.1 is the plane
        // z = 0.1 over [0, 4]²; M is the plane z = 0 with a 1 × 1 hole.
        let mut control = flat_grid(4, 4);
        for p in control.positions_mut() {
            p.z = 0.1;
        }
        let mesh = plane_with_hole((1.5, 2.5));
        let caster = make_raycaster(RayBackend::Embree, &mesh).unwrap();
        let ev = make_evaluator(Backend::Osd, &control, &EvalOptions::default()).unwrap();
        let diag = mesh.bbox_diagonal();
        let d = compute_displacement(&control, ev.as_ref(), caster.as_ref(), 5, 1.0, diag, 0.25)
            .unwrap();
        let pos = d.limit_positions();
        let over_hole =
            |p: DVec3| p.x > 1.5 + 1e-9 && p.x < 2.5 - 1e-9 && p.y > 1.5 + 1e-9 && p.y < 2.5 - 1e-9;
        let n_hole = pos.iter().filter(|&&p| over_hole(p)).count();
        // Sample spacing 0.25: the open square (1.5, 2.5)² holds 3 × 3.
        assert_eq!(n_hole, 9);
        for (i, &p) in pos.iter().enumerate() {
            if !on_hole_rim(p) {
                assert_eq!(d.projected[i], !over_hole(p), "sample {i} at {p}");
            }
            // A constant field inpaints to itself: every offset is -0.1,
            // the unprojectable ones included (they used to be 0, leaving
            // the limit surface's error there).
            assert!(
                (d.offsets[i] + 0.1).abs() < 1e-9,
                "sample {i}: {}",
                d.offsets[i]
            );
        }
        assert_eq!(
            d.stats.unprojectable,
            d.projected.iter().filter(|&&p| !p).count()
        );
        assert!(d.stats.unprojectable >= 9 && d.stats.other_sheet == 0);
    }

    /// Samples exactly above the rim of the hole: the line grazes an edge
    /// of M, hit or miss as the ray caster's edge rule decides.
    fn on_hole_rim(p: DVec3) -> bool {
        let on = |x: f64| (x - 1.5).abs() < 1e-9 || (x - 2.5).abs() < 1e-9;
        let within = |x: f64| (1.5 - 1e-9..=2.5 + 1e-9).contains(&x);
        (on(p.x) && within(p.y)) || (on(p.y) && within(p.x))
    }

    #[test]
    fn inpainting_reproduces_a_linear_field() {
        // On the uniform welded grid of a flat control grid (every cell
        // split along the same diagonal) a linear function is discrete
        // harmonic, so the fill must recover it, not just smear values.
        let control = flat_grid(4, 4);
        let grid = PatchGrid::new(&control, 5).unwrap();
        let ev = make_evaluator(Backend::Osd, &control, &EvalOptions::default()).unwrap();
        let pos: Vec<DVec3> = ev
            .evaluate(control.positions(), grid.locations())
            .unwrap()
            .iter()
            .map(|p| p.position)
            .collect();
        let f = |p: DVec3| 0.3 * p.x - 0.7 * p.y + 0.05;
        let truth: Vec<f64> = pos.iter().map(|&p| f(p)).collect();
        let known: Vec<bool> = pos
            .iter()
            .map(|p| !(p.x > 0.9 && p.x < 2.6 && p.y > 1.1 && p.y < 2.9))
            .collect();
        assert!(known.iter().filter(|&&k| !k).count() >= 20);
        let mut v: Vec<f64> = truth
            .iter()
            .zip(&known)
            .map(|(&t, &k)| if k { t } else { 0.0 })
            .collect();
        inpaint(&grid, &mut v, &known);
        for i in 0..v.len() {
            // 64 Gauss–Seidel sweeps on a hole 7 samples across leave a
            // residual far below 1e-6 of the field's range (≈ 4).
            assert!(
                (v[i] - truth[i]).abs() < 1e-6,
                "sample {i}: {} vs {}",
                v[i],
                truth[i]
            );
        }
    }
}
