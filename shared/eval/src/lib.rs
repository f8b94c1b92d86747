//! Simulated clutter clearing for psgrasp (the paper's "Simulated Experiments", Table I).
//!
//! - [`execute`]: one grasp executed in rapier3d by a free-floating Franka hand (kinematic palm,
//!   force-limited fingers on prismatic impulse joints), judged as success or a named failure.
//!
//! Determinism: every random process takes a seed; the same seed gives the same outcome on the
//! same build and platform (rapier is not built with cross-platform determinism).
#![warn(missing_docs)]

pub mod execute;

pub use execute::{
    execute_grasp, hand_collides, pregrasp_pose, Execution, ExecutionConfig, ExecutionReport,
    GraspCommand, GraspOutcome,
};

use std::path::PathBuf;

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
    /// A grasp command cannot be executed (non-finite pose, bad opening, bad gripper).
    #[error("invalid grasp command: {0}")]
    InvalidGrasp(&'static str),
    /// Building or rendering a scene failed.
    #[error(transparent)]
    Sim(#[from] psgrasp_sim::SimError),
    /// Fusing the depth image into a normal grid failed.
    #[error("fusion failed: {0}")]
    Fusion(#[from] psgrasp_fusion::FusionError),
    /// The detector (inference backend) failed or could not be built.
    #[error("detector failed: {0}")]
    Inference(#[from] psgrasp_inference::InferenceError),
    /// Grasp selection could not run.
    #[error("selection failed: {0}")]
    Selection(#[from] psgrasp_selection::SelectionError),
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        #[source]
        source: std::io::Error,
    },
}
