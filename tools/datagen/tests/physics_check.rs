//! The labels' physics check (ACRONYM's) on analytic scenes: labels that hold stay, grasps that
//! cannot hold are dropped (or kept with quality 0) and counted, a label and its mirror are
//! checked once.
use nalgebra::Vector3;
use psgrasp_datagen::{
    check_labels_in_physics, generate_labels, FailedLabels, GenerationConfig, GraspLabel,
    LabelConfig, LabelPhysicsCheck, LabelSet,
};
use psgrasp_geometry::{CameraIntrinsics, GripperModel};
use psgrasp_sim::{default_camera, MeshLibrary, Scene};
use psgrasp_test_support::scenes::boxes_on_floor;

fn labels_of(scene: &Scene) -> LabelSet {
    let camera = default_camera(scene.bin(), CameraIntrinsics::default_640x480());
    let rendering = scene.render(&camera);
    generate_labels(
        scene,
        &camera,
        &rendering,
        &GripperModel::default(),
        &LabelConfig::quick(),
        3,
    )
}

#[test]
fn labels_that_hold_stay_and_grasps_beside_the_object_are_dropped() {
    // A 40 mm cube in the middle of the bin: its antipodal labels hold.
    let scene = boxes_on_floor(&[([0.02, 0.02, 0.02], [0.0, 0.0])]);
    let set = labels_of(&scene);
    // The first 12 pairs (each label followed by its mirror) and one grasp moved 100 mm beside
    // the cube: the hand closes on nothing.
    let mut labels: Vec<GraspLabel> = set.labels.iter().take(24).copied().collect();
    assert_eq!(labels.len(), 24, "too few labels on the cube");
    let mut beside = labels[0];
    beside.contact += Vector3::new(0.1, 0.0, 0.0);
    labels.push(beside);
    let run = |check: &LabelPhysicsCheck| {
        let mut stats = set.stats.clone();
        let kept = check_labels_in_physics(
            &scene,
            &MeshLibrary::default(),
            &GripperModel::default(),
            labels.clone(),
            check,
            &mut stats,
        );
        (kept, stats)
    };
    let (kept, stats) = run(&LabelPhysicsCheck {
        max_width_m: 1.0,
        ..LabelPhysicsCheck::default()
    });
    // One check per physical grasp: 12 pairs and the moved one.
    assert_eq!(stats.physics_checked, 13);
    assert!(!kept.contains(&beside), "a grasp beside the cube was kept");
    assert!(stats.physics_failed >= 1);
    assert_eq!(kept.len() + 2 * stats.physics_failed - 1, labels.len());
    assert!(
        kept.len() >= 20,
        "only {} of 24 cube labels held",
        kept.len()
    );
    // A label and its mirror share their verdict, and the counts describe what is stored.
    assert_eq!(kept.len() % 2, 0);
    assert_eq!(stats.configurations, kept.len());
    assert_eq!(
        stats.grasps,
        kept.iter().map(GraspLabel::free_count).sum::<usize>()
    );
    assert_eq!(stats.grasps_per_object.iter().sum::<usize>(), stats.grasps);

    // Kept with quality 0 instead: every label stays, in order and otherwise unchanged; those
    // the drop mode keeps keep their quality, the others (the same count) have quality 0.
    let (all, zero_stats) = run(&LabelPhysicsCheck {
        max_width_m: 1.0,
        failed_labels: FailedLabels::ZeroQuality,
        ..LabelPhysicsCheck::default()
    });
    assert_eq!(all.len(), labels.len());
    assert_eq!(
        (zero_stats.physics_checked, zero_stats.physics_failed),
        (stats.physics_checked, stats.physics_failed)
    );
    let held: Vec<GraspLabel> = all.iter().filter(|l| l.quality > 0.0).copied().collect();
    assert_eq!(held, kept);
    for (stored, given) in all.iter().zip(&labels) {
        assert_eq!(stored.contact, given.contact);
        assert!(stored.quality == given.quality || stored.quality == 0.0);
    }
    assert_eq!(
        all.last().unwrap().quality,
        0.0,
        "the grasp beside the cube"
    );
    assert_eq!(zero_stats.configurations, labels.len());

    // Only labels narrower than the limit are checked: at a limit under every width nothing
    // is checked or dropped; off (the default) leaves the labels as they are.
    let narrowest = labels.iter().map(|l| l.width).fold(f32::INFINITY, f32::min);
    for check in [
        LabelPhysicsCheck {
            max_width_m: 0.5 * narrowest,
            ..LabelPhysicsCheck::default()
        },
        LabelPhysicsCheck::default(),
    ] {
        let (same, stats) = run(&check);
        assert_eq!(same, labels);
        assert_eq!((stats.physics_checked, stats.physics_failed), (0, 0));
    }
}

#[test]
fn the_check_is_stored_in_a_dataset_configuration_only_when_on() {
    // Datasets made without the check keep their manifests (and manifest hashes).
    let off = serde_json::to_value(GenerationConfig::default()).unwrap();
    assert!(off.get("physics_check").is_none());
    let on: GenerationConfig = toml::from_str(
        "[physics_check]\nmax_width_m = 0.2\n[physics_check.execution]\nlift_height_m = 0.1\n",
    )
    .unwrap();
    assert_eq!(on.physics_check.max_width_m, 0.2);
    assert_eq!(on.physics_check.execution.lift_height_m, 0.1);
    assert!(on.physics_check.execution.close_after_approach_contact);
    let json = serde_json::to_value(&on).unwrap();
    assert_eq!(json["physics_check"]["max_width_m"], 0.2f32 as f64);
    // A manifest's configuration reads back as it was written.
    let back: GenerationConfig = serde_json::from_value(json.clone()).unwrap();
    assert_eq!(back.physics_check, on.physics_check);
    // The fate of failed labels is written only when not the default drop (manifests of
    // datasets made before the setting existed stay the same), and reads back.
    assert!(json["physics_check"].get("failed_labels").is_none());
    let zero: GenerationConfig =
        toml::from_str("[physics_check]\nmax_width_m = 0.2\nfailed_labels = \"zero_quality\"\n")
            .unwrap();
    assert_eq!(zero.physics_check.failed_labels, FailedLabels::ZeroQuality);
    let json = serde_json::to_value(&zero).unwrap();
    assert_eq!(json["physics_check"]["failed_labels"], "zero_quality");
    let back: GenerationConfig = serde_json::from_value(json).unwrap();
    assert_eq!(back.physics_check, zero.physics_check);
    assert!(toml::from_str::<GenerationConfig>(
        "[physics_check]\nmax_width_m = 0.2\nfailed_labels = \"keep\"\n"
    )
    .is_err());
    // Misspelt keys are refused, in the check and in its execution table.
    assert!(toml::from_str::<GenerationConfig>("[physics_check]\nmax_width = 0.2\n").is_err());
    assert!(
        toml::from_str::<GenerationConfig>("[physics_check.execution]\nlift_hieght_m = 0.1\n")
            .is_err()
    );
}
