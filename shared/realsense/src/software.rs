//! librealsense software devices: a device whose frames the program pushes, which runs the
//! same sensor, frame-queue and frame code as a camera. For tests without hardware.
use crate::camera::{Device, Intrinsics, TimestampDomain};
use crate::ffi;
use crate::{call, Error, Library};
use std::ffi::{c_int, c_void, CString};

/// A software device (`rs2_create_software_device`).
pub struct SoftwareDevice {
    device: Device,
}

/// A Z16 depth stream to add to a software sensor.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthStream {
    /// Intrinsics (width and height are the stream's).
    pub intrinsics: Intrinsics,
    /// Frames per second.
    pub fps: u32,
    /// Metres per depth count (the sensor's read-only `RS2_OPTION_DEPTH_UNITS`).
    pub depth_unit_m: f32,
}

/// A software depth sensor whose frames [`SoftwareDepthSensor::push_z16`] injects.
pub struct SoftwareDepthSensor {
    lib: &'static Library,
    ptr: *mut ffi::rs2_sensor,
    profile: *const ffi::rs2_stream_profile,
    width: u32,
    height: u32,
}

impl Drop for SoftwareDepthSensor {
    fn drop(&mut self) {
        // SAFETY: owned (the stream profile belongs to the sensor), deleted once.
        unsafe { (self.lib.api.rs2_delete_sensor)(self.ptr) }
    }
}

fn c_string(s: &str) -> Result<CString, Error> {
    CString::new(s).map_err(|_| Error::Invalid(format!("{s:?} contains a NUL byte")))
}

impl SoftwareDevice {
    /// A new software device with `serial` as its serial number.
    pub fn new(lib: &'static Library, serial: &str) -> Result<Self, Error> {
        let ptr = call!(&lib.api, rs2_create_software_device)?;
        if ptr.is_null() {
            return Err(Error::Invalid(
                "rs2_create_software_device returned no object".into(),
            ));
        }
        let device = Device { lib, ptr };
        let serial = c_string(serial)?;
        let info = ffi::RS2_CAMERA_INFO_SERIAL_NUMBER;
        call!(
            &lib.api,
            rs2_software_device_register_info,
            ptr,
            info,
            serial.as_ptr()
        )?;
        Ok(Self { device })
    }

    /// Adds a sensor named `name` with one Z16 depth stream and its depth units.
    pub fn add_depth_sensor(
        &mut self,
        name: &str,
        stream: &DepthStream,
    ) -> Result<SoftwareDepthSensor, Error> {
        let lib = self.device.lib;
        let api = &lib.api;
        let name = c_string(name)?;
        let ptr = call!(
            api,
            rs2_software_device_add_sensor,
            self.device.ptr,
            name.as_ptr()
        )?;
        if ptr.is_null() {
            return Err(Error::Invalid(
                "rs2_software_device_add_sensor returned no object".into(),
            ));
        }
        let mut sensor = SoftwareDepthSensor {
            lib,
            ptr,
            profile: std::ptr::null(),
            width: stream.intrinsics.width,
            height: stream.intrinsics.height,
        };
        let i = &stream.intrinsics;
        let to_int =
            |v: u32| c_int::try_from(v).map_err(|_| Error::Invalid(format!("{v} too large")));
        let video = ffi::rs2_video_stream {
            type_: ffi::RS2_STREAM_DEPTH,
            index: 0,
            uid: 0,
            width: to_int(i.width)?,
            height: to_int(i.height)?,
            fps: to_int(stream.fps)?,
            bpp: 2,
            fmt: ffi::RS2_FORMAT_Z16,
            intrinsics: ffi::rs2_intrinsics {
                width: to_int(i.width)?,
                height: to_int(i.height)?,
                ppx: i.ppx,
                ppy: i.ppy,
                fx: i.fx,
                fy: i.fy,
                model: i.model,
                coeffs: i.coeffs,
            },
        };
        sensor.profile = call!(api, rs2_software_sensor_add_video_stream, ptr, video)?;
        let option = ffi::RS2_OPTION_DEPTH_UNITS;
        call!(
            api,
            rs2_software_sensor_add_read_only_option,
            ptr,
            option,
            stream.depth_unit_m
        )?;
        Ok(sensor)
    }

    /// The device, to open as a camera ([`crate::RealSenseCamera::from_device`]); its sensors
    /// keep working.
    pub fn into_device(self) -> Device {
        self.device
    }
}

impl SoftwareDepthSensor {
    /// Injects one frame of depth counts (row-major, `width * height`), stamped `timestamp_ms`
    /// in `domain`. librealsense drops frames pushed while the sensor is not streaming.
    pub fn push_z16(
        &self,
        counts: &[u16],
        timestamp_ms: f64,
        domain: TimestampDomain,
        frame_number: i32,
    ) -> Result<(), Error> {
        let n = self.width as usize * self.height as usize;
        if counts.len() != n {
            return Err(Error::Invalid(format!(
                "{} depth counts for a {}x{} stream",
                counts.len(),
                self.width,
                self.height
            )));
        }
        // librealsense keeps the pixels until it calls the deleter (`free`).
        // SAFETY: a fresh allocation of `2 n` bytes, filled before it is handed over.
        let pixels = unsafe { libc::malloc(2 * n.max(1)) }.cast::<u16>();
        if pixels.is_null() {
            return Err(Error::Invalid("out of memory for a software frame".into()));
        }
        // SAFETY: `pixels` holds `n` u16 values.
        unsafe { std::ptr::copy_nonoverlapping(counts.as_ptr(), pixels, n) };
        unsafe extern "C" fn free_pixels(p: *mut c_void) {
            // SAFETY: allocated with malloc above, freed once by librealsense.
            unsafe { libc::free(p) }
        }
        let frame = ffi::rs2_software_video_frame {
            pixels: pixels.cast(),
            deleter: Some(free_pixels),
            stride: (2 * self.width) as c_int,
            bpp: 2,
            timestamp: timestamp_ms,
            domain: domain.raw(),
            frame_number,
            profile: self.profile,
            // 0: the sensor's RS2_OPTION_DEPTH_UNITS.
            depth_units: 0.0,
        };
        call!(
            &self.lib.api,
            rs2_software_sensor_on_video_frame,
            self.ptr,
            frame
        )
    }
}
