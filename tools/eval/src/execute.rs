//! Grasp execution in rapier3d: a free-floating Franka hand picks one object.
//!
//! The hand is the [`GripperModel`]'s three boxes: a kinematic palm (moved pose by pose) and two
//! dynamic fingers on prismatic impulse joints, driven by force-limited motors. One attempt
//! ([`execute_grasp`]):
//!
//! 1. **Pre-grasp check.** The open hand at the pre-grasp pose (the grasp pose backed off
//!    [`ExecutionConfig::pregrasp_distance_m`] along −approach) is tested geometrically against the
//!    exact scene, bin included. A collision aborts the attempt ([`GraspOutcome::PregraspCollision`])
//!    before any physics runs.
//! 2. **Approach** from the pre-grasp to the grasp pose at [`ExecutionConfig::approach_speed_m_s`].
//!    Any gripper contact closer than [`ExecutionConfig::touch_distance_m`] stops the hand where
//!    it is: without this, the kinematic palm pushes on and a grasp on an object wider than the
//!    opening can wedge the object between the fingers and "succeed". By default the attempt then
//!    fails ([`GraspOutcome::ApproachContact`]); with
//!    [`ExecutionConfig::close_after_approach_contact`] the hand closes and lifts from where it
//!    stopped, as VGN's and GIGA's clutter-removal simulations do (`allow_contact=True`).
//! 3. **Close** with a velocity motor limited to [`ExecutionConfig::finger_force_n`] per finger
//!    until the fingers stop.
//! 4. **Lift** [`ExecutionConfig::lift_height_m`] straight up from where the approach ended and
//!    **hold**.
//! 5. **Judge.** An object counts as lifted when it rose more than
//!    [`ExecutionConfig::lifted_fraction`] of the lift height. Success: exactly one lifted object,
//!    touching a finger, and an opening above [`ExecutionConfig::min_opening_m`]. Two or more lifted
//!    objects are a [`GraspOutcome::DoubleGrasp`] (a failure, as in the paper).
//! 6. **Settle.** The hand (and a successfully held object) is removed and the rest settles; the
//!    resulting [`SceneDescription`] is what the next attempt sees. Objects that end outside the bin
//!    are dropped from it and reported.
//!
//! Measured pitfalls built in: rapier's default contacts (30 Hz) are too soft to grip, so the
//! contact natural frequency is raised ([`ExecutionConfig::contact_natural_frequency_hz`]); the
//! fingers use impulse joints (multibody joints on a kinematic palm gave no contact response).
//!
//! Same scene, grasp and configuration → the same outcome and the same resulting scene (on one
//! build and platform).
use crate::EvalError;
use nalgebra::{Isometry3, Translation3, Vector3};
use psgrasp_geometry::{BinModel, GripperModel};
use psgrasp_sim::convert::{pose_from_glam, pose_to_glam, vec_to_glam};
use psgrasp_sim::{MeshLibrary, Scene, SceneDescription, SceneObject, SettleConfig};
use rapier3d::prelude::{
    ActiveCollisionTypes, ColliderBuilder, ColliderHandle, Group, ImpulseJointHandle,
    InteractionGroups, InteractionTestMode, JointAxis, MotorModel, PhysicsWorld,
    PrismaticJointBuilder, RigidBodyBuilder, RigidBodyHandle, SharedShape,
};
use serde::{Deserialize, Serialize};

/// Settings of one grasp execution; every threshold has a default.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ExecutionConfig {
    /// Physics time step, seconds.
    pub dt_s: f32,
    /// Velocity-solver iterations per step.
    pub solver_iterations: usize,
    /// Natural frequency of the contact constraints, Hz (rapier's default 30 Hz lets objects
    /// sink into the fingers and slip).
    pub contact_natural_frequency_hz: f32,
    /// Damping ratio of the contact constraints.
    pub contact_damping_ratio: f32,
    /// Distance the pre-grasp pose is backed off along −approach, metres (paper: 5–10 cm).
    pub pregrasp_distance_m: f32,
    /// Margin added to the hand boxes in the geometric pre-grasp check, metres.
    pub pregrasp_margin_m: f32,
    /// Palm speed from the pre-grasp to the grasp pose, m/s.
    pub approach_speed_m_s: f32,
    /// Stop the approach when the hand touches anything (off: the kinematic palm pushes through).
    pub abort_on_approach_contact: bool,
    /// After a stopped approach, close and lift from where the hand stopped instead of failing
    /// the attempt (VGN's and GIGA's `allow_contact=True`). Off by default: a touch fails.
    pub close_after_approach_contact: bool,
    /// A contact point closer than this counts as touching, metres.
    pub touch_distance_m: f32,
    /// Closing speed of each finger, m/s.
    pub close_speed_m_s: f32,
    /// Force limit of each finger motor, newtons (the Franka hand grasps with up to 70 N; a
    /// lower force keeps the soft contacts from sinking millimetres into light objects).
    pub finger_force_n: f32,
    /// Longest closing phase, seconds.
    pub max_close_time_s: f32,
    /// The fingers count as stopped below this speed, m/s ...
    pub finger_stopped_speed_m_s: f32,
    /// ... for this long, seconds.
    pub finger_stopped_time_s: f32,
    /// Mass of each finger, kg.
    pub finger_mass_kg: f32,
    /// Friction coefficient of the finger pads.
    pub finger_friction: f32,
    /// Lift height, metres (straight up in the workspace frame).
    pub lift_height_m: f32,
    /// Lift speed, m/s.
    pub lift_speed_m_s: f32,
    /// Hold time after the lift, seconds.
    pub hold_time_s: f32,
    /// A held object keeps the fingers at least this far apart, metres.
    pub min_opening_m: f32,
    /// An object counts as lifted when it rose more than this fraction of the lift height.
    pub lifted_fraction: f32,
    /// Longest settling time of the remaining objects after the attempt, seconds.
    pub settle_time_s: f32,
    /// Object material, damping and the rest test, shared with scene generation.
    pub objects: SettleConfig,
}

impl Default for ExecutionConfig {
    fn default() -> Self {
        Self {
            dt_s: 1.0 / 240.0,
            solver_iterations: 8,
            contact_natural_frequency_hz: 120.0,
            contact_damping_ratio: 10.0,
            pregrasp_distance_m: 0.08,
            pregrasp_margin_m: 0.0,
            approach_speed_m_s: 0.2,
            abort_on_approach_contact: true,
            close_after_approach_contact: false,
            touch_distance_m: 0.0005,
            close_speed_m_s: 0.1,
            finger_force_n: 20.0,
            max_close_time_s: 0.6,
            finger_stopped_speed_m_s: 0.002,
            finger_stopped_time_s: 0.05,
            finger_mass_kg: 0.05,
            finger_friction: 1.0,
            lift_height_m: 0.15,
            lift_speed_m_s: 0.3,
            hold_time_s: 0.3,
            min_opening_m: 0.002,
            lifted_fraction: 0.5,
            settle_time_s: 1.5,
            objects: SettleConfig::default(),
        }
    }
}

fn check(ok: bool, field: &'static str, reason: &'static str) -> Result<(), EvalError> {
    if ok {
        Ok(())
    } else {
        Err(EvalError::InvalidConfig { field, reason })
    }
}

impl ExecutionConfig {
    /// Checks every field's range.
    pub fn validate(&self) -> Result<(), EvalError> {
        let pos = |v: f32| v.is_finite() && v > 0.0;
        let nonneg = |v: f32| v.is_finite() && v >= 0.0;
        check(
            self.dt_s > 0.0 && self.dt_s <= 0.02,
            "dt_s",
            "must lie in (0, 0.02] s",
        )?;
        check(
            (1..=100).contains(&self.solver_iterations),
            "solver_iterations",
            "must lie in 1..=100",
        )?;
        check(
            pos(self.contact_natural_frequency_hz),
            "contact_natural_frequency_hz",
            "must be > 0",
        )?;
        check(
            pos(self.contact_damping_ratio),
            "contact_damping_ratio",
            "must be > 0",
        )?;
        check(
            nonneg(self.pregrasp_distance_m) && self.pregrasp_distance_m < 1.0,
            "pregrasp_distance_m",
            "must lie in [0, 1) m",
        )?;
        check(
            nonneg(self.pregrasp_margin_m),
            "pregrasp_margin_m",
            "must be >= 0",
        )?;
        check(
            pos(self.approach_speed_m_s),
            "approach_speed_m_s",
            "must be > 0",
        )?;
        check(
            nonneg(self.touch_distance_m),
            "touch_distance_m",
            "must be >= 0",
        )?;
        check(pos(self.close_speed_m_s), "close_speed_m_s", "must be > 0")?;
        check(pos(self.finger_force_n), "finger_force_n", "must be > 0")?;
        check(
            pos(self.max_close_time_s),
            "max_close_time_s",
            "must be > 0",
        )?;
        check(
            pos(self.finger_stopped_speed_m_s),
            "finger_stopped_speed_m_s",
            "must be > 0",
        )?;
        check(
            nonneg(self.finger_stopped_time_s),
            "finger_stopped_time_s",
            "must be >= 0",
        )?;
        check(pos(self.finger_mass_kg), "finger_mass_kg", "must be > 0")?;
        check(
            nonneg(self.finger_friction),
            "finger_friction",
            "must be >= 0",
        )?;
        check(
            pos(self.lift_height_m) && self.lift_height_m < 2.0,
            "lift_height_m",
            "must lie in (0, 2) m",
        )?;
        check(pos(self.lift_speed_m_s), "lift_speed_m_s", "must be > 0")?;
        check(nonneg(self.hold_time_s), "hold_time_s", "must be >= 0")?;
        check(nonneg(self.min_opening_m), "min_opening_m", "must be >= 0")?;
        check(
            self.lifted_fraction > 0.0 && self.lifted_fraction < 1.0,
            "lifted_fraction",
            "must lie in (0, 1)",
        )?;
        check(nonneg(self.settle_time_s), "settle_time_s", "must be >= 0")?;
        let o = &self.objects;
        check(
            nonneg(o.friction) && nonneg(o.restitution) && pos(o.density),
            "objects",
            "friction and restitution must be >= 0, density > 0",
        )?;
        Ok(())
    }
}

/// What to execute: the hand pose at the grasp and the opening to command before closing.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GraspCommand {
    /// Gripper pose at the grasp (x = baseline, z = approach, origin = TCP between the contacts).
    pub workspace_from_gripper: Isometry3<f32>,
    /// Opening before closing, metres (clamped to the gripper's maximum).
    pub opening_m: f32,
}

impl From<&psgrasp_selection::SelectedGrasp> for GraspCommand {
    fn from(g: &psgrasp_selection::SelectedGrasp) -> Self {
        Self {
            workspace_from_gripper: g.workspace_from_gripper,
            opening_m: g.opening_m,
        }
    }
}

/// How an attempt ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GraspOutcome {
    /// Exactly one object was lifted and held.
    Success,
    /// The open hand at the pre-grasp pose overlaps the scene or the bin (no motion executed).
    PregraspCollision,
    /// The hand touched something on its way from the pre-grasp to the grasp pose.
    ApproachContact,
    /// No object was lifted (the fingers closed on nothing, or the object slipped out).
    NothingHeld,
    /// More than one object was lifted.
    DoubleGrasp,
}

impl GraspOutcome {
    /// True for [`GraspOutcome::Success`].
    pub fn is_success(self) -> bool {
        self == GraspOutcome::Success
    }
}

/// What happened in one attempt.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ExecutionReport {
    /// The outcome.
    pub outcome: GraspOutcome,
    /// Index (in the input scene) of the object taken out on success.
    pub removed_object: Option<usize>,
    /// Indices (in the input scene) of the objects that were lifted.
    pub lifted_objects: Vec<usize>,
    /// Indices (in the input scene) of objects that ended outside the bin.
    pub lost_objects: Vec<usize>,
    /// Finger opening at the end of the hold, metres (the commanded opening if never closed).
    pub final_opening_m: f32,
    /// Physics steps simulated.
    pub steps: usize,
    /// Whether the remaining objects came to rest within the settling time.
    pub settled: bool,
    /// The touch that stopped the approach short of the grasp pose (`None`: it reached it).
    pub approach_touch: Option<ApproachTouch>,
}

impl ExecutionReport {
    /// Whether a touch stopped the approach short of the grasp pose.
    pub fn approach_contact(&self) -> bool {
        self.approach_touch.is_some()
    }
}

/// The part of the hand that touched something first on the approach.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum HandPart {
    /// The palm (hand body).
    Palm,
    /// One of the two fingers.
    Finger,
}

/// The touch that stopped an approach: which hand part, what it touched, how far short.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ApproachTouch {
    /// The hand part in contact.
    pub part: HandPart,
    /// Index (in the input scene) of the object touched; `None`: the bin.
    pub object: Option<usize>,
    /// Distance the palm was still short of the grasp pose, metres.
    pub short_of_grasp_m: f32,
}

/// The result of [`execute_grasp`]: the report and the scene the next attempt sees.
#[derive(Debug, Clone, PartialEq)]
pub struct Execution {
    /// What happened.
    pub report: ExecutionReport,
    /// The scene afterwards (held and lost objects removed, the others where physics left them).
    pub scene_after: SceneDescription,
}

const GROUP_HAND: Group = Group::GROUP_1;
const GROUP_WORLD: Group = Group::GROUP_2;
/// `user_data` of bin colliders (objects store their index + 1, the hand 0).
const USER_BIN: u128 = u128::MAX;
/// `user_data` of hand colliders.
const USER_HAND: u128 = 0;

struct Hand {
    palm: RigidBodyHandle,
    fingers: [RigidBodyHandle; 2],
    joints: [ImpulseJointHandle; 2],
    colliders: [ColliderHandle; 3],
    finger_thickness: f32,
}

/// The pre-grasp pose of `command`: the grasp pose backed off `distance` along −approach.
pub fn pregrasp_pose(command: &GraspCommand, distance: f32) -> Isometry3<f32> {
    let pose = command.workspace_from_gripper;
    let approach = pose.rotation * Vector3::z();
    Isometry3::from_parts(
        Translation3::from(pose.translation.vector - approach * distance),
        pose.rotation,
    )
}

/// True if the open hand at `pose` overlaps the exact scene (objects or bin).
pub fn hand_collides(
    scene: &Scene,
    gripper: &GripperModel,
    pose: &Isometry3<f32>,
    opening_m: f32,
    margin_m: f32,
) -> bool {
    gripper.boxes(pose, opening_m).iter().any(|b| {
        let grown = psgrasp_geometry::OrientedBox {
            parent_from_box: b.parent_from_box,
            half_extents: b.half_extents.add_scalar(margin_m),
        };
        scene.box_collides(&grown, None)
    })
}

fn validate_command(command: &GraspCommand, gripper: &GripperModel) -> Result<(), EvalError> {
    let p = &command.workspace_from_gripper;
    let finite = p.translation.vector.iter().all(|v| v.is_finite())
        && p.rotation.coords.iter().all(|v| v.is_finite());
    if !finite {
        return Err(EvalError::InvalidGrasp("pose is not finite"));
    }
    if !(command.opening_m.is_finite() && command.opening_m > 0.0) {
        return Err(EvalError::InvalidGrasp(
            "opening must be positive and finite",
        ));
    }
    if !(gripper.max_opening_m.is_finite() && gripper.max_opening_m > 0.0)
        || gripper
            .finger_size_m
            .iter()
            .chain(&gripper.palm_size_m)
            .any(|v| !(v.is_finite() && *v > 0.0))
    {
        return Err(EvalError::InvalidGrasp("gripper sizes must be positive"));
    }
    Ok(())
}

/// True if the open hand of `command` at its pre-grasp pose overlaps the exact scene: the check
/// [`execute_grasp`] starts with (`cfg.pregrasp_distance_m` back, `cfg.pregrasp_margin_m` grown).
pub fn pregrasp_collides(
    scene: &Scene,
    gripper: &GripperModel,
    command: &GraspCommand,
    cfg: &ExecutionConfig,
) -> bool {
    let opening = command.opening_m.min(gripper.max_opening_m);
    let pregrasp = pregrasp_pose(command, cfg.pregrasp_distance_m);
    hand_collides(scene, gripper, &pregrasp, opening, cfg.pregrasp_margin_m)
}

/// Executes one grasp on `scene` (see the module docs). `meshes` must hold the meshes the scene's
/// objects reference. Deterministic.
pub fn execute_grasp(
    scene: &Scene,
    meshes: &MeshLibrary,
    gripper: &GripperModel,
    command: &GraspCommand,
    cfg: &ExecutionConfig,
) -> Result<Execution, EvalError> {
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
    let pregrasp = pregrasp_pose(command, cfg.pregrasp_distance_m);

    let desc = scene.description();
    let mut world = PhysicsWorld::new();
    world.gravity = vec_to_glam(&Vector3::new(0.0, 0.0, -9.81));
    let ip = &mut world.integration_parameters;
    ip.dt = cfg.dt_s;
    ip.num_solver_iterations = cfg.solver_iterations;
    ip.contact_softness.natural_frequency = cfg.contact_natural_frequency_hz;
    ip.contact_softness.damping_ratio = cfg.contact_damping_ratio;
    // Recycled contacts keep stale distances: the contact abort needs fresh ones.
    ip.contact_recycling = false;
    ip.static_contact_softness.natural_frequency = ip
        .static_contact_softness
        .natural_frequency
        .max(cfg.contact_natural_frequency_hz);

    insert_bin(&mut world, &desc.bin, &cfg.objects);
    let objects = insert_objects(&mut world, desc, meshes, cfg)?;
    let hand = insert_hand(&mut world, gripper, &pregrasp, opening, cfg);
    let mut steps = 0usize;

    // Approach.
    let distance = cfg.pregrasp_distance_m;
    let n_approach = ((distance / (cfg.approach_speed_m_s * cfg.dt_s)).ceil() as usize).max(1);
    let mut touch = None;
    // Where the palm is when the approach ends (the grasp pose unless a touch stopped it).
    let mut reached = command.workspace_from_gripper;
    for s in 1..=n_approach {
        let t = s as f32 / n_approach as f32;
        let short = distance * (1.0 - t);
        let pose = pregrasp_pose(command, short);
        move_palm(&mut world, &hand, &pose);
        world.step();
        steps += 1;
        if cfg.abort_on_approach_contact {
            if let Some((part, object)) = first_touch(&world, &hand, cfg.touch_distance_m) {
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
            let speed = finger_speeds(&world, &hand);
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
            move_palm(&mut world, &hand, &pose);
            world.step();
            steps += 1;
        }
        let n_hold = (cfg.hold_time_s / cfg.dt_s).ceil() as usize;
        for _ in 0..n_hold {
            world.step();
            steps += 1;
        }
        final_opening = hand_opening(&world, &hand);
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
        let touching = fingers_touch(&world, &hand, cfg.touch_distance_m.max(0.002));
        outcome = match lifted.as_slice() {
            [] => GraspOutcome::NothingHeld,
            [i] if touching.contains(i) && final_opening > cfg.min_opening_m => {
                GraspOutcome::Success
            }
            [_] => GraspOutcome::NothingHeld,
            _ => GraspOutcome::DoubleGrasp,
        };
    }

    // Remove the hand (and the held object), let the rest settle.
    for b in [hand.palm, hand.fingers[0], hand.fingers[1]] {
        world.remove_body(b);
    }
    let removed_object = (outcome == GraspOutcome::Success).then(|| lifted[0]);
    if let Some(i) = removed_object {
        world.remove_body(objects[i]);
    }
    let (settle_steps, settled) = settle(&mut world, &objects, removed_object, cfg);
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

fn world_groups() -> InteractionGroups {
    InteractionGroups::new(GROUP_WORLD, Group::ALL, InteractionTestMode::And)
}

fn hand_groups() -> InteractionGroups {
    InteractionGroups::new(GROUP_HAND, GROUP_WORLD, InteractionTestMode::And)
}

fn insert_bin(world: &mut PhysicsWorld, bin: &BinModel, material: &SettleConfig) {
    // Walls padded outward (as in scene generation) so that nothing tunnels through them.
    let pad = material.wall_padding_m.max(0.0);
    let outward = [
        Vector3::new(0.0, 0.0, -1.0),
        -Vector3::x(),
        Vector3::x(),
        -Vector3::y(),
        Vector3::y(),
    ];
    for (b, dir) in bin.boxes().iter().zip(outward) {
        let half = b.half_extents + dir.abs() * (0.5 * pad);
        let centre = b.parent_from_box.translation.vector + dir * (0.5 * pad);
        let collider = ColliderBuilder::new(SharedShape::cuboid(half.x, half.y, half.z))
            .position(pose_to_glam(&Isometry3::translation(
                centre.x, centre.y, centre.z,
            )))
            .friction(material.friction)
            .restitution(material.restitution)
            .collision_groups(world_groups())
            .user_data(USER_BIN)
            .build();
        world.insert_collider(collider, None);
    }
}

fn insert_objects(
    world: &mut PhysicsWorld,
    desc: &SceneDescription,
    meshes: &MeshLibrary,
    cfg: &ExecutionConfig,
) -> Result<Vec<RigidBodyHandle>, EvalError> {
    let m = &cfg.objects;
    let mut handles = Vec::with_capacity(desc.objects.len());
    for (i, obj) in desc.objects.iter().enumerate() {
        let shape = obj.spec.build_physics_shape(meshes)?;
        let body = RigidBodyBuilder::dynamic()
            .pose(pose_to_glam(&obj.workspace_from_object))
            .linear_damping(m.linear_damping.max(0.0))
            .angular_damping(m.angular_damping.max(0.0))
            .user_data(i as u128 + 1)
            .build();
        let h = world.insert_body(body);
        let collider = ColliderBuilder::new(shape)
            .friction(m.friction)
            .restitution(m.restitution)
            .density(m.density)
            .collision_groups(world_groups())
            .user_data(i as u128 + 1)
            .build();
        world.insert_collider(collider, Some(h));
        handles.push(h);
    }
    Ok(handles)
}

fn insert_hand(
    world: &mut PhysicsWorld,
    gripper: &GripperModel,
    pose: &Isometry3<f32>,
    opening: f32,
    cfg: &ExecutionConfig,
) -> Hand {
    let [palm_box, left_box, right_box] = gripper.boxes_in_gripper_frame(opening);
    let palm = world.insert_body(
        RigidBodyBuilder::kinematic_position_based()
            .pose(pose_to_glam(pose))
            .build(),
    );
    let palm_collider = ColliderBuilder::new(SharedShape::cuboid(
        palm_box.half_extents.x,
        palm_box.half_extents.y,
        palm_box.half_extents.z,
    ))
    .position(pose_to_glam(&palm_box.parent_from_box))
    // A kinematic body has no contacts with fixed ones (the bin) unless asked for.
    .active_collision_types(ActiveCollisionTypes::all())
    .collision_groups(hand_groups())
    .user_data(USER_HAND)
    .build();
    let palm_c = world.insert_collider(palm_collider, Some(palm));
    let ft = gripper.finger_size_m[0];
    let finger_z = left_box.parent_from_box.translation.z;
    let mut fingers = [palm; 2];
    let mut joints = [ImpulseJointHandle::invalid(); 2];
    let mut colliders = [palm_c; 3];
    for (k, (b, sign)) in [(left_box, -1.0f32), (right_box, 1.0)]
        .into_iter()
        .enumerate()
    {
        let body = world.insert_body(
            RigidBodyBuilder::dynamic()
                .pose(pose_to_glam(&(pose * b.parent_from_box)))
                .can_sleep(false)
                .build(),
        );
        let c = ColliderBuilder::new(SharedShape::cuboid(
            b.half_extents.x,
            b.half_extents.y,
            b.half_extents.z,
        ))
        .mass(cfg.finger_mass_kg)
        .friction(cfg.finger_friction)
        .restitution(0.0)
        .collision_groups(hand_groups())
        .user_data(USER_HAND)
        .build();
        colliders[k + 1] = world.insert_collider(c, Some(body));
        let axis = vec_to_glam(&(Vector3::x() * sign));
        let joint = PrismaticJointBuilder::new(axis)
            .local_anchor1(vec_to_glam(&Vector3::new(sign * 0.5 * ft, 0.0, finger_z)))
            .local_anchor2(vec_to_glam(&Vector3::zeros()))
            .limits([0.0, 0.5 * gripper.max_opening_m])
            .motor_position(0.5 * opening, 1.0e4, 200.0)
            .motor_max_force(cfg.finger_force_n.max(200.0))
            .contacts_enabled(false)
            .build();
        joints[k] = world.insert_impulse_joint(palm, body, joint);
        fingers[k] = body;
    }
    Hand {
        palm,
        fingers,
        joints,
        colliders,
        finger_thickness: ft,
    }
}

fn move_palm(world: &mut PhysicsWorld, hand: &Hand, pose: &Isometry3<f32>) {
    if let Some(b) = world.bodies.get_mut(hand.palm) {
        b.set_next_kinematic_position(pose_to_glam(pose));
    }
}

/// What hand collider `collider` touches closer than `touch`, one item per contact pair:
/// `Some(object index)`, or `None` for the bin (hand parts only meet the world: `hand_groups`).
fn touched_by(
    world: &PhysicsWorld,
    collider: ColliderHandle,
    touch: f32,
) -> impl Iterator<Item = Option<usize>> + '_ {
    world
        .narrow_phase
        .contact_pairs_with(collider)
        .filter_map(move |pair| {
            let close = pair
                .manifolds()
                .iter()
                .any(|m| m.points.iter().any(|p| p.dist < touch));
            let other = if pair.collider1 == collider {
                pair.collider2
            } else {
                pair.collider1
            };
            let data = world.colliders.get(other)?.user_data;
            close.then(|| (data != USER_BIN && data != USER_HAND).then(|| (data - 1) as usize))
        })
}

/// The first hand collider (palm, then fingers) touching something closer than `touch`, and
/// what it touches (`Some(object index)`, `None` for the bin).
fn first_touch(world: &PhysicsWorld, hand: &Hand, touch: f32) -> Option<(HandPart, Option<usize>)> {
    hand.colliders.iter().enumerate().find_map(|(k, c)| {
        let part = if k == 0 {
            HandPart::Palm
        } else {
            HandPart::Finger
        };
        touched_by(world, *c, touch)
            .next()
            .map(|object| (part, object))
    })
}

/// Object indices with a contact closer than `touch` to either finger.
fn fingers_touch(world: &PhysicsWorld, hand: &Hand, touch: f32) -> Vec<usize> {
    let mut out: Vec<usize> = hand.colliders[1..]
        .iter()
        .flat_map(|c| touched_by(world, *c, touch))
        .flatten()
        .collect();
    out.sort_unstable();
    out.dedup();
    out
}

/// Largest finger speed along the closing axis relative to the palm, m/s.
fn finger_speeds(world: &PhysicsWorld, hand: &Hand) -> f32 {
    let Some(palm) = world.bodies.get(hand.palm) else {
        return 0.0;
    };
    let x = palm.position().rotation * parry3d::math::Vector::X;
    hand.fingers
        .iter()
        .filter_map(|f| world.bodies.get(*f))
        .map(|f| (f.linvel() - palm.linvel()).dot(x).abs())
        .fold(0.0, f32::max)
}

/// Gap between the finger pads, metres.
fn hand_opening(world: &PhysicsWorld, hand: &Hand) -> f32 {
    let (Some(palm), Some(l), Some(r)) = (
        world.bodies.get(hand.palm),
        world.bodies.get(hand.fingers[0]),
        world.bodies.get(hand.fingers[1]),
    ) else {
        return 0.0;
    };
    let inv = pose_from_glam(palm.position()).inverse();
    let xl = (inv * pose_from_glam(l.position())).translation.x;
    let xr = (inv * pose_from_glam(r.position())).translation.x;
    (xr - xl - hand.finger_thickness).max(0.0)
}

/// Steps until every remaining object rests or the settling time runs out.
fn settle(
    world: &mut PhysicsWorld,
    objects: &[RigidBodyHandle],
    removed: Option<usize>,
    cfg: &ExecutionConfig,
) -> (usize, bool) {
    let max_steps = (cfg.settle_time_s / cfg.dt_s).ceil() as usize;
    let at_rest = |world: &PhysicsWorld| {
        objects.iter().enumerate().all(|(i, h)| {
            Some(i) == removed
                || world.bodies.get(*h).is_none_or(|b| {
                    b.is_sleeping()
                        || (b.linvel().length() < cfg.objects.rest_linear_speed
                            && b.angvel().length() < cfg.objects.rest_angular_speed)
                })
        })
    };
    let mut steps = 0;
    let mut rest = at_rest(world);
    while !rest && steps < max_steps {
        world.step();
        steps += 1;
        if steps.is_multiple_of(5) {
            rest = at_rest(world);
        }
    }
    (steps, rest)
}

/// The remaining objects with their new poses; objects outside the bin are left out and listed.
fn collect_scene(
    world: &PhysicsWorld,
    desc: &SceneDescription,
    objects: &[RigidBodyHandle],
    removed: Option<usize>,
) -> (SceneDescription, Vec<usize>) {
    let bin = &desc.bin;
    let c = bin.floor_center;
    let [lx, ly, _] = bin.inner_size_m;
    let mut kept = Vec::new();
    let mut lost = Vec::new();
    for (i, (obj, h)) in desc.objects.iter().zip(objects).enumerate() {
        if Some(i) == removed {
            continue;
        }
        let pose = world
            .bodies
            .get(*h)
            .map(|b| pose_from_glam(b.position()))
            .filter(|p| p.translation.vector.iter().all(|v| v.is_finite()));
        let inside = pose.is_some_and(|p| {
            let t = p.translation.vector;
            (t.x - c.x).abs() <= 0.5 * lx
                && (t.y - c.y).abs() <= 0.5 * ly
                && t.z >= c.z - 0.01
                && t.z <= bin.rim_z() + 0.05
        });
        match pose {
            Some(p) if inside => kept.push(SceneObject {
                spec: obj.spec.clone(),
                workspace_from_object: p,
            }),
            _ => lost.push(i),
        }
    }
    (
        SceneDescription {
            bin: *bin,
            objects: kept,
        },
        lost,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn partial_toml_keeps_defaults_and_rejects_typos() {
        let cfg: ExecutionConfig = toml::from_str("lift_height_m = 0.1\n").unwrap();
        assert_eq!(cfg.lift_height_m, 0.1);
        assert_eq!(cfg.dt_s, ExecutionConfig::default().dt_s);
        assert!(toml::from_str::<ExecutionConfig>("lift_hieght_m = 0.1\n").is_err());
    }

    #[test]
    fn bad_settings_and_commands_are_errors() {
        let bad = ExecutionConfig {
            lifted_fraction: 1.5,
            ..Default::default()
        };
        assert!(matches!(
            bad.validate(),
            Err(EvalError::InvalidConfig {
                field: "lifted_fraction",
                ..
            })
        ));
        let g = GripperModel::default();
        let mut cmd = GraspCommand {
            workspace_from_gripper: Isometry3::identity(),
            opening_m: 0.05,
        };
        assert!(validate_command(&cmd, &g).is_ok());
        cmd.opening_m = f32::NAN;
        assert!(matches!(
            validate_command(&cmd, &g),
            Err(EvalError::InvalidGrasp(_))
        ));
        cmd.opening_m = 0.05;
        cmd.workspace_from_gripper.translation.x = f32::INFINITY;
        assert!(validate_command(&cmd, &g).is_err());
    }

    #[test]
    fn pregrasp_backs_off_along_the_approach() {
        let cmd = GraspCommand {
            workspace_from_gripper: Isometry3::translation(0.1, 0.2, 0.3),
            opening_m: 0.05,
        };
        // Identity rotation: approach = +z, so the pre-grasp lies below.
        let p = pregrasp_pose(&cmd, 0.08);
        assert!((p.translation.vector - Vector3::new(0.1, 0.2, 0.22)).norm() < 1e-6);
    }
}
