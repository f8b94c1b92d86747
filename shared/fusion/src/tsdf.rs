//! The projective TSDF volume and its integration loop.
use crate::normals::{self, NormalScratch};
use crate::{FusionConfig, FusionError, NormalGrid};
use psgrasp_geometry::{
    depth::is_valid_depth, CameraIntrinsics, CameraModel, DepthError, DepthImage, Workspace,
};
use std::sync::Mutex;

/// Voxels of a column projected per batch in the integration loop.
const MAX_COLUMN: usize = 64;

/// What one call of [`TsdfVolume::integrate`] did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct IntegrationStats {
    /// Pixels in the frame.
    pub pixels: usize,
    /// Pixels with a usable depth (finite, positive and inside the configured depth range).
    pub valid_pixels: usize,
    /// Pixels skipped because their depth is NaN, infinite, zero or negative.
    pub invalid_pixels: usize,
    /// Pixels with a finite positive depth outside `[min_depth_m, max_depth_m]`, also skipped.
    pub out_of_range_pixels: usize,
    /// Voxel updates inside the truncation band (|sdf| < truncation).
    pub band_updates: usize,
    /// Voxel updates in free space in front of the band (integrated as +1).
    pub free_updates: usize,
    /// Never-observed voxels this frame marked as occluded (behind the band).
    pub occluded_voxels: usize,
    /// Frames integrated into the volume so far, this one included.
    pub frames_integrated: u32,
}

/// A projective truncated signed distance volume over a [`Workspace`].
///
/// Stores the truncation-normalised signed distance (in [−1, 1], positive in front of the
/// surface) and an integration weight per voxel. Never-observed voxels read +1; voxels seen only
/// from behind the band (occluded or inside objects) read −1 with weight 0, so a later view that
/// observes them overrides the mark.
///
/// Memory: 24 bytes per voxel (6 MiB for 64³), all allocated in [`TsdfVolume::new`]; integration
/// and [`TsdfVolume::write_normal_grid`] allocate nothing afterwards.
pub struct TsdfVolume {
    workspace: Workspace,
    config: FusionConfig,
    tsdf: Vec<f32>,
    weight: Vec<f32>,
    frames: u32,
    /// Scratch of the normal extraction (behind a lock so extraction can take `&self`).
    scratch: Mutex<NormalScratch>,
}

impl std::fmt::Debug for TsdfVolume {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TsdfVolume")
            .field("workspace", &self.workspace)
            .field("config", &self.config)
            .field("frames", &self.frames)
            .finish_non_exhaustive()
    }
}

impl Clone for TsdfVolume {
    fn clone(&self) -> Self {
        Self {
            workspace: self.workspace,
            config: self.config,
            tsdf: self.tsdf.clone(),
            weight: self.weight.clone(),
            frames: self.frames,
            scratch: Mutex::new(NormalScratch::with_capacity(&self.workspace)),
        }
    }
}

impl TsdfVolume {
    /// An empty volume (every voxel unobserved, +1).
    pub fn new(workspace: Workspace, config: &FusionConfig) -> Result<Self, FusionError> {
        workspace.validate()?;
        config.validate()?;
        let n = workspace.voxel_count();
        Ok(Self {
            workspace,
            config: *config,
            tsdf: vec![1.0; n],
            weight: vec![0.0; n],
            frames: 0,
            scratch: Mutex::new(NormalScratch::with_capacity(&workspace)),
        })
    }

    /// Forgets every observation.
    pub fn reset(&mut self) {
        self.tsdf.fill(1.0);
        self.weight.fill(0.0);
        self.frames = 0;
    }

    /// The grid geometry.
    pub fn workspace(&self) -> &Workspace {
        &self.workspace
    }

    /// The configuration in use.
    pub fn config(&self) -> &FusionConfig {
        &self.config
    }

    /// Truncation distance in metres.
    pub fn truncation_m(&self) -> f32 {
        self.config.truncation_voxels * self.workspace.voxel_size_m
    }

    /// Normalised TSDF in workspace index order (see [`crate::NormalGridView::tsdf`]).
    pub fn tsdf(&self) -> &[f32] {
        &self.tsdf
    }

    /// Integration weights in workspace index order (0 = never observed).
    pub fn weights(&self) -> &[f32] {
        &self.weight
    }

    /// Frames integrated since creation or the last [`TsdfVolume::reset`].
    pub fn frames_integrated(&self) -> u32 {
        self.frames
    }

    /// Fuses one depth frame seen by `camera` (pose = `workspace_from_camera`).
    ///
    /// Each voxel centre is projected into the frame (nearest pixel); its signed distance along
    /// the pixel ray, `(depth − z)·‖K⁻¹(u, v, 1)‖`, is truncated to the band and merged into the
    /// voxel's weighted running average. Pixels with NaN, zero, negative or out-of-range depth are
    /// skipped and counted.
    ///
    /// Errors (the volume is left untouched): invalid camera → [`FusionError::Geometry`]; frame
    /// size ≠ intrinsics → [`FusionError::FrameSizeMismatch`]; a data buffer of the wrong length
    /// → [`FusionError::Depth`] (`SizeMismatch`); no usable pixel → `Depth(NoValidPixels)`;
    /// no measured point inside the workspace box → [`FusionError::EmptyView`].
    pub fn integrate(
        &mut self,
        depth: &DepthImage,
        camera: &CameraModel,
    ) -> Result<IntegrationStats, FusionError> {
        camera.validate()?;
        let k = camera.intrinsics;
        crate::check_frame(depth, &k)?;
        let mut stats = self.count_pixels(depth, &k);
        if stats.valid_pixels == 0 {
            if stats.out_of_range_pixels == 0 {
                return Err(DepthError::NoValidPixels.into());
            }
            return Err(FusionError::EmptyView);
        }
        if !self.sees_workspace(depth, camera) {
            return Err(FusionError::EmptyView);
        }
        self.integrate_prepared(depth, camera, &mut stats);
        self.frames = self.frames.saturating_add(1);
        stats.frames_integrated = self.frames;
        Ok(stats)
    }

    /// Counts usable, invalid and out-of-range pixels.
    fn count_pixels(&self, depth: &DepthImage, k: &CameraIntrinsics) -> IntegrationStats {
        let n = k.pixel_count();
        let (lo, hi) = (self.config.min_depth_m, self.config.max_depth_m);
        let (mut valid, mut invalid) = (0usize, 0usize);
        for &d in &depth.data {
            invalid += usize::from(!is_valid_depth(d));
            valid += usize::from(in_range(d, lo, hi));
        }
        IntegrationStats {
            pixels: n,
            valid_pixels: valid,
            invalid_pixels: invalid,
            out_of_range_pixels: n - valid - invalid,
            ..IntegrationStats::default()
        }
    }

    /// True if some usable pixel back-projects into the workspace box. Checks a sparse lattice
    /// first (almost always enough), then every pixel.
    fn sees_workspace(&self, depth: &DepthImage, camera: &CameraModel) -> bool {
        let k = &camera.intrinsics;
        let iso = camera.workspace_from_camera;
        let ext = self.workspace.extent();
        let w = k.width as usize;
        let (lo, hi) = (self.config.min_depth_m, self.config.max_depth_m);
        let inside = |idx: usize| {
            let d = depth.data[idx];
            if !in_range(d, lo, hi) {
                return false;
            }
            let (u, v) = ((idx % w) as f32, (idx / w) as f32);
            let p = iso * k.deproject(u, v, d);
            (0.0..ext.x).contains(&p.x)
                && (0.0..ext.y).contains(&p.y)
                && (0.0..ext.z).contains(&p.z)
        };
        let n = depth.data.len();
        (0..n).step_by(61).any(inside) || (0..n).any(inside)
    }

    /// The hot loop: one pass over all voxels, column by column (z fastest).
    fn integrate_prepared(
        &mut self,
        depth: &DepthImage,
        camera: &CameraModel,
        stats: &mut IntegrationStats,
    ) {
        let k = camera.intrinsics;
        let camera_from_workspace = camera.workspace_from_camera.inverse();
        let r = camera_from_workspace
            .rotation
            .to_rotation_matrix()
            .into_inner();
        let t = camera_from_workspace.translation.vector;
        let s = self.workspace.voxel_size_m;
        let [nx, ny, nz] = self.workspace.dims.map(|d| d as usize);
        let trunc = self.truncation_m();
        let inv_trunc = 1.0 / trunc;
        let max_w = self.config.max_weight;
        let carve = self.config.carve_free_space;
        let inv_falloff = 1.0 / self.config.behind_falloff;
        let min_behind = self.config.behind_min_weight;
        let free_w = self.config.free_space_weight;
        let (fx, fy) = (k.fx, k.fy);
        let (cx, cy) = (k.cx, k.cy);
        let (wu, hu) = (k.width as usize, k.height as usize);
        // Projections within half a pixel of the image are in view; the top-left pixel of the
        // interpolation square is clamped so the square stays inside the image.
        let (u_lo, u_hi) = (-0.5f32, k.width as f32 - 0.5);
        let (v_lo, v_hi) = (-0.5f32, k.height as f32 - 0.5);
        let (u_max, v_max) = (wu.saturating_sub(2) as f32, hu.saturating_sub(2) as f32);
        let (sx, sy) = (usize::from(wu >= 2), if hu >= 2 { wu } else { 0 });
        let w = k.width;
        let bilinear = self.config.bilinear_depth;
        let jump = self.config.max_depth_jump_m;
        let step = [r[(0, 2)] * s, r[(1, 2)] * s, r[(2, 2)] * s];
        let near = 1e-4f32;
        let depth = &depth.data[..];
        let (lo, hi) = (self.config.min_depth_m, self.config.max_depth_m);
        let (mut band, mut free, mut occluded) = (0usize, 0usize, 0usize);
        // Per-column scratch: pixel index (u32::MAX = not in view) and camera z of each voxel.
        let mut pix = [0u32; MAX_COLUMN];
        let mut zs = [0f32; MAX_COLUMN];
        let mut ray = [0f32; MAX_COLUMN];
        let mut frac = [[0f32; 2]; MAX_COLUMN];
        for i in 0..nx {
            for j in 0..ny {
                let (px, py, pz) = ((i as f32 + 0.5) * s, (j as f32 + 0.5) * s, 0.5 * s);
                let base = [
                    r[(0, 0)] * px + r[(0, 1)] * py + r[(0, 2)] * pz + t.x,
                    r[(1, 0)] * px + r[(1, 1)] * py + r[(1, 2)] * pz + t.y,
                    r[(2, 0)] * px + r[(2, 1)] * py + r[(2, 2)] * pz + t.z,
                ];
                let col = (i * ny + j) * nz;
                // Chunks of the column keep the projection branch-free (vectorisable).
                for k0 in (0..nz).step_by(MAX_COLUMN) {
                    let len = MAX_COLUMN.min(nz - k0);
                    for kk in 0..len {
                        let kf = (k0 + kk) as f32;
                        let x = base[0] + kf * step[0];
                        let y = base[1] + kf * step[1];
                        let z = base[2] + kf * step[2];
                        let inv_z = 1.0 / z;
                        let uf = x * inv_z * fx + cx;
                        let vf = y * inv_z * fy + cy;
                        let inside = z > near && uf >= u_lo && uf < u_hi && vf >= v_lo && vf < v_hi;
                        // Clamped, so truncation is a floor; NaN becomes 0.
                        let u0 = uf.max(0.0).min(u_max) as u32;
                        let v0 = vf.max(0.0).min(v_max) as u32;
                        frac[kk] = [
                            (uf - u0 as f32).clamp(0.0, 1.0),
                            (vf - v0 as f32).clamp(0.0, 1.0),
                        ];
                        let index = v0.wrapping_mul(w).wrapping_add(u0);
                        pix[kk] = if inside { index } else { u32::MAX };
                        zs[kk] = z;
                        // Ray length per unit depth through this voxel.
                        ray[kk] = (x * x + y * y + z * z).sqrt() * inv_z;
                    }
                    let tsdf = &mut self.tsdf[col + k0..col + k0 + len];
                    let weight = &mut self.weight[col + k0..col + k0 + len];
                    for kk in 0..len {
                        let p = pix[kk] as usize;
                        if p >= depth.len() {
                            continue;
                        }
                        let [fu, fv] = frac[kk];
                        let corners = [p, p + sx, p + sy, p + sx + sy];
                        let wts = [
                            (1.0 - fu) * (1.0 - fv),
                            fu * (1.0 - fv),
                            (1.0 - fu) * fv,
                            fu * fv,
                        ];
                        let ds = corners.map(|c| depth[c]);
                        // Non-short-circuit `&`: branch-free validity of all four corners.
                        let all_ok = in_range(ds[0], lo, hi)
                            & in_range(ds[1], lo, hi)
                            & in_range(ds[2], lo, hi)
                            & in_range(ds[3], lo, hi);
                        let spread = ds[0].max(ds[1]).max(ds[2].max(ds[3]))
                            - ds[0].min(ds[1]).min(ds[2].min(ds[3]));
                        let d = if bilinear && all_ok && spread <= jump {
                            ds[0] * wts[0] + ds[1] * wts[1] + ds[2] * wts[2] + ds[3] * wts[3]
                        } else {
                            // Nearest usable pixel: the usable corner of largest weight.
                            let mut best = (-1.0f32, 0.0f32);
                            for (&d, &wc) in ds.iter().zip(&wts) {
                                if wc > best.0 && in_range(d, lo, hi) {
                                    best = (wc, d);
                                }
                            }
                            if best.0 < 0.0 {
                                continue;
                            }
                            best.1
                        };
                        let sdf = (d - zs[kk]) * ray[kk];
                        let (ts, wt) = (&mut tsdf[kk], &mut weight[kk]);
                        if sdf < -trunc {
                            if *wt == 0.0 && *ts != -1.0 {
                                *ts = -1.0;
                                occluded += 1;
                            }
                            continue;
                        }
                        let value = sdf * inv_trunc;
                        let (value, wv) = if value >= 1.0 {
                            if !carve {
                                continue;
                            }
                            free += 1;
                            (1.0, free_w)
                        } else {
                            band += 1;
                            let wv = if value < 0.0 {
                                (1.0 + value * inv_falloff).max(min_behind)
                            } else {
                                1.0
                            };
                            (value, wv)
                        };
                        let w0 = *wt;
                        *ts = (*ts * w0 + value * wv) / (w0 + wv);
                        *wt = (w0 + wv).min(max_w);
                    }
                }
            }
        }
        stats.band_updates = band;
        stats.free_updates = free;
        stats.occluded_voxels = occluded;
    }

    /// Extracts the normal grid into new buffers.
    pub fn normal_grid(&self) -> NormalGrid {
        let n = self.workspace.voxel_count();
        let mut normals = vec![0.0; 3 * n];
        let mut tsdf = vec![0.0; n];
        self.extract(&mut normals, &mut tsdf);
        NormalGrid {
            workspace: self.workspace,
            normals,
            tsdf,
            truncation_m: self.truncation_m(),
        }
    }

    /// Writes the normal grid straight into caller buffers (e.g. a shared-memory loan), without
    /// allocating: `normals_out` is channel-major (`3 · N`), `tsdf_out` has `N` values. Every
    /// element is overwritten.
    pub fn write_normal_grid(
        &self,
        normals_out: &mut [f32],
        tsdf_out: &mut [f32],
    ) -> Result<(), FusionError> {
        check_buffers(&self.workspace, normals_out, tsdf_out)?;
        self.extract(normals_out, tsdf_out);
        Ok(())
    }

    fn extract(&self, normals_out: &mut [f32], tsdf_out: &mut [f32]) {
        // The scratch holds no state between calls: a poisoned lock is harmless.
        let mut scratch = self.scratch.lock().unwrap_or_else(|e| e.into_inner());
        tsdf_out.copy_from_slice(&self.tsdf);
        normals::extract(
            &self.workspace,
            &self.config,
            &self.tsdf,
            &self.weight,
            &mut scratch,
            normals_out,
        );
    }
}

/// A usable depth: finite, positive and inside `[lo, hi]` (NaN fails every comparison).
#[inline(always)]
fn in_range(d: f32, lo: f32, hi: f32) -> bool {
    (d > 0.0) & (d >= lo) & (d <= hi)
}

fn check_buffers(ws: &Workspace, normals: &[f32], tsdf: &[f32]) -> Result<(), FusionError> {
    let n = ws.voxel_count();
    if normals.len() != 3 * n {
        return Err(FusionError::BufferSize {
            name: "normals",
            got: normals.len(),
            expected: 3 * n,
        });
    }
    if tsdf.len() != n {
        return Err(FusionError::BufferSize {
            name: "tsdf",
            got: tsdf.len(),
            expected: n,
        });
    }
    Ok(())
}

/// One-shot: fuses a single frame and returns its normal grid.
pub fn fuse_normal_grid(
    depth: &DepthImage,
    camera: &CameraModel,
    workspace: &Workspace,
    config: &FusionConfig,
) -> Result<NormalGrid, FusionError> {
    let mut volume = TsdfVolume::new(*workspace, config)?;
    volume.integrate(depth, camera)?;
    Ok(volume.normal_grid())
}

/// One-shot into caller buffers (see [`TsdfVolume::write_normal_grid`]). Allocates a temporary
/// volume; a long-running stage should keep a [`TsdfVolume`] and call `reset`/`integrate`/
/// `write_normal_grid` instead. Buffer sizes are checked before any work.
pub fn fuse_into(
    depth: &DepthImage,
    camera: &CameraModel,
    workspace: &Workspace,
    config: &FusionConfig,
    normals_out: &mut [f32],
    tsdf_out: &mut [f32],
) -> Result<IntegrationStats, FusionError> {
    workspace.validate()?;
    check_buffers(workspace, normals_out, tsdf_out)?;
    let mut volume = TsdfVolume::new(*workspace, config)?;
    let stats = volume.integrate(depth, camera)?;
    volume.write_normal_grid(normals_out, tsdf_out)?;
    Ok(stats)
}
