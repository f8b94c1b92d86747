//! Why the objects a round leaves have no grasp: each remaining object's
//! [`Graspability`] on the final scene (the labeller's tests on candidates over its whole surface,
//! every approach pose split by what blocks it), recorded with the scene, and the report's tables
//! of the verdicts by level, object kind and start zone.
//!
//! It reads the final scene after the round and changes nothing the round does: attempts,
//! outcomes and every rate are what they were before it existed.
use crate::protocol::{ProtocolConfig, RemainingObject};
use psgrasp_datagen::{
    graspability, visible_pixels_per_object, GraspabilityConfig, GraspabilityVerdict,
};
use psgrasp_geometry::CameraModel;
use psgrasp_sim::{Scene, WallZone};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::fmt::Write as _;

/// First contacts sampled on each object left (about 0.05 s of one core per object; the
/// labeller samples 300 per visible object, plus refinement).
pub const CANDIDATES_PER_OBJECT: u32 = 128;

/// The seed of every diagnosis (each object draws from its own stream of it).
pub const DIAGNOSIS_SEED: u64 = 0x1ef7_0be5;

/// The objects of `scene`, a round's final scene seen by `camera`, with their start zones
/// (from `start`, [`RemainingObject::with_start_zones`] of the first scene) and their
/// graspability under `cfg`'s hand and labeller settings. The diagnosis takes one fixed seed, so
/// the same final scene gets the same verdicts whatever the run seed (a round copied from
/// another seed, [`crate::seed_copies`], stays equal to the round run under its own).
pub fn remaining_objects(
    scene: &Scene,
    camera: &CameraModel,
    start: &[(RemainingObject, WallZone)],
    cfg: &ProtocolConfig,
) -> Vec<RemainingObject> {
    let n = scene.object_count();
    if n == 0 {
        return Vec::new();
    }
    let pixels = visible_pixels_per_object(&scene.render(camera).segmentation, n);
    let check = GraspabilityConfig {
        candidates_per_object: CANDIDATES_PER_OBJECT,
    };
    let mut left: Vec<RemainingObject> = (0..n)
        .filter_map(|i| {
            let (mut object, _) = RemainingObject::of_object(scene, i)?;
            object.graspability = Some(graspability(
                scene,
                &cfg.scenes.cell.gripper,
                &cfg.scenes.labels,
                i,
                pixels[i],
                &check,
                DIAGNOSIS_SEED,
            ));
            Some(object)
        })
        .collect();
    RemainingObject::match_start_zones(&mut left, start);
    left
}

/// The verdicts of the objects left in one report cell.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct LeftoverVerdicts {
    /// Objects left that carry a diagnosis.
    pub diagnosed: usize,
    /// Of those, by verdict (snake-case name).
    pub by_verdict: BTreeMap<GraspabilityVerdict, usize>,
    /// Of those, by `kind / start zone` (meshes as `mesh (library)`) and verdict.
    pub by_kind_and_start: BTreeMap<String, BTreeMap<GraspabilityVerdict, usize>>,
}

impl LeftoverVerdicts {
    /// Counts `object` if it carries a diagnosis.
    pub fn add(&mut self, object: &RemainingObject) {
        let Some(g) = &object.graspability else {
            return;
        };
        self.diagnosed += 1;
        *self.by_verdict.entry(g.verdict).or_default() += 1;
        let zone = match object.start_zone {
            Some(WallZone::Interior) => "interior",
            Some(WallZone::Wall) => "by a wall",
            Some(WallZone::Corner) => "in a corner",
            None => "start unknown",
        };
        // Meshes by their library (`ycb`, `random_urdfs`): the object names' prefix.
        let kind = match object.name.split_once('/') {
            Some((library, _)) if object.kind == "mesh" => format!("mesh ({library})"),
            _ => object.kind.clone(),
        };
        *self
            .by_kind_and_start
            .entry(format!("{kind} / {zone}"))
            .or_default()
            .entry(g.verdict)
            .or_default() += 1;
    }

    fn count(&self, v: GraspabilityVerdict) -> usize {
        self.by_verdict.get(&v).copied().unwrap_or(0)
    }
}

/// The verdicts in table order.
const VERDICTS: [GraspabilityVerdict; 8] = [
    GraspabilityVerdict::Graspable,
    GraspabilityVerdict::Hidden,
    GraspabilityVerdict::NoGraspFitsHand,
    GraspabilityVerdict::Floor,
    GraspabilityVerdict::Wall,
    GraspabilityVerdict::OtherObjects,
    GraspabilityVerdict::ItsOwnShape,
    GraspabilityVerdict::Several,
];

/// The report's section: one row per (detector label, level name, objects left, verdicts)
/// with a diagnosis, then the same rows by object kind and start zone. Empty when no cell has
/// one.
pub fn markdown(rows: &[(&str, &str, usize, &LeftoverVerdicts)]) -> String {
    let mut s = String::new();
    if rows.iter().all(|r| r.3.diagnosed == 0) {
        return s;
    }
    let _ = writeln!(
        s,
        "\n## Why the objects left have no grasp\n\nEach object left at a round's end, in the \
         final scene: first contacts sampled over its whole surface, the labeller's width and \
         antipodal-quality tests, then each of the 18 approach poses tested part by part for \
         what blocks it. *graspable*: some pose is free (a detector's miss, or the oracle's \
         physics check or selection refused it); *hidden*: too few visible pixels for the \
         labeller; *no grasp fits the hand*: no antipodal pair within the opening; otherwise \
         what blocks the most poses alone: the floor, a side wall, other objects, the object \
         itself, or several things at once.\n"
    );
    let header: Vec<&str> = VERDICTS.iter().map(|v| v.name()).collect();
    let _ = writeln!(
        s,
        "| Detector | Level | left (diagnosed) | {} |\n|---|---|---|{}",
        header.join(" | "),
        "---|".repeat(VERDICTS.len())
    );
    for (detector, level, left, v) in rows.iter().filter(|r| r.3.diagnosed > 0) {
        let counts: Vec<String> = VERDICTS.iter().map(|&k| v.count(k).to_string()).collect();
        let _ = writeln!(
            s,
            "| {detector} | {level} | {left} ({}) | {} |",
            v.diagnosed,
            counts.join(" | ")
        );
    }
    let _ = writeln!(
        s,
        "\nThe same objects by kind and where they started: left, then verdicts.\n\n\
         | Detector | Level | by kind / start zone |\n|---|---|---|"
    );
    for (detector, level, _, v) in rows.iter().filter(|r| r.3.diagnosed > 0) {
        let groups: Vec<String> = v
            .by_kind_and_start
            .iter()
            .map(|(group, verdicts)| {
                let n: usize = verdicts.values().sum();
                let parts: Vec<String> = verdicts
                    .iter()
                    .map(|(k, c)| format!("{} {c}", k.name()))
                    .collect();
                format!("{group}: {n} ({})", parts.join(", "))
            })
            .collect();
        let _ = writeln!(s, "| {detector} | {level} | {} |", groups.join("; "));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use psgrasp_test_support::scenes::boxes_on_floor;

    #[test]
    fn objects_left_carry_their_verdicts_and_the_report_counts_them() {
        // A free cube in the middle, a cube in the −x/−y corner and a plate wider than the
        // opening, as a round's final scene; the start had the same objects.
        let scene = boxes_on_floor(&[
            ([0.02, 0.02, 0.02], [0.0, 0.0]),
            ([0.02, 0.02, 0.02], [-0.279, -0.179]),
            ([0.06, 0.06, 0.008], [0.15, 0.05]),
        ]);
        let cfg = ProtocolConfig::default();
        let camera = psgrasp_sim::default_camera(scene.bin(), cfg.scenes.intrinsics);
        let start = RemainingObject::with_start_zones(&scene);
        let left = remaining_objects(&scene, &camera, &start, &cfg);
        let verdicts: Vec<_> = left
            .iter()
            .map(|o| o.graspability.unwrap().verdict)
            .collect();
        use GraspabilityVerdict as V;
        assert_eq!(verdicts, [V::Graspable, V::Wall, V::Floor]);
        assert!(left
            .iter()
            .all(|o| o.graspability.unwrap().visible_pixels > 100));
        assert_eq!(
            left[1].start_zone,
            Some(WallZone::Corner),
            "the start zone is kept"
        );
        // The same final scene gets the same diagnosis.
        assert_eq!(left, remaining_objects(&scene, &camera, &start, &cfg));

        let mut cell = LeftoverVerdicts::default();
        left.iter().for_each(|o| cell.add(o));
        let mut urdf = left[0].clone();
        (urdf.name, urdf.kind) = ("random_urdfs/254".into(), "mesh".into());
        cell.add(&urdf);
        let mut undiagnosed = left[0].clone();
        undiagnosed.graspability = None;
        cell.add(&undiagnosed);
        assert_eq!(cell.diagnosed, 4);
        assert_eq!(cell.count(V::Wall), 1);
        assert_eq!(
            cell.by_kind_and_start.get("box / in a corner").unwrap()[&V::Wall],
            1
        );
        let md = markdown(&[("Oracle", "Easy", 5, &cell)]);
        assert!(
            md.contains("| Oracle | Easy | 5 (4) | 2 | 0 | 0 | 1 | 1 | 0 | 0 | 0 |"),
            "{md}"
        );
        assert!(md.contains("box / in a corner: 1 (wall 1)"), "{md}");
        assert!(
            md.contains("mesh (random_urdfs) / interior: 1 (graspable 1)"),
            "{md}"
        );
        // Cells without a diagnosis (older records) leave the section out.
        let empty = LeftoverVerdicts::default();
        assert!(markdown(&[("Oracle", "Easy", 4, &empty)]).is_empty());
    }
}
