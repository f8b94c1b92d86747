//! Prometheus/OpenMetrics metrics of a pipeline as a cell controller sees it: frame outcomes by
//! status, per-stage latency histograms (from every outcome's timestamps) and per-worker counters
//! (from the stages' statistics). Served at `/metrics` by the HTTP endpoint.
use crate::monitor::FrameOutcome;
use prometheus_client::encoding::EncodeLabelSet;
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::metrics::histogram::{exponential_buckets, Histogram};
use prometheus_client::registry::Registry;
use psgrasp_ipc::{Stage, StageStats, Stamp, StatusCode};
use std::collections::HashMap;

/// Latency buckets: 1 ms doubling to ~4 s.
const LATENCY_BUCKETS: (f64, f64, u16) = (0.001, 2.0, 13);

/// The spans of a frame's journey whose latency is recorded.
const SPANS: [(&str, Stamp, Stamp); 5] = [
    ("fusion", Stamp::FusionStart, Stamp::FusionEnd),
    ("inference", Stamp::InferenceStart, Stamp::InferenceEnd),
    ("selection", Stamp::SelectionStart, Stamp::SelectionEnd),
    ("end_to_end", Stamp::IngestPublished, Stamp::SelectionEnd),
    ("capture_to_picks", Stamp::Capture, Stamp::SelectionEnd),
];

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct StatusLabels {
    status: String,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct SpanLabels {
    span: String,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct WorkerLabels {
    stage: String,
    worker: String,
}

/// The metrics registry and what was last taken from each worker's statistics.
pub struct CellMetrics {
    registry: Registry,
    frames: Family<StatusLabels, Counter>,
    latency: Family<SpanLabels, Histogram>,
    frames_in: Family<WorkerLabels, Counter>,
    frames_out: Family<WorkerLabels, Counter>,
    errors: Family<WorkerLabels, Counter>,
    dropped: Family<WorkerLabels, Counter>,
    up: Family<WorkerLabels, Gauge>,
    /// Per (stage, worker): the statistics already counted (a new pid starts from zero).
    counted: HashMap<(u32, u32), StageStats>,
}

fn latency_histogram() -> Histogram {
    let (start, factor, n) = LATENCY_BUCKETS;
    Histogram::new(exponential_buckets(start, factor, n))
}

impl Default for CellMetrics {
    fn default() -> Self {
        Self::new()
    }
}

impl CellMetrics {
    /// An empty registry with every metric family registered.
    pub fn new() -> Self {
        let mut registry = Registry::with_prefix("psgrasp");
        let frames = Family::<StatusLabels, Counter>::default();
        registry.register(
            "frames",
            "Frame outcomes seen on the picks service, by status",
            frames.clone(),
        );
        let latency = Family::<SpanLabels, Histogram>::new_with_constructor(
            latency_histogram as fn() -> Histogram,
        );
        registry.register(
            "latency_seconds",
            "Time per stage and end to end of every successful frame",
            latency.clone(),
        );
        let worker = |registry: &mut Registry, name: &str, help: &str| {
            let f = Family::<WorkerLabels, Counter>::default();
            registry.register(name, help, f.clone());
            f
        };
        let frames_in = worker(
            &mut registry,
            "stage_frames_in",
            "Messages a worker received",
        );
        let frames_out = worker(
            &mut registry,
            "stage_frames_out",
            "Outputs a worker published",
        );
        let errors = worker(
            &mut registry,
            "stage_errors",
            "Error records a worker published",
        );
        let dropped = worker(
            &mut registry,
            "stage_dropped",
            "Deliveries a worker dropped under overload",
        );
        let up = Family::<WorkerLabels, Gauge>::default();
        registry.register(
            "stage_up",
            "1 if the worker's statistics are recent",
            up.clone(),
        );
        Self {
            registry,
            frames,
            latency,
            frames_in,
            frames_out,
            errors,
            dropped,
            up,
            counted: HashMap::new(),
        }
    }

    /// Counts one frame outcome and, for a successful frame, its latencies.
    pub fn observe_outcome(&self, o: &FrameOutcome) {
        self.frames
            .get_or_create(&StatusLabels {
                status: crate::controller::status_name(o.status()),
            })
            .inc();
        if o.status() != StatusCode::Ok {
            return;
        }
        for (span, from, to) in SPANS {
            let ms = o.header.span_ms(from, to);
            if ms > 0.0 {
                self.latency
                    .get_or_create(&SpanLabels { span: span.into() })
                    .observe(ms * 1e-3);
            }
        }
    }

    /// Takes in a worker's latest statistics (`up`: recent enough).
    pub fn observe_stats(&mut self, st: &StageStats, up: bool) {
        let labels = WorkerLabels {
            stage: Stage::from_u32(st.stage)
                .map_or("unknown", Stage::name)
                .into(),
            worker: st.worker.to_string(),
        };
        let key = (st.stage, st.worker);
        let before = match self.counted.get(&key) {
            Some(b) if b.pid == st.pid => *b,
            _ => StageStats::default(),
        };
        let add = |f: &Family<WorkerLabels, Counter>, now: u64, was: u64| {
            f.get_or_create(&labels).inc_by(now.saturating_sub(was));
        };
        add(&self.frames_in, st.frames_in, before.frames_in);
        add(&self.frames_out, st.frames_out, before.frames_out);
        add(&self.errors, st.errors, before.errors);
        add(&self.dropped, st.dropped, before.dropped);
        self.up.get_or_create(&labels).set(up as i64);
        self.counted.insert(key, *st);
    }

    /// The metrics in the OpenMetrics text format.
    pub fn encode(&self) -> String {
        let mut out = String::new();
        prometheus_client::encoding::text::encode(&mut out, &self.registry)
            .expect("writing to a String cannot fail");
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use psgrasp_ipc::{FrameHeader, MessageKind};

    #[test]
    fn counters_follow_restarts_and_latencies_land_in_buckets() {
        let mut m = CellMetrics::new();
        let mut st = StageStats {
            stage: Stage::Inference as u32,
            worker: 0,
            pid: 10,
            frames_in: 5,
            frames_out: 4,
            errors: 1,
            ..Default::default()
        };
        m.observe_stats(&st, true);
        st.frames_in = 7;
        m.observe_stats(&st, true);
        // A restarted worker counts from zero again; the counter goes on.
        st.pid = 11;
        st.frames_in = 2;
        m.observe_stats(&st, false);
        let mut h = FrameHeader {
            kind: MessageKind::SelectedGrasps as u32,
            ..Default::default()
        };
        h.stamps_ns[Stamp::IngestPublished as usize] = 1_000_000_000;
        h.stamps_ns[Stamp::SelectionEnd as usize] = 1_050_000_000;
        m.observe_outcome(&FrameOutcome {
            header: h,
            picks: vec![],
        });
        let text = m.encode();
        assert!(
            text.contains("psgrasp_stage_frames_in_total{stage=\"inference\",worker=\"0\"} 9"),
            "{text}"
        );
        assert!(text.contains("psgrasp_stage_up{stage=\"inference\",worker=\"0\"} 0"));
        assert!(text.contains("psgrasp_frames_total{status=\"Ok\"} 1"));
        // 50 ms end to end: in the 64 ms bucket, not in the 32 ms one.
        assert!(
            text.contains("psgrasp_latency_seconds_bucket{le=\"0.064\",span=\"end_to_end\"} 1"),
            "{text}"
        );
        assert!(text.contains("psgrasp_latency_seconds_bucket{le=\"0.032\",span=\"end_to_end\"} 0"));
        assert!(text.ends_with("# EOF\n"));
    }
}
