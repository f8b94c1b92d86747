//! Collision checks against the observed scene.
//!
//! [`OccupancyGrid`] turns a fused normal grid (or a bare normalised TSDF) into occupied voxels,
//! stored as per-column prefix counts so that an oriented box costs one interval per column of its
//! footprint; [`SceneCollisionChecker`] pairs it with a [`GripperModel`] and tests the palm and
//! finger boxes of a grasp pose against it. The analytic inference backend scores approaches with
//! it and grasp selection rejects colliding picks with it; see [`occupancy`] for the rules.
#![warn(missing_docs)]

pub mod occupancy;
pub mod surface;

pub use occupancy::{OccupancyConfig, OccupancyGrid, SceneCollisionChecker};
pub use surface::{cells_under_surface_in_box, volume_share_under_surface};

use psgrasp_fusion::GridError;
use psgrasp_geometry::GeometryError;
#[cfg(doc)]
use psgrasp_geometry::GripperModel;

/// Errors of building an occupancy grid or checking the scene's inputs.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum CollisionError {
    /// The normal grid or TSDF is unusable (workspace, buffer length, non-finite or out-of-range
    /// values, truncation distance).
    #[error(transparent)]
    Grid(#[from] GridError),
    /// An occupancy setting is out of its valid range.
    #[error("invalid configuration field `{field}`: {reason}")]
    InvalidConfig {
        /// Name of the field.
        field: &'static str,
        /// What the valid range is.
        reason: &'static str,
    },
    /// The gripper model checked against the scene is unusable (see [`GripperModel::validate`]).
    #[error(transparent)]
    Gripper(GeometryError),
}
