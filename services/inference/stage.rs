//! inference: normal grid → grasp configurations through the configured backend
//! ([`psgrasp_perception::InferenceStep`]).
use crate::stage::{run_stage, Output, Sent, Stage, StageArgs, StageContext, StepFailure};
use anyhow::Result;
use psgrasp_fusion::{HeightMapView, NormalGridView};
use psgrasp_ipc::{FrameHeader, GraspRecord, MessageKind, Stamp, StatusCode};
use psgrasp_perception::{grid_message_views, InferenceStep};
use psgrasp_selection::SurfaceCheck;
use std::time::Duration;

/// Checks a grid message's payload against its header (and the cell's
/// `[selection.surface_check]`, which decides whether the frame's height map follows the grid)
/// and borrows it as its views.
pub fn grid_view<'a>(
    h: &FrameHeader,
    payload: &'a [f32],
    surface_check: &SurfaceCheck,
) -> Result<(NormalGridView<'a>, Option<HeightMapView<'a>>), String> {
    let workspace = h.workspace();
    workspace.validate().map_err(|e| e.to_string())?;
    grid_message_views(&workspace, surface_check, payload, h.truncation_m)
}

/// The inference step.
pub struct Inference {
    step: InferenceStep<'static>,
    seed: u64,
    /// Whether the grid messages carry the frame's height map after the grid.
    surface_check: SurfaceCheck,
}

impl Stage for Inference {
    type Input = f32;
    type Output = GraspRecord;
    const STAGE: psgrasp_ipc::Stage = psgrasp_ipc::Stage::Inference;
    const INPUT: MessageKind = MessageKind::NormalGrid;
    const ENTERED: Stamp = Stamp::FusionEnd;
    const OUTPUT: MessageKind = MessageKind::GraspSet;
    const START: Stamp = Stamp::InferenceStart;
    const END: Stamp = Stamp::InferenceEnd;

    fn process(
        &mut self,
        h: &FrameHeader,
        payload: &[f32],
        out: Output<'_, GraspRecord>,
    ) -> Result<Result<Sent, StepFailure>> {
        let view = match grid_view(h, payload, &self.surface_check) {
            Ok((v, _)) => v,
            Err(m) => return Ok(Err(StepFailure::new(StatusCode::ProtocolError, m))),
        };
        let configs = match self.step.infer(&view, self.seed) {
            Ok(c) => c,
            Err(e) => return Ok(Err(StepFailure::new(StatusCode::InferenceFailed, e))),
        };
        let records: Vec<GraspRecord> = configs.iter().map(GraspRecord::from).collect();
        out.send_slice(&records).map(Ok)
    }
}

/// The inference process.
pub fn run(args: StageArgs) -> Result<()> {
    let mut ctx = StageContext::new(psgrasp_ipc::Stage::Inference, &args)?;
    let names = ctx.node.names.clone();
    // A model (learned or VGN) whose card does not match the workspace or gripper fails here, at
    // start-up.
    let step = InferenceStep::new(&ctx.config.cell)?;
    let mut stage = Inference {
        step,
        seed: ctx.config.pipeline.seed,
        surface_check: ctx.config.cell.selection.surface_check,
    };
    let grid_sub = ctx.node.subscriber::<f32>(&names.grid())?;
    ctx.attach_inputs(&[(&grid_sub, ctx.config.pipeline.workers.fusion as usize)])?;
    let grasps_pub = ctx.node.publisher::<GraspRecord>(&names.grasps(), 1024)?;
    tracing::info!(
        "inference[{}] ready (backend {})",
        ctx.worker,
        stage.step.backend_name()
    );
    run_stage(
        &mut ctx,
        &mut stage,
        &grid_sub,
        &grasps_pub,
        &[],
        Duration::from_millis(200),
    )?;
    Ok(())
}
