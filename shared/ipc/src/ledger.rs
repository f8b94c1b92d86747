//! The frame ledger: every frame admitted into the pipeline ends as picks or exactly one error
//! record, whichever single process dies.
//!
//! camera-ingest admits frames and keeps the ledger; every other stage reports on the
//! `progress` service when a frame leaves it ([`ProgressKind::Left`], stamped with the end stamp
//! its output carries, which is when the frame entered the next stage's queue) and when a worker
//! starts taking frames ([`ProgressKind::Started`], after its inputs are attached). From these
//! the ledger knows where each frame is and decides that a frame is lost:
//! - at once, when the worker that holds it restarted: the frame entered that worker's queue
//!   before the new instance started, so it died with the old one (or reached no one). The new
//!   instance drops such stale frames unprocessed ([`is_stale`]), so the decision is final;
//! - after the loss timeout otherwise (a stalled stage, an event it missed).
//!
//! The ledger also bounds the frames in flight (admission control): with every subscriber queue
//! at least that deep, no stage queue can overflow, so frames are not dropped under overload.
use crate::header::{Stage, StatusCode};
use iceoryx2::prelude::ZeroCopySend;
use std::collections::{BTreeMap, BTreeSet, HashMap};

/// What a [`ProgressEvent`] reports.
#[repr(u32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ProgressKind {
    /// A frame left a stage (output or error record published).
    Left = 1,
    /// A worker (re)started and takes frames from now on.
    Started = 2,
    /// The ledger ended a frame with an error record (stages drop later results of it).
    Verdict = 3,
    /// camera-ingest admitted a frame into the pipeline (for observers: it must end).
    Admitted = 4,
}

/// One progress report on `<pipeline>/progress` (header-only traffic, deep queue).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, ZeroCopySend)]
#[type_name("psgrasp::ProgressEvent/v1")]
pub struct ProgressEvent {
    /// A [`ProgressKind`] as `u32`.
    pub kind: u32,
    /// The reporting [`Stage`] as `u32`.
    pub stage: u32,
    /// Worker index of the reporter.
    pub worker: u32,
    /// Process id of the reporter.
    pub pid: u32,
    /// The frame (`Left`, `Verdict`); 0 for `Started`.
    pub frame_id: u64,
    /// `Left`: the end stamp of the output; `Started`: when the worker started taking frames;
    /// `Verdict`: when the ledger decided.
    pub stamp_ns: u64,
}

impl ProgressEvent {
    /// An event of `kind` from `stage`/`worker` of this process.
    pub fn new(
        kind: ProgressKind,
        stage: Stage,
        worker: u32,
        frame_id: u64,
        stamp_ns: u64,
    ) -> Self {
        Self {
            kind: kind as u32,
            stage: stage as u32,
            worker,
            pid: std::process::id(),
            frame_id,
            stamp_ns,
        }
    }

    /// The decoded kind (`None`: an undefined wire value).
    pub fn kind(&self) -> Option<ProgressKind> {
        [
            ProgressKind::Left,
            ProgressKind::Started,
            ProgressKind::Verdict,
        ]
        .into_iter()
        .find(|k| *k as u32 == self.kind)
    }
}

/// True when a frame that entered a worker's queue at `entered_ns` predates the worker
/// instance that started at `started_ns`: the ledger has declared it lost, so the worker must
/// drop it unprocessed (0 = stamp missing, never stale).
pub fn is_stale(entered_ns: u64, started_ns: u64) -> bool {
    entered_ns != 0 && entered_ns < started_ns
}

/// The ledger's decision to end a frame with an error record.
#[derive(Debug, Clone, PartialEq)]
pub struct Verdict {
    /// The frame.
    pub frame_id: u64,
    /// The stage where the frame was lost.
    pub stage: Stage,
    /// Status of the error record.
    pub status: StatusCode,
    /// The cause, for the record's message.
    pub message: String,
}

/// A bounded set of recent frame ids (oldest forgotten first).
#[derive(Debug, Clone)]
pub struct RecentIds {
    ids: BTreeSet<u64>,
    capacity: usize,
}

impl RecentIds {
    /// A set remembering at most `capacity` ids.
    pub fn new(capacity: usize) -> Self {
        Self {
            ids: BTreeSet::new(),
            capacity: capacity.max(1),
        }
    }

    /// Adds `id`; false if it was present.
    pub fn insert(&mut self, id: u64) -> bool {
        let new = self.ids.insert(id);
        while self.ids.len() > self.capacity {
            self.ids.pop_first();
        }
        new
    }

    /// True if `id` is remembered.
    pub fn contains(&self, id: u64) -> bool {
        self.ids.contains(&id)
    }
}

/// Where an admitted frame is.
#[derive(Debug, Clone, Copy)]
struct InFlight {
    admitted_ns: u64,
    /// The stage whose queue (or step) holds it.
    at: Stage,
    /// When it entered that stage's queue.
    entered_ns: u64,
}

/// Frames ended (kept to recognise late results).
const ENDED_MEMORY: usize = 65_536;

/// The ledger of the frames camera-ingest admitted (see the module documentation).
#[derive(Debug, Clone)]
pub struct FrameLedger {
    /// Workers of grid-fusion, inference, grasp-selection.
    workers: [u32; 3],
    timeout_ns: u64,
    in_flight: BTreeMap<u64, InFlight>,
    ended: RecentIds,
    /// Latest start (ns) and pid of every worker seen starting.
    started: HashMap<(u32, u32), (u64, u32)>,
}

fn stage_index(stage: Stage) -> Option<usize> {
    match stage {
        Stage::GridFusion => Some(0),
        Stage::Inference => Some(1),
        Stage::GraspSelection => Some(2),
        Stage::CameraIngest => None,
    }
}

fn next_stage(stage: Stage) -> Option<Stage> {
    match stage {
        Stage::CameraIngest => Some(Stage::GridFusion),
        Stage::GridFusion => Some(Stage::Inference),
        Stage::Inference => Some(Stage::GraspSelection),
        Stage::GraspSelection => None,
    }
}

impl FrameLedger {
    /// A ledger for a pipeline with `workers` = [grid-fusion, inference, grasp-selection]
    /// workers and a loss timeout in nanoseconds.
    pub fn new(workers: [u32; 3], timeout_ns: u64) -> Self {
        Self {
            workers: workers.map(|w| w.max(1)),
            timeout_ns,
            in_flight: BTreeMap::new(),
            ended: RecentIds::new(ENDED_MEMORY),
            started: HashMap::new(),
        }
    }

    /// Frames admitted and not yet ended.
    pub fn in_flight(&self) -> usize {
        self.in_flight.len()
    }

    /// The worker of `stage` that handles `frame_id`.
    fn owner(&self, stage: Stage, frame_id: u64) -> u32 {
        stage_index(stage).map_or(0, |i| (frame_id % self.workers[i] as u64) as u32)
    }

    /// The verdict for a frame that entered `stage` at `entered_ns`, if the worker holding it
    /// has restarted since.
    fn restarted_since(&self, stage: Stage, frame_id: u64, entered_ns: u64) -> Option<Verdict> {
        let worker = self.owner(stage, frame_id);
        let &(started_ns, pid) = self.started.get(&(stage as u32, worker))?;
        is_stale(entered_ns, started_ns).then(|| Verdict {
            frame_id,
            stage,
            status: StatusCode::Lost,
            message: format!(
                "{}[{worker}] restarted (now pid {pid}) while the frame was queued or processed \
                 there",
                stage.name()
            ),
        })
    }

    /// Records a frame published to grid-fusion at `published_ns`.
    pub fn admit(&mut self, frame_id: u64, published_ns: u64) -> Option<Verdict> {
        self.in_flight.insert(
            frame_id,
            InFlight {
                admitted_ns: published_ns,
                at: Stage::GridFusion,
                entered_ns: published_ns,
            },
        );
        let verdict = self.restarted_since(Stage::GridFusion, frame_id, published_ns);
        if let Some(v) = &verdict {
            self.end(v.frame_id);
        }
        verdict
    }

    fn end(&mut self, frame_id: u64) {
        self.in_flight.remove(&frame_id);
        self.ended.insert(frame_id);
    }

    /// True if `frame_id` was admitted and has ended (outcome seen or verdict given).
    pub fn ended(&self, frame_id: u64) -> bool {
        self.ended.contains(frame_id)
    }

    /// Applies a batch of progress events in time order (events from different publishers
    /// arrive in any order; a drain of the queue holds every event sent before the newest);
    /// returns the frames to end with an error record.
    pub fn apply(&mut self, events: &mut [ProgressEvent]) -> Vec<Verdict> {
        events.sort_by_key(|e| e.stamp_ns);
        let mut verdicts = Vec::new();
        for e in events.iter() {
            let Some(stage) = Stage::from_u32(e.stage) else {
                continue;
            };
            match e.kind() {
                Some(ProgressKind::Left) => verdicts.extend(self.left(stage, e)),
                Some(ProgressKind::Started) => verdicts.extend(self.worker_started(stage, e)),
                Some(ProgressKind::Verdict | ProgressKind::Admitted) | None => {}
            }
        }
        verdicts
    }

    fn left(&mut self, stage: Stage, e: &ProgressEvent) -> Option<Verdict> {
        let frame = self.in_flight.get_mut(&e.frame_id)?;
        let Some(next) = next_stage(stage) else {
            // The last stage published the outcome.
            self.end(e.frame_id);
            return None;
        };
        frame.at = next;
        frame.entered_ns = e.stamp_ns;
        let verdict = self.restarted_since(next, e.frame_id, e.stamp_ns);
        if verdict.is_some() {
            self.end(e.frame_id);
        }
        verdict
    }

    fn worker_started(&mut self, stage: Stage, e: &ProgressEvent) -> Vec<Verdict> {
        self.started
            .insert((stage as u32, e.worker), (e.stamp_ns, e.pid));
        let lost: Vec<Verdict> = self
            .in_flight
            .iter()
            .filter(|(&id, f)| f.at == stage && self.owner(stage, id) == e.worker)
            .filter_map(|(&id, f)| self.restarted_since(stage, id, f.entered_ns))
            .collect();
        for v in &lost {
            self.end(v.frame_id);
        }
        lost
    }

    /// Frames admitted more than the loss timeout before `now_ns` without an outcome.
    pub fn expire(&mut self, now_ns: u64) -> Vec<Verdict> {
        let timeout_ms = self.timeout_ns / 1_000_000;
        let lost: Vec<Verdict> = self
            .in_flight
            .iter()
            .filter(|(_, f)| now_ns.saturating_sub(f.admitted_ns) > self.timeout_ns)
            .map(|(&id, f)| Verdict {
                frame_id: id,
                stage: f.at,
                status: StatusCode::Lost,
                message: format!(
                    "no result within {timeout_ms} ms; last seen queued for {}[{}] (stalled, or \
                     a report was missed)",
                    f.at.name(),
                    self.owner(f.at, id)
                ),
            })
            .collect();
        for v in &lost {
            self.end(v.frame_id);
        }
        lost
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    fn left(stage: Stage, worker: u32, frame_id: u64, at: u64) -> ProgressEvent {
        ProgressEvent::new(ProgressKind::Left, stage, worker, frame_id, at)
    }

    fn started(stage: Stage, worker: u32, at: u64) -> ProgressEvent {
        ProgressEvent::new(ProgressKind::Started, stage, worker, 0, at)
    }

    #[test]
    fn a_frame_ends_with_its_outcome_and_counts_in_flight_until_then() {
        let mut l = FrameLedger::new([1, 1, 1], 1000 * MS);
        assert!(l.admit(10, 100).is_none());
        assert!(l.admit(11, 101).is_none());
        assert_eq!(l.in_flight(), 2);
        let mut ev = vec![
            left(Stage::GraspSelection, 0, 10, 400),
            left(Stage::GridFusion, 0, 10, 200),
            left(Stage::Inference, 0, 10, 300),
        ];
        assert!(l.apply(&mut ev).is_empty());
        assert_eq!(l.in_flight(), 1);
        assert!(l.ended(10));
        // A frame the ledger never admitted (an earlier camera instance's) is ignored.
        assert!(l
            .apply(&mut [left(Stage::GraspSelection, 0, 99, 500)])
            .is_empty());
        assert_eq!(l.in_flight(), 1);
    }

    #[test]
    fn a_restarted_worker_ends_the_frames_it_held_and_only_those() {
        // Two inference workers: frame 20 belongs to worker 0, frame 21 to worker 1.
        let mut l = FrameLedger::new([1, 2, 1], 10_000 * MS);
        for id in [20, 21, 22] {
            l.admit(id, 100);
        }
        let mut ev = vec![
            left(Stage::GridFusion, 0, 20, 200),
            left(Stage::GridFusion, 0, 21, 210),
        ];
        assert!(l.apply(&mut ev).is_empty());
        // inference[0] restarts at 300: frame 20 (entered at 200) died with it; 21 is on worker
        // 1, 22 has not reached inference.
        let v = l.apply(&mut [started(Stage::Inference, 0, 300)]);
        assert_eq!(v.len(), 1);
        assert_eq!((v[0].frame_id, v[0].stage), (20, Stage::Inference));
        assert!(
            v[0].message.contains("inference[0] restarted"),
            "{}",
            v[0].message
        );
        // Frame 22 reaches inference[0] after the restart: fine.
        assert!(l
            .apply(&mut [left(Stage::GridFusion, 0, 22, 310)])
            .is_empty());
        assert_eq!(l.in_flight(), 2);
        // A late outcome of frame 20 does not revive it.
        l.apply(&mut [left(Stage::GraspSelection, 0, 20, 400)]);
        assert_eq!(l.in_flight(), 2);
    }

    #[test]
    fn a_frame_sent_to_a_worker_before_its_restart_is_lost_whatever_the_event_order() {
        let mut l = FrameLedger::new([1, 1, 1], 10_000 * MS);
        l.admit(30, 100);
        // The restart of grasp-selection is seen before the report that frame 30 left
        // inference at 250 (before the restart at 300): sorted by time, so still lost.
        let mut ev = vec![
            started(Stage::GraspSelection, 0, 300),
            left(Stage::Inference, 0, 30, 250),
            left(Stage::GridFusion, 0, 30, 200),
        ];
        let v = l.apply(&mut ev);
        assert_eq!(v.len(), 1);
        assert_eq!(v[0].stage, Stage::GraspSelection);
        // In separate batches, the late report is judged against the known restart.
        let mut l = FrameLedger::new([1, 1, 1], 10_000 * MS);
        l.admit(31, 100);
        assert!(l.apply(&mut [started(Stage::Inference, 0, 300)]).is_empty());
        let v = l.apply(&mut [left(Stage::GridFusion, 0, 31, 250)]);
        assert_eq!(v.len(), 1);
        // Frames published to a grid-fusion that restarted since are lost at admission.
        assert!(l
            .apply(&mut [started(Stage::GridFusion, 0, 500)])
            .is_empty());
        assert_eq!(l.admit(32, 400).map(|v| v.stage), Some(Stage::GridFusion));
        assert!(l.admit(33, 600).is_none());
    }

    #[test]
    fn silence_expires_after_the_timeout_naming_where_the_frame_was() {
        let mut l = FrameLedger::new([1, 1, 1], 1000 * MS);
        l.admit(40, 0);
        l.admit(41, 500 * MS);
        l.apply(&mut [left(Stage::GridFusion, 0, 40, 10 * MS)]);
        assert!(l.expire(900 * MS).is_empty());
        let v = l.expire(1200 * MS);
        assert_eq!(v.len(), 1);
        assert_eq!(v[0].frame_id, 40);
        assert!(v[0].message.contains("inference[0]"), "{}", v[0].message);
        assert_eq!(l.expire(1600 * MS).len(), 1);
        assert_eq!(l.in_flight(), 0);
    }

    #[test]
    fn stale_means_strictly_before_the_start_and_a_missing_stamp_never_is() {
        assert!(is_stale(99, 100));
        assert!(!is_stale(100, 100));
        assert!(!is_stale(0, 100));
        let mut ids = RecentIds::new(2);
        assert!(ids.insert(1) && ids.insert(2) && ids.insert(3));
        assert!(!ids.insert(3));
        assert!(!ids.contains(1) && ids.contains(2));
    }
}
