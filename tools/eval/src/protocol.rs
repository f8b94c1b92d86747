//! The paper's clearing protocol on one test scene ([`run_scene`]).
//!
//! The scene is the dataset's test scene for the same level, run seed and index
//! (`psgrasp datagen --difficulty <level> --seed <S>` scene `i`): seed
//! `derive_seed(S, i)`, test objects only, the level's object count, physics and camera. With
//! [`ProtocolConfig::settle_first_scene`] it first rests in the execution physics. Each
//! round:
//!
//! 1. render the depth image of the current scene (dex noise on `challenging`; frame 0 uses the
//!    dataset's noise seed);
//! 2. **detection** (timed): the pipeline's perception chain ([`Perception::detect_with`]:
//!    depth-scale correction and fusion → the detector's [`InferenceBackend::infer`], ranked and
//!    cut as in the pipeline → selection) — configurations by antipodal quality, for each the first 8 of 18
//!    approaches by collision score, the first with `q > 0.5`, `σ > 0.5`, a free grasp pose,
//!    approach path and pre-grasp pose against the observed scene (and, with
//!    [`ProtocolConfig::skip_colliding_pregrasps`], a pre-grasp pose free in the simulated scene);
//! 3. execute the pick in physics ([`crate::execute_grasp`]); the scene afterwards is the next
//!    round's scene.
//!
//! A scene ends when the bin is empty, no grasp is found, after
//! [`ProtocolConfig::max_consecutive_failures`] failed attempts in a row, or at the attempt cap.
use crate::oracle::{label_holds_in_isolation, oracle_configurations, OracleConfig};
use crate::EvalError;
use nalgebra::Point3;
use psgrasp_datagen::{derive_seed, Difficulty, GenerationConfig, Graspability};
use psgrasp_inference::InferenceBackend;
use psgrasp_perception::{CellConfig, DetectionTimings, Perception, Proposer};
use psgrasp_selection::{FailedPicks, PickSpot, RejectionCounts};
use psgrasp_sim::execute::{
    execute_grasp, pregrasp_collides, settle_scene, ApproachTouch, ExecutionConfig, GraspCommand,
    GraspOutcome, HandPart,
};
use psgrasp_sim::{
    add_dex_noise, default_camera, generate_scene, MeshLibrary, ObjectLibrary, Scene, WallZone,
    WallZones,
};
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// Everything that shapes an evaluation apart from the detector, level, seed and scene index.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct ProtocolConfig {
    /// Scene generation (camera, noise, physics) and the cell — workspace, bin, gripper,
    /// fusion, depth-scale correction, selection and how the steps are joined — exactly as for
    /// the dataset and the pipeline: their tables sit at the top level (`[gripper]`,
    /// `[selection]`, `[depth_scale]`, …). `labels` is used by the oracle only; the detector's
    /// backend comes from the detector list, not from `[inference]`.
    #[serde(flatten)]
    pub scenes: GenerationConfig,
    /// Grasp execution in physics.
    pub execution: ExecutionConfig,
    /// The paper's "executable" grasp: selection also tests each pick's open hand at the
    /// pre-grasp pose against the simulated scene (the check [`execute_grasp`] starts with) and
    /// skips a colliding one for the next approach or configuration, instead of executing it as
    /// a failed attempt (`pregrasp_collision`). Off by default: a perception-only pipeline cannot
    /// look into the true scene.
    pub skip_colliding_pregrasps: bool,
    /// Let the first scene of a round rest in the execution physics before its first frame, as
    /// the scene of every later attempt has ([`settle_scene`]): scene generation settles piles
    /// with softer contacts, and a generated pile shifts under the first attempt's hand while the
    /// execution world pushes its overlaps apart. The paper generates and executes in one
    /// simulator. Objects that leave the bin while settling count as lost. Off by default
    /// (Table I's runs before 2026-12-06 were made without it).
    pub settle_first_scene: bool,
    /// A scene ends after this many failed attempts in a row (the paper: 3).
    pub max_consecutive_failures: u32,
    /// A scene ends after this many attempts in any case.
    pub max_attempts_per_scene: u32,
    /// The oracle's labels checked in physics as ACRONYM checks the paper's labels.
    pub oracle: OracleConfig,
}

impl Default for ProtocolConfig {
    fn default() -> Self {
        Self {
            scenes: GenerationConfig::default(),
            execution: ExecutionConfig::default(),
            skip_colliding_pregrasps: false,
            settle_first_scene: false,
            max_consecutive_failures: 3,
            max_attempts_per_scene: 100,
            oracle: OracleConfig::default(),
        }
    }
}

impl ProtocolConfig {
    /// The cell the detectors run in (the pipeline's perception chain and its settings).
    pub fn cell(&self) -> &CellConfig {
        &self.scenes.cell
    }

    /// Checks the settings this crate owns, the cell's and the execution settings.
    pub fn validate(&self) -> Result<(), EvalError> {
        if self.max_consecutive_failures == 0 {
            return Err(EvalError::InvalidConfig {
                field: "max_consecutive_failures",
                reason: "must be at least 1",
            });
        }
        if self.max_attempts_per_scene == 0 {
            return Err(EvalError::InvalidConfig {
                field: "max_attempts_per_scene",
                reason: "must be at least 1",
            });
        }
        let w = self.oracle.physics_check_max_width_m;
        if !(w.is_finite() && w >= 0.0) {
            return Err(EvalError::InvalidConfig {
                field: "oracle.physics_check_max_width_m",
                reason: "must be a width >= 0 m",
            });
        }
        self.scenes
            .labels
            .validate()
            .map_err(|e| EvalError::InvalidConfig {
                field: e.field,
                reason: e.reason,
            })?;
        self.cell().validate()?;
        Ok(self.execution.validate()?)
    }
}

/// Why a scene ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SceneEnd {
    /// No object is left in the bin.
    Cleared,
    /// The detector and selection found no executable grasp.
    NoGrasp,
    /// Too many failed attempts in a row.
    ConsecutiveFailures,
    /// The attempt cap was reached.
    AttemptLimit,
}

/// One executed grasp attempt (a line of the records file).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AttemptRecord {
    /// Attempt number within the scene, from 0.
    pub attempt: u32,
    /// Objects in the bin before the attempt.
    pub objects_before: usize,
    /// Grasp configurations the detector returned.
    pub configurations: usize,
    /// Antipodal quality of the executed pick.
    pub quality: f32,
    /// Collision score of its approach.
    pub collision_score: f32,
    /// Concentration κ of its baseline distribution (0 where the detector has none: the
    /// oracle, the analytic and VGN-style baselines; absent in records before 2026-12-04).
    #[serde(default)]
    pub kappa: Option<f32>,
    /// Index of its approach (0..18).
    pub approach_index: usize,
    /// Where the pick was: TCP, baseline and approach in the workspace frame (failure analysis;
    /// absent in records before 2026-12-06).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pose: Option<PickPose>,
    /// Share of the pads' closing region under the frame's measured surface
    /// ([`psgrasp_selection::SelectedGrasp::pad_fill`]; absent without the surface check).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pad_fill: Option<f32>,
    /// Contact-to-contact width, metres.
    pub width_m: f32,
    /// Commanded opening, metres.
    pub opening_m: f32,
    /// How it ended.
    pub outcome: GraspOutcome,
    /// Objects lifted together (2+ is a double grasp).
    pub lifted: usize,
    /// Objects that left the bin during the attempt.
    pub lost: usize,
    /// Finger opening at the end of the hold, metres.
    pub final_opening_m: f32,
    /// Whether a touch stopped the approach short of the grasp pose (with
    /// `close_after_approach_contact` the attempt went on from there).
    #[serde(default)]
    pub approach_contact: bool,
    /// What stopped the approach (failure analysis; `None`: it reached the grasp pose).
    #[serde(default)]
    pub approach_touch: Option<TouchRecord>,
    /// The object the pick aimed at (failure analysis).
    #[serde(default)]
    pub target: Option<PickTarget>,
    /// Approaches selection refused on this frame because their pre-grasp pose collides in the
    /// simulated scene ([`ProtocolConfig::skip_colliding_pregrasps`]; 0 when off).
    #[serde(default)]
    pub pregrasps_skipped: usize,
    /// Oracle labels refused on this frame because they did not hold their object in the
    /// physics check ([`OracleConfig::physics_check_max_width_m`]; 0 when off).
    #[serde(default)]
    pub labels_failed_physics: usize,
    /// The pick came from selection's fallback tier (`[selection.fallback]`: nothing passed the
    /// primary score thresholds on this frame).
    #[serde(default)]
    pub fallback: bool,
    /// Picks of the frame handed out last because they lie near a recently failed pick
    /// (`[selection.failed_pick_memory]`; 0 without it, and then not written).
    #[serde(default, skip_serializing_if = "is_zero_count")]
    pub deferred_near_failure: usize,
    /// The depth scale the correction found on this frame (`None`: correction off, or nothing
    /// to go by); applied when it is off by at least `depth_scale.min_correction`.
    #[serde(default)]
    pub depth_scale: Option<f32>,
    /// Depth rendering, milliseconds (not part of detection).
    pub render_ms: f64,
    /// Fusion of the normal grid, milliseconds.
    pub fusion_ms: f64,
    /// The detector's `infer`, milliseconds.
    pub inference_ms: f64,
    /// Grasp selection, milliseconds.
    pub selection_ms: f64,
    /// Physics of the attempt, milliseconds.
    pub execution_ms: f64,
}

/// A pick's pose in the workspace frame, as recorded for failure analysis.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PickPose {
    /// Tool centre point, metres.
    pub tcp_m: [f32; 3],
    /// Unit baseline (the gripper's x axis).
    pub baseline: [f32; 3],
    /// Unit approach (the gripper's z axis).
    pub approach: [f32; 3],
}

impl From<PickSpot> for PickPose {
    fn from(spot: PickSpot) -> Self {
        Self {
            tcp_m: spot.tcp,
            baseline: spot.closing,
            approach: spot.approach,
        }
    }
}

/// What touched what when an approach stopped short of the grasp pose.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TouchRecord {
    /// The hand part in contact.
    pub part: HandPart,
    /// What it touched.
    pub touched: TouchedThing,
    /// Distance the palm was still short of the grasp pose, metres.
    pub short_of_grasp_m: f32,
}

/// What a stopped approach touched, relative to the pick.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TouchedThing {
    /// The object nearest to the pick's TCP (the one the grasp aims at).
    Target,
    /// Another object.
    OtherObject,
    /// The bin.
    Bin,
}

/// The object a pick aims at: the one whose surface is nearest to its TCP (failure analysis).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PickTarget {
    /// Its name in the object library.
    pub name: String,
    /// Its family (`box`, `sphere`, …).
    pub kind: String,
    /// Signed distance from the TCP to its surface, metres (negative: the TCP lies inside it,
    /// as it does between the contacts of a well-placed grasp).
    pub tcp_distance_m: f32,
    /// Its index in the scene before the attempt (not recorded).
    #[serde(skip)]
    pub(crate) index: usize,
}

impl PickTarget {
    /// The object of `scene` nearest to `tcp`; `None` for an empty scene.
    pub fn nearest(scene: &Scene, tcp: &Point3<f32>) -> Option<Self> {
        let (index, d) = (0..scene.object_count())
            .filter_map(|i| scene.object_signed_distance(i, tcp).map(|d| (i, d)))
            .min_by(|a, b| a.1.total_cmp(&b.1))?;
        let spec = &scene.objects()[index].spec;
        Some(Self {
            name: spec.name.clone(),
            kind: format!("{:?}", spec.kind).to_lowercase(),
            tcp_distance_m: d,
            index,
        })
    }
}

impl TouchRecord {
    /// Classifies `touch` against the pick's `target`.
    fn new(touch: &ApproachTouch, target: Option<&PickTarget>) -> Self {
        let touched = match touch.object {
            None => TouchedThing::Bin,
            Some(i) if target.is_some_and(|t| t.index == i) => TouchedThing::Target,
            Some(_) => TouchedThing::OtherObject,
        };
        Self {
            part: touch.part,
            touched,
            short_of_grasp_m: touch.short_of_grasp_m,
        }
    }
}

/// The totals of one scene (the closing line of a scene in the records file).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SceneSummary {
    /// Objects in the bin at the start.
    pub objects: usize,
    /// Executed attempts.
    pub attempts: u32,
    /// Successful attempts (= objects removed by grasping).
    pub successes: u32,
    /// Objects that left the bin by other means (knocked out).
    pub lost: usize,
    /// Objects still in the bin at the end.
    pub remaining: usize,
    /// Why the scene ended.
    pub end: SceneEnd,
    /// Frames detected (attempts plus a final frame without a grasp, if any).
    pub frames: u32,
    /// Total detection time (fusion + inference + selection), milliseconds.
    pub detection_ms: f64,
    /// Grasp configurations returned over all frames.
    pub configurations: usize,
    /// Wall time of the whole scene, milliseconds.
    pub scene_ms: f64,
    /// Why selection found nothing on the last frame (scenes ending in [`SceneEnd::NoGrasp`]).
    #[serde(default)]
    pub final_rejections: Option<RejectionCounts>,
    /// The objects left in the bin at the end (failure analysis).
    #[serde(default)]
    pub remaining_objects: Vec<RemainingObject>,
    /// Where the scene's objects lay relative to the side walls when the round began (absent
    /// in records written before 2026-12-04).
    #[serde(default)]
    pub start_wall_zones: Option<WallZones>,
    /// Set on a round recorded as a copy of the same round under this run seed (a detector that
    /// samples nothing on a noise-free stored scene: [`crate::seed_copies`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub copied_from_seed: Option<u64>,
}

/// An object left in the bin when a scene ended.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RemainingObject {
    /// Its name in the object library.
    pub name: String,
    /// Its family (`box`, `sphere`, …).
    pub kind: String,
    /// Size of its world-frame bounding box along x, y, z, metres.
    pub extent_m: [f32; 3],
    /// Centre of that box relative to the centre of the bin floor, metres.
    pub center_m: [f32; 3],
    /// Gap between that box and the nearest side wall, metres (negative: it overlaps a wall's
    /// plane, e.g. leaning on it).
    pub wall_gap_m: f32,
    /// Where it lay when the round began ([`RemainingObject::match_start_zones`]; absent in
    /// records written before 2026-12-04).
    #[serde(default)]
    pub start_zone: Option<WallZone>,
    /// Why it has no grasp in the final scene ([`crate::leftovers`]; absent in records written
    /// before 2026-12-05).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub graspability: Option<Graspability>,
}

impl RemainingObject {
    /// Every object of `scene`.
    pub fn of_scene(scene: &Scene) -> Vec<Self> {
        Self::with_start_zones(scene)
            .into_iter()
            .map(|(o, _)| o)
            .collect()
    }

    /// Every object of `scene` with its wall zone there (the round's start, for
    /// [`RemainingObject::match_start_zones`]).
    pub fn with_start_zones(scene: &Scene) -> Vec<(Self, WallZone)> {
        (0..scene.object_count())
            .filter_map(|i| Self::of_object(scene, i))
            .collect()
    }

    /// Object `i` of `scene` and its wall zone (`None` for an index that is not an object).
    pub fn of_object(scene: &Scene, i: usize) -> Option<(Self, WallZone)> {
        let c = scene.bin().floor_center;
        let (lo, hi) = scene.object_aabb(i)?;
        let [gap_x, gap_y] = scene.object_wall_gaps(i)?;
        let o = &scene.objects()[i];
        let object = Self {
            name: o.spec.name.clone(),
            kind: format!("{:?}", o.spec.kind).to_lowercase(),
            extent_m: (hi - lo).into(),
            center_m: [
                0.5 * (lo.x + hi.x) - c.x,
                0.5 * (lo.y + hi.y) - c.y,
                0.5 * (lo.z + hi.z) - c.z,
            ],
            wall_gap_m: gap_x.min(gap_y),
            start_zone: None,
            graspability: None,
        };
        Some((object, WallZone::of_gaps(gap_x, gap_y)))
    }

    /// Sets each object's `start_zone` from the round's start ([`Self::with_start_zones`] of its
    /// first scene): the unmatched object of the same name whose start lay nearest (objects keep
    /// their names; a name can repeat).
    pub fn match_start_zones(left: &mut [Self], start: &[(Self, WallZone)]) {
        let mut start: Vec<Option<&(Self, WallZone)>> = start.iter().map(Some).collect();
        for o in left.iter_mut() {
            let distance = |s: &Self| {
                let d: f32 = (0..3)
                    .map(|k| (s.center_m[k] - o.center_m[k]).powi(2))
                    .sum();
                d.sqrt()
            };
            let nearest = start
                .iter()
                .enumerate()
                .filter_map(|(i, s)| s.filter(|(s, _)| s.name == o.name).map(|s| (i, s)))
                .min_by(|a, b| distance(&a.1 .0).total_cmp(&distance(&b.1 .0)))
                .map(|(i, _)| i);
            if let Some(i) = nearest {
                o.start_zone = start[i].take().map(|(_, z)| *z);
            }
        }
    }
}

/// The result of [`run_scene`].
#[derive(Debug, Clone, PartialEq)]
pub struct SceneRun {
    /// Every executed attempt, in order.
    pub attempts: Vec<AttemptRecord>,
    /// The totals.
    pub summary: SceneSummary,
}

/// Seed of test scene `index` of a run (the dataset's `derive_seed(run_seed, index)`).
pub fn scene_seed(run_seed: u64, index: u64) -> u64 {
    derive_seed(run_seed, index)
}

/// What proposes the grasps of each round.
pub enum Detector<'a> {
    /// A perception backend on the fused normal grid (the pipeline's path).
    Backend(&'a mut dyn InferenceBackend),
    /// Ground truth instead of perception: the dataset's labeler
    /// ([`psgrasp_datagen::generate_labels`] with the protocol's `scenes.labels`) on the true
    /// scene, every label a configuration with quality `q` and collision scores 1 (free) or 0.
    /// An upper bound of what a perfect detector reaches under this protocol and physics.
    Oracle,
}

/// Runs the clearing protocol on test scene `index` of `level` for `run_seed` with `detector`.
/// `library`/`meshes` are the object source (the level picks its test objects from it).
/// Deterministic for the same inputs (wall times aside).
pub fn run_scene(
    level: Difficulty,
    run_seed: u64,
    index: u64,
    library: &ObjectLibrary,
    meshes: &MeshLibrary,
    detector: &mut dyn InferenceBackend,
    cfg: &ProtocolConfig,
) -> Result<SceneRun, EvalError> {
    run_scene_with(
        level,
        run_seed,
        index,
        library,
        meshes,
        Detector::Backend(detector),
        cfg,
    )
}

/// [`run_scene`] for any [`Detector`], the ground-truth oracle included.
pub fn run_scene_with(
    level: Difficulty,
    run_seed: u64,
    index: u64,
    library: &ObjectLibrary,
    meshes: &MeshLibrary,
    detector: Detector<'_>,
    cfg: &ProtocolConfig,
) -> Result<SceneRun, EvalError> {
    if level == Difficulty::Train {
        return Err(EvalError::InvalidConfig {
            field: "level",
            reason: "evaluation uses the test levels easy, medium and challenging",
        });
    }
    cfg.validate()?;
    let started = Instant::now();
    let seed = scene_seed(run_seed, index);
    let gen = &cfg.scenes;
    let recipe = gen.scene_recipe(level);
    let pool = library.select(Some(level.split()), level.simple_only());
    let (first, _) = generate_scene(derive_seed(seed, 1), &pool, &gen.cell.bin, meshes, &recipe)?;
    clear_scene(level, seed, first, meshes, detector, cfg, started)
}

/// Runs the clearing protocol on `first`, a scene of `level` (a stored test scene or one just
/// generated): `seed` ([`scene_seed`] of the run seed and scene index) seeds the depth noise and
/// the detector's sampling of every round.
pub fn clear_scene(
    level: Difficulty,
    seed: u64,
    first: Scene,
    meshes: &MeshLibrary,
    mut detector: Detector<'_>,
    cfg: &ProtocolConfig,
    started: Instant,
) -> Result<SceneRun, EvalError> {
    let gen = &cfg.scenes;
    let gripper = gen.cell.gripper;
    let camera = default_camera(first.bin(), gen.intrinsics);
    let objects = first.object_count();
    let (first, lost_settling) = if cfg.settle_first_scene {
        // As long as scene generation may take to settle a pile.
        let limit = cfg.execution.objects.max_time_s;
        let settled = settle_scene(&first, meshes, &cfg.execution, limit)?;
        let lost = settled.lost_objects.len();
        (Scene::with_meshes(settled.scene_after, meshes)?, lost)
    } else {
        (first, 0)
    };
    let start = RemainingObject::with_start_zones(&first);
    let start_wall_zones: WallZones = start.iter().map(|(_, zone)| *zone).collect();
    let mut scene = first;

    let oracle = matches!(detector, Detector::Oracle);
    let mut perception = match &mut detector {
        Detector::Backend(b) => Perception::with_backend(cfg.cell(), Box::new(&mut **b))?,
        Detector::Oracle => Perception::for_external_proposals(cfg.cell())?,
    };
    let mut attempts = Vec::new();
    // The cell's memory of failed picks: the robot knows whether a pick held.
    let mut failed_picks = FailedPicks::new(cfg.cell().selection.failed_pick_memory);
    let (mut successes, mut lost, mut failures_in_row) = (0u32, lost_settling, 0u32);
    let (mut frames, mut detection_ms, mut configurations) = (0u32, 0.0f64, 0usize);
    let mut final_rejections = None;
    let end = loop {
        if scene.object_count() == 0 {
            break SceneEnd::Cleared;
        }
        if attempts.len() as u32 >= cfg.max_attempts_per_scene {
            break SceneEnd::AttemptLimit;
        }
        let k = attempts.len() as u64;
        let t = Instant::now();
        // One ray cast per frame: the segmentation is what the oracle's labeler needs.
        let rendering = scene.render(&camera);
        let noisy = level.noisy().then(|| {
            let noise_seed = if k == 0 {
                derive_seed(seed, 2)
            } else {
                derive_seed(derive_seed(seed, 2), k)
            };
            add_dex_noise(&rendering.depth, noise_seed, &gen.noise)
        });
        let render_ms = ms(t);
        let depth = noisy.as_ref().unwrap_or(&rendering.depth);
        let detect_seed = derive_seed(derive_seed(seed, 4), k);
        // The detection is the pipeline's perception chain; only the oracle's proposals and the
        // paper's pre-grasp test in the simulated scene come from the simulation.
        let mut propose_oracle =
            || oracle_configurations(&scene, &camera, &rendering, cfg, detect_seed);
        let proposer = if oracle {
            Proposer::External(&mut propose_oracle)
        } else {
            Proposer::Backend
        };
        let mut skipped_in_simulation = 0usize;
        let mut failed_physics = 0usize;
        let check_width = cfg.oracle.physics_check_max_width_m;
        let detection = perception.detect_with(depth, &camera, detect_seed, proposer, |pick| {
            let command = grasp_command(pick);
            if oracle
                && pick.width < check_width
                && !label_holds_in_isolation(&scene, meshes, &gripper, &command, &cfg.execution)
            {
                failed_physics += 1;
                return false;
            }
            if !cfg.skip_colliding_pregrasps {
                return true;
            }
            let free = !pregrasp_collides(&scene, &gripper, &command, &cfg.execution);
            skipped_in_simulation += usize::from(!free);
            free
        })?;
        let DetectionTimings {
            fusion_ms,
            inference_ms,
            selection_ms,
        } = detection.timings;
        let configs = &detection.configurations;
        let mut picks = detection.selection;
        let deferred_near_failure = failed_picks.order(&mut picks.picks, |p| {
            PickSpot::of_pose(&p.workspace_from_gripper)
        });
        let scale = detection.depth_scale.and_then(|s| s.estimate);
        frames += 1;
        detection_ms += fusion_ms + inference_ms + selection_ms;
        configurations += configs.len();
        let Some(pick) = picks.picks.first() else {
            final_rejections = Some(picks.rejected);
            break SceneEnd::NoGrasp;
        };
        let t = Instant::now();
        let ex = execute_grasp(
            &scene,
            meshes,
            &gripper,
            &grasp_command(pick),
            &cfg.execution,
        )?;
        let execution_ms = ms(t);
        let r = &ex.report;
        let tcp = Point3::from(pick.workspace_from_gripper.translation.vector);
        let spot = PickSpot::of_pose(&pick.workspace_from_gripper);
        let target = PickTarget::nearest(&scene, &tcp);
        attempts.push(AttemptRecord {
            attempt: k as u32,
            objects_before: scene.object_count(),
            configurations: configs.len(),
            quality: pick.quality,
            collision_score: pick.collision_score,
            kappa: configs.get(pick.configuration_index).map(|c| c.kappa),
            approach_index: pick.approach_index,
            pose: Some(spot.into()),
            pad_fill: pick.pad_fill,
            width_m: pick.width,
            opening_m: pick.opening_m,
            outcome: r.outcome,
            lifted: r.lifted_objects.len(),
            lost: r.lost_objects.len(),
            final_opening_m: r.final_opening_m,
            approach_contact: r.approach_contact(),
            approach_touch: r
                .approach_touch
                .as_ref()
                .map(|t| TouchRecord::new(t, target.as_ref())),
            target,
            pregrasps_skipped: skipped_in_simulation,
            labels_failed_physics: failed_physics,
            fallback: picks.fallback,
            deferred_near_failure,
            depth_scale: scale.map(|s| s.scale),
            render_ms,
            fusion_ms,
            inference_ms,
            selection_ms,
            execution_ms,
        });
        lost += r.lost_objects.len();
        failed_picks.pick_done(spot, r.outcome.is_success());
        if r.outcome.is_success() {
            successes += 1;
            failures_in_row = 0;
        } else {
            failures_in_row += 1;
        }
        scene = Scene::with_meshes(ex.scene_after, meshes)?;
        if failures_in_row >= cfg.max_consecutive_failures {
            break SceneEnd::ConsecutiveFailures;
        }
    };
    let summary = SceneSummary {
        objects,
        attempts: attempts.len() as u32,
        successes,
        lost,
        remaining: scene.object_count(),
        end,
        frames,
        detection_ms,
        configurations,
        scene_ms: ms(started),
        final_rejections,
        remaining_objects: crate::leftovers::remaining_objects(&scene, &camera, &start, cfg),
        start_wall_zones: Some(start_wall_zones),
        copied_from_seed: None,
    };
    Ok(SceneRun { attempts, summary })
}

fn is_zero_count(n: &usize) -> bool {
    *n == 0
}

/// What the simulated hand executes for a selected pick.
fn grasp_command(pick: &psgrasp_selection::SelectedGrasp) -> GraspCommand {
    GraspCommand {
        workspace_from_gripper: pick.workspace_from_gripper,
        opening_m: pick.opening_m,
        pregrasp_distance_m: pick.pregrasp_distance_m,
    }
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}
