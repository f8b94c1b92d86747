//! The frame seen from above as a height map: per square cell of the workspace's floor plan,
//! the highest surface point the depth frame measured there. A top-down camera cannot see under
//! a surface, so everything below a cell's height counts as occupied; cells the frame did not
//! measure hold no height (free). Unlike the 9 mm voxel grid, the cells can be as fine as the
//! camera's pixels: selection uses the map to test the fingers where the voxel grid is too coarse
//! (`docs/evaluation.md`, "The fingers against the depth frame").
use crate::{check_frame, FusionError};
use psgrasp_geometry::{depth::is_valid_depth, CameraModel, DepthImage, Workspace};

/// A cell no depth measurement fell into.
pub const NO_HEIGHT: f32 = f32::NEG_INFINITY;

/// Where the cells of a height map lie: `nx × ny` squares of `cell_m` from the workspace's
/// origin, x-major (`index = i · ny + j`), covering the workspace's floor plan.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeightMapGeometry {
    /// Edge length of one cell, metres.
    pub cell_m: f32,
    /// Cells along x.
    pub nx: usize,
    /// Cells along y.
    pub ny: usize,
}

impl HeightMapGeometry {
    /// The cells of `cell_m` covering `workspace`'s floor plan (a partial last cell counts).
    pub fn new(workspace: &Workspace, cell_m: f32) -> Result<Self, FusionError> {
        workspace.validate()?;
        if !(cell_m.is_finite() && cell_m >= 1e-4) {
            return Err(FusionError::InvalidConfig(
                "height map cell must be a finite size of at least 0.1 mm",
            ));
        }
        let extent = |d: u32| d as f32 * workspace.voxel_size_m;
        let cells = |d: u32| (extent(d) / cell_m).ceil().max(1.0) as usize;
        Ok(Self {
            cell_m,
            nx: cells(workspace.dims[0]),
            ny: cells(workspace.dims[1]),
        })
    }

    /// Number of cells.
    pub fn len(&self) -> usize {
        self.nx * self.ny
    }

    /// True for a map without cells (never for one built by [`HeightMapGeometry::new`]).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The cell holding floor-plan point (x, y), if inside.
    #[inline]
    pub fn cell_of(&self, x: f32, y: f32) -> Option<(usize, usize)> {
        let (i, j) = ((x / self.cell_m).floor(), (y / self.cell_m).floor());
        (i >= 0.0 && j >= 0.0 && (i as usize) < self.nx && (j as usize) < self.ny)
            .then_some((i as usize, j as usize))
    }
}

/// Writes the height map of `depth` seen by `camera` into `out` (`geometry.len()` values): per
/// cell the highest workspace z of the frame's valid pixels whose back-projected point falls in
/// it, [`NO_HEIGHT`] where none does. The frame should be depth-scale corrected first, as for
/// fusion: a range-scale error raises or lowers every height.
pub fn write_height_map(
    depth: &DepthImage,
    camera: &CameraModel,
    geometry: &HeightMapGeometry,
    out: &mut [f32],
) -> Result<(), FusionError> {
    camera.validate()?;
    check_frame(depth, &camera.intrinsics)?;
    if out.len() != geometry.len() {
        return Err(FusionError::BufferSize {
            name: "height map",
            got: out.len(),
            expected: geometry.len(),
        });
    }
    out.fill(NO_HEIGHT);
    let k = &camera.intrinsics;
    // p = R·(d·(u − cx)/fx, d·(v − cy)/fy, d) + t = d·(a_u·R₀ + (b_v·R₁ + R₂)) + t: the ray
    // direction is one multiply-add per pixel on top of per-column and per-row terms (2.2 ms per
    // 640×480 frame this way against 5.3 ms through the isometry; `cargo bench -p psgrasp-fusion`).
    let r = camera.workspace_from_camera.rotation.to_rotation_matrix();
    let m = r.matrix();
    let t = camera.workspace_from_camera.translation.vector;
    let column = |c: usize| nalgebra::Vector3::new(m[(0, c)], m[(1, c)], m[(2, c)]);
    let (r0, r1, r2) = (column(0), column(1), column(2));
    let inv_cell = 1.0 / geometry.cell_m;
    let (nx, ny) = (geometry.nx as f32, geometry.ny as f32);
    let width = depth.width as usize;
    let column_terms: Vec<f32> = (0..width).map(|u| (u as f32 - k.cx) / k.fx).collect();
    for (v, row) in depth.data.chunks_exact(width).enumerate() {
        let row_dir = r1 * ((v as f32 - k.cy) / k.fy) + r2;
        for (&a, &d) in column_terms.iter().zip(row) {
            if !is_valid_depth(d) {
                continue;
            }
            let dir = r0 * a + row_dir;
            let p = dir * d + t;
            let (fi, fj) = ((p.x * inv_cell).floor(), (p.y * inv_cell).floor());
            if fi >= 0.0 && fj >= 0.0 && fi < nx && fj < ny {
                let h = &mut out[fi as usize * geometry.ny + fj as usize];
                *h = h.max(p.z);
            }
        }
    }
    Ok(())
}

/// A borrowed height map (a message's tail, or [`write_height_map`]'s output).
#[derive(Debug, Clone, Copy)]
pub struct HeightMapView<'a> {
    /// Its cells.
    pub geometry: HeightMapGeometry,
    /// Heights in workspace z, metres, x-major; [`NO_HEIGHT`] where nothing was measured.
    pub heights: &'a [f32],
}

impl HeightMapView<'_> {
    /// The height of cell (i, j) ([`NO_HEIGHT`] when unmeasured or outside).
    #[inline]
    pub fn height(&self, i: usize, j: usize) -> f32 {
        if i < self.geometry.nx && j < self.geometry.ny {
            self.heights[i * self.geometry.ny + j]
        } else {
            NO_HEIGHT
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;
    use psgrasp_geometry::CameraIntrinsics;

    #[test]
    fn a_flat_floor_and_a_raised_block_give_their_heights() {
        // A top-down camera 0.7 m over the middle of the workspace sees the floor (z = 0)
        // everywhere except a 60 mm square block 40 mm high around the centre.
        let ws = Workspace::default();
        let half = 0.5 * 64.0 * 0.009;
        let camera = CameraModel::top_down(
            CameraIntrinsics::default_640x480(),
            Point3::new(half, half, 0.7),
        );
        let k = camera.intrinsics;
        let mut data = vec![0.0; k.pixel_count()];
        for v in 0..k.height as usize {
            for u in 0..k.width as usize {
                let ray = camera.workspace_from_camera * k.ray_direction(u as f32, v as f32);
                let t_floor = 0.7 / -ray.z;
                let hit = Point3::new(half, half, 0.7) + ray * t_floor;
                let on_block = (hit.x - half).abs() < 0.03 && (hit.y - half).abs() < 0.03;
                // Depth is along the optical axis: the height below the camera. The strip
                // x < 50 mm measured nothing (invalid depth).
                data[v * k.width as usize + u] = if hit.x < 0.05 {
                    0.0
                } else if on_block {
                    0.7 - 0.04
                } else {
                    0.7
                };
            }
        }
        let depth = DepthImage::from_metres(k.width, k.height, data).unwrap();
        let geometry = HeightMapGeometry::new(&ws, 0.002).unwrap();
        assert_eq!((geometry.nx, geometry.ny), (288, 288));
        let mut heights = vec![0.0; geometry.len()];
        write_height_map(&depth, &camera, &geometry, &mut heights).unwrap();
        let map = HeightMapView {
            geometry,
            heights: &heights,
        };
        let at = |x: f32, y: f32| {
            let (i, j) = geometry.cell_of(x, y).unwrap();
            map.height(i, j)
        };
        assert!((at(half, half) - 0.04).abs() < 1e-4);
        assert!((at(half + 0.02, half - 0.02) - 0.04).abs() < 1e-4);
        assert!(at(half + 0.05, half).abs() < 1e-4);
        assert!(at(0.1, 0.1).abs() < 1e-4);
        // Where the frame measured nothing, and outside the map, there is no height.
        assert_eq!(at(0.02, half), NO_HEIGHT);
        assert_eq!(map.height(geometry.nx, 0), NO_HEIGHT);
        // A wrong buffer or a bad cell size is an error, not a panic.
        assert!(write_height_map(&depth, &camera, &geometry, &mut [0.0; 3]).is_err());
        assert!(HeightMapGeometry::new(&ws, 0.0).is_err());
        assert!(HeightMapGeometry::new(&ws, f32::NAN).is_err());
    }
}
