//! ACRONYM's physics check of grasp labels ([`check_labels_in_physics`]): the labeler's
//! antipodal test says that two contacts lie in each other's friction cones; the paper's labels
//! come from ACRONYM, which also closes the hand on the object in a physics engine and keeps only
//! the grasps that hold it. Labels that fail are dropped (ACRONYM's successful grasps only), so
//! that a model learns the grasps that hold rather than every antipodal pair (on the new benchmark
//! the oracle refuses about 25 labels per executed pick in challenging scenes for failing this
//! check: docs/evaluation.md), or kept with quality 0 ([`FailedLabels::ZeroQuality`]): the contact
//! and its geometry stay in the labels, the quality says that the grasp does not hold.
use crate::labels::{GraspLabel, LabelStats};
use psgrasp_geometry::{GripperModel, N_APPROACHES};
use psgrasp_sim::execute::{verify_grasp_in_isolation, ExecutionConfig, GraspCommand};
use psgrasp_sim::{MeshLibrary, Scene};
use serde::{Deserialize, Deserializer, Serialize};
use std::collections::HashMap;

/// What becomes of a label that fails the physics check.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FailedLabels {
    /// Not stored: the labels are ACRONYM's successful grasps only.
    #[default]
    Drop,
    /// Stored with antipodal quality 0: the label grid keeps its contact and gripper space, the
    /// baseline, width and approach targets keep their geometry, and the quality target says
    /// that it does not hold (the learned quality becomes "antipodal and holds").
    ZeroQuality,
}

impl FailedLabels {
    fn is_drop(&self) -> bool {
        *self == Self::Drop
    }
}

/// Which labels must also hold their object in ACRONYM's physics check, and how it is run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LabelPhysicsCheck {
    /// Labels narrower than this (m) are checked (0 = none: the labeler's labels as they are;
    /// above the hand's opening: all). The oracle's `physics_check_max_width_m` alike.
    pub max_width_m: f32,
    /// The hand opens to the label's width plus twice this before the approach, at most its
    /// maximum opening (the evaluation protocol's `selection.clearance.opening_clearance_m`).
    pub opening_clearance_m: f32,
    /// The approach starts this far before the grasp pose (selection's pre-grasp distance).
    pub pregrasp_distance_m: f32,
    /// The simulated hand and physics (the evaluation protocol's `[execution]`); keys given
    /// replace those of this check's default (which closes after an approach contact, as the
    /// benchmark's protocol does), the others keep it.
    #[serde(deserialize_with = "execution_over_check_default")]
    pub execution: ExecutionConfig,
    /// What becomes of the labels that fail (stored only when not the default, so that the
    /// manifests of datasets made before the setting existed are unchanged).
    #[serde(skip_serializing_if = "FailedLabels::is_drop")]
    pub failed_labels: FailedLabels,
}

/// Deserializes an `[execution]` table over [`LabelPhysicsCheck::default`]'s execution rather
/// than over [`ExecutionConfig::default`] (a partial table must not switch settings back).
fn execution_over_check_default<'de, D: Deserializer<'de>>(
    deserializer: D,
) -> Result<ExecutionConfig, D::Error> {
    use serde::de::Error;
    fn merge(base: &mut serde_json::Value, given: serde_json::Value) {
        match (base, given) {
            (serde_json::Value::Object(base), serde_json::Value::Object(given)) => {
                for (key, value) in given {
                    match base.get_mut(&key) {
                        Some(slot) => merge(slot, value),
                        None => {
                            base.insert(key, value);
                        }
                    }
                }
            }
            (slot, given) => *slot = given,
        }
    }
    let given = serde_json::Value::deserialize(deserializer)?;
    let mut merged =
        serde_json::to_value(LabelPhysicsCheck::default().execution).map_err(D::Error::custom)?;
    merge(&mut merged, given);
    serde_json::from_value(merged).map_err(D::Error::custom)
}

impl Default for LabelPhysicsCheck {
    fn default() -> Self {
        Self {
            max_width_m: 0.0,
            opening_clearance_m: 0.04,
            pregrasp_distance_m: 0.08,
            execution: ExecutionConfig {
                close_after_approach_contact: true,
                ..ExecutionConfig::default()
            },
            failed_labels: FailedLabels::Drop,
        }
    }
}

impl LabelPhysicsCheck {
    /// Whether no label is checked (the default; such configurations serialize without it).
    pub fn is_off(&self) -> bool {
        self.max_width_m <= 0.0
    }

    /// The command the check executes for `label`: its most top-down collision-free approach
    /// (the one a top-down pick would use; the label's mirror gets the same hand pose).
    pub fn command(&self, label: &GraspLabel, gripper: &GripperModel) -> GraspCommand {
        let approach = (0..N_APPROACHES)
            .filter(|&i| label.collision_free[i])
            .min_by(|&i, &j| {
                let z = |k: usize| label.grasp(k).approach.z;
                z(i).total_cmp(&z(j))
            })
            .unwrap_or(0);
        GraspCommand {
            workspace_from_gripper: label.grasp(approach).workspace_from_gripper(),
            opening_m: psgrasp_geometry::commanded_opening_m(
                label.width,
                2.0 * self.opening_clearance_m,
                gripper.max_opening_m,
            ),
            pregrasp_distance_m: self.pregrasp_distance_m,
        }
    }
}

/// Keeps the labels that hold their object in ACRONYM's check (those narrower than
/// [`LabelPhysicsCheck::max_width_m`]; wider ones pass unchecked); the others are dropped or
/// stored with quality 0 ([`LabelPhysicsCheck::failed_labels`]). Updates `stats` (the counts of
/// what is stored, and [`LabelStats::physics_checked`] / `physics_failed`, counted per physical
/// grasp: a label and its mirror are one check). A check that cannot run (an unusable command
/// or object) counts as a failure. Deterministic.
pub fn check_labels_in_physics(
    scene: &Scene,
    meshes: &MeshLibrary,
    gripper: &GripperModel,
    labels: Vec<GraspLabel>,
    check: &LabelPhysicsCheck,
    stats: &mut LabelStats,
) -> Vec<GraspLabel> {
    if check.is_off() {
        return labels;
    }
    let mut results: HashMap<GraspKey, bool> = HashMap::new();
    let mut holds = |label: &GraspLabel| {
        if label.width >= check.max_width_m {
            return true;
        }
        *results.entry(GraspKey::of(label)).or_insert_with(|| {
            let command = check.command(label, gripper);
            let holds = verify_grasp_in_isolation(
                scene,
                meshes,
                gripper,
                &command,
                label.object as usize,
                &check.execution,
            )
            .is_ok_and(|outcome| outcome.is_success());
            stats.physics_checked += 1;
            stats.physics_failed += usize::from(!holds);
            holds
        })
    };
    let kept: Vec<GraspLabel> = match check.failed_labels {
        FailedLabels::Drop => labels.into_iter().filter(|label| holds(label)).collect(),
        FailedLabels::ZeroQuality => labels
            .into_iter()
            .map(|mut label| {
                if !holds(&label) {
                    label.quality = 0.0;
                }
                label
            })
            .collect(),
    };
    stats.count_stored(&kept);
    kept
}

/// One physical grasp, whichever contact a label starts from: the object, the grasp centre and
/// width to 0.1 mm and the baseline's line to 1e-4.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
struct GraspKey([i32; 8]);

impl GraspKey {
    fn of(label: &GraspLabel) -> Self {
        let centre = label.contact + label.baseline * (0.5 * label.width);
        let b = label.baseline;
        // The line's direction with a fixed sign: the first clearly non-zero component positive.
        let sign = [b.x, b.y, b.z]
            .into_iter()
            .find(|v| v.abs() > 1e-3)
            .map_or(1.0, f32::signum);
        let mm10 = |v: f32| (v * 1e4).round() as i32;
        Self([
            label.object as i32,
            mm10(centre.x),
            mm10(centre.y),
            mm10(centre.z),
            mm10(label.width),
            mm10(sign * b.x),
            mm10(sign * b.y),
            mm10(sign * b.z),
        ])
    }
}
