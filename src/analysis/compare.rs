//! Agreement between two Fitmaps of the same mesh (fast vs exact, two ray
//! casters, two thread counts): the criteria of issue 3 — Spearman rank
//! correlation of F_S, and F_M compared in radius steps.

use serde::Serialize;

use super::fitmap::Fitmap;

/// Ranks with ties averaged (the standard definition Spearman's ρ needs).
pub fn ranks(x: &[f64]) -> Vec<f64> {
    let mut idx: Vec<usize> = (0..x.len()).collect();
    idx.sort_by(|&a, &b| x[a].total_cmp(&x[b]).then(a.cmp(&b)));
    let mut r = vec![0.0; x.len()];
    let mut i = 0;
    while i < idx.len() {
        let mut j = i;
        while j + 1 < idx.len() && x[idx[j + 1]] == x[idx[i]] {
            j += 1;
        }
        let avg = (i + j) as f64 / 2.0;
        for &k in &idx[i..=j] {
            r[k] = avg;
        }
        i = j + 1;
    }
    r
}

/// Pearson correlation; `None` when a side is constant or lengths differ.
pub fn pearson(x: &[f64], y: &[f64]) -> Option<f64> {
    if x.len() != y.len() || x.len() < 2 {
        return None;
    }
    let n = x.len() as f64;
    let mx = x.iter().sum::<f64>() / n;
    let my = y.iter().sum::<f64>() / n;
    let (mut sxy, mut sxx, mut syy) = (0.0, 0.0, 0.0);
    for (a, b) in x.iter().zip(y) {
        sxy += (a - mx) * (b - my);
        sxx += (a - mx) * (a - mx);
        syy += (b - my) * (b - my);
    }
    if sxx > 0.0 && syy > 0.0 {
        Some(sxy / (sxx * syy).sqrt())
    } else {
        None
    }
}

/// Spearman's rank correlation ρ (Pearson of the tie-averaged ranks).
pub fn spearman(x: &[f64], y: &[f64]) -> Option<f64> {
    pearson(&ranks(x), &ranks(y))
}

/// How two Fitmaps of one mesh agree.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FitmapAgreement {
    pub vertices: usize,
    /// Spearman ρ of F_S (`None` when one side is constant).
    pub s_spearman: Option<f64>,
    /// Largest |ΔF_S| relative to the larger of the two means.
    pub s_max_rel_diff: f64,
    /// Fraction of vertices with F_M on the same radius step.
    pub m_same_step: f64,
    /// Largest difference of F_M in radius steps, and one vertex where it
    /// happens.
    pub m_max_step_diff: u32,
    pub m_worst_vertex: usize,
}

impl FitmapAgreement {
    /// The criterion: ρ(F_S) >= 0.95 (or both F_S identical),
    /// >= 90 % of F_M on the same step, never more than one step apart.
    pub fn passes(&self) -> bool {
        let s_ok = match self.s_spearman {
            Some(r) => r >= 0.95,
            None => self.s_max_rel_diff <= 1e-9,
        };
        s_ok && self.m_same_step >= 0.9 && self.m_max_step_diff <= 1
    }
}

/// Compares two Fitmaps of the same mesh (panics never; lengths must match,
/// else every field reports total disagreement).
pub fn compare_fitmaps(a: &Fitmap, b: &Fitmap) -> FitmapAgreement {
    let n = a.s.len();
    if b.s.len() != n || a.m_step.len() != n || b.m_step.len() != n {
        return FitmapAgreement {
            vertices: n,
            s_spearman: None,
            s_max_rel_diff: f64::INFINITY,
            m_same_step: 0.0,
            m_max_step_diff: u32::MAX,
            m_worst_vertex: 0,
        };
    }
    let mean = |x: &[f64]| x.iter().sum::<f64>() / (x.len().max(1) as f64);
    let scale = mean(&a.s).max(mean(&b.s)).max(f64::MIN_POSITIVE);
    let s_max_rel_diff =
        a.s.iter()
            .zip(&b.s)
            .map(|(x, y)| (x - y).abs() / scale)
            .fold(0.0, f64::max);
    let (mut same, mut worst, mut worst_v) = (0usize, 0u32, 0usize);
    for v in 0..n {
        let d = (a.m_step[v] as i32 - b.m_step[v] as i32).unsigned_abs();
        if d == 0 {
            same += 1;
        }
        if d > worst {
            worst = d;
            worst_v = v;
        }
    }
    FitmapAgreement {
        vertices: n,
        s_spearman: spearman(&a.s, &b.s),
        s_max_rel_diff,
        m_same_step: if n > 0 { same as f64 / n as f64 } else { 1.0 },
        m_max_step_diff: worst,
        m_worst_vertex: worst_v,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spearman_known_values() {
        let x = [1.0, 2.0, 3.0, 4.0, 5.0];
        assert!((spearman(&x, &[2.0, 4.0, 8.0, 16.0, 32.0]).unwrap() - 1.0).abs() < 1e-12);
        assert!((spearman(&x, &[5.0, 4.0, 3.0, 2.0, 1.0]).unwrap() + 1.0).abs() < 1e-12);
        // Textbook example with one swap: ρ = 1 - 6·2 / (5·24) = 0.9.
        assert!((spearman(&x, &[1.0, 3.0, 2.0, 4.0, 5.0]).unwrap() - 0.9).abs() < 1e-12);
        assert_eq!(ranks(&[3.0, 1.0, 3.0]), vec![1.5, 0.0, 1.5]);
        assert!(spearman(&x, &[1.0; 5]).is_none());
    }
}
