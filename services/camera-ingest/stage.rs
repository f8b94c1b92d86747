//! camera-ingest: pulls frames from the configured [`crate::sources`] source, checks them,
//! admits them into the pipeline and keeps the [`FrameLedger`], so that every admitted frame ends
//! as picks or exactly one error record whichever stage dies. It has no input, so it runs its
//! own source loop instead of the stage driver, with the same context and counters.
//!
//! Admission control: at most `pipeline.max_frames_in_flight` frames are in the pipeline. A
//! paced camera refuses a frame beyond that with an `Overload` record; an unpaced one
//! (`rate_hz = 0`, replaying recorded data) waits for room, which is back-pressure without loss.
use crate::sources::source_from_config;
use crate::stage::{stats_due, StageArgs, StageContext};
use anyhow::Result;
use psgrasp_config::PipelineConfig;
use psgrasp_geometry::{CameraModel, DepthImage};
use psgrasp_ipc::{
    now_ns, FrameHeader, FrameLedger, FramePublisher, FrameSubscriber, MessageKind, PickRecord,
    ProgressEvent, ProgressKind, Stage, Stamp, StatusCode, Verdict,
};
use std::time::{Duration, Instant};

/// How often an idle or waiting camera-ingest settles the ledger.
const LEDGER_TICK: Duration = Duration::from_millis(5);

/// The ports and the ledger that account for every admitted frame.
struct Accounting {
    ledger: FrameLedger,
    progress: FrameSubscriber<ProgressEvent>,
    /// Every frame's outcome (grasp-selection's, and the records decided here): the last
    /// stage's report that a frame ended, in the same message, so it cannot be missed.
    ended: FrameSubscriber<PickRecord>,
    /// Error records decided here (lost frames, refused and invalid frames).
    outcomes: FramePublisher<PickRecord>,
    events: Vec<ProgressEvent>,
    template: FrameHeader,
    max_in_flight: usize,
}

impl Accounting {
    /// Reads the progress reports and publishes the error record of every frame the ledger
    /// ends (a stage holding it restarted, or the loss timeout passed).
    fn settle(&mut self, ctx: &mut StageContext) -> Result<()> {
        // Progress first, then outcomes: an outcome sent before a restart report is then seen
        // in the same batch (the batch is applied in time order).
        while let Some(s) = self.progress.receive()? {
            self.events.extend_from_slice(s.payload());
        }
        while let Some(s) = self.ended.receive()? {
            let h = s.user_header();
            self.events.push(ProgressEvent::new(
                ProgressKind::Left,
                Stage::GraspSelection,
                h.workers[2] as u32,
                h.frame_id,
                h.stamps_ns[Stamp::SelectionEnd as usize],
            ));
        }
        let mut verdicts = self.ledger.apply(&mut self.events);
        self.events.clear();
        verdicts.extend(self.ledger.expire(now_ns()));
        for v in verdicts {
            self.publish_verdict(ctx, &v)?;
        }
        Ok(())
    }

    fn publish_verdict(&self, ctx: &mut StageContext, v: &Verdict) -> Result<()> {
        tracing::warn!("frame {}: {}", v.frame_id, v.message);
        // Stages drop a late result of the frame: it has its outcome now.
        ctx.report_verdict(v.frame_id);
        self.publish_record(v.frame_id, v.status, v.stage, &v.message)?;
        ctx.stats.errors += 1;
        Ok(())
    }

    /// Publishes the error record of `frame_id` as its outcome.
    fn publish_record(
        &self,
        frame_id: u64,
        status: StatusCode,
        stage: Stage,
        message: &str,
    ) -> Result<()> {
        let mut rec = FrameHeader {
            frame_id,
            ..self.template
        }
        .into_error(status, stage, message);
        rec.stamp(Stamp::SelectionEnd);
        self.outcomes.send_header(rec)?;
        Ok(())
    }

    fn full(&self) -> bool {
        self.ledger.in_flight() >= self.max_in_flight
    }
}

/// The camera-ingest process: pulls frames from the configured source and admits them.
pub fn run(args: StageArgs) -> Result<()> {
    let mut ctx = StageContext::new(Stage::CameraIngest, &args)?;
    let cfg = ctx.config.clone();
    let names = ctx.node.names.clone();
    let mut source = source_from_config(&cfg)?;
    let depth_pub = ctx
        .node
        .publisher::<f32>(&names.depth(), cfg.camera.intrinsics.pixel_count())?;
    let fallback_camera = cfg.camera_model();
    let mut template = FrameHeader::new(
        MessageKind::SelectedGrasps,
        0,
        cfg.camera.source_id,
        &fallback_camera,
        &cfg.cell.workspace,
        0,
    );
    template.stamp(Stamp::IngestPublished);
    let w = cfg.pipeline.workers;
    let mut acc = Accounting {
        ledger: FrameLedger::new(
            [w.fusion, w.inference, w.selection],
            cfg.pipeline.loss_timeout_ms * 1_000_000,
        ),
        progress: ctx.node.progress_subscriber()?,
        ended: ctx.node.outcome_subscriber()?,
        outcomes: ctx.node.outcome_publisher(1)?,
        events: Vec::new(),
        template,
        max_in_flight: cfg.pipeline.max_frames_in_flight,
    };
    if !wait_for_chain(&ctx, &cfg, &depth_pub) {
        return Ok(());
    }
    ctx.report_started()?;
    tracing::info!(
        "camera-ingest: source {} at {} Hz, at most {} frames in flight",
        source.name(),
        cfg.camera.rate_hz,
        cfg.pipeline.max_frames_in_flight
    );
    let period =
        (cfg.camera.rate_hz > 0.0).then(|| Duration::from_secs_f64(1.0 / cfg.camera.rate_hz));
    let mut last_id = 0u64;
    let mut published = 0u64;
    let mut last_stats = Instant::now();
    let mut next_due = Instant::now();
    while cfg.camera.frames == 0 || published < cfg.camera.frames {
        acc.settle(&mut ctx)?;
        if let Some(p) = period {
            if !sleep_until(&mut ctx, &mut acc, next_due)? {
                break;
            }
            next_due = next_due.max(Instant::now() - p) + p;
        } else {
            // Unpaced: wait for room instead of refusing (back-pressure without loss).
            while acc.full() {
                if !ctx.node.sleep(LEDGER_TICK) {
                    break;
                }
                acc.settle(&mut ctx)?;
            }
            if !ctx.node.sleep(Duration::ZERO) {
                break;
            }
        }
        // Frame ids are microsecond timestamps made strictly increasing: unique across restarts.
        let frame_id = (now_ns() / 1000).max(last_id + 1);
        last_id = frame_id;
        let started = Instant::now();
        let frame = match source.next_frame() {
            Ok(Some(f)) => Ok(f),
            Ok(None) => {
                tracing::info!("camera-ingest: source exhausted after {published} frames");
                break;
            }
            Err(e) => Err(e),
        };
        ctx.stats.frames_in += 1;
        ctx.stats.last_frame_id = frame_id;
        published += 1;
        let checked = frame
            .map_err(|e| (StatusCode::InvalidDepth, format!("{e:#}")))
            .and_then(|f| validate_frame(&f.depth, &f.camera).map(|_| f));
        acc.settle(&mut ctx)?;
        match checked {
            Ok(_) if acc.full() => {
                let msg = format!(
                    "refused at admission: {} frames in flight (pipeline.max_frames_in_flight); \
                     the camera is faster than the pipeline",
                    acc.ledger.in_flight()
                );
                tracing::debug!("frame {frame_id}: {msg}");
                acc.publish_record(frame_id, StatusCode::Overload, Stage::CameraIngest, &msg)?;
                ctx.stats.errors += 1;
            }
            Ok(f) => {
                let mut h = FrameHeader::new(
                    MessageKind::DepthFrame,
                    frame_id,
                    cfg.camera.source_id,
                    &f.camera,
                    &cfg.cell.workspace,
                    f.capture_ns,
                );
                h.stamp(Stamp::IngestPublished);
                depth_pub
                    .send_with::<()>(h, f.depth.data.len(), |buf| {
                        buf.copy_from_slice(&f.depth.data);
                        Ok(())
                    })?
                    .ok();
                let published_ns = h.stamps_ns[Stamp::IngestPublished as usize];
                ctx.report_admitted(frame_id, published_ns);
                if let Some(v) = acc.ledger.admit(frame_id, published_ns) {
                    acc.publish_verdict(&mut ctx, &v)?;
                }
                ctx.stats.frames_out += 1;
            }
            Err((status, msg)) => {
                // Ends here: the error record is the frame's outcome.
                tracing::warn!("frame {frame_id}: {msg}");
                acc.publish_record(frame_id, status, Stage::CameraIngest, &msg)?;
                ctx.stats.errors += 1;
            }
        }
        ctx.stats.busy_ns += started.elapsed().as_nanos() as u64;
        ctx.stats.dropped = depth_pub.dropped();
        if stats_due(&mut last_stats, cfg.pipeline.stats_interval_ms) {
            ctx.publish_stats();
        }
    }
    ctx.stats.dropped = depth_pub.dropped();
    ctx.publish_stats();
    ctx.log_summary();
    // A finite source: stay up, accounting for the frames still in flight, until stopped, and
    // keep reporting statistics (a controller's health check sees an idle camera, not a dead one).
    if cfg.camera.frames > 0 {
        while ctx.node.sleep(LEDGER_TICK) {
            acc.settle(&mut ctx)?;
            if stats_due(&mut last_stats, cfg.pipeline.stats_interval_ms) {
                ctx.publish_stats();
            }
        }
    }
    Ok(())
}

/// Waits (up to `camera.wait_for_subscribers_ms`) until the whole chain is attached, so the
/// first frames are not published into the void. False on a termination signal.
fn wait_for_chain(
    ctx: &StageContext,
    cfg: &PipelineConfig,
    depth_pub: &FramePublisher<f32>,
) -> bool {
    let want_fusion = cfg.pipeline.workers.fusion as usize;
    let want_selection = cfg.pipeline.workers.selection as usize;
    let names = &ctx.node.names;
    // Each stage creates its output publishers only once its inputs are attached
    // (`StageContext::attach_inputs`), so the selection workers' pick publishers (besides this
    // process's own) mean the whole chain is ready.
    let picks_publishers = || {
        ctx.node
            .publisher_count::<PickRecord>(&names.picks())
            .unwrap_or(1)
            .saturating_sub(1)
    };
    let ready = ctx.node.wait_until(
        Duration::from_millis(cfg.camera.wait_for_subscribers_ms),
        || depth_pub.subscriber_count() >= want_fusion && picks_publishers() >= want_selection,
    );
    match ready {
        None => return false,
        Some(true) => {}
        Some(false) => tracing::warn!(
            "publishing before all stages are ready ({} of {want_fusion} grid-fusion workers \
             subscribed, {} of {want_selection} grasp-selection workers publish picks)",
            depth_pub.subscriber_count(),
            picks_publishers()
        ),
    }
    true
}

/// Sleeps until `due`, settling the ledger meanwhile; false on a termination signal.
fn sleep_until(ctx: &mut StageContext, acc: &mut Accounting, due: Instant) -> Result<bool> {
    loop {
        let now = Instant::now();
        if now >= due {
            return Ok(ctx.node.sleep(Duration::ZERO));
        }
        if !ctx.node.sleep((due - now).min(LEDGER_TICK)) {
            return Ok(false);
        }
        acc.settle(ctx)?;
    }
}

/// Checks a source frame before it enters the pipeline; the status says what is wrong.
fn validate_frame(depth: &DepthImage, camera: &CameraModel) -> Result<(), (StatusCode, String)> {
    camera.validate().map_err(|e| {
        (
            StatusCode::InvalidCamera,
            format!("camera intrinsics/pose: {e}"),
        )
    })?;
    if depth.width != camera.intrinsics.width || depth.height != camera.intrinsics.height {
        return Err((
            StatusCode::InvalidDepth,
            format!(
                "frame is {}×{} but the intrinsics say {}×{}",
                depth.width, depth.height, camera.intrinsics.width, camera.intrinsics.height
            ),
        ));
    }
    depth
        .require_valid()
        .map_err(|e| (StatusCode::InvalidDepth, e.to_string()))
}
