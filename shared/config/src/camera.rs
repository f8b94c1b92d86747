//! `[camera]`: where depth frames come from (synthetic, replay, RealSense) and the camera's pose.
use nalgebra::Isometry3;
use psgrasp_geometry::CameraIntrinsics;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// Where depth frames come from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CameraSection {
    /// `synthetic` (built-in procedural bin scene), `replay` (files) or `realsense` (an Intel
    /// RealSense camera).
    pub source: SourceKind,
    /// Frames per second; 0 = as fast as the pipeline accepts.
    pub rate_hz: f64,
    /// Frames to publish before stopping; 0 = run until stopped.
    pub frames: u64,
    /// Camera id written into every header.
    pub source_id: u32,
    /// Intrinsics (synthetic source; replay reads its own intrinsics file unless absent, and
    /// the realsense source the device's).
    #[serde(deserialize_with = "psgrasp_geometry::camera::deserialize_intrinsics_strict")]
    pub intrinsics: CameraIntrinsics,
    /// Camera pose in the workspace frame; `None` = top-down above the bin at `height_above_rim_m`
    /// (synthetic) or fitted to the dominant plane (replay, realsense).
    pub pose: Option<PoseConfig>,
    /// Camera height above the bin rim for the default top-down pose.
    pub height_above_rim_m: f32,
    /// Start-up barrier: how long each stage waits for its upstream publishers (attaching to
    /// them) and the camera for the whole chain before publishing the first frame; after it,
    /// they start anyway with a warning.
    pub wait_for_subscribers_ms: u64,
    /// Synthetic source settings.
    pub synthetic: SyntheticSource,
    /// Replay source settings.
    pub replay: ReplaySource,
    /// RealSense source settings.
    pub realsense: RealSenseSource,
}

impl Default for CameraSection {
    fn default() -> Self {
        Self {
            source: SourceKind::Synthetic,
            rate_hz: 2.0,
            frames: 0,
            source_id: 0,
            intrinsics: CameraIntrinsics::default_640x480(),
            pose: None,
            height_above_rim_m: 0.6,
            wait_for_subscribers_ms: 10_000,
            synthetic: SyntheticSource::default(),
            replay: ReplaySource::default(),
            realsense: RealSenseSource::default(),
        }
    }
}

/// Depth source kind.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SourceKind {
    /// Built-in procedural bin scene rendered by ray casting.
    Synthetic,
    /// 16-bit PNG or `.npy` depth files.
    Replay,
    /// An Intel RealSense depth camera through librealsense2, loaded at run time.
    Realsense,
}

/// Settings of the synthetic source.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SyntheticSource {
    /// Scene seed; frame `k` uses scene `seed + k / frames_per_scene`.
    pub seed: u64,
    /// Objects per scene.
    pub objects: usize,
    /// Frames rendered from each scene before a new one is generated.
    pub frames_per_scene: u64,
    /// Add the simulated sensor noise.
    pub noise: bool,
}

impl Default for SyntheticSource {
    fn default() -> Self {
        Self {
            seed: 7,
            objects: 8,
            frames_per_scene: 1,
            noise: false,
        }
    }
}

/// Settings of the replay source.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(default, deny_unknown_fields)]
pub struct ReplaySource {
    /// A depth file or a folder of them (sorted by name).
    pub path: PathBuf,
    /// Intrinsics JSON/TOML (`width, height, fx, fy, cx, cy[, depth_unit_m]`); empty = use `camera.intrinsics`.
    pub intrinsics_file: PathBuf,
    /// Metres per depth count for 16-bit files (overridden by `depth_unit_m` in the intrinsics file).
    pub depth_unit_m: Option<f32>,
    /// Start again at the first file after the last.
    pub looping: bool,
}

/// Largest RealSense depth image side, pixels.
pub const REALSENSE_MAX_SIDE: u32 = 4096;
/// Fastest RealSense depth stream, frames per second.
pub const REALSENSE_MAX_FPS: u32 = 300;
/// Longest wait for a RealSense frame, milliseconds.
pub const REALSENSE_MAX_TIMEOUT_MS: u32 = 60_000;

/// Settings of the RealSense source: the device and its Z16 depth stream. Intrinsics and depth
/// scale come from the device; the pose from `camera.pose` or a plane fit.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RealSenseSource {
    /// Serial number of the camera to open; `None` = the first one found.
    pub serial: Option<String>,
    /// Depth stream width, pixels (a mode the camera offers, e.g. 640 or 848).
    pub width: u32,
    /// Depth stream height, pixels.
    pub height: u32,
    /// Depth stream rate, frames per second (the camera's; `camera.rate_hz` paces the pipeline).
    pub fps: u32,
    /// librealsense2 to load (a `librealsense2.so` or the `pyrealsense2` wheel's module,
    /// relative to the config file); `None` = `$PSGRASP_REALSENSE_LIB`, a system
    /// `librealsense2.so`, then the project venv's `pyrealsense2`.
    pub library: Option<PathBuf>,
    /// Longest wait for a frame before it counts as a failed read, milliseconds.
    pub timeout_ms: u32,
}

impl Default for RealSenseSource {
    fn default() -> Self {
        Self {
            serial: None,
            width: 640,
            height: 480,
            fps: 30,
            library: None,
            timeout_ms: 5000,
        }
    }
}

/// A rigid pose: translation in metres and a unit quaternion (x, y, z, w).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PoseConfig {
    /// Translation (m).
    pub translation: [f32; 3],
    /// Rotation quaternion x, y, z, w.
    pub rotation_xyzw: [f32; 4],
}

impl PoseConfig {
    /// As an isometry (the quaternion is normalised).
    pub fn isometry(&self) -> Isometry3<f32> {
        psgrasp_geometry::pose_from_xyzw(self.translation, self.rotation_xyzw)
    }
}
