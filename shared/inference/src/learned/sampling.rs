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
        let mut lo = [0usize; 3];
        let mut hi = [0usize; 3];
        let mut f = [0f32; 3];
        for a in 0..3 {
            let max = (self.dims[a] - 1) as f32;
            // `max(0.0)` first: a NaN coordinate becomes 0 instead of poisoning the index.
            let u = (p[a] * self.inv_voxel_size - 0.5).max(0.0).min(max);
            let i0 = (u as usize).min(self.dims[a].saturating_sub(2));
            lo[a] = i0;
            hi[a] = (i0 + 1).min(self.dims[a] - 1);
            f[a] = u - i0 as f32;
        }
        let (sx, sy) = (self.dims[1] * self.dims[2], self.dims[2]);
        let xs = [lo[0] * sx, hi[0] * sx];
        let ys = [lo[1] * sy, hi[1] * sy];
        let zs = [lo[2], hi[2]];
        let wx = [1.0 - f[0], f[0]];
        let wy = [1.0 - f[1], f[1]];
        let wz = [1.0 - f[2], f[2]];
        let mut off = [0usize; 8];
        let mut w = [0f32; 8];
        for (n, (o, wt)) in off.iter_mut().zip(w.iter_mut()).enumerate() {
            let (a, b, c) = (n >> 2, (n >> 1) & 1, n & 1);
            *o = xs[a] + ys[b] + zs[c];
            *wt = wx[a] * wy[b] * wz[c];
        }
        (off, w)
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

/// Samples every level at every point and concatenates the levels: `out` becomes the row-major
/// `[points.len(), Σ C_l]` feature matrix (resized; its allocation is reused).
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
        for i in 0..voxels {
            let (a, b, c) = (l0[i], l1[i], l2[i]);
            if !(a.is_finite() && b.is_finite() && c.is_finite()) {
                return Err(ModelError::NonFiniteOutput {
                    output: "label_logits",
                    index: i,
                });
            }
            let m = a.max(b).max(c);
            let (ea, eb, ec) = ((a - m).exp(), (b - m).exp(), (c - m).exp());
            let inv = 1.0 / (ea + eb + ec);
            self.contact[i] = eb * inv;
            self.gripper[i] = ec * inv;
        }
        Ok(())
    }
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
