//! The fingers against the depth frame: a second scene test at the camera's resolution.
//!
//! The observed-scene test ([`psgrasp_collision::OccupancyGrid`]) works on the 9 mm voxels of the
//! normal grid, tested at their centres, so a finger may overlap an object's footprint by about
//! half a voxel and still pass; the hand then touches the object on its way down. With
//! [`SurfaceCheck::enabled`], fusion also writes the frame's height map (cells of
//! [`SurfaceCheck::cell_m`], everything under a measured surface solid) and selection refuses an
//! approach whose fingers at the grasp pose, grown by [`SurfaceCheck::margin_m`], hold at least
//! [`SurfaceCheck::min_cells`] cells' columns ([`crate::RejectionReason::SurfaceCollision`]).
//! Measured on the evaluation (docs/evaluation.md, "The fingers against the depth frame").

use psgrasp_fusion::{FusionError, HeightMapGeometry};
use psgrasp_geometry::{check_setting, Workspace};
use serde::{Deserialize, Serialize};

use crate::SelectionError;

/// `[selection.surface_check]`: the fingers against the frame's height map.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SurfaceCheck {
    /// Test the fingers against the height map (fusion then appends it to the grid message).
    pub enabled: bool,
    /// Edge length of a height-map cell, metres (about the camera's pixel footprint on the bin
    /// floor or coarser).
    pub cell_m: f32,
    /// The finger boxes are grown by this much for the test, metres (negative: shrunk, which
    /// tolerates depth noise at the price of letting small overlaps pass).
    pub margin_m: f32,
    /// An approach is refused when at least this many cells' columns meet a finger.
    pub min_cells: usize,
    /// Picks whose pads would close on less than this share of measured surface
    /// ([`crate::SelectedGrasp::pad_fill`]) are deferred: handed out only after every pick that
    /// reaches it, never refused. 0 (the default) defers nothing.
    pub defer_pad_fill_below: f32,
}

impl Default for SurfaceCheck {
    fn default() -> Self {
        Self {
            enabled: false,
            cell_m: 0.002,
            margin_m: 0.001,
            min_cells: 1,
            defer_pad_fill_below: 0.0,
        }
    }
}

impl SurfaceCheck {
    /// The cell size lies in [0.5, 20] mm, the margin in [−10, 10] mm, at least one cell
    /// counts, and the deferral's fill lies in [0, 1].
    pub fn validate(&self) -> Result<(), SelectionError> {
        check_setting(
            self.cell_m.is_finite() && (0.0005..=0.02).contains(&self.cell_m),
            "surface_check.cell_m",
            "must lie in [0.0005, 0.02] m",
        )?;
        check_setting(
            self.margin_m.is_finite() && (-0.01..=0.01).contains(&self.margin_m),
            "surface_check.margin_m",
            "must lie in [-0.01, 0.01] m",
        )?;
        check_setting(
            self.min_cells >= 1,
            "surface_check.min_cells",
            "must be at least 1",
        )?;
        check_setting(
            (0.0..=1.0).contains(&self.defer_pad_fill_below),
            "surface_check.defer_pad_fill_below",
            "must lie in [0, 1]",
        )?;
        Ok(())
    }

    /// Whether `pick` goes after every pick whose pad fill reaches
    /// [`SurfaceCheck::defer_pad_fill_below`] (a pick without a fill is never deferred).
    pub fn defers(&self, pick: &crate::SelectedGrasp) -> bool {
        pick.pad_fill
            .is_some_and(|fill| fill < self.defer_pad_fill_below)
    }

    /// The height map's cells over `workspace` when enabled (`None`: no map).
    pub fn geometry(
        &self,
        workspace: &Workspace,
    ) -> Result<Option<HeightMapGeometry>, FusionError> {
        if self.enabled {
            HeightMapGeometry::new(workspace, self.cell_m).map(Some)
        } else {
            Ok(None)
        }
    }

    /// Values the height map adds to a grid message (0 when disabled).
    pub fn message_len(&self, workspace: &Workspace) -> Result<usize, FusionError> {
        Ok(self.geometry(workspace)?.map_or(0, |g| g.len()))
    }
}

/// `true` for the default (disabled) check, which is then not written.
pub(crate) fn is_default(check: &SurfaceCheck) -> bool {
    *check == SurfaceCheck::default()
}
