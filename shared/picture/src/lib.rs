//! Pictures for people: a depth image in grey (near = bright) with grasps drawn on it, written
//! as an 8-bit RGB PNG. `psgrasp detect --png`, `psgrasp demo --png` and `psgrasp inspect` draw
//! with it.
#![warn(missing_docs)]
use nalgebra::{Isometry3, Point3};
use psgrasp_geometry::depth::is_valid_depth;
use psgrasp_geometry::{CameraModel, DepthImage, GripperModel};
use std::path::{Path, PathBuf};

/// Writing a picture failed.
#[derive(Debug, thiserror::Error)]
pub enum PictureError {
    /// The file could not be created or written.
    #[error("writing {path}: {error}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        error: std::io::Error,
    },
    /// PNG encoding failed.
    #[error("encoding {path} as PNG: {reason}")]
    Png {
        /// The file.
        path: PathBuf,
        /// The encoder's message.
        reason: String,
    },
}

/// Depth steps told apart in pictures, metres: finer than any object's relief, coarser than the
/// noise of a depth camera on a flat surface.
pub const DEPTH_STEP_M: f32 = 0.003;

/// An RGB colour.
pub type Rgb = [u8; 3];

/// An 8-bit RGB image.
#[derive(Debug, Clone, PartialEq)]
pub struct RgbImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Row-major RGB bytes.
    pub data: Vec<u8>,
}

impl RgbImage {
    /// A black image.
    pub fn new(width: u32, height: u32) -> Self {
        Self {
            width,
            height,
            data: vec![0; 3 * width as usize * height as usize],
        }
    }

    /// `depth` in grey, near = bright, no measurement black. The grey level is the depth's rank
    /// among the frame's valid depths, in steps of [`DEPTH_STEP_M`] (histogram equalisation): a
    /// frame that sees both the objects and a far background keeps the objects' relief visible,
    /// and sensor noise on a flat floor stays within one step instead of turning into speckle.
    pub fn from_depth(depth: &DepthImage) -> Self {
        let step = |d: f32| (d / DEPTH_STEP_M).floor() as i64;
        let mut sorted: Vec<i64> = depth
            .data
            .iter()
            .filter(|d| is_valid_depth(**d))
            .map(|d| step(*d))
            .collect();
        sorted.sort_unstable();
        let n = sorted.len().max(1) as f32;
        let mut img = Self::new(depth.width, depth.height);
        for (i, d) in depth.data.iter().enumerate() {
            if is_valid_depth(*d) {
                let q = step(*d);
                let rank = sorted.partition_point(|x| *x < q) as f32;
                let g = (235.0 - 195.0 * rank / n).clamp(0.0, 255.0) as u8;
                img.data[3 * i..3 * i + 3].copy_from_slice(&[g, g, g]);
            }
        }
        img
    }

    /// The colour at pixel (`x`, `y`); `None` outside.
    pub fn get(&self, x: u32, y: u32) -> Option<Rgb> {
        (x < self.width && y < self.height).then(|| {
            let i = 3 * (y as usize * self.width as usize + x as usize);
            [self.data[i], self.data[i + 1], self.data[i + 2]]
        })
    }

    /// Sets pixel (`x`, `y`) if it lies inside.
    pub fn put(&mut self, x: i64, y: i64, c: Rgb) {
        if x >= 0 && y >= 0 && (x as u32) < self.width && (y as u32) < self.height {
            let i = 3 * (y as usize * self.width as usize + x as usize);
            self.data[i..i + 3].copy_from_slice(&c);
        }
    }

    /// A one-pixel line from `a` to `b` (pixel coordinates), clipped to the image.
    pub fn line(&mut self, a: (f32, f32), b: (f32, f32), c: Rgb) {
        let finite = |p: (f32, f32)| p.0.is_finite() && p.1.is_finite();
        if !finite(a) || !finite(b) {
            return;
        }
        let (x0, y0, x1, y1) = (
            a.0.round() as i64,
            a.1.round() as i64,
            b.0.round() as i64,
            b.1.round() as i64,
        );
        let (dx, dy) = ((x1 - x0).abs(), -(y1 - y0).abs());
        let (sx, sy) = (if x0 < x1 { 1 } else { -1 }, if y0 < y1 { 1 } else { -1 });
        let (mut x, mut y, mut err) = (x0, y0, dx + dy);
        // Bounded: a segment longer than the image's diagonal twice over is cut.
        let most = 2 * (self.width as i64 + self.height as i64);
        for _ in 0..most.max(16) {
            self.put(x, y, c);
            if x == x1 && y == y1 {
                break;
            }
            let e2 = 2 * err;
            if e2 >= dy {
                err += dy;
                x += sx;
            }
            if e2 <= dx {
                err += dx;
                y += sy;
            }
        }
    }

    /// A 3×3 dot at `p`.
    pub fn dot(&mut self, p: (f32, f32), c: Rgb) {
        if !(p.0.is_finite() && p.1.is_finite()) {
            return;
        }
        for dy in -1..=1 {
            for dx in -1..=1 {
                self.put(p.0.round() as i64 + dx, p.1.round() as i64 + dy, c);
            }
        }
    }

    /// Writes `n` in a 3×5 pixel font scaled by `scale`, its top-left corner at `at`.
    pub fn number(&mut self, n: u32, at: (f32, f32), scale: u32, c: Rgb) {
        let scale = scale.max(1) as i64;
        let (x0, y0) = (at.0.round() as i64, at.1.round() as i64);
        for (k, digit) in n.to_string().bytes().enumerate() {
            let glyph = DIGITS[(digit - b'0') as usize];
            for (row, bits) in glyph.iter().enumerate() {
                for col in 0..3 {
                    if bits & (0b100 >> col) != 0 {
                        for sy in 0..scale {
                            for sx in 0..scale {
                                self.put(
                                    x0 + (4 * k as i64 + col) * scale + sx,
                                    y0 + row as i64 * scale + sy,
                                    c,
                                );
                            }
                        }
                    }
                }
            }
        }
    }

    /// Encodes the image as a PNG file.
    pub fn write_png(&self, path: &Path) -> Result<(), PictureError> {
        let io = |error: std::io::Error| PictureError::Io {
            path: path.to_path_buf(),
            error,
        };
        let file = std::fs::File::create(path).map_err(io)?;
        let mut enc = png::Encoder::new(std::io::BufWriter::new(file), self.width, self.height);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        let png_err = |e: png::EncodingError| PictureError::Png {
            path: path.to_path_buf(),
            reason: e.to_string(),
        };
        let mut writer = enc.write_header().map_err(png_err)?;
        writer.write_image_data(&self.data).map_err(png_err)?;
        writer.finish().map_err(png_err)
    }
}

/// 3×5 bitmaps of the digits 0–9, one row per entry, bit 2 = left column.
const DIGITS: [[u8; 5]; 10] = [
    [0b111, 0b101, 0b101, 0b101, 0b111],
    [0b010, 0b110, 0b010, 0b010, 0b111],
    [0b111, 0b001, 0b111, 0b100, 0b111],
    [0b111, 0b001, 0b011, 0b001, 0b111],
    [0b101, 0b101, 0b111, 0b001, 0b001],
    [0b111, 0b100, 0b111, 0b001, 0b111],
    [0b111, 0b100, 0b111, 0b101, 0b111],
    [0b111, 0b001, 0b010, 0b010, 0b010],
    [0b111, 0b101, 0b111, 0b101, 0b111],
    [0b111, 0b101, 0b111, 0b001, 0b111],
];

/// A colour for `t` in [0, 1]: red at 0, yellow at ½, green at 1.
pub fn ramp(t: f32) -> Rgb {
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let r = (255.0 * (2.0 - 2.0 * t).min(1.0)) as u8;
    let g = (255.0 * (2.0 * t).min(1.0)) as u8;
    [r, g, 0]
}

/// The twelve edges of a box as corner index pairs ([`psgrasp_geometry::OrientedBox::corners`]
/// numbers corner `i` by its bits: x, y, z).
const BOX_EDGES: [(usize, usize); 12] = [
    (0, 1),
    (2, 3),
    (4, 5),
    (6, 7),
    (0, 2),
    (1, 3),
    (4, 6),
    (5, 7),
    (0, 4),
    (1, 5),
    (2, 6),
    (3, 7),
];

/// Projects workspace points into a camera's image.
pub struct Projector {
    camera: CameraModel,
    camera_from_workspace: Isometry3<f32>,
}

impl Projector {
    /// For `camera`.
    pub fn new(camera: &CameraModel) -> Self {
        Self {
            camera: *camera,
            camera_from_workspace: camera.workspace_from_camera.inverse(),
        }
    }

    /// The pixel of workspace point `p`; `None` behind the camera.
    pub fn pixel(&self, p: &Point3<f32>) -> Option<(f32, f32)> {
        self.camera
            .intrinsics
            .project(&(self.camera_from_workspace * p))
    }
}

/// Draws the outline of an axis-aligned box of the workspace frame (`lo` to `hi`, e.g. the
/// voxel grid: what the detector sees).
pub fn draw_box(
    img: &mut RgbImage,
    projector: &Projector,
    lo: Point3<f32>,
    hi: Point3<f32>,
    colour: Rgb,
) {
    let corner = |i: usize| {
        Point3::new(
            if i & 1 == 0 { lo.x } else { hi.x },
            if i & 2 == 0 { lo.y } else { hi.y },
            if i & 4 == 0 { lo.z } else { hi.z },
        )
    };
    let corners: [Option<(f32, f32)>; 8] = std::array::from_fn(|i| projector.pixel(&corner(i)));
    for (i, j) in BOX_EDGES {
        if let (Some(a), Some(b)) = (corners[i], corners[j]) {
            img.line(a, b, colour);
        }
    }
}

/// Draws a gripper at `workspace_from_gripper` opened to `opening_m`: the outlines of its palm
/// and finger boxes, and a dot at the TCP.
pub fn draw_gripper(
    img: &mut RgbImage,
    projector: &Projector,
    gripper: &GripperModel,
    workspace_from_gripper: &Isometry3<f32>,
    opening_m: f32,
    colour: Rgb,
) {
    for b in gripper.boxes(workspace_from_gripper, opening_m) {
        let corners = b.corners().map(|c| projector.pixel(&c));
        for (i, j) in BOX_EDGES {
            if let (Some(a), Some(b)) = (corners[i], corners[j]) {
                img.line(a, b, colour);
            }
        }
    }
    if let Some(p) = projector.pixel(&Point3::from(workspace_from_gripper.translation.vector)) {
        img.dot(p, colour);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use psgrasp_geometry::CameraIntrinsics;

    #[test]
    fn a_top_down_gripper_is_drawn_where_the_camera_sees_it() {
        let camera = CameraModel::top_down(
            CameraIntrinsics::default_640x480(),
            Point3::new(0.2, 0.2, 0.8),
        );
        let projector = Projector::new(&camera);
        let mut img = RgbImage::new(640, 480);
        // Straight below the camera, approaching downwards.
        let down = Isometry3::face_towards(
            &Point3::new(0.2, 0.2, 0.1),
            &Point3::new(0.2, 0.2, 0.0),
            &nalgebra::Vector3::y(),
        );
        let green = ramp(1.0);
        draw_gripper(
            &mut img,
            &projector,
            &GripperModel::default(),
            &down,
            0.05,
            green,
        );
        let centre = projector.pixel(&Point3::new(0.2, 0.2, 0.1)).unwrap();
        assert!((centre.0 - 320.0).abs() < 2.0 && (centre.1 - 240.0).abs() < 2.0);
        assert_eq!(img.get(320, 240), Some(green), "the TCP dot");
        let lit = img.data.chunks(3).filter(|p| *p == green).count();
        assert!(lit > 500, "box outlines drawn ({lit} pixels)");
        // Nothing far from the gripper.
        assert_eq!(img.get(5, 5), Some([0, 0, 0]));
        assert_eq!(ramp(0.0), [255, 0, 0]);
        assert_eq!(ramp(0.5), [255, 255, 0]);
    }

    #[test]
    fn numbers_and_pngs() {
        let mut img = RgbImage::new(20, 8);
        img.number(10, (0.0, 0.0), 1, [255, 255, 255]);
        assert_eq!(img.get(1, 0), Some([255, 255, 255]), "top of the 1");
        assert_eq!(img.get(5, 2), Some([0, 0, 0]), "hole of the 0");
        let path = std::env::temp_dir().join(format!("psgrasp-picture-{}.png", std::process::id()));
        img.write_png(&path).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(&bytes[1..4], b"PNG");
        std::fs::remove_file(&path).unwrap();
        let err = img
            .write_png(Path::new("/nonexistent/dir/x.png"))
            .unwrap_err();
        assert!(err.to_string().contains("/nonexistent/dir/x.png"));
    }
}
