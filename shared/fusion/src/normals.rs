//! Normal extraction: the unit normal of the nearest surface point for every band voxel.
//!
//! Method:
//! 1. cache `F` (signed distance in voxels) and its gradient `∇F` for the voxels of each column
//!    between its lowest and highest band voxel (±1) — central differences, one-sided next to
//!    truncated or unobserved neighbours, whose clamped values would bias the difference —
//!    then (optionally) smooth the gradients of band voxels with a separable [1, 2, 1] kernel
//!    against sensor noise;
//! 2. for a band voxel `x`, step to the zero level set along the gradient (`t = x − F ∇F/|∇F|²`)
//!    and read the trilinearly interpolated gradient there;
//! 3. iterate closest-point updates `t ← x ∓ |x − q| n(t)`, where `q` is the projection of `t`
//!    onto the level set. A projective TSDF's level sets are the surface shifted along the view
//!    rays, so the gradient at `x` itself is the normal at the ray hit, not at the nearest point
//!    (off by ~8° two voxels above a 16 cm sphere at 30° slope); each iteration shrinks that
//!    error by the factor distance/curvature-radius.
//! 4. band voxels without a usable gradient (thin structures, conflicting views) take the mean
//!    normal of their 6-neighbours.
use crate::FusionConfig;
use psgrasp_geometry::Workspace;

/// Squared step (voxels²) below which the closest-point iteration stops: 0.02 voxel.
const CONVERGED_SQ: f32 = 0.02 * 0.02;

/// `[F, ∂F/∂x, ∂F/∂y, ∂F/∂z]` in voxel units; F = NaN where never observed.
type FieldSample = [f32; 4];

/// Reusable buffers of the normal extraction.
#[derive(Debug, Default)]
pub(crate) struct NormalScratch {
    /// Cached field, valid only inside each column's `ranges` entry.
    field: Vec<FieldSample>,
    /// Per column `[lo, hi]` (inclusive) of valid `field` entries; `lo > hi` = none.
    ranges: Vec<[u16; 2]>,
    /// Gradient smoothing buffer.
    smoothed: Vec<[f32; 3]>,
}

impl NormalScratch {
    pub(crate) fn with_capacity(ws: &Workspace) -> Self {
        let n = ws.voxel_count();
        let cols = ws.dims[0] as usize * ws.dims[1] as usize;
        Self {
            field: vec![[0.0; 4]; n],
            ranges: vec![[1, 0]; cols],
            smoothed: vec![[0.0; 3]; n],
        }
    }
}

/// True for a voxel of the truncation band.
#[inline]
pub(crate) fn in_band(tsdf: f32) -> bool {
    tsdf.abs() < 1.0
}

/// The cached field and where it is valid.
struct Field<'a> {
    dims: [usize; 3],
    samples: &'a [FieldSample],
    ranges: &'a [[u16; 2]],
}

pub(crate) fn extract(
    ws: &Workspace,
    config: &FusionConfig,
    tsdf: &[f32],
    weight: &[f32],
    scratch: &mut NormalScratch,
    normals_out: &mut [f32],
) {
    let n = ws.voxel_count();
    let dims = ws.dims.map(|d| d as usize);
    let [nx, ny, nz] = dims;
    let trunc = config.truncation_voxels;
    scratch.field.resize(n, [0.0; 4]);
    scratch.ranges.resize(nx * ny, [1, 0]);
    band_ranges(dims, tsdf, &mut scratch.ranges);
    build_field(
        dims,
        trunc,
        tsdf,
        weight,
        &scratch.ranges,
        &mut scratch.field,
    );
    if config.smooth_gradients {
        scratch.smoothed.resize(n, [0.0; 3]);
        for axis in [2, 1, 0] {
            smooth_gradients(
                dims,
                axis,
                trunc,
                &scratch.ranges,
                &mut scratch.field,
                &mut scratch.smoothed,
            );
        }
    }
    let field = Field {
        dims,
        samples: &scratch.field,
        ranges: &scratch.ranges,
    };

    normals_out.fill(0.0);
    let (nx_out, rest) = normals_out.split_at_mut(n);
    let (ny_out, nz_out) = rest.split_at_mut(n);
    let min_g2 = config.min_gradient * config.min_gradient;
    let iterations = config.normal_iterations;
    let mut missing = 0usize;
    for i in 0..nx {
        for j in 0..ny {
            let c = i * ny + j;
            let [lo, hi] = scratch.ranges[c];
            for k in lo as usize..=hi as usize {
                let idx = c * nz + k;
                if !in_band(tsdf[idx]) {
                    continue;
                }
                let x = [i as f32, j as f32, k as f32];
                let fx = field.samples[idx];
                match nearest_surface_normal(&field, x, fx, trunc, iterations, min_g2) {
                    Some(nrm) => {
                        nx_out[idx] = nrm[0];
                        ny_out[idx] = nrm[1];
                        nz_out[idx] = nrm[2];
                    }
                    None => missing += 1,
                }
            }
        }
    }
    if missing > 0 {
        fill_missing(dims, tsdf, nx_out, ny_out, nz_out);
    }
}

/// Per column: the band voxels' k-range widened by one voxel (where the field is needed).
fn band_ranges(dims: [usize; 3], tsdf: &[f32], ranges: &mut [[u16; 2]]) {
    let nz = dims[2];
    for (c, range) in ranges.iter_mut().enumerate() {
        let col = &tsdf[c * nz..(c + 1) * nz];
        *range = match (
            col.iter().position(|t| in_band(*t)),
            col.iter().rposition(|t| in_band(*t)),
        ) {
            (Some(lo), Some(hi)) => [lo.saturating_sub(1) as u16, (hi + 1).min(nz - 1) as u16],
            _ => [1, 0],
        };
    }
}

/// Caches F and ∇F inside each column's range.
fn build_field(
    dims: [usize; 3],
    trunc: f32,
    tsdf: &[f32],
    weight: &[f32],
    ranges: &[[u16; 2]],
    field: &mut [FieldSample],
) {
    let [nx, ny, nz] = dims;
    // A neighbour is reliable if observed and inside the band; next to an unreliable neighbour
    // the difference is one-sided. Grid borders count as unreliable.
    #[inline(always)]
    fn diff(lo: f32, lo_ok: bool, f0: f32, hi: f32, hi_ok: bool) -> f32 {
        if lo_ok == hi_ok {
            0.5 * (hi - lo)
        } else if lo_ok {
            f0 - lo
        } else {
            hi - f0
        }
    }
    let ok = |idx: usize| weight[idx] > 0.0 && in_band(tsdf[idx]);
    let v = |idx: usize| tsdf[idx] * trunc;
    let sx = ny * nz;
    for i in 0..nx {
        for j in 0..ny {
            let [lo, hi] = ranges[i * ny + j];
            let col = (i * ny + j) * nz;
            let (xm, xm_in) = if i > 0 {
                (col - sx, true)
            } else {
                (col, false)
            };
            let (xp, xp_in) = if i + 1 < nx {
                (col + sx, true)
            } else {
                (col, false)
            };
            let (ym, ym_in) = if j > 0 {
                (col - nz, true)
            } else {
                (col, false)
            };
            let (yp, yp_in) = if j + 1 < ny {
                (col + nz, true)
            } else {
                (col, false)
            };
            for k in lo as usize..=hi as usize {
                let idx = col + k;
                let f0 = v(idx);
                let (a, b) = (xm + k, xp + k);
                let gx = diff(v(a), xm_in && ok(a), f0, v(b), xp_in && ok(b));
                let (a, b) = (ym + k, yp + k);
                let gy = diff(v(a), ym_in && ok(a), f0, v(b), yp_in && ok(b));
                let (a, b) = (idx - (k > 0) as usize, idx + (k + 1 < nz) as usize);
                let gz = diff(v(a), k > 0 && ok(a), f0, v(b), k + 1 < nz && ok(b));
                let f = if weight[idx] > 0.0 { f0 } else { f32::NAN };
                field[idx] = [f, gx, gy, gz];
            }
        }
    }
}

/// One pass of the separable [1, 2, 1] smoothing of the cached gradients of band voxels along
/// `axis`; neighbours outside the band or the cached ranges are left out (weights renormalised).
fn smooth_gradients(
    dims: [usize; 3],
    axis: usize,
    trunc: f32,
    ranges: &[[u16; 2]],
    field: &mut [FieldSample],
    out: &mut [[f32; 3]],
) {
    let [nx, ny, nz] = dims;
    // Band voxels: observed (F not NaN) and inside the truncation band.
    let band = |f: &FieldSample| f[0].abs() < trunc;
    let col_step = [ny, 1, 0][axis];
    let voxel_step = col_step * nz + usize::from(axis == 2);
    for i in 0..nx {
        for j in 0..ny {
            let c = i * ny + j;
            let coord = [i, j, 0][axis];
            let has_lo = axis == 2 || coord > 0;
            let has_hi = axis == 2 || coord + 1 < dims[axis];
            let range_lo = if axis != 2 && has_lo {
                ranges[c - col_step]
            } else {
                ranges[c]
            };
            let range_hi = if axis != 2 && has_hi {
                ranges[c + col_step]
            } else {
                ranges[c]
            };
            let [lo, hi] = ranges[c];
            for k in lo as usize..=hi as usize {
                let idx = c * nz + k;
                let g = field[idx];
                if !band(&g) {
                    out[idx] = [g[1], g[2], g[3]];
                    continue;
                }
                let mut acc = [2.0 * g[1], 2.0 * g[2], 2.0 * g[3]];
                let mut total = 2.0f32;
                let lo_ok = if axis == 2 {
                    k > lo as usize
                } else {
                    has_lo && (range_lo[0] as usize..=range_lo[1] as usize).contains(&k)
                };
                let hi_ok = if axis == 2 {
                    k < hi as usize
                } else {
                    has_hi && (range_hi[0] as usize..=range_hi[1] as usize).contains(&k)
                };
                for (ok, nidx) in [
                    (lo_ok, idx.wrapping_sub(voxel_step)),
                    (hi_ok, idx + voxel_step),
                ] {
                    if !ok {
                        continue;
                    }
                    let h = field[nidx];
                    if band(&h) {
                        acc[0] += h[1];
                        acc[1] += h[2];
                        acc[2] += h[3];
                        total += 1.0;
                    }
                }
                let inv = 1.0 / total;
                out[idx] = acc.map(|a| a * inv);
            }
        }
    }
    for (c, &[lo, hi]) in ranges.iter().enumerate() {
        for idx in c * nz + lo as usize..=c * nz + hi as usize {
            let [a, b, d] = out[idx];
            field[idx][1] = a;
            field[idx][2] = b;
            field[idx][3] = d;
        }
    }
}

/// Trilinear interpolation of the cached field at continuous voxel coordinates `p` (voxel
/// centres at integers), clamped to the grid. Corners outside the cached ranges or never
/// observed are left out and the weights renormalised; `None` if no corner is usable.
#[inline]
fn sample(field: &Field<'_>, p: [f32; 3]) -> Option<FieldSample> {
    let dims = field.dims;
    let mut i0 = [0usize; 3];
    let mut fr = [0.0f32; 3];
    let mut step = [0usize; 3];
    for a in 0..3 {
        if dims[a] < 2 {
            continue;
        }
        let max = (dims[a] - 1) as f32;
        // NaN maps to 0; the clamp makes truncation a floor.
        let c = p[a].max(0.0).min(max);
        let fl = (c as usize).min(dims[a] - 2);
        i0[a] = fl;
        fr[a] = c - fl as f32;
        step[a] = 1;
    }
    let nz = dims[2];
    let (k0, k1) = (i0[2], i0[2] + step[2]);
    let mut acc = [0.0f32; 4];
    let mut total = 0.0f32;
    for (di, wx) in [(0, 1.0 - fr[0]), (step[0], fr[0])] {
        for (dj, wy) in [(0, 1.0 - fr[1]), (step[1], fr[1])] {
            let c = (i0[0] + di) * dims[1] + i0[1] + dj;
            let [lo, hi] = field.ranges[c];
            let (lo, hi) = (lo as usize, hi as usize);
            let wxy = wx * wy;
            for (k, w) in [(k0, wxy * (1.0 - fr[2])), (k1, wxy * fr[2])] {
                if k < lo || k > hi {
                    continue;
                }
                let corner = field.samples[c * nz + k];
                if corner[0].is_nan() {
                    continue;
                }
                total += w;
                for (a, v) in acc.iter_mut().zip(corner) {
                    *a += w * v;
                }
            }
        }
    }
    if total < 1e-3 {
        return None;
    }
    let inv = 1.0 / total;
    Some(acc.map(|a| a * inv))
}

#[inline]
fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Closest-point iterations from voxel centre `x` (voxel units) with cached sample `fx`.
fn nearest_surface_normal(
    field: &Field<'_>,
    x: [f32; 3],
    fx: FieldSample,
    trunc: f32,
    iterations: u32,
    min_g2: f32,
) -> Option<[f32; 3]> {
    let max_step = 1.5 * trunc;
    let f = fx[0];
    let g = [fx[1], fx[2], fx[3]];
    let g2 = dot(g, g);
    if g2 < min_g2 {
        return None;
    }
    let gl = g2.sqrt();
    let mut n = [g[0] / gl, g[1] / gl, g[2] / gl];
    // First-order projection onto the zero level set.
    let d = (f / gl).clamp(-max_step, max_step);
    let mut t = [x[0] - d * n[0], x[1] - d * n[1], x[2] - d * n[2]];
    let side = if f >= 0.0 { 1.0 } else { -1.0 };
    for it in 0..=iterations {
        let Some(s) = sample(field, t) else { break };
        let gt = [s[1], s[2], s[3]];
        let gt2 = dot(gt, gt);
        if gt2 < min_g2 {
            break;
        }
        let inv_gl = 1.0 / gt2.sqrt();
        n = [gt[0] * inv_gl, gt[1] * inv_gl, gt[2] * inv_gl];
        if it == iterations {
            break;
        }
        // Surface point near t, then the point at the same distance from x along n(t).
        let dt = (s[0] * inv_gl).clamp(-max_step, max_step);
        let q = [t[0] - dt * n[0], t[1] - dt * n[1], t[2] - dt * n[2]];
        let r = [x[0] - q[0], x[1] - q[1], x[2] - q[2]];
        let dist = dot(r, r).sqrt().min(max_step) * side;
        let next = [x[0] - dist * n[0], x[1] - dist * n[1], x[2] - dist * n[2]];
        let moved = [next[0] - t[0], next[1] - t[1], next[2] - t[2]];
        t = next;
        // Converged (always after one step on planes): the normal at t will not change.
        if dot(moved, moved) < CONVERGED_SQ {
            break;
        }
    }
    Some(n)
}

/// Gives band voxels without a normal the mean normal of their 6-neighbours.
fn fill_missing(dims: [usize; 3], tsdf: &[f32], nx: &mut [f32], ny: &mut [f32], nz: &mut [f32]) {
    let [dx, dy, dz] = dims;
    let strides = [dy * dz, dz, 1];
    for idx in 0..tsdf.len() {
        if !in_band(tsdf[idx]) || nx[idx] != 0.0 || ny[idx] != 0.0 || nz[idx] != 0.0 {
            continue;
        }
        let c = [idx / (dy * dz), (idx / dz) % dy, idx % dz];
        let mut acc = [0.0f32; 3];
        for a in 0..3 {
            let lo = (c[a] > 0).then(|| idx - strides[a]);
            let hi = (c[a] + 1 < [dx, dy, dz][a]).then(|| idx + strides[a]);
            for nb in [lo, hi].into_iter().flatten() {
                acc[0] += nx[nb];
                acc[1] += ny[nb];
                acc[2] += nz[nb];
            }
        }
        let l = dot(acc, acc).sqrt();
        if l > 1e-6 {
            nx[idx] = acc[0] / l;
            ny[idx] = acc[1] / l;
            nz[idx] = acc[2] / l;
        }
    }
}
