//! The psgrasp processes: stage runtime, depth sources, launcher/supervisor, demo and stress
//! tools. The stage binaries under `services/<stage>/main.rs` are thin wrappers around
//! [`stages`]; the `psgrasp` CLI (`services/cli/main.rs`) drives everything else.
#![warn(missing_docs)]

pub mod client;
pub mod launcher;
pub mod runtime;
pub mod sources;
pub mod stages;
pub mod stress;
