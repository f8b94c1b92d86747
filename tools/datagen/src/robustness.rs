//! Robust quality of a label (Dex-Net's robust grasp metric, here for a labelled grasp): how
//! often the grasp still holds when the hand lands a few millimetres and degrees off it.
//!
//! A detector never executes a label exactly: its contact, baseline and width come from a 9 mm
//! grid and a network a few millimetres and degrees off (docs/evaluation.md, "Where the shipped
//! model still fails": most failed picks have a finger come down on the target itself or close
//! on nothing). ACRONYM's antipodal quality scores only the exact pair, so the quality head cannot
//! learn which grasps tolerate that error. With `[labels.robust_quality]` each label is executed
//! `samples` times at a perturbed hand pose, opened as the evaluation commands it (width plus
//! `opening_clearance_m`); a sample succeeds when the open hand is free of every object and the
//! bin, and both fingers closing along the perturbed baseline meet the target at an antipodal
//! pair (quality above the labeler's threshold). The stored quality becomes
//! `threshold + (q − threshold)·s` for success share `s` (still above the threshold exactly when
//! some perturbed execution holds), or with `max_drop` set `q − max_drop·(1 − s)`, which keeps the
//! qualities' scale: the first form moved the stored mean from 0.90 to 0.69, and a network
//! regressing to it predicts most grasps below the selection's 0.5 (docs/model.md, "Robust
//! quality").
use crate::labels::GraspLabel;
use nalgebra::{Isometry3, Point3, Translation3, Unit, UnitQuaternion, Vector3};
use psgrasp_geometry::{
    antipodal_quality, check_setting, commanded_opening_m, GripperModel, OutOfRange,
};
use psgrasp_sim::execute::hand_collides;
use psgrasp_sim::Scene;
use rand::Rng;
use rand_distr::{Distribution, Normal, StandardNormal};
use serde::{Deserialize, Serialize};

/// The perturbation model of the robust quality (`[labels.robust_quality]` of a datagen config).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RobustQuality {
    /// Perturbed executions per label (a label and its mirror share them).
    pub samples: usize,
    /// Standard deviation of the hand position error along each axis (m).
    pub position_sigma_m: f32,
    /// Standard deviation of the hand orientation error (degrees, about a random axis).
    pub angle_sigma_deg: f32,
    /// The hand opens to the width plus this, capped at its maximum opening (m): the evaluation
    /// protocol's `[selection.clearance] opening_clearance_m`.
    pub opening_clearance_m: f32,
    /// `Some(d)`: the stored quality is `q − d·(1 − share)` (at least 0). `None` (the default,
    /// not written to manifests): `threshold + (q − threshold)·share`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_drop: Option<f32>,
}

impl Default for RobustQuality {
    /// 8 samples, 3 mm and 5° (half a voxel, and the learned model's width error of ≈ 7.6 mm
    /// moving the hand centre ≈ 4 mm), opened as `config/eval-protocol-franka-fingertip.toml`.
    fn default() -> Self {
        Self {
            samples: 8,
            position_sigma_m: 0.003,
            angle_sigma_deg: 5.0,
            opening_clearance_m: 0.04,
            max_drop: None,
        }
    }
}

impl RobustQuality {
    /// At least one sample; distances finite and in `[0, 0.1)` m; the angle in `[0, 45]`°.
    pub fn validate(&self) -> Result<(), OutOfRange> {
        check_setting(
            self.samples >= 1,
            "labels.robust_quality.samples",
            "must be at least 1",
        )?;
        let metric = |v: f32| v.is_finite() && (0.0..0.1).contains(&v);
        check_setting(
            metric(self.position_sigma_m),
            "labels.robust_quality.position_sigma_m",
            "must lie in [0, 0.1) m",
        )?;
        check_setting(
            metric(self.opening_clearance_m),
            "labels.robust_quality.opening_clearance_m",
            "must lie in [0, 0.1) m",
        )?;
        check_setting(
            self.angle_sigma_deg.is_finite() && (0.0..=45.0).contains(&self.angle_sigma_deg),
            "labels.robust_quality.angle_sigma_deg",
            "must lie in [0, 45] degrees",
        )?;
        check_setting(
            self.max_drop
                .is_none_or(|d| d.is_finite() && (0.0..=1.0).contains(&d)),
            "labels.robust_quality.max_drop",
            "must lie in [0, 1]",
        )
    }

    /// The share of perturbed executions of `label` that hold its object (0 when it has no
    /// collision-free approach). Each sample executes one of its free approaches, in turn.
    pub fn success_share(
        &self,
        scene: &Scene,
        gripper: &GripperModel,
        label: &GraspLabel,
        min_quality: f32,
        rng: &mut impl Rng,
    ) -> f32 {
        let free: Vec<usize> = (0..label.collision_free.len())
            .filter(|&i| label.collision_free[i])
            .collect();
        if free.is_empty() || self.samples == 0 {
            return 0.0;
        }
        let opening =
            commanded_opening_m(label.width, self.opening_clearance_m, gripper.max_opening_m);
        let held = (0..self.samples)
            .filter(|&k| {
                let pose = label.grasp(free[k % free.len()]).workspace_from_gripper();
                let perturbed = self.perturb(&pose, rng);
                holds(
                    scene,
                    gripper,
                    label.object as usize,
                    &perturbed,
                    opening,
                    min_quality,
                )
            })
            .count();
        held as f32 / self.samples as f32
    }

    /// The stored quality of a label of antipodal `quality` whose perturbed executions held
    /// `share` of the time: `q − max_drop·(1 − share)` (at least 0) with `max_drop` set,
    /// otherwise blended towards `min_quality`, `min + (q − min)·share`.
    pub fn blend(&self, quality: f32, min_quality: f32, share: f32) -> f32 {
        let share = share.clamp(0.0, 1.0);
        match self.max_drop {
            Some(drop) => (quality - drop * (1.0 - share)).max(0.0),
            None => min_quality + (quality - min_quality) * share,
        }
    }

    /// `pose` moved by a normal position error and turned by a normal angle about a uniformly
    /// random axis through its tool centre point.
    fn perturb(&self, pose: &Isometry3<f32>, rng: &mut impl Rng) -> Isometry3<f32> {
        let mut normal = || -> f32 { StandardNormal.sample(rng) };
        let shift = Vector3::new(normal(), normal(), normal()) * self.position_sigma_m;
        let axis = Vector3::new(normal(), normal(), normal());
        let angle =
            Normal::new(0.0, self.angle_sigma_deg.to_radians()).map_or(0.0, |d| d.sample(rng));
        let turn = Unit::try_new(axis, 1e-6).map_or_else(UnitQuaternion::identity, |a| {
            UnitQuaternion::from_axis_angle(&a, angle)
        });
        Isometry3::from_parts(
            Translation3::from(pose.translation.vector + shift),
            turn * pose.rotation,
        )
    }
}

/// True when the hand at `pose` (gripper frame: x the baseline, z the approach), open at
/// `opening`, is free of everything and its fingers closing along x meet `object` at an
/// antipodal pair of quality above `min_quality`.
fn holds(
    scene: &Scene,
    gripper: &GripperModel,
    object: usize,
    pose: &Isometry3<f32>,
    opening: f32,
    min_quality: f32,
) -> bool {
    if hand_collides(scene, gripper, pose, opening, 0.0) {
        return false;
    }
    let centre = Point3::from(pose.translation.vector);
    let x = pose.rotation * Vector3::x();
    let half = 0.5 * opening;
    let touch = |from: Point3<f32>, dir: Vector3<f32>| {
        scene
            .cast_ray_object(object, &from, &dir, opening, true)
            .filter(|(toi, _)| *toi > 0.0)
    };
    let (Some((_, n1)), Some((_, n2))) =
        (touch(centre - x * half, x), touch(centre + x * half, -x))
    else {
        return false;
    };
    antipodal_quality(&x, &n1, &n2) > min_quality
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blend_keeps_the_threshold_and_the_exact_quality_at_its_ends() {
        let toward = RobustQuality::default();
        assert_eq!(toward.blend(0.9, 0.5, 1.0), 0.9);
        assert_eq!(toward.blend(0.9, 0.5, 0.0), 0.5);
        assert!((toward.blend(0.9, 0.5, 0.5) - 0.7).abs() < 1e-6);
        assert_eq!(toward.blend(0.9, 0.5, 7.0), 0.9);
        let fixed = RobustQuality {
            max_drop: Some(0.3),
            ..toward
        };
        assert_eq!(fixed.blend(0.9, 0.5, 1.0), 0.9);
        assert!((fixed.blend(0.9, 0.5, 0.0) - 0.6).abs() < 1e-6);
        assert!((fixed.blend(0.6, 0.5, 0.5) - 0.45).abs() < 1e-6);
        assert_eq!(fixed.blend(0.2, 0.5, 0.0), 0.0);
    }

    #[test]
    fn bad_settings_name_their_key() {
        RobustQuality::default().validate().unwrap();
        let bad = |r: RobustQuality| r.validate().unwrap_err().field;
        let d = RobustQuality::default();
        assert_eq!(
            bad(RobustQuality { samples: 0, ..d }),
            "labels.robust_quality.samples"
        );
        assert_eq!(
            bad(RobustQuality {
                position_sigma_m: f32::NAN,
                ..d
            }),
            "labels.robust_quality.position_sigma_m"
        );
        assert_eq!(
            bad(RobustQuality {
                angle_sigma_deg: 90.0,
                ..d
            }),
            "labels.robust_quality.angle_sigma_deg"
        );
        assert_eq!(
            bad(RobustQuality {
                max_drop: Some(-0.1),
                ..d
            }),
            "labels.robust_quality.max_drop"
        );
    }
}
