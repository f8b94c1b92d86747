//! inference: normal grid → grasp configurations through the configured backend
//! ([`psgrasp_perception::InferenceStep`]).
use crate::stage::{run_stage, Output, Sent, Stage, StageArgs, StageContext, StepFailure};
use anyhow::Result;
use psgrasp_fusion::NormalGridView;
use psgrasp_ipc::{FrameHeader, GraspRecord, MessageKind, Stamp, StatusCode};
use psgrasp_perception::InferenceStep;
use std::time::Duration;

/// Checks a grid message's payload against its header and borrows it as a grid view.
pub fn grid_view<'a>(h: &FrameHeader, payload: &'a [f32]) -> Result<NormalGridView<'a>, String> {
    let workspace = h.workspace();
    workspace.validate().map_err(|e| e.to_string())?;
    let n = workspace.voxel_count();
    if payload.len() != 4 * n {
        return Err(format!(
            "grid payload has {} values, header dims need {}",
            payload.len(),
            4 * n
        ));
    }
    let (normals, tsdf) = payload.split_at(3 * n);
    Ok(NormalGridView {
        workspace,
        normals,
        tsdf,
        truncation_m: h.truncation_m,
    })
}

/// The inference step.
pub struct Inference {
    step: InferenceStep<'static>,
    seed: u64,
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
        let view = match grid_view(h, payload) {
            Ok(v) => v,
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
