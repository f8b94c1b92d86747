//! [`ExecutionConfig`]: the settings of one grasp execution, with defaults and range checks.
use crate::SettleConfig;
use crate::SimError;
use psgrasp_geometry::check_setting;
use serde::{Deserialize, Serialize};

/// Settings of one grasp execution; every threshold has a default.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ExecutionConfig {
    /// Physics time step, seconds.
    pub dt_s: f32,
    /// Velocity-solver iterations per step.
    pub solver_iterations: usize,
    /// Natural frequency of the contact constraints, Hz. Rapier's default 30 Hz lets objects
    /// sink into the fingers and slip; at 120 Hz the 20 N pads still sink 1–4 mm per side and
    /// close through plates under 10 mm thick, so a held thin part read as "nothing held"
    /// (docs/evaluation.md, "Why the oracle misses"). 1000 Hz holds a 3 mm plate at 2.7 mm.
    pub contact_natural_frequency_hz: f32,
    /// Damping ratio of the contact constraints.
    pub contact_damping_ratio: f32,
    /// Margin added to the hand boxes in the geometric pre-grasp check, metres.
    pub pregrasp_margin_m: f32,
    /// Palm speed from the pre-grasp to the grasp pose, m/s.
    pub approach_speed_m_s: f32,
    /// Stop the approach when the hand touches anything (off: the kinematic palm pushes through).
    pub abort_on_approach_contact: bool,
    /// After a stopped approach, close and lift from where the hand stopped instead of failing
    /// the attempt (VGN's and GIGA's `allow_contact=True`). Off by default: a touch fails.
    pub close_after_approach_contact: bool,
    /// A contact point closer than this counts as touching, metres.
    pub touch_distance_m: f32,
    /// Closing speed of each finger, m/s.
    pub close_speed_m_s: f32,
    /// Force limit of each finger motor, newtons (the Franka hand grasps with up to 70 N; a
    /// lower force keeps the soft contacts from sinking millimetres into light objects).
    pub finger_force_n: f32,
    /// Longest closing phase, seconds.
    pub max_close_time_s: f32,
    /// The fingers count as stopped below this speed, m/s ...
    pub finger_stopped_speed_m_s: f32,
    /// ... for this long, seconds.
    pub finger_stopped_time_s: f32,
    /// Mass of each finger, kg.
    pub finger_mass_kg: f32,
    /// Friction coefficient of the finger pads.
    pub finger_friction: f32,
    /// Lift height, metres (straight up in the workspace frame).
    pub lift_height_m: f32,
    /// Lift speed, m/s.
    pub lift_speed_m_s: f32,
    /// Hold time after the lift, seconds.
    pub hold_time_s: f32,
    /// A held object keeps the fingers at least this far apart, metres.
    pub min_opening_m: f32,
    /// An object counts as lifted when it rose more than this fraction of the lift height.
    pub lifted_fraction: f32,
    /// Longest settling time of the remaining objects after the attempt, seconds.
    pub settle_time_s: f32,
    /// Object material, damping and the rest test, shared with scene generation.
    pub objects: SettleConfig,
}

impl Default for ExecutionConfig {
    fn default() -> Self {
        Self {
            dt_s: 1.0 / 240.0,
            solver_iterations: 8,
            contact_natural_frequency_hz: 1000.0,
            contact_damping_ratio: 10.0,
            pregrasp_margin_m: 0.0,
            approach_speed_m_s: 0.2,
            abort_on_approach_contact: true,
            close_after_approach_contact: false,
            touch_distance_m: 0.0005,
            close_speed_m_s: 0.1,
            finger_force_n: 20.0,
            max_close_time_s: 0.6,
            finger_stopped_speed_m_s: 0.002,
            finger_stopped_time_s: 0.05,
            finger_mass_kg: 0.05,
            finger_friction: 1.0,
            lift_height_m: 0.15,
            lift_speed_m_s: 0.3,
            hold_time_s: 0.3,
            min_opening_m: 0.002,
            lifted_fraction: 0.5,
            settle_time_s: 1.5,
            objects: SettleConfig::default(),
        }
    }
}

impl ExecutionConfig {
    /// Checks every field's range.
    pub fn validate(&self) -> Result<(), SimError> {
        let pos = |v: f32| v.is_finite() && v > 0.0;
        let nonneg = |v: f32| v.is_finite() && v >= 0.0;
        check_setting(
            self.dt_s > 0.0 && self.dt_s <= 0.02,
            "dt_s",
            "must lie in (0, 0.02] s",
        )?;
        check_setting(
            (1..=100).contains(&self.solver_iterations),
            "solver_iterations",
            "must lie in 1..=100",
        )?;
        check_setting(
            pos(self.contact_natural_frequency_hz),
            "contact_natural_frequency_hz",
            "must be > 0",
        )?;
        check_setting(
            pos(self.contact_damping_ratio),
            "contact_damping_ratio",
            "must be > 0",
        )?;
        check_setting(
            nonneg(self.pregrasp_margin_m),
            "pregrasp_margin_m",
            "must be >= 0",
        )?;
        check_setting(
            pos(self.approach_speed_m_s),
            "approach_speed_m_s",
            "must be > 0",
        )?;
        check_setting(
            nonneg(self.touch_distance_m),
            "touch_distance_m",
            "must be >= 0",
        )?;
        check_setting(pos(self.close_speed_m_s), "close_speed_m_s", "must be > 0")?;
        check_setting(pos(self.finger_force_n), "finger_force_n", "must be > 0")?;
        check_setting(
            pos(self.max_close_time_s),
            "max_close_time_s",
            "must be > 0",
        )?;
        check_setting(
            pos(self.finger_stopped_speed_m_s),
            "finger_stopped_speed_m_s",
            "must be > 0",
        )?;
        check_setting(
            nonneg(self.finger_stopped_time_s),
            "finger_stopped_time_s",
            "must be >= 0",
        )?;
        check_setting(pos(self.finger_mass_kg), "finger_mass_kg", "must be > 0")?;
        check_setting(
            nonneg(self.finger_friction),
            "finger_friction",
            "must be >= 0",
        )?;
        check_setting(
            pos(self.lift_height_m) && self.lift_height_m < 2.0,
            "lift_height_m",
            "must lie in (0, 2) m",
        )?;
        check_setting(pos(self.lift_speed_m_s), "lift_speed_m_s", "must be > 0")?;
        check_setting(nonneg(self.hold_time_s), "hold_time_s", "must be >= 0")?;
        check_setting(nonneg(self.min_opening_m), "min_opening_m", "must be >= 0")?;
        check_setting(
            self.lifted_fraction > 0.0 && self.lifted_fraction < 1.0,
            "lifted_fraction",
            "must lie in (0, 1)",
        )?;
        check_setting(nonneg(self.settle_time_s), "settle_time_s", "must be >= 0")?;
        let o = &self.objects;
        check_setting(
            nonneg(o.friction) && nonneg(o.restitution) && pos(o.density),
            "objects",
            "friction and restitution must be >= 0, density > 0",
        )?;
        Ok(())
    }
}
