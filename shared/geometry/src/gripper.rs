//! A Franka-hand-like parallel-jaw gripper as three boxes (palm and two fingers).
//!
//! Gripper frame: origin at the tool centre point (TCP, midway between the contacts),
//! x along the closing baseline, z along the approach (palm → object), y = z × x.
//! The fingertips reach `tip_beyond_tcp_m` past the TCP; the finger bases (and the palm face)
//! lie `finger_length_m − tip_beyond_tcp_m` behind it.
use crate::GeometryError;
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

/// Box dimensions of the gripper, in metres.
///
/// Read from a file (a configuration table, a dataset) it is a [`crate::GripperTable`]: the
/// built-in gripper file named by `model` (`config/grippers/`, default
/// [`crate::DEFAULT_GRIPPER`]) with any of the four keys given beside it taking their place;
/// unknown keys are refused.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "crate::grippers::GripperTable")]
pub struct GripperModel {
    /// Largest opening between the finger pads.
    pub max_opening_m: f32,
    /// Finger size: thickness along x (closing direction), width along y, length along z.
    pub finger_size_m: [f32; 3],
    /// Palm size along x, y, z.
    pub palm_size_m: [f32; 3],
    /// How far the fingertips reach beyond the TCP along the approach.
    pub tip_beyond_tcp_m: f32,
}

impl Default for GripperModel {
    /// The hand of the default gripper file ([`crate::DEFAULT_GRIPPER`], `config/grippers/`):
    /// the Franka hand (80 mm max opening, fingers 21×26×54 mm, hand 204×63×92 mm) with the
    /// fingertips 9.5 mm past the TCP, the hand the shipped models were trained with.
    fn default() -> Self {
        crate::grippers::default_gripper()
    }
}

/// An oriented box: pose of its centre and half extents along its local axes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OrientedBox {
    /// Maps box-local points into the parent frame; the origin is the box centre.
    pub parent_from_box: Isometry3<f32>,
    /// Half extents along the local x, y, z axes.
    pub half_extents: Vector3<f32>,
}

impl OrientedBox {
    /// True if `p` (parent frame) is inside the box grown by `margin` on every side.
    #[inline]
    pub fn contains(&self, p: &Point3<f32>, margin: f32) -> bool {
        let l = self.parent_from_box.inverse_transform_point(p);
        l.x.abs() <= self.half_extents.x + margin
            && l.y.abs() <= self.half_extents.y + margin
            && l.z.abs() <= self.half_extents.z + margin
    }

    /// The same box seen from one frame further out: `outer_from_parent` applied to its pose.
    pub fn placed(&self, outer_from_parent: &Isometry3<f32>) -> OrientedBox {
        OrientedBox {
            parent_from_box: outer_from_parent * self.parent_from_box,
            half_extents: self.half_extents,
        }
    }

    /// The eight corners in the parent frame.
    pub fn corners(&self) -> [Point3<f32>; 8] {
        let h = self.half_extents;
        std::array::from_fn(|i| {
            let s = Vector3::new(
                if i & 1 == 0 { -h.x } else { h.x },
                if i & 2 == 0 { -h.y } else { h.y },
                if i & 4 == 0 { -h.z } else { h.z },
            );
            self.parent_from_box * Point3::from(s)
        })
    }

    /// Axis-aligned bounds (min, max) in the parent frame.
    pub fn aabb(&self) -> (Point3<f32>, Point3<f32>) {
        let c = self.corners();
        let mut lo = c[0];
        let mut hi = c[0];
        for p in &c[1..] {
            lo = lo.inf(p);
            hi = hi.sup(p);
        }
        (lo, hi)
    }
}

impl GripperModel {
    /// Checks that the box sizes and the maximum opening are positive and finite and that the
    /// fingertips reach at most a finger length past the TCP
    /// ([`GeometryError::InvalidGripper`] otherwise).
    pub fn validate(&self) -> Result<(), GeometryError> {
        let sizes = self
            .finger_size_m
            .iter()
            .chain(self.palm_size_m.iter())
            .chain(std::iter::once(&self.max_opening_m));
        for &v in sizes {
            if !(v.is_finite() && v > 0.0) {
                return Err(GeometryError::InvalidGripper(
                    "sizes and max opening must be positive and finite",
                ));
            }
        }
        if !self.tip_beyond_tcp_m.is_finite()
            || self.tip_beyond_tcp_m < 0.0
            || self.tip_beyond_tcp_m > self.finger_size_m[2]
        {
            return Err(GeometryError::InvalidGripper(
                "tip_beyond_tcp_m must lie in [0, finger length]",
            ));
        }
        Ok(())
    }

    /// Distance from the TCP back to the palm face (finger bases) along the approach.
    pub fn tcp_to_palm_m(&self) -> f32 {
        self.finger_size_m[2] - self.tip_beyond_tcp_m
    }

    /// The palm and two finger boxes in the gripper frame for a given opening (clamped to
    /// `[0, max_opening_m]`): `[palm, left finger (−x), right finger (+x)]`.
    pub fn boxes_in_gripper_frame(&self, opening_m: f32) -> [OrientedBox; 3] {
        let opening = opening_m.clamp(0.0, self.max_opening_m);
        let [ft, fw, fl] = self.finger_size_m;
        let [px, py, pz] = self.palm_size_m;
        let finger_z = self.tip_beyond_tcp_m - 0.5 * fl;
        let palm_z = -self.tcp_to_palm_m() - 0.5 * pz;
        let at = |x: f32, z: f32| {
            Isometry3::from_parts(Translation3::new(x, 0.0, z), UnitQuaternion::identity())
        };
        [
            OrientedBox {
                parent_from_box: at(0.0, palm_z),
                half_extents: Vector3::new(0.5 * px, 0.5 * py, 0.5 * pz),
            },
            OrientedBox {
                parent_from_box: at(-0.5 * opening - 0.5 * ft, finger_z),
                half_extents: Vector3::new(0.5 * ft, 0.5 * fw, 0.5 * fl),
            },
            OrientedBox {
                parent_from_box: at(0.5 * opening + 0.5 * ft, finger_z),
                half_extents: Vector3::new(0.5 * ft, 0.5 * fw, 0.5 * fl),
            },
        ]
    }

    /// The three boxes placed at `workspace_from_gripper`.
    pub fn boxes(
        &self,
        workspace_from_gripper: &Isometry3<f32>,
        opening_m: f32,
    ) -> [OrientedBox; 3] {
        self.boxes_in_gripper_frame(opening_m)
            .map(|b| b.placed(workspace_from_gripper))
    }

    /// The stretches of the two pads' closing paths between `near_m` and `far_m` beyond the
    /// contact planes of a grasp of `width_m` (x = ±width/2), gripper frame, left then right:
    /// what a pad sweeps through just before it reaches its contact. A grasped object reaching
    /// into them is touched elsewhere first. Empty boxes (zero x extent) when `far_m ≤ near_m`.
    pub fn pad_sweep_regions(&self, width_m: f32, near_m: f32, far_m: f32) -> [OrientedBox; 2] {
        let [_, fw, fl] = self.finger_size_m;
        let half = 0.5 * (far_m - near_m).max(0.0);
        let x = 0.5 * width_m + near_m + half;
        [-1.0f32, 1.0].map(|sign| OrientedBox {
            parent_from_box: Isometry3::translation(
                sign * x,
                0.0,
                self.tip_beyond_tcp_m - 0.5 * fl,
            ),
            half_extents: Vector3::new(half, 0.5 * fw, 0.5 * fl),
        })
    }

    /// The closing region between the finger pads (where the object must be), gripper frame.
    pub fn closing_region(&self, opening_m: f32) -> OrientedBox {
        let [_, fw, fl] = self.finger_size_m;
        OrientedBox {
            parent_from_box: Isometry3::translation(0.0, 0.0, self.tip_beyond_tcp_m - 0.5 * fl),
            half_extents: Vector3::new(
                0.5 * opening_m.clamp(0.0, self.max_opening_m),
                0.5 * fw,
                0.5 * fl,
            ),
        }
    }

    /// What the pads close on for a grasp of `width_m`, gripper frame: the box between the two
    /// contact planes (x = ±width/2), as wide as the fingers (y) and as long as the pads along
    /// the approach (z within `tip_beyond_tcp_m` of the TCP; the pads are centred on it).
    pub fn pad_closing_region(&self, width_m: f32) -> OrientedBox {
        let [_, fw, _] = self.finger_size_m;
        OrientedBox {
            parent_from_box: Isometry3::identity(),
            half_extents: Vector3::new(
                0.5 * width_m.clamp(0.0, self.max_opening_m),
                0.5 * fw,
                self.tip_beyond_tcp_m,
            ),
        }
    }

    /// True if any of `points` (workspace frame) lies inside the gripper boxes grown by `margin`.
    pub fn collides_with_points<'a>(
        &self,
        workspace_from_gripper: &Isometry3<f32>,
        opening_m: f32,
        margin: f32,
        points: impl IntoIterator<Item = &'a Point3<f32>>,
    ) -> bool {
        let boxes = self.boxes(workspace_from_gripper, opening_m);
        points
            .into_iter()
            .any(|p| boxes.iter().any(|b| b.contains(p, margin)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pad_sweeps_lie_between_the_contact_planes_and_the_fingers() {
        let g = GripperModel::default();
        let [left, right] = g.pad_sweep_regions(0.03, 0.002, 0.01);
        let [_, finger, _] = g.boxes_in_gripper_frame(0.05);
        for (b, sign) in [(left, -1.0f32), (right, 1.0)] {
            let x = b.parent_from_box.translation.x;
            // From 2 mm to 10 mm beyond the contact plane at ±15 mm, as wide and long as a pad.
            assert!((sign * x - b.half_extents.x - 0.017).abs() < 1e-6);
            assert!((sign * x + b.half_extents.x - 0.025).abs() < 1e-6);
            assert_eq!(b.half_extents.yz(), finger.half_extents.yz());
            assert_eq!(
                b.parent_from_box.translation.z,
                finger.parent_from_box.translation.z
            );
        }
        let [empty, _] = g.pad_sweep_regions(0.03, 0.01, 0.005);
        assert_eq!(empty.half_extents.x, 0.0);
    }

    #[test]
    fn fingers_straddle_the_tcp() {
        let g = GripperModel::default();
        let [palm, left, right] = g.boxes_in_gripper_frame(0.04);
        // Inner finger faces at ±20 mm.
        assert!(((left.parent_from_box.translation.x + left.half_extents.x) + 0.02).abs() < 1e-6);
        assert!(((right.parent_from_box.translation.x - right.half_extents.x) - 0.02).abs() < 1e-6);
        // The TCP itself is free; a point just inside a finger is not.
        assert!(!g.collides_with_points(&Isometry3::identity(), 0.04, 0.0, &[Point3::origin()]));
        assert!(g.collides_with_points(
            &Isometry3::identity(),
            0.04,
            0.0,
            &[Point3::new(0.025, 0.0, 0.0)]
        ));
        // Palm sits behind the fingers.
        assert!(palm.parent_from_box.translation.z < -g.tcp_to_palm_m());
        // Opening is clamped to the maximum.
        let [_, l, r] = g.boxes_in_gripper_frame(1.0);
        let gap = (r.parent_from_box.translation.x - r.half_extents.x)
            - (l.parent_from_box.translation.x + l.half_extents.x);
        assert!((gap - g.max_opening_m).abs() < 1e-6);
    }

    #[test]
    fn validate_accepts_the_default_and_rejects_bad_sizes() {
        assert_eq!(GripperModel::default().validate(), Ok(()));
        let bad = GripperModel {
            max_opening_m: -0.1,
            ..GripperModel::default()
        };
        assert!(matches!(
            bad.validate(),
            Err(GeometryError::InvalidGripper(_))
        ));
        let tip = GripperModel {
            tip_beyond_tcp_m: 1.0,
            ..GripperModel::default()
        };
        assert!(matches!(
            tip.validate(),
            Err(GeometryError::InvalidGripper(_))
        ));
    }
}
