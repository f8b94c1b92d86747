//! The psgrasp processes. The folders read as the data flow: `camera-ingest` → `grid-fusion` →
//! `inference` → `grasp-selection`, each a thin `main.rs` and a `stage.rs` that supplies only its
//! step to the one stage driver ([`stage::run_stage`]); the next-pick server and client sit
//! side by side in `next-pick`. The perception itself is `psgrasp-perception`'s chain, which the
//! stages call one step per process. The launcher/supervisor, monitor, demo and stress tools are
//! used by the `psgrasp` CLI (`services/cli/main.rs`).
#![warn(missing_docs)]

#[path = "camera-ingest/stage.rs"]
pub mod camera_ingest;
pub mod controller;
pub mod detect;
#[path = "grasp-selection/stage.rs"]
pub mod grasp_selection;
#[path = "grid-fusion/stage.rs"]
pub mod grid_fusion;
pub mod http;
#[path = "inference/stage.rs"]
pub mod inference;
pub mod launcher;
pub mod metrics;
pub mod monitor;
#[path = "next-pick/mod.rs"]
pub mod next_pick;
pub mod pick_json;
pub mod run;
#[path = "camera-ingest/sources.rs"]
pub mod sources;
pub mod stage;
pub mod stress;
