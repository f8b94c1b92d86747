//! The observed scene as occupied voxels, and a fast gripper collision test against them.
//!
//! A voxel is occupied when its normalised TSDF is below [`OccupancyConfig::occupied_below_tsdf`]:
//! everything behind an observed surface counts, by default including the unobserved space under
//! and behind objects (fusion stores −1 there), so the test is conservative about what the camera
//! could not see ([`OccupancyConfig::unobserved_is_occupied`]). Space outside the grid is free.
//!
//! Boxes are tested against voxel *centres*: a voxel collides with a box when its centre lies inside
//! the box grown by `margin` (the same rule as [`OrientedBox::contains`]). The grid keeps, per
//! vertical column, a prefix count of occupied voxels, so one box costs one interval computation per
//! column of its footprint instead of one test per voxel of its bounding box.
use crate::CollisionError;
use nalgebra::{Isometry3, Point3};
use psgrasp_fusion::{GridError, NormalGridView};
use psgrasp_geometry::{GripperModel, OrientedBox, Workspace};
use serde::{Deserialize, Serialize};

/// How the observed scene is turned into occupied voxels.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OccupancyConfig {
    /// A voxel is occupied when its normalised TSDF is strictly below this value. 0 marks every
    /// voxel whose centre lies behind the observed surface; a small positive value also marks a
    /// thin layer in front of it (more conservative).
    pub occupied_below_tsdf: f32,
    /// Count unobserved voxels (normalised TSDF at or below `unobserved_at_or_below_tsdf`: beyond
    /// the truncation band behind a surface, e.g. the shadow of an object) as occupied. `true` is
    /// the safe choice; `false` checks only against space seen to be behind a surface (within the
    /// band), like point-cloud based checkers such as GPD do.
    pub unobserved_is_occupied: bool,
    /// Normalised TSDF at or below which a voxel counts as unobserved (fusion stores exactly −1).
    pub unobserved_at_or_below_tsdf: f32,
}

impl Default for OccupancyConfig {
    fn default() -> Self {
        Self {
            occupied_below_tsdf: 0.0,
            unobserved_is_occupied: true,
            unobserved_at_or_below_tsdf: -0.999,
        }
    }
}

impl OccupancyConfig {
    /// Checks the threshold lies in (−1, 1].
    pub fn validate(&self) -> Result<(), CollisionError> {
        if !(self.occupied_below_tsdf > -1.0 && self.occupied_below_tsdf <= 1.0) {
            return Err(CollisionError::InvalidConfig {
                field: "occupied_below_tsdf",
                reason: "must lie in (-1, 1]",
            });
        }
        if !(self.unobserved_at_or_below_tsdf >= -1.0
            && self.unobserved_at_or_below_tsdf < self.occupied_below_tsdf)
        {
            return Err(CollisionError::InvalidConfig {
                field: "unobserved_at_or_below_tsdf",
                reason: "must lie in [-1, occupied_below_tsdf)",
            });
        }
        Ok(())
    }
}

/// Occupied voxels of one grid, stored as per-column prefix counts for fast box queries.
#[derive(Debug, Clone, PartialEq)]
pub struct OccupancyGrid {
    workspace: Workspace,
    /// `prefix[column · (nz + 1) + k]` = occupied voxels with index `< k` in that column, where
    /// `column = i · ny + j`.
    prefix: Vec<u16>,
    /// Per column: index of the highest occupied voxel + 1 (0 for an empty column).
    heights: Vec<u16>,
    /// Per block of `BLOCK × BLOCK` columns: the largest column height.
    block_heights: Vec<u16>,
    occupied: usize,
}

/// Side of the column blocks whose maximum height lets box queries skip free space.
const BLOCK: usize = 4;

/// Inclusive voxel index range `[lo, hi]` whose centres `(k + 0.5)·s` lie in `[a, b]`, clipped to
/// `0..n`; `None` when empty.
#[inline]
fn centre_range(a: f32, b: f32, s: f32, n: usize) -> Option<(usize, usize)> {
    let lo = (a / s - 0.5).ceil().max(0.0);
    let hi = (b / s - 0.5).floor().min(n as f32 - 1.0);
    // NaN bounds (from a degenerate box) give an empty range.
    if lo.is_nan() || hi.is_nan() || lo > hi {
        return None;
    }
    Some((lo as usize, hi as usize))
}

/// One face pair (slab) of a box, prepared for vertical-line queries.
#[derive(Debug, Clone, Copy)]
enum Slab {
    /// The slab's axis is horizontal: it bounds (x, y) only, `|ax·dx + ay·dy| ≤ h`.
    Vertical { ax: f32, ay: f32, h: f32 },
    /// The slab cuts every vertical line in `z − cz ∈ kx·dx + ky·dy ± hz`.
    Tilted { kx: f32, ky: f32, hz: f32 },
}

/// A box grown by a margin, prepared for column queries.
pub(crate) struct GrownBox {
    centre: Point3<f32>,
    slabs: [Slab; 3],
    /// Workspace-frame bounds of the grown box.
    pub(crate) lo: Point3<f32>,
    pub(crate) hi: Point3<f32>,
}

impl GrownBox {
    /// `b` grown by `margin` on every side (a negative margin shrinks it); `None` for a
    /// non-finite box or one shrunk below nothing.
    pub(crate) fn new(b: &OrientedBox, margin: f32) -> Option<Self> {
        let half = [
            b.half_extents.x + margin,
            b.half_extents.y + margin,
            b.half_extents.z + margin,
        ];
        if half.iter().any(|h| !(h.is_finite() && *h >= 0.0)) {
            return None;
        }
        let rot = b.parent_from_box.rotation.to_rotation_matrix();
        let m = rot.matrix();
        let centre = Point3::from(b.parent_from_box.translation.vector);
        if !(centre.coords.iter().all(|v| v.is_finite()) && m.iter().all(|v| v.is_finite())) {
            return None;
        }
        let slabs = std::array::from_fn(|c| {
            let (ax, ay, az) = (m[(0, c)], m[(1, c)], m[(2, c)]);
            if az.abs() < 1e-6 {
                Slab::Vertical { ax, ay, h: half[c] }
            } else {
                Slab::Tilted {
                    kx: -ax / az,
                    ky: -ay / az,
                    hz: half[c] / az.abs(),
                }
            }
        });
        // Half extent of the grown box's AABB along each workspace axis.
        let ext = nalgebra::Vector3::from_fn(|r, _| {
            (0..3).map(|c| m[(r, c)].abs() * half[c]).sum::<f32>()
        });
        Some(Self {
            centre,
            slabs,
            lo: centre - ext,
            hi: centre + ext,
        })
    }

    /// The z interval of the vertical line through (x, y) inside the box, if any.
    #[inline]
    pub(crate) fn z_interval(&self, x: f32, y: f32) -> Option<(f32, f32)> {
        let (dx, dy) = (x - self.centre.x, y - self.centre.y);
        let (mut zlo, mut zhi) = (f32::NEG_INFINITY, f32::INFINITY);
        for slab in &self.slabs {
            match *slab {
                Slab::Vertical { ax, ay, h } => {
                    if (ax * dx + ay * dy).abs() > h {
                        return None;
                    }
                }
                Slab::Tilted { kx, ky, hz } => {
                    let mid = kx * dx + ky * dy;
                    zlo = zlo.max(mid - hz);
                    zhi = zhi.min(mid + hz);
                }
            }
        }
        if zlo > zhi {
            return None;
        }
        Some((self.centre.z + zlo, self.centre.z + zhi))
    }
}

impl OccupancyGrid {
    /// Occupancy of a normal grid (validated first).
    pub fn from_normal_grid(
        grid: &NormalGridView<'_>,
        cfg: &OccupancyConfig,
    ) -> Result<Self, CollisionError> {
        grid.validate()?;
        Self::from_tsdf(grid.workspace, grid.tsdf, cfg)
    }

    /// Occupancy of a normalised TSDF in workspace layout.
    pub fn from_tsdf(
        workspace: Workspace,
        tsdf: &[f32],
        cfg: &OccupancyConfig,
    ) -> Result<Self, CollisionError> {
        workspace.validate().map_err(GridError::from)?;
        cfg.validate()?;
        let n = workspace.voxel_count();
        if tsdf.len() != n {
            return Err(GridError::GridSizeMismatch {
                channel: "tsdf",
                got: tsdf.len(),
                expected: n,
            }
            .into());
        }
        let [nx, ny, nz] = workspace.dims.map(|d| d as usize);
        let mut prefix = vec![0u16; nx * ny * (nz + 1)];
        let mut occupied = 0usize;
        for column in 0..nx * ny {
            let values = &tsdf[column * nz..(column + 1) * nz];
            let out = &mut prefix[column * (nz + 1)..(column + 1) * (nz + 1)];
            let mut count = 0u16;
            for (k, &v) in values.iter().enumerate() {
                // NaN counts as occupied: unknown space is treated conservatively.
                let occupied = v < cfg.occupied_below_tsdf
                    && (cfg.unobserved_is_occupied || v > cfg.unobserved_at_or_below_tsdf);
                if occupied || v.is_nan() {
                    count += 1;
                }
                out[k + 1] = count;
            }
            occupied += count as usize;
        }
        let mut heights = vec![0u16; nx * ny];
        for (column, h) in heights.iter_mut().enumerate() {
            let p = &prefix[column * (nz + 1)..(column + 1) * (nz + 1)];
            // The highest occupied voxel is the last index where the prefix count grows.
            *h = (1..=nz).rev().find(|&k| p[k] != p[k - 1]).unwrap_or(0) as u16;
        }
        let (bx, by) = (nx.div_ceil(BLOCK), ny.div_ceil(BLOCK));
        let mut block_heights = vec![0u16; bx * by];
        for i in 0..nx {
            for j in 0..ny {
                let b = &mut block_heights[(i / BLOCK) * by + j / BLOCK];
                *b = (*b).max(heights[i * ny + j]);
            }
        }
        Ok(Self {
            workspace,
            prefix,
            heights,
            block_heights,
            occupied,
        })
    }

    /// The grid geometry.
    pub fn workspace(&self) -> &Workspace {
        &self.workspace
    }

    /// Number of occupied voxels.
    pub fn occupied_count(&self) -> usize {
        self.occupied
    }

    /// True if voxel (i, j, k) is occupied; out-of-grid voxels are free.
    pub fn is_occupied(&self, i: usize, j: usize, k: usize) -> bool {
        let [nx, ny, nz] = self.workspace.dims.map(|d| d as usize);
        if i >= nx || j >= ny || k >= nz {
            return false;
        }
        let base = (i * ny + j) * (nz + 1);
        self.prefix[base + k + 1] != self.prefix[base + k]
    }

    /// True if the voxel containing `p` is occupied (false outside the grid).
    pub fn is_occupied_at(&self, p: &Point3<f32>) -> bool {
        self.workspace
            .voxel_of(p)
            .is_some_and(|[i, j, k]| self.is_occupied(i, j, k))
    }

    /// Occupied voxels in column (i, j) with index in `[k0, k1]`.
    #[inline]
    fn column_count(&self, i: usize, j: usize, k0: usize, k1: usize) -> usize {
        let nz1 = self.workspace.dims[2] as usize + 1;
        let base = (i * self.workspace.dims[1] as usize + j) * nz1;
        (self.prefix[base + k1 + 1] - self.prefix[base + k0]) as usize
    }

    /// Visits the occupied-voxel count of every column segment inside `b`; stops early when `f`
    /// returns true and reports whether it did.
    fn visit_box(&self, b: &GrownBox, mut f: impl FnMut(usize) -> bool) -> bool {
        let s = self.workspace.voxel_size_m;
        let [nx, ny, nz] = self.workspace.dims.map(|d| d as usize);
        let (Some((i0, i1)), Some((j0, j1)), Some((kb, _))) = (
            centre_range(b.lo.x, b.hi.x, s, nx),
            centre_range(b.lo.y, b.hi.y, s, ny),
            centre_range(b.lo.z, b.hi.z, s, nz),
        ) else {
            return false;
        };
        let by = ny.div_ceil(BLOCK);
        for bi in i0 / BLOCK..=i1 / BLOCK {
            for bj in j0 / BLOCK..=j1 / BLOCK {
                // Everything occupied in this block lies below the box's lowest voxel layer.
                if (self.block_heights[bi * by + bj] as usize) <= kb {
                    continue;
                }
                for i in (bi * BLOCK).max(i0)..=(bi * BLOCK + BLOCK - 1).min(i1) {
                    let x = (i as f32 + 0.5) * s;
                    for j in (bj * BLOCK).max(j0)..=(bj * BLOCK + BLOCK - 1).min(j1) {
                        if (self.heights[i * ny + j] as usize) <= kb {
                            continue;
                        }
                        let y = (j as f32 + 0.5) * s;
                        let Some((za, zb)) = b.z_interval(x, y) else {
                            continue;
                        };
                        let Some((k0, k1)) = centre_range(za, zb, s, nz) else {
                            continue;
                        };
                        let c = self.column_count(i, j, k0, k1);
                        if c > 0 && f(c) {
                            return true;
                        }
                    }
                }
            }
        }
        false
    }

    /// True if any occupied voxel centre lies inside `b` grown by `margin`. A box with non-finite
    /// pose or size, or a negative grown size, counts as colliding (fail safe).
    pub fn box_collides(&self, b: &OrientedBox, margin: f32) -> bool {
        match GrownBox::new(b, margin) {
            Some(g) => self.visit_box(&g, |_| true),
            None => true,
        }
    }

    /// Number of occupied voxel centres inside `b` grown by `margin` (`usize::MAX` for an invalid
    /// box, see [`Self::box_collides`]).
    pub fn count_in_box(&self, b: &OrientedBox, margin: f32) -> usize {
        let Some(g) = GrownBox::new(b, margin) else {
            return usize::MAX;
        };
        let mut total = 0;
        self.visit_box(&g, |c| {
            total += c;
            false
        });
        total
    }

    /// Number of occupied voxel centres inside the union of `boxes`, each grown by `margin`
    /// (a voxel inside several boxes counts once; `usize::MAX` if any box is invalid).
    pub fn count_in_union(&self, boxes: &[OrientedBox], margin: f32) -> usize {
        let grown: Option<Vec<GrownBox>> = boxes.iter().map(|b| GrownBox::new(b, margin)).collect();
        let Some(grown) = grown else {
            return usize::MAX;
        };
        if grown.is_empty() {
            return 0;
        }
        let s = self.workspace.voxel_size_m;
        let [nx, ny, nz] = self.workspace.dims.map(|d| d as usize);
        let lo = grown.iter().fold(grown[0].lo, |a, g| a.inf(&g.lo));
        let hi = grown.iter().fold(grown[0].hi, |a, g| a.sup(&g.hi));
        let (Some((i0, i1)), Some((j0, j1)), Some((kb, _))) = (
            centre_range(lo.x, hi.x, s, nx),
            centre_range(lo.y, hi.y, s, ny),
            centre_range(lo.z, hi.z, s, nz),
        ) else {
            return 0;
        };
        let mut total = 0;
        let mut ranges: Vec<(usize, usize)> = Vec::with_capacity(grown.len());
        for i in i0..=i1 {
            let x = (i as f32 + 0.5) * s;
            for j in j0..=j1 {
                // Everything occupied in this column lies below the lowest box layer.
                if (self.heights[i * ny + j] as usize) <= kb {
                    continue;
                }
                let y = (j as f32 + 0.5) * s;
                ranges.clear();
                ranges.extend(
                    grown
                        .iter()
                        .filter_map(|g| g.z_interval(x, y))
                        .filter_map(|(a, b)| centre_range(a, b, s, nz)),
                );
                ranges.sort_unstable();
                // Merge overlapping index ranges and count each once.
                let mut current: Option<(usize, usize)> = None;
                for &(a, b) in ranges.iter() {
                    match current {
                        Some((ca, cb)) if a <= cb + 1 => current = Some((ca, cb.max(b))),
                        Some((ca, cb)) => {
                            total += self.column_count(i, j, ca, cb);
                            current = Some((a, b));
                        }
                        None => current = Some((a, b)),
                    }
                }
                if let Some((ca, cb)) = current {
                    total += self.column_count(i, j, ca, cb);
                }
            }
        }
        total
    }
}

/// The occupancy of the observed scene together with the gripper model: the collision test shared
/// by the inference backends and grasp selection.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneCollisionChecker {
    occupancy: OccupancyGrid,
    gripper: GripperModel,
}

impl SceneCollisionChecker {
    /// Wraps an occupancy grid and a gripper.
    pub fn new(occupancy: OccupancyGrid, gripper: GripperModel) -> Self {
        Self { occupancy, gripper }
    }

    /// Builds the occupancy of `grid` and wraps it with `gripper`.
    pub fn from_normal_grid(
        grid: &NormalGridView<'_>,
        cfg: &OccupancyConfig,
        gripper: GripperModel,
    ) -> Result<Self, CollisionError> {
        Ok(Self::new(
            OccupancyGrid::from_normal_grid(grid, cfg)?,
            gripper,
        ))
    }

    /// The occupancy grid.
    pub fn occupancy(&self) -> &OccupancyGrid {
        &self.occupancy
    }

    /// The gripper model.
    pub fn gripper(&self) -> &GripperModel {
        &self.gripper
    }

    /// True if the gripper (palm and both fingers at `opening_m`, see
    /// [`GripperModel::boxes`]) placed at `workspace_from_gripper` and grown by `margin` contains
    /// an occupied voxel centre. Fingers are tested first: they are the likelier to collide.
    pub fn gripper_collides(
        &self,
        workspace_from_gripper: &Isometry3<f32>,
        opening_m: f32,
        margin: f32,
    ) -> bool {
        let [palm, left, right] = self.gripper.boxes(workspace_from_gripper, opening_m);
        [left, right, palm]
            .iter()
            .any(|b| self.occupancy.box_collides(b, margin))
    }

    /// Number of occupied voxel centres inside the gripper (each voxel counted once).
    pub fn gripper_collision_count(
        &self,
        workspace_from_gripper: &Isometry3<f32>,
        opening_m: f32,
        margin: f32,
    ) -> usize {
        self.occupancy.count_in_union(
            &self.gripper.boxes(workspace_from_gripper, opening_m),
            margin,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion, Vector3};

    /// A 20³ grid of 1 cm voxels occupied below z = 5 cm (a floor).
    fn floor_grid() -> OccupancyGrid {
        let ws = Workspace {
            dims: [20, 20, 20],
            voxel_size_m: 0.01,
        };
        let tsdf: Vec<f32> = (0..ws.voxel_count())
            .map(|idx| {
                let [i, j, k] = ws.unindex(idx);
                let z = ws.voxel_center(i, j, k).z;
                ((z - 0.05) / 0.03).clamp(-1.0, 1.0)
            })
            .collect();
        OccupancyGrid::from_tsdf(ws, &tsdf, &OccupancyConfig::default()).unwrap()
    }

    /// Brute-force reference: test every voxel centre with `OrientedBox::contains`.
    fn brute_count(g: &OccupancyGrid, b: &OrientedBox, margin: f32) -> usize {
        let ws = *g.workspace();
        (0..ws.voxel_count())
            .filter(|&idx| {
                let [i, j, k] = ws.unindex(idx);
                g.is_occupied(i, j, k) && b.contains(&ws.voxel_center(i, j, k), margin)
            })
            .count()
    }

    #[test]
    fn floor_occupancy_is_the_lower_five_layers() {
        let g = floor_grid();
        assert_eq!(g.occupied_count(), 20 * 20 * 5);
        assert!(g.is_occupied(3, 4, 4));
        assert!(!g.is_occupied(3, 4, 5));
        assert!(!g.is_occupied(30, 4, 0), "outside the grid is free");
        assert!(g.is_occupied_at(&Point3::new(0.1, 0.1, 0.01)));
    }

    #[test]
    fn column_queries_match_brute_force_for_rotated_boxes() {
        let g = floor_grid();
        let mut checked = 0;
        for (n, angle) in [0.0f32, 0.3, 0.9, 1.7, 2.5].iter().enumerate() {
            for z in [0.02f32, 0.045, 0.06, 0.09] {
                let rot = UnitQuaternion::from_scaled_axis(
                    Vector3::new(1.0, 0.5 * n as f32, 0.2).normalize() * *angle,
                );
                let b = OrientedBox {
                    parent_from_box: Isometry3::from_parts(Translation3::new(0.1, 0.08, z), rot),
                    half_extents: Vector3::new(0.04, 0.015, 0.025),
                };
                for margin in [0.0, 0.004] {
                    let expected = brute_count(&g, &b, margin);
                    assert_eq!(
                        g.count_in_box(&b, margin),
                        expected,
                        "angle {angle} z {z} margin {margin}"
                    );
                    assert_eq!(g.box_collides(&b, margin), expected > 0);
                    checked += usize::from(expected > 0);
                }
            }
        }
        assert!(checked > 10, "the sweep must include colliding boxes");
    }

    #[test]
    fn column_queries_match_brute_force_in_clutter() {
        use nalgebra::Point2;
        use psgrasp_test_support::synthetic::SyntheticScene;
        use rand::{Rng, SeedableRng};
        let ws = Workspace {
            dims: [30, 26, 20],
            voxel_size_m: 0.009,
        };
        let scene = SyntheticScene::random_clutter(
            0.02,
            Point2::new(0.03, 0.03),
            Point2::new(0.24, 0.2),
            10,
            3,
        );
        let grid = scene.normal_grid(ws, 0.027);
        let g = OccupancyGrid::from_normal_grid(&grid.view(), &OccupancyConfig::default()).unwrap();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let (mut colliding, mut free) = (0, 0);
        for _ in 0..300 {
            let rot = UnitQuaternion::from_scaled_axis(Vector3::from_fn(|_, _| {
                rng.random_range(-2.0f32..2.0)
            }));
            let t = Translation3::new(
                rng.random_range(-0.02..0.3),
                rng.random_range(-0.02..0.26),
                rng.random_range(0.0..0.2),
            );
            let half = Vector3::from_fn(|_, _| rng.random_range(0.004f32..0.06));
            let b = OrientedBox {
                parent_from_box: Isometry3::from_parts(t, rot),
                half_extents: half,
            };
            let expected = brute_count(&g, &b, 0.003);
            assert_eq!(g.count_in_box(&b, 0.003), expected);
            assert_eq!(g.box_collides(&b, 0.003), expected > 0);
            assert_eq!(g.count_in_union(&[b], 0.003), expected);
            if expected > 0 {
                colliding += 1
            } else {
                free += 1
            }
        }
        assert!(
            colliding > 30 && free > 30,
            "{colliding} colliding, {free} free"
        );
    }

    #[test]
    fn union_counts_overlapping_voxels_once() {
        let g = floor_grid();
        let b = OrientedBox {
            parent_from_box: Isometry3::translation(0.1, 0.1, 0.03),
            half_extents: Vector3::new(0.03, 0.03, 0.03),
        };
        let single = g.count_in_box(&b, 0.0);
        assert!(single > 0);
        assert_eq!(g.count_in_union(&[b, b], 0.0), single);
        let shifted = OrientedBox {
            parent_from_box: Isometry3::translation(0.13, 0.1, 0.03),
            ..b
        };
        let both = g.count_in_box(&b, 0.0) + g.count_in_box(&shifted, 0.0);
        let union = g.count_in_union(&[b, shifted], 0.0);
        assert!(union < both && union > single);
    }

    #[test]
    fn gripper_above_the_floor_is_free_and_lowered_into_it_collides() {
        let g = SceneCollisionChecker::new(floor_grid(), GripperModel::default());
        // Straight down: gripper z = −workspace z.
        let down = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f32::consts::PI);
        let tip = GripperModel::default().tip_beyond_tcp_m;
        // Fingertips 1 cm above the floor surface (occupied centres reach z = 4.5 cm).
        let above = Isometry3::from_parts(Translation3::new(0.1, 0.1, 0.05 + tip + 0.01), down);
        assert!(!g.gripper_collides(&above, 0.05, 0.002));
        assert_eq!(g.gripper_collision_count(&above, 0.05, 0.002), 0);
        let into = Isometry3::from_parts(Translation3::new(0.1, 0.1, 0.05 + tip - 0.015), down);
        assert!(g.gripper_collides(&into, 0.05, 0.0));
        assert!(g.gripper_collision_count(&into, 0.05, 0.0) > 0);
        // A NaN pose fails safe.
        let nan = Isometry3::from_parts(Translation3::new(f32::NAN, 0.1, 0.5), down);
        assert!(g.gripper_collides(&nan, 0.05, 0.0));
    }

    #[test]
    fn unobserved_space_is_occupied_only_when_asked() {
        // One column: free above, a band behind the surface, then unobserved (−1) below.
        let ws = Workspace {
            dims: [1, 1, 6],
            voxel_size_m: 0.01,
        };
        let tsdf = [-1.0, -1.0, -0.6, -0.2, 0.3, 1.0];
        let safe = OccupancyGrid::from_tsdf(ws, &tsdf, &OccupancyConfig::default()).unwrap();
        assert_eq!(safe.occupied_count(), 4);
        let seen_only = OccupancyConfig {
            unobserved_is_occupied: false,
            ..OccupancyConfig::default()
        };
        let optimistic = OccupancyGrid::from_tsdf(ws, &tsdf, &seen_only).unwrap();
        assert_eq!(optimistic.occupied_count(), 2);
        assert!(!optimistic.is_occupied(0, 0, 0) && optimistic.is_occupied(0, 0, 2));
        let bad = OccupancyConfig {
            unobserved_at_or_below_tsdf: 0.5,
            ..OccupancyConfig::default()
        };
        assert!(OccupancyGrid::from_tsdf(ws, &tsdf, &bad).is_err());
    }

    #[test]
    fn bad_inputs_are_errors() {
        let ws = Workspace {
            dims: [2, 2, 2],
            voxel_size_m: 0.01,
        };
        assert!(matches!(
            OccupancyGrid::from_tsdf(ws, &[0.0; 7], &OccupancyConfig::default()),
            Err(CollisionError::Grid(GridError::GridSizeMismatch { .. }))
        ));
        assert!(matches!(
            OccupancyGrid::from_tsdf(
                ws,
                &[0.0; 8],
                &OccupancyConfig {
                    occupied_below_tsdf: 2.0,
                    ..OccupancyConfig::default()
                }
            ),
            Err(CollisionError::InvalidConfig { .. })
        ));
    }
}
