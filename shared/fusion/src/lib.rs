//! Depth frames → projective TSDF → normal grid.
//!
//! Grid layout (shared with the IPC messages and the network): every scalar grid is a `Vec<f32>`
//! in [`Workspace`] index order (x-major, z fastest). The normal grid is channel-major:
//! `normals[c · N + idx]` for channel `c ∈ {x, y, z}` and voxel `idx` — exactly the `[3, X, Y, Z]`
//! input tensor of the network.
//!
//! The data flow:
//!
//! 1. [`TsdfVolume::integrate`] fuses depth frames (any number, from any viewpoint) into a
//!    projective truncated signed distance field with a weighted running average.
//! 2. [`TsdfVolume::write_normal_grid`] (or [`TsdfVolume::normal_grid`]) stores, for every voxel
//!    of the truncation band, the unit normal of the *nearest* observed surface point (found by a
//!    few closest-point iterations on the fused field's zero level set), pointing to free space.
//! 3. For a real camera whose pose is unknown, [`fit_support_plane`] finds the table/bin floor and
//!    [`workspace_camera_from_plane`] places the workspace box on it.
//!
//! [`fuse_normal_grid`] and [`fuse_into`] do steps 1–2 for a single frame.
#![warn(missing_docs)]

mod config;
mod depth_png;
mod depth_scale;
mod height_map;
mod normals;
mod plane;
mod tsdf;
mod validate;

pub use config::FusionConfig;
pub use depth_png::{
    decode_depth_png, load_depth_png, load_depth_png_sized, save_depth_png, DepthPngError,
};
pub use depth_scale::{correct_depth_scale, estimate_depth_scale, DepthScale, DepthScaleConfig};
pub use height_map::{write_height_map, HeightMapGeometry, HeightMapView, NO_HEIGHT};
pub use plane::{
    fit_support_plane, workspace_camera_from_plane, PlacementConfig, Plane, PlaneFitConfig,
};
pub use tsdf::{fuse_into, fuse_normal_grid, IntegrationStats, TsdfVolume};
pub use validate::{GridError, TSDF_RANGE_TOLERANCE};

use psgrasp_geometry::Workspace;

/// Checks that `depth` is a frame of `intrinsics` (same size, full buffer); the caller has
/// validated the intrinsics (or the camera holding them).
pub(crate) fn check_frame(
    depth: &psgrasp_geometry::DepthImage,
    intrinsics: &psgrasp_geometry::CameraIntrinsics,
) -> Result<(), FusionError> {
    if depth.width != intrinsics.width || depth.height != intrinsics.height {
        return Err(FusionError::FrameSizeMismatch {
            got_w: depth.width,
            got_h: depth.height,
            want_w: intrinsics.width,
            want_h: intrinsics.height,
        });
    }
    if depth.data.len() != intrinsics.pixel_count() {
        return Err(psgrasp_geometry::DepthError::SizeMismatch {
            got: depth.data.len(),
            expected: intrinsics.pixel_count(),
            width: depth.width,
            height: depth.height,
        }
        .into());
    }
    Ok(())
}

/// Errors from fusion.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum FusionError {
    /// The depth frame does not match the camera intrinsics.
    #[error("depth frame is {got_w}×{got_h}, camera intrinsics say {want_w}×{want_h}")]
    FrameSizeMismatch {
        /// Frame width.
        got_w: u32,
        /// Frame height.
        got_h: u32,
        /// Intrinsics width.
        want_w: u32,
        /// Intrinsics height.
        want_h: u32,
    },
    /// Bad camera or workspace geometry.
    #[error(transparent)]
    Geometry(#[from] psgrasp_geometry::GeometryError),
    /// Bad depth data.
    #[error(transparent)]
    Depth(#[from] psgrasp_geometry::DepthError),
    /// An output buffer has the wrong length.
    #[error("output buffer {name} has {got} elements, expected {expected}")]
    BufferSize {
        /// Which buffer.
        name: &'static str,
        /// Its length.
        got: usize,
        /// Required length.
        expected: usize,
    },
    /// The frame saw nothing inside the workspace.
    #[error("no depth measurement falls inside the workspace")]
    EmptyView,
    /// A configuration value is out of its valid range.
    #[error("invalid configuration: {0}")]
    InvalidConfig(&'static str),
    /// Too few valid back-projected points to fit a plane.
    #[error("only {got} valid points to fit a plane, need at least {needed}")]
    TooFewPoints {
        /// Points available.
        got: usize,
        /// Minimum required ([`PlaneFitConfig::min_inliers`]).
        needed: usize,
    },
    /// RANSAC found no plane supported by enough inliers.
    #[error("no plane with enough support: best has {inliers} of {points} points")]
    PlaneNotFound {
        /// Inliers of the best plane.
        inliers: usize,
        /// Points tested.
        points: usize,
    },
    /// The plane cannot carry the workspace (degenerate normal, or the optical axis misses it).
    #[error("cannot place the workspace on the plane: {0}")]
    BadPlane(&'static str),
}

/// A borrowed normal grid, e.g. straight out of a shared-memory sample.
#[derive(Debug, Clone, Copy)]
pub struct NormalGridView<'a> {
    /// The grid geometry.
    pub workspace: Workspace,
    /// Channel-major unit normals (`3 · N` values); zero vectors outside the truncation band.
    pub normals: &'a [f32],
    /// Truncated signed distance in units of the truncation distance, in [−1, 1]; +1 = free or
    /// unobserved in front of the surface, −1 = behind the surface (occluded/inside).
    pub tsdf: &'a [f32],
    /// Truncation distance in metres.
    pub truncation_m: f32,
}

/// An owned normal grid.
#[derive(Debug, Clone, PartialEq)]
pub struct NormalGrid {
    /// The grid geometry.
    pub workspace: Workspace,
    /// Channel-major unit normals (`3 · N` values).
    pub normals: Vec<f32>,
    /// Normalised TSDF in [−1, 1] (see [`NormalGridView::tsdf`]).
    pub tsdf: Vec<f32>,
    /// Truncation distance in metres.
    pub truncation_m: f32,
}

impl NormalGrid {
    /// Borrows the grid.
    pub fn view(&self) -> NormalGridView<'_> {
        NormalGridView {
            workspace: self.workspace,
            normals: &self.normals,
            tsdf: &self.tsdf,
            truncation_m: self.truncation_m,
        }
    }
}

impl NormalGridView<'_> {
    /// The normal stored at voxel `idx`.
    #[inline]
    pub fn normal(&self, idx: usize) -> [f32; 3] {
        let n = self.workspace.voxel_count();
        [
            self.normals[idx],
            self.normals[n + idx],
            self.normals[2 * n + idx],
        ]
    }

    /// Copies into an owned grid.
    pub fn to_owned(&self) -> NormalGrid {
        NormalGrid {
            workspace: self.workspace,
            normals: self.normals.to_vec(),
            tsdf: self.tsdf.to_vec(),
            truncation_m: self.truncation_m,
        }
    }

    /// True if voxel `idx` lies in the truncation band (a non-zero normal is stored there).
    #[inline]
    pub fn in_band(&self, idx: usize) -> bool {
        let [x, y, z] = self.normal(idx);
        x != 0.0 || y != 0.0 || z != 0.0
    }

    /// Number of voxels that carry a normal.
    pub fn band_voxel_count(&self) -> usize {
        (0..self.workspace.voxel_count())
            .filter(|&i| self.in_band(i))
            .count()
    }
}
