//! The graspability verdict on hand-placed scenes whose answer is known.
use psgrasp_datagen::{graspability, GraspabilityConfig, GraspabilityVerdict, LabelConfig};
use psgrasp_geometry::GripperModel;
use psgrasp_sim::Scene;
use psgrasp_test_support::scenes::boxes_on_floor;

fn verdict_of(scene: &Scene, object: usize) -> psgrasp_datagen::Graspability {
    graspability(
        scene,
        &GripperModel::default(),
        &LabelConfig::default(),
        object,
        1000,
        &GraspabilityConfig::default(),
        11,
    )
}

#[test]
fn a_free_cube_in_the_middle_is_graspable() {
    let scene = boxes_on_floor(&[([0.02, 0.02, 0.02], [0.0, 0.0])]);
    let g = verdict_of(&scene, 0);
    assert_eq!(g.verdict, GraspabilityVerdict::Graspable, "{g:?}");
    assert!(g.free > 0 && g.antipodal_pairs > 0);
}

#[test]
fn a_plate_wider_than_the_opening_is_blocked_by_the_floor() {
    // 120 × 120 × 16 mm: the only pairs that fit the 80 mm opening pinch its thickness, and a
    // finger under it would go through the floor.
    let scene = boxes_on_floor(&[([0.06, 0.06, 0.008], [0.0, 0.0])]);
    let g = verdict_of(&scene, 0);
    assert_eq!(g.verdict, GraspabilityVerdict::Floor, "{g:?}");
    assert_eq!(g.free, 0);
}

#[test]
fn a_cube_wider_than_the_opening_in_every_direction_has_no_grasp() {
    let scene = boxes_on_floor(&[([0.05, 0.05, 0.05], [0.0, 0.0])]);
    let g = verdict_of(&scene, 0);
    assert_eq!(g.verdict, GraspabilityVerdict::NoGraspFitsHand, "{g:?}");
    assert_eq!(g.antipodal_pairs, 0);
}

#[test]
fn a_cube_in_a_corner_is_blocked_by_the_walls() {
    // The default bin is 600 × 400 mm: the cube touches the −x and −y walls within 1 mm.
    let scene = boxes_on_floor(&[([0.02, 0.02, 0.02], [-0.279, -0.179])]);
    let g = verdict_of(&scene, 0);
    assert_eq!(g.verdict, GraspabilityVerdict::Wall, "{g:?}");
    assert!(g.blocked.wall > g.blocked.floor + g.blocked.other_objects);
}

#[test]
fn a_cube_boxed_in_by_neighbours_is_blocked_by_other_objects() {
    // A 40 mm cube with a taller 40 mm-wide block touching it on each side (1 mm gaps).
    let h = [0.02, 0.02, 0.02];
    let side = [0.02, 0.06, 0.04];
    let front = [0.06, 0.02, 0.04];
    let scene = boxes_on_floor(&[
        (h, [0.0, 0.0]),
        (side, [0.041, 0.0]),
        (side, [-0.041, 0.0]),
        (front, [0.0, 0.041]),
        (front, [0.0, -0.041]),
    ]);
    let g = verdict_of(&scene, 0);
    assert_eq!(g.verdict, GraspabilityVerdict::OtherObjects, "{g:?}");
    // Taken out of the ring, the same cube is graspable: the neighbours were the blockers.
    let alone = boxes_on_floor(&[(h, [0.0, 0.0])]);
    assert_eq!(
        verdict_of(&alone, 0).verdict,
        GraspabilityVerdict::Graspable
    );
}

#[test]
fn the_verdict_is_deterministic_for_a_seed_and_hidden_objects_are_named() {
    let scene = boxes_on_floor(&[([0.02, 0.02, 0.02], [0.1, 0.0])]);
    let a = verdict_of(&scene, 0);
    assert_eq!(a, verdict_of(&scene, 0));
    let hidden = graspability(
        &scene,
        &GripperModel::default(),
        &LabelConfig::default(),
        0,
        3,
        &GraspabilityConfig::default(),
        11,
    );
    assert_eq!(hidden.verdict, GraspabilityVerdict::Hidden);
    assert_eq!((hidden.free, hidden.poses), (a.free, a.poses));
}

#[test]
fn a_low_bar_blocked_by_the_floor_is_reached_with_the_tool_centre_point_raised() {
    // A 60 × 14 × 8 mm bar lying flat: with the contacts at the tool centre point the fingertips
    // (9.5 mm beyond it) end under the floor for every pair. Raised along the approach, the
    // hand clears the floor for the pairs across the bar (their baselines tilted in the friction
    // cone put the lower finger deeper, so it takes more than the 8 mm the bar is thick).
    let scene = boxes_on_floor(&[([0.03, 0.007, 0.004], [0.0, 0.0])]);
    let at = |lifts_m: &[f32]| {
        graspability(
            &scene,
            &GripperModel::default(),
            &LabelConfig {
                tcp_lifts_m: lifts_m.to_vec(),
                ..LabelConfig::default()
            },
            0,
            1000,
            &GraspabilityConfig::default(),
            11,
        )
    };
    let flush = at(&[]);
    assert_eq!(flush.verdict, GraspabilityVerdict::Floor, "{flush:?}");
    assert_eq!(flush.free, 0);
    let raised = at(&[0.01, 0.02]);
    assert_eq!(raised.verdict, GraspabilityVerdict::Graspable, "{raised:?}");
    assert_eq!(raised.antipodal_pairs, flush.antipodal_pairs);
    assert!(raised.free > 10, "{raised:?}");
}
