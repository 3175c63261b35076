//! Mechanical mode: Lavoué, Dupont & Baskurt (2007), "Subdivision surface
//! fitting for efficient compression and coding of 3D models" — CAD parts
//! as compact control meshes whose sharp features are creases.
//!
//! Stages, one module each, in the paper's order:
//! 1. [`curvature`] (§3.1): normal-cycle curvature tensors per vertex.
//! 2. [`segment`] (§4): near-constant-curvature regions bounded by the
//!    sharp edges.
//! 3. [`network`] + [`curves`] (§5): boundary pieces between corners,
//!    each fitted by a 1-6-1 subdivision curve with few control points
//!    (feature lines to their polyline; smooth boundaries, de-zigzagged,
//!    to M), with corners added where a feature kinks.
//! 4. [`polyhedron`] (§6): per region, the synchronised boundary control
//!    polygon cut into facets along curvature-coherent chords.
//! 5. [`optimize`] (§7): least-squares geometry with the curve control
//!    points fixed, and error-driven enrichment, in bounded rounds.
//! 6. Assembly (here): one [`ControlMesh`], every curve segment an
//!    infinitely sharp crease, every curve end a corner.
//!
//! The scheme is Catmull-Clark with creases (what OpenSubdiv, USD and every
//! DCC tool evaluate; triangles use the default "catmark" triangle rule),
//! not the paper's quad/triangle scheme: a crease's limit is the same cubic
//! B-spline under both, so §5's curves are unaffected.

pub mod curvature;
pub mod curves;
pub mod network;
pub mod optimize;
pub mod polyhedron;
pub mod segment;
pub mod topology;

use std::collections::{HashMap, HashSet};
use std::time::Instant;

use serde::Serialize;

use crate::error::{Error, Result};
use crate::mesh::{ControlMesh, TriMesh};
use crate::raycast::RayCaster;
use crate::DVec3;

/// An `f64` with a total order (`f64::total_cmp`), for the Dijkstra heaps
/// of the segmentation and polyhedron steps.
#[derive(Copy, Clone, PartialEq)]
pub(crate) struct OrdF(pub(crate) f64);
impl Eq for OrdF {}
impl PartialOrd for OrdF {
    fn partial_cmp(&self, o: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(o))
    }
}
impl Ord for OrdF {
    fn cmp(&self, o: &Self) -> std::cmp::Ordering {
        self.0.total_cmp(&o.0)
    }
}

pub use curvature::{vertex_curvatures, CurvatureOptions, VertexCurvature};
pub use segment::{segment, SegmentOptions, Segmentation};
pub use topology::{Topology, SHARP_DIHEDRAL_DEG};

/// Paper's `E_limit` (§8): 3 × 10⁻³ of the bounding-box diagonal.
pub const DEFAULT_MAX_ERROR: f64 = 3e-3;
/// `m₀` (§7.3): geometry iterations per round.
pub const DEFAULT_M0: usize = 5;
/// Enrichment rounds at most. Each round at least splits one face, so the
/// loop ends; 8 rounds of splitting every over-limit face multiply a face
/// by at most 4⁸, and [`MechanicalOptions::max_faces`] caps the total.
pub const DEFAULT_MAX_ROUNDS: usize = 8;
/// `--mode auto` picks mechanical when at least this share of M's interior
/// edges is sharp (dihedral above [`SHARP_DIHEDRAL_DEG`]): 0.5 % (and see
/// [`AUTO_FLAT_SHARE`]). A CAD tessellation has its feature lines as edges
/// (several per cent of them); a dense organic scan a few noisy spikes at
/// most.
pub const AUTO_SHARP_SHARE: f64 = 0.005;

/// Options of [`build_control`].
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
#[non_exhaustive]
pub struct MechanicalOptions {
    /// `E_limit`: RMS distance per control face, fraction of the diagonal.
    pub max_error: f64,
    /// Largest distance to M of the curve of a piece mixing sharp and
    /// smooth edges (a feature line continued across a smooth part, see
    /// `segment`), and the least room its smooth edges get from their
    /// (smoothed) polyline, fraction of the diagonal: 0.8 × 10⁻³, inside
    /// the 1‰ features-kept bar (see `fit_one`).
    pub curve_tolerance: f64,
    /// Largest distance from a feature line (a boundary piece made of sharp
    /// edges of M: its vertices and points along its edges) to its fitted
    /// curve, fraction of the diagonal: 0.97 × 10⁻³, the features-kept bar
    /// (1‰) less a margin for the tessellation of the crease curve by which
    /// it is checked (see [`curves::fit_feature`]). Measured as a true
    /// point-to-curve distance, so no chord-to-arc room is needed.
    pub feature_tolerance: f64,
    /// Largest distance to M of a curve along a smooth region boundary
    /// (no sharp edge on it: not a feature line), fraction of the
    /// diagonal: the paper's curve threshold, 2 × 10⁻³ (§8).
    pub smooth_curve_tolerance: f64,
    pub m0: usize,
    pub max_rounds: usize,
    /// Stop enriching beyond this many faces: 20 000.
    pub max_faces: usize,
    /// Umbrella fairness weight of the geometry step: 0.01 (see
    /// [`crate::fit`]).
    pub fairness: f64,
    /// Objective of the geometry step: SDM, the paper's (§7.1). Written
    /// by its variant name in `report.json` (`"Sdm"`), as it always was.
    #[serde(
        serialize_with = "crate::fit::Objective::serialize_variant_name",
        deserialize_with = "objective_variant_name"
    )]
    pub objective: optimize::Objective,
}

impl Default for MechanicalOptions {
    fn default() -> Self {
        MechanicalOptions {
            max_error: DEFAULT_MAX_ERROR,
            curve_tolerance: 0.8e-3,
            feature_tolerance: 0.97e-3,
            smooth_curve_tolerance: 2e-3,
            m0: DEFAULT_M0,
            max_rounds: DEFAULT_MAX_ROUNDS,
            max_faces: 20_000,
            fairness: 0.01,
            objective: optimize::Objective::Sdm,
        }
    }
}

impl MechanicalOptions {
    /// Sets `E_limit` and keeps the curve tolerances "coherent" with it
    /// (§8: the paper's curve threshold is ⅔ of its `E_limit`): below the
    /// default `E_limit` they shrink in proportion — features to `E/3`
    /// (0.97‰ at most), smooth boundaries to `2E/3` (2‰ at most). A tight
    /// `E_limit` with 1‰ crease curves cannot be met near the creases, and
    /// the enrichment spends its faces there in vain (the scaled curves
    /// lower the RMS at the same face count).
    pub fn with_max_error(mut self, e: f64) -> Self {
        self.max_error = e;
        let d = MechanicalOptions::default();
        self.feature_tolerance = d.feature_tolerance.min(e / 3.0);
        self.curve_tolerance = d.curve_tolerance.min(e / 3.0);
        self.smooth_curve_tolerance = d.smooth_curve_tolerance.min(2.0 * e / 3.0);
        self
    }
    pub fn with_objective(mut self, o: optimize::Objective) -> Self {
        self.objective = o;
        self
    }
    pub fn with_max_rounds(mut self, n: usize) -> Self {
        self.max_rounds = n;
        self
    }
    fn check(&self) -> Result<()> {
        let ok = |x: f64| x.is_finite() && x > 0.0 && x < 1.0;
        if !ok(self.max_error)
            || !ok(self.curve_tolerance)
            || !ok(self.feature_tolerance)
            || !ok(self.smooth_curve_tolerance)
        {
            return Err(Error::option("max_error", format!(
                "mechanical: max_error {} and curve_tolerance {} must be in (0, 1) (fractions of the diagonal)",
                self.max_error, self.curve_tolerance
            )));
        }
        Ok(())
    }
}

/// What [`build_control`] did, for `report.json`.
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
pub struct MechanicalStats {
    pub sharp_edges: usize,
    pub sharp_edges_inside_regions: usize,
    /// Sharp edges inside regions kept as creases on slits of their
    /// region's boundary ([`SegmentOptions::slits`]).
    pub slit_edges: usize,
    pub regions: usize,
    pub region_splits: usize,
    pub regions_merged: usize,
    /// Region pairs merged across smooth boundaries (see [`segment`]).
    pub regions_merged_smooth: usize,
    pub planar_regions: usize,
    /// Regions left out (not discs after the splits, or a degenerate
    /// boundary polygon): holes in the control mesh.
    pub regions_skipped: usize,
    pub corners: usize,
    pub curves: usize,
    pub curve_control_points: usize,
    /// Corners added where a feature line kinks (§5's sharp vertices).
    pub kink_corners: usize,
    /// Largest polyline-to-curve distance over the feature (all-sharp)
    /// pieces, ‰ of the diagonal (smooth pieces: see [`PieceStat`]).
    #[serde(deserialize_with = "nullable_f64")]
    pub curve_max_error_permille: f64,
    pub pieces: Vec<PieceStat>,
    /// Initial facets per region (§6).
    pub region_initial_faces: Vec<usize>,
    pub initial_faces: usize,
    pub initial_vertices: usize,
    /// A region was rebuilt as a star because the chord layout failed.
    pub star_fallback: bool,
    pub rounds: Vec<optimize::Round>,
    /// The control mesh as returned (after the last geometry pass, which
    /// follows the last round): what `--max-error` is judged on.
    pub output: optimize::Round,
    /// The returned control mesh has faces above `max_error`.
    pub error_limit_reached: bool,
    pub seconds: Vec<(String, f64)>,
}

/// The control mesh and its stats.
#[derive(Clone, Debug)]
pub struct Built {
    pub control: ControlMesh,
    pub stats: MechanicalStats,
    /// The segmentation region (§4) of each face of `control`.
    pub face_region: Vec<u32>,
}

/// Share of M's interior edges that are sharp, and share that are flat
/// (dihedral below [`FLAT_DIHEDRAL_DEG`]).
///
/// The same counts as [`Topology`]'s edges (interior: exactly two
/// triangles; the dihedral is the angle between their normals) from M's
/// sorted sides, without building the topology: `--mode auto` asks this
/// of every input, and a full [`Topology`] of a million triangles is a
/// second on one core.
pub fn edge_shares(mesh: &TriMesh) -> (f64, f64) {
    use rayon::prelude::*;
    let normals: Vec<DVec3> = (0..mesh.triangles.len())
        .into_par_iter()
        .map(|t| {
            let [a, b, c] = mesh.triangle(t);
            (b - a).cross(c - a).normalize_or_zero()
        })
        .collect();
    let sides = mesh.sorted_sides();
    let (sharp_t, flat_t) = (
        SHARP_DIHEDRAL_DEG.to_radians(),
        FLAT_DIHEDRAL_DEG.to_radians(),
    );
    let (mut interior, mut sharp, mut flat) = (0usize, 0usize, 0usize);
    for run in sides.chunk_by(|a, b| a.0 == b.0) {
        if let [(_, f0), (_, f1)] = run {
            let (n0, n1) = (normals[*f0 as usize], normals[*f1 as usize]);
            let angle = n0.dot(n1).clamp(-1.0, 1.0).acos();
            interior += 1;
            sharp += usize::from(angle > sharp_t);
            flat += usize::from(angle < flat_t);
        }
    }
    let n = interior.max(1) as f64;
    (sharp as f64 / n, flat as f64 / n)
}

/// An edge bending by less than this (degrees) is flat: 1°.
pub const FLAT_DIHEDRAL_DEG: f64 = 1.0;
/// `--mode auto` also asks for this share of flat edges: 30 %. Sharp
/// edges alone do not tell a CAD part from a coarse organic mesh (the two
/// can have as many edges above 30°); what
/// does is that a CAD part is mostly flat or singly curved between its
/// features, so most of its edges do not bend at all.
pub const AUTO_FLAT_SHARE: f64 = 0.3;

/// Why a mode was used, for `report.json`.
#[derive(Clone, Debug, Serialize)]
pub struct ModeChoice {
    /// `"mechanical"` or `"organic"`.
    pub mode: &'static str,
    /// `"auto"` or `"forced"`.
    pub how: &'static str,
    pub sharp_edge_share: f64,
    pub threshold: f64,
    pub flat_edge_share: f64,
    pub flat_threshold: f64,
    pub reason: String,
}

/// The names a run record holds as `&'static str` (a pipeline, how it was
/// chosen), read back from `report.json`: a name no run writes is an
/// error, so a record read back holds the same values it was written with.
pub(crate) fn static_name<E: serde::de::Error>(s: &str) -> std::result::Result<&'static str, E> {
    const NAMES: [&str; 4] = ["mechanical", "organic", "auto", "forced"];
    NAMES
        .into_iter()
        .find(|n| *n == s)
        .ok_or_else(|| E::custom(format!("unknown name `{s}` (one of {NAMES:?})")))
}

/// [`ModeChoice`] as `report.json` holds it, names owned.
#[derive(serde::Deserialize)]
struct ModeChoiceText {
    mode: String,
    how: String,
    sharp_edge_share: f64,
    threshold: f64,
    flat_edge_share: f64,
    flat_threshold: f64,
    reason: String,
}

// By hand: a derived impl would borrow the `&'static str` fields from the
// input, so it could only read from `'static` text.
impl<'de> serde::Deserialize<'de> for ModeChoice {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        let t = <ModeChoiceText as serde::Deserialize>::deserialize(d)?;
        Ok(ModeChoice {
            mode: static_name(&t.mode)?,
            how: static_name(&t.how)?,
            sharp_edge_share: t.sharp_edge_share,
            threshold: t.threshold,
            flat_edge_share: t.flat_edge_share,
            flat_threshold: t.flat_threshold,
            reason: t.reason,
        })
    }
}

/// The objective written by `Objective::serialize_variant_name`
/// (`"Point"`, `"Sdm"`), read back.
fn objective_variant_name<'de, D: serde::Deserializer<'de>>(
    d: D,
) -> std::result::Result<optimize::Objective, D::Error> {
    match <String as serde::Deserialize>::deserialize(d)?.as_str() {
        "Point" => Ok(optimize::Objective::Point),
        "Sdm" => Ok(optimize::Objective::Sdm),
        s => Err(<D::Error as serde::de::Error>::custom(format!(
            "unknown objective `{s}` (Point or Sdm)"
        ))),
    }
}

/// A figure that may be infinite or NaN (`report.json` writes those as
/// `null`, JSON having no such numbers), read back as NaN: written again,
/// it is `null` again.
pub(crate) fn nullable_f64<'de, D: serde::Deserializer<'de>>(
    d: D,
) -> std::result::Result<f64, D::Error> {
    Ok(<Option<f64> as serde::Deserialize>::deserialize(d)?.unwrap_or(f64::NAN))
}

/// `--mode auto`'s rule (see [`AUTO_SHARP_SHARE`]).
pub fn choose_mode(mesh: &TriMesh) -> ModeChoice {
    let (share, flat) = edge_shares(mesh);
    let mech = share >= AUTO_SHARP_SHARE && flat >= AUTO_FLAT_SHARE;
    ModeChoice {
        mode: if mech { "mechanical" } else { "organic" },
        how: "auto",
        sharp_edge_share: share,
        threshold: AUTO_SHARP_SHARE,
        flat_edge_share: flat,
        flat_threshold: AUTO_FLAT_SHARE,
        reason: format!(
            "{:.2} % of the interior edges are sharp (dihedral > {SHARP_DIHEDRAL_DEG}°; mechanical needs >= {:.2} %) and {:.1} % flat (< {FLAT_DIHEDRAL_DEG}°; needs >= {:.0} %)",
            100.0 * share,
            100.0 * AUTO_SHARP_SHARE,
            100.0 * flat,
            100.0 * AUTO_FLAT_SHARE
        ),
    }
}

/// Passes of kink detection in §5 (see [`CurveFit::with_kink_corners`]).
const KINK_PASSES: usize = 4;
/// A boundary vertex turning by less than this (degrees) is not tried as a
/// kink corner: 10°, below any CAD feature's bend; a feature arc's
/// tessellation may turn by more per edge on its tightest arcs, which the
/// fit keeps smooth since splitting there saves nothing.
const KINK_MIN_TURN_DEG: f64 = 10.0;

/// See [`tip_corners`]: a fading feature chain of at least
/// this many sharp edges gets a corner at its tip: 8. A CAD part's fading
/// features run over several times as many edges; the noise chains of an
/// organic scan forced through mechanical mode mostly over fewer, and
/// corners at all their tips ruin its fit (docs/status.md, "Measurements
/// behind the code").
const TIP_CHAIN_EDGES: usize = 8;

/// §5's curves for a network.
struct PieceFits {
    /// Per piece, whether each polyline edge is a sharp edge of M.
    edge_sharp: Vec<Vec<bool>>,
    /// Every edge of the piece is sharp.
    sharp_piece: Vec<bool>,
    /// The points each curve was fitted to (see [`smooth_piece`]).
    smoothed: Vec<Vec<DVec3>>,
    fitted: Vec<curves::Curve>,
}

/// Curves already fitted, by piece (its vertices of M, closed, least
/// control points): the kink passes of [`CurveFit::with_kink_corners`] rebuild the
/// network and refit every piece, most of them unchanged. A fit depends
/// only on its key, so the cache changes no result.
type FitCache = std::sync::Mutex<HashMap<(Vec<u32>, bool, usize), curves::Curve>>;

/// The curve tolerances of [`MechanicalOptions`] in units of M.
struct Tols {
    curve: f64,
    feature: f64,
    smooth: f64,
}

/// Fits one piece (§5) with the fewest control points
/// ([`curves::fit_samples_until`]).
///
/// Along its sharp edges (a feature line) the curve passes within
/// `tols.feature` of every point of the polyline, the features-kept bar.
/// Elsewhere a boundary is no feature line: the (smoothed) polyline only
/// says where the boundary runs, within half its mean edge length (the
/// zigzag's amplitude, what the region reach of `optimize` covers) is as
/// good as on it, and what must hold is that the curve lies on M within
/// `tols.smooth`, the paper's curve threshold (§8: 2 × 10⁻³, "coherent"
/// with `E_limit`), so that smooth region boundaries cost as few fixed
/// control points as the fit allows. A piece mixing both (a feature line
/// continued across a smooth part, see `segment`) gets each tolerance on
/// its own edges, and its curve must lie within `tols.curve` of M.
fn fit_one(
    pts: &[DVec3],
    closed: bool,
    min_n: usize,
    edge_sharp: &[bool],
    tols: &Tols,
    caster: &dyn RayCaster,
) -> curves::Curve {
    if edge_sharp.iter().all(|&s| s) {
        return curves::fit_feature(pts, closed, min_n, tols.feature);
    }
    let m = pts.len();
    let segs = if closed { m } else { m - 1 };
    let len: f64 = (0..segs)
        .map(|k| (pts[(k + 1) % m] - pts[k]).length())
        .sum();
    let loose = tols.curve.max(0.5 * len / segs.max(1) as f64);
    let edge_tol: Vec<f64> = edge_sharp
        .iter()
        .map(|&s| if s { tols.feature } else { loose })
        .collect();
    let to_mesh = if edge_sharp.iter().any(|&s| s) {
        tols.curve
    } else {
        tols.smooth
    };
    curves::fit_samples_until(pts, closed, min_n, &edge_tol, &|c: &curves::Curve| {
        curve_to_mesh(c, caster) <= to_mesh
    })
}

/// Fits every piece of `net` (§5), with enough control points that no two
/// curves share a control edge and no curve is a degenerate loop.
fn fit_pieces(
    mesh: &TriMesh,
    topo: &Topology,
    sharp: &[bool],
    caster: &dyn RayCaster,
    net: &network::Network,
    tols: &Tols,
    cache: &FitCache,
) -> PieceFits {
    use rayon::prelude::*;
    let edge_sharp_of = |a: u32, b: u32| {
        topo.vertex_edges(a).iter().any(|&e| {
            let ed = &topo.edges[e as usize];
            (ed.v[0] == b || ed.v[1] == b) && sharp[e as usize]
        })
    };
    let edge_sharp: Vec<Vec<bool>> = net
        .pieces
        .iter()
        .map(|p| {
            let m = p.verts.len();
            let segs = if p.closed { m } else { m - 1 };
            (0..segs)
                .map(|k| edge_sharp_of(p.verts[k], p.verts[(k + 1) % m]))
                .collect()
        })
        .collect();
    let sharp_piece: Vec<bool> = edge_sharp.iter().map(|e| e.iter().all(|&s| s)).collect();
    // The points each curve is fitted to. Along a feature (sharp edges of
    // M) the polyline *is* the feature line and is kept as it is: the
    // crease must follow it within `feature_tolerance`. Elsewhere a boundary
    // separates two curvature classes across a smooth part of M and
    // zigzags along triangle edges (amplitude up to an edge length):
    // fitting that within the curve tolerance costs one control point per
    // vertex, and a cubic B-spline interpolating a zigzag oscillates far
    // off M. §4's boundary
    // rectification is what removes the zigzag in the paper; here the
    // vertices not on a sharp edge are smoothed along the piece (10 passes
    // of the ¼-½-¼ filter, which cancels the period-2 zigzag outright) and
    // projected back onto M, and the fit is also checked against M itself
    // (curve samples within `smooth_curve_tolerance` of M,
    // `curve_tolerance` on a piece mixing sharp and smooth edges).
    let smoothed: Vec<Vec<DVec3>> = net
        .pieces
        .par_iter()
        .zip(&edge_sharp)
        .map(|(p, es)| {
            let pts: Vec<DVec3> = p
                .verts
                .iter()
                .map(|&v| mesh.positions[v as usize])
                .collect();
            smooth_piece(&pts, p.closed, es, tols.smooth, caster)
        })
        .collect();
    let mut mins: Vec<usize> = net
        .pieces
        .iter()
        .map(|p| {
            if p.closed || p.verts.first() == p.verts.last() {
                4
            } else {
                2
            }
        })
        .collect();
    let fit_all = |mins: &[usize]| -> Vec<curves::Curve> {
        net.pieces
            .par_iter()
            .zip(mins)
            .zip(&smoothed)
            .zip(&edge_sharp)
            .map(|(((p, &m), pp), es)| {
                let key = (p.verts.clone(), p.closed, m);
                let hit = cache.lock().ok().and_then(|c| c.get(&key).cloned());
                hit.unwrap_or_else(|| {
                    let c = fit_one(pp, p.closed, m, es, tols, caster);
                    if let Ok(mut cache) = cache.lock() {
                        cache.insert(key, c.clone());
                    }
                    c
                })
            })
            .collect()
    };
    let mut fitted = fit_all(&mins);
    for _ in 0..3 {
        let mut seen: HashSet<(u32, u32)> = HashSet::new();
        let mut again = false;
        for (i, (p, c)) in net.pieces.iter().zip(&fitted).enumerate() {
            if !p.closed && c.control.len() == 2 {
                let (a, b) = (p.verts[0], *p.verts.last().unwrap_or(&p.verts[0]));
                if !seen.insert((a.min(b), a.max(b))) {
                    mins[i] = 3;
                    again = true;
                }
            }
        }
        if !again {
            break;
        }
        fitted = fit_all(&mins);
    }
    PieceFits {
        edge_sharp,
        sharp_piece,
        smoothed,
        fitted,
    }
}

/// Vertices of M where splitting a piece into two curves with a corner
/// saves control points (see [`CurveFit::with_kink_corners`]): per piece of 4 or more
/// control points, the (up to 3) vertices on a sharp edge that turn most
/// (over 2 polyline steps where an edge is not sharp, to see past a
/// zigzag), at least [`KINK_MIN_TURN_DEG`]; the best saving wins.
fn kinks(net: &network::Network, f: &PieceFits, caster: &dyn RayCaster, tols: &Tols) -> Vec<u32> {
    use rayon::prelude::*;
    let cos_min = KINK_MIN_TURN_DEG.to_radians().cos();
    net.pieces
        .par_iter()
        .enumerate()
        .filter_map(|(i, p)| {
            let n = f.fitted[i].control.len();
            let pp = &f.smoothed[i];
            let es = &f.edge_sharp[i];
            let m = pp.len();
            if n < 4 || m < 3 {
                return None;
            }
            let at = |k: isize| -> Option<usize> {
                if p.closed {
                    Some(k.rem_euclid(m as isize) as usize)
                } else {
                    (k >= 0 && (k as usize) < m).then_some(k as usize)
                }
            };
            let mut cands: Vec<(f64, usize)> = Vec::new();
            let range = if p.closed { 0..m } else { 1..m - 1 };
            for k in range {
                let before = es[(k + es.len() - 1) % es.len()];
                let after = es[k % es.len()];
                if !(before || after) {
                    continue;
                }
                let step = if before && after { 1 } else { 2 };
                let (Some(a), Some(b)) = (at(k as isize - step), at(k as isize + step)) else {
                    continue;
                };
                let d0 = (pp[k] - pp[a]).normalize_or_zero();
                let d1 = (pp[b] - pp[k]).normalize_or_zero();
                let c = d0.dot(d1);
                if c < cos_min {
                    cands.push((c, k));
                }
            }
            cands.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)));
            cands.truncate(3);
            let mut best: Option<(usize, usize)> = None;
            for &(_, k) in &cands {
                let cost = if p.closed {
                    let mut q: Vec<DVec3> = pp[k..].to_vec();
                    q.extend_from_slice(&pp[..=k]);
                    let mut qs: Vec<bool> = es[k..].to_vec();
                    qs.extend_from_slice(&es[..k]);
                    fit_one(&q, false, 4, &qs, tols, caster).control.len() - 1
                } else {
                    let l = fit_one(&pp[..=k], false, 2, &es[..k], tols, caster);
                    let r = fit_one(&pp[k..], false, 2, &es[k..m - 1], tols, caster);
                    l.control.len() + r.control.len() - 1
                };
                if cost < n && best.map_or(true, |b| cost < b.0) {
                    best = Some((cost, k));
                }
            }
            best.map(|(_, k)| p.verts[k])
        })
        .collect()
}

/// Taubin's μ for λ = ½: pass-band frequency `1/λ + 1/μ` ≈ 0.11 (his
/// suggested 0.01–0.1 range's top: a boundary piece has tens of vertices,
/// not thousands).
const TAUBIN_MU: f64 = -0.53;

/// `points` (a boundary piece) with the vertices that touch no sharp edge
/// (`edge_sharp[k]`: edge `k → k+1`) smoothed and projected onto M (see
/// [`fit_pieces`]); open pieces keep their ends.
fn smooth_piece(
    points: &[DVec3],
    closed: bool,
    edge_sharp: &[bool],
    off_tol: f64,
    caster: &dyn RayCaster,
) -> Vec<DVec3> {
    let m = points.len();
    let movable: Vec<bool> = (0..m)
        .map(|i| {
            let before = if i > 0 {
                Some(edge_sharp[i - 1])
            } else if closed {
                Some(edge_sharp[m - 1])
            } else {
                None
            };
            let after = edge_sharp.get(i).copied();
            match (before, after) {
                (Some(b), Some(a)) => !a && !b,
                _ => false,
            }
        })
        .collect();
    if !movable.iter().any(|&x| x) {
        return points.to_vec();
    }
    let smooth = |mu: Option<f64>| {
        let mut p = points.to_vec();
        for pass in 0..if mu.is_some() { 20 } else { 10 } {
            let w = match mu {
                Some(mu) if pass % 2 == 1 => mu,
                _ => 0.5,
            };
            let q = p.clone();
            for i in 0..m {
                if movable[i] {
                    let prev = q[(i + m - 1) % m];
                    let next = q[(i + 1) % m];
                    p[i] = q[i] + w * (0.5 * (prev + next) - q[i]);
                }
            }
        }
        p
    };
    // The ¼-½-¼ filter moves a zigzag's vertices onto its midline, which
    // crosses the polyline's own edges; where the piece turns (round a
    // rib's filleted end) its ten passes also cut the corner, off the
    // polyline into the neighbouring region (the crease fitted there lay
    // off its own region along a whole face edge, and that face stayed
    // over `--max-error` through every enrichment round). Such a piece is
    // smoothed by Taubin's λ|μ filter instead ("A signal processing
    // approach to fair surface design", SIGGRAPH 1995, §4): its λ = ½
    // passes cancel the zigzag as before, its μ passes undo the
    // shrinkage. Only there: on every piece it raised the RMS of a part
    // without such corners.
    let mut p = smooth(None);
    let seg_dist = |x: DVec3| {
        (0..m - usize::from(!closed))
            .map(|k| {
                let (a, b) = (points[k], points[(k + 1) % m]);
                let ab = b - a;
                let t =
                    ((x - a).dot(ab) / ab.length_squared().max(f64::MIN_POSITIVE)).clamp(0.0, 1.0);
                (a + t * ab - x).length()
            })
            .fold(f64::INFINITY, f64::min)
    };
    if (0..m).any(|i| movable[i] && seg_dist(p[i]) > off_tol) {
        p = smooth(Some(TAUBIN_MU));
    }
    let idx: Vec<usize> = (0..m).filter(|&i| movable[i]).collect();
    let q: Vec<DVec3> = idx.iter().map(|&i| p[i]).collect();
    if let Ok(h) = caster.closest_points(&q, f64::INFINITY) {
        for (&i, h) in idx.iter().zip(h) {
            p[i] = h.map_or(points[i], |h| h.point);
        }
    } else {
        return points.to_vec();
    }
    p
}

/// Largest distance from samples of `c` (8 per control segment) to M; a
/// failed query counts as infinitely far.
fn curve_to_mesh(c: &curves::Curve, caster: &dyn RayCaster) -> f64 {
    let n = c.control.len();
    let segs = if c.closed { n } else { n - 1 };
    let q: Vec<DVec3> = (0..=8 * segs)
        .map(|i| curves::eval(&c.control, c.closed, i as f64 / 8.0))
        .collect();
    match caster.closest_points(&q, f64::INFINITY) {
        Ok(h) => h
            .iter()
            .map(|x| x.map_or(f64::INFINITY, |x| x.distance))
            .fold(0.0, f64::max),
        Err(_) => f64::INFINITY,
    }
}

/// One boundary piece's curve, for `report.json`.
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
pub struct PieceStat {
    pub polyline_vertices: usize,
    pub control_points: usize,
    /// Every edge of the piece is a sharp edge of M.
    pub sharp: bool,
    pub closed: bool,
    /// Largest polyline-to-curve distance, ‰ of the diagonal.
    #[serde(deserialize_with = "nullable_f64")]
    pub max_error_permille: f64,
}

/// Builds the mechanical control mesh of `mesh` (`caster` over it).
///
/// One curve network (§5), fitted with the fewest control points
/// ([`curves::fit_feature`] along feature lines, [`curves::fit_samples_until`]
/// elsewhere, see `fit_one`), then §6's polyhedra and §7's fitting and
/// enrichment on it. (A second, conservative curve fitter once rebuilt
/// the parts that ended far over `max_error`; the cause was §6's cut, which
/// spanned half-pipe regions with single chords from the middle control
/// point of a smooth side, see `polyhedron::MAX_CHORD_BEND`. With that
/// rule the CAD parts end under `max_error` with the compact network, and
/// the second fitter is gone; an organic mesh forced through this mode is
/// sent to the organic pipeline by `--mode auto`. The history is in
/// docs/status.md, "Measurements behind the code".)
///
/// Fading features are left as slits ([`SegmentOptions::slits`]) when
/// every one hangs from its region's boundary, else (or when a slit
/// region's polyhedron could not be built: a region skipped, the star
/// fallback) continued to the far side of their regions.
pub fn build_control(
    mesh: &TriMesh,
    caster: &dyn RayCaster,
    opts: &MechanicalOptions,
) -> Result<Built> {
    // An error of the slit build (a slit polygon the facets could not
    // cover, then no star layout either) is answered by the other build,
    // which repeats it if it was not the slits' doing.
    match build_with(mesh, caster, opts, true) {
        Ok(slit)
            if slit.stats.slit_edges == 0
                || (slit.stats.regions_skipped == 0 && !slit.stats.star_fallback) =>
        {
            Ok(slit)
        }
        _ => build_with(mesh, caster, opts, false),
    }
}

/// Wall-clock seconds per stage, for `report.json`.
struct Laps {
    seconds: Vec<(String, f64)>,
    t: Instant,
}

impl Laps {
    fn start() -> Self {
        Laps {
            seconds: Vec::new(),
            t: Instant::now(),
        }
    }
    /// Records the time since the last lap as stage `name`.
    fn lap(&mut self, name: &str) {
        self.seconds
            .push((name.to_string(), self.t.elapsed().as_secs_f64()));
        self.t = Instant::now();
    }
}

/// The pipeline of [`build_control`] with or without slits, one named
/// step per stage of Lavoué et al.: curvature (§3.1), segmentation (§4),
/// boundary curves (§5), polyhedra (§6), fitting and enrichment (§7), and
/// the assembly of the stats.
fn build_with(
    mesh: &TriMesh,
    caster: &dyn RayCaster,
    opts: &MechanicalOptions,
    slits: bool,
) -> Result<Built> {
    let diag = checked_diagonal(mesh, opts)?;
    let mut laps = Laps::start();
    let topo = Topology::new(mesh);
    let curv = vertex_curvatures(mesh, &topo, &CurvatureOptions::default());
    laps.lap("curvature");
    // §4: regions of near-constant curvature, sharp edges on boundaries.
    let seg = segment(
        mesh,
        &topo,
        &curv,
        &SegmentOptions {
            slits,
            ..SegmentOptions::default()
        },
    );
    // Sharp edges left inside regions are slits of their region's boundary
    // loop (only with `slits`; without, they are rounded off).
    let slits = seg.slits;
    let slit_edges = if slits { seg.sharp_edges_inside } else { 0 };
    let sharp = topo.sharp_edges();
    let tols = Tols {
        curve: opts.curve_tolerance * diag,
        feature: opts.feature_tolerance * diag,
        smooth: opts.smooth_curve_tolerance * diag,
    };
    // §5: the boundary network between corners (feature tips first) and
    // its curves, with corners added where a feature kinks.
    let network_with = |extra_corner: &[bool]| {
        network::build_network(
            mesh,
            &topo,
            &seg.region,
            seg.num_regions,
            &sharp,
            extra_corner,
            slits,
        )
    };
    let extra_corner = tip_corners(&topo, &sharp, mesh.positions.len());
    let net = network_with(&extra_corner);
    laps.lap("segmentation");
    let fit = CurveFit {
        mesh,
        topo: &topo,
        sharp: &sharp,
        caster,
        tols: &tols,
    };
    let (net, stage, kink_corners) = fit.with_kink_corners(net, extra_corner, &network_with);
    laps.lap("curves");

    // §6: the curves' control points, each region's boundary polygon and
    // its facets (a star per region when they make no valid mesh).
    let mut ctl = curve_controls(mesh, &net, &stage.fitted)?;
    let region_tris = region_triangles(&seg);
    let (polygons, skipped) = region_polygons(&net, &ctl.piece_ctrl, slit_edges);
    into_planes(mesh, &region_tris, &polygons, &mut ctl.positions, diag);
    let facets = cut_facets(mesh, &curv, &region_tris, &net, &polygons, &ctl, diag);
    let mut polys = optimize::Polys {
        positions: ctl.positions.clone(),
        faces: facets.faces,
        fixed: ctl.fixed,
        creases: ctl.creases.clone(),
        corners: ctl.corners.clone(),
        face_region: facets.face_region,
    };
    let star_fallback = polys.to_control().is_err();
    if star_fallback {
        star_layout(
            mesh,
            &region_tris,
            &polygons,
            &ctl.positions,
            &mut polys,
            true,
        );
        if polys.to_control().is_err() {
            // A ladder chord doubling an edge of a neighbour: plain stars.
            star_layout(
                mesh,
                &region_tris,
                &polygons,
                &ctl.positions,
                &mut polys,
                false,
            );
        }
        polys.to_control()?;
    }
    let initial_faces = polys.faces.len();
    let initial_vertices = polys.positions.len();
    laps.lap("polyhedron");

    // §7: fitting and enrichment with the curve points fixed.
    let optimize::Optimized { rounds, output } = fit_and_enrich(
        mesh,
        caster,
        &topo,
        &sharp,
        &curv,
        &region_tris,
        &mut polys,
        opts,
    )?;
    laps.lap("optimize");
    let control = polys.to_control()?;
    let error_limit_reached = output.faces_over_limit > 0;
    let (curve_max_error_permille, pieces) = piece_stats(&net, &stage, diag);
    Ok(Built {
        control,
        face_region: polys.face_region.clone(),
        stats: MechanicalStats {
            sharp_edges: seg.sharp_edges,
            sharp_edges_inside_regions: seg.sharp_edges_inside - slit_edges,
            slit_edges,
            regions: seg.num_regions,
            region_splits: seg.splits,
            regions_merged: seg.merged,
            regions_merged_smooth: seg.merged_smooth,
            planar_regions: facets.planar_regions,
            regions_skipped: skipped,
            corners: ctl.corners.len(),
            curves: net.pieces.len(),
            curve_control_points: ctl.fixed,
            kink_corners,
            curve_max_error_permille,
            pieces,
            region_initial_faces: facets.region_initial_faces,
            initial_faces,
            initial_vertices,
            star_fallback,
            rounds,
            output,
            error_limit_reached,
            seconds: laps.seconds,
        },
    })
}

/// Checks the options and that `mesh` has triangles and a proper
/// bounding box; returns its diagonal, the unit of every tolerance
/// (§8: fractions of the diagonal).
fn checked_diagonal(mesh: &TriMesh, opts: &MechanicalOptions) -> Result<f64> {
    opts.check()?;
    let diag = mesh.bbox_diagonal();
    if mesh.triangles.is_empty() || !(diag.is_finite() && diag > 0.0) {
        return Err(Error::invalid_data(
            "input mesh",
            "mesh",
            "is empty or has a degenerate bounding box; the mechanical mode needs a solid",
        ));
    }
    Ok(diag)
}

/// The tip corners of §5's network, per vertex of M.
///
/// A feature that fades out (a vertex with one sharp edge of M) ends
/// where its boundary piece stops being a feature line and goes on as a
/// smooth continuation (see `segment` step 3b): a corner there lets the
/// feature part be fitted as a feature line and the continuation as a
/// smooth boundary (§5's piecewise smooth curves), where one curve for
/// both needs the feature tolerance along a boundary that has no
/// feature (it saves curve control points).
/// Only at the tip of a chain of at least [`TIP_CHAIN_EDGES`] sharp
/// edges: a short chain (noise on a scan, hundreds of them)
/// is a feature line of two control points at most, and a corner at its
/// tip only cuts the boundary into more pieces.
fn tip_corners(topo: &Topology, sharp: &[bool], nv: usize) -> Vec<bool> {
    let sharp_deg = topo.sharp_degree(sharp);
    (0..nv as u32)
        .map(|v| {
            sharp_deg[v as usize] == 1
                && sharp_chain_edges(topo, sharp, &sharp_deg, v) >= TIP_CHAIN_EDGES
        })
        .collect()
}

/// Sharp edges of the chain from `tip` (a vertex with one sharp edge)
/// through vertices with two, counted up to [`TIP_CHAIN_EDGES`] (see
/// [`tip_corners`]).
fn sharp_chain_edges(topo: &Topology, sharp: &[bool], sharp_deg: &[usize], tip: u32) -> usize {
    let (mut v, mut prev, mut n) = (tip, u32::MAX, 0usize);
    loop {
        let Some(&e) = topo
            .vertex_edges(v)
            .iter()
            .find(|&&e| sharp[e as usize] && e != prev)
        else {
            return n;
        };
        n += 1;
        let ed = &topo.edges[e as usize];
        v = if ed.v[0] == v { ed.v[1] } else { ed.v[0] };
        prev = e;
        if sharp_deg[v as usize] != 2 || n >= TIP_CHAIN_EDGES {
            return n;
        }
    }
}

/// What §5's fit of a network reads: M, its sharp edges, the caster over
/// it and the tolerances.
struct CurveFit<'a> {
    mesh: &'a TriMesh,
    topo: &'a Topology,
    sharp: &'a [bool],
    caster: &'a dyn RayCaster,
    tols: &'a Tols,
}

impl CurveFit<'_> {
    /// §5's curves for `net`, with kink corners. The paper's fit is
    /// "piecewise smooth ... including sharp vertex processing" (LDB05b):
    /// a piece whose polyline kinks along a feature gets a corner there
    /// when that saves control points (a cubic B-spline needs many points
    /// to bend sharply, two straight halves need none). Up to
    /// [`KINK_PASSES`] passes, each one corner per piece at most, each
    /// rebuilding the network (`network_with` the corners so far) and
    /// refitting it. Returns the final network, its fits and the number of
    /// kink corners.
    fn with_kink_corners(
        &self,
        mut net: network::Network,
        mut extra_corner: Vec<bool>,
        network_with: &dyn Fn(&[bool]) -> network::Network,
    ) -> (network::Network, PieceFits, usize) {
        let cache = FitCache::default();
        let (mesh, topo, sharp, caster, tols) =
            (self.mesh, self.topo, self.sharp, self.caster, self.tols);
        let mut stage = fit_pieces(mesh, topo, sharp, caster, &net, tols, &cache);
        let mut kink_corners = 0;
        for _ in 0..KINK_PASSES {
            let found = kinks(&net, &stage, caster, tols);
            if found.is_empty() {
                break;
            }
            kink_corners += found.len();
            for v in found {
                extra_corner[v as usize] = true;
            }
            net = network_with(&extra_corner);
            stage = fit_pieces(mesh, topo, sharp, caster, &net, tols, &cache);
        }
        (net, stage, kink_corners)
    }
}

/// The control points of §5's curves, the fixed vertices of the control
/// mesh (§7.3: "boundary control points are fixed").
struct CurveControls {
    /// Corners first, then every curve's inner control points.
    positions: Vec<DVec3>,
    /// Control ids of the corners, sorted.
    corners: Vec<u32>,
    /// Control edges of the curves between two regions: infinitely sharp
    /// creases of the output (a curve along M's open boundary is its
    /// boundary already).
    creases: HashSet<(u32, u32)>,
    /// Per piece: control ids and their anchors (vertices of M).
    piece_ctrl: Vec<Vec<polyhedron::PolyVertex>>,
    /// `positions.len()`: vertices `0..fixed` are never moved.
    fixed: usize,
}

fn edge_key(a: u32, b: u32) -> (u32, u32) {
    (a.min(b), a.max(b))
}

/// Numbers the control points of `fitted` (one curve per piece of `net`):
/// the corners once, shared by the curves ending there (eq. 2's corner
/// rule), then each curve's inner points; each control point is anchored
/// at the polyline vertex whose curve parameter is nearest to its index,
/// which §6 uses to place it on M.
fn curve_controls(
    mesh: &TriMesh,
    net: &network::Network,
    fitted: &[curves::Curve],
) -> Result<CurveControls> {
    let mut positions: Vec<DVec3> = Vec::new();
    let mut corner_id: HashMap<u32, u32> = HashMap::new();
    for (v, &c) in net.corner.iter().enumerate() {
        if c && net.on_boundary[v] {
            corner_id.insert(v as u32, positions.len() as u32);
            positions.push(mesh.positions[v]);
        }
    }
    let mut creases: HashSet<(u32, u32)> = HashSet::new();
    let mut piece_ctrl: Vec<Vec<polyhedron::PolyVertex>> = Vec::new();
    for (p, c) in net.pieces.iter().zip(fitted) {
        let n = c.control.len();
        let mut list = Vec::with_capacity(n);
        for (i, &x) in c.control.iter().enumerate() {
            let end = if p.closed {
                None
            } else if i == 0 {
                p.verts.first()
            } else if i == n - 1 {
                p.verts.last()
            } else {
                None
            };
            let id = if let Some(v) = end {
                // An open piece ends at corners by construction (network.rs);
                // a miss is a network defect, reported instead of a panic.
                *corner_id.get(v).ok_or_else(|| Error::Topology {
                    element: format!("vertex {v}"),
                    msg:
                        "a boundary curve of the segmentation ends at a vertex that is not a corner"
                            .into(),
                })?
            } else {
                positions.push(x);
                positions.len() as u32 - 1
            };
            let anchor = (0..p.verts.len())
                .min_by(|&a, &b| {
                    let da = (c.params[a] - i as f64).abs();
                    let db = (c.params[b] - i as f64).abs();
                    da.total_cmp(&db)
                })
                .map_or(p.verts[0], |j| p.verts[j]);
            list.push(polyhedron::PolyVertex { id, anchor });
        }
        if p.regions[1] != u32::MAX {
            let segs = if p.closed { n } else { n - 1 };
            for k in 0..segs {
                creases.insert(edge_key(list[k].id, list[(k + 1) % n].id));
            }
        }
        piece_ctrl.push(list);
    }
    let fixed = positions.len();
    let mut corners: Vec<u32> = corner_id.values().copied().collect();
    corners.sort_unstable();
    Ok(CurveControls {
        positions,
        corners,
        creases,
        piece_ctrl,
        fixed,
    })
}

/// Triangles of M per region of the segmentation, in index order.
fn region_triangles(seg: &Segmentation) -> Vec<Vec<u32>> {
    let mut region_tris: Vec<Vec<u32>> = vec![Vec::new(); seg.num_regions];
    for (tr, &r) in seg.region.iter().enumerate() {
        region_tris[r as usize].push(tr as u32);
    }
    region_tris
}

/// §6's synchronised boundary control polygon of each region: its loop's
/// curves' control points in order (each piece's last point is the next
/// one's first). `None` for a region §6 cannot build here, a hole in the
/// control mesh: one with several boundary loops (not a disc), fewer than
/// three points, or a point visited twice — except along a slit, whose
/// points the loop visits once per side, never twice in a row. Returns
/// the polygons and the number of regions skipped.
fn region_polygons(
    net: &network::Network,
    piece_ctrl: &[Vec<polyhedron::PolyVertex>],
    slit_edges: usize,
) -> (Vec<Option<Vec<polyhedron::PolyVertex>>>, usize) {
    let mut polygons: Vec<Option<Vec<polyhedron::PolyVertex>>> = Vec::new();
    let mut skipped = 0;
    for loops in &net.loops {
        let poly = (loops.len() == 1)
            .then(|| {
                let mut poly: Vec<polyhedron::PolyVertex> = Vec::new();
                for &(pi, fwd) in &loops[0] {
                    let mut l = piece_ctrl[pi].clone();
                    if !fwd {
                        l.reverse();
                    }
                    if !net.pieces[pi].closed {
                        l.pop();
                    }
                    poly.extend(l);
                }
                poly
            })
            .filter(|p| {
                let mut ids: Vec<u32> = p.iter().map(|x| x.id).collect();
                ids.sort_unstable();
                ids.dedup();
                let n = p.len();
                p.len() >= 3
                    && (ids.len() == n
                        || (slit_edges > 0 && (0..n).all(|k| p[k].id != p[(k + 1) % n].id)))
            });
        if poly.is_none() {
            skipped += 1;
        }
        polygons.push(poly);
    }
    (polygons, skipped)
}

/// §6's initial facets, all regions.
struct Facets {
    faces: Vec<Vec<u32>>,
    face_region: Vec<u32>,
    region_initial_faces: Vec<usize>,
    planar_regions: usize,
}

/// Cuts each region's polygon into facets along curvature-coherent chords
/// (§6, [`polyhedron::cut_region`]); the regions share the control edges
/// cut so far (`edges`, starting with every curve's), so no chord doubles
/// a control edge of another region.
fn cut_facets(
    mesh: &TriMesh,
    curv: &[VertexCurvature],
    region_tris: &[Vec<u32>],
    net: &network::Network,
    polygons: &[Option<Vec<polyhedron::PolyVertex>>],
    ctl: &CurveControls,
    diag: f64,
) -> Facets {
    let mut edges: HashSet<(u32, u32)> = ctl.creases.clone();
    for pc in &ctl.piece_ctrl {
        for w in pc.windows(2) {
            edges.insert(edge_key(w[0].id, w[1].id));
        }
    }
    let mut out = Facets {
        faces: Vec::new(),
        face_region: Vec::new(),
        region_initial_faces: vec![0usize; polygons.len()],
        planar_regions: 0,
    };
    for (r, poly) in polygons.iter().enumerate() {
        let Some(poly) = poly else { continue };
        let g = polyhedron::RegionGeom::new(mesh, curv, &region_tris[r], &net.on_boundary, diag);
        if g.planar.is_some() {
            out.planar_regions += 1;
        }
        let fr = polyhedron::cut_region(&g, poly, &ctl.positions, &mut edges);
        out.region_initial_faces[r] = fr.len();
        out.face_region
            .extend(std::iter::repeat(r as u32).take(fr.len()));
        out.faces.extend(fr);
    }
    out
}

/// Moves the curve control points on the boundary of a planar region
/// (see [`polyhedron::region_plane`]) into its plane; a point on two or
/// more such regions goes to the meeting of their planes (alternating
/// projections, exact in a few sweeps for planes at a CAD edge's angles).
///
/// §5 fits a smooth boundary to lie on M within the curve tolerance, and
/// between a flat face and a tangent fillet "on M" includes the fillet's
/// first rise: a casting's plate-to-rib-fillet curves had control points
/// above the plate. The plate's facets then leave their plane to meet
/// them, and with every curve point fixed (§7.3) no enrichment inside the
/// region can take that back (a face stayed over the bound through every
/// round). A curve of control points in a
/// plane lies in it (a B-spline is an affine combination of its points),
/// which is where M's edge of the face is; the fillet side's free points
/// follow in §7.
fn into_planes(
    mesh: &TriMesh,
    region_tris: &[Vec<u32>],
    polygons: &[Option<Vec<polyhedron::PolyVertex>>],
    positions: &mut [DVec3],
    diag: f64,
) {
    let mut planes_of: HashMap<u32, Vec<(DVec3, DVec3)>> = HashMap::new();
    for (r, poly) in polygons.iter().enumerate() {
        let (Some(poly), Some(tris)) = (poly, region_tris.get(r)) else {
            continue;
        };
        let Some(plane) = polyhedron::region_plane(mesh, tris, diag) else {
            continue;
        };
        for v in poly {
            planes_of.entry(v.id).or_default().push(plane);
        }
    }
    let mut ids: Vec<u32> = planes_of.keys().copied().collect();
    ids.sort_unstable();
    for id in ids {
        let planes = &planes_of[&id];
        let mut p = positions[id as usize];
        for _ in 0..PLANE_SWEEPS {
            for &(c, n) in planes {
                p -= (p - c).dot(n) * n;
            }
        }
        positions[id as usize] = p;
    }
}

/// Sweeps of [`into_planes`]' alternating projections: 16 (two planes at
/// 30° leave 0.75^16 ≈ 1 % of the first offset; at 90° one sweep is
/// exact).
const PLANE_SWEEPS: usize = 16;

/// The fallback of §6 when the facets do not make a valid control mesh:
/// every region a star, one free centre (its triangles' mean centroid)
/// joined to each edge of its polygon. Crude, but always valid, and §7's
/// enrichment refines it where the error asks. With `bounded`, a polygon
/// longer than [`optimize::MAX_FAN_VALENCE`] is cut into a ladder of quads
/// between its two sides instead (each corner gains at most two chords):
/// a star centre joined to 49 boundary points was one control vertex of
/// valence 49 carrying a whole face of a casting.
fn star_layout(
    mesh: &TriMesh,
    region_tris: &[Vec<u32>],
    polygons: &[Option<Vec<polyhedron::PolyVertex>>],
    positions: &[DVec3],
    polys: &mut optimize::Polys,
    bounded: bool,
) {
    let mut pos = positions.to_vec();
    let mut faces = Vec::new();
    let mut face_region = Vec::new();
    for (r, poly) in polygons.iter().enumerate() {
        let Some(poly) = poly else { continue };
        if bounded && poly.len() > optimize::MAX_FAN_VALENCE {
            // Rungs from both ends of the loop towards its far side.
            let (mut l, mut h) = (0usize, poly.len() - 1);
            while h - l >= 3 {
                faces.push(vec![poly[l].id, poly[l + 1].id, poly[h - 1].id, poly[h].id]);
                face_region.push(r as u32);
                l += 1;
                h -= 1;
            }
            // Two corners left are the last rung's chord; three, a
            // triangle.
            if h - l == 2 {
                faces.push((l..=h).map(|k| poly[k].id).collect());
                face_region.push(r as u32);
            }
            continue;
        }
        let c = region_tris[r]
            .iter()
            .map(|&tr| {
                let [a, b, c] = mesh.triangle(tr as usize);
                (a + b + c) / 3.0
            })
            .sum::<DVec3>()
            / region_tris[r].len().max(1) as f64;
        pos.push(c);
        let ci = pos.len() as u32 - 1;
        for k in 0..poly.len() {
            faces.push(vec![poly[k].id, poly[(k + 1) % poly.len()].id, ci]);
            face_region.push(r as u32);
        }
    }
    polys.positions = pos;
    polys.faces = faces;
    polys.face_region = face_region;
}

/// Each region's reach for the foot points of §7.1: its triangles and
/// two rings beyond its smooth (non-sharp) boundary edges, never across
/// a feature (see `optimize`).
fn region_reach(topo: &Topology, sharp: &[bool], region_tris: &[Vec<u32>]) -> Vec<Vec<u32>> {
    region_tris
        .iter()
        .map(|ts| {
            let mut seen: HashSet<u32> = ts.iter().copied().collect();
            let mut front: Vec<u32> = ts.clone();
            for _ in 0..2 {
                let mut next = Vec::new();
                for &t in &front {
                    for &e in &topo.tri_edges[t as usize] {
                        if sharp[e as usize] {
                            continue;
                        }
                        if let Some(o) = topo.edges[e as usize].other_face(t) {
                            if seen.insert(o) {
                                next.push(o);
                            }
                        }
                    }
                }
                front = next;
            }
            let mut v: Vec<u32> = seen.into_iter().collect();
            v.sort_unstable();
            v
        })
        .collect()
}

/// §7: least-squares geometry with the curve control points fixed and
/// error-driven enrichment, in bounded rounds ([`optimize::optimize`]),
/// each sample's foot restricted to its region's reach
/// ([`region_reach`]) and SDM's frames from the curvature tensors of the
/// vertices off the features ([`optimize::tri_frames`]).
#[allow(clippy::too_many_arguments)]
fn fit_and_enrich(
    mesh: &TriMesh,
    caster: &dyn RayCaster,
    topo: &Topology,
    sharp: &[bool],
    curv: &[VertexCurvature],
    region_tris: &[Vec<u32>],
    polys: &mut optimize::Polys,
    opts: &MechanicalOptions,
) -> Result<optimize::Optimized> {
    let reach = region_reach(topo, sharp, region_tris);
    let on_sharp: Vec<bool> = (0..mesh.positions.len() as u32)
        .map(|v| topo.vertex_edges(v).iter().any(|&e| sharp[e as usize]))
        .collect();
    let frames = optimize::tri_frames(mesh, curv, &on_sharp);
    optimize::optimize(
        mesh,
        caster,
        &reach,
        polys,
        &frames,
        &optimize::OptimizeOptions {
            objective: opts.objective,
            sdm_tangent_floor: 0.05,
            max_error: opts.max_error,
            m0: opts.m0,
            max_rounds: opts.max_rounds,
            max_faces: opts.max_faces,
            fairness: opts.fairness,
        },
    )
}

/// The curves' figures for `report.json`: the largest distance over the
/// feature pieces (‰ of the diagonal), and one [`PieceStat`] per piece.
fn piece_stats(net: &network::Network, stage: &PieceFits, diag: f64) -> (f64, Vec<PieceStat>) {
    let fitted = &stage.fitted;
    let worst = 1000.0
        * fitted
            .iter()
            .zip(&stage.sharp_piece)
            .filter(|(_, &s)| s)
            .map(|(c, _)| c.max_error)
            .fold(0.0, f64::max)
        / diag;
    let pieces = net
        .pieces
        .iter()
        .zip(fitted)
        .zip(&stage.sharp_piece)
        .map(|((p, c), &sharp)| PieceStat {
            polyline_vertices: p.verts.len(),
            control_points: c.control.len(),
            sharp,
            closed: p.closed,
            max_error_permille: 1000.0 * c.max_error / diag,
        })
        .collect();
    (worst, pieces)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The bounded star of a long loop (2 regions sharing a 25-gon: a
    /// sphere cut at its equator) is a
    /// valid control mesh whose valences stay small, where the plain star
    /// has two centres of valence 25.
    #[test]
    fn bounded_star_layout_keeps_valences_small() {
        let n = 25u32;
        let positions: Vec<DVec3> = (0..n)
            .map(|k| {
                let a = std::f64::consts::TAU * k as f64 / n as f64;
                DVec3::new(a.cos(), a.sin(), 0.0)
            })
            .collect();
        let up: Vec<polyhedron::PolyVertex> = (0..n)
            .map(|id| polyhedron::PolyVertex { id, anchor: 0 })
            .collect();
        // The other side runs the loop backwards from another start, so
        // that its chords are not the first side's.
        let down: Vec<polyhedron::PolyVertex> = (0..n)
            .map(|k| polyhedron::PolyVertex {
                id: (6 + n - k) % n,
                anchor: 0,
            })
            .collect();
        let polygons = vec![Some(up), Some(down)];
        // One triangle of M per region for the plain star's centres.
        let mesh = TriMesh {
            positions: vec![DVec3::Z, DVec3::X, DVec3::Y, -DVec3::Z],
            triangles: vec![[0, 1, 2], [3, 2, 1]],
        };
        let region_tris = vec![vec![0], vec![1]];
        let mut polys = optimize::Polys {
            positions: positions.clone(),
            faces: Vec::new(),
            fixed: n as usize,
            creases: HashSet::new(),
            corners: Vec::new(),
            face_region: Vec::new(),
        };
        let max_valence = |polys: &optimize::Polys| {
            let c = polys.to_control().unwrap();
            c.validate().unwrap();
            (0..c.num_vertices() as u32)
                .map(|v| c.vertex_faces(crate::mesh::VertexId(v)).count())
                .max()
                .unwrap()
        };
        star_layout(
            &mesh,
            &region_tris,
            &polygons,
            &positions,
            &mut polys,
            false,
        );
        assert_eq!(max_valence(&polys), n as usize);
        star_layout(&mesh, &region_tris, &polygons, &positions, &mut polys, true);
        // Each corner: its two boundary edges and at most two chords per
        // side.
        assert!(max_valence(&polys) <= 6, "{}", max_valence(&polys));
        assert_eq!(polys.positions.len(), n as usize, "no centre added");
    }
}
