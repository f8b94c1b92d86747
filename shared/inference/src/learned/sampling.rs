//! Contact sampling and trilinear feature sampling (network contract, "Feature sampling").
//!
//! Grids are channel-major `[C, X, Y, Z]` (k fastest). A point `p` (metres, workspace frame) is
//! sampled on a level with voxel size `s_l` at continuous voxel coordinates
//! `u = p / s_l − 0.5`, clamped per axis to `[0, dim − 1]`, by trilinear interpolation of the
//! 8 neighbouring voxel centres — `F.grid_sample(…, padding_mode="border", align_corners=False)`.
//!
//! These loops are the hot path of the learned backend: they take caller-owned output buffers,
//! allocate nothing per point and compute the 8 corner offsets and weights once per point and
//! level, then sweep the channels.
use super::card::{ModelError, SUBVOXELS_PER_CONTACT};
use psgrasp_geometry::Workspace;

/// One grid level, borrowed: `channels` planes of `dims` voxels, channel-major.
#[derive(Debug, Clone, Copy)]
pub struct GridLevel<'a> {
    data: &'a [f32],
    channels: usize,
    dims: [usize; 3],
    inv_voxel_size: f32,
    voxel_size_m: f32,
}

impl<'a> GridLevel<'a> {
    /// Wraps `data` (`channels · X · Y · Z` values) with voxel size `voxel_size_m`.
    pub fn new(
        data: &'a [f32],
        channels: usize,
        dims: [usize; 3],
        voxel_size_m: f32,
    ) -> Result<Self, ModelError> {
        let n = dims.iter().product::<usize>() * channels;
        if n == 0 || data.len() != n {
            return Err(ModelError::GraphInterface {
                graph: "unet",
                reason: format!(
                    "grid of {channels} channels × {dims:?} needs {n} values, got {}",
                    data.len()
                ),
            });
        }
        if !(voxel_size_m.is_finite() && voxel_size_m > 0.0) {
            return Err(ModelError::InvalidCard {
                field: "grid.voxel_size_m",
                reason: format!("voxel size {voxel_size_m} must be positive"),
            });
        }
        Ok(Self {
            data,
            channels,
            dims,
            inv_voxel_size: 1.0 / voxel_size_m,
            voxel_size_m,
        })
    }

    /// Channels C.
    pub fn channels(&self) -> usize {
        self.channels
    }

    /// Voxels per axis.
    pub fn dims(&self) -> [usize; 3] {
        self.dims
    }

    /// Voxel edge in metres.
    pub fn voxel_size_m(&self) -> f32 {
        self.voxel_size_m
    }

    /// Voxels per channel plane.
    pub fn plane_len(&self) -> usize {
        self.dims[0] * self.dims[1] * self.dims[2]
    }

    /// The flat data.
    pub fn data(&self) -> &'a [f32] {
        self.data
    }

    /// The 8 corner offsets (within one plane) and trilinear weights of point `p`, clamped
    /// convention. Corner order: x major, then y, then z; low before high.
    #[inline(always)]
    pub fn corners(&self, p: [f32; 3]) -> ([usize; 8], [f32; 8]) {
        trilinear_corners(p, self.dims, self.inv_voxel_size)
    }

    /// Trilinear values of channel 0 at `N` points given as coordinate arrays (structure of
    /// arrays, so that the index and weight arithmetic vectorises; only the 8 loads per point are
    /// scalar). Same values as [`GridLevel::sample`].
    #[inline]
    pub fn sample_points<const N: usize>(
        &self,
        xs: &[f32; N],
        ys: &[f32; N],
        zs: &[f32; N],
    ) -> [f32; N] {
        let d = self.dims;
        let strides = [d[1] * d[2], d[2], 1];
        let mut base = [0i32; N];
        let mut fr = [[0f32; N]; 3];
        for (a, coords) in [xs, ys, zs].into_iter().enumerate() {
            let max = (d[a] - 1) as f32;
            let hi = d[a].saturating_sub(2) as i32;
            let stride = strides[a] as i32;
            for i in 0..N {
                let u = (coords[i] * self.inv_voxel_size - 0.5).max(0.0).min(max);
                let i0 = (u as i32).min(hi);
                fr[a][i] = u - i0 as f32;
                base[i] += i0 * stride;
            }
        }
        let step: [usize; 3] = std::array::from_fn(|a| if d[a] > 1 { strides[a] } else { 0 });
        let plane = &self.data[..self.plane_len()];
        let mut out = [0f32; N];
        for i in 0..N {
            let b = base[i] as usize;
            let (fx, fy, fz) = (fr[0][i], fr[1][i], fr[2][i]);
            let v = |dx: usize, dy: usize, dz: usize| {
                plane[b + dx * step[0] + dy * step[1] + dz * step[2]]
            };
            let c00 = v(0, 0, 0) + fz * (v(0, 0, 1) - v(0, 0, 0));
            let c01 = v(0, 1, 0) + fz * (v(0, 1, 1) - v(0, 1, 0));
            let c10 = v(1, 0, 0) + fz * (v(1, 0, 1) - v(1, 0, 0));
            let c11 = v(1, 1, 0) + fz * (v(1, 1, 1) - v(1, 1, 0));
            let c0 = c00 + fy * (c01 - c00);
            let c1 = c10 + fy * (c11 - c10);
            out[i] = c0 + fx * (c1 - c0);
        }
        out
    }

    /// Trilinear value of channel `c` at `p` (clamped convention). `c` must be < channels.
    pub fn sample(&self, c: usize, p: [f32; 3]) -> f32 {
        let (off, w) = self.corners(p);
        let plane = &self.data[c * self.plane_len()..(c + 1) * self.plane_len()];
        off.iter()
            .zip(w.iter())
            .map(|(&o, &wt)| wt * plane[o])
            .sum()
    }
}

/// The 8 corner voxel offsets (linear, one channel) and trilinear weights of `p` on a grid of
/// `dims` voxels with `1 / voxel size = inv_voxel_size`, clamped convention.
#[inline(always)]
fn trilinear_corners(p: [f32; 3], dims: [usize; 3], inv_voxel_size: f32) -> ([usize; 8], [f32; 8]) {
    let strides = [dims[1] * dims[2], dims[2], 1];
    let mut base = 0;
    let mut step = [0usize; 3];
    let mut f = [0f32; 3];
    for a in 0..3 {
        let max = (dims[a] - 1) as f32;
        // `max(0.0)` first: a NaN coordinate becomes 0 instead of poisoning the index.
        let u = (p[a] * inv_voxel_size - 0.5).max(0.0).min(max);
        // The low corner is at most dims − 2, so the high corner (low + 1) is always inside;
        // an axis of one voxel uses that voxel twice.
        let i0 = (u as usize).min(dims[a].saturating_sub(2));
        base += i0 * strides[a];
        step[a] = if dims[a] > 1 { strides[a] } else { 0 };
        f[a] = u - i0 as f32;
    }
    let wx = [1.0 - f[0], f[0]];
    let wy = [1.0 - f[1], f[1]];
    let wz = [1.0 - f[2], f[2]];
    let mut off = [0usize; 8];
    let mut w = [0f32; 8];
    for (n, (o, wt)) in off.iter_mut().zip(w.iter_mut()).enumerate() {
        let (a, b, c) = (n >> 2, (n >> 1) & 1, n & 1);
        *o = base + a * step[0] + b * step[1] + c * step[2];
        *wt = wx[a] * wy[b] * wz[c];
    }
    (off, w)
}

/// Samples every level at every point and concatenates the levels: `out` becomes the row-major
/// `[points.len(), Σ C_l]` feature matrix (resized; its allocation is reused).
///
/// This reads the channel-major grids directly (8 gathers per channel); [`FeaturePyramid`] is the
/// faster path for many points.
pub fn sample_features(levels: &[GridLevel<'_>], points: &[[f32; 3]], out: &mut Vec<f32>) {
    let f: usize = levels.iter().map(|l| l.channels).sum();
    out.clear();
    out.resize(points.len() * f, 0.0);
    let mut level_offset = 0;
    for level in levels {
        let plane = level.plane_len();
        let c_l = level.channels;
        for (p, row) in points.iter().zip(out.chunks_exact_mut(f)) {
            let (off, w) = level.corners(*p);
            let dst = &mut row[level_offset..level_offset + c_l];
            for (d, src) in dst.iter_mut().zip(level.data.chunks_exact(plane)) {
                *d = w[0] * src[off[0]]
                    + w[1] * src[off[1]]
                    + w[2] * src[off[2]]
                    + w[3] * src[off[3]]
                    + w[4] * src[off[4]]
                    + w[5] * src[off[5]]
                    + w[6] * src[off[6]]
                    + w[7] * src[off[7]];
            }
        }
        level_offset += c_l;
    }
}

/// One level stored channel-last (`[X, Y, Z, C]`): the C features of a voxel are contiguous.
#[derive(Debug, Clone, Default)]
struct ChannelLastLevel {
    data: Vec<f32>,
    channels: usize,
    dims: [usize; 3],
    inv_voxel_size: f32,
}

/// The encoder levels copied channel-last, so that trilinear feature sampling reads 8 contiguous
/// rows of C values per point and level (vectorised) instead of 8·C scattered values. Buffers are
/// reused from frame to frame.
#[derive(Debug, Clone, Default)]
pub struct FeaturePyramid {
    levels: Vec<ChannelLastLevel>,
}

/// Voxels per block of the channel-last transposition (keeps a block's C planes in L1).
const TRANSPOSE_BLOCK: usize = 256;

impl FeaturePyramid {
    /// Copies `levels` channel-last into `self` (single thread).
    pub fn fill(&mut self, levels: &[GridLevel<'_>]) {
        self.fill_with(levels, |data, level| transpose_blocks(level, data, 0));
    }

    /// Copies `levels` channel-last, running the transposition on `pool`.
    pub fn fill_in(&mut self, levels: &[GridLevel<'_>], pool: &rayon::ThreadPool) {
        use rayon::prelude::*;
        self.fill_with(levels, |data, level| {
            let rows = TRANSPOSE_BLOCK * level.channels;
            pool.install(|| {
                data.par_chunks_mut(rows)
                    .enumerate()
                    .for_each(|(b, chunk)| transpose_blocks(level, chunk, b * TRANSPOSE_BLOCK));
            })
        });
    }

    fn fill_with(
        &mut self,
        levels: &[GridLevel<'_>],
        mut transpose: impl FnMut(&mut [f32], &GridLevel<'_>),
    ) {
        self.levels
            .resize_with(levels.len(), ChannelLastLevel::default);
        for (dst, src) in self.levels.iter_mut().zip(levels) {
            dst.channels = src.channels;
            dst.dims = src.dims;
            dst.inv_voxel_size = src.inv_voxel_size;
            dst.data.clear();
            dst.data.resize(src.data.len(), 0.0);
            transpose(&mut dst.data, src);
        }
    }

    /// Feature size F = Σ C_l.
    pub fn feature_dim(&self) -> usize {
        self.levels.iter().map(|l| l.channels).sum()
    }

    /// Features of `points` into `out` (`[points.len(), F]`, resized; allocation reused).
    pub fn sample(&self, points: &[[f32; 3]], out: &mut Vec<f32>) {
        out.clear();
        out.resize(points.len() * self.feature_dim(), 0.0);
        self.sample_into(points, out);
    }

    /// Features of `points` into `out` on `pool` (same values as [`FeaturePyramid::sample`]).
    pub fn sample_in(&self, points: &[[f32; 3]], out: &mut Vec<f32>, pool: &rayon::ThreadPool) {
        use rayon::prelude::*;
        const CHUNK: usize = 512;
        let f = self.feature_dim();
        out.clear();
        out.resize(points.len() * f, 0.0);
        if f == 0 {
            return;
        }
        pool.install(|| {
            out.par_chunks_mut(CHUNK * f)
                .zip(points.par_chunks(CHUNK))
                .for_each(|(o, p)| self.sample_into(p, o));
        });
    }

    /// Features of `points` into `out`, which must hold `points.len() · F` values.
    fn sample_into(&self, points: &[[f32; 3]], out: &mut [f32]) {
        let f = self.feature_dim();
        if f == 0 {
            return;
        }
        for (p, row) in points.iter().zip(out.chunks_exact_mut(f)) {
            let mut start = 0;
            for level in &self.levels {
                let c = level.channels;
                let (off, w) = trilinear_corners(*p, level.dims, level.inv_voxel_size);
                let dst = &mut row[start..start + c];
                let r: [&[f32]; 8] =
                    std::array::from_fn(|k| &level.data[off[k] * c..off[k] * c + c]);
                for (i, d) in dst.iter_mut().enumerate() {
                    *d = w[0] * r[0][i]
                        + w[1] * r[1][i]
                        + w[2] * r[2][i]
                        + w[3] * r[3][i]
                        + w[4] * r[4][i]
                        + w[5] * r[5][i]
                        + w[6] * r[6][i]
                        + w[7] * r[7][i];
                }
                start += c;
            }
        }
    }
}

/// Writes voxels `first..` of `level` channel-last into `dst` (whole voxels, `dst.len() / C` of
/// them), block by block.
fn transpose_blocks(level: &GridLevel<'_>, dst: &mut [f32], first: usize) {
    let c = level.channels;
    let n = level.plane_len();
    for (b, block) in dst.chunks_mut(TRANSPOSE_BLOCK * c).enumerate() {
        let v0 = first + b * TRANSPOSE_BLOCK;
        let len = block.len() / c;
        for ch in 0..c {
            let src = &level.data[ch * n + v0..ch * n + v0 + len];
            for (v, &x) in src.iter().enumerate() {
                block[v * c + ch] = x;
            }
        }
    }
}

/// Class probabilities of the level-0 grid: `P_contact` and `P_gripper` per voxel (the softmax of
/// the three label logits; `P_empty` is not kept).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ClassProbabilities {
    /// `P(contact)` per voxel, workspace layout.
    pub contact: Vec<f32>,
    /// `P(gripper)` per voxel, workspace layout.
    pub gripper: Vec<f32>,
}

impl ClassProbabilities {
    /// Softmax over the classes of `logits` (`[3, N]`, channel-major), into `self` (buffers reused).
    pub fn compute(&mut self, logits: &[f32], voxels: usize) -> Result<(), ModelError> {
        if logits.len() != 3 * voxels {
            return Err(ModelError::GraphInterface {
                graph: "unet",
                reason: format!(
                    "label_logits has {} values, 3 classes × {voxels} voxels expected",
                    logits.len()
                ),
            });
        }
        let (l0, rest) = logits.split_at(voxels);
        let (l1, l2) = rest.split_at(voxels);
        self.contact.clear();
        self.contact.resize(voxels, 0.0);
        self.gripper.clear();
        self.gripper.resize(voxels, 0.0);
        // Branch-free so that it vectorises; non-finite logits are detected by an OR reduction.
        let mut bad = false;
        for ((((pc, pg), &a), &b), &c) in self
            .contact
            .iter_mut()
            .zip(self.gripper.iter_mut())
            .zip(l0)
            .zip(l1)
            .zip(l2)
        {
            bad |= !(a.is_finite() & b.is_finite() & c.is_finite());
            let m = a.max(b).max(c);
            let (ea, eb, ec) = (
                exp_nonpositive(a - m),
                exp_nonpositive(b - m),
                exp_nonpositive(c - m),
            );
            let inv = 1.0 / (ea + eb + ec);
            *pc = eb * inv;
            *pg = ec * inv;
        }
        if bad {
            let index = (0..voxels)
                .find(|&i| !(l0[i].is_finite() && l1[i].is_finite() && l2[i].is_finite()))
                .unwrap_or(0);
            return Err(ModelError::NonFiniteOutput {
                output: "label_logits",
                index,
            });
        }
        Ok(())
    }
}

/// `e^x` for `x ≤ 0` (Cephes `expf` polynomial, relative error below 3e-7; arguments below −87,
/// and NaN, give `e^−87`). Branch-free so that loops over it vectorise.
#[inline(always)]
pub fn exp_nonpositive(x: f32) -> f32 {
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    // Adding and subtracting 1.5·2^23 rounds to the nearest integer in f32 arithmetic.
    const ROUND: f32 = 12_582_912.0;
    // Not `clamp`: it passes NaN through, `max` turns it into −87.
    #[allow(clippy::manual_clamp)]
    let x = x.max(-87.0).min(0.0);
    let n = (x * std::f32::consts::LOG2_E + ROUND) - ROUND;
    let r = x - n * LN2_HI - n * LN2_LO;
    let mut p = 1.987_569_1e-4_f32;
    p = p * r + 1.398_199_9e-3;
    p = p * r + 8.333_452e-3;
    p = p * r + 4.166_579_6e-2;
    p = p * r + 1.666_666_5e-1;
    p = p * r + 0.5;
    let e_r = p * r * r + r + 1.0;
    e_r * f32::from_bits(((n as i32 + 127) as u32) << 23)
}

/// Contact voxels: linear indices with `P_contact ≥ threshold`, ascending. If more than
/// `max_voxels` qualify, the `max_voxels` highest `P_contact` are kept (ties → lower index), still
/// returned in ascending index order.
pub fn select_contact_voxels(
    p_contact: &[f32],
    threshold: f32,
    max_voxels: usize,
    out: &mut Vec<u32>,
) {
    out.clear();
    out.extend(
        p_contact
            .iter()
            .enumerate()
            .filter(|(_, &p)| p >= threshold)
            .map(|(i, _)| i as u32),
    );
    if out.len() > max_voxels {
        let rank = |a: &u32, b: &u32| {
            p_contact[*b as usize]
                .total_cmp(&p_contact[*a as usize])
                .then(a.cmp(b))
        };
        if max_voxels == 0 {
            out.clear();
            return;
        }
        out.select_nth_unstable_by(max_voxels - 1, rank);
        out.truncate(max_voxels);
        out.sort_unstable();
    }
}

/// The 8 sub-voxel centres of each contact voxel: voxel centre + (±s/4, ±s/4, ±s/4), dx major, then
/// dy, then dz, − before +. `out` is overwritten (allocation reused).
pub fn contact_points(workspace: &Workspace, voxels: &[u32], out: &mut Vec<[f32; 3]>) {
    out.clear();
    out.reserve(voxels.len() * SUBVOXELS_PER_CONTACT);
    let s = workspace.voxel_size_m;
    let q = 0.25 * s;
    for &v in voxels {
        let [i, j, k] = workspace.unindex(v as usize);
        let c = [
            (i as f32 + 0.5) * s,
            (j as f32 + 0.5) * s,
            (k as f32 + 0.5) * s,
        ];
        for dx in [-q, q] {
            for dy in [-q, q] {
                for dz in [-q, q] {
                    out.push([c[0] + dx, c[1] + dy, c[2] + dz]);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ws(dims: [u32; 3], s: f32) -> Workspace {
        Workspace {
            dims,
            voxel_size_m: s,
        }
    }

    /// A 2-channel grid: channel 0 = 2x − y + 0.5z + 0.1, channel 1 = −x + 3z (at voxel centres).
    fn linear_grid(w: &Workspace) -> Vec<f32> {
        let n = w.voxel_count();
        let mut g = vec![0.0; 2 * n];
        for idx in 0..n {
            let [i, j, k] = w.unindex(idx);
            let c = w.voxel_center(i, j, k);
            g[idx] = 2.0 * c.x - c.y + 0.5 * c.z + 0.1;
            g[n + idx] = -c.x + 3.0 * c.z;
        }
        g
    }

    #[test]
    fn trilinear_reproduces_linear_fields_inside() {
        let w = ws([6, 7, 8], 0.01);
        let g = linear_grid(&w);
        let level = GridLevel::new(&g, 2, [6, 7, 8], 0.01).unwrap();
        for p in [
            [0.0333, 0.0471, 0.0219],
            [0.005, 0.005, 0.005],
            [0.055, 0.065, 0.075],
        ] {
            let e0 = 2.0 * p[0] - p[1] + 0.5 * p[2] + 0.1;
            let e1 = -p[0] + 3.0 * p[2];
            assert!((level.sample(0, p) - e0).abs() < 1e-5, "{p:?}");
            assert!((level.sample(1, p) - e1).abs() < 1e-5, "{p:?}");
            // Agrees with the geometry crate's trilinear.
            let q = nalgebra::Point3::from(p);
            assert!((level.sample(0, p) - w.trilinear(&g[..w.voxel_count()], &q)).abs() < 1e-6);
        }
    }

    #[test]
    fn trilinear_clamps_to_the_border() {
        let w = ws([4, 4, 4], 0.02);
        let g = linear_grid(&w);
        let level = GridLevel::new(&g, 2, [4, 4, 4], 0.02).unwrap();
        // Outside or within half a voxel of the boundary the value is that of the clamped point.
        let inside = [0.01, 0.03, 0.07]; // x at the first centre, z at the last centre
        for p in [[-0.5, 0.03, 0.2], [0.004, 0.03, 0.079], [0.01, 0.03, 0.07]] {
            assert!(
                (level.sample(0, p) - level.sample(0, inside)).abs() < 1e-6,
                "{p:?}"
            );
        }
        // Exactly on the last centre along every axis: the corner voxel's value.
        let n = w.voxel_count();
        let last = w.index(3, 3, 3);
        assert!((level.sample(1, [0.07, 0.07, 0.07]) - g[n + last]).abs() < 1e-6);
        // A NaN coordinate samples the low border instead of panicking.
        assert!(level.sample(0, [f32::NAN, 0.03, 0.03]).is_finite());
    }

    #[test]
    fn single_voxel_axes_are_constant() {
        let g = [1.0f32, 2.0, 3.0]; // dims [1, 1, 3]
        let level = GridLevel::new(&g, 1, [1, 1, 3], 0.1).unwrap();
        assert!((level.sample(0, [0.7, -3.0, 0.1]) - 1.5).abs() < 1e-6);
        assert!((level.sample(0, [0.0, 0.0, 0.25]) - 3.0).abs() < 1e-6);
    }

    #[test]
    fn features_concatenate_levels_in_order() {
        let w0 = ws([8, 8, 8], 0.01);
        let w1 = ws([4, 4, 4], 0.02);
        let g0 = linear_grid(&w0);
        let g1: Vec<f32> = linear_grid(&w1).iter().map(|v| 10.0 * v).collect();
        let levels = [
            GridLevel::new(&g0, 2, [8, 8, 8], 0.01).unwrap(),
            GridLevel::new(&g1[..w1.voxel_count()], 1, [4, 4, 4], 0.02).unwrap(),
        ];
        let points = [[0.021, 0.033, 0.047], [0.05, 0.011, 0.06]];
        let mut out = vec![99.0; 3];
        sample_features(&levels, &points, &mut out);
        assert_eq!(out.len(), 6);
        for (n, p) in points.iter().enumerate() {
            assert!((out[3 * n] - (2.0 * p[0] - p[1] + 0.5 * p[2] + 0.1)).abs() < 1e-5);
            assert!((out[3 * n + 1] - (-p[0] + 3.0 * p[2])).abs() < 1e-5);
            let e = 10.0 * (2.0 * p[0] - p[1] + 0.5 * p[2] + 0.1);
            assert!(
                (out[3 * n + 2] - e).abs() < 1e-4,
                "{} vs {e}",
                out[3 * n + 2]
            );
        }
    }

    #[test]
    fn feature_pyramid_matches_the_direct_sampler() {
        let w0 = ws([8, 6, 4], 0.01);
        let w1 = ws([4, 3, 2], 0.02);
        let g0: Vec<f32> = (0..3 * w0.voxel_count())
            .map(|i| ((i * 7919) % 101) as f32 * 0.1)
            .collect();
        let g1: Vec<f32> = (0..5 * w1.voxel_count())
            .map(|i| ((i * 104729) % 37) as f32 - 18.0)
            .collect();
        let levels = [
            GridLevel::new(&g0, 3, [8, 6, 4], 0.01).unwrap(),
            GridLevel::new(&g1, 5, [4, 3, 2], 0.02).unwrap(),
        ];
        // Points inside, on the border and outside the grid.
        let points: Vec<[f32; 3]> = (0..300)
            .map(|i| {
                let t = i as f32;
                [
                    (t * 0.37).sin() * 0.05 + 0.04,
                    (t * 0.11).cos() * 0.04 + 0.03,
                    (t * 0.07) % 0.05 - 0.005,
                ]
            })
            .collect();
        let mut direct = Vec::new();
        sample_features(&levels, &points, &mut direct);
        let mut pyramid = FeaturePyramid::default();
        pyramid.fill(&levels);
        assert_eq!(pyramid.feature_dim(), 8);
        let mut fast = vec![1.0; 3];
        pyramid.sample(&points, &mut fast);
        assert_eq!(fast.len(), direct.len());
        for (a, b) in fast.iter().zip(&direct) {
            assert!((a - b).abs() <= 1e-6 * b.abs().max(1.0), "{a} vs {b}");
        }
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .unwrap();
        let mut par = Vec::new();
        let mut pyramid2 = FeaturePyramid::default();
        pyramid2.fill_in(&levels, &pool);
        pyramid2.sample_in(&points, &mut par, &pool);
        assert_eq!(par, fast, "the thread pool must not change a single bit");
    }

    #[test]
    fn batched_scalar_sampling_matches_single_points() {
        let w = ws([7, 5, 1], 0.01);
        let g: Vec<f32> = (0..w.voxel_count())
            .map(|i| ((i * 31) % 17) as f32 * 0.05)
            .collect();
        let level = GridLevel::new(&g, 1, [7, 5, 1], 0.01).unwrap();
        let pts: [[f32; 3]; 18] = std::array::from_fn(|i| {
            let t = i as f32;
            [t * 0.0043 - 0.01, (t * 0.7).sin() * 0.03 + 0.02, t * 0.001]
        });
        let xs = pts.map(|p| p[0]);
        let ys = pts.map(|p| p[1]);
        let zs = pts.map(|p| p[2]);
        let batch = level.sample_points(&xs, &ys, &zs);
        for (p, v) in pts.iter().zip(batch) {
            assert!((level.sample(0, *p) - v).abs() < 1e-6, "{p:?}");
        }
    }

    #[test]
    fn fast_exp_is_accurate() {
        for i in 0..=20_000 {
            let x = -(i as f32) * 0.0045; // 0 .. −90
            let e = (x as f64).exp();
            let ours = exp_nonpositive(x) as f64;
            if x >= -87.0 {
                assert!(((ours - e) / e).abs() < 3e-7, "x = {x}: {ours} vs {e}");
            } else {
                assert!(ours <= 1.7e-38 && ours > 0.0);
            }
        }
        assert_eq!(exp_nonpositive(0.0), 1.0);
        assert!(exp_nonpositive(f32::NAN).is_finite());
    }

    #[test]
    fn grid_level_rejects_wrong_lengths() {
        let g = vec![0.0; 10];
        assert!(GridLevel::new(&g, 1, [2, 2, 2], 0.01).is_err());
        assert!(GridLevel::new(&g[..8], 1, [2, 2, 2], 0.0).is_err());
        assert!(GridLevel::new(&g[..8], 1, [2, 2, 2], 0.01).is_ok());
    }

    #[test]
    fn softmax_probabilities_known_values() {
        // voxel 0: equal logits → 1/3 each; voxel 1: contact dominant; voxel 2: huge logits stay finite.
        let logits = [0.0, 0.0, 1000.0, 0.0, 2.0_f32.ln(), 1000.0, 0.0, 0.0, 999.0];
        let mut p = ClassProbabilities::default();
        p.compute(&logits, 3).unwrap();
        assert!((p.contact[0] - 1.0 / 3.0).abs() < 1e-6);
        assert!((p.contact[1] - 0.5).abs() < 1e-6 && (p.gripper[1] - 0.25).abs() < 1e-6);
        let e = 1.0f32.exp();
        assert!((p.contact[2] - e / (2.0 * e + 1.0)).abs() < 1e-6);
        assert!((p.gripper[2] - 1.0 / (2.0 * e + 1.0)).abs() < 1e-6);
        assert!(p.compute(&logits[..8], 3).is_err());
        let mut bad = logits;
        bad[4] = f32::NAN;
        assert!(matches!(
            p.compute(&bad, 3),
            Err(ModelError::NonFiniteOutput { index: 1, .. })
        ));
    }

    #[test]
    fn contact_selection_thresholds_and_caps() {
        let p = [0.2, 0.9, 0.5, 0.7, 0.9, 0.49, 1.0];
        let mut out = Vec::new();
        select_contact_voxels(&p, 0.5, 100, &mut out);
        assert_eq!(out, vec![1, 2, 3, 4, 6]);
        // Cap 3: 1.0 (6), then the tie at 0.9 keeps both (1, 4) → ascending.
        select_contact_voxels(&p, 0.5, 3, &mut out);
        assert_eq!(out, vec![1, 4, 6]);
        // Cap 2: the tie at 0.9 is broken towards the lower index.
        select_contact_voxels(&p, 0.5, 2, &mut out);
        assert_eq!(out, vec![1, 6]);
        select_contact_voxels(&p, 0.5, 0, &mut out);
        assert!(out.is_empty());
    }

    #[test]
    fn contact_points_are_the_subvoxel_centres_in_order() {
        let w = ws([4, 5, 6], 0.008);
        let idx = w.index(1, 2, 3) as u32;
        let mut pts = Vec::new();
        contact_points(&w, &[idx], &mut pts);
        assert_eq!(pts.len(), 8);
        let c = w.voxel_center(1, 2, 3);
        assert!((pts[0][0] - (c.x - 0.002)).abs() < 1e-7);
        assert!((pts[0][2] - (c.z - 0.002)).abs() < 1e-7);
        assert!((pts[1][2] - (c.z + 0.002)).abs() < 1e-7 && pts[1][0] == pts[0][0]);
        assert!((pts[2][1] - (c.y + 0.002)).abs() < 1e-7);
        assert!((pts[4][0] - (c.x + 0.002)).abs() < 1e-7);
        // Every sub-voxel centre lies in the contact voxel, and their mean is the voxel centre.
        let mean: [f32; 3] = std::array::from_fn(|a| pts.iter().map(|p| p[a]).sum::<f32>() / 8.0);
        for a in 0..3 {
            assert!((mean[a] - c[a]).abs() < 1e-6);
        }
        for p in &pts {
            assert_eq!(w.voxel_of(&nalgebra::Point3::from(*p)), Some([1, 2, 3]));
        }
    }
}
