//! A cell controller's connection to a running pipeline: the next pick (waiting for one with a
//! timeout), reporting how a pick went, the latest frames' outcomes and the stages' health. The
//! C API (`bindings/c`) and the HTTP endpoint ([`crate::http`]) are thin layers over it.
use crate::monitor::{FrameOutcome, PipelineMonitor};
use crate::next_pick::PickClient;
use anyhow::Result;
use psgrasp_ipc::{
    ChannelConfig, NextPickMode, NextPickStatus, PickRecord, Stage, StageStats, StatusCode,
};
use serde::Serialize;
use std::collections::{BTreeMap, VecDeque};
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::{Duration, Instant};

/// Outcomes kept for "the picks of frame N".
pub const RECENT_OUTCOMES: usize = 64;
/// A stage worker whose statistics are older than this many statistics intervals counts as down.
pub const STATS_INTERVALS_UNTIL_DOWN: u64 = 3;
/// How often a waiting request asks again (no frame yet, all picks used, awaiting a new frame).
const RETRY: Duration = Duration::from_millis(20);

/// How a pick went, as a controller reports it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PickResult {
    /// The object was picked: the scene changed, the next pick comes from a newer frame.
    Success,
    /// The pick failed: the next pick is the next one of the same frame.
    Failure,
}

/// The answer to a pick request (a value returned once per request: boxing the pick would only
/// add an allocation).
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PickAnswer {
    /// A pick of frame `frame_id`.
    Pick {
        /// The frame.
        frame_id: u64,
        /// The pick.
        pick: PickRecord,
    },
    /// No pick in time; the last thing grasp-selection said (`None`: it never answered, no
    /// pipeline of that name is running or its grasp-selection is down).
    NoPick(Option<NextPickStatus>),
}

/// One stage worker as its latest statistics describe it.
#[derive(Debug, Clone, Serialize)]
pub struct WorkerHealth {
    /// Stage name.
    pub stage: &'static str,
    /// Worker index.
    pub worker: u32,
    /// Process id.
    pub pid: u32,
    /// Messages received (own shard only).
    pub frames_in: u64,
    /// Outputs published.
    pub frames_out: u64,
    /// Error records published.
    pub errors: u64,
    /// Deliveries dropped under overload.
    pub dropped: u64,
    /// Age of these statistics, milliseconds.
    pub age_ms: u64,
    /// Statistics recent enough (within [`STATS_INTERVALS_UNTIL_DOWN`] intervals).
    pub up: bool,
}

/// The pipeline as this client sees it.
#[derive(Debug, Clone, Serialize)]
pub struct CellStatus {
    /// Pipeline name.
    pub pipeline: String,
    /// Every stage has a worker that is up.
    pub healthy: bool,
    /// The latest frame's id (`None`: no outcome seen since connecting).
    pub latest_frame_id: Option<u64>,
    /// The latest frame's outcome (`Ok` or an error status name).
    pub latest_status: Option<String>,
    /// The same as its wire code (0 = picks; the error record's status otherwise, as in
    /// `docs/architecture.md`).
    pub latest_status_code: Option<u32>,
    /// Picks of the latest frame (0 for an error record).
    pub latest_picks: usize,
    /// The latest error record's stage and message, if the latest frame is one.
    pub latest_error: Option<String>,
    /// Outcomes seen since connecting, by status.
    pub outcomes: BTreeMap<String, u64>,
    /// Every stage worker seen.
    pub workers: Vec<WorkerHealth>,
}

/// Connection to pipeline `name`'s picks, outcomes and statistics.
pub struct CellClient {
    pipeline: String,
    monitor: PipelineMonitor,
    picks: PickClient,
    stats_interval: Duration,
    recent: VecDeque<FrameOutcome>,
    outcomes: BTreeMap<String, u64>,
    stats_seen: BTreeMap<(u32, u32), (StageStats, Instant)>,
}

static CLIENTS: AtomicU32 = AtomicU32::new(0);

/// The name of a status for people and metrics labels.
pub fn status_name(s: StatusCode) -> String {
    format!("{s:?}")
}

impl CellClient {
    /// Connects to the pipeline named `pipeline` with its channel settings (the pipeline's
    /// `[pipeline.channel]`; the defaults unless it sets them) and its statistics interval.
    pub fn connect(
        pipeline: &str,
        channel: ChannelConfig,
        stats_interval: Duration,
    ) -> Result<Self> {
        let n = CLIENTS.fetch_add(1, Ordering::Relaxed);
        let node_name = format!("{pipeline}-client-{}-{n}", std::process::id());
        let monitor = PipelineMonitor::connect(&node_name, pipeline, channel)?;
        let picks = PickClient::connect(monitor.node())?;
        Ok(Self {
            pipeline: pipeline.to_owned(),
            monitor,
            picks,
            stats_interval,
            recent: VecDeque::new(),
            outcomes: BTreeMap::new(),
            stats_seen: BTreeMap::new(),
        })
    }

    /// Connects to the pipeline of `cfg`.
    pub fn of(cfg: &psgrasp_config::PipelineConfig) -> Result<Self> {
        Self::connect(
            &cfg.pipeline.name,
            cfg.pipeline.channel,
            Duration::from_millis(cfg.pipeline.stats_interval_ms),
        )
    }

    /// The pipeline's name.
    pub fn pipeline(&self) -> &str {
        &self.pipeline
    }

    /// Takes in the outcomes and statistics that arrived; returns the new outcomes.
    pub fn poll(&mut self) -> Result<Vec<FrameOutcome>> {
        let mut new = Vec::new();
        while let Some(o) = self.monitor.next_outcome(Duration::ZERO)? {
            *self.outcomes.entry(status_name(o.status())).or_default() += 1;
            self.recent.push_back(o.clone());
            while self.recent.len() > RECENT_OUTCOMES {
                self.recent.pop_front();
            }
            new.push(o);
        }
        self.monitor.drain_stats()?;
        let now = Instant::now();
        for (key, st) in &self.monitor.latest_stats {
            let changed = self
                .stats_seen
                .get(key)
                .is_none_or(|(old, _)| old.stamp_ns != st.stamp_ns);
            if changed {
                self.stats_seen.insert(*key, (*st, now));
            }
        }
        Ok(new)
    }

    /// The next pick: in `mode` first, then (no frame yet, all picks used, awaiting a frame
    /// newer than a successful pick) asking again for the current pick until one comes or
    /// `timeout` passes.
    pub fn next_pick(&mut self, mode: NextPickMode, timeout: Duration) -> Result<PickAnswer> {
        let deadline = Instant::now() + timeout;
        let mut mode = mode;
        let mut last = None;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            if let Some(r) = self.picks.next_pick(mode, left.max(RETRY))? {
                last = r.status();
                match last {
                    Some(NextPickStatus::Pick) => {
                        return Ok(PickAnswer::Pick {
                            frame_id: r.frame_id,
                            pick: r.pick,
                        })
                    }
                    Some(NextPickStatus::BadRequest) | None => return Ok(PickAnswer::NoPick(last)),
                    _ => {}
                }
                // Reported once; from now on only the current pick is asked for.
                mode = NextPickMode::Current;
            }
            if Instant::now() + RETRY >= deadline || !self.monitor.node().sleep(RETRY) {
                return Ok(PickAnswer::NoPick(last));
            }
        }
    }

    /// Reports how the last pick went and returns the next one (waiting up to `timeout`).
    pub fn report(&mut self, result: PickResult, timeout: Duration) -> Result<PickAnswer> {
        let mode = match result {
            PickResult::Success => NextPickMode::AfterSuccess,
            PickResult::Failure => NextPickMode::AfterFailure,
        };
        self.next_pick(mode, timeout)
    }

    /// The latest outcome seen (picks or an error record).
    pub fn latest(&mut self) -> Result<Option<&FrameOutcome>> {
        self.poll()?;
        Ok(self.recent.back())
    }

    /// The outcome of frame `frame_id`, if it is among the last [`RECENT_OUTCOMES`] seen.
    pub fn outcome(&mut self, frame_id: u64) -> Result<Option<&FrameOutcome>> {
        self.poll()?;
        Ok(self.recent.iter().find(|o| o.frame_id() == frame_id))
    }

    /// Health and counts as of now.
    pub fn status(&mut self) -> Result<CellStatus> {
        self.poll()?;
        let workers: Vec<WorkerHealth> = self
            .stats_seen
            .values()
            .map(|(st, seen)| WorkerHealth {
                stage: Stage::from_u32(st.stage).map_or("unknown", Stage::name),
                worker: st.worker,
                pid: st.pid,
                frames_in: st.frames_in,
                frames_out: st.frames_out,
                errors: st.errors,
                dropped: st.dropped,
                age_ms: seen.elapsed().as_millis() as u64,
                up: self.is_up(seen),
            })
            .collect();
        let healthy = Stage::ALL
            .iter()
            .all(|s| workers.iter().any(|w| w.stage == s.name() && w.up));
        let latest = self.recent.back();
        Ok(CellStatus {
            pipeline: self.pipeline.clone(),
            healthy,
            latest_frame_id: latest.map(FrameOutcome::frame_id),
            latest_status: latest.map(|o| status_name(o.status())),
            latest_status_code: latest.map(|o| o.status() as u32),
            latest_picks: latest.map_or(0, |o| o.picks.len()),
            latest_error: latest.filter(|o| o.status() != StatusCode::Ok).map(|o| {
                format!(
                    "{}: {}",
                    o.error_stage().map_or("unknown stage", Stage::name),
                    o.header.error_text()
                )
            }),
            outcomes: self.outcomes.clone(),
            workers,
        })
    }

    /// Whether statistics that changed at `seen` are recent enough for their worker to count
    /// as up (within [`STATS_INTERVALS_UNTIL_DOWN`] statistics intervals).
    fn is_up(&self, seen: &Instant) -> bool {
        seen.elapsed() <= self.stats_interval * STATS_INTERVALS_UNTIL_DOWN as u32
    }

    /// The latest statistics of every worker seen, and whether that worker is up.
    pub fn worker_stats(&self) -> impl Iterator<Item = (&StageStats, bool)> {
        self.stats_seen
            .values()
            .map(|(st, seen)| (st, self.is_up(seen)))
    }
}
