//! The samples the same-sheet test rejects, looked at again
//! (`SUBDFIT_DISP_SHEET`, off by default; issue 40, gargoyle 421).
//!
//! [`super::compute_displacement`] rejects a line's nearest hit when it
//! lies beyond `3·d_M + slack` (d_M: the sample's distance to M) and
//! inpaints the sample from its neighbours. On gargoyle 421 under the
//! single-draw configuration those 222 samples (0.9 % of 24,992) carry
//! 66 % of D's squared error (D → M 0.50‰ against 0.30‰ over the
//! projected samples; docs/status.md, "Adaptive displacement"): most lie
//! where the limit surface spans a crevice (between a wing and the arm,
//! d_M up to 12.8‰), its normal making ~80° with M's at the closest point,
//! so the line's nearest hit lies 4–15 d_M away, on the crevice's walls or
//! floor — the sample's own sheet, met at a grazing angle, not another
//! sheet. The harmonic fill leaves those samples hanging in the crevice's
//! mouth (their displaced points 3.0‰ from M in RMS).
//!
//! [`resolve`] tells the two apart by orientation: M's outward normal at a
//! hit on the sample's own sheet faces the way the limit normal does (the
//! sheet the patch approximates), while the far side of a thin part faces
//! the other way. Of the line's hits (both directions, nearest first, up
//! to [`MAX_HITS`] each way) the nearest whose triangle's normal makes a
//! cosine of at least [`MIN_COS`] with the limit normal and which lies
//! within [`FAR_FACTOR`]`·d_M + slack` is taken as the sample's offset and
//! the sample counts as projected, provided M's nearest sheet itself faces
//! the limit normal's way ([`OWN_MIN_COS`]); the others stay unprojectable
//! and are inpainted from the (now larger) set of known samples as before.
//!
//! Measured (docs/status.md, "Adaptive displacement", session 25): it
//! lowers RMS D where the rejected samples are grazing hits on their own
//! sheet (gargoyle 421 0.504 → 0.492‰, homer 272 0.794 → 0.680‰, gargoyle
//! 402 0.253 → 0.245‰ under the single draw), but not to gargoyle 421's
//! bar: most of its error is a knot of the limit surface 18‰ inside M
//! whose samples' lines, taken or inpainted, cannot lay D on M.

use crate::error::Result;
use crate::mesh::TriMesh;
use crate::raycast::{Ray, RayCaster};
use crate::DVec3;

use super::{inpaint, Displacement};

/// Hits read along each direction of a line at most.
const MAX_HITS: usize = 6;

/// How far, in distances to M, an orientation-consistent hit may lie
/// (the same-sheet test's factor is 3). Gargoyle 421 (single draw, its
/// control mesh measured with `report::evaluate_surfaces`): factor 4 / 6 /
/// 8 at cosine 0.5 give RMS D 0.498 / 0.488 / 0.491‰ against 0.501‰ off;
/// 12 at 0.3 gives 0.611‰, 30 at 0 3.15‰ (grazing hits of neighbouring
/// samples far apart on M: D's triangles span the crevice).
const FAR_FACTOR: f64 = 6.0;

/// Least cosine between M's normal at the hit and the limit normal
/// (60°): at 0 the same run gives 0.548‰, at 0.7 0.494‰, at 0.9 0.504‰.
const MIN_COS: f64 = 0.5;

/// Least cosine between M's normal at the sample's closest point and the
/// limit normal: where M's nearest sheet faces away, the limit surface is
/// folded inside out over it, and a hit several distances away yanks the
/// sample across the fold. Bunny at the defaults has such a knot (9
/// samples, cosine −0.7, hits at 4–6 d_M): without this test RMS D rises
/// 0.683 → 0.770‰, with it stays 0.683‰; gargoyle 421 0.488 → 0.489‰,
/// homer 272 0.673 → 0.685‰, gargoyle's defaults 0.280 → 0.279‰ (all
/// measured with `report::evaluate_surfaces` on the runs' control meshes);
/// 0.3 instead: 421 0.500‰, gargoyle's defaults 0.313‰.
const OWN_MIN_COS: f64 = 0.0;

/// Whether the pass runs (`SUBDFIT_DISP_SHEET` set and not `0`).
pub fn enabled() -> bool {
    crate::switches::not_zero("SUBDFIT_DISP_SHEET").unwrap_or(false)
}

/// `SUBDFIT_DISP_SHEET=fixed`: the samples still unprojectable after the
/// pass also keep their inpainted offsets through the least squares (the
/// ridge of the samples over M's holes, `displace::lsq`), which otherwise
/// moves them like the rest. Gargoyle 421 0.488 → 0.413‰, but spot 81
/// 0.400 → 0.437‰, gargoyle 402 0.249 → 0.271‰ (M → D rises: those
/// samples no longer reach out to cover M); measured, not the pass's
/// default.
pub fn fixed() -> bool {
    enabled() && crate::switches::text("SUBDFIT_DISP_SHEET").as_deref() == Some("fixed")
}

/// The hits of the line through `o` along `n` within `max_t`, both
/// directions, up to [`MAX_HITS`] each way: `(t, cosine of M's normal
/// there with n)`, by increasing `|t|`.
fn line_hits(
    mesh: &TriMesh,
    caster: &dyn RayCaster,
    origins: &[DVec3],
    dirs: &[DVec3],
    max_t: f64,
    step: f64,
) -> Result<Vec<Vec<(f64, f64)>>> {
    let n = origins.len();
    let mut out: Vec<Vec<(f64, f64)>> = vec![Vec::new(); n];
    for sign in [1.0, -1.0] {
        // Per line, the parameter the next ray starts from (None: done).
        let mut from: Vec<Option<f64>> = vec![Some(0.0); n];
        for _ in 0..MAX_HITS {
            let live: Vec<usize> = (0..n).filter(|&i| from[i].is_some()).collect();
            if live.is_empty() {
                break;
            }
            let rays: Vec<Ray> = live
                .iter()
                .map(|&i| Ray {
                    origin: origins[i],
                    dir: sign * dirs[i],
                    tmin: from[i].unwrap_or(0.0),
                    tmax: max_t,
                })
                .collect();
            let hits = caster.first_hits(&rays)?;
            for (&i, h) in live.iter().zip(hits) {
                match h {
                    Some(h) => {
                        let [a, b, c] = mesh.triangle(h.triangle as usize);
                        let m = (b - a).cross(c - a).normalize_or_zero();
                        out[i].push((sign * h.t, m.dot(dirs[i])));
                        from[i] = Some(h.t + step).filter(|&t| t <= max_t);
                    }
                    None => from[i] = None,
                }
            }
        }
    }
    for h in &mut out {
        h.sort_by(|a, b| a.0.abs().total_cmp(&b.0.abs()).then(b.0.total_cmp(&a.0)));
    }
    Ok(out)
}

/// What [`resolve`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Resolved {
    /// Unprojectable independent samples looked at.
    pub looked: usize,
    /// Of those, given an orientation-consistent hit.
    pub resolved: usize,
}

/// The pass of the module docs on a finished displacement (φ's offsets,
/// inpainted; before any least squares): `mesh` is M, `caster` built over
/// it, `max_dist` φ's search distance, `slack` the same-sheet test's.
pub fn resolve(
    disp: &mut Displacement,
    mesh: &TriMesh,
    caster: &dyn RayCaster,
    max_dist: f64,
    diag: f64,
    slack: f64,
) -> Result<Resolved> {
    let grid = disp.grid.clone();
    let mut dependent = vec![false; disp.offsets.len()];
    for d in grid.dependents() {
        dependent[d.sample as usize] = true;
    }
    let looked: Vec<usize> = (0..disp.offsets.len())
        .filter(|&i| !disp.projected[i] && !dependent[i])
        .collect();
    if looked.is_empty() {
        disp.stats.sheet_resolved = Some(0);
        return Ok(Resolved::default());
    }
    let origins: Vec<DVec3> = looked.iter().map(|&i| disp.limit[i].position).collect();
    let dirs: Vec<DVec3> = looked.iter().map(|&i| disp.directions[i]).collect();
    let step = 1e-7 * diag;
    let hits = line_hits(mesh, caster, &origins, &dirs, max_dist, step)?;
    let closest = caster.closest_points(&origins, f64::INFINITY)?;
    let mut resolved = 0;
    for ((&i, h), c) in looked.iter().zip(&hits).zip(&closest) {
        let Some(c) = c else { continue };
        let [a, b, e] = mesh.triangle(c.triangle as usize);
        let own = (b - a)
            .cross(e - a)
            .normalize_or_zero()
            .dot(disp.directions[i]);
        if own < OWN_MIN_COS {
            continue;
        }
        let bound = FAR_FACTOR * c.distance + slack;
        let pick = h
            .iter()
            .take_while(|(t, _)| t.abs() <= bound)
            .find(|(_, m)| *m >= MIN_COS);
        if let Some(&(t, _)) = pick {
            disp.offsets[i] = t;
            disp.projected[i] = true;
            resolved += 1;
        }
    }
    if resolved > 0 {
        for d in grid.dependents() {
            disp.projected[d.sample as usize] =
                disp.projected[d.a as usize] && disp.projected[d.b as usize];
        }
        inpaint(&grid, &mut disp.offsets, &disp.projected);
        grid.apply_dependents(&mut disp.offsets);
        let st = &mut disp.stats;
        st.unprojectable -= resolved.min(st.unprojectable);
        st.other_sheet -= resolved.min(st.other_sheet);
        st.unprojectable_percent =
            100.0 * st.unprojectable as f64 / disp.offsets.len().max(1) as f64;
        let max_abs = disp.offsets.iter().fold(0.0f64, |m, d| m.max(d.abs()));
        st.max_abs_offset_permille = 1000.0 * max_abs / diag.max(f64::MIN_POSITIVE);
    }
    disp.stats.sheet_resolved = Some(resolved);
    Ok(Resolved {
        looked: looked.len(),
        resolved,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fixtures::{flat_grid, tri_grid};
    use crate::raycast::{make_raycaster, RayBackend};
    use crate::subdiv::{make_evaluator, Backend, EvalOptions};

    /// A floor `z = −0.1 x` over `[−1, 4.15] × [−1, 5]` meeting a wall
    /// through `x = 4.15` at `z = 0.3` (`z ∈ [−1, 1]`, leaning by `lean`:
    /// `x = 4.15 − lean·(z − 0.3)`, its triangles facing `+x`); the
    /// floor's triangles face `+z`, or `−z` without `up` (the far side of
    /// a thin part, seen from above).
    fn floor_and_wall(up: bool, lean: f64) -> TriMesh {
        let mut mesh = tri_grid(
            20,
            |i, j| {
                let x = -1.0 + 5.15 * i as f64 / 20.0;
                DVec3::new(x, -1.0 + 6.0 * j as f64 / 20.0, -0.1 * x)
            },
            |_, _| true,
        );
        if !up {
            for t in &mut mesh.triangles {
                t.swap(1, 2);
            }
        }
        let wall = tri_grid(
            20,
            |i, j| {
                let z = -1.0 + 2.0 * j as f64 / 20.0;
                DVec3::new(4.15 - lean * (z - 0.3), -1.0 + 6.0 * i as f64 / 20.0, z)
            },
            |_, _| true,
        );
        let base = mesh.positions.len() as u32;
        mesh.positions.extend(wall.positions);
        mesh.triangles
            .extend(wall.triangles.iter().map(|t| t.map(|v| v + base)));
        mesh
    }

    #[test]
    fn a_rejected_sample_takes_the_hit_on_its_own_sheet_not_the_far_side() {
        // The limit surface is the plane z = 0.3 over [0, 4]² (samples
        // 0.25 apart). At x = 4 the wall is 0.15 away while the floor
        // lies 0.7 down the (vertical) normal line: the same-sheet test
        // (0.7 > 3 · 0.15 + slack) rejects the floor hit and the column is
        // inpainted from x = 3.75, whose floor is 0.025 higher: the
        // displaced points float 0.025 above M. The pass takes the floor
        // hit (0.7 ≤ 6 · 0.15 + slack, M's normal along the limit normal)
        // and puts them on the floor exactly; when the floor faces away
        // (the far side of a thin part), or the samples' nearest sheet
        // does (the wall: a limit surface folded over it), it leaves them
        // as they were.
        let mut control = flat_grid(4, 4);
        for p in control.positions_mut() {
            p.z = 0.3;
        }
        let ev = make_evaluator(Backend::Osd, &control, &EvalOptions::default()).unwrap();
        let (slack, max_dist) = (0.01, 2.0);
        let displace = |caster: &dyn RayCaster, diag: f64| {
            super::super::compute_displacement(
                &control,
                ev.as_ref(),
                caster,
                5,
                max_dist,
                diag,
                slack,
            )
            .unwrap()
        };
        // (floor facing away, wall leaning away): only the first resolves.
        for (flip, against) in [(false, false), (true, false), (false, true)] {
            let probe = floor_and_wall(true, 0.0);
            let diag = probe.bbox_diagonal();
            let d0 = displace(
                make_raycaster(RayBackend::Embree, &probe).unwrap().as_ref(),
                diag,
            );
            // The floor faces the way the limit normal does, or with
            // `flip` the other way; the wall (the samples' nearest sheet)
            // leans so that it faces the limit normal's way a little (the
            // pass's own-sheet test, `OWN_MIN_COS`).
            let up = d0.directions[0].z > 0.0;
            let lean = if up == against { -0.05 } else { 0.05 };
            let mesh = floor_and_wall(up != flip, lean);
            let caster = make_raycaster(RayBackend::Embree, &mesh).unwrap();
            let before = displace(caster.as_ref(), diag);
            let pos = before.limit_positions();
            let edge: Vec<usize> = (0..pos.len())
                .filter(|&i| (pos[i].x - 4.0).abs() < 1e-9)
                .collect();
            assert_eq!(edge.len(), 17);
            // Exactly the x = 4 column is rejected, as another sheet.
            for (i, p) in pos.iter().enumerate() {
                assert_eq!(before.projected[i], !edge.contains(&i), "sample {i} at {p}");
            }
            assert_eq!(before.stats.other_sheet, 17);
            let height = |d: &Displacement, i: usize| {
                let q = pos[i] + d.offsets[i] * d.directions[i];
                q.z + 0.1 * q.x
            };
            for &i in &edge {
                // Inpainted from x = 3.75: 0.025 above the floor.
                assert!(
                    (height(&before, i) - 0.025).abs() < 1e-6,
                    "{}",
                    height(&before, i)
                );
            }
            let mut after = before.clone();
            let r = resolve(&mut after, &mesh, caster.as_ref(), max_dist, diag, slack).unwrap();
            assert_eq!(r.looked, 17);
            if flip || against {
                assert_eq!(r.resolved, 0);
                assert_eq!(after.stats.sheet_resolved, Some(0));
                assert!(after
                    .offsets
                    .iter()
                    .zip(&before.offsets)
                    .all(|(a, b)| a.to_bits() == b.to_bits()));
                assert!(edge.iter().all(|&i| !after.projected[i]));
            } else {
                assert_eq!(r.resolved, 17);
                assert_eq!(after.stats.unprojectable, 0);
                assert_eq!(after.stats.sheet_resolved, Some(17));
                for i in 0..pos.len() {
                    assert!(after.projected[i]);
                    // On the floor (the hit), or unchanged.
                    if edge.contains(&i) {
                        assert!(height(&after, i).abs() < 1e-9, "{}", height(&after, i));
                    } else {
                        assert_eq!(after.offsets[i].to_bits(), before.offsets[i].to_bits());
                    }
                }
            }
        }
    }
}
