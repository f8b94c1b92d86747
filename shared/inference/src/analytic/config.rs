//! The analytic backend's settings ([`AnalyticConfig`], [`ContactRegion`]) and their validation.
use crate::InferenceError;
use nalgebra::Point3;
use psgrasp_collision::OccupancyConfig;
use psgrasp_geometry::BinModel;
use psgrasp_geometry::{check_setting, HandClearance};
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
    /// Accept second contacts on the unobserved side (see the [`analytic`](super) module docs).
    pub occluded_second_contact: bool,
    /// Quality factor for occluded second contacts, in [0, 1].
    pub occluded_quality_factor: f32,
    /// Configurations with a lower antipodal quality are dropped.
    pub min_quality: f32,
    /// Most configurations returned per frame (the best by quality).
    pub max_configurations: usize,
    /// The hand's clearances for the collision scores (opening and scene margin). Not read from
    /// `[inference]`: a cell sets them from `[selection.clearance]`, so the scores test the hand
    /// that selection checks and commands (`psgrasp_perception::CellConfig::effective_backend`).
    #[serde(skip)]
    pub clearance: HandClearance,
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
        check_setting(
            ok,
            "contact_region",
            "corners must be finite with min_m <= max_m",
        )
        .map_err(Into::into)
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
            clearance: HandClearance::default(),
            require_free_approach: true,
            occupancy: OccupancyConfig::default(),
            contact_region: None,
        }
    }
}

impl AnalyticConfig {
    /// Checks every field's range.
    pub fn validate(&self) -> Result<(), InferenceError> {
        let c = self;
        check_setting(
            c.surface_search_voxels > 0.0 && c.surface_search_voxels <= 3.0,
            "surface_search_voxels",
            "must lie in (0, 3]",
        )?;
        check_setting(
            c.min_normal_norm > 0.0 && c.min_normal_norm <= 1.0,
            "min_normal_norm",
            "must lie in (0, 1]",
        )?;
        check_setting(
            (0.0..=90.0).contains(&c.skip_upward_normals_deg),
            "skip_upward_normals_deg",
            "must lie in [0, 90]",
        )?;
        check_setting(
            (0.0..45.0).contains(&c.vertical_face_tilt_deg),
            "vertical_face_tilt_deg",
            "must lie in [0, 45)",
        )?;
        check_setting(
            c.max_contact_samples > 0,
            "max_contact_samples",
            "must be at least 1",
        )?;
        check_setting(
            (1..=64).contains(&c.directions_per_contact),
            "directions_per_contact",
            "must lie in 1..=64",
        )?;
        check_setting(
            c.friction_cone_half_angle_deg > 0.0 && c.friction_cone_half_angle_deg < 90.0,
            "friction_cone_half_angle_deg",
            "must lie in (0, 90)",
        )?;
        check_setting(
            c.ray_step_voxels > 0.01 && c.ray_step_voxels <= 1.0,
            "ray_step_voxels",
            "must lie in (0.01, 1]",
        )?;
        check_setting(
            c.entry_search_voxels >= 0.0 && c.entry_search_voxels <= 5.0,
            "entry_search_voxels",
            "must lie in [0, 5]",
        )?;
        check_setting(
            c.min_width_m >= 0.0 && c.min_width_m.is_finite(),
            "min_width_m",
            "must be finite and >= 0",
        )?;
        check_setting(
            c.width_margin_m >= 0.0 && c.width_margin_m.is_finite(),
            "width_margin_m",
            "must be finite and >= 0",
        )?;
        check_setting(
            (0.0..=1.0).contains(&c.occluded_quality_factor),
            "occluded_quality_factor",
            "must lie in [0, 1]",
        )?;
        check_setting(
            (0.0..=1.0).contains(&c.min_quality),
            "min_quality",
            "must lie in [0, 1]",
        )?;
        check_setting(
            c.max_configurations > 0,
            "max_configurations",
            "must be at least 1",
        )?;
        c.clearance.validate()?;
        if let Some(r) = &c.contact_region {
            r.validate()?;
        }
        Ok(c.occupancy.validate()?)
    }
}
