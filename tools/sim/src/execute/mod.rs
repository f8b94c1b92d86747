//! Grasp execution in rapier3d: a free-floating Franka hand picks one object.
//!
//! The hand is the [`GripperModel`]'s three boxes: a kinematic palm (moved pose by pose) and two
//! dynamic fingers on prismatic impulse joints, driven by force-limited motors. One attempt
//! ([`execute_grasp`]):
//!
//! 1. **Pre-grasp check.** The open hand at the pre-grasp pose (the grasp pose backed off
//!    [`GraspCommand::pregrasp_distance_m`], selection's `clearance.pregrasp_distance_m`, along −approach) is tested geometrically against the
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
//!
//! The code: `config` (the settings), `world` (the rapier world: bin, objects, settling and the
//! scene afterwards), `hand` (the hand's bodies, joints and touch decoding) and `sequence`
//! ([`execute_grasp`]: the steps above).
mod config;
mod hand;
mod sequence;
mod world;

pub use config::ExecutionConfig;
pub use sequence::{
    execute_grasp, execute_grasp_traced, settle_scene, verify_grasp_in_isolation, SettledScene,
};

use crate::SimError;
use crate::{Scene, SceneDescription};
use nalgebra::{Isometry3, Translation3, Vector3};
use psgrasp_geometry::GripperModel;
use serde::{Deserialize, Serialize};

/// What to execute: the hand pose at the grasp and the opening to command before closing.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GraspCommand {
    /// Gripper pose at the grasp (x = baseline, z = approach, origin = TCP between the contacts).
    pub workspace_from_gripper: Isometry3<f32>,
    /// Opening before closing, metres (clamped to the gripper's maximum).
    pub opening_m: f32,
    /// How far before the grasp pose the approach starts, along −approach, metres (the pick's
    /// pre-grasp pose).
    pub pregrasp_distance_m: f32,
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

/// The motion phase a [`TraceSample`] was taken in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Phase {
    /// From the pre-grasp towards the grasp pose.
    Approach,
    /// Fingers closing.
    Close,
    /// Lifting straight up.
    Lift,
    /// Holding at the lift height.
    Hold,
}

/// The state after one physics step of [`execute_grasp_traced`]: where the hand and the objects
/// are and what each finger touches (to follow one attempt step by step).
#[derive(Debug, Clone, PartialEq)]
pub struct TraceSample {
    /// The phase of the step.
    pub phase: Phase,
    /// Physics steps so far.
    pub step: usize,
    /// Gap between the finger pads, metres.
    pub opening_m: f32,
    /// The palm's (gripper frame's) pose in the workspace.
    pub workspace_from_palm: Isometry3<f32>,
    /// Every object's pose in the workspace (input scene order).
    pub workspace_from_objects: Vec<Isometry3<f32>>,
    /// Object indices each finger (left, right) touches closer than the touch distance.
    pub finger_touches: [Vec<usize>; 2],
}

/// The result of [`execute_grasp`]: the report and the scene the next attempt sees.
#[derive(Debug, Clone, PartialEq)]
pub struct Execution {
    /// What happened.
    pub report: ExecutionReport,
    /// The scene afterwards (held and lost objects removed, the others where physics left them).
    pub scene_after: SceneDescription,
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

fn validate_command(command: &GraspCommand, gripper: &GripperModel) -> Result<(), SimError> {
    let p = &command.workspace_from_gripper;
    let finite = p.translation.vector.iter().all(|v| v.is_finite())
        && p.rotation.coords.iter().all(|v| v.is_finite());
    if !finite {
        return Err(SimError::InvalidGrasp("pose is not finite"));
    }
    if !(command.opening_m.is_finite() && command.opening_m > 0.0) {
        return Err(SimError::InvalidGrasp(
            "opening must be positive and finite",
        ));
    }
    if !(command.pregrasp_distance_m.is_finite()
        && (0.0..1.0).contains(&command.pregrasp_distance_m))
    {
        return Err(SimError::InvalidGrasp(
            "pre-grasp distance must lie in [0, 1) m",
        ));
    }
    if !(gripper.max_opening_m.is_finite() && gripper.max_opening_m > 0.0)
        || gripper
            .finger_size_m
            .iter()
            .chain(&gripper.palm_size_m)
            .any(|v| !(v.is_finite() && *v > 0.0))
    {
        return Err(SimError::InvalidGrasp("gripper sizes must be positive"));
    }
    Ok(())
}

/// True if the open hand of `command` at its pre-grasp pose overlaps the exact scene: the check
/// [`execute_grasp`] starts with (`command.pregrasp_distance_m` back, `cfg.pregrasp_margin_m` grown).
pub fn pregrasp_collides(
    scene: &Scene,
    gripper: &GripperModel,
    command: &GraspCommand,
    cfg: &ExecutionConfig,
) -> bool {
    let opening = command.opening_m.min(gripper.max_opening_m);
    let pregrasp = pregrasp_pose(command, command.pregrasp_distance_m);
    hand_collides(scene, gripper, &pregrasp, opening, cfg.pregrasp_margin_m)
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
            Err(SimError::InvalidSetting {
                field: "lifted_fraction",
                ..
            })
        ));
        let g = GripperModel::default();
        let mut cmd = GraspCommand {
            workspace_from_gripper: Isometry3::identity(),
            opening_m: 0.05,
            pregrasp_distance_m: 0.08,
        };
        assert!(validate_command(&cmd, &g).is_ok());
        cmd.opening_m = f32::NAN;
        assert!(matches!(
            validate_command(&cmd, &g),
            Err(SimError::InvalidGrasp(_))
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
            pregrasp_distance_m: 0.08,
        };
        // Identity rotation: approach = +z, so the pre-grasp lies below.
        let p = pregrasp_pose(&cmd, 0.08);
        assert!((p.translation.vector - Vector3::new(0.1, 0.2, 0.22)).norm() < 1e-6);
    }
}
