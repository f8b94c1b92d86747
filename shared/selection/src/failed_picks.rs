//! A memory of failed picks: for the next few picks after one failed, picks that would grasp at
//! the same spot in the same way are handed out only after every other pick.
//!
//! A failed grasp often leaves the scene as it was (nothing held, the object barely moved), and
//! the next frame's best pick is then the same grasp again. In the evaluation's challenging
//! scenes the shipped cell re-picks within 3 cm and 20° of a failed pick on 11 % of its picks
//! after a failure, and three failures in a row end a round (docs/evaluation.md, "A memory of
//! failed picks"). Deferring, not refusing: when only such picks are left they still come, so the
//! memory never turns a frame with picks into one without.
use nalgebra::{Point3, Vector3};
use psgrasp_geometry::check_setting;
use serde::{Deserialize, Serialize};

use crate::SelectionError;

/// `[selection.failed_pick_memory]`: how long and how near a failed pick defers others.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FailedPickMemory {
    /// How many picks after a failed one (whatever their outcome) picks near it are deferred
    /// for; 0 (the default) turns the memory off.
    pub picks: u32,
    /// A pick is near a failed one when its tool centre point lies within this distance, metres…
    pub radius_m: f32,
    /// …and both its approach direction and its closing axis (either way round: the fingers are
    /// alike) within this angle of the failed pick's, degrees: the same grasp, give or take.
    pub max_angle_deg: f32,
}

impl Default for FailedPickMemory {
    fn default() -> Self {
        Self {
            picks: 0,
            radius_m: 0.03,
            max_angle_deg: 20.0,
        }
    }
}

impl FailedPickMemory {
    /// Whether the memory defers anything.
    pub fn enabled(&self) -> bool {
        self.picks > 0
    }

    /// At most 100 picks, a radius in [0, 0.5] m and an angle in [0, 180]°.
    pub fn validate(&self) -> Result<(), SelectionError> {
        check_setting(
            self.picks <= 100,
            "failed_pick_memory.picks",
            "must be at most 100",
        )?;
        check_setting(
            self.radius_m.is_finite() && (0.0..=0.5).contains(&self.radius_m),
            "failed_pick_memory.radius_m",
            "must lie in [0, 0.5] m",
        )?;
        check_setting(
            self.max_angle_deg.is_finite() && (0.0..=180.0).contains(&self.max_angle_deg),
            "failed_pick_memory.max_angle_deg",
            "must lie in [0, 180] degrees",
        )?;
        Ok(())
    }
}

/// `true` for the default (off) memory, which is then not written.
pub(crate) fn is_default(memory: &FailedPickMemory) -> bool {
    *memory == FailedPickMemory::default()
}

/// Where a pick grasps and how: its tool centre point, unit approach direction and unit closing
/// axis, in one frame (the workspace's).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PickSpot {
    /// Tool centre point, metres.
    pub tcp: [f32; 3],
    /// Unit approach direction (the gripper's z axis).
    pub approach: [f32; 3],
    /// Unit closing axis between the fingers (the gripper's x axis, the grasp's baseline).
    pub closing: [f32; 3],
}

impl PickSpot {
    /// The spot of a gripper pose (x = baseline, z = approach, origin = TCP).
    pub fn of_pose(pose: &nalgebra::Isometry3<f32>) -> Self {
        Self::of_rotation(pose.translation.vector.into(), &pose.rotation)
    }

    /// The spot of a gripper at `tcp` turned by `rotation` (x = closing axis, z = approach).
    pub fn of_rotation(tcp: [f32; 3], rotation: &nalgebra::UnitQuaternion<f32>) -> Self {
        Self {
            tcp,
            approach: (rotation * Vector3::z()).into(),
            closing: (rotation * Vector3::x()).into(),
        }
    }

    fn near(&self, other: &PickSpot, memory: &FailedPickMemory) -> bool {
        let distance = (Point3::from(self.tcp) - Point3::from(other.tcp)).norm();
        let cos_max = memory.max_angle_deg.to_radians().cos();
        let cos = |a: [f32; 3], b: [f32; 3]| Vector3::from(a).dot(&Vector3::from(b));
        distance <= memory.radius_m
            && cos(self.approach, other.approach) >= cos_max
            && cos(self.closing, other.closing).abs() >= cos_max
    }
}

/// A failed pick still remembered.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
struct Remembered {
    spot: PickSpot,
    picks_left: u32,
}

/// The failed picks among the last [`FailedPickMemory::picks`] picks.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct FailedPicks {
    memory: FailedPickMemory,
    remembered: Vec<Remembered>,
}

impl FailedPicks {
    /// An empty memory with `memory`'s settings.
    pub fn new(memory: FailedPickMemory) -> Self {
        Self {
            memory,
            remembered: Vec::new(),
        }
    }

    /// Replaces the settings, keeping the failures remembered (a restarted server under a new
    /// configuration); an off memory forgets them all.
    pub fn set_memory(&mut self, memory: FailedPickMemory) {
        self.memory = memory;
        if !memory.enabled() {
            self.remembered.clear();
        }
        for r in &mut self.remembered {
            r.picks_left = r.picks_left.min(memory.picks);
        }
    }

    /// Takes in the outcome of an executed pick: it counts against every failure remembered,
    /// and when it failed (`held` false) it is remembered for the next
    /// [`FailedPickMemory::picks`] picks (nothing when the memory is off).
    pub fn pick_done(&mut self, spot: PickSpot, held: bool) {
        for r in &mut self.remembered {
            r.picks_left -= 1;
        }
        self.remembered.retain(|r| r.picks_left > 0);
        if !held && self.memory.enabled() {
            self.remembered.push(Remembered {
                spot,
                picks_left: self.memory.picks,
            });
        }
    }

    /// Whether `spot` lies near a remembered failed pick.
    pub fn is_near_failure(&self, spot: &PickSpot) -> bool {
        self.remembered
            .iter()
            .any(|r| r.spot.near(spot, &self.memory))
    }

    /// Number of failed picks remembered.
    pub fn len(&self) -> usize {
        self.remembered.len()
    }

    /// Whether no failed pick is remembered.
    pub fn is_empty(&self) -> bool {
        self.remembered.is_empty()
    }

    /// Orders a frame's `picks` (best first): those near a remembered failure go after all the
    /// others, each group in its own order. Returns how many picks were deferred.
    pub fn order<T>(&self, picks: &mut Vec<T>, spot: impl Fn(&T) -> PickSpot) -> usize {
        if self.remembered.is_empty() {
            return 0;
        }
        let (mut kept, deferred): (Vec<T>, Vec<T>) = picks
            .drain(..)
            .partition(|p| !self.is_near_failure(&spot(p)));
        let count = deferred.len();
        kept.extend(deferred);
        *picks = kept;
        count
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A pick at x tilted about y by `tilt_deg`, closing along x turned about the vertical by
    /// `turn_deg`.
    fn turned(x: f32, tilt_deg: f32, turn_deg: f32) -> PickSpot {
        let (t, u) = (tilt_deg.to_radians(), turn_deg.to_radians());
        PickSpot {
            tcp: [x, 0.2, 0.05],
            approach: [t.sin(), 0.0, -t.cos()],
            closing: [u.cos() * t.cos(), u.sin(), u.cos() * t.sin()],
        }
    }

    fn spot(x: f32, tilt_deg: f32) -> PickSpot {
        turned(x, tilt_deg, 0.0)
    }

    fn memory(picks: u32) -> FailedPicks {
        FailedPicks::new(FailedPickMemory {
            picks,
            ..Default::default()
        })
    }

    #[test]
    fn picks_near_a_failure_go_last_for_the_remembered_picks_only() {
        let mut failed = memory(2);
        failed.pick_done(spot(0.10, 0.0), false);
        // 1 cm away and 10° off: near; 5 cm away: not; same place, 40° off: not.
        let frame = || vec![spot(0.11, 10.0), spot(0.15, 0.0), spot(0.10, 40.0)];
        let mut picks = frame();
        assert_eq!(failed.order(&mut picks, |p| *p), 1);
        assert_eq!(
            picks,
            vec![spot(0.15, 0.0), spot(0.10, 40.0), spot(0.11, 10.0)]
        );
        // The next pick held; the failure still counts for one more pick.
        failed.pick_done(picks[0], true);
        let mut picks = frame();
        assert_eq!(failed.order(&mut picks, |p| *p), 1);
        assert_eq!(picks[2], spot(0.11, 10.0));
        // Two picks later the failure is forgotten: the frame keeps its order.
        failed.pick_done(picks[0], true);
        assert!(failed.is_empty());
        let mut picks = frame();
        assert_eq!(failed.order(&mut picks, |p| *p), 0);
        assert_eq!(picks, frame());
    }

    #[test]
    fn the_same_spot_closing_another_way_is_another_grasp() {
        let mut failed = memory(1);
        failed.pick_done(turned(0.10, 0.0, 0.0), false);
        // The fingers swapped (180°) are the same grasp; turned 45° about the vertical, not.
        assert!(failed.is_near_failure(&turned(0.10, 0.0, 180.0)));
        assert!(failed.is_near_failure(&turned(0.11, 0.0, 15.0)));
        assert!(!failed.is_near_failure(&turned(0.10, 0.0, 45.0)));
    }

    #[test]
    fn a_frame_of_only_deferred_picks_keeps_them_all() {
        let mut failed = memory(1);
        failed.pick_done(spot(0.10, 0.0), false);
        let mut picks = vec![spot(0.10, 5.0), spot(0.12, 0.0)];
        assert_eq!(failed.order(&mut picks, |p| *p), 2);
        assert_eq!(picks, vec![spot(0.10, 5.0), spot(0.12, 0.0)]);
    }

    #[test]
    fn an_off_memory_remembers_nothing_and_turning_it_off_forgets() {
        let mut failed = memory(0);
        failed.pick_done(spot(0.10, 0.0), false);
        assert!(failed.is_empty());
        let mut picks = vec![spot(0.10, 0.0)];
        assert_eq!(failed.order(&mut picks, |p| *p), 0);
        let mut failed = memory(3);
        failed.pick_done(spot(0.10, 0.0), false);
        failed.set_memory(FailedPickMemory {
            picks: 1,
            ..Default::default()
        });
        assert_eq!(failed.len(), 1);
        failed.pick_done(spot(0.30, 0.0), true);
        assert!(
            failed.is_empty(),
            "the shorter memory applies to what was remembered"
        );
        failed.pick_done(spot(0.10, 0.0), false);
        failed.set_memory(FailedPickMemory::default());
        assert!(failed.is_empty());
    }
    #[test]
    fn the_spot_of_a_pose_is_its_origin_and_z_axis() {
        let pose = nalgebra::Isometry3::new(
            Vector3::new(0.1, 0.2, 0.3),
            Vector3::x() * std::f32::consts::PI, // z turned to point down
        );
        let s = PickSpot::of_pose(&pose);
        assert_eq!(s.tcp, [0.1, 0.2, 0.3]);
        assert!((s.approach[2] + 1.0).abs() < 1e-6);
        assert!((s.closing[0] - 1.0).abs() < 1e-6);
    }

    #[test]
    fn settings_out_of_range_are_refused() {
        let bad = FailedPickMemory {
            radius_m: -0.01,
            ..Default::default()
        };
        assert!(bad.validate().is_err());
        let bad = FailedPickMemory {
            max_angle_deg: f32::NAN,
            ..Default::default()
        };
        assert!(bad.validate().is_err());
        assert!(FailedPickMemory::default().validate().is_ok());
    }
}
