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

/// `min(α h_S, β h_M)` graded at γ, before the boundary loops' caps
/// (graded as [`FieldOptions::grading`] says).
fn fitmap_graded(s: &Surface, hs: &[f64], hm: &[f64], alpha: f64, opts: &FieldOptions) -> Vec<f64> {
    graded_with(s, hs, hm, alpha, opts, opts.grading)
}

/// `min(α h_S, β h_M)` graded at γ by `grading`.
pub fn graded_with(
    s: &Surface,
    hs: &[f64],
    hm: &[f64],
    alpha: f64,
    opts: &FieldOptions,
    grading: Grading,
) -> Vec<f64> {
    let beta = opts.m_fitmap_scale;
    let grading = grading.on(s);
    let mut h: Vec<f64> = match grading {
        // (`on` has resolved `ClampWithHoles` to one of the others.)
        Grading::Minimum | Grading::ClampWithHoles => hs
            .iter()
            .zip(hm)
            .map(|(&a, &b)| (alpha * a).min(beta * b))
            .collect(),
        Grading::Clamp { .. } | Grading::Smooth { .. } => {
            // h_S alone (β h_M where there is no F_S) is evened out in
            // ln h; F_M stays a hard bound, applied after.
            let mut u: Vec<f64> = hs
                .iter()
                .zip(hm)
                .map(|(&a, &b)| if a.is_finite() { alpha * a } else { beta * b }.ln())
                .collect();
            match grading {
                Grading::Smooth { steps, .. } => smooth_log(s, &mut u, steps),
                _ => clamp_log_gradient(s, &mut u, opts.gradation),
            }
            u.iter()
                .zip(hm)
                .map(|(&x, &b)| x.exp().min(beta * b))
                .collect()
        }
    };
    grade(s, &mut h, opts.gradation);
    h
}

/// How the raw sizes `min(α h_S, β h_M)` are graded (`FIELD_GRADING`,
/// issue 40's adaptivity, docs/status.md "Field-aligned layout", session
/// 15). The grading limits how fast h may change (Persson's and
/// Borouchaki et al.'s size gradation, `|∇h| ≤ γ`), which the lattice
/// needs; how it gets there decides how much of F_S's contrast survives.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Grading {
    /// The largest field below the raw one ([`grade`]): every vertex
    /// whose F_S is high by noise lowers a cone of radius ~(h − h_i)/γ
    /// around it (τ 1 %: 98 % of the bunny's vertices lowered, ρ(h, 1/F_S)
    /// 0.996 → 0.746).
    Minimum,
    /// Two-sided: ln(α h_S) is moved, area-weighted and keeping its
    /// area-weighted mean, until no edge has `|Δ ln h| > γ |e| / h_low`
    /// (the same slope as [`grade`]'s, in relative terms), a dip being
    /// shared with its surroundings rather than imposed on them; then
    /// `min(·, β h_M)` and [`grade`] (F_M's bound is kept as before).
    /// `keep_count`: at the natural size α is set so that the field
    /// predicts the [`Grading::Minimum`] field's count.
    Clamp { keep_count: bool },
    /// Comparison: `steps` area-weighted neighbour means of ln(α h_S),
    /// then as `Clamp`'s F_M bound and [`grade`].
    Smooth { steps: usize, keep_count: bool },
    /// `Clamp` (count kept) on a surface with boundary loops, `Minimum`
    /// on a closed one ([`super::FieldOptions::with_natural_adaptivity`]).
    /// Measured in-process at τ 1 % with the holes' caps at 2γ and the
    /// sized relaxation (docs/status.md, session 16): on the bunny, whose
    /// caps set α ≈ 0.55, the clamp's lattice follows h at ρ 0.75 against
    /// the minimum's 0.68 (ρ(radius, 1/F_S) 0.65 against 0.55); on the
    /// closed gargoyle (α = 1) the clamp's lattice falls 6 % short of its
    /// count and follows h at ρ 0.49–0.51 against 0.58 (ρ 0.43–0.47
    /// against 0.62).
    ClampWithHoles,
}

impl Grading {
    /// `min` (or unset), `clamp[:n]`, `smooth:STEPS[:n]` (`:n`: natural
    /// α, the count not kept).
    pub fn parse(v: &str) -> Option<Grading> {
        let mut it = v.trim().split(':');
        let kind = it.next()?;
        let rest: Vec<&str> = it.collect();
        let keep = |x: Option<&&str>| x.map_or(Some(true), |x| (*x == "n").then_some(false));
        match kind {
            "" | "min" => Some(Grading::Minimum),
            "clamp-holes" if rest.is_empty() => Some(Grading::ClampWithHoles),
            "clamp" => Some(Grading::Clamp {
                keep_count: keep(rest.first())?,
            }),
            "smooth" => Some(Grading::Smooth {
                steps: rest.first()?.parse().ok()?,
                keep_count: keep(rest.get(1))?,
            }),
            _ => None,
        }
    }

    /// The `FIELD_GRADING` switch ([`Grading::Minimum`] when unset or
    /// unparsable).
    pub fn current() -> Grading {
        crate::switches::text("FIELD_GRADING")
            .and_then(|v| Grading::parse(&v))
            .unwrap_or(Grading::Minimum)
    }

    /// The grading used on `s` ([`Grading::ClampWithHoles`] resolved).
    pub fn on(self, s: &Surface) -> Grading {
        match self {
            Grading::ClampWithHoles if s.boundary_edges.is_empty() => Grading::Minimum,
            Grading::ClampWithHoles => Grading::Clamp { keep_count: true },
            g => g,
        }
    }

    fn keeps_count(self) -> bool {
        match self {
            Grading::Minimum | Grading::ClampWithHoles => false,
            Grading::Clamp { keep_count } | Grading::Smooth { keep_count, .. } => keep_count,
        }
    }
}

/// Sweeps of [`clamp_log_gradient`] at most; the [`grade`] after it
/// enforces the bound wherever they did not.
const CLAMP_SWEEPS: usize = 200;

/// Two-sided gradient limit on u = ln h: each edge with
/// `|u_i − u_j| > γ |e| / h_low` (h_low the smaller end; `ln(h_low + γ|e|)
/// − ln h_low` to first order, [`grade`]'s slope) has both ends moved
/// towards each other, each by the share of the excess that the other
/// end's area carries, so `Σ a_i u_i` is kept by every move (a vertex's
/// noise is spread over the area that must absorb it, not imposed on
/// it). Gauss–Seidel over M's sorted edges, alternating directions, until
/// no excess is above 1 % of its bound or [`CLAMP_SWEEPS`]: deterministic.
pub fn clamp_log_gradient(s: &Surface, u: &mut [f64], gamma: f64) {
    if gamma <= 0.0 {
        return;
    }
    let len: Vec<f64> = s
        .edges
        .iter()
        .map(|&[a, b]| gamma * (s.positions[a as usize] - s.positions[b as usize]).length())
        .collect();
    for sweep in 0..CLAMP_SWEEPS {
        let mut worst: f64 = 0.0;
        let mut step = |k: usize| {
            let [a, b] = s.edges[k];
            let (a, b) = (a as usize, b as usize);
            let (lo, hi) = if u[a] <= u[b] { (a, b) } else { (b, a) };
            let bound = len[k] / u[lo].exp();
            let excess = u[hi] - u[lo] - bound;
            if excess > 0.0 {
                worst = worst.max(excess / bound);
                let (wl, wh) = (s.areas[lo], s.areas[hi]);
                let w = wl + wh;
                if w > 0.0 {
                    u[hi] -= excess * wl / w;
                    u[lo] += excess * wh / w;
                } else {
                    u[hi] -= 0.5 * excess;
                    u[lo] += 0.5 * excess;
                }
            }
        };
        if sweep % 2 == 0 {
            (0..s.edges.len()).for_each(&mut step);
        } else {
            (0..s.edges.len()).rev().for_each(&mut step);
        }
        if worst < 0.01 {
            break;
        }
    }
}

/// `steps` Jacobi steps of u ← the area-weighted mean of u over the
/// vertex and its neighbours.
fn smooth_log(s: &Surface, u: &mut [f64], steps: usize) {
    for _ in 0..steps {
        let prev = u.to_vec();
        for (i, x) in u.iter_mut().enumerate() {
            let (mut sum, mut w) = (s.areas[i] * prev[i], s.areas[i]);
            for &j in s.neighbours(i) {
                sum += s.areas[j as usize] * prev[j as usize];
                w += s.areas[j as usize];
            }
            if w > 0.0 {
                *x = sum / w;
            }
        }
    }
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

/// The α at which [`sizing_at`] (graded by [`FieldOptions::grading`])
/// predicts the count of the [`Grading::Minimum`] field at `alpha0`: a
/// grading that lowers fewer vertices asks for fewer patches at α = 1,
/// and keeping the count compares where the patches go, not how many.
fn count_kept_alpha(s: &Surface, hs: &[f64], hm: &[f64], alpha0: f64, opts: &FieldOptions) -> f64 {
    let mut reference = graded_with(s, hs, hm, alpha0, opts, Grading::Minimum);
    cap_at_boundaries(s, &mut reference, opts.gradation, opts.loop_cap_slope);
    let target = predicted_faces(s, &reference);
    let count = |a: f64| predicted_faces(s, &sizing_at(s, hs, hm, a, opts));
    bisect_ln(|a| count(a) > target, 1e-3 * alpha0, 10.0 * alpha0, 1e-3)
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
    Ok(bisect_ln(|a| count(a) > target, 1e-4, RELAX_LIMIT, 1e-6))
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
    bisect_ln(|mu| count(mu) > n as f64, 1.0, RELAX_LIMIT, 1e-6)
}

/// The upper end of [`alpha_for_faces`]' and [`m_relaxation_for_faces`]'
/// searches: at it h_S and F_M no longer bound the sizes anywhere.
const RELAX_LIMIT: f64 = 1e4;

/// The sizing at `--faces n` when `n` is below what the boundary loops'
/// caps alone ask for ([`cap_at_boundaries`]: with F_S and F_M relaxed
/// without end, the sizes are the caps' cones, graded out of the holes).
/// Relaxing α and μ to [`RELAX_LIMIT`] there made the sizes grow with
/// the distance from the holes alone: on the bunny at `--faces 300`
/// (five small holes at its base, a floor of 310 predicted patches) the
/// ears, far from the holes and thin, got the largest patches, and the
/// lattice and its count collapses lost them (RMS L 51‰, 9.7 % of M
/// unprojectable, where the greedy layout's 296 patches give 4.4‰).
/// Instead the natural field (F_S, F_M and the caps, as without a
/// target) is scaled as a whole by the factor t that predicts `n`: every
/// bound is relaxed alike, as the greedy simplifier relaxes both halting
/// tests alike (Fitmaps §3.3; README, `--faces`), so the thin parts keep
/// their share. The loops then get fewer than
/// [`MIN_LATTICE_EDGES_PER_LOOP`] lattice edges; a lattice that tears
/// there is retried smaller by the count passes. Reported as α = t α₀
/// and μ = t.
fn floor_scaled(
    s: &Surface,
    hs: &[f64],
    hm: &[f64],
    n: usize,
    opts: &FieldOptions,
) -> (Vec<f64>, f64, f64, f64) {
    let a0 = natural_alpha(s, hs, hm, opts);
    let a0 = if opts.grading.on(s).keeps_count() {
        count_kept_alpha(s, hs, hm, a0, opts)
    } else {
        a0
    };
    let mut base = sizing_at(s, hs, hm, a0, opts);
    for x in &mut base {
        *x = x.max(s.mean_edge);
    }
    let scaled = |t: f64| -> Vec<f64> { base.iter().map(|x| (t * x).max(s.mean_edge)).collect() };
    let t = bisect_ln(
        |t| predicted_faces(s, &scaled(t)) > n as f64,
        1.0,
        RELAX_LIMIT,
        1e-6,
    );
    let h = scaled(t);
    let predicted = predicted_faces(s, &h);
    (h, t * a0, t, predicted)
}

/// The sizing field of [`super::field_layout`]: `(h, α, μ, predicted
/// faces)`, μ from [`m_relaxation_for_faces`] (all bounds scaled alike
/// by [`floor_scaled`] when the loops' caps alone ask for more than the
/// target).
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
            if relaxed >= RELAX_LIMIT * (1.0 - 1e-9) {
                return Ok(floor_scaled(s, &hs, &hm, n, opts));
            }
            for x in &mut hm {
                *x *= relaxed;
            }
            a
        }
        None => {
            let a = natural_alpha(s, &hs, &hm, opts);
            if opts.grading.on(s).keeps_count() {
                count_kept_alpha(s, &hs, &hm, a, opts)
            } else {
                a
            }
        }
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
/// `s_only` drops F_M where there is an F_S: `α h_S` (μ β h_M where there
/// is no F_S), so F_M does not set the ranks the relaxation aims at.
#[allow(clippy::too_many_arguments)]
pub fn relaxation_sizes(
    s: &Surface,
    mesh: &TriMesh,
    fitmap: &Fitmap,
    opts: &FieldOptions,
    alpha: f64,
    mu: f64,
    gamma: f64,
    s_only: bool,
) -> Result<Vec<f64>> {
    let (hs, hm) = fitmap_limits(mesh, fitmap, opts.s_fitmap_scale)?;
    let beta = opts.m_fitmap_scale * mu;
    let mut h: Vec<f64> = hs
        .iter()
        .zip(&hm)
        .map(|(&a, &b)| match (s_only, a.is_finite()) {
            (true, true) => alpha * a,
            (true, false) => beta * b,
            (false, _) => (alpha * a).min(beta * b),
        })
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
    let caster = crate::raycast::bvh::BvhCaster::shared(mesh)?;
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::DVec3;

    /// A flat 40 × 40 grid of unit cells (edges 1 and √2).
    fn plane() -> Surface {
        let m =
            crate::fixtures::tri_grid(40, |i, j| DVec3::new(i as f64, j as f64, 0.0), |_, _| true);
        Surface::new(&m).unwrap()
    }

    #[test]
    fn grading_parses_its_switch() {
        assert_eq!(Grading::parse(""), Some(Grading::Minimum));
        assert_eq!(Grading::parse("min"), Some(Grading::Minimum));
        assert_eq!(
            Grading::parse("clamp"),
            Some(Grading::Clamp { keep_count: true })
        );
        assert_eq!(
            Grading::parse("clamp:n"),
            Some(Grading::Clamp { keep_count: false })
        );
        assert_eq!(
            Grading::parse("smooth:4"),
            Some(Grading::Smooth {
                steps: 4,
                keep_count: true
            })
        );
        assert_eq!(Grading::parse("smooth"), None);
        assert_eq!(Grading::parse("clamp:x"), None);
        assert_eq!(Grading::parse("max"), None);
    }

    /// One vertex whose size is 30 % of its surroundings' (F_S noise): the
    /// running minimum lowers a cone of radius (1 − 0.3)/γ = 2.8 around it
    /// (17 vertices below 0.95 on this grid),
    /// the two-sided clamp shares the dip (ln 0.3 ≈ −1.2 of one vertex's
    /// area) and lowers far fewer vertices by more than 5 %; both end
    /// within the slope γ on every edge, and a ramp already within it is
    /// left as it is.
    #[test]
    fn the_clamp_shares_a_dip_instead_of_spreading_it() {
        let s = plane();
        let gamma = 0.25;
        let centre = 20 * 41 + 20;
        let mut raw = vec![1.0; s.len()];
        raw[centre] = 0.3;
        let mut minimum = raw.clone();
        grade(&s, &mut minimum, gamma);
        let mut u: Vec<f64> = raw.iter().map(|x: &f64| x.ln()).collect();
        clamp_log_gradient(&s, &mut u, gamma);
        let mut clamped: Vec<f64> = u.iter().map(|x| x.exp()).collect();
        // Mean of ln h kept (equal interior areas, the dip far from the
        // boundary).
        let mean = |v: &[f64]| {
            v.iter().zip(&s.areas).map(|(x, a)| a * x.ln()).sum::<f64>()
                / s.areas.iter().sum::<f64>()
        };
        assert!((mean(&clamped) - mean(&raw)).abs() < 1e-9);
        let lowered = |v: &[f64]| v.iter().filter(|&&x| x < 0.95).count();
        assert!(
            lowered(&minimum) >= 15 && lowered(&clamped) * 3 <= lowered(&minimum),
            "{} against {}",
            lowered(&clamped),
            lowered(&minimum)
        );
        // The dip's depth is shared: more than half of its ln is gone
        // (0.56 measured; the minimum keeps 0.3).
        assert!(clamped[centre] > 0.5, "{}", clamped[centre]);
        // Within the slope to the clamp's 1 % (then grade makes it exact).
        for &[a, b] in &s.edges {
            let (a, b) = (a as usize, b as usize);
            let d = (s.positions[a] - s.positions[b]).length();
            let (lo, hi) = (clamped[a].min(clamped[b]), clamped[a].max(clamped[b]));
            assert!(hi.ln() - lo.ln() <= 1.011 * gamma * d / lo);
        }
        grade(&s, &mut clamped, gamma);
        assert!(clamped[centre] > 0.5);
        // A ramp of slope γ/2 is already graded: unchanged.
        let ramp: Vec<f64> = s
            .positions
            .iter()
            .map(|p| 1.0 + 0.5 * gamma * p.x)
            .collect();
        let mut u: Vec<f64> = ramp.iter().map(|x| x.ln()).collect();
        clamp_log_gradient(&s, &mut u, gamma);
        for (x, r) in u.iter().zip(&ramp) {
            assert!((x.exp() - r).abs() < 1e-12);
        }
    }

    /// With the count kept, the two-sided grading predicts the running
    /// minimum's count (to the bisection's 0.1 % in α) on a field of noise.
    #[test]
    fn the_clamp_keeps_the_count_of_the_minimum() {
        let s = plane();
        let opts = FieldOptions::default();
        // h_S between 2 and 6, a smooth trend and a vertex-scale ripple.
        let hs: Vec<f64> = s
            .positions
            .iter()
            .enumerate()
            .map(|(i, p)| 2.0 + 0.08 * p.x + if i % 7 == 0 { -1.0 } else { 0.0 } + 0.8)
            .collect();
        let hm = vec![f64::INFINITY; s.len()];
        let reference = graded_with(&s, &hs, &hm, 1.0, &opts, Grading::Minimum);
        let clamp = Grading::Clamp { keep_count: true };
        let n0 = predicted_faces(&s, &reference);
        let count = |a: f64| predicted_faces(&s, &graded_with(&s, &hs, &hm, a, &opts, clamp));
        assert!(count(1.0) < n0, "{} against {n0}", count(1.0));
        let a = bisect_ln(|a| count(a) > n0, 1e-3, 10.0, 1e-3);
        assert!(a < 1.0 && (count(a) - n0).abs() <= 0.005 * n0);
    }
}
