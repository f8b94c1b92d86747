//! The analytic backend on a grid fused from the rendered depth of a procedural scene (a single
//! top-down view), through selection, checked against the exact scene geometry.
use nalgebra::Point3;
use psgrasp_geometry::{BinModel, GripperModel, Workspace};
use psgrasp_inference::InferenceBackend;
use psgrasp_test_support::grasps::{analytic_backend_in_bin, pick_gripper_points};
use psgrasp_test_support::scenes::fused_top_down;

#[test]
fn fused_procedural_scene_yields_collision_free_picks() {
    let bin = BinModel::default();
    let gripper = GripperModel::default();
    // The scene as dropped before the central drop region (released anywhere from above the
    // rim): on scene 0 dropped the new way, 8 objects pile up so tightly that one pick's finger
    // meets an object hidden under another by 7.6 mm (what a single top-down view cannot see;
    // the evaluation's simulated pre-grasp check is there for that).
    let library = psgrasp_sim::ObjectLibrary::procedural();
    let recipe = psgrasp_sim::SceneRecipe {
        min_objects: 8,
        max_objects: 8,
        settle: psgrasp_sim::SettleConfig {
            drop_region_fraction: 1.0,
            release_height_m: 0.29,
            ..Default::default()
        },
        ..Default::default()
    };
    let (scene, _) = psgrasp_sim::generate_scene(
        0,
        &library.select(None, false),
        &bin,
        &psgrasp_sim::MeshLibrary::default(),
        &recipe,
    )
    .unwrap();
    assert_eq!(scene.object_count(), 8);
    let grid = fused_top_down(&scene, &Workspace::default());
    let mut backend = analytic_backend_in_bin(&bin, gripper);
    let configs = backend.infer(&grid.view(), 0).unwrap();
    let stats = backend.last_stats();
    // Before tilted side-face normals were straightened this scene gave no configuration at all.
    assert!(
        configs.len() >= 15,
        "{} configurations: {stats:?}",
        configs.len()
    );
    // Every pick is checked below, so no spacing: the dropped pile lies within a few
    // centimetres (with the default 5 cm spacing it gives 1 pick; the spread is tested in
    // `analytic_to_picks.rs`).
    let cfg = psgrasp_selection::SelectionConfig {
        pick_spacing_m: 0.0,
        ..Default::default()
    };
    let sel = psgrasp_selection::select(&configs, &grid.view(), &bin, &gripper, &cfg).unwrap();
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
        for p in pick_gripper_points(&gripper, pick, 7) {
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
    // The fingers close on an object for most picks.
    assert!(
        2 * holding > sel.picks.len(),
        "{holding} of {} picks hold an object",
        sel.picks.len()
    );
}
