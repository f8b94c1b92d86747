//! `psgrasp inspect`: a PNG of a scene's depth image with its labelled grasps drawn on it.
use crate::dataset::SceneRecord;
use crate::DatagenError;
use nalgebra::Point3;
use psgrasp_geometry::depth::is_valid_depth;
use std::path::Path;

/// An RGB image.
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
    fn put(&mut self, x: i64, y: i64, c: [u8; 3]) {
        if x >= 0 && y >= 0 && (x as u32) < self.width && (y as u32) < self.height {
            let i = 3 * (y as usize * self.width as usize + x as usize);
            self.data[i..i + 3].copy_from_slice(&c);
        }
    }

    fn line(&mut self, a: (f32, f32), b: (f32, f32), c: [u8; 3]) {
        let (x0, y0, x1, y1) = (
            a.0.round() as i64,
            a.1.round() as i64,
            b.0.round() as i64,
            b.1.round() as i64,
        );
        let (dx, dy) = ((x1 - x0).abs(), -(y1 - y0).abs());
        let (sx, sy) = (if x0 < x1 { 1 } else { -1 }, if y0 < y1 { 1 } else { -1 });
        let (mut x, mut y, mut err) = (x0, y0, dx + dy);
        for _ in 0..4096 {
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

    fn dot(&mut self, p: (f32, f32), c: [u8; 3]) {
        for dy in -1..=1 {
            for dx in -1..=1 {
                self.put(p.0.round() as i64 + dx, p.1.round() as i64 + dy, c);
            }
        }
    }

    /// Encodes as PNG.
    pub fn write_png(&self, path: &Path) -> Result<(), DatagenError> {
        let io = |error: std::io::Error| DatagenError::Io {
            path: path.to_path_buf(),
            error,
        };
        let file = std::fs::File::create(path).map_err(io)?;
        let mut enc = png::Encoder::new(std::io::BufWriter::new(file), self.width, self.height);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        let png_err = |e: png::EncodingError| DatagenError::Png {
            path: path.to_path_buf(),
            reason: e.to_string(),
        };
        let mut writer = enc.write_header().map_err(png_err)?;
        writer.write_image_data(&self.data).map_err(png_err)?;
        writer.finish().map_err(png_err)
    }
}

/// Renders the depth image (near = bright) with up to `max_grasps` grasp configurations drawn:
/// the contact pair as a line coloured by quality (red at 0.5 → green at 1), the first contact as
/// a dot, and the most downward collision-free approach as a blue line from the grasp centre to
/// the approach point.
pub fn render_inspection(
    record: &SceneRecord,
    max_grasps: usize,
    use_input_depth: bool,
) -> RgbImage {
    let depth = if use_input_depth {
        &record.depth
    } else {
        &record.depth_clean
    };
    let (w, h) = (depth.width, depth.height);
    let valid: Vec<f32> = depth
        .data
        .iter()
        .copied()
        .filter(|d| is_valid_depth(*d))
        .collect();
    let lo = valid.iter().copied().fold(f32::INFINITY, f32::min);
    let hi = valid.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    let span = (hi - lo).max(1e-6);
    let mut img = RgbImage {
        width: w,
        height: h,
        data: vec![0; 3 * w as usize * h as usize],
    };
    for (i, d) in depth.data.iter().enumerate() {
        if is_valid_depth(*d) {
            let g = (235.0 - 195.0 * (d - lo) / span).clamp(0.0, 255.0) as u8;
            img.data[3 * i..3 * i + 3].copy_from_slice(&[g, g, g]);
        }
    }
    let camera = record.meta.camera;
    let from_ws = camera.workspace_from_camera.inverse();
    let project = |p: &Point3<f32>| camera.intrinsics.project(&(from_ws * p));
    let n = record.labels.len();
    let take = max_grasps.min(n);
    let gripper = record.meta.gripper;
    for k in 0..take {
        let l = &record.labels[k * n / take.max(1)];
        let t = ((l.quality - 0.5) / 0.5).clamp(0.0, 1.0);
        let colour = [(255.0 * (1.0 - t)) as u8, (255.0 * t) as u8, 0];
        let (Some(a), Some(b)) = (project(&l.contact), project(&l.second_contact())) else {
            continue;
        };
        img.line(a, b, colour);
        // The collision-free approach closest to straight down (middle indices).
        let mid = (psgrasp_geometry::N_APPROACHES as f32 - 1.0) / 2.0;
        if let Some(i) = (0..psgrasp_geometry::N_APPROACHES)
            .filter(|&i| l.collision_free[i])
            .min_by(|&x, &y| (x as f32 - mid).abs().total_cmp(&(y as f32 - mid).abs()))
        {
            let g = l.grasp(i);
            if let (Some(c), Some(tp)) =
                (project(&g.center()), project(&g.approach_point(&gripper)))
            {
                img.line(c, tp, [40, 90, 255]);
            }
        }
        img.dot(a, colour);
    }
    img
}
