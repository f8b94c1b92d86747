//! Payload element types (all `#[repr(C)]`, `f32`/`u32` only, no padding surprises).
use iceoryx2::prelude::ZeroCopySend;
use nalgebra::{Isometry3, Point3, UnitQuaternion, Vector3};
use psgrasp_geometry::{pose_from_xyzw, BaseFrame, GraspConfiguration, N_APPROACHES};

/// One grasp configuration `C = (c, b, {σ_i}, w, q, κ)` (112 bytes).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("psgrasp::GraspRecord/v1")]
pub struct GraspRecord {
    /// Contact point, workspace frame, metres.
    pub contact: [f32; 3],
    /// Unit baseline.
    pub baseline: [f32; 3],
    /// Collision scores of the 18 approaches `a_i = R_γi b⊥`, γ_i evenly over [π/2, 3π/2].
    pub collision_scores: [f32; N_APPROACHES],
    /// Opening width, metres.
    pub width: f32,
    /// Antipodal quality.
    pub quality: f32,
    /// Baseline concentration κ (0 if the backend does not model it).
    pub kappa: f32,
    /// The floor κ0 the backend clamps κ to (0: none; was a reserved zero before it carried the
    /// model card's `kappa0`, so an older sender reads as "no floor").
    pub kappa_floor: f32,
}

impl From<&GraspConfiguration> for GraspRecord {
    fn from(c: &GraspConfiguration) -> Self {
        Self {
            contact: c.contact.coords.into(),
            baseline: c.baseline.into(),
            collision_scores: c.collision_scores,
            width: c.width,
            quality: c.quality,
            kappa: c.kappa,
            kappa_floor: c.kappa_floor,
        }
    }
}

impl From<&GraspRecord> for GraspConfiguration {
    fn from(r: &GraspRecord) -> Self {
        Self {
            contact: Point3::from(r.contact),
            baseline: Vector3::from(r.baseline),
            collision_scores: r.collision_scores,
            width: r.width,
            quality: r.quality,
            kappa: r.kappa,
            kappa_floor: r.kappa_floor,
        }
    }
}

/// One executable pick: gripper pose (TCP), pre-grasp pose and scores in the workspace frame,
/// and the same poses in the robot base frame with the flange pose that puts the TCP there and
/// the camera pose that produced it (200 bytes; protocol v2).
#[repr(C)]
#[derive(
    Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, serde::Serialize, serde::Deserialize,
)]
#[type_name("psgrasp::PickRecord/v2")]
pub struct PickRecord {
    /// TCP position in the workspace frame, metres.
    pub position: [f32; 3],
    /// Gripper orientation quaternion xyzw (gripper x = closing direction, z = approach).
    pub orientation_xyzw: [f32; 4],
    /// Pre-grasp TCP position (same orientation), backed off along −approach.
    pub pregrasp_position: [f32; 3],
    /// Opening width, metres.
    pub width: f32,
    /// Antipodal quality.
    pub quality: f32,
    /// Collision score of the chosen approach.
    pub collision_score: f32,
    /// Index of the grasp configuration in the frame's grasp set.
    pub configuration_index: u32,
    /// Index of the approach (0..18).
    pub approach_index: u32,
    /// Rank in the pick order (0 = best).
    pub rank: u32,
    /// Contact point, workspace frame.
    pub contact: [f32; 3],
    /// 1 if the robot base frame comes from a configured hand-eye calibration (`[robot]
    /// camera_in_base`); 0 if none is configured and the base frame is the workspace frame.
    pub base_calibrated: u32,
    /// TCP position in the robot base frame, metres.
    pub base_position: [f32; 3],
    /// TCP orientation in the robot base frame, quaternion xyzw.
    pub base_orientation_xyzw: [f32; 4],
    /// Pre-grasp TCP position in the robot base frame (same orientation).
    pub base_pregrasp_position: [f32; 3],
    /// Flange position in the robot base frame that puts the TCP at the pick.
    pub flange_position: [f32; 3],
    /// Flange orientation in the robot base frame, quaternion xyzw.
    pub flange_orientation_xyzw: [f32; 4],
    /// Flange position of the pre-grasp pose (same orientation).
    pub flange_pregrasp_position: [f32; 3],
    /// The camera's position in the robot base frame when the frame was taken.
    pub camera_position: [f32; 3],
    /// The camera's orientation in the robot base frame, quaternion xyzw.
    pub camera_orientation_xyzw: [f32; 4],
    /// 1 if the pick comes from selection's fallback tier (`[selection.fallback]`: nothing on the
    /// frame passed the primary quality and collision-score thresholds), else 0.
    pub fallback: u32,
    /// Share of the region the pads close on that lies under the frame's measured surface
    /// (selection's pad fill, 0..1; `[selection.surface_check]`), valid if `pad_fill_measured`
    /// is 1. A low fill is a pick that closes on an edge or on little of its object.
    #[serde(default)]
    pub pad_fill: f32,
    /// 1 if `pad_fill` was measured (the surface check on and the pads over the height map), else
    /// 0 (the two were reserved zeros before, so an older sender reads as "not measured"; in
    /// serialized records saved before them, e.g. a next-pick state file, they default so).
    #[serde(default)]
    pub pad_fill_measured: u32,
}

fn xyzw(q: &UnitQuaternion<f64>) -> [f32; 4] {
    let c = q.coords;
    [c[0] as f32, c[1] as f32, c[2] as f32, c[3] as f32]
}

fn position(p: &Isometry3<f64>) -> [f32; 3] {
    p.translation.vector.cast::<f32>().into()
}

impl PickRecord {
    /// Builds a record from poses in the workspace frame and puts them into the robot base frame
    /// `base` of the frame.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        workspace_from_gripper: &Isometry3<f32>,
        pregrasp: &Isometry3<f32>,
        contact: &Point3<f32>,
        width: f32,
        quality: f32,
        collision_score: f32,
        configuration_index: u32,
        approach_index: u32,
        rank: u32,
        base: &BaseFrame,
    ) -> Self {
        let q = workspace_from_gripper.rotation.coords;
        let grasp = base.pose(workspace_from_gripper);
        let pre = base.pose(pregrasp);
        Self {
            position: workspace_from_gripper.translation.vector.into(),
            orientation_xyzw: [q[0], q[1], q[2], q[3]],
            pregrasp_position: pregrasp.translation.vector.into(),
            width,
            quality,
            collision_score,
            configuration_index,
            approach_index,
            rank,
            contact: contact.coords.into(),
            base_calibrated: base.calibrated as u32,
            base_position: position(&grasp.tcp),
            base_orientation_xyzw: xyzw(&grasp.tcp.rotation),
            base_pregrasp_position: position(&pre.tcp),
            flange_position: position(&grasp.flange),
            flange_orientation_xyzw: xyzw(&grasp.flange.rotation),
            flange_pregrasp_position: position(&pre.flange),
            camera_position: position(&base.camera_in_base),
            camera_orientation_xyzw: xyzw(&base.camera_in_base.rotation),
            fallback: 0,
            pad_fill: 0.0,
            pad_fill_measured: 0,
        }
    }

    /// The pick's pad fill, if it was measured.
    pub fn pad_fill(&self) -> Option<f32> {
        (self.pad_fill_measured != 0).then_some(self.pad_fill)
    }

    /// The record with pad fill `fill` (`None`: not measured).
    pub fn with_pad_fill(self, fill: Option<f32>) -> Self {
        Self {
            pad_fill: fill.unwrap_or(0.0),
            pad_fill_measured: u32::from(fill.is_some()),
            ..self
        }
    }

    /// The TCP pose in the workspace frame.
    pub fn workspace_from_gripper(&self) -> Isometry3<f32> {
        pose_from_xyzw(self.position, self.orientation_xyzw)
    }

    /// The TCP pose in the robot base frame.
    pub fn base_from_gripper(&self) -> Isometry3<f32> {
        pose_from_xyzw(self.base_position, self.base_orientation_xyzw)
    }

    /// The flange pose in the robot base frame.
    pub fn base_from_flange(&self) -> Isometry3<f32> {
        pose_from_xyzw(self.flange_position, self.flange_orientation_xyzw)
    }

    /// The camera pose in the robot base frame.
    pub fn base_from_camera(&self) -> Isometry3<f32> {
        pose_from_xyzw(self.camera_position, self.camera_orientation_xyzw)
    }

    /// The approach direction (gripper z axis) in the workspace frame.
    pub fn approach(&self) -> Vector3<f32> {
        self.workspace_from_gripper().rotation * Vector3::z()
    }
}

/// Periodic statistics of one stage worker (published on `<pipeline>/stats`).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("psgrasp::StageStats/v1")]
pub struct StageStats {
    /// [`crate::Stage`] as `u32`.
    pub stage: u32,
    /// Worker index.
    pub worker: u32,
    /// Process id.
    pub pid: u32,
    /// Frames dropped unprocessed because they were queued for this worker's previous
    /// instance (the frame ledger reported them lost when this one started).
    pub stale: u32,
    /// Messages received (own shard only).
    pub frames_in: u64,
    /// Successful outputs published.
    pub frames_out: u64,
    /// Error records published (bad input, failures, lost frames).
    pub errors: u64,
    /// Deliveries that failed under overload (receiver buffer full with the drop policy).
    pub dropped: u64,
    /// Frame id of the last message handled.
    pub last_frame_id: u64,
    /// Total processing time in nanoseconds.
    pub busy_ns: u64,
    /// When these statistics were taken.
    pub stamp_ns: u64,
}

/// A cell controller's request to grasp-selection.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("psgrasp::NextPickRequest/v1")]
pub struct NextPickRequest {
    /// A [`NextPickMode`] as `u32` (0 current, 1 previous failed → next, 2 previous succeeded →
    /// a newer frame's best); read it with
    /// [`NextPickRequest::mode`].
    pub mode: u32,
    /// Reserved, zero.
    pub reserved: u32,
}

/// What a [`NextPickRequest`] asks for (its `mode` on the wire).
#[repr(u32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NextPickMode {
    /// The pick handed out now (the same one again until it is reported failed or a new frame
    /// arrives).
    Current = 0,
    /// The previous pick failed: move on to the next one.
    AfterFailure = 1,
    /// The previous pick succeeded: the scene has changed, so no pick of a frame taken before
    /// now is handed out any more; the answer waits for a newer frame.
    AfterSuccess = 2,
}

impl NextPickMode {
    /// The mode of a wire value; `None` for a value no version of the protocol defines.
    pub fn from_u32(v: u32) -> Option<Self> {
        match v {
            0 => Some(Self::Current),
            1 => Some(Self::AfterFailure),
            2 => Some(Self::AfterSuccess),
            _ => None,
        }
    }
}

impl NextPickRequest {
    /// A request for `mode`.
    pub fn new(mode: NextPickMode) -> Self {
        Self {
            mode: mode as u32,
            reserved: 0,
        }
    }

    /// The requested mode; `None` for an undefined wire value.
    pub fn mode(&self) -> Option<NextPickMode> {
        NextPickMode::from_u32(self.mode)
    }
}

/// The answer's `status` on the wire.
#[repr(u32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NextPickStatus {
    /// A pick is attached.
    Pick = 0,
    /// No frame has been processed yet.
    NoFrameYet = 1,
    /// Every pick of the latest frame has been handed out.
    Exhausted = 2,
    /// The request's mode is not one this server knows.
    BadRequest = 3,
    /// A pick was reported successful; no frame taken after that has been processed yet.
    AwaitingNewFrame = 4,
}

impl NextPickStatus {
    /// The status of a wire value; `None` for a value no version of the protocol defines.
    pub fn from_u32(v: u32) -> Option<Self> {
        match v {
            0 => Some(Self::Pick),
            1 => Some(Self::NoFrameYet),
            2 => Some(Self::Exhausted),
            3 => Some(Self::BadRequest),
            4 => Some(Self::AwaitingNewFrame),
            _ => None,
        }
    }
}

/// The answer to a [`NextPickRequest`].
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("psgrasp::NextPickResponse/v2")]
pub struct NextPickResponse {
    /// A [`NextPickStatus`] as `u32` (0 pick, 1 no frame yet, 2 exhausted, 3 bad request); read
    /// it with [`NextPickResponse::status`].
    pub status: u32,
    /// Reserved, zero.
    pub reserved: u32,
    /// Frame the pick belongs to.
    pub frame_id: u64,
    /// The pick (valid when `status == 0`).
    pub pick: PickRecord,
}

impl NextPickResponse {
    /// An answer without a pick.
    pub fn without_pick(status: NextPickStatus, frame_id: u64) -> Self {
        Self {
            status: status as u32,
            frame_id,
            ..Default::default()
        }
    }

    /// The answer carrying `pick` of `frame_id`.
    pub fn with_pick(frame_id: u64, pick: PickRecord) -> Self {
        Self {
            status: NextPickStatus::Pick as u32,
            reserved: 0,
            frame_id,
            pick,
        }
    }

    /// The status; `None` for an undefined wire value.
    pub fn status(&self) -> Option<NextPickStatus> {
        NextPickStatus::from_u32(self.status)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Translation3;
    use psgrasp_geometry::RobotConfig;
    use std::mem::size_of;

    #[test]
    fn record_sizes() {
        assert_eq!(size_of::<GraspRecord>(), 112);
        assert_eq!(size_of::<PickRecord>(), 200);
        assert_eq!(size_of::<StageStats>(), 72);
        assert_eq!(size_of::<NextPickResponse>(), 216);
    }

    #[test]
    fn next_pick_wire_values_round_trip_and_unknown_ones_are_refused() {
        for mode in [
            NextPickMode::Current,
            NextPickMode::AfterFailure,
            NextPickMode::AfterSuccess,
        ] {
            assert_eq!(NextPickRequest::new(mode).mode(), Some(mode));
        }
        assert_eq!(NextPickRequest::new(NextPickMode::AfterFailure).mode, 1);
        let bogus = NextPickRequest {
            mode: 7,
            reserved: 0,
        };
        assert_eq!(bogus.mode(), None);
        for status in [
            NextPickStatus::Pick,
            NextPickStatus::NoFrameYet,
            NextPickStatus::Exhausted,
            NextPickStatus::BadRequest,
            NextPickStatus::AwaitingNewFrame,
        ] {
            assert_eq!(NextPickStatus::from_u32(status as u32), Some(status));
        }
        assert_eq!(
            NextPickResponse::without_pick(NextPickStatus::Exhausted, 9).status,
            2
        );
        assert_eq!(NextPickStatus::from_u32(5), None);
    }

    #[test]
    fn grasp_record_round_trip() {
        let mut scores = [0.0; N_APPROACHES];
        scores[3] = 1.0;
        let c = GraspConfiguration {
            contact: Point3::new(0.1, 0.2, 0.3),
            baseline: Vector3::new(0.0, 1.0, 0.0),
            collision_scores: scores,
            width: 0.05,
            quality: 0.8,
            kappa: 40.0,
            kappa_floor: 25.0,
        };
        let r = GraspRecord::from(&c);
        assert_eq!(GraspConfiguration::from(&r), c);
    }

    #[test]
    fn pick_record_round_trip() {
        let pose = Isometry3::new(Vector3::new(0.1, 0.2, 0.3), Vector3::new(0.4, -0.2, 1.0));
        let pre = Isometry3::from_parts(Translation3::new(0.1, 0.2, 0.4), pose.rotation);
        let r = PickRecord::new(
            &pose,
            &pre,
            &Point3::new(0.1, 0.2, 0.29),
            0.03,
            0.9,
            1.0,
            4,
            9,
            0,
            &RobotConfig::default()
                .resolve(0.01)
                .unwrap()
                .base_frame(&Isometry3::identity()),
        );
        let back = r.workspace_from_gripper();
        assert!((back.to_homogeneous() - pose.to_homogeneous()).norm() < 1e-5);
        assert!((r.approach() - pose.rotation * Vector3::z()).norm() < 1e-6);
        // Uncalibrated: base frame = workspace frame; the camera pose is the workspace one.
        assert_eq!(r.base_calibrated, 0);
        let base = r.base_from_gripper();
        assert!((base.to_homogeneous() - pose.to_homogeneous()).norm() < 1e-5);
        let flange = r.base_from_flange();
        let tcp_from_flange = flange.inverse() * base;
        assert!((tcp_from_flange.translation.vector.norm() - (0.1034 - 0.01)).abs() < 1e-5);
    }
}
