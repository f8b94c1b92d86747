//! How far the hand keeps clear when it approaches a grasp: one definition for the analytic
//! backend's collision scores, selection's checks and the evaluation's execution.
use crate::setting::{check_setting, OutOfRange};
use serde::{Deserialize, Serialize};

/// The hand's clearances around a grasp (`[selection.clearance]` of a cell's configuration).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct HandClearance {
    /// The hand is checked and commanded open at the grasp width plus this, capped at the
    /// maximum opening, metres.
    pub opening_clearance_m: f32,
    /// Gripper boxes are grown by this margin against the observed scene, metres.
    pub collision_margin_m: f32,
    /// The pre-grasp pose is the grasp pose backed off this far along −approach, metres.
    pub pregrasp_distance_m: f32,
}

impl Default for HandClearance {
    fn default() -> Self {
        Self {
            opening_clearance_m: 0.02,
            collision_margin_m: 0.004,
            pregrasp_distance_m: 0.08,
        }
    }
}

impl HandClearance {
    /// Each distance is finite and in `[0, 1)` m (the margin below 0.1 m).
    pub fn validate(&self) -> Result<(), OutOfRange> {
        let metric = |v: f32| v.is_finite() && (0.0..1.0).contains(&v);
        check_setting(
            metric(self.pregrasp_distance_m),
            "pregrasp_distance_m",
            "must lie in [0, 1) m",
        )?;
        check_setting(
            metric(self.opening_clearance_m),
            "opening_clearance_m",
            "must lie in [0, 1) m",
        )?;
        check_setting(
            self.collision_margin_m.is_finite() && (0.0..0.1).contains(&self.collision_margin_m),
            "collision_margin_m",
            "must lie in [0, 0.1) m",
        )
    }

    /// The opening for a grasp of `width`: [`commanded_opening_m`] with this clearance.
    pub fn opening_m(&self, width: f32, max_opening_m: f32) -> f32 {
        commanded_opening_m(width, self.opening_clearance_m, max_opening_m)
    }
}

/// The opening a hand is commanded to before it approaches a grasp of `width_m`:
/// `min(width_m + opening_clearance_m, max_opening_m)` (selection, execution, and the label
/// checks that stand in for them).
pub fn commanded_opening_m(width_m: f32, opening_clearance_m: f32, max_opening_m: f32) -> f32 {
    (width_m + opening_clearance_m).min(max_opening_m)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_validate_and_bad_distances_name_their_key() {
        HandClearance::default().validate().unwrap();
        let c = HandClearance {
            collision_margin_m: 0.2,
            ..Default::default()
        };
        assert_eq!(c.validate().unwrap_err().field, "collision_margin_m");
        let c = HandClearance {
            pregrasp_distance_m: f32::NAN,
            ..Default::default()
        };
        assert_eq!(c.validate().unwrap_err().field, "pregrasp_distance_m");
        assert_eq!(HandClearance::default().opening_m(0.07, 0.08), 0.08);
        assert!((HandClearance::default().opening_m(0.03, 0.08) - 0.05).abs() < 1e-6);
    }
}
