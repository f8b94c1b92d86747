//! The ground-truth oracle ([`crate::Detector::Oracle`]): the dataset labeler's grasps on the true
//! scene, optionally checked in physics the way ACRONYM checks the paper's labels.
use crate::protocol::{PickTarget, ProtocolConfig};
use nalgebra::Point3;
use psgrasp_datagen::generate_labels;
use psgrasp_geometry::{CameraModel, GraspConfiguration, GripperModel};
use psgrasp_sim::execute::{verify_grasp_in_isolation, ExecutionConfig, GraspCommand};
use psgrasp_sim::{MeshLibrary, Rendering, Scene};
use serde::{Deserialize, Serialize};

/// How the ground-truth oracle's labels are defined beyond the labeler's antipodal test.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OracleConfig {
    /// Labels narrower than this (metres) must also hold their object in ACRONYM's physics
    /// check ([`verify_grasp_in_isolation`]: the object alone, free-floating, closed on and
    /// lifted) before the oracle proposes them; 0 checks none (the labeler's labels as they are).
    pub physics_check_max_width_m: f32,
}

impl Default for OracleConfig {
    fn default() -> Self {
        Self {
            physics_check_max_width_m: 0.0,
        }
    }
}

/// Whether `command` holds the object nearest to its TCP in ACRONYM's check
/// ([`verify_grasp_in_isolation`]); `false` when no object is near or the check fails to run.
pub(crate) fn label_holds_in_isolation(
    scene: &Scene,
    meshes: &MeshLibrary,
    gripper: &GripperModel,
    command: &GraspCommand,
    cfg: &ExecutionConfig,
) -> bool {
    let tcp = Point3::from(command.workspace_from_gripper.translation.vector);
    PickTarget::nearest(scene, &tcp).is_some_and(|t| {
        verify_grasp_in_isolation(scene, meshes, gripper, command, t.index, cfg)
            .is_ok_and(|o| o.is_success())
    })
}

/// The ground-truth labels of `scene` (clean `rendering` from `camera`) as grasp configurations
/// ([`Detector::Oracle`]).
pub(crate) fn oracle_configurations(
    scene: &Scene,
    camera: &CameraModel,
    rendering: &Rendering,
    cfg: &ProtocolConfig,
    seed: u64,
) -> Vec<GraspConfiguration> {
    let gen = &cfg.scenes;
    generate_labels(
        scene,
        camera,
        rendering,
        &gen.cell.gripper,
        &gen.labels,
        seed,
    )
    .labels
    .iter()
    .map(|l| GraspConfiguration {
        contact: l.contact,
        baseline: l.baseline,
        collision_scores: l.collision_free.map(|free| if free { 1.0 } else { 0.0 }),
        width: l.width,
        quality: l.quality,
        kappa: 0.0,
        kappa_floor: 0.0,
    })
    .collect()
}
