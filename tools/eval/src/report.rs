//! Metrics over finished scenes and the reports: a Markdown summary, a JSON summary and a PNG bar
//! chart of SR and CR per level and detector.
//!
//! Per (detector, level) and seed: success rate `SR = Σ successes / Σ attempts` and clearing rate
//! `CR = Σ successes / Σ objects` over the scenes (pooled, as VGN and the paper count them). The
//! table gives the mean over seeds ± the standard deviation over seeds; with a single seed, ± is
//! the standard error over scenes instead (ratio estimator: `√(n/(n−1)·Σ(s_i − R·a_i)²) / Σ a_i`).
//! Detection time is fusion + inference + selection per frame; "grasps/s" are successful grasps
//! per second of detection time.
use crate::kappa::KappaBins;
use crate::leftovers::LeftoverVerdicts;
use crate::paired::{paired_differences, PairedDifference};
use crate::plot::{BarChart, Panel};
use crate::protocol::{AttemptRecord, TouchedThing};
use crate::records::{RecordLine, SceneKey};
use psgrasp_datagen::Difficulty;
use psgrasp_sim::WallZone;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::fmt::Write as _;

/// A rate with its spread.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Estimate {
    /// Mean over seeds (a fraction in [0, 1]); `None` without data.
    pub mean: Option<f64>,
    /// Standard deviation over seeds, or the standard error over scenes for one seed.
    pub spread: f64,
}

/// The metrics of one detector on one level.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CellMetrics {
    /// Detector name.
    pub detector: String,
    /// Level.
    pub level: Difficulty,
    /// Seeds with at least one scene.
    pub seeds: usize,
    /// Finished scenes.
    pub scenes: usize,
    /// Of those, rounds recorded as copies of the same round under another seed
    /// ([`crate::seed_copies`]).
    #[serde(default)]
    pub copied_scenes: usize,
    /// Objects at the start, summed.
    pub objects: usize,
    /// Attempts.
    pub attempts: usize,
    /// Successful attempts.
    pub successes: usize,
    /// Objects knocked out of the bin.
    pub lost: usize,
    /// Success rate.
    pub success_rate: Estimate,
    /// Clearing rate.
    pub clearing_rate: Estimate,
    /// Mean detection time (fusion + inference + selection) per frame, milliseconds.
    pub detection_ms_per_frame: f64,
    /// Mean grasp configurations per frame.
    pub configurations_per_frame: f64,
    /// Successful grasps per second of detection time.
    pub grasps_per_detection_s: f64,
    /// Mean physics time per attempt, milliseconds.
    pub execution_ms_per_attempt: f64,
    /// How the scenes ended.
    pub ends: BTreeMap<String, usize>,
    /// How the attempts ended.
    pub outcomes: BTreeMap<String, usize>,
    /// Attempts whose approach a touch stopped short of the grasp pose (whatever the outcome).
    #[serde(default)]
    pub approach_touches: usize,
    /// Failed attempts by cause ([`failure_cause`]).
    #[serde(default)]
    pub failure_causes: BTreeMap<String, usize>,
    /// Attempts whose pick came from selection's fallback tier (`[selection.fallback]`).
    #[serde(default)]
    pub fallback_attempts: usize,
    /// Of those, the successful ones.
    #[serde(default)]
    pub fallback_successes: usize,
    /// Objects left in the bin when the scenes ended, by kind.
    #[serde(default)]
    pub left_by_kind: BTreeMap<String, usize>,
    /// Of the objects left, those within [`NEAR_WALL_M`] of a side wall.
    #[serde(default)]
    pub left_near_wall: usize,
    /// Objects at the start of the rounds, by where they lay ([`WallZone::ALL`] order: interior,
    /// by one wall, in a corner); only rounds whose records carry the start.
    #[serde(default)]
    pub started_by_zone: [usize; 3],
    /// Of those, the objects left when the rounds ended, by where they started.
    #[serde(default)]
    pub left_by_start_zone: [usize; 3],
    /// The executed grasps by κ quartile (detectors with a baseline distribution; records
    /// that carry κ).
    #[serde(default)]
    pub kappa: Option<KappaBins>,
    /// Why the objects left have no grasp (records that carry the diagnosis).
    #[serde(default)]
    pub leftovers: LeftoverVerdicts,
}

/// A pick whose TCP lies farther than this outside the object it aimed at missed it, metres.
pub const OFF_TARGET_M: f32 = 0.002;

/// Why a failed attempt failed, for the report: what stopped its approach (`touched_target`,
/// `touched_other_object`, `touched_bin`), or, when the hand reached the grasp pose, whether its
/// TCP was off the object it aimed at (`reached_off_target`, more than [`OFF_TARGET_M`] outside)
/// or on it (`reached_on_target`); `reached` for records without a target (older runs).
pub fn failure_cause(a: &AttemptRecord) -> &'static str {
    if let Some(t) = &a.approach_touch {
        return match t.touched {
            TouchedThing::Target => "touched_target",
            TouchedThing::OtherObject => "touched_other_object",
            TouchedThing::Bin => "touched_bin",
        };
    }
    match &a.target {
        Some(t) if t.tcp_distance_m > OFF_TARGET_M => "reached_off_target",
        Some(_) => "reached_on_target",
        None => "reached",
    }
}

/// The index of `zone` in [`WallZone::ALL`].
fn zone_index(zone: WallZone) -> Option<usize> {
    WallZone::ALL.iter().position(|z| *z == zone)
}

/// An object left this close to a side wall counts as "by a wall" in the report (the same
/// threshold as the datasets' wall statistics).
pub use psgrasp_sim::NEAR_WALL_M;

/// The whole summary.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    /// Detector names in table order, with display labels.
    pub detectors: Vec<(String, String)>,
    /// Levels in table order.
    pub levels: Vec<Difficulty>,
    /// One cell per detector and level (detector-major).
    pub cells: Vec<CellMetrics>,
    /// CR of each detector minus the one listed before it, on the same rounds.
    #[serde(default)]
    pub paired: Vec<PairedDifference>,
}

fn snake<T: Serialize>(v: &T) -> String {
    serde_json::to_value(v)
        .ok()
        .and_then(|v| v.as_str().map(str::to_owned))
        .unwrap_or_default()
}

/// Standard error of the ratio `Σ num / Σ den` over units (delta method).
pub(crate) fn ratio_se(num: &[f64], den: &[f64]) -> f64 {
    let n = num.len();
    let total: f64 = den.iter().sum();
    if n < 2 || total <= 0.0 {
        return 0.0;
    }
    let r = num.iter().sum::<f64>() / total;
    let ss: f64 = num.iter().zip(den).map(|(s, a)| (s - r * a).powi(2)).sum();
    (n as f64 / (n as f64 - 1.0) * ss).sqrt() / total
}

fn mean_sd(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    let sd = if v.len() > 1 {
        (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0)).sqrt()
    } else {
        0.0
    };
    (m, sd)
}

fn estimate(per_seed: &BTreeMap<u64, (Vec<f64>, Vec<f64>)>) -> Estimate {
    let rates: Vec<f64> = per_seed
        .values()
        .filter_map(|(num, den)| {
            let d: f64 = den.iter().sum();
            (d > 0.0).then(|| num.iter().sum::<f64>() / d)
        })
        .collect();
    if rates.is_empty() {
        return Estimate {
            mean: None,
            spread: 0.0,
        };
    }
    let (mean, sd) = mean_sd(&rates);
    let spread = if rates.len() > 1 {
        sd
    } else {
        per_seed
            .values()
            .next()
            .map_or(0.0, |(num, den)| ratio_se(num, den))
    };
    Estimate {
        mean: Some(mean),
        spread,
    }
}

/// Computes the summary over `lines` for the given detectors (name, label), levels, seeds and
/// scenes `0..scenes`.
pub fn summarize(
    lines: &[RecordLine],
    detectors: &[(String, String)],
    levels: &[Difficulty],
    seeds: &[u64],
    scenes: u64,
) -> Summary {
    let wanted = |k: &SceneKey| k.scene < scenes && seeds.contains(&k.seed);
    let mut cells = Vec::new();
    for (name, _) in detectors {
        for &level in levels {
            let mine = |k: &SceneKey| &k.detector == name && k.level == level && wanted(k);
            let mut sr: BTreeMap<u64, (Vec<f64>, Vec<f64>)> = BTreeMap::new();
            let mut cr: BTreeMap<u64, (Vec<f64>, Vec<f64>)> = BTreeMap::new();
            let mut c = CellMetrics {
                detector: name.clone(),
                level,
                seeds: 0,
                scenes: 0,
                copied_scenes: 0,
                objects: 0,
                attempts: 0,
                successes: 0,
                lost: 0,
                success_rate: Estimate {
                    mean: None,
                    spread: 0.0,
                },
                clearing_rate: Estimate {
                    mean: None,
                    spread: 0.0,
                },
                detection_ms_per_frame: 0.0,
                configurations_per_frame: 0.0,
                grasps_per_detection_s: 0.0,
                execution_ms_per_attempt: 0.0,
                ends: BTreeMap::new(),
                outcomes: BTreeMap::new(),
                approach_touches: 0,
                failure_causes: BTreeMap::new(),
                fallback_attempts: 0,
                fallback_successes: 0,
                left_by_kind: BTreeMap::new(),
                left_near_wall: 0,
                started_by_zone: [0; 3],
                left_by_start_zone: [0; 3],
                kappa: None,
                leftovers: LeftoverVerdicts::default(),
            };
            let mut kappas: Vec<(f32, bool)> = Vec::new();
            let (mut frames, mut det_ms, mut configs, mut exec_ms) = (0u64, 0.0, 0usize, 0.0);
            for line in lines {
                match line {
                    RecordLine::Scene { key, summary: s } if mine(key) => {
                        c.scenes += 1;
                        c.copied_scenes += usize::from(s.copied_from_seed.is_some());
                        c.objects += s.objects;
                        c.attempts += s.attempts as usize;
                        c.successes += s.successes as usize;
                        c.lost += s.lost;
                        frames += u64::from(s.frames);
                        det_ms += s.detection_ms;
                        configs += s.configurations;
                        *c.ends.entry(snake(&s.end)).or_default() += 1;
                        for o in &s.remaining_objects {
                            *c.left_by_kind.entry(o.kind.clone()).or_default() += 1;
                            c.left_near_wall += usize::from(o.wall_gap_m < NEAR_WALL_M);
                            c.leftovers.add(o);
                        }
                        if let Some(z) = s.start_wall_zones {
                            let by_zone = [
                                z.objects - z.near_wall,
                                z.near_wall - z.in_corner,
                                z.in_corner,
                            ];
                            (0..3).for_each(|k| c.started_by_zone[k] += by_zone[k]);
                            for o in &s.remaining_objects {
                                if let Some(k) = o.start_zone.and_then(zone_index) {
                                    c.left_by_start_zone[k] += 1;
                                }
                            }
                        }
                        let e = sr.entry(key.seed).or_default();
                        e.0.push(f64::from(s.successes));
                        e.1.push(f64::from(s.attempts));
                        let e = cr.entry(key.seed).or_default();
                        e.0.push(f64::from(s.successes));
                        e.1.push(s.objects as f64);
                    }
                    RecordLine::Attempt { key, attempt } if mine(key) => {
                        *c.outcomes.entry(snake(&attempt.outcome)).or_default() += 1;
                        c.approach_touches += usize::from(attempt.approach_contact);
                        if attempt.fallback {
                            c.fallback_attempts += 1;
                            c.fallback_successes += usize::from(attempt.outcome.is_success());
                        }
                        if !attempt.outcome.is_success() {
                            *c.failure_causes
                                .entry(failure_cause(attempt).to_string())
                                .or_default() += 1;
                        }
                        exec_ms += attempt.execution_ms;
                        if let Some(k) = attempt.kappa {
                            kappas.push((k, attempt.outcome.is_success()));
                        }
                    }
                    _ => {}
                }
            }
            c.kappa = KappaBins::of(&kappas);
            c.seeds = cr.len();
            c.success_rate = estimate(&sr);
            c.clearing_rate = estimate(&cr);
            if frames > 0 {
                c.detection_ms_per_frame = det_ms / frames as f64;
                c.configurations_per_frame = configs as f64 / frames as f64;
            }
            if det_ms > 0.0 {
                c.grasps_per_detection_s = c.successes as f64 / (det_ms / 1e3);
            }
            if c.attempts > 0 {
                c.execution_ms_per_attempt = exec_ms / c.attempts as f64;
            }
            cells.push(c);
        }
    }
    Summary {
        detectors: detectors.to_vec(),
        levels: levels.to_vec(),
        cells,
        paired: paired_differences(lines, detectors, levels, seeds, scenes),
    }
}

pub(crate) fn level_name(l: Difficulty) -> &'static str {
    match l {
        Difficulty::Train => "Train",
        Difficulty::Easy => "Easy",
        Difficulty::Medium => "Medium",
        Difficulty::Challenging => "Challenging",
    }
}

fn pct(e: &Estimate) -> String {
    match e.mean {
        Some(m) => format!("{:.1} ± {:.1}", 100.0 * m, 100.0 * e.spread),
        None => "–".into(),
    }
}

impl Summary {
    fn cell(&self, detector: &str, level: Difficulty) -> Option<&CellMetrics> {
        self.cells
            .iter()
            .find(|c| c.detector == detector && c.level == level)
    }

    /// The Markdown report: the Table I layout (SR/CR per level), then detection cost and how
    /// scenes and attempts ended.
    pub fn markdown(&self, seeds: &[u64]) -> String {
        let mut s = String::new();
        let spread = if seeds.len() > 1 {
            format!("mean ± sd over {} seeds", seeds.len())
        } else {
            "± standard error over scenes, one seed".into()
        };
        let _ = writeln!(
            s,
            "## Success rate (SR) and clearing rate (CR), % ({spread})\n"
        );
        let mut head = String::from("| Detector |");
        let mut rule = String::from("|---|");
        for l in &self.levels {
            let _ = write!(head, " {} SR | {} CR |", level_name(*l), level_name(*l));
            rule.push_str("---|---|");
        }
        let _ = writeln!(s, "{head} scenes per level (all seeds) |\n{rule}---|");
        for (name, label) in &self.detectors {
            let mut row = format!("| {label} |");
            let mut counts = Vec::new();
            for l in &self.levels {
                let c = self.cell(name, *l);
                let (a, b) = c.map_or(("–".into(), "–".into()), |c| {
                    (pct(&c.success_rate), pct(&c.clearing_rate))
                });
                let _ = write!(row, " {a} | {b} |");
                counts.push(c.map_or(0, |c| c.scenes).to_string());
            }
            let _ = writeln!(s, "{row} {} |", counts.join(" / "));
        }
        let copied: usize = self.cells.iter().map(|c| c.copied_scenes).sum();
        if copied > 0 {
            let scenes: usize = self.cells.iter().map(|c| c.scenes).sum();
            let _ = writeln!(
                s,
                "\n{copied} of the {scenes} rounds are copies of the same round under another seed \
                 (detectors that sample nothing, on the stored noise-free levels: the seed cannot \
                 change them, so their spread over seeds is 0)."
            );
        }
        s.push_str(&crate::paired::markdown(&self.paired, |d| self.label(d)));
        let _ = writeln!(s, "\n## Per level\n");
        let _ = writeln!(
            s,
            "| Detector | Level | scenes | objects | attempts | successes | lost | detection ms/frame | configurations/frame | grasps/s detection | physics ms/attempt | scene ends | attempt outcomes | approach stopped by a touch | failed attempts by cause |"
        );
        let _ = writeln!(
            s,
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"
        );
        let fmt_map = |m: &BTreeMap<String, usize>| {
            m.iter()
                .map(|(k, v)| format!("{k} {v}"))
                .collect::<Vec<_>>()
                .join(", ")
        };
        for c in &self.cells {
            let label = self.label(&c.detector);
            let _ = writeln!(
                s,
                "| {label} | {} | {} | {} | {} | {} | {} | {:.0} | {:.0} | {:.2} | {:.0} | {} | {} | {} | {} |",
                level_name(c.level),
                c.scenes,
                c.objects,
                c.attempts,
                c.successes,
                c.lost,
                c.detection_ms_per_frame,
                c.configurations_per_frame,
                c.grasps_per_detection_s,
                c.execution_ms_per_attempt,
                fmt_map(&c.ends),
                fmt_map(&c.outcomes),
                c.approach_touches,
                fmt_map(&c.failure_causes),
            );
        }
        if self.cells.iter().any(|c| c.fallback_attempts > 0) {
            let _ = writeln!(
                s,
                "\n## Picks from the selection's fallback tier\n\nAttempts whose pick came from `[selection.fallback]` (nothing on the frame passed the primary score thresholds), and how many held.\n\n| Detector | Level | attempts that fell back | of all attempts | held |\n|---|---|---|---|---|"
            );
            for c in self.cells.iter().filter(|c| c.fallback_attempts > 0) {
                let _ = writeln!(
                    s,
                    "| {} | {} | {} | {} | {} ({:.0} %) |",
                    self.label(&c.detector),
                    level_name(c.level),
                    c.fallback_attempts,
                    c.attempts,
                    c.fallback_successes,
                    100.0 * c.fallback_successes as f64 / c.fallback_attempts as f64,
                );
            }
        }
        let _ = writeln!(
            s,
            "\n## Objects left in the bin\n\n| Detector | Level | left | within {:.0} mm of a wall | by kind |\n|---|---|---|---|---|",
            NEAR_WALL_M * 1e3
        );
        for c in &self.cells {
            let left: usize = c.left_by_kind.values().sum();
            let _ = writeln!(
                s,
                "| {} | {} | {left} | {} | {} |",
                self.label(&c.detector),
                level_name(c.level),
                c.left_near_wall,
                fmt_map(&c.left_by_kind),
            );
        }
        if self
            .cells
            .iter()
            .any(|c| c.started_by_zone.iter().sum::<usize>() > 0)
        {
            let _ = writeln!(
                s,
                "\n## Objects by where they started\n\nObjects at the start of the rounds by their \
                 place in the bin (bounding box within {:.0} mm of one side wall, of two, or \
                 neither): started, left at the end, share cleared.\n\n| Detector | Level | \
                 interior | by a wall | in a corner |\n|---|---|---|---|---|",
                NEAR_WALL_M * 1e3
            );
            for c in &self.cells {
                let zone = |k: usize| {
                    let (n, left) = (c.started_by_zone[k], c.left_by_start_zone[k]);
                    if n == 0 {
                        "0".to_string()
                    } else {
                        let cleared = 100.0 * n.saturating_sub(left) as f64 / n as f64;
                        format!("{n}, left {left} ({cleared:.0} % cleared)")
                    }
                };
                let _ = writeln!(
                    s,
                    "| {} | {} | {} | {} | {} |",
                    self.label(&c.detector),
                    level_name(c.level),
                    zone(0),
                    zone(1),
                    zone(2),
                );
            }
        }
        let leftover_rows: Vec<_> = self
            .cells
            .iter()
            .map(|c| {
                let left: usize = c.left_by_kind.values().sum();
                (
                    self.label(&c.detector),
                    level_name(c.level),
                    left,
                    &c.leftovers,
                )
            })
            .collect();
        s.push_str(&crate::leftovers::markdown(&leftover_rows));
        if self.cells.iter().any(|c| c.kappa.is_some()) {
            let _ = writeln!(
                s,
                "\n## Concentration κ of the executed grasps\n\nMean κ of the successful / failed \
                 attempts, then the attempts split at the quartiles of their κ: κ range, success \
                 rate, attempts.\n\n| Detector | Level | mean κ success / failure | by κ quartile |\n\
                 |---|---|---|---|"
            );
            for c in &self.cells {
                if let Some(k) = &c.kappa {
                    let _ = writeln!(
                        s,
                        "| {} | {} | {} |",
                        self.label(&c.detector),
                        level_name(c.level),
                        k.describe()
                    );
                }
            }
        }
        s
    }

    fn label<'a>(&'a self, detector: &'a str) -> &'a str {
        self.detectors
            .iter()
            .find(|(n, _)| n == detector)
            .map_or(detector, |(_, l)| l.as_str())
    }

    /// The bar chart: SR (top) and CR (bottom), one group per level, one bar per detector.
    pub fn chart(&self) -> BarChart {
        let panel = |title: &str, rate: fn(&CellMetrics) -> &Estimate| Panel {
            title: title.into(),
            groups: self
                .levels
                .iter()
                .map(|l| {
                    let values = self
                        .detectors
                        .iter()
                        .map(|(n, _)| {
                            self.cell(n, *l)
                                .and_then(|c| rate(c).mean.map(|m| (m, rate(c).spread)))
                        })
                        .collect();
                    (level_name(*l).to_uppercase(), values)
                })
                .collect(),
        };
        BarChart {
            series: self.detectors.iter().map(|(_, l)| l.clone()).collect(),
            panels: vec![
                panel("SUCCESS RATE (%)", |c| &c.success_rate),
                panel("CLEARING RATE (%)", |c| &c.clearing_rate),
            ],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::{RemainingObject, SceneEnd, SceneSummary};

    fn scene(seed: u64, index: u64, objects: usize, attempts: u32, successes: u32) -> RecordLine {
        RecordLine::Scene {
            key: SceneKey {
                detector: "a".into(),
                level: Difficulty::Easy,
                seed,
                scene: index,
            },
            summary: SceneSummary {
                objects,
                attempts,
                successes,
                lost: 0,
                remaining: objects - successes as usize,
                end: SceneEnd::NoGrasp,
                frames: attempts + 1,
                detection_ms: 100.0 * f64::from(attempts + 1),
                configurations: 10,
                scene_ms: 1.0,
                final_rejections: None,
                remaining_objects: Vec::new(),
                start_wall_zones: None,
                copied_from_seed: None,
            },
        }
    }

    #[test]
    fn rates_pool_scenes_and_spread_follows_the_seed_count() {
        let detectors = [("a".to_string(), "A".to_string())];
        // One seed: scenes (objects, attempts, successes) = (4, 4, 2), (2, 2, 2).
        let lines = vec![
            scene(0, 0, 4, 4, 2),
            scene(0, 1, 2, 2, 2),
            scene(0, 5, 9, 9, 0),
        ];
        let s = summarize(&lines, &detectors, &[Difficulty::Easy], &[0], 2);
        let c = &s.cells[0];
        assert_eq!((c.scenes, c.objects, c.attempts, c.successes), (2, 6, 6, 4));
        assert!((c.success_rate.mean.unwrap() - 4.0 / 6.0).abs() < 1e-12);
        assert!((c.clearing_rate.mean.unwrap() - 4.0 / 6.0).abs() < 1e-12);
        // Ratio SE by hand: r = 2/3, residuals 2 − 8/3 = −2/3 and 2 − 4/3 = 2/3.
        let se = (2.0f64 * (4.0 / 9.0 + 4.0 / 9.0)).sqrt() / 6.0;
        assert!((c.success_rate.spread - se).abs() < 1e-12);
        // 4 successes over 8 frames of 100 ms.
        assert!((c.grasps_per_detection_s - 5.0).abs() < 1e-9);
        assert!((c.detection_ms_per_frame - 100.0).abs() < 1e-9);

        // Two seeds: SR 0.5 and 1.0 → mean 0.75, sd √0.125.
        let lines = vec![scene(0, 0, 4, 4, 2), scene(1, 0, 2, 2, 2)];
        let s = summarize(&lines, &detectors, &[Difficulty::Easy], &[0, 1], 1);
        let c = &s.cells[0];
        assert_eq!(c.seeds, 2);
        assert!((c.success_rate.mean.unwrap() - 0.75).abs() < 1e-12);
        assert!((c.success_rate.spread - 0.125f64.sqrt()).abs() < 1e-12);
        let md = s.markdown(&[0, 1]);
        assert!(md.contains("| A | 75.0 ± 35.4 |"), "{md}");
        // No data: a dash, not a zero.
        let s = summarize(&[], &detectors, &[Difficulty::Medium], &[0], 10);
        assert!(s.cells[0].success_rate.mean.is_none());
        assert!(s.markdown(&[0]).contains("| A | – | – | 0 |"));
    }

    #[test]
    fn objects_left_are_counted_by_kind_and_wall_distance() {
        let left = |kind: &str, wall_gap_m: f32| RemainingObject {
            name: format!("proc-{kind}"),
            kind: kind.into(),
            extent_m: [0.05; 3],
            center_m: [0.0; 3],
            wall_gap_m,
            start_zone: None,
            graspability: None,
        };
        let mut a = scene(0, 0, 4, 2, 1);
        let mut b = scene(0, 1, 3, 1, 1);
        for (line, objects) in [
            (
                &mut a,
                vec![left("sphere", 0.001), left("box", 0.1), left("box", -0.002)],
            ),
            (&mut b, vec![left("sphere", 0.05), left("sphere", 0.019)]),
        ] {
            if let RecordLine::Scene { summary, .. } = line {
                summary.remaining = objects.len();
                summary.remaining_objects = objects;
            }
        }
        let detectors = [("a".to_string(), "A".to_string())];
        let s = summarize(&[a, b], &detectors, &[Difficulty::Easy], &[0], 2);
        let c = &s.cells[0];
        assert_eq!(c.left_by_kind.get("sphere"), Some(&3));
        assert_eq!(c.left_by_kind.get("box"), Some(&2));
        // 1 mm, −2 mm (leaning on the wall) and 19 mm are by a wall; 50 and 100 mm are not.
        assert_eq!(c.left_near_wall, 3);
        let md = s.markdown(&[0]);
        assert!(
            md.contains("| A | Easy | 5 | 3 | box 2, sphere 3 |"),
            "{md}"
        );
        // Records without the round's start (before 2026-12-04) leave the start table out.
        assert!(!md.contains("where they started"), "{md}");
    }

    #[test]
    fn objects_are_counted_by_where_they_started() {
        use psgrasp_sim::WallZones;
        let left = |zone: WallZone| RemainingObject {
            name: "proc-box".into(),
            kind: "box".into(),
            extent_m: [0.05; 3],
            center_m: [0.0; 3],
            wall_gap_m: 0.0,
            start_zone: Some(zone),
            graspability: None,
        };
        // Scene a: 10 objects, 4 by a wall of which 1 in a corner; left: 1 interior, 2 by a
        // wall, the corner one. Scene b: 5 objects, all interior, 1 left.
        let mut a = scene(0, 0, 10, 6, 6);
        let mut b = scene(0, 1, 5, 4, 4);
        for (line, start, objects) in [
            (
                &mut a,
                (10, 4, 1),
                vec![
                    left(WallZone::Interior),
                    left(WallZone::Wall),
                    left(WallZone::Wall),
                    left(WallZone::Corner),
                ],
            ),
            (&mut b, (5, 0, 0), vec![left(WallZone::Interior)]),
        ] {
            if let RecordLine::Scene { summary, .. } = line {
                summary.remaining = objects.len();
                summary.remaining_objects = objects;
                summary.start_wall_zones = Some(WallZones {
                    objects: start.0,
                    near_wall: start.1,
                    in_corner: start.2,
                });
            }
        }
        let detectors = [("a".to_string(), "A".to_string())];
        let s = summarize(&[a, b], &detectors, &[Difficulty::Easy], &[0], 2);
        let c = &s.cells[0];
        assert_eq!(c.started_by_zone, [11, 3, 1]);
        assert_eq!(c.left_by_start_zone, [2, 2, 1]);
        let md = s.markdown(&[0]);
        assert!(
            md.contains("| A | Easy | 11, left 2 (82 % cleared) | 3, left 2 (33 % cleared) | 1, left 1 (0 % cleared) |"),
            "{md}"
        );
    }

    #[test]
    fn attempt_outcomes_and_approach_touches_are_counted() {
        // Records as written on disk; the first has no `approach_contact` (older runs).
        let attempt = |outcome: &str, touch: Option<bool>| {
            let touch = touch.map_or(String::new(), |t| format!(r#","approach_contact":{t}"#));
            serde_json::from_str::<RecordLine>(&format!(
                r#"{{"type":"attempt","detector":"a","level":"easy","seed":0,"scene":0,"attempt":0,"objects_before":2,"configurations":5,"quality":0.9,"collision_score":1.0,"approach_index":3,"width_m":0.03,"opening_m":0.05,"outcome":"{outcome}","lifted":1,"lost":0,"final_opening_m":0.03{touch},"render_ms":1.0,"fusion_ms":1.0,"inference_ms":1.0,"selection_ms":1.0,"execution_ms":4.0}}"#
            ))
            .unwrap()
        };
        let lines = vec![
            attempt("success", None),
            attempt("success", Some(true)),
            attempt("approach_contact", Some(true)),
            attempt("nothing_held", Some(false)),
            scene(0, 0, 2, 4, 2),
        ];
        let detectors = [("a".to_string(), "A".to_string())];
        let s = summarize(&lines, &detectors, &[Difficulty::Easy], &[0], 1);
        let c = &s.cells[0];
        assert_eq!(c.outcomes.get("success"), Some(&2));
        assert_eq!(c.outcomes.get("approach_contact"), Some(&1));
        assert_eq!(c.approach_touches, 2);
        assert!((c.execution_ms_per_attempt - 4.0).abs() < 1e-9);
        assert!(s
            .markdown(&[0])
            .contains("| approach_contact 1, nothing_held 1, success 2 | 2 |"));
    }

    /// An attempt record as written on disk, with `extra` fields (each led by a comma) appended.
    fn attempt_line(outcome: &str, collision_score: f32, extra: &str) -> RecordLine {
        serde_json::from_str::<RecordLine>(&format!(
            r#"{{"type":"attempt","detector":"a","level":"easy","seed":0,"scene":0,"attempt":0,"objects_before":2,"configurations":5,"quality":0.9,"collision_score":{collision_score},"approach_index":3,"width_m":0.03,"opening_m":0.05,"outcome":"{outcome}","lifted":0,"lost":0,"final_opening_m":0.0{extra},"render_ms":1.0,"fusion_ms":1.0,"inference_ms":1.0,"selection_ms":1.0,"execution_ms":4.0}}"#
        ))
        .unwrap()
    }

    #[test]
    fn attempts_from_the_fallback_tier_are_counted_and_reported() {
        let attempt = |outcome: &str, fallback: &str| attempt_line(outcome, 0.3, fallback);
        let detectors = [("a".to_string(), "A".to_string())];
        // Records without the field (older runs, or the fallback off): no section.
        let plain = vec![attempt("success", ""), scene(0, 0, 2, 1, 1)];
        let s = summarize(&plain, &detectors, &[Difficulty::Easy], &[0], 1);
        assert_eq!(s.cells[0].fallback_attempts, 0);
        assert!(!s.markdown(&[0]).contains("fallback tier"));
        let lines = vec![
            attempt("success", r#","fallback":false"#),
            attempt("success", r#","fallback":true"#),
            attempt("nothing_held", r#","fallback":true"#),
            attempt("nothing_held", r#","fallback":true"#),
            scene(0, 0, 3, 4, 2),
        ];
        let s = summarize(&lines, &detectors, &[Difficulty::Easy], &[0], 1);
        let c = &s.cells[0];
        assert_eq!((c.fallback_attempts, c.fallback_successes), (3, 1));
        let md = s.markdown(&[0]);
        assert!(md.contains("| A | Easy | 3 | 4 | 1 (33 %) |"), "{md}");
    }

    #[test]
    fn failed_attempts_are_counted_by_cause() {
        // Records as written on disk, with the touch and target of newer runs (the last has
        // neither: an older run).
        let attempt = |outcome: &str, extra: &str| attempt_line(outcome, 1.0, extra);
        let target = |d: f32| {
            format!(r#","target":{{"name":"proc-001-box","kind":"box","tcp_distance_m":{d}}}"#)
        };
        let touch = |what: &str| {
            format!(
                r#","approach_contact":true,"approach_touch":{{"part":"finger","touched":"{what}","short_of_grasp_m":0.01}}{}"#,
                target(-0.003)
            )
        };
        let lines = vec![
            attempt("success", &touch("other_object")),
            attempt("nothing_held", &touch("target")),
            attempt("nothing_held", &touch("bin")),
            attempt("nothing_held", &target(0.005)),
            attempt("double_grasp", &target(-0.004)),
            attempt("nothing_held", ""),
            scene(0, 0, 2, 6, 1),
        ];
        let detectors = [("a".to_string(), "A".to_string())];
        let s = summarize(&lines, &detectors, &[Difficulty::Easy], &[0], 1);
        let c = &s.cells[0];
        let causes: Vec<(&str, usize)> = c
            .failure_causes
            .iter()
            .map(|(k, v)| (k.as_str(), *v))
            .collect();
        assert_eq!(
            causes,
            [
                ("reached", 1),
                ("reached_off_target", 1),
                ("reached_on_target", 1),
                ("touched_bin", 1),
                ("touched_target", 1)
            ]
        );
        assert_eq!(c.approach_touches, 3);
        assert!(s.markdown(&[0]).contains(
            "| 3 | reached 1, reached_off_target 1, reached_on_target 1, touched_bin 1, touched_target 1 |"
        ));
    }
}
