//! Training targets: the label grid (contact / gripper / empty space) and the normal grid.
use crate::labels::GraspLabel;
use psgrasp_fusion::{fuse_normal_grid, FusionConfig, FusionError, NormalGrid};
use psgrasp_geometry::{CameraModel, DepthImage, GripperModel, Workspace};

/// Label-grid class of empty space.
pub const LABEL_EMPTY: u8 = 0;
/// Label-grid class of contact space (a voxel holding a labelled contact point `c`).
pub const LABEL_CONTACT: u8 = 1;
/// Label-grid class of gripper space (a voxel holding the approach point `t` of a collision-free
/// grasp). Contact space wins where both fall into one voxel.
pub const LABEL_GRIPPER: u8 = 2;

/// Builds the label grid (workspace layout, one `u8` class per voxel).
pub fn label_grid(labels: &[GraspLabel], gripper: &GripperModel, workspace: &Workspace) -> Vec<u8> {
    let mut grid = vec![LABEL_EMPTY; workspace.voxel_count()];
    for l in labels {
        for i in 0..psgrasp_geometry::N_APPROACHES {
            if l.collision_free[i] {
                let t = l.grasp(i).approach_point(gripper);
                if let Some([x, y, z]) = workspace.voxel_of(&t) {
                    grid[workspace.index(x, y, z)] = LABEL_GRIPPER;
                }
            }
        }
    }
    for l in labels {
        if let Some([x, y, z]) = workspace.voxel_of(&l.contact) {
            grid[workspace.index(x, y, z)] = LABEL_CONTACT;
        }
    }
    grid
}

/// The network input: the normal grid fused from `depth` (via psgrasp-fusion).
pub fn normal_grid(
    depth: &DepthImage,
    camera: &CameraModel,
    workspace: &Workspace,
    config: &FusionConfig,
) -> Result<NormalGrid, FusionError> {
    fuse_normal_grid(depth, camera, workspace, config)
}
