//! The robot cell around the workspace: where the camera sits in the robot's base frame (the
//! hand-eye calibration) and where the gripper's TCP sits on the robot's flange, so that every
//! pick can be handed to a controller in its own frame.
//!
//! Frames: `base` is the robot base frame, `flange` the robot's tool flange, `tcp` the psgrasp
//! gripper frame (origin midway between the finger pads at grasp depth, x = closing direction,
//! z = approach; `docs/architecture.md`), `fingertips` the same axes with the origin moved
//! forward to the centre of the fingertips (where robot vendors put their default TCP).
use crate::GeometryError;
use nalgebra::{Isometry3, Matrix3, Matrix4, Quaternion, Rotation3, Translation3, UnitQuaternion};
use serde::{Deserialize, Serialize};

/// Largest accepted deviation of a configured rotation from a proper rotation (quaternion norm
/// minus one, or the entries of `RᵀR − I` and `det R − 1` for a matrix). Calibration tools print
/// six to nine digits; anything further off is a typo, not rounding.
pub const ROTATION_TOLERANCE: f64 = 1e-3;

/// Franka Hand: distance from the robot flange to the centre of the fingertips along the flange
/// z axis (libfranka's default `F_T_EE`, 0.1034 m).
pub const FRANKA_FLANGE_TO_FINGERTIPS_M: f64 = 0.1034;

/// A rigid pose as written in a configuration: either `translation_m` (+ `rotation_xyzw`, unit
/// quaternion x, y, z, w; identity if omitted) or a homogeneous 4×4 `matrix` (row-major, last row
/// `0 0 0 1`), never both.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct PoseSetting {
    /// Translation, metres.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub translation_m: Option<[f64; 3]>,
    /// Rotation as a unit quaternion (x, y, z, w).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rotation_xyzw: Option<[f64; 4]>,
    /// The whole pose as a homogeneous matrix, rows first.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub matrix: Option<[[f64; 4]; 4]>,
}

impl PoseSetting {
    /// A pose given by translation and quaternion.
    pub fn from_parts(translation_m: [f64; 3], rotation_xyzw: [f64; 4]) -> Self {
        Self {
            translation_m: Some(translation_m),
            rotation_xyzw: Some(rotation_xyzw),
            matrix: None,
        }
    }

    /// The pose, checked: finite numbers, a proper rotation within [`ROTATION_TOLERANCE`]
    /// (re-normalised), and exactly one of the two forms.
    pub fn isometry(&self) -> Result<Isometry3<f64>, String> {
        let finite = |v: &[f64]| v.iter().all(|x| x.is_finite());
        match (self.matrix, self.translation_m, self.rotation_xyzw) {
            (Some(_), Some(_), _) | (Some(_), _, Some(_)) => {
                Err("give either `matrix` or `translation_m`/`rotation_xyzw`, not both".into())
            }
            (Some(m), None, None) => {
                if !m.iter().all(|row| finite(row)) {
                    return Err("matrix has a non-finite entry".into());
                }
                if m[3] != [0.0, 0.0, 0.0, 1.0] {
                    return Err(format!(
                        "matrix's last row must be [0, 0, 0, 1], not {:?}",
                        m[3]
                    ));
                }
                let r = Matrix3::from_fn(|i, j| m[i][j]);
                let orthogonality = (r.transpose() * r - Matrix3::identity()).abs().max();
                let det = r.determinant();
                if orthogonality > ROTATION_TOLERANCE || (det - 1.0).abs() > ROTATION_TOLERANCE {
                    return Err(format!(
                        "matrix's upper-left 3×3 is not a rotation (|RᵀR − I| = {orthogonality:.2e}, det = {det:.6})"
                    ));
                }
                let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_eps(
                    &r,
                    1e-12,
                    100,
                    Rotation3::identity(),
                ));
                Ok(Isometry3::from_parts(
                    Translation3::new(m[0][3], m[1][3], m[2][3]),
                    rotation,
                ))
            }
            (None, t, q) => {
                let t = t.unwrap_or([0.0; 3]);
                let q = q.unwrap_or([0.0, 0.0, 0.0, 1.0]);
                if !finite(&t) || !finite(&q) {
                    return Err("translation_m / rotation_xyzw has a non-finite entry".into());
                }
                let norm = q.iter().map(|x| x * x).sum::<f64>().sqrt();
                if (norm - 1.0).abs() > ROTATION_TOLERANCE {
                    return Err(format!(
                        "rotation_xyzw must be a unit quaternion (x, y, z, w), its norm is {norm:.6}"
                    ));
                }
                Ok(Isometry3::from_parts(
                    Translation3::new(t[0], t[1], t[2]),
                    UnitQuaternion::from_quaternion(Quaternion::new(q[3], q[0], q[1], q[2])),
                ))
            }
        }
    }
}

/// `[robot]`: the camera's pose in the robot base frame and the gripper's place on the flange.
/// Every key is optional: without `camera_in_base` the picks' base frame is the workspace frame
/// (and the picks say so).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RobotConfig {
    /// The camera's pose in the robot base frame: the result of the hand-eye calibration
    /// (camera frame as in the frame header: x right, y down, z along the optical axis).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub camera_in_base: Option<PoseSetting>,
    /// The fingertip frame (the gripper frame's axes, origin at the centre of the fingertips)
    /// in the robot flange frame. Default: the Franka Hand on a Panda/FR3 flange,
    /// 0.1034 m along z, turned +45° about z (the hand sits at −45° and closes along its own y,
    /// psgrasp's gripper closes along x).
    pub fingertips_in_flange: PoseSetting,
}

impl Default for RobotConfig {
    fn default() -> Self {
        let half = std::f64::consts::FRAC_PI_8;
        Self {
            camera_in_base: None,
            fingertips_in_flange: PoseSetting::from_parts(
                [0.0, 0.0, FRANKA_FLANGE_TO_FINGERTIPS_M],
                [0.0, 0.0, half.sin(), half.cos()],
            ),
        }
    }
}

impl RobotConfig {
    /// Checks both poses.
    pub fn validate(&self) -> Result<(), GeometryError> {
        self.resolve(0.0).map(|_| ())
    }

    /// The cell's geometry for a gripper whose fingertips reach `tip_beyond_tcp_m` beyond its TCP.
    pub fn resolve(&self, tip_beyond_tcp_m: f32) -> Result<RobotCell, GeometryError> {
        let camera_in_base = match &self.camera_in_base {
            Some(p) => Some(
                p.isometry()
                    .map_err(|e| GeometryError::InvalidRobot(format!("camera_in_base: {e}")))?,
            ),
            None => None,
        };
        let fingertips_in_flange = self
            .fingertips_in_flange
            .isometry()
            .map_err(|e| GeometryError::InvalidRobot(format!("fingertips_in_flange: {e}")))?;
        let tcp_in_fingertips = Translation3::new(0.0, 0.0, -(tip_beyond_tcp_m as f64));
        Ok(RobotCell {
            camera_in_base,
            tcp_in_flange: fingertips_in_flange * tcp_in_fingertips,
        })
    }
}

/// The resolved robot cell.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RobotCell {
    /// The calibrated camera pose in the base frame (`None`: uncalibrated).
    pub camera_in_base: Option<Isometry3<f64>>,
    /// The gripper frame (TCP) in the flange frame.
    pub tcp_in_flange: Isometry3<f64>,
}

/// The robot base frame of one frame's picks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BaseFrame {
    /// Maps workspace points into the base frame.
    pub base_from_workspace: Isometry3<f64>,
    /// The camera's pose in the base frame.
    pub camera_in_base: Isometry3<f64>,
    /// False when no calibration is configured: the base frame is then the workspace frame.
    pub calibrated: bool,
    /// The TCP in the flange frame.
    pub tcp_in_flange: Isometry3<f64>,
}

/// A pose in the base frame, of the TCP and of the flange that puts the TCP there.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseInBase {
    /// The gripper frame (TCP) in the base frame.
    pub tcp: Isometry3<f64>,
    /// The flange in the base frame.
    pub flange: Isometry3<f64>,
}

impl RobotCell {
    /// The base frame of a frame whose camera was at `workspace_from_camera`.
    pub fn base_frame(&self, workspace_from_camera: &Isometry3<f32>) -> BaseFrame {
        let workspace_from_camera: Isometry3<f64> = workspace_from_camera.cast();
        match self.camera_in_base {
            Some(base_from_camera) => BaseFrame {
                base_from_workspace: base_from_camera * workspace_from_camera.inverse(),
                camera_in_base: base_from_camera,
                calibrated: true,
                tcp_in_flange: self.tcp_in_flange,
            },
            None => BaseFrame {
                base_from_workspace: Isometry3::identity(),
                camera_in_base: workspace_from_camera,
                calibrated: false,
                tcp_in_flange: self.tcp_in_flange,
            },
        }
    }
}

impl BaseFrame {
    /// A gripper pose given in the workspace frame, in the base frame.
    pub fn pose(&self, workspace_from_gripper: &Isometry3<f32>) -> PoseInBase {
        let tcp = self.base_from_workspace * workspace_from_gripper.cast::<f64>();
        PoseInBase {
            tcp,
            flange: tcp * self.tcp_in_flange.inverse(),
        }
    }
}

/// `pose` as a row-major homogeneous 4×4 matrix.
pub fn matrix_rows(pose: &Isometry3<f64>) -> [[f64; 4]; 4] {
    let m: Matrix4<f64> = pose.to_homogeneous();
    std::array::from_fn(|i| std::array::from_fn(|j| m[(i, j)]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Point3, Vector3};

    fn close(a: &Isometry3<f64>, b: &Isometry3<f64>) -> bool {
        (a.to_homogeneous() - b.to_homogeneous()).abs().max() < 1e-9
    }

    #[test]
    fn matrix_and_quaternion_forms_give_the_same_pose() {
        let q = UnitQuaternion::from_euler_angles(0.3, -1.1, 2.0);
        let pose = Isometry3::from_parts(Translation3::new(0.4, -0.2, 1.3), q);
        let c = q.coords;
        let by_parts = PoseSetting::from_parts([0.4, -0.2, 1.3], [c[0], c[1], c[2], c[3]]);
        let by_matrix = PoseSetting {
            matrix: Some(matrix_rows(&pose)),
            ..Default::default()
        };
        assert!(close(&by_parts.isometry().unwrap(), &pose));
        assert!(close(&by_matrix.isometry().unwrap(), &pose));
    }

    #[test]
    fn bad_poses_are_refused_with_the_reason() {
        let not_unit = PoseSetting::from_parts([0.0; 3], [0.0, 0.0, 0.0, 2.0]);
        assert!(not_unit.isometry().unwrap_err().contains("unit quaternion"));
        let mut m = matrix_rows(&Isometry3::identity());
        m[0][0] = 2.0;
        let skewed = PoseSetting {
            matrix: Some(m),
            ..Default::default()
        };
        assert!(skewed.isometry().unwrap_err().contains("not a rotation"));
        let mut m = matrix_rows(&Isometry3::identity());
        m[3][2] = 1.0;
        let projective = PoseSetting {
            matrix: Some(m),
            ..Default::default()
        };
        assert!(projective.isometry().unwrap_err().contains("last row"));
        let both = PoseSetting {
            matrix: Some(matrix_rows(&Isometry3::identity())),
            translation_m: Some([0.0; 3]),
            rotation_xyzw: None,
        };
        assert!(both.isometry().unwrap_err().contains("not both"));
        let robot = RobotConfig {
            camera_in_base: Some(not_unit),
            ..Default::default()
        };
        let e = robot.validate().unwrap_err().to_string();
        assert!(e.contains("robot cell: camera_in_base"), "{e}");
    }

    #[test]
    fn a_pick_in_the_base_frame_is_the_calibration_applied_to_the_workspace_pose() {
        // Camera 1.2 m above the base origin looking down (camera z = −base z).
        let base_from_camera = Isometry3::from_parts(
            Translation3::new(0.5, 0.1, 1.2),
            UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI),
        );
        let c = base_from_camera.rotation.coords;
        let robot = RobotConfig {
            camera_in_base: Some(PoseSetting::from_parts(
                [0.5, 0.1, 1.2],
                [c[0], c[1], c[2], c[3]],
            )),
            ..Default::default()
        };
        let cell = robot.resolve(0.0095).unwrap();
        let workspace_from_camera = Isometry3::from_parts(
            Translation3::new(0.15f32, 0.15, 0.8),
            UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f32::consts::PI),
        );
        let frame = cell.base_frame(&workspace_from_camera);
        assert!(frame.calibrated);
        let grasp = Isometry3::from_parts(
            Translation3::new(0.1f32, 0.2, 0.05),
            UnitQuaternion::from_euler_angles(0.2, 0.1, -0.4),
        );
        let p = frame.pose(&grasp);
        // The grasp centre seen from the camera, then put into the base by the calibration.
        let in_camera = workspace_from_camera.inverse_transform_point(&Point3::new(0.1, 0.2, 0.05));
        let expected = base_from_camera * in_camera.cast::<f64>();
        assert!((p.tcp.translation.vector - expected.coords).norm() < 1e-6);
        // The flange sits 0.1034 − 0.0095 m behind the TCP along the approach.
        let back = p.tcp.rotation * Vector3::z() * (FRANKA_FLANGE_TO_FINGERTIPS_M - 0.0095);
        assert!((p.flange.translation.vector - (p.tcp.translation.vector - back)).norm() < 1e-9);
        // Uncalibrated: the base frame is the workspace frame.
        let plain = RobotConfig::default().resolve(0.0095).unwrap();
        let f = plain.base_frame(&workspace_from_camera);
        assert!(!f.calibrated);
        assert!(close(&f.pose(&grasp).tcp, &grasp.cast()));
    }

    #[test]
    fn a_robot_table_reads_both_forms_and_refuses_unknown_keys() {
        let r: RobotConfig = toml::from_str(
            "camera_in_base = { matrix = [[1,0,0,0.5],[0,-1,0,0],[0,0,-1,1.2],[0,0,0,1]] }",
        )
        .unwrap();
        let p = r.resolve(0.0).unwrap().camera_in_base.unwrap();
        assert!((p.translation.vector - Vector3::new(0.5, 0.0, 1.2)).norm() < 1e-12);
        assert_eq!(
            r.fingertips_in_flange,
            RobotConfig::default().fingertips_in_flange
        );
        assert!(toml::from_str::<RobotConfig>("camera_pose = {}").is_err());
        assert!(
            toml::from_str::<RobotConfig>("camera_in_base = { translation = [0,0,0] }").is_err()
        );
    }
}
