//! grasp-selection: grasp set → ranked executable picks ([`psgrasp_perception::SelectionStep`]),
//! loss detection for every announced frame, and (worker 0) the next-pick server.
use crate::inference::grid_view;
use crate::next_pick::NextPickServer;
use crate::stage::{run_stage, Output, Sent, Shard, Stage, StageArgs, StageContext, StepFailure};
use anyhow::Result;
use psgrasp_geometry::{GraspConfiguration, Workspace};
use psgrasp_ipc::{
    now_ns, FrameHeader, FramePublisher, FrameSubscriber, FrameTracker, GraspRecord, MessageKind,
    PickRecord, Stamp, StatusCode, TrackerEvent,
};
use psgrasp_perception::SelectionStep;
use psgrasp_selection::Selection;
use std::collections::BTreeMap;
use std::time::Duration;

/// Grids kept for matching grasp sets by frame id.
const GRID_CACHE: usize = 16;

/// The grasp-selection step and its side inputs.
pub struct GraspSelection<'a> {
    step: SelectionStep,
    /// Most picks published per frame (`selection.top_k`).
    max_picks: usize,
    /// The frames of this worker (its share of the grid side input).
    shard: Shard,
    announce: &'a FrameSubscriber<u8>,
    grid: &'a FrameSubscriber<f32>,
    grids: BTreeMap<u64, (FrameHeader, Vec<f32>)>,
    tracker: FrameTracker,
    loss_timeout_ms: u64,
    workspace: Workspace,
    server: Option<NextPickServer<'a>>,
}

impl GraspSelection<'_> {
    /// The picks of one grasp set on its frame's grid.
    fn select(
        &self,
        configs: &[GraspConfiguration],
        grid: &(FrameHeader, Vec<f32>),
    ) -> Result<Vec<PickRecord>, StepFailure> {
        let view = grid_view(&grid.0, &grid.1)
            .map_err(|m| StepFailure::new(StatusCode::ProtocolError, m))?;
        let selection = self
            .step
            .select(configs, &view)
            .map_err(|e| StepFailure::new(StatusCode::SelectionFailed, e))?;
        Ok(pick_records(&selection, configs, self.max_picks))
    }
}

/// The pick records of `selection` (picks of `configs`), best first, at most `max`: what
/// grasp-selection publishes on `picks`.
pub fn pick_records(
    selection: &Selection,
    configs: &[GraspConfiguration],
    max: usize,
) -> Vec<PickRecord> {
    selection
        .picks
        .iter()
        .take(max)
        .enumerate()
        .map(|(rank, p)| {
            PickRecord::new(
                &p.workspace_from_gripper,
                &p.pregrasp,
                &configs[p.configuration_index].contact,
                p.width,
                p.quality,
                p.collision_score,
                p.configuration_index as u32,
                p.approach_index as u32,
                rank as u32,
            )
        })
        .collect()
}

impl Stage for GraspSelection<'_> {
    type Input = GraspRecord;
    type Output = PickRecord;
    const STAGE: psgrasp_ipc::Stage = psgrasp_ipc::Stage::GraspSelection;
    const INPUT: MessageKind = MessageKind::GraspSet;
    const OUTPUT: MessageKind = MessageKind::SelectedGrasps;
    const START: Stamp = Stamp::SelectionStart;
    const END: Stamp = Stamp::SelectionEnd;

    fn before_frames(&mut self) -> Result<()> {
        while let Some(s) = self.announce.receive()? {
            self.tracker.announce(s.user_header().frame_id, now_ns());
        }
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

    fn admit(&mut self, h: &FrameHeader) -> bool {
        if self.tracker.complete(h.frame_id) == TrackerEvent::Duplicate {
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
        let Some(grid) = self.grids.remove(&h.frame_id) else {
            return Ok(Err(StepFailure::new(
                StatusCode::SelectionFailed,
                "normal grid of this frame never arrived (dropped under overload); no collision \
                 check possible",
            )));
        };
        match self.select(&configs, &grid) {
            Ok(picks) => out.send_slice(&picks).map(Ok),
            Err(f) => Ok(Err(f)),
        }
    }

    fn after_frames(&mut self, out: &FramePublisher<PickRecord>, errors: &mut u64) -> Result<()> {
        for lost in self.tracker.expire(now_ns()) {
            let msg = format!(
                "no result within {} ms: a stage died or dropped the frame under overload",
                self.loss_timeout_ms
            );
            tracing::warn!("frame {lost}: {msg}");
            let mut rec = FrameHeader {
                frame_id: lost,
                ..FrameHeader::default()
            }
            .into_error(StatusCode::Lost, Self::STAGE, &msg);
            rec.kind = MessageKind::SelectedGrasps as u32;
            rec.grid_dims = self.workspace.dims;
            rec.voxel_size_m = self.workspace.voxel_size_m;
            rec.stamp(Stamp::SelectionEnd);
            out.send_header(rec)?;
            *errors += 1;
        }
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
    let grasps_sub = ctx.node.subscriber::<GraspRecord>(&names.grasps())?;
    let grid_sub = ctx.node.subscriber::<f32>(&names.grid())?;
    let announce_sub = ctx
        .node
        .subscriber_with_buffer::<u8>(&names.announce(), 1024)?;
    let w = cfg.pipeline.workers;
    ctx.attach_inputs(&[
        (&announce_sub, 1),
        (&grid_sub, w.fusion as usize),
        (&grasps_sub, w.inference as usize),
    ])?;
    let max_picks = cfg.cell.selection.top_k;
    let picks_pub = ctx
        .node
        .publisher::<PickRecord>(&names.picks(), max_picks.max(1))?;
    // Worker 0 answers "next pick" requests from the picks of all workers.
    let server_ports = match ctx.worker {
        0 => Some(NextPickServer::ports(&ctx.node)?),
        _ => None,
    };
    let mut side = vec![announce_sub.listener(), grid_sub.listener()];
    if let Some(ports) = &server_ports {
        side.extend(ports.listeners());
    }
    let mut stage = GraspSelection {
        step,
        max_picks,
        shard: ctx.shard(),
        announce: &announce_sub,
        grid: &grid_sub,
        grids: BTreeMap::new(),
        tracker: FrameTracker::new(
            ctx.workers as u64,
            ctx.worker as u64,
            cfg.pipeline.loss_timeout_ms * 1_000_000,
        ),
        loss_timeout_ms: cfg.pipeline.loss_timeout_ms,
        workspace: cfg.cell.workspace,
        server: server_ports.as_ref().map(NextPickServer::new),
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
