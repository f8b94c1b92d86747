//! Detectors as data: a named [`BackendConfig`] each, compared through the same
//! [`InferenceBackend`] trait and the same render → fusion → backend → selection code.
//!
//! A detector list is a TOML file:
//!
//! ```toml
//! [[detector]]
//! name = "analytic"
//! label = "Analytic antipodal (GPD-style)"
//! backend = { kind = "analytic" }
//!
//! [[detector]]
//! name = "w-kappa-8app"
//! label = "Ours (w κ + 8app)"
//! backend = { kind = "learned", model_dir = "models/default" }
//!
//! [[detector]]
//! name = "vgn"
//! label = "VGN (retrained)"
//! backend = { kind = "vgn", model_dir = "models/vgn" }
//!
//! [[detector]]
//! name = "oracle"
//! label = "Ground-truth labels (upper bound)"
//! backend = { kind = "oracle" }
//! ```
//!
//! `kind = "oracle"` is not a perception backend: it proposes the dataset labeler's grasps on the
//! true scene ([`crate::Detector::Oracle`]), the bound a perfect detector could reach.
//!
//! Without a file, [`default_detectors`] gives the analytic baseline plus one detector per model
//! directory (a folder with a `card.json`) under `models/`: a VGN detector for a VGN card, a
//! learned one otherwise.
use crate::overrides::SelectionOverrides;
use crate::protocol::ProtocolConfig;
use crate::EvalError;
use psgrasp_inference::{BackendConfig, InferenceBackend, LearnedConfig};
use serde::{Deserialize, Deserializer, Serialize, Serializer};
use std::path::{Path, PathBuf};

/// What proposes a detector's grasps: a perception backend, or the ground-truth oracle.
/// Written as a backend table; the oracle is `{ kind = "oracle" }`.
#[derive(Debug, Clone, PartialEq)]
pub enum DetectorBackend {
    /// An inference backend on the fused normal grid (as the pipeline runs it).
    Backend(BackendConfig),
    /// The dataset labeler on the true scene ([`crate::Detector::Oracle`]).
    Oracle,
}

/// The `kind` of [`DetectorBackend::Oracle`].
pub const ORACLE_KIND: &str = "oracle";

impl DetectorBackend {
    /// The kind name (`analytic`, `learned`, `vgn`, `oracle`).
    pub fn kind(&self) -> &'static str {
        match self {
            DetectorBackend::Backend(b) => b.kind(),
            DetectorBackend::Oracle => ORACLE_KIND,
        }
    }

    /// The inference backend settings (`None` for the oracle).
    pub fn backend(&self) -> Option<&BackendConfig> {
        match self {
            DetectorBackend::Backend(b) => Some(b),
            DetectorBackend::Oracle => None,
        }
    }
}

impl From<BackendConfig> for DetectorBackend {
    fn from(b: BackendConfig) -> Self {
        DetectorBackend::Backend(b)
    }
}

impl Serialize for DetectorBackend {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self {
            DetectorBackend::Backend(b) => b.serialize(s),
            DetectorBackend::Oracle => {
                use serde::ser::SerializeMap;
                let mut m = s.serialize_map(Some(1))?;
                m.serialize_entry("kind", ORACLE_KIND)?;
                m.end()
            }
        }
    }
}

impl<'de> Deserialize<'de> for DetectorBackend {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        use serde::de::Error;
        // Through a JSON value, so that backend settings keep their own error messages.
        let value = serde_json::Value::deserialize(d)?;
        match value.as_object() {
            Some(table) if table.get("kind").and_then(|k| k.as_str()) == Some(ORACLE_KIND) => {
                match table.keys().find(|k| *k != "kind") {
                    Some(extra) => Err(D::Error::custom(format!(
                        "the oracle takes no settings (`{extra}`); its labeler settings are the \
                         protocol's `scenes.labels`"
                    ))),
                    None => Ok(DetectorBackend::Oracle),
                }
            }
            _ => BackendConfig::deserialize(value)
                .map(DetectorBackend::Backend)
                .map_err(D::Error::custom),
        }
    }
}

/// A built detector: what [`crate::Detector`] borrows for each scene.
pub enum BuiltDetector {
    /// A ready inference backend.
    Backend(Box<dyn InferenceBackend>),
    /// The ground-truth oracle.
    Oracle,
}

impl BuiltDetector {
    /// Borrowed for [`crate::run_scene_with`].
    pub fn as_detector(&mut self) -> crate::Detector<'_> {
        match self {
            BuiltDetector::Backend(b) => crate::Detector::Backend(b.as_mut()),
            BuiltDetector::Oracle => crate::Detector::Oracle,
        }
    }

    /// Whether the detector's proposals can depend on the detection seed (the oracle samples
    /// labels; backends say so themselves, [`InferenceBackend::uses_seed`]).
    pub fn uses_seed(&self) -> bool {
        match self {
            BuiltDetector::Backend(b) => b.uses_seed(),
            BuiltDetector::Oracle => true,
        }
    }
}

/// One detector: a name (used on the command line and in records) and its backend settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DetectorSpec {
    /// Short unique name: letters, digits, `-`, `_`, `.` (it names files and records).
    pub name: String,
    /// Display name for tables and plots (defaults to `name`).
    #[serde(default)]
    pub label: Option<String>,
    /// The backend and its settings (or the oracle).
    pub backend: DetectorBackend,
    /// The protocol's selection settings this detector replaces for itself only (the keys
    /// `min_quality`, `selection_fallback`, `selection_surface_check`, `selection_pick_order`,
    /// `selection_min_contact_wall_distance_m` in its table); a row with any is labelled as such.
    #[serde(flatten)]
    pub selection: SelectionOverrides,
}

/// The detector list file: `[[detector]]` tables.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DetectorList {
    /// The detectors, in table order.
    #[serde(default, rename = "detector")]
    pub detectors: Vec<DetectorSpec>,
}

impl DetectorSpec {
    /// A detector `name` on `backend`, with no label and the protocol's selection (no
    /// overrides).
    pub fn new(name: &str, backend: DetectorBackend) -> Self {
        Self {
            name: name.into(),
            label: None,
            backend,
            selection: SelectionOverrides::default(),
        }
    }

    /// The analytic antipodal baseline with default settings.
    pub fn analytic() -> Self {
        Self {
            label: Some("Analytic antipodal (GPD-style)".into()),
            ..Self::new(
                "analytic",
                BackendConfig::Analytic(Default::default()).into(),
            )
        }
    }

    /// A learned detector reading the model in `model_dir`.
    pub fn learned(name: &str, model_dir: PathBuf) -> Self {
        // One runtime thread: the evaluation runs scenes in parallel (`--jobs`).
        let backend = BackendConfig::Learned(LearnedConfig {
            model_dir,
            threads: 1,
            ..Default::default()
        });
        Self::new(name, backend.into())
    }

    /// A detector for the model directory `dir`: VGN for a VGN card, learned otherwise
    /// ([`BackendConfig::for_model_dir`]), with one runtime thread.
    pub fn for_model_dir(name: &str, dir: PathBuf) -> Self {
        // One runtime thread: the evaluation runs scenes in parallel (`--jobs`).
        Self::new(name, BackendConfig::for_model_dir(&dir, 1).into())
    }

    /// The display name.
    pub fn display_name(&self) -> &str {
        self.label.as_deref().unwrap_or(&self.name)
    }

    /// Checks the name and the selection override.
    pub fn validate(&self) -> Result<(), EvalError> {
        if let Some(q) = self.selection.min_quality {
            if !(0.0..=1.0).contains(&q) {
                return Err(EvalError::InvalidDetector {
                    name: self.name.clone(),
                    reason: format!("min_quality {q} must be in [0, 1]"),
                });
            }
        }
        if !self.selection.is_empty() {
            // Against the selection this detector gets under the default protocol (its own
            // `min_quality` applied); the protocol it runs under is checked again when it selects.
            self.protocol(&ProtocolConfig::default())
                .scenes
                .cell
                .selection
                .validate()
                .map_err(|e| EvalError::InvalidDetector {
                    name: self.name.clone(),
                    reason: format!("selection override: {e}"),
                })?;
        }
        let ok = !self.name.is_empty()
            && self.name.len() <= 64
            && self
                .name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'));
        if ok {
            Ok(())
        } else {
            Err(EvalError::InvalidDetector {
                name: self.name.clone(),
                reason: "names use 1-64 letters, digits, '-', '_' or '.'".into(),
            })
        }
    }

    /// The backend configuration as the evaluation runs it: as the cell runs it
    /// ([`psgrasp_perception::CellConfig::effective_backend`]: an analytic backend without a
    /// contact region gets the bin interior, so the thin bin walls are never grasped).
    pub fn effective_backend(&self, protocol: &ProtocolConfig) -> DetectorBackend {
        match &self.backend {
            DetectorBackend::Backend(b) => {
                DetectorBackend::Backend(protocol.cell().effective_backend(b))
            }
            DetectorBackend::Oracle => DetectorBackend::Oracle,
        }
    }

    /// The protocol this detector runs under: `protocol` with the detector's
    /// [`DetectorSpec::selection`] overrides applied to the cell's selection.
    pub fn protocol(&self, protocol: &ProtocolConfig) -> ProtocolConfig {
        let mut p = protocol.clone();
        self.selection.apply(&mut p.scenes.cell.selection);
        p
    }

    /// Builds the backend for the protocol's cell (its workspace and gripper).
    pub fn build(&self, protocol: &ProtocolConfig) -> Result<BuiltDetector, EvalError> {
        self.validate()?;
        let DetectorBackend::Backend(backend) = &self.backend else {
            return Ok(BuiltDetector::Oracle);
        };
        protocol
            .cell()
            .build_backend(backend)
            .map(BuiltDetector::Backend)
            .map_err(|error| EvalError::Detector {
                name: self.name.clone(),
                error,
            })
    }
}

impl DetectorList {
    /// Parses a detector list and checks that names are valid and unique.
    pub fn from_toml(text: &str) -> Result<Self, EvalError> {
        let list: DetectorList = toml::from_str(text).map_err(|e| EvalError::InvalidDetector {
            name: "*".into(),
            reason: e.to_string(),
        })?;
        list.validate()?;
        Ok(list)
    }

    /// Reads a detector list file.
    pub fn read(path: &Path) -> Result<Self, EvalError> {
        let text = std::fs::read_to_string(path).map_err(|error| EvalError::Io {
            path: path.to_owned(),
            error,
        })?;
        Self::from_toml(&text)
    }

    /// Checks names (valid, unique).
    pub fn validate(&self) -> Result<(), EvalError> {
        let mut seen = std::collections::BTreeSet::new();
        for d in &self.detectors {
            d.validate()?;
            if !seen.insert(d.name.as_str()) {
                return Err(EvalError::InvalidDetector {
                    name: d.name.clone(),
                    reason: "appears twice".into(),
                });
            }
        }
        Ok(())
    }

    /// The detectors named in `names` (all of them when `names` is empty), in the given order.
    pub fn pick(&self, names: &[String]) -> Result<Vec<DetectorSpec>, EvalError> {
        if names.is_empty() {
            return Ok(self.detectors.clone());
        }
        names
            .iter()
            .map(|n| {
                self.detectors
                    .iter()
                    .find(|d| &d.name == n)
                    .cloned()
                    .ok_or_else(|| EvalError::UnknownDetector {
                        name: n.clone(),
                        known: self.detectors.iter().map(|d| d.name.clone()).collect(),
                    })
            })
            .collect()
    }
}

/// The built-in detector list: the analytic baseline, then one detector per model directory
/// under `models_dir` (a sub-folder holding `card.json`, named after the folder, in name order;
/// VGN for a VGN card, learned otherwise). A missing `models_dir` gives the analytic baseline
/// only.
pub fn default_detectors(models_dir: &Path) -> DetectorList {
    let mut detectors = vec![DetectorSpec::analytic()];
    let mut dirs: Vec<(String, PathBuf)> = std::fs::read_dir(models_dir)
        .into_iter()
        .flatten()
        .flatten()
        .filter(|e| {
            e.path()
                .join(psgrasp_inference::learned::card::CARD_FILE)
                .is_file()
        })
        .filter_map(|e| {
            let name = e.file_name().to_str()?.to_owned();
            Some((name, e.path()))
        })
        .collect();
    dirs.sort();
    for (name, path) in dirs {
        let spec = DetectorSpec::for_model_dir(&name, path);
        if spec.validate().is_ok() && name != "analytic" {
            detectors.push(spec);
        }
    }
    DetectorList { detectors }
}

#[cfg(test)]
mod tests {
    use super::*;
    use psgrasp_selection::PickOrder;

    #[test]
    fn the_shipped_detector_file_builds_each_detector_for_its_hand() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
        let mut list = DetectorList::read(&root.join("config/eval-detectors.toml")).unwrap();
        let franka = ProtocolConfig::default();
        let mut old_hand = franka.clone();
        old_hand.scenes.cell.gripper = psgrasp_geometry::grippers::named("franka-15mm").unwrap();
        for spec in &mut list.detectors {
            if let DetectorBackend::Backend(backend) = &mut spec.backend {
                backend.resolve_paths(&root);
            }
            // Every shipped model is for the real Franka hand; the 15 mm hand refuses them.
            let (hand, other) = (&franka, &old_hand);
            if let Err(error) = spec.build(hand) {
                panic!("{}: {error}", spec.name);
            }
            let learned = matches!(spec.backend.kind(), "learned" | "vgn");
            assert_eq!(spec.build(other).is_err(), learned, "{}", spec.name);
        }
    }

    #[test]
    fn detector_list_parses_with_defaults_and_rejects_bad_entries() {
        let list = DetectorList::from_toml(
            "[[detector]]\nname = \"analytic\"\nbackend = { kind = \"analytic\", min_quality = 0.6 }\n\
             [[detector]]\nname = \"w-kappa-1app\"\nlabel = \"Ours (w κ + 1app)\"\n\
             backend = { kind = \"learned\", model_dir = \"models/1app\" }\n\
             [[detector]]\nname = \"vgn\"\n\
             backend = { kind = \"vgn\", model_dir = \"models/vgn\", quality_threshold = 0.8 }\n",
        )
        .unwrap();
        assert_eq!(list.detectors.len(), 3);
        let Some(BackendConfig::Vgn(v)) = list.detectors[2].backend.backend() else {
            panic!("vgn expected")
        };
        assert_eq!(v.quality_threshold, 0.8);
        assert_eq!(v.model_dir, PathBuf::from("models/vgn"));
        let Some(BackendConfig::Analytic(a)) = list.detectors[0].backend.backend() else {
            panic!("analytic expected")
        };
        assert_eq!(a.min_quality, 0.6);
        assert_eq!(list.detectors[1].display_name(), "Ours (w κ + 1app)");
        assert_eq!(list.detectors[1].backend.kind(), "learned");
        let picked = list.pick(&["w-kappa-1app".into()]).unwrap();
        assert_eq!(picked[0].name, "w-kappa-1app");
        assert!(matches!(
            list.pick(&["nope".into()]),
            Err(EvalError::UnknownDetector { .. })
        ));
        // Duplicate names, bad names, unknown keys.
        let dup = "[[detector]]\nname = \"a\"\nbackend = { kind = \"analytic\" }\n".repeat(2);
        assert!(DetectorList::from_toml(&dup).is_err());
        assert!(DetectorList::from_toml(
            "[[detector]]\nname = \"a b\"\nbackend = { kind = \"analytic\" }\n"
        )
        .is_err());
        assert!(DetectorList::from_toml(
            "[[detector]]\nname = \"a\"\nbakend = { kind = \"analytic\" }\n"
        )
        .is_err());
        // Backend settings keep their own errors; the oracle takes no settings.
        let err = DetectorList::from_toml(
            "[[detector]]\nname = \"a\"\nbackend = { kind = \"analytic\", min_qualty = 1 }\n",
        )
        .unwrap_err()
        .to_string();
        assert!(err.contains("min_qualty"), "{err}");
        let oracle = DetectorList::from_toml(
            "[[detector]]\nname = \"o\"\nbackend = { kind = \"oracle\" }\n",
        )
        .unwrap();
        assert_eq!(oracle.detectors[0].backend, DetectorBackend::Oracle);
        assert!(DetectorList::from_toml(
            "[[detector]]\nname = \"o\"\nbackend = { kind = \"oracle\", seed = 1 }\n"
        )
        .is_err());
        // Round trip through run.json's JSON.
        for d in list.detectors.iter().chain(&oracle.detectors) {
            let json = serde_json::to_string(&d.backend).unwrap();
            let back: DetectorBackend = serde_json::from_str(&json).unwrap();
            assert_eq!(back, d.backend);
        }
    }

    #[test]
    fn a_detector_s_selection_fallback_reaches_its_protocol_only() {
        let list = DetectorList::from_toml(
            "[[detector]]\nname = \"strict\"\nbackend = { kind = \"analytic\" }\n\
             [[detector]]\nname = \"loose\"\nbackend = { kind = \"analytic\" }\n\
             selection_fallback = { min_quality = 0.3, min_collision_score = 0.2 }\n",
        )
        .unwrap();
        let protocol = ProtocolConfig::default();
        assert_eq!(list.detectors[0].protocol(&protocol), protocol);
        let loose = list.detectors[1].protocol(&protocol);
        let f = loose.scenes.cell.selection.fallback.unwrap();
        assert_eq!((f.min_quality, f.min_collision_score), (0.3, 0.2));
        assert_eq!(loose.scenes.cell.selection.min_quality, 0.5);
        // Stricter than the paper's 0.5, or an unknown key: refused when the list is read.
        for bad in [
            "{ min_quality = 0.7, min_collision_score = 0.2 }",
            "{ min_quality = 0.3, min_colision_score = 0.2 }",
        ] {
            let text = format!(
                "[[detector]]\nname = \"x\"\nbackend = {{ kind = \"analytic\" }}\n\
                 selection_fallback = {bad}\n"
            );
            assert!(DetectorList::from_toml(&text).is_err(), "{bad}");
        }
    }

    #[test]
    fn a_detector_s_wall_distance_reaches_its_protocol_only() {
        let list = DetectorList::from_toml(
            "[[detector]]\nname = \"plain\"\nbackend = { kind = \"analytic\" }\n\
             [[detector]]\nname = \"walls\"\nbackend = { kind = \"analytic\" }\n\
             selection_min_contact_wall_distance_m = 0.005\n",
        )
        .unwrap();
        let protocol = ProtocolConfig::default();
        assert_eq!(list.detectors[0].protocol(&protocol), protocol);
        let walls = list.detectors[1].protocol(&protocol);
        assert_eq!(
            walls.scenes.cell.selection.min_contact_wall_distance_m,
            0.005
        );
        let text = "[[detector]]\nname = \"x\"\nbackend = { kind = \"analytic\" }\n\
                    selection_min_contact_wall_distance_m = -0.01\n";
        assert!(DetectorList::from_toml(text).is_err());
    }

    #[test]
    fn a_detector_s_failed_pick_memory_reaches_its_protocol_only() {
        let list = DetectorList::from_toml(
            "[[detector]]\nname = \"plain\"\nbackend = { kind = \"analytic\" }\n\
             [[detector]]\nname = \"memory\"\nbackend = { kind = \"analytic\" }\n\
             selection_failed_pick_memory = { picks = 2 }\n",
        )
        .unwrap();
        let protocol = ProtocolConfig::default();
        assert_eq!(list.detectors[0].protocol(&protocol), protocol);
        let memory = list.detectors[1]
            .protocol(&protocol)
            .scenes
            .cell
            .selection
            .failed_pick_memory;
        assert_eq!(
            (memory.picks, memory.radius_m, memory.max_angle_deg),
            (2, 0.03, 20.0)
        );
        for bad in [
            "{ picks = 2, radius_m = -0.1 }",
            "{ frame = 2 }",
            "{ picks = 200 }",
        ] {
            let text = format!(
                "[[detector]]\nname = \"x\"\nbackend = {{ kind = \"analytic\" }}\n\
                 selection_failed_pick_memory = {bad}\n"
            );
            assert!(DetectorList::from_toml(&text).is_err(), "{bad}");
        }
    }

    #[test]
    fn a_detector_s_surface_check_reaches_its_protocol_only() {
        let list = DetectorList::from_toml(
            "[[detector]]\nname = \"plain\"\nbackend = { kind = \"analytic\" }\n\
             [[detector]]\nname = \"fine\"\nbackend = { kind = \"analytic\" }\n\
             selection_surface_check = { enabled = true, cell_m = 0.003 }\n",
        )
        .unwrap();
        let protocol = ProtocolConfig::default();
        assert_eq!(list.detectors[0].protocol(&protocol), protocol);
        let check = list.detectors[1]
            .protocol(&protocol)
            .scenes
            .cell
            .selection
            .surface_check;
        assert!(check.enabled);
        assert_eq!(
            (check.cell_m, check.margin_m, check.min_cells),
            (0.003, 0.001, 1)
        );
        // Out of range, or an unknown key: refused when the list is read.
        for bad in [
            "{ enabled = true, cell_m = 0.5 }",
            "{ enabled = true, cel_m = 0.002 }",
        ] {
            let text = format!(
                "[[detector]]\nname = \"x\"\nbackend = {{ kind = \"analytic\" }}\n\
                 selection_surface_check = {bad}\n"
            );
            assert!(DetectorList::from_toml(&text).is_err(), "{bad}");
        }
    }

    #[test]
    fn a_detector_s_pick_order_reaches_its_protocol_only() {
        let list = DetectorList::from_toml(
            "[[detector]]\nname = \"plain\"\nbackend = { kind = \"analytic\" }\n\
             [[detector]]\nname = \"sure\"\nbackend = { kind = \"analytic\" }\n\
             selection_pick_order = \"confident-first\"\n",
        )
        .unwrap();
        let protocol = ProtocolConfig::default();
        assert_eq!(list.detectors[0].protocol(&protocol), protocol);
        let sure = list.detectors[1].protocol(&protocol);
        assert_eq!(
            sure.scenes.cell.selection.pick_order,
            PickOrder::ConfidentFirst
        );
        let text = "[[detector]]\nname = \"x\"\nbackend = { kind = \"analytic\" }\n\
                    selection_pick_order = \"most-confident\"\n";
        assert!(DetectorList::from_toml(text).is_err());
        // A misspelt override key is refused, not read as the protocol's setting.
        let text = "[[detector]]\nname = \"x\"\nbackend = { kind = \"analytic\" }\n\
                    selection_pik_order = \"confident-first\"\n";
        let err = DetectorList::from_toml(text).unwrap_err().to_string();
        assert!(err.contains("selection_pik_order"), "{err}");
    }

    #[test]
    fn defaults_find_model_directories() {
        let dir = tempfile::tempdir().unwrap();
        assert_eq!(
            default_detectors(&dir.path().join("missing"))
                .detectors
                .len(),
            1
        );
        for name in ["w-kappa-8app", "wo-kappa-1app"] {
            std::fs::create_dir(dir.path().join(name)).unwrap();
            std::fs::write(dir.path().join(name).join("card.json"), "{}").unwrap();
        }
        std::fs::create_dir(dir.path().join("vgn")).unwrap();
        std::fs::write(
            dir.path().join("vgn/card.json"),
            "{\"format\": \"psgrasp-vgn-model\"}",
        )
        .unwrap();
        std::fs::create_dir(dir.path().join("no-card")).unwrap();
        let list = default_detectors(dir.path());
        let names: Vec<&str> = list.detectors.iter().map(|d| d.name.as_str()).collect();
        assert_eq!(names, ["analytic", "vgn", "w-kappa-8app", "wo-kappa-1app"]);
        let Some(BackendConfig::Learned(l)) = list.detectors[2].backend.backend() else {
            panic!("learned expected")
        };
        assert_eq!(l.model_dir, dir.path().join("w-kappa-8app"));
        assert_eq!(l.threads, 1);
        let Some(BackendConfig::Vgn(v)) = list.detectors[1].backend.backend() else {
            panic!("vgn expected")
        };
        assert_eq!(v.model_dir, dir.path().join("vgn"));
        assert_eq!(v.threads, 1);
    }

    #[test]
    fn analytic_contacts_are_kept_inside_the_bin() {
        let proto = ProtocolConfig::default();
        let DetectorBackend::Backend(BackendConfig::Analytic(a)) =
            DetectorSpec::analytic().effective_backend(&proto)
        else {
            panic!("analytic expected")
        };
        let region = a.contact_region.unwrap();
        let bin = proto.scenes.cell.bin;
        assert!(region.contains(&bin.floor_center.map(|v| v + 0.01)));
        assert!(!region.contains(&(bin.floor_center - nalgebra::Vector3::new(0.0, 0.0, 0.001))));
    }
}
