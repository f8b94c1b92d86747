//! The fallback tier: looser score thresholds tried only when no configuration passes the paper's.
//!
//! A detector's quality and collision scores are its own estimates; when none of a frame's
//! configurations reaches the thresholds (the paper's 0.5) while objects remain, a cell would
//! rather try the best grasp that still passes every *geometric* check (bin, observed scene,
//! pre-grasp, approach path, tilt) than stop. [`FallbackThresholds`] names those looser score
//! thresholds, and keeps contacts away from the side walls in that tier (there the collision
//! score is what tells an object's grasp from a grasp of the bin's wall or rim); the selection marks picks made under them ([`crate::Selection::fallback`]) so a
//! controller can treat them differently (e.g. slower approach, or ask for a new view first).

use psgrasp_geometry::{check_setting, N_APPROACHES};
use serde::{Deserialize, Serialize};

use crate::{SelectionConfig, SelectionError};

/// Score thresholds of the fallback tier (each at most the primary one).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FallbackThresholds {
    /// Configurations with a lower antipodal quality are rejected in the fallback tier.
    pub min_quality: f32,
    /// Approaches with a lower collision score are rejected in the fallback tier.
    pub min_collision_score: f32,
    /// In the fallback tier, contacts closer than this to a side wall's inner face are rejected,
    /// metres (`SelectionConfig::min_contact_wall_distance_m`): at the walls and on the rim the
    /// collision score is what tells a grasp of an object from a grasp of the bin.
    #[serde(default = "default_wall_distance")]
    pub min_contact_wall_distance_m: f32,
    /// Approaches tried per configuration in the fallback tier, best collision score first
    /// (1..=18). `None` (default, and then not written): the primary tier's
    /// `approaches_per_configuration`. More approaches give a frame where every best approach is
    /// blocked by the bin or a neighbour a pick from another direction.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub approaches_per_configuration: Option<usize>,
}

/// [`FallbackThresholds::min_contact_wall_distance_m`]'s default, metres.
pub const DEFAULT_FALLBACK_WALL_DISTANCE_M: f32 = 0.015;

fn default_wall_distance() -> f32 {
    DEFAULT_FALLBACK_WALL_DISTANCE_M
}

impl FallbackThresholds {
    /// Both thresholds lie in [0, 1] and no higher than the primary tier's (a fallback that is
    /// stricter than the first pass could never pick anything the first pass refused).
    pub fn validate(&self, primary: &SelectionConfig) -> Result<(), SelectionError> {
        check_setting(
            (0.0..=primary.min_quality).contains(&self.min_quality),
            "fallback.min_quality",
            "must lie in [0, min_quality]",
        )?;
        check_setting(
            (0.0..=primary.min_collision_score).contains(&self.min_collision_score),
            "fallback.min_collision_score",
            "must lie in [0, min_collision_score]",
        )?;
        check_setting(
            (0.0..0.2).contains(&self.min_contact_wall_distance_m),
            "fallback.min_contact_wall_distance_m",
            "must lie in [0, 0.2) m",
        )?;
        check_setting(
            self.approaches_per_configuration
                .is_none_or(|n| (1..=N_APPROACHES).contains(&n)),
            "fallback.approaches_per_configuration",
            "must lie in 1..=18",
        )?;
        Ok(())
    }

    /// `primary` with these thresholds and no further fallback: the second pass's settings.
    pub fn applied_to(&self, primary: &SelectionConfig) -> SelectionConfig {
        SelectionConfig {
            min_quality: self.min_quality,
            min_collision_score: self.min_collision_score,
            min_contact_wall_distance_m: self
                .min_contact_wall_distance_m
                .max(primary.min_contact_wall_distance_m),
            approaches_per_configuration: self
                .approaches_per_configuration
                .unwrap_or(primary.approaches_per_configuration),
            fallback: None,
            ..primary.clone()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_fallback_stricter_than_the_primary_tier_is_refused() {
        let primary = SelectionConfig::default();
        let ok = FallbackThresholds {
            min_quality: 0.2,
            min_collision_score: 0.5,
            min_contact_wall_distance_m: 0.0,
            approaches_per_configuration: Some(18),
        };
        assert!(ok.validate(&primary).is_ok());
        for bad in [
            (0.6, 0.2, 0.01, None),
            (0.2, 0.7, 0.01, None),
            (-0.1, 0.2, 0.01, None),
            (0.2, f32::NAN, 0.01, None),
            (0.2, 0.2, -0.01, None),
            (0.2, 0.2, 0.5, None),
            (0.2, 0.2, 0.01, Some(0)),
            (0.2, 0.2, 0.01, Some(19)),
        ] {
            let f = FallbackThresholds {
                min_quality: bad.0,
                min_collision_score: bad.1,
                min_contact_wall_distance_m: bad.2,
                approaches_per_configuration: bad.3,
            };
            assert!(f.validate(&primary).is_err(), "{bad:?} accepted");
        }
    }

    #[test]
    fn the_second_pass_takes_only_the_score_thresholds() {
        let primary = SelectionConfig {
            top_k: 3,
            fallback: Some(FallbackThresholds {
                min_quality: 0.25,
                min_collision_score: 0.2,
                min_contact_wall_distance_m: 0.01,
                approaches_per_configuration: None,
            }),
            ..SelectionConfig::default()
        };
        let second = primary.fallback.unwrap().applied_to(&primary);
        assert_eq!(
            second.approaches_per_configuration,
            primary.approaches_per_configuration
        );
        let wider = FallbackThresholds {
            approaches_per_configuration: Some(18),
            ..primary.fallback.unwrap()
        };
        assert_eq!(wider.applied_to(&primary).approaches_per_configuration, 18);
        assert_eq!(second.min_quality, 0.25);
        assert_eq!(second.min_collision_score, 0.2);
        assert_eq!(second.min_contact_wall_distance_m, 0.01);
        assert_eq!(second.fallback, None);
        assert_eq!(second.top_k, 3);
        assert_eq!(second.clearance, primary.clearance);
    }
}
