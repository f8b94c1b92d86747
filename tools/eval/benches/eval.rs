//! `cargo bench -p psgrasp-eval`: milliseconds per grasp attempt (physics only) on a lone box and
//! in settled clutter, and seconds per clearing round with the analytic detector.
use nalgebra::{Point3, Vector3};
use psgrasp_datagen::Difficulty;
use psgrasp_eval::{
    execute_grasp, run_scene_with, DetectorSpec, ExecutionConfig, GraspCommand, ProtocolConfig,
};
use psgrasp_geometry::{BinModel, GripperModel};
use psgrasp_sim::{MeshLibrary, ObjectLibrary, Scene};
use psgrasp_test_support::grasps::top_down_pose;
use psgrasp_test_support::scenes::boxes_on_floor;
use std::time::Instant;

fn top_down_at(p: Vector3<f32>, opening_m: f32) -> GraspCommand {
    GraspCommand {
        workspace_from_gripper: top_down_pose(Point3::from(p)),
        opening_m,
        pregrasp_distance_m: 0.08,
    }
}

fn time_attempts(label: &str, scene: &Scene, cmds: &[GraspCommand], reps: usize) {
    let meshes = MeshLibrary::default();
    let gripper = GripperModel::default();
    let cfg = ExecutionConfig::default();
    let mut times = Vec::new();
    let mut steps = 0;
    for _ in 0..reps {
        for c in cmds {
            let t = Instant::now();
            let ex = execute_grasp(scene, &meshes, &gripper, c, &cfg).expect("execution runs");
            times.push(t.elapsed().as_secs_f64() * 1e3);
            steps += ex.report.steps;
        }
    }
    times.sort_by(f64::total_cmp);
    let mean = times.iter().sum::<f64>() / times.len() as f64;
    println!(
        "| {label} | {} | {:.1} | {:.1} | {:.1} | {:.0} |",
        times.len(),
        times[0],
        times[times.len() / 2],
        mean,
        steps as f64 / times.len() as f64
    );
}

fn main() {
    println!("## Grasp execution (physics only, one thread)\n");
    println!("| scene | attempts | min ms | median ms | mean ms | steps/attempt |");
    println!("|---|---|---|---|---|---|");
    let bin = BinModel::default();
    let c = bin.floor_center;
    let lone = boxes_on_floor(&[([0.02, 0.03, 0.025], [0.0, 0.0])]);
    time_attempts(
        "1 box, successful grasp",
        &lone,
        &[top_down_at(Vector3::new(c.x, c.y, c.z + 0.025), 0.06)],
        10,
    );
    for n in [15usize, 35] {
        let scene = psgrasp_sim::procedural_scene(7, n, &bin).expect("scene");
        // Straight-down grasps at each object's centre: a mix of successes and failures.
        let cmds: Vec<GraspCommand> = scene
            .objects()
            .iter()
            .map(|o| top_down_at(o.workspace_from_object.translation.vector, 0.07))
            .collect();
        time_attempts(
            &format!("{} settled objects, top-down at each", scene.object_count()),
            &scene,
            &cmds,
            1,
        );
    }

    println!("\n## Clearing rounds (analytic detector, release build, one thread)\n");
    println!("| level | scenes | objects | attempts | s/scene | ms/attempt (all) | detection ms/frame | physics ms/attempt |");
    println!("|---|---|---|---|---|---|---|---|");
    let library = ObjectLibrary::procedural();
    let meshes = MeshLibrary::default();
    let proto = ProtocolConfig::default();
    let detector = DetectorSpec::analytic();
    for (level, scenes) in [
        (Difficulty::Easy, 3u64),
        (Difficulty::Medium, 2),
        (Difficulty::Challenging, 1),
    ] {
        let mut backend = detector.build(&proto).expect("backend");
        let (mut objects, mut attempts, mut det_ms, mut frames, mut phys_ms) =
            (0usize, 0usize, 0.0, 0usize, 0.0);
        let t = Instant::now();
        for i in 0..scenes {
            let r = run_scene_with(
                level,
                0,
                i,
                &library,
                &meshes,
                backend.as_detector(),
                &proto,
            )
            .expect("scene runs");
            objects += r.summary.objects;
            attempts += r.attempts.len();
            frames += r.summary.frames as usize;
            det_ms += r.summary.detection_ms;
            phys_ms += r.attempts.iter().map(|a| a.execution_ms).sum::<f64>();
        }
        let s = t.elapsed().as_secs_f64();
        println!(
            "| {level:?} | {scenes} | {objects} | {attempts} | {:.1} | {:.0} | {:.0} | {:.0} |",
            s / scenes as f64,
            1e3 * s / attempts.max(1) as f64,
            det_ms / frames.max(1) as f64,
            phys_ms / attempts.max(1) as f64,
        );
    }
}
