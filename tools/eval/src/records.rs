//! The on-disk state of an evaluation run: `run.json` (what was run) and `records.jsonl` (one JSON
//! object per line: every attempt, then one closing line per finished scene).
//!
//! Line format (`type` tells them apart):
//!
//! ```json
//! {"type":"attempt","detector":"analytic","level":"easy","seed":0,"scene":3,"attempt":0,"outcome":"success",...}
//! {"type":"scene","detector":"analytic","level":"easy","seed":0,"scene":3,"objects":4,"successes":3,...}
//! ```
//!
//! A scene's lines are appended together once it is finished, its `scene` line last. On resume
//! ([`RecordsFile::open`]) a scene counts as done when its `scene` line parses; attempt lines of
//! unfinished scenes and a torn last line (a killed run) are dropped, and those scenes run again
//! (deterministically, so with the same outcome).
use crate::detectors::{DetectorBackend, DetectorSpec};
use crate::overrides::{LegacyOverrideMaps, SelectionOverrides};
use crate::protocol::{AttemptRecord, ProtocolConfig, SceneSummary};
use crate::EvalError;
use psgrasp_datagen::Difficulty;
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, HashSet};
use std::io::Write;
use std::path::{Path, PathBuf};

/// Version of the run and records format.
pub const RECORDS_VERSION: u32 = 1;
/// File name of the run description.
pub const RUN_FILE: &str = "run.json";
/// File name of the records.
pub const RECORDS_FILE: &str = "records.jsonl";

/// Which scene of which run a record belongs to.
#[derive(Debug, Clone, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct SceneKey {
    /// Detector name.
    pub detector: String,
    /// Test level.
    pub level: Difficulty,
    /// Run seed.
    pub seed: u64,
    /// Scene index.
    pub scene: u64,
}

/// One line of `records.jsonl`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum RecordLine {
    /// One executed attempt.
    Attempt {
        /// The scene.
        #[serde(flatten)]
        key: SceneKey,
        /// The attempt.
        #[serde(flatten)]
        attempt: AttemptRecord,
    },
    /// A finished scene.
    Scene {
        /// The scene.
        #[serde(flatten)]
        key: SceneKey,
        /// Its totals.
        #[serde(flatten)]
        summary: SceneSummary,
    },
}

impl RecordLine {
    /// The scene the line belongs to.
    pub fn key(&self) -> &SceneKey {
        match self {
            RecordLine::Attempt { key, .. } | RecordLine::Scene { key, .. } => key,
        }
    }
}

/// What a run directory was made with (`run.json`); a resumed run must match it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(from = "StoredRunDescription")]
pub struct RunDescription {
    /// Always `psgrasp-eval`.
    pub format: String,
    /// [`RECORDS_VERSION`].
    pub version: u32,
    /// Object source name (`procedural`, `ycb`, ...).
    pub object_source: String,
    /// The protocol settings.
    pub protocol: ProtocolConfig,
    /// Every detector run into this directory, by name, with the backend settings it ran with.
    pub detectors: BTreeMap<String, DetectorBackend>,
    /// Detectors that ran with their own selection settings ([`DetectorSpec::selection`]), by
    /// name; absent names ran with the protocol's.
    ///
    /// [`DetectorSpec::selection`]: crate::DetectorSpec::selection
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub selection_overrides: BTreeMap<String, SelectionOverrides>,
}

/// `run.json` as read: today's form, or the one before overrides were one record per detector
/// (five maps, one per setting), folded into today's.
#[derive(Deserialize)]
struct StoredRunDescription {
    format: String,
    version: u32,
    object_source: String,
    protocol: ProtocolConfig,
    detectors: BTreeMap<String, DetectorBackend>,
    #[serde(default)]
    selection_overrides: BTreeMap<String, SelectionOverrides>,
    #[serde(flatten)]
    legacy: LegacyOverrideMaps,
}

impl From<StoredRunDescription> for RunDescription {
    fn from(stored: StoredRunDescription) -> Self {
        let mut selection_overrides = stored.selection_overrides;
        stored.legacy.fold_into(&mut selection_overrides);
        selection_overrides.retain(|_, o| !o.is_empty());
        Self {
            format: stored.format,
            version: stored.version,
            object_source: stored.object_source,
            protocol: stored.protocol,
            detectors: stored.detectors,
            selection_overrides,
        }
    }
}

impl RunDescription {
    /// The description of a run of `detectors` on `object_source` under `protocol`: each
    /// detector's backend as the evaluation runs it, and its selection overrides.
    pub fn new(
        object_source: String,
        protocol: &ProtocolConfig,
        detectors: &[DetectorSpec],
    ) -> Self {
        Self {
            format: "psgrasp-eval".into(),
            version: RECORDS_VERSION,
            object_source,
            protocol: protocol.clone(),
            detectors: detectors
                .iter()
                .map(|d| (d.name.clone(), d.effective_backend(protocol)))
                .collect(),
            selection_overrides: detectors
                .iter()
                .filter(|d| !d.selection.is_empty())
                .map(|d| (d.name.clone(), d.selection))
                .collect(),
        }
    }

    /// Reads `dir/run.json` if it exists.
    pub fn read(dir: &Path) -> Result<Option<Self>, EvalError> {
        let path = dir.join(RUN_FILE);
        if !path.exists() {
            return Ok(None);
        }
        let text = std::fs::read_to_string(&path).map_err(|error| EvalError::Io {
            path: path.clone(),
            error,
        })?;
        serde_json::from_str(&text)
            .map(Some)
            .map_err(|e| EvalError::Records {
                path,
                reason: e.to_string(),
            })
    }

    /// Writes `dir/run.json` atomically.
    pub fn write(&self, dir: &Path) -> Result<(), EvalError> {
        let text = serde_json::to_string_pretty(self).map_err(|e| EvalError::Records {
            path: dir.join(RUN_FILE),
            reason: e.to_string(),
        })?;
        write_atomic(&dir.join(RUN_FILE), text.as_bytes())
    }

    /// Merges `other` (this run's request) into the stored description: the object source and
    /// protocol must be equal, and a detector name already present must have the same settings.
    pub fn merge(&mut self, other: &RunDescription, dir: &Path) -> Result<(), EvalError> {
        let mismatch = |what: String| EvalError::RunMismatch {
            dir: dir.to_owned(),
            what,
        };
        if self.version != other.version {
            return Err(mismatch(format!(
                "format version {} (this build writes {})",
                self.version, other.version
            )));
        }
        if self.object_source != other.object_source {
            return Err(mismatch(format!(
                "object source `{}`, now `{}`",
                self.object_source, other.object_source
            )));
        }
        if self.protocol != other.protocol {
            return Err(mismatch("protocol settings".into()));
        }
        for (name, cfg) in &other.detectors {
            let same_override =
                self.selection_overrides.get(name) == other.selection_overrides.get(name);
            match self.detectors.get(name) {
                Some(old) if old != cfg || !same_override => {
                    return Err(mismatch(format!("settings of detector `{name}`")))
                }
                Some(_) => {}
                None => {
                    self.detectors.insert(name.clone(), cfg.clone());
                    if let Some(o) = other.selection_overrides.get(name) {
                        self.selection_overrides.insert(name.clone(), *o);
                    }
                }
            }
        }
        Ok(())
    }
}

/// Writes `bytes` to `path` through a temporary file and a rename.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), EvalError> {
    let io = |error| EvalError::Io {
        path: path.to_owned(),
        error,
    };
    let tmp = path.with_extension("tmp");
    std::fs::write(&tmp, bytes).map_err(io)?;
    std::fs::rename(&tmp, path).map_err(io)
}

/// The records of a run directory, opened for appending.
#[derive(Debug)]
pub struct RecordsFile {
    path: PathBuf,
    file: std::fs::File,
    lines: Vec<RecordLine>,
    done: HashSet<SceneKey>,
    dropped: usize,
}

impl RecordsFile {
    /// Opens (or creates) `dir/records.jsonl`, keeps the lines of finished scenes and drops the
    /// rest (rewriting the file when anything was dropped).
    pub fn open(dir: &Path) -> Result<Self, EvalError> {
        let path = dir.join(RECORDS_FILE);
        let io = |error| EvalError::Io {
            path: path.clone(),
            error,
        };
        let text = match std::fs::read_to_string(&path) {
            Ok(t) => t,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => String::new(),
            Err(e) => return Err(io(e)),
        };
        let mut parsed = Vec::new();
        let mut dropped = 0;
        for line in text.lines().filter(|l| !l.trim().is_empty()) {
            match serde_json::from_str::<RecordLine>(line) {
                Ok(r) => parsed.push(r),
                Err(_) => dropped += 1,
            }
        }
        let done: HashSet<SceneKey> = parsed
            .iter()
            .filter_map(|r| match r {
                RecordLine::Scene { key, .. } => Some(key.clone()),
                RecordLine::Attempt { .. } => None,
            })
            .collect();
        let before = parsed.len();
        let mut seen_scene = HashSet::new();
        parsed.retain(|r| {
            done.contains(r.key())
                && match r {
                    RecordLine::Scene { key, .. } => seen_scene.insert(key.clone()),
                    RecordLine::Attempt { .. } => true,
                }
        });
        dropped += before - parsed.len();
        if dropped > 0 {
            let mut out = Vec::new();
            for r in &parsed {
                out.extend(encode(r, &path)?);
            }
            write_atomic(&path, &out)?;
        }
        let file = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&path)
            .map_err(io)?;
        Ok(Self {
            path,
            file,
            lines: parsed,
            done,
            dropped,
        })
    }

    /// True if the scene has finished before.
    pub fn is_done(&self, key: &SceneKey) -> bool {
        self.done.contains(key)
    }

    /// The scenes finished before, in no particular order.
    pub fn finished(&self) -> impl Iterator<Item = &SceneKey> {
        self.done.iter()
    }

    /// Lines dropped when opening (unfinished scenes, torn lines).
    pub fn dropped(&self) -> usize {
        self.dropped
    }

    /// All lines of finished scenes.
    pub fn lines(&self) -> &[RecordLine] {
        &self.lines
    }

    /// The attempts and summary of a finished scene (`None` if it has not finished).
    pub fn finished_scene(&self, key: &SceneKey) -> Option<(Vec<AttemptRecord>, SceneSummary)> {
        if !self.is_done(key) {
            return None;
        }
        let mut attempts = Vec::new();
        for line in &self.lines {
            match line {
                RecordLine::Attempt { key: k, attempt } if k == key => {
                    attempts.push(attempt.clone())
                }
                RecordLine::Scene { key: k, summary } if k == key => {
                    return Some((attempts, summary.clone()))
                }
                _ => {}
            }
        }
        None
    }

    /// Appends `copy` as a copy of the finished scene `source` (same attempts and summary, the
    /// summary naming the seed of the round that was run); an error if `source` has not finished.
    pub fn append_copy(&mut self, source: &SceneKey, copy: &SceneKey) -> Result<(), EvalError> {
        let (attempts, mut summary) =
            self.finished_scene(source)
                .ok_or_else(|| EvalError::Records {
                    path: self.path.clone(),
                    reason: format!("no finished round {source:?} to copy as {copy:?}"),
                })?;
        summary.copied_from_seed = Some(summary.copied_from_seed.unwrap_or(source.seed));
        self.append_scene(copy, &attempts, &summary)
    }

    /// Appends a finished scene: its attempts, then its closing line, in one write.
    pub fn append_scene(
        &mut self,
        key: &SceneKey,
        attempts: &[AttemptRecord],
        summary: &SceneSummary,
    ) -> Result<(), EvalError> {
        let mut lines: Vec<RecordLine> = attempts
            .iter()
            .map(|a| RecordLine::Attempt {
                key: key.clone(),
                attempt: a.clone(),
            })
            .collect();
        lines.push(RecordLine::Scene {
            key: key.clone(),
            summary: summary.clone(),
        });
        let mut bytes = Vec::new();
        for r in &lines {
            bytes.extend(encode(r, &self.path)?);
        }
        self.file
            .write_all(&bytes)
            .and_then(|_| self.file.flush())
            .map_err(|error| EvalError::Io {
                path: self.path.clone(),
                error,
            })?;
        self.lines.extend(lines);
        self.done.insert(key.clone());
        Ok(())
    }
}

fn encode(r: &RecordLine, path: &Path) -> Result<Vec<u8>, EvalError> {
    let mut v = serde_json::to_vec(r).map_err(|e| EvalError::Records {
        path: path.to_owned(),
        reason: e.to_string(),
    })?;
    v.push(b'\n');
    Ok(v)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::protocol::SceneEnd;
    use crate::DetectorList;
    use psgrasp_inference::BackendConfig;
    use psgrasp_selection::PickOrder;
    use psgrasp_sim::execute::GraspOutcome;

    fn key(scene: u64) -> SceneKey {
        SceneKey {
            detector: "analytic".into(),
            level: Difficulty::Easy,
            seed: 7,
            scene,
        }
    }

    fn attempt(k: u32) -> AttemptRecord {
        AttemptRecord {
            attempt: k,
            objects_before: 3,
            configurations: 10,
            quality: 0.9,
            collision_score: 1.0,
            kappa: Some(30.0),
            approach_index: 8,
            pose: None,
            pad_fill: Some(0.8),
            width_m: 0.03,
            opening_m: 0.05,
            outcome: GraspOutcome::Success,
            lifted: 1,
            lost: 0,
            final_opening_m: 0.029,
            approach_contact: false,
            approach_touch: None,
            target: None,
            pregrasps_skipped: 0,
            labels_failed_physics: 0,
            fallback: false,
            deferred_near_failure: 0,
            depth_scale: None,
            render_ms: 1.0,
            fusion_ms: 2.0,
            inference_ms: 3.0,
            selection_ms: 4.0,
            execution_ms: 5.0,
        }
    }

    pub(crate) fn summary() -> SceneSummary {
        SceneSummary {
            objects: 3,
            attempts: 2,
            successes: 2,
            lost: 0,
            remaining: 1,
            end: SceneEnd::NoGrasp,
            frames: 3,
            detection_ms: 27.0,
            configurations: 30,
            scene_ms: 100.0,
            final_rejections: Some(Default::default()),
            remaining_objects: Vec::new(),
            start_wall_zones: None,
            copied_from_seed: None,
        }
    }

    #[test]
    fn a_copy_repeats_a_finished_round_and_names_its_seed() {
        let dir = tempfile::tempdir().unwrap();
        let mut f = RecordsFile::open(dir.path()).unwrap();
        let copy = SceneKey { seed: 8, ..key(0) };
        // Nothing to copy yet: an error, and nothing written.
        assert!(f.append_copy(&key(0), &copy).is_err());
        assert!(!f.is_done(&copy));
        f.append_scene(&key(0), &[attempt(0), attempt(1)], &summary())
            .unwrap();
        f.append_copy(&key(0), &copy).unwrap();
        let (attempts, copied) = RecordsFile::open(dir.path())
            .unwrap()
            .finished_scene(&copy)
            .unwrap();
        assert_eq!(attempts, [attempt(0), attempt(1)]);
        assert_eq!(copied.copied_from_seed, Some(7));
        assert_eq!(
            SceneSummary {
                copied_from_seed: None,
                ..copied
            },
            summary()
        );
    }

    #[test]
    fn lines_round_trip_and_torn_or_unfinished_scenes_are_dropped() {
        let dir = tempfile::tempdir().unwrap();
        {
            let mut f = RecordsFile::open(dir.path()).unwrap();
            f.append_scene(&key(0), &[attempt(0), attempt(1)], &summary())
                .unwrap();
        }
        // A killed run: attempts of scene 1 without its closing line, then a torn line.
        let path = dir.path().join(RECORDS_FILE);
        let mut text = std::fs::read_to_string(&path).unwrap();
        let line = serde_json::to_string(&RecordLine::Attempt {
            key: key(1),
            attempt: attempt(0),
        })
        .unwrap();
        assert!(line.contains("\"type\":\"attempt\"") && line.contains("\"level\":\"easy\""));
        text.push_str(&line);
        text.push('\n');
        text.push_str("{\"type\":\"scene\",\"detector\":\"analytic\",\"le");
        std::fs::write(&path, text).unwrap();

        let f = RecordsFile::open(dir.path()).unwrap();
        assert!(f.is_done(&key(0)));
        assert!(!f.is_done(&key(1)));
        assert_eq!(f.dropped(), 2);
        assert_eq!(f.lines().len(), 3);
        assert_eq!(
            f.lines()[2],
            RecordLine::Scene {
                key: key(0),
                summary: summary()
            }
        );
        // The file was cleaned: reopening drops nothing.
        drop(f);
        assert_eq!(RecordsFile::open(dir.path()).unwrap().dropped(), 0);
    }

    #[test]
    fn run_descriptions_merge_or_refuse() {
        let dir = Path::new("/nonexistent");
        let base = RunDescription {
            format: "psgrasp-eval".into(),
            version: RECORDS_VERSION,
            object_source: "procedural".into(),
            protocol: ProtocolConfig::default(),
            detectors: BTreeMap::from([("analytic".to_string(), BackendConfig::default().into())]),
            selection_overrides: BTreeMap::new(),
        };
        let mut stored = base.clone();
        let mut more = base.clone();
        more.detectors
            .insert("other".into(), BackendConfig::default().into());
        stored.merge(&more, dir).unwrap();
        assert_eq!(stored.detectors.len(), 2);
        let mut changed = base.clone();
        changed.protocol.max_consecutive_failures = 5;
        assert!(matches!(
            stored.merge(&changed, dir),
            Err(EvalError::RunMismatch { .. })
        ));
        let mut retuned = base.clone();
        let Some(DetectorBackend::Backend(BackendConfig::Analytic(a))) =
            retuned.detectors.get_mut("analytic")
        else {
            panic!("analytic expected")
        };
        a.min_quality = 0.9;
        assert!(stored.merge(&retuned, dir).is_err());
        // The same backend with its own selection threshold is other settings too; a new
        // detector brings its threshold along.
        let mut thresholded = base.clone();
        let min_quality = SelectionOverrides {
            min_quality: Some(0.3),
            ..Default::default()
        };
        thresholded
            .selection_overrides
            .insert("analytic".into(), min_quality);
        assert!(stored.merge(&thresholded, dir).is_err());
        let mut third = base.clone();
        third
            .detectors
            .insert("third".into(), BackendConfig::default().into());
        third
            .selection_overrides
            .insert("third".into(), min_quality);
        stored.merge(&third, dir).unwrap();
        assert_eq!(stored.selection_overrides.get("third"), Some(&min_quality));
        assert!(stored.merge(&third, dir).is_ok());
        // So is another distance of the contacts from the walls.
        let mut walls = third.clone();
        let wall_distance = SelectionOverrides {
            min_contact_wall_distance_m: Some(0.005),
            ..Default::default()
        };
        walls
            .selection_overrides
            .insert("third".into(), wall_distance);
        assert!(stored.merge(&walls, dir).is_err());
        let mut fourth = base.clone();
        fourth
            .detectors
            .insert("fourth".into(), BackendConfig::default().into());
        fourth
            .selection_overrides
            .insert("fourth".into(), wall_distance);
        stored.merge(&fourth, dir).unwrap();
        assert!(stored.merge(&fourth, dir).is_ok());
        assert!(stored.merge(&walls, dir).is_err());
    }

    /// A run directory written before overrides were one record per detector (five maps, one
    /// per setting) still resumes: session 43's `run.json` of the cell's rows (kept as a fixture,
    /// `tests/fixtures/run-five-override-maps.json`) reads into one record per detector, accepts
    /// the same detectors from today's detector list, refuses one with another setting, and is
    /// written back in today's form only.
    #[test]
    fn a_run_json_with_the_old_override_maps_resumes() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
        let fixture = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/fixtures/run-five-override-maps.json");
        let old_dir = tempfile::tempdir().unwrap();
        std::fs::copy(&fixture, old_dir.path().join(RUN_FILE)).unwrap();
        let old_dir = old_dir.path();
        let text = std::fs::read_to_string(old_dir.join(RUN_FILE)).unwrap();
        assert!(
            text.contains("\"selection_pick_order\": {"),
            "an old-form file"
        );
        assert!(!text.contains("selection_overrides"), "an old-form file");
        let mut stored = RunDescription::read(old_dir).unwrap().unwrap();
        let walls = stored.selection_overrides["w-kappa-8app-cell-walls-wide"];
        assert_eq!(walls.min_contact_wall_distance_m, Some(0.005));
        assert_eq!(walls.pick_order, Some(PickOrder::ConfidentFirst));
        assert!(walls.surface_check.unwrap().enabled);
        assert_eq!(
            walls.fallback.unwrap().approaches_per_configuration,
            Some(18)
        );
        assert_eq!(walls.min_quality, None);
        assert!(!stored.selection_overrides.contains_key("oracle"));

        let list = DetectorList::read(&root.join("config/eval-detectors.toml")).unwrap();
        let names = ["w-kappa-8app-cell-walls-wide".to_string(), "oracle".into()];
        let request = RunDescription::new(
            stored.object_source.clone(),
            &stored.protocol,
            &list.pick(&names).unwrap(),
        );
        stored.merge(&request, old_dir).unwrap();
        let mut moved = list.pick(&names[..1]).unwrap();
        moved[0].selection.min_contact_wall_distance_m = Some(0.01);
        let other = RunDescription::new(stored.object_source.clone(), &stored.protocol, &moved);
        assert!(stored.merge(&other, old_dir).is_err());

        let dir = tempfile::tempdir().unwrap();
        stored.write(dir.path()).unwrap();
        let written = std::fs::read_to_string(dir.path().join(RUN_FILE)).unwrap();
        assert!(
            !written.contains("\"selection_pick_order\": {"),
            "{written}"
        );
        assert!(written.contains("\"selection_overrides\""));
        assert_eq!(RunDescription::read(dir.path()).unwrap().unwrap(), stored);
    }
}
