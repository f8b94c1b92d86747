//! Contact grasps `g = (c, b, a, w)` and grasp configurations `C = (c, b, {a_i}, {σ_i}, w, q, κ)`.
//!
//! Approach vectors follow the paper: `a_i = R_{γ_i} b_⊥`, with `b_⊥` the Gram–Schmidt projection of
//! the workspace "down" direction onto the plane orthogonal to `b` and `γ_i` evenly spaced over
//! `[π/2, 3π/2]` (both ends included). With this convention `γ = π` gives the approach closest to
//! straight down and every `a_i` has a non-positive z component, i.e. all approaches point downward.
use crate::gripper::GripperModel;
use nalgebra::{
    Isometry3, Matrix3, Point3, Rotation3, Translation3, Unit, UnitQuaternion, Vector3,
};
use serde::{Deserialize, Serialize};

/// Number of approach vectors per grasp configuration (`n_r` in the paper).
pub const N_APPROACHES: usize = 18;

/// A parallel-jaw grasp anchored at a contact point.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ContactGrasp {
    /// First contact point `c` (workspace frame).
    pub contact: Point3<f32>,
    /// Unit baseline `b`, from `c` towards the second contact `c + w·b`.
    pub baseline: Vector3<f32>,
    /// Unit approach `a`, from the palm towards the object; orthogonal to `b`.
    pub approach: Vector3<f32>,
    /// Opening width `w` between the two contacts.
    pub width: f32,
}

impl ContactGrasp {
    /// The second contact `c + w·b`.
    pub fn second_contact(&self) -> Point3<f32> {
        self.contact + self.baseline * self.width
    }

    /// The grasp centre, midway between the contacts (the tool centre point).
    pub fn center(&self) -> Point3<f32> {
        self.contact + self.baseline * (0.5 * self.width)
    }

    /// Pose of the gripper frame (x = baseline, z = approach, origin = tool centre point)
    /// in the workspace frame.
    pub fn workspace_from_gripper(&self) -> Isometry3<f32> {
        let x = self.baseline.normalize();
        // Re-orthogonalise the approach against the baseline to absorb rounding.
        let z = (self.approach - x * x.dot(&self.approach)).normalize();
        let y = z.cross(&x);
        let rot = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[x, y, z]));
        Isometry3::from_parts(
            Translation3::from(self.center().coords),
            UnitQuaternion::from_rotation_matrix(&rot),
        )
    }

    /// [`Self::workspace_from_gripper`] with the tool centre point raised `lift_m` back along the
    /// approach: the contacts then meet the pads `lift_m` below their centre.
    pub fn workspace_from_gripper_lifted(&self, lift_m: f32) -> Isometry3<f32> {
        self.workspace_from_gripper() * Translation3::new(0.0, 0.0, -lift_m)
    }

    /// The approach point `t`: the centre of the finger bases, `tcp − a·d`, where `d` is the
    /// distance from the tool centre point to the palm face of `gripper`.
    pub fn approach_point(&self, gripper: &GripperModel) -> Point3<f32> {
        self.center() - self.approach * gripper.tcp_to_palm_m()
    }

    /// True if all fields are finite and the directions are unit and orthogonal (within `tol`).
    pub fn is_well_formed(&self, tol: f32) -> bool {
        let finite = self
            .contact
            .coords
            .iter()
            .chain(self.baseline.iter())
            .chain(self.approach.iter())
            .all(|v| v.is_finite())
            && self.width.is_finite();
        finite
            && (self.baseline.norm() - 1.0).abs() < tol
            && (self.approach.norm() - 1.0).abs() < tol
            && self.baseline.dot(&self.approach).abs() < tol
            && self.width >= 0.0
    }
}

/// The network's output at one contact point: a baseline, `n_r` approaches with collision scores,
/// opening width, antipodal quality and baseline concentration `κ`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GraspConfiguration {
    /// Contact point `c` (workspace frame).
    pub contact: Point3<f32>,
    /// Unit baseline `b` (mean `ν` of the baseline distribution).
    pub baseline: Vector3<f32>,
    /// Collision scores `σ_i` in [0, 1] for the approaches `a_i` (1 = collision-free).
    pub collision_scores: [f32; N_APPROACHES],
    /// Opening width `w` in metres.
    pub width: f32,
    /// Antipodal quality `q` in [0, 1].
    pub quality: f32,
    /// Concentration `κ` of the Power-Spherical baseline distribution (0 if not modelled).
    pub kappa: f32,
    /// The floor `κ0` the backend clamps `κ` to (the model card's `kappa0`): `κ` at the floor
    /// means the network's own estimate was at or below it. 0 where `κ` is not modelled or has
    /// no floor. Selection's `confident-first` order reads it from each configuration.
    #[serde(default, skip_serializing_if = "crate::is_zero")]
    pub kappa_floor: f32,
}

impl GraspConfiguration {
    /// The `n_r` approach vectors of this configuration.
    pub fn approaches(&self) -> [Vector3<f32>; N_APPROACHES] {
        approach_vectors(&self.baseline)
    }

    /// The contact grasp using approach `i`.
    pub fn grasp(&self, i: usize) -> ContactGrasp {
        ContactGrasp {
            contact: self.contact,
            baseline: self.baseline,
            approach: self.approaches()[i],
            width: self.width,
        }
    }

    /// Approach indices ordered by decreasing collision score (ties by index).
    pub fn approaches_by_score(&self) -> [usize; N_APPROACHES] {
        let mut idx: [usize; N_APPROACHES] = std::array::from_fn(|i| i);
        idx.sort_by(|&a, &b| {
            self.collision_scores[b]
                .total_cmp(&self.collision_scores[a])
                .then(a.cmp(&b))
        });
        idx
    }
}

/// The rotation angles `γ_i`: `n` values evenly spaced over `[π/2, 3π/2]`, ends included.
pub fn approach_angles(n: usize) -> Vec<f32> {
    use std::f32::consts::PI;
    match n {
        0 => vec![],
        1 => vec![PI],
        _ => (0..n)
            .map(|i| 0.5 * PI + PI * i as f32 / (n - 1) as f32)
            .collect(),
    }
}

/// `b_⊥`: the unit vector orthogonal to `b` closest to straight up (+z), from Gram–Schmidt.
/// For a vertical baseline the workspace +x axis is used instead.
pub fn baseline_perpendicular(b: &Vector3<f32>) -> Vector3<f32> {
    let b = b.normalize();
    let up = Vector3::z();
    let p = up - b * b.dot(&up);
    if p.norm() > 1e-3 {
        p.normalize()
    } else {
        let x = Vector3::x();
        (x - b * b.dot(&x)).normalize()
    }
}

/// The `N_APPROACHES` approach vectors `a_i = R_{γ_i} b_⊥` for baseline `b`.
pub fn approach_vectors(b: &Vector3<f32>) -> [Vector3<f32>; N_APPROACHES] {
    let b = b.normalize();
    let axis = Unit::new_unchecked(b);
    let perp = baseline_perpendicular(&b);
    let angles = approach_angles(N_APPROACHES);
    std::array::from_fn(|i| Rotation3::from_axis_angle(&axis, angles[i]) * perp)
}

/// Antipodal quality `q = |cos(b, n1)|·|cos(b, n2)|` for unit normals at the two contacts.
pub fn antipodal_quality(baseline: &Vector3<f32>, n1: &Vector3<f32>, n2: &Vector3<f32>) -> f32 {
    let b = baseline.normalize();
    (b.dot(&n1.normalize()).abs() * b.dot(&n2.normalize()).abs()).clamp(0.0, 1.0)
}

/// Most tool-centre-point lifts a configuration may list ([`check_tcp_lifts`]).
pub const MAX_TCP_LIFTS: usize = 8;

/// Runs `check` with the tool centre point at the contacts (lift 0), then at each of
/// `extra_lifts_m` (a `tcp_lifts_m` setting of labels or selection) in order, and returns the
/// first success; when every lift fails, the unlifted pose's failure (what blocks the grasp as the
/// paper's frame places it).
pub fn at_first_passing_lift<T, E>(
    extra_lifts_m: &[f32],
    mut check: impl FnMut(f32) -> Result<T, E>,
) -> Result<T, E> {
    let unlifted = check(0.0);
    if unlifted.is_ok() {
        return unlifted;
    }
    for &lift in extra_lifts_m {
        let lifted = check(lift);
        if lifted.is_ok() {
            return lifted;
        }
    }
    unlifted
}

/// Checks a `tcp_lifts_m` setting: at most [`MAX_TCP_LIFTS`] values, each finite, in
/// `(0, 0.05]` m and larger than the one before.
pub fn check_tcp_lifts(lifts_m: &[f32], field: &'static str) -> Result<(), crate::OutOfRange> {
    let in_range = lifts_m
        .iter()
        .all(|v| v.is_finite() && *v > 0.0 && *v <= 0.05);
    let increasing = lifts_m.windows(2).all(|w| w[1] > w[0]);
    crate::check_setting(
        lifts_m.len() <= MAX_TCP_LIFTS && in_range && increasing,
        field,
        "at most 8 increasing values in (0, 0.05] m",
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_first_passing_lift_wins_and_the_unlifted_failure_is_kept() {
        let mut tried = Vec::new();
        let passes_from_5mm = |lift: f32| if lift >= 0.005 { Ok(lift) } else { Err(lift) };
        let r = at_first_passing_lift(&[0.003, 0.006, 0.009], |lift| {
            tried.push(lift);
            passes_from_5mm(lift)
        });
        assert_eq!(r, Ok(0.006));
        assert_eq!(tried, [0.0, 0.003, 0.006]);
        assert_eq!(at_first_passing_lift(&[0.003], passes_from_5mm), Err(0.0));
        assert_eq!(at_first_passing_lift(&[], |_| Ok::<_, ()>(1)), Ok(1));
    }

    #[test]
    fn approaches_are_orthogonal_and_point_down() {
        for b in [
            Vector3::new(1.0, 0.0, 0.0),
            Vector3::new(0.3, -0.8, 0.5),
            Vector3::new(0.0, 0.0, 1.0),
        ] {
            let b = b.normalize();
            let a = approach_vectors(&b);
            for ai in a.iter() {
                assert!((ai.norm() - 1.0).abs() < 1e-5);
                assert!(ai.dot(&b).abs() < 1e-5);
                assert!(ai.z <= 1e-5, "approach {ai:?} points up for baseline {b:?}");
            }
            // First and last are opposite horizontal-most directions; the middle pair brackets straight down.
            assert!((a[0] + a[N_APPROACHES - 1]).norm() < 1e-4);
        }
        // Horizontal baseline: the middle approaches are nearly straight down.
        let a = approach_vectors(&Vector3::x());
        assert!(a[8].z < -0.98 && a[9].z < -0.98);
    }

    #[test]
    fn antipodal_quality_known_values() {
        let b = Vector3::x();
        assert!((antipodal_quality(&b, &-Vector3::x(), &Vector3::x()) - 1.0).abs() < 1e-6);
        let n = Vector3::new(1.0, 1.0, 0.0).normalize();
        assert!((antipodal_quality(&b, &n, &n) - 0.5).abs() < 1e-6);
        assert!(antipodal_quality(&b, &Vector3::y(), &Vector3::x()) < 1e-6);
    }

    #[test]
    fn gripper_frame_is_right_handed_and_centered() {
        let g = ContactGrasp {
            contact: Point3::new(0.1, 0.2, 0.05),
            baseline: Vector3::y(),
            approach: -Vector3::z(),
            width: 0.04,
        };
        let pose = g.workspace_from_gripper();
        assert!((pose * Point3::origin() - Point3::new(0.1, 0.22, 0.05)).norm() < 1e-6);
        assert!((pose.rotation * Vector3::x() - Vector3::y()).norm() < 1e-6);
        assert!((pose.rotation * Vector3::z() + Vector3::z()).norm() < 1e-6);
        assert!((pose.rotation.to_rotation_matrix().matrix().determinant() - 1.0).abs() < 1e-5);
        assert!(g.is_well_formed(1e-4));
    }

    #[test]
    fn approaches_by_score_orders_descending() {
        let mut cfg = GraspConfiguration {
            contact: Point3::origin(),
            baseline: Vector3::x(),
            collision_scores: [0.1; N_APPROACHES],
            width: 0.03,
            quality: 0.9,
            kappa: 25.0,
            kappa_floor: 0.0,
        };
        cfg.collision_scores[5] = 0.9;
        cfg.collision_scores[2] = 0.7;
        let order = cfg.approaches_by_score();
        assert_eq!(&order[..3], &[5, 2, 0]);
    }
}
