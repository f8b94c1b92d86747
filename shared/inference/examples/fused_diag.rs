//! Diagnostics: the analytic backend on grids fused from rendered depth of procedural scenes.
//!
//! `cargo run -p psgrasp-inference --example fused_diag -- [seeds] [objects]`
use nalgebra::Point3;
use psgrasp_geometry::{BinModel, GripperModel, Workspace};
use psgrasp_inference::InferenceBackend;
use psgrasp_test_support::grasps::{analytic_backend_in_bin, pick_gripper_points, select_default};
use psgrasp_test_support::scenes::fused_top_down;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let seeds: u64 = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(3);
    let n: usize = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(8);
    let bin = BinModel::default();
    let gripper = GripperModel::default();
    for seed in 0..seeds {
        let scene = psgrasp_sim::procedural_scene(seed, n, &bin).expect("scene");
        let grid = fused_top_down(&scene, &Workspace::default());
        let mut backend = analytic_backend_in_bin(&bin, gripper);
        let t = std::time::Instant::now();
        let configs = backend.infer(&grid.view(), seed).expect("infer");
        let dt = t.elapsed();
        let sel = select_default(&configs, &grid, &bin, &gripper);
        // Deepest penetration of any pick's gripper (grasp + pre-grasp) into the exact objects.
        let mut worst = 0.0f32;
        let mut holds = 0;
        for pick in &sel.picks {
            let tcp = Point3::from(pick.workspace_from_gripper.translation.vector);
            if (0..scene.object_count()).any(|o| scene.object_contains_point(o, &tcp)) {
                holds += 1;
            }
            for p in pick_gripper_points(&gripper, pick, 7) {
                for o in 0..scene.object_count() {
                    if let Some(d) = scene.object_signed_distance(o, &p) {
                        worst = worst.max(-d);
                    }
                }
            }
        }
        println!(
            "seed {seed}: objects {} configs {} picks {} (tcp inside object {holds}) worst penetration {:.1} mm, infer {:.0} ms\n  stats {:?}\n  rejected {:?}",
            scene.object_count(),
            configs.len(),
            sel.picks.len(),
            worst * 1000.0,
            dt.as_secs_f64() * 1e3,
            backend.last_stats(),
            sel.rejected
        );
    }
}
