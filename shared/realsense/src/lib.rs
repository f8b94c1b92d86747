//! Intel RealSense depth cameras through librealsense2's C API, loaded with `dlopen` at run
//! time, so building needs nothing extra and machines without librealsense build too.
//!
//! [`Library::load`] finds the library (a configured path, `$PSGRASP_REALSENSE_LIB`, a system
//! `librealsense2.so`, or the `pyrealsense2` wheel of the project's venv);
//! [`RealSenseCamera::open`] starts a Z16 depth stream on the first device (or one by serial
//! number) and [`RealSenseCamera::next_frame`] returns frames in metres. The [`software`]
//! module builds a librealsense software device, which runs the same frame path without a
//! camera (the crate's tests use it).
#![warn(missing_docs)]

mod camera;
#[allow(unsafe_op_in_unsafe_fn)]
mod ffi;
mod load;
pub mod software;

pub use camera::{
    CameraSettings, DepthFrame, Device, Intrinsics, RealSenseCamera, TimestampDomain, MAX_FPS,
    MAX_SIDE,
};
pub use load::{Library, INSTALL_HINT, LIBRARY_ENV, PYTHON_ENV, SYSTEM_DIRS, VENV_ENV};

use std::ffi::{c_char, CStr};
use std::path::PathBuf;

/// Errors of loading librealsense, finding a camera and reading frames.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// No candidate library file exists.
    #[error("librealsense2 not found: tried {}; {INSTALL_HINT}", .tried.join(", "))]
    NotFound {
        /// The paths tried, in order.
        tried: Vec<String>,
    },
    /// A library file exists but could not be loaded or lacks librealsense's API.
    #[error("cannot load librealsense2 from {}: {reason}{}", .path.display(), load_hint(.reason))]
    Load {
        /// The file.
        path: PathBuf,
        /// The loader's message.
        reason: String,
    },
    /// A librealsense call failed.
    #[error("librealsense: {function}({args}): {message}")]
    Api {
        /// The failed function.
        function: String,
        /// Its arguments as librealsense prints them.
        args: String,
        /// librealsense's message.
        message: String,
    },
    /// The library reports no device.
    #[error("no RealSense device found (librealsense {version} loaded from {})", .path.display())]
    NoDevice {
        /// Library version.
        version: String,
        /// Library file.
        path: PathBuf,
    },
    /// No device has the requested serial number.
    #[error("no RealSense device with serial number {serial:?} (found: {})", .found.join(", "))]
    SerialNotFound {
        /// The requested serial number.
        serial: String,
        /// Serial numbers of the connected devices.
        found: Vec<String>,
    },
    /// The device has no depth sensor.
    #[error("RealSense device {device} has no depth sensor")]
    NoDepthSensor {
        /// Device name and serial number.
        device: String,
    },
    /// The depth sensor offers no Z16 stream of the requested size and rate.
    #[error("RealSense device {device} has no Z16 depth stream {wanted} (available: {})", .available.join(", "))]
    NoProfile {
        /// Device name and serial number.
        device: String,
        /// `WxH@FPS` requested.
        wanted: String,
        /// The Z16 depth streams it offers.
        available: Vec<String>,
    },
    /// No frame arrived in time.
    #[error("no depth frame from the RealSense device within {ms} ms")]
    Timeout {
        /// The wait, milliseconds.
        ms: u32,
    },
    /// A frame or setting librealsense handed back is unusable.
    #[error("RealSense: {0}")]
    Invalid(String),
}

fn load_hint(reason: &str) -> &'static str {
    if reason.contains("libusb") {
        " (librealsense needs libusb: apt-get install libusb-1.0-0)"
    } else if reason.contains("libudev") {
        " (librealsense needs libudev: apt-get install libudev1)"
    } else {
        ""
    }
}

/// Turns the error a call left in `err` into an [`Error::Api`], freeing it.
pub(crate) fn check(api: &ffi::Api, err: *mut ffi::rs2_error) -> Result<(), Error> {
    if err.is_null() {
        return Ok(());
    }
    let text = |p: *const c_char| {
        if p.is_null() {
            String::new()
        } else {
            // SAFETY: librealsense returns NUL-terminated strings owned by the error.
            unsafe { CStr::from_ptr(p) }.to_string_lossy().into_owned()
        }
    };
    // SAFETY: `err` is a live error from librealsense, freed once after reading it.
    let e = unsafe {
        let e = Error::Api {
            function: text((api.rs2_get_failed_function)(err)),
            args: text((api.rs2_get_failed_args)(err)),
            message: text((api.rs2_get_error_message)(err)),
        };
        (api.rs2_free_error)(err);
        e
    };
    Err(e)
}

/// Calls a librealsense function with an error out-pointer appended, returning its result or
/// the error (`call!(api, rs2_fn, args...)`).
macro_rules! call {
    ($api:expr, $f:ident $(, $arg:expr)* $(,)?) => {{
        let api: &$crate::ffi::Api = $api;
        let mut err: *mut $crate::ffi::rs2_error = std::ptr::null_mut();
        #[allow(unused_unsafe)]
        // SAFETY: every handle passed is live (owned by an RAII wrapper of this crate).
        let out = unsafe { (api.$f)($($arg,)* &mut err) };
        $crate::check(api, err).map(|()| out)
    }};
}
pub(crate) use call;
