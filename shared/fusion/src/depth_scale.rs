//! Depth-scale correction against the known bin.
//!
//! A depth camera's range can be off by one factor over the whole frame (drift of a stereo
//! baseline or a stale calibration; the "dex" noise model of VGN, GIGA and our datasets draws it
//! per frame from Gamma(1000, 0.001): σ ≈ 3 %, ±20 mm at 0.7 m, enough to put every fingertip
//! above or into the object). The bin's floor and inner walls are known surfaces in the workspace
//! frame: a pixel that sees them measures `s · d_bin`, a pixel on an object in front of them less.
//! [`estimate_depth_scale`] takes the median ratio `d / d_bin` of each small pixel block (which
//! averages out per-pixel noise) and finds `s` as the farthest well-supported peak of these
//! ratios; [`correct_depth_scale`] divides the frame by it.
use crate::FusionError;
use psgrasp_geometry::{depth::is_valid_depth, BinModel, CameraModel, DepthImage};
use serde::{Deserialize, Serialize};

/// Settings of the depth-scale correction.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DepthScaleConfig {
    /// Estimate and correct the scale of every frame.
    pub enabled: bool,
    /// Side of the square pixel blocks whose median ratio is one sample. Default 16.
    pub block_pixels: u32,
    /// Largest scale error searched, as a fraction (ratios in `[1 − d, 1 + d]`). Default 0.12.
    pub max_deviation: f32,
    /// Width of the ratio histogram's bins. Default 0.0005.
    pub bin_width: f32,
    /// Half-width of the window a peak's support is summed over. Default 0.002.
    pub peak_halfwidth: f32,
    /// Share of the blocks that see into the bin a peak must gather to count as the bin's
    /// surface. Default 0.05.
    pub min_support: f32,
    /// Corrections smaller than this (|s − 1|) are not applied: a calibrated camera's frames
    /// stay bit for bit as they are. Default 0.002.
    pub min_correction: f32,
}

impl Default for DepthScaleConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            block_pixels: 16,
            max_deviation: 0.12,
            bin_width: 0.0005,
            peak_halfwidth: 0.002,
            min_support: 0.05,
            min_correction: 0.002,
        }
    }
}

impl DepthScaleConfig {
    /// Checks every field.
    pub fn validate(&self) -> Result<(), FusionError> {
        let bad = |m| Err(FusionError::InvalidConfig(m));
        if !(1..=64).contains(&self.block_pixels) {
            return bad("depth_scale.block_pixels must be in 1..=64");
        }
        if !(self.max_deviation > 0.0 && self.max_deviation < 0.5) {
            return bad("depth_scale.max_deviation must lie in (0, 0.5)");
        }
        if !(self.bin_width > 0.0 && self.bin_width <= 0.1 * self.max_deviation) {
            return bad("depth_scale.bin_width must lie in (0, max_deviation / 10]");
        }
        if !(self.peak_halfwidth >= 0.0 && self.peak_halfwidth < self.max_deviation) {
            return bad("depth_scale.peak_halfwidth must lie in [0, max_deviation)");
        }
        if !(self.min_support > 0.0 && self.min_support <= 1.0) {
            return bad("depth_scale.min_support must lie in (0, 1]");
        }
        if !(self.min_correction >= 0.0 && self.min_correction < self.max_deviation) {
            return bad("depth_scale.min_correction must lie in [0, max_deviation)");
        }
        Ok(())
    }
}

/// The scale found in one frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DepthScale {
    /// Measured depth / true depth (1 = calibrated).
    pub scale: f32,
    /// Share of the counted blocks in the bin's peak.
    pub support: f32,
    /// Blocks counted: at least half their pixels see into the bin's opening with a valid depth.
    pub blocks: usize,
}

/// Depth (along the optical axis) at which the ray through pixel `(u, v)` leaves the empty bin
/// through its floor or an inner wall; `None` when the ray does not pass the bin's opening.
fn empty_bin_depth(camera: &CameraModel, bin: &BinModel, u: f32, v: f32) -> Option<f32> {
    let k = &camera.intrinsics;
    let iso = &camera.workspace_from_camera;
    // Camera-frame direction with unit z: the ray parameter is the depth.
    let dir = iso.rotation * nalgebra::Vector3::new((u - k.cx) / k.fx, (v - k.cy) / k.fy, 1.0);
    let o = iso.translation.vector;
    if dir.z >= -1e-6 || o.z <= bin.rim_z() {
        return None;
    }
    let c = bin.floor_center;
    let [lx, ly, _] = bin.inner_size_m;
    let (x0, x1, y0, y1) = (
        c.x - 0.5 * lx,
        c.x + 0.5 * lx,
        c.y - 0.5 * ly,
        c.y + 0.5 * ly,
    );
    let t_rim = (bin.rim_z() - o.z) / dir.z;
    let (rx, ry) = (o.x + t_rim * dir.x, o.y + t_rim * dir.y);
    if !(rx > x0 && rx < x1 && ry > y0 && ry < y1) {
        return None;
    }
    let mut t = (c.z - o.z) / dir.z;
    let exit = |o: f32, d: f32, lo: f32, hi: f32| {
        if d > 1e-9 {
            (hi - o) / d
        } else if d < -1e-9 {
            (lo - o) / d
        } else {
            f32::INFINITY
        }
    };
    t = t
        .min(exit(o.x, dir.x, x0, x1))
        .min(exit(o.y, dir.y, y0, y1));
    (t.is_finite() && t > 0.0).then_some(t)
}

/// Estimates the frame's depth scale from the pixels that see into the bin. `None` when no
/// ratio peak gathers [`DepthScaleConfig::min_support`] of them (too little of the bin visible,
/// or a scale error beyond [`DepthScaleConfig::max_deviation`]).
pub fn estimate_depth_scale(
    depth: &DepthImage,
    camera: &CameraModel,
    bin: &BinModel,
    cfg: &DepthScaleConfig,
) -> Result<Option<DepthScale>, FusionError> {
    cfg.validate()?;
    camera.validate()?;
    crate::check_frame(depth, &camera.intrinsics)?;
    let (lo, hi) = (1.0 - cfg.max_deviation, 1.0 + cfg.max_deviation);
    let bins = ((hi - lo) / cfg.bin_width).ceil() as usize;
    let mut histogram = vec![0u32; bins];
    let mut ratios = Vec::new();
    let mut blocks = 0usize;
    let b = cfg.block_pixels as usize;
    let (w, h) = (depth.width as usize, depth.height as usize);
    let mut in_block = Vec::with_capacity(b * b);
    for by in (0..h).step_by(b) {
        for bx in (0..w).step_by(b) {
            in_block.clear();
            // Every second pixel each way: the block median averages as well, at a quarter of
            // the cost.
            for v in (by..(by + b).min(h)).step_by(2) {
                for u in (bx..(bx + b).min(w)).step_by(2) {
                    let d = depth.data[v * w + u];
                    if !is_valid_depth(d) {
                        continue;
                    }
                    if let Some(expected) = empty_bin_depth(camera, bin, u as f32, v as f32) {
                        in_block.push(d / expected);
                    }
                }
            }
            let sampled = b.div_ceil(2) * b.div_ceil(2);
            if in_block.is_empty() || 2 * in_block.len() < sampled {
                continue;
            }
            blocks += 1;
            let mid = in_block.len() / 2;
            let r = *in_block.select_nth_unstable_by(mid, f32::total_cmp).1;
            if r >= lo && r < hi {
                histogram[(((r - lo) / cfg.bin_width) as usize).min(bins - 1)] += 1;
                ratios.push(r);
            }
        }
    }
    if blocks == 0 {
        return Ok(None);
    }
    // Support of each bin: the counts within ±peak_halfwidth (prefix sums).
    let half = (cfg.peak_halfwidth / cfg.bin_width).round() as usize;
    let mut prefix = vec![0u64; bins + 1];
    for (i, &h) in histogram.iter().enumerate() {
        prefix[i + 1] = prefix[i] + u64::from(h);
    }
    let support = |i: usize| prefix[(i + half + 1).min(bins)] - prefix[i.saturating_sub(half)];
    let need = (cfg.min_support * blocks as f32).ceil().max(1.0) as u64;
    // Nothing lies behind the bin's surfaces: its peak is the farthest one with enough support.
    // From the top, find the first bin with enough support, then climb to the local maximum.
    let Some(mut peak) = (0..bins).rev().find(|&i| support(i) >= need) else {
        return Ok(None);
    };
    while peak > 0 && support(peak - 1) >= support(peak) {
        peak -= 1;
    }
    let centre = lo + (peak as f32 + 0.5) * cfg.bin_width;
    let window = (half as f32 + 0.5) * cfg.bin_width;
    let mut near: Vec<f32> = ratios
        .into_iter()
        .filter(|r| (r - centre).abs() <= window)
        .collect();
    if near.is_empty() {
        return Ok(None);
    }
    near.sort_by(f32::total_cmp);
    let scale = near[near.len() / 2];
    Ok(Some(DepthScale {
        scale,
        support: support(peak) as f32 / blocks as f32,
        blocks,
    }))
}

/// Estimates the frame's scale and divides every valid depth by it when it is off by at least
/// [`DepthScaleConfig::min_correction`]. Returns the estimate (`None`: nothing to go by, the frame
/// is unchanged) and whether it was applied. Does nothing when the correction is disabled.
pub fn correct_depth_scale(
    depth: &mut DepthImage,
    camera: &CameraModel,
    bin: &BinModel,
    cfg: &DepthScaleConfig,
) -> Result<(Option<DepthScale>, bool), FusionError> {
    if !cfg.enabled {
        return Ok((None, false));
    }
    let estimate = estimate_depth_scale(depth, camera, bin, cfg)?;
    let apply = estimate.is_some_and(|e| (e.scale - 1.0).abs() >= cfg.min_correction);
    if let (true, Some(e)) = (apply, estimate) {
        let inv = 1.0 / e.scale;
        for d in depth.data.iter_mut().filter(|d| is_valid_depth(**d)) {
            *d *= inv;
        }
    }
    Ok((estimate, apply))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;
    use psgrasp_geometry::CameraIntrinsics;

    /// The empty default bin seen from 0.7 m above its rim, scaled by `s`, with a flat box
    /// 40 mm high on the floor under the first `covered` of the image's width.
    fn frame(s: f32, covered: f32) -> (DepthImage, CameraModel, BinModel) {
        let bin = BinModel::default();
        let eye = Point3::new(bin.floor_center.x, bin.floor_center.y, bin.rim_z() + 0.7);
        let camera = CameraModel::top_down(CameraIntrinsics::default_640x480(), eye);
        let k = camera.intrinsics;
        let mut data = vec![0.0; k.pixel_count()];
        for v in 0..k.height {
            for u in 0..k.width {
                if let Some(d) = empty_bin_depth(&camera, &bin, u as f32, v as f32) {
                    let on_box = (u as f32) < covered * k.width as f32;
                    let floor = bin.rim_z() + 0.7 - bin.floor_center.z;
                    let d = if on_box && (d - floor).abs() < 1e-4 {
                        d - 0.04
                    } else {
                        d
                    };
                    data[(v * k.width + u) as usize] = s * d;
                }
            }
        }
        (
            DepthImage::from_metres(k.width, k.height, data).unwrap(),
            camera,
            bin,
        )
    }

    #[test]
    fn the_bins_scale_is_found_behind_an_object_covering_most_of_it() {
        let cfg = DepthScaleConfig {
            enabled: true,
            ..DepthScaleConfig::default()
        };
        for s in [0.93f32, 0.99, 1.0, 1.04, 1.11] {
            let (mut depth, camera, bin) = frame(s, 0.9);
            let e = estimate_depth_scale(&depth, &camera, &bin, &cfg)
                .unwrap()
                .unwrap();
            assert!((e.scale - s).abs() < 1e-4, "{s}: {e:?}");
            // The box top (40 mm closer) covers about half of what sees into the bin; the bin's
            // surfaces behind it are the farther peak and win.
            assert!(e.support > 0.3 && e.support < 0.6, "{e:?}");
            let (_, applied) = correct_depth_scale(&mut depth, &camera, &bin, &cfg).unwrap();
            assert_eq!(applied, s != 1.0);
            let (fixed, _, _) = frame(1.0, 0.9);
            for (a, b) in depth.data.iter().zip(&fixed.data) {
                assert!((a - b).abs() < 1e-4 * b.max(1.0));
            }
        }
    }

    #[test]
    fn bad_settings_are_refused() {
        let ok = DepthScaleConfig::default();
        assert!(ok.validate().is_ok());
        for bad in [
            DepthScaleConfig {
                block_pixels: 0,
                ..ok
            },
            DepthScaleConfig {
                max_deviation: 0.0,
                ..ok
            },
            DepthScaleConfig {
                bin_width: 0.1,
                ..ok
            },
            DepthScaleConfig {
                min_support: 0.0,
                ..ok
            },
            DepthScaleConfig {
                min_correction: f32::NAN,
                ..ok
            },
        ] {
            assert!(bad.validate().is_err(), "{bad:?}");
        }
    }
}
