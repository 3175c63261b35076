//! The tube cap (`SUBDFIT_FIELD_TUBE_CAP=k`, off by default; issue 40,
//! homer at `--faces 272` under the single draw, docs/status.md
//! "Field-aligned layout", session 25, helper fingers): where M is a tube
//! thinner than the lattice step (homer's fingers: 14–17‰ of the
//! diagonal across, asked 37.5‰ edges), no sizing built from the Fitmap
//! holds it: the lattice's points, compared extrinsically (Jakob et al.
//! 2015, §5.2), are farther apart than the tube is wide, so the whole
//! tube rounds to one or two lattice points and the extraction leaves it
//! under a patch or two whose limit surface misses the tip
//! (unprojectable). A tube of thickness t has circumference ≈ π t and is
//! held by a ring of four quads when their edges are ≤ π t / 4; so the
//! sizes are capped at `k · t` there (k ≈ π / 4), a cap that the face
//! count's scaling does not relax (the rest of the mesh pays for it).
//!
//! A vertex is on a tube when the ray along −n from it leaves M's solid
//! after a thickness t, and from the midpoint of that chord a ray in one
//! of the cross field's two tangent directions, both ways, meets M within
//! [`TUBE_SPAN`] · t (and not nearer than [`TUBE_MIN`] · t): across a
//! tube's axis the chord's midpoint is its centre (t / (2 cos θ) for a
//! direction θ off the perpendicular), while along a thin sheet (a wing)
//! both directions run the sheet's width, and at its rim across it the
//! sheet's thickness, so sheets keep their sizes.

use crate::error::Result;
use crate::raycast::{Ray, RayCaster};
use crate::DVec3;

use super::Surface;

/// Half-chords across a tube within this many thicknesses count (θ up to
/// 60° off the perpendicular to the axis).
pub const TUBE_SPAN: f64 = 1.0;

/// ... and beyond this many: across a round tube the half-chord is at
/// least t / 2, while at a sheet's rim the chord along −n runs the
/// sheet's width and the half-chords across it are the sheet's half
/// thickness, far below (a tube flattened 2:1 is still one from its flat
/// sides).
pub const TUBE_MIN: f64 = 0.25;

/// The ray along −n starts this many mean edges in, past the vertex's own
/// triangles.
const START_EDGES: f64 = 0.05;

/// Per vertex, `k · t` where M is a tube of thickness t at it (never
/// below M's mean edge: the lattice cannot resolve less), infinite
/// elsewhere (see the module docs).
pub fn tube_caps(s: &Surface, dirs: &[DVec3], caster: &dyn RayCaster, k: f64) -> Result<Vec<f64>> {
    let n = s.len();
    let eps = START_EDGES * s.mean_edge;
    let inward: Vec<Ray> = (0..n)
        .map(|i| Ray {
            origin: s.positions[i],
            dir: -s.normals[i],
            tmin: eps,
            tmax: f64::INFINITY,
        })
        .collect();
    let thick: Vec<f64> = caster
        .first_hits(&inward)?
        .iter()
        .map(|h| h.map_or(f64::INFINITY, |h| h.t))
        .collect();
    // Four tangent rays from each chord's midpoint (misses and open
    // chords: no ray, no cap).
    let mut rays = Vec::with_capacity(4 * n);
    for i in 0..n {
        let t = thick[i];
        let c = s.positions[i] - 0.5 * t * s.normals[i];
        let q = dirs[i];
        let b = s.normals[i].cross(q);
        for d in [q, -q, b, -b] {
            rays.push(Ray {
                origin: if t.is_finite() { c } else { s.positions[i] },
                dir: d,
                tmin: 0.0,
                tmax: if t.is_finite() { TUBE_SPAN * t } else { 0.0 },
            });
        }
    }
    let across = caster.first_hits(&rays)?;
    let caps: Vec<f64> = (0..n)
        .map(|i| {
            let hit = |j: usize| across[4 * i + j].is_some_and(|h| h.t >= TUBE_MIN * thick[i]);
            let tube = thick[i].is_finite() && ((hit(0) && hit(1)) || (hit(2) && hit(3)));
            if tube {
                (k * thick[i]).max(s.mean_edge)
            } else {
                f64::INFINITY
            }
        })
        .collect();
    // `FIELD_DUMP=DIR` (a trace): per vertex its position, thickness and cap.
    if let Some(dir) = crate::switches::text("FIELD_DUMP").filter(|d| !d.is_empty()) {
        let mut text = String::new();
        for i in 0..n {
            let p = s.positions[i];
            text.push_str(&format!(
                "{} {} {} {} {}\n",
                p.x, p.y, p.z, thick[i], caps[i]
            ));
        }
        let _ = std::fs::write(format!("{dir}/tube-caps.txt"), text);
    }
    Ok(caps)
}

/// A tube is capped only where it is thinner than this share of the
/// lattice step (`SUBDFIT_FIELD_TUBE_SKIP`): there the lattice skips it
/// (homer's fingers, t ≈ 0.4 h at `--faces 272`), while a tube about as
/// thick as the step is held by the coarse lattice already (capping
/// every tube, spot's legs and ears at `--faces 81` went from RMS L
/// 8.6‰ to 16.7‰, docs/status.md session 25).
pub const TUBE_SKIP: f64 = 0.5;

/// `h` capped at `caps` (those of factor `k`) where the tube is thinner
/// than `skip` times h, and graded again at `gamma`
/// ([`super::sizing::grade`]: the cap spreads into the surroundings at
/// the sizing's own slope, so the lattice steps down to the tube).
pub fn capped(s: &Surface, h: &[f64], caps: &[f64], k: f64, skip: f64, gamma: f64) -> Vec<f64> {
    let mut out: Vec<f64> = h
        .iter()
        .zip(caps)
        .map(|(&a, &c)| if c < k * skip * a { a.min(c) } else { a })
        .collect();
    super::sizing::grade(s, &mut out, gamma);
    out
}
