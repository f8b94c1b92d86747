//! 16-bit PNG depth frames (the format RealSense tools and most datasets write).
use psgrasp_geometry::{DepthError, DepthImage, FrameSize};
use std::fs::File;
use std::io::{BufReader, BufWriter, Read};
use std::path::Path;

/// Errors reading or writing depth PNGs. Each message names its cause, which is therefore not
/// also the [`source`](std::error::Error::source) (`{:#}` would print it twice).
#[derive(Debug, thiserror::Error)]
pub enum DepthPngError {
    /// The file could not be opened or created.
    #[error("depth png {path}: {error}")]
    Io {
        /// The file.
        path: String,
        /// The cause.
        error: std::io::Error,
    },
    /// The PNG stream is malformed.
    #[error("decoding depth png: {0}")]
    Decode(png::DecodingError),
    /// Writing the PNG stream failed.
    #[error("encoding depth png: {0}")]
    Encode(png::EncodingError),
    /// The PNG is not single-channel 16-bit.
    #[error("depth png must be 16-bit grayscale, got {color:?} at {bits} bits")]
    UnsupportedFormat {
        /// Colour type found.
        color: png::ColorType,
        /// Bits per sample found.
        bits: u8,
    },
    /// Bad unit, pixel count or frame size (the header's size is refused before decoding).
    #[error(transparent)]
    Depth(#[from] DepthError),
}

impl From<png::DecodingError> for DepthPngError {
    fn from(e: png::DecodingError) -> Self {
        Self::Decode(e)
    }
}

impl From<png::EncodingError> for DepthPngError {
    fn from(e: png::EncodingError) -> Self {
        Self::Encode(e)
    }
}

/// Reads a 16-bit grayscale PNG whose counts are `unit_m` metres each (0.001 for millimetres);
/// count 0 becomes depth 0 (no measurement). Any frame size within [`FrameSize::Bounded`] is
/// accepted; [`load_depth_png_sized`] holds the frame to a camera's size.
pub fn load_depth_png(path: impl AsRef<Path>, unit_m: f32) -> Result<DepthImage, DepthPngError> {
    load_depth_png_sized(path, unit_m, FrameSize::Bounded)
}

/// [`load_depth_png`] for frames of `size`: the PNG header's width and height are checked
/// before a pixel is decoded or a buffer allocated.
pub fn load_depth_png_sized(
    path: impl AsRef<Path>,
    unit_m: f32,
    size: FrameSize,
) -> Result<DepthImage, DepthPngError> {
    check_unit(unit_m)?;
    let path = path.as_ref();
    let file = File::open(path).map_err(|error| DepthPngError::Io {
        path: path.display().to_string(),
        error,
    })?;
    decode(BufReader::new(file), unit_m, size)
}

/// [`load_depth_png_sized`] for a PNG already in memory (a frame received whole, a fuzz input).
pub fn decode_depth_png(
    bytes: &[u8],
    unit_m: f32,
    size: FrameSize,
) -> Result<DepthImage, DepthPngError> {
    check_unit(unit_m)?;
    decode(bytes, unit_m, size)
}

fn check_unit(unit_m: f32) -> Result<(), DepthPngError> {
    if unit_m.is_finite() && unit_m > 0.0 {
        Ok(())
    } else {
        Err(DepthError::BadUnit(unit_m).into())
    }
}

fn decode(stream: impl Read, unit_m: f32, size: FrameSize) -> Result<DepthImage, DepthPngError> {
    let mut decoder = png::Decoder::new(stream);
    decoder.set_transformations(png::Transformations::IDENTITY);
    let mut reader = decoder.read_info()?;
    let info = reader.info();
    let (width, height) = (info.width, info.height);
    // From the header alone, before the pixel buffer exists.
    size.check(u64::from(width), u64::from(height))?;
    if info.color_type != png::ColorType::Grayscale || info.bit_depth != png::BitDepth::Sixteen {
        return Err(DepthPngError::UnsupportedFormat {
            color: info.color_type,
            bits: info.bit_depth as u8,
        });
    }
    let mut buf = vec![0u8; reader.output_buffer_size()];
    let frame = reader.next_frame(&mut buf)?;
    let metres: Vec<f32> = buf[..frame.buffer_size()]
        .chunks_exact(2)
        .map(|b| f32::from(u16::from_be_bytes([b[0], b[1]])) * unit_m)
        .collect();
    Ok(DepthImage::from_metres(width, height, metres)?)
}

/// Writes `depth` as a 16-bit grayscale PNG in counts of `unit_m` metres (invalid pixels → 0,
/// values beyond 65535 counts saturate).
pub fn save_depth_png(
    path: impl AsRef<Path>,
    depth: &DepthImage,
    unit_m: f32,
) -> Result<(), DepthPngError> {
    check_unit(unit_m)?;
    let expected = depth.width as usize * depth.height as usize;
    if depth.data.len() != expected || depth.width == 0 || depth.height == 0 {
        return Err(DepthError::SizeMismatch {
            got: depth.data.len(),
            expected,
            width: depth.width,
            height: depth.height,
        }
        .into());
    }
    let path = path.as_ref();
    let file = File::create(path).map_err(|error| DepthPngError::Io {
        path: path.display().to_string(),
        error,
    })?;
    let mut encoder = png::Encoder::new(BufWriter::new(file), depth.width, depth.height);
    encoder.set_color(png::ColorType::Grayscale);
    encoder.set_depth(png::BitDepth::Sixteen);
    let mut writer = encoder.write_header()?;
    let bytes: Vec<u8> = depth
        .to_u16(unit_m)
        .iter()
        .flat_map(|v| v.to_be_bytes())
        .collect();
    writer.write_image_data(&bytes)?;
    writer.finish()?;
    Ok(())
}
