//! The analytic antipodal backend: the geometric (GPD-style) baseline.
//!
//! For one normal grid:
//!
//! 1. **Surface points.** Every free voxel (tsdf ≥ 0) with an occupied 6-neighbour and a stored
//!    normal `n` is a candidate first contact, placed at `centre − d·n`. `d` is the smaller of the
//!    stored distance `tsdf·truncation` and the distance to where the TSDF crosses zero along `−n`
//!    (searched up to [`AnalyticConfig::surface_search_voxels`]): both are at least the true
//!    distance for an exact field, and a projective TSDF overstates distances to surfaces seen at
//!    grazing angles — the sides of objects in a top-down view — where the crossing is the better
//!    estimate, while at edges the stored value is. Contacts whose outward
//!    normal is within [`AnalyticConfig::skip_upward_normals_deg`] of straight up are skipped: their
//!    inward ray runs down into whatever supports the object, never to a graspable opposite face.
//!    Normals tilted upward by less than [`AnalyticConfig::vertical_face_tilt_deg`] are made
//!    horizontal (here and at observed second contacts): a TSDF fused from a top-down view tilts the
//!    normals of vertical side faces ~20° upward, which otherwise sends the inward baseline down
//!    into the support and fails the opposite face's friction-cone test.
//! 2. **Sampling (seeded).** Up to [`AnalyticConfig::max_contact_samples`] contacts are drawn without
//!    replacement; for each, [`AnalyticConfig::directions_per_contact`] baselines are tried: the
//!    inward normal `−n₁` itself and directions drawn uniformly in the friction cone around it.
//! 3. **Second contact.** A ray from the contact along the baseline walks the trilinear TSDF until it
//!    leaves the occupied region (the TSDF crosses zero from below) within
//!    `max opening − width_margin_m`. Two cases:
//!    - *observed*: the interpolated grid normal at the exit point is valid — it is the second
//!      contact's normal `n₂`, which must lie inside the friction cone around the baseline;
//!      `q = antipodal_quality(b, n₁, n₂)`.
//!    - *occluded*: no valid normal there. From a single top-down view the far side of an object is
//!      often not seen; the TSDF then stays at −1 through the object's shadow and jumps to +1 where
//!      the shadow ends, so the exit point is the farthest the object can extend along the ray. We
//!      accept it (if [`AnalyticConfig::occluded_second_contact`]) with that width — an upper bound,
//!      so the gripper opens wide enough — and, since `n₂` is unknown, the estimated quality
//!      `q = |b·n₁| · occluded_quality_factor`, which ranks such grasps below observed antipodal pairs.
//!
//!    The best baseline per contact (highest `q`) is kept: one configuration per contact point.
//! 4. **Collision scores.** For the 18 approach vectors `a_i` of the baseline, the gripper at opening
//!    `min(w + clearance.opening_clearance_m, max opening)` is tested against the observed occupancy
//!    ([`SceneCollisionChecker`]): `σ_i = 1` if free, else 0.
//!
//! Configurations are returned sorted by quality (descending), at most
//! [`AnalyticConfig::max_configurations`]; `κ = 0` (this backend does not model the baseline
//! uncertainty). Same grid and seed → same output.
mod config;

pub use config::{AnalyticConfig, ContactRegion};

use crate::{validate_grid, validate_gripper, InferenceBackend, InferenceError};
use nalgebra::{Point3, Vector3};
use psgrasp_collision::{OccupancyGrid, SceneCollisionChecker};
use psgrasp_fusion::NormalGridView;
use psgrasp_geometry::{
    antipodal_quality, approach_vectors, ContactGrasp, GraspConfiguration, GripperModel,
    N_APPROACHES,
};
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// Counters of the last [`AnalyticBackend::infer`] call, for logs and tuning.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct AnalyticStats {
    /// Surface-band voxels eligible as first contacts.
    pub surface_voxels: usize,
    /// Contacts sampled from them.
    pub sampled_contacts: usize,
    /// Rays cast (contacts × directions).
    pub rays_cast: usize,
    /// Rays that found an observed second contact.
    pub observed_exits: usize,
    /// Rays that found an occluded second contact.
    pub occluded_exits: usize,
    /// Contacts whose best baseline reached the quality threshold.
    pub candidates: usize,
    /// Candidates dropped because all 18 approaches collide.
    pub all_approaches_colliding: usize,
    /// Configurations returned.
    pub configurations: usize,
}

/// A surface point usable as a first contact.
#[derive(Debug, Clone, Copy)]
struct SurfacePoint {
    point: Point3<f32>,
    normal: Vector3<f32>,
}

/// Where a ray leaves the occupied region.
#[derive(Debug, Clone, Copy)]
enum Exit {
    /// A seen surface with this unit outward normal.
    Observed { width: f32, normal: Vector3<f32> },
    /// The unobserved side: no normal is known.
    Occluded { width: f32 },
}

/// A contact with its best baseline, before collision scoring.
#[derive(Debug, Clone, Copy)]
struct Candidate {
    contact: Point3<f32>,
    baseline: Vector3<f32>,
    width: f32,
    quality: f32,
}

/// The analytic antipodal backend (see the module docs).
#[derive(Debug, Clone)]
pub struct AnalyticBackend {
    cfg: AnalyticConfig,
    gripper: GripperModel,
    stats: AnalyticStats,
}

/// A unit vector uniformly distributed in the cone of half-angle `half_angle` around unit `axis`.
fn sample_in_cone(rng: &mut impl Rng, axis: &Vector3<f32>, half_angle: f32) -> Vector3<f32> {
    let cos_max = half_angle.cos();
    let cos_t = 1.0 - rng.random::<f32>() * (1.0 - cos_max);
    let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
    let phi = rng.random::<f32>() * std::f32::consts::TAU;
    let helper = if axis.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let e1 = axis.cross(&helper).normalize();
    let e2 = axis.cross(&e1);
    (axis * cos_t + e1 * (sin_t * phi.cos()) + e2 * (sin_t * phi.sin())).normalize()
}

impl AnalyticBackend {
    /// A backend with validated settings for `gripper`.
    pub fn new(cfg: AnalyticConfig, gripper: GripperModel) -> Result<Self, InferenceError> {
        cfg.validate()?;
        validate_gripper(&gripper)?;
        if gripper.max_opening_m - cfg.width_margin_m <= cfg.min_width_m {
            return Err(InferenceError::InvalidConfig {
                field: "width_margin_m",
                reason: "max opening minus width margin must exceed min_width_m",
            });
        }
        Ok(Self {
            cfg,
            gripper,
            stats: AnalyticStats::default(),
        })
    }

    /// The settings.
    pub fn config(&self) -> &AnalyticConfig {
        &self.cfg
    }

    /// The gripper model.
    pub fn gripper(&self) -> &GripperModel {
        &self.gripper
    }

    /// Counters of the last call to [`InferenceBackend::infer`].
    pub fn last_stats(&self) -> AnalyticStats {
        self.stats
    }

    /// `n` (unit) with a small upward tilt removed (see [`AnalyticConfig::vertical_face_tilt_deg`]).
    fn deskew(&self, n: Vector3<f32>) -> Vector3<f32> {
        let sin_tol = self.cfg.vertical_face_tilt_deg.to_radians().sin();
        if n.z > 0.0 && n.z < sin_tol {
            let h = Vector3::new(n.x, n.y, 0.0);
            let len = h.norm();
            if len > 1e-6 {
                return h / len;
            }
        }
        n
    }

    /// Candidate first contacts of the grid, in voxel order.
    fn surface_points(&self, grid: &NormalGridView<'_>) -> Vec<SurfacePoint> {
        let ws = &grid.workspace;
        let [nx, ny, nz] = ws.dims.map(|d| d as usize);
        let up_cos = self.cfg.skip_upward_normals_deg.to_radians().cos();
        let search = self.cfg.surface_search_voxels * ws.voxel_size_m;
        let tsdf = grid.tsdf;
        let mut out = Vec::new();
        for (idx, &t) in tsdf.iter().enumerate() {
            if t < 0.0 {
                continue;
            }
            let [i, j, k] = ws.unindex(idx);
            // A free voxel next to an occupied one: the surface passes between them.
            let (sy, sz) = (nz, 1);
            let sx = ny * nz;
            let behind = (i > 0 && tsdf[idx - sx] < 0.0)
                || (i + 1 < nx && tsdf[idx + sx] < 0.0)
                || (j > 0 && tsdf[idx - sy] < 0.0)
                || (j + 1 < ny && tsdf[idx + sy] < 0.0)
                || (k > 0 && tsdf[idx - sz] < 0.0)
                || (k + 1 < nz && tsdf[idx + sz] < 0.0);
            if !behind {
                continue;
            }
            let n = Vector3::from(grid.normal(idx));
            let len = n.norm();
            if len < self.cfg.min_normal_norm {
                continue;
            }
            let n = n / len;
            if n.z >= up_cos {
                continue;
            }
            // Two estimates of the distance to the surface, both at least the true one when the
            // field is exact or overstated (projective): the stored value and the zero crossing
            // along −n. The smaller is the better; the stored value alone only if plausible.
            let centre = ws.voxel_center(i, j, k);
            let stored = t * grid.truncation_m;
            let d = match self.surface_along(grid, &centre, &n) {
                Some(crossing) => stored.min(crossing),
                None if stored <= search => stored,
                None => continue,
            };
            let point = centre - n * d;
            if self.cfg.contact_region.is_some_and(|r| !r.contains(&point)) {
                continue;
            }
            out.push(SurfacePoint {
                point,
                normal: self.deskew(n),
            });
        }
        out
    }

    /// Distance from the free point `from` along `−normal` to where the TSDF crosses zero, if
    /// within [`AnalyticConfig::surface_search_voxels`].
    fn surface_along(
        &self,
        grid: &NormalGridView<'_>,
        from: &Point3<f32>,
        normal: &Vector3<f32>,
    ) -> Option<f32> {
        let ws = &grid.workspace;
        let step = self.cfg.ray_step_voxels * ws.voxel_size_m;
        let limit = self.cfg.surface_search_voxels * ws.voxel_size_m;
        let (mut dp, mut vp) = (0.0, ws.trilinear(grid.tsdf, from));
        let mut d = step;
        while d <= limit + 1e-6 {
            let p = from - normal * d;
            if !ws.contains(&p) {
                return None;
            }
            let v = ws.trilinear(grid.tsdf, &p);
            if v < 0.0 {
                let at = if vp > v {
                    dp + (d - dp) * vp / (vp - v)
                } else {
                    d
                };
                return Some(at);
            }
            (dp, vp) = (d, v);
            d += step;
        }
        None
    }

    /// Marches from `start` along unit `dir` to where the ray leaves the occupied region.
    fn cast(
        &self,
        grid: &NormalGridView<'_>,
        start: &Point3<f32>,
        dir: &Vector3<f32>,
        max_width: f32,
    ) -> Option<Exit> {
        let ws = &grid.workspace;
        let step = self.cfg.ray_step_voxels * ws.voxel_size_m;
        let entry_limit = self.cfg.entry_search_voxels * ws.voxel_size_m + step;
        let mut prev: Option<(f32, f32)> = None;
        let mut t = step;
        while t <= max_width + step {
            let p = start + dir * t;
            if !ws.contains(&p) {
                return None;
            }
            let v = ws.trilinear(grid.tsdf, &p);
            match prev {
                None => {
                    if v < 0.0 {
                        prev = Some((t, v));
                    } else if t > entry_limit {
                        return None;
                    }
                }
                Some((tp, vp)) if v >= 0.0 => {
                    let width = tp + (t - tp) * (-vp) / (v - vp);
                    if width < self.cfg.min_width_m || width > max_width {
                        return None;
                    }
                    let exit = start + dir * width;
                    let n = ws.voxel_count();
                    let normal = Vector3::from_fn(|a, _| {
                        ws.trilinear(&grid.normals[a * n..(a + 1) * n], &exit)
                    });
                    let len = normal.norm();
                    return Some(if len >= self.cfg.min_normal_norm {
                        Exit::Observed {
                            width,
                            normal: self.deskew(normal / len),
                        }
                    } else {
                        Exit::Occluded { width }
                    });
                }
                Some(_) => prev = Some((t, v)),
            }
            t += step;
        }
        None
    }

    /// The best baseline at one contact, if any reaches the quality threshold.
    fn best_candidate(
        &mut self,
        grid: &NormalGridView<'_>,
        sp: &SurfacePoint,
        rng: &mut ChaCha8Rng,
    ) -> Option<Candidate> {
        let cone = self.cfg.friction_cone_half_angle_deg.to_radians();
        let cone_cos = cone.cos();
        let max_width = self.gripper.max_opening_m - self.cfg.width_margin_m;
        let inward = -sp.normal;
        let mut best: Option<Candidate> = None;
        for d in 0..self.cfg.directions_per_contact {
            let b = if d == 0 {
                inward
            } else {
                sample_in_cone(rng, &inward, cone)
            };
            self.stats.rays_cast += 1;
            let (width, quality) = match self.cast(grid, &sp.point, &b, max_width) {
                None => continue,
                Some(Exit::Observed { width, normal }) => {
                    self.stats.observed_exits += 1;
                    if normal.dot(&b) < cone_cos {
                        continue;
                    }
                    (width, antipodal_quality(&b, &sp.normal, &normal))
                }
                Some(Exit::Occluded { width }) => {
                    self.stats.occluded_exits += 1;
                    if !self.cfg.occluded_second_contact {
                        continue;
                    }
                    (
                        width,
                        b.dot(&sp.normal).abs() * self.cfg.occluded_quality_factor,
                    )
                }
            };
            let second = sp.point + b * width;
            if self
                .cfg
                .contact_region
                .is_some_and(|r| !r.contains(&second))
            {
                continue;
            }
            if best.is_none_or(|c| quality > c.quality) {
                best = Some(Candidate {
                    contact: sp.point,
                    baseline: b,
                    width,
                    quality,
                });
            }
        }
        best.filter(|c| c.quality >= self.cfg.min_quality)
    }

    /// Collision scores of the 18 approaches of a candidate.
    fn collision_scores(
        &self,
        checker: &SceneCollisionChecker,
        c: &Candidate,
    ) -> [f32; N_APPROACHES] {
        let opening = self
            .cfg
            .clearance
            .opening_m(c.width, self.gripper.max_opening_m);
        let approaches = approach_vectors(&c.baseline);
        std::array::from_fn(|i| {
            let grasp = ContactGrasp {
                contact: c.contact,
                baseline: c.baseline,
                approach: approaches[i],
                width: c.width,
            };
            let pose = grasp.workspace_from_gripper();
            if checker.gripper_collides(&pose, opening, self.cfg.clearance.collision_margin_m) {
                0.0
            } else {
                1.0
            }
        })
    }
}

impl InferenceBackend for AnalyticBackend {
    fn name(&self) -> &str {
        "analytic"
    }

    fn infer(
        &mut self,
        grid: &NormalGridView<'_>,
        seed: u64,
    ) -> Result<Vec<GraspConfiguration>, InferenceError> {
        validate_grid(grid)?;
        self.stats = AnalyticStats::default();
        let occupancy = OccupancyGrid::from_tsdf(grid.workspace, grid.tsdf, &self.cfg.occupancy)?;
        let checker = SceneCollisionChecker::new(occupancy, self.gripper);
        let mut rng = ChaCha8Rng::seed_from_u64(seed);

        let mut surface = self.surface_points(grid);
        self.stats.surface_voxels = surface.len();
        surface.shuffle(&mut rng);
        surface.truncate(self.cfg.max_contact_samples);
        self.stats.sampled_contacts = surface.len();

        let mut candidates: Vec<Candidate> = Vec::new();
        for sp in &surface {
            if let Some(c) = self.best_candidate(grid, sp, &mut rng) {
                candidates.push(c);
            }
        }
        self.stats.candidates = candidates.len();
        // Stable sort: equal qualities keep the (seeded) sampling order.
        candidates.sort_by(|a, b| b.quality.total_cmp(&a.quality));

        let mut out = Vec::with_capacity(candidates.len().min(self.cfg.max_configurations));
        for c in &candidates {
            if out.len() >= self.cfg.max_configurations {
                break;
            }
            let collision_scores = self.collision_scores(&checker, c);
            if self.cfg.require_free_approach && collision_scores.iter().all(|&s| s == 0.0) {
                self.stats.all_approaches_colliding += 1;
                continue;
            }
            out.push(GraspConfiguration {
                contact: c.contact,
                baseline: c.baseline,
                collision_scores,
                width: c.width,
                quality: c.quality,
                kappa: 0.0,
                kappa_floor: 0.0,
            });
        }
        self.stats.configurations = out.len();
        Ok(out)
    }
}
