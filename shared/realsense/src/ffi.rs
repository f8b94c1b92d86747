//! The part of librealsense2's C API this crate uses (`rs.h`, `rs_context.h`, `rs_device.h`,
//! `rs_sensor.h`, `rs_frame.h`, `rs_internal.h` of librealsense 2.59), resolved from a loaded
//! library into a table of function pointers.
#![allow(non_camel_case_types, missing_docs)]

use std::ffi::{c_char, c_int, c_uint, c_ulonglong, c_void};

macro_rules! opaque {
    ($($name:ident),* $(,)?) => {
        $(#[repr(C)] pub struct $name { _private: [u8; 0] })*
    };
}
opaque!(
    rs2_error,
    rs2_context,
    rs2_device_list,
    rs2_device,
    rs2_sensor_list,
    rs2_sensor,
    rs2_stream_profile_list,
    rs2_stream_profile,
    rs2_frame_queue,
    rs2_frame,
);

/// `rs2_stream`, `rs2_format`, `rs2_option`, … are C enums: `int` on every supported ABI.
pub type rs2_enum = c_int;
pub const RS2_STREAM_DEPTH: rs2_enum = 1;
pub const RS2_FORMAT_Z16: rs2_enum = 1;
pub const RS2_OPTION_DEPTH_UNITS: rs2_enum = 28;
pub const RS2_EXTENSION_DEPTH_SENSOR: rs2_enum = 7;
pub const RS2_EXTENSION_DEPTH_FRAME: rs2_enum = 12;
pub const RS2_CAMERA_INFO_NAME: rs2_enum = 0;
pub const RS2_CAMERA_INFO_SERIAL_NUMBER: rs2_enum = 1;
pub const RS2_TIMESTAMP_DOMAIN_HARDWARE_CLOCK: rs2_enum = 0;
pub const RS2_TIMESTAMP_DOMAIN_SYSTEM_TIME: rs2_enum = 1;
pub const RS2_TIMESTAMP_DOMAIN_GLOBAL_TIME: rs2_enum = 2;

/// `rs2_intrinsics` (`rs_types.h`).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct rs2_intrinsics {
    pub width: c_int,
    pub height: c_int,
    pub ppx: f32,
    pub ppy: f32,
    pub fx: f32,
    pub fy: f32,
    pub model: rs2_enum,
    pub coeffs: [f32; 5],
}

/// `rs2_video_stream` (`rs_internal.h`).
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct rs2_video_stream {
    pub type_: rs2_enum,
    pub index: c_int,
    pub uid: c_int,
    pub width: c_int,
    pub height: c_int,
    pub fps: c_int,
    pub bpp: c_int,
    pub fmt: rs2_enum,
    pub intrinsics: rs2_intrinsics,
}

/// `rs2_software_video_frame` (`rs_internal.h`; `depth_units` since 2.35).
#[repr(C)]
pub struct rs2_software_video_frame {
    pub pixels: *mut c_void,
    pub deleter: Option<unsafe extern "C" fn(*mut c_void)>,
    pub stride: c_int,
    pub bpp: c_int,
    pub timestamp: f64,
    pub domain: rs2_enum,
    pub frame_number: c_int,
    pub profile: *const rs2_stream_profile,
    pub depth_units: f32,
}

type E = *mut *mut rs2_error;

macro_rules! api {
    ($($name:ident: fn($($arg:ty),*) $(-> $ret:ty)?;)*) => {
        /// librealsense2's functions, resolved once from the loaded library.
        pub struct Api {
            $(pub $name: unsafe extern "C" fn($($arg),*) $(-> $ret)?,)*
        }

        impl Api {
            /// Resolves every function; the first missing one is named in the error.
            ///
            /// # Safety
            /// `lib` must be librealsense2 (or a module exporting its C API), so that each
            /// symbol has the declared signature.
            pub unsafe fn resolve(lib: &libloading::os::unix::Library) -> Result<Self, String> {
                Ok(Self {
                    $($name: *lib
                        .get::<unsafe extern "C" fn($($arg),*) $(-> $ret)?>(stringify!($name))
                        .map_err(|e| format!("symbol {}: {}", stringify!($name), crate::load::dl_error(&e)))?,)*
                })
            }
        }
    };
}

api! {
    rs2_get_api_version: fn(E) -> c_int;
    rs2_get_error_message: fn(*const rs2_error) -> *const c_char;
    rs2_get_failed_function: fn(*const rs2_error) -> *const c_char;
    rs2_get_failed_args: fn(*const rs2_error) -> *const c_char;
    rs2_free_error: fn(*mut rs2_error);
    rs2_create_context: fn(c_int, E) -> *mut rs2_context;
    rs2_delete_context: fn(*mut rs2_context);
    rs2_query_devices: fn(*const rs2_context, E) -> *mut rs2_device_list;
    rs2_get_device_count: fn(*const rs2_device_list, E) -> c_int;
    rs2_delete_device_list: fn(*mut rs2_device_list);
    rs2_create_device: fn(*const rs2_device_list, c_int, E) -> *mut rs2_device;
    rs2_delete_device: fn(*mut rs2_device);
    rs2_supports_device_info: fn(*const rs2_device, rs2_enum, E) -> c_int;
    rs2_get_device_info: fn(*const rs2_device, rs2_enum, E) -> *const c_char;
    rs2_query_sensors: fn(*const rs2_device, E) -> *mut rs2_sensor_list;
    rs2_get_sensors_count: fn(*const rs2_sensor_list, E) -> c_int;
    rs2_delete_sensor_list: fn(*mut rs2_sensor_list);
    rs2_create_sensor: fn(*const rs2_sensor_list, c_int, E) -> *mut rs2_sensor;
    rs2_delete_sensor: fn(*mut rs2_sensor);
    rs2_is_sensor_extendable_to: fn(*const rs2_sensor, rs2_enum, E) -> c_int;
    rs2_get_depth_scale: fn(*mut rs2_sensor, E) -> f32;
    rs2_get_stream_profiles: fn(*mut rs2_sensor, E) -> *mut rs2_stream_profile_list;
    rs2_get_stream_profiles_count: fn(*const rs2_stream_profile_list, E) -> c_int;
    rs2_get_stream_profile: fn(*const rs2_stream_profile_list, c_int, E) -> *const rs2_stream_profile;
    rs2_delete_stream_profiles_list: fn(*mut rs2_stream_profile_list);
    rs2_get_stream_profile_data: fn(
        *const rs2_stream_profile,
        *mut rs2_enum,
        *mut rs2_enum,
        *mut c_int,
        *mut c_int,
        *mut c_int,
        E
    );
    rs2_get_video_stream_resolution: fn(*const rs2_stream_profile, *mut c_int, *mut c_int, E);
    rs2_get_video_stream_intrinsics: fn(*const rs2_stream_profile, *mut rs2_intrinsics, E);
    rs2_open: fn(*mut rs2_sensor, *const rs2_stream_profile, E);
    rs2_close: fn(*const rs2_sensor, E);
    rs2_start_queue: fn(*const rs2_sensor, *mut rs2_frame_queue, E);
    rs2_stop: fn(*const rs2_sensor, E);
    rs2_create_frame_queue: fn(c_int, E) -> *mut rs2_frame_queue;
    rs2_delete_frame_queue: fn(*mut rs2_frame_queue);
    rs2_try_wait_for_frame: fn(*mut rs2_frame_queue, c_uint, *mut *mut rs2_frame, E) -> c_int;
    rs2_release_frame: fn(*mut rs2_frame);
    rs2_get_frame_width: fn(*const rs2_frame, E) -> c_int;
    rs2_get_frame_height: fn(*const rs2_frame, E) -> c_int;
    rs2_get_frame_stride_in_bytes: fn(*const rs2_frame, E) -> c_int;
    rs2_get_frame_bits_per_pixel: fn(*const rs2_frame, E) -> c_int;
    rs2_get_frame_data: fn(*const rs2_frame, E) -> *const c_void;
    rs2_get_frame_timestamp: fn(*const rs2_frame, E) -> f64;
    rs2_get_frame_timestamp_domain: fn(*const rs2_frame, E) -> rs2_enum;
    rs2_get_frame_number: fn(*const rs2_frame, E) -> c_ulonglong;
    rs2_is_frame_extendable_to: fn(*const rs2_frame, rs2_enum, E) -> c_int;
    rs2_depth_frame_get_units: fn(*const rs2_frame, E) -> f32;
    rs2_create_software_device: fn(E) -> *mut rs2_device;
    rs2_software_device_add_sensor: fn(*mut rs2_device, *const c_char, E) -> *mut rs2_sensor;
    rs2_software_device_register_info: fn(*mut rs2_device, rs2_enum, *const c_char, E);
    rs2_software_sensor_add_video_stream: fn(*mut rs2_sensor, rs2_video_stream, E) -> *mut rs2_stream_profile;
    rs2_software_sensor_add_read_only_option: fn(*mut rs2_sensor, rs2_enum, f32, E);
    rs2_software_sensor_on_video_frame: fn(*mut rs2_sensor, rs2_software_video_frame, E);
}
