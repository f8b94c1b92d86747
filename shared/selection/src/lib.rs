//! Grasp selection: grasp configurations → checked, ranked picks.
//!
//! Follows the paper's execution protocol. Configurations are visited by antipodal quality
//! (descending); within one, the first [`SelectionConfig::approaches_per_configuration`] approaches
//! by collision score (descending, [`GraspConfiguration::approaches_by_score`]) are tried in turn, and
//! the first approach that passes every check becomes that configuration's pick (one pick per contact
//! point). Checks, in order, each counted in [`RejectionCounts`] when it fails:
//!
//! per configuration — finite and well-formed ([`RejectionReason::InvalidConfiguration`]), quality
//! ([`RejectionReason::Quality`]), width within the gripper's opening ([`RejectionReason::Width`]),
//! both contacts inside the bin ([`RejectionReason::ContactOutsideBin`]: grasping a wall or the rim);
//!
//! per approach — collision score ([`RejectionReason::CollisionScore`]), tilt from straight down
//! ([`RejectionReason::Tilt`], the reachability cone), gripper at the grasp pose against the bin walls
//! and floor ([`RejectionReason::BinCollision`], oriented box–box test) and against the observed
//! scene ([`RejectionReason::SceneCollision`], the occupancy checker of `psgrasp-collision`), the
//! pre-grasp pose backed off along −approach ([`RejectionReason::PregraspCollision`]), poses
//! between the two ([`RejectionReason::ApproachPathCollision`]), and, with
//! [`SelectionConfig::surface_check`] enabled, the fingers at the grasp pose against the depth
//! frame's height map ([`RejectionReason::SurfaceCollision`], [`surface`]).
//!
//! The gripper is checked open at `min(width + clearance.opening_clearance_m, max opening)`: the opening the
//! robot should command ([`SelectedGrasp::opening_m`]). A configuration whose grasp centre lies
//! within [`SelectionConfig::pick_spacing_m`] of a pick already taken is passed over
//! (non-maximum suppression in space, counted as `near_better_pick`), so the picks spread over
//! the objects. Configurations are visited, and picks ordered, by [`SelectionConfig::pick_order`]
//! (quality by default), then collision score, and cut to [`SelectionConfig::top_k`].
#![warn(missing_docs)]

pub mod checker;
pub mod failed_picks;
pub mod fallback;
pub mod order;
pub mod overlap;
mod pass;
pub mod surface;

pub use checker::GraspChecker;
pub use failed_picks::{FailedPickMemory, FailedPicks, PickSpot};
pub use fallback::FallbackThresholds;
pub use order::{grasp_centre, OrderSettings, PickOrder};
pub use overlap::boxes_overlap;
pub use surface::SurfaceCheck;

use pass::{select_from, ObservedScene};

use nalgebra::Isometry3;
use psgrasp_collision::{CollisionError, OccupancyConfig, OccupancyGrid};
use psgrasp_fusion::{HeightMapView, NormalGridView};
use psgrasp_geometry::{
    check_setting, check_tcp_lifts, BinModel, GraspConfiguration, GripperModel, HandClearance,
    N_APPROACHES,
};
use serde::{Deserialize, Serialize};

/// Errors that prevent selection from running at all (bad configurations of grasps are counted as
/// rejections instead).
#[derive(Debug, thiserror::Error)]
pub enum SelectionError {
    /// A setting is out of its valid range.
    #[error("invalid selection setting `{field}`: {reason}")]
    InvalidConfig {
        /// Name of the field.
        field: &'static str,
        /// What the valid range is.
        reason: &'static str,
    },
    /// The bin model is unusable (non-positive or non-finite sizes).
    #[error("invalid bin model: {0}")]
    InvalidBin(&'static str),
    /// The normal grid or the gripper model is invalid, or the occupancy could not be built.
    #[error(transparent)]
    Scene(#[from] CollisionError),
    /// `surface_check` is enabled but no height map (or one of other cells) came with the grid.
    #[error("surface_check is enabled but the frame's height map is {0}")]
    HeightMap(&'static str),
}

impl From<psgrasp_geometry::OutOfRange> for SelectionError {
    fn from(e: psgrasp_geometry::OutOfRange) -> Self {
        Self::InvalidConfig {
            field: e.field,
            reason: e.reason,
        }
    }
}

/// Selection settings; every threshold has a default.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SelectionConfig {
    /// Most picks returned.
    pub top_k: usize,
    /// Approaches tried per configuration, best collision score first (the paper: 8 of 18).
    pub approaches_per_configuration: usize,
    /// Configurations with a lower antipodal quality are rejected.
    pub min_quality: f32,
    /// Approaches with a lower collision score are rejected.
    pub min_collision_score: f32,
    /// Largest angle between the approach and straight down (the reachability cone), degrees.
    pub max_approach_tilt_deg: f32,
    /// Poses checked between the pre-grasp and the grasp pose (evenly spaced, ends excluded).
    pub approach_path_samples: usize,
    /// The hand's opening clearance, scene margin and pre-grasp distance: the one definition the
    /// analytic backend's collision scores and the evaluation's execution use too.
    pub clearance: HandClearance,
    /// Gripper boxes are grown by this margin against the bin walls and floor, metres.
    pub bin_margin_m: f32,
    /// Contacts may lie at most this far outside the bin's inner volume, metres.
    pub bin_contact_tolerance_m: f32,
    /// Contacts closer than this to a side wall's inner face are rejected too
    /// ([`RejectionReason::ContactOutsideBin`]), metres; 0 (default): only
    /// `bin_contact_tolerance_m` applies (and then not written, so stored configurations keep
    /// their form). The fallback tier sets it: where the learned collision score is not trusted,
    /// grasps on and at the walls are left out. A few millimetres in the primary tier refuse
    /// grasps that close on the bin's rim (`config/default.toml`).
    #[serde(skip_serializing_if = "psgrasp_geometry::is_zero")]
    pub min_contact_wall_distance_m: f32,
    /// Check the gripper against the bin walls and floor.
    pub check_bin_collision: bool,
    /// Check the gripper against the observed scene (occupied voxels of the grid).
    pub check_scene_collision: bool,
    /// How the grid becomes occupied voxels for the scene check.
    pub occupancy: OccupancyConfig,
    /// A configuration whose grasp centre lies closer than this to a pick already taken is
    /// passed over, metres (0: no spacing; picks may then be the same grasp millimetres apart).
    pub pick_spacing_m: f32,
    /// Which picks come first: `quality` (the paper's), `confident-quality`, `confident-first`,
    /// `topmost`, or `centre-first`.
    pub pick_order: PickOrder,
    /// `confident-quality` only: a baseline counts as right within this angle of the predicted
    /// mean, degrees (the pick check's label match uses 20°). Not written at its default, so
    /// stored configurations (dataset manifests, evaluation runs) keep their form.
    #[serde(skip_serializing_if = "is_default_baseline_tolerance")]
    pub baseline_tolerance_deg: f32,
    /// `confident-first` only: κ strictly above this counts as confident, for every
    /// configuration. `None` (default, and then not written): each configuration's own floor
    /// ([`GraspConfiguration::kappa_floor`], the model card's `kappa0` that the inference stage
    /// sends with the grasp set), so a model trained with another κ0 needs no setting here.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub confident_kappa_above: Option<f32>,
    /// An approach whose grasp pose, pre-grasp or path fails the collision checks with the tool
    /// centre point at the contacts' midpoint (the paper's grasp frame) is tried again with it
    /// raised these distances back along the approach, in order, metres: the contacts then meet
    /// the pads below their centre (a real pad holds anywhere along its length; keep the lifts
    /// within half the pad's length). The pick is the first lift that passes. Empty (default):
    /// the paper's frame only (and then not written, so stored configurations keep their form).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub tcp_lifts_m: Vec<f32>,
    /// Looser score thresholds tried when no configuration passes `min_quality` and
    /// `min_collision_score` (every geometric check stays); picks made under them are marked
    /// ([`Selection::fallback`]). `None` (default): the paper's thresholds only (and then not
    /// written, so stored configurations keep their form).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fallback: Option<FallbackThresholds>,
    /// The fingers at the grasp pose against the depth frame's height map (off by default, and
    /// then not written, so stored configurations keep their form).
    #[serde(skip_serializing_if = "surface::is_default")]
    pub surface_check: SurfaceCheck,
    /// Picks near a pick reported failed are handed out last for a few picks (off by default,
    /// and then not written, so stored configurations keep their form; [`failed_picks`]).
    #[serde(skip_serializing_if = "failed_picks::is_default")]
    pub failed_pick_memory: FailedPickMemory,
}

/// `SelectionConfig::baseline_tolerance_deg`'s default, degrees.
pub const DEFAULT_BASELINE_TOLERANCE_DEG: f32 = 20.0;

fn is_default_baseline_tolerance(deg: &f32) -> bool {
    *deg == DEFAULT_BASELINE_TOLERANCE_DEG
}

impl Default for SelectionConfig {
    fn default() -> Self {
        Self {
            top_k: 10,
            approaches_per_configuration: 8,
            min_quality: 0.5,
            min_collision_score: 0.5,
            max_approach_tilt_deg: 60.0,
            approach_path_samples: 2,
            clearance: HandClearance::default(),
            bin_margin_m: 0.003,
            bin_contact_tolerance_m: 0.005,
            min_contact_wall_distance_m: 0.0,
            check_bin_collision: true,
            check_scene_collision: true,
            occupancy: OccupancyConfig::default(),
            pick_spacing_m: 0.05,
            pick_order: PickOrder::Quality,
            baseline_tolerance_deg: DEFAULT_BASELINE_TOLERANCE_DEG,
            confident_kappa_above: None,
            tcp_lifts_m: Vec::new(),
            fallback: None,
            surface_check: SurfaceCheck::default(),
            failed_pick_memory: FailedPickMemory::default(),
        }
    }
}

impl SelectionConfig {
    /// Checks every field's range.
    pub fn validate(&self) -> Result<(), SelectionError> {
        let c = self;
        let metric = |v: f32| v.is_finite() && (0.0..1.0).contains(&v);
        check_setting(c.top_k >= 1, "top_k", "must be at least 1")?;
        check_setting(
            (1..=N_APPROACHES).contains(&c.approaches_per_configuration),
            "approaches_per_configuration",
            "must lie in 1..=18",
        )?;
        check_setting(
            (0.0..=1.0).contains(&c.min_quality),
            "min_quality",
            "must lie in [0, 1]",
        )?;
        check_setting(
            (0.0..=1.0).contains(&c.min_collision_score),
            "min_collision_score",
            "must lie in [0, 1]",
        )?;
        check_setting(
            c.max_approach_tilt_deg > 0.0 && c.max_approach_tilt_deg <= 180.0,
            "max_approach_tilt_deg",
            "must lie in (0, 180]",
        )?;
        check_setting(
            c.approach_path_samples <= 100,
            "approach_path_samples",
            "must be at most 100",
        )?;
        c.clearance.validate()?;
        check_setting(
            metric(c.bin_margin_m),
            "bin_margin_m",
            "must lie in [0, 1) m",
        )?;
        check_setting(
            metric(c.bin_contact_tolerance_m),
            "bin_contact_tolerance_m",
            "must lie in [0, 1) m",
        )?;
        check_setting(
            metric(c.min_contact_wall_distance_m),
            "min_contact_wall_distance_m",
            "must lie in [0, 1) m",
        )?;
        check_setting(
            metric(c.pick_spacing_m),
            "pick_spacing_m",
            "must lie in [0, 1) m",
        )?;
        check_setting(
            c.baseline_tolerance_deg > 0.0 && c.baseline_tolerance_deg < 180.0,
            "baseline_tolerance_deg",
            "must lie in (0, 180)",
        )?;
        check_setting(
            c.confident_kappa_above
                .is_none_or(|k| k.is_finite() && k >= 0.0),
            "confident_kappa_above",
            "must be finite and ≥ 0",
        )?;
        c.occupancy.validate()?;
        check_tcp_lifts(&c.tcp_lifts_m, "tcp_lifts_m")?;
        if let Some(f) = &c.fallback {
            f.validate(c)?;
        }
        c.surface_check.validate()?;
        c.failed_pick_memory.validate()?;
        Ok(())
    }
}

/// Why a configuration or one of its approaches was not picked.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RejectionReason {
    /// Non-finite values, a non-unit baseline, a negative width or scores outside [0, 1].
    InvalidConfiguration,
    /// Antipodal quality below [`SelectionConfig::min_quality`].
    Quality,
    /// Width larger than the gripper's maximum opening.
    Width,
    /// A contact lies outside the bin's inner volume (the grasp would hold a wall or the rim).
    ContactOutsideBin,
    /// Collision score below [`SelectionConfig::min_collision_score`].
    CollisionScore,
    /// Approach tilted more than [`SelectionConfig::max_approach_tilt_deg`] from straight down.
    Tilt,
    /// Gripper at the grasp pose overlaps the bin walls or floor.
    BinCollision,
    /// Gripper at the grasp pose overlaps occupied voxels of the observed scene.
    SceneCollision,
    /// Gripper at the pre-grasp pose overlaps the bin or the observed scene.
    PregraspCollision,
    /// Gripper between the pre-grasp and the grasp pose overlaps the bin or the observed scene.
    ApproachPathCollision,
    /// A finger at the grasp pose meets the depth frame's height map
    /// ([`SelectionConfig::surface_check`]).
    SurfaceCollision,
}

/// How many times each check failed. Per-configuration reasons count configurations; per-approach
/// reasons count approaches (a configuration contributes up to
/// [`SelectionConfig::approaches_per_configuration`] of them).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct RejectionCounts {
    /// See [`RejectionReason::InvalidConfiguration`].
    pub invalid_configuration: usize,
    /// See [`RejectionReason::Quality`].
    pub quality: usize,
    /// See [`RejectionReason::Width`].
    pub width: usize,
    /// See [`RejectionReason::ContactOutsideBin`].
    pub contact_outside_bin: usize,
    /// See [`RejectionReason::CollisionScore`].
    pub collision_score: usize,
    /// See [`RejectionReason::Tilt`].
    pub tilt: usize,
    /// See [`RejectionReason::BinCollision`].
    pub bin_collision: usize,
    /// See [`RejectionReason::SceneCollision`].
    pub scene_collision: usize,
    /// See [`RejectionReason::PregraspCollision`].
    pub pregrasp_collision: usize,
    /// See [`RejectionReason::ApproachPathCollision`].
    pub approach_path_collision: usize,
    /// See [`RejectionReason::SurfaceCollision`].
    #[serde(default)]
    pub surface_collision: usize,
    /// Configurations with no approach left to try (all examined approaches rejected).
    pub no_valid_approach: usize,
    /// Configurations never examined because `top_k` better picks were already found.
    pub not_examined: usize,
    /// Configurations passed over because a better pick lies within `pick_spacing_m`.
    #[serde(default)]
    pub near_better_pick: usize,
    /// Configurations whose pick was deferred behind the others because its pads would close on
    /// too little measured surface ([`SurfaceCheck::defer_pad_fill_below`]; not a rejection: such
    /// picks fill up `top_k` after the others).
    #[serde(default)]
    pub deferred_pad_fill: usize,
}

impl RejectionCounts {
    /// Counts one rejection.
    pub fn add(&mut self, reason: RejectionReason) {
        *self.slot(reason) += 1;
    }

    /// The count of one reason.
    pub fn get(&self, reason: RejectionReason) -> usize {
        let mut copy = *self;
        *copy.slot(reason)
    }

    fn slot(&mut self, reason: RejectionReason) -> &mut usize {
        match reason {
            RejectionReason::InvalidConfiguration => &mut self.invalid_configuration,
            RejectionReason::Quality => &mut self.quality,
            RejectionReason::Width => &mut self.width,
            RejectionReason::ContactOutsideBin => &mut self.contact_outside_bin,
            RejectionReason::CollisionScore => &mut self.collision_score,
            RejectionReason::Tilt => &mut self.tilt,
            RejectionReason::BinCollision => &mut self.bin_collision,
            RejectionReason::SceneCollision => &mut self.scene_collision,
            RejectionReason::PregraspCollision => &mut self.pregrasp_collision,
            RejectionReason::ApproachPathCollision => &mut self.approach_path_collision,
            RejectionReason::SurfaceCollision => &mut self.surface_collision,
        }
    }
}

/// An executable grasp.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SelectedGrasp {
    /// Gripper pose at the grasp (x = baseline, z = approach, origin = TCP between the contacts).
    pub workspace_from_gripper: Isometry3<f32>,
    /// Gripper pose before the final approach: the grasp pose backed off along −approach.
    pub pregrasp: Isometry3<f32>,
    /// How far `pregrasp` is backed off along −approach, metres (the execution moves in from
    /// there).
    pub pregrasp_distance_m: f32,
    /// Contact-to-contact width, metres.
    pub width: f32,
    /// Opening to command before closing: `min(width + clearance, max opening)`, metres.
    pub opening_m: f32,
    /// Antipodal quality of the configuration.
    pub quality: f32,
    /// Collision score of the chosen approach.
    pub collision_score: f32,
    /// Index of the configuration in the input slice.
    pub configuration_index: usize,
    /// Index of the chosen approach (0..18) within the configuration.
    pub approach_index: usize,
    /// Share of what the pads close on ([`psgrasp_geometry::GripperModel::pad_closing_region`]
    /// at the grasp pose) that lies under the frame's measured surface: near 1 when the pads
    /// meet an object over their whole length, low when they close over its top or beside it.
    /// `None` without the surface check's height map.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pad_fill: Option<f32>,
}

/// The result of [`select`].
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Selection {
    /// Picks, best first (`pick_order`, then collision score), at most `top_k`, at least
    /// `pick_spacing_m` apart.
    pub picks: Vec<SelectedGrasp>,
    /// Why the other configurations and approaches were rejected (in the pass whose picks these
    /// are: the fallback tier's when [`Selection::fallback`]).
    pub rejected: RejectionCounts,
    /// The picks come from the fallback tier ([`SelectionConfig::fallback`]): nothing passed the
    /// primary score thresholds.
    #[serde(default)]
    pub fallback: bool,
}

/// Selects up to `top_k` executable grasps from `configs` (see the crate docs for the order and
/// the checks). The observed scene is the occupancy of `grid`.
pub fn select(
    configs: &[GraspConfiguration],
    grid: &NormalGridView<'_>,
    bin: &BinModel,
    gripper: &GripperModel,
    cfg: &SelectionConfig,
) -> Result<Selection, SelectionError> {
    select_filtered(configs, grid, bin, gripper, cfg, |_| true)
}

/// [`select`] with one more check after all of selection's own: `pregrasp_free(pick)` returning
/// false rejects that approach as [`RejectionReason::PregraspCollision`] and the next approach of
/// the configuration is tried. The evaluation uses it for the paper's "no collision at its
/// pre-grasp pose", tested against the simulated scene.
pub fn select_filtered(
    configs: &[GraspConfiguration],
    grid: &NormalGridView<'_>,
    bin: &BinModel,
    gripper: &GripperModel,
    cfg: &SelectionConfig,
    pregrasp_free: impl FnMut(&SelectedGrasp) -> bool,
) -> Result<Selection, SelectionError> {
    select_observed(configs, grid, None, bin, gripper, cfg, pregrasp_free)
}

/// [`select_filtered`] with the frame's height map for [`SelectionConfig::surface_check`]; an
/// enabled check without a map of its cells is an error (the check is never skipped silently).
pub fn select_observed(
    configs: &[GraspConfiguration],
    grid: &NormalGridView<'_>,
    surface: Option<HeightMapView<'_>>,
    bin: &BinModel,
    gripper: &GripperModel,
    cfg: &SelectionConfig,
    pregrasp_free: impl FnMut(&SelectedGrasp) -> bool,
) -> Result<Selection, SelectionError> {
    cfg.validate()?;
    let surface = if cfg.surface_check.enabled {
        let map = surface.ok_or(SelectionError::HeightMap("missing"))?;
        let expected = cfg
            .surface_check
            .geometry(&grid.workspace)
            .map_err(|_| SelectionError::HeightMap("not of the grid's workspace"))?;
        if expected != Some(map.geometry) || map.heights.len() != map.geometry.len() {
            return Err(SelectionError::HeightMap(
                "not of surface_check.cell_m over the grid's workspace",
            ));
        }
        Some(map)
    } else {
        None
    };
    let occupancy = if cfg.check_scene_collision {
        Some(OccupancyGrid::from_normal_grid(grid, &cfg.occupancy)?)
    } else {
        None
    };
    let scene = ObservedScene {
        occupancy: occupancy.as_ref(),
        surface,
    };
    select_from(configs, scene, bin, gripper, cfg, pregrasp_free)
}

/// [`select`] with a prebuilt occupancy grid (`None`: no scene check), e.g. shared with the
/// inference backend.
pub fn select_with_occupancy(
    configs: &[GraspConfiguration],
    occupancy: Option<&OccupancyGrid>,
    bin: &BinModel,
    gripper: &GripperModel,
    cfg: &SelectionConfig,
) -> Result<Selection, SelectionError> {
    let scene = ObservedScene {
        occupancy,
        surface: None,
    };
    select_from(configs, scene, bin, gripper, cfg, |_| true)
}
