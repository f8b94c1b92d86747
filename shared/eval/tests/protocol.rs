//! The clearing protocol on real test scenes with the analytic detector.
use psgrasp_datagen::Difficulty;
use psgrasp_eval::{run_scene, DetectorSpec, ProtocolConfig, SceneEnd, SceneRun};
use psgrasp_sim::{MeshLibrary, ObjectLibrary};

fn run(level: Difficulty, seed: u64, index: u64, proto: &ProtocolConfig) -> SceneRun {
    let mut backend = DetectorSpec::analytic().build(proto).unwrap();
    run_scene(
        level,
        seed,
        index,
        &ObjectLibrary::procedural(),
        &MeshLibrary::default(),
        backend.as_mut(),
        proto,
    )
    .unwrap()
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
    proto.execution.min_opening_m = 0.079;
    proto.max_consecutive_failures = 2;
    let r = run(Difficulty::Easy, 0, 0, &proto);
    assert_eq!(r.summary.successes, 0);
    assert_eq!(r.summary.end, SceneEnd::ConsecutiveFailures);
    assert_eq!(r.summary.attempts, 2);
    assert!(run_scene(
        Difficulty::Train,
        0,
        0,
        &ObjectLibrary::procedural(),
        &MeshLibrary::default(),
        DetectorSpec::analytic().build(&proto).unwrap().as_mut(),
        &proto
    )
    .is_err());
}
