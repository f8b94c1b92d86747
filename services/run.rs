//! Runs frames through a live pipeline and accounts for every one: outcomes by status, second
//! outcomes, frames admitted without any outcome, and, in a chaos drill, a stage killed at
//! intervals with the time until it took frames again and until picks came back.
use crate::launcher::Supervisor;
use crate::monitor::{FrameOutcome, PipelineMonitor};
use anyhow::Result;
use psgrasp_config::PipelineConfig;
use psgrasp_ipc::{now_ns, termination_requested, Stage, Stamp, StatusCode};
use rand::{Rng, SeedableRng};
use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;
use std::time::{Duration, Instant};

/// A chaos drill: SIGKILL one stage process every `every`, rotating over the four stages (a
/// seeded random worker of each).
#[derive(Debug, Clone, Copy)]
pub struct ChaosPlan {
    /// Time between kills.
    pub every: Duration,
    /// Seed of the worker choice.
    pub seed: u64,
}

/// What to run.
#[derive(Debug, Clone, Copy)]
pub struct RunOptions {
    /// Frames to run: outcomes to collect (a finite camera) or frames to admit (a chaos drill,
    /// whose camera runs until stopped).
    pub frames: u64,
    /// Longest run; a chaos drill stops killing and winds down at this point.
    pub timeout: Duration,
    /// Kill stages meanwhile.
    pub chaos: Option<ChaosPlan>,
}

/// One kill of a chaos drill.
#[derive(Debug, Clone)]
pub struct Kill {
    /// The stage killed.
    pub stage: Stage,
    /// Its worker.
    pub worker: u32,
    /// When (ns).
    pub at_ns: u64,
    /// Kill → the new instance reported it takes frames.
    pub restarted_after: Option<Duration>,
    /// When the new instance started (ns).
    started_ns: Option<u64>,
    /// Kill → the first picks of a frame admitted after the new instance started.
    pub recovered_after: Option<Duration>,
}

/// Everything a run observed.
#[derive(Debug, Default)]
pub struct RunReport {
    /// The first outcome of every frame, by frame id.
    pub outcomes: BTreeMap<u64, FrameOutcome>,
    /// Outcomes of frames that already had one (should be 0).
    pub second_outcomes: u64,
    /// What the first few second outcomes were (first and second status and reason).
    pub second_outcome_examples: Vec<String>,
    /// Frames camera-ingest reported admitted.
    pub admitted: BTreeSet<u64>,
    /// Stage restarts done by the supervisor.
    pub restarts: u32,
    /// The kills of a chaos drill.
    pub kills: Vec<Kill>,
    /// Wall time from the start to the last outcome.
    pub wall: Duration,
    /// Stopped by SIGINT/SIGTERM.
    pub interrupted: bool,
}

impl RunReport {
    /// Frames that entered the pipeline: admitted, or ended at admission (refused, invalid).
    pub fn sent(&self) -> usize {
        self.admitted.len()
            + self
                .outcomes
                .keys()
                .filter(|id| !self.admitted.contains(id))
                .count()
    }

    /// Frames admitted that have no outcome.
    pub fn unaccounted(&self) -> Vec<u64> {
        self.admitted
            .iter()
            .filter(|id| !self.outcomes.contains_key(id))
            .copied()
            .collect()
    }

    /// Outcomes by status.
    pub fn by_status(&self) -> BTreeMap<String, usize> {
        let mut by_status = BTreeMap::new();
        for o in self.outcomes.values() {
            *by_status.entry(format!("{:?}", o.status())).or_default() += 1;
        }
        by_status
    }

    fn take(&mut self, o: FrameOutcome) {
        let now = now_ns();
        if o.status() == StatusCode::Ok {
            let admitted_ns = o.header.stamps_ns[Stamp::IngestPublished as usize];
            for k in &mut self.kills {
                if k.recovered_after.is_none() && k.started_ns.is_some_and(|s| admitted_ns > s) {
                    k.recovered_after = Some(Duration::from_nanos(now.saturating_sub(k.at_ns)));
                }
            }
        }
        let describe = |o: &FrameOutcome| {
            format!(
                "{:?} from {:?} ({})",
                o.status(),
                o.error_stage(),
                o.header.error_text()
            )
        };
        let second = describe(&o);
        if let Some(first) = self.outcomes.insert(o.frame_id(), o) {
            self.second_outcomes += 1;
            if self.second_outcome_examples.len() < 10 {
                self.second_outcome_examples.push(format!(
                    "frame {}: {} then {second}",
                    first.frame_id(),
                    describe(&first)
                ));
            }
        }
    }
}

/// The drill's rotation over the stages.
const ROTATION: [Stage; 4] = [
    Stage::GridFusion,
    Stage::Inference,
    Stage::GraspSelection,
    Stage::CameraIngest,
];

/// Starts the pipeline of `cfg` and runs it as `opts` says; returns what it observed and the
/// still running supervisor (the caller shuts it down). Stops early on SIGINT/SIGTERM.
pub fn run_pipeline(
    cfg: &PipelineConfig,
    opts: RunOptions,
    bin_dir: &Path,
) -> Result<(RunReport, Supervisor)> {
    let mut monitor = PipelineMonitor::of(cfg)?;
    let mut cfg = cfg.clone();
    if opts.chaos.is_some() {
        // The drill's kills are deliberate and isolated: each restart is a first one (shortest
        // backoff) and none counts towards giving up.
        cfg.pipeline.restart_window_s = 1;
        cfg.pipeline.max_restarts = u32::MAX;
    }
    let cfg = &cfg;
    let mut sup = Supervisor::launch(cfg, bin_dir, true)?;
    let start = Instant::now();
    let mut report = RunReport::default();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(opts.chaos.map_or(0, |c| c.seed));
    let mut next_kill = opts.chaos.map(|c| start + c.every);
    let mut turn = 0usize;
    // A drill winds down: no more kills, all stages up, camera stopped, in-flight frames end.
    let mut wind_down: Option<Instant> = None;
    let drain_limit = Duration::from_millis(cfg.pipeline.loss_timeout_ms) + Duration::from_secs(2);
    loop {
        if termination_requested() {
            report.interrupted = true;
            break;
        }
        for e in sup.poll()? {
            if e.ends_with(" restarted") {
                report.restarts += 1;
            }
            tracing::info!("{e}");
        }
        let failures = sup.failures();
        anyhow::ensure!(
            failures.is_empty(),
            "pipeline failed: {}",
            failures.join("; ")
        );
        if let Some(o) = monitor.next_outcome(Duration::from_millis(20))? {
            report.take(o);
        }
        let progress = monitor.drain_progress()?;
        report.admitted.extend(progress.admitted);
        for (stage, worker, _pid, started_ns) in progress.started {
            for k in &mut report.kills {
                if k.stage == stage
                    && k.worker == worker
                    && k.started_ns.is_none()
                    && started_ns > k.at_ns
                {
                    k.started_ns = Some(started_ns);
                    k.restarted_after = Some(Duration::from_nanos(started_ns - k.at_ns));
                }
            }
        }
        match opts.chaos {
            None => {
                if report.outcomes.len() as u64 >= opts.frames || start.elapsed() >= opts.timeout {
                    break;
                }
            }
            Some(plan) => {
                if wind_down.is_none()
                    && (report.sent() as u64 >= opts.frames || start.elapsed() >= opts.timeout)
                {
                    next_kill = None;
                }
                if let Some(due) = next_kill {
                    if Instant::now() >= due && !sup.restart_pending() {
                        let stage = ROTATION[turn % ROTATION.len()];
                        turn += 1;
                        let workers = workers_of(cfg, stage);
                        let worker = rng.random_range(0..workers);
                        if sup.kill(stage, worker)?.is_some() {
                            report.kills.push(Kill {
                                stage,
                                worker,
                                at_ns: now_ns(),
                                restarted_after: None,
                                started_ns: None,
                                recovered_after: None,
                            });
                        }
                        next_kill = Some(due + plan.every);
                    }
                } else if wind_down.is_none() {
                    // The last kill's recovery is measured on frames admitted after it.
                    let last_done = report.kills.last().is_none_or(|k| {
                        k.recovered_after.is_some()
                            || now_ns().saturating_sub(k.at_ns) > drain_limit.as_nanos() as u64
                    });
                    // Stop the camera once every killed stage is back (or give up waiting).
                    let all_back = !sup.restart_pending() && last_done;
                    if all_back || start.elapsed() >= opts.timeout + drain_limit {
                        sup.stop(Stage::CameraIngest, 0);
                        wind_down = Some(Instant::now());
                    }
                } else if let Some(t) = wind_down {
                    if report.unaccounted().is_empty() || t.elapsed() >= drain_limit {
                        break;
                    }
                }
            }
        }
    }
    monitor.drain_stats()?;
    report.wall = start.elapsed();
    Ok((report, sup))
}

/// Collects `frames` outcomes of the pipeline of `cfg` (or stops after `timeout`).
pub fn run_frames(
    cfg: &PipelineConfig,
    frames: u64,
    timeout: Duration,
    bin_dir: &Path,
) -> Result<(RunReport, Supervisor)> {
    run_pipeline(
        cfg,
        RunOptions {
            frames,
            timeout,
            chaos: None,
        },
        bin_dir,
    )
}

fn workers_of(cfg: &PipelineConfig, stage: Stage) -> u32 {
    let w = cfg.pipeline.workers;
    match stage {
        Stage::CameraIngest => 1,
        Stage::GridFusion => w.fusion,
        Stage::Inference => w.inference,
        Stage::GraspSelection => w.selection,
    }
}
