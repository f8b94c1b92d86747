//! Core geometry of psgrasp.
//!
//! Frames are named in identifiers: `workspace_from_camera` maps camera-frame points into the
//! workspace frame. The workspace frame has its origin at the minimum corner of the voxel grid,
//! `z` pointing up (against gravity); the camera frame is the usual pinhole frame (`x` right,
//! `y` down, `z` along the optical axis). All lengths are metres unless a name says otherwise.
#![warn(missing_docs)]

pub mod bin;
pub mod camera;
pub mod clearance;
pub mod depth;
pub mod grasp;
pub mod gripper;
pub mod grippers;
pub mod robot;
pub mod setting;
pub mod workspace;

pub use bin::BinModel;
pub use camera::{CameraIntrinsics, CameraModel};
pub use clearance::{commanded_opening_m, HandClearance};
pub use depth::{DepthError, DepthImage, FrameSize, MAX_DEPTH_PIXELS, MAX_IMAGE_SIDE};
pub use grasp::{
    antipodal_quality, approach_angles, approach_vectors, at_first_passing_lift,
    baseline_perpendicular, check_tcp_lifts, ContactGrasp, GraspConfiguration, MAX_TCP_LIFTS,
    N_APPROACHES,
};
pub use gripper::{GripperModel, OrientedBox};
pub use grippers::{GripperTable, DEFAULT_GRIPPER, GRIPPER_FILES};
pub use robot::{BaseFrame, PoseInBase, PoseSetting, RobotCell, RobotConfig};
pub use setting::{check_setting, is_zero, OutOfRange};
pub use workspace::Workspace;

/// The pose with translation `position` and the unit quaternion `xyzw` (x, y, z, w; normalised),
/// as poses are written in configuration files, message fields and JSON.
pub fn pose_from_xyzw(position: [f32; 3], xyzw: [f32; 4]) -> nalgebra::Isometry3<f32> {
    let [x, y, z, w] = xyzw;
    nalgebra::Isometry3::from_parts(
        nalgebra::Translation3::from(nalgebra::Vector3::from(position)),
        nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(w, x, y, z)),
    )
}

/// Errors raised when geometry inputs are invalid.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum GeometryError {
    /// Camera intrinsics are unusable (non-positive focal length, zero size, NaN, ...).
    #[error("invalid camera intrinsics: {0}")]
    InvalidIntrinsics(&'static str),
    /// The workspace description is unusable.
    #[error("invalid workspace: {0}")]
    InvalidWorkspace(&'static str),
    /// A pose contains non-finite numbers.
    #[error("invalid pose: {0}")]
    InvalidPose(&'static str),
    /// The gripper model is unusable (non-positive or non-finite sizes, fingertips beyond the
    /// fingers); see [`GripperModel::validate`].
    #[error("invalid gripper model: {0}")]
    InvalidGripper(&'static str),
    /// The robot cell (`[robot]`: hand-eye calibration, gripper on the flange) is unusable.
    #[error("invalid robot cell: {0}")]
    InvalidRobot(String),
}
