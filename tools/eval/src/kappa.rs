//! Does the learned concentration κ say which grasps succeed? The executed grasps of one detector
//! and level by κ quartile, with the success rate in each ([`KappaBins`]; the paper's claim is
//! that κ models the baseline's uncertainty, so confident grasps should succeed more often).
use crate::plot::{Bar, BarChart, Panel};
use crate::report::{level_name, Summary};
use serde::{Deserialize, Serialize};

/// Legend of [`chart`]: the quartiles, lowest κ first.
const QUARTILES: [&str; 4] = [
    "lowest kappa quarter",
    "second quarter",
    "third quarter",
    "highest kappa quarter",
];

/// The executed grasps of a cell split at the quartiles of their κ.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct KappaBins {
    /// κ at the bin edges: minimum, the three quartiles, maximum.
    pub edges: [f32; 5],
    /// Attempts per bin (lowest κ first).
    pub attempts: [usize; 4],
    /// Successes per bin.
    pub successes: [usize; 4],
    /// Mean κ of the successful attempts.
    pub mean_success: f32,
    /// Mean κ of the failed attempts.
    pub mean_failure: f32,
}

impl KappaBins {
    /// The bins of `(κ, success)` pairs; `None` with fewer than 4 attempts, no κ above 0
    /// (detectors without a baseline distribution) or one κ for all (the "wo κ" ablation's fixed
    /// κ0: its quarters would split ties arbitrarily).
    pub fn of(attempts: &[(f32, bool)]) -> Option<Self> {
        let mut sorted: Vec<(f32, bool)> = attempts
            .iter()
            .copied()
            .filter(|(k, _)| k.is_finite())
            .collect();
        if sorted.len() < 4 || sorted.iter().all(|(k, _)| *k <= 0.0) {
            return None;
        }
        sorted.sort_by(|a, b| a.0.total_cmp(&b.0));
        if sorted[0].0 == sorted[sorted.len() - 1].0 {
            return None;
        }
        let n = sorted.len();
        let mut bins = Self {
            edges: [0.0; 5],
            attempts: [0; 4],
            successes: [0; 4],
            mean_success: 0.0,
            mean_failure: 0.0,
        };
        for (q, edge) in bins.edges.iter_mut().enumerate() {
            *edge = sorted[(q * (n - 1)) / 4].0;
        }
        // Rank quartiles: the i-th smallest κ goes to bin ⌊4i/n⌋ (ties split by rank).
        for (i, (_, success)) in sorted.iter().enumerate() {
            let bin = (4 * i) / n;
            bins.attempts[bin] += 1;
            bins.successes[bin] += usize::from(*success);
        }
        let mean = |want: bool| {
            let v: Vec<f32> = sorted
                .iter()
                .filter(|(_, s)| *s == want)
                .map(|(k, _)| *k)
                .collect();
            if v.is_empty() {
                f32::NAN
            } else {
                v.iter().sum::<f32>() / v.len() as f32
            }
        };
        bins.mean_success = mean(true);
        bins.mean_failure = mean(false);
        Some(bins)
    }

    /// One Markdown cell: mean κ of successes / failures, then per quartile its κ range and
    /// success rate.
    pub fn describe(&self) -> String {
        let quartiles: Vec<String> = (0..4)
            .map(|q| {
                let rate = 100.0 * self.successes[q] as f64 / self.attempts[q].max(1) as f64;
                format!(
                    "κ {:.1}–{:.1}: {rate:.0} % of {}",
                    self.edges[q],
                    self.edges[q + 1],
                    self.attempts[q]
                )
            })
            .collect();
        format!(
            "{:.1} / {:.1} | {}",
            self.mean_success,
            self.mean_failure,
            quartiles.join("; ")
        )
    }
}

/// κ against grasp success as a bar chart (`summary-kappa.png`): one panel per level, one group
/// per detector with κ bins, one bar per κ quartile with its success rate (whisker: the binomial
/// standard error). `None` when no cell has κ bins.
pub fn chart(summary: &Summary) -> Option<BarChart> {
    let panels: Vec<Panel> = summary
        .levels
        .iter()
        .filter_map(|level| {
            let groups: Vec<(String, Vec<Option<Bar>>)> = summary
                .cells
                .iter()
                .filter(|c| c.level == *level)
                .filter_map(|c| {
                    let bins = c.kappa.as_ref()?;
                    let bars = (0..4)
                        .map(|q| {
                            let n = bins.attempts[q];
                            (n > 0).then(|| {
                                let p = bins.successes[q] as f64 / n as f64;
                                (p, (p * (1.0 - p) / n as f64).sqrt())
                            })
                        })
                        .collect();
                    Some((c.detector.to_uppercase(), bars))
                })
                .collect();
            (!groups.is_empty()).then(|| Panel {
                title: format!(
                    "{}: SUCCESS RATE BY KAPPA QUARTER (%)",
                    level_name(*level).to_uppercase()
                ),
                groups,
            })
        })
        .collect();
    (!panels.is_empty()).then(|| BarChart {
        series: QUARTILES.iter().map(|q| q.to_string()).collect(),
        panels,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quartiles_split_by_rank_and_rates_follow_kappa() {
        // κ 1..=8: the upper half succeeds.
        let attempts: Vec<(f32, bool)> = (1..=8).map(|k| (k as f32, k > 4)).collect();
        let b = KappaBins::of(&attempts).unwrap();
        assert_eq!(b.attempts, [2, 2, 2, 2]);
        assert_eq!(b.successes, [0, 0, 2, 2]);
        assert_eq!(b.edges[0], 1.0);
        assert_eq!(b.edges[4], 8.0);
        assert!((b.mean_success - 6.5).abs() < 1e-6 && (b.mean_failure - 2.5).abs() < 1e-6);
        assert!(
            b.describe().starts_with("6.5 / 2.5 | κ 1.0–"),
            "{}",
            b.describe()
        );
        // Detectors without κ, or too few attempts, get no bins.
        assert!(KappaBins::of(&[(0.0, true); 10]).is_none());
        assert!(
            KappaBins::of(&[(25.0, true), (25.0, false), (25.0, true), (25.0, true)]).is_none()
        );
        assert!(KappaBins::of(&attempts[..3]).is_none());
    }
}
