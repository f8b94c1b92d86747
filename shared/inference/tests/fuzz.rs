//! Fuzz target of the model cards (docs/testing.md, "Fuzzing"): arbitrary text parses as a
//! learned or VGN card and is checked against the pipeline, or fails with a clean
//! [`ModelError`](psgrasp_inference::ModelError); never a panic.
use psgrasp_fuzz_support::{bolero, Dictionary, Mutated, Target};
use psgrasp_geometry::{GripperModel, Workspace};
use psgrasp_inference::{ModelCard, VgnCard};
use std::path::Path;

#[global_allocator]
static ALLOC: psgrasp_fuzz_support::TrackingAllocator = psgrasp_fuzz_support::TrackingAllocator;

fn target() -> Target {
    Target::new(env!("CARGO_MANIFEST_DIR"), "model_card")
}

fn check_cards(bytes: &[u8]) {
    let Ok(text) = std::str::from_utf8(bytes) else {
        return;
    };
    let path = Path::new("card.json");
    let (workspace, gripper) = (Workspace::default(), GripperModel::default());
    if let Ok(card) = ModelCard::from_json(text, path) {
        if card.validate().is_ok() {
            let _ = card.check_pipeline(&workspace, &gripper);
            assert!(card.workspace().validate().is_ok());
            for l in 0..card.levels() {
                assert!(card.level_dims(l).iter().all(|&d| d > 0), "{card:?}");
            }
            assert_eq!(
                card.feature_dim() as u64,
                card.unet
                    .channels
                    .iter()
                    .map(|&c| u64::from(c))
                    .sum::<u64>()
            );
        }
    }
    if let Ok(card) = VgnCard::from_json(text, path) {
        if card.validate().is_ok() {
            let _ = card.check_workspace(&workspace);
            let _ = card.check_gripper(&gripper);
            assert!(card.workspace().validate().is_ok());
        }
    }
}

#[test]
fn model_card() {
    let t = target();
    bolero::check!(name = t.name).for_each(|bytes: &[u8]| t.run(bytes, check_cards));
}

#[test]
fn model_card_mutated() {
    let t = target();
    let seeds = t.seeds();
    let dict = Dictionary::text(&seeds);
    bolero::check!(name = "model_card_mutated")
        .with_type::<Mutated>()
        .for_each(|m: &Mutated| t.run(&m.apply(&seeds, &dict), check_cards));
}
