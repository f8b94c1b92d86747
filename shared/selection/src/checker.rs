//! The per-configuration and per-approach checks of the selection (see the crate docs for the
//! order): validity, quality, width, contacts inside the bin; collision score, tilt, the gripper
//! against the bin and the observed scene at the grasp pose, the pre-grasp pose and between them,
//! and the fingers at the grasp pose against the depth frame's height map (when enabled).

use nalgebra::{Isometry3, Point3, Translation3, Vector3};
use psgrasp_collision::{
    cells_under_surface_in_box, volume_share_under_surface, CollisionError, OccupancyGrid,
};
use psgrasp_fusion::HeightMapView;
use psgrasp_geometry::{
    at_first_passing_lift, BinModel, GraspConfiguration, GripperModel, OrientedBox, N_APPROACHES,
};

use crate::{boxes_overlap, RejectionReason, SelectedGrasp, SelectionConfig, SelectionError};

/// Checks single configurations and approaches against one bin and one observed scene.
#[derive(Debug, Clone)]
pub struct GraspChecker<'a> {
    cfg: &'a SelectionConfig,
    gripper: GripperModel,
    bin: BinModel,
    bin_boxes: [OrientedBox; 5],
    scene: Option<&'a OccupancyGrid>,
    /// The frame's height map for [`SelectionConfig::surface_check`] (`None`: not tested).
    surface: Option<HeightMapView<'a>>,
    cos_max_tilt: f32,
}

fn validate_bin(bin: &BinModel) -> Result<(), SelectionError> {
    let sizes_ok = bin.inner_size_m.iter().all(|v| v.is_finite() && *v > 0.0);
    let wall_ok = bin.wall_thickness_m.is_finite() && bin.wall_thickness_m > 0.0;
    let centre_ok = bin.floor_center.coords.iter().all(|v| v.is_finite());
    if sizes_ok && wall_ok && centre_ok {
        Ok(())
    } else {
        Err(SelectionError::InvalidBin(
            "sizes and wall thickness must be positive, the floor centre finite",
        ))
    }
}

impl<'a> GraspChecker<'a> {
    /// A checker for `gripper` in `bin`; `scene` is the observed occupancy (`None` skips the scene
    /// test, as does [`SelectionConfig::check_scene_collision`] = false).
    pub fn new(
        cfg: &'a SelectionConfig,
        gripper: GripperModel,
        bin: BinModel,
        scene: Option<&'a OccupancyGrid>,
    ) -> Result<Self, SelectionError> {
        cfg.validate()?;
        gripper.validate().map_err(CollisionError::Gripper)?;
        validate_bin(&bin)?;
        Ok(Self {
            cfg,
            gripper,
            bin,
            bin_boxes: bin.boxes(),
            scene: scene.filter(|_| cfg.check_scene_collision),
            surface: None,
            cos_max_tilt: cfg.max_approach_tilt_deg.to_radians().cos(),
        })
    }

    /// The same checker also testing the fingers at the grasp pose against `surface`, the frame's
    /// height map, when [`SelectionConfig::surface_check`] is enabled (`None`: no such test).
    pub fn with_surface(self, surface: Option<HeightMapView<'a>>) -> Self {
        Self {
            surface: surface.filter(|_| self.cfg.surface_check.enabled),
            ..self
        }
    }

    /// The per-configuration checks: validity, quality, width, contacts inside the bin.
    pub fn check_configuration(&self, c: &GraspConfiguration) -> Result<(), RejectionReason> {
        let finite = c
            .contact
            .coords
            .iter()
            .chain(c.baseline.iter())
            .all(|v| v.is_finite())
            && c.width.is_finite()
            && c.quality.is_finite();
        let scores_ok = c
            .collision_scores
            .iter()
            .all(|s| s.is_finite() && (0.0..=1.0).contains(s));
        if !finite || !scores_ok || (c.baseline.norm() - 1.0).abs() > 1e-3 || c.width < 0.0 {
            return Err(RejectionReason::InvalidConfiguration);
        }
        if c.quality < self.cfg.min_quality {
            return Err(RejectionReason::Quality);
        }
        if c.width > self.gripper.max_opening_m {
            return Err(RejectionReason::Width);
        }
        let second = c.contact + c.baseline * c.width;
        if !self.inside_bin(&c.contact) || !self.inside_bin(&second) {
            return Err(RejectionReason::ContactOutsideBin);
        }
        Ok(())
    }

    fn inside_bin(&self, p: &Point3<f32>) -> bool {
        let d = p - self.bin.floor_center;
        let tol = self.cfg.bin_contact_tolerance_m;
        let wall = self.cfg.min_contact_wall_distance_m;
        // Half the side extent a contact may reach: past the wall's face by the tolerance, or
        // short of it by the wall distance when one is set.
        let side = if wall > 0.0 { -wall } else { tol };
        let [lx, ly, lz] = self.bin.inner_size_m;
        d.x.abs() <= 0.5 * lx + side
            && d.y.abs() <= 0.5 * ly + side
            && d.z >= -tol
            && d.z <= lz + tol
    }

    /// True if the gripper at `pose`, open at `opening`, hits the bin or the observed scene.
    fn gripper_collides(&self, pose: &Isometry3<f32>, opening: f32) -> Option<RejectionReason> {
        let boxes = self.gripper.boxes(pose, opening);
        if self.cfg.check_bin_collision
            && boxes.iter().any(|g| {
                self.bin_boxes
                    .iter()
                    .any(|w| boxes_overlap(g, w, self.cfg.bin_margin_m))
            })
        {
            return Some(RejectionReason::BinCollision);
        }
        if let Some(scene) = self.scene {
            // Fingers first: they are the likelier to collide.
            if [1, 2, 0]
                .iter()
                .any(|&i| scene.box_collides(&boxes[i], self.cfg.clearance.collision_margin_m))
            {
                return Some(RejectionReason::SceneCollision);
            }
        }
        None
    }

    /// The per-approach checks for approach `approach_index` of `c` (the configuration checks are
    /// not repeated); on success the pick, tagged with `configuration_index`.
    pub fn check_approach(
        &self,
        c: &GraspConfiguration,
        configuration_index: usize,
        approach_index: usize,
    ) -> Result<SelectedGrasp, RejectionReason> {
        if approach_index >= N_APPROACHES {
            return Err(RejectionReason::InvalidConfiguration);
        }
        let score = c.collision_scores[approach_index];
        if score < self.cfg.min_collision_score {
            return Err(RejectionReason::CollisionScore);
        }
        let grasp = c.grasp(approach_index);
        // Tilt from straight down: cos = a · (−z).
        if -grasp.approach.z < self.cos_max_tilt - 1e-6 {
            return Err(RejectionReason::Tilt);
        }
        let opening = self
            .cfg
            .clearance
            .opening_m(c.width, self.gripper.max_opening_m);
        at_first_passing_lift(&self.cfg.tcp_lifts_m, |lift| {
            let pose = grasp.workspace_from_gripper_lifted(lift);
            let pregrasp = self.check_pose_and_path(&pose, opening)?;
            Ok(SelectedGrasp {
                workspace_from_gripper: pose,
                pregrasp,
                pregrasp_distance_m: self.cfg.clearance.pregrasp_distance_m,
                width: c.width,
                opening_m: opening,
                quality: c.quality,
                collision_score: score,
                configuration_index,
                approach_index,
                pad_fill: self.pad_fill(&pose, c.width),
            })
        })
    }

    /// [`SelectedGrasp::pad_fill`] of a grasp of `width` at `pose` (`None` without a height map).
    fn pad_fill(&self, pose: &Isometry3<f32>, width: f32) -> Option<f32> {
        let region = self.gripper.pad_closing_region(width).placed(pose);
        volume_share_under_surface(self.surface.as_ref()?, &region)
    }

    /// The grasp pose, its pre-grasp backed off along −approach and the poses between them
    /// against the bin and the scene; the pre-grasp pose when all are free.
    fn check_pose_and_path(
        &self,
        pose: &Isometry3<f32>,
        opening: f32,
    ) -> Result<Isometry3<f32>, RejectionReason> {
        if let Some(reason) = self.gripper_collides(pose, opening) {
            return Err(reason);
        }
        let approach: Vector3<f32> = pose.rotation * Vector3::z();
        let backed_off = |distance: f32| {
            Isometry3::from_parts(
                Translation3::from(pose.translation.vector - approach * distance),
                pose.rotation,
            )
        };
        let pregrasp = backed_off(self.cfg.clearance.pregrasp_distance_m);
        if self.gripper_collides(&pregrasp, opening).is_some() {
            return Err(RejectionReason::PregraspCollision);
        }
        let n = self.cfg.approach_path_samples;
        for s in 1..=n {
            let distance = self.cfg.clearance.pregrasp_distance_m * s as f32 / (n + 1) as f32;
            if self
                .gripper_collides(&backed_off(distance), opening)
                .is_some()
            {
                return Err(RejectionReason::ApproachPathCollision);
            }
        }
        if let Some(map) = &self.surface {
            let check = &self.cfg.surface_check;
            let boxes = self.gripper.boxes(pose, opening);
            let cells: usize = [&boxes[1], &boxes[2]]
                .iter()
                .map(|finger| {
                    cells_under_surface_in_box(map, finger, check.margin_m, check.min_cells)
                })
                .sum();
            if cells >= check.min_cells {
                return Err(RejectionReason::SurfaceCollision);
            }
        }
        Ok(pregrasp)
    }
}
