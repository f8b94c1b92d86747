//! The workspace: an axis-aligned voxel grid whose minimum corner is the workspace origin.
use crate::GeometryError;
use nalgebra::{Point3, Vector3};
use serde::{Deserialize, Serialize};

/// The voxel grid over the bin. Voxel `(i, j, k)` has its centre at
/// `((i + 0.5)·s, (j + 0.5)·s, (k + 0.5)·s)` in the workspace frame; linear index `(i·ny + j)·nz + k`
/// (x-major, z fastest), the layout of every grid psgrasp stores.
///
/// Read from a file (a configuration table, a dataset), every key is optional: missing keys
/// take the [`Default`] values; unknown keys are refused.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Workspace {
    /// Voxels along x, y, z.
    pub dims: [u32; 3],
    /// Edge length of one voxel in metres.
    pub voxel_size_m: f32,
}

impl Default for Workspace {
    /// The paper's grid: 64³ voxels of 9 mm (0.576 m cube).
    fn default() -> Self {
        Self {
            dims: [64, 64, 64],
            voxel_size_m: 0.009,
        }
    }
}

impl Workspace {
    /// Checks dimensions and voxel size.
    pub fn validate(&self) -> Result<(), GeometryError> {
        if self.dims.iter().any(|&d| d == 0 || d > 512) {
            return Err(GeometryError::InvalidWorkspace(
                "grid dimensions must be in 1..=512",
            ));
        }
        if !(self.voxel_size_m.is_finite() && self.voxel_size_m > 1e-4 && self.voxel_size_m < 1.0) {
            return Err(GeometryError::InvalidWorkspace(
                "voxel size must be in (0.1 mm, 1 m)",
            ));
        }
        Ok(())
    }

    /// Number of voxels.
    pub fn voxel_count(&self) -> usize {
        self.dims.iter().map(|&d| d as usize).product()
    }

    /// Metric size of the box.
    pub fn extent(&self) -> Vector3<f32> {
        Vector3::new(
            self.dims[0] as f32,
            self.dims[1] as f32,
            self.dims[2] as f32,
        ) * self.voxel_size_m
    }

    /// Linear index of voxel (i, j, k).
    #[inline]
    pub fn index(&self, i: usize, j: usize, k: usize) -> usize {
        (i * self.dims[1] as usize + j) * self.dims[2] as usize + k
    }

    /// Voxel (i, j, k) of a linear index.
    #[inline]
    pub fn unindex(&self, idx: usize) -> [usize; 3] {
        let nz = self.dims[2] as usize;
        let ny = self.dims[1] as usize;
        [idx / (ny * nz), (idx / nz) % ny, idx % nz]
    }

    /// Centre of voxel (i, j, k) in the workspace frame.
    #[inline]
    pub fn voxel_center(&self, i: usize, j: usize, k: usize) -> Point3<f32> {
        let s = self.voxel_size_m;
        Point3::new(
            (i as f32 + 0.5) * s,
            (j as f32 + 0.5) * s,
            (k as f32 + 0.5) * s,
        )
    }

    /// Continuous voxel coordinates of a workspace point (voxel centres at integer + 0.5).
    #[inline]
    pub fn to_voxel_coordinates(&self, p: &Point3<f32>) -> Vector3<f32> {
        p.coords / self.voxel_size_m
    }

    /// The voxel containing `p`, if inside the grid.
    pub fn voxel_of(&self, p: &Point3<f32>) -> Option<[usize; 3]> {
        let v = self.to_voxel_coordinates(p);
        let mut out = [0usize; 3];
        for a in 0..3 {
            if !(v[a] >= 0.0 && v[a] < self.dims[a] as f32) {
                return None;
            }
            out[a] = v[a] as usize;
        }
        Some(out)
    }

    /// True if `p` lies inside the box.
    pub fn contains(&self, p: &Point3<f32>) -> bool {
        self.voxel_of(p).is_some()
    }

    /// Trilinear interpolation of a scalar grid (workspace layout) at point `p`; values outside
    /// the grid are clamped to the border.
    pub fn trilinear(&self, grid: &[f32], p: &Point3<f32>) -> f32 {
        debug_assert_eq!(grid.len(), self.voxel_count());
        let v = self.to_voxel_coordinates(p) - Vector3::repeat(0.5);
        let mut i0 = [0usize; 3];
        let mut f = [0f32; 3];
        for a in 0..3 {
            let max = self.dims[a] as f32 - 1.0;
            let x = v[a].clamp(0.0, max);
            let fl = x.floor().min((max - 1.0).max(0.0));
            i0[a] = fl as usize;
            f[a] = x - fl;
        }
        let hi = |a: usize| (i0[a] + 1).min(self.dims[a] as usize - 1);
        let mut acc = 0.0;
        for (dx, wx) in [(i0[0], 1.0 - f[0]), (hi(0), f[0])] {
            for (dy, wy) in [(i0[1], 1.0 - f[1]), (hi(1), f[1])] {
                for (dz, wz) in [(i0[2], 1.0 - f[2]), (hi(2), f[2])] {
                    acc += wx * wy * wz * grid[self.index(dx, dy, dz)];
                }
            }
        }
        acc
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn index_round_trip() {
        let ws = Workspace {
            dims: [5, 6, 7],
            voxel_size_m: 0.01,
        };
        for idx in 0..ws.voxel_count() {
            let [i, j, k] = ws.unindex(idx);
            assert_eq!(ws.index(i, j, k), idx);
        }
        assert_eq!(ws.voxel_of(&ws.voxel_center(2, 3, 4)), Some([2, 3, 4]));
        assert_eq!(ws.voxel_of(&Point3::new(-0.001, 0.0, 0.0)), None);
    }

    #[test]
    fn trilinear_reproduces_linear_field() {
        let ws = Workspace {
            dims: [8, 8, 8],
            voxel_size_m: 0.01,
        };
        let grid: Vec<f32> = (0..ws.voxel_count())
            .map(|idx| {
                let c = ws.voxel_center(ws.unindex(idx)[0], ws.unindex(idx)[1], ws.unindex(idx)[2]);
                2.0 * c.x - c.y + 0.5 * c.z
            })
            .collect();
        let p = Point3::new(0.0333, 0.0471, 0.0219);
        let expected = 2.0 * p.x - p.y + 0.5 * p.z;
        assert!((ws.trilinear(&grid, &p) - expected).abs() < 1e-5);
    }
}
