//! The four stage processes. Each: set up from the config, then one event loop that drains its
//! inputs, writes its output straight into shared memory and turns every failure into an error
//! record that travels on to the end of the pipeline.
use crate::runtime::{run_event_loop, LoopExit, StageArgs, StageContext};
use crate::sources::source_from_config;
use anyhow::Result;
use iceoryx2::prelude::*;
use psgrasp_fusion::{FusionError, NormalGridView, TsdfVolume};
use psgrasp_geometry::{DepthImage, GraspConfiguration};
use psgrasp_ipc::{
    now_ns, FrameHeader, FrameTracker, GraspRecord, MessageKind, NextPickRequest, NextPickResponse,
    PickRecord, Stage, Stamp, StatusCode, TrackerEvent,
};
use std::collections::BTreeMap;
use std::time::{Duration, Instant};

/// Largest grasp set a stage publishes (configurations beyond it are cut, best first).
pub const MAX_GRASPS_PER_FRAME: usize = 16_384;
/// Largest pick list per frame.
pub const MAX_PICKS_PER_FRAME: usize = 256;

fn stats_due(last: &mut Instant, interval_ms: u64) -> bool {
    if last.elapsed() >= Duration::from_millis(interval_ms) {
        *last = Instant::now();
        true
    } else {
        false
    }
}

/// camera-ingest: pulls frames from the configured source and publishes them.
pub fn run_camera_ingest(args: StageArgs) -> Result<()> {
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
            &cfg.workspace,
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
                    &cfg.workspace,
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
                    &cfg.workspace,
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

/// The error record a stage publishes for a frame that ends with it: an upstream error record
/// (`input` not ok) is forwarded unchanged; otherwise `out` becomes an error raised at `stage`.
/// Either way `end` is stamped.
fn error_record(
    input: &FrameHeader,
    out: FrameHeader,
    stage: Stage,
    status: StatusCode,
    msg: &str,
    end: Stamp,
) -> FrameHeader {
    let mut rec = if input.is_ok() {
        tracing::warn!("frame {}: {msg}", input.frame_id);
        out.into_error(status, stage, msg)
    } else {
        out
    };
    rec.stamp(end);
    rec
}

fn fusion_status(e: &FusionError) -> StatusCode {
    match e {
        FusionError::Geometry(_) => StatusCode::InvalidCamera,
        FusionError::FrameSizeMismatch { .. } | FusionError::Depth(_) => StatusCode::InvalidDepth,
        _ => StatusCode::FusionFailed,
    }
}

/// grid-fusion: depth frame → normal grid, fused straight into the shared-memory loan.
pub fn run_grid_fusion(args: StageArgs) -> Result<()> {
    let mut ctx = StageContext::new(Stage::GridFusion, &args)?;
    let cfg = ctx.config.clone();
    let names = ctx.node.names.clone();
    let n = cfg.workspace.voxel_count();
    let depth_sub = ctx.node.subscriber::<f32>(&names.depth())?;
    ctx.attach_inputs(&[(&depth_sub, 1)])?;
    let grid_pub = ctx.node.publisher::<f32>(&names.grid(), 4 * n)?;
    let mut volume = TsdfVolume::new(cfg.workspace, &cfg.fusion)?;
    let mut last_stats = Instant::now();
    tracing::info!("grid-fusion[{}] ready ({} voxels)", ctx.worker, n);
    let exit = run_event_loop(&[depth_sub.listener()], Duration::from_millis(200), || {
        while let Some(sample) = depth_sub.receive()? {
            let h = *sample.user_header();
            if !ctx.owns(h.frame_id) {
                continue;
            }
            let started = Instant::now();
            ctx.stats.frames_in += 1;
            ctx.stats.last_frame_id = h.frame_id;
            let mut out = h.forwarded(MessageKind::NormalGrid);
            out.stamp(Stamp::FusionStart);
            out.workers[0] = ctx.worker as u16;
            out.truncation_m = volume.truncation_m();
            let error = if let Err(m) = h.check(MessageKind::DepthFrame) {
                Some((StatusCode::ProtocolError, m))
            } else if !h.is_ok() {
                None // forwarded below as the error record it already is
            } else {
                let camera = h.camera();
                let result = DepthImage::from_metres(
                    h.image_size[0],
                    h.image_size[1],
                    sample.payload().to_vec(),
                )
                .map_err(FusionError::from)
                .and_then(|mut depth| {
                    let (scale, applied) = psgrasp_fusion::correct_depth_scale(
                        &mut depth,
                        &camera,
                        &cfg.bin,
                        &cfg.depth_scale,
                    )?;
                    if cfg.depth_scale.enabled {
                        match scale {
                            Some(s) => tracing::debug!(
                                "frame {}: depth scale {:.4} (support {:.2}, applied {applied})",
                                h.frame_id,
                                s.scale,
                                s.support
                            ),
                            None => tracing::warn!(
                                "frame {}: no depth scale found (too little of the bin visible); \
                                 frame left as measured",
                                h.frame_id
                            ),
                        }
                    }
                    volume.reset();
                    volume.integrate(&depth, &camera)
                });
                match result {
                    Ok(_) => {
                        let sent = grid_pub.send_with_stamp(
                            out,
                            4 * n,
                            |buf| {
                                let (normals, tsdf) = buf.split_at_mut(3 * n);
                                volume.write_normal_grid(normals, tsdf)
                            },
                            Some(Stamp::FusionEnd),
                        )?;
                        match sent {
                            Ok(_) => {
                                ctx.stats.frames_out += 1;
                                None
                            }
                            Err(e) => Some((fusion_status(&e), e.to_string())),
                        }
                    }
                    Err(e) => Some((fusion_status(&e), e.to_string())),
                }
            };
            let failed = if h.is_ok() {
                error
            } else {
                Some((h.status(), String::new()))
            };
            if let Some((status, msg)) = failed {
                grid_pub.send_header(error_record(
                    &h,
                    out,
                    Stage::GridFusion,
                    status,
                    &msg,
                    Stamp::FusionEnd,
                ))?;
                ctx.stats.errors += 1;
            }
            ctx.stats.busy_ns += started.elapsed().as_nanos() as u64;
        }
        ctx.stats.dropped = grid_pub.dropped();
        if stats_due(&mut last_stats, cfg.pipeline.stats_interval_ms) {
            ctx.publish_stats();
        }
        Ok(true)
    })?;
    finish(&mut ctx, exit)
}

fn finish(ctx: &mut StageContext, exit: LoopExit) -> Result<()> {
    ctx.publish_stats();
    ctx.log_summary();
    tracing::debug!("{} exit: {exit:?}", ctx.stage.name());
    Ok(())
}

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

/// inference: normal grid → grasp configurations through the configured backend.
pub fn run_inference(args: StageArgs) -> Result<()> {
    let mut ctx = StageContext::new(Stage::Inference, &args)?;
    let cfg = ctx.config.clone();
    let names = ctx.node.names.clone();
    let grid_sub = ctx.node.subscriber::<f32>(&names.grid())?;
    // Unless configured, the analytic backend's contacts are restricted to the bin interior.
    let backend_cfg = cfg
        .inference
        .clone()
        .with_bin_interior_contacts(&cfg.bin, 0.005);
    // A model (learned or VGN) whose card does not match the workspace or gripper fails here, at
    // start-up.
    let mut backend =
        psgrasp_inference::backend_for_workspace(&backend_cfg, &cfg.workspace, cfg.gripper)?;
    ctx.attach_inputs(&[(&grid_sub, cfg.pipeline.workers.fusion as usize)])?;
    let grasps_pub = ctx.node.publisher::<GraspRecord>(&names.grasps(), 1024)?;
    let mut last_stats = Instant::now();
    tracing::info!(
        "inference[{}] ready (backend {})",
        ctx.worker,
        backend.name()
    );
    let exit = run_event_loop(&[grid_sub.listener()], Duration::from_millis(200), || {
        while let Some(sample) = grid_sub.receive()? {
            let h = *sample.user_header();
            if !ctx.owns(h.frame_id) {
                continue;
            }
            let started = Instant::now();
            ctx.stats.frames_in += 1;
            ctx.stats.last_frame_id = h.frame_id;
            let mut out = h.forwarded(MessageKind::GraspSet);
            out.stamp(Stamp::InferenceStart);
            out.workers[1] = ctx.worker as u16;
            let result: Result<Vec<GraspConfiguration>, (StatusCode, String)> = if !h.is_ok() {
                Err((h.status(), String::new()))
            } else {
                h.check(MessageKind::NormalGrid)
                    .map_err(|m| (StatusCode::ProtocolError, m))
                    .and_then(|_| {
                        grid_view(&h, sample.payload()).map_err(|m| (StatusCode::ProtocolError, m))
                    })
                    .and_then(|view| {
                        backend
                            .infer(&view, cfg.pipeline.seed)
                            .map_err(|e| (StatusCode::InferenceFailed, e.to_string()))
                    })
            };
            drop(sample);
            match result {
                Ok(mut configs) => {
                    configs.sort_by(|a, b| b.quality.total_cmp(&a.quality));
                    configs.truncate(MAX_GRASPS_PER_FRAME);
                    out.stamp(Stamp::InferenceEnd);
                    let records: Vec<GraspRecord> = configs.iter().map(GraspRecord::from).collect();
                    grasps_pub.send_slice(out, &records)?;
                    ctx.stats.frames_out += 1;
                }
                Err((status, msg)) => {
                    grasps_pub.send_header(error_record(
                        &h,
                        out,
                        Stage::Inference,
                        status,
                        &msg,
                        Stamp::InferenceEnd,
                    ))?;
                    ctx.stats.errors += 1;
                }
            }
            ctx.stats.busy_ns += started.elapsed().as_nanos() as u64;
        }
        ctx.stats.dropped = grasps_pub.dropped();
        if stats_due(&mut last_stats, cfg.pipeline.stats_interval_ms) {
            ctx.publish_stats();
        }
        Ok(true)
    })?;
    finish(&mut ctx, exit)
}

/// Grids kept for matching grasp sets by frame id.
const GRID_CACHE: usize = 16;

/// grasp-selection: grasp set → ranked executable picks, loss detection, and the next-pick server.
pub fn run_grasp_selection(args: StageArgs) -> Result<()> {
    let mut ctx = StageContext::new(Stage::GraspSelection, &args)?;
    let cfg = ctx.config.clone();
    let names = ctx.node.names.clone();
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
    let picks_pub = ctx
        .node
        .publisher::<PickRecord>(&names.picks(), MAX_PICKS_PER_FRAME)?;
    let mut tracker = FrameTracker::new(
        ctx.workers as u64,
        ctx.worker as u64,
        cfg.pipeline.loss_timeout_ms * 1_000_000,
    );
    let mut grids: BTreeMap<u64, (FrameHeader, Vec<f32>)> = BTreeMap::new();
    // Worker 0 answers "next pick" requests from the picks of all workers.
    let (mut server, server_inputs) = match ctx.worker {
        0 => {
            let (server, inputs) = NextPickServer::new(&ctx)?;
            (Some(server), Some(inputs))
        }
        _ => (None, None),
    };
    let mut listeners = vec![
        grasps_sub.listener(),
        announce_sub.listener(),
        grid_sub.listener(),
    ];
    if let Some((listener, picks)) = &server_inputs {
        listeners.push(listener);
        listeners.push(picks.listener());
    }
    let mut last_stats = Instant::now();
    tracing::info!("grasp-selection[{}] ready", ctx.worker);
    let exit = run_event_loop(&listeners, Duration::from_millis(20), || {
        while let Some(s) = announce_sub.receive()? {
            tracker.announce(s.user_header().frame_id, now_ns());
        }
        while let Some(s) = grid_sub.receive()? {
            let h = *s.user_header();
            if ctx.owns(h.frame_id) && h.is_ok() {
                grids.insert(h.frame_id, (h, s.payload().to_vec()));
                while grids.len() > GRID_CACHE {
                    grids.pop_first();
                }
            }
        }
        while let Some(sample) = grasps_sub.receive()? {
            let h = *sample.user_header();
            if !ctx.owns(h.frame_id) {
                continue;
            }
            ctx.stats.frames_in += 1;
            ctx.stats.last_frame_id = h.frame_id;
            if tracker.complete(h.frame_id) == TrackerEvent::Duplicate {
                tracing::warn!(
                    "frame {}: result after it was reported lost; dropped",
                    h.frame_id
                );
                continue;
            }
            let started = Instant::now();
            let mut out = h.forwarded(MessageKind::SelectedGrasps);
            out.stamp(Stamp::SelectionStart);
            out.workers[2] = ctx.worker as u16;
            let configs: Vec<GraspConfiguration> = sample
                .payload()
                .iter()
                .map(GraspConfiguration::from)
                .collect();
            drop(sample);
            let grid = grids.remove(&h.frame_id);
            let result: Result<Vec<PickRecord>, (StatusCode, String)> = if !h.is_ok() {
                Err((h.status(), String::new()))
            } else if let Err(m) = h.check(MessageKind::GraspSet) {
                Err((StatusCode::ProtocolError, m))
            } else if let Some((gh, data)) = &grid {
                grid_view(gh, data)
                    .map_err(|m| (StatusCode::ProtocolError, m))
                    .and_then(|view| {
                        let selection = psgrasp_selection::select(
                            &configs,
                            &view,
                            &cfg.bin,
                            &cfg.gripper,
                            &cfg.selection,
                        )
                        .map_err(|e| (StatusCode::SelectionFailed, e.to_string()))?;
                        Ok(selection
                            .picks
                            .iter()
                            .take(MAX_PICKS_PER_FRAME)
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
                            .collect())
                    })
            } else {
                Err((StatusCode::SelectionFailed, "normal grid of this frame never arrived (dropped under overload); no collision check possible".into()))
            };
            match result {
                Ok(picks) => {
                    out.stamp(Stamp::SelectionEnd);
                    picks_pub.send_slice(out, &picks)?;
                    ctx.stats.frames_out += 1;
                }
                Err((status, msg)) => {
                    picks_pub.send_header(error_record(
                        &h,
                        out,
                        Stage::GraspSelection,
                        status,
                        &msg,
                        Stamp::SelectionEnd,
                    ))?;
                    ctx.stats.errors += 1;
                }
            }
            ctx.stats.busy_ns += started.elapsed().as_nanos() as u64;
        }
        for lost in tracker.expire(now_ns()) {
            let msg = format!(
                "no result within {} ms: a stage died or dropped the frame under overload",
                cfg.pipeline.loss_timeout_ms
            );
            tracing::warn!("frame {lost}: {msg}");
            let mut rec = FrameHeader {
                frame_id: lost,
                ..FrameHeader::default()
            }
            .into_error(StatusCode::Lost, Stage::GraspSelection, &msg);
            rec.kind = MessageKind::SelectedGrasps as u32;
            rec.grid_dims = cfg.workspace.dims;
            rec.voxel_size_m = cfg.workspace.voxel_size_m;
            rec.stamp(Stamp::SelectionEnd);
            picks_pub.send_header(rec)?;
            ctx.stats.errors += 1;
        }
        if let (Some(s), Some((_, picks))) = (server.as_mut(), server_inputs.as_ref()) {
            s.serve(picks)?;
        }
        ctx.stats.dropped = picks_pub.dropped();
        if stats_due(&mut last_stats, cfg.pipeline.stats_interval_ms) {
            ctx.publish_stats();
        }
        Ok(true)
    })?;
    finish(&mut ctx, exit)
}

/// Serves `next-pick` requests from the latest successful pick list.
struct NextPickServer {
    server: iceoryx2::port::server::Server<ipc::Service, NextPickRequest, (), NextPickResponse, ()>,
    latest: Option<(u64, Vec<PickRecord>)>,
    cursor: usize,
}

impl NextPickServer {
    /// The server plus what wakes it: the request event listener and the picks subscriber.
    #[allow(clippy::type_complexity)]
    fn new(
        ctx: &StageContext,
    ) -> Result<(
        Self,
        (
            iceoryx2::port::listener::Listener<ipc::Service>,
            psgrasp_ipc::FrameSubscriber<PickRecord>,
        ),
    )> {
        let (service, event) = ctx.node.next_pick_service()?;
        let server = service
            .server_builder()
            .create()
            .map_err(|e| anyhow::anyhow!("next-pick server: {e:?}"))?;
        let listener = event
            .listener_builder()
            .create()
            .map_err(|e| anyhow::anyhow!("next-pick listener: {e:?}"))?;
        let picks = ctx.node.subscriber::<PickRecord>(&ctx.node.names.picks())?;
        Ok((
            Self {
                server,
                latest: None,
                cursor: 0,
            },
            (listener, picks),
        ))
    }

    fn serve(&mut self, picks: &psgrasp_ipc::FrameSubscriber<PickRecord>) -> Result<()> {
        while let Some(s) = picks.receive()? {
            let h = s.user_header();
            if h.is_ok() && self.latest.as_ref().is_none_or(|(id, _)| h.frame_id > *id) {
                self.latest = Some((h.frame_id, s.payload().to_vec()));
                self.cursor = 0;
            }
        }
        while let Some(active) = self
            .server
            .receive()
            .map_err(|e| anyhow::anyhow!("next-pick receive: {e:?}"))?
        {
            let mode = active.payload().mode;
            let response = match &self.latest {
                None => NextPickResponse {
                    status: 1,
                    ..Default::default()
                },
                Some((frame_id, picks)) => {
                    // mode 0: hand out the current pick; mode 1: the previous one failed, advance.
                    if mode == 1 {
                        self.cursor += 1;
                    }
                    match picks.get(self.cursor) {
                        Some(p) => NextPickResponse {
                            status: 0,
                            reserved: 0,
                            frame_id: *frame_id,
                            pick: *p,
                        },
                        None => NextPickResponse {
                            status: 2,
                            frame_id: *frame_id,
                            ..Default::default()
                        },
                    }
                }
            };
            active
                .send_copy(response)
                .map_err(|e| anyhow::anyhow!("next-pick respond: {e:?}"))?;
        }
        Ok(())
    }
}
