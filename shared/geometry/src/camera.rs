//! Pinhole camera intrinsics and the camera pose relative to the workspace.
use crate::depth::MAX_IMAGE_SIDE;
use crate::GeometryError;
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

/// Pinhole intrinsics of a depth camera, in pixels.
///
/// Read from a file, every key is optional (missing keys take the [`Default`] values) and other
/// keys are ignored: the intrinsics files of camera tools carry more (a depth unit,
/// distortion). A configuration table, where a misspelt key must fail, is read with
/// [`deserialize_intrinsics_strict`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct CameraIntrinsics {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Focal length along x in pixels.
    pub fx: f32,
    /// Focal length along y in pixels.
    pub fy: f32,
    /// Principal point x in pixels.
    pub cx: f32,
    /// Principal point y in pixels.
    pub cy: f32,
}

/// Reads [`CameraIntrinsics`] refusing unknown keys (missing keys still take the defaults), for
/// a configuration's intrinsics table: `#[serde(deserialize_with = "...")]`.
pub fn deserialize_intrinsics_strict<'de, D: serde::Deserializer<'de>>(
    deserializer: D,
) -> Result<CameraIntrinsics, D::Error> {
    /// The same keys, refusing others.
    #[derive(Deserialize)]
    #[serde(default, deny_unknown_fields)]
    struct Strict {
        width: u32,
        height: u32,
        fx: f32,
        fy: f32,
        cx: f32,
        cy: f32,
    }
    impl Default for Strict {
        fn default() -> Self {
            let k = CameraIntrinsics::default();
            Self {
                width: k.width,
                height: k.height,
                fx: k.fx,
                fy: k.fy,
                cx: k.cx,
                cy: k.cy,
            }
        }
    }
    let s = Strict::deserialize(deserializer)?;
    Ok(CameraIntrinsics {
        width: s.width,
        height: s.height,
        fx: s.fx,
        fy: s.fy,
        cx: s.cx,
        cy: s.cy,
    })
}

impl Default for CameraIntrinsics {
    /// [`CameraIntrinsics::default_640x480`].
    fn default() -> Self {
        Self::default_640x480()
    }
}

impl CameraIntrinsics {
    /// A 640×480 camera with a ~58° horizontal field of view (RealSense-like).
    pub fn default_640x480() -> Self {
        Self {
            width: 640,
            height: 480,
            fx: 580.0,
            fy: 580.0,
            cx: 319.5,
            cy: 239.5,
        }
    }

    /// Checks that the intrinsics describe a usable pinhole camera.
    pub fn validate(&self) -> Result<(), GeometryError> {
        let finite = [self.fx, self.fy, self.cx, self.cy]
            .iter()
            .all(|v| v.is_finite());
        if !finite {
            return Err(GeometryError::InvalidIntrinsics(
                "non-finite focal length or principal point",
            ));
        }
        if self.width == 0 || self.height == 0 {
            return Err(GeometryError::InvalidIntrinsics(
                "image width and height must be > 0",
            ));
        }
        if self.width > MAX_IMAGE_SIDE || self.height > MAX_IMAGE_SIDE {
            return Err(GeometryError::InvalidIntrinsics(
                "image larger than 8192 (MAX_IMAGE_SIDE) pixels on a side",
            ));
        }
        if self.fx <= 0.0 || self.fy <= 0.0 {
            return Err(GeometryError::InvalidIntrinsics(
                "focal lengths must be > 0",
            ));
        }
        let (w, h) = (self.width as f32, self.height as f32);
        if !(-w..=2.0 * w).contains(&self.cx) || !(-h..=2.0 * h).contains(&self.cy) {
            return Err(GeometryError::InvalidIntrinsics(
                "principal point far outside the image",
            ));
        }
        Ok(())
    }

    /// Number of pixels.
    pub fn pixel_count(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// Back-projects pixel (u, v) at depth `z` (metres along the optical axis) into the camera frame.
    pub fn deproject(&self, u: f32, v: f32, z: f32) -> Point3<f32> {
        Point3::new((u - self.cx) * z / self.fx, (v - self.cy) * z / self.fy, z)
    }

    /// Projects a camera-frame point to pixel coordinates; `None` behind the camera.
    pub fn project(&self, p: &Point3<f32>) -> Option<(f32, f32)> {
        if p.z <= 1e-6 {
            return None;
        }
        Some((self.fx * p.x / p.z + self.cx, self.fy * p.y / p.z + self.cy))
    }

    /// Unit ray direction (camera frame) through the centre of pixel (u, v).
    pub fn ray_direction(&self, u: f32, v: f32) -> Vector3<f32> {
        Vector3::new((u - self.cx) / self.fx, (v - self.cy) / self.fy, 1.0).normalize()
    }
}

/// A camera: intrinsics plus its pose in the workspace frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CameraModel {
    /// Pinhole intrinsics.
    pub intrinsics: CameraIntrinsics,
    /// Maps camera-frame points into the workspace frame.
    pub workspace_from_camera: Isometry3<f32>,
}

impl CameraModel {
    /// A camera looking straight down (optical axis = −z of the workspace) from `eye`,
    /// with image x along workspace +x and image y along workspace −y.
    pub fn top_down(intrinsics: CameraIntrinsics, eye: Point3<f32>) -> Self {
        // Camera axes in workspace coordinates: x_c = +x, y_c = −y, z_c = −z (rotation by π about x).
        let rotation = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f32::consts::PI);
        let workspace_from_camera = Isometry3::from_parts(Translation3::from(eye.coords), rotation);
        Self {
            intrinsics,
            workspace_from_camera,
        }
    }

    /// Validates intrinsics and pose.
    pub fn validate(&self) -> Result<(), GeometryError> {
        self.intrinsics.validate()?;
        let t = self.workspace_from_camera.translation.vector;
        let q = self.workspace_from_camera.rotation.coords;
        if !(t.iter().all(|v| v.is_finite()) && q.iter().all(|v| v.is_finite())) {
            return Err(GeometryError::InvalidPose(
                "camera pose has non-finite entries",
            ));
        }
        Ok(())
    }

    /// Camera centre in the workspace frame.
    pub fn eye(&self) -> Point3<f32> {
        Point3::from(self.workspace_from_camera.translation.vector)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn project_deproject_round_trip() {
        let k = CameraIntrinsics::default_640x480();
        let p = k.deproject(100.0, 400.0, 0.75);
        let (u, v) = k.project(&p).unwrap();
        assert!((u - 100.0).abs() < 1e-3 && (v - 400.0).abs() < 1e-3);
    }

    #[test]
    fn bad_intrinsics_are_rejected() {
        let mut k = CameraIntrinsics::default_640x480();
        k.fx = f32::NAN;
        assert!(k.validate().is_err());
        let mut k = CameraIntrinsics::default_640x480();
        k.fy = -1.0;
        assert!(k.validate().is_err());
        let mut k = CameraIntrinsics::default_640x480();
        k.width = 0;
        assert!(k.validate().is_err());
        assert!(CameraIntrinsics::default_640x480().validate().is_ok());
    }

    #[test]
    fn top_down_camera_looks_down() {
        let cam = CameraModel::top_down(
            CameraIntrinsics::default_640x480(),
            Point3::new(0.3, 0.3, 0.9),
        );
        let axis = cam.workspace_from_camera.rotation * Vector3::z();
        assert!((axis - Vector3::new(0.0, 0.0, -1.0)).norm() < 1e-6);
        let x = cam.workspace_from_camera.rotation * Vector3::x();
        assert!((x - Vector3::x()).norm() < 1e-6);
    }
}
