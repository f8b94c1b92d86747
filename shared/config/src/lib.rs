//! Pipeline configuration (`config/default.toml`): one TOML file describes the whole pipeline —
//! stages and their worker counts, queues, camera source, workspace, bin, gripper and the
//! settings of fusion, inference and selection. It is validated completely at load time, so a
//! malformed file fails before any process starts, with the file and the offending key named.
#![warn(missing_docs)]

use nalgebra::Point3;
use psgrasp_geometry::CameraModel;
use psgrasp_ipc::ChannelConfig;
pub use psgrasp_perception::CellConfig;
use psgrasp_perception::NoUnknownKeys;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

mod camera;
pub use camera::{
    CameraSection, PoseConfig, RealSenseSource, ReplaySource, SourceKind, SyntheticSource,
    REALSENSE_MAX_FPS, REALSENSE_MAX_SIDE, REALSENSE_MAX_TIMEOUT_MS,
};

/// Errors of loading or validating a configuration. The message names the cause itself, which
/// is therefore not also its [`source`](std::error::Error::source) (an alternate-format chain,
/// `{:#}`, would print it twice).
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The file could not be read.
    #[error("cannot read config {path}: {error}")]
    Read {
        /// File path.
        path: PathBuf,
        /// I/O error.
        error: std::io::Error,
    },
    /// The TOML is malformed or has unknown/mistyped keys.
    #[error("malformed config {path}: {error}")]
    Parse {
        /// File path (or `<string>`).
        path: PathBuf,
        /// TOML error with line and column.
        error: toml::de::Error,
    },

    /// The values are inconsistent or out of range.
    #[error("invalid config {path}: {field}: {reason}")]
    Invalid {
        /// File path (or `<string>`).
        path: PathBuf,
        /// The offending key.
        field: &'static str,
        /// What is wrong.
        reason: String,
    },
}

/// The whole pipeline configuration: the process graph, the depth source and the cell
/// ([`CellConfig`]: workspace, bin, gripper, fusion, depth scale, inference, selection and how
/// the perception steps are joined), whose tables sit at the top level of the file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(default)]
pub struct PipelineConfig {
    /// Process graph and queue settings.
    pub pipeline: PipelineSection,
    /// Depth source.
    pub camera: CameraSection,
    /// The HTTP/JSON endpoint for cell controllers (off by default).
    pub http: HttpSection,
    /// The cell: what every perception step needs (its tables at the top level).
    #[serde(flatten)]
    pub cell: CellConfig,
    /// Refuses top-level keys that no table takes.
    #[serde(flatten, skip_serializing)]
    pub unknown_keys: NoUnknownKeys,
}

/// `[http]`: the HTTP/JSON endpoint `psgrasp up` serves for cell controllers.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct HttpSection {
    /// Serve it (off by default: nothing listens unless asked).
    pub enabled: bool,
    /// Address to listen on; the default serves this machine only.
    pub bind: String,
    /// TCP port (0: one the system picks, printed at start).
    pub port: u16,
    /// How long a pick request waits for a pick when it does not say (`wait_ms`).
    pub default_wait_ms: u64,
    /// Longest wait a pick request may ask for.
    pub max_wait_ms: u64,
}

impl Default for HttpSection {
    fn default() -> Self {
        Self {
            enabled: false,
            bind: "127.0.0.1".into(),
            port: 8471,
            default_wait_ms: 0,
            max_wait_ms: 60_000,
        }
    }
}

/// Longest duration setting, milliseconds (one day): in nanoseconds it still fits a `u64`.
pub const MAX_DURATION_MS: u64 = 86_400_000;
/// Most frames in flight (`pipeline.max_frames_in_flight`); outcome queues hold this many.
pub const MAX_FRAMES_IN_FLIGHT: usize = psgrasp_ipc::OUTCOME_BUFFER / 2;
/// Slowest camera rate other than 0 (one frame per 1000 s).
pub const MIN_RATE_HZ: f64 = 1e-3;
/// Fastest camera rate.
pub const MAX_RATE_HZ: f64 = 10_000.0;

/// Process graph and queues.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PipelineSection {
    /// Name of this pipeline instance; all shared-memory services live under `psgrasp/<name>/`,
    /// so two pipelines (or parallel tests) never interfere.
    pub name: String,
    /// Queue settings of every channel.
    pub channel: ChannelConfig,
    /// Worker processes per stage (frames are sharded by `frame_id % workers`).
    pub workers: WorkerCounts,
    /// A frame with no result after this long is reported as `Lost` (frames held by a stage
    /// that restarts are reported at once, when its new instance starts).
    pub loss_timeout_ms: u64,
    /// Frames admitted by camera-ingest and not yet ended (picks or error record). At the
    /// limit, a paced camera refuses its next frame with an `Overload` record and an unpaced
    /// one (`rate_hz = 0`) waits. At most `channel.subscriber_buffer`, so no stage queue can
    /// overflow.
    pub max_frames_in_flight: usize,
    /// How often stages publish statistics.
    pub stats_interval_ms: u64,
    /// Restart a stage that died (launcher).
    pub restart_on_failure: bool,
    /// Seed for every sampling step downstream of the camera (same grid + seed → same grasps).
    pub seed: u64,
    /// Give up on a stage that died this many times within `restart_window_s`.
    pub max_restarts: u32,
    /// Window for `max_restarts`.
    pub restart_window_s: u64,
    /// Wait before the first restart of a stage that died, milliseconds; doubled for each
    /// further restart within `restart_window_s`.
    pub restart_backoff_ms: u64,
    /// Longest wait before a restart, milliseconds.
    pub restart_backoff_max_ms: u64,
}

impl Default for PipelineSection {
    fn default() -> Self {
        Self {
            name: "default".into(),
            channel: ChannelConfig::default(),
            workers: WorkerCounts::default(),
            loss_timeout_ms: 10_000,
            max_frames_in_flight: 4,
            stats_interval_ms: 1000,
            restart_on_failure: true,
            seed: 0,
            max_restarts: 5,
            restart_window_s: 60,
            restart_backoff_ms: 100,
            restart_backoff_max_ms: 5_000,
        }
    }
}

/// Worker processes per stage.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct WorkerCounts {
    /// grid-fusion workers.
    pub fusion: u32,
    /// inference workers.
    pub inference: u32,
    /// grasp-selection workers.
    pub selection: u32,
}

impl Default for WorkerCounts {
    fn default() -> Self {
        Self {
            fusion: 1,
            inference: 1,
            selection: 1,
        }
    }
}

impl PipelineConfig {
    /// Loads and validates a TOML file.
    /// A learned or VGN backend's relative `model_dir` and `ort_library` are taken relative to the
    /// file's directory (so `config/default.toml` names `../models/default`), which makes the
    /// file work from any working directory; they are stored as absolute paths.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|error| ConfigError::Read {
            path: path.into(),
            error,
        })?;
        let mut cfg = Self::parse(&text, path)?;
        // Absolute, so a configuration written back out (stress, demo) still names the same files.
        let base = std::path::absolute(path)
            .ok()
            .and_then(|p| p.parent().map(Path::to_path_buf))
            .unwrap_or_default();
        cfg.resolve_paths(&base);
        Ok(cfg)
    }

    /// Joins the model backend's relative paths onto `base` (see [`PipelineConfig::load`]).
    fn resolve_paths(&mut self, base: &Path) {
        self.cell.inference.resolve_paths(base);
        if let Some(lib) = &mut self.camera.realsense.library {
            if lib.is_relative() {
                *lib = base.join(&*lib);
            }
        }
    }

    /// Parses and validates TOML text (`origin` names it in errors); unknown keys are refused
    /// at every level.
    pub fn parse(text: &str, origin: &Path) -> Result<Self, ConfigError> {
        let cfg: Self = toml::from_str(text).map_err(|error| ConfigError::Parse {
            path: origin.into(),
            error,
        })?;
        cfg.validate(origin)?;
        Ok(cfg)
    }

    /// Serialises back to TOML.
    pub fn to_toml(&self) -> String {
        toml::to_string_pretty(self).unwrap_or_default()
    }

    /// Checks ranges and cross-field consistency.
    pub fn validate(&self, origin: &Path) -> Result<(), ConfigError> {
        let bad = |field: &'static str, reason: String| ConfigError::Invalid {
            path: origin.into(),
            field,
            reason,
        };
        let p = &self.pipeline;
        if p.name.is_empty()
            || !p
                .name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
        {
            return Err(bad(
                "pipeline.name",
                format!("{:?} must be non-empty [A-Za-z0-9_-]", p.name),
            ));
        }
        if p.name.len() > 48 {
            return Err(bad("pipeline.name", "longer than 48 characters".into()));
        }
        let w = p.workers;
        for (field, n) in [
            ("pipeline.workers.fusion", w.fusion),
            ("pipeline.workers.inference", w.inference),
            ("pipeline.workers.selection", w.selection),
        ] {
            if n == 0 || n as usize > p.channel.max_publishers {
                return Err(bad(
                    field,
                    format!(
                        "{n} must be in 1..={} (channel.max_publishers)",
                        p.channel.max_publishers
                    ),
                ));
            }
        }
        if p.channel.subscriber_buffer == 0 || p.channel.subscriber_buffer > 1024 {
            return Err(bad(
                "pipeline.channel.subscriber_buffer",
                format!("{} must be in 1..=1024", p.channel.subscriber_buffer),
            ));
        }
        if !(1..=p.channel.subscriber_buffer.min(MAX_FRAMES_IN_FLIGHT))
            .contains(&p.max_frames_in_flight)
        {
            return Err(bad(
                "pipeline.max_frames_in_flight",
                format!(
                    "{} must be in 1..={} (channel.subscriber_buffer, at most \
                     {MAX_FRAMES_IN_FLIGHT}): deeper than a queue, frames would be dropped",
                    p.max_frames_in_flight,
                    p.channel.subscriber_buffer.min(MAX_FRAMES_IN_FLIGHT)
                ),
            ));
        }
        let max_subs_needed = (w.fusion.max(w.inference).max(w.selection) + 2) as usize;
        if p.channel.max_subscribers < max_subs_needed {
            return Err(bad(
                "pipeline.channel.max_subscribers",
                format!(
                    "{} < {max_subs_needed} (workers + monitors)",
                    p.channel.max_subscribers
                ),
            ));
        }
        // Durations are used as nanoseconds (u64) and `Duration`s: bounded so none can overflow.
        for (field, ms, min) in [
            ("pipeline.loss_timeout_ms", p.loss_timeout_ms, 100),
            ("pipeline.stats_interval_ms", p.stats_interval_ms, 1),
            (
                "pipeline.channel.block_timeout_ms",
                p.channel.block_timeout_ms,
                0,
            ),
            (
                "camera.wait_for_subscribers_ms",
                self.camera.wait_for_subscribers_ms,
                0,
            ),
        ] {
            if !(min..=MAX_DURATION_MS).contains(&ms) {
                return Err(bad(
                    field,
                    format!("{ms} must be in {min}..={MAX_DURATION_MS} ms"),
                ));
            }
        }
        let h = &self.http;
        if h.bind.parse::<std::net::IpAddr>().is_err() {
            return Err(bad(
                "http.bind",
                format!(
                    "{:?} is not an IP address (e.g. 127.0.0.1, 0.0.0.0, ::1)",
                    h.bind
                ),
            ));
        }
        if !(1..=MAX_DURATION_MS).contains(&h.max_wait_ms) || h.default_wait_ms > h.max_wait_ms {
            return Err(bad(
                "http.default_wait_ms",
                format!(
                    "need 0 ≤ default_wait_ms ({}) ≤ max_wait_ms ({}) ≤ {MAX_DURATION_MS}, max_wait_ms ≥ 1",
                    h.default_wait_ms, h.max_wait_ms
                ),
            ));
        }
        if !(1..=MAX_DURATION_MS / 1000).contains(&p.restart_window_s) {
            return Err(bad(
                "pipeline.restart_window_s",
                format!(
                    "{} must be in 1..={} s",
                    p.restart_window_s,
                    MAX_DURATION_MS / 1000
                ),
            ));
        }
        let c = &self.camera;
        if !(c.rate_hz == 0.0 || (MIN_RATE_HZ..=MAX_RATE_HZ).contains(&c.rate_hz)) {
            return Err(bad(
                "camera.rate_hz",
                format!(
                    "{} must be 0 (as fast as accepted) or in {MIN_RATE_HZ}..={MAX_RATE_HZ} Hz",
                    c.rate_hz
                ),
            ));
        }
        c.intrinsics
            .validate()
            .map_err(|e| bad("camera.intrinsics", e.to_string()))?;
        if !(c.height_above_rim_m.is_finite() && c.height_above_rim_m > 0.0) {
            return Err(bad(
                "camera.height_above_rim_m",
                format!("{} must be > 0 m", c.height_above_rim_m),
            ));
        }
        if let Some(pose) = &c.pose {
            let finite = pose
                .translation
                .iter()
                .chain(pose.rotation_xyzw.iter())
                .all(|v| v.is_finite());
            let norm = pose.rotation_xyzw.iter().map(|v| v * v).sum::<f32>().sqrt();
            if !finite || (norm - 1.0).abs() > 1e-2 {
                return Err(bad(
                    "camera.pose",
                    "translation must be finite and rotation_xyzw a unit quaternion".into(),
                ));
            }
        }
        if c.source == SourceKind::Replay && c.replay.path.as_os_str().is_empty() {
            return Err(bad(
                "camera.replay.path",
                "replay source needs a path".into(),
            ));
        }
        if let Some(u) = c.replay.depth_unit_m {
            if !(u.is_finite() && u > 0.0) {
                return Err(bad(
                    "camera.replay.depth_unit_m",
                    format!("{u} must be > 0"),
                ));
            }
        }
        let rs = &c.realsense;
        for (field, v, max) in [
            ("camera.realsense.width", rs.width, REALSENSE_MAX_SIDE),
            ("camera.realsense.height", rs.height, REALSENSE_MAX_SIDE),
            ("camera.realsense.fps", rs.fps, REALSENSE_MAX_FPS),
            (
                "camera.realsense.timeout_ms",
                rs.timeout_ms,
                REALSENSE_MAX_TIMEOUT_MS,
            ),
        ] {
            if !(1..=max).contains(&v) {
                return Err(bad(field, format!("{v} must be in 1..={max}")));
            }
        }
        if let Some(serial) = &rs.serial {
            if serial.is_empty() || serial.contains('\0') {
                return Err(bad(
                    "camera.realsense.serial",
                    format!("{serial:?} must be a non-empty serial number (or left out)"),
                ));
            }
        }
        if rs
            .library
            .as_ref()
            .is_some_and(|p| p.as_os_str().is_empty())
        {
            return Err(bad(
                "camera.realsense.library",
                "must name a file (or be left out)".into(),
            ));
        }
        if c.source == SourceKind::Synthetic
            && (c.synthetic.objects == 0 || c.synthetic.objects > 64)
        {
            return Err(bad(
                "camera.synthetic.objects",
                format!("{} must be in 1..=64", c.synthetic.objects),
            ));
        }
        if c.synthetic.frames_per_scene == 0 {
            return Err(bad(
                "camera.synthetic.frames_per_scene",
                "must be ≥ 1".into(),
            ));
        }
        self.cell.validate().map_err(|e| bad(e.field, e.reason))?;
        Ok(())
    }

    /// The camera model for the synthetic source or an explicit pose: the configured pose, or
    /// top-down above the bin centre at `height_above_rim_m`.
    pub fn camera_model(&self) -> CameraModel {
        match &self.camera.pose {
            Some(p) => CameraModel {
                intrinsics: self.camera.intrinsics,
                workspace_from_camera: p.isometry(),
            },
            None => {
                let bin = &self.cell.bin;
                let c = bin.floor_center;
                CameraModel::top_down(
                    self.camera.intrinsics,
                    Point3::new(c.x, c.y, bin.rim_z() + self.camera.height_above_rim_m),
                )
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;
    use psgrasp_inference::BackendConfig;

    fn parse(s: &str) -> Result<PipelineConfig, ConfigError> {
        PipelineConfig::parse(s, Path::new("<test>"))
    }

    #[test]
    fn shipped_default_config_is_valid() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/default.toml");
        let cfg = PipelineConfig::load(&path).expect("config/default.toml must load");
        assert_eq!(cfg.cell.workspace, psgrasp_geometry::Workspace::default());
    }

    #[test]
    fn learned_model_paths_are_relative_to_the_config_file() {
        let dir = std::env::temp_dir().join(format!("psgrasp-config-{}", std::process::id()));
        std::fs::create_dir_all(dir.join("config")).unwrap();
        let file = dir.join("config/x.toml");
        std::fs::write(
            &file,
            "[inference]\nkind = \"learned\"\nmodel_dir = \"../models/m\"\nort_library = \"/abs/libonnxruntime.so\"\n",
        )
        .unwrap();
        let cfg = PipelineConfig::load(&file).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        let BackendConfig::Learned(l) = cfg.cell.inference else {
            panic!("expected a learned backend");
        };
        assert_eq!(l.model_dir, dir.join("config/../models/m"));
        assert_eq!(l.ort_library, Some(PathBuf::from("/abs/libonnxruntime.so")));
    }

    #[test]
    fn the_realsense_library_path_is_relative_to_the_config_file() {
        let dir = std::env::temp_dir().join(format!("psgrasp-config-rs-{}", std::process::id()));
        std::fs::create_dir_all(dir.join("config")).unwrap();
        let file = dir.join("config/x.toml");
        std::fs::write(
            &file,
            "[camera.realsense]\nlibrary = \"../lib/librealsense2.so\"\n",
        )
        .unwrap();
        let cfg = PipelineConfig::load(&file).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        assert_eq!(
            cfg.camera.realsense.library,
            Some(dir.join("config/../lib/librealsense2.so"))
        );
        assert_eq!(
            parse("[camera.realsense]\nlibrary = \"/abs/librealsense2.so\"")
                .unwrap()
                .camera
                .realsense
                .library,
            Some(PathBuf::from("/abs/librealsense2.so"))
        );
    }

    #[test]
    fn the_native_runtime_is_the_shipped_default_and_runs_the_learned_backend_only() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/default.toml");
        let cfg = PipelineConfig::load(&path).unwrap();
        let BackendConfig::Learned(l) = &cfg.cell.inference else {
            panic!("the shipped default is the learned backend");
        };
        assert_eq!(l.runtime, psgrasp_inference::RuntimeKind::Native);
        let cfg = parse("[inference]\nkind = \"learned\"\nruntime = \"native\"\n").unwrap();
        let BackendConfig::Learned(l) = &cfg.cell.inference else {
            panic!("expected a learned backend");
        };
        assert_eq!(l.runtime, psgrasp_inference::RuntimeKind::Native);
        let err = parse("[inference]\nkind = \"vgn\"\nruntime = \"native\"\n")
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("runtime") && err.contains("learned backend only"),
            "{err}"
        );
        let err = parse("[inference]\nkind = \"learned\"\nruntime = \"nativ\"\n")
            .unwrap_err()
            .to_string();
        assert!(err.contains("native"), "{err}");
        // The approximate mode is the native runtime's, and bounded.
        let band = "[inference]\nkind = \"learned\"\nnative_band_voxels = 8\n";
        let err = parse(&format!("{band}runtime = \"tract\"\n"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("native_band_voxels"), "{err}");
        parse(&format!("{band}runtime = \"native\"\n")).unwrap();
        let err = parse(&format!("{band}runtime = \"native\"\n").replace("= 8", "= 65"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("native_band_voxels"), "{err}");
    }

    #[test]
    fn vgn_model_paths_are_relative_to_the_config_file() {
        let dir = std::env::temp_dir().join(format!("psgrasp-config-vgn-{}", std::process::id()));
        std::fs::create_dir_all(dir.join("config")).unwrap();
        let file = dir.join("config/x.toml");
        std::fs::write(
            &file,
            "[inference]\nkind = \"vgn\"\nmodel_dir = \"../models/vgn\"\nort_library = \"lib/libonnxruntime.so\"\nquality_threshold = 0.8\n",
        )
        .unwrap();
        let cfg = PipelineConfig::load(&file).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        let BackendConfig::Vgn(v) = cfg.cell.inference else {
            panic!("expected a vgn backend");
        };
        assert_eq!(v.model_dir, dir.join("config/../models/vgn"));
        assert_eq!(
            v.ort_library,
            Some(dir.join("config/lib/libonnxruntime.so"))
        );
        assert_eq!(v.quality_threshold, 0.8);
    }

    #[test]
    fn empty_file_gives_defaults_and_round_trips() {
        let cfg = parse("").unwrap();
        assert_eq!(cfg, PipelineConfig::default());
        assert_eq!(parse(&cfg.to_toml()).unwrap(), cfg);
    }

    #[test]
    fn malformed_and_invalid_files_are_rejected_with_the_key() {
        let e = parse("[pipeline\nname = 1").unwrap_err();
        assert!(matches!(e, ConfigError::Parse { .. }), "{e}");
        let e = parse("[pipeline]\nnmae = \"x\"").unwrap_err();
        assert!(e.to_string().contains("nmae"), "{e}");
        let e = parse("[pipeline.workers]\ninference = 0").unwrap_err();
        assert!(e.to_string().contains("pipeline.workers.inference"), "{e}");
        let e = parse("[camera.intrinsics]\nwidth = 640\nheight = 480\nfx = -1.0\nfy = 500.0\ncx = 320.0\ncy = 240.0").unwrap_err();
        assert!(e.to_string().contains("camera.intrinsics"), "{e}");
        let e = parse("[workspace]\ndims = [64, 64, 0]\nvoxel_size_m = 0.009").unwrap_err();
        assert!(e.to_string().contains("workspace"), "{e}");
        let e = parse("[pipeline]\nname = \"a/b\"").unwrap_err();
        assert!(e.to_string().contains("pipeline.name"), "{e}");
        let e = parse("[camera]\nsource = \"replay\"").unwrap_err();
        assert!(e.to_string().contains("camera.replay.path"), "{e}");
        let e = parse("[camera.realsense]\nfps = 0").unwrap_err();
        assert_eq!(
            e.to_string(),
            "invalid config <test>: camera.realsense.fps: 0 must be in 1..=300"
        );
        let e = parse("[camera.realsense]\nwidth = 100000").unwrap_err();
        assert!(e.to_string().contains("camera.realsense.width"), "{e}");
        let e = parse("[camera.realsense]\nserial = \"\"").unwrap_err();
        assert!(e.to_string().contains("camera.realsense.serial"), "{e}");
        let e = parse("[camera.realsense]\nwdth = 640").unwrap_err();
        assert!(e.to_string().contains("wdth"), "{e}");
        let rs = parse(
            "[camera]\nsource = \"realsense\"\n[camera.realsense]\nserial = \"123\"\nwidth = 848\n",
        )
        .unwrap()
        .camera;
        assert_eq!(rs.source, SourceKind::Realsense);
        assert_eq!(
            (
                rs.realsense.serial.as_deref(),
                rs.realsense.width,
                rs.realsense.height
            ),
            (Some("123"), 848, 480)
        );
        let e = parse("[depth_scale]\nenabled = true\nmax_deviation = 0.9").unwrap_err();
        assert!(e.to_string().contains("depth_scale"), "{e}");
        assert!(
            parse("[depth_scale]\nenabled = true")
                .unwrap()
                .cell
                .depth_scale
                .enabled
        );
        // Rates and durations that would overflow or panic in a stage are refused by key.
        let e = parse("[camera]\nrate_hz = 1e-300").unwrap_err();
        assert!(e.to_string().contains("camera.rate_hz"), "{e}");
        let e = parse("[camera]\nrate_hz = nan").unwrap_err();
        assert!(e.to_string().contains("camera.rate_hz"), "{e}");
        let e = parse("[camera]\nheight_above_rim_m = nan").unwrap_err();
        assert!(e.to_string().contains("camera.height_above_rim_m"), "{e}");
        assert_eq!(parse("[camera]\nrate_hz = 0").unwrap().camera.rate_hz, 0.0);
        let e = parse("[pipeline]\nloss_timeout_ms = 18446744073710").unwrap_err();
        assert!(e.to_string().contains("pipeline.loss_timeout_ms"), "{e}");
        let e = parse("[pipeline.channel]\nblock_timeout_ms = 18446744073710").unwrap_err();
        assert!(e.to_string().contains("block_timeout_ms"), "{e}");
        let e = parse("[pipeline]\nrestart_window_s = 0").unwrap_err();
        assert!(e.to_string().contains("restart_window_s"), "{e}");
        // A setting a stage would refuse at start-up is refused here already.
        let e = parse("[fusion]\ntruncation_voxels = -4.0").unwrap_err();
        assert!(e.to_string().contains("fusion"), "{e}");
        let e = parse("[selection]\nmin_quality = 2.0").unwrap_err();
        assert!(e.to_string().contains("min_quality"), "{e}");
        let e = parse("[perception]\nmax_grasps_per_frame = 0").unwrap_err();
        assert!(
            e.to_string().contains("perception.max_grasps_per_frame"),
            "{e}"
        );
        let e = parse("[inferense]\nkind = \"analytic\"").unwrap_err();
        assert!(matches!(e, ConfigError::Parse { .. }), "{e}");
        assert!(e.to_string().contains("inferense"), "{e}");
        let e = parse("[selection]\ntop_kk = 3").unwrap_err();
        assert!(e.to_string().contains("top_kk"), "{e}");
        let e = PipelineConfig::load(Path::new("/nonexistent/psgrasp.toml")).unwrap_err();
        assert!(matches!(e, ConfigError::Read { .. }));
    }

    #[test]
    fn default_camera_looks_down_at_the_bin() {
        let cfg = PipelineConfig::default();
        let cam = cfg.camera_model();
        let eye = cam.eye();
        assert!((eye.x - cfg.cell.bin.floor_center.x).abs() < 1e-6);
        assert!(eye.z > cfg.cell.bin.rim_z());
        let axis = cam.workspace_from_camera.rotation * Vector3::z();
        assert!(axis.z < -0.999);
    }
}
