//! Issue 17: the gripper file is the single source of the hand. Label generation, grasp
//! selection and grasp execution all take the hand of the protocol's `[gripper] model`, so the
//! fingertip depth they work with is the file's, and changing the file changes all three.
use nalgebra::{Point3, Vector3};
use psgrasp_datagen::{generate_labels, LabelConfig};
use psgrasp_eval::{hand_collides, ProtocolConfig};
use psgrasp_geometry::grippers::named;
use psgrasp_geometry::{BinModel, CameraIntrinsics, GraspConfiguration, N_APPROACHES};
use psgrasp_selection::{GraspChecker, RejectionReason, SelectionConfig};
use psgrasp_sim::{
    default_camera, procedural_scene, ObjectKind, Primitive, Scene, SceneDescription,
};
use psgrasp_test_support::scenes::{on_floor, single_part};

fn protocol(model: &str) -> ProtocolConfig {
    toml::from_str(&format!("[gripper]\nmodel = \"{model}\"\n")).unwrap()
}

/// A 40 mm cube on the bin floor.
fn low_box() -> Scene {
    let bin = BinModel::default();
    let spec = single_part(
        "low-box",
        ObjectKind::Box,
        Primitive::Cuboid {
            half_extents: [0.02; 3],
        },
    );
    let objects = vec![on_floor(&bin, spec, [0.0, 0.0], 0.02)];
    Scene::new(SceneDescription { bin, objects }).unwrap()
}

/// A grasp straight down (approach 8 of a horizontal baseline is within 6° of vertical) whose
/// TCP lies `height_m` above the bin floor, in the middle of an empty bin.
fn top_down_at(bin: &BinModel, height_m: f32) -> GraspConfiguration {
    GraspConfiguration {
        contact: Point3::new(
            bin.floor_center.x - 0.02,
            bin.floor_center.y,
            bin.floor_center.z + height_m,
        ),
        baseline: Vector3::x(),
        collision_scores: [1.0; N_APPROACHES],
        width: 0.04,
        quality: 1.0,
        kappa: 0.0,
        kappa_floor: 0.0,
    }
}

/// Lowest TCP height above the floor among the labels whose top-down approach is free.
fn lowest_free_top_down_tcp(scene: &Scene, p: &ProtocolConfig) -> f32 {
    let camera = default_camera(scene.bin(), CameraIntrinsics::default_640x480());
    let rendering = scene.render(&camera);
    let labels = generate_labels(
        scene,
        &camera,
        &rendering,
        &p.cell().gripper,
        &LabelConfig::default(),
        3,
    )
    .labels;
    labels
        .iter()
        .filter(|l| l.baseline.z.abs() < 0.05 && (l.collision_free[8] || l.collision_free[9]))
        .map(|l| {
            let tcp = l.contact + l.baseline * (0.5 * l.width);
            tcp.z - scene.bin().floor_center.z
        })
        .fold(f32::INFINITY, f32::min)
}

#[test]
fn the_gripper_file_sets_the_fingertip_depth_of_labels_selection_and_execution() {
    let real = protocol("franka");
    let old = protocol("franka-15mm");
    assert_eq!(real.cell().gripper, named("franka").unwrap());
    assert_eq!(old.cell().gripper, named("franka-15mm").unwrap());
    let (real_tip, old_tip) = (0.0095, 0.015);
    assert_eq!(real.cell().gripper.tip_beyond_tcp_m, real_tip);

    // Labels: no free top-down label puts the fingertips into the floor, and the real hand's
    // shorter reach finds grasps lower on the box than the 15 mm model allows.
    let scene = low_box();
    let low_real = lowest_free_top_down_tcp(&scene, &real);
    let low_old = lowest_free_top_down_tcp(&scene, &old);
    assert!(low_real >= real_tip - 1e-4, "{low_real}");
    assert!(low_old >= old_tip - 1e-4, "{low_old}");
    assert!(low_real < old_tip, "real hand lowest TCP {low_real}");

    // Selection and execution: a grasp from (nearly) straight down with its TCP 14.5 mm above
    // the floor reaches into the floor with the 15 mm fingertips and clears it, by more than
    // selection's 3 mm bin margin, with the real hand's 9.5 mm.
    let bin = *scene.bin();
    let empty = Scene::new(SceneDescription {
        bin,
        objects: vec![],
    })
    .unwrap();
    let grasp = top_down_at(&bin, 0.0145);
    let pose = grasp.grasp(8).workspace_from_gripper();
    let cfg = SelectionConfig::default();
    for (p, floor_hit) in [(&real, false), (&old, true)] {
        let gripper = p.cell().gripper;
        let checker = GraspChecker::new(&cfg, gripper, bin, None).unwrap();
        let selected = checker.check_approach(&grasp, 0, 8);
        assert_eq!(
            selected.err(),
            floor_hit.then_some(RejectionReason::BinCollision),
            "selection, tip {}",
            gripper.tip_beyond_tcp_m
        );
        assert_eq!(
            hand_collides(&empty, &gripper, &pose, grasp.width + 0.02, 0.0),
            floor_hit,
            "execution, tip {}",
            gripper.tip_beyond_tcp_m
        );
    }
}

#[test]
fn robotiq_labels_differ_from_franka_labels_on_the_same_scene() {
    let bin = BinModel::default();
    let scene = procedural_scene(11, 8, &bin).unwrap();
    let camera = default_camera(scene.bin(), CameraIntrinsics::default_640x480());
    let rendering = scene.render(&camera);
    let labels_of = |model: &str| {
        let gripper = protocol(model).cell().gripper;
        let labels = generate_labels(
            &scene,
            &camera,
            &rendering,
            &gripper,
            &LabelConfig::quick(),
            5,
        )
        .labels;
        for l in &labels {
            assert!(
                l.width <= gripper.max_opening_m,
                "{model}: width {}",
                l.width
            );
        }
        labels
    };
    let franka = labels_of("franka");
    let robotiq = labels_of("robotiq-2f85");
    assert!(!franka.is_empty() && !robotiq.is_empty());
    assert_ne!(franka, robotiq);
    let free =
        |v: &[psgrasp_datagen::GraspLabel]| -> usize { v.iter().map(|l| l.free_count()).sum() };
    assert_ne!(free(&franka), free(&robotiq));
}
