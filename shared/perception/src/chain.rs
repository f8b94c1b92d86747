//! The steps of the chain and the chain itself.
use crate::config::{CellConfig, InvalidSetting};
use psgrasp_fusion::{
    correct_depth_scale, write_height_map, DepthScale, FusionError, HeightMapGeometry,
    HeightMapView, NormalGridView, TsdfVolume,
};
use psgrasp_geometry::{CameraModel, DepthImage, GraspConfiguration};
use psgrasp_inference::{InferenceBackend, InferenceError};
use psgrasp_selection::{select_observed, SelectedGrasp, Selection, SelectionError, SurfaceCheck};
use std::borrow::Cow;
use std::time::Instant;

/// Why the chain failed on a frame, by step.
#[derive(Debug, thiserror::Error)]
pub enum PerceptionError {
    /// The cell's configuration is out of range (named in the message, so not a source too).
    #[error("invalid cell configuration: {0}")]
    Config(InvalidSetting),
    /// Depth-scale correction or fusion failed (bad frame, bad camera).
    #[error(transparent)]
    Fusion(#[from] FusionError),
    /// The backend failed (or could not be built).
    #[error(transparent)]
    Inference(#[from] InferenceError),
    /// Selection failed.
    #[error(transparent)]
    Selection(#[from] SelectionError),
    /// The chain was built for external proposals only and was asked to run its backend.
    #[error("this perception chain has no inference backend (external proposals only)")]
    NoBackend,
}

impl From<InvalidSetting> for PerceptionError {
    fn from(e: InvalidSetting) -> Self {
        Self::Config(e)
    }
}

/// What the depth-scale correction found on a frame (only when it is enabled).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthScaleOutcome {
    /// The frame's range-scale estimate; `None` when too little of the bin was visible.
    pub estimate: Option<DepthScale>,
    /// Whether the frame was divided by it (it was off by at least `min_correction`).
    pub applied: bool,
}

/// grid-fusion's step: depth-scale correction (when enabled) and TSDF fusion into a volume that
/// is reused from frame to frame; with `[selection.surface_check]` enabled, also the frame's
/// height map, sent after the normal grid in the same message.
#[derive(Debug)]
pub struct FusionStep {
    volume: TsdfVolume,
    cell: CellConfig,
    /// The height map's cells and the last frame's heights (`None`: not wanted).
    height_map: Option<(HeightMapGeometry, Vec<f32>)>,
}

impl FusionStep {
    /// The step for `cell` (its workspace, bin, fusion and depth-scale settings).
    pub fn new(cell: &CellConfig) -> Result<Self, PerceptionError> {
        cell.validate()?;
        let height_map = cell
            .selection
            .surface_check
            .geometry(&cell.workspace)?
            .map(|g| (g, vec![psgrasp_fusion::NO_HEIGHT; g.len()]));
        Ok(Self {
            volume: TsdfVolume::new(cell.workspace, &cell.fusion)?,
            cell: cell.clone(),
            height_map,
        })
    }

    /// Corrects `depth` (when enabled; a borrowed frame is copied only then) and fuses it into
    /// a fresh volume; the normal grid is then written by [`FusionStep::write_grid`].
    pub fn fuse(
        &mut self,
        mut depth: Cow<'_, DepthImage>,
        camera: &CameraModel,
    ) -> Result<Option<DepthScaleOutcome>, PerceptionError> {
        let scale = if self.cell.depth_scale.enabled {
            let (estimate, applied) = correct_depth_scale(
                depth.to_mut(),
                camera,
                &self.cell.bin,
                &self.cell.depth_scale,
            )?;
            Some(DepthScaleOutcome { estimate, applied })
        } else {
            None
        };
        self.volume.reset();
        self.volume.integrate(&depth, camera)?;
        if let Some((geometry, heights)) = &mut self.height_map {
            write_height_map(&depth, camera, geometry, heights)?;
        }
        Ok(scale)
    }

    /// Values of the normal grid message: `3·N` normals then `N` TSDF values, then the height
    /// map's cells when `[selection.surface_check]` is enabled ([`grid_message_views`]).
    pub fn grid_len(&self) -> usize {
        4 * self.cell.workspace.voxel_count() + self.height_map.as_ref().map_or(0, |m| m.1.len())
    }

    /// The TSDF truncation distance of the grid, metres.
    pub fn truncation_m(&self) -> f32 {
        self.volume.truncation_m()
    }

    /// Writes the fused normal grid into `out` ([`FusionStep::grid_len`] values: the network's
    /// `[4, X, Y, Z]` input, normals first), e.g. straight into a shared-memory loan.
    pub fn write_grid(&self, out: &mut [f32]) -> Result<(), PerceptionError> {
        if out.len() != self.grid_len() {
            return Err(FusionError::BufferSize {
                name: "grid message",
                got: out.len(),
                expected: self.grid_len(),
            }
            .into());
        }
        let n = self.cell.workspace.voxel_count();
        let (grid, heights) = out.split_at_mut(4 * n);
        let (normals, tsdf) = grid.split_at_mut(3 * n);
        self.volume.write_normal_grid(normals, tsdf)?;
        if let Some((_, map)) = &self.height_map {
            heights.copy_from_slice(map);
        }
        Ok(())
    }
}

/// Borrows a grid message (`values`: the normal grid of `workspace`, then the height map when
/// `surface_check` is enabled) as its views; an error names the length it should have had.
pub fn grid_message_views<'g>(
    workspace: &psgrasp_geometry::Workspace,
    surface_check: &SurfaceCheck,
    values: &'g [f32],
    truncation_m: f32,
) -> Result<(NormalGridView<'g>, Option<HeightMapView<'g>>), String> {
    let n = workspace.voxel_count();
    let geometry = surface_check
        .geometry(workspace)
        .map_err(|e| e.to_string())?;
    let expected = 4 * n + geometry.map_or(0, |g| g.len());
    if values.len() != expected {
        return Err(format!(
            "grid payload has {} values, the header's dims and [selection.surface_check] need {}",
            values.len(),
            expected
        ));
    }
    let (grid, heights) = values.split_at(4 * n);
    let (normals, tsdf) = grid.split_at(3 * n);
    let view = NormalGridView {
        workspace: *workspace,
        normals,
        tsdf,
        truncation_m,
    };
    Ok((
        view,
        geometry.map(|geometry| HeightMapView { geometry, heights }),
    ))
}

/// inference's step: the backend on a normal grid, the grasp set ranked by antipodal quality and
/// cut at [`crate::ChainConfig::max_grasps_per_frame`].
pub struct InferenceStep<'b> {
    backend: Box<dyn InferenceBackend + 'b>,
    max_grasps: usize,
}

impl std::fmt::Debug for InferenceStep<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("InferenceStep")
            .field("backend", &self.backend.name())
            .field("max_grasps", &self.max_grasps)
            .finish()
    }
}

impl InferenceStep<'static> {
    /// The step with the cell's own backend (`[inference]`), built and checked against the
    /// cell's workspace and gripper.
    pub fn new(cell: &CellConfig) -> Result<Self, PerceptionError> {
        cell.validate()?;
        Ok(Self::with_backend(
            cell,
            cell.build_backend(&cell.inference)?,
        ))
    }
}

impl<'b> InferenceStep<'b> {
    /// The step with a backend built elsewhere (the evaluation's detectors).
    pub fn with_backend(cell: &CellConfig, backend: Box<dyn InferenceBackend + 'b>) -> Self {
        Self {
            backend,
            max_grasps: cell.perception.max_grasps_per_frame,
        }
    }

    /// The backend's name.
    pub fn backend_name(&self) -> &str {
        self.backend.name()
    }

    /// Grasp configurations for `grid`, best antipodal quality first, at most
    /// `max_grasps_per_frame`; `seed` makes the backend's sampling deterministic.
    pub fn infer(
        &mut self,
        grid: &NormalGridView<'_>,
        seed: u64,
    ) -> Result<Vec<GraspConfiguration>, PerceptionError> {
        let mut configs = self.backend.infer(grid, seed)?;
        rank_and_cut(&mut configs, self.max_grasps);
        Ok(configs)
    }
}

/// Ranks a grasp set by antipodal quality (stable: equal qualities keep the backend's order)
/// and cuts it at `max`.
fn rank_and_cut(configs: &mut Vec<GraspConfiguration>, max: usize) {
    configs.sort_by(|a, b| b.quality.total_cmp(&a.quality));
    configs.truncate(max);
}

/// grasp-selection's step: ranking, reachability and collision checks against the bin and the
/// observed grid.
#[derive(Debug, Clone)]
pub struct SelectionStep {
    cell: CellConfig,
}

impl SelectionStep {
    /// The step for `cell` (its bin, gripper and selection settings).
    pub fn new(cell: &CellConfig) -> Result<Self, PerceptionError> {
        cell.validate()?;
        Ok(Self { cell: cell.clone() })
    }

    /// The cell it selects for.
    pub fn cell(&self) -> &CellConfig {
        &self.cell
    }

    /// Picks from `configs` on the observed `grid` (and the frame's height map `surface` when
    /// `[selection.surface_check]` is enabled), best first.
    pub fn select(
        &self,
        configs: &[GraspConfiguration],
        grid: &NormalGridView<'_>,
        surface: Option<HeightMapView<'_>>,
    ) -> Result<Selection, PerceptionError> {
        self.select_filtered(configs, grid, surface, |_| true)
    }

    /// [`SelectionStep::select`] with one more check after selection's own (the evaluation's
    /// pre-grasp test in the simulated scene); `false` rejects that approach.
    pub fn select_filtered(
        &self,
        configs: &[GraspConfiguration],
        grid: &NormalGridView<'_>,
        surface: Option<HeightMapView<'_>>,
        keep: impl FnMut(&SelectedGrasp) -> bool,
    ) -> Result<Selection, PerceptionError> {
        let c = &self.cell;
        Ok(select_observed(
            configs,
            grid,
            surface,
            &c.bin,
            &c.gripper,
            &c.selection,
            keep,
        )?)
    }
}

/// Where the grasp configurations of a frame come from.
pub enum Proposer<'p> {
    /// The chain's own inference step (the pipeline's path).
    Backend,
    /// Somebody else's proposals (the evaluation's ground-truth oracle); not ranked or cut.
    External(&'p mut dyn FnMut() -> Vec<GraspConfiguration>),
}

/// Wall time of each step of one frame, milliseconds.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct DetectionTimings {
    /// Depth-scale correction and fusion.
    pub fusion_ms: f64,
    /// Inference (or the external proposer).
    pub inference_ms: f64,
    /// Selection.
    pub selection_ms: f64,
}

/// The result of one frame through the chain.
#[derive(Debug, Clone)]
pub struct Detection {
    /// The grasp set selection ranked (best quality first for the chain's backend).
    pub configurations: Vec<GraspConfiguration>,
    /// The picks and the rejection counts.
    pub selection: Selection,
    /// What the depth-scale correction found (`None`: disabled).
    pub depth_scale: Option<DepthScaleOutcome>,
    /// Time per step.
    pub timings: DetectionTimings,
}

/// The whole chain in one process: `psgrasp eval`, `psgrasp detect` and the tests.
#[derive(Debug)]
pub struct Perception<'b> {
    fusion: FusionStep,
    inference: Option<InferenceStep<'b>>,
    selection: SelectionStep,
    grid: Vec<f32>,
    cell: CellConfig,
}

impl Perception<'static> {
    /// The chain of `cell` with its own backend (`[inference]`).
    pub fn new(cell: &CellConfig) -> Result<Self, PerceptionError> {
        let inference = InferenceStep::new(cell)?;
        Self::from_steps(cell, Some(inference))
    }

    /// The chain of `cell` without a backend: every frame's proposals come from a
    /// [`Proposer::External`] (the evaluation's ground-truth oracle).
    pub fn for_external_proposals(cell: &CellConfig) -> Result<Self, PerceptionError> {
        Self::from_steps(cell, None)
    }
}

impl<'b> Perception<'b> {
    /// The chain of `cell` with a backend built elsewhere (the evaluation's detectors).
    pub fn with_backend(
        cell: &CellConfig,
        backend: Box<dyn InferenceBackend + 'b>,
    ) -> Result<Self, PerceptionError> {
        let inference = InferenceStep::with_backend(cell, backend);
        Self::from_steps(cell, Some(inference))
    }

    fn from_steps(
        cell: &CellConfig,
        inference: Option<InferenceStep<'b>>,
    ) -> Result<Self, PerceptionError> {
        let fusion = FusionStep::new(cell)?;
        Ok(Self {
            grid: vec![0.0; fusion.grid_len()],
            fusion,
            inference,
            selection: SelectionStep::new(cell)?,
            cell: cell.clone(),
        })
    }

    /// The cell this chain runs.
    pub fn cell(&self) -> &CellConfig {
        &self.cell
    }

    /// The backend's name (`external` without one).
    pub fn backend_name(&self) -> &str {
        self.inference
            .as_ref()
            .map_or("external", InferenceStep::backend_name)
    }

    /// One depth frame → picks, as the pipeline computes it (`seed`: the backend's sampling).
    pub fn detect(
        &mut self,
        depth: &DepthImage,
        camera: &CameraModel,
        seed: u64,
    ) -> Result<Detection, PerceptionError> {
        self.detect_with(depth, camera, seed, Proposer::Backend, |_| true)
    }

    /// [`Perception::detect`] with the proposals from `proposer` and one more selection check
    /// (`keep`; see [`SelectionStep::select_filtered`]).
    pub fn detect_with(
        &mut self,
        depth: &DepthImage,
        camera: &CameraModel,
        seed: u64,
        proposer: Proposer<'_>,
        keep: impl FnMut(&SelectedGrasp) -> bool,
    ) -> Result<Detection, PerceptionError> {
        let t = Instant::now();
        let depth_scale = self.fusion.fuse(Cow::Borrowed(depth), camera)?;
        self.fusion.write_grid(&mut self.grid)?;
        let fusion_ms = ms(t);
        let (grid, surface) = grid_message_views(
            &self.cell.workspace,
            &self.cell.selection.surface_check,
            &self.grid,
            self.fusion.truncation_m(),
        )
        .map_err(|_| FusionError::BufferSize {
            name: "grid message",
            got: self.grid.len(),
            expected: self.fusion.grid_len(),
        })?;
        let t = Instant::now();
        let configurations = match proposer {
            Proposer::Backend => self
                .inference
                .as_mut()
                .ok_or(PerceptionError::NoBackend)?
                .infer(&grid, seed)?,
            Proposer::External(propose) => propose(),
        };
        let inference_ms = ms(t);
        let t = Instant::now();
        let selection = self
            .selection
            .select_filtered(&configurations, &grid, surface, keep)?;
        let selection_ms = ms(t);
        Ok(Detection {
            configurations,
            selection,
            depth_scale,
            timings: DetectionTimings {
                fusion_ms,
                inference_ms,
                selection_ms,
            },
        })
    }
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config(quality: f32) -> GraspConfiguration {
        GraspConfiguration {
            contact: nalgebra::Point3::origin(),
            baseline: nalgebra::Vector3::x(),
            collision_scores: [1.0; 18],
            width: 0.03,
            quality,
            kappa: 0.0,
            kappa_floor: 0.0,
        }
    }

    #[test]
    fn grasp_sets_are_ranked_stably_and_cut() {
        let mut configs: Vec<_> = [0.2, 0.9, 0.5, 0.9, 0.1].map(config).into();
        configs[3].width = 0.04; // the second 0.9 stays behind the first
        rank_and_cut(&mut configs, 3);
        let q: Vec<f32> = configs.iter().map(|c| c.quality).collect();
        assert_eq!(q, [0.9, 0.9, 0.5]);
        assert_eq!(configs[0].width, 0.03);
        assert_eq!(configs[1].width, 0.04);
    }
}
