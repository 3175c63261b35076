//! Bounded metrics (issue 39): above [`METRIC_SAMPLES`] points, a direction
//! of the accuracy figures (and the projectability) is measured on a
//! random sample of its points instead of all of them, with a 95 %
//! confidence interval in `report.json`; `--exact-metrics` measures all.
//!
//! The sample is a Bernoulli draw, each point kept with probability
//! `p = METRIC_SAMPLES / n` by a hash of its index and a per-direction
//! stream (deterministic, the same at any thread count, spread over the
//! whole surface since the points come in triangle order). The area
//! weights stay the points' own, so an area-weighted mean `R = Σ w y / Σ w`
//! over the sample is the ratio estimator of the full figure. Its standard
//! error by linearisation (Cochran, *Sampling Techniques*, 3rd ed., §6.4,
//! eq. 6.9, with the finite-population correction `1 − f`):
//! `se(R)² = (1 − f) / (n w̄²) · Σ (w_i (y_i − R))² / (n − 1)`.
//! For an RMS, `y = d²` and the interval is carried through the square
//! root by the delta method: half-width `1.96 se(R) / (2 √R)`. The max of
//! a sample is only a lower bound of the max (stated in the report's
//! docs); the mean's own error is of the same order as the RMS's.

/// Points per direction measured in full; above it, a sample of about this
/// many. The shared test meshes (≤ 70k triangles: M's 3-point quadrature
/// ≤ 210k points) stay exact at the default; the 1.1M-triangle ladder rung
/// has 3.3M quadrature points per direction, of which ~18M closest-point
/// queries in all made the stage 11 of its 19 s.
pub const METRIC_SAMPLES: usize = 300_000;

/// Streams of [`subset`], one per measured direction (independent draws).
pub(crate) const STREAM_L_TO_M: u64 = 1;
pub(crate) const STREAM_M_TO_L: u64 = 2;
pub(crate) const STREAM_M_TO_D: u64 = 3;
pub(crate) const STREAM_PROJECTABILITY: u64 = 4;

/// SplitMix64 (Steele, Lea & Flood 2014): a well-mixed hash of one word.
fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// The indices of `n` points a direction measures: `None` for all of them
/// (`exact`, or `n` within [`METRIC_SAMPLES`]), else the Bernoulli sample
/// of the module docs, in increasing order.
pub(crate) fn subset(n: usize, exact: bool, stream: u64) -> Option<Vec<usize>> {
    if exact || n <= METRIC_SAMPLES {
        return None;
    }
    let p = METRIC_SAMPLES as f64 / n as f64;
    // Keep i iff its hash, as a fraction of 2^64, is below p.
    let bound = (p * u64::MAX as f64) as u64;
    let key = mix(stream.wrapping_mul(0xd1b5_4a32_d192_ed03));
    Some((0..n).filter(|&i| mix(key ^ i as u64) < bound).collect())
}

/// Half-width of the 95 % interval of the area-weighted mean
/// `R = Σ w y / Σ w` of a sample (`y`, weights `w`; weight-0 points are not
/// samples) drawn from `population` points (module docs); 0 when the
/// sample is the population.
pub(crate) fn ratio_ci95(y: &[f64], w: &[f64], population: usize) -> f64 {
    let (mut n, mut sw, mut swy) = (0usize, 0.0, 0.0);
    for (&yi, &wi) in y.iter().zip(w) {
        if wi > 0.0 {
            n += 1;
            sw += wi;
            swy += wi * yi;
        }
    }
    if n < 2 || n >= population || sw <= 0.0 {
        return 0.0;
    }
    let r = swy / sw;
    let ss: f64 = y
        .iter()
        .zip(w)
        .filter(|(_, &wi)| wi > 0.0)
        .map(|(&yi, &wi)| (wi * (yi - r)).powi(2))
        .sum();
    let wbar = sw / n as f64;
    let f = n as f64 / population as f64;
    let var = (1.0 - f) / (n as f64 * wbar * wbar) * ss / (n as f64 - 1.0);
    1.96 * var.max(0.0).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn subset_is_exact_below_the_bound_and_about_the_bound_above() {
        assert!(subset(METRIC_SAMPLES, false, 1).is_none());
        assert!(subset(10 * METRIC_SAMPLES, true, 1).is_none());
        let n = 4 * METRIC_SAMPLES;
        let s = subset(n, false, 1).unwrap();
        // Binomial(n, 1/4): sd = sqrt(n p (1-p)) ≈ 474; 6 sd either side.
        let sd = (n as f64 * 0.25 * 0.75).sqrt();
        assert!(
            (s.len() as f64 - METRIC_SAMPLES as f64).abs() < 6.0 * sd,
            "{}",
            s.len()
        );
        assert!(s.windows(2).all(|x| x[0] < x[1]));
        // Another stream draws other points.
        let t = subset(n, false, 2).unwrap();
        assert_ne!(s[..100], t[..100]);
    }

    #[test]
    fn interval_covers_the_population_mean_at_its_stated_rate() {
        // y_i = a known function of i with unequal weights; 200 independent
        // samples of ~300k of 1.2M points: the 95 % interval must cover the
        // population's weighted mean in ≥ 90 % of them (binomial(200, 0.95)
        // falls below 180 with probability < 1e-3).
        let n = 4 * METRIC_SAMPLES;
        let y: Vec<f64> = (0..n).map(|i| ((i % 977) as f64).sqrt()).collect();
        let w: Vec<f64> = (0..n).map(|i| 1.0 + (i % 13) as f64).collect();
        let full = y.iter().zip(&w).map(|(a, b)| a * b).sum::<f64>() / w.iter().sum::<f64>();
        let mut covered = 0;
        for stream in 0..200 {
            let s = subset(n, false, 100 + stream).unwrap();
            let ys: Vec<f64> = s.iter().map(|&i| y[i]).collect();
            let ws: Vec<f64> = s.iter().map(|&i| w[i]).collect();
            let r = ys.iter().zip(&ws).map(|(a, b)| a * b).sum::<f64>() / ws.iter().sum::<f64>();
            let h = ratio_ci95(&ys, &ws, n);
            assert!(h > 0.0);
            if (r - full).abs() <= h {
                covered += 1;
            }
        }
        assert!(covered >= 180, "covered {covered} of 200");
        assert_eq!(ratio_ci95(&y[..10], &w[..10], 10), 0.0);
    }
}
