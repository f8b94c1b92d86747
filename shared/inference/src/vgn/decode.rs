//! Decoding VGN's per-voxel outputs into [`GraspConfiguration`]s, following VGN's
//! post-processing (Breyer et al., `vgn/detection.py`: `process` and `select`):
//!
//! 1. **Smoothing**: the quality grid is convolved with a Gaussian of `σ` voxels (separable,
//!    truncated at 4σ, clamped borders as SciPy's `mode="nearest"`; σ = 0 disables it).
//! 2. **Width check**: voxels whose predicted width lies outside `[min_width_m, max_width_m]` (or
//!    whose outputs are degenerate) get quality 0.
//! 3. **Threshold and NMS**: a voxel is a candidate if its quality is positive, at least the
//!    threshold and no voxel in the `n³` window around it has a higher quality (SciPy's
//!    `maximum_filter(size=n)`: offsets `−⌊n/2⌋ ..= ⌈n/2⌉ − 1` per axis; equal maxima all survive).
//! 4. **Ranking**: candidates by quality, descending (ties by voxel index), at most `max_grasps`.
//! 5. **Grasps**: the grasp of voxel `v` has its tool centre point at the voxel centre; the
//!    baseline `b` is re-normalised and the approach `a` orthogonalised against it, then snapped to
//!    the nearest of the 18 discrete approaches of `±b` ([`snap_approach`]). The configuration has
//!    contact `centre − b·w/2`, collision score 1 at the snapped approach and 0 elsewhere (so
//!    selection uses exactly that approach), quality = smoothed quality and `κ = 0`.
use super::VgnConfig;
use crate::model_error::ModelError;
use nalgebra::{Point3, Vector3};
use psgrasp_geometry::{
    approach_vectors, GraspConfiguration, GripperModel, Workspace, N_APPROACHES,
};

/// The network's four output grids for one frame, channel-major over the workspace (voxel index
/// `(i·Y + j)·Z + k`, channel `c` of voxel `v` at `c·N + v`).
#[derive(Debug, Clone, Copy)]
pub struct VgnOutputs<'a> {
    /// `[N]` grasp quality in [0, 1].
    pub quality: &'a [f32],
    /// `[3, N]` unit baselines (sign arbitrary).
    pub baseline: &'a [f32],
    /// `[3, N]` unit approaches, orthogonal to the baselines.
    pub approach: &'a [f32],
    /// `[N]` opening widths in metres.
    pub width: &'a [f32],
}

impl VgnOutputs<'_> {
    /// Checks the lengths against `n` voxels and that every value is finite.
    pub fn check(&self, n: usize) -> Result<(), ModelError> {
        for (name, v, c) in [
            ("quality", self.quality, 1),
            ("baseline", self.baseline, 3),
            ("approach", self.approach, 3),
            ("width", self.width, 1),
        ] {
            if v.len() != c * n {
                return Err(ModelError::GraphInterface {
                    graph: "vgn",
                    reason: format!("output `{name}` has {} values, {c} × {n} expected", v.len()),
                });
            }
            if let Some(index) = v.iter().position(|x| !x.is_finite()) {
                return Err(ModelError::NonFiniteOutput {
                    output: name,
                    index,
                });
            }
        }
        Ok(())
    }

    fn vector(data: &[f32], n: usize, v: usize) -> Vector3<f32> {
        Vector3::new(data[v], data[n + v], data[2 * n + v])
    }
}

/// The decoding settings (from a [`VgnConfig`] and the gripper).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VgnDecodeSettings {
    /// Smallest smoothed quality of a grasp.
    pub quality_threshold: f32,
    /// Standard deviation of the Gaussian smoothing, in voxels; 0 = none.
    pub smoothing_sigma_voxels: f32,
    /// Edge of the non-maximum-suppression window, in voxels (1 = no suppression).
    pub nms_window_voxels: usize,
    /// Narrowest accepted width.
    pub min_width_m: f32,
    /// Widest accepted width (the gripper's maximum opening).
    pub max_width_m: f32,
    /// Most grasps per frame.
    pub max_grasps: usize,
}

impl VgnDecodeSettings {
    /// The settings of `cfg` for `gripper` (widths above its maximum opening are rejected).
    pub fn new(cfg: &VgnConfig, gripper: &GripperModel) -> Self {
        Self {
            quality_threshold: cfg.quality_threshold,
            smoothing_sigma_voxels: cfg.smoothing_sigma_voxels,
            nms_window_voxels: cfg.nms_window_voxels,
            min_width_m: cfg.min_width_m,
            max_width_m: gripper.max_opening_m,
            max_grasps: cfg.max_grasps,
        }
    }
}

/// The normalised Gaussian kernel of `sigma` voxels truncated at 4σ (SciPy's radius
/// `⌊4σ + ½⌋`); `[1]` for σ = 0.
pub fn gaussian_kernel(sigma: f32) -> Vec<f32> {
    if !(sigma > 0.0 && sigma.is_finite()) {
        return vec![1.0];
    }
    let radius = (4.0 * sigma + 0.5) as i64;
    let mut k: Vec<f32> = (-radius..=radius)
        .map(|t| (-(t * t) as f32 / (2.0 * sigma * sigma)).exp())
        .collect();
    let sum: f32 = k.iter().sum();
    k.iter_mut().for_each(|v| *v /= sum);
    k
}

/// Convolves `src` along `axis` of a `dims` grid (workspace layout) with the odd-length `kernel`,
/// borders clamped; `line` is scratch space.
fn convolve_axis(
    src: &[f32],
    dst: &mut [f32],
    dims: [usize; 3],
    axis: usize,
    kernel: &[f32],
    line: &mut Vec<f32>,
) {
    let strides = [dims[1] * dims[2], dims[2], 1];
    let (n, stride) = (dims[axis], strides[axis]);
    let (a, b) = match axis {
        0 => (1, 2),
        1 => (0, 2),
        _ => (0, 1),
    };
    let r = kernel.len() / 2;
    for u in 0..dims[a] {
        for w in 0..dims[b] {
            let base = u * strides[a] + w * strides[b];
            // The line padded by r clamped values on each side.
            line.clear();
            line.extend(std::iter::repeat_n(src[base], r));
            line.extend((0..n).map(|p| src[base + p * stride]));
            line.extend(std::iter::repeat_n(src[base + (n - 1) * stride], r));
            for (p, window) in line.windows(kernel.len()).enumerate() {
                dst[base + p * stride] = window.iter().zip(kernel).map(|(x, k)| x * k).sum();
            }
        }
    }
}

/// Offsets `lo ..= hi` of an `n`-voxel window (SciPy's `maximum_filter(size=n)`, origin 0).
fn window_offsets(n: usize) -> (isize, isize) {
    let n = n.max(1) as isize;
    (-(n / 2), (n - 1) / 2)
}

/// The signed baseline `s·b` (`s = ±1`) and the index `i` maximising `a · approach_vectors(s·b)[i]`:
/// the predicted approach snapped to the nearest of the 18 discrete approaches. `b` is normalised
/// and `a` orthogonalised against it first. The approaches of `−b` are those of `b` in reverse
/// order, so `s = +1` is kept unless `−b` is better by more than rounding (1e-6).
pub fn snap_approach(baseline: &Vector3<f32>, approach: &Vector3<f32>) -> (Vector3<f32>, usize) {
    let b = baseline.normalize();
    let a = approach - b * b.dot(approach);
    let a = a.try_normalize(1e-9).unwrap_or_else(Vector3::zeros);
    let best = |b: &Vector3<f32>| {
        let av = approach_vectors(b);
        let mut best = (f32::NEG_INFINITY, 0);
        for (i, v) in av.iter().enumerate() {
            let d = a.dot(v);
            if d > best.0 {
                best = (d, i);
            }
        }
        best
    };
    let plus = best(&b);
    let minus = best(&-b);
    if minus.0 > plus.0 + 1e-6 {
        (-b, minus.1)
    } else {
        (b, plus.1)
    }
}

/// Decodes VGN outputs frame by frame, keeping its buffers between frames.
#[derive(Debug, Clone)]
pub struct VgnDecoder {
    settings: VgnDecodeSettings,
    kernel: Vec<f32>,
    /// Smoothed, width-checked quality of the last frame.
    quality: Vec<f32>,
    scratch: Vec<f32>,
    line: Vec<f32>,
    /// (quality, voxel) of the last frame's NMS survivors, best first.
    candidates: Vec<(f32, u32)>,
}

impl VgnDecoder {
    /// A decoder for `settings`.
    pub fn new(settings: VgnDecodeSettings) -> Self {
        Self {
            kernel: gaussian_kernel(settings.smoothing_sigma_voxels),
            settings,
            quality: Vec::new(),
            scratch: Vec::new(),
            line: Vec::new(),
            candidates: Vec::new(),
        }
    }

    /// The settings.
    pub fn settings(&self) -> &VgnDecodeSettings {
        &self.settings
    }

    /// The last frame's smoothed quality grid with width-rejected voxels set to 0.
    pub fn processed_quality(&self) -> &[f32] {
        &self.quality
    }

    /// Voxels that passed threshold and NMS in the last frame (before the `max_grasps` cap).
    pub fn candidate_count(&self) -> usize {
        self.candidates.len()
    }

    /// Decodes one frame of `outputs` on `workspace` into `out` (cleared first).
    pub fn decode(
        &mut self,
        workspace: &Workspace,
        outputs: &VgnOutputs<'_>,
        out: &mut Vec<GraspConfiguration>,
    ) -> Result<(), ModelError> {
        out.clear();
        let n = workspace.voxel_count();
        outputs.check(n)?;
        let dims = workspace.dims.map(|d| d as usize);
        self.smooth(outputs.quality, dims);
        self.reject_widths(outputs, n);
        self.select(dims);
        let s = &self.settings;
        self.candidates
            .sort_unstable_by(|x, y| y.0.total_cmp(&x.0).then(x.1.cmp(&y.1)));
        out.reserve(self.candidates.len().min(s.max_grasps));
        for &(q, v) in self.candidates.iter().take(s.max_grasps) {
            let v = v as usize;
            let [i, j, k] = workspace.unindex(v);
            let centre: Point3<f32> = workspace.voxel_center(i, j, k);
            let b = VgnOutputs::vector(outputs.baseline, n, v);
            let a = VgnOutputs::vector(outputs.approach, n, v);
            let (baseline, index) = snap_approach(&b, &a);
            let width = outputs.width[v];
            let mut collision_scores = [0.0; N_APPROACHES];
            collision_scores[index] = 1.0;
            out.push(GraspConfiguration {
                contact: centre - baseline * (0.5 * width),
                baseline,
                collision_scores,
                width,
                quality: q.clamp(0.0, 1.0),
                kappa: 0.0,
                kappa_floor: 0.0,
            });
        }
        Ok(())
    }

    /// `quality` ← the smoothed input (a copy when smoothing is off).
    fn smooth(&mut self, input: &[f32], dims: [usize; 3]) {
        if self.kernel.len() == 1 {
            self.quality.clear();
            self.quality.extend_from_slice(input);
            return;
        }
        self.quality.resize(input.len(), 0.0);
        self.scratch.resize(input.len(), 0.0);
        let (k, line) = (&self.kernel, &mut self.line);
        convolve_axis(input, &mut self.quality, dims, 2, k, line);
        convolve_axis(&self.quality, &mut self.scratch, dims, 1, k, line);
        convolve_axis(&self.scratch, &mut self.quality, dims, 0, k, line);
    }

    /// Sets the quality of voxels with an out-of-range width or a degenerate baseline to 0.
    fn reject_widths(&mut self, outputs: &VgnOutputs<'_>, n: usize) {
        let s = &self.settings;
        for (v, q) in self.quality.iter_mut().enumerate() {
            let w = outputs.width[v];
            let b = VgnOutputs::vector(outputs.baseline, n, v);
            if !(w >= s.min_width_m && w <= s.max_width_m) || b.norm_squared() < 1e-12 {
                *q = 0.0;
            }
        }
    }

    /// `candidates` ← voxels with positive quality ≥ the threshold that are maxima of their
    /// window.
    fn select(&mut self, dims: [usize; 3]) {
        self.candidates.clear();
        let (lo, hi) = window_offsets(self.settings.nms_window_voxels);
        let threshold = self.settings.quality_threshold;
        let q = &self.quality;
        let range = |c: usize, d: usize| {
            let a = (c as isize + lo).max(0) as usize;
            let b = (c as isize + hi).min(d as isize - 1) as usize;
            a..=b
        };
        for (v, &qv) in q.iter().enumerate() {
            if !(qv > 0.0 && qv >= threshold) {
                continue;
            }
            let (i, j, k) = (
                v / (dims[1] * dims[2]),
                (v / dims[2]) % dims[1],
                v % dims[2],
            );
            let is_max = range(i, dims[0]).all(|x| {
                range(j, dims[1]).all(|y| {
                    let row = (x * dims[1] + y) * dims[2];
                    range(k, dims[2]).all(|z| q[row + z] <= qv)
                })
            });
            if is_max {
                self.candidates.push((qv, v as u32));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gaussian_kernel_matches_scipy_truncation() {
        assert_eq!(gaussian_kernel(0.0), vec![1.0]);
        let k = gaussian_kernel(1.0);
        assert_eq!(k.len(), 9);
        assert!((k.iter().sum::<f32>() - 1.0).abs() < 1e-6);
        // scipy.ndimage._gaussian_kernel1d(1.0, 0, 4)[4] = 0.39894...
        assert!((k[4] - 0.398_942_3).abs() < 1e-4, "{}", k[4]);
        assert_eq!(gaussian_kernel(0.5).len(), 5);
    }

    #[test]
    fn smoothing_preserves_constants_and_mass_of_an_interior_impulse() {
        let dims = [7usize, 8, 9];
        let n = dims.iter().product();
        let settings = VgnDecodeSettings {
            quality_threshold: 0.0,
            smoothing_sigma_voxels: 0.7,
            nms_window_voxels: 1,
            min_width_m: 0.0,
            max_width_m: 1.0,
            max_grasps: 10,
        };
        let mut d = VgnDecoder::new(settings);
        d.smooth(&vec![0.25; n], dims);
        assert!(d.quality.iter().all(|v| (v - 0.25).abs() < 1e-6));
        let mut impulse = vec![0.0; n];
        let centre = (3 * dims[1] + 4) * dims[2] + 4;
        impulse[centre] = 1.0;
        d.smooth(&impulse, dims);
        assert!((d.quality.iter().sum::<f32>() - 1.0).abs() < 1e-5);
        let k = gaussian_kernel(0.7);
        let r = k.len() / 2;
        assert!((d.quality[centre] - k[r].powi(3)).abs() < 1e-6);
        // Separable: one step along x weighs k[r+1]·k[r]².
        let nx = centre + dims[1] * dims[2];
        assert!((d.quality[nx] - k[r + 1] * k[r] * k[r]).abs() < 1e-6);
    }

    #[test]
    fn window_offsets_follow_scipy() {
        assert_eq!(window_offsets(1), (0, 0));
        assert_eq!(window_offsets(3), (-1, 1));
        assert_eq!(window_offsets(4), (-2, 1));
        assert_eq!(window_offsets(5), (-2, 2));
    }

    #[test]
    fn approaches_of_the_flipped_baseline_are_reversed() {
        for b in [
            Vector3::new(1.0, 0.0, 0.0),
            Vector3::new(0.3, -0.8, 0.5).normalize(),
            Vector3::new(0.0, 0.6, -0.8),
        ] {
            let plus = approach_vectors(&b);
            let minus = approach_vectors(&-b);
            for i in 0..N_APPROACHES {
                assert!((plus[i] - minus[N_APPROACHES - 1 - i]).norm() < 1e-5);
            }
        }
    }

    #[test]
    fn snapping_returns_the_exact_approach_and_is_within_half_a_step() {
        let b = Vector3::new(0.3, -0.8, 0.5).normalize();
        let av = approach_vectors(&b);
        for (i, a) in av.iter().enumerate() {
            let (sb, idx) = snap_approach(&(b * 2.0), a);
            assert_eq!(sb, b);
            assert_eq!(idx, i);
        }
        // Any in-range approach lands within half the 180°/17 spacing.
        let half_step = std::f32::consts::PI / 17.0 / 2.0 + 1e-4;
        for t in 0..=100 {
            let g = std::f32::consts::FRAC_PI_2 + std::f32::consts::PI * t as f32 / 100.0;
            let rot = nalgebra::Rotation3::from_axis_angle(&nalgebra::Unit::new_normalize(b), g);
            let a = rot * psgrasp_geometry::baseline_perpendicular(&b);
            // Add a component along b: it must be removed before snapping.
            let (sb, idx) = snap_approach(&b, &(a + b * 0.3));
            let snapped = approach_vectors(&sb)[idx];
            assert!(
                snapped.angle(&a) <= half_step,
                "γ {g}: {}",
                snapped.angle(&a)
            );
        }
    }
}
