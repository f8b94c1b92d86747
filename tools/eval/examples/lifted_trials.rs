//! Do grasps that only clear the scene with the tool centre point raised hold in physics?
//! Labels the test set's scenes twice (contacts at the tool centre point, and with the tool
//! centre point raised LIFT_MM back along the approach), then executes an evenly spread sample of
//! (a) the approaches free without the lift, as labelled today, and (b) the approaches free only
//! with the lift, executed raised; prints the outcomes of both.
//! `cargo run --release -p psgrasp-eval --example lifted_trials -- [LEVEL] [SCENES] [GRASPS_PER_SCENE] [LIFT_MM]`
mod common;

use psgrasp_datagen::labels::{check_pose, generate_labels, PoseCheck};
use psgrasp_datagen::{Difficulty, LabelConfig};
use psgrasp_eval::{execute_grasp, GraspCommand, GraspOutcome};
use std::collections::BTreeMap;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let level = common::level_arg(args.get(1), Difficulty::Medium);
    let scenes: u64 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(5);
    let per_scene: usize = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(20);
    let lift_m = args
        .get(4)
        .and_then(|s| s.parse::<f32>().ok())
        .unwrap_or(9.0)
        * 1e-3;
    let (cfg, set) = common::benchmark();
    let gripper = cfg.scenes.cell.gripper;
    let lifted_config = LabelConfig {
        tcp_lifts_m: vec![lift_m],
        ..cfg.scenes.labels.clone()
    };
    // outcomes[class][outcome]: class 0 = free without the lift, 1 = free only lifted.
    let mut outcomes: [BTreeMap<String, usize>; 2] = [BTreeMap::new(), BTreeMap::new()];
    let mut only_lifted_total = 0usize;
    for i in 0..scenes {
        let (scene, labels) = common::labelled_scene(&cfg, &set, level, i);
        let camera = psgrasp_sim::default_camera(scene.bin(), cfg.scenes.intrinsics);
        let rendering = scene.render(&camera);
        let lifted =
            generate_labels(&scene, &camera, &rendering, &gripper, &lifted_config, i).labels;
        // Approaches free at the lift that the unlifted pose test refuses.
        let only_lifted: Vec<(usize, usize)> = common::free_grasps(&lifted)
            .filter(|&(k, a)| {
                let l = &lifted[k];
                check_pose(
                    &scene,
                    &gripper,
                    &l.grasp(a),
                    l.object as usize,
                    &cfg.scenes.labels,
                ) != PoseCheck::Free
            })
            .collect();
        only_lifted_total += only_lifted.len();
        for (k, a) in common::spread(&only_lifted, per_scene) {
            let l = &lifted[k];
            let cmd = GraspCommand {
                workspace_from_gripper: l.grasp(a).workspace_from_gripper_lifted(lift_m),
                opening_m: gripper.max_opening_m,
                pregrasp_distance_m: cfg.cell().selection.clearance.pregrasp_distance_m,
            };
            let ex = execute_grasp(&scene, &set.meshes, &gripper, &cmd, &cfg.execution).unwrap();
            *outcomes[1]
                .entry(format!("{:?}", ex.report.outcome))
                .or_default() += 1;
        }
        for (k, a) in common::spread_free_grasps(&labels, |_| true, per_scene) {
            let cmd = common::label_command(&cfg, &labels[k], a);
            let ex = execute_grasp(&scene, &set.meshes, &gripper, &cmd, &cfg.execution).unwrap();
            *outcomes[0]
                .entry(format!("{:?}", ex.report.outcome))
                .or_default() += 1;
        }
        eprintln!(
            "scene {i}: {} labels, {} lifted labels, {} approaches free only lifted",
            labels.len(),
            lifted.len(),
            only_lifted.len()
        );
    }
    println!(
        "{level:?}, {scenes} scenes, lift {:.1} mm; {only_lifted_total} approaches free only lifted",
        lift_m * 1e3
    );
    for (name, o) in ["free without the lift", "free only lifted"]
        .iter()
        .zip(&outcomes)
    {
        let tried: usize = o
            .iter()
            .filter(|(k, _)| k.as_str() != format!("{:?}", GraspOutcome::PregraspCollision))
            .map(|(_, n)| n)
            .sum();
        let ok = o
            .get(&format!("{:?}", GraspOutcome::Success))
            .copied()
            .unwrap_or(0);
        println!(
            "  {name}: success {ok} / {tried} = {:.1} % (pre-grasp collisions left out); {o:?}",
            100.0 * ok as f64 / tried.max(1) as f64
        );
    }
}
