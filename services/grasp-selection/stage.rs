//! grasp-selection: grasp set → ranked executable picks ([`psgrasp_perception::SelectionStep`])
//! published as the frame's outcome, and (worker 0) the next-pick server. Frames the ledger
//! already ended (camera-ingest's verdicts on `progress`) are not published a second time.
use crate::inference::grid_view;
use crate::next_pick::{state_path, NextPickServer};
use crate::stage::{run_stage, Output, Sent, Shard, Stage, StageArgs, StageContext, StepFailure};
use anyhow::Result;
use psgrasp_geometry::{BaseFrame, GraspConfiguration, RobotCell};
use psgrasp_ipc::{
    FrameHeader, FrameSubscriber, GraspRecord, MessageKind, PickRecord, ProgressEvent,
    ProgressKind, RecentIds, Stamp, StatusCode,
};
use psgrasp_perception::SelectionStep;
use psgrasp_selection::Selection;
use std::collections::BTreeMap;
use std::time::Duration;

/// Grids kept for matching grasp sets by frame id.
const GRID_CACHE: usize = 16;
/// Frames ended by the ledger that are remembered (to drop a late result of one).
const VERDICT_MEMORY: usize = 4096;

/// The grasp-selection step and its side inputs.
pub struct GraspSelection<'a> {
    step: SelectionStep,
    /// Most picks published per frame (`selection.top_k`).
    max_picks: usize,
    /// The robot around the cell (`[robot]`): picks are also given in its base frame.
    robot: RobotCell,
    /// The frames of this worker (its share of the grid side input).
    shard: Shard,
    progress: &'a FrameSubscriber<ProgressEvent>,
    grid: &'a FrameSubscriber<f32>,
    grids: BTreeMap<u64, (FrameHeader, Vec<f32>)>,
    /// Frames the ledger ended with an error record.
    ended_by_ledger: RecentIds,
    /// When this worker started taking frames.
    started_ns: u64,
    server: Option<NextPickServer<'a>>,
}

impl GraspSelection<'_> {
    /// Moves the grids waiting on the side input into the cache.
    fn take_grids(&mut self) -> Result<()> {
        while let Some(s) = self.grid.receive()? {
            let h = *s.user_header();
            if self.shard.owns(h.frame_id) && h.is_ok() {
                self.grids.insert(h.frame_id, (h, s.payload().to_vec()));
                while self.grids.len() > GRID_CACHE {
                    self.grids.pop_first();
                }
            }
        }
        Ok(())
    }

    /// The picks of one grasp set on its frame's grid.
    fn select(
        &self,
        configs: &[GraspConfiguration],
        grid: &(FrameHeader, Vec<f32>),
    ) -> Result<Vec<PickRecord>, StepFailure> {
        let (view, surface) =
            grid_view(&grid.0, &grid.1, &self.step.cell().selection.surface_check)
                .map_err(|m| StepFailure::new(StatusCode::ProtocolError, m))?;
        let selection = self
            .step
            .select(configs, &view, surface)
            .map_err(|e| StepFailure::new(StatusCode::SelectionFailed, e))?;
        let base = self
            .robot
            .base_frame(&grid.0.camera().workspace_from_camera);
        Ok(pick_records(&selection, configs, self.max_picks, &base))
    }
}

/// The pick records of `selection` (picks of `configs`), best first, at most `max`, with their
/// poses also in the robot base frame `base`: what grasp-selection publishes on `picks`.
pub fn pick_records(
    selection: &Selection,
    configs: &[GraspConfiguration],
    max: usize,
    base: &BaseFrame,
) -> Vec<PickRecord> {
    selection
        .picks
        .iter()
        .take(max)
        .enumerate()
        .map(|(rank, p)| {
            PickRecord {
                fallback: u32::from(selection.fallback),
                ..PickRecord::new(
                    &p.workspace_from_gripper,
                    &p.pregrasp,
                    &configs[p.configuration_index].contact,
                    p.width,
                    p.quality,
                    p.collision_score,
                    p.configuration_index as u32,
                    p.approach_index as u32,
                    rank as u32,
                    base,
                )
            }
            .with_pad_fill(p.pad_fill)
        })
        .collect()
}

impl Stage for GraspSelection<'_> {
    type Input = GraspRecord;
    type Output = PickRecord;
    const STAGE: psgrasp_ipc::Stage = psgrasp_ipc::Stage::GraspSelection;
    const INPUT: MessageKind = MessageKind::GraspSet;
    const ENTERED: Stamp = Stamp::InferenceEnd;
    const OUTPUT: MessageKind = MessageKind::SelectedGrasps;
    const START: Stamp = Stamp::SelectionStart;
    const END: Stamp = Stamp::SelectionEnd;

    fn before_frames(&mut self) -> Result<()> {
        while let Some(s) = self.progress.receive()? {
            for e in s.payload() {
                if e.kind() == Some(ProgressKind::Verdict) {
                    self.ended_by_ledger.insert(e.frame_id);
                }
            }
        }
        self.take_grids()
    }

    fn admit(&mut self, h: &FrameHeader) -> bool {
        if self.ended_by_ledger.contains(h.frame_id) {
            tracing::warn!(
                "frame {}: result after it was reported lost; dropped",
                h.frame_id
            );
            return false;
        }
        true
    }

    fn process(
        &mut self,
        h: &FrameHeader,
        payload: &[GraspRecord],
        out: Output<'_, PickRecord>,
    ) -> Result<Result<Sent, StepFailure>> {
        let configs: Vec<GraspConfiguration> =
            payload.iter().map(GraspConfiguration::from).collect();
        if !self.grids.contains_key(&h.frame_id) {
            // The grid is published before inference starts on it, so it waits on the side
            // input by now, but it may have arrived after this batch's `before_frames` (a grasp
            // set that came in while an earlier one of the batch was being processed).
            self.take_grids()?;
        }
        let Some(grid) = self.grids.remove(&h.frame_id) else {
            let why = if h.stamps_ns[Stamp::FusionEnd as usize] < self.started_ns {
                "its normal grid was published before this grasp-selection worker (re)started"
            } else {
                "its normal grid never arrived"
            };
            return Ok(Err(StepFailure::new(
                StatusCode::SelectionFailed,
                format!("{why}; no collision check possible"),
            )));
        };
        match self.select(&configs, &grid) {
            Ok(picks) => out.send_slice(&picks).map(Ok),
            Err(f) => Ok(Err(f)),
        }
    }

    fn after_frames(
        &mut self,
        _out: &psgrasp_ipc::FramePublisher<PickRecord>,
        _errors: &mut u64,
    ) -> Result<()> {
        if let Some(server) = self.server.as_mut() {
            server.serve()?;
        }
        Ok(())
    }
}

/// The grasp-selection process.
pub fn run(args: StageArgs) -> Result<()> {
    let mut ctx = StageContext::new(psgrasp_ipc::Stage::GraspSelection, &args)?;
    let cfg = ctx.config.clone();
    let names = ctx.node.names.clone();
    let step = SelectionStep::new(&cfg.cell)?;
    let robot = cfg.cell.robot_cell()?;
    let grasps_sub = ctx.node.subscriber::<GraspRecord>(&names.grasps())?;
    let grid_sub = ctx.node.subscriber::<f32>(&names.grid())?;
    let progress_sub = ctx.node.progress_subscriber()?;
    let w = cfg.pipeline.workers;
    ctx.attach_inputs(&[
        (&grid_sub, w.fusion as usize),
        (&grasps_sub, w.inference as usize),
    ])?;
    let max_picks = cfg.cell.selection.top_k;
    let picks_pub = ctx.node.outcome_publisher(max_picks)?;
    // Worker 0 answers "next pick" requests from the picks of all workers.
    let server_ports = match ctx.worker {
        0 => Some(NextPickServer::ports(&ctx.node)?),
        _ => None,
    };
    let mut side = vec![progress_sub.listener(), grid_sub.listener()];
    if let Some(ports) = &server_ports {
        side.extend(ports.listeners());
    }
    let mut stage = GraspSelection {
        step,
        max_picks,
        robot,
        shard: ctx.shard(),
        progress: &progress_sub,
        grid: &grid_sub,
        grids: BTreeMap::new(),
        ended_by_ledger: RecentIds::new(VERDICT_MEMORY),
        started_ns: ctx.started_ns,
        server: server_ports.as_ref().map(|ports| {
            let state = state_path(&cfg.pipeline.name);
            NextPickServer::new(ports, state, cfg.cell.selection.failed_pick_memory)
        }),
    };
    tracing::info!("grasp-selection[{}] ready", ctx.worker);
    run_stage(
        &mut ctx,
        &mut stage,
        &grasps_sub,
        &picks_pub,
        &side,
        Duration::from_millis(20),
    )?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Isometry3, Point3, Vector3};
    use psgrasp_selection::SelectedGrasp;

    #[test]
    fn pick_records_say_whether_the_selection_fell_back_and_their_pad_fill() {
        let config = GraspConfiguration {
            contact: Point3::new(0.2, 0.25, 0.06),
            baseline: Vector3::x(),
            collision_scores: [0.3; psgrasp_geometry::N_APPROACHES],
            width: 0.04,
            quality: 0.9,
            kappa: 25.0,
            kappa_floor: 0.0,
        };
        let pose = Isometry3::translation(0.22, 0.25, 0.06);
        let pick = SelectedGrasp {
            workspace_from_gripper: pose,
            pregrasp: Isometry3::translation(0.22, 0.25, 0.16),
            pregrasp_distance_m: 0.1,
            width: 0.04,
            opening_m: 0.08,
            quality: 0.9,
            collision_score: 0.3,
            configuration_index: 0,
            approach_index: 8,
            pad_fill: None,
        };
        let base = psgrasp_geometry::RobotConfig::default()
            .resolve(0.0095)
            .unwrap()
            .base_frame(&Isometry3::identity());
        for (fallback, pad_fill) in [(false, None), (true, Some(0.62))] {
            let pick = SelectedGrasp { pad_fill, ..pick };
            let selection = Selection {
                picks: vec![pick, pick],
                rejected: Default::default(),
                fallback,
            };
            let records = pick_records(&selection, &[config], 1, &base);
            assert_eq!(records.len(), 1);
            assert_eq!(records[0].fallback, u32::from(fallback));
            assert_eq!(records[0].pad_fill(), pad_fill);
            assert_eq!(records[0].pad_fill_measured, u32::from(pad_fill.is_some()));
            assert_eq!(records[0].approach_index, 8);
        }
    }
}
