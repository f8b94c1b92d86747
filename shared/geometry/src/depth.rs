//! Depth images in metres, with conversion from 16-bit millimetre frames.
use crate::CameraIntrinsics;
use serde::{Deserialize, Serialize};

/// Errors for malformed depth data.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum DepthError {
    /// The number of pixels does not match width × height.
    #[error("depth buffer has {got} pixels, expected {expected} ({width}×{height})")]
    SizeMismatch {
        /// Pixels received.
        got: usize,
        /// Pixels expected.
        expected: usize,
        /// Declared width.
        width: u32,
        /// Declared height.
        height: u32,
    },
    /// No pixel carries a valid (finite, positive) depth.
    #[error("depth image has no valid pixel (all zero, NaN or negative)")]
    NoValidPixels,
    /// The depth unit is not a positive finite number.
    #[error("depth unit must be a positive finite number of metres, got {0}")]
    BadUnit(f32),
    /// A depth file's header declares a frame larger than the loader accepts
    /// ([`FrameSize::Bounded`]); refused before any pixel is decoded.
    #[error(
        "depth frame is {width}×{height}, larger than {MAX_IMAGE_SIDE} on a side or \
         {MAX_DEPTH_PIXELS} pixels"
    )]
    TooLarge {
        /// Declared width.
        width: u64,
        /// Declared height.
        height: u64,
    },
    /// A depth file's header declares a frame without pixels.
    #[error("depth frame is {width}×{height}: no pixels")]
    EmptyFrame {
        /// Declared width.
        width: u64,
        /// Declared height.
        height: u64,
    },
    /// A depth file's header declares another size than the camera's ([`FrameSize::Exactly`]);
    /// refused before any pixel is decoded.
    #[error(
        "depth frame is {width}×{height} but the camera is {expected_width}×{expected_height}"
    )]
    WrongSize {
        /// Declared width.
        width: u64,
        /// Declared height.
        height: u64,
        /// The camera's width.
        expected_width: u32,
        /// The camera's height.
        expected_height: u32,
    },
}

/// Longest side of a camera image or depth frame, pixels.
pub const MAX_IMAGE_SIDE: u32 = 8192;

/// Most pixels a depth loader decodes without a camera size to hold the frame to ([`FrameSize::Bounded`]):
/// 4096², 64 MiB as `f32` metres — above every depth camera's resolution, and far below the
/// 8192² (over 500 MiB decoded) a side limit alone would let through.
pub const MAX_DEPTH_PIXELS: u64 = 4096 * 4096;

/// The frame sizes a depth loader accepts, checked against a file's header before any pixel is
/// decoded or allocated.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameSize {
    /// Any size with at least one pixel, at most [`MAX_IMAGE_SIDE`] on a side and
    /// [`MAX_DEPTH_PIXELS`] in all.
    Bounded,
    /// Exactly this size (the camera's, e.g. the intrinsics frames are replayed with).
    Exactly {
        /// Width in pixels.
        width: u32,
        /// Height in pixels.
        height: u32,
    },
}

impl FrameSize {
    /// Exactly the size of `intrinsics`.
    pub fn of(intrinsics: &CameraIntrinsics) -> Self {
        Self::Exactly {
            width: intrinsics.width,
            height: intrinsics.height,
        }
    }

    /// Checks a declared `width × height` (from a file header, before decoding). Also refuses
    /// an empty frame, and for [`FrameSize::Exactly`] anything but that size.
    pub fn check(&self, width: u64, height: u64) -> Result<(), DepthError> {
        let side = u64::from(MAX_IMAGE_SIDE);
        let too_large = width > side || height > side || width * height > MAX_DEPTH_PIXELS;
        match *self {
            FrameSize::Exactly {
                width: w,
                height: h,
            } if (width, height) != (u64::from(w), u64::from(h)) => Err(DepthError::WrongSize {
                width,
                height,
                expected_width: w,
                expected_height: h,
            }),
            FrameSize::Exactly { .. } => Ok(()),
            FrameSize::Bounded if too_large => Err(DepthError::TooLarge { width, height }),
            FrameSize::Bounded if width == 0 || height == 0 => {
                Err(DepthError::EmptyFrame { width, height })
            }
            FrameSize::Bounded => Ok(()),
        }
    }
}

/// A depth image in metres; 0, negative or non-finite values mean "no measurement".
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DepthImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Row-major depth along the optical axis, metres.
    pub data: Vec<f32>,
}

impl DepthImage {
    /// Wraps a metre buffer, checking its size.
    pub fn from_metres(width: u32, height: u32, data: Vec<f32>) -> Result<Self, DepthError> {
        let expected = width as usize * height as usize;
        if data.len() != expected {
            return Err(DepthError::SizeMismatch {
                got: data.len(),
                expected,
                width,
                height,
            });
        }
        Ok(Self {
            width,
            height,
            data,
        })
    }

    /// Converts a 16-bit frame with `unit_m` metres per count (0.001 for millimetres).
    pub fn from_u16(width: u32, height: u32, raw: &[u16], unit_m: f32) -> Result<Self, DepthError> {
        if !(unit_m.is_finite() && unit_m > 0.0) {
            return Err(DepthError::BadUnit(unit_m));
        }
        let data = raw.iter().map(|&d| d as f32 * unit_m).collect();
        Self::from_metres(width, height, data)
    }

    /// Converts to 16-bit counts of `unit_m` metres (0 = invalid), saturating.
    pub fn to_u16(&self, unit_m: f32) -> Vec<u16> {
        self.data
            .iter()
            .map(|&d| {
                if is_valid_depth(d) {
                    (d / unit_m).round().clamp(0.0, 65535.0) as u16
                } else {
                    0
                }
            })
            .collect()
    }

    /// Depth at pixel (u, v).
    pub fn at(&self, u: u32, v: u32) -> f32 {
        self.data[v as usize * self.width as usize + u as usize]
    }

    /// Number of pixels with a usable measurement.
    pub fn valid_count(&self) -> usize {
        self.data.iter().filter(|d| is_valid_depth(**d)).count()
    }

    /// Fails if the image carries no usable measurement.
    pub fn require_valid(&self) -> Result<(), DepthError> {
        if self.valid_count() == 0 {
            Err(DepthError::NoValidPixels)
        } else {
            Ok(())
        }
    }
}

/// True for a finite, positive depth.
#[inline]
pub fn is_valid_depth(d: f32) -> bool {
    d.is_finite() && d > 0.0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_size_limits() {
        let b = FrameSize::Bounded;
        assert!(b.check(640, 480).is_ok());
        assert!(b.check(8192, 2).is_ok());
        assert!(b.check(4096, 4096).is_ok());
        assert!(matches!(
            b.check(8192, 8192),
            Err(DepthError::TooLarge { .. })
        ));
        assert!(matches!(b.check(8193, 1), Err(DepthError::TooLarge { .. })));
        assert!(matches!(
            b.check(u64::MAX, u64::MAX),
            Err(DepthError::TooLarge { .. })
        ));
        assert!(matches!(b.check(0, 5), Err(DepthError::EmptyFrame { .. })));
        let cam = FrameSize::of(&CameraIntrinsics::default_640x480());
        assert!(cam.check(640, 480).is_ok());
        let e = cam.check(480, 640).unwrap_err();
        assert_eq!(
            e.to_string(),
            "depth frame is 480×640 but the camera is 640×480"
        );
    }

    #[test]
    fn size_mismatch_is_an_error() {
        assert!(matches!(
            DepthImage::from_metres(4, 4, vec![1.0; 15]),
            Err(DepthError::SizeMismatch {
                got: 15,
                expected: 16,
                ..
            })
        ));
    }

    #[test]
    fn u16_round_trip_and_invalid_pixels() {
        let img = DepthImage::from_metres(2, 2, vec![0.5, f32::NAN, 0.0, 1.234]).unwrap();
        assert_eq!(img.valid_count(), 2);
        let raw = img.to_u16(0.001);
        assert_eq!(raw, vec![500, 0, 0, 1234]);
        let back = DepthImage::from_u16(2, 2, &raw, 0.001).unwrap();
        assert!((back.at(1, 1) - 1.234).abs() < 1e-6);
        assert!(DepthImage::from_metres(1, 1, vec![f32::NAN])
            .unwrap()
            .require_valid()
            .is_err());
        assert!(DepthImage::from_u16(1, 1, &[1], 0.0).is_err());
    }
}
