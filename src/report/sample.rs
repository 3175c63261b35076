//! Bounded metrics (issue 39): a direction of the accuracy figures (and
//! the projectability) is measured on a fixed number of points drawn from
//! it instead of all of them, with a 95 % confidence interval of each RMS,
//! mean and percentage in `report.json`; `--exact-metrics` measures all.
//!
//! The draw is stratified by area (probability proportional to size, one
//! draw per stratum; Cochran, *Sampling Techniques*, 3rd ed., §5A.11 for
//! the design, §9A.3 for PPS): the points' weights (their shares of the
//! surface's area), laid end to end in point order, are cut into `m` equal
//! strata and one point is drawn in each, at a hashed offset (seeded per
//! direction, the same at any thread count). The points come in triangle
//! order — patch by patch on the fitted surfaces — so a stratum is a small
//! piece of the surface and the draws spread over all of it. A point of
//! weight `w_i` is drawn with probability `m w_i / W`, so the plain mean of
//! the drawn `y` is an unbiased estimate of the area-weighted mean
//! `Σ w y / W` (every stratum's draw has expectation its own slice's
//! weighted mean).
//!
//! Its variance is `Σ_h σ_h² / m²`, one term per stratum; with one draw a
//! stratum has no variance estimate of its own, so adjacent strata are
//! paired ("collapsed strata", Cochran §5A.12): `E[(y_a − y_b)²] = σ_a² +
//! σ_b² + (μ_a − μ_b)²`, which over-estimates the pair's variance by the
//! squared difference of their means — the interval errs on the wide side.
//! For an RMS, `y = d²` and the interval is carried through the square
//! root by the delta method: half-width `1.96 se / (2 RMS)`.
//!
//! A max has no such estimate: the max of a sample is only a lower bound
//! of the population's. The figures that steer geometry (RMS L: the
//! output tessellation's chord target and the `--max-error` check; the
//! unprojectable area: `--mode auto`'s second opinion) are measured on
//! every point up to [`DECISION_SAMPLES`], so outputs never depend on a
//! draw at the shared meshes' sizes; the displaced surface's two
//! directions and its breakdown, which only report, are drawn at
//! [`METRIC_SAMPLES`].

/// Draws per direction of the displaced surface D (both directions and
/// the breakdown of its S → M error); a direction with no more points is
/// measured in full. Bunny's D has 865k quadrature points (its S → M was
/// the largest single share of the stage's queries) and M 210k; at 100k
/// draws RMS D's interval is about ±1 % of the figure (docs/status.md,
/// "Scale", session 11).
pub const METRIC_SAMPLES: usize = 100_000;

/// Draws per direction of the figures that steer geometry (L both ways,
/// projectability, module docs): the shared test meshes (≤ 70k triangles:
/// M's 3-point quadrature ≤ 210k points) are measured in full; the
/// 1.1M-triangle ladder rung has 3.3M quadrature points per direction.
pub const DECISION_SAMPLES: usize = 300_000;

/// Streams of [`stratified`], one per measured direction (independent
/// draws).
pub(crate) const STREAM_L_TO_M: u64 = 1;
pub(crate) const STREAM_M_TO_L: u64 = 2;
pub(crate) const STREAM_M_TO_D: u64 = 3;
pub(crate) const STREAM_PROJECTABILITY: u64 = 4;
pub(crate) const STREAM_D_TO_M: u64 = 5;

/// SplitMix64 (Steele, Lea & Flood 2014): a well-mixed hash of one word.
fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// A uniform draw in [0, 1) for stratum `h` of `stream`.
fn unit(stream: u64, h: usize) -> f64 {
    let key = mix(stream.wrapping_mul(0xd1b5_4a32_d192_ed03));
    // The top 53 bits: every value exactly representable, below 1.
    (mix(key ^ h as u64) >> 11) as f64 / (1u64 << 53) as f64
}

/// The points of weights `w` a direction measures: `None` for all of them
/// (`bound` is `None`: exact, or no more positive-weight points than
/// `bound`), else one point index per stratum (module docs), `bound` of
/// them, non-decreasing (a point heavier than a stratum may be drawn more
/// than once). Points of weight 0 are never drawn.
pub(crate) fn stratified(w: &[f64], bound: Option<usize>, stream: u64) -> Option<Vec<usize>> {
    stratified_by(w.len(), |i| w[i], bound, stream)
}

/// [`stratified`] over `n` weights given by `w(i)` rather than stored: the
/// same draws, for point sets computed on demand (a 10M-triangle input's
/// quadrature has 30M weights, 240 MB that a draw of 100k does not need).
pub(crate) fn stratified_by(
    n: usize,
    w: impl Fn(usize) -> f64,
    bound: Option<usize>,
    stream: u64,
) -> Option<Vec<usize>> {
    let m = bound?;
    let positive = (0..n).filter(|&i| w(i) > 0.0).count();
    if positive <= m || m == 0 {
        return None;
    }
    let last = (0..n).rposition(|i| w(i) > 0.0)?;
    let total: f64 = (0..n).map(&w).filter(|&x| x > 0.0).sum();
    let (mut i, mut below) = (0usize, 0.0);
    let mut out = Vec::with_capacity(m);
    for h in 0..m {
        let u = (h as f64 + unit(stream, h)) / m as f64 * total;
        // Advance to the point whose weight interval [below, below + w_i)
        // holds u; rounding in the running sum can only push the last
        // draws past the end, onto the last weighted point.
        while i < last && (w(i) <= 0.0 || below + w(i) <= u) {
            below += w(i).max(0.0);
            i += 1;
        }
        out.push(i);
    }
    Some(out)
}

/// Half-width of the 95 % interval of the mean of `y`, one value per
/// stratum in stratum order (module docs: adjacent strata paired, an odd
/// last one joined to the pair before it).
pub(crate) fn stratified_ci95(y: &[f64]) -> f64 {
    let m = y.len();
    if m < 2 {
        return 0.0;
    }
    let mut sum = 0.0;
    let mut start = 0;
    while start < m {
        // Groups of two; the last of an odd count takes three.
        let len = if m - start == 3 { 3 } else { 2 };
        let g = &y[start..start + len];
        let mean = g.iter().sum::<f64>() / len as f64;
        let ss: f64 = g.iter().map(|v| (v - mean).powi(2)).sum();
        // k/(k−1) Σ (y − ȳ)² estimates Σ σ² of the group's k strata.
        sum += len as f64 / (len as f64 - 1.0) * ss;
        start += len;
    }
    1.96 * (sum.max(0.0)).sqrt() / m as f64
}

/// Half-width of the 95 % interval of the mean of `y` over the draws in a
/// domain (`(in domain, y)`, one per stratum in stratum order): the ratio
/// `R = Σ I y / Σ I` of two stratified means, linearised (Cochran §6.4) to
/// the mean of `z = I (y − R) / p̂`, `p̂` the share of draws in the domain.
pub(crate) fn domain_ci95(draws: &[(bool, f64)]) -> f64 {
    let inside = draws.iter().filter(|d| d.0).count();
    if inside == 0 {
        return 0.0;
    }
    let r = draws.iter().filter(|d| d.0).map(|d| d.1).sum::<f64>() / inside as f64;
    let p = inside as f64 / draws.len() as f64;
    let z: Vec<f64> = draws
        .iter()
        .map(|&(i, y)| if i { (y - r) / p } else { 0.0 })
        .collect();
    stratified_ci95(&z)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stratified_is_exact_within_the_bound_and_draws_by_area_above() {
        let w = vec![1.0; 10];
        assert!(stratified(&w, Some(10), 1).is_none());
        assert!(stratified(&w, None, 1).is_none());
        // Zero weights do not count towards the population nor get drawn.
        let mut w: Vec<f64> = (0..1000).map(|i| (i % 7) as f64).collect();
        let s = stratified(&w, Some(200), 1).unwrap();
        assert_eq!(s.len(), 200);
        assert!(s.windows(2).all(|x| x[0] <= x[1]));
        assert!(s.iter().all(|&i| w[i] > 0.0));
        // Another stream draws other points.
        let t = stratified(&w, Some(200), 2).unwrap();
        assert_ne!(s, t);
        // A point of weight above a stratum's is drawn in every stratum
        // it covers: weight 1000 of a total ~4000, 100 strata of ~40.
        w[500] = 1000.0;
        let s = stratified(&w, Some(100), 3).unwrap();
        let hits = s.iter().filter(|&&i| i == 500).count();
        let total: f64 = w.iter().sum();
        let expect = 100.0 * 1000.0 / total;
        assert!((hits as f64 - expect).abs() <= 1.0, "{hits} vs {expect}");
    }

    /// The population `y` (weights `w`) of the coverage tests: a smooth
    /// trend plus a rough term, unequal weights with zeros.
    fn population(n: usize) -> (Vec<f64>, Vec<f64>) {
        let y = (0..n)
            .map(|i| {
                let t = i as f64 / n as f64;
                (6.0 * t).sin().powi(2) + ((i * 7919 % 977) as f64 / 977.0).powi(3)
            })
            .collect();
        let w = (0..n).map(|i| (i % 13) as f64).collect();
        (y, w)
    }

    #[test]
    fn interval_covers_the_population_mean_at_its_stated_rate() {
        // 200 independent draws of 2,000 strata from 100k points: the 95 %
        // interval must cover the population's weighted mean in ≥ 180
        // (binomial(200, 0.95) falls below 180 with probability < 1e-3;
        // the collapsed-strata interval is, if anything, wider).
        let (y, w) = population(100_000);
        let full = y.iter().zip(&w).map(|(a, b)| a * b).sum::<f64>() / w.iter().sum::<f64>();
        let mut covered = 0;
        let mut widths = 0.0;
        for stream in 0..200 {
            let s = stratified(&w, Some(2_000), 100 + stream).unwrap();
            let ys: Vec<f64> = s.iter().map(|&i| y[i]).collect();
            let r = ys.iter().sum::<f64>() / ys.len() as f64;
            let h = stratified_ci95(&ys);
            assert!(h > 0.0);
            widths += h;
            if (r - full).abs() <= h {
                covered += 1;
            }
        }
        assert!(covered >= 180, "covered {covered} of 200");
        // Not vacuous: the interval is far narrower than y's own spread
        // (y spans [0, 2]; a simple random sample of 2,000 would give
        // ±0.02 or so).
        assert!(widths / 200.0 < 0.03, "mean half-width {}", widths / 200.0);
        assert_eq!(stratified_ci95(&[1.0]), 0.0);
    }

    #[test]
    fn domain_interval_covers_the_domain_mean_at_its_stated_rate() {
        // The domain: points whose index is not ≡ 0 mod 5 (a fifth of the
        // points out, as unprojectable triangles are taken out of the
        // breakdown's S → M). Same rates as above.
        let (y, w) = population(100_000);
        let inside = |i: usize| i % 5 != 0;
        let (mut num, mut den) = (0.0, 0.0);
        for i in (0..y.len()).filter(|&i| inside(i)) {
            num += w[i] * y[i];
            den += w[i];
        }
        let full = num / den;
        let mut covered = 0;
        for stream in 0..200 {
            let s = stratified(&w, Some(2_000), 500 + stream).unwrap();
            let d: Vec<(bool, f64)> = s.iter().map(|&i| (inside(i), y[i])).collect();
            let (n, sum) = d
                .iter()
                .filter(|x| x.0)
                .fold((0, 0.0), |(n, s), x| (n + 1, s + x.1));
            let h = domain_ci95(&d);
            assert!(h > 0.0 && h < 0.05);
            if (sum / n as f64 - full).abs() <= h {
                covered += 1;
            }
        }
        assert!(covered >= 180, "covered {covered} of 200");
    }

    #[test]
    fn a_constant_has_a_zero_interval_and_an_odd_count_is_handled() {
        assert_eq!(stratified_ci95(&[2.0; 7]), 0.0);
        // Three strata: one group of three, k/(k−1) Σ (y − ȳ)² = 1.5 · 2.
        let h = stratified_ci95(&[0.0, 1.0, 2.0]);
        assert!((h - 1.96 * 3.0f64.sqrt() / 3.0).abs() < 1e-12, "{h}");
    }
}
