//! The clearing protocol on real test scenes with the analytic detector and the ground-truth
//! oracle.
use psgrasp_datagen::Difficulty;
use psgrasp_eval::{
    run_scene_with, Detector, DetectorBackend, DetectorSpec, GraspOutcome, ProtocolConfig,
    SceneEnd, SceneRun,
};
use psgrasp_sim::{MeshLibrary, ObjectLibrary, Split};

fn run_with(
    spec: &DetectorSpec,
    level: Difficulty,
    seed: u64,
    index: u64,
    proto: &ProtocolConfig,
) -> SceneRun {
    let mut detector = spec.build(proto).unwrap();
    run_scene_with(
        level,
        seed,
        index,
        &ObjectLibrary::procedural(),
        &MeshLibrary::default(),
        detector.as_detector(),
        proto,
    )
    .unwrap()
}

fn run(level: Difficulty, seed: u64, index: u64, proto: &ProtocolConfig) -> SceneRun {
    run_with(&DetectorSpec::analytic(), level, seed, index, proto)
}

fn oracle() -> DetectorSpec {
    DetectorSpec::new("oracle", DetectorBackend::Oracle)
}

/// Everything but the wall times.
fn outcome_key(r: &SceneRun) -> String {
    let mut s = r.summary.clone();
    s.detection_ms = 0.0;
    s.scene_ms = 0.0;
    let attempts: Vec<_> = r
        .attempts
        .iter()
        .map(|a| {
            let mut a = a.clone();
            (
                a.render_ms,
                a.fusion_ms,
                a.inference_ms,
                a.selection_ms,
                a.execution_ms,
            ) = (0.0, 0.0, 0.0, 0.0, 0.0);
            a
        })
        .collect();
    format!("{s:?} {attempts:?}")
}

#[test]
fn easy_scene_round_is_consistent_and_deterministic() {
    let proto = ProtocolConfig::default();
    let a = run(Difficulty::Easy, 0, 0, &proto);
    let s = &a.summary;
    assert!(s.attempts >= 1 && s.successes >= 1, "{s:?}");
    assert_eq!(s.attempts as usize, a.attempts.len());
    assert_eq!(
        s.successes as usize,
        a.attempts.iter().filter(|r| r.outcome.is_success()).count()
    );
    // Every object is accounted for: grasped, knocked out, or still there.
    assert_eq!(s.objects, s.successes as usize + s.lost + s.remaining);
    match s.end {
        SceneEnd::Cleared => assert_eq!(s.remaining, 0),
        SceneEnd::NoGrasp => assert_eq!(s.frames, s.attempts + 1),
        SceneEnd::ConsecutiveFailures => assert!(s.attempts >= 3),
        SceneEnd::AttemptLimit => assert_eq!(s.attempts, proto.max_attempts_per_scene),
    }
    // Objects before each attempt go down by one per success (no losses in this scene).
    for w in a.attempts.windows(2) {
        let removed = usize::from(w[0].outcome.is_success()) + w[0].lost;
        assert_eq!(w[1].objects_before, w[0].objects_before - removed);
    }
    assert!(a
        .attempts
        .iter()
        .all(|r| r.quality > 0.5 && r.collision_score > 0.5 && r.opening_m <= 0.08 + 1e-6));
    // Same seed, same run.
    let b = run(Difficulty::Easy, 0, 0, &proto);
    assert_eq!(outcome_key(&a), outcome_key(&b));
}

#[test]
fn three_failures_in_a_row_end_the_scene() {
    // A held object keeps the fingers 30-60 mm apart: demanding 79 mm judges every attempt a
    // failure, so the scene ends after the configured number of failures in a row.
    let mut proto = ProtocolConfig::default();
    // An easy scene where the default protocol attempts at least twice.
    let scene = (0..20)
        .find(|&i| run(Difficulty::Easy, i, 0, &proto).summary.attempts >= 2)
        .expect("an easy scene with two attempts");
    proto.execution.min_opening_m = 0.079;
    proto.max_consecutive_failures = 2;
    let r = run(Difficulty::Easy, scene, 0, &proto);
    assert_eq!(r.summary.successes, 0);
    assert_eq!(r.summary.end, SceneEnd::ConsecutiveFailures);
    assert_eq!(r.summary.attempts, 2);
    assert!(run_scene_with(
        Difficulty::Train,
        0,
        0,
        &ObjectLibrary::procedural(),
        &MeshLibrary::default(),
        Detector::Oracle,
        &proto
    )
    .is_err());
}

#[test]
fn oracle_executes_ground_truth_grasps_and_reports_what_is_left() {
    // Easy scene 0 of seed 0: four boxes and balls. The oracle proposes the labeler's grasps on
    // the true scene: every executed pick is a labelled collision-free approach (score exactly 1).
    let proto = ProtocolConfig::default();
    let a = run_with(&oracle(), Difficulty::Easy, 0, 0, &proto);
    let s = &a.summary;
    assert!(s.successes >= 2, "{s:?}");
    assert!(a
        .attempts
        .iter()
        .all(|r| r.collision_score == 1.0 && r.quality > 0.5));
    assert_eq!(s.objects, s.successes as usize + s.lost + s.remaining);
    // The objects left are reported, each a test object inside the bin.
    assert_eq!(s.remaining_objects.len(), s.remaining);
    let test_names: Vec<String> = ObjectLibrary::procedural()
        .select(Some(Split::Test), true)
        .iter()
        .map(|o| o.spec.name.clone())
        .collect();
    for o in &s.remaining_objects {
        assert!(test_names.contains(&o.name), "{o:?}");
        assert!(o.extent_m.iter().all(|&e| e > 0.0 && e < 0.3), "{o:?}");
        assert!(
            o.center_m[0].abs() < 0.3 && o.center_m[1].abs() < 0.2,
            "{o:?}"
        );
    }
    // Every attempt names the object it aimed at; a ground-truth grasp's TCP (midway between
    // two contacts on a box or ball) lies inside it. A touch is described exactly when the
    // approach was stopped.
    for r in &a.attempts {
        let t = r.target.as_ref().expect("target");
        assert!(test_names.contains(&t.name), "{t:?}");
        assert!(
            ["box", "sphere", "cylinder"].contains(&t.kind.as_str()),
            "{t:?}"
        );
        if r.outcome == GraspOutcome::Success {
            assert!(t.tcp_distance_m < 0.0, "{t:?}");
        }
        assert_eq!(r.approach_touch.is_some(), r.approach_contact, "{r:?}");
        // The pick's pose is recorded: unit, orthogonal axes, the approach pointing down, the
        // TCP inside the bin; no pad fill without the surface check's height map.
        let pose = r.pose.expect("pose");
        let unit = |v: [f32; 3]| nalgebra::Vector3::from(v);
        let (b, a) = (unit(pose.baseline), unit(pose.approach));
        assert!((b.norm() - 1.0).abs() < 1e-4 && (a.norm() - 1.0).abs() < 1e-4);
        assert!(b.dot(&a).abs() < 1e-4 && a.z < 0.0, "{pose:?}");
        assert!(pose.tcp_m[2] > 0.018 && pose.tcp_m[2] < 0.3, "{pose:?}");
        assert_eq!(r.pad_fill, None);
    }
    let b = run_with(&oracle(), Difficulty::Easy, 0, 0, &proto);
    assert_eq!(outcome_key(&a), outcome_key(&b));
}

#[test]
fn objects_left_in_the_bin_are_described() {
    // The analytic detector leaves objects behind in easy scene 1 of seed 0 (boxes, balls and
    // cylinders): each is described with its size and its distance to the nearest side wall.
    let r = run(Difficulty::Easy, 0, 1, &ProtocolConfig::default());
    let s = &r.summary;
    assert!(s.remaining > 0, "{s:?}");
    assert_eq!(s.remaining_objects.len(), s.remaining);
    // The round's start is recorded: every object by its place, every one left by where it
    // started.
    let start = s.start_wall_zones.expect("start zones");
    assert_eq!(start.objects, s.objects);
    for o in &s.remaining_objects {
        assert!(o.start_zone.is_some(), "{o:?}");
        assert!(
            ["box", "sphere", "cylinder"].contains(&o.kind.as_str()),
            "{o:?}"
        );
        if o.kind == "sphere" {
            // A ball's box is a cube.
            assert!((o.extent_m[0] - o.extent_m[2]).abs() < 1e-4, "{o:?}");
        }
        assert!(o.wall_gap_m > -0.01 && o.wall_gap_m < 0.2, "{o:?}");
    }
}

#[test]
fn pregrasps_colliding_in_simulation_are_skipped_not_failed() {
    // A 25 mm margin on the simulated pre-grasp check makes the open hand "collide" whenever
    // an object or a wall is near its pre-grasp pose. By default such a pick is executed and
    // fails at once (`pregrasp_collision`); with the paper's "executable grasp" selection skips
    // it for the next approach or configuration, and no attempt fails that way.
    let mut strict = ProtocolConfig::default();
    strict.execution.pregrasp_margin_m = 0.025;
    strict.max_consecutive_failures = 100;
    strict.max_attempts_per_scene = 4;
    let mut paper = strict.clone();
    paper.skip_colliding_pregrasps = true;
    let pregrasp_failures = |r: &SceneRun| {
        r.attempts
            .iter()
            .filter(|a| a.outcome == GraspOutcome::PregraspCollision)
            .count()
    };
    let (mut failed, mut skipped) = (0, 0);
    for index in 0..3 {
        let a = run(Difficulty::Medium, 0, index, &strict);
        let b = run(Difficulty::Medium, 0, index, &paper);
        failed += pregrasp_failures(&a);
        assert_eq!(pregrasp_failures(&b), 0, "{:?}", b.attempts);
        // Executed picks passed the simulated check; the ones before them were skipped.
        skipped += b
            .attempts
            .iter()
            .map(|a| a.pregrasps_skipped)
            .sum::<usize>();
    }
    assert!(
        failed > 0,
        "the margin should make some default picks collide"
    );
    assert!(
        skipped > 0,
        "the paper's selection should have skipped colliding picks"
    );
}

#[test]
fn the_oracle_physics_check_is_off_by_default_and_its_width_is_checked() {
    let cfg: psgrasp_eval::ProtocolConfig =
        toml::from_str("[oracle]\nphysics_check_max_width_m = 0.02\n").unwrap();
    assert_eq!(cfg.oracle.physics_check_max_width_m, 0.02);
    assert!(cfg.validate().is_ok());
    assert_eq!(
        psgrasp_eval::ProtocolConfig::default()
            .oracle
            .physics_check_max_width_m,
        0.0
    );
    let bad: psgrasp_eval::ProtocolConfig =
        toml::from_str("[oracle]\nphysics_check_max_width_m = -0.01\n").unwrap();
    let err = bad.validate().unwrap_err().to_string();
    assert!(err.contains("oracle.physics_check_max_width_m"), "{err}");
    // Unknown keys in the table are refused, naming them.
    assert!(toml::from_str::<psgrasp_eval::ProtocolConfig>("[oracle]\nwidth = 1\n").is_err());
}

#[test]
fn objects_left_are_traced_to_where_they_started() {
    use psgrasp_eval::RemainingObject;
    use psgrasp_sim::{WallZone, WallZones};
    use psgrasp_test_support::scenes::boxes_on_floor;
    // Three 40 mm cubes of one name in the 600 × 400 mm bin: in the middle, 5 mm from the +x
    // wall, and 5 mm from the +x and +y walls.
    let h = [0.02; 3];
    let first = boxes_on_floor(&[(h, [0.0, 0.0]), (h, [0.275, 0.0]), (h, [0.275, 0.175])]);
    assert_eq!(
        first.wall_zones(),
        WallZones {
            objects: 3,
            near_wall: 2,
            in_corner: 1
        }
    );
    let zones: Vec<_> = (0..3).map(|i| first.object_wall_zone(i).unwrap()).collect();
    assert_eq!(zones, WallZone::ALL);
    // The eval's start records agree with the scene's zones; the wall gap is the nearer one.
    let start = RemainingObject::with_start_zones(&first);
    assert_eq!(start.iter().map(|(_, z)| *z).collect::<Vec<_>>(), zones);
    assert!(
        (start[1].0.wall_gap_m - 0.005).abs() < 1e-4,
        "{}",
        start[1].0.wall_gap_m
    );
    // The wall box was picked; the middle one was pushed 30 mm towards the corner one, which
    // stayed: each keeps the zone it started in, whatever name it shares.
    let end = boxes_on_floor(&[(h, [0.03, 0.02]), (h, [0.275, 0.175])]);
    let mut left = RemainingObject::of_scene(&end);
    assert_eq!(left[0].name, left[1].name);
    RemainingObject::match_start_zones(&mut left, &start);
    let started: Vec<_> = left.iter().map(|o| o.start_zone).collect();
    assert_eq!(started, [Some(WallZone::Interior), Some(WallZone::Corner)]);
}

#[test]
fn a_round_on_a_settled_first_scene_accounts_for_every_stored_object() {
    let plain = ProtocolConfig::default();
    let settled = ProtocolConfig {
        settle_first_scene: true,
        ..ProtocolConfig::default()
    };
    let a = run(Difficulty::Medium, 0, 0, &plain);
    let b = run(Difficulty::Medium, 0, 0, &settled);
    let s = &b.summary;
    // The count is the generated scene's: an object leaving the bin while settling is lost.
    assert_eq!(s.objects, a.summary.objects);
    assert_eq!(s.objects, s.successes as usize + s.lost + s.remaining);
    let lost_settling = s.lost - b.attempts.iter().map(|r| r.lost).sum::<usize>();
    if let Some(first) = b.attempts.first() {
        assert_eq!(first.objects_before, s.objects - lost_settling);
    }
    // The piles moved: the first frame's detection differs from the round without settling.
    assert_ne!(outcome_key(&a), outcome_key(&b));
    assert_eq!(
        outcome_key(&b),
        outcome_key(&run(Difficulty::Medium, 0, 0, &settled))
    );
}
