//! Dense 6-DoF grasp labels, training targets and the on-disk dataset for psgrasp.
//!
//! Data flow per scene ([`generate::generate_record`]): pick objects of the right split → drop
//! and settle them (psgrasp-sim) → render clean depth and segmentation → dex noise → labels
//! ([`labels::generate_labels`]) → normal grid (psgrasp-fusion) and label grid
//! ([`targets::label_grid`]) → one safetensors file ([`dataset`]). The CLI entry points are
//! [`cli::run_datagen`] and [`cli::run_inspect`].
#![warn(missing_docs)]

pub mod approach_path;
pub mod cli;
pub mod dataset;
pub mod generate;
pub mod graspability;
pub mod inspect;
pub mod labels;
pub mod physics_check;
pub mod robustness;
pub mod targets;
pub mod verify;

pub use cli::{run_datagen, run_inspect, DatagenArgs, InspectArgs, ObjectSource};
pub use dataset::{read_scene, write_scene, Manifest, SceneMeta, SceneRecord};
pub use generate::{
    derive_seed, generate_record, generate_record_with_recipe, Difficulty, GenerationConfig,
    ObjectCounts,
};
pub use graspability::{
    graspability, visible_pixels_per_object, BlockedPoses, Graspability, GraspabilityConfig,
    GraspabilityVerdict,
};
pub use labels::{generate_labels, GraspLabel, LabelConfig, LabelSet, LabelStats};
pub use physics_check::{check_labels_in_physics, FailedLabels, LabelPhysicsCheck};
pub use targets::{label_grid, LABEL_CONTACT, LABEL_EMPTY, LABEL_GRIPPER};

use std::path::PathBuf;

/// Errors of dataset generation and I/O.
#[derive(Debug, thiserror::Error)]
pub enum DatagenError {
    /// Scene simulation failed.
    #[error(transparent)]
    Sim(#[from] psgrasp_sim::SimError),
    /// Fusing the normal grid failed (named in the message, so not a source too).
    #[error("normal-grid fusion failed: {0}")]
    Fusion(psgrasp_fusion::FusionError),
    /// A file could not be read or written.
    #[error("{path}: {error}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error (named in the message).
        error: std::io::Error,
    },
    /// JSON metadata could not be encoded or decoded (named in the message).
    #[error("metadata JSON: {0}")]
    Json(serde_json::Error),
    /// A tensor is missing or has the wrong dtype or shape.
    #[error("tensor '{name}': {reason}")]
    Tensor {
        /// Tensor name (`*` for the whole file).
        name: String,
        /// What is wrong.
        reason: String,
    },
    /// The scene file has no psgrasp metadata.
    #[error("scene file has no '{}' metadata", dataset::METADATA_KEY)]
    MissingMetadata,
    /// The scene file was written by an incompatible format version.
    #[error("scene format version {found}, this build reads {expected}")]
    FormatVersion {
        /// Version in the file.
        found: u32,
        /// Version this build reads.
        expected: u32,
    },
    /// The output directory holds a dataset made with other settings.
    #[error("{dir} holds a dataset with a different seed, difficulty, object source or config; use another --out")]
    ManifestMismatch {
        /// The directory.
        dir: PathBuf,
    },
    /// A PNG could not be written.
    #[error("{path}: PNG encoding failed: {reason}")]
    Png {
        /// The file.
        path: PathBuf,
        /// Encoder message.
        reason: String,
    },
}

impl From<psgrasp_fusion::FusionError> for DatagenError {
    fn from(e: psgrasp_fusion::FusionError) -> Self {
        Self::Fusion(e)
    }
}

impl From<serde_json::Error> for DatagenError {
    fn from(e: serde_json::Error) -> Self {
        Self::Json(e)
    }
}
