//! Fuzz target of the evaluation and dataset configuration files (docs/testing.md, "Fuzzing"):
//! arbitrary text parses as a protocol (`psgrasp eval --config`), a detector list
//! (`--detectors-file`) or a dataset configuration (`psgrasp datagen --config`) and validates,
//! or fails with a clean error; never a panic.
use psgrasp_datagen::GenerationConfig;
use psgrasp_eval::{DetectorList, ProtocolConfig};
use psgrasp_fuzz_support::{bolero, Dictionary, Mutated, Target};

#[global_allocator]
static ALLOC: psgrasp_fuzz_support::TrackingAllocator = psgrasp_fuzz_support::TrackingAllocator;

fn target() -> Target {
    Target::new(env!("CARGO_MANIFEST_DIR"), "eval_config")
}

fn parse(bytes: &[u8]) {
    let Ok(text) = std::str::from_utf8(bytes) else {
        return;
    };
    if let Ok(protocol) = toml::from_str::<ProtocolConfig>(text) {
        if protocol.validate().is_ok() {
            assert!(protocol.cell().validate().is_ok());
        }
    }
    if let Ok(list) = DetectorList::from_toml(text) {
        for d in &list.detectors {
            assert!(!d.name.is_empty());
        }
    }
    if let Ok(scenes) = toml::from_str::<GenerationConfig>(text) {
        let _ = scenes.cell.validate();
        let _ = scenes.intrinsics.validate();
    }
}

#[test]
fn eval_config() {
    let t = target();
    bolero::check!(name = t.name).for_each(|bytes: &[u8]| t.run(bytes, parse));
}

#[test]
fn eval_config_mutated() {
    let t = target();
    let seeds = t.seeds();
    let dict = Dictionary::text(&seeds);
    bolero::check!(name = "eval_config_mutated")
        .with_type::<Mutated>()
        .for_each(|m: &Mutated| t.run(&m.apply(&seeds, &dict), parse));
}
