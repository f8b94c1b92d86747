//! The RealSense depth source: an Intel RealSense camera through librealsense2, loaded at run
//! time (`psgrasp-realsense`). Intrinsics and depth scale come from the device; the pose from
//! `camera.pose`, or the workspace is placed on the dominant plane once, as for replay.
use super::{CameraPlacement, DepthSource, SourceFrame};
use anyhow::{Context, Result};
use psgrasp_config::PipelineConfig;
use psgrasp_geometry::{CameraIntrinsics, DepthImage};
use psgrasp_ipc::now_ns;
use psgrasp_realsense::{CameraSettings, Library, RealSenseCamera};

/// Frames of a RealSense camera's Z16 depth stream, in metres.
pub struct RealSenseSource {
    camera: RealSenseCamera,
    placement: CameraPlacement,
}

impl RealSenseSource {
    /// Loads librealsense2 and opens the camera of `camera.realsense`.
    pub fn new(cfg: &PipelineConfig) -> Result<Self> {
        let r = &cfg.camera.realsense;
        let lib = Library::load(r.library.as_deref())?;
        let camera = RealSenseCamera::open(lib, &Self::settings(cfg))?;
        Self::from_camera(camera, cfg)
    }

    /// The camera settings of `camera.realsense` (the newest frame is always the one read).
    pub fn settings(cfg: &PipelineConfig) -> CameraSettings {
        let r = &cfg.camera.realsense;
        CameraSettings {
            serial: r.serial.clone(),
            width: r.width,
            height: r.height,
            fps: r.fps,
            queue_size: 1,
            timeout_ms: r.timeout_ms,
        }
    }

    /// A source reading an opened camera (a librealsense software device's in tests).
    pub fn from_camera(camera: RealSenseCamera, cfg: &PipelineConfig) -> Result<Self> {
        let k = camera.intrinsics();
        let intrinsics = CameraIntrinsics {
            width: k.width,
            height: k.height,
            fx: k.fx,
            fy: k.fy,
            cx: k.ppx,
            cy: k.ppy,
        };
        intrinsics
            .validate()
            .with_context(|| format!("intrinsics of {}", camera.label()))?;
        if k.coeffs.iter().any(|c| *c != 0.0) {
            // The D400 depth stream is rectified (all zero); the pinhole model ignores the rest.
            tracing::warn!(
                "{}: distortion coefficients {:?} (model {}) are ignored",
                camera.label(),
                k.coeffs,
                k.model
            );
        }
        tracing::info!(
            "RealSense {}: {}x{} depth, {} m per count",
            camera.label(),
            k.width,
            k.height,
            camera.depth_scale()
        );
        Ok(Self {
            camera,
            placement: CameraPlacement::new(intrinsics, cfg),
        })
    }

    /// The depth stream's intrinsics (from the device).
    pub fn intrinsics(&self) -> CameraIntrinsics {
        self.placement.intrinsics()
    }

    /// Metres per depth count of the device's depth sensor.
    pub fn depth_scale(&self) -> f32 {
        self.camera.depth_scale()
    }
}

impl DepthSource for RealSenseSource {
    fn name(&self) -> &str {
        "realsense"
    }

    fn next_frame(&mut self) -> Result<Option<SourceFrame>> {
        let frame = self.camera.next_frame()?;
        let capture_ns = frame.capture_unix_ns().unwrap_or_else(now_ns);
        let depth = DepthImage::from_metres(frame.width, frame.height, frame.depth_m)
            .with_context(|| format!("frame {} of {}", frame.frame_number, self.camera.label()))?;
        let camera = self.placement.camera_for(&depth)?;
        Ok(Some(SourceFrame {
            depth,
            camera,
            capture_ns,
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use psgrasp_config::{PoseConfig, SourceKind};
    use psgrasp_realsense::software::{DepthStream, SoftwareDevice};
    use psgrasp_realsense::{Intrinsics, TimestampDomain};

    /// Metres per count of the software camera.
    const UNIT_M: f32 = 0.0001;

    fn small_camera_config() -> PipelineConfig {
        let mut cfg = PipelineConfig::default();
        cfg.camera.intrinsics = CameraIntrinsics {
            width: 160,
            height: 120,
            fx: 150.0,
            fy: 150.0,
            cx: 79.5,
            cy: 59.5,
        };
        cfg
    }

    /// The library, or `None` when `PSGRASP_SKIP_REALSENSE=1` (a missing one fails the test).
    fn library() -> Option<&'static Library> {
        if std::env::var("PSGRASP_SKIP_REALSENSE").as_deref() == Ok("1") {
            return None;
        }
        Some(Library::load(None).unwrap_or_else(|e| {
            panic!("{e}\n(scripts/test.sh installs it; PSGRASP_SKIP_REALSENSE=1 skips)")
        }))
    }

    #[test]
    fn a_realsense_frame_of_a_rendered_bin_enters_in_metres_with_the_device_intrinsics() {
        let Some(lib) = library() else { return };
        let cfg = small_camera_config();
        // A synthetic bin, quantised to Z16 counts as a camera would send it.
        let truth = crate::sources::SyntheticSource::new(&cfg)
            .render(0)
            .unwrap();
        let counts: Vec<u16> = truth
            .data
            .iter()
            .map(|d| {
                if d.is_finite() {
                    (d / UNIT_M).round() as u16
                } else {
                    0
                }
            })
            .collect();
        let k = cfg.camera.intrinsics;
        let mut dev = SoftwareDevice::new(lib, "SW-BIN").unwrap();
        let stream = DepthStream {
            intrinsics: Intrinsics {
                width: k.width,
                height: k.height,
                fx: k.fx,
                fy: k.fy,
                ppx: k.cx,
                ppy: k.cy,
                model: 0,
                coeffs: [0.0; 5],
            },
            fps: 15,
            depth_unit_m: UNIT_M,
        };
        let sensor = dev.add_depth_sensor("Stereo Module", &stream).unwrap();
        let mut rs_cfg = cfg.clone();
        rs_cfg.camera.source = SourceKind::Realsense;
        rs_cfg.camera.realsense.width = k.width;
        rs_cfg.camera.realsense.height = k.height;
        rs_cfg.camera.realsense.fps = 15;
        let settings = RealSenseSource::settings(&rs_cfg);
        let camera = RealSenseCamera::from_device(dev.into_device(), &settings).unwrap();
        // No configured pose: the workspace is placed on the bin floor by the plane fit.
        let mut source = RealSenseSource::from_camera(camera, &rs_cfg).unwrap();
        assert_eq!(source.intrinsics(), k);
        assert_eq!(source.depth_scale(), UNIT_M);
        sensor
            .push_z16(&counts, 0.0, TimestampDomain::HardwareClock, 1)
            .unwrap();
        let before = now_ns();
        let frame = source.next_frame().unwrap().unwrap();
        assert!(
            frame.capture_ns >= before,
            "camera-clock stamps get the host's time"
        );
        let want: Vec<f32> = counts.iter().map(|&c| f32::from(c) * UNIT_M).collect();
        assert_eq!(frame.depth.data, want);
        assert_eq!(frame.camera.intrinsics, k);
        // The fitted pose puts the camera where the synthetic camera was, to within 1 cm.
        let eye_fit = frame.camera.eye();
        let eye_true = cfg.camera_model().eye();
        assert!(
            (eye_fit.z - eye_true.z).abs() < 0.01,
            "camera height {} (fit) vs {} (rendered)",
            eye_fit.z,
            eye_true.z
        );
        // A configured pose is used as is.
        rs_cfg.camera.pose = Some(PoseConfig {
            translation: [0.3, 0.3, 0.9],
            rotation_xyzw: [1.0, 0.0, 0.0, 0.0],
        });
        let mut dev = SoftwareDevice::new(lib, "SW-POSE").unwrap();
        let sensor = dev.add_depth_sensor("Stereo Module", &stream).unwrap();
        let camera = RealSenseCamera::from_device(dev.into_device(), &settings).unwrap();
        let mut source = RealSenseSource::from_camera(camera, &rs_cfg).unwrap();
        sensor
            .push_z16(&counts, 1.7e12, TimestampDomain::SystemTime, 1)
            .unwrap();
        let frame = source.next_frame().unwrap().unwrap();
        assert_eq!(frame.capture_ns, 1_700_000_000_000_000_000);
        assert_eq!(
            frame.camera.workspace_from_camera,
            rs_cfg.camera.pose.unwrap().isometry()
        );
    }

    #[test]
    fn preflight_names_a_missing_library_or_camera() {
        let mut cfg = small_camera_config();
        cfg.camera.source = SourceKind::Realsense;
        cfg.camera.realsense.library = Some("/nonexistent/librealsense2.so".into());
        let err = crate::launcher::preflight(&cfg).unwrap_err();
        assert!(
            format!("{err:#}").starts_with(
                "camera-ingest: depth source: librealsense2 not found: tried \
                 /nonexistent/librealsense2.so; install"
            ),
            "{err:#}"
        );
        let Some(lib) = library() else { return };
        cfg.camera.realsense.library = Some(lib.path().to_path_buf());
        match crate::launcher::preflight(&cfg) {
            Err(err) => assert_eq!(
                format!("{err:#}"),
                format!(
                    "camera-ingest: depth source: no RealSense device found (librealsense \
                     2.59.1 loaded from {})",
                    lib.path().display()
                )
            ),
            Ok(()) => eprintln!("a RealSense camera is attached"),
        }
    }
}
