//! Follows narrow label grasps (the oracle's typical miss) step by step: executes the labeler's
//! collision-free grasps under a width limit on random-URDF objects of test-set scenes with a
//! trace, and reports for each failure when the target object lost the fingers and how it moved
//! in the gripper frame (x = closing axis, y = along the pads, z = approach) while closing and
//! while lifting. Pre-grasp collisions and approach touches are left out.
//! `cargo run --release -p psgrasp-eval --example narrow_trace -- [LEVEL] [SCENES] [MAX_WIDTH_MM] [PER_SCENE]`
mod common;

use nalgebra::{Isometry3, Vector3};
use psgrasp_datagen::Difficulty;
use psgrasp_eval::{execute_grasp_traced, GraspOutcome, Phase, TraceSample};

/// The target's offset from the palm and its rotation angle from the first sample (gripper frame).
fn relative(s: &TraceSample, target: usize, first: &Isometry3<f32>) -> (Vector3<f32>, f32) {
    let palm_from_object = s.workspace_from_palm.inverse() * s.workspace_from_objects[target];
    let turned = (first.rotation.inverse() * palm_from_object.rotation)
        .angle()
        .to_degrees();
    (palm_from_object.translation.vector * 1e3, turned)
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let level = common::level_arg(args.get(1), Difficulty::Challenging);
    let scenes: u64 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(3);
    let max_width = args
        .get(3)
        .and_then(|s| s.parse::<f32>().ok())
        .unwrap_or(20.0)
        * 1e-3;
    let per_scene: usize = args.get(4).and_then(|s| s.parse().ok()).unwrap_or(10);
    let (cfg, set) = common::benchmark();
    let gripper = cfg.scenes.cell.gripper;
    let mut tally = std::collections::BTreeMap::new();
    for i in 0..scenes {
        let (scene, labels) = common::labelled_scene(&cfg, &set, level, i);
        let narrow = |l: &psgrasp_datagen::GraspLabel| {
            l.width < max_width
                && scene.objects()[l.object as usize]
                    .spec
                    .name
                    .starts_with("random")
        };
        for (k, a) in common::spread_free_grasps(&labels, narrow, per_scene) {
            let l = &labels[k];
            let target = l.object as usize;
            let cmd = common::label_command(&cfg, l, a);
            let mut samples: Vec<TraceSample> = Vec::new();
            let mut keep = |s: &TraceSample| samples.push(s.clone());
            let ex = execute_grasp_traced(
                &scene,
                &set.meshes,
                &gripper,
                &cmd,
                &cfg.execution,
                Some(&mut keep),
            )
            .unwrap();
            let outcome = ex.report.outcome;
            if matches!(
                outcome,
                GraspOutcome::PregraspCollision | GraspOutcome::ApproachContact
            ) {
                continue;
            }
            let phase_start = |p: Phase| samples.iter().position(|s| s.phase == p);
            let (Some(close), Some(lift)) = (phase_start(Phase::Close), phase_start(Phase::Lift))
            else {
                continue;
            };
            let first = samples[close].workspace_from_palm.inverse()
                * samples[close].workspace_from_objects[target];
            let (p0, _) = relative(&samples[close], target, &first);
            let (p1, r1) = relative(&samples[lift - 1], target, &first);
            let (p2, r2) = relative(samples.last().unwrap(), target, &first);
            let both = |s: &TraceSample| s.finger_touches.iter().all(|f| f.contains(&target));
            let ever_both = samples[close..lift].iter().any(both);
            let held_at_lift = both(&samples[lift - 1]);
            // The first step after which the target no longer touches both fingers for good.
            let lost_at = samples
                .iter()
                .rposition(both)
                .and_then(|k| samples.get(k + 1))
                .map(|s| s.phase);
            let kind = if outcome == GraspOutcome::Success {
                "success".to_string()
            } else if !ever_both {
                "never held by both pads while closing".to_string()
            } else if !held_at_lift {
                "held, then lost while closing".to_string()
            } else {
                format!("held at lift, lost during {:?}", lost_at)
            };
            *tally.entry(kind.clone()).or_insert(0usize) += 1;
            let d_close = p1 - p0;
            let d_lift = p2 - p1;
            println!(
                "scene {i} label {k} w {:4.1} mm {:?}: {kind}; close moved it ({:+5.1}, {:+5.1}, {:+5.1}) mm, turned {:4.1}°; \
                 lift+hold ({:+5.1}, {:+5.1}, {:+5.1}) mm, turned {:4.1}°; opening {:4.1} → {:4.1} mm",
                l.width * 1e3,
                outcome,
                d_close.x, d_close.y, d_close.z, r1,
                d_lift.x, d_lift.y, d_lift.z, r2 - r1,
                samples[lift - 1].opening_m * 1e3,
                samples.last().unwrap().opening_m * 1e3,
            );
        }
    }
    println!(
        "summary (narrow grasps under {:.0} mm on random-URDF objects):",
        max_width * 1e3
    );
    for (k, v) in tally {
        println!("  {v:4}  {k}");
    }
}
