//! The perception chain of a bin-picking cell, written once: one depth frame in, ranked,
//! collision-checked picks out.
//!
//! ```text
//! depth ──▶ depth-scale correction ──▶ fusion ──▶ normal grid ──▶ inference ──▶ configurations ──▶ selection ──▶ picks
//!          └──────────── FusionStep ───────────┘                └ InferenceStep ┘                 └ SelectionStep ┘
//! ```
//!
//! [`CellConfig`] describes the cell (workspace grid, bin, gripper and the settings of every
//! step); the pipeline configuration, the dataset configuration and the evaluation protocol embed
//! it, so all three read the same TOML tables (`[workspace]`, `[bin]`, `[gripper]`, `[fusion]`,
//! `[depth_scale]`, `[inference]`, `[selection]`, `[perception]`).
//!
//! The pipeline runs one step per process (grid-fusion: [`FusionStep`], inference:
//! [`InferenceStep`], grasp-selection: [`SelectionStep`]); `psgrasp eval`, `psgrasp detect` and
//! the tests run the whole chain in one process with [`Perception::detect`]. Both call the same
//! step functions, so the evaluation runs exactly what the cell runs.
#![warn(missing_docs)]

mod chain;
mod config;

pub use chain::{
    grid_message_views, DepthScaleOutcome, Detection, DetectionTimings, FusionStep, InferenceStep,
    Perception, PerceptionError, Proposer, SelectionStep,
};
pub use config::{CellConfig, ChainConfig, InvalidSetting, NoUnknownKeys};
