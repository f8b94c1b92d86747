//! The hand's straight descent to a grasp, as a training-label test: the open hand moves from the
//! pre-grasp pose (backed off along the approach) down to the grasp pose, opened at the grasp
//! width plus a clearance, as selection commands it and the evaluation executes it
//! (`[selection.clearance]`). ACRONYM's labels test the grasp pose alone, so a grasp whose fingers
//! come down on the object's wider top (a ball's lower half, a box's far edge under a tilted
//! baseline) or on a neighbour is labelled collision-free although the descent stops on it. With
//! this test on, such approaches are labelled colliding, so the collision head learns to rank
//! them below approaches the hand can reach.
//!
//! The hand only translates along its approach axis (gripper `+z`) during the descent, so the
//! space each of its boxes sweeps is that box stretched back along `−z` by the descent's length:
//! one exact box test per part, no sampling.
use nalgebra::{Isometry3, Translation3};
use psgrasp_geometry::{GripperModel, OrientedBox};
use psgrasp_sim::Scene;
use serde::{Deserialize, Serialize};

/// The descent test's settings (`[labels.approach_path]` of a datagen configuration).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ApproachPathCheck {
    /// The hand descends open at the grasp width plus this (m), capped at the maximum opening:
    /// the evaluation protocol's `[selection.clearance] opening_clearance_m`.
    pub opening_clearance_m: f32,
    /// The descent starts this far back along the approach (m): the pre-grasp distance
    /// (`[selection.clearance] pregrasp_distance_m`).
    pub distance_m: f32,
}

impl Default for ApproachPathCheck {
    fn default() -> Self {
        Self {
            opening_clearance_m: 0.04,
            distance_m: 0.08,
        }
    }
}

impl ApproachPathCheck {
    /// Both distances finite and in `[0, 1)` m.
    pub fn validate(&self) -> Result<(), psgrasp_geometry::OutOfRange> {
        let metric = |v: f32| v.is_finite() && (0.0..1.0).contains(&v);
        psgrasp_geometry::check_setting(
            metric(self.opening_clearance_m),
            "labels.approach_path.opening_clearance_m",
            "must lie in [0, 1) m",
        )?;
        psgrasp_geometry::check_setting(
            metric(self.distance_m),
            "labels.approach_path.distance_m",
            "must lie in [0, 1) m",
        )
    }

    /// The palm and finger boxes swept by the descent to `workspace_from_gripper` of a grasp of
    /// `width_m` (workspace frame; `[palm, left finger, right finger]`).
    pub fn swept_boxes(
        &self,
        gripper: &GripperModel,
        workspace_from_gripper: &Isometry3<f32>,
        width_m: f32,
    ) -> [OrientedBox; 3] {
        let opening = psgrasp_geometry::commanded_opening_m(
            width_m,
            self.opening_clearance_m,
            gripper.max_opening_m,
        );
        let half = 0.5 * self.distance_m;
        gripper.boxes_in_gripper_frame(opening).map(|b| {
            let stretched = OrientedBox {
                parent_from_box: Translation3::new(0.0, 0.0, -half) * b.parent_from_box,
                half_extents: b.half_extents + nalgebra::Vector3::new(0.0, 0.0, half),
            };
            stretched.placed(workspace_from_gripper)
        })
    }

    /// True when any part of the descending hand meets an object (the grasped one included) or
    /// the bin.
    pub fn blocked(
        &self,
        scene: &Scene,
        gripper: &GripperModel,
        workspace_from_gripper: &Isometry3<f32>,
        width_m: f32,
    ) -> bool {
        self.swept_boxes(gripper, workspace_from_gripper, width_m)
            .iter()
            .any(|b| scene.box_collides(b, None))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Point3, UnitQuaternion, Vector3};

    #[test]
    fn swept_boxes_cover_every_pose_of_the_descent_and_nothing_below_the_grasp() {
        let gripper = GripperModel::default();
        let check = ApproachPathCheck::default();
        let pose = Isometry3::from_parts(
            Translation3::new(0.1, -0.2, 0.3),
            UnitQuaternion::from_euler_angles(0.4, -0.3, 1.1),
        );
        let width = 0.03;
        let opening = width + check.opening_clearance_m;
        let swept = check.swept_boxes(&gripper, &pose, width);
        for step in 0..=10 {
            let back = check.distance_m * step as f32 / 10.0;
            let at = pose * Translation3::new(0.0, 0.0, -back);
            for (part, b) in gripper.boxes(&at, opening).iter().enumerate() {
                for corner in b.corners() {
                    assert!(
                        swept[part].contains(&corner, 1e-5),
                        "part {part} at {back} m"
                    );
                }
            }
        }
        // A point just beyond the fingertips at the grasp pose is outside every swept box.
        let tip = pose * Point3::new(0.5 * opening, 0.0, gripper.tip_beyond_tcp_m + 1e-3);
        assert!(swept.iter().all(|b| !b.contains(&tip, 0.0)));
        // The palm's swept box reaches the pre-grasp pose's palm top and not beyond.
        let pregrasp = pose * Translation3::new(0.0, 0.0, -check.distance_m);
        let palm_top =
            pregrasp * Point3::new(0.0, 0.0, -gripper.tcp_to_palm_m() - gripper.palm_size_m[2]);
        assert!(swept[0].contains(&palm_top, 1e-5));
        assert!(!swept[0].contains(&(palm_top + (pose.rotation * -Vector3::z()) * 2e-3), 0.0));
    }

    #[test]
    fn bad_settings_are_refused_by_name() {
        let bad = ApproachPathCheck {
            distance_m: f32::NAN,
            ..Default::default()
        };
        let err = bad.validate().unwrap_err().to_string();
        assert!(err.contains("labels.approach_path.distance_m"), "{err}");
        assert!(ApproachPathCheck::default().validate().is_ok());
    }
}
