//! [`execute_grasp`]: pre-grasp check, approach, close, lift and hold, judge, settle.
use super::hand::{
    finger_speeds, fingers_touch, first_touch, hand_opening, holding_distance, insert_hand,
    move_palm, touches_per_finger, Hand,
};
use super::world::{collect_scene, execution_world, insert_lone_object, insert_scene, settle};
use super::{
    pregrasp_collides, pregrasp_pose, validate_command, ApproachTouch, Execution, ExecutionConfig,
    ExecutionReport, GraspCommand, GraspOutcome, Phase, TraceSample,
};
use crate::convert::{pose_from_glam, vec_from_glam, vec_to_glam};
use crate::SimError;
use crate::{MeshLibrary, Scene, SceneDescription};
use nalgebra::{Isometry3, Translation3, Vector3};
use psgrasp_geometry::GripperModel;
use rapier3d::prelude::{JointAxis, MotorModel, PhysicsWorld, RigidBodyHandle};

/// Executes one grasp on `scene` (see the module docs). `meshes` must hold the meshes the scene's
/// objects reference. Deterministic.
pub fn execute_grasp(
    scene: &Scene,
    meshes: &MeshLibrary,
    gripper: &GripperModel,
    command: &GraspCommand,
    cfg: &ExecutionConfig,
) -> Result<Execution, SimError> {
    execute_grasp_traced(scene, meshes, gripper, command, cfg, None)
}

/// ACRONYM's check of a grasp label (the paper's labels are verified this way): object
/// `object` of `scene` alone, free-floating at its pose without gravity and without the bin or
/// the other objects, the hand approaching from the pre-grasp pose and closing; gravity is
/// switched on for the lift and hold, and the grasp holds when the object is still between the
/// pads at the end ([`GraspOutcome::Success`]). What a label checked so says is that the pads
/// hold the object, not that the grasp can be reached in the scene (the collision flags).
/// Deterministic.
pub fn verify_grasp_in_isolation(
    scene: &Scene,
    meshes: &MeshLibrary,
    gripper: &GripperModel,
    command: &GraspCommand,
    object: usize,
    cfg: &ExecutionConfig,
) -> Result<GraspOutcome, SimError> {
    cfg.validate()?;
    validate_command(command, gripper)?;
    let opening = command.opening_m.min(gripper.max_opening_m);
    let mut world = execution_world(cfg);
    let gravity = vec_from_glam(world.gravity);
    world.gravity = vec_to_glam(&Vector3::zeros());
    let objects = [insert_lone_object(
        &mut world,
        scene.description(),
        object,
        meshes,
        cfg,
    )?];
    let pregrasp = pregrasp_pose(command, command.pregrasp_distance_m);
    let hand = insert_hand(&mut world, gripper, &pregrasp, opening, cfg);
    let motion = run_motion(
        &mut world,
        &hand,
        &objects,
        command,
        opening,
        cfg,
        Some(gravity),
        &mut |_, _, _, _, _| {},
    );
    Ok(motion.outcome)
}

/// What [`settle_scene`] left.
#[derive(Debug, Clone, PartialEq)]
pub struct SettledScene {
    /// The objects still in the bin, at their poses after settling.
    pub scene_after: SceneDescription,
    /// Indices (in the input scene) of the objects that ended outside the bin.
    pub lost_objects: Vec<usize>,
    /// Physics steps taken.
    pub steps: usize,
    /// True if every object came to rest within the time given.
    pub settled: bool,
}

/// `scene` after resting in the world every attempt runs in (no hand), for at most
/// `max_time_s` simulated seconds. Scene generation settles its piles with its own, softer
/// contacts and a longer time step ([`crate::SettleConfig`]), so objects in a generated pile
/// overlap by what those contacts allow and shift when an attempt's stiffer world resolves the
/// overlaps while the hand moves in; the scene after an attempt has already rested in that world.
/// Settling a generated scene here first gives its first attempt the same footing. Objects that
/// end outside the bin are dropped and listed. Deterministic.
pub fn settle_scene(
    scene: &Scene,
    meshes: &MeshLibrary,
    cfg: &ExecutionConfig,
    max_time_s: f32,
) -> Result<SettledScene, SimError> {
    cfg.validate()?;
    if !(max_time_s.is_finite() && max_time_s >= 0.0) {
        return Err(SimError::InvalidSetting {
            field: "max_time_s",
            reason: "must be a time >= 0 s",
        });
    }
    let desc = scene.description();
    let mut world = execution_world(cfg);
    let objects = insert_scene(&mut world, desc, meshes, cfg)?;
    let max_steps = (max_time_s / cfg.dt_s).ceil() as usize;
    let (steps, settled) = settle(&mut world, &objects, None, cfg, Some(max_steps));
    let (scene_after, lost_objects) = collect_scene(&world, desc, &objects, None);
    Ok(SettledScene {
        scene_after,
        lost_objects,
        steps,
        settled,
    })
}

/// The state after a step, for a trace.
fn sample(
    world: &PhysicsWorld,
    hand: &Hand,
    objects: &[RigidBodyHandle],
    phase: Phase,
    step: usize,
    cfg: &ExecutionConfig,
) -> TraceSample {
    let pose = |h: RigidBodyHandle| {
        world
            .bodies
            .get(h)
            .map_or(Isometry3::identity(), |b| pose_from_glam(b.position()))
    };
    TraceSample {
        phase,
        step,
        opening_m: hand_opening(world, hand),
        workspace_from_palm: pose(hand.palm),
        workspace_from_objects: objects.iter().map(|h| pose(*h)).collect(),
        finger_touches: touches_per_finger(world, hand, holding_distance(cfg)),
    }
}

/// [`execute_grasp`], calling `trace` (when given) after every physics step of the approach,
/// close, lift and hold with where the hand and objects are and what the fingers touch. The
/// outcome does not depend on whether a trace is taken.
pub fn execute_grasp_traced(
    scene: &Scene,
    meshes: &MeshLibrary,
    gripper: &GripperModel,
    command: &GraspCommand,
    cfg: &ExecutionConfig,
    mut trace: Option<&mut dyn FnMut(&TraceSample)>,
) -> Result<Execution, SimError> {
    let mut record =
        |world: &PhysicsWorld, hand: &Hand, objects: &[RigidBodyHandle], phase, step| {
            if let Some(f) = trace.as_mut() {
                f(&sample(world, hand, objects, phase, step, cfg));
            }
        };
    cfg.validate()?;
    validate_command(command, gripper)?;
    let opening = command.opening_m.min(gripper.max_opening_m);
    if pregrasp_collides(scene, gripper, command, cfg) {
        return Ok(Execution {
            report: ExecutionReport {
                outcome: GraspOutcome::PregraspCollision,
                removed_object: None,
                lifted_objects: Vec::new(),
                lost_objects: Vec::new(),
                final_opening_m: opening,
                steps: 0,
                settled: true,
                approach_touch: None,
            },
            scene_after: scene.description().clone(),
        });
    }
    let pregrasp = pregrasp_pose(command, command.pregrasp_distance_m);

    let desc = scene.description();
    let mut world = execution_world(cfg);
    let objects = insert_scene(&mut world, desc, meshes, cfg)?;
    let hand = insert_hand(&mut world, gripper, &pregrasp, opening, cfg);
    let Motion {
        outcome,
        lifted,
        final_opening,
        touch,
        mut steps,
    } = run_motion(
        &mut world,
        &hand,
        &objects,
        command,
        opening,
        cfg,
        None,
        &mut record,
    );

    // Remove the hand (and the held object), let the rest settle.
    for b in [hand.palm, hand.fingers[0], hand.fingers[1]] {
        world.remove_body(b);
    }
    let removed_object = (outcome == GraspOutcome::Success).then(|| lifted[0]);
    if let Some(i) = removed_object {
        world.remove_body(objects[i]);
    }
    let (settle_steps, settled) = settle(&mut world, &objects, removed_object, cfg, None);
    steps += settle_steps;

    let (scene_after, lost_objects) = collect_scene(&world, desc, &objects, removed_object);
    Ok(Execution {
        report: ExecutionReport {
            outcome,
            removed_object,
            lifted_objects: lifted,
            lost_objects,
            final_opening_m: final_opening,
            steps,
            settled,
            approach_touch: touch,
        },
        scene_after,
    })
}

/// What the approach, close, lift and hold of one attempt did.
struct Motion {
    outcome: GraspOutcome,
    lifted: Vec<usize>,
    final_opening: f32,
    touch: Option<ApproachTouch>,
    steps: usize,
}

/// Called after every physics step with the world, the hand, the objects, the phase and the
/// step count (a trace, or nothing).
type StepRecorder<'a> = dyn FnMut(&PhysicsWorld, &Hand, &[RigidBodyHandle], Phase, usize) + 'a;

/// Approach from the pre-grasp pose, close, lift and hold, and judge (steps 2–5 of the module
/// docs) with the hand already at the pre-grasp pose. `gravity_from_lift`: the gravity switched
/// on when the lift starts (ACRONYM's check runs the approach and the closing without it).
#[allow(clippy::too_many_arguments)]
fn run_motion(
    world: &mut PhysicsWorld,
    hand: &Hand,
    objects: &[RigidBodyHandle],
    command: &GraspCommand,
    opening: f32,
    cfg: &ExecutionConfig,
    gravity_from_lift: Option<Vector3<f32>>,
    record: &mut StepRecorder<'_>,
) -> Motion {
    let mut steps = 0usize;

    // Approach.
    let distance = command.pregrasp_distance_m;
    let n_approach = ((distance / (cfg.approach_speed_m_s * cfg.dt_s)).ceil() as usize).max(1);
    let mut touch = None;
    // Where the palm is when the approach ends (the grasp pose unless a touch stopped it).
    let mut reached = command.workspace_from_gripper;
    for s in 1..=n_approach {
        let t = s as f32 / n_approach as f32;
        let short = distance * (1.0 - t);
        let pose = pregrasp_pose(command, short);
        move_palm(world, hand, &pose);
        world.step();
        steps += 1;
        record(world, hand, objects, Phase::Approach, steps);
        if cfg.abort_on_approach_contact {
            if let Some((part, object)) = first_touch(world, hand, cfg.touch_distance_m) {
                touch = Some(ApproachTouch {
                    part,
                    object,
                    short_of_grasp_m: short,
                });
                reached = pose;
                break;
            }
        }
    }

    let mut outcome = GraspOutcome::ApproachContact;
    let mut lifted = Vec::new();
    let mut final_opening = opening;
    if touch.is_none() || cfg.close_after_approach_contact {
        // Close.
        for j in hand.joints {
            if let Some(joint) = world.impulse_joints.get_mut(j, true) {
                // Force-based velocity motor, gain high enough that a blocked finger pushes
                // with the full force limit (an acceleration-based gain scales with the light
                // finger's mass and squeezes with almost nothing).
                let gain = 20.0 * cfg.finger_force_n / cfg.close_speed_m_s;
                joint
                    .data
                    .set_motor_model(JointAxis::LinX, MotorModel::ForceBased)
                    .set_motor_velocity(JointAxis::LinX, -cfg.close_speed_m_s, gain)
                    .set_motor_max_force(JointAxis::LinX, cfg.finger_force_n);
            }
        }
        let max_close = (cfg.max_close_time_s / cfg.dt_s).ceil() as usize;
        let stopped_needed = (cfg.finger_stopped_time_s / cfg.dt_s).ceil() as usize;
        let mut stopped = 0usize;
        for _ in 0..max_close {
            world.step();
            steps += 1;
            record(world, hand, objects, Phase::Close, steps);
            let speed = finger_speeds(world, hand);
            if speed < cfg.finger_stopped_speed_m_s {
                stopped += 1;
                if stopped > stopped_needed {
                    break;
                }
            } else {
                stopped = 0;
            }
        }
        // Lift and hold.
        if let Some(g) = gravity_from_lift {
            world.gravity = vec_to_glam(&g);
        }
        let start_z: Vec<f32> = objects
            .iter()
            .map(|h| world.bodies.get(*h).map_or(0.0, |b| b.translation().z))
            .collect();
        let n_lift = ((cfg.lift_height_m / (cfg.lift_speed_m_s * cfg.dt_s)).ceil() as usize).max(1);
        for s in 1..=n_lift {
            let dz = cfg.lift_height_m * s as f32 / n_lift as f32;
            let pose = Isometry3::from_parts(
                Translation3::from(reached.translation.vector + Vector3::z() * dz),
                reached.rotation,
            );
            move_palm(world, hand, &pose);
            world.step();
            steps += 1;
            record(world, hand, objects, Phase::Lift, steps);
        }
        let n_hold = (cfg.hold_time_s / cfg.dt_s).ceil() as usize;
        for _ in 0..n_hold {
            world.step();
            steps += 1;
            record(world, hand, objects, Phase::Hold, steps);
        }
        final_opening = hand_opening(world, hand);
        lifted = objects
            .iter()
            .enumerate()
            .filter(|(i, h)| {
                world.bodies.get(**h).is_some_and(|b| {
                    b.translation().z - start_z[*i] > cfg.lifted_fraction * cfg.lift_height_m
                })
            })
            .map(|(i, _)| i)
            .collect::<Vec<_>>();
        let touching = fingers_touch(world, hand, holding_distance(cfg));
        outcome = match lifted.as_slice() {
            [] => GraspOutcome::NothingHeld,
            [i] if touching.contains(i) && final_opening > cfg.min_opening_m => {
                GraspOutcome::Success
            }
            [_] => GraspOutcome::NothingHeld,
            _ => GraspOutcome::DoubleGrasp,
        };
    }

    Motion {
        outcome,
        lifted,
        final_opening,
        touch,
        steps,
    }
}
