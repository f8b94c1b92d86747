//! camera-ingest: pulls frames from the configured [`crate::sources`] source, checks them and
//! publishes them, announcing every frame id so that each one ends somewhere. It has no input,
//! so it runs its own source loop instead of the stage driver, with the same context and
//! counters.
use crate::sources::source_from_config;
use crate::stage::{stats_due, StageArgs, StageContext};
use anyhow::Result;
use psgrasp_geometry::DepthImage;
use psgrasp_ipc::{now_ns, FrameHeader, MessageKind, PickRecord, Stage, Stamp, StatusCode};
use std::time::{Duration, Instant};

/// The camera-ingest process: pulls frames from the configured source and publishes them.
pub fn run(args: StageArgs) -> Result<()> {
    let mut ctx = StageContext::new(Stage::CameraIngest, &args)?;
    let cfg = ctx.config.clone();
    let names = ctx.node.names.clone();
    let mut source = source_from_config(&cfg)?;
    let depth_pub = ctx
        .node
        .publisher::<f32>(&names.depth(), cfg.camera.intrinsics.pixel_count())?;
    let announce_pub = ctx
        .node
        .publisher_with_buffer::<u8>(&names.announce(), 1, 1024)?;

    // Wait for the consumers so the first frames are not published into the void.
    let want_fusion = cfg.pipeline.workers.fusion as usize;
    let want_selection = cfg.pipeline.workers.selection as usize;
    // Each stage creates its output publishers only once its inputs are attached
    // (`StageContext::attach_inputs`), so the selection workers' pick publishers mean the whole
    // chain is ready.
    let picks_publishers = || {
        ctx.node
            .publisher_count::<PickRecord>(&names.picks())
            .unwrap_or(0)
    };
    let chain_ready = ctx.node.wait_until(
        Duration::from_millis(cfg.camera.wait_for_subscribers_ms),
        || {
            depth_pub.subscriber_count() >= want_fusion
                && announce_pub.subscriber_count() >= want_selection
                && picks_publishers() >= want_selection
        },
    );
    if chain_ready.is_none() {
        return Ok(());
    }
    if depth_pub.subscriber_count() < want_fusion {
        tracing::warn!(
            "publishing without all grid-fusion workers connected ({} of {want_fusion})",
            depth_pub.subscriber_count()
        );
    }
    if picks_publishers() < want_selection {
        tracing::warn!(
            "publishing before all stages are ready ({} of {want_selection} grasp-selection \
             workers publish picks)",
            picks_publishers()
        );
    }
    tracing::info!(
        "camera-ingest: source {} at {} Hz",
        source.name(),
        cfg.camera.rate_hz
    );

    let period = if cfg.camera.rate_hz > 0.0 {
        Some(Duration::from_secs_f64(1.0 / cfg.camera.rate_hz))
    } else {
        None
    };
    let fallback_camera = cfg.camera_model();
    let mut last_id = 0u64;
    let mut published = 0u64;
    let mut last_stats = Instant::now();
    let mut next_due = Instant::now();
    loop {
        if cfg.camera.frames > 0 && published >= cfg.camera.frames {
            break;
        }
        if let Some(p) = period {
            let now = Instant::now();
            if next_due > now && ctx.node.node().wait(next_due - now).is_err() {
                break;
            }
            next_due = next_due.max(Instant::now() - p) + p;
        } else if ctx.node.node().wait(Duration::ZERO).is_err() {
            break;
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
        let mut announce = FrameHeader::new(
            MessageKind::Announce,
            frame_id,
            cfg.camera.source_id,
            &fallback_camera,
            &cfg.cell.workspace,
            now_ns(),
        );
        announce.stamp(Stamp::IngestPublished);
        announce_pub.send_header(announce)?;
        ctx.stats.frames_in += 1;
        ctx.stats.last_frame_id = frame_id;
        let checked = frame
            .map_err(|e| (StatusCode::InvalidDepth, format!("{e:#}")))
            .and_then(|f| validate_frame(&f.depth, &f.camera).map(|_| f));
        match checked {
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
                ctx.stats.frames_out += 1;
            }
            Err((status, msg)) => {
                tracing::warn!("frame {frame_id}: {msg}");
                let mut h = FrameHeader::new(
                    MessageKind::DepthFrame,
                    frame_id,
                    cfg.camera.source_id,
                    &fallback_camera,
                    &cfg.cell.workspace,
                    now_ns(),
                )
                .into_error(status, Stage::CameraIngest, &msg);
                h.stamp(Stamp::IngestPublished);
                depth_pub.send_header(h)?;
                ctx.stats.errors += 1;
            }
        }
        published += 1;
        ctx.stats.busy_ns += started.elapsed().as_nanos() as u64;
        ctx.stats.dropped = depth_pub.dropped();
        if stats_due(&mut last_stats, cfg.pipeline.stats_interval_ms) {
            ctx.publish_stats();
        }
    }
    ctx.stats.dropped = depth_pub.dropped();
    ctx.publish_stats();
    ctx.log_summary();
    // Stay alive until stopped so late subscribers can still drain (the launcher stops us).
    if cfg.camera.frames > 0 {
        while ctx.node.node().wait(Duration::from_millis(200)).is_ok() {}
    }
    Ok(())
}

/// Checks a source frame before it enters the pipeline; the status says what is wrong.
fn validate_frame(
    depth: &DepthImage,
    camera: &psgrasp_geometry::CameraModel,
) -> Result<(), (StatusCode, String)> {
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
