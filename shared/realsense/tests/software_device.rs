//! The RealSense source through the real librealsense, without a camera: frames pushed into a
//! librealsense software device are read back through the same sensor, frame-queue and frame
//! path a camera uses. Without the library these tests fail and say how to install it, unless
//! `PSGRASP_SKIP_REALSENSE=1` is set.
use psgrasp_realsense::software::{DepthStream, SoftwareDepthSensor, SoftwareDevice};
use psgrasp_realsense::{
    CameraSettings, Error, Intrinsics, Library, RealSenseCamera, TimestampDomain,
};
use std::path::Path;
use std::time::Instant;

/// The library, or `None` when the tests are skipped explicitly.
fn library() -> Option<&'static Library> {
    if std::env::var("PSGRASP_SKIP_REALSENSE").as_deref() == Ok("1") {
        eprintln!("PSGRASP_SKIP_REALSENSE=1: RealSense test skipped");
        return None;
    }
    match Library::load(None) {
        Ok(lib) => Some(lib),
        Err(e) => panic!(
            "{e}\n\nThe RealSense tests run through the real librealsense2: run \
             scripts/setup-python.sh (it installs the pinned pyrealsense2 wheel into the venv) \
             and `apt-get install -y libusb-1.0-0` (scripts/test.sh does both), or point \
             PSGRASP_REALSENSE_LIB at a librealsense2.so; PSGRASP_SKIP_REALSENSE=1 skips them."
        ),
    }
}

const W: u32 = 16;
const H: u32 = 12;
const FPS: u32 = 30;
const UNIT_M: f32 = 0.000_125;

fn intrinsics() -> Intrinsics {
    Intrinsics {
        width: W,
        height: H,
        fx: 12.25,
        fy: 13.5,
        ppx: 7.75,
        ppy: 5.625,
        model: 0,
        coeffs: [0.0; 5],
    }
}

/// A camera on a software device with one depth sensor; the sensor pushes its frames.
fn software_camera(
    lib: &'static Library,
    settings: &CameraSettings,
) -> Result<(RealSenseCamera, SoftwareDepthSensor), Error> {
    let mut dev = SoftwareDevice::new(lib, "SW-0001")?;
    let stream = DepthStream {
        intrinsics: intrinsics(),
        fps: FPS,
        depth_unit_m: UNIT_M,
    };
    let sensor = dev.add_depth_sensor("Stereo Module", &stream)?;
    let camera = RealSenseCamera::from_device(dev.into_device(), settings)?;
    Ok((camera, sensor))
}

fn settings() -> CameraSettings {
    CameraSettings {
        width: W,
        height: H,
        fps: FPS,
        ..CameraSettings::default()
    }
}

/// Frame `k`: a ramp of counts with a hole (0 = no measurement) that moves with `k`.
fn counts(k: u32) -> Vec<u16> {
    (0..W * H)
        .map(|i| {
            if i % 37 == k % 37 {
                0
            } else {
                ((4000 + 97 * i + 1009 * k) % 60_000 + 1) as u16
            }
        })
        .collect()
}

#[test]
fn software_device_frames_come_back_in_metres_with_the_stream_intrinsics() {
    let Some(lib) = library() else { return };
    assert_eq!(lib.version(), "2.59.1", "{lib:?}");
    let (mut camera, sensor) = software_camera(lib, &settings()).unwrap();
    assert_eq!(camera.intrinsics(), intrinsics());
    assert_eq!(camera.depth_scale(), UNIT_M);
    assert_eq!(camera.label(), "RealSense (SW-0001)");
    const FRAMES: u32 = 50;
    let start = Instant::now();
    for k in 1..=FRAMES {
        let c = counts(k);
        let t_ms = 1.7e12 + 33.0 * f64::from(k);
        sensor
            .push_z16(&c, t_ms, TimestampDomain::SystemTime, k as i32)
            .unwrap();
        let frame = camera.next_frame().unwrap();
        assert_eq!((frame.width, frame.height), (W, H));
        assert_eq!(frame.depth_unit_m, UNIT_M);
        let want: Vec<f32> = c.iter().map(|&v| f32::from(v) * UNIT_M).collect();
        assert_eq!(frame.depth_m, want, "frame {k}");
        let holes = frame.depth_m.iter().filter(|d| **d == 0.0).count();
        assert_eq!(holes, c.iter().filter(|v| **v == 0).count());
        assert!(holes >= 5, "{holes} pixels without a measurement");
        assert_eq!(frame.frame_number, u64::from(k));
        assert_eq!(frame.timestamp_ms, t_ms);
        assert_eq!(frame.timestamp_domain, TimestampDomain::SystemTime);
        assert_eq!(frame.capture_unix_ns(), Some((t_ms * 1e6) as u64));
    }
    eprintln!(
        "{FRAMES} frames of {W}x{H} pushed and read back in {:.1} ms ({lib:?})",
        start.elapsed().as_secs_f64() * 1e3
    );
}

#[test]
fn a_full_queue_keeps_the_newest_frame_and_an_empty_one_times_out() {
    let Some(lib) = library() else { return };
    let s = CameraSettings {
        timeout_ms: 50,
        ..settings()
    };
    let (mut camera, sensor) = software_camera(lib, &s).unwrap();
    for k in 1..=3 {
        let domain = TimestampDomain::HardwareClock;
        sensor
            .push_z16(&counts(k), 10.0 * f64::from(k), domain, k as i32)
            .unwrap();
    }
    let frame = camera.next_frame().unwrap();
    assert_eq!(frame.frame_number, 3);
    assert_eq!(frame.capture_unix_ns(), None, "a camera-clock timestamp");
    let err = camera.next_frame().unwrap_err();
    assert!(matches!(err, Error::Timeout { ms: 50 }), "{err}");
    assert_eq!(
        err.to_string(),
        "no depth frame from the RealSense device within 50 ms"
    );
}

#[test]
fn bad_settings_and_frames_are_errors_naming_the_cause() {
    let Some(lib) = library() else { return };
    let wrong = CameraSettings {
        width: 640,
        height: 480,
        ..settings()
    };
    let err = software_camera(lib, &wrong)
        .err()
        .expect("no 640x480 stream");
    assert_eq!(
        err.to_string(),
        "RealSense device RealSense (SW-0001) has no Z16 depth stream 640x480@30 \
         (available: 16x12@30)"
    );
    let zero = CameraSettings {
        fps: 0,
        ..settings()
    };
    let err = software_camera(lib, &zero).err().expect("fps 0");
    assert!(err.to_string().contains("fps 0 must be in 1..="), "{err}");
    let (_camera, sensor) = software_camera(lib, &settings()).unwrap();
    let err = sensor
        .push_z16(&[1, 2, 3], 0.0, TimestampDomain::SystemTime, 1)
        .unwrap_err();
    assert_eq!(
        err.to_string(),
        "RealSense: 3 depth counts for a 16x12 stream"
    );
}

#[test]
fn without_a_camera_opening_one_says_no_device_was_found() {
    let Some(lib) = library() else { return };
    match RealSenseCamera::open(lib, &CameraSettings::default()) {
        Err(e @ Error::NoDevice { .. }) => assert_eq!(
            e.to_string(),
            format!(
                "no RealSense device found (librealsense 2.59.1 loaded from {})",
                lib.path().display()
            )
        ),
        Err(e) => panic!("expected no device, got: {e}"),
        // A machine with a camera attached: it must stream what it says.
        Ok(camera) => eprintln!("a camera is attached: {}", camera.label()),
    }
    // The same library file loads once.
    let again = Library::load_file(lib.path()).unwrap();
    assert!(std::ptr::eq(again, lib));
}

#[test]
fn a_missing_library_is_not_found_with_the_paths_tried() {
    let path = Path::new("/nonexistent/librealsense2.so.2.59");
    let err = Library::load(Some(path)).unwrap_err();
    assert!(matches!(err, Error::NotFound { .. }), "{err}");
    assert!(
        err.to_string().starts_with(
            "librealsense2 not found: tried /nonexistent/librealsense2.so.2.59; install"
        ),
        "{err}"
    );
    // A file that is not a library is a load error naming the file.
    let not_lib = std::env::temp_dir().join(format!("psgrasp-not-rs-{}.so", std::process::id()));
    std::fs::write(&not_lib, b"not a library").unwrap();
    let err = Library::load(Some(&not_lib)).unwrap_err();
    std::fs::remove_file(&not_lib).ok();
    assert!(matches!(err, Error::Load { .. }), "{err}");
    assert!(
        err.to_string().starts_with(&format!(
            "cannot load librealsense2 from {}: ",
            not_lib.display()
        )),
        "{err}"
    );
}
