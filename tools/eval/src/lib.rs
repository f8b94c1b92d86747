//! Simulated clutter clearing for psgrasp (the paper's "Simulated Experiments", Table I).
//!
//! - [`execute`]: one grasp executed in rapier3d by a free-floating Franka hand (kinematic palm,
//!   force-limited fingers on prismatic impulse joints), judged as success or a named failure.
//! - [`protocol`]: the paper's clearing protocol on one test scene: render → fusion → detector →
//!   selection → execution, round after round.
//! - [`detectors`]: detectors as data (named `BackendConfig`s or the ground-truth oracle, a TOML
//!   list), each with its own [`overrides`] of the protocol's selection.
//! - [`records`]: the resumable run directory (`run.json`, `records.jsonl`, one JSON line per
//!   attempt and per finished scene).
//! - [`leftovers`]: why each object a round leaves has no grasp (its graspability on the final
//!   scene), and the report's tables of it.
//! - [`paired`]: CR differences between detectors on the same rounds, with standard errors.
//! - [`report`] and [`plot`]: SR/CR per level and detector as Markdown, JSON and a PNG chart.
//! - [`cli`]: `psgrasp eval` ([`EvalArgs`], [`run_eval`]): detectors × levels × seeds × scenes in
//!   parallel, resumable, with progress and the reports at the end.
//!
//! Determinism: every random process takes a seed; the same seed gives the same outcome on the
//! same build and platform (rapier is not built with cross-platform determinism).
#![warn(missing_docs)]

pub mod cli;
pub mod detectors;
pub mod kappa;
pub mod leftovers;
pub mod oracle;
pub mod overrides;
pub mod paired;
pub mod plot;
pub mod protocol;
pub mod records;
pub mod report;
pub mod seed_copies;
pub mod testset;

pub use cli::{run_eval, EvalArgs};
pub use detectors::{
    default_detectors, BuiltDetector, DetectorBackend, DetectorList, DetectorSpec,
};
pub use oracle::OracleConfig;
pub use overrides::SelectionOverrides;
pub use protocol::{
    clear_scene, run_scene, run_scene_with, scene_seed, AttemptRecord, Detector, PickTarget,
    ProtocolConfig, RemainingObject, SceneEnd, SceneRun, SceneSummary, TouchRecord, TouchedThing,
};
pub use psgrasp_sim::execute::{
    execute_grasp, execute_grasp_traced, hand_collides, pregrasp_pose, settle_scene,
    verify_grasp_in_isolation, ApproachTouch, Execution, ExecutionConfig, ExecutionReport,
    GraspCommand, GraspOutcome, HandPart, Phase, SettledScene, TraceSample,
};
pub use testset::{TestSet, TestSetManifest, DEFAULT_TESTSET_DIR};

use std::path::PathBuf;

impl From<psgrasp_perception::PerceptionError> for EvalError {
    fn from(e: psgrasp_perception::PerceptionError) -> Self {
        use psgrasp_perception::PerceptionError as P;
        match e {
            P::Config(c) => Self::Cell(c),
            P::Fusion(f) => Self::Fusion(f),
            P::Inference(i) => Self::Inference(i),
            P::Selection(s) => Self::Selection(s),
            P::NoBackend => Self::InvalidConfig {
                field: "detector",
                reason: "a backend detector needs its backend",
            },
        }
    }
}

/// Errors of the evaluation.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// A configuration value is out of its valid range.
    #[error("invalid evaluation setting `{field}`: {reason}")]
    InvalidConfig {
        /// Name of the field.
        field: &'static str,
        /// What the valid range is.
        reason: &'static str,
    },
    /// Building or rendering a scene failed.
    #[error(transparent)]
    Sim(#[from] psgrasp_sim::SimError),
    /// Fusing the depth image into a normal grid failed (named in the message).
    #[error("fusion failed: {0}")]
    Fusion(psgrasp_fusion::FusionError),
    /// The detector (inference backend) failed or could not be built; the message names the
    /// cause with its own causes (a model error has some).
    #[error("detector failed: {}", causes(.0))]
    Inference(psgrasp_inference::InferenceError),
    /// A detector could not be built; the message names the cause with its own causes.
    #[error("detector `{name}`: {}", causes(.error))]
    Detector {
        /// The detector's name.
        name: String,
        /// Why.
        error: psgrasp_inference::InferenceError,
    },
    /// A detector entry is invalid (bad or duplicate name, unparsable list).
    #[error("detector `{name}`: {reason}")]
    InvalidDetector {
        /// The detector's name (`*` for the whole list).
        name: String,
        /// What is wrong.
        reason: String,
    },
    /// A detector was asked for that the list does not hold.
    #[error("unknown detector `{name}` (known: {})", known.join(", "))]
    UnknownDetector {
        /// The name asked for.
        name: String,
        /// The names the list holds.
        known: Vec<String>,
    },
    /// Grasp selection could not run (named in the message).
    #[error("selection failed: {0}")]
    Selection(psgrasp_selection::SelectionError),
    /// The cell's settings are out of range (named in the message).
    #[error("invalid cell setting: {0}")]
    Cell(psgrasp_perception::InvalidSetting),
    /// A records or run file is unreadable or could not be encoded.
    #[error("{path}: {reason}")]
    Records {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// The output directory holds a run made with other settings.
    #[error("{dir} holds an evaluation with different {what}; use another --out")]
    RunMismatch {
        /// The directory.
        dir: PathBuf,
        /// What differs.
        what: String,
    },
    /// A fixed test set is missing, changed or does not hold what was asked for.
    #[error("test set {dir}: {reason}")]
    TestSet {
        /// Its directory.
        dir: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// A PNG could not be written.
    #[error("{path}: PNG encoding failed: {reason}")]
    Png {
        /// The file.
        path: PathBuf,
        /// Encoder message.
        reason: String,
    },
    /// A file could not be read or written.
    #[error("{path}: {error}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error (named in the message).
        error: std::io::Error,
    },
}

/// `e` and its chain of sources, joined by ": " (what `{:#}` prints for an `anyhow::Error`): a
/// message that names a cause this way does not return it as its source too.
fn causes(e: &dyn std::error::Error) -> String {
    let mut out = e.to_string();
    let mut next = e.source();
    while let Some(cause) = next {
        out.push_str(": ");
        out.push_str(&cause.to_string());
        next = cause.source();
    }
    out
}

impl From<psgrasp_inference::InferenceError> for EvalError {
    fn from(e: psgrasp_inference::InferenceError) -> Self {
        Self::Inference(e)
    }
}

impl From<psgrasp_fusion::FusionError> for EvalError {
    fn from(e: psgrasp_fusion::FusionError) -> Self {
        Self::Fusion(e)
    }
}

impl From<psgrasp_selection::SelectionError> for EvalError {
    fn from(e: psgrasp_selection::SelectionError) -> Self {
        Self::Selection(e)
    }
}

impl From<psgrasp_perception::InvalidSetting> for EvalError {
    fn from(e: psgrasp_perception::InvalidSetting) -> Self {
        Self::Cell(e)
    }
}

impl From<psgrasp_geometry::OutOfRange> for EvalError {
    fn from(e: psgrasp_geometry::OutOfRange) -> Self {
        Self::InvalidConfig {
            field: e.field,
            reason: e.reason,
        }
    }
}
