//! Diagnostics: the analytic backend on grids fused from rendered depth of procedural scenes.
//!
//! `cargo run -p psgrasp-inference --example fused_diag -- [seeds] [objects]`
use nalgebra::Point3;
use psgrasp_fusion::{fuse_normal_grid, FusionConfig};
use psgrasp_geometry::{BinModel, CameraIntrinsics, CameraModel, GripperModel, Workspace};
use psgrasp_inference::{AnalyticBackend, AnalyticConfig, ContactRegion, InferenceBackend};
use psgrasp_selection::{select, SelectionConfig};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let seeds: u64 = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(3);
    let n: usize = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(8);
    let bin = BinModel::default();
    let gripper = GripperModel::default();
    for seed in 0..seeds {
        let scene = psgrasp_sim::procedural_scene(seed, n, &bin).expect("scene");
        let camera = CameraModel::top_down(
            CameraIntrinsics::default_640x480(),
            Point3::new(0.288, 0.288, 0.018 + 0.28 + 0.6),
        );
        let depth = scene.render_depth(&camera);
        let grid = fuse_normal_grid(
            &depth,
            &camera,
            &Workspace::default(),
            &FusionConfig::default(),
        )
        .expect("fusion");
        let cfg = AnalyticConfig {
            contact_region: Some(ContactRegion::inside_bin(&bin, 0.005)),
            ..AnalyticConfig::default()
        };
        let mut backend = AnalyticBackend::new(cfg, gripper).expect("backend");
        let t = std::time::Instant::now();
        let configs = backend.infer(&grid.view(), seed).expect("infer");
        let dt = t.elapsed();
        let sel = select(
            &configs,
            &grid.view(),
            &bin,
            &gripper,
            &SelectionConfig::default(),
        )
        .expect("select");
        // Deepest penetration of any pick's gripper (grasp + pre-grasp) into the exact objects.
        let mut worst = 0.0f32;
        let mut holds = 0;
        for pick in &sel.picks {
            let tcp = Point3::from(pick.workspace_from_gripper.translation.vector);
            if (0..scene.object_count()).any(|o| scene.object_contains_point(o, &tcp)) {
                holds += 1;
            }
            for pose in [pick.workspace_from_gripper, pick.pregrasp] {
                for b in gripper.boxes(&pose, pick.opening_m) {
                    for i in 0..7 * 7 * 7 {
                        let f = |v: usize| v as f32 / 3.0 - 1.0;
                        let local = Point3::new(
                            f(i % 7) * b.half_extents.x,
                            f((i / 7) % 7) * b.half_extents.y,
                            f(i / 49) * b.half_extents.z,
                        );
                        let p = b.parent_from_box * local;
                        for o in 0..scene.object_count() {
                            if let Some(d) = scene.object_signed_distance(o, &p) {
                                worst = worst.max(-d);
                            }
                        }
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
