//! Helpers shared by the multi-process tests.
#![allow(dead_code)]
use iceoryx2::node::NodeView;
use iceoryx2::prelude::*;
use psgrasp_config::PipelineConfig;
use psgrasp_inference::BackendConfig;
use std::path::PathBuf;

/// The directory of the stage binaries built for the tests.
pub fn bin_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_BIN_EXE_psgrasp-grid-fusion"))
        .parent()
        .unwrap()
        .to_path_buf()
}

/// `config/default.toml` as shipped (the learned model in `models/default`), for test `tag`.
pub fn shipped_config(tag: &str) -> PipelineConfig {
    let mut cfg = PipelineConfig::load(&PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/config/default.toml"
    )))
    .unwrap();
    cfg.pipeline.name = format!("t-{tag}-{}", std::process::id());
    cfg.camera.synthetic.objects = 4;
    cfg.camera.rate_hz = 0.0;
    cfg
}

/// The shipped configuration with the analytic backend: the pipeline-mechanics tests need fast,
/// model-independent inference.
pub fn test_config(tag: &str) -> PipelineConfig {
    let mut cfg = shipped_config(tag);
    cfg.cell.inference = BackendConfig::Analytic(Default::default());
    cfg
}

/// Nodes of `pipeline` still registered with iceoryx2 (alive or dead).
pub fn nodes_of(pipeline: &str) -> usize {
    let mut n = 0;
    Node::<ipc::Service>::list(Config::global_config(), |state| {
        let name = match &state {
            NodeState::Alive(v) => v.details().as_ref().map(|d| d.name().as_str().to_string()),
            NodeState::Dead(v) => v.details().as_ref().map(|d| d.name().as_str().to_string()),
            _ => None,
        };
        // `<pipeline>-…`: "stress-123" must not count the nodes of "stress-1234".
        if name.is_some_and(|s| s == pipeline || s.starts_with(&format!("{pipeline}-"))) {
            n += 1;
        }
        CallbackProgression::Continue
    })
    .unwrap();
    n
}
