//! The fast mode of the Fitmap (the default): the same quantities as the
//! exact mode ([`super::exact`]) from the seed vertices of
//! [`FAST_SEED_RULE`], layered balls, a clustered proxy of M for the
//! large radii and a sequential Monte Carlo estimate of the flipped area
//! with the literal test as its fallback (see the parent module's docs).

use super::exact::exact_ball;
use super::*;

/// Fast mode: the expected size of a fit on a proxy level, in clusters;
/// bigger balls are subsampled uniformly (an unbiased subsample of the
/// least-squares sum of §3.1.2, see `keep_vertex`). Level-0 balls are fitted
/// with every vertex.
/// 256 points determine a cubic's RMS residual to a few percent.
pub const FAST_MAX_FIT_POINTS: usize = 256;

/// Fast mode: balls expected (`π r² n_M / |M|`) to hold more vertices than
/// this are gathered on a proxy of M instead of M itself.
pub const FAST_LEVEL0_MAX_VERTICES: f64 = 600.0;

/// Fast mode: proxy cell size = r / this, so that a ball holds about
/// `π · 6² ≈ 110` clusters (five times the 20 points a cubic fit needs,
/// [`MIN_FIT_POINTS`]) and M's shape is resolved to 1/6 of the radius.
pub const FAST_PROXY_CELLS_PER_RADIUS: f64 = 6.0;

/// Fast mode: the M-test of a ball with more triangles than this uses
/// [`FAST_M_SAMPLES`] Monte Carlo samples instead of the literal test.
pub const FAST_LITERAL_M_MAX_TRIANGLES: usize = 64;

/// Fast mode: the most triangles drawn to estimate the flipped area of a
/// large ball ([`flip_test_sampled`]). Where the sequential test has not
/// decided by then the fraction is within ~±2 standard errors of τ, i.e.
/// `sqrt(f (1 - f) / 384)` ≈ ±1.1 % at f = 5 %, and the literal test
/// decides where affordable ([`FAST_LITERAL_FALLBACK_MAX_TRIANGLES`]).
pub const FAST_M_SAMPLES: usize = 384;

/// Fast mode: a level-0 ball whose sampled M-test is still undecided
/// after [`FAST_M_SAMPLES`] draws (its flipped fraction is within about
/// ±2 standard errors of τ) gets the literal test when it has at most this
/// many triangles: there the exact mode's verdict is one cast away, and a
/// verdict taken from the estimate would differ from it about half the
/// time.
pub const FAST_LITERAL_FALLBACK_MAX_TRIANGLES: usize = 4096;

/// Fast mode: triangles per batch of the sequential M-test (one batch of
/// rays per Embree call).
pub const FAST_M_BATCH: usize = 48;

/// Fast mode: z of the Wilson interval that stops the sequential M-test
/// (two-sided ~95 %).
pub const FAST_M_Z: f64 = 2.0;

/// `cap` of [`analyse_vertex_fast`] for an analysis of F_S alone.
pub(super) const NO_M_TEST: u8 = u8::MAX;

/// What the fast mode keeps of a fitted radius for its M-test.
enum FastBall {
    /// A level-0 ball: its triangles are the prefix of `sc.tris` (sorted by
    /// key) with key <= its radius.
    Level0,
    /// Clusters of proxy level `li` in the ball.
    Proxy(usize, Vec<u32>),
}

/// The triangles of the level-0 layered ball `sc.sorted0` with their key —
/// the radius from which all three vertices are in the ball — sorted by
/// (key, triangle) into `sc.tris`, and their running area sums into
/// `sc.tri_cum` (only the M-test needs them).
fn level0_triangles(ctx: &Ctx, sc: &mut Scratch) {
    sc.tris.clear();
    sc.tri_cum.clear();
    sc.tri_keys.clear();
    // The keys of a layered ball are radii (`layered_balls`), and a
    // triangle's key is the largest of its vertices' keys: the index of
    // that radius orders the triangles as the key does. Sorting one integer
    // `(radius index, triangle)` per triangle gives the (key, triangle)
    // order without comparing floats.
    // A vertex's radius index is kept (not its key, a float that would
    // need a search of the radii per triangle); `u8::MAX` = outside the
    // ball, above every index, so a triangle's largest says it all.
    let radii = &ctx.radii;
    let mut layer = 0usize;
    for &(k, v) in &sc.sorted0 {
        while radii[layer] < k {
            layer += 1;
        }
        debug_assert_eq!(radii[layer], k, "layered keys are radii");
        sc.layer_at[v as usize] = layer as u8;
    }
    let stamp = sc.next_stamp();
    let vt = &ctx.adj.vt;
    for (j, &(_, v)) in sc.sorted0.iter().enumerate() {
        // Scattered reads (a vertex's triangles, their marks and corners):
        // asked for ahead of use so that the misses overlap ([`prefetch`];
        // 7 % of the Fitmap was this loop waiting, perf on bunny).
        if let Some(&(_, a)) = sc.sorted0.get(j + 2) {
            prefetch(
                vt.items
                    .as_ptr()
                    .wrapping_add(vt.offsets[a as usize] as usize),
            );
        }
        let row = vt.row(v as usize);
        for &t in row {
            prefetch(sc.tmark.as_ptr().wrapping_add(t as usize));
            prefetch(ctx.mesh.triangles.as_ptr().wrapping_add(t as usize));
        }
        for &t in row {
            if sc.tmark[t as usize] != stamp {
                sc.tmark[t as usize] = stamp;
                let [a, b, c] = ctx.mesh.triangles[t as usize];
                let layer = sc.layer_at[a as usize]
                    .max(sc.layer_at[b as usize])
                    .max(sc.layer_at[c as usize]);
                if layer != u8::MAX {
                    sc.tri_keys.push(((layer as u64) << 32) | t as u64);
                }
            }
        }
    }
    sc.tri_keys.sort_unstable();
    sc.tris.extend(
        sc.tri_keys
            .iter()
            .map(|&key| (radii[(key >> 32) as usize], key as u32)),
    );
    for &(_, v) in &sc.sorted0 {
        sc.layer_at[v as usize] = u8::MAX;
    }
    let mut acc = 0.0;
    for &(_, t) in &sc.tris {
        acc += ctx.areas[t as usize];
        sc.tri_cum.push(acc);
    }
}

/// The fast analysis of vertex `p`; the M-test tries radii `<= cap` only
/// (`cap = NO_M_TEST`: none, F_S alone).
///
/// Fitmaps §3.1.2 (the S-fitmap from the cubic fits' residuals over the
/// radii) and §3.1.3 (the M-fitmap, the largest radius whose cubic passes
/// the flip test), with the fast mode's approximations: small radii are
/// fitted on M itself ([`fit_level0_radii`]), large ones on the proxy
/// levels ([`fit_proxy_radius`]), and the M-test estimates the flip
/// fraction by sampling ([`FastMTest`]).
pub(super) fn analyse_vertex_fast(ctx: &Ctx, sc: &mut Scratch, p: u32, cap: usize) -> VertexResult {
    let h = RADIUS_STEPS;
    let mut res = VertexResult {
        m_step: h as u8,
        ..Default::default()
    };
    let n = ctx.normals[p as usize];
    if n == DVec3::ZERO {
        return res;
    }
    let centre = ctx.mesh.positions[p as usize];
    let frame = Frame::from_normal(centre, n);
    let mut fits = FastFits {
        errors: Vec::with_capacity(h + 1),
        balls: (0..=h).map(|_| None).collect(),
        tested: Vec::with_capacity(h + 1),
    };

    // Radii gathered on M itself: one traversal for all of them.
    let i0 = ctx.level_of.iter().take_while(|l| l.is_none()).count();
    sc.sorted0.clear();
    if i0 > 0 {
        fit_level0_radii(ctx, sc, p, &frame, i0, &mut res, &mut fits);
    }
    // Large radii on the proxies.
    for i in i0..=h {
        fit_proxy_radius(ctx, sc, p, &frame, i, &mut res, &mut fits);
    }

    let tested: Vec<usize> = if cap == NO_M_TEST as usize {
        Vec::new()
    } else {
        fits.tested.iter().copied().filter(|&i| i <= cap).collect()
    };
    let mut m_test = FastMTest {
        ctx,
        p,
        frame: &frame,
        balls: &fits.balls,
        tris_ready: false,
        rays: 0,
    };
    m_from_top_down(&mut res, &tested, |i| m_test.test(i, sc));
    res.rays = m_test.rays;
    res.defined = !fits.errors.is_empty();
    res.s = s_from_errors(&fits.errors);
    res
}

/// The fast mode's fits of one vertex, per radius index: the residuals
/// for F_S (Fitmaps §3.1.2), the cubic and ball the M-test needs, and the
/// radii that got a cubic, increasing.
struct FastFits {
    errors: Vec<(f64, f64)>,
    balls: Vec<Option<(Cubic, FastBall)>>,
    tested: Vec<usize>,
}

/// The fits of the radii `..i0`, gathered on M itself in one layered
/// traversal; leaves the level-0 ball in `sc.sorted0` for the M-test.
#[allow(clippy::needless_range_loop)] // radius index shared by several per-radius arrays
fn fit_level0_radii(
    ctx: &Ctx,
    sc: &mut Scratch,
    p: u32,
    frame: &Frame,
    i0: usize,
    res: &mut VertexResult,
    fits: &mut FastFits,
) {
    let centre = ctx.mesh.positions[p as usize];
    let mut sorted = std::mem::take(&mut sc.sorted);
    let stamp = sc.next_stamp();
    layered_balls(
        &ctx.adj.vv,
        &ctx.mesh.positions,
        p,
        centre,
        &ctx.radii[..i0],
        &mut sc.mark,
        stamp,
        &mut sc.pending,
        &mut sorted,
    );
    // The balls are nested prefixes of `sorted` (by key), so the points of
    // every radius are a prefix of the whole ball's local coordinates:
    // taken into the frame once, not once per radius (the same values in
    // the same order, hence the same fits).
    sc.pts.clear();
    sc.pts.extend(
        sorted
            .iter()
            .map(|&(_, v)| frame.to_local(ctx.mesh.positions[v as usize])),
    );
    for i in 0..i0 {
        let r = ctx.radii[i];
        let nb = sorted.partition_point(|&(k, _)| k <= r);
        if nb < MIN_FIT_POINTS {
            continue;
        }
        // Every vertex of the ball, as in the exact mode: the fit costs
        // O(|B|) and level-0 balls are small (at most about
        // FAST_LEVEL0_MAX_VERTICES), while a subsampled cubic would move
        // the M-test's lines and with them verdicts near τ.
        res.fits += 1;
        let Some(CubicFit { cubic, rms }) = fit_cubic(&sc.pts[..nb], None, r) else {
            continue;
        };
        fits.errors.push((r, rms));
        fits.balls[i] = Some((cubic, FastBall::Level0));
        fits.tested.push(i);
    }
    // Keep the level-0 ball for the M-test; the proxies reuse the
    // other buffer.
    sc.sorted = std::mem::replace(&mut sc.sorted0, sorted);
}

/// The fit of radius index `i` on its proxy level (none for a level-0
/// radius): the clusters in the ball, weighted by the vertices they stand
/// for, subsampled to [`FAST_MAX_FIT_POINTS`] by a per-vertex hash.
fn fit_proxy_radius(
    ctx: &Ctx,
    sc: &mut Scratch,
    p: u32,
    frame: &Frame,
    i: usize,
    res: &mut VertexResult,
    fits: &mut FastFits,
) {
    let Some(li) = ctx.level_of[i] else { return };
    let centre = ctx.mesh.positions[p as usize];
    let level = &ctx.levels[li];
    let r = ctx.radii[i];
    let mut sorted = std::mem::take(&mut sc.sorted);
    let stamp = sc.next_stamp();
    layered_balls(
        &level.adj,
        &level.rep,
        level.cluster_of[p as usize],
        centre,
        &[r],
        &mut sc.level_mark[li],
        stamp,
        &mut sc.pending,
        &mut sorted,
    );
    sc.pts.clear();
    sc.w.clear();
    let total_w: f64 = sorted.iter().map(|&(_, c)| level.weight[c as usize]).sum();
    if total_w >= MIN_FIT_POINTS as f64 && sorted.len() >= MIN_FIT_POINTS.min(10) {
        let take = |c: u32, sc: &mut Scratch| {
            sc.pts.push(frame.to_local(level.rep[c as usize]));
            sc.w.push(level.weight[c as usize]);
        };
        if sorted.len() <= FAST_MAX_FIT_POINTS {
            for &(_, c) in &sorted {
                take(c, sc);
            }
        } else {
            let keep = FAST_MAX_FIT_POINTS as f64 / sorted.len() as f64;
            for &(_, c) in &sorted {
                if keep_vertex(ctx.opts.seed, p, c, keep) {
                    take(c, sc);
                }
            }
        }
        res.fits += 1;
        if let Some(CubicFit { cubic, rms }) = fit_cubic(&sc.pts, Some(&sc.w), r) {
            fits.errors.push((r, rms));
            let clusters = sorted.iter().map(|&(_, c)| c).collect();
            fits.balls[i] = Some((cubic, FastBall::Proxy(li, clusters)));
            fits.tested.push(i);
        }
    }
    sc.sorted = sorted;
}

/// The fast M-test of one vertex (Fitmaps §3.1.3): one radius's test at a
/// time, as [`m_from_top_down`] asks, counting the rays cast. Level-0
/// triangles are gathered on the first level-0 test only: the top-down
/// M-test often stops on a proxy radius first.
struct FastMTest<'a, 'c> {
    ctx: &'a Ctx<'c>,
    p: u32,
    frame: &'a Frame,
    balls: &'a [Option<(Cubic, FastBall)>],
    tris_ready: bool,
    rays: u64,
}

impl FastMTest<'_, '_> {
    /// One radius's test, as the exact mode's decision where the estimate
    /// is too close to τ to give it (`decide_fast`).
    fn test(&mut self, i: usize, sc: &mut Scratch) -> Option<bool> {
        let ctx = self.ctx;
        let (cubic, ball) = self.balls[i].as_ref()?;
        let r = ctx.radii[i];
        let mut rng = ChaCha8Rng::seed_from_u64(stream_seed(ctx.opts.seed, self.p, i));
        if matches!(ball, FastBall::Level0) && !self.tris_ready {
            level0_triangles(ctx, sc);
            self.tris_ready = true;
        }
        sc.memo.reset();
        // The triangles of a level-0 ball: all three vertices inside.
        let nt = sc.tris.partition_point(|&(k, _)| k <= r);
        let (sampled, k) = self.sample(sc, cubic, ball, r, nt, &mut rng);
        self.rays += k;
        match sampled {
            Sampled::Nothing => None,
            Sampled::Decided(pass) => Some(pass),
            Sampled::Undecided { passes } => self.undecided(sc, cubic, ball, i, nt, passes),
        }
    }

    /// The estimate of the flip fraction: literal on a small level-0 ball,
    /// sampled by area otherwise (M's triangles, or the proxy clusters'
    /// triangles through their clusters).
    fn sample(
        &self,
        sc: &mut Scratch,
        cubic: &Cubic,
        ball: &FastBall,
        r: f64,
        nt: usize,
        rng: &mut ChaCha8Rng,
    ) -> (Sampled, u64) {
        let (ctx, frame) = (self.ctx, self.frame);
        match ball {
            FastBall::Level0 if nt <= FAST_LITERAL_M_MAX_TRIANGLES => {
                let t: Vec<u32> = sc.tris[..nt].iter().map(|&(_, t)| t).collect();
                let (pass, k) =
                    flip_passes_literal(ctx, frame, cubic, r, &t, None, ctx.opts.tolerance);
                (pass.map_or(Sampled::Nothing, Sampled::Decided), k)
            }
            FastBall::Level0 => {
                let (tris, cum) = (&sc.tris, &sc.tri_cum[..nt]);
                let acc = cum[nt - 1];
                let mut sample = |rng: &mut ChaCha8Rng, out: &mut Vec<u32>| {
                    // A NaN sum has no area either.
                    if acc.is_nan() || acc <= 0.0 {
                        return false;
                    }
                    out.extend((0..FAST_M_BATCH).map(|_| tris[draw(cum, rng)].1));
                    true
                };
                flip_test_sampled(ctx, frame, cubic, r, &mut sample, rng, &mut sc.memo)
            }
            FastBall::Proxy(li, clusters) => {
                let level = &ctx.levels[*li];
                let mut cum = Vec::with_capacity(clusters.len());
                let mut acc = 0.0;
                for &c in clusters {
                    acc += level.area[c as usize];
                    cum.push(acc);
                }
                let mut sample = |rng: &mut ChaCha8Rng, out: &mut Vec<u32>| {
                    if acc <= 0.0 {
                        return false;
                    }
                    draw_proxy_batch(level, clusters, &cum, rng, out);
                    true
                };
                flip_test_sampled(ctx, frame, cubic, r, &mut sample, rng, &mut sc.memo)
            }
        }
    }

    /// The verdict where the estimate is within its uncertainty of τ
    /// (`passes`: the estimate's side).
    fn undecided(
        &mut self,
        sc: &mut Scratch,
        cubic: &Cubic,
        ball: &FastBall,
        i: usize,
        nt: usize,
        passes: bool,
    ) -> Option<bool> {
        let (ctx, frame) = (self.ctx, self.frame);
        let r = ctx.radii[i];
        match ball {
            // A level-0 ball has the exact mode's cubic: the literal test
            // on its triangles (those drawn already known) is the exact
            // mode's verdict.
            FastBall::Level0 if nt <= FAST_LITERAL_FALLBACK_MAX_TRIANGLES => {
                let t: Vec<u32> = sc.tris[..nt].iter().map(|&(_, t)| t).collect();
                let (pass, k) = flip_passes_literal(
                    ctx,
                    frame,
                    cubic,
                    r,
                    &t,
                    Some(&sc.memo),
                    ctx.opts.tolerance,
                );
                self.rays += k;
                pass
            }
            // A proxy ball's cubic is not the exact mode's: the exact
            // ball, cubic and literal test, when asked for.
            FastBall::Proxy(..) if ctx.opts.certify => {
                let (_, exact) = exact_ball(ctx, sc, self.p, frame, i);
                let (cubic, _, tris) = exact?;
                let (pass, k) =
                    flip_passes_literal(ctx, frame, &cubic, r, &tris, None, ctx.opts.tolerance);
                self.rays += k;
                pass
            }
            _ => Some(passes),
        }
    }
}

/// Fast mode: a vertex analysed because its seed neighbours disagree on
/// F_M ([`FAST_SEED_RULE`]) tests the radii from at most this many steps
/// above the highest seed neighbour's F_M down, not from `r_h`. Its F_M is
/// one edge (~`r_0`) from theirs, and a radius that fails at every seed
/// around it fails there too but for a fold narrower than an edge; the
/// radii skipped are the expensive ones (failing M-tests of the largest
/// balls, Monte Carlo up to [`FAST_M_SAMPLES`] draws each). One step
/// saves a fifth of the CPU time for a fraction of a percent of the
/// vertices leaving F_M's exact step; zero steps save more but come too
/// near the 90 % agreement criterion (docs/status.md, "Measurements
/// behind the code").
pub const FAST_M_STEPS_ABOVE_SEEDS: usize = 1;

/// Fast mode: an interpolated vertex whose seed neighbours' F_S differ by
/// more than this ratio (largest / smallest) gets its own F_S (the fits of
/// its balls, no M-test; F_M stays interpolated). F_S varies slowly at the
/// scale of one edge (every ball of a vertex holds its neighbour's ball of
/// one step smaller radius), but Spearman's ρ compares *ranks*,
/// and on a CAD model with a narrow F_S range the mean of the neighbours
/// reorders vertices; fitting those whose seeds differ brings ρ most of
/// the way to the all-analysed value for a few percent more CPU time
/// (docs/status.md, "Measurements behind the code").
pub const FAST_S_DIRECT_SPREAD: f64 = 1.05;

/// Fast mode: which vertices are analysed, and how the others get their
/// values. The seeds are the greedy maximal independent set of the vertex
/// graph in vertex order (a vertex is a seed unless an earlier neighbour
/// is one): about a quarter to a third of the vertices, every other vertex
/// adjacent to at least one seed, so no vertex is more than one edge (~r_0)
/// from an analysed one. A non-seed vertex takes
/// - F_S = the mean of its seed neighbours' F_S (linear interpolation of
///   the field at the scale of one edge, the same interpolation §3.1.1
///   uses over faces), and
/// - F_M = the step its seed neighbours agree on. Where they do not all
///   agree the field changes at the scale of one edge (a fold's border,
///   where the flipped fraction sits at τ over several radii) and no
///   interpolation is trustworthy: the vertex is analysed itself, testing
///   radii from [`FAST_M_STEPS_ABOVE_SEEDS`] above its seed neighbours'
///   highest step down.
/// - Where the seed neighbours' F_S differ by more than
///   [`FAST_S_DIRECT_SPREAD`], F_S is computed directly instead.
///
/// Seeds whose analysis is undefined (no well-posed cubic) do not count;
/// a vertex with no defined seed neighbour is analysed itself.
pub const FAST_SEED_RULE: &str =
    "greedy 1-ring independent set; F_S mean, F_M agreed step, else analysed";

/// The seeds of [`FAST_SEED_RULE`], in increasing order.
pub(super) fn fast_seeds(vv: &Csr, nv: usize) -> Vec<u32> {
    let mut seed = vec![false; nv];
    let mut out = Vec::with_capacity(nv / 3);
    for v in 0..nv {
        if !vv
            .row(v)
            .iter()
            .any(|&w| (w as usize) < v && seed[w as usize])
        {
            seed[v] = true;
            out.push(v as u32);
        }
    }
    out
}

/// A non-seed vertex's values from its analysed neighbours
/// ([`FAST_SEED_RULE`]); `None` when no neighbour has a defined analysis.
pub(super) fn interpolate_from_seeds(
    vv: &Csr,
    v: usize,
    results: &[VertexResult],
    analysed: &[bool],
) -> Option<VertexResult> {
    let (mut s, mut k, mut step, mut hi) = (0.0, 0usize, u8::MAX, 0u8);
    for &w in vv.row(v) {
        let r = &results[w as usize];
        if analysed[w as usize] && r.defined {
            s += r.s;
            k += 1;
            step = step.min(r.m_step);
            hi = hi.max(r.m_step);
        }
    }
    (k > 0 && hi == step).then(|| VertexResult::from_seeds(s / k as f64, step))
}

/// The sparse fast mode ([`FitmapOptions::sparse`], off by default): a
/// non-seed vertex whose seed neighbours disagree on F_M is not analysed
/// but takes the rounded mean of their steps (a geometric mean of their
/// radii; F_S as in [`FAST_SEED_RULE`]: their mean, or fitted directly
/// where they differ by more than [`FAST_S_DIRECT_SPREAD`]). Why: where
/// the seeds one edge apart disagree, the vertex's own analysed step is as
/// uncertain as theirs (flipped fractions near τ over several radii, see
/// [`Fitmap::m`]). Measured on the default fast mode's fallbacks (bunny /
/// gargoyle / spot / homer / cheburashka: 4,736 / 7,727 / 897 / 1,998 /
/// 1,699 vertices): 94–97 % land within their seeds' range; the rounded
/// mean of the seeds' steps is 0.60 / 0.77 / 0.81 / 0.67 / 0.73 steps from
/// the analysed step on average (the lower median 0.60–0.95, the lowest
/// step 0.69–0.99); the seeds' mean F_S is 2.2–3.9 % from the fitted one.
/// The fallbacks were 37 % (bunny) to 49 % (gargoyle) of the Fitmap's
/// CPU. Vertices with no defined seed neighbour are still analysed.
/// Off by default because the greedy layout's patch count follows these
/// vertices' steps (+9 to +20 % patches on the five shared meshes, beyond
/// the spread of the full Fitmap's own Monte Carlo seeds); no power of the
/// mean ([`SPARSE_POWER_ENV`]) and no choice of κ₀ removed that bias
/// (docs/status.md, "Scale", session 14).
pub const SPARSE_RULE: &str =
    "seeds disagreeing on F_M: the rounded mean of their steps, not an analysis";

/// Default power of [`SPARSE_RULE`]'s mean of the seeds' F_M: −2, the
/// mean F_M⁻² (the quantity κ₀ integrates). [`SPARSE_POWER_ENV`] picks
/// another (−1: the mean F_M⁻¹; 0: the mean step, a geometric mean).
pub const SPARSE_POWER: f64 = -2.0;

/// Measurement aid: `SUBDFIT_FITMAP_SPARSE_POWER=p` sets the power of the
/// sparse rule's mean (see [`SPARSE_POWER`]); unset or unparsable: −2.
pub const SPARSE_POWER_ENV: &str = "SUBDFIT_FITMAP_SPARSE_POWER";

/// The power of the sparse rule's mean ([`SPARSE_POWER_ENV`]).
pub(super) fn sparse_power() -> f64 {
    crate::switches::parsed::<f64>(SPARSE_POWER_ENV)
        .filter(|p| p.is_finite())
        .unwrap_or(SPARSE_POWER)
}

/// [`SPARSE_RULE`]'s values for `v` from its defined analysed neighbours
/// (F_S their mean, F_M the step of the power mean of their F_M with
/// power `power` — [`SPARSE_POWER`] by default, the mean F_M⁻²; `ln_ratio`
/// = ln(r_{i+1} / r_i)); `None` when it has none.
pub(super) fn interpolate_disagreeing(
    vv: &Csr,
    v: usize,
    results: &[VertexResult],
    analysed: &[bool],
    ln_ratio: f64,
    power: f64,
) -> Option<VertexResult> {
    let (mut s, mut acc, mut k) = (0.0, 0.0, 0usize);
    for &w in vv.row(v) {
        let r = &results[w as usize];
        if analysed[w as usize] && r.defined {
            s += r.s;
            // r^p relative to r_0: radii[i] = r_0 q^i, q = e^ln_ratio
            // (p = 0: the step itself, whose mean is the log of the
            // geometric mean radius).
            acc += if power == 0.0 {
                r.m_step as f64
            } else {
                (power * ln_ratio * r.m_step as f64).exp()
            };
            k += 1;
        }
    }
    if k == 0 {
        return None;
    }
    // The step whose r^p is nearest (in log) to the mean of the seeds'.
    let x = if power == 0.0 {
        acc / k as f64
    } else {
        (acc / k as f64).ln() / (power * ln_ratio)
    };
    let step = if x.is_finite() {
        x.round().clamp(0.0, RADIUS_STEPS as f64) as u8
    } else {
        0
    };
    Some(VertexResult::from_seeds(s / k as f64, step))
}

/// The defined analysed neighbours of `v`: (F_S range, highest F_M step),
/// `None` when there are none.
pub(super) fn seed_neighbour_range(
    vv: &Csr,
    v: usize,
    results: &[VertexResult],
    analysed: &[bool],
) -> Option<((f64, f64), u8)> {
    let mut out: Option<((f64, f64), u8)> = None;
    for &w in vv.row(v) {
        let r = &results[w as usize];
        if analysed[w as usize] && r.defined {
            let ((lo, hi), m) = out.unwrap_or(((r.s, r.s), r.m_step));
            out = Some(((lo.min(r.s), hi.max(r.s)), m.max(r.m_step)));
        }
    }
    out
}

/// Outcome of [`flip_test_sampled`].
#[derive(Copy, Clone, Debug, PartialEq)]
enum Sampled {
    /// The ball has no area (nothing to test), or ray casting failed.
    Nothing,
    /// The Wilson interval lies on one side of τ: `true` = passes.
    Decided(bool),
    /// Still straddling τ after [`FAST_M_SAMPLES`] draws: the flipped
    /// fraction is within a few percent of τ, where the caller decides
    /// literally if it can; `passes` is the point estimate's verdict.
    Undecided { passes: bool },
}

/// [`FAST_M_BATCH`] area-proportional draws of a triangle of a proxy ball:
/// a cluster of `clusters` by its area (`cum`, their running sums), then
/// one of its triangles by theirs ([`ProxyLevel::tri_cum_row`]).
///
/// The same triangles, in the same order, as drawing them one at a time
/// (`clusters[draw(cum)]`, then `tris.row(c)[draw(tri_cum_row(c))]`): the
/// uniform variates are taken from `rng` in that order first, and each is
/// scaled by the same total. What changes is the memory traffic: a
/// cluster's rows of `tris` and `tri_cum` are global arrays met at random,
/// and one draw after another waited for three cache misses each (80 % of
/// the draws' time, perf on bunny, where the draws were 12 % of the
/// Fitmap). Here the rows of the whole batch are prefetched
/// ([`prefetch`]) before any of them is searched, so their misses overlap.
fn draw_proxy_batch(
    level: &ProxyLevel,
    clusters: &[u32],
    cum: &[f64],
    rng: &mut ChaCha8Rng,
    out: &mut Vec<u32>,
) {
    let mut u = [0.0f64; 2 * FAST_M_BATCH];
    for x in u.iter_mut() {
        *x = rng.gen::<f64>();
    }
    let mut cs = [0usize; FAST_M_BATCH];
    for (c, pair) in cs.iter_mut().zip(u.chunks_exact(2)) {
        *c = clusters[pick(cum, pair[0])] as usize;
        prefetch(level.tris.offsets.as_ptr().wrapping_add(*c));
    }
    for &c in &cs {
        let (lo, hi) = (
            level.tris.offsets[c] as usize,
            level.tris.offsets[c + 1] as usize,
        );
        // Every line of the row's running sums (8 per line; rows are a
        // cluster's few dozen triangles, the cap only bounds a rare large
        // one), and the start of its triangle list.
        for k in (lo..hi).step_by(8).take(8) {
            prefetch(level.tri_cum.as_ptr().wrapping_add(k));
        }
        if hi > lo {
            prefetch(level.tri_cum.as_ptr().wrapping_add(hi - 1));
            prefetch(level.tris.items.as_ptr().wrapping_add(lo));
        }
    }
    out.extend(
        cs.iter()
            .zip(u.chunks_exact(2))
            .map(|(&c, pair)| level.tris.row(c)[pick(level.tri_cum_row(c), pair[1])]),
    );
}

/// Fast-mode M-test of a large ball: the literal flipped fraction
/// ([`flip_fraction_literal`]) estimated by Monte Carlo over the ball's
/// triangles. `draw` appends [`FAST_M_BATCH`] triangles of the ball, each
/// with probability proportional to its area, or returns `false` when the
/// ball has no area; a triangle's verdict is the literal one (the same
/// samples, [`MSamples`], the same rule, [`triangle_verdicts`]), so the
/// fraction of drawn triangles not reached is an unbiased estimate of the
/// literal flipped fraction for the same cubic. The verdicts go to `memo`
/// (reset by the caller for each cubic).
///
/// Sequential test: triangles come in batches of [`FAST_M_BATCH`]; after
/// each batch the test stops as soon as the Wilson score interval (z =
/// [`FAST_M_Z`]) of the flipped fraction lies entirely below τ (pass) or
/// above it (fail). Typical balls are far from τ (no fold at all, or a fold
/// filling much of the ball) and stop after one to three batches. After
/// [`FAST_M_SAMPLES`] draws the fraction is within a few percent of τ and
/// the test returns [`Sampled::Undecided`]: there the estimate cannot be
/// trusted to give the literal verdict, and the caller takes the literal
/// one where it can (see `decide_fast`).
///
/// The decision is monotone in τ for a given seed: the draws are a prefix
/// of one stream, and if the test for τ₁ passes at n (upper bound < τ₁),
/// every lower bound before n was <= τ₁ < τ₂, so the test for τ₂ cannot
/// fail earlier and passes by n (the literal fraction is one number, so the
/// fallback is monotone too).
fn flip_test_sampled(
    ctx: &Ctx,
    frame: &Frame,
    cubic: &Cubic,
    r: f64,
    draw: &mut dyn FnMut(&mut ChaCha8Rng, &mut Vec<u32>) -> bool,
    rng: &mut ChaCha8Rng,
    memo: &mut VerdictMemo,
) -> (Sampled, u64) {
    let tau = ctx.opts.tolerance;
    let (mut n, mut k, mut rays) = (0usize, 0usize, 0u64);
    let mut batch = Vec::with_capacity(FAST_M_BATCH);
    let mut todo = Vec::with_capacity(FAST_M_BATCH);
    let mut reached = Vec::with_capacity(FAST_M_BATCH);
    while n < FAST_M_SAMPLES {
        batch.clear();
        todo.clear();
        if !draw(rng, &mut batch) {
            return (Sampled::Nothing, rays);
        }
        for &t in &batch {
            if memo.get(t).is_none() && !todo.contains(&t) {
                todo.push(t);
            }
        }
        n += batch.len();
        // The batch's verdicts in parts, the decision looked at between
        // them: the test below at the end of the batch is decided already
        // when it is for every verdict still unknown (see
        // `batch_decided`), and the rest of the batch is not cast.
        for part in todo.chunks(FAST_M_PART) {
            if let Some(pass) = batch_decided(&batch, memo, k, n, tau) {
                return (Sampled::Decided(pass), rays);
            }
            let Some(c) = triangle_verdicts(ctx, frame, cubic, r, part, &mut reached) else {
                return (Sampled::Nothing, rays);
            };
            for (&t, &ok) in part.iter().zip(&reached) {
                memo.set(t, ok);
            }
            rays += c;
        }
        k += batch
            .iter()
            .filter(|&&t| memo.get(t) == Some(false))
            .count();
        let (lo, hi) = wilson(k, n, FAST_M_Z);
        if hi < tau {
            return (Sampled::Decided(true), rays);
        }
        if lo > tau {
            return (Sampled::Decided(false), rays);
        }
    }
    let passes = (k as f64) < tau * n as f64;
    (Sampled::Undecided { passes }, rays)
}

/// Triangles of a batch of [`flip_test_sampled`] whose verdicts are cast
/// together before the batch's decision is looked at again: a quarter of
/// [`FAST_M_BATCH`], so a clearly failing ball stops after a part of its
/// first batch, while each call still casts a few dozen lines.
const FAST_M_PART: usize = 12;

/// The decision [`flip_test_sampled`] takes at the end of the current
/// batch (`batch`, drawn; `k` flipped among the draws before it; `n` draws
/// with it), when it is known already from the verdicts in `memo`: both
/// Wilson bounds grow with the number flipped
/// (`wilson_bounds_grow_with_the_count`), so if the batch's known flipped
/// draws alone put the lower bound above τ it fails whatever the rest,
/// and if it passes with every unknown draw flipped it passes. `None`
/// while the unknown verdicts could still change it; the end-of-batch test
/// itself is unchanged, so the decisions (and F_M) are the same as casting
/// the whole batch.
fn batch_decided(batch: &[u32], memo: &VerdictMemo, k: usize, n: usize, tau: f64) -> Option<bool> {
    let (mut flipped, mut unknown) = (0usize, 0usize);
    for &t in batch {
        match memo.get(t) {
            Some(false) => flipped += 1,
            None => unknown += 1,
            Some(true) => {}
        }
    }
    let (_, hi) = wilson(k + flipped + unknown, n, FAST_M_Z);
    if hi < tau {
        return Some(true);
    }
    let (lo, _) = wilson(k + flipped, n, FAST_M_Z);
    (lo > tau).then_some(false)
}

/// Wilson score interval of a binomial proportion `k / n`.
fn wilson(k: usize, n: usize, z: f64) -> (f64, f64) {
    let (n, p) = (n as f64, k as f64 / n as f64);
    let z2 = z * z;
    let d = 1.0 + z2 / n;
    let c = (p + z2 / (2.0 * n)) / d;
    let h = z * (p * (1.0 - p) / n + z2 / (4.0 * n * n)).sqrt() / d;
    (c - h, c + h)
}
/// Area-proportional draw from a cumulative table.
fn draw(cum: &[f64], rng: &mut ChaCha8Rng) -> usize {
    pick(cum, rng.gen::<f64>())
}

/// The index [`draw`] takes for the uniform variate `u` in [0, 1).
#[inline]
fn pick(cum: &[f64], u: f64) -> usize {
    let total = *cum.last().unwrap_or(&0.0);
    let x = u * total;
    cum.partition_point(|&c| c <= x)
        .min(cum.len().saturating_sub(1))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// [`SPARSE_RULE`] on a star (vertex 0, neighbours 1..=k): the seeds'
    /// step when they agree; between the lowest and highest step, and at
    /// or below their rounded mean (F_M⁻² weighs the small radii), when
    /// they do not; exactly the step of the mean F_M⁻² on a worked case;
    /// F_S their mean; neighbours not analysed or undefined ignored; `None`
    /// with no usable neighbour.
    #[test]
    fn sparse_rule_takes_the_mean_inverse_square_radius() {
        let ln_q = 1.6f64.ln();
        let star = |steps: &[u8]| {
            let k = steps.len() as u32;
            let vv = Csr::from_pairs(k as usize + 1, (1..=k).map(|w| (0, w)).collect());
            let mut results = vec![VertexResult::default(); k as usize + 1];
            for (j, &st) in steps.iter().enumerate() {
                results[j + 1] = VertexResult {
                    s: 1.0 + j as f64,
                    m_step: st,
                    defined: true,
                    ..Default::default()
                };
            }
            (vv, results)
        };
        let (vv, results) = star(&[5, 5, 5]);
        let all = vec![true; 4];
        let r = interpolate_disagreeing(&vv, 0, &results, &all, ln_q, SPARSE_POWER).unwrap();
        assert_eq!(r.m_step, 5);
        assert_eq!(r.s, 2.0);
        // {3, 7}: x = -ln((q⁻⁶ + q⁻¹⁴) / 2) / (2 ln q) = 3.713 -> 4, below
        // the plain mean 5.
        let (vv, results) = star(&[3, 7]);
        let r = interpolate_disagreeing(&vv, 0, &results, &all[..3], ln_q, SPARSE_POWER).unwrap();
        let x = -((1.6f64.powi(-6) + 1.6f64.powi(-14)) / 2.0).ln() / (2.0 * ln_q);
        assert!((x - 3.713).abs() < 0.001, "{x}");
        assert_eq!(r.m_step, 4);
        for steps in [[0u8, 8, 8, 8], [2, 3, 3, 6], [8, 7, 8, 7], [1, 1, 1, 2]] {
            let (vv, results) = star(&steps);
            let r =
                interpolate_disagreeing(&vv, 0, &results, &[true; 5], ln_q, SPARSE_POWER).unwrap();
            let (lo, hi) = (*steps.iter().min().unwrap(), *steps.iter().max().unwrap());
            let mean = steps.iter().map(|&x| x as f64).sum::<f64>() / 4.0;
            assert!(r.m_step >= lo && r.m_step <= hi, "{steps:?} {}", r.m_step);
            assert!(r.m_step as f64 <= mean.round(), "{steps:?} {}", r.m_step);
            assert_eq!(r.m_floor, r.m_step == 0);
        }
        // Only analysed, defined neighbours count.
        let (vv, mut results) = star(&[2, 8, 8]);
        results[1].defined = false;
        let r = interpolate_disagreeing(&vv, 0, &results, &[true; 4], ln_q, SPARSE_POWER).unwrap();
        assert_eq!((r.m_step, r.s), (8, 2.5));
        let r = interpolate_disagreeing(
            &vv,
            0,
            &results,
            &[true, true, false, false],
            ln_q,
            SPARSE_POWER,
        );
        assert!(r.is_none());
    }

    /// `batch_decided` relies on both Wilson bounds being non-decreasing in
    /// the flipped count at every sample size the sequential test reaches
    /// (multiples of [`FAST_M_BATCH`] up to [`FAST_M_SAMPLES`]), in floating
    /// point as computed, not only in exact arithmetic: checked on that
    /// whole finite grid.
    #[test]
    fn wilson_bounds_grow_with_the_count() {
        for n in (FAST_M_BATCH..=FAST_M_SAMPLES).step_by(FAST_M_BATCH) {
            let mut prev = wilson(0, n, FAST_M_Z);
            for k in 1..=n {
                let b = wilson(k, n, FAST_M_Z);
                assert!(b.0 >= prev.0 && b.1 >= prev.1, "n = {n}, k = {k}");
                prev = b;
            }
        }
    }

    /// An early decision of `batch_decided` is the end-of-batch decision
    /// for every way the unknown verdicts can come out: for each split of
    /// a 48-draw batch into known flipped / known reached / unknown draws,
    /// every completion of the unknowns, several τ and earlier counts.
    #[test]
    fn batch_decision_is_the_end_of_batch_one() {
        let mut memo = VerdictMemo::new();
        let batch: Vec<u32> = (0..FAST_M_BATCH as u32).collect();
        let mut early = 0;
        for tau in [0.01, 0.05, 0.1, 0.3] {
            for n_prev in [0, FAST_M_BATCH, 4 * FAST_M_BATCH] {
                for k_prev in [0, n_prev / 20, n_prev / 2] {
                    for flipped in (0..=FAST_M_BATCH).step_by(3) {
                        for unknown in (0..=FAST_M_BATCH - flipped).step_by(5) {
                            memo.reset();
                            for (j, &t) in batch.iter().enumerate() {
                                if j < flipped {
                                    memo.set(t, false);
                                } else if j >= flipped + unknown {
                                    memo.set(t, true);
                                }
                            }
                            let n = n_prev + FAST_M_BATCH;
                            let Some(pass) = batch_decided(&batch, &memo, k_prev, n, tau) else {
                                continue;
                            };
                            early += 1;
                            for extra in 0..=unknown {
                                let (lo, hi) = wilson(k_prev + flipped + extra, n, FAST_M_Z);
                                let end = if hi < tau {
                                    Some(true)
                                } else if lo > tau {
                                    Some(false)
                                } else {
                                    None
                                };
                                assert_eq!(
                                    end,
                                    Some(pass),
                                    "τ {tau} n {n} f {flipped} u {unknown}"
                                );
                            }
                        }
                    }
                }
            }
        }
        assert!(early > 100, "the grid must hold early decisions ({early})");
    }
}
