//! Fuzz target of the pipeline configuration (docs/testing.md, "Fuzzing"): arbitrary text parses
//! and validates, or fails with a clean error; never a panic. A configuration that passes is
//! also what `psgrasp check-config` prints: its TOML parses back to the same configuration.
use psgrasp_config::PipelineConfig;
use psgrasp_fuzz_support::{bolero, Dictionary, Mutated, Target};
use std::path::Path;

#[global_allocator]
static ALLOC: psgrasp_fuzz_support::TrackingAllocator = psgrasp_fuzz_support::TrackingAllocator;

fn target() -> Target {
    Target::new(env!("CARGO_MANIFEST_DIR"), "pipeline_config")
}

fn parse(bytes: &[u8]) {
    let Ok(text) = std::str::from_utf8(bytes) else {
        return;
    };
    let origin = Path::new("<fuzz>");
    if let Ok(cfg) = PipelineConfig::parse(text, origin) {
        let written = cfg.to_toml();
        let back = PipelineConfig::parse(&written, origin)
            .unwrap_or_else(|e| panic!("check-config's output does not load: {e}\n{written}"));
        assert_eq!(
            back, cfg,
            "check-config's output loads differently:\n{written}"
        );
        let camera = cfg.camera_model();
        assert!(camera.validate().is_ok(), "{camera:?}");
    }
}

#[test]
fn pipeline_config() {
    let t = target();
    bolero::check!(name = t.name).for_each(|bytes: &[u8]| t.run(bytes, parse));
}

#[test]
fn pipeline_config_mutated() {
    let t = target();
    let seeds = t.seeds();
    let dict = Dictionary::text(&seeds);
    bolero::check!(name = "pipeline_config_mutated")
        .with_type::<Mutated>()
        .for_each(|m: &Mutated| t.run(&m.apply(&seeds, &dict), parse));
}
