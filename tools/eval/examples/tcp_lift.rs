//! How many objects of the test set's scenes gain a collision-free grasp pose when the tool
//! centre point may sit higher than the contacts (the contacts then meet the pads below their
//! centre: the Franka pad is 18.5 mm long, so up to ≈ 9 mm still puts the pad on the contact).
//! Graspability verdicts at each lift, and the objects that turn graspable, by their verdict at 0.
//! `cargo run --release -p psgrasp-eval --example tcp_lift -- [LEVEL] [SCENES] [LIFTS_MM] [CANDIDATES]`
//! (LIFTS_MM comma-separated, default `0,3,6,9`; CANDIDATES first contacts per object, default
//! the evaluation's 128).
#[allow(dead_code)]
mod common;

use psgrasp_datagen::graspability::{graspability, visible_pixels_per_object};
use psgrasp_datagen::{Difficulty, GraspabilityConfig, GraspabilityVerdict, LabelConfig};
use std::collections::BTreeMap;

fn main() {
    let (cfg, set) = common::benchmark();
    let args: Vec<String> = std::env::args().collect();
    let level = common::level_arg(args.get(1), Difficulty::Challenging);
    let scenes: u64 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(5);
    let lifts_mm: Vec<f32> = args
        .get(3)
        .map(|s| s.split(',').filter_map(|v| v.trim().parse().ok()).collect())
        .unwrap_or_else(|| vec![0.0, 3.0, 6.0, 9.0]);
    let candidates: u32 = args
        .get(4)
        .and_then(|s| s.parse().ok())
        .unwrap_or(GraspabilityConfig::default().candidates_per_object);
    let gripper = cfg.scenes.cell.gripper;
    // verdicts[lift][verdict] and, per lift, objects turned graspable by their verdict at lift 0.
    let mut verdicts: Vec<BTreeMap<&'static str, usize>> = vec![BTreeMap::new(); lifts_mm.len()];
    let mut gained: Vec<BTreeMap<&'static str, usize>> = vec![BTreeMap::new(); lifts_mm.len()];
    let mut objects = 0usize;
    for index in 0..scenes {
        let scene = set.scene(level, index).unwrap();
        let camera = psgrasp_sim::default_camera(scene.bin(), cfg.scenes.intrinsics);
        let pixels =
            visible_pixels_per_object(&scene.render(&camera).segmentation, scene.object_count());
        for (object, &visible) in pixels.iter().enumerate() {
            objects += 1;
            let mut at_zero = GraspabilityVerdict::Graspable;
            for (k, lift) in lifts_mm.iter().enumerate() {
                let check = GraspabilityConfig {
                    candidates_per_object: candidates,
                };
                let labels = LabelConfig {
                    tcp_lifts_m: if *lift > 0.0 {
                        vec![lift * 1e-3]
                    } else {
                        Vec::new()
                    },
                    ..cfg.scenes.labels.clone()
                };
                let g = graspability(&scene, &gripper, &labels, object, visible, &check, 7);
                if k == 0 {
                    at_zero = g.verdict;
                }
                *verdicts[k].entry(g.verdict.name()).or_default() += 1;
                if g.verdict == GraspabilityVerdict::Graspable
                    && at_zero != GraspabilityVerdict::Graspable
                {
                    *gained[k].entry(at_zero.name()).or_default() += 1;
                }
            }
        }
    }
    println!(
        "{level:?}, {scenes} scenes as they start, {objects} objects, {candidates} first contacts each"
    );
    for (k, lift) in lifts_mm.iter().enumerate() {
        println!(
            "lift {lift:4.1} mm: {:?}; turned graspable (by verdict at {:.1} mm): {:?}",
            verdicts[k], lifts_mm[0], gained[k]
        );
    }
}
