//! One detector's own selection settings: the protocol's `[selection]` values a detector row
//! replaces for itself only ([`SelectionOverrides`]).
//!
//! The same record is written in the detector list (flattened into a `[[detector]]` table) and
//! stored once per detector in `run.json`, so a new override is added here and nowhere else: the
//! list reads it, [`SelectionOverrides::apply`] runs it, and a resumed run compares it.
use psgrasp_selection::{
    FailedPickMemory, FallbackThresholds, PickOrder, SelectionConfig, SurfaceCheck,
};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// The protocol's selection settings one detector replaces; `None` keeps the protocol's value.
/// Every row with an override is labelled as such, and its values are chosen on generated
/// scenes (`--generate-scenes`, seeds never reported), never on the test set.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SelectionOverrides {
    /// `[selection] min_quality` (the paper's protocol executes q > 0.5). For a model whose
    /// quality head is calibrated differently.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub min_quality: Option<f32>,
    /// `[selection.fallback]`: looser score thresholds tried when nothing passes the paper's.
    #[serde(
        default,
        rename = "selection_fallback",
        skip_serializing_if = "Option::is_none"
    )]
    pub fallback: Option<FallbackThresholds>,
    /// `[selection.surface_check]`: the fingers against the depth frame's height map.
    #[serde(
        default,
        rename = "selection_surface_check",
        skip_serializing_if = "Option::is_none"
    )]
    pub surface_check: Option<SurfaceCheck>,
    /// `[selection] pick_order` (the paper visits configurations by quality).
    #[serde(
        default,
        rename = "selection_pick_order",
        skip_serializing_if = "Option::is_none"
    )]
    pub pick_order: Option<PickOrder>,
    /// `[selection] min_contact_wall_distance_m`: contacts closer than this to a side wall's
    /// inner face (or beyond it) are refused in the primary tier too (the paper's protocol
    /// admits contacts up to `bin_contact_tolerance_m` beyond it).
    #[serde(
        default,
        rename = "selection_min_contact_wall_distance_m",
        skip_serializing_if = "Option::is_none"
    )]
    pub min_contact_wall_distance_m: Option<f32>,
    /// `[selection.failed_pick_memory]`: picks near a failed pick go last for a few picks.
    #[serde(
        default,
        rename = "selection_failed_pick_memory",
        skip_serializing_if = "Option::is_none"
    )]
    pub failed_pick_memory: Option<FailedPickMemory>,
}

impl SelectionOverrides {
    /// Whether nothing is overridden (the detector runs the protocol's selection).
    pub fn is_empty(&self) -> bool {
        *self == Self::default()
    }

    /// Writes the overridden values into `selection`.
    pub fn apply(&self, selection: &mut SelectionConfig) {
        if let Some(q) = self.min_quality {
            selection.min_quality = q;
        }
        if let Some(f) = self.fallback {
            selection.fallback = Some(f);
        }
        if let Some(c) = self.surface_check {
            selection.surface_check = c;
        }
        if let Some(o) = self.pick_order {
            selection.pick_order = o;
        }
        if let Some(d) = self.min_contact_wall_distance_m {
            selection.min_contact_wall_distance_m = d;
        }
        if let Some(m) = self.failed_pick_memory {
            selection.failed_pick_memory = m;
        }
    }
}

/// `run.json`'s overrides as written before they were one record per detector (format version
/// 1 files up to session 43): one map per setting, by detector name. Read, never written.
#[derive(Debug, Clone, Default, Deserialize)]
pub(crate) struct LegacyOverrideMaps {
    #[serde(default)]
    min_quality: BTreeMap<String, f32>,
    #[serde(default)]
    selection_fallback: BTreeMap<String, FallbackThresholds>,
    #[serde(default)]
    selection_surface_check: BTreeMap<String, SurfaceCheck>,
    #[serde(default)]
    selection_pick_order: BTreeMap<String, PickOrder>,
    #[serde(default)]
    selection_min_contact_wall_distance_m: BTreeMap<String, f32>,
}

impl LegacyOverrideMaps {
    /// Folds the maps into `into`, one record per detector; a setting a record already has
    /// (written in the new form) is kept.
    pub(crate) fn fold_into(self, into: &mut BTreeMap<String, SelectionOverrides>) {
        fn fold<T: Copy>(
            map: BTreeMap<String, T>,
            into: &mut BTreeMap<String, SelectionOverrides>,
            field: fn(&mut SelectionOverrides) -> &mut Option<T>,
        ) {
            for (name, value) in map {
                field(into.entry(name).or_default()).get_or_insert(value);
            }
        }
        fold(self.min_quality, into, |o| &mut o.min_quality);
        fold(self.selection_fallback, into, |o| &mut o.fallback);
        fold(self.selection_surface_check, into, |o| &mut o.surface_check);
        fold(self.selection_pick_order, into, |o| &mut o.pick_order);
        fold(self.selection_min_contact_wall_distance_m, into, |o| {
            &mut o.min_contact_wall_distance_m
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn overrides_apply_only_what_they_set() {
        let base = SelectionConfig::default();
        let mut selection = base.clone();
        SelectionOverrides::default().apply(&mut selection);
        assert_eq!(selection, base);
        let walls = SelectionOverrides {
            min_contact_wall_distance_m: Some(0.004),
            pick_order: Some(PickOrder::ConfidentFirst),
            ..Default::default()
        };
        assert!(!walls.is_empty());
        walls.apply(&mut selection);
        assert_eq!(selection.min_contact_wall_distance_m, 0.004);
        assert_eq!(selection.pick_order, PickOrder::ConfidentFirst);
        assert_eq!(selection.min_quality, base.min_quality);
        assert_eq!(selection.fallback, base.fallback);
    }

    #[test]
    fn legacy_maps_fold_into_one_record_per_detector() {
        let legacy: LegacyOverrideMaps = serde_json::from_str(
            r#"{"min_quality": {"a": 0.3},
                "selection_pick_order": {"a": "confident-first", "b": "confident-first"},
                "selection_min_contact_wall_distance_m": {"b": 0.004}}"#,
        )
        .unwrap();
        let mut records = BTreeMap::new();
        legacy.fold_into(&mut records);
        assert_eq!(records.len(), 2);
        assert_eq!(records["a"].min_quality, Some(0.3));
        assert_eq!(records["a"].pick_order, Some(PickOrder::ConfidentFirst));
        assert_eq!(records["a"].min_contact_wall_distance_m, None);
        assert_eq!(records["b"].min_contact_wall_distance_m, Some(0.004));
        assert_eq!(records["b"].min_quality, None);
        // The record serialises under the detector list's key names.
        let json = serde_json::to_value(records["b"]).unwrap();
        assert_eq!(
            json,
            serde_json::json!({"selection_pick_order": "confident-first",
                               "selection_min_contact_wall_distance_m": 0.004f32})
        );
    }
}
