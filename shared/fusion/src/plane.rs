//! Finding the support plane (table or bin floor) in a frame and placing the workspace on it.
use crate::FusionError;
use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use psgrasp_geometry::{
    depth::is_valid_depth, CameraIntrinsics, CameraModel, DepthImage, Workspace,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// Parameters of [`fit_support_plane`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PlaneFitConfig {
    /// Use every `pixel_stride`-th pixel in each direction. Default 4.
    pub pixel_stride: u32,
    /// Ignore depths below this (metres). Default 0.1 m.
    pub min_depth_m: f32,
    /// Ignore depths beyond this (metres). Default 3 m.
    pub max_depth_m: f32,
    /// RANSAC hypotheses. Default 400.
    pub iterations: u32,
    /// Point-to-plane distance (metres) below which a point supports a plane. Default 6 mm.
    pub inlier_threshold_m: f32,
    /// Hypotheses are scored on at most this many randomly chosen points. Default 3000.
    pub max_score_points: usize,
    /// Least-squares refinement rounds on the inliers of the best hypothesis. Default 3.
    pub refine_rounds: u32,
    /// Minimum number of inliers of the final plane. Default 200.
    pub min_inliers: usize,
    /// Minimum share of the sampled points that must support the final plane. Default 0.2.
    pub min_inlier_fraction: f32,
}

impl Default for PlaneFitConfig {
    fn default() -> Self {
        Self {
            pixel_stride: 4,
            min_depth_m: 0.1,
            max_depth_m: 3.0,
            iterations: 400,
            inlier_threshold_m: 0.006,
            max_score_points: 3000,
            refine_rounds: 3,
            min_inliers: 200,
            min_inlier_fraction: 0.2,
        }
    }
}

impl PlaneFitConfig {
    /// Checks every field.
    pub fn validate(&self) -> Result<(), FusionError> {
        if self.pixel_stride == 0 || self.pixel_stride > 64 {
            return Err(FusionError::InvalidConfig("pixel_stride must be in 1..=64"));
        }
        if !(self.min_depth_m.is_finite()
            && self.max_depth_m.is_finite()
            && self.min_depth_m >= 0.0
            && self.max_depth_m > self.min_depth_m)
        {
            return Err(FusionError::InvalidConfig(
                "need 0 <= min_depth_m < max_depth_m",
            ));
        }
        if self.iterations == 0 {
            return Err(FusionError::InvalidConfig("iterations must be > 0"));
        }
        if !(self.inlier_threshold_m.is_finite() && self.inlier_threshold_m > 0.0) {
            return Err(FusionError::InvalidConfig("inlier_threshold_m must be > 0"));
        }
        if self.max_score_points < 3 {
            return Err(FusionError::InvalidConfig("max_score_points must be >= 3"));
        }
        if self.min_inliers < 3 {
            return Err(FusionError::InvalidConfig("min_inliers must be >= 3"));
        }
        if !(self.min_inlier_fraction.is_finite()
            && (0.0..=1.0).contains(&self.min_inlier_fraction))
        {
            return Err(FusionError::InvalidConfig(
                "min_inlier_fraction must be in [0, 1]",
            ));
        }
        Ok(())
    }
}

/// A plane in the camera frame: points `p` with `normal · p + offset_m = 0`. The normal points
/// towards the camera, so `offset_m` is the camera centre's height above the plane.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Plane {
    /// Unit normal (camera frame), pointing to the camera side.
    pub normal: Vector3<f32>,
    /// Signed offset in metres (> 0: distance of the camera centre from the plane).
    pub offset_m: f32,
    /// Points within the inlier threshold of the final plane.
    pub inlier_count: usize,
    /// Points the fit was run on.
    pub point_count: usize,
    /// RMS point-to-plane distance of the inliers, metres.
    pub rms_m: f32,
}

impl Plane {
    /// Signed distance of a camera-frame point (positive on the camera side).
    pub fn signed_distance(&self, p: &Point3<f32>) -> f32 {
        self.normal.dot(&p.coords) + self.offset_m
    }

    /// Share of the fitted points that support the plane.
    pub fn inlier_fraction(&self) -> f32 {
        if self.point_count == 0 {
            0.0
        } else {
            self.inlier_count as f32 / self.point_count as f32
        }
    }
}

/// Fits the dominant plane of a depth frame: seeded RANSAC on back-projected pixels, then
/// least-squares (PCA) refinement on the inliers. The same seed gives the same plane.
pub fn fit_support_plane(
    depth: &DepthImage,
    intrinsics: &CameraIntrinsics,
    config: &PlaneFitConfig,
    seed: u64,
) -> Result<Plane, FusionError> {
    config.validate()?;
    intrinsics.validate()?;
    crate::check_frame(depth, intrinsics)?;
    if depth.valid_count() == 0 {
        return Err(psgrasp_geometry::DepthError::NoValidPixels.into());
    }
    let stride = config.pixel_stride as usize;
    let mut points = Vec::new();
    for v in (0..depth.height as usize).step_by(stride) {
        for u in (0..depth.width as usize).step_by(stride) {
            let d = depth.data[v * depth.width as usize + u];
            if is_valid_depth(d) && d >= config.min_depth_m && d <= config.max_depth_m {
                points.push(intrinsics.deproject(u as f32, v as f32, d).coords);
            }
        }
    }
    if points.len() < config.min_inliers.max(3) {
        return Err(FusionError::TooFewPoints {
            got: points.len(),
            needed: config.min_inliers.max(3),
        });
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let score_set: Vec<Vector3<f32>> = if points.len() <= config.max_score_points {
        points.clone()
    } else {
        (0..config.max_score_points)
            .map(|_| points[rng.random_range(0..points.len())])
            .collect()
    };
    let thr = config.inlier_threshold_m;
    let mut best: Option<(usize, Vector3<f32>, f32)> = None;
    for _ in 0..config.iterations {
        let a = points[rng.random_range(0..points.len())];
        let b = points[rng.random_range(0..points.len())];
        let c = points[rng.random_range(0..points.len())];
        let n = (b - a).cross(&(c - a));
        let len = n.norm();
        // Skip (near-)collinear samples: the cross product of 1 cm edges is ~1e-4 m².
        if len.is_nan() || len <= 1e-7 {
            continue;
        }
        let n = n / len;
        let off = -n.dot(&a);
        let count = score_set
            .iter()
            .filter(|p| (n.dot(p) + off).abs() < thr)
            .count();
        if best.is_none_or(|(bc, _, _)| count > bc) {
            best = Some((count, n, off));
        }
    }
    let Some((_, mut normal, mut offset)) = best else {
        return Err(FusionError::PlaneNotFound {
            inliers: 0,
            points: points.len(),
        });
    };
    let mut inliers = 0;
    let mut rms = 0.0;
    for _ in 0..config.refine_rounds.max(1) {
        let Some((n, off)) = refine(&points, normal, offset, thr) else {
            break;
        };
        normal = n;
        offset = off;
        (inliers, rms) = support(&points, normal, offset, thr);
    }
    if inliers == 0 {
        (inliers, rms) = support(&points, normal, offset, thr);
    }
    if inliers < config.min_inliers
        || (inliers as f32) < config.min_inlier_fraction * points.len() as f32
    {
        return Err(FusionError::PlaneNotFound {
            inliers,
            points: points.len(),
        });
    }
    if offset.abs() < 1e-6 {
        return Err(FusionError::BadPlane(
            "plane passes through the camera centre",
        ));
    }
    if offset < 0.0 {
        normal = -normal;
        offset = -offset;
    }
    Ok(Plane {
        normal,
        offset_m: offset,
        inlier_count: inliers,
        point_count: points.len(),
        rms_m: rms,
    })
}

/// Inlier count and RMS distance of the inliers.
fn support(points: &[Vector3<f32>], n: Vector3<f32>, off: f32, thr: f32) -> (usize, f32) {
    let mut count = 0usize;
    let mut sq = 0.0f64;
    for p in points {
        let d = n.dot(p) + off;
        if d.abs() < thr {
            count += 1;
            sq += (d * d) as f64;
        }
    }
    let rms = if count > 0 {
        (sq / count as f64).sqrt() as f32
    } else {
        0.0
    };
    (count, rms)
}

/// Least-squares plane through the inliers of (n, off): the smallest principal axis.
fn refine(
    points: &[Vector3<f32>],
    n: Vector3<f32>,
    off: f32,
    thr: f32,
) -> Option<(Vector3<f32>, f32)> {
    let mut sum = nalgebra::Vector3::<f64>::zeros();
    let mut count = 0usize;
    for p in points.iter().filter(|p| (n.dot(p) + off).abs() < thr) {
        sum += p.cast::<f64>();
        count += 1;
    }
    if count < 3 {
        return None;
    }
    let mean = sum / count as f64;
    let mut cov = Matrix3::<f64>::zeros();
    for p in points.iter().filter(|p| (n.dot(p) + off).abs() < thr) {
        let d = p.cast::<f64>() - mean;
        cov += d * d.transpose();
    }
    let eig = cov.symmetric_eigen();
    let (imin, _) = eig
        .eigenvalues
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(b.1))?;
    let mut normal = eig.eigenvectors.column(imin).into_owned();
    if normal.dot(&n.cast::<f64>()) < 0.0 {
        normal = -normal;
    }
    let normal = normal.normalize();
    if !normal.iter().all(|v| v.is_finite()) {
        return None;
    }
    Some((normal.cast::<f32>(), -normal.dot(&mean) as f32))
}

/// Where [`workspace_camera_from_plane`] puts the workspace on the plane.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PlacementConfig {
    /// Height of the plane above the workspace floor (metres), so the surface and the band
    /// below it stay inside the grid. Default 0.02 m.
    pub plane_height_m: f32,
}

impl Default for PlacementConfig {
    fn default() -> Self {
        Self {
            plane_height_m: 0.02,
        }
    }
}

/// Camera pose that puts the workspace box on `plane`: workspace z = the plane normal (towards
/// the camera), the plane at workspace height `plane_height_m`, the box centred (in x and y) on
/// the point where the optical axis meets the plane, workspace x along the camera x axis
/// projected onto the plane.
pub fn workspace_camera_from_plane(
    plane: &Plane,
    intrinsics: &CameraIntrinsics,
    workspace: &Workspace,
    placement: &PlacementConfig,
) -> Result<CameraModel, FusionError> {
    intrinsics.validate()?;
    workspace.validate()?;
    if !placement.plane_height_m.is_finite() {
        return Err(FusionError::InvalidConfig("plane_height_m must be finite"));
    }
    let len = plane.normal.norm();
    if !(len.is_finite() && len > 1e-6 && plane.offset_m.is_finite()) {
        return Err(FusionError::BadPlane("non-finite or zero normal"));
    }
    let mut z_w = plane.normal / len;
    let mut offset = plane.offset_m / len;
    if offset < 0.0 {
        z_w = -z_w;
        offset = -offset;
    }
    // Optical axis (0, 0, s): z_w.z · s + offset = 0.
    if z_w.z > -1e-3 {
        return Err(FusionError::BadPlane(
            "the optical axis does not meet the plane in front of the camera",
        ));
    }
    let centre = Vector3::new(0.0, 0.0, -offset / z_w.z);
    let mut x_w = Vector3::x() - z_w * z_w.x;
    if x_w.norm() < 1e-3 {
        x_w = Vector3::y() - z_w * z_w.y;
    }
    let x_w = x_w.normalize();
    let y_w = z_w.cross(&x_w);
    let ext = workspace.extent();
    let origin =
        centre - x_w * (0.5 * ext.x) - y_w * (0.5 * ext.y) - z_w * placement.plane_height_m;
    let camera_from_workspace = Matrix3::from_columns(&[x_w, y_w, z_w]);
    let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(
        camera_from_workspace.transpose(),
    ));
    let translation = -(rotation * origin);
    let workspace_from_camera = Isometry3::from_parts(Translation3::from(translation), rotation);
    Ok(CameraModel {
        intrinsics: *intrinsics,
        workspace_from_camera,
    })
}
