//! Bookkeeping that guarantees every frame ends as a result or an explicit error record.
//!
//! camera-ingest announces every frame id it publishes; the last stage tracks announced ids and
//! declares a frame lost once no result arrived within the loss timeout (a stage died, or the
//! frame was dropped under overload). Results may overtake their announcement.
use std::collections::{BTreeMap, BTreeSet};

/// What the tracker decided about a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TrackerEvent {
    /// The frame is now accounted for (first result or error record).
    Completed,
    /// A result arrived for a frame already completed or declared lost; drop it.
    Duplicate,
}

/// Tracks frame ids of one shard (`id % stride == offset`).
#[derive(Debug, Clone)]
pub struct FrameTracker {
    stride: u64,
    offset: u64,
    timeout_ns: u64,
    pending: BTreeMap<u64, u64>,
    done: BTreeSet<u64>,
    done_capacity: usize,
}

impl FrameTracker {
    /// A tracker for shard `offset` of `stride` workers with a loss timeout in nanoseconds.
    pub fn new(stride: u64, offset: u64, timeout_ns: u64) -> Self {
        let stride = stride.max(1);
        Self {
            stride,
            offset: offset % stride,
            timeout_ns,
            pending: BTreeMap::new(),
            done: BTreeSet::new(),
            done_capacity: 65536,
        }
    }

    /// True if this shard owns `frame_id`.
    pub fn owns(&self, frame_id: u64) -> bool {
        frame_id % self.stride == self.offset
    }

    /// Registers an announced frame (ignored if not ours or already completed).
    pub fn announce(&mut self, frame_id: u64, now_ns: u64) {
        if self.owns(frame_id) && !self.done.contains(&frame_id) {
            self.pending.entry(frame_id).or_insert(now_ns);
        }
    }

    /// Registers a result or error record for `frame_id`.
    pub fn complete(&mut self, frame_id: u64) -> TrackerEvent {
        if self.done.contains(&frame_id) {
            return TrackerEvent::Duplicate;
        }
        self.pending.remove(&frame_id);
        self.remember(frame_id);
        TrackerEvent::Completed
    }

    /// Frames whose timeout expired at `now_ns`; they are marked done and must be reported lost.
    pub fn expire(&mut self, now_ns: u64) -> Vec<u64> {
        let lost: Vec<u64> = self
            .pending
            .iter()
            .filter(|(_, &t)| now_ns.saturating_sub(t) > self.timeout_ns)
            .map(|(&id, _)| id)
            .collect();
        for id in &lost {
            self.pending.remove(id);
            self.remember(*id);
        }
        lost
    }

    /// Number of frames announced but not yet accounted for.
    pub fn pending(&self) -> usize {
        self.pending.len()
    }

    fn remember(&mut self, id: u64) {
        self.done.insert(id);
        while self.done.len() > self.done_capacity {
            self.done.pop_first();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn results_complete_and_silence_expires() {
        let mut t = FrameTracker::new(1, 0, 1_000);
        for id in 0..5 {
            t.announce(id, 100);
        }
        assert_eq!(t.complete(0), TrackerEvent::Completed);
        assert_eq!(t.complete(2), TrackerEvent::Completed);
        assert_eq!(t.complete(2), TrackerEvent::Duplicate);
        assert!(t.expire(1_000).is_empty());
        assert_eq!(t.expire(1_200), vec![1, 3, 4]);
        assert_eq!(t.pending(), 0);
        // A late result after the loss report is a duplicate, not a second outcome.
        assert_eq!(t.complete(3), TrackerEvent::Duplicate);
    }

    #[test]
    fn result_may_overtake_announcement() {
        let mut t = FrameTracker::new(1, 0, 10);
        assert_eq!(t.complete(7), TrackerEvent::Completed);
        t.announce(7, 0);
        assert!(t.expire(1_000).is_empty());
    }

    #[test]
    fn shards_only_track_their_ids() {
        let mut t = FrameTracker::new(2, 1, 10);
        for id in 0..6 {
            t.announce(id, 0);
        }
        assert_eq!(t.expire(100), vec![1, 3, 5]);
    }
}
