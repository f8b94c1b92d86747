//! The next-pick server (in grasp-selection worker 0): hands out the picks of the latest
//! successful frame one by one to a cell controller. Its cursor is saved to a state file on
//! every change, so a restarted grasp-selection carries on where the dead one stopped.
use anyhow::{Context, Result};
use iceoryx2::port::listener::Listener;
use iceoryx2::prelude::*;
use nalgebra::{Quaternion, UnitQuaternion};
use psgrasp_ipc::{
    FrameSubscriber, NextPickMode, NextPickRequest, NextPickResponse, NextPickStatus, PickRecord,
    PipelineNode,
};
use psgrasp_selection::{FailedPickMemory, FailedPicks, PickSpot};
use std::path::{Path, PathBuf};

type Server =
    iceoryx2::port::server::Server<ipc::Service, NextPickRequest, (), NextPickResponse, ()>;

/// The ports the server needs: the request-response server, the listener that wakes it on a
/// request, and a subscriber to the picks of every grasp-selection worker.
pub struct NextPickPorts {
    server: Server,
    requests: Listener<ipc::Service>,
    picks: FrameSubscriber<PickRecord>,
}

impl NextPickPorts {
    /// What wakes the server: a request, or new picks.
    pub fn listeners(&self) -> [&Listener<ipc::Service>; 2] {
        [&self.requests, self.picks.listener()]
    }
}

/// Which pick of the latest successful frame a controller gets next.
#[derive(Debug, Default, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PickCursor {
    latest: Option<(u64, Vec<PickRecord>)>,
    cursor: usize,
    /// Whether the pick at `cursor` has been handed out: only then does a failure report move
    /// past it (a new frame's first pick is never skipped).
    handed_out: bool,
    /// When a pick was last reported successful (µs, the clock of frame ids): frames up to
    /// then show the scene before that pick, so none of their picks is handed out.
    #[serde(default)]
    picked_at_us: Option<u64>,
    /// Picks reported failed: a new frame's picks near one go last
    /// (`[selection.failed_pick_memory]`).
    #[serde(default)]
    failed: FailedPicks,
}

impl PickCursor {
    /// An empty cursor whose new frames' picks near a failed one go last for the next
    /// `memory.picks` picks.
    pub fn with_memory(memory: FailedPickMemory) -> Self {
        Self {
            failed: FailedPicks::new(memory),
            ..Self::default()
        }
    }

    /// Takes in the picks of `frame_id` if it is newer than the latest; starts at its best pick
    /// (picks near a recently failed pick moved last, keeping their `rank`). True if it did.
    pub fn offer(&mut self, frame_id: u64, picks: &[PickRecord]) -> bool {
        if self.latest.as_ref().is_none_or(|(id, _)| frame_id > *id) {
            let mut picks = picks.to_vec();
            let deferred = self.failed.order(&mut picks, pick_spot);
            if deferred > 0 {
                tracing::info!(
                    "next-pick: frame {frame_id}: {deferred} pick(s) near a failed pick go last"
                );
            }
            self.latest = Some((frame_id, picks));
            self.cursor = 0;
            self.handed_out = false;
            if self.picked_at_us.is_some_and(|t| frame_id > t) {
                self.picked_at_us = None;
            }
            return true;
        }
        false
    }

    /// Saves the cursor to `path` (atomically: a temporary file renamed over it).
    pub fn save(&self, path: &Path) -> Result<()> {
        let tmp = path.with_extension("tmp");
        std::fs::write(&tmp, serde_json::to_vec(self)?)
            .with_context(|| format!("writing {}", tmp.display()))?;
        std::fs::rename(&tmp, path).with_context(|| format!("replacing {}", path.display()))?;
        Ok(())
    }

    /// The cursor saved at `path`; empty if there is none.
    pub fn load(path: &Path) -> Result<Self> {
        match std::fs::read(path) {
            Ok(bytes) => serde_json::from_slice(&bytes)
                .with_context(|| format!("reading the next-pick state {}", path.display())),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(Self::default()),
            Err(e) => Err(e).with_context(|| format!("reading {}", path.display())),
        }
    }

    /// The pick handed out last and not yet reported on.
    fn handed_out_pick(&self) -> Option<PickRecord> {
        let (_, picks) = self.latest.as_ref()?;
        self.handed_out
            .then(|| picks.get(self.cursor).copied())
            .flatten()
    }

    /// The answer to a request in `mode` (`None`: an undefined wire value) received at
    /// `now_us` (µs, the clock of frame ids).
    pub fn answer(&mut self, mode: Option<NextPickMode>, now_us: u64) -> NextPickResponse {
        let reported = self.handed_out_pick();
        if mode == Some(NextPickMode::AfterSuccess) {
            self.picked_at_us = Some(now_us);
            if let Some(held) = reported {
                self.failed.pick_done(pick_spot(&held), true);
            }
            // Reported once: a repeated success report counts no second pick.
            self.handed_out = false;
        }
        let Some((frame_id, picks)) = &self.latest else {
            return NextPickResponse::without_pick(NextPickStatus::NoFrameYet, 0);
        };
        match mode {
            None => return NextPickResponse::without_pick(NextPickStatus::BadRequest, *frame_id),
            Some(NextPickMode::AfterFailure) if self.handed_out => {
                if let Some(failed) = reported {
                    self.failed.pick_done(pick_spot(&failed), false);
                }
                self.cursor += 1;
            }
            Some(_) => {}
        }
        if self.picked_at_us.is_some_and(|t| *frame_id <= t) {
            return NextPickResponse::without_pick(NextPickStatus::AwaitingNewFrame, *frame_id);
        }
        match picks.get(self.cursor) {
            Some(p) => {
                self.handed_out = true;
                NextPickResponse::with_pick(*frame_id, *p)
            }
            None => NextPickResponse::without_pick(NextPickStatus::Exhausted, *frame_id),
        }
    }
}

/// Where a pick record grasps (workspace frame) and from where.
fn pick_spot(pick: &PickRecord) -> PickSpot {
    let [x, y, z, w] = pick.orientation_xyzw;
    PickSpot::of_rotation(
        pick.position,
        &UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z)),
    )
}

/// Where the next-pick server of pipeline `pipeline` keeps its cursor (the launcher removes it
/// when a pipeline starts and stops).
pub fn state_path(pipeline: &str) -> PathBuf {
    std::env::temp_dir()
        .join("psgrasp")
        .join(format!("{pipeline}-next-pick.json"))
}

/// Serves `next-pick` requests from the latest successful pick list.
pub struct NextPickServer<'p> {
    ports: &'p NextPickPorts,
    picks: PickCursor,
    state: PathBuf,
}

impl<'p> NextPickServer<'p> {
    /// Opens the server's ports on `node`.
    pub fn ports(node: &PipelineNode) -> Result<NextPickPorts> {
        let (service, event) = node.next_pick_service()?;
        let server = service
            .server_builder()
            .create()
            .map_err(|e| anyhow::anyhow!("next-pick server: {e:?}"))?;
        let requests = event
            .listener_builder()
            .create()
            .map_err(|e| anyhow::anyhow!("next-pick listener: {e:?}"))?;
        let picks = node.outcome_subscriber()?;
        Ok(NextPickPorts {
            server,
            requests,
            picks,
        })
    }

    /// A server on `ports` that carries on from the cursor saved at `state` (a restart), or
    /// starts empty; its memory of failed picks follows `memory` (a restart keeps the failures
    /// remembered, under the settings given now).
    pub fn new(ports: &'p NextPickPorts, state: PathBuf, memory: FailedPickMemory) -> Self {
        if let Some(dir) = state.parent() {
            let _ = std::fs::create_dir_all(dir);
        }
        let mut picks = PickCursor::load(&state).unwrap_or_else(|e| {
            tracing::warn!("{e:#}; starting without picks");
            PickCursor::default()
        });
        picks.failed.set_memory(memory);
        if let Some((frame_id, _)) = &picks.latest {
            tracing::info!("next-pick: carrying on with the picks of frame {frame_id}");
        }
        Self {
            ports,
            picks,
            state,
        }
    }

    fn save(&self) {
        if let Err(e) = self.picks.save(&self.state) {
            tracing::warn!("next-pick state not saved: {e:#}");
        }
    }

    /// Takes in new pick lists, then answers every pending request.
    pub fn serve(&mut self) -> Result<()> {
        let mut changed = false;
        while let Some(s) = self.ports.picks.receive()? {
            let h = s.user_header();
            if h.is_ok() {
                changed |= self.picks.offer(h.frame_id, s.payload());
            }
        }
        if changed {
            self.save();
        }
        while let Some(active) = self
            .ports
            .server
            .receive()
            .map_err(|e| anyhow::anyhow!("next-pick receive: {e:?}"))?
        {
            let now_us = psgrasp_ipc::now_ns() / 1000;
            let response = self.picks.answer(active.payload().mode(), now_us);
            self.save();
            active
                .send_copy(response)
                .map_err(|e| anyhow::anyhow!("next-pick respond: {e:?}"))?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn picks(n: u32) -> Vec<PickRecord> {
        (0..n)
            .map(|rank| PickRecord {
                rank,
                ..Default::default()
            })
            .collect()
    }

    fn rank(r: NextPickResponse) -> Option<u32> {
        (r.status() == Some(NextPickStatus::Pick)).then_some(r.pick.rank)
    }

    #[test]
    fn a_failure_report_moves_on_but_never_past_a_pick_not_yet_handed_out() {
        let mut c = PickCursor::default();
        assert_eq!(
            c.answer(Some(NextPickMode::Current), 0).status(),
            Some(NextPickStatus::NoFrameYet)
        );
        c.offer(10, &picks(3));
        assert_eq!(rank(c.answer(Some(NextPickMode::Current), 0)), Some(0));
        assert_eq!(rank(c.answer(Some(NextPickMode::Current), 0)), Some(0));
        assert_eq!(rank(c.answer(Some(NextPickMode::AfterFailure), 0)), Some(1));
        // A new frame arrives: the failure report of the old pick gives the new frame's best,
        // not its second (issue 19, failure 7).
        c.offer(11, &picks(3));
        let r = c.answer(Some(NextPickMode::AfterFailure), 0);
        assert_eq!((r.frame_id, rank(r)), (11, Some(0)));
        assert_eq!(rank(c.answer(Some(NextPickMode::AfterFailure), 0)), Some(1));
        assert_eq!(rank(c.answer(Some(NextPickMode::AfterFailure), 0)), Some(2));
        assert_eq!(
            c.answer(Some(NextPickMode::AfterFailure), 0).status(),
            Some(NextPickStatus::Exhausted)
        );
        // An older frame never replaces a newer one; an undefined mode is refused.
        assert!(!c.offer(9, &picks(1)));
        assert_eq!(c.answer(None, 0).status(), Some(NextPickStatus::BadRequest));
        assert_eq!(c.answer(None, 0).frame_id, 11);
    }

    /// Picks top-down at x = `xs` (ranks in order).
    fn picks_at(xs: &[f32]) -> Vec<PickRecord> {
        xs.iter()
            .enumerate()
            .map(|(rank, &x)| PickRecord {
                rank: rank as u32,
                position: [x, 0.2, 0.05],
                orientation_xyzw: [1.0, 0.0, 0.0, 0.0], // z turned to point down
                ..Default::default()
            })
            .collect()
    }

    #[test]
    fn a_failed_pick_s_spot_goes_last_for_the_next_picks_with_the_memory_on() {
        let memory = FailedPickMemory {
            picks: 1,
            ..Default::default()
        };
        for (mut c, expected) in [
            (PickCursor::with_memory(memory), [Some(1), Some(0)]),
            (PickCursor::default(), [Some(0), Some(1)]),
        ] {
            c.offer(10, &picks_at(&[0.10, 0.30]));
            assert_eq!(rank(c.answer(Some(NextPickMode::Current), 0)), Some(0));
            // The pick at x = 0.10 failed; the next frame's best is 1 cm from it.
            assert_eq!(rank(c.answer(Some(NextPickMode::AfterFailure), 0)), Some(1));
            c.offer(11, &picks_at(&[0.11, 0.20]));
            let first = rank(c.answer(Some(NextPickMode::Current), 0));
            let second = rank(c.answer(Some(NextPickMode::AfterFailure), 0));
            assert_eq!([first, second], expected);
            // One pick later (reported held) the failure is forgotten: the best pick comes
            // first again.
            c.answer(Some(NextPickMode::AfterSuccess), 5);
            c.answer(Some(NextPickMode::AfterSuccess), 6);
            c.offer(12, &picks_at(&[0.11, 0.20]));
            assert_eq!(rank(c.answer(Some(NextPickMode::Current), 10)), Some(0));
        }
    }

    #[test]
    fn a_success_report_hands_out_nothing_until_a_newer_frame_arrives() {
        let mut c = PickCursor::default();
        c.offer(100, &picks(3));
        assert_eq!(rank(c.answer(Some(NextPickMode::Current), 150)), Some(0));
        // Picked at t = 200: frame 100 shows the scene before the pick.
        let r = c.answer(Some(NextPickMode::AfterSuccess), 200);
        assert_eq!(r.status(), Some(NextPickStatus::AwaitingNewFrame));
        assert_eq!(
            c.answer(Some(NextPickMode::AfterFailure), 210).status(),
            Some(NextPickStatus::AwaitingNewFrame)
        );
        // A frame taken before the pick that finished later is no better.
        c.offer(190, &picks(2));
        assert_eq!(
            c.answer(Some(NextPickMode::Current), 220).status(),
            Some(NextPickStatus::AwaitingNewFrame)
        );
        c.offer(250, &picks(2));
        let r = c.answer(Some(NextPickMode::Current), 260);
        assert_eq!((r.frame_id, rank(r)), (250, Some(0)));
    }

    #[test]
    fn the_cursor_survives_a_restart_through_its_state_file() {
        let dir = std::env::temp_dir().join(format!("psgrasp-cursor-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("state.json");
        assert_eq!(PickCursor::load(&path).unwrap(), PickCursor::default());
        let mut c = PickCursor::default();
        let mut p = picks(3);
        p[1].position = [0.1, -0.25, 1.0 / 3.0];
        c.offer(42, &p);
        c.answer(Some(NextPickMode::Current), 0);
        c.answer(Some(NextPickMode::AfterFailure), 0);
        c.save(&path).unwrap();
        let mut restored = PickCursor::load(&path).unwrap();
        assert_eq!(restored, c, "bit-exact picks and the same position");
        let r = restored.answer(Some(NextPickMode::AfterFailure), 0);
        assert_eq!((r.frame_id, rank(r)), (42, Some(2)));
        std::fs::write(&path, b"{not json").unwrap();
        assert!(PickCursor::load(&path).is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_state_file_saved_before_picks_carried_their_pad_fill_still_loads() {
        let dir = std::env::temp_dir().join(format!("psgrasp-cursor-old-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("state.json");
        let mut c = PickCursor::default();
        let p: Vec<PickRecord> = picks(2)
            .into_iter()
            .map(|p| p.with_pad_fill(Some(0.8)))
            .collect();
        c.offer(7, &p);
        // The previous version's form: two reserved words where the pad fill is now.
        let mut v = serde_json::to_value(&c).unwrap();
        for pick in v["latest"][1].as_array_mut().unwrap() {
            let pick = pick.as_object_mut().unwrap();
            assert!(
                pick.remove("pad_fill").is_some() && pick.remove("pad_fill_measured").is_some()
            );
            pick.insert("reserved".into(), serde_json::json!([0, 0]));
        }
        std::fs::write(&path, serde_json::to_vec(&v).unwrap()).unwrap();
        let mut restored = PickCursor::load(&path).unwrap();
        let r = restored.answer(Some(NextPickMode::Current), 0);
        assert_eq!((r.frame_id, rank(r)), (7, Some(0)));
        assert_eq!(r.pick.pad_fill(), None, "an old record reads as unmeasured");
        assert_eq!(r.pick, p[0].with_pad_fill(None));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
