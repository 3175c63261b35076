//! The tessellations written as `limit.ply` and `displaced.ply`: `N × N`
//! cells per patch (`--tessellation N`), welded, so they are watertight
//! wherever the control mesh is closed.
//!
//! - `limit.ply`: the exact limit surface (OpenSubdiv) at the grid points,
//!   each cell split along the same diagonal;
//! - `displaced.ply`: at each grid point the limit point plus the
//!   displacement *vector* (`offset · direction` at each of the `R × R`
//!   samples, the direction by [`crate::displace`]'s rule: the limit
//!   normal, the normalised sum of the patches' normals on creases and
//!   corners) read by bilinear interpolation in the patch's `(u, v)` —
//!   what a host does with `displacement_vector.exr` and its UVs, exactly
//!   (Blender's Displace in RGB-to-XYZ mode lands on these vertices to
//!   f32 round-off). At the samples it is the scalar map along the
//!   direction; between them the two differ by the turn of the direction
//!   within a texel times the offset: nothing on smooth parts, but up to
//!   1.5 % of the diagonal where the limit surface folds (spot), where
//!   "along the normal" means something different in every renderer.
//!   Shared-edge samples are the same numbers on both sides, so the
//!   displaced surface is watertight wherever L is. Cells split along the
//!   shorter displaced diagonal.
//!
//! **Chord error** is the distance between the tessellation and the exact
//! limit surface, measured at every cell's edge midpoints and at the
//! midpoint of its diagonal (where a piecewise-linear interpolant of a
//! smooth surface is furthest from it, to second order) as the distance
//! from the linear point to the tangent plane of the surface point at the
//! same parameter (to second order, its distance to the surface). The default `N`
//! is the smallest power of two ([`MIN_SEGMENTS`] to [`MAX_SEGMENTS`], and below
//! [`MAX_DEFAULT_SAMPLES`] vertices) whose RMS chord error is below a
//! tenth of the fit's RMS distance L → M and whose largest is below that
//! RMS distance itself. (The largest sits at extraordinary vertices, where
//! Catmull-Clark's curvature is unbounded, and falls slowly with N: a
//! tenth of RMS L there would take N = 64 on spot and more on fandisk, for
//! files of 50 MB.) So the
//! file is the fitted surface to well within the fit's own error; a power
//! of two, so that a renderer's uniform subdivision at level log₂ N puts
//! its vertices on ours. The figures are in `report.json`'s
//! `tessellation`.

use serde::Serialize;

use crate::displace::{BsplineTiles, Displacement, PatchGrid, Reconstruction};
use crate::error::{Error, Result};
use crate::mesh::{ControlMesh, FaceId, TriMesh};
use crate::subdiv::{LimitEvaluator, SurfaceLocation};
use crate::DVec3;

/// The smallest default tessellation: never coarser than the grids the
/// measurements use on the shared meshes (13–22 cells per side).
pub const MIN_SEGMENTS: usize = 16;

/// The largest default tessellation (cells per patch side); a given
/// `--tessellation` may go to [`MAX_GIVEN_SEGMENTS`].
pub const MAX_SEGMENTS: usize = 64;

/// The default stops doubling before the files would pass this many
/// vertices (a few hundred MB of PLY): the chord error is then reported as
/// missing its target.
pub const MAX_DEFAULT_SAMPLES: usize = 4_000_000;

/// The largest `--tessellation` accepted.
pub const MAX_GIVEN_SEGMENTS: usize = 1024;

/// Figures of the written tessellations, for `report.json`.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct TessellationStats {
    /// Cells per patch side of `limit.ply` and `displaced.ply`.
    pub segments_per_patch_side: usize,
    /// Whether `segments_per_patch_side` was given or chosen (module docs).
    pub given: bool,
    /// Chord error of `limit.ply` against the exact limit surface, ‰ of
    /// M's diagonal.
    pub chord_error_max_permille: f64,
    pub chord_error_rms_permille: f64,
    /// A tenth of the fit's RMS L: the default's bound on the RMS chord
    /// error, and ten times it (RMS L itself) on the largest (module
    /// docs).
    pub target_permille: f64,
    pub target_met: bool,
}

/// The two tessellations and their figures.
pub struct Tessellations {
    pub limit: TriMesh,
    pub displaced: TriMesh,
    /// Per vertex of `displaced`: its offset, and whether every sample the
    /// interpolation reads was projected (`displaced.ply`'s `displacement`
    /// and `projected`).
    pub offsets: Vec<f64>,
    pub projected: Vec<bool>,
    pub stats: TessellationStats,
}

/// `limit.ply` and `displaced.ply` for `control` (all quads) and its
/// displacement `d`, at `segments` cells per patch side or the default
/// (module docs) for a fit of RMS L `rms_l_permille`: [`density`], then
/// [`tessellate_at`].
pub fn tessellate(
    control: &ControlMesh,
    evaluator: &dyn LimitEvaluator,
    d: &Displacement,
    diag: f64,
    segments: Option<usize>,
    rms_l_permille: f64,
) -> Result<Tessellations> {
    let density = density(control, evaluator, diag, segments, rms_l_permille)?;
    tessellate_at(control, evaluator, d, density)
}

/// The tessellations' cells per patch side and their chord error
/// ([`density`]): what needs only the control mesh and RMS L, not the
/// displacement, so that [`crate::report`] runs it beside the displacement
/// (on L's side, whose worker otherwise idles through the displacement's
/// serial parts; session 22).
pub struct Density {
    n: usize,
    segments: Option<usize>,
    max: f64,
    rms: f64,
    target: f64,
    /// The uniform grid at `n` and its limit positions, when at most
    /// [`KEPT_SAMPLES`]: a uniform displacement (or a given `segments`)
    /// tessellates on them; else [`tessellate_at`] evaluates them again
    /// (the same bits) if it needs them.
    uniform: Option<(PatchGrid, Vec<DVec3>)>,
}

/// [`Density::uniform`] is kept up to this many samples (~48 MB with their
/// locations): it waits beside the whole displacement, whose peak on big
/// inputs it would otherwise add to (session 20's peaks).
const KEPT_SAMPLES: usize = 1 << 20;

/// The default `N` (module docs) for a fit of RMS L `rms_l_permille`, or
/// the given `segments`, with the chord error of the uniform grid at `N`.
pub fn density(
    control: &ControlMesh,
    evaluator: &dyn LimitEvaluator,
    diag: f64,
    segments: Option<usize>,
    rms_l_permille: f64,
) -> Result<Density> {
    if let Some(n) = segments {
        if n == 0 || n > MAX_GIVEN_SEGMENTS {
            return Err(Error::option(
                "tessellation",
                format!("tessellation: {n} cells per patch side; give 1 to {MAX_GIVEN_SEGMENTS}"),
            ));
        }
    }
    let target = 0.1 * rms_l_permille;
    let mut n = segments.unwrap_or(MIN_SEGMENTS);
    let (grid, limit, (max, rms)) = loop {
        let grid = PatchGrid::new(control, n + 1)?;
        let limit = evaluator.evaluate(control.positions(), grid.locations())?;
        let pos: Vec<DVec3> = limit.iter().map(|p| p.position).collect();
        let (max, rms) = chord_error(control, evaluator, &grid, &pos)?;
        crate::watch::memtrace("tessellate: chord error");
        let (max, rms) = (1000.0 * max / diag, 1000.0 * rms / diag);
        let next_samples = grid.num_patches() * (2 * n + 1) * (2 * n + 1);
        let met = rms <= target && max <= 10.0 * target;
        if segments.is_some() || met || 2 * n > MAX_SEGMENTS || next_samples > MAX_DEFAULT_SAMPLES {
            break (grid, pos, (max, rms));
        }
        n *= 2;
    };
    let uniform = (limit.len() <= KEPT_SAMPLES).then_some((grid, limit));
    Ok(Density {
        n,
        segments,
        max,
        rms,
        target,
        uniform,
    })
}

/// The tessellations of `control` and its displacement `d` at `density`
/// ([`tessellate`]).
pub fn tessellate_at(
    control: &ControlMesh,
    evaluator: &dyn LimitEvaluator,
    d: &Displacement,
    density: Density,
) -> Result<Tessellations> {
    let Density {
        n,
        segments,
        max,
        rms,
        target,
        uniform,
    } = density;
    // A displacement of per-patch resolutions: each patch tessellated at
    // least as finely as its tile (N·2^j cells, nested across edges, so
    // the grid stays welded and watertight), so that no sample of a fine
    // tile falls between the vertices. A `--tessellation N` the user gave
    // is kept as given, as with uniform tiles finer than N.
    let (grid, positions) = if d.grid.is_uniform() || segments.is_some() {
        match uniform {
            Some(kept) => kept,
            None => {
                let grid = PatchGrid::new(control, n + 1)?;
                let limit = evaluator.evaluate(control.positions(), grid.locations())?;
                let pos = limit.iter().map(|p| p.position).collect();
                (grid, pos)
            }
        }
    } else {
        // The uniform grid's samples go before the finer grid's are
        // evaluated (session 20: both held at once were the peak of
        // gargoyle τ 1 % under `SUBDFIT_DISP_LEVEL0`).
        drop(uniform);
        let res: Vec<usize> = (0..control.num_faces())
            .map(|f| {
                let mut cells = n;
                // The B-spline bends within a knot cell: two cells each.
                let least = match d.reconstruction {
                    Reconstruction::Bspline => 2 * (d.grid.patch_res(f) - 1),
                    Reconstruction::Bilinear => d.grid.patch_res(f) - 1,
                };
                while cells < least {
                    cells *= 2;
                }
                cells + 1
            })
            .collect();
        let grid = PatchGrid::with_resolutions_from(control, &res, d.grid.first_level())?;
        let limit = evaluator.evaluate(control.positions(), grid.locations())?;
        let pos = limit.iter().map(|p| p.position).collect();
        (grid, pos)
    };
    crate::watch::memtrace("tessellate: grid evaluated");
    // The host's lookup: bilinear in the samples, or the cubic B-spline of
    // the coefficients (`crate::displace::BsplineTiles`).
    let tiles = (d.reconstruction == Reconstruction::Bspline).then(|| BsplineTiles::new(&d.grid));
    let (offsets, projected): (Vec<f64>, Vec<bool>) = grid
        .locations()
        .iter()
        .map(|l| lookup(d, tiles.as_ref(), l, |s| d.offsets[s]))
        .unzip();
    let vectors = d.vectors();
    let displaced_positions: Vec<DVec3> = positions
        .iter()
        .zip(grid.locations())
        .map(|(&p, l)| p + lookup(d, tiles.as_ref(), l, |s| vectors[s]).0)
        .collect();
    Ok(Tessellations {
        limit: TriMesh {
            triangles: grid.triangles(),
            positions,
        },
        displaced: TriMesh {
            triangles: grid.triangles_shorter_diagonal(&displaced_positions),
            positions: displaced_positions,
        },
        offsets,
        projected,
        stats: TessellationStats {
            segments_per_patch_side: n,
            given: segments.is_some(),
            chord_error_max_permille: max,
            chord_error_rms_permille: rms,
            target_permille: target,
            target_met: rms <= target && max <= 10.0 * target,
        },
    })
}

/// `value(sample)` at `loc` as the host reads it: [`bilinear`], or the
/// B-spline of `tiles` when given (and whether every sample read was
/// projected).
fn lookup<T>(
    d: &Displacement,
    tiles: Option<&BsplineTiles>,
    loc: &SurfaceLocation,
    value: impl Fn(usize) -> T,
) -> (T, bool)
where
    T: std::ops::Mul<f64, Output = T> + std::ops::Add<Output = T> + Default,
{
    let Some(tiles) = tiles else {
        return bilinear(d, loc, value);
    };
    let terms = tiles.terms(loc.face.idx(), loc.u, loc.v);
    let projected = terms.iter().all(|e| d.projected[e.0 as usize]);
    let v = terms
        .iter()
        .fold(T::default(), |a, &(s, w)| a + value(s as usize) * w);
    (v, projected)
}

/// `value(sample)` at `loc` (a quad patch location): bilinear in the
/// patch's `R × R` samples, as a renderer filters the atlas between texel
/// centres; and whether the samples with a nonzero weight were all
/// projected.
fn bilinear<T>(d: &Displacement, loc: &SurfaceLocation, value: impl Fn(usize) -> T) -> (T, bool)
where
    T: std::ops::Mul<f64, Output = T> + std::ops::Add<Output = T>,
{
    let g = &d.grid;
    let f = loc.face.idx();
    let r1 = g.patch_res(f) - 1;
    let at = |x: f64| {
        let x = x.clamp(0.0, 1.0) * r1 as f64;
        let i = (x.floor() as usize).min(r1 - 1);
        (i, x - i as f64)
    };
    let ((i, s), (j, t)) = (at(loc.u), at(loc.v));
    let o = |i: usize, j: usize| value(g.sample(f, i, j) as usize);
    let value = (o(i, j) * (1.0 - s) + o(i + 1, j) * s) * (1.0 - t)
        + (o(i, j + 1) * (1.0 - s) + o(i + 1, j + 1) * s) * t;
    let mut projected = true;
    for (di, wi) in [(0, 1.0 - s), (1, s)] {
        for (dj, wj) in [(0, 1.0 - t), (1, t)] {
            if wi * wj > 0.0 {
                projected &= d.projected[g.sample(f, i + di, j + dj) as usize];
            }
        }
    }
    (value, projected)
}

/// How many midpoints [`chord_error`] evaluates at once (whole patches,
/// so a batch may run over by one patch's).
const CHORD_BATCH: usize = 1 << 16;

/// Largest and RMS chord error (module docs) of the tessellation of
/// `grid` with vertex positions `pos`, in model units. The midpoints are
/// evaluated a batch of patches at a time, summed in the same order as at
/// once (the same bits): session 20, gargoyle τ 1 % under
/// `SUBDFIT_DISP_LEVEL0` held ~4 M midpoints with their limit points and
/// chords at once, most of its 1.4 GB peak.
fn chord_error(
    control: &ControlMesh,
    evaluator: &dyn LimitEvaluator,
    grid: &PatchGrid,
    pos: &[DVec3],
) -> Result<(f64, f64)> {
    chord_error_in(control, evaluator, grid, pos, CHORD_BATCH)
}

/// [`chord_error`] with batches of at least `batch` midpoints.
fn chord_error_in(
    control: &ControlMesh,
    evaluator: &dyn LimitEvaluator,
    grid: &PatchGrid,
    pos: &[DVec3],
    batch: usize,
) -> Result<(f64, f64)> {
    let mut locs = Vec::new();
    let mut linear = Vec::new();
    let (mut max, mut sum, mut count) = (0.0f64, 0.0, 0usize);
    let mut flush = |locs: &mut Vec<SurfaceLocation>, linear: &mut Vec<DVec3>| -> Result<()> {
        let exact = evaluator.evaluate(control.positions(), locs)?;
        for (e, l) in exact.iter().zip(linear.iter()) {
            // The normal component: near an extraordinary vertex the
            // parametrisation is far from uniform, so the linear point and the
            // surface point at the same parameter are apart *along* the
            // surface too, which is not an error of the shape.
            let dist = (e.position - *l).dot(e.normal()).abs();
            max = max.max(dist);
            sum += dist * dist;
        }
        count += locs.len();
        locs.clear();
        linear.clear();
        Ok(())
    };
    for f in 0..grid.num_patches() {
        let r1 = grid.patch_res(f) - 1;
        let h = 1.0 / r1 as f64;
        let p = |i: usize, j: usize| pos[grid.sample(f, i, j) as usize];
        let face = FaceId(f as u32);
        for j in 0..=r1 {
            for i in 0..=r1 {
                let (u, v) = (i as f64 * h, j as f64 * h);
                // Edge midpoints along u and v (the last row and column
                // close the grid), and the diagonal a–c of
                // `PatchGrid::triangles`.
                if i < r1 {
                    locs.push(SurfaceLocation::quad(face, u + 0.5 * h, v));
                    linear.push(0.5 * (p(i, j) + p(i + 1, j)));
                }
                if j < r1 {
                    locs.push(SurfaceLocation::quad(face, u, v + 0.5 * h));
                    linear.push(0.5 * (p(i, j) + p(i, j + 1)));
                }
                if i < r1 && j < r1 {
                    locs.push(SurfaceLocation::quad(face, u + 0.5 * h, v + 0.5 * h));
                    linear.push(0.5 * (p(i, j) + p(i + 1, j + 1)));
                }
            }
        }
        if locs.len() >= batch {
            flush(&mut locs, &mut linear)?;
        }
    }
    if !locs.is_empty() {
        flush(&mut locs, &mut linear)?;
    }
    Ok((max, (sum / count.max(1) as f64).sqrt()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::subdiv::{make_evaluator, Backend, EvalOptions};

    /// The batched chord error is the all-at-once one bit for bit: the
    /// same midpoints, summed in the same order (one patch per batch
    /// against all six of the cube's in one).
    #[test]
    fn chord_error_in_batches_is_the_whole_grids_bits() {
        let control = crate::fixtures::cube();
        let evaluator =
            make_evaluator(Backend::Osd, &control, &EvalOptions::default()).expect("evaluator");
        let grid = PatchGrid::new(&control, 9).expect("grid");
        let limit = evaluator
            .evaluate(control.positions(), grid.locations())
            .expect("limit");
        let pos: Vec<DVec3> = limit.iter().map(|p| p.position).collect();
        let run = |batch| chord_error_in(&control, evaluator.as_ref(), &grid, &pos, batch);
        let (max1, rms1) = run(1).expect("per patch");
        let (max_all, rms_all) = run(usize::MAX).expect("at once");
        // The cube's limit is curved: a chord is off it (not a vacuous 0 = 0).
        assert!(rms1 > 0.0 && max1 >= rms1, "max {max1}, rms {rms1}");
        assert_eq!(max1.to_bits(), max_all.to_bits());
        assert_eq!(rms1.to_bits(), rms_all.to_bits());
    }

    /// The tessellations from a [`Density`] made beforehand are
    /// [`tessellate`]'s, bit for bit, whether the density kept its uniform
    /// grid or [`tessellate_at`] evaluates it again: a displacement of
    /// uniform tiles (the branch that reads the kept grid) on a cube whose
    /// limit is displaced onto the unit sphere.
    #[test]
    fn density_made_beforehand_gives_the_same_tessellations() {
        let control = crate::fixtures::cube();
        let ev =
            make_evaluator(Backend::Osd, &control, &EvalOptions::default()).expect("evaluator");
        let fine = PatchGrid::new(&control, 21).expect("grid");
        let sphere = TriMesh {
            positions: ev
                .evaluate(control.positions(), fine.locations())
                .expect("limit")
                .iter()
                .map(|p| p.position.normalize())
                .collect(),
            triangles: fine.triangles(),
        };
        let diag = sphere.bbox_diagonal();
        let caster = crate::raycast::make_raycaster(crate::raycast::RayBackend::Embree, &sphere)
            .expect("caster");
        let d = crate::displace::compute_displacement(
            &control,
            ev.as_ref(),
            caster.as_ref(),
            5,
            2.0,
            diag,
            0.05,
        )
        .expect("displacement");
        assert!(d.grid.is_uniform());
        let bits = |t: &Tessellations| {
            let p = |m: &TriMesh| -> Vec<[u64; 3]> {
                m.positions
                    .iter()
                    .map(|x| x.to_array().map(f64::to_bits))
                    .collect()
            };
            let o: Vec<u64> = t.offsets.iter().map(|x| x.to_bits()).collect();
            let tris = (t.limit.triangles.clone(), t.displaced.triangles.clone());
            (p(&t.limit), p(&t.displaced), o, t.projected.clone(), tris)
        };
        for segments in [None, Some(3)] {
            let whole = tessellate(&control, ev.as_ref(), &d, diag, segments, 0.5).expect("whole");
            // The displacement moved the cube's limit: the test is not 0 = 0.
            assert!(whole.offsets.iter().any(|o| o.abs() > 1e-3));
            let make = || density(&control, ev.as_ref(), diag, segments, 0.5).expect("density");
            let kept = make();
            assert!(kept.uniform.is_some());
            let mut dropped = make();
            dropped.uniform = None;
            for dens in [kept, dropped] {
                let t = tessellate_at(&control, ev.as_ref(), &d, dens).expect("at");
                assert!(bits(&t) == bits(&whole), "{segments:?}");
                assert_eq!(t.stats, whole.stats);
            }
        }
    }
}
