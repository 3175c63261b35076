//! Step 2: the target edge length h per vertex from the Fitmap.
//!
//! The greedy simplifier accepts a patch of radius r (centre to farthest
//! corner) when `r · F_S ≤ κ` (the S-fitmap test, κ = `s_fitmap_scale` ·
//! κ₀ with κ₀ from [`crate::quad::s_fitmap_kappa`]) and `r ≤ F_M` (the
//! M-fitmap test, Fitmaps §3.3.1). A square of edge h has r = h/√2, so the
//! same limits in edge length are `h_S = √2 κ / F_S` and `h_M = √2 F_M`,
//! and `h = min(α h_S, β h_M)` (design note, step 2): at α = β = 1 the
//! field layout aims at the patches the simplifier would stop at. Then
//! `h_i ← min(h_i, h_j + γ |x_i − x_j|)` grades it (only ever lowering h,
//! so F_M's bound survives). α for a face count N solves `∫ dA / h² = N`
//! by bisection (a quad of edge h covers h²).

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use crate::analysis::Fitmap;
use crate::error::{Error, Result};
use crate::mesh::TriMesh;

use super::{FieldOptions, Surface};

/// The ungraded limits `(h_S, h_M)` per vertex (`h_S` infinite where the
/// Fitmap has no F_S).
pub fn fitmap_limits(
    mesh: &TriMesh,
    fitmap: &Fitmap,
    s_fitmap_scale: f64,
) -> Result<(Vec<f64>, Vec<f64>)> {
    let kappa = s_fitmap_scale * crate::quad::s_fitmap_kappa(mesh, fitmap);
    let sqrt2 = std::f64::consts::SQRT_2;
    let r_max = fitmap.radii.last().copied().unwrap_or(f64::INFINITY);
    let mut hs = Vec::with_capacity(fitmap.s.len());
    let mut hm = Vec::with_capacity(fitmap.m.len());
    for (i, (&s, &m)) in fitmap.s.iter().zip(&fitmap.m).enumerate() {
        if !(m.is_finite() && m > 0.0) {
            return Err(Error::numerical(
                "field layout",
                format!("vertex {i}: F_M = {m} is not a positive radius"),
            ));
        }
        hs.push(if kappa > 0.0 && s > 0.0 && s.is_finite() {
            sqrt2 * kappa / s
        } else {
            f64::INFINITY
        });
        hm.push(sqrt2 * m.min(r_max));
    }
    Ok((hs, hm))
}

/// `h_i ≤ h_j + γ |x_i − x_j|` over M's edges, by a Dijkstra-like sweep
/// from the smallest h (each vertex settled once, so the result is the
/// largest graded field below the input: deterministic, ties by index).
pub fn grade(s: &Surface, h: &mut [f64], gamma: f64) {
    let mut heap: BinaryHeap<Reverse<(u64, u32)>> = h
        .iter()
        .enumerate()
        .map(|(i, &x)| Reverse((x.to_bits(), i as u32)))
        .collect();
    let mut done = vec![false; h.len()];
    while let Some(Reverse((bits, i))) = heap.pop() {
        let i = i as usize;
        if done[i] || f64::from_bits(bits) != h[i] {
            continue;
        }
        done[i] = true;
        for &j in s.neighbours(i) {
            let j = j as usize;
            let cand = h[i] + gamma * (s.positions[i] - s.positions[j]).length();
            if !done[j] && cand < h[j] {
                h[j] = cand;
                heap.push(Reverse((cand.to_bits(), j as u32)));
            }
        }
    }
}

/// `∫ dA / h²` (vertex areas): the quads of edge h that cover M.
pub fn predicted_faces(s: &Surface, h: &[f64]) -> f64 {
    s.areas.iter().zip(h).map(|(a, x)| a / (x * x)).sum()
}

/// Lattice edges (at the solved spacing 2h) that each boundary loop of M
/// must get at least: a loop shorter than a few lattice cells cannot be
/// kept by the extraction (measured: bunny's five small holes tore the
/// lattice at every global refinement down to 0.41 h).
pub const MIN_LATTICE_EDGES_PER_LOOP: f64 = 6.0;

/// Caps h on each boundary loop of M at `length / (2 ·`
/// [`MIN_LATTICE_EDGES_PER_LOOP`]`)`, spread into the surface at slope
/// `loop_slope · γ`: holes are kept by refining locally, not by refining
/// the whole field. At `loop_slope` 1 (the default,
/// [`FieldOptions::loop_cap_slope`]) h is capped and regraded at γ as a
/// whole. Spread at γ the five small holes of the bunny set its sizes
/// almost everywhere (τ 1 %: 99 % of the vertices below their own
/// limits, 475 predicted patches where the S- and M-fitmaps alone,
/// graded, ask for 326); at 2γ the cap stays nearer the holes, measured
/// in docs/status.md ("Field-aligned layout", 2026-12-05 adaptivity).
pub fn cap_at_boundaries(s: &Surface, h: &mut [f64], gamma: f64, loop_slope: f64) {
    if loop_slope == 1.0 {
        cap_loops(s, h, None);
        grade(s, h, gamma);
    } else {
        cap_loops(s, h, Some(loop_slope * gamma));
    }
}

/// h on each boundary loop of M at most `length / (2 ·`
/// [`MIN_LATTICE_EDGES_PER_LOOP`]`)`: set on the loops' vertices
/// (`slope` `None`), or graded at `slope` on their own and then taken as
/// a minimum (h itself is not regraded: where it is graded at a slope ≤
/// `slope` the result is the graded minimum of both).
fn cap_loops(s: &Surface, h: &mut [f64], slope: Option<f64>) {
    if s.boundary_edges.is_empty() {
        return;
    }
    let mut uf = super::UnionFind::new(s.len());
    for &[a, b] in &s.boundary_edges {
        uf.union(a as usize, b as usize);
    }
    let mut length = vec![0.0; s.len()];
    for &[a, b] in &s.boundary_edges {
        let r = uf.find(a as usize);
        length[r] += (s.positions[a as usize] - s.positions[b as usize]).length();
    }
    let mut cap = vec![f64::INFINITY; s.len()];
    for &[a, _] in &s.boundary_edges {
        let r = uf.find(a as usize);
        cap[a as usize] = h[a as usize].min(length[r] / (2.0 * MIN_LATTICE_EDGES_PER_LOOP));
    }
    if let Some(slope) = slope {
        grade(s, &mut cap, slope);
    }
    for (x, c) in h.iter_mut().zip(&cap) {
        *x = x.min(*c);
    }
}

/// The graded sizing field at scale α.
pub fn sizing_at(s: &Surface, hs: &[f64], hm: &[f64], alpha: f64, opts: &FieldOptions) -> Vec<f64> {
    let mut h = fitmap_graded(s, hs, hm, alpha, opts);
    cap_at_boundaries(s, &mut h, opts.gradation, opts.loop_cap_slope);
    h
}

/// `min(α h_S, β h_M)` graded at γ, before the boundary loops' caps.
fn fitmap_graded(s: &Surface, hs: &[f64], hm: &[f64], alpha: f64, opts: &FieldOptions) -> Vec<f64> {
    let mut h: Vec<f64> = hs
        .iter()
        .zip(hm)
        .map(|(&a, &b)| (alpha * a).min(opts.m_fitmap_scale * b))
        .collect();
    grade(s, &mut h, opts.gradation);
    h
}

/// α of the natural size (no `--faces`): 1, except on a mesh with
/// boundary loops whose caps spread faster than γ
/// ([`FieldOptions::loop_cap_slope`] > 1), where it is the α at which
/// [`sizing_at`] predicts the count of the same field with the caps
/// spread at γ. That count is what τ has bought so far (the bunny meets
/// the Fitmaps paper's Table 1 count with it); the steeper spread lays
/// free most of the bunny, and α < 1 puts those patches where F_S asks
/// for them rather than around the holes. α to 0.1 %.
pub fn natural_alpha(s: &Surface, hs: &[f64], hm: &[f64], opts: &FieldOptions) -> f64 {
    if s.boundary_edges.is_empty() || opts.loop_cap_slope == 1.0 {
        return 1.0;
    }
    let mut reference = fitmap_graded(s, hs, hm, 1.0, opts);
    cap_loops(s, &mut reference, Some(opts.gradation));
    let target = predicted_faces(s, &reference);
    let count = |a: f64| predicted_faces(s, &sizing_at(s, hs, hm, a, opts));
    bisect_ln(|a| count(a) > target, 1e-3, 1.0, 1e-3)
}

/// α with `predicted_faces(sizing_at(α)) ≈ n` (bisection on ln α; the
/// count falls monotonically with α). When even an unbounded α predicts
/// more than `n` faces (F_M alone asks for more), the largest α that
/// still changes the field is returned: F_M's limit is never relaxed.
pub fn alpha_for_faces(
    s: &Surface,
    hs: &[f64],
    hm: &[f64],
    n: usize,
    opts: &FieldOptions,
) -> Result<f64> {
    if n == 0 {
        return Err(Error::option("faces", "field layout: a target of 0 faces"));
    }
    let target = n as f64;
    let count = |a: f64| predicted_faces(s, &sizing_at(s, hs, hm, a, opts));
    Ok(bisect_ln(|a| count(a) > target, 1e-4, 1e4, 1e-6))
}

/// The x in [lo, hi] (bisection on ln x) where `above(x)` turns false
/// (`above` true for small x), to `tol` in ln x; `hi` when it never does.
fn bisect_ln(above: impl Fn(f64) -> bool, lo: f64, hi: f64, tol: f64) -> f64 {
    let (mut lo, mut hi) = (lo.ln(), hi.ln());
    if above(hi.exp()) {
        return hi.exp();
    }
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if above(mid.exp()) {
            lo = mid;
        } else {
            hi = mid;
        }
        if hi - lo < tol {
            break;
        }
    }
    (0.5 * (lo + hi)).exp()
}

/// When α alone cannot bring the count down to `n` (the M-fitmap bound
/// asks for more faces), the factor μ ≥ 1 on F_M's bound that does: the
/// sizes are then `min(α h_S, μ β h_M)`, and μ is reported
/// ([`super::FieldStats::m_fitmap_relaxed`]). The greedy simplifier tests
/// F_M only at a patch's projected centre, where this field takes the
/// minimum over every vertex, graded: measured at τ = 1 %, F_M alone
/// predicts 2.5× the greedy layout's natural count on gargoyle.
pub fn m_relaxation_for_faces(
    s: &Surface,
    hs: &[f64],
    hm: &[f64],
    alpha: f64,
    n: usize,
    opts: &FieldOptions,
) -> f64 {
    let count = |mu: f64| {
        let hm: Vec<f64> = hm.iter().map(|x| mu * x).collect();
        predicted_faces(s, &sizing_at(s, hs, &hm, alpha, opts))
    };
    if count(1.0) <= n as f64 {
        return 1.0;
    }
    bisect_ln(|mu| count(mu) > n as f64, 1.0, 1e4, 1e-6)
}

/// The sizing field of [`super::field_layout`]: `(h, α, μ, predicted
/// faces)`, μ from [`m_relaxation_for_faces`].
pub fn sizing_for(
    s: &Surface,
    mesh: &TriMesh,
    fitmap: &Fitmap,
    opts: &FieldOptions,
) -> Result<(Vec<f64>, f64, f64, f64)> {
    let (hs, mut hm) = fitmap_limits(mesh, fitmap, opts.s_fitmap_scale)?;
    let mut relaxed = 1.0;
    let alpha = match opts.target_faces {
        Some(n) => {
            let a = alpha_for_faces(s, &hs, &hm, n, opts)?;
            relaxed = m_relaxation_for_faces(s, &hs, &hm, a, n, opts);
            for x in &mut hm {
                *x *= relaxed;
            }
            a
        }
        None => natural_alpha(s, &hs, &hm, opts),
    };
    // The lattice cannot resolve lengths below M's own edges.
    let mut h = sizing_at(s, &hs, &hm, alpha, opts);
    for x in &mut h {
        *x = x.max(s.mean_edge);
    }
    let n = predicted_faces(s, &h);
    Ok((h, alpha, relaxed, n))
}

/// The sizes the post-extraction sized relaxation aims at
/// ([`super::extract::SizedRelax`]): `min(α h_S, μ β h_M)` at the layout's
/// α and μ, graded at `gamma` (infinite: not graded) and without the
/// boundary loops' caps, which are there to keep the lattice's topology,
/// not the fit's sizes. Only their ratios matter to the relaxation.
pub fn relaxation_sizes(
    s: &Surface,
    mesh: &TriMesh,
    fitmap: &Fitmap,
    opts: &FieldOptions,
    alpha: f64,
    mu: f64,
    gamma: f64,
) -> Result<Vec<f64>> {
    let (hs, hm) = fitmap_limits(mesh, fitmap, opts.s_fitmap_scale)?;
    let beta = opts.m_fitmap_scale * mu;
    let mut h: Vec<f64> = hs
        .iter()
        .zip(&hm)
        .map(|(&a, &b)| (alpha * a).min(beta * b))
        .collect();
    if gamma.is_finite() {
        grade(s, &mut h, gamma);
    }
    for x in &mut h {
        *x = x.max(s.mean_edge);
    }
    Ok(h)
}

/// Spearman's ρ between each patch's radius (centre to farthest corner)
/// and 1/F_S at its centre (the mean over the nearest triangle of `mesh`
/// of its vertices' positive F_S): issue 40's adaptivity check, the same
/// figure as the greedy layout's [`crate::quad::SimplifyStats`]
/// `adaptivity_spearman`. `None` when fewer than two patches have an F_S.
pub fn adaptivity_spearman(
    mesh: &TriMesh,
    fitmap: &Fitmap,
    control: &crate::mesh::ControlMesh,
) -> Result<Option<f64>> {
    use crate::raycast::RayCaster;
    let (mut centres, mut radius) = (Vec::new(), Vec::new());
    for f in control.faces() {
        let q: Vec<crate::DVec3> = control
            .face_vertices(f)
            .map(|v| control.position(v))
            .collect();
        let c = q.iter().copied().sum::<crate::DVec3>() / q.len() as f64;
        radius.push(q.iter().map(|p| (*p - c).length()).fold(0.0, f64::max));
        centres.push(c);
    }
    let caster = crate::raycast::bvh::BvhCaster::new(mesh)?;
    let nearest = caster.closest_points(&centres, f64::INFINITY)?;
    let (mut r, mut inv) = (Vec::new(), Vec::new());
    for (c, &rad) in nearest.iter().zip(&radius) {
        let Some(c) = c else { continue };
        let fs: Vec<f64> = mesh.triangles[c.triangle as usize]
            .iter()
            .map(|&v| fitmap.s[v as usize])
            .filter(|s| *s > 0.0 && s.is_finite())
            .collect();
        if !fs.is_empty() {
            r.push(rad);
            inv.push(fs.len() as f64 / fs.iter().sum::<f64>());
        }
    }
    Ok(crate::analysis::spearman(&r, &inv))
}
