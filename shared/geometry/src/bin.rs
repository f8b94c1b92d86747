//! The bin (tote) the objects lie in, as a floor and four wall boxes.
use crate::gripper::OrientedBox;
use nalgebra::{Isometry3, Point3, Vector3};
use serde::{Deserialize, Serialize};

/// An open box: inner size, wall thickness and where its floor centre sits in the workspace frame.
/// The bin is axis-aligned with the workspace; its inner floor surface is at `floor_center.z`.
///
/// Read from a file (a configuration table, a dataset), every key is optional: missing keys
/// take the [`Default`] values; unknown keys are refused.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BinModel {
    /// Inner length (x), width (y) and height (z) in metres.
    pub inner_size_m: [f32; 3],
    /// Thickness of the floor and walls.
    pub wall_thickness_m: f32,
    /// Centre of the inner floor surface in the workspace frame.
    pub floor_center: Point3<f32>,
}

impl Default for BinModel {
    /// The paper's 600×400×280 mm bin, centred on a default 64³ × 9 mm workspace, floor 18 mm
    /// (two voxels) above the grid's bottom so the floor surface lies inside the grid.
    fn default() -> Self {
        Self {
            inner_size_m: [0.6, 0.4, 0.28],
            wall_thickness_m: 0.01,
            floor_center: Point3::new(0.288, 0.288, 0.018),
        }
    }
}

impl BinModel {
    /// The smaller bin used for scene diversity (400×300×200 mm), same placement.
    pub fn small() -> Self {
        Self {
            inner_size_m: [0.4, 0.3, 0.2],
            ..Self::default()
        }
    }

    /// Floor and four walls as boxes in the workspace frame: `[floor, −x, +x, −y, +y]`.
    pub fn boxes(&self) -> [OrientedBox; 5] {
        let [lx, ly, lz] = self.inner_size_m;
        let t = self.wall_thickness_m;
        let c = self.floor_center;
        let make = |center: Vector3<f32>, half: Vector3<f32>| OrientedBox {
            parent_from_box: Isometry3::translation(c.x + center.x, c.y + center.y, c.z + center.z),
            half_extents: half,
        };
        let wall_z = 0.5 * lz;
        [
            make(
                Vector3::new(0.0, 0.0, -0.5 * t),
                Vector3::new(0.5 * lx + t, 0.5 * ly + t, 0.5 * t),
            ),
            make(
                Vector3::new(-0.5 * lx - 0.5 * t, 0.0, wall_z),
                Vector3::new(0.5 * t, 0.5 * ly + t, 0.5 * lz),
            ),
            make(
                Vector3::new(0.5 * lx + 0.5 * t, 0.0, wall_z),
                Vector3::new(0.5 * t, 0.5 * ly + t, 0.5 * lz),
            ),
            make(
                Vector3::new(0.0, -0.5 * ly - 0.5 * t, wall_z),
                Vector3::new(0.5 * lx, 0.5 * t, 0.5 * lz),
            ),
            make(
                Vector3::new(0.0, 0.5 * ly + 0.5 * t, wall_z),
                Vector3::new(0.5 * lx, 0.5 * t, 0.5 * lz),
            ),
        ]
    }

    /// True if `p` is inside the bin's inner volume.
    pub fn contains_inner(&self, p: &Point3<f32>) -> bool {
        let d = p - self.floor_center;
        d.x.abs() <= 0.5 * self.inner_size_m[0]
            && d.y.abs() <= 0.5 * self.inner_size_m[1]
            && d.z >= 0.0
            && d.z <= self.inner_size_m[2]
    }

    /// Top rim height (z of the wall tops) in the workspace frame.
    pub fn rim_z(&self) -> f32 {
        self.floor_center.z + self.inner_size_m[2]
    }
}
