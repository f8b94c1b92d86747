//! The error of loading or running a model of the ONNX backends (learned and VGN): reading and
//! checking the model directory and its card, loading and running the graphs on a runtime.
use crate::learned::card::{CARD_FORMAT, CARD_FORMAT_VERSION};
use std::path::PathBuf;

/// Errors of loading or running a learned model (the learned backend's or a VGN model).
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    /// A file of the model directory could not be read.
    #[error("cannot read {path}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        #[source]
        source: std::io::Error,
    },
    /// `card.json` is not valid JSON or misses a required field.
    #[error("model card {path} is malformed")]
    CardJson {
        /// The card file.
        path: PathBuf,
        /// The parse error (names the field and line).
        #[source]
        source: serde_json::Error,
    },
    /// The card's `format` is not [`CARD_FORMAT`].
    #[error("card field `format` is {found:?}, expected {CARD_FORMAT:?}")]
    Format {
        /// The value found.
        found: String,
    },
    /// The card's `format_version` is not [`CARD_FORMAT_VERSION`].
    #[error(
        "card field `format_version` is {found}, this build reads version {CARD_FORMAT_VERSION}"
    )]
    FormatVersion {
        /// The value found.
        found: u32,
    },
    /// A card field disagrees with the pipeline configuration (grid, gripper, approaches).
    #[error("card field `{field}` is {card}, the pipeline has {expected}")]
    Mismatch {
        /// Dotted card path, e.g. `grid.voxel_size_m`.
        field: &'static str,
        /// The card's value.
        card: String,
        /// The pipeline's value.
        expected: String,
    },
    /// A card field is out of range or inconsistent with other card fields.
    #[error("card field `{field}` is invalid: {reason}")]
    InvalidCard {
        /// Dotted card path.
        field: &'static str,
        /// What is wrong.
        reason: String,
    },
    /// An ONNX file's SHA-256 differs from the card (corrupt or replaced file).
    #[error("{path}: sha256 {actual} does not match the card's {expected}")]
    Sha256Mismatch {
        /// The ONNX file.
        path: PathBuf,
        /// SHA-256 recorded in the card.
        expected: String,
        /// SHA-256 of the file on disk.
        actual: String,
    },
    /// An ONNX graph could not be parsed or prepared by the runtime.
    #[error("cannot load graph `{graph}` with {runtime}")]
    Graph {
        /// `"unet"`, `"mlp"` (learned backend) or `"vgn"`.
        graph: &'static str,
        /// `"tract"` or `"ort"`.
        runtime: &'static str,
        /// The runtime's error.
        #[source]
        source: Box<dyn std::error::Error + Send + Sync + 'static>,
    },
    /// A graph's inputs or outputs do not follow the interface contract (names, shapes).
    #[error("graph `{graph}` does not match the interface: {reason}")]
    GraphInterface {
        /// `"unet"`, `"mlp"` (learned backend) or `"vgn"`.
        graph: &'static str,
        /// What differs.
        reason: String,
    },
    /// Running a graph failed.
    #[error("running graph `{graph}` with {runtime} failed")]
    Run {
        /// `"unet"`, `"mlp"` (learned backend) or `"vgn"`.
        graph: &'static str,
        /// `"tract"` or `"ort"`.
        runtime: &'static str,
        /// The runtime's error.
        #[source]
        source: Box<dyn std::error::Error + Send + Sync + 'static>,
    },
    /// A graph produced a NaN or infinity.
    #[error("graph output `{output}` holds a non-finite value at index {index}")]
    NonFiniteOutput {
        /// The output name.
        output: &'static str,
        /// First offending index (flat).
        index: usize,
    },
    /// The requested runtime is not available in this build or could not be started.
    #[error("runtime `{runtime}` is unavailable: {reason}")]
    RuntimeUnavailable {
        /// The runtime name.
        runtime: &'static str,
        /// Why (feature not compiled in, library not found, ...).
        reason: String,
    },
}
