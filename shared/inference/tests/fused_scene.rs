//! The analytic backend on a grid fused from the rendered depth of a procedural scene (a single
//! top-down view), through selection, checked against the exact scene geometry.
use nalgebra::Point3;
use psgrasp_fusion::{fuse_normal_grid, FusionConfig};
use psgrasp_geometry::{BinModel, CameraIntrinsics, CameraModel, GripperModel, Workspace};
use psgrasp_inference::{AnalyticBackend, AnalyticConfig, ContactRegion, InferenceBackend};
use psgrasp_selection::{select, SelectionConfig};

#[test]
fn fused_procedural_scene_yields_collision_free_picks() {
    let bin = BinModel::default();
    let gripper = GripperModel::default();
    let scene = psgrasp_sim::procedural_scene(0, 8, &bin).unwrap();
    assert_eq!(scene.object_count(), 8);
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
    .unwrap();
    let cfg = AnalyticConfig {
        contact_region: Some(ContactRegion::inside_bin(&bin, 0.005)),
        ..AnalyticConfig::default()
    };
    let mut backend = AnalyticBackend::new(cfg, gripper).unwrap();
    let configs = backend.infer(&grid.view(), 0).unwrap();
    let stats = backend.last_stats();
    // Before tilted side-face normals were straightened this scene gave no configuration at all.
    assert!(
        configs.len() >= 15,
        "{} configurations: {stats:?}",
        configs.len()
    );
    let sel = select(
        &configs,
        &grid.view(),
        &bin,
        &gripper,
        &SelectionConfig::default(),
    )
    .unwrap();
    assert!(
        sel.picks.len() >= 5,
        "{} picks: {:?}",
        sel.picks.len(),
        sel.rejected
    );

    let inside_any =
        |p: &Point3<f32>| (0..scene.object_count()).any(|o| scene.object_contains_point(o, p));
    let mut holding = 0;
    for pick in &sel.picks {
        let tcp = Point3::from(pick.workspace_from_gripper.translation.vector);
        holding += usize::from(inside_any(&tcp));
        // No sample of the gripper (grasp and pre-grasp poses) lies deeper than 5 mm inside an
        // object of the exact scene.
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
                        let d = scene.object_signed_distance(o, &p).unwrap();
                        assert!(
                            d > -0.005,
                            "gripper point {p:?} is {} m inside object {o}",
                            -d
                        );
                    }
                }
            }
        }
    }
    // The fingers close on an object for most picks.
    assert!(
        2 * holding > sel.picks.len(),
        "{holding} of {} picks hold an object",
        sel.picks.len()
    );
}
