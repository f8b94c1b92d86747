//! grid-fusion: depth frame → normal grid, fused straight into the shared-memory loan
//! ([`psgrasp_perception::FusionStep`]).
use crate::stage::{run_stage, Output, Sent, Stage, StageArgs, StageContext, StepFailure};
use anyhow::Result;
use psgrasp_fusion::FusionError;
use psgrasp_geometry::DepthImage;
use psgrasp_ipc::{FrameHeader, MessageKind, Stamp, StatusCode};
use psgrasp_perception::{FusionStep, PerceptionError};
use std::borrow::Cow;
use std::time::Duration;

/// The grid-fusion step.
pub struct GridFusion {
    step: FusionStep,
}

/// The status of an error record for a failed fusion.
fn fusion_status(e: &PerceptionError) -> StatusCode {
    match e {
        PerceptionError::Fusion(FusionError::Geometry(_)) => StatusCode::InvalidCamera,
        PerceptionError::Fusion(FusionError::FrameSizeMismatch { .. })
        | PerceptionError::Fusion(FusionError::Depth(_)) => StatusCode::InvalidDepth,
        _ => StatusCode::FusionFailed,
    }
}

fn failure(e: PerceptionError) -> StepFailure {
    StepFailure::new(fusion_status(&e), e)
}

impl Stage for GridFusion {
    type Input = f32;
    type Output = f32;
    const STAGE: psgrasp_ipc::Stage = psgrasp_ipc::Stage::GridFusion;
    const INPUT: MessageKind = MessageKind::DepthFrame;
    const ENTERED: Stamp = Stamp::IngestPublished;
    const OUTPUT: MessageKind = MessageKind::NormalGrid;
    const START: Stamp = Stamp::FusionStart;
    const END: Stamp = Stamp::FusionEnd;

    fn prepare(&self, out: &mut FrameHeader) {
        out.truncation_m = self.step.truncation_m();
    }

    fn process(
        &mut self,
        h: &FrameHeader,
        payload: &[f32],
        out: Output<'_, f32>,
    ) -> Result<Result<Sent, StepFailure>> {
        let camera = h.camera();
        let fused = DepthImage::from_metres(h.image_size[0], h.image_size[1], payload.to_vec())
            .map_err(|e| PerceptionError::Fusion(FusionError::from(e)))
            .and_then(|depth| self.step.fuse(Cow::Owned(depth), &camera));
        match fused {
            Ok(scale) => {
                if let Some(s) = scale {
                    match s.estimate {
                        Some(e) => tracing::debug!(
                            "frame {}: depth scale {:.4} (support {:.2}, applied {})",
                            h.frame_id,
                            e.scale,
                            e.support,
                            s.applied
                        ),
                        None => tracing::warn!(
                            "frame {}: no depth scale found (too little of the bin visible); \
                             frame left as measured",
                            h.frame_id
                        ),
                    }
                }
            }
            Err(e) => return Ok(Err(failure(e))),
        }
        let step = &self.step;
        out.send_with(step.grid_len(), |buf| step.write_grid(buf).map_err(failure))
    }
}

/// The grid-fusion process.
pub fn run(args: StageArgs) -> Result<()> {
    let mut ctx = StageContext::new(psgrasp_ipc::Stage::GridFusion, &args)?;
    let names = ctx.node.names.clone();
    let mut stage = GridFusion {
        step: FusionStep::new(&ctx.config.cell)?,
    };
    let depth_sub = ctx.node.subscriber::<f32>(&names.depth())?;
    ctx.attach_inputs(&[(&depth_sub, 1)])?;
    let grid_pub = ctx
        .node
        .publisher::<f32>(&names.grid(), stage.step.grid_len())?;
    tracing::info!(
        "grid-fusion[{}] ready ({} voxels)",
        ctx.worker,
        ctx.config.cell.workspace.voxel_count()
    );
    run_stage(
        &mut ctx,
        &mut stage,
        &depth_sub,
        &grid_pub,
        &[],
        Duration::from_millis(200),
    )?;
    Ok(())
}
