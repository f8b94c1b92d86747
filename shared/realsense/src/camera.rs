//! Devices, the depth stream and its frames, each librealsense object owned by a wrapper that
//! releases it.
use crate::ffi::{self, rs2_enum};
use crate::{call, Error, Library};
use std::ffi::{c_int, CStr};

/// Metres per depth count when neither the frame nor the sensor says (librealsense's default).
const DEFAULT_DEPTH_UNIT_M: f32 = 0.001;

/// Which camera and which depth stream to open.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CameraSettings {
    /// Serial number of the device; `None` = the first one found.
    pub serial: Option<String>,
    /// Depth image width, pixels.
    pub width: u32,
    /// Depth image height, pixels.
    pub height: u32,
    /// Frames per second of the depth stream.
    pub fps: u32,
    /// Frames kept waiting for [`RealSenseCamera::next_frame`]; when full, the oldest is
    /// dropped, so 1 always hands out the newest frame.
    pub queue_size: u32,
    /// Longest wait for a frame, milliseconds.
    pub timeout_ms: u32,
}

impl Default for CameraSettings {
    fn default() -> Self {
        Self {
            serial: None,
            width: 640,
            height: 480,
            fps: 30,
            queue_size: 1,
            timeout_ms: 5000,
        }
    }
}

/// Pinhole intrinsics of the depth stream (`rs2_intrinsics`), pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Intrinsics {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Focal length x.
    pub fx: f32,
    /// Focal length y.
    pub fy: f32,
    /// Principal point x.
    pub ppx: f32,
    /// Principal point y.
    pub ppy: f32,
    /// librealsense's distortion model (`rs2_distortion`; 0 = none).
    pub model: i32,
    /// Distortion coefficients.
    pub coeffs: [f32; 5],
}

/// The clock of a frame's timestamp (`rs2_timestamp_domain`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TimestampDomain {
    /// The camera's own clock.
    HardwareClock,
    /// The host's clock at arrival (ms since the Unix epoch).
    SystemTime,
    /// The camera clock mapped onto the host's (ms since the Unix epoch).
    GlobalTime,
    /// Another domain number.
    Other(i32),
}

impl TimestampDomain {
    fn from_raw(v: rs2_enum) -> Self {
        match v {
            ffi::RS2_TIMESTAMP_DOMAIN_HARDWARE_CLOCK => Self::HardwareClock,
            ffi::RS2_TIMESTAMP_DOMAIN_SYSTEM_TIME => Self::SystemTime,
            ffi::RS2_TIMESTAMP_DOMAIN_GLOBAL_TIME => Self::GlobalTime,
            v => Self::Other(v),
        }
    }

    /// The raw `rs2_timestamp_domain`.
    pub fn raw(self) -> i32 {
        match self {
            Self::HardwareClock => ffi::RS2_TIMESTAMP_DOMAIN_HARDWARE_CLOCK,
            Self::SystemTime => ffi::RS2_TIMESTAMP_DOMAIN_SYSTEM_TIME,
            Self::GlobalTime => ffi::RS2_TIMESTAMP_DOMAIN_GLOBAL_TIME,
            Self::Other(v) => v,
        }
    }
}

/// One depth frame in metres.
#[derive(Debug, Clone, PartialEq)]
pub struct DepthFrame {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Depth per pixel, row-major, metres (0 = no measurement).
    pub depth_m: Vec<f32>,
    /// Metres per count the frame was converted with.
    pub depth_unit_m: f32,
    /// Capture timestamp, milliseconds in `timestamp_domain`.
    pub timestamp_ms: f64,
    /// The clock of `timestamp_ms`.
    pub timestamp_domain: TimestampDomain,
    /// librealsense's frame counter.
    pub frame_number: u64,
}

impl DepthFrame {
    /// The capture time as Unix nanoseconds, when the timestamp is on the host's clock.
    pub fn capture_unix_ns(&self) -> Option<u64> {
        let on_host = matches!(
            self.timestamp_domain,
            TimestampDomain::SystemTime | TimestampDomain::GlobalTime
        );
        let ns = self.timestamp_ms * 1e6;
        (on_host && ns.is_finite() && ns > 0.0 && ns < u64::MAX as f64).then_some(ns as u64)
    }
}

/// A librealsense context (`rs2_context`).
struct Context {
    lib: &'static Library,
    ptr: *mut ffi::rs2_context,
}

impl Drop for Context {
    fn drop(&mut self) {
        // SAFETY: owned, deleted once.
        unsafe { (self.lib.api.rs2_delete_context)(self.ptr) }
    }
}

/// A RealSense device (`rs2_device`): a camera, or a software device.
pub struct Device {
    pub(crate) lib: &'static Library,
    pub(crate) ptr: *mut ffi::rs2_device,
}

// SAFETY: librealsense's handles may be used from any thread, one at a time.
unsafe impl Send for Device {}

impl Drop for Device {
    fn drop(&mut self) {
        // SAFETY: owned, deleted once.
        unsafe { (self.lib.api.rs2_delete_device)(self.ptr) }
    }
}

impl Device {
    /// A camera-info string (`rs2_camera_info`), when the device has it.
    fn info(&self, info: rs2_enum) -> Option<String> {
        let api = &self.lib.api;
        if call!(api, rs2_supports_device_info, self.ptr, info).ok()? == 0 {
            return None;
        }
        let p = call!(api, rs2_get_device_info, self.ptr, info).ok()?;
        // SAFETY: a NUL-terminated string owned by the device.
        (!p.is_null()).then(|| unsafe { CStr::from_ptr(p) }.to_string_lossy().into_owned())
    }

    /// The device's serial number.
    pub fn serial(&self) -> Option<String> {
        self.info(ffi::RS2_CAMERA_INFO_SERIAL_NUMBER)
    }

    /// "name (serial)" for messages ("RealSense" when the device has no name, as software
    /// devices of librealsense 2.59).
    pub fn label(&self) -> String {
        let name = self.info(ffi::RS2_CAMERA_INFO_NAME);
        let serial = self.serial().unwrap_or_else(|| "no serial".into());
        format!("{} ({serial})", name.as_deref().unwrap_or("RealSense"))
    }
}

macro_rules! owned {
    ($name:ident, $raw:ty, $delete:ident) => {
        struct $name {
            lib: &'static Library,
            ptr: *mut $raw,
        }
        impl Drop for $name {
            fn drop(&mut self) {
                // SAFETY: owned, deleted once.
                unsafe { (self.lib.api.$delete)(self.ptr) }
            }
        }
    };
}
owned!(Sensor, ffi::rs2_sensor, rs2_delete_sensor);
owned!(
    ProfileList,
    ffi::rs2_stream_profile_list,
    rs2_delete_stream_profiles_list
);
owned!(FrameQueue, ffi::rs2_frame_queue, rs2_delete_frame_queue);
owned!(Frame, ffi::rs2_frame, rs2_release_frame);
owned!(DeviceList, ffi::rs2_device_list, rs2_delete_device_list);
owned!(SensorList, ffi::rs2_sensor_list, rs2_delete_sensor_list);

/// A non-null handle, or an error naming the call that returned null.
fn non_null<T>(ptr: *mut T, what: &str) -> Result<*mut T, Error> {
    if ptr.is_null() {
        Err(Error::Invalid(format!("{what} returned no object")))
    } else {
        Ok(ptr)
    }
}

/// A depth camera streaming Z16 frames into a frame queue (sensor `open` + `start_queue`).
pub struct RealSenseCamera {
    lib: &'static Library,
    // Dropped in this order after `Drop::drop` stopped and closed the sensor.
    queue: FrameQueue,
    _profiles: ProfileList,
    sensor: Sensor,
    device: Device,
    _context: Option<Context>,
    label: String,
    intrinsics: Intrinsics,
    depth_scale: f32,
    timeout_ms: u32,
}

// SAFETY: librealsense's handles may be used from any thread, one at a time.
unsafe impl Send for RealSenseCamera {}

impl Drop for RealSenseCamera {
    fn drop(&mut self) {
        // Errors here (e.g. a camera unplugged) leave nothing more to release.
        let _ = call!(&self.lib.api, rs2_stop, self.sensor.ptr);
        let _ = call!(&self.lib.api, rs2_close, self.sensor.ptr);
    }
}

impl RealSenseCamera {
    /// Opens the first device (or the one with `settings.serial`) and starts its depth stream.
    pub fn open(lib: &'static Library, settings: &CameraSettings) -> Result<Self, Error> {
        let api = &lib.api;
        let ctx = call!(api, rs2_create_context, lib.api_version())?;
        let ctx = Context {
            lib,
            ptr: non_null(ctx, "rs2_create_context")?,
        };
        let list = call!(api, rs2_query_devices, ctx.ptr)?;
        let list = DeviceList {
            lib,
            ptr: non_null(list, "rs2_query_devices")?,
        };
        let count = call!(api, rs2_get_device_count, list.ptr)?;
        if count <= 0 {
            return Err(Error::NoDevice {
                version: lib.version(),
                path: lib.path().to_path_buf(),
            });
        }
        let mut found = Vec::new();
        for i in 0..count {
            let dev = call!(api, rs2_create_device, list.ptr, i)?;
            let device = Device {
                lib,
                ptr: non_null(dev, "rs2_create_device")?,
            };
            let serial = device.serial();
            let wanted = settings.serial.as_ref();
            if wanted.is_none() || wanted == serial.as_ref() {
                let mut camera = Self::from_device(device, settings)?;
                camera._context = Some(ctx);
                return Ok(camera);
            }
            found.push(serial.unwrap_or_else(|| "?".into()));
        }
        Err(Error::SerialNotFound {
            serial: settings.serial.clone().unwrap_or_default(),
            found,
        })
    }

    /// Starts the depth stream of `device` (a camera, or a [`crate::software`] device): finds
    /// its depth sensor and the Z16 stream of the configured size and rate, reads the depth
    /// scale and intrinsics, and starts the sensor into a frame queue.
    pub fn from_device(device: Device, settings: &CameraSettings) -> Result<Self, Error> {
        check_settings(settings)?;
        let lib = device.lib;
        let api = &lib.api;
        let label = device.label();
        let sensors = call!(api, rs2_query_sensors, device.ptr)?;
        let sensors = SensorList {
            lib,
            ptr: non_null(sensors, "rs2_query_sensors")?,
        };
        let mut depth_sensor = None;
        for i in 0..call!(api, rs2_get_sensors_count, sensors.ptr)? {
            let s = call!(api, rs2_create_sensor, sensors.ptr, i)?;
            let sensor = Sensor {
                lib,
                ptr: non_null(s, "rs2_create_sensor")?,
            };
            let ext = ffi::RS2_EXTENSION_DEPTH_SENSOR;
            if call!(api, rs2_is_sensor_extendable_to, sensor.ptr, ext)? != 0 {
                depth_sensor = Some(sensor);
                break;
            }
        }
        let sensor = depth_sensor.ok_or_else(|| Error::NoDepthSensor {
            device: label.clone(),
        })?;
        let depth_scale = call!(api, rs2_get_depth_scale, sensor.ptr)?;
        if !(depth_scale.is_finite() && depth_scale > 0.0) {
            return Err(Error::Invalid(format!(
                "{label}: depth scale {depth_scale} is not a positive number of metres"
            )));
        }
        let profiles = call!(api, rs2_get_stream_profiles, sensor.ptr)?;
        let profiles = ProfileList {
            lib,
            ptr: non_null(profiles, "rs2_get_stream_profiles")?,
        };
        let (w, h, fps) = (settings.width, settings.height, settings.fps);
        let mut chosen = None;
        let mut available = Vec::new();
        for i in 0..call!(api, rs2_get_stream_profiles_count, profiles.ptr)? {
            let p = call!(api, rs2_get_stream_profile, profiles.ptr, i)?;
            let (mut stream, mut format, mut index, mut uid, mut rate) = (0, 0, 0, 0, 0);
            call!(
                api,
                rs2_get_stream_profile_data,
                p,
                &mut stream,
                &mut format,
                &mut index,
                &mut uid,
                &mut rate
            )?;
            if stream != ffi::RS2_STREAM_DEPTH || format != ffi::RS2_FORMAT_Z16 {
                continue;
            }
            let (mut pw, mut ph): (c_int, c_int) = (0, 0);
            call!(api, rs2_get_video_stream_resolution, p, &mut pw, &mut ph)?;
            available.push(format!("{pw}x{ph}@{rate}"));
            if chosen.is_none() && (pw, ph, rate) == (w as c_int, h as c_int, fps as c_int) {
                chosen = Some(p);
            }
        }
        let profile = chosen.ok_or_else(|| Error::NoProfile {
            device: label.clone(),
            wanted: format!("{w}x{h}@{fps}"),
            available,
        })?;
        let mut raw = ffi::rs2_intrinsics::default();
        call!(api, rs2_get_video_stream_intrinsics, profile, &mut raw)?;
        let intrinsics = Intrinsics {
            width: u32::try_from(raw.width).unwrap_or(0),
            height: u32::try_from(raw.height).unwrap_or(0),
            fx: raw.fx,
            fy: raw.fy,
            ppx: raw.ppx,
            ppy: raw.ppy,
            model: raw.model,
            coeffs: raw.coeffs,
        };
        if (intrinsics.width, intrinsics.height) != (w, h) {
            return Err(Error::Invalid(format!(
                "{label}: the {w}x{h} stream's intrinsics are {}x{}",
                intrinsics.width, intrinsics.height
            )));
        }
        let queue = call!(api, rs2_create_frame_queue, settings.queue_size as c_int)?;
        let queue = FrameQueue {
            lib,
            ptr: non_null(queue, "rs2_create_frame_queue")?,
        };
        call!(api, rs2_open, sensor.ptr, profile)?;
        if let Err(e) = call!(api, rs2_start_queue, sensor.ptr, queue.ptr) {
            let _ = call!(api, rs2_close, sensor.ptr);
            return Err(e);
        }
        Ok(Self {
            lib,
            queue,
            _profiles: profiles,
            sensor,
            device,
            _context: None,
            label,
            intrinsics,
            depth_scale,
            timeout_ms: settings.timeout_ms,
        })
    }

    /// The depth stream's intrinsics.
    pub fn intrinsics(&self) -> Intrinsics {
        self.intrinsics
    }

    /// Metres per depth count of the depth sensor (`RS2_OPTION_DEPTH_UNITS`).
    pub fn depth_scale(&self) -> f32 {
        self.depth_scale
    }

    /// "name (serial)" of the device.
    pub fn label(&self) -> &str {
        &self.label
    }

    /// The device streaming.
    pub fn device(&self) -> &Device {
        &self.device
    }

    /// Waits for the next depth frame (at most `timeout_ms`) and converts it to metres with the
    /// frame's depth units (the sensor's depth scale when the frame has none).
    pub fn next_frame(&mut self) -> Result<DepthFrame, Error> {
        let api = &self.lib.api;
        let mut raw = std::ptr::null_mut();
        let got = call!(
            api,
            rs2_try_wait_for_frame,
            self.queue.ptr,
            self.timeout_ms,
            &mut raw
        )?;
        if got == 0 || raw.is_null() {
            return Err(Error::Timeout {
                ms: self.timeout_ms,
            });
        }
        let frame = Frame {
            lib: self.lib,
            ptr: raw,
        };
        let f = frame.ptr;
        let width = call!(api, rs2_get_frame_width, f)?;
        let height = call!(api, rs2_get_frame_height, f)?;
        let stride = call!(api, rs2_get_frame_stride_in_bytes, f)?;
        let bpp = call!(api, rs2_get_frame_bits_per_pixel, f)?;
        let i = self.intrinsics;
        if (width, height) != (i.width as c_int, i.height as c_int) || bpp != 16 {
            return Err(Error::Invalid(format!(
                "{}: a {width}x{height} frame of {bpp} bits per pixel on the {}x{} Z16 stream",
                self.label, i.width, i.height
            )));
        }
        let (w, h) = (i.width as usize, i.height as usize);
        let stride = usize::try_from(stride).unwrap_or(0);
        if stride < 2 * w {
            return Err(Error::Invalid(format!(
                "{}: stride of {stride} bytes for {w} pixels of 2 bytes",
                self.label
            )));
        }
        let data = call!(api, rs2_get_frame_data, f)?.cast::<u8>();
        if data.is_null() {
            return Err(Error::Invalid(format!(
                "{}: a frame without pixels",
                self.label
            )));
        }
        // SAFETY: librealsense holds `height` rows of `stride` bytes while the frame is held.
        let bytes = unsafe { std::slice::from_raw_parts(data, stride * h) };
        let ext = ffi::RS2_EXTENSION_DEPTH_FRAME;
        let frame_units = if call!(api, rs2_is_frame_extendable_to, f, ext)? != 0 {
            call!(api, rs2_depth_frame_get_units, f)?
        } else {
            0.0
        };
        let unit = [frame_units, self.depth_scale, DEFAULT_DEPTH_UNIT_M]
            .into_iter()
            .find(|u| u.is_finite() && *u > 0.0)
            .unwrap_or(DEFAULT_DEPTH_UNIT_M);
        let mut depth_m = Vec::with_capacity(w * h);
        for row in bytes.chunks_exact(stride) {
            depth_m.extend(
                row[..2 * w]
                    .chunks_exact(2)
                    .map(|c| f32::from(u16::from_le_bytes([c[0], c[1]])) * unit),
            );
        }
        let timestamp_ms = call!(api, rs2_get_frame_timestamp, f)?;
        let domain = call!(api, rs2_get_frame_timestamp_domain, f)?;
        let frame_number = call!(api, rs2_get_frame_number, f)?;
        drop(frame);
        Ok(DepthFrame {
            width: i.width,
            height: i.height,
            depth_m,
            depth_unit_m: unit,
            timestamp_ms,
            timestamp_domain: TimestampDomain::from_raw(domain),
            frame_number,
        })
    }
}

/// Largest depth image side accepted, pixels.
pub const MAX_SIDE: u32 = 4096;
/// Fastest depth stream accepted, frames per second.
pub const MAX_FPS: u32 = 1000;

fn check_settings(s: &CameraSettings) -> Result<(), Error> {
    let bad = |what: String| Err(Error::Invalid(what));
    if !(1..=MAX_SIDE).contains(&s.width) || !(1..=MAX_SIDE).contains(&s.height) {
        return bad(format!(
            "{}x{} must be within 1..={MAX_SIDE} pixels a side",
            s.width, s.height
        ));
    }
    if !(1..=MAX_FPS).contains(&s.fps) {
        return bad(format!("fps {} must be in 1..={MAX_FPS}", s.fps));
    }
    if !(1..=64).contains(&s.queue_size) {
        return bad(format!("queue size {} must be in 1..=64", s.queue_size));
    }
    if s.timeout_ms == 0 {
        return bad("timeout must be > 0 ms".into());
    }
    Ok(())
}
