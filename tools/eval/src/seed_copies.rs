//! Rounds that the run seed cannot change: run once, recorded for every seed.
//!
//! On the fixed test set, scene i of a level is the same stored scene under every run seed; the
//! seed only seeds the depth noise (the noisy levels: challenging) and the detector's sampling
//! (the oracle's labels, the analytic backend's candidates). A detector whose backend samples
//! nothing ([`psgrasp_inference::InferenceBackend::uses_seed`] false: the learned and the
//! VGN-style networks) therefore plays exactly the same round under every seed on the
//! noise-free levels (easy, medium). Such a round runs once, for the first seed that needs it,
//! and is recorded for the other seeds, in this run or a later one into the same directory, as a
//! copy whose summary names the seed it was run under (`copied_from_seed`). `psgrasp eval
//! --run-every-seed` runs every round instead (the test
//! `copied_rounds_equal_rounds_run_under_their_own_seed` compares the two).
use crate::records::{RecordsFile, SceneKey};
use psgrasp_datagen::Difficulty;
use std::collections::HashMap;

/// Whether a round of a detector on a level plays the same under every run seed: stored scenes
/// (not generated from the seed), a level without depth noise, a detector that samples nothing.
pub fn round_is_seed_independent(
    level: Difficulty,
    stored_scenes: bool,
    detector_uses_seed: bool,
) -> bool {
    stored_scenes && !level.noisy() && !detector_uses_seed
}

/// Which rounds to run and which to copy.
#[derive(Debug, Default, PartialEq)]
pub struct SeedCopyPlan {
    /// Rounds to run, in the order given.
    pub run: Vec<SceneKey>,
    /// Copies of rounds finished before: (source, copy).
    pub copy_now: Vec<(SceneKey, SceneKey)>,
    /// Copies to record when the round they are keyed by has finished.
    pub copy_after: HashMap<SceneKey, Vec<SceneKey>>,
}

impl SeedCopyPlan {
    /// Rounds planned in all (run and copied).
    pub fn len(&self) -> usize {
        self.run.len() + self.copy_now.len() + self.copy_after.values().map(Vec::len).sum::<usize>()
    }

    /// True if nothing is left to run or copy.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Plans the unfinished rounds `todo` (in run order): a seed-independent round (`independent`)
/// is copied from the same round finished under the lowest seed in `records` (this run or an
/// earlier one into the same directory, e.g. `--seed 0` first and `--seed 1,2` later), or else
/// run for the first of its seeds in `todo` and copied for the others when that one finishes.
pub fn plan(
    todo: Vec<SceneKey>,
    records: &RecordsFile,
    independent: impl Fn(&SceneKey) -> bool,
) -> SeedCopyPlan {
    let mut out = SeedCopyPlan::default();
    // (detector, level, scene) → the lowest seed it has finished under.
    let mut finished: HashMap<(String, Difficulty, u64), u64> = HashMap::new();
    for key in records.finished() {
        let seed = finished
            .entry((key.detector.clone(), key.level, key.scene))
            .or_insert(key.seed);
        *seed = (*seed).min(key.seed);
    }
    // (detector, level, scene) → the round that runs for all seeds.
    let mut runner: HashMap<(String, Difficulty, u64), SceneKey> = HashMap::new();
    for key in todo {
        if !independent(&key) {
            out.run.push(key);
            continue;
        }
        let group = (key.detector.clone(), key.level, key.scene);
        if let Some(&seed) = finished.get(&group) {
            let source = SceneKey {
                seed,
                ..key.clone()
            };
            out.copy_now.push((source, key));
            continue;
        }
        match runner.get(&group) {
            Some(first) => out.copy_after.entry(first.clone()).or_default().push(key),
            None => {
                runner.insert(group, key.clone());
                out.run.push(key);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn key(detector: &str, level: Difficulty, seed: u64, scene: u64) -> SceneKey {
        SceneKey {
            detector: detector.into(),
            level,
            seed,
            scene,
        }
    }

    /// The records of a run directory in which the rounds `finished` have finished.
    fn records_with(dir: &std::path::Path, finished: &[SceneKey]) -> RecordsFile {
        let mut records = RecordsFile::open(dir).unwrap();
        let summary = crate::records::tests::summary();
        for k in finished {
            records.append_scene(k, &[], &summary).unwrap();
        }
        records
    }

    #[test]
    fn only_sampling_free_detectors_on_stored_noise_free_scenes_are_copied() {
        use Difficulty::*;
        assert!(round_is_seed_independent(Easy, true, false));
        assert!(round_is_seed_independent(Medium, true, false));
        // Depth noise is seeded; generated scenes come from the seed; sampling detectors differ.
        assert!(!round_is_seed_independent(Challenging, true, false));
        assert!(!round_is_seed_independent(Easy, false, false));
        assert!(!round_is_seed_independent(Medium, true, true));
    }

    #[test]
    fn the_first_seed_runs_and_the_others_copy_it_or_a_finished_round() {
        let dir = tempfile::tempdir().unwrap();
        // Scene 1 of "net" finished under seed 0 in an earlier run.
        let records = records_with(dir.path(), &[key("net", Difficulty::Easy, 0, 1)]);
        let mut todo = Vec::new();
        for scene in 0..2 {
            for seed in [0, 1, 2] {
                for d in ["net", "sampler"] {
                    let k = key(d, Difficulty::Easy, seed, scene);
                    if !records.is_done(&k) {
                        todo.push(k);
                    }
                }
            }
        }
        let plan = plan(todo, &records, |k| k.detector == "net");
        let net = |seed, scene| key("net", Difficulty::Easy, seed, scene);
        let sampler = |seed, scene| key("sampler", Difficulty::Easy, seed, scene);
        assert_eq!(
            plan.run,
            [
                net(0, 0),
                sampler(0, 0),
                sampler(1, 0),
                sampler(2, 0),
                sampler(0, 1),
                sampler(1, 1),
                sampler(2, 1)
            ]
        );
        assert_eq!(plan.copy_after.len(), 1);
        assert_eq!(plan.copy_after[&net(0, 0)], [net(1, 0), net(2, 0)]);
        assert_eq!(
            plan.copy_now,
            [(net(0, 1), net(1, 1)), (net(0, 1), net(2, 1))]
        );
        assert_eq!(plan.len(), 11);
    }

    #[test]
    fn a_later_run_of_other_seeds_copies_the_rounds_an_earlier_run_finished() {
        let dir = tempfile::tempdir().unwrap();
        // `--seed 0` finished scene 0 of both levels; `--seed 1,2` comes later.
        let records = records_with(
            dir.path(),
            &[
                key("net", Difficulty::Easy, 0, 0),
                key("net", Difficulty::Challenging, 0, 0),
            ],
        );
        let todo: Vec<_> = [1, 2]
            .into_iter()
            .flat_map(|seed| {
                [Difficulty::Easy, Difficulty::Challenging].map(|l| key("net", l, seed, 0))
            })
            .collect();
        // The noisy level depends on the seed: it runs; the noise-free one is copied from seed 0.
        let plan = plan(todo, &records, |k| k.level == Difficulty::Easy);
        let easy = |seed| key("net", Difficulty::Easy, seed, 0);
        let challenging = |seed| key("net", Difficulty::Challenging, seed, 0);
        assert_eq!(plan.run, [challenging(1), challenging(2)]);
        assert_eq!(plan.copy_now, [(easy(0), easy(1)), (easy(0), easy(2))]);
        assert!(plan.copy_after.is_empty());
    }
}
