//! Label generation checked against analytic scenes and by independent re-checks.
use nalgebra::{Point3, Vector3};
use psgrasp_datagen::labels::{check_pose, check_pose_lifted, PoseCheck, RobustQuality};
use psgrasp_datagen::verify::{
    contact_surface_error, gripper_hits_scene_sampled, recompute_quality,
};
use psgrasp_datagen::{
    generate_labels, label_grid, GraspLabel, LabelConfig, LABEL_CONTACT, LABEL_GRIPPER,
};
use psgrasp_geometry::{BinModel, CameraIntrinsics, GripperModel, Workspace, N_APPROACHES};
use psgrasp_sim::{
    default_camera, procedural_scene, ObjectKind, Primitive, Scene, SceneDescription,
};
use psgrasp_test_support::scenes::{on_floor, single_part};
use rand::{Rng, SeedableRng};

fn single_object_scene(primitive: Primitive, half_height: f32) -> Scene {
    let bin = BinModel::default();
    let spec = single_part("single", ObjectKind::Box, primitive);
    let objects = vec![on_floor(&bin, spec, [0.0, 0.0], half_height)];
    Scene::new(SceneDescription { bin, objects }).unwrap()
}

fn cube_scene(half: f32) -> Scene {
    single_object_scene(
        Primitive::Cuboid {
            half_extents: [half; 3],
        },
        half,
    )
}

fn labels_for(scene: &Scene, config: &LabelConfig, seed: u64) -> Vec<GraspLabel> {
    let camera = default_camera(scene.bin(), CameraIntrinsics::default_640x480());
    let rendering = scene.render(&camera);
    generate_labels(
        scene,
        &camera,
        &rendering,
        &GripperModel::default(),
        config,
        seed,
    )
    .labels
}

#[test]
fn isolated_cube_labels_match_the_analytic_answer() {
    let half = 0.02;
    let scene = cube_scene(half);
    let config = LabelConfig::quick();
    let labels = labels_for(&scene, &config, 5);
    assert!(
        labels.len() > 20,
        "only {} labels on an isolated cube",
        labels.len()
    );
    let gripper = GripperModel::default();
    let mut quality_agree = 0;
    for l in &labels {
        assert!(l.quality > config.min_quality);
        assert!(l.width <= gripper.max_opening_m - config.width_margin_m + 1e-6);
        assert!(l.free_count() > 0);
        // Both contacts lie on the cube surface.
        assert!(contact_surface_error(&scene, l).unwrap() < 1e-4);
        // Quality > 0.5 on a cube means opposite faces: width = 2·half / |cos(b, n1)|.
        assert!(l.contact_normal.dot(&l.second_normal) < -0.999, "{l:?}");
        let expected = 2.0 * half / l.baseline.dot(&l.contact_normal).abs();
        assert!(
            (l.width - expected).abs() < 1e-4,
            "width {} vs {expected}",
            l.width
        );
        let analytic = l.baseline.dot(&l.contact_normal).powi(2);
        assert!((l.quality - analytic).abs() < 1e-4);
        // Independent normals (finite differences of the signed distance).
        if recompute_quality(&scene, l, 2e-4).is_some_and(|q| (q - l.quality).abs() < 0.02) {
            quality_agree += 1;
        }
        // The near-vertical approaches clear a lone cube resting on the floor whenever the
        // baseline is horizontal (contacts on the side faces).
        if l.baseline.z.abs() < 0.05 && l.contact.z > scene.bin().floor_center.z + 0.016 {
            assert!(
                l.collision_free[8] || l.collision_free[9],
                "top-down approach blocked: {l:?}"
            );
        }
    }
    // Finite differences disagree only within ~0.2 mm of an edge.
    assert!(
        quality_agree as f32 >= 0.95 * labels.len() as f32,
        "{quality_agree}/{}",
        labels.len()
    );
}

#[test]
fn labels_are_deterministic_for_a_seed() {
    let scene = cube_scene(0.025);
    let a = labels_for(&scene, &LabelConfig::quick(), 9);
    let b = labels_for(&scene, &LabelConfig::quick(), 9);
    let c = labels_for(&scene, &LabelConfig::quick(), 10);
    assert_eq!(a, b);
    assert_ne!(a, c);
}

#[test]
fn no_label_where_the_gripper_intersects_anything() {
    let bin = BinModel::default();
    let scene = procedural_scene(3, 10, &bin).unwrap();
    let config = LabelConfig::quick();
    let labels = labels_for(&scene, &config, 3);
    assert!(
        !labels.is_empty(),
        "a 10-object scene should have some grasp"
    );
    let gripper = GripperModel::default();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
    let (mut free_checked, mut blocked_checked, mut blocked_confirmed) = (0, 0, 0);
    for _ in 0..30 {
        let l = &labels[rng.random_range(0..labels.len())];
        let opening = (l.width + 2.0 * config.approach_clearance_m).min(gripper.max_opening_m);
        for i in 0..N_APPROACHES {
            if l.collision_free[i] {
                // Dense samples on the gripper boxes never fall inside an object or the bin.
                assert!(
                    !gripper_hits_scene_sampled(&scene, &gripper, l, i, opening, 0.002),
                    "label {l:?} approach {i} intersects the scene"
                );
                free_checked += 1;
            } else if matches!(
                check_pose(&scene, &gripper, &l.grasp(i), l.object as usize, &config),
                PoseCheck::PalmCollision | PoseCheck::FingerCollision
            ) {
                blocked_checked += 1;
                if gripper_hits_scene_sampled(&scene, &gripper, l, i, opening, 0.002) {
                    blocked_confirmed += 1;
                }
            }
        }
    }
    assert!(free_checked > 0);
    // Collisions shallower than the 2 mm sampling step can escape the sampled check.
    assert!(
        blocked_confirmed as f32 >= 0.8 * blocked_checked as f32,
        "{blocked_confirmed}/{blocked_checked}"
    );
}

#[test]
fn mirrored_label_is_the_same_gripper_pose_set() {
    let l = GraspLabel {
        contact: Point3::new(0.2, 0.3, 0.05),
        baseline: Vector3::new(0.8, 0.1, 0.2).normalize(),
        contact_normal: -Vector3::x(),
        second_normal: Vector3::x(),
        width: 0.05,
        quality: 0.8,
        collision_free: std::array::from_fn(|i| i % 3 == 0),
        object: 0,
    };
    let m = l.mirrored();
    assert!((m.second_contact() - l.contact).norm() < 1e-6);
    let g = GripperModel::default();
    for i in 0..N_APPROACHES {
        let a = l.grasp(N_APPROACHES - 1 - i);
        let b = m.grasp(i);
        assert!((a.center() - b.center()).norm() < 1e-6);
        assert!((a.approach - b.approach).norm() < 1e-5, "approach {i}");
        assert_eq!(m.collision_free[i], l.collision_free[N_APPROACHES - 1 - i]);
        // The palm box is the same box (the hand is symmetric under a half turn about a).
        let pa = g.boxes(&a.workspace_from_gripper(), 0.05)[0]
            .parent_from_box
            .translation
            .vector;
        let pb = g.boxes(&b.workspace_from_gripper(), 0.05)[0]
            .parent_from_box
            .translation
            .vector;
        assert!((pa - pb).norm() < 1e-6);
    }
}

#[test]
fn label_grid_marks_contacts_and_approach_points() {
    let scene = cube_scene(0.02);
    let labels = labels_for(&scene, &LabelConfig::quick(), 2);
    let ws = Workspace::default();
    let g = GripperModel::default();
    let grid = label_grid(&labels, &g, &ws);
    for l in &labels {
        let [x, y, z] = ws.voxel_of(&l.contact).unwrap();
        assert_eq!(grid[ws.index(x, y, z)], LABEL_CONTACT);
        for i in (0..N_APPROACHES).filter(|&i| l.collision_free[i]) {
            let [x, y, z] = ws.voxel_of(&l.grasp(i).approach_point(&g)).unwrap();
            assert!(
                grid[ws.index(x, y, z)] == LABEL_GRIPPER
                    || grid[ws.index(x, y, z)] == LABEL_CONTACT
            );
        }
    }
    let marked = grid.iter().filter(|c| **c != 0).count();
    assert!(marked > 0 && marked < grid.len() / 100);
}

#[test]
fn isolated_sphere_is_grasped_across_its_equator() {
    let r = 0.02;
    let scene = single_object_scene(Primitive::Ball { radius: r }, r);
    let labels = labels_for(&scene, &LabelConfig::quick(), 4);
    assert!(labels.len() > 20, "{} labels", labels.len());
    let centre = scene.objects()[0].workspace_from_object.translation.vector;
    for l in &labels {
        // Antipodal on a sphere: the contact normals are radial, q = cos²(b, n).
        let n1 = (l.contact.coords - centre).normalize();
        assert!((n1 - l.contact_normal).norm() < 1e-3);
        assert!((l.quality - l.baseline.dot(&n1).powi(2)).abs() < 1e-3);
        assert!(l.width <= 2.0 * r + 1e-4);
    }
    // Some grasp passes near the equator with a top-down approach.
    assert!(labels
        .iter()
        .any(|l| l.baseline.z.abs() < 0.3 && (l.collision_free[8] || l.collision_free[9])));
}

#[test]
fn a_raised_tool_centre_point_labels_a_low_bar_the_contacts_frame_cannot() {
    // A 60 × 14 × 8 mm bar lying flat: at the contacts' midpoint the fingertips, 9.5 mm beyond
    // it, are under the floor for every pair; with lifts of 10 and 20 mm back along the approach
    // to try, the pairs across the bar get free approaches, each free at a lift whose fingertips
    // stay above the floor and blocked without it.
    let scene = single_object_scene(
        Primitive::Cuboid {
            half_extents: [0.03, 0.007, 0.004],
        },
        0.004,
    );
    let flush = LabelConfig::quick();
    assert!(labels_for(&scene, &flush, 5).is_empty());
    let raised = LabelConfig {
        tcp_lifts_m: vec![0.01, 0.02],
        ..LabelConfig::quick()
    };
    let labels = labels_for(&scene, &raised, 5);
    assert!(!labels.is_empty());
    let gripper = GripperModel::default();
    let floor_top = scene.bin().floor_center.z;
    for l in &labels {
        for i in (0..N_APPROACHES).filter(|&i| l.collision_free[i]) {
            // Free at one of the lifts, whose fingertips stay above the floor.
            let lift = [0.01, 0.02]
                .into_iter()
                .find(|&lift| {
                    check_pose_lifted(
                        &scene,
                        &gripper,
                        &l.grasp(i),
                        l.object as usize,
                        &flush,
                        lift,
                    ) == PoseCheck::Free
                })
                .expect("free at a lift");
            let tip = l.grasp(i).workspace_from_gripper_lifted(lift)
                * Point3::new(0.0, 0.0, gripper.tip_beyond_tcp_m);
            assert!(tip.z > floor_top, "fingertip {tip:?} under the floor");
            assert_ne!(
                check_pose(&scene, &gripper, &l.grasp(i), l.object as usize, &flush),
                PoseCheck::Free
            );
        }
    }
}

#[test]
fn the_default_label_config_writes_no_lift_so_old_manifests_keep_their_hashes() {
    let text = serde_json::to_string(&LabelConfig::default()).unwrap();
    assert!(!text.contains("tcp_lifts_m"), "{text}");
    let raised = LabelConfig {
        tcp_lifts_m: vec![0.003, 0.006],
        ..LabelConfig::default()
    };
    let back: LabelConfig = serde_json::from_str(&serde_json::to_string(&raised).unwrap()).unwrap();
    assert_eq!(back, raised);
}

#[test]
fn bad_tcp_lifts_are_refused_by_name() {
    for lifts in [vec![-0.01], vec![0.006, 0.003], vec![f32::INFINITY]] {
        let config = LabelConfig {
            tcp_lifts_m: lifts.clone(),
            ..LabelConfig::default()
        };
        let e = config.validate().unwrap_err();
        assert_eq!(e.field, "labels.tcp_lifts_m", "{lifts:?}");
    }
    assert!(LabelConfig::default().validate().is_ok());
}

#[test]
fn the_descent_test_drops_approaches_whose_open_hand_meets_a_neighbour() {
    // Two 40 mm cubes 35 mm apart on the floor. ACRONYM's pose test opens the hand 2 × 10 mm wider
    // than the pair, so a finger fits in the gap beside its contact; the hand the protocol
    // commands is 2 × 20 mm wider than the pair and comes straight down from 80 mm back, so that
    // finger meets the neighbour. With the descent test on, no free approach's descent meets a
    // cube or the floor (checked independently: each gripper box at every 1 mm of the descent
    // against the cubes by selection's separating-axis test, overlaps deeper than 0.1 mm), while
    // the pose test alone labels some whose descent does.
    let half = 0.02;
    let gap = 0.035;
    let dx = half + 0.5 * gap;
    let scene = psgrasp_test_support::scenes::boxes_on_floor(&[
        ([half; 3], [-dx, 0.0]),
        ([half; 3], [dx, 0.0]),
    ]);
    let cubes: Vec<psgrasp_geometry::OrientedBox> = scene
        .objects()
        .iter()
        .map(|o| psgrasp_geometry::OrientedBox {
            parent_from_box: o.workspace_from_object,
            half_extents: Vector3::repeat(half),
        })
        .collect();
    let floor_top = scene.bin().floor_center.z;
    let gripper = GripperModel::default();
    let path = psgrasp_datagen::labels::ApproachPathCheck::default();
    let descent_meets = |l: &GraspLabel, i: usize| {
        let opening = (l.width + path.opening_clearance_m).min(gripper.max_opening_m);
        (0..=80).any(|k| {
            let pose = l
                .grasp(i)
                .workspace_from_gripper_lifted(path.distance_m * k as f32 / 80.0);
            gripper.boxes(&pose, opening).iter().any(|b| {
                cubes
                    .iter()
                    .any(|c| psgrasp_selection::boxes_overlap(b, c, -1e-4))
                    || b.corners().iter().any(|p| p.z < floor_top)
            })
        })
    };
    let count_meeting = |labels: &[GraspLabel]| {
        labels
            .iter()
            .flat_map(|l| {
                (0..N_APPROACHES)
                    .filter(|&i| l.collision_free[i])
                    .map(move |i| (l, i))
            })
            .filter(|(l, i)| descent_meets(l, *i))
            .count()
    };
    let pose_only = labels_for(&scene, &LabelConfig::quick(), 4);
    assert!(
        count_meeting(&pose_only) > 0,
        "the pose test alone should label some approach whose descent meets a cube"
    );
    let with_descent = LabelConfig {
        approach_path: Some(path),
        ..LabelConfig::quick()
    };
    let camera = default_camera(scene.bin(), CameraIntrinsics::default_640x480());
    let set = generate_labels(
        &scene,
        &camera,
        &scene.render(&camera),
        &gripper,
        &with_descent,
        4,
    );
    assert!(set.labels.len() > 10, "only {} labels", set.labels.len());
    assert!(set.stats.approach_path_blocked > 0);
    assert_eq!(count_meeting(&set.labels), 0);
    // Written to the manifest's config when on, absent by default (old manifests keep their hashes).
    let text = serde_json::to_string(&with_descent).unwrap();
    assert!(text.contains("approach_path"), "{text}");
    assert!(!serde_json::to_string(&LabelConfig::default())
        .unwrap()
        .contains("approach_path"));
}

/// Perturbations of the given size; the hand opened as the labeler checks it (width + 2 × 10 mm).
fn robust(position_sigma_m: f32, angle_sigma_deg: f32, samples: usize) -> RobustQuality {
    RobustQuality {
        samples,
        position_sigma_m,
        angle_sigma_deg,
        opening_clearance_m: 2.0 * LabelConfig::default().approach_clearance_m,
        max_drop: None,
    }
}

fn mean_share(scene: &Scene, labels: &[&GraspLabel], r: &RobustQuality, min: f32) -> f32 {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    let gripper = GripperModel::default();
    let sum: f32 = labels
        .iter()
        .map(|l| r.success_share(scene, &gripper, l, min, &mut rng))
        .sum();
    sum / labels.len() as f32
}

#[test]
fn an_exact_execution_of_a_lone_cubes_label_always_holds_and_a_sloppy_one_often_fails() {
    let scene = cube_scene(0.02);
    let config = LabelConfig::quick();
    let labels = labels_for(&scene, &config, 5);
    let all: Vec<&GraspLabel> = labels.iter().collect();
    let min = config.min_quality;
    assert_eq!(mean_share(&scene, &all, &robust(0.0, 0.0, 4), min), 1.0);
    let sloppy = mean_share(&scene, &all, &robust(0.02, 15.0, 16), min);
    assert!(sloppy < 0.6, "2 cm and 15° off still hold {sloppy}");
}

#[test]
fn grasps_that_fill_the_hands_opening_are_less_robust_than_grasps_with_room() {
    // The same 5 cm tall box, 4 cm or 7 cm across x, grasped from above at 3–4 cm height (the
    // fingertips well above the floor, the palm well above the box): across the wide box the
    // 8 cm hand keeps 5 mm beside each face, across the narrow one 10 mm (the labeler's clearance).
    let config = LabelConfig {
        contacts_per_object: 400,
        refine_samples_per_object: 2000,
        ..LabelConfig::quick()
    };
    let shift_only = robust(0.004, 0.0, 32);
    let share_across = |half_x: f32, min_width: f32, max_width: f32| {
        let scene = single_object_scene(
            Primitive::Cuboid {
                half_extents: [half_x, 0.02, 0.025],
            },
            0.025,
        );
        let floor = scene.objects()[0]
            .workspace_from_object
            .translation
            .vector
            .z
            - 0.025;
        let labels = labels_for(&scene, &config, 9);
        // Square pairs across x, executed from straight above only.
        let across: Vec<GraspLabel> = labels
            .iter()
            .filter(|l| l.quality > 0.9 && l.baseline.x.abs() > 0.9)
            .filter(|l| (min_width..max_width).contains(&l.width))
            .filter(|l| {
                (0.03..0.04).contains(&(0.5 * (l.contact.z + l.second_contact().z) - floor))
            })
            .filter_map(|l| {
                let top_down = (0..N_APPROACHES)
                    .find(|&i| l.collision_free[i] && l.grasp(i).approach.z < -0.95)?;
                let mut only = *l;
                only.collision_free = [false; N_APPROACHES];
                only.collision_free[top_down] = true;
                Some(only)
            })
            .collect();
        assert!(across.len() >= 10, "{} labels across x", across.len());
        let refs: Vec<&GraspLabel> = across.iter().collect();
        mean_share(&scene, &refs, &shift_only, config.min_quality)
    };
    let roomy = share_across(0.02, 0.0, 0.05);
    let tight = share_across(0.035, 0.065, 0.08);
    assert!(
        tight + 0.25 < roomy,
        "filling the opening {tight}, with room {roomy}"
    );
}

#[test]
fn robust_quality_reranks_the_same_labels_deterministically() {
    let scene = cube_scene(0.02);
    let plain = LabelConfig::quick();
    let robust_config = LabelConfig {
        robust_quality: Some(RobustQuality::default()),
        ..LabelConfig::quick()
    };
    let before = labels_for(&scene, &plain, 11);
    let after = labels_for(&scene, &robust_config, 11);
    assert_eq!(after, labels_for(&scene, &robust_config, 11));
    assert_eq!(before.len(), after.len());
    let mut lowered = 0;
    for (b, a) in before.iter().zip(&after) {
        assert_eq!(
            (b.contact, b.baseline, b.width),
            (a.contact, a.baseline, a.width)
        );
        assert_eq!(b.collision_free, a.collision_free);
        assert!(a.quality >= plain.min_quality && a.quality <= b.quality + 1e-6);
        lowered += usize::from(a.quality < b.quality - 1e-6);
    }
    assert!(lowered > 0, "no label lost quality to the perturbations");
    for pair in after.chunks(2) {
        assert_eq!(pair[0].quality, pair[1].quality, "a label and its mirror");
    }
    let text = serde_json::to_string(&plain).unwrap();
    assert!(!text.contains("robust_quality"), "{text}");
    let back: LabelConfig =
        serde_json::from_str(&serde_json::to_string(&robust_config).unwrap()).unwrap();
    assert_eq!(back, robust_config);
    let bad = LabelConfig {
        robust_quality: Some(robust(0.003, 90.0, 8)),
        ..LabelConfig::quick()
    };
    assert_eq!(
        bad.validate().unwrap_err().field,
        "labels.robust_quality.angle_sigma_deg"
    );
}
