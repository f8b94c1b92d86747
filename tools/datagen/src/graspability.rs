//! Why one object of a scene has, or has no, collision-free grasp for the hand.
//!
//! The label generator's tests on candidate grasps sampled over the object's whole surface (first
//! contact on a random line through its bounding sphere, baseline in the friction cone, second
//! contact where the far finger closes, width and antipodal quality as for labels), then each of
//! the 18 approach poses checked part by part for *what* blocks it: the bin floor, a side wall,
//! another object, the object itself. `psgrasp eval` runs it on the objects a round leaves, so a
//! ceiling below 100 % can be explained object by object.
use crate::labels::{
    antipodal_pair, sample_cone, surface_point_on_random_line, GraspLabel, LabelConfig,
};
use psgrasp_geometry::{at_first_passing_lift, GripperModel, N_APPROACHES};
use psgrasp_sim::{HitTarget, Scene};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// What keeps an object without a collision-free grasp (or that it has one).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GraspabilityVerdict {
    /// At least one sampled grasp pose is collision-free: the labeller can label it.
    Graspable,
    /// Too few of its pixels are visible from the camera for the labeller to sample it (it lies
    /// under other objects); the counts say what would block it once uncovered.
    Hidden,
    /// No antipodal pair on it fits the hand's opening (too large in every direction sampled).
    NoGraspFitsHand,
    /// Most blocked poses are blocked by the bin floor alone (the fingers would go through it).
    Floor,
    /// Most blocked poses are blocked by a side wall alone.
    Wall,
    /// Most blocked poses are blocked by other objects alone.
    OtherObjects,
    /// Most blocked poses are blocked by the object itself alone (the palm or a finger on it).
    ItsOwnShape,
    /// Every blocked pose has more than one blocker.
    Several,
}

impl GraspabilityVerdict {
    /// Short name for reports.
    pub fn name(self) -> &'static str {
        match self {
            Self::Graspable => "graspable",
            Self::Hidden => "hidden",
            Self::NoGraspFitsHand => "no grasp fits the hand",
            Self::Floor => "floor",
            Self::Wall => "wall",
            Self::OtherObjects => "other objects",
            Self::ItsOwnShape => "its own shape",
            Self::Several => "several",
        }
    }
}

/// Approach poses that exactly one thing blocks, by that thing, and those with several.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct BlockedPoses {
    /// Blocked by the bin floor only.
    pub floor: u32,
    /// Blocked by one or more side walls only.
    pub wall: u32,
    /// Blocked by other objects only.
    pub other_objects: u32,
    /// Blocked by the object itself only.
    pub itself: u32,
    /// Blocked by more than one of these.
    pub several: u32,
}

/// The graspability of one object: candidate counts, blocked poses and the verdict.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Graspability {
    /// Its pixels in the camera's segmentation.
    pub visible_pixels: u32,
    /// Contact–baseline candidates sampled on its surface.
    pub candidates: u32,
    /// Candidates that pass the labeller's width and antipodal-quality tests.
    pub antipodal_pairs: u32,
    /// Approach poses tested (pairs × 18).
    pub poses: u32,
    /// Poses free of everything (the labeller's collision-free test).
    pub free: u32,
    /// The blocked poses by what blocks them.
    pub blocked: BlockedPoses,
    /// The summary.
    pub verdict: GraspabilityVerdict,
}

/// How hard [`graspability`] looks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct GraspabilityConfig {
    /// First contacts sampled on the object's surface (one baseline each).
    pub candidates_per_object: u32,
}

impl Default for GraspabilityConfig {
    fn default() -> Self {
        Self {
            candidates_per_object: 128,
        }
    }
}

/// What blocks one pose, as bits.
const FLOOR: u8 = 1;
const WALL: u8 = 2;
const OTHER: u8 = 4;
const ITSELF: u8 = 8;

/// Everything that blocks `label`'s approach `i` under the labeller's pose test
/// ([`crate::labels::check_pose`]): 0 if the pose is free at one of the labeller's lifts of the
/// tool centre point, otherwise what blocks the unlifted pose.
fn pose_blockers(
    scene: &Scene,
    gripper: &GripperModel,
    label: &GraspLabel,
    approach: usize,
    config: &LabelConfig,
) -> u8 {
    let free = at_first_passing_lift(&config.tcp_lifts_m, |lift| {
        match pose_blockers_lifted(scene, gripper, label, approach, config, lift) {
            0 => Ok(()),
            blockers => Err(blockers),
        }
    });
    free.map_or_else(|blockers| blockers, |()| 0)
}

/// What blocks `label`'s approach `i` with the tool centre point raised `lift_m`
/// ([`crate::labels::check_pose_lifted`]: hand opened `width + 2·clearance`, then the closing
/// region), as bits.
fn pose_blockers_lifted(
    scene: &Scene,
    gripper: &GripperModel,
    label: &GraspLabel,
    approach: usize,
    config: &LabelConfig,
    lift_m: f32,
) -> u8 {
    let grasp = label.grasp(approach);
    let pose = grasp.workspace_from_gripper_lifted(lift_m);
    let object = label.object as usize;
    let opening = psgrasp_geometry::commanded_opening_m(
        grasp.width,
        2.0 * config.approach_clearance_m,
        gripper.max_opening_m,
    );
    let mut blockers = 0u8;
    let mut add = |b: &psgrasp_geometry::OrientedBox, skip_self: bool| {
        let mut bin = false;
        for target in scene.box_colliders(b) {
            match target {
                HitTarget::Object(i) if i == object => {
                    if !skip_self {
                        blockers |= ITSELF;
                    }
                }
                HitTarget::Object(_) => blockers |= OTHER,
                HitTarget::Bin => bin = true,
            }
        }
        if bin {
            for part in scene.box_bin_parts(b) {
                blockers |= if part == 0 { FLOOR } else { WALL };
            }
        }
    };
    for b in gripper.boxes(&pose, opening).iter() {
        add(b, false);
    }
    if config.check_closing_region {
        add(&gripper.closing_region(grasp.width).placed(&pose), true);
    }
    blockers
}

/// The graspability of object `object` of `scene` for `gripper` under the labeller's tests
/// (`labels`), with `visible_pixels` from the camera's segmentation. Deterministic for `seed`.
pub fn graspability(
    scene: &Scene,
    gripper: &GripperModel,
    labels: &LabelConfig,
    object: usize,
    visible_pixels: u32,
    config: &GraspabilityConfig,
    seed: u64,
) -> Graspability {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(object as u64);
    let max_width = gripper.max_opening_m - labels.width_margin_m;
    let half_angle = labels
        .friction_cone_half_angle_deg
        .clamp(0.0, 89.0)
        .to_radians();
    let centre = scene.objects()[object]
        .workspace_from_object
        .translation
        .vector;
    let radius = scene.object_bounding_radius(object).unwrap_or(0.1);
    let mut out = Graspability {
        visible_pixels,
        candidates: 0,
        antipodal_pairs: 0,
        poses: 0,
        free: 0,
        blocked: BlockedPoses::default(),
        verdict: GraspabilityVerdict::Several,
    };
    for _ in 0..config.candidates_per_object {
        let Some((point, normal)) =
            surface_point_on_random_line(scene, object, &centre, radius, &mut rng)
        else {
            continue;
        };
        let b = sample_cone(&mut rng, &-normal, half_angle);
        out.candidates += 1;
        let Some(pair) = antipodal_pair(scene, object, &point, &normal, &b, max_width, labels)
        else {
            continue;
        };
        out.antipodal_pairs += 1;
        let label = pair.label(object);
        for approach in 0..N_APPROACHES {
            out.poses += 1;
            let blockers = pose_blockers(scene, gripper, &label, approach, labels);
            let counter = match blockers {
                0 => &mut out.free,
                FLOOR => &mut out.blocked.floor,
                WALL => &mut out.blocked.wall,
                OTHER => &mut out.blocked.other_objects,
                ITSELF => &mut out.blocked.itself,
                _ => &mut out.blocked.several,
            };
            *counter += 1;
        }
    }
    out.verdict = verdict(&out, labels.min_visible_pixels as u32);
    out
}

/// The verdict of the counts: hidden, then no pair, then graspable, then the single blocker
/// that blocks the most poses alone.
fn verdict(g: &Graspability, min_visible_pixels: u32) -> GraspabilityVerdict {
    use GraspabilityVerdict as V;
    if g.visible_pixels < min_visible_pixels.max(1) {
        return V::Hidden;
    }
    if g.antipodal_pairs == 0 {
        return V::NoGraspFitsHand;
    }
    if g.free > 0 {
        return V::Graspable;
    }
    let b = &g.blocked;
    [
        (b.floor, V::Floor),
        (b.wall, V::Wall),
        (b.other_objects, V::OtherObjects),
        (b.itself, V::ItsOwnShape),
    ]
    .into_iter()
    .filter(|(n, _)| *n > 0)
    .max_by_key(|(n, _)| *n)
    .map_or(V::Several, |(_, v)| v)
}

/// Pixels per object index in a segmentation image (objects at `SEGMENT_OBJECT0` and up).
pub fn visible_pixels_per_object(segmentation: &[u16], object_count: usize) -> Vec<u32> {
    let mut counts = vec![0u32; object_count];
    for &s in segmentation {
        if s >= psgrasp_sim::SEGMENT_OBJECT0 {
            if let Some(n) = counts.get_mut((s - psgrasp_sim::SEGMENT_OBJECT0) as usize) {
                *n += 1;
            }
        }
    }
    counts
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::labels::{check_pose, PoseCheck};
    use nalgebra::Vector3;

    fn counts(floor: u32, wall: u32, other: u32, itself: u32, several: u32) -> Graspability {
        Graspability {
            visible_pixels: 100,
            candidates: 10,
            antipodal_pairs: 5,
            poses: 90,
            free: 0,
            blocked: BlockedPoses {
                floor,
                wall,
                other_objects: other,
                itself,
                several,
            },
            verdict: GraspabilityVerdict::Several,
        }
    }

    #[test]
    fn the_verdict_names_the_blocker_that_blocks_most_poses_alone() {
        use GraspabilityVerdict as V;
        assert_eq!(verdict(&counts(3, 40, 7, 0, 40), 20), V::Wall);
        assert_eq!(verdict(&counts(30, 4, 7, 0, 49), 20), V::Floor);
        assert_eq!(verdict(&counts(0, 0, 0, 0, 90), 20), V::Several);
        let mut g = counts(3, 40, 7, 0, 39);
        g.free = 1;
        assert_eq!(verdict(&g, 20), V::Graspable);
        g.visible_pixels = 5;
        assert_eq!(verdict(&g, 20), V::Hidden);
        let mut g = counts(0, 0, 0, 0, 0);
        g.antipodal_pairs = 0;
        assert_eq!(verdict(&g, 20), V::NoGraspFitsHand);
    }

    #[test]
    fn the_blocker_split_agrees_with_the_labellers_pose_test() {
        // Boxes of several sizes, one in a corner, two touching: every pose the split calls
        // free is free for check_pose, and every blocked one is blocked there.
        let gripper = GripperModel::default();
        let config = LabelConfig::quick();
        let scene = psgrasp_test_support::scenes::boxes_on_floor(&[
            ([0.02, 0.02, 0.02], [0.0, 0.0]),
            ([0.02, 0.03, 0.015], [0.041, 0.0]),
            ([0.06, 0.06, 0.01], [0.15, 0.1]),
            ([0.02, 0.02, 0.03], [-0.279, -0.179]),
        ]);
        let max_width = gripper.max_opening_m - config.width_margin_m;
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let (mut free, mut blocked) = (0, 0);
        for object in 0..scene.object_count() {
            let centre = scene.objects()[object]
                .workspace_from_object
                .translation
                .vector;
            for _ in 0..40 {
                let d = sample_cone(&mut rng, &Vector3::z(), std::f32::consts::PI);
                let origin = nalgebra::Point3::from(centre - d * 0.3);
                let Some((toi, n)) = scene.cast_ray_object(object, &origin, &d, 0.6, true) else {
                    continue;
                };
                let b = sample_cone(&mut rng, &-n, 0.5);
                let Some(pair) = antipodal_pair(
                    &scene,
                    object,
                    &(origin + d * toi),
                    &n,
                    &b,
                    max_width,
                    &config,
                ) else {
                    continue;
                };
                let label = pair.label(object);
                for a in 0..N_APPROACHES {
                    let split = pose_blockers(&scene, &gripper, &label, a, &config);
                    let check = check_pose(&scene, &gripper, &label.grasp(a), object, &config);
                    assert_eq!(
                        split == 0,
                        check == PoseCheck::Free,
                        "object {object}, approach {a}"
                    );
                    if split == 0 {
                        free += 1;
                    } else {
                        blocked += 1;
                    }
                }
            }
        }
        assert!(free > 0 && blocked > 0, "free {free}, blocked {blocked}");
    }
}
