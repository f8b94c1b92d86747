//! Paired differences of the clearing rate between detectors that played the same rounds: each
//! detector against the one listed before it. In Table I's order (VGN, VGN dense, wo κ + 1app,
//! w κ + 1app, w κ + 8app, oracle) that is every step of the paper's ablation (κ, then the eight
//! approaches) and the gap to the oracle. On the same scenes the difference varies far less than
//! either rate, so it separates detectors that the per-detector spreads cannot.
//!
//! Unit: one scene index (its rounds under every seed both detectors finished), so rounds of the
//! same scene under different seeds, which are correlated, are not counted as independent.
//! Difference `D = Σ_s Σ_seeds (successes_a − successes_b) / Σ_s Σ_seeds objects`, standard error
//! by the delta method over the scene units (the report's ratio estimator).
use crate::records::{RecordLine, SceneKey};
use crate::report::{level_name, ratio_se};
use psgrasp_datagen::Difficulty;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::fmt::Write as _;

/// The CR difference of `detector` minus `against` on one level.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PairedDifference {
    /// The detector.
    pub detector: String,
    /// The detector listed before it.
    pub against: String,
    /// Level.
    pub level: Difficulty,
    /// Scene indices with at least one round of both under the same seed.
    pub scenes: usize,
    /// Rounds paired (scene index and seed).
    pub rounds: usize,
    /// CR difference (fraction; positive: `detector` clears more).
    pub difference: f64,
    /// Its standard error over the scene units.
    pub standard_error: f64,
    /// Scene units where `detector` cleared more / fewer objects.
    pub better: usize,
    /// See `better`.
    pub worse: usize,
}

/// Paired differences of each detector in `detectors` (table order) against the one before it,
/// per level, over the finished rounds among `seeds` and scenes `0..scenes`.
pub fn paired_differences(
    lines: &[RecordLine],
    detectors: &[(String, String)],
    levels: &[Difficulty],
    seeds: &[u64],
    scenes: u64,
) -> Vec<PairedDifference> {
    // (detector, level, seed, scene) → (successes, objects).
    let mut rounds: BTreeMap<(&str, Difficulty, u64, u64), (f64, f64)> = BTreeMap::new();
    for line in lines {
        if let RecordLine::Scene { key, summary } = line {
            let SceneKey {
                detector,
                level,
                seed,
                scene,
            } = key;
            if *scene < scenes && seeds.contains(seed) {
                rounds.insert(
                    (detector.as_str(), *level, *seed, *scene),
                    (f64::from(summary.successes), summary.objects as f64),
                );
            }
        }
    }
    let mut out = Vec::new();
    for pair in detectors.windows(2) {
        let (against, detector) = (&pair[0].0, &pair[1].0);
        for &level in levels {
            // Scene index → (Σ successes difference, Σ objects, rounds).
            let mut units: BTreeMap<u64, (f64, f64, usize)> = BTreeMap::new();
            for (&(d, l, seed, scene), &(mine, objects)) in &rounds {
                if d != detector || l != level {
                    continue;
                }
                if let Some(&(theirs, _)) = rounds.get(&(against.as_str(), level, seed, scene)) {
                    let u = units.entry(scene).or_default();
                    u.0 += mine - theirs;
                    u.1 += objects;
                    u.2 += 1;
                }
            }
            if units.is_empty() {
                continue;
            }
            let num: Vec<f64> = units.values().map(|u| u.0).collect();
            let den: Vec<f64> = units.values().map(|u| u.1).collect();
            out.push(PairedDifference {
                detector: detector.clone(),
                against: against.clone(),
                level,
                scenes: units.len(),
                rounds: units.values().map(|u| u.2).sum(),
                difference: num.iter().sum::<f64>() / den.iter().sum::<f64>(),
                standard_error: ratio_se(&num, &den),
                better: num.iter().filter(|d| **d > 0.0).count(),
                worse: num.iter().filter(|d| **d < 0.0).count(),
            });
        }
    }
    out
}

/// The report's section (empty without pairs); `label` maps a detector name to its label.
pub fn markdown<'a>(pairs: &'a [PairedDifference], label: impl Fn(&'a str) -> &'a str) -> String {
    let mut s = String::new();
    if pairs.is_empty() {
        return s;
    }
    let _ = writeln!(
        s,
        "\n## Paired differences in CR\n\nEach detector against the one listed before it, on the \
         rounds both finished (same scene and seed): CR difference in points, its standard error \
         over scenes (a scene's rounds under all seeds are one unit), their ratio, and the scenes \
         where it cleared more / fewer objects.\n\n| Detector | against | Level | scenes (rounds) \
         | CR difference | standard error | difference / se | scenes better / worse |\n\
         |---|---|---|---|---|---|---|---|"
    );
    for p in pairs {
        let ratio = if p.standard_error > 0.0 {
            format!("{:+.1}", p.difference / p.standard_error)
        } else {
            "–".into()
        };
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} ({}) | {:+.1} | {:.1} | {ratio} | {} / {} |",
            label(&p.detector),
            label(&p.against),
            level_name(p.level),
            p.scenes,
            p.rounds,
            100.0 * p.difference,
            100.0 * p.standard_error,
            p.better,
            p.worse,
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::{SceneEnd, SceneSummary};

    fn round(detector: &str, seed: u64, scene: u64, objects: usize, successes: u32) -> RecordLine {
        RecordLine::Scene {
            key: SceneKey {
                detector: detector.into(),
                level: Difficulty::Medium,
                seed,
                scene,
            },
            summary: SceneSummary {
                objects,
                attempts: successes,
                successes,
                lost: 0,
                remaining: objects - successes as usize,
                end: SceneEnd::NoGrasp,
                frames: successes + 1,
                detection_ms: 0.0,
                configurations: 0,
                scene_ms: 0.0,
                final_rejections: None,
                remaining_objects: Vec::new(),
                start_wall_zones: None,
                copied_from_seed: None,
            },
        }
    }

    #[test]
    fn differences_pair_the_same_rounds_and_cluster_seeds_by_scene() {
        let detectors = [
            ("a".to_string(), "A".to_string()),
            ("b".to_string(), "B".to_string()),
            ("c".to_string(), "C".to_string()),
        ];
        // Scene 0 (10 objects) under seeds 0 and 1, scene 1 (5 objects) under seed 0 only for b.
        let lines = vec![
            round("a", 0, 0, 10, 5),
            round("a", 1, 0, 10, 6),
            round("a", 0, 1, 5, 1),
            round("b", 0, 0, 10, 8),
            round("b", 1, 0, 10, 8),
            round("b", 0, 1, 5, 3),
            round("b", 1, 1, 5, 5), // a has no seed-1 round of scene 1: not paired
            round("c", 0, 0, 10, 8),
        ];
        let pairs = paired_differences(&lines, &detectors, &[Difficulty::Medium], &[0, 1], 10);
        assert_eq!(pairs.len(), 2);
        let ab = &pairs[0];
        assert_eq!((ab.detector.as_str(), ab.against.as_str()), ("b", "a"));
        // Units: scene 0 → (+3 +2, 20 objects), scene 1 → (+2, 5 objects).
        assert_eq!((ab.scenes, ab.rounds), (2, 3));
        assert!((ab.difference - 7.0 / 25.0).abs() < 1e-12);
        let r = 7.0 / 25.0;
        let ss: f64 = (5.0f64 - r * 20.0).powi(2) + (2.0f64 - r * 5.0).powi(2);
        assert!((ab.standard_error - (2.0 * ss).sqrt() / 25.0).abs() < 1e-12);
        assert_eq!((ab.better, ab.worse), (2, 0));
        // c against b: one round, no spread.
        let bc = &pairs[1];
        assert_eq!((bc.scenes, bc.rounds, bc.better + bc.worse), (1, 1, 0));
        assert_eq!(bc.difference, 0.0);
        let md = markdown(&pairs, |d| match d {
            "a" => "A",
            "b" => "B",
            _ => "C",
        });
        assert!(md.contains("| B | A | Medium | 2 (3) | +28.0 |"), "{md}");
        assert!(
            md.contains("| C | B | Medium | 1 (1) | +0.0 | 0.0 | – | 0 / 0 |"),
            "{md}"
        );
        // Scenes outside the requested range are left out.
        assert!(
            paired_differences(&lines, &detectors, &[Difficulty::Medium], &[0, 1], 0).is_empty()
        );
    }
}
