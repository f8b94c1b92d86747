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
//!    `min(w + opening_clearance_m, max opening)` is tested against the observed occupancy
//!    ([`SceneCollisionChecker`]): `σ_i = 1` if free, else 0.
//!
//! Configurations are returned sorted by quality (descending), at most
//! [`AnalyticConfig::max_configurations`]; `κ = 0` (this backend does not model the baseline
//! uncertainty). Same grid and seed → same output.
use crate::{validate_grid, validate_gripper, InferenceBackend, InferenceError};
use nalgebra::{Point3, Vector3};
use psgrasp_collision::{OccupancyConfig, OccupancyGrid, SceneCollisionChecker};
use psgrasp_fusion::NormalGridView;
use psgrasp_geometry::{
    antipodal_quality, approach_vectors, BinModel, ContactGrasp, GraspConfiguration, GripperModel,
    N_APPROACHES,
};
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// Settings of the analytic backend; every threshold has a default tuned for the 9 mm grid.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AnalyticConfig {
    /// How far (voxels) the zero crossing is searched along `−n` from a free voxel next to the
    /// surface; without a crossing, stored distances beyond this are not trusted.
    pub surface_search_voxels: f32,
    /// A stored or interpolated normal shorter than this is "no normal" (outside the band).
    pub min_normal_norm: f32,
    /// Contacts whose outward normal is within this angle of straight up are not sampled.
    pub skip_upward_normals_deg: f32,
    /// Normals tilted upward by less than this angle from horizontal are treated as horizontal
    /// (first contacts and observed second contacts). A TSDF fused from a top-down view tilts
    /// the normals of vertical side faces upward by ~20° (the projective distance shrinks with
    /// height along the face); without this the inward baseline dives into the support and the
    /// opposite face fails the friction cone. 0 disables it.
    pub vertical_face_tilt_deg: f32,
    /// Most contacts sampled per frame.
    pub max_contact_samples: usize,
    /// Baselines tried per contact: `−n₁` plus `directions_per_contact − 1` drawn in the cone.
    pub directions_per_contact: usize,
    /// Friction cone half-angle: baselines are sampled within it around `−n₁`, and an observed
    /// second contact's normal must lie within it around the baseline.
    pub friction_cone_half_angle_deg: f32,
    /// Ray-marching step in voxels.
    pub ray_step_voxels: f32,
    /// How far (voxels) a ray may travel from the contact before it must enter the occupied region.
    pub entry_search_voxels: f32,
    /// Smallest accepted opening width.
    pub min_width_m: f32,
    /// Widths must be at most `max_opening − width_margin_m` (grasps close to the maximum opening
    /// fail in execution).
    pub width_margin_m: f32,
    /// Accept second contacts on the unobserved side (see the module docs).
    pub occluded_second_contact: bool,
    /// Quality factor for occluded second contacts, in [0, 1].
    pub occluded_quality_factor: f32,
    /// Configurations with a lower antipodal quality are dropped.
    pub min_quality: f32,
    /// Most configurations returned per frame (the best by quality).
    pub max_configurations: usize,
    /// Opening used for the collision scores: width plus this clearance (capped at the maximum).
    pub opening_clearance_m: f32,
    /// Gripper boxes are grown by this margin for the collision scores.
    pub collision_margin_m: f32,
    /// Drop configurations whose 18 approaches all collide.
    pub require_free_approach: bool,
    /// How the TSDF becomes occupied voxels.
    pub occupancy: OccupancyConfig,
    /// If set, both contacts must lie inside this box (e.g. the bin's inner volume, see
    /// [`ContactRegion::inside_bin`]); otherwise the whole grid is used, bin walls included.
    pub contact_region: Option<ContactRegion>,
}

/// An axis-aligned box of the workspace frame that grasp contacts must lie in.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ContactRegion {
    /// Minimum corner, metres.
    pub min_m: [f32; 3],
    /// Maximum corner, metres.
    pub max_m: [f32; 3],
}

impl ContactRegion {
    /// The inner volume of `bin` shrunk by `inset_m` on every side (the floor side included), so
    /// that the walls and floor themselves are never grasped.
    pub fn inside_bin(bin: &BinModel, inset_m: f32) -> Self {
        let [lx, ly, lz] = bin.inner_size_m;
        let c = bin.floor_center;
        Self {
            min_m: [
                c.x - 0.5 * lx + inset_m,
                c.y - 0.5 * ly + inset_m,
                c.z + inset_m,
            ],
            max_m: [
                c.x + 0.5 * lx - inset_m,
                c.y + 0.5 * ly - inset_m,
                c.z + lz - inset_m,
            ],
        }
    }

    /// True if `p` lies inside the region (boundary included).
    pub fn contains(&self, p: &Point3<f32>) -> bool {
        (0..3).all(|a| p[a] >= self.min_m[a] && p[a] <= self.max_m[a])
    }

    /// Checks the corners are finite and ordered.
    pub fn validate(&self) -> Result<(), InferenceError> {
        let ok = (0..3).all(|a| {
            self.min_m[a].is_finite() && self.max_m[a].is_finite() && self.min_m[a] <= self.max_m[a]
        });
        check(
            ok,
            "contact_region",
            "corners must be finite with min_m <= max_m",
        )
    }
}

impl Default for AnalyticConfig {
    fn default() -> Self {
        Self {
            surface_search_voxels: 1.5,
            min_normal_norm: 0.5,
            skip_upward_normals_deg: 25.0,
            vertical_face_tilt_deg: 30.0,
            max_contact_samples: 4000,
            directions_per_contact: 8,
            friction_cone_half_angle_deg: 20.0,
            ray_step_voxels: 0.25,
            entry_search_voxels: 1.0,
            min_width_m: 0.005,
            width_margin_m: 0.01,
            occluded_second_contact: true,
            occluded_quality_factor: 0.75,
            min_quality: 0.5,
            max_configurations: 1000,
            opening_clearance_m: 0.02,
            collision_margin_m: 0.004,
            require_free_approach: true,
            occupancy: OccupancyConfig::default(),
            contact_region: None,
        }
    }
}

fn check(ok: bool, field: &'static str, reason: &'static str) -> Result<(), InferenceError> {
    if ok {
        Ok(())
    } else {
        Err(InferenceError::InvalidConfig { field, reason })
    }
}

impl AnalyticConfig {
    /// Checks every field's range.
    pub fn validate(&self) -> Result<(), InferenceError> {
        let c = self;
        check(
            c.surface_search_voxels > 0.0 && c.surface_search_voxels <= 3.0,
            "surface_search_voxels",
            "must lie in (0, 3]",
        )?;
        check(
            c.min_normal_norm > 0.0 && c.min_normal_norm <= 1.0,
            "min_normal_norm",
            "must lie in (0, 1]",
        )?;
        check(
            (0.0..=90.0).contains(&c.skip_upward_normals_deg),
            "skip_upward_normals_deg",
            "must lie in [0, 90]",
        )?;
        check(
            (0.0..45.0).contains(&c.vertical_face_tilt_deg),
            "vertical_face_tilt_deg",
            "must lie in [0, 45)",
        )?;
        check(
            c.max_contact_samples > 0,
            "max_contact_samples",
            "must be at least 1",
        )?;
        check(
            (1..=64).contains(&c.directions_per_contact),
            "directions_per_contact",
            "must lie in 1..=64",
        )?;
        check(
            c.friction_cone_half_angle_deg > 0.0 && c.friction_cone_half_angle_deg < 90.0,
            "friction_cone_half_angle_deg",
            "must lie in (0, 90)",
        )?;
        check(
            c.ray_step_voxels > 0.01 && c.ray_step_voxels <= 1.0,
            "ray_step_voxels",
            "must lie in (0.01, 1]",
        )?;
        check(
            c.entry_search_voxels >= 0.0 && c.entry_search_voxels <= 5.0,
            "entry_search_voxels",
            "must lie in [0, 5]",
        )?;
        check(
            c.min_width_m >= 0.0 && c.min_width_m.is_finite(),
            "min_width_m",
            "must be finite and >= 0",
        )?;
        check(
            c.width_margin_m >= 0.0 && c.width_margin_m.is_finite(),
            "width_margin_m",
            "must be finite and >= 0",
        )?;
        check(
            (0.0..=1.0).contains(&c.occluded_quality_factor),
            "occluded_quality_factor",
            "must lie in [0, 1]",
        )?;
        check(
            (0.0..=1.0).contains(&c.min_quality),
            "min_quality",
            "must lie in [0, 1]",
        )?;
        check(
            c.max_configurations > 0,
            "max_configurations",
            "must be at least 1",
        )?;
        check(
            c.opening_clearance_m >= 0.0 && c.opening_clearance_m.is_finite(),
            "opening_clearance_m",
            "must be finite and >= 0",
        )?;
        check(
            c.collision_margin_m >= 0.0 && c.collision_margin_m < 0.1,
            "collision_margin_m",
            "must lie in [0, 0.1)",
        )?;
        if let Some(r) = &c.contact_region {
            r.validate()?;
        }
        Ok(c.occupancy.validate()?)
    }
}

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
        let opening = (c.width + self.cfg.opening_clearance_m).min(self.gripper.max_opening_m);
        let approaches = approach_vectors(&c.baseline);
        std::array::from_fn(|i| {
            let grasp = ContactGrasp {
                contact: c.contact,
                baseline: c.baseline,
                approach: approaches[i],
                width: c.width,
            };
            let pose = grasp.workspace_from_gripper();
            if checker.gripper_collides(&pose, opening, self.cfg.collision_margin_m) {
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
            });
        }
        self.stats.configurations = out.len();
        Ok(out)
    }
}
