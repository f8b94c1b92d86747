//! Gripper poses and checks of picks against a scene: the analytic backend as the pipeline
//! configures it for a bin and default selection, gripper poses from axes, and points sampled through the gripper's
//! boxes to test for penetration.
use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use psgrasp_fusion::NormalGrid;
use psgrasp_geometry::{BinModel, GraspConfiguration, GripperModel};
use psgrasp_inference::{AnalyticBackend, AnalyticConfig, BackendConfig};
use psgrasp_perception::CellConfig;
use psgrasp_selection::{select, SelectedGrasp, Selection, SelectionConfig};

/// Gripper pose with baseline `x`, approach `z` (y = z × x) and the TCP at `tcp`.
pub fn gripper_pose(tcp: Point3<f32>, x: Vector3<f32>, z: Vector3<f32>) -> Isometry3<f32> {
    let y = z.cross(&x);
    let r = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[x, y, z]));
    Isometry3::from_parts(
        Translation3::from(tcp.coords),
        UnitQuaternion::from_rotation_matrix(&r),
    )
}

/// A straight-down gripper pose (approach −z) with its baseline along x and the TCP at `tcp`.
pub fn top_down_pose(tcp: Point3<f32>) -> Isometry3<f32> {
    gripper_pose(tcp, Vector3::x(), -Vector3::z())
}

/// The analytic backend with default settings as a default cell with `bin` and `gripper` runs
/// it ([`CellConfig::effective_backend`]: contacts kept `contact_region_inset_m` inside the bin).
pub fn analytic_backend_in_bin(bin: &BinModel, gripper: GripperModel) -> AnalyticBackend {
    let cell = CellConfig {
        bin: *bin,
        gripper,
        ..CellConfig::default()
    };
    let BackendConfig::Analytic(cfg) =
        cell.effective_backend(&BackendConfig::Analytic(AnalyticConfig::default()))
    else {
        unreachable!("an analytic configuration stays analytic")
    };
    AnalyticBackend::new(cfg, gripper).expect("analytic backend")
}

/// [`select`] with the default selection settings on `grid`, for `bin` and `gripper`.
pub fn select_default(
    configs: &[GraspConfiguration],
    grid: &NormalGrid,
    bin: &BinModel,
    gripper: &GripperModel,
) -> Selection {
    select(
        configs,
        &grid.view(),
        bin,
        gripper,
        &SelectionConfig::default(),
    )
    .expect("selection")
}

/// `n`³ points evenly spread through each box of the gripper at `pose` with `opening_m`, from
/// corner to corner (`n` ≥ 2), box by box.
pub fn gripper_points(
    gripper: &GripperModel,
    pose: &Isometry3<f32>,
    opening_m: f32,
    n: usize,
) -> Vec<Point3<f32>> {
    let half = (n - 1) as f32 / 2.0;
    let f = |v: usize| v as f32 / half - 1.0;
    let mut points = Vec::with_capacity(3 * n * n * n);
    for b in gripper.boxes(pose, opening_m) {
        for i in 0..n * n * n {
            let local = Point3::new(
                f(i % n) * b.half_extents.x,
                f((i / n) % n) * b.half_extents.y,
                f(i / (n * n)) * b.half_extents.z,
            );
            points.push(b.parent_from_box * local);
        }
    }
    points
}

/// [`gripper_points`] of `pick`'s gripper at the grasp pose, then at the pre-grasp pose.
pub fn pick_gripper_points(
    gripper: &GripperModel,
    pick: &SelectedGrasp,
    n: usize,
) -> Vec<Point3<f32>> {
    [pick.workspace_from_gripper, pick.pregrasp]
        .iter()
        .flat_map(|pose| gripper_points(gripper, pose, pick.opening_m, n))
        .collect()
}
