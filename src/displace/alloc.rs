//! Per-patch displacement resolution under a sample budget
//! (`--displacement-samples N`).
//!
//! A uniform `R × R` grid gives every patch the same samples whatever its
//! size and whatever detail lies under it. Here patch `f` gets its own
//! level `k_f`, `R_f = 2^{k_f} + 1` samples per side, so that across every
//! edge the finer side's grid contains the coarser side's and the edge's
//! in-between samples are dependent ([`super::PatchGrid`]).
//!
//! **Square, not `R_u × R_v`.** An edge is shared by two patches whose
//! `u` and `v` directions are unrelated, so with separate `R_u`, `R_v` a
//! patch's level on each side would be coupled to both directions of every
//! neighbour, and a tile's four borders could need four different
//! resolutions: the nesting of levels across edges (what makes both tiles
//! read the same function along the edge) would become a constraint
//! system instead of a `min` per edge. The patches of the layout are close
//! to square on M (the simplification keeps them so), where anisotropic
//! sampling gains little.
//!
//! **What a level costs and buys.** The displaced surface a host renders
//! is the limit surface plus the bilinear interpolation of the
//! displacement vectors between samples, so a patch's error is the
//! interpolation error of its displacement field. Rather than modelling it
//! from a per-patch detail figure (`n_f ∝ A_f · detail^p`), it is
//! *measured*: a pilot grid at a uniform level `k_p` (about
//! [`PILOT_FACTOR`] times the budget) gives φ's displacement vectors, and
//! for each patch and each level `k < k_p` the area-weighted squared
//! difference between the pilot's values and their bilinear interpolation
//! from the level-`k` subgrid (the nested levels are subgrids of the
//! pilot). That table is the error of the level, up to the pilot's own
//! (unresolved) error. Pilot samples that φ could not project (over a
//! hole of M, or reaching only another sheet) are left out: their values
//! are inpainted, and the jumps at a hole's rim are no detail a finer tile
//! could carry. Beyond the pilot the error falls per level as it did over
//! the last measured level, at most 16-fold ([`LEVEL_FALL`]: bilinear
//! interpolation of a smooth field errs by `O(h² |∇²d|)`). With a fixed
//! 16-fold fall and the unprojectable samples counted, the finest tiles
//! went to patches over holes and the least squares diverged there; this
//! rule puts them on real detail (measured: docs/status.md,
//! "Measurements behind the code"). (The
//! model's closed form is the `p` of the brief: minimising
//! `Σ A_f κ_f² h_f⁴` with `Σ A_f / h_f² = N` gives samples
//! `n_f = A_f / h_f² ∝ A_f κ_f^{2/3}`, i.e. `p = 2/3` with the field's
//! curvature `κ_f` as the detail. The measured table needs no exponent and
//! also sees detail that is not a smooth curvature: creases of M inside a
//! patch, thin features.)
//!
//! **Greedy allocation.** Every patch starts at level 1 (`R = 3`); the
//! upgrade with the largest error decrease per added independent sample is
//! taken while it fits in the budget (the exact count: each shared sample
//! once, dependent ones not at all). An upgrade that would overshoot is
//! dropped and smaller ones continue, so the total ends within the last
//! small upgrade of the budget. The error of a level is convex in the
//! level (it falls geometrically), so this is the usual greedy for a
//! separable convex allocation. Ties break by patch index: deterministic.

use std::cmp::Ordering;
use std::collections::{BTreeMap, BinaryHeap};

use serde::Serialize;

use crate::error::Result;
use crate::mesh::ControlMesh;
use crate::raycast::RayCaster;
use crate::subdiv::LimitEvaluator;

use super::{Displacement, PatchGrid, Probe, Probed};

/// The deepest level: `R = 65`, 64 cells per patch side (the cap of
/// [`super::auto_resolution`]).
pub const MAX_LEVEL: u32 = 6;

/// The pilot grid has at least this many times the budget's samples (at a
/// level no deeper than [`MAX_LEVEL`]); the level rounds up, so it holds
/// 2–8 times the budget. At 4 (4–16×) the pilot was most of the stage's
/// time, and 2 allocated within 1 % of its D (bunny 0.0965‰ both,
/// gargoyle 0.249‰ against 0.247‰, τ 1 %, one least-squares round;
/// docs/status.md, "Adaptive displacement").
pub const PILOT_FACTOR: f64 = 2.0;

/// The pilot grid's samples are kept below this (memory and time of the
/// φ projection on huge inputs).
const PILOT_MAX_SAMPLES: usize = 4_000_000;

/// The largest fall of the squared interpolation error per level beyond
/// the pilot: that of a smooth field (`h` halves, the error `∝ h²`, its
/// square `∝ h⁴`).
const LEVEL_FALL: f64 = 16.0;

/// What [`allocate_resolutions`] chose, for `report.json`
/// (`displacement.adaptive`).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct AdaptiveStats {
    /// The budget of independent samples asked for.
    pub budget: usize,
    /// Independent samples used (each shared sample once).
    pub samples: usize,
    /// Samples on edges between resolutions that interpolate their coarse
    /// neighbours (stored in the finer tile, not counted in `samples`).
    pub dependent_samples: usize,
    /// Samples per side of the pilot grid that measured the errors.
    pub pilot_resolution: usize,
    /// Patches per resolution (samples per side).
    pub resolution_histogram: BTreeMap<usize, usize>,
}

/// A per-patch resolution and its figures.
#[derive(Clone, Debug)]
pub struct Allocation {
    pub resolutions: Vec<usize>,
    /// The level the greedy started from ([`first_level`]): the least a
    /// grid of `resolutions` may hold ([`PatchGrid::with_resolutions_from`]).
    pub first_level: u32,
    pub stats: AdaptiveStats,
    /// What the final grid takes from the pilot.
    pub pilot: Pilot,
}

/// The pilot's part in the final displacement ([`Allocation::pilot`]).
#[derive(Clone, Debug)]
pub enum Pilot {
    /// The pilot grid and φ's answers on it, for the final grid to reuse
    /// where its samples are the pilot's ([`super::displacement_after`]).
    Probed(Probed),
    /// The final grid is the pilot grid (every patch at the pilot's level:
    /// on the 4.4M-triangle ladder rung all are at [`MAX_LEVEL`]), so the
    /// final displacement is the pilot's: the same answers at every sample
    /// and the same same-sheet test and inpainting of them
    /// ([`super::finish`]), which the final grid would only repeat.
    Final(Displacement),
}

/// A candidate upgrade in the greedy's queue: error decrease per sample,
/// then the lower patch index first.
#[derive(PartialEq)]
struct Upgrade {
    gain: f64,
    patch: usize,
    /// The sample cost the gain was computed with.
    cost: usize,
}

impl Eq for Upgrade {}

impl Ord for Upgrade {
    fn cmp(&self, other: &Self) -> Ordering {
        self.gain
            .total_cmp(&other.gain)
            .then(other.patch.cmp(&self.patch))
    }
}

impl PartialOrd for Upgrade {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

fn res_of(level: u32) -> usize {
    (1usize << level) + 1
}

/// Per-patch resolutions of `control` (all quads) whose welded grid holds
/// about `budget` independent samples, allocated where the displacement
/// needs them (module docs). The other arguments are
/// [`super::compute_displacement`]'s, for the pilot grid.
pub fn allocate_resolutions(
    control: &ControlMesh,
    evaluator: &dyn LimitEvaluator,
    caster: &dyn RayCaster,
    budget: usize,
    max_dist: f64,
    diag: f64,
    slack: f64,
) -> Result<Allocation> {
    let nf = control.num_faces();
    let mut kp = 2;
    while kp < MAX_LEVEL
        && ((nf as f64) * 4f64.powi(kp as i32)) < PILOT_FACTOR * budget as f64
        && nf * res_of(kp + 1).pow(2) <= PILOT_MAX_SAMPLES
    {
        kp += 1;
    }
    let pilot_grid = PatchGrid::new(control, res_of(kp))?;
    let sheet = super::SameSheet::new(diag, slack);
    let probe = super::probe(
        &pilot_grid,
        control,
        evaluator,
        caster,
        max_dist,
        sheet,
        None,
    )?;
    // φ's answers before the same-sheet test, for a final grid that
    // differs from the pilot's (the test clears the other-sheet hits).
    let (hits, closest) = (probe.hits.clone(), probe.closest.clone());
    let pilot = super::finish(pilot_grid, probe, diag, slack);
    let first = first_level(control, budget);
    let errors = level_errors(&pilot, kp, first);
    let levels = greedy_levels(control, &errors, budget, first);
    let resolutions: Vec<usize> = levels.iter().map(|&k| res_of(k)).collect();
    let mut histogram = BTreeMap::new();
    for &r in &resolutions {
        *histogram.entry(r).or_insert(0) += 1;
    }
    // `PatchGrid::new` and `with_resolutions` build the same grid from the
    // same resolutions (`PatchGrid::build`).
    let same = levels.iter().all(|&k| k == kp);
    let built;
    let grid = match same {
        true => &pilot.grid,
        false => {
            built = PatchGrid::with_resolutions_from(control, &resolutions, first)?;
            &built
        }
    };
    let stats = AdaptiveStats {
        budget,
        samples: grid.num_independent(),
        dependent_samples: grid.dependents().len(),
        pilot_resolution: res_of(kp),
        resolution_histogram: histogram,
    };
    let pilot = match same {
        true => Pilot::Final(pilot),
        false => Pilot::Probed(Probed {
            grid: pilot.grid,
            probe: Probe {
                limit: pilot.limit,
                directions: pilot.directions,
                hits,
                closest,
            },
        }),
    };
    Ok(Allocation {
        stats,
        resolutions,
        first_level: first,
        pilot,
    })
}

/// The switch that lets the greedy leave a patch at level 0 (`R = 2`, its
/// corners alone; [`first_level`]).
pub const LEVEL0_ENV: &str = "SUBDFIT_DISP_LEVEL0";

/// The level every patch starts at: 1 (`R = 3`), or 0 under
/// [`LEVEL0_ENV`] where the level-1 floor would eat most of the budget
/// ([`first_level_for`]). Why level 0: the smallest tile fixes a floor of
/// about 4 samples a patch (its centre, half of its four edge midpoints,
/// its corners), so on a layout refined for the displacement
/// (`SUBDFIT_DISP_REFINE`) at ~18 samples an original patch the floor
/// took ~16 and left the greedy nothing to place (session 18: gargoyle
/// τ 1 % at 1391, 0.222 → 0.226‰). From level 0 the floor is the corners
/// (about one sample a patch) and the greedy places the rest on the
/// quarters that carry the detail: the same rule (largest error decrease
/// per sample) at a four times finer grain in area.
pub fn first_level(control: &ControlMesh, budget: usize) -> u32 {
    first_level_for(
        crate::switches::on(LEVEL0_ENV),
        level1_floor(control),
        budget,
    )
}

/// The samples of `control`'s uniform level-1 grid (`R = 3`: its
/// vertices, edge midpoints and patch centres), the floor an allocation
/// from level 1 spends before its greedy places anything.
pub fn level1_floor(control: &ControlMesh) -> usize {
    control.num_vertices() + control.num_edges() + control.num_faces()
}

/// [`first_level`]'s rule: level 0 when `level0` (the switch) is on and
/// the level-1 floor `floor1` takes more than 4/5 of `budget`, else 1.
/// Why 4/5 (session 20, `SUBDFIT_DISP_REFINE` cages, floor ≈ 4 samples a
/// refined patch): gargoyle τ 1 % at 1357 / 1391 (floor 87–89 % of the
/// budget) gain 13 % of RMS D from level 0 (0.218 → 0.189‰), cheburashka
/// at 460 (floor above the budget) 7 %; spot at 81 (floor 44 %) loses 4 %
/// (0.432 → 0.449‰: with room for the greedy, the pilot's interpolation
/// error prefers corner-only quarters that the least squares then gains
/// less on), and homer at 272 (72 % once refined; refined at level 0 its
/// unprojectable share crossed the 0.1 % bar) stays unrefined as on main
/// (`convert::tail`'s gate asks this rule of the refined cage). 4/5 sits
/// midway between homer's 72 % and gargoyle's 87 %.
pub fn first_level_for(level0: bool, floor1: usize, budget: usize) -> u32 {
    u32::from(!(level0 && 5 * floor1 > 4 * budget))
}

/// Per patch, the squared interpolation error of each level `0..=MAX_LEVEL`
/// (index = level; levels below `first` unused) from the pilot grid at
/// level `kp` (module docs): measured below `kp`, the model beyond.
fn level_errors(pilot_d: &Displacement, kp: u32, first: u32) -> Vec<[f64; MAX_LEVEL as usize + 1]> {
    use rayon::prelude::*;
    let (pilot, limit) = (&pilot_d.grid, &pilot_d.limit);
    let vectors = pilot_d.vectors();

    let n = 1usize << kp;
    let h2 = 1.0 / (n * n) as f64;
    (0..pilot.num_patches())
        .into_par_iter()
        .map(|f| {
            let at = |i: usize, j: usize| pilot.sample(f, i, j) as usize;
            let mut err = [0.0; MAX_LEVEL as usize + 1];
            for k in first..kp {
                let s = 1usize << (kp - k);
                let mut sum = 0.0;
                for j in 0..=n {
                    for i in 0..=n {
                        let (ci, cj) = ((i / s).min(n / s - 1), (j / s).min(n / s - 1));
                        let (x, y) = (
                            (i - ci * s) as f64 / s as f64,
                            (j - cj * s) as f64 / s as f64,
                        );
                        let v = |a: usize, b: usize| vectors[at((ci + a) * s, (cj + b) * s)];
                        let b = (v(0, 0) * (1.0 - x) + v(1, 0) * x) * (1.0 - y)
                            + (v(0, 1) * (1.0 - x) + v(1, 1) * x) * y;
                        let p = &limit[at(i, j)];
                        // Unprojectable samples (over a hole, another
                        // sheet) hold inpainted values: no detail to buy.
                        if !pilot_d.projected[at(i, j)] {
                            continue;
                        }
                        // Area element of the pilot sample on the limit surface.
                        let w = p.du.cross(p.dv).length() * h2;
                        sum += w * (vectors[at(i, j)] - b).length_squared();
                    }
                }
                err[k as usize] = sum;
            }
            // The patch's own measured fall over the last measured level,
            // at most the smooth model's (module docs).
            let fall = if kp >= 3 && err[kp as usize - 1] > 0.0 {
                (err[kp as usize - 2] / err[kp as usize - 1]).clamp(1.0, LEVEL_FALL)
            } else {
                LEVEL_FALL
            };
            for k in kp..=MAX_LEVEL {
                err[k as usize] = err[kp as usize - 1] / fall.powi((k - kp + 1) as i32);
            }
            err
        })
        .collect()
}

/// The greedy of the module docs: per patch a level in `first..=MAX_LEVEL`.
fn greedy_levels(
    control: &ControlMesh,
    errors: &[[f64; MAX_LEVEL as usize + 1]],
    budget: usize,
    first: u32,
) -> Vec<u32> {
    let nf = control.num_faces();
    let face_edges: Vec<Vec<usize>> = control
        .faces()
        .map(|f| control.face_halfedges(f).map(|h| h.edge().idx()).collect())
        .collect();
    let mut edge_faces: Vec<Vec<usize>> = vec![Vec::new(); control.num_edges()];
    for (f, es) in face_edges.iter().enumerate() {
        for &e in es {
            edge_faces[e].push(f);
        }
    }
    let mut level = vec![first; nf];
    // Independent samples of an edge: its coarser side's interior points.
    let edge_count = |level: &[u32], e: usize| -> usize {
        edge_faces[e]
            .iter()
            .map(|&f| res_of(level[f]))
            .min()
            .unwrap_or(2)
            - 2
    };
    let interior = |k: u32| (res_of(k) - 2).pow(2);
    let mut total = control.num_vertices()
        + (0..control.num_edges())
            .map(|e| edge_count(&level, e))
            .sum::<usize>()
        + nf * interior(first);
    let cost = |level: &mut Vec<u32>, f: usize| -> usize {
        let k = level[f];
        let before: usize = face_edges[f].iter().map(|&e| edge_count(level, e)).sum();
        level[f] = k + 1;
        let after: usize = face_edges[f].iter().map(|&e| edge_count(level, e)).sum();
        level[f] = k;
        interior(k + 1) - interior(k) + after - before
    };
    let gain = |f: usize, k: u32, c: usize| {
        (errors[f][k as usize] - errors[f][k as usize + 1]).max(0.0) / c.max(1) as f64
    };
    let mut heap = BinaryHeap::new();
    for f in 0..nf {
        let c = cost(&mut level, f);
        heap.push(Upgrade {
            gain: gain(f, first, c),
            patch: f,
            cost: c,
        });
    }
    while let Some(up) = heap.pop() {
        let f = up.patch;
        let c = cost(&mut level, f);
        if c != up.cost {
            // A neighbour changed since: queue it again at its true price.
            heap.push(Upgrade {
                gain: gain(f, level[f], c),
                patch: f,
                cost: c,
            });
            continue;
        }
        if total + c > budget {
            // Would overshoot: this patch stays; smaller upgrades go on.
            continue;
        }
        level[f] += 1;
        total += c;
        if level[f] < MAX_LEVEL {
            let c = cost(&mut level, f);
            heap.push(Upgrade {
                gain: gain(f, level[f], c),
                patch: f,
                cost: c,
            });
        }
    }
    level
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fixtures::flat_grid;

    #[test]
    fn greedy_meets_the_budget_and_follows_the_error() {
        // Patch 0's error is 100 times the others' at every level: it must
        // end at least as fine as every other patch, and the count of the
        // resulting grid is the greedy's own and within 5 % of the budget.
        let m = flat_grid(8, 8);
        let nf = m.num_faces();
        let mut errors = vec![[0.0; MAX_LEVEL as usize + 1]; nf];
        for (f, e) in errors.iter_mut().enumerate() {
            for (k, ek) in e.iter_mut().enumerate().skip(1) {
                *ek = if f == 0 { 100.0 } else { 1.0 } * 16f64.powi(-(k as i32));
            }
        }
        for budget in [1500, 4000, 12000] {
            let levels = greedy_levels(&m, &errors, budget, 1);
            let res: Vec<usize> = levels.iter().map(|&k| res_of(k)).collect();
            let g = PatchGrid::with_resolutions(&m, &res).unwrap();
            let n = g.num_independent();
            assert!(n <= budget, "budget {budget}: {n} samples, {res:?}");
            assert!(
                n as f64 >= 0.95 * budget as f64,
                "budget {budget}: {n}, {res:?}"
            );
            assert!(levels.iter().all(|&k| k <= levels[0]), "{levels:?}");
            assert!(levels[0] > levels[nf - 1], "{levels:?}");
        }
    }
}

#[cfg(test)]
mod level0_tests {
    use super::*;
    use crate::fixtures::flat_grid;

    /// From level 0 (`SUBDFIT_DISP_LEVEL0`), at budgets below the level-1
    /// floor (289 samples here: the greedy from level 1 could place
    /// nothing): every patch with error gets a tile (they all fit from
    /// 181 samples, and their upgrades out-gain any upgrade of a patch
    /// without error, which only a leftover too small for theirs buys),
    /// at least half the patches without error stay at their corners
    /// (`R = 2`), the grid of mixed 2s and finer tiles builds and
    /// triangulates, and its count is the greedy's own and within 5 % of
    /// the budget (as from level 1).
    #[test]
    fn greedy_from_level_0_spends_the_budget_where_the_error_is() {
        let m = flat_grid(8, 8);
        let nf = m.num_faces();
        let mut errors = vec![[0.0; MAX_LEVEL as usize + 1]; nf];
        // The left half's patches carry error, the right half's none.
        let rough = |f: usize| f % 8 < 4;
        for (f, e) in errors.iter_mut().enumerate() {
            for (k, ek) in e.iter_mut().enumerate() {
                *ek = if rough(f) {
                    16f64.powi(-(k as i32))
                } else {
                    0.0
                };
            }
        }
        let floor1 = PatchGrid::new(&m, 3).unwrap().num_independent();
        assert_eq!(floor1, 289);
        for budget in [200, 250, floor1 - 1] {
            let levels = greedy_levels(&m, &errors, budget, 0);
            let res: Vec<usize> = levels.iter().map(|&k| res_of(k)).collect();
            let g = PatchGrid::with_resolutions_from(&m, &res, 0).unwrap();
            let n = g.num_independent();
            assert!(
                n <= budget && n as f64 >= 0.95 * budget as f64,
                "{budget}: {n}"
            );
            let smooth_at_0 = (0..nf).filter(|&f| !rough(f) && levels[f] == 0).count();
            assert!(2 * smooth_at_0 >= nf / 2, "{budget}: {levels:?}");
            assert!(
                (0..nf).filter(|&f| rough(f)).all(|f| levels[f] >= 1),
                "{levels:?}"
            );
            assert_eq!(g.triangles().len(), g.triangle_range(nf - 1).end);
        }
    }
}

#[cfg(test)]
mod gate_tests {
    use super::*;
    use crate::fixtures::{cube, flat_grid};

    /// `first_level_for`'s guarantee, on a closed and an open cage and
    /// their refinements: `level1_floor` is the level-1 grid's own count
    /// (so the rule reads the real floor); level 0 is chosen exactly where
    /// that floor exceeds 4/5 of the budget, so from level 1 the greedy
    /// always has at least a fifth of the budget to place; never without
    /// the switch; and a grid started at the chosen level builds, within
    /// the budget (within 5 % of it from level 0 on the 6 × 6 grid).
    #[test]
    fn level0_only_where_the_level1_floor_takes_over_four_fifths() {
        let closed = crate::subdiv::refine::refine_once_keeping_infinite(&cube()).unwrap();
        for m in [cube(), closed, flat_grid(6, 6)] {
            let nf = m.num_faces();
            let floor1 = PatchGrid::new(&m, 3).unwrap().num_independent();
            assert_eq!(level1_floor(&m), floor1);
            let floor0 = PatchGrid::new(&m, 2).unwrap().num_independent();
            let mut errors = vec![[0.0; MAX_LEVEL as usize + 1]; nf];
            for (f, e) in errors.iter_mut().enumerate() {
                for (k, ek) in e.iter_mut().enumerate() {
                    *ek = (1 + f % 3) as f64 * 16f64.powi(-(k as i32));
                }
            }
            for budget in floor0..3 * floor1 {
                assert_eq!(first_level_for(false, floor1, budget), 1);
                let first = first_level_for(true, floor1, budget);
                assert_eq!(first == 0, 5 * floor1 > 4 * budget, "{budget}");
                if first == 1 {
                    assert!(5 * (budget - floor1) >= budget, "{budget}");
                }
                if budget % 7 != 0 || (first == 1 && budget < floor1) {
                    continue;
                }
                let levels = greedy_levels(&m, &errors, budget, first);
                assert!(levels.iter().all(|&k| k >= first));
                let res: Vec<usize> = levels.iter().map(|&k| res_of(k)).collect();
                let g = PatchGrid::with_resolutions_from(&m, &res, first).unwrap();
                let n = g.num_independent();
                assert!(n <= budget, "{budget}: {n}");
                // On the 36 patches, below 4/5 of the level-1 floor the
                // upgrades (a level or two) are small against the budget.
                if nf >= 36 && first == 0 {
                    assert!(20 * n >= 19 * budget, "{budget}: {n}");
                }
            }
        }
    }
}

#[cfg(test)]
mod detail_tests {
    use super::*;
    use crate::displace::{compute_displacement, displacement_on, HostSurface};
    use crate::fixtures::cube;
    use crate::mesh::TriMesh;
    use crate::raycast::{make_raycaster, RayBackend};
    use crate::report::{distance_stats, quadrature_points};
    use crate::subdiv::{make_evaluator, Backend, EvalOptions};

    /// The cube refined once (24 patches) and M: a fine welded sampling
    /// of its limit surface, displaced along the limit normal by ripples
    /// of amplitude 0.02 (wavelength ≈ 0.6, two across the cap) on a cap
    /// of about 45° around +z (the four patches of the cube's top face)
    /// and none elsewhere.
    fn rippled_cube() -> (
        crate::mesh::ControlMesh,
        Box<dyn crate::subdiv::LimitEvaluator>,
        TriMesh,
    ) {
        let control = crate::subdiv::refine::refine_once_keeping_infinite(&cube()).unwrap();
        let ev = make_evaluator(Backend::Osd, &control, &EvalOptions::default()).unwrap();
        let fine = PatchGrid::new(&control, 49).unwrap();
        let ripple = |p: &crate::subdiv::LimitPoint| {
            let d = p.position.normalize();
            let cap = ((d.z - 0.7) / 0.15).clamp(0.0, 1.0);
            p.position + p.normal() * 0.02 * cap * (10.0 * d.x).sin() * (10.0 * d.y).sin()
        };
        let mesh = TriMesh {
            positions: ev
                .evaluate(control.positions(), fine.locations())
                .unwrap()
                .iter()
                .map(ripple)
                .collect(),
            triangles: fine.triangles(),
        };
        (control, ev, mesh)
    }

    /// [`rippled_cube`] with what every test here measures it by: M's
    /// diagonal and Embree scene, the allocation at a budget and a fresh
    /// displacement on a grid (φ at the tests' 0.5 reach and 1 % spread).
    struct Rippled {
        control: crate::mesh::ControlMesh,
        ev: Box<dyn crate::subdiv::LimitEvaluator>,
        mesh: TriMesh,
        diag: f64,
        caster: Box<dyn RayCaster>,
    }

    impl Rippled {
        fn new() -> Self {
            let (control, ev, mesh) = rippled_cube();
            let diag = mesh.bbox_diagonal();
            let caster = make_raycaster(RayBackend::Embree, &mesh).unwrap();
            Rippled {
                control,
                ev,
                mesh,
                diag,
                caster,
            }
        }

        fn allocate(&self, budget: usize) -> Allocation {
            let (c, ev, caster) = (&self.control, self.ev.as_ref(), self.caster.as_ref());
            allocate_resolutions(c, ev, caster, budget, 0.5, self.diag, 0.01).unwrap()
        }

        fn fresh(&self, grid: PatchGrid) -> Displacement {
            let (c, ev, caster) = (&self.control, self.ev.as_ref(), self.caster.as_ref());
            displacement_on(grid, c, ev, caster, 0.5, self.diag, 0.01).unwrap()
        }
    }

    #[test]
    fn the_final_grid_reusing_the_pilot_is_the_fresh_one_bit_for_bit() {
        // `displacement_after` takes the pilot's limit points, hits and
        // closest distances where the final grid samples the same
        // location: every figure must be the one a fresh evaluation gives
        // (the outputs' byte identity rests on it), including the samples
        // that are not shared (patches finer than the pilot, edge samples
        // the finer side owns) and the dependents.
        let rc = Rippled::new();
        let (control, ev, diag, caster) =
            (&rc.control, rc.ev.as_ref(), rc.diag, rc.caster.as_ref());
        // A budget above the pilot's level on the cap (the pilot is at
        // 2–8× the budget, the finest level beyond it is extrapolated).
        for budget in [600, 2500] {
            let alloc = rc.allocate(budget);
            let Pilot::Probed(pilot) = &alloc.pilot else {
                panic!("budget {budget}: mixed resolutions, yet the pilot's grid");
            };
            let grid = PatchGrid::with_resolutions(control, &alloc.resolutions).unwrap();
            let fresh = rc.fresh(grid.clone());
            let reused = crate::displace::displacement_after(
                grid, pilot, control, ev, caster, 0.5, diag, 0.01,
            )
            .unwrap();
            assert_same_displacement(&fresh, &reused, budget);
            // Something was reused (a patch at or below the pilot's
            // level), and something was not (mixed resolutions: edge
            // samples the finer side owns), else the test says nothing
            // about one of the two paths.
            let pr = pilot.grid.res();
            let r = &alloc.resolutions;
            assert!(r.iter().any(|&x| x <= pr), "budget {budget}: {r:?}");
            assert!(r.windows(2).any(|w| w[0] != w[1]), "budget {budget}: {r:?}");
        }
    }

    /// `a` and `b` bit for bit: limit points, directions, offsets, flags
    /// and figures (what the written files are made of).
    fn assert_same_displacement(a: &Displacement, b: &Displacement, budget: usize) {
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        let pts = |d: &Displacement| {
            d.limit
                .iter()
                .flat_map(|p| [p.position, p.du, p.dv])
                .chain(d.directions.iter().copied())
                .flat_map(|v| v.to_array())
                .collect::<Vec<f64>>()
        };
        assert_eq!(bits(&pts(a)), bits(&pts(b)), "budget {budget}");
        assert_eq!(bits(&a.offsets), bits(&b.offsets), "budget {budget}");
        assert_eq!(a.projected, b.projected, "budget {budget}");
        assert_eq!(a.stats, b.stats, "budget {budget}");
        assert_eq!(a.grid.locations().len(), b.grid.locations().len());
        for (p, q) in a.grid.locations().iter().zip(b.grid.locations()) {
            assert!(p.face == q.face && p.u.to_bits() == q.u.to_bits());
            assert!(p.v.to_bits() == q.v.to_bits() && p.sub == q.sub);
        }
    }

    #[test]
    fn a_final_grid_equal_to_the_pilot_is_the_pilot_displacement() {
        // A budget above every patch at the deepest level (24 patches of
        // 65² samples, ~10⁵): the pilot is at `MAX_LEVEL` and so is every
        // patch, as on the 4.4M-triangle ladder rung. The allocation then
        // hands over the pilot's displacement, which must be the one the
        // final grid computes afresh.
        let rc = Rippled::new();
        let control = &rc.control;
        let budget = 1_000_000;
        let alloc = rc.allocate(budget);
        assert!(alloc.resolutions.iter().all(|&r| r == res_of(MAX_LEVEL)));
        let Pilot::Final(kept) = &alloc.pilot else {
            panic!("every patch at the pilot's level, yet no final displacement");
        };
        let grid = PatchGrid::with_resolutions(control, &alloc.resolutions).unwrap();
        assert_eq!(alloc.stats.samples, grid.num_independent());
        assert_eq!(alloc.stats.dependent_samples, 0);
        let fresh = rc.fresh(grid);
        assert_same_displacement(&fresh, kept, budget);
    }

    #[test]
    fn adaptive_beats_uniform_where_detail_is_concentrated() {
        // Control and M: [`rippled_cube`]. At equal
        // independent samples the per-patch allocation must put its
        // samples on the cap and so lower RMS M → D (D: the host's
        // bilinear surface, φ offsets).
        let rc = Rippled::new();
        let (control, ev, mesh, diag) = (&rc.control, rc.ev.as_ref(), &rc.mesh, rc.diag);
        let caster = rc.caster.as_ref();
        let (mp, mw) = quadrature_points(mesh);
        let rms = |d: &Displacement| {
            let host = HostSurface::new(control, ev, d).unwrap();
            let dm = host.mesh(d);
            let dc = make_raycaster(RayBackend::Embree, &dm).unwrap();
            distance_stats(&mp, &mw, dc.as_ref(), diag)
                .unwrap()
                .rms_permille
        };
        let uniform = compute_displacement(control, ev, caster, 9, 0.5, diag, 0.01).unwrap();
        let budget = uniform.grid.num_independent();
        let alloc = rc.allocate(budget);
        let grid = PatchGrid::with_resolutions(control, &alloc.resolutions).unwrap();
        let n = grid.num_independent();
        assert!(
            n <= budget && n as f64 >= 0.95 * budget as f64,
            "{n} of {budget}"
        );
        let adaptive = rc.fresh(grid);
        let (u, a) = (rms(&uniform), rms(&adaptive));
        // The top face's patches (centres at z ≈ 0.82) are at least as
        // fine as every patch away from the cap (centre below z = 0.5,
        // where M is the limit surface itself).
        let centre_z = |f: usize| {
            let l = crate::subdiv::SurfaceLocation::quad(crate::mesh::FaceId(f as u32), 0.5, 0.5);
            ev.evaluate(control.positions(), &[l]).unwrap()[0]
                .position
                .normalize()
                .z
        };
        let r = &alloc.resolutions;
        let cap: Vec<usize> = (0..r.len()).filter(|&f| centre_z(f) > 0.75).collect();
        assert_eq!(cap.len(), 4);
        let cap_min = cap.iter().map(|&f| r[f]).min();
        let off_max = (0..r.len())
            .filter(|&f| centre_z(f) < 0.5)
            .map(|f| r[f])
            .max();
        let msg = format!("uniform {u:.4}‰, adaptive {a:.4}‰, {:?}", alloc.stats);
        assert!(cap_min >= off_max, "{msg}");
        // Measured: see the message; ask for a clear margin (the ripples
        // dominate both errors).
        assert!(a < 0.7 * u, "{msg}");
    }
}
