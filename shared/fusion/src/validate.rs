//! Input checks of a normal grid: the checks every consumer (inference backends, the collision
//! checker) runs before reading one.
use crate::NormalGridView;
use psgrasp_geometry::GeometryError;

/// Largest |normalised TSDF| accepted by [`NormalGridView::validate`]; values are defined in
/// [−1, 1] and this leaves room for rounding in producers.
pub const TSDF_RANGE_TOLERANCE: f32 = 1e-3;

/// Why a normal grid is unusable.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum GridError {
    /// The grid's workspace description is unusable (zero dimension, bad voxel size); the
    /// message is the workspace check's own ("invalid workspace: ...").
    #[error(transparent)]
    Workspace(#[from] GeometryError),
    /// A grid channel does not have the length its workspace implies.
    #[error("grid {channel} has {got} values, the workspace needs {expected}")]
    GridSizeMismatch {
        /// Which buffer: `"tsdf"` or `"normals"`.
        channel: &'static str,
        /// Values received.
        got: usize,
        /// Values required by the workspace (N for the TSDF, 3·N for the normals).
        expected: usize,
    },
    /// The grid holds a NaN or infinity.
    #[error("grid {channel} holds a non-finite value at index {index}")]
    NonFiniteInput {
        /// Which buffer: `"tsdf"` or `"normals"`.
        channel: &'static str,
        /// First offending index into that buffer.
        index: usize,
    },
    /// A normalised TSDF value lies outside [−1, 1].
    #[error("normalised TSDF value {value} at voxel {index} is outside [-1, 1]")]
    TsdfOutOfRange {
        /// Voxel index.
        index: usize,
        /// The value found.
        value: f32,
    },
    /// The truncation distance is not a positive finite number.
    #[error("truncation distance must be positive and finite, got {0} m")]
    InvalidTruncation(f32),
}

impl NormalGridView<'_> {
    /// Checks the grid before use: valid workspace, buffer lengths, finite values, TSDF in
    /// [−1, 1] (up to [`TSDF_RANGE_TOLERANCE`]) and a positive truncation distance.
    pub fn validate(&self) -> Result<(), GridError> {
        self.workspace.validate()?;
        let n = self.workspace.voxel_count();
        if self.tsdf.len() != n {
            return Err(GridError::GridSizeMismatch {
                channel: "tsdf",
                got: self.tsdf.len(),
                expected: n,
            });
        }
        if self.normals.len() != 3 * n {
            return Err(GridError::GridSizeMismatch {
                channel: "normals",
                got: self.normals.len(),
                expected: 3 * n,
            });
        }
        if !(self.truncation_m.is_finite() && self.truncation_m > 0.0) {
            return Err(GridError::InvalidTruncation(self.truncation_m));
        }
        if let Some(index) = self.normals.iter().position(|v| !v.is_finite()) {
            return Err(GridError::NonFiniteInput {
                channel: "normals",
                index,
            });
        }
        for (index, &value) in self.tsdf.iter().enumerate() {
            if !value.is_finite() {
                return Err(GridError::NonFiniteInput {
                    channel: "tsdf",
                    index,
                });
            }
            if value.abs() > 1.0 + TSDF_RANGE_TOLERANCE {
                return Err(GridError::TsdfOutOfRange { index, value });
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::NormalGrid;
    use psgrasp_geometry::Workspace;

    fn small_grid() -> NormalGrid {
        let workspace = Workspace {
            dims: [4, 5, 6],
            voxel_size_m: 0.01,
        };
        let n = workspace.voxel_count();
        NormalGrid {
            workspace,
            normals: vec![0.0; 3 * n],
            tsdf: vec![1.0; n],
            truncation_m: 0.03,
        }
    }

    #[test]
    fn valid_grid_passes_and_bad_grids_are_reported_precisely() {
        let mut g = small_grid();
        assert_eq!(g.view().validate(), Ok(()));
        g.tsdf[5] = 1.0 + 0.5 * TSDF_RANGE_TOLERANCE;
        assert_eq!(g.view().validate(), Ok(()), "rounding is tolerated");
        g.tsdf[5] = -1.5;
        assert_eq!(
            g.view().validate(),
            Err(GridError::TsdfOutOfRange {
                index: 5,
                value: -1.5
            })
        );
        let mut g = small_grid();
        g.normals.pop();
        assert_eq!(
            g.view().validate(),
            Err(GridError::GridSizeMismatch {
                channel: "normals",
                got: 359,
                expected: 360
            })
        );
        let mut g = small_grid();
        g.workspace.voxel_size_m = 0.0;
        assert!(matches!(g.view().validate(), Err(GridError::Workspace(_))));
        assert_eq!(
            GridError::InvalidTruncation(0.0).to_string(),
            "truncation distance must be positive and finite, got 0 m"
        );
    }
}
