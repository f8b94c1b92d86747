//! The context of a stage process: argument parsing, config loading, the iceoryx2 node, the
//! WaitSet loop and the statistics it publishes.
use anyhow::{Context, Result};
use clap::Parser;
use iceoryx2::port::listener::Listener;
use iceoryx2::prelude::*;
use psgrasp_config::PipelineConfig;
use psgrasp_ipc::{
    now_ns, FrameHeader, FramePublisher, InputPort, PipelineNode, ProgressEvent, ProgressKind,
    Stage, StageStats,
};
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// True (and `last` reset) when `interval_ms` has passed since `last`: statistics are due.
pub fn stats_due(last: &mut Instant, interval_ms: u64) -> bool {
    if last.elapsed() >= Duration::from_millis(interval_ms) {
        *last = Instant::now();
        true
    } else {
        false
    }
}

/// Command-line arguments of a stage binary.
#[derive(Debug, Clone, Parser)]
pub struct StageArgs {
    /// Pipeline configuration file.
    #[arg(long, default_value = "config/default.toml")]
    pub config: PathBuf,
    /// Index of this worker among the stage's workers (frames with `frame_id % workers == worker`).
    #[arg(long, default_value_t = 0)]
    pub worker: u32,
}

/// Initialises logging to stderr (`RUST_LOG` overrides the level, default `info`;
/// `PSGRASP_IOX_DEBUG` set turns on iceoryx2's own debug log).
pub fn init_logging() {
    let filter =
        tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into());
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_target(false)
        .try_init();
    if std::env::var_os("PSGRASP_IOX_DEBUG").is_some() {
        iceoryx2::prelude::set_log_level(LogLevel::Debug);
    } else {
        iceoryx2::prelude::set_log_level(LogLevel::Error);
    }
}

/// The frames one worker of a stage handles: those with `frame_id % workers == worker`, so
/// every frame is handled by exactly one worker.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shard {
    /// Index of the worker.
    pub worker: u32,
    /// Workers of the stage.
    pub workers: u32,
}

impl Shard {
    /// True if this worker handles `frame_id`.
    pub fn owns(&self, frame_id: u64) -> bool {
        frame_id % self.workers as u64 == self.worker as u64
    }
}

/// A stage process's shared state.
pub struct StageContext {
    /// Which stage this is.
    pub stage: Stage,
    /// Worker index.
    pub worker: u32,
    /// Number of workers of this stage.
    pub workers: u32,
    /// The validated configuration.
    pub config: PipelineConfig,
    /// The iceoryx2 node.
    pub node: PipelineNode,
    stats_pub: FramePublisher<StageStats>,
    /// Progress reports for the frame ledger (see [`ProgressReporter`]).
    pub progress_pub: FramePublisher<ProgressEvent>,
    /// When this worker started taking frames (set once its inputs are attached); frames
    /// queued for it before are stale.
    pub started_ns: u64,
    /// Counters published periodically.
    pub stats: StageStats,
}

impl StageContext {
    /// Loads the config, validates the worker index and creates the node `<pipeline>-<stage>-<worker>`.
    pub fn new(stage: Stage, args: &StageArgs) -> Result<Self> {
        let config = PipelineConfig::load(&args.config)?;
        // Started by hand or by a launcher: either way /dev/shm must hold the buffers.
        crate::launcher::check_shm_space(&config)?;
        let workers = match stage {
            Stage::CameraIngest => 1,
            Stage::GridFusion => config.pipeline.workers.fusion,
            Stage::Inference => config.pipeline.workers.inference,
            Stage::GraspSelection => config.pipeline.workers.selection,
        };
        anyhow::ensure!(
            args.worker < workers,
            "worker index {} but {} has {workers} worker(s)",
            args.worker,
            stage.name()
        );
        let node_name = format!("{}-{}-{}", config.pipeline.name, stage.name(), args.worker);
        let node = PipelineNode::new(&node_name, &config.pipeline.name, config.pipeline.channel)
            .with_context(|| format!("starting {node_name}"))?;
        let stats_pub = node.publisher_with_buffer::<StageStats>(&node.names.stats(), 1, 64)?;
        let progress_pub = node.progress_publisher()?;
        let stats = StageStats {
            stage: stage as u32,
            worker: args.worker,
            pid: std::process::id(),
            ..Default::default()
        };
        Ok(Self {
            stage,
            worker: args.worker,
            workers,
            config,
            node,
            stats_pub,
            progress_pub,
            started_ns: u64::MAX,
            stats,
        })
    }

    /// Reports on `progress` that this worker takes frames from now on: the frame ledger ends
    /// the frames its previous instance held, and this instance drops them (see
    /// [`psgrasp_ipc::is_stale`]).
    pub fn report_started(&mut self) -> Result<()> {
        self.started_ns = now_ns();
        let event = ProgressEvent::new(
            ProgressKind::Started,
            self.stage,
            self.worker,
            0,
            self.started_ns,
        );
        self.progress_pub
            .send_slice(FrameHeader::default(), std::slice::from_ref(&event))?;
        Ok(())
    }

    /// Reports on `progress` that the ledger ended frame `frame_id` (grasp-selection then
    /// drops a late result of it).
    pub fn report_verdict(&self, frame_id: u64) {
        ProgressReporter::new(&self.progress_pub, self.stage, self.worker).report(
            ProgressKind::Verdict,
            frame_id,
            now_ns(),
        );
    }

    /// Reports on `progress` that camera-ingest admitted frame `frame_id` at `stamp_ns`.
    pub fn report_admitted(&self, frame_id: u64, stamp_ns: u64) {
        ProgressReporter::new(&self.progress_pub, self.stage, self.worker).report(
            ProgressKind::Admitted,
            frame_id,
            stamp_ns,
        );
    }

    /// Start-up barrier: waits (up to `camera.wait_for_subscribers_ms`) until every input has at
    /// least its expected number of publishers, attaching to them. A stage creates its output
    /// publishers only after this, so the camera (which waits for the last stage's publishers)
    /// sends no frame before the whole chain is attached: iceoryx2 discards a delivery to a
    /// subscriber whose queue filled up before it attached. Returns false (after a warning) if
    /// the wait timed out, and an error on a termination signal.
    /// Reports the worker started ([`Self::report_started`]) once attached, timed out or not.
    pub fn attach_inputs(&mut self, inputs: &[(&dyn InputPort, usize)]) -> Result<bool> {
        let attached = self.wait_for_inputs(inputs)?;
        self.report_started()?;
        Ok(attached)
    }

    fn wait_for_inputs(&self, inputs: &[(&dyn InputPort, usize)]) -> Result<bool> {
        let timeout = Duration::from_millis(self.config.camera.wait_for_subscribers_ms);
        let ready = self.node.wait_until(timeout, || {
            let mut all = true;
            for (port, want) in inputs {
                // Count first, then attach: the attach then sees at least the counted publishers.
                all &= port.publisher_count() >= *want;
                port.attach();
            }
            all
        });
        match ready {
            None => anyhow::bail!("terminated while waiting for upstream stages"),
            Some(true) => Ok(true),
            Some(false) => {
                for (port, want) in inputs {
                    if port.publisher_count() < *want {
                        tracing::warn!(
                            "{}[{}]: starting with {} of {want} publisher(s) on {}",
                            self.stage.name(),
                            self.worker,
                            port.publisher_count(),
                            port.service()
                        );
                    }
                }
                Ok(false)
            }
        }
    }

    /// The frames this worker handles.
    pub fn shard(&self) -> Shard {
        Shard {
            worker: self.worker,
            workers: self.workers,
        }
    }

    /// True if this worker handles `frame_id`.
    pub fn owns(&self, frame_id: u64) -> bool {
        self.shard().owns(frame_id)
    }

    /// Publishes the current counters.
    pub fn publish_stats(&mut self) {
        self.stats.stamp_ns = now_ns();
        let header = FrameHeader::default();
        if let Err(e) = self
            .stats_pub
            .send_slice(header, std::slice::from_ref(&self.stats))
        {
            tracing::warn!("stats publish failed: {e}");
        }
    }

    /// Logs the counters (on exit).
    pub fn log_summary(&self) {
        let s = &self.stats;
        tracing::info!(
            "{}[{}] done: in {} out {} errors {} dropped {} busy {:.1} ms",
            self.stage.name(),
            self.worker,
            s.frames_in,
            s.frames_out,
            s.errors,
            s.dropped,
            s.busy_ns as f64 * 1e-6
        );
    }
}

/// Sends this worker's progress reports (borrows only the context's progress publisher).
pub struct ProgressReporter<'a> {
    publisher: &'a FramePublisher<ProgressEvent>,
    stage: Stage,
    worker: u32,
}

impl<'a> ProgressReporter<'a> {
    /// The reporter of `worker` of `stage` on `publisher` (a context's `progress_pub`; taking
    /// the field, not the context, leaves the rest of the context free to change meanwhile).
    pub fn new(publisher: &'a FramePublisher<ProgressEvent>, stage: Stage, worker: u32) -> Self {
        Self {
            publisher,
            stage,
            worker,
        }
    }

    /// Reports that frame `frame_id` leaves this stage with end stamp `end_ns`.
    pub fn left(&self, frame_id: u64, end_ns: u64) {
        self.report(ProgressKind::Left, frame_id, end_ns);
    }

    fn report(&self, kind: ProgressKind, frame_id: u64, stamp_ns: u64) {
        let event = ProgressEvent::new(kind, self.stage, self.worker, frame_id, stamp_ns);
        if let Err(e) = self
            .publisher
            .send_slice(FrameHeader::default(), std::slice::from_ref(&event))
        {
            tracing::warn!("frame {frame_id}: progress report failed: {e}");
        }
    }
}

/// Why an event loop ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LoopExit {
    /// SIGTERM / SIGINT.
    Signal,
    /// The handler asked to stop.
    Done,
}

/// Sleeps in a WaitSet until one of `listeners` fires or `tick` passes, then calls `on_wake`
/// (which drains all inputs and does housekeeping). Returns `Ok(Done)` when `on_wake` returns
/// `Ok(false)`, `Ok(Signal)` on SIGTERM/SIGINT.
pub fn run_event_loop(
    listeners: &[&Listener<ipc::Service>],
    tick: Duration,
    mut on_wake: impl FnMut() -> Result<bool>,
) -> Result<LoopExit> {
    let waitset = WaitSetBuilder::new()
        .signal_handling_mode(SignalHandlingMode::HandleTerminationRequests)
        .create::<ipc::Service>()
        .map_err(|e| anyhow::anyhow!("creating WaitSet: {e:?}"))?;
    let mut guards = Vec::new();
    for l in listeners {
        guards.push(
            waitset
                .attach_notification(*l)
                .map_err(|e| anyhow::anyhow!("attaching listener: {e:?}"))?,
        );
    }
    let _tick = waitset
        .attach_interval(tick)
        .map_err(|e| anyhow::anyhow!("attaching interval: {e:?}"))?;
    let mut result: Result<bool> = Ok(true);
    loop {
        // A request latched before the WaitSet existed (during start-up) is not reported again.
        if psgrasp_ipc::termination_requested() {
            return Ok(LoopExit::Signal);
        }
        let run = waitset
            .wait_and_process_once(|_id| {
                for l in listeners {
                    let _ = l.try_wait(|_| {});
                }
                CallbackProgression::Continue
            })
            .map_err(|e| anyhow::anyhow!("WaitSet: {e:?}"))?;
        match run {
            WaitSetRunResult::TerminationRequest | WaitSetRunResult::Interrupt => {
                psgrasp_ipc::note_termination();
                return Ok(LoopExit::Signal);
            }
            _ => {}
        }
        match on_wake() {
            Ok(true) => {}
            Ok(false) => break,
            Err(e) => {
                result = Err(e);
                break;
            }
        }
    }
    result.map(|_| LoopExit::Done)
}

/// Makes this process end (SIGTERM, handled like any stop request) when the process that
/// started it dies, however it dies (Linux `PR_SET_PDEATHSIG`). A launcher passes its pid in
/// [`crate::launcher::PARENT_PID_ENV`]; if that process is already gone, this returns an error.
pub fn end_with_parent() -> Result<()> {
    // SAFETY: prctl with PR_SET_PDEATHSIG takes a signal number; getppid cannot fail.
    let parent = unsafe {
        libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM);
        libc::getppid()
    };
    if let Some(launcher) = std::env::var(crate::launcher::PARENT_PID_ENV)
        .ok()
        .and_then(|v| v.parse::<i32>().ok())
    {
        anyhow::ensure!(
            parent == launcher,
            "the launcher (pid {launcher}) that started this stage is gone"
        );
    }
    Ok(())
}

/// Runs a stage's `main`: logging, ending with the parent, and an exit code with a clear
/// message on failure.
pub fn stage_main(stage: Stage, run: fn(StageArgs) -> Result<()>) -> std::process::ExitCode {
    init_logging();
    let args = StageArgs::parse();
    if let Err(e) = end_with_parent() {
        tracing::error!("{} not started: {e:#}", stage.name());
        return std::process::ExitCode::FAILURE;
    }
    match run(args) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            tracing::error!("{} failed: {e:#}", stage.name());
            std::process::ExitCode::FAILURE
        }
    }
}

use iceoryx2::waitset::WaitSetRunResult;
