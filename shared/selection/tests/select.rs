//! Selection on hand-made configurations in the default bin, with known answers.
use nalgebra::{Point2, Point3, Vector3};
use psgrasp_fusion::NormalGrid;
use psgrasp_geometry::{BinModel, GraspConfiguration, GripperModel, Workspace, N_APPROACHES};
use psgrasp_selection::{
    select, select_filtered, FallbackThresholds, GraspChecker, PickOrder, RejectionReason,
    SelectionConfig, SelectionError,
};
use psgrasp_test_support::synthetic::{Primitive, SyntheticScene};

const TRUNC: f32 = 0.027;

fn bin() -> BinModel {
    BinModel::default()
}

fn floor_z() -> f32 {
    bin().floor_center.z
}

/// The observed scene: the bin floor plus `objects`.
fn scene(objects: &[Primitive]) -> NormalGrid {
    let mut s = SyntheticScene::floor(floor_z());
    s.objects.extend_from_slice(objects);
    s.normal_grid(Workspace::default(), TRUNC)
}

/// A configuration at `contact` with baseline +x, width 40 mm, and collision score `score` for the
/// approaches in `free`, 0 for the others.
fn config(contact: [f32; 3], quality: f32, free: &[usize], score: f32) -> GraspConfiguration {
    let mut collision_scores = [0.0; N_APPROACHES];
    for &i in free {
        collision_scores[i] = score;
    }
    GraspConfiguration {
        contact: Point3::from(contact),
        baseline: Vector3::x(),
        collision_scores,
        width: 0.04,
        quality,
        kappa: 0.0,
        kappa_floor: 0.0,
    }
}

/// Approaches 8 and 9 are the two within 6° of straight down for a horizontal baseline.
const DOWN: [usize; 2] = [8, 9];

fn run(
    configs: &[GraspConfiguration],
    grid: &NormalGrid,
    cfg: &SelectionConfig,
) -> psgrasp_selection::Selection {
    select(configs, &grid.view(), &bin(), &GripperModel::default(), cfg).unwrap()
}

/// The configuration indices of the picks `cfg` makes, best first.
fn picked(configs: &[GraspConfiguration], grid: &NormalGrid, cfg: SelectionConfig) -> Vec<usize> {
    run(configs, grid, &cfg)
        .picks
        .iter()
        .map(|p| p.configuration_index)
        .collect()
}

#[test]
fn fingers_in_a_bin_wall_are_rejected_for_that_reason() {
    let grid = scene(&[]);
    let cfg = SelectionConfig::default();
    // Baseline along y, first contact 12 mm from the −y wall's inner face (y = 0.088): the fingers
    // open 60 mm around the TCP at y = 0.12, so the −y finger sits inside the wall.
    let near_wall = GraspConfiguration {
        baseline: Vector3::y(),
        ..config(
            [0.288, 0.100, 0.06],
            0.95,
            &(5..=12).collect::<Vec<_>>(),
            1.0,
        )
    };
    let sel = run(&[near_wall], &grid, &cfg);
    assert!(sel.picks.is_empty());
    assert_eq!(sel.rejected.bin_collision, 8, "{:?}", sel.rejected);
    assert_eq!(sel.rejected.no_valid_approach, 1);
    let checker = GraspChecker::new(&cfg, GripperModel::default(), bin(), None).unwrap();
    assert_eq!(
        checker.check_approach(&near_wall, 0, 8).unwrap_err(),
        RejectionReason::BinCollision
    );

    // The same grasp in the middle of the bin is picked. Approaches are tried by score, ties by
    // index, so approach 5 (37° tilt) comes first.
    let centred = GraspConfiguration {
        contact: Point3::new(0.288, 0.25, 0.06),
        ..near_wall
    };
    let sel = run(&[centred], &grid, &cfg);
    assert_eq!(sel.picks.len(), 1, "{:?}", sel.rejected);
    assert_eq!(sel.picks[0].approach_index, 5);
    assert_eq!(sel.rejected, Default::default());
}

#[test]
fn approach_tilted_beyond_the_cone_is_rejected() {
    let grid = scene(&[]);
    // Only approach 0 is collision-free: horizontal (−y) for a baseline along +x.
    let c = config([0.268, 0.2, 0.1], 0.9, &[0], 1.0);
    assert!(c.approaches()[0].z.abs() < 1e-5);
    let sel = run(&[c], &grid, &SelectionConfig::default());
    assert!(sel.picks.is_empty());
    assert_eq!(sel.rejected.tilt, 1);
    assert_eq!(
        sel.rejected.collision_score, 7,
        "the other 7 of the first 8 approaches score 0"
    );

    let wide_cone = SelectionConfig {
        max_approach_tilt_deg: 95.0,
        ..SelectionConfig::default()
    };
    let sel = run(&[c], &grid, &wide_cone);
    assert_eq!(sel.picks.len(), 1, "{:?}", sel.rejected);
    let pick = &sel.picks[0];
    assert_eq!(pick.approach_index, 0);
    // The pre-grasp is backed off 80 mm against the (horizontal) approach, i.e. along +y.
    let back = pick.pregrasp.translation.vector - pick.workspace_from_gripper.translation.vector;
    assert!(
        (back - Vector3::new(0.0, 0.08, 0.0)).norm() < 1e-5,
        "{back:?}"
    );
    assert!((pick.opening_m - 0.06).abs() < 1e-6);
}

#[test]
fn picks_are_ordered_by_quality_then_collision_score() {
    let grid = scene(&[]);
    let mut c0 = config([0.15, 0.2, 0.06], 0.6, &DOWN, 0.9);
    // c0's best-scored approach is horizontal: rejected for tilt, approach 9 (0.9) is taken.
    c0.collision_scores[0] = 1.0;
    c0.collision_scores[8] = 0.0;
    let configs = [
        c0,
        config([0.25, 0.2, 0.06], 0.9, &DOWN, 0.8),
        config([0.35, 0.2, 0.06], 0.9, &DOWN, 0.95),
        config([0.45, 0.2, 0.06], 0.7, &DOWN, 1.0),
        config([0.30, 0.35, 0.06], 0.4, &DOWN, 1.0),
    ];
    let sel = run(&configs, &grid, &SelectionConfig::default());
    let order: Vec<usize> = sel.picks.iter().map(|p| p.configuration_index).collect();
    assert_eq!(order, vec![2, 1, 3, 0]);
    assert_eq!(sel.picks[3].approach_index, 9);
    assert_eq!(sel.picks[3].collision_score, 0.9);
    assert_eq!(
        sel.picks[0].approach_index, 8,
        "ties in score go to the lower index"
    );
    assert_eq!(sel.rejected.tilt, 1);
    assert_eq!(sel.rejected.quality, 1);
    for p in &sel.picks {
        let c = &configs[p.configuration_index];
        assert_eq!(p.quality, c.quality);
        let tcp = c.contact + c.baseline * (0.5 * c.width);
        assert!((p.workspace_from_gripper.translation.vector - tcp.coords).norm() < 1e-6);
        assert!((p.workspace_from_gripper.rotation * Vector3::x() - c.baseline).norm() < 1e-5);
    }
}

#[test]
fn an_extra_pregrasp_check_moves_on_to_the_next_approach() {
    // Two configurations, both free straight down (approaches 8 and 9, 8 scored higher). The
    // caller's check (in the evaluation: the pre-grasp pose against the simulated scene) refuses
    // approach 8 of the better configuration: its approach 9 is taken instead, the refusal is
    // counted as a pre-grasp collision, and the other configuration keeps approach 8.
    let mut best = config([0.25, 0.2, 0.06], 0.9, &DOWN, 0.8);
    best.collision_scores[8] = 0.9;
    let mut other = config([0.35, 0.2, 0.06], 0.7, &DOWN, 0.8);
    other.collision_scores[8] = 0.9;
    let configs = [best, other];
    let grid = scene(&[]);
    let cfg = SelectionConfig::default();
    let mut asked = Vec::new();
    let sel = select_filtered(
        &configs,
        &grid.view(),
        &bin(),
        &GripperModel::default(),
        &cfg,
        |pick| {
            asked.push((pick.configuration_index, pick.approach_index));
            !(pick.configuration_index == 0 && pick.approach_index == 8)
        },
    )
    .unwrap();
    assert_eq!(asked, vec![(0, 8), (0, 9), (1, 8)]);
    let got: Vec<(usize, usize)> = sel
        .picks
        .iter()
        .map(|p| (p.configuration_index, p.approach_index))
        .collect();
    assert_eq!(got, vec![(0, 9), (1, 8)]);
    assert_eq!(sel.rejected.pregrasp_collision, 1);
    // Refusing everything leaves no pick, every examined approach counted.
    let none = select_filtered(
        &configs,
        &grid.view(),
        &bin(),
        &GripperModel::default(),
        &cfg,
        |_| false,
    )
    .unwrap();
    assert!(none.picks.is_empty());
    assert_eq!(none.rejected.pregrasp_collision, 4);
    assert_eq!(none.rejected.no_valid_approach, 2);
}

#[test]
fn top_k_keeps_the_best_and_skips_the_rest() {
    let grid = scene(&[]);
    let mut configs = Vec::new();
    for (n, (x, y)) in [0.12f32, 0.2, 0.28, 0.36, 0.44]
        .iter()
        .flat_map(|x| [0.15f32, 0.25, 0.35].map(|y| (*x, y)))
        .enumerate()
    {
        configs.push(config([x, y, 0.06], 0.55 + 0.03 * n as f32, &DOWN, 1.0));
    }
    assert_eq!(configs.len(), 15);
    let sel = run(&configs, &grid, &SelectionConfig::default());
    let order: Vec<usize> = sel.picks.iter().map(|p| p.configuration_index).collect();
    assert_eq!(order, (5..15).rev().collect::<Vec<_>>());
    assert_eq!(sel.rejected.not_examined, 5);
    let all = run(
        &configs,
        &grid,
        &SelectionConfig {
            top_k: 20,
            ..SelectionConfig::default()
        },
    );
    assert_eq!(all.picks.len(), 15, "{:?}", all.rejected);
}

/// A 40×60×50 mm box in the middle of the bin and a grasp across it, 25 mm above the floor.
fn box_and_grasp() -> (Primitive, GraspConfiguration) {
    let b = Primitive::Box {
        center_xy: Point2::new(0.288, 0.288),
        size_m: Vector3::new(0.04, 0.06, 0.05),
        yaw_rad: 0.0,
    };
    (
        b,
        config([0.268, 0.288, floor_z() + 0.025], 0.95, &DOWN, 1.0),
    )
}

/// Marks the voxels with centres in `[lo, hi]` as occupied (−1, no normal): an overhang that a
/// top-down camera could not see, e.g. a robot part or a lid.
fn add_obstacle(grid: &mut NormalGrid, lo: [f32; 3], hi: [f32; 3]) {
    let ws = grid.workspace;
    let n = ws.voxel_count();
    for idx in 0..n {
        let [i, j, k] = ws.unindex(idx);
        let p = ws.voxel_center(i, j, k);
        if (0..3).all(|a| p[a] >= lo[a] && p[a] <= hi[a]) {
            grid.tsdf[idx] = -1.0;
            for a in 0..3 {
                grid.normals[a * n + idx] = 0.0;
            }
        }
    }
}

#[test]
fn pregrasp_collision_with_an_obstacle_above_the_grasp() {
    let (object, c) = box_and_grasp();
    let clear = scene(&[object]);
    let sel = run(&[c], &clear, &SelectionConfig::default());
    assert_eq!(sel.picks.len(), 1, "{:?}", sel.rejected);

    // 150–170 mm above the TCP: above the palm at the grasp (its top is 131 mm above the TCP), in
    // the palm's way 80 mm higher at the pre-grasp.
    let tcp_z = c.contact.z;
    let mut blocked = clear.clone();
    add_obstacle(
        &mut blocked,
        [0.2, 0.25, tcp_z + 0.15],
        [0.38, 0.33, tcp_z + 0.17],
    );
    let sel = run(&[c], &blocked, &SelectionConfig::default());
    assert!(sel.picks.is_empty());
    assert_eq!(sel.rejected.pregrasp_collision, 2, "{:?}", sel.rejected);
    assert_eq!(sel.rejected.scene_collision, 0);
    assert_eq!(sel.rejected.collision_score, 6);
    // Without the scene check the obstacle is invisible.
    let blind = SelectionConfig {
        check_scene_collision: false,
        ..SelectionConfig::default()
    };
    assert_eq!(run(&[c], &blocked, &blind).picks.len(), 1);
}

#[test]
fn obstacle_between_pregrasp_and_grasp_is_found_on_the_path() {
    let (object, c) = box_and_grasp();
    let mut grid = scene(&[object]);
    let tcp_z = c.contact.z;
    // A thin plate 152–160 mm above the TCP, with the pre-grasp 300 mm back: neither end pose
    // touches it, the poses in between do.
    add_obstacle(
        &mut grid,
        [0.2, 0.25, tcp_z + 0.152],
        [0.38, 0.33, tcp_z + 0.16],
    );
    let far = SelectionConfig {
        clearance: psgrasp_geometry::HandClearance {
            pregrasp_distance_m: 0.3,
            ..Default::default()
        },
        ..SelectionConfig::default()
    };
    let sel = run(&[c], &grid, &far);
    assert!(sel.picks.is_empty());
    assert_eq!(
        sel.rejected.approach_path_collision, 2,
        "{:?}",
        sel.rejected
    );
    let no_path = SelectionConfig {
        approach_path_samples: 0,
        ..far
    };
    assert_eq!(run(&[c], &grid, &no_path).picks.len(), 1);
}

#[test]
fn fingers_in_a_neighbouring_object_are_a_scene_collision() {
    let (object, c) = box_and_grasp();
    // The +x finger (opening 60 mm) occupies x ∈ [0.318, 0.339]; a neighbour at x ∈ [0.325, 0.355].
    let neighbour = Primitive::Box {
        center_xy: Point2::new(0.34, 0.288),
        size_m: Vector3::new(0.03, 0.06, 0.05),
        yaw_rad: 0.0,
    };
    let grid = scene(&[object, neighbour]);
    let sel = run(&[c], &grid, &SelectionConfig::default());
    assert!(sel.picks.is_empty());
    assert_eq!(sel.rejected.scene_collision, 2, "{:?}", sel.rejected);
}

#[test]
fn configurations_outside_the_bin_or_malformed_are_counted() {
    let grid = scene(&[]);
    let mut nan = config([0.2, 0.2, 0.06], 0.9, &DOWN, 1.0);
    nan.contact.x = f32::NAN;
    let mut not_unit = config([0.2, 0.2, 0.06], 0.9, &DOWN, 1.0);
    not_unit.baseline *= 2.0;
    let mut too_wide = config([0.2, 0.2, 0.06], 0.9, &DOWN, 1.0);
    too_wide.width = 0.1;
    // Second contact 6 mm beyond the +y wall's inner face (y = 0.488): grasping the wall.
    let wall = GraspConfiguration {
        baseline: Vector3::y(),
        width: 0.016,
        ..config([0.3, 0.478, 0.1], 0.9, &DOWN, 1.0)
    };
    let mut nan_quality = config([0.3, 0.3, 0.06], 0.9, &DOWN, 1.0);
    nan_quality.quality = f32::NAN;
    let sel = run(
        &[nan, not_unit, too_wide, wall, nan_quality],
        &grid,
        &SelectionConfig::default(),
    );
    assert!(sel.picks.is_empty());
    assert_eq!(sel.rejected.invalid_configuration, 3);
    assert_eq!(sel.rejected.width, 1);
    assert_eq!(sel.rejected.contact_outside_bin, 1);
    assert_eq!(sel.rejected.get(RejectionReason::ContactOutsideBin), 1);
}

#[test]
fn bad_settings_and_grids_are_errors() {
    let grid = scene(&[]);
    let cfg = SelectionConfig {
        approaches_per_configuration: 19,
        ..SelectionConfig::default()
    };
    assert!(matches!(
        select(&[], &grid.view(), &bin(), &GripperModel::default(), &cfg),
        Err(SelectionError::InvalidConfig {
            field: "approaches_per_configuration",
            ..
        })
    ));
    let mut bad = grid.clone();
    bad.tsdf.pop();
    assert!(matches!(
        select(
            &[],
            &bad.view(),
            &bin(),
            &GripperModel::default(),
            &SelectionConfig::default()
        ),
        Err(SelectionError::Scene(_))
    ));
    let bad_bin = BinModel {
        wall_thickness_m: f32::NAN,
        ..bin()
    };
    assert!(matches!(
        select(
            &[],
            &grid.view(),
            &bad_bin,
            &GripperModel::default(),
            &SelectionConfig::default()
        ),
        Err(SelectionError::InvalidBin(_))
    ));
}

#[test]
fn config_parses_from_toml_with_defaults() {
    let cfg: SelectionConfig = toml::from_str("top_k = 3\nmax_approach_tilt_deg = 45.0\n").unwrap();
    assert_eq!(cfg.top_k, 3);
    assert_eq!(cfg.approaches_per_configuration, 8);
    assert_eq!(cfg.clearance.pregrasp_distance_m, 0.08);
    assert!(toml::from_str::<SelectionConfig>("top_kk = 3\n").is_err());
}

/// Four objects 12 cm apart; the best 20 configurations all lie on the first (within ±1 cm), as
/// a model's do on its favourite object. Without spacing the top four picks are the same grasp
/// millimetres apart; with the default spacing they hit the four objects, best object first.
#[test]
fn picks_spread_over_separated_objects() {
    let grid = scene(&[]);
    let objects = [[0.15f32, 0.2], [0.27, 0.2], [0.39, 0.2], [0.27, 0.32]];
    let mut configs = Vec::new();
    for (o, [x, y]) in objects.iter().enumerate() {
        for j in 0..20 {
            let jitter = (j as f32 / 19.0 - 0.5) * 0.02;
            let quality = if o == 0 {
                0.9 + 0.004 * j as f32
            } else {
                0.6 + 0.05 * o as f32 + 0.001 * j as f32
            };
            configs.push(config([x + jitter, y - jitter, 0.06], quality, &DOWN, 1.0));
        }
    }
    let object_of = |p: &psgrasp_selection::SelectedGrasp| {
        let t = p.workspace_from_gripper.translation.vector;
        objects
            .iter()
            .position(|[x, y]| (t.x - (x + 0.02)).hypot(t.y - y) < 0.03)
            .unwrap()
    };
    let crowded = run(
        &configs,
        &grid,
        &SelectionConfig {
            top_k: 4,
            pick_spacing_m: 0.0,
            ..SelectionConfig::default()
        },
    );
    let hit: Vec<usize> = crowded.picks.iter().map(object_of).collect();
    assert_eq!(hit, vec![0, 0, 0, 0]);
    let cfg = SelectionConfig {
        top_k: 4,
        ..SelectionConfig::default()
    };
    let spread = run(&configs, &grid, &cfg);
    let hit: Vec<usize> = spread.picks.iter().map(object_of).collect();
    assert_eq!(hit, vec![0, 3, 2, 1], "best object first, then by quality");
    assert_eq!(
        spread.picks[0], crowded.picks[0],
        "the best pick is the same"
    );
    assert!(spread.rejected.near_better_pick >= 19 * 3);
    for (i, a) in spread.picks.iter().enumerate() {
        for b in &spread.picks[i + 1..] {
            let d = (a.workspace_from_gripper.translation.vector
                - b.workspace_from_gripper.translation.vector)
                .norm();
            assert!(d >= cfg.pick_spacing_m, "picks {d} m apart");
        }
    }
}

/// `topmost` hands out the highest grasp first, `centre-first` the one nearest the middle of
/// the floor, whatever their quality.
#[test]
fn the_pick_order_policy_decides_which_pick_comes_first() {
    let grid = scene(&[]);
    let c = bin().floor_center;
    let configs = [
        config([c.x - 0.02, c.y, c.z + 0.04], 0.9, &DOWN, 1.0),
        config([c.x + 0.15, c.y, c.z + 0.12], 0.6, &DOWN, 1.0),
        config([c.x - 0.2, c.y + 0.1, c.z + 0.08], 0.7, &DOWN, 1.0),
    ];
    let first = |order: PickOrder| {
        let cfg = SelectionConfig {
            pick_order: order,
            ..SelectionConfig::default()
        };
        let sel = run(&configs, &grid, &cfg);
        assert_eq!(sel.picks.len(), 3);
        sel.picks
            .iter()
            .map(|p| p.configuration_index)
            .collect::<Vec<_>>()
    };
    assert_eq!(first(PickOrder::Quality), vec![0, 2, 1]);
    assert_eq!(first(PickOrder::Topmost), vec![1, 2, 0]);
    assert_eq!(first(PickOrder::CentreFirst), vec![0, 1, 2]);
    // No κ on these configurations (as from the analytic backend): quality order.
    assert_eq!(first(PickOrder::ConfidentQuality), vec![0, 2, 1]);
}

/// `confident-quality` puts a slightly poorer grasp with a far sharper baseline distribution
/// before a better-scored one whose baseline is uncertain; the tolerance decides by how much.
#[test]
fn confident_quality_puts_a_sharp_baseline_before_a_slightly_better_uncertain_one() {
    let grid = scene(&[]);
    let c = bin().floor_center;
    let mut configs = [
        config([c.x - 0.1, c.y, c.z + 0.04], 0.9, &DOWN, 1.0),
        config([c.x + 0.1, c.y, c.z + 0.04], 0.8, &DOWN, 1.0),
    ];
    configs[0].kappa = 25.0;
    configs[1].kappa = 100.0;
    let order = |pick_order: PickOrder, baseline_tolerance_deg: f32| {
        let cfg = SelectionConfig {
            pick_order,
            baseline_tolerance_deg,
            ..SelectionConfig::default()
        };
        picked(&configs, &grid, cfg)
    };
    assert_eq!(order(PickOrder::Quality, 20.0), vec![0, 1]);
    // 20°: 0.9 · 0.55 against 0.8 · 0.96.
    assert_eq!(order(PickOrder::ConfidentQuality, 20.0), vec![1, 0]);
    // 90°: both baselines nearly surely within it, quality decides again.
    assert_eq!(order(PickOrder::ConfidentQuality, 90.0), vec![0, 1]);
    let bad = SelectionConfig {
        baseline_tolerance_deg: 0.0,
        ..SelectionConfig::default()
    };
    assert!(format!("{:?}", bad.validate().unwrap_err()).contains("baseline_tolerance_deg"));
}

/// `confident-first` takes every configuration whose κ lies above its floor before any at the
/// floor, each tier by quality; the floor comes with each configuration (the model card's κ0)
/// unless the setting fixes one, and without κ the quality order stays.
#[test]
fn confident_first_takes_kappa_above_the_floor_before_better_scored_floor_grasps() {
    let grid = scene(&[]);
    let c = bin().floor_center;
    let mut configs = [
        config([c.x - 0.15, c.y, c.z + 0.04], 0.95, &DOWN, 1.0),
        config([c.x, c.y, c.z + 0.04], 0.6, &DOWN, 1.0),
        config([c.x + 0.15, c.y, c.z + 0.04], 0.7, &DOWN, 1.0),
    ];
    for (k, kappa) in configs.iter_mut().zip([25.0, 25.5, 40.0]) {
        k.kappa = kappa;
        k.kappa_floor = 25.0;
    }
    let order = |configs: &[GraspConfiguration], confident_kappa_above: Option<f32>| {
        let cfg = SelectionConfig {
            pick_order: PickOrder::ConfidentFirst,
            confident_kappa_above,
            ..SelectionConfig::default()
        };
        picked(configs, &grid, cfg)
    };
    assert_eq!(order(&configs, None), vec![2, 1, 0]);
    // A model whose floor is 30 sends κ 25 and 25.5 as the same tier.
    for k in configs.iter_mut() {
        k.kappa_floor = 30.0;
    }
    assert_eq!(order(&configs, None), vec![2, 0, 1]);
    // The setting overrides the floors the configurations carry.
    assert_eq!(order(&configs, Some(25.0)), vec![2, 1, 0]);
    // No κ (analytic, VGN-style, oracle: κ = floor = 0): the quality order.
    for k in configs.iter_mut() {
        k.kappa = 0.0;
        k.kappa_floor = 0.0;
    }
    assert_eq!(order(&configs, None), vec![0, 2, 1]);
    let bad = SelectionConfig {
        confident_kappa_above: Some(f32::NAN),
        ..SelectionConfig::default()
    };
    assert!(format!("{:?}", bad.validate().unwrap_err()).contains("confident_kappa_above"));
}

#[test]
fn a_grasp_low_over_the_floor_is_picked_with_the_tool_centre_point_raised() {
    // Contacts 6 mm above the floor in the middle of the bin: with the tool centre point there,
    // the fingertips (9.5 mm beyond it) reach under the floor, so every approach fails.
    let grid = scene(&[]);
    let low = config([0.268, 0.288, floor_z() + 0.006], 0.95, &DOWN, 1.0);
    let flush = SelectionConfig::default();
    let sel = run(&[low], &grid, &flush);
    assert!(sel.picks.is_empty());
    assert_eq!(sel.rejected.bin_collision, 2, "{:?}", sel.rejected);

    // Tried again raised: the first lift that clears the floor (and its margins) is the pick,
    // its pose the unlifted one moved back along the approach by that lift.
    let lifts = vec![0.004, 0.008, 0.012, 0.016, 0.02];
    let raised = SelectionConfig {
        tcp_lifts_m: lifts.clone(),
        ..SelectionConfig::default()
    };
    let sel = run(&[low], &grid, &raised);
    assert_eq!(sel.picks.len(), 1, "{:?}", sel.rejected);
    let pick = sel.picks[0];
    let grasp = low.grasp(pick.approach_index);
    let unlifted = grasp.workspace_from_gripper().translation.vector;
    let moved = pick.workspace_from_gripper.translation.vector - unlifted;
    let lift = moved.norm();
    assert!(
        moved.dot(&grasp.approach) < 0.0,
        "moved {moved:?} not back along the approach"
    );
    let k = lifts
        .iter()
        .position(|l| (l - lift).abs() < 1e-5)
        .unwrap_or_else(|| panic!("lift {lift} is not one of {lifts:?}"));
    let gripper = GripperModel::default();
    let tip = pick.workspace_from_gripper * Point3::new(0.0, 0.0, gripper.tip_beyond_tcp_m);
    assert!(tip.z > floor_z(), "fingertip {tip:?} under the floor");
    // The lifts before it do not clear: the smallest lift that works is taken.
    let fewer = SelectionConfig {
        tcp_lifts_m: lifts[..k].to_vec(),
        ..SelectionConfig::default()
    };
    assert!(run(&[low], &grid, &fewer).picks.is_empty());
}

#[test]
fn tcp_lifts_outside_their_range_are_refused_by_name() {
    for lifts in [
        vec![0.0],
        vec![0.01, 0.005],
        vec![0.06],
        vec![f32::NAN],
        vec![0.001; 9],
    ] {
        let cfg = SelectionConfig {
            tcp_lifts_m: lifts.clone(),
            ..SelectionConfig::default()
        };
        match cfg.validate() {
            Err(SelectionError::InvalidConfig { field, .. }) => {
                assert_eq!(field, "tcp_lifts_m", "{lifts:?}")
            }
            other => panic!("{lifts:?} accepted: {other:?}"),
        }
    }
}

#[test]
fn the_default_config_writes_no_lifts_tolerance_or_fallback_so_stored_configurations_keep_their_form(
) {
    let text = toml::to_string(&SelectionConfig::default()).unwrap();
    assert!(!text.contains("tcp_lifts_m"), "{text}");
    assert!(!text.contains("baseline_tolerance_deg"), "{text}");
    assert!(!text.contains("fallback"), "{text}");
    assert!(!text.contains("wall_distance"), "{text}");
    let raised = SelectionConfig {
        tcp_lifts_m: vec![0.003, 0.006],
        baseline_tolerance_deg: 12.5,
        fallback: Some(FallbackThresholds {
            min_quality: 0.3,
            min_collision_score: 0.2,
            min_contact_wall_distance_m: 0.01,
            approaches_per_configuration: None,
        }),
        ..SelectionConfig::default()
    };
    assert!(toml::to_string(&raised)
        .unwrap()
        .contains("baseline_tolerance_deg = 12.5"));
    let back: SelectionConfig = toml::from_str(&toml::to_string(&raised).unwrap()).unwrap();
    assert_eq!(back, raised);
}

#[test]
fn the_fallback_tier_picks_only_when_nothing_passes_the_primary_thresholds() {
    let grid = scene(&[]);
    let loose = FallbackThresholds {
        min_quality: 0.25,
        min_collision_score: 0.25,
        min_contact_wall_distance_m: 0.0,
        approaches_per_configuration: None,
    };
    let with_fallback = SelectionConfig {
        fallback: Some(loose),
        ..SelectionConfig::default()
    };
    // Under the paper's 0.5: a low collision score, a low quality; both geometrically free.
    let low_score = config([0.20, 0.25, 0.06], 0.9, &DOWN, 0.3);
    let low_quality = config([0.37, 0.25, 0.06], 0.4, &DOWN, 0.9);
    // Below even the fallback's thresholds.
    let hopeless = config([0.288, 0.35, 0.06], 0.2, &DOWN, 0.1);
    let weak = [low_score, low_quality, hopeless];

    // Off (the paper's protocol): nothing.
    let sel = run(&weak, &grid, &SelectionConfig::default());
    assert!(sel.picks.is_empty() && !sel.fallback);
    // On: the two weak-but-free grasps, marked, in quality order; the rejections are the fallback pass's.
    let sel = run(&weak, &grid, &with_fallback);
    assert!(sel.fallback);
    let picked: Vec<usize> = sel.picks.iter().map(|p| p.configuration_index).collect();
    assert_eq!(picked, vec![0, 1], "{:?}", sel.rejected);
    assert_eq!(sel.rejected.quality, 1, "{:?}", sel.rejected);

    // A grasp that passes the primary thresholds: the fallback tier is not used at all.
    let strong = config([0.288, 0.25, 0.06], 0.9, &DOWN, 0.9);
    let sel = run(&[low_score, strong, low_quality], &grid, &with_fallback);
    assert!(!sel.fallback);
    let picked: Vec<usize> = sel.picks.iter().map(|p| p.configuration_index).collect();
    assert_eq!(picked, vec![1]);

    // The fallback relaxes scores only: a weak grasp whose fingers sit in a bin wall stays refused.
    let in_wall = GraspConfiguration {
        baseline: Vector3::y(),
        ..config([0.288, 0.100, 0.06], 0.9, &DOWN, 0.3)
    };
    let sel = run(&[in_wall], &grid, &with_fallback);
    assert!(sel.picks.is_empty() && sel.fallback);
    assert_eq!(sel.rejected.bin_collision, 2, "{:?}", sel.rejected);

    // Its wall distance: a weak grasp 40 mm from the −y wall, closing along the wall (the hand,
    // 63 mm thick, clears it), is taken by a fallback without one and left by one that keeps
    // contacts 50 mm off.
    let by_wall = config([0.288, 0.128, 0.06], 0.9, &DOWN, 0.3);
    let sel = run(&[by_wall], &grid, &with_fallback);
    assert_eq!(sel.picks.len(), 1, "{:?}", sel.rejected);
    let keep_off = SelectionConfig {
        fallback: Some(FallbackThresholds {
            min_contact_wall_distance_m: 0.05,
            ..loose
        }),
        ..SelectionConfig::default()
    };
    let sel = run(&[by_wall], &grid, &keep_off);
    assert!(sel.picks.is_empty() && sel.fallback);
    assert_eq!(sel.rejected.contact_outside_bin, 1, "{:?}", sel.rejected);
    // The primary tier keeps no wall distance: a strong grasp there is picked.
    let strong_by_wall = config([0.288, 0.128, 0.06], 0.9, &DOWN, 0.9);
    assert_eq!(run(&[strong_by_wall], &grid, &keep_off).picks.len(), 1);

    // A fallback stricter than the primary tier is a configuration error.
    let stricter = SelectionConfig {
        fallback: Some(FallbackThresholds {
            min_quality: 0.6,
            min_collision_score: 0.25,
            min_contact_wall_distance_m: 0.0,
            approaches_per_configuration: None,
        }),
        ..SelectionConfig::default()
    };
    let err = select(
        &weak,
        &grid.view(),
        &bin(),
        &GripperModel::default(),
        &stricter,
    )
    .unwrap_err();
    assert!(err.to_string().contains("fallback.min_quality"), "{err}");
}

#[test]
fn the_fallback_tier_may_look_past_the_primary_tiers_approaches() {
    let grid = scene(&[]);
    // Under the paper's 0.5 everywhere: the eight best-scored approaches lie 58–90° from straight
    // down (beyond a 45° reachability cone), the two straight-down ones (8, 9) come ninth and tenth.
    let mut sideways_first = config([0.288, 0.25, 0.06], 0.9, &DOWN, 0.3);
    for i in [0, 1, 2, 3, 14, 15, 16, 17] {
        sideways_first.collision_scores[i] = 0.4;
    }
    let fallback = |approaches| SelectionConfig {
        fallback: Some(FallbackThresholds {
            min_quality: 0.25,
            min_collision_score: 0.25,
            min_contact_wall_distance_m: 0.0,
            approaches_per_configuration: approaches,
        }),
        max_approach_tilt_deg: 45.0,
        ..SelectionConfig::default()
    };
    // The primary tier's eight approaches: every one is tilted out of reach.
    let sel = run(&[sideways_first], &grid, &fallback(None));
    assert!(sel.picks.is_empty() && sel.fallback);
    assert_eq!(sel.rejected.tilt, 8, "{:?}", sel.rejected);
    // All eighteen in the fallback tier: the pick comes straight down.
    let sel = run(&[sideways_first], &grid, &fallback(Some(18)));
    assert!(sel.fallback);
    assert_eq!(sel.picks.len(), 1, "{:?}", sel.rejected);
    assert!(DOWN.contains(&sel.picks[0].approach_index));
    // The primary tier itself keeps its eight: strong scores behind eight sideways ones are
    // found only by the second pass, and the pick says so.
    let mut strong_sideways = config([0.288, 0.25, 0.06], 0.9, &DOWN, 0.9);
    for i in [0, 1, 2, 3, 14, 15, 16, 17] {
        strong_sideways.collision_scores[i] = 0.95;
    }
    let sel = run(&[strong_sideways], &grid, &fallback(Some(18)));
    assert_eq!(sel.picks.len(), 1, "{:?}", sel.rejected);
    assert!(sel.fallback);
}
