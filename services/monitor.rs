//! Watching a pipeline from outside, for cell controllers, tools and tests: every frame's
//! outcome (picks or an error record) and the stages' statistics.
use anyhow::Result;
use psgrasp_ipc::{
    ChannelConfig, FrameHeader, FrameSubscriber, PickRecord, PipelineNode, Stage, StageStats,
    StatusCode,
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
    /// Latest statistics per (stage, worker).
    pub latest_stats: HashMap<(u32, u32), StageStats>,
}

impl PipelineMonitor {
    /// Connects to pipeline `pipeline` (node name must be unique per process).
    pub fn connect(node_name: &str, pipeline: &str, channel: ChannelConfig) -> Result<Self> {
        let node = PipelineNode::new(node_name, pipeline, channel)?;
        let picks = node.outcome_subscriber()?;
        let stats = node.subscriber_with_buffer::<StageStats>(&node.names.stats(), 64)?;
        Ok(Self {
            node,
            picks,
            stats,
            latest_stats: HashMap::new(),
        })
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

    /// The underlying node (for its signal-aware `wait`).
    pub fn node(&self) -> &PipelineNode {
        &self.node
    }
}
