//! The graspability verdict of every object of a few test-set scenes (as they start, before any
//! pick), with the time the diagnosis takes per object: what `psgrasp eval` records for the
//! objects a round leaves.
//! `cargo run --release -p psgrasp-eval --example graspability -- [LEVEL] [SCENES]`
// The label helpers of `common` serve the other examples.
#[allow(dead_code)]
mod common;

use psgrasp_datagen::Difficulty;
use psgrasp_eval::leftovers::remaining_objects;
use psgrasp_eval::RemainingObject;
use std::collections::BTreeMap;
use std::time::Instant;

fn main() {
    let (cfg, set) = common::benchmark();
    let args: Vec<String> = std::env::args().collect();
    let level = common::level_arg(args.get(1), Difficulty::Challenging);
    let scenes: u64 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(3);
    let mut verdicts: BTreeMap<String, usize> = BTreeMap::new();
    let (mut objects, mut seconds) = (0usize, 0.0f64);
    for index in 0..scenes {
        let scene = set.scene(level, index).unwrap();
        let camera = psgrasp_sim::default_camera(scene.bin(), cfg.scenes.intrinsics);
        let start = RemainingObject::with_start_zones(&scene);
        let t = Instant::now();
        let all = remaining_objects(&scene, &camera, &start, &cfg);
        seconds += t.elapsed().as_secs_f64();
        objects += all.len();
        for o in &all {
            let g = o.graspability.expect("diagnosed");
            *verdicts.entry(g.verdict.name().to_string()).or_default() += 1;
        }
    }
    println!("{level:?}, {scenes} scenes, {objects} objects at the start");
    for (v, n) in &verdicts {
        println!("  {v}: {n}");
    }
    println!(
        "diagnosis: {:.1} ms per object ({:.2} s per scene)",
        1e3 * seconds / objects.max(1) as f64,
        seconds / scenes.max(1) as f64
    );
}
