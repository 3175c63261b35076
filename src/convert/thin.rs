//! At a fixed patch count (`--faces N`), a second field layout that moves
//! lattice size to the patches whose fitted limit surface stands off M′
//! (issue 40, session 10).
//!
//! Measured last session (docs/status.md, "Where the field layout's RMS D
//! gap at the peers' counts lies", `examples/thin_diag.rs`): on spot at 80
//! patches and cheburashka at 458 one patch held ~74 % of the displaced
//! surface's squared distance to M: its limit spans a thin part and passes
//! 6–27‰ from M, where no displacement along its normal reaches M. At a
//! fixed count with `--max-error inf` no round refines it.
//!
//! So after the first layout's fit, the limit surface is sampled (a grid
//! of cells per patch, as [`super::field`] measures M′ → limit) and each
//! sample's distance to M′ is taken, the direction in which D → M misses:
//! the RMS over the limit's area is the round's criterion ([`off_m`]).
//! A patch whose own RMS is above [`FAR`] times the whole surface's is
//! "far"; h is lowered under it by the Fitmap's error model E(r) = a r⁴
//! (Fitmaps §3.1.2: `(rms / rms_p)^¼`, at most [`MAX_REFINE`]), on the
//! vertices of M′ nearest to it and under its samples; the sizing is
//! regraded and scaled back to the first layout's predicted count
//! ([`lowered_sizing`]), laid out at N again with the same count passes
//! as the first ([`crate::quad::field::field_layout_counted`]) and fitted.
//! The round with the lower criterion is kept, so the second round never
//! raises the kept result's measured limit → M′ RMS.
//!
//! On by default ([`THIN_ROUND_DEFAULT`]; `SUBDFIT_THIN_ROUND=0` turns it
//! off): measured at the peers' counts (docs/status.md, Field-aligned
//! layout, session 10) it was kept on homer at 272 (RMS D 1.09 → 0.45‰)
//! and not kept, or not run, on spot, cheburashka and gargoyle (their
//! outputs byte-identical). A variant that judged the rounds by the
//! samples the displacement cannot carry onto M′ only was measured worse
//! there (cheburashka: RMS L 1.84 → 4.71‰) and is not kept.

use crate::error::Result;
use crate::fit::Fitted;
use crate::mesh::{ControlMesh, TriMesh};
use crate::quad::field::{field_layout_counted, sizing, FieldOptions, Surface};
use crate::raycast::bvh::BvhCaster;
use crate::raycast::RayCaster;
use crate::report::StageTimer;

use super::field::{FieldRound, Sizes};
use super::layout::FieldRelayout;

/// Whether the second round runs without [`THIN_ROUND_ENV`].
pub const THIN_ROUND_DEFAULT: bool = true;

/// The environment switch: `1` runs the second round, `0` does not
/// (unset: [`THIN_ROUND_DEFAULT`]).
pub const THIN_ROUND_ENV: &str = "SUBDFIT_THIN_ROUND";

/// A patch is far when its RMS distance to M′ is above this many times
/// the whole limit surface's (the test is meant to pick a few patches,
/// not a tail: on gargoyle no patch is far at 1357 or 1391 patches).
pub const FAR: f64 = 3.0;

/// The smallest factor on h under a far patch (a quarter of its area:
/// the lattice then lays about four patches where it laid one).
pub const MAX_REFINE: f64 = 0.5;

/// Whether the second round is on (module docs).
pub fn enabled() -> bool {
    match std::env::var(THIN_ROUND_ENV) {
        Ok(v) if v.trim() == "0" => false,
        Ok(v) if v.trim() == "1" => true,
        _ => THIN_ROUND_DEFAULT,
    }
}

/// [`off_m`]'s measurement of a fitted control mesh.
#[derive(Clone, Debug)]
pub struct OffM {
    /// RMS distance from the limit surface to M′ over the limit's area
    /// (units of M′): the round's criterion.
    pub rms: f64,
    /// The far patches (control faces).
    pub far: Vec<u32>,
    /// Per vertex of M′, the factor on h its far patch asks for (1 where
    /// none does).
    pub factor: Vec<f64>,
}

/// The limit surface of `control` against `mesh` (M′, `caster` over it):
/// the area-weighted RMS distance of its samples to M′, its far patches
/// and the factors on h they ask for (module docs).
pub fn off_m(mesh: &TriMesh, caster: &BvhCaster, control: &ControlMesh) -> Result<OffM> {
    let k = super::field::grid_cells(mesh, control);
    let (surface, tri_face, locs, _) = super::field::limit_grid(control, k)?;
    let weights = crate::report::vertex_areas(&surface);
    let near = caster.closest_points(&surface.positions, f64::INFINITY)?;
    let faces = control.num_faces();
    let mut sum = vec![(0.0, 0.0); faces];
    let (mut all, mut area) = (0.0, 0.0);
    for ((c, &a), loc) in near.iter().zip(&weights).zip(&locs) {
        let Some(c) = c else { continue };
        let d2 = c.distance * c.distance;
        let s = &mut sum[loc.face.0 as usize];
        s.0 += a * d2;
        s.1 += a;
        all += a * d2;
        area += a;
    }
    let rms = (all / f64::max(area, f64::MIN_POSITIVE)).sqrt();
    let patch_rms: Vec<f64> = sum
        .iter()
        .map(|&(e, a)| if a > 0.0 { (e / a).sqrt() } else { 0.0 })
        .collect();
    let is_far: Vec<bool> = patch_rms.iter().map(|&r| r > FAR * rms).collect();
    let far: Vec<u32> = (0..faces)
        .filter(|&f| is_far[f])
        .map(|f| f as u32)
        .collect();
    let mut factor = vec![1.0; mesh.positions.len()];
    if far.is_empty() {
        return Ok(OffM { rms, far, factor });
    }
    // E(r) = a r⁴ (Fitmaps §3.1.2): h × (rms / rms_p)^¼ brings the patch's
    // error to the surface's.
    let of = |f: usize| (rms / patch_rms[f]).powf(0.25).max(MAX_REFINE);
    // The vertices of M′ whose nearest limit point lies on a far patch
    // (the part of M′ it stands for) ...
    let grid = BvhCaster::new(&surface)?;
    let nearest = grid.closest_points(&mesh.positions, f64::INFINITY)?;
    for (v, c) in nearest.iter().enumerate() {
        let Some(c) = c else { continue };
        let f = tri_face[c.triangle as usize] as usize;
        if is_far[f] {
            factor[v] = f64::min(factor[v], of(f));
        }
    }
    // ... and those under its samples (across a thin part the samples'
    // nearest points lie on both sheets, some nearer to other patches).
    for (c, loc) in near.iter().zip(&locs) {
        let (Some(c), f) = (c, loc.face.0 as usize) else {
            continue;
        };
        if is_far[f] {
            for v in mesh.triangles[c.triangle as usize] {
                factor[v as usize] = f64::min(factor[v as usize], of(f));
            }
        }
    }
    Ok(OffM { rms, far, factor })
}

/// `h0` lowered by `factor`, graded at `gamma`, at least M′'s mean edge,
/// and scaled so that it predicts as many patches as `h0` (the patches
/// added under the far ones taken from everywhere else:
/// [`sizing::predicted_faces`], `∫ dA / h²`).
pub fn lowered_sizing(surf: &Surface, h0: &[f64], factor: &[f64], gamma: f64) -> Vec<f64> {
    let target = sizing::predicted_faces(surf, h0);
    let at = |c: f64| -> Vec<f64> {
        let mut h: Vec<f64> = h0.iter().zip(factor).map(|(h, f)| c * h * f).collect();
        sizing::grade(surf, &mut h, gamma);
        for x in &mut h {
            *x = x.max(surf.mean_edge);
        }
        h
    };
    // The count falls monotonically with c; the lowered sizing predicts
    // more than `h0` at c = 1, so c ≥ 1 (bisection on ln c up to 4).
    let (mut lo, mut hi) = (0.0f64, 4.0f64.ln());
    for _ in 0..40 {
        let mid = 0.5 * (lo + hi);
        if sizing::predicted_faces(surf, &at(mid.exp())) > target {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    at(hi.exp())
}

/// The second round (module docs) after the first round's fit `first`:
/// the round fitted by `fit` on a layout at `fo`'s count whose sizing is
/// lowered under the far patches, pushed on `rounds`, and the fit kept by
/// the lower [`off_m`] RMS. `first` unchanged when no patch is far.
pub(super) fn second_round(
    timer: &mut StageTimer,
    relayout: &FieldRelayout,
    fo: &FieldOptions,
    first: Fitted,
    rounds: &mut Vec<FieldRound>,
    mut fit: impl FnMut(&mut StageTimer, ControlMesh) -> Result<Fitted>,
) -> Result<Fitted> {
    let mesh = &relayout.mesh;
    let permille = 1000.0 / mesh.bbox_diagonal();
    let caster = BvhCaster::new(mesh)?;
    let m0 = timer.run("thin round", || off_m(mesh, &caster, &first.control))?;
    if let Some(r) = rounds.last_mut() {
        r.off_m_permille = Some(permille * m0.rms);
        r.patches_off_m = Some(m0.far.len());
    }
    if m0.far.is_empty() {
        return Ok(first);
    }
    let laid = timer.run("field layout", || {
        let s = Sizes::new(mesh, &relayout.fitmap, fo)?;
        let h = lowered_sizing(&s.surf, &s.h, &m0.factor, fo.gradation);
        field_layout_counted(&relayout.prepared, mesh, &relayout.fitmap, h, fo)
    })?;
    let (faces, irregular) = (laid.control.num_faces(), laid.stats.irregular_vertices);
    let second = fit(timer, laid.control)?;
    let m1 = timer.run("thin round", || off_m(mesh, &caster, &second.control))?;
    // Kept only at the count asked for (`--faces`' ±2 % window, or no
    // farther from N than the first round).
    let n = fo.target_faces.map_or(faces, |n| n) as f64;
    let off = |f: usize| (f as f64 - n).abs();
    let first_faces = first.control.num_faces();
    let at_count = off(faces) <= f64::max(0.02 * n, off(first_faces));
    let keep_second = at_count && m1.rms < m0.rms;
    rounds.push(FieldRound {
        target_faces: fo.target_faces,
        faces,
        irregular_vertices: irregular,
        fit_rms_permille: second.report.final_rms_permille,
        layout_rms_permille: None,
        adaptivity_spearman: None,
        layout_unprojectable_percent: None,
        layout_thin_percent: None,
        patches_refined: 0,
        patches_coarsened: 0,
        patches_unprojectable: 0,
        size_factor: Some(laid.stats.size_factor),
        patches_split: None,
        off_m_permille: Some(permille * m1.rms),
        patches_off_m: Some(m1.far.len()),
        kept: Some(keep_second),
    });
    Ok(if keep_second { second } else { first })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::DVec3;

    /// The square [0, n]² as a triangle mesh of `m` × `m` cells per
    /// unit.
    fn plane(n: usize, m: usize) -> TriMesh {
        let s = n * m;
        let positions = (0..=s)
            .flat_map(|j| (0..=s).map(move |i| DVec3::new(i as f64, j as f64, 0.0) / m as f64))
            .collect();
        let at = |i: usize, j: usize| (j * (s + 1) + i) as u32;
        let triangles = (0..s)
            .flat_map(|j| (0..s).map(move |i| (i, j)))
            .flat_map(|(i, j)| {
                [
                    [at(i, j), at(i + 1, j), at(i + 1, j + 1)],
                    [at(i, j), at(i + 1, j + 1), at(i, j + 1)],
                ]
            })
            .collect();
        TriMesh {
            positions,
            triangles,
        }
    }

    /// An `n` × `n` quad grid on the same square, its vertex at `(5, 5)`
    /// lifted by `lift`: the limit stands off the plane around it only.
    fn grid(n: usize, lift: f64) -> ControlMesh {
        let positions = (0..=n)
            .flat_map(|j| {
                (0..=n).map(move |i| {
                    let z = if (i, j) == (5, 5) { lift } else { 0.0 };
                    DVec3::new(i as f64, j as f64, z)
                })
            })
            .collect();
        let at = |i: usize, j: usize| (j * (n + 1) + i) as u32;
        let quads: Vec<[u32; 4]> = (0..n)
            .flat_map(|j| (0..n).map(move |i| (i, j)))
            .map(|(i, j)| [at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1)])
            .collect();
        ControlMesh::from_polygons(positions, &quads).expect("grid")
    }

    /// A limit lifted around one control vertex: the four patches at it
    /// are far (their RMS is several times the surface's), a corner patch
    /// is not; h is lowered on the plane's vertices under them by the r⁴
    /// model (never below [`MAX_REFINE`]) and left alone at the corner.
    /// On a flat grid nothing is far and the criterion is ~0.
    #[test]
    fn a_patch_standing_off_the_mesh_is_far_and_lowers_h_under_it() {
        let mesh = plane(10, 3);
        let caster = BvhCaster::new(&mesh).expect("caster");
        let flat = off_m(&mesh, &caster, &grid(10, 0.0)).expect("flat");
        assert!(flat.far.is_empty(), "{:?}", flat.far);
        assert!(flat.rms < 1e-9, "{}", flat.rms);
        assert!(flat.factor.iter().all(|&f| f == 1.0));
        let lifted = off_m(&mesh, &caster, &grid(10, 2.0)).expect("lifted");
        assert!(lifted.rms > 0.05, "{}", lifted.rms);
        // Faces are numbered row by row: (i, j) is face 10 j + i.
        let face = |i: u32, j: u32| 10 * j + i;
        for f in [face(4, 4), face(5, 4), face(4, 5), face(5, 5)] {
            assert!(lifted.far.contains(&f), "{f} not in {:?}", lifted.far);
        }
        assert!(!lifted.far.contains(&face(0, 0)));
        assert!(lifted.far.len() <= 16, "{:?}", lifted.far);
        // The plane's vertex under (5, 5) and at the corner (0, 0).
        let centre = (5 * 3) * (10 * 3 + 1) + 5 * 3;
        assert!(lifted.factor[centre] < 1.0 && lifted.factor[centre] >= MAX_REFINE);
        assert_eq!(lifted.factor[0], 1.0);
    }

    /// The lowered sizing predicts the first sizing's patch count (the
    /// added patches taken from elsewhere, to the bisection's 1e-6), is
    /// lower where the factor is and higher than before elsewhere, and
    /// keeps the grading slope γ.
    #[test]
    fn the_lowered_sizing_keeps_the_predicted_count() {
        let mesh = plane(10, 3);
        let surf = Surface::new(&mesh).expect("surface");
        let h0 = vec![0.5; mesh.positions.len()];
        let factor: Vec<f64> = mesh
            .positions
            .iter()
            .map(|p| {
                if (*p - DVec3::new(5.0, 5.0, 0.0)).length() < 1.0 {
                    0.5
                } else {
                    1.0
                }
            })
            .collect();
        let gamma = 0.5;
        let h = lowered_sizing(&surf, &h0, &factor, gamma);
        let (n0, n) = (
            sizing::predicted_faces(&surf, &h0),
            sizing::predicted_faces(&surf, &h),
        );
        assert!((n / n0 - 1.0).abs() < 1e-4, "{n} vs {n0}");
        let centre = (5 * 3) * (10 * 3 + 1) + 5 * 3;
        assert!(h[centre] < 0.5 && h[0] > 0.5, "{} {}", h[centre], h[0]);
        for &[a, b] in &surf.edges {
            let d = (mesh.positions[a as usize] - mesh.positions[b as usize]).length();
            assert!((h[a as usize] - h[b as usize]).abs() <= gamma * d + 1e-12);
        }
    }
}
