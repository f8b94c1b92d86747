//! 16-bit PNG depth frames (the format RealSense tools and most datasets write).
use psgrasp_geometry::{DepthError, DepthImage};
use std::fs::File;
use std::io::{BufReader, BufWriter};
use std::path::Path;

/// Errors reading or writing depth PNGs.
#[derive(Debug, thiserror::Error)]
pub enum DepthPngError {
    /// The file could not be opened or created.
    #[error("depth png {path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The cause.
        #[source]
        source: std::io::Error,
    },
    /// The PNG stream is malformed.
    #[error("decoding depth png: {0}")]
    Decode(#[from] png::DecodingError),
    /// Writing the PNG stream failed.
    #[error("encoding depth png: {0}")]
    Encode(#[from] png::EncodingError),
    /// The PNG is not single-channel 16-bit.
    #[error("depth png must be 16-bit grayscale, got {color:?} at {bits} bits")]
    UnsupportedFormat {
        /// Colour type found.
        color: png::ColorType,
        /// Bits per sample found.
        bits: u8,
    },
    /// The image is larger than 8192 pixels on a side.
    #[error("depth png is {width}×{height}, larger than 8192 on a side")]
    TooLarge {
        /// Width.
        width: u32,
        /// Height.
        height: u32,
    },
    /// Bad unit or pixel count.
    #[error(transparent)]
    Depth(#[from] DepthError),
}

/// Reads a 16-bit grayscale PNG whose counts are `unit_m` metres each (0.001 for millimetres);
/// count 0 becomes depth 0 (no measurement).
pub fn load_depth_png(path: impl AsRef<Path>, unit_m: f32) -> Result<DepthImage, DepthPngError> {
    if !(unit_m.is_finite() && unit_m > 0.0) {
        return Err(DepthError::BadUnit(unit_m).into());
    }
    let path = path.as_ref();
    let file = File::open(path).map_err(|source| DepthPngError::Io {
        path: path.display().to_string(),
        source,
    })?;
    let mut decoder = png::Decoder::new(BufReader::new(file));
    decoder.set_transformations(png::Transformations::IDENTITY);
    let mut reader = decoder.read_info()?;
    let info = reader.info();
    let (width, height) = (info.width, info.height);
    if width > 8192 || height > 8192 {
        return Err(DepthPngError::TooLarge { width, height });
    }
    if info.color_type != png::ColorType::Grayscale || info.bit_depth != png::BitDepth::Sixteen {
        return Err(DepthPngError::UnsupportedFormat {
            color: info.color_type,
            bits: info.bit_depth as u8,
        });
    }
    let mut buf = vec![0u8; reader.output_buffer_size()];
    let frame = reader.next_frame(&mut buf)?;
    let bytes = &buf[..frame.buffer_size()];
    let raw: Vec<u16> = bytes
        .chunks_exact(2)
        .map(|b| u16::from_be_bytes([b[0], b[1]]))
        .collect();
    Ok(DepthImage::from_u16(width, height, &raw, unit_m)?)
}

/// Writes `depth` as a 16-bit grayscale PNG in counts of `unit_m` metres (invalid pixels → 0,
/// values beyond 65535 counts saturate).
pub fn save_depth_png(
    path: impl AsRef<Path>,
    depth: &DepthImage,
    unit_m: f32,
) -> Result<(), DepthPngError> {
    if !(unit_m.is_finite() && unit_m > 0.0) {
        return Err(DepthError::BadUnit(unit_m).into());
    }
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
    let file = File::create(path).map_err(|source| DepthPngError::Io {
        path: path.display().to_string(),
        source,
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
