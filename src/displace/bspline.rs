//! The bicubic B-spline reconstruction of the displacement maps
//! (`--displacement-reconstruction bspline`, issue 37 item 2).
//!
//! **What a host computes.** Cycles' "Cubic" image interpolation (Blender's
//! image texture node, interpolation "Cubic") is the uniform cubic
//! B-spline on the texel lattice: at texel coordinate `x` (texel centres at
//! integers) it reads the four texels `⌊x⌋ − 1 … ⌊x⌋ + 2` per axis with the
//! weights `(1 − t)³/6, (3t³ − 6t² + 4)/6, (−3t³ + 3t² + 3t + 1)/6, t³/6`
//! ([`weights`]). The spline *approximates* its texels (at a texel centre
//! it is `(c₋₁ + 4c₀ + c₁)/6`), so the written values are B-spline
//! coefficients, solved for by the least squares
//! ([`super::refine_offsets_on`] on a [`super::HostSurface`] built with
//! this basis), not samples of the displacement. A tile's coefficients sit
//! where its samples do: coefficient `(i, j)` at `(u, v) = (i, j)/(R − 1)`.
//!
//! **Watertight across patch edges.** The lookup at a tile's border reads
//! one texel beyond it, in the gutter. Holding the neighbour's coefficients
//! there (in this tile's orientation) cannot work at an extraordinary
//! vertex, where the texel diagonally beyond a tile corner belongs to no
//! single patch. Instead every gutter texel is the *linear extrapolation*
//! of the tile's own border (`c₋₁ = 2c₀ − c₁`, the tensor product of it at
//! the corners; [`BsplineTiles::coefficient`]). With that phantom the
//! weights across the border sum to `c₀` exactly
//! (`(2c₀ − c₁)/6 + 4c₀/6 + c₁/6`), so the curve along each tile edge is
//! the one-dimensional cubic B-spline of the border row of coefficients
//! alone, with the same phantom at its ends, and at a corner it is the
//! corner coefficient. The border rows are the welded samples shared by
//! both tiles ([`super::PatchGrid`]), so both tiles read the same curve:
//! the displaced surface is continuous along every edge and at every
//! vertex whatever its valence. The price is that the spline's second
//! derivative across a tile border is zero (the phantom is collinear), so
//! the spline is C⁰, not C², between tiles, and near a border it carries
//! less curvature than it could; the least squares sees that and places
//! the coefficients for it.
//!
//! **Edges between resolutions.** A coarse edge curve is reproduced on the
//! finer side by knot insertion (Lane–Riesenfeld subdivision of the uniform
//! cubic B-spline: new vertex coefficients `(c_{k−1} + 6c_k + c_{k+1})/8`,
//! new edge coefficients `(c_k + c_{k+1})/2`), applied log₂ m times for a
//! ratio m. The linear phantom commutes with it (the refined end
//! coefficient is `c₀`, the refined phantom is again `2c′₀ − c′₁`), so the
//! finer tile's border row, refined from the coarse one's shared samples
//! ([`refinement`]), gives the coarse curve exactly. The finer side's
//! border coefficients are then all functions of the coarse samples, the
//! even ones too (unlike the bilinear scheme, where they are the coarse
//! samples themselves): the in-between samples stay dependent as before,
//! the independent unknowns and the sample budget are unchanged.

use std::collections::HashMap;

use super::PatchGrid;

/// The uniform cubic B-spline weights of the knots `i − 1 … i + 2` at
/// `t ∈ [0, 1]` past knot `i` (Cycles' `cubic_w0` … `cubic_w3`).
pub fn weights(t: f64) -> [f64; 4] {
    let s = 1.0 - t;
    [
        s * s * s / 6.0,
        (3.0 * t * t * t - 6.0 * t * t + 4.0) / 6.0,
        (-3.0 * t * t * t + 3.0 * t * t + 3.0 * t + 1.0) / 6.0,
        t * t * t / 6.0,
    ]
}

/// The coefficients of a cubic B-spline curve of `n` cells refined `m`
/// times finer (`m` a power of two) by knot insertion with the linear end
/// phantom (module docs): row `k` (`0..=n·m`) holds the weights of the
/// coarse coefficients `0..=n`.
pub fn refinement(n: usize, m: usize) -> Refinement {
    // Dense rows over the coarse coefficients: n ≤ 4095, m·n ≤ 4096, and
    // this runs once per (n, m) pair met in a grid.
    let mut rows: Vec<Vec<f64>> = (0..=n)
        .map(|k| {
            let mut r = vec![0.0; n + 1];
            r[k] = 1.0;
            r
        })
        .collect();
    let mut step = 1;
    while step < m {
        let c = rows.len() - 1;
        let at = |k: isize| -> Vec<f64> {
            // The linear phantom beyond either end.
            let lin = |a: usize, b: usize| -> Vec<f64> {
                rows[a]
                    .iter()
                    .zip(&rows[b])
                    .map(|(x, y)| 2.0 * x - y)
                    .collect()
            };
            match k {
                -1 => lin(0, 1.min(c)),
                k if k as usize > c => lin(c, c.saturating_sub(1)),
                k => rows[k as usize].clone(),
            }
        };
        let mut next = Vec::with_capacity(2 * c + 1);
        for k in 0..=c as isize {
            let (a, b, d) = (at(k - 1), at(k), at(k + 1));
            next.push((0..=n).map(|l| (a[l] + 6.0 * b[l] + d[l]) / 8.0).collect());
            if (k as usize) < c {
                next.push((0..=n).map(|l| 0.5 * (b[l] + d[l])).collect());
            }
        }
        rows = next;
        step *= 2;
    }
    rows.into_iter()
        .map(|r| {
            r.into_iter()
                .enumerate()
                .filter(|&(_, w)| w != 0.0)
                .collect()
        })
        .collect()
}

/// Rows of [`refinement`]: per fine coefficient, its coarse weights.
pub type Refinement = Vec<Vec<(usize, f64)>>;

/// The B-spline coefficients of every tile of a grid as combinations of
/// its independent samples (module docs).
pub struct BsplineTiles<'a> {
    grid: &'a PatchGrid,
    /// [`refinement`] per (coarse cells, ratio) met on an edge.
    refine: HashMap<(usize, usize), Refinement>,
}

impl<'a> BsplineTiles<'a> {
    pub fn new(grid: &'a PatchGrid) -> BsplineTiles<'a> {
        let mut refine = HashMap::new();
        for f in 0..grid.num_patches() {
            let r1 = grid.patch_res(f) - 1;
            for side in 0..4 {
                let n = grid.side_coarse_res(f, side) - 1;
                if n < r1 {
                    refine
                        .entry((n, r1 / n))
                        .or_insert_with(|| refinement(n, r1 / n));
                }
            }
        }
        BsplineTiles { grid, refine }
    }

    pub fn grid(&self) -> &PatchGrid {
        self.grid
    }

    /// Adds `scale ×` coefficient `(i, j)` of tile `f` (`i, j` in
    /// `−1 ..= R − 1 + 1`: one texel of gutter, the linear phantom) to
    /// `out` as `(sample, weight)` terms over independent samples; a sample
    /// already in `out` is summed into.
    pub fn coefficient(&self, f: usize, i: isize, j: isize, scale: f64, out: &mut Vec<(u32, f64)>) {
        let r1 = (self.grid.patch_res(f) - 1) as isize;
        // The phantom of the module docs: 2c₀ − c₁ beyond each border.
        if i < 0 || i > r1 {
            let (a, b) = if i < 0 { (0, 1) } else { (r1, r1 - 1) };
            self.coefficient(f, a, j, 2.0 * scale, out);
            self.coefficient(f, b.clamp(0, r1), j, -scale, out);
            return;
        }
        if j < 0 || j > r1 {
            let (a, b) = if j < 0 { (0, 1) } else { (r1, r1 - 1) };
            self.coefficient(f, i, a, 2.0 * scale, out);
            self.coefficient(f, i, b.clamp(0, r1), -scale, out);
            return;
        }
        let (i, j, r1) = (i as usize, j as usize, r1 as usize);
        // A border coefficient (not a corner) of the finer side of an edge:
        // refined from the coarse side's samples.
        let corner = (i == 0 || i == r1) && (j == 0 || j == r1);
        let side = if corner {
            None
        } else if j == 0 {
            Some((0, i))
        } else if i == r1 {
            Some((1, j))
        } else if j == r1 {
            Some((2, r1 - i))
        } else if i == 0 {
            Some((3, r1 - j))
        } else {
            None
        };
        if let Some((s, k)) = side {
            let n = self.grid.side_coarse_res(f, s) - 1;
            if n < r1 {
                let m = r1 / n;
                for &(l, w) in &self.refine[&(n, m)][k] {
                    add(out, self.grid.side_sample(f, s, l * m), scale * w);
                }
                return;
            }
        }
        add(out, self.grid.sample(f, i, j), scale);
    }

    /// The terms of the spline of tile `f` at `(u, v)` (module docs), with
    /// no zero weight: what a host's cubic lookup of the written tile
    /// gives there as a combination of the independent samples.
    pub fn terms(&self, f: usize, u: f64, v: f64) -> Vec<(u32, f64)> {
        let r1 = self.grid.patch_res(f) - 1;
        // A point on a knot line reads exactly that knot's weights
        // (`PatchGrid::cell_at`'s snap).
        let at = |x: f64| {
            let (i, t) = self.grid.cell_at(f, x);
            (i as isize, weights(t))
        };
        let ((i, wu), (j, wv)) = (at(u), at(v));
        // The phantom folded in per axis first, so that a weight that is
        // zero (the first row inside a border, read at the border) is
        // exactly zero, not a rounding residue that would couple the
        // samples of two tiles.
        let (fu, fv) = (fold(i, wu, r1), fold(j, wv, r1));
        let mut out = Vec::with_capacity(16);
        for &(b, wb) in &fv {
            for &(a, wa) in &fu {
                self.coefficient(f, a as isize, b as isize, wa * wb, &mut out);
            }
        }
        // Sums over a finer tile's refined border rows leave residues of
        // weights that are zero (coarse knots outside the coarse lookup's
        // four): dropped; a real weight this small moves D by 1e-13 of
        // an offset.
        out.retain(|e| e.1.abs() > 1e-13);
        out
    }

    /// The spline at every sample of the grid (at its own knot), from
    /// `value` per independent sample: what a host with only a bilinear
    /// lookup is given (USD's maps, [`crate::report`]'s outputs), so that
    /// it interpolates the spline's values at the samples. The spline is
    /// continuous across patch edges, so a sample shared by tiles gets the
    /// same value from each up to round-off; the last tile in patch order
    /// sets it (a fixed order: the same bytes at any thread count).
    pub fn at_samples<T>(&self, value: impl Fn(usize) -> T) -> Vec<T>
    where
        T: Copy + Default + std::ops::Add<Output = T> + std::ops::Mul<f64, Output = T>,
    {
        let g = self.grid;
        let mut out = vec![T::default(); g.num_samples()];
        for f in 0..g.num_patches() {
            let r1 = g.patch_res(f) - 1;
            for j in 0..=r1 {
                for i in 0..=r1 {
                    let (u, v) = (i as f64 / r1 as f64, j as f64 / r1 as f64);
                    out[g.sample(f, i, j) as usize] = self
                        .terms(f, u, v)
                        .iter()
                        .fold(T::default(), |acc, &(s, w)| acc + value(s as usize) * w);
                }
            }
        }
        out
    }

    /// Every independent sample the spline of tile `f` reads over its
    /// knot cells `i0..i0 + span`, `j0..j0 + span` (cell `i` reads the
    /// knots `i − 1 ..= i + 2`), for the normal equations' pattern.
    pub fn window(&self, f: usize, i0: usize, j0: usize, span: usize, out: &mut Vec<u32>) {
        let r1 = self.grid.patch_res(f) - 1;
        let mut terms = Vec::new();
        for j in j0 as isize - 1..=(j0 + span + 1).min(r1 + 1) as isize {
            for i in i0 as isize - 1..=(i0 + span + 1).min(r1 + 1) as isize {
                terms.clear();
                self.coefficient(f, i, j, 1.0, &mut terms);
                out.extend(terms.iter().map(|e| e.0));
            }
        }
        out.sort_unstable();
        out.dedup();
    }
}

/// The weights `w` of the knots `i − 1 ..= i + 2` of one axis as weights
/// of the knots `0 ..= r1`, the linear phantom beyond either end folded in
/// (module docs); zero weights dropped.
fn fold(i: isize, w: [f64; 4], r1: usize) -> Vec<(usize, f64)> {
    let r1 = r1 as isize;
    let mut out: Vec<(usize, f64)> = Vec::with_capacity(5);
    let mut push = |k: isize, x: f64| {
        let k = k.clamp(0, r1) as usize;
        match out.iter_mut().find(|e| e.0 == k) {
            Some(e) => e.1 += x,
            None => out.push((k, x)),
        }
    };
    for (d, &wd) in w.iter().enumerate() {
        if wd == 0.0 {
            continue;
        }
        match i + d as isize - 1 {
            k if k < 0 => {
                push(0, 2.0 * wd);
                push(1, -wd);
            }
            k if k > r1 => {
                push(r1, 2.0 * wd);
                push(r1 - 1, -wd);
            }
            k => push(k, wd),
        }
    }
    out.retain(|e| e.1 != 0.0);
    out
}

/// Adds `(s, w)` to `out`, summing into an entry of the same sample.
fn add(out: &mut Vec<(u32, f64)>, s: u32, w: f64) {
    match out.iter_mut().find(|e| e.0 == s) {
        Some(e) => e.1 += w,
        None => out.push((s, w)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The curve `Σ_k c_k B(x − k)` of `c` (linear phantom at both ends) at
    /// `x ∈ [0, n]`.
    fn curve(c: &[f64], x: f64) -> f64 {
        let n = c.len() - 1;
        let at = |k: isize| -> f64 {
            if k < 0 {
                2.0 * c[0] - c[1]
            } else if k as usize > n {
                2.0 * c[n] - c[n - 1]
            } else {
                c[k as usize]
            }
        };
        let i = (x.floor() as usize).min(n - 1);
        let w = weights(x - i as f64);
        (0..4).map(|d| w[d] * at(i as isize + d as isize - 1)).sum()
    }

    #[test]
    fn weights_are_a_partition_of_unity_and_reproduce_lines() {
        for k in 0..=20 {
            let t = k as f64 / 20.0;
            let w = weights(t);
            assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-15);
            // Σ w_d (d − 1) = t: the cubic B-spline reproduces linears.
            let x: f64 = (0..4).map(|d| w[d] * (d as f64 - 1.0)).sum();
            assert!((x - t).abs() < 1e-15, "{t}: {x}");
        }
    }

    #[test]
    fn refinement_reproduces_the_coarse_curve() {
        // Arbitrary coefficients on 4 cells; refined 2, 4 and 8 times the
        // curve (each with its own linear phantom) must be the same
        // function of the edge parameter: what keeps tiles of different
        // resolutions watertight. Exact up to rounding.
        let c = [0.3, -1.2, 0.7, 2.0, -0.4];
        for m in [2, 4, 8] {
            let rows = refinement(4, m);
            assert_eq!(rows.len(), 4 * m + 1);
            let fine: Vec<f64> = rows
                .iter()
                .map(|r| r.iter().map(|&(l, w)| w * c[l]).sum())
                .collect();
            assert_eq!(fine[0], c[0]);
            assert_eq!(fine[4 * m], c[4]);
            for k in 0..=400 {
                let x = 4.0 * k as f64 / 400.0;
                let (a, b) = (curve(&c, x), curve(&fine, x * m as f64));
                assert!((a - b).abs() < 1e-12, "m {m}, x {x}: {a} vs {b}");
            }
        }
    }
}

#[cfg(test)]
mod grid_tests {
    use super::*;
    use crate::displace::{Atlas, AtlasLayout, Displacement, DisplacementStats, Reconstruction};
    use crate::fixtures::cube;
    use crate::subdiv::{make_evaluator, Backend, EvalOptions};

    /// The refined cube (24 patches, eight valence-3 vertices) with tiles
    /// of 2, 4 and 8 knot cells side by side, and deterministic
    /// pseudo-random values at every sample.
    fn mixed() -> (crate::mesh::ControlMesh, PatchGrid, Vec<f64>) {
        let control = crate::subdiv::refine::refine_once_keeping_infinite(&cube()).unwrap();
        let res: Vec<usize> = (0..control.num_faces()).map(|f| [3, 5, 9][f % 3]).collect();
        let grid = PatchGrid::with_resolutions(&control, &res).unwrap();
        assert!(!grid.dependents().is_empty());
        let values = (0..grid.num_samples())
            .map(|k| ((k as f64 * 12.9898).sin() * 43758.5453).fract())
            .collect();
        (control, grid, values)
    }

    #[test]
    fn the_spline_agrees_across_every_edge_and_vertex() {
        // Every point of a patch border, read in each patch that holds it
        // (a welded finer grid says which points coincide), must give the
        // same value: the displaced surface is watertight along edges
        // between resolutions and at the valence-3 vertices. Up to
        // rounding of sums of ~20 terms of magnitude ≤ 2.
        let (control, grid, values) = mixed();
        let tiles = BsplineTiles::new(&grid);
        let fine: Vec<usize> = (0..grid.num_patches())
            .map(|f| 4 * (grid.patch_res(f) - 1) + 1)
            .collect();
        let probe = PatchGrid::with_resolutions(&control, &fine).unwrap();
        let mut seen: Vec<Option<f64>> = vec![None; probe.num_samples()];
        let mut compared = 0;
        for f in 0..probe.num_patches() {
            let r1 = probe.patch_res(f) - 1;
            for j in 0..=r1 {
                for i in 0..=r1 {
                    if !(i == 0 || j == 0 || i == r1 || j == r1) {
                        continue;
                    }
                    let (u, v) = (i as f64 / r1 as f64, j as f64 / r1 as f64);
                    let t = tiles.terms(f, u, v);
                    assert!(t
                        .iter()
                        .all(|e| !grid.dependents().iter().any(|d| d.sample == e.0)));
                    let x: f64 = t.iter().map(|&(s, w)| w * values[s as usize]).sum();
                    let s = probe.sample(f, i, j) as usize;
                    match seen[s] {
                        None => seen[s] = Some(x),
                        Some(y) => {
                            compared += 1;
                            assert!((x - y).abs() < 1e-12, "patch {f} ({i}, {j}): {x} vs {y}");
                        }
                    }
                }
            }
        }
        assert!(compared > 500, "{compared}");
    }

    #[test]
    fn a_cubic_lookup_of_the_baked_atlas_is_the_spline() {
        // Emulate Cycles' cubic filter on the written texels (four per
        // axis, B-spline weights, texel centres at the samples) at points
        // all over every tile, borders included: it must read the spline
        // the least squares fits, so the gutter holds the right phantom.
        let (control, grid, values) = mixed();
        let ev = make_evaluator(Backend::Osd, &control, &EvalOptions::default()).unwrap();
        let limit = ev.evaluate(control.positions(), grid.locations()).unwrap();
        let n = grid.num_samples();
        let d = Displacement {
            directions: limit.iter().map(|p| p.normal()).collect(),
            limit,
            offsets: values,
            projected: vec![true; n],
            stats: DisplacementStats::default(),
            reconstruction: Reconstruction::Bspline,
            grid,
        };
        let atlas = Atlas::for_grid(&d.grid, AtlasLayout::Single).unwrap();
        let img = atlas.bake(&d).unwrap();
        let tiles = BsplineTiles::new(&d.grid);
        let (w, h) = (atlas.width as f64, atlas.height as f64);
        for f in 0..d.grid.num_patches() {
            let r1 = d.grid.patch_res(f) - 1;
            let o = atlas.uv(f, 0, 0);
            let (x0, y0) = (o.x * w - 0.5, (1.0 - o.y) * h - 0.5);
            for k in 0..=10 {
                for l in 0..=10 {
                    let (u, v) = (k as f64 / 10.0, l as f64 / 10.0);
                    let (x, y) = (x0 + u * r1 as f64, y0 + v * r1 as f64);
                    let (ix, iy) = (x.floor(), y.floor());
                    let (wx, wy) = (weights(x - ix), weights(y - iy));
                    let mut got = 0.0;
                    for (b, wb) in wy.iter().enumerate() {
                        for (a, wa) in wx.iter().enumerate() {
                            let px = (ix as isize + a as isize - 1) as usize;
                            let py = (iy as isize + b as isize - 1) as usize;
                            got += wa * wb * img[py * atlas.width + px] as f64;
                        }
                    }
                    let want: f64 = tiles
                        .terms(f, u, v)
                        .iter()
                        .map(|&(s, wt)| wt * d.offsets[s as usize])
                        .sum();
                    // Texels are f32: ~1e-7 relative on values ≤ 4.
                    assert!(
                        (got - want).abs() < 1e-5,
                        "patch {f} ({u}, {v}): {got} vs {want}"
                    );
                }
            }
        }
    }
}
