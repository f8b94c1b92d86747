//! What every stage process shares: the [`Stage`] trait (one frame in, one message out) and
//! [`run_stage`], the one driver that does everything around a stage's step — receive, shard,
//! check the header, forward upstream error records, time, send, turn a failed step into an
//! error record, count, and publish statistics.
//!
//! camera-ingest has no input and runs its own source loop, with the same context and counters.
mod context;

pub use context::{
    end_with_parent, init_logging, run_event_loop, stage_main, stats_due, LoopExit,
    ProgressReporter, Shard, StageArgs, StageContext,
};

use anyhow::Result;
use iceoryx2::port::listener::Listener;
use iceoryx2::prelude::*;
use psgrasp_ipc::{
    is_stale, FrameHeader, FramePublisher, FrameSubscriber, MessageKind, Stamp, StatusCode,
};
use std::fmt::Debug;
use std::time::{Duration, Instant};

/// Why a stage's step failed on a frame: the status and reason of its error record.
#[derive(Debug, Clone, PartialEq)]
pub struct StepFailure {
    /// The status code of the error record.
    pub status: StatusCode,
    /// The reason (`error_message`).
    pub message: String,
}

impl StepFailure {
    /// A failure with `status` and `message`.
    pub fn new(status: StatusCode, message: impl ToString) -> Self {
        Self {
            status,
            message: message.to_string(),
        }
    }
}

/// Proof that a step published its output (only [`Output`]'s send methods make one).
#[derive(Debug)]
pub struct Sent(());

/// Where a step writes its one output message: the prepared header (forwarded from the input,
/// start stamp and worker index set) and the output publisher. The end stamp is written at send,
/// and the frame reported as left this stage (for the frame ledger) just before the send: a stage
/// killed in between leaves a frame the ledger times out, never one that ends twice.
pub struct Output<'p, T: Debug + ZeroCopySend + Default + Copy + 'static> {
    publisher: &'p FramePublisher<T>,
    header: FrameHeader,
    end: Stamp,
    report_left: &'p dyn Fn(&FrameHeader),
}

impl<T: Debug + ZeroCopySend + Default + Copy + 'static> Output<'_, T> {
    /// The header the output will carry (stage-specific fields may be set on it).
    pub fn header_mut(&mut self) -> &mut FrameHeader {
        &mut self.header
    }

    /// Sends `items` as the frame's output.
    pub fn send_slice(self, items: &[T]) -> Result<Sent> {
        let sent = self.send_with(items.len(), |buf| {
            buf.copy_from_slice(items);
            Ok(())
        })?;
        Ok(sent.expect("copying never fails"))
    }

    /// Fills `len` elements straight in shared memory and sends them (zero copy); the end stamp
    /// is taken after `fill`. A failing `fill` sends nothing and becomes the frame's error.
    pub fn send_with(
        self,
        len: usize,
        fill: impl FnOnce(&mut [T]) -> Result<(), StepFailure>,
    ) -> Result<Result<Sent, StepFailure>> {
        let sent = self.publisher.send_with_stamp(
            self.header,
            len,
            fill,
            Some(self.end),
            self.report_left,
        )?;
        Ok(sent.map(|_| Sent(())))
    }
}

/// One stage of the pipeline between camera-ingest and the cell: its step on one frame, the rest
/// is [`run_stage`]'s.
pub trait Stage {
    /// Element of the input payload.
    type Input: Debug + ZeroCopySend + 'static;
    /// Element of the output payload.
    type Output: Debug + ZeroCopySend + Default + Copy + 'static;
    /// Which stage this is (error records, statistics, worker slot in the header).
    const STAGE: psgrasp_ipc::Stage;
    /// The message kind read.
    const INPUT: MessageKind;
    /// The input's stamp of when it entered this stage's queue (the upstream end stamp).
    const ENTERED: Stamp;
    /// The message kind written.
    const OUTPUT: MessageKind;
    /// Stamped when the step starts.
    const START: Stamp;
    /// Stamped when the output (or the error record) is sent.
    const END: Stamp;

    /// Processes one frame of this worker whose header is ok and of the input kind: writes its
    /// output through `out`, or says why it failed (the driver publishes the error record).
    /// An `Err` of the outer result (the transport failed) ends the stage.
    fn process(
        &mut self,
        header: &FrameHeader,
        payload: &[Self::Input],
        out: Output<'_, Self::Output>,
    ) -> Result<Result<Sent, StepFailure>>;

    /// Sets stage-specific fields on every outgoing header, error records included.
    fn prepare(&self, _out: &mut FrameHeader) {}

    /// Runs on every wake-up before the input is drained (side inputs).
    fn before_frames(&mut self) -> Result<()> {
        Ok(())
    }

    /// Whether a frame of this worker is processed at all; a refused frame is not counted.
    fn admit(&mut self, _header: &FrameHeader) -> bool {
        true
    }

    /// Runs on every wake-up after the input is drained (timeouts, requests); may publish
    /// error records on `out` and count them in `errors`.
    fn after_frames(
        &mut self,
        _out: &FramePublisher<Self::Output>,
        _errors: &mut u64,
    ) -> Result<()> {
        Ok(())
    }
}

/// The error record a stage publishes for a frame that ends with it: an upstream error record
/// (`input` not ok) is forwarded unchanged; otherwise `out` becomes an error raised at `stage`.
/// Either way `end` is stamped.
pub fn error_record(
    input: &FrameHeader,
    out: FrameHeader,
    stage: psgrasp_ipc::Stage,
    failure: &StepFailure,
    end: Stamp,
) -> FrameHeader {
    let mut rec = if input.is_ok() {
        tracing::warn!("frame {}: {}", input.frame_id, failure.message);
        out.into_error(failure.status, stage, &failure.message)
    } else {
        out
    };
    rec.stamp(end);
    rec
}

/// Slot of a stage in [`FrameHeader::workers`].
fn worker_slot(stage: psgrasp_ipc::Stage) -> Option<usize> {
    match stage {
        psgrasp_ipc::Stage::GridFusion => Some(0),
        psgrasp_ipc::Stage::Inference => Some(1),
        psgrasp_ipc::Stage::GraspSelection => Some(2),
        psgrasp_ipc::Stage::CameraIngest => None,
    }
}

/// Runs `stage` until a termination signal: sleeps until `input` or one of `side_listeners`
/// fires (or `tick` passes), then drains the input frame by frame into `output`.
pub fn run_stage<S: Stage>(
    ctx: &mut StageContext,
    stage: &mut S,
    input: &FrameSubscriber<S::Input>,
    output: &FramePublisher<S::Output>,
    side_listeners: &[&Listener<ipc::Service>],
    tick: Duration,
) -> Result<LoopExit> {
    let mut listeners = vec![input.listener()];
    listeners.extend_from_slice(side_listeners);
    let stats_interval_ms = ctx.config.pipeline.stats_interval_ms;
    let mut last_stats = Instant::now();
    let exit = run_event_loop(&listeners, tick, || {
        stage.before_frames()?;
        while let Some(sample) = input.receive()? {
            let h = *sample.user_header();
            if !ctx.owns(h.frame_id) {
                continue;
            }
            ctx.stats.frames_in += 1;
            ctx.stats.last_frame_id = h.frame_id;
            if is_stale(h.stamps_ns[S::ENTERED as usize], ctx.started_ns) {
                // Sent to this worker's previous instance (or to no one while it restarted):
                // the frame ledger has already ended it as lost.
                tracing::debug!(
                    "frame {}: queued before this worker started; dropped",
                    h.frame_id
                );
                ctx.stats.stale += 1;
                continue;
            }
            if !stage.admit(&h) {
                continue;
            }
            let started = Instant::now();
            // The last stage's output is the outcome itself, which the ledger reads.
            let progress = ProgressReporter::new(&ctx.progress_pub, ctx.stage, ctx.worker);
            let report_left = |sent: &FrameHeader| {
                if S::STAGE != psgrasp_ipc::Stage::GraspSelection {
                    progress.left(sent.frame_id, sent.stamps_ns[S::END as usize]);
                }
            };
            let mut out = h.forwarded(S::OUTPUT);
            out.stamp(S::START);
            if let Some(slot) = worker_slot(S::STAGE) {
                out.workers[slot] = ctx.worker as u16;
            }
            stage.prepare(&mut out);
            let failure = if !h.is_ok() {
                Err(StepFailure::new(h.status(), ""))
            } else if let Err(m) = h.check(S::INPUT) {
                Err(StepFailure::new(StatusCode::ProtocolError, m))
            } else {
                let output = Output {
                    publisher: output,
                    header: out,
                    end: S::END,
                    report_left: &report_left,
                };
                stage.process(&h, sample.payload(), output)?
            };
            drop(sample);
            match failure {
                Ok(Sent(_)) => ctx.stats.frames_out += 1,
                Err(f) => {
                    let rec = error_record(&h, out, S::STAGE, &f, S::END);
                    report_left(&rec);
                    output.send_header(rec)?;
                    ctx.stats.errors += 1;
                }
            }
            ctx.stats.busy_ns += started.elapsed().as_nanos() as u64;
        }
        stage.after_frames(output, &mut ctx.stats.errors)?;
        ctx.stats.dropped = output.dropped();
        if stats_due(&mut last_stats, stats_interval_ms) {
            ctx.publish_stats();
        }
        Ok(true)
    })?;
    ctx.publish_stats();
    ctx.log_summary();
    tracing::debug!("{} exit: {exit:?}", ctx.stage.name());
    Ok(exit)
}
