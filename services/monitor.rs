//! Watching a pipeline from outside, for cell controllers, tools and tests: every frame's
//! outcome (picks or an error record) and the stages' statistics.
use anyhow::Result;
use psgrasp_ipc::{
    ChannelConfig, FrameHeader, FrameSubscriber, PickRecord, PipelineNode, ProgressEvent,
    ProgressKind, Stage, StageStats, StatusCode,
};
use std::collections::HashMap;
use std::time::{Duration, Instant};

/// The end of one frame's journey: picks or an error record.
#[derive(Debug, Clone)]
pub struct FrameOutcome {
    /// The final header (timestamps of every stage, status).
    pub header: FrameHeader,
    /// Ranked picks (empty for error records).
    pub picks: Vec<PickRecord>,
}

impl FrameOutcome {
    /// Frame id.
    pub fn frame_id(&self) -> u64 {
        self.header.frame_id
    }
    /// Status of the frame.
    pub fn status(&self) -> StatusCode {
        self.header.status()
    }
    /// Stage that raised the error, if any.
    pub fn error_stage(&self) -> Option<Stage> {
        Stage::from_u32(self.header.error_stage)
    }
}

/// Subscribes to a pipeline's results and statistics.
pub struct PipelineMonitor {
    node: PipelineNode,
    picks: FrameSubscriber<PickRecord>,
    stats: FrameSubscriber<StageStats>,
    progress: FrameSubscriber<ProgressEvent>,
    /// Latest statistics per (stage, worker).
    pub latest_stats: HashMap<(u32, u32), StageStats>,
}

/// What the stages reported on `progress` since the last call (see
/// [`PipelineMonitor::drain_progress`]).
#[derive(Debug, Default, Clone)]
pub struct ProgressSummary {
    /// Frames camera-ingest admitted into the pipeline.
    pub admitted: Vec<u64>,
    /// Workers that started taking frames: (stage, worker, pid, when in ns).
    pub started: Vec<(Stage, u32, u32, u64)>,
}

impl PipelineMonitor {
    /// Connects to pipeline `pipeline` (node name must be unique per process).
    pub fn connect(node_name: &str, pipeline: &str, channel: ChannelConfig) -> Result<Self> {
        let node = PipelineNode::new(node_name, pipeline, channel)?;
        let picks = node.outcome_subscriber()?;
        let stats = node.subscriber_with_buffer::<StageStats>(&node.names.stats(), 64)?;
        let progress = node.progress_subscriber()?;
        Ok(Self {
            node,
            picks,
            stats,
            progress,
            latest_stats: HashMap::new(),
        })
    }

    /// Connects to the pipeline of `cfg` as its monitor (node `<name>-monitor`: one per
    /// process and pipeline).
    pub fn of(cfg: &psgrasp_config::PipelineConfig) -> Result<Self> {
        Self::connect(
            &format!("{}-monitor", cfg.pipeline.name),
            &cfg.pipeline.name,
            cfg.pipeline.channel,
        )
    }

    /// Waits up to `timeout` for the next outcome. `Ok(None)` on timeout or a termination signal.
    pub fn next_outcome(&mut self, timeout: Duration) -> Result<Option<FrameOutcome>> {
        let deadline = Instant::now() + timeout;
        loop {
            self.drain_stats()?;
            if let Some(s) = self.picks.receive()? {
                return Ok(Some(FrameOutcome {
                    header: *s.user_header(),
                    picks: s.payload().to_vec(),
                }));
            }
            let now = Instant::now();
            if now >= deadline {
                return Ok(None);
            }
            self.picks
                .wait((deadline - now).min(Duration::from_millis(50)));
            if !self.node.sleep(Duration::ZERO) {
                return Ok(None);
            }
        }
    }

    /// Reads queued statistics.
    pub fn drain_stats(&mut self) -> Result<()> {
        while let Some(s) = self.stats.receive()? {
            if let Some(st) = s.payload().first() {
                self.latest_stats.insert((st.stage, st.worker), *st);
            }
        }
        Ok(())
    }

    /// Reads queued progress reports: admitted frames and (re)started workers.
    pub fn drain_progress(&mut self) -> Result<ProgressSummary> {
        let mut out = ProgressSummary::default();
        while let Some(s) = self.progress.receive()? {
            for e in s.payload() {
                match (e.kind(), Stage::from_u32(e.stage)) {
                    (Some(ProgressKind::Admitted), _) => out.admitted.push(e.frame_id),
                    (Some(ProgressKind::Started), Some(stage)) => {
                        out.started.push((stage, e.worker, e.pid, e.stamp_ns))
                    }
                    _ => {}
                }
            }
        }
        Ok(out)
    }

    /// The underlying node (for its signal-aware `wait`).
    pub fn node(&self) -> &PipelineNode {
        &self.node
    }
}
