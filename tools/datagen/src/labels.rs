//! Dense grasp labels, ACRONYM-style, for a simulated scene.
//!
//! Pipeline per scene: sample first contacts `c` on each object's *visible* surface (object-aware:
//! the same number of samples per visible object, through the rendered segmentation), sample
//! baselines `b` in the friction cone around the inward normal, find the second contact where the
//! far finger closing along `−b` from the maximum opening first touches the object, keep pairs
//! with antipodal quality above the threshold and width within the gripper's range, then test the
//! open gripper (palm + two fingers, opened `width + 2·approach_clearance`) at each of the 18
//! approach vectors against the whole scene (every object, the grasped one included, and the
//! bin). A grasp configuration is stored when at least one approach is collision-free.
pub use crate::approach_path::ApproachPathCheck;
pub use crate::robustness::RobustQuality;
use nalgebra::{Point3, Vector3};
use psgrasp_geometry::{
    antipodal_quality, at_first_passing_lift, ContactGrasp, GraspConfiguration, GripperModel,
    N_APPROACHES,
};
use psgrasp_sim::{HitTarget, Rendering, Scene, SEGMENT_OBJECT0};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// Tuning of the label generator.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct LabelConfig {
    /// First contacts sampled per object that the camera sees.
    pub contacts_per_object: usize,
    /// Share of those contacts drawn on the object's visible surface (camera rays through its
    /// pixels); the rest are drawn on its whole surface (random lines through its bounding sphere),
    /// which reaches the side faces a top-down view barely sees.
    pub visible_share: f32,
    /// Whole-surface contacts whose normal is within ~25° of vertical (|n_z| > 0.9) are kept
    /// with this probability: their baselines are near-vertical and the matching horizontal
    /// approaches rarely clear the bin floor, so sampling effort goes to side faces instead.
    pub steep_normal_keep_probability: f32,
    /// Refinement samples (one contact and one baseline each) per object that got a grasp in
    /// the exploration pass, drawn near its successful contacts.
    pub refine_samples_per_object: usize,
    /// Half-width of the square (in the tangent plane) refinement contacts are drawn from (m).
    pub refine_radius_m: f32,
    /// Baselines sampled per first contact.
    pub baselines_per_contact: usize,
    /// Half-angle of the cone around the inward normal that baselines are drawn from (degrees).
    pub friction_cone_half_angle_deg: f32,
    /// Smallest antipodal quality kept (the paper: 0.5).
    pub min_quality: f32,
    /// Widths must stay below the maximum opening minus this margin (m).
    pub width_margin_m: f32,
    /// Smallest width kept (m).
    pub min_width_m: f32,
    /// Gap on each side between a finger and its contact while the gripper approaches (m).
    pub approach_clearance_m: f32,
    /// Objects seen by fewer pixels than this get no contact samples.
    pub min_visible_pixels: usize,
    /// Reject an approach if another object (or the bin) intrudes the closing region.
    pub check_closing_region: bool,
    /// Also store each pair seen from its second contact (`c₂`, `−b`); its collision flags are the
    /// first one's reversed (same gripper poses, turned by π about the approach).
    pub store_symmetric: bool,
    /// An approach whose pose collides with the tool centre point at the contacts' midpoint (the
    /// paper's grasp frame) is tried again raised these distances back along the approach, in
    /// order (m): the contacts then meet the pads below their centre, as a real pad holds
    /// anywhere along its length. The approach is free if any lift is. Empty (the default, not
    /// written to manifests): the paper's frame only.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub tcp_lifts_m: Vec<f32>,
    /// Also test the open hand's straight descent from the pre-grasp pose
    /// ([`ApproachPathCheck`]): an approach whose descent meets anything is colliding. `None`
    /// (the default, not written to manifests): the grasp pose alone, as ACRONYM.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub approach_path: Option<ApproachPathCheck>,
    /// Store each label's quality blended by how often perturbed executions of it hold
    /// ([`RobustQuality`]). `None` (the default, not written to manifests): ACRONYM's antipodal
    /// quality of the exact pair.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub robust_quality: Option<RobustQuality>,
}

impl Default for LabelConfig {
    fn default() -> Self {
        Self {
            contacts_per_object: 300,
            visible_share: 0.3,
            steep_normal_keep_probability: 0.25,
            refine_samples_per_object: 700,
            refine_radius_m: 0.01,
            baselines_per_contact: 4,
            friction_cone_half_angle_deg: 40.0,
            min_quality: 0.5,
            width_margin_m: 0.008,
            min_width_m: 0.002,
            approach_clearance_m: 0.01,
            min_visible_pixels: 20,
            check_closing_region: true,
            store_symmetric: true,
            tcp_lifts_m: Vec::new(),
            approach_path: None,
            robust_quality: None,
        }
    }
}

impl LabelConfig {
    /// Checks the settings whose bad values would not fail on their own (the lifts of the tool
    /// centre point, `labels.tcp_lifts_m`; the descent test, `labels.approach_path`; the robust
    /// quality's perturbations, `labels.robust_quality`).
    pub fn validate(&self) -> Result<(), psgrasp_geometry::OutOfRange> {
        psgrasp_geometry::check_tcp_lifts(&self.tcp_lifts_m, "labels.tcp_lifts_m")?;
        self.approach_path
            .as_ref()
            .map_or(Ok(()), ApproachPathCheck::validate)?;
        self.robust_quality
            .as_ref()
            .map_or(Ok(()), RobustQuality::validate)
    }

    /// A small configuration for tests and previews (about a tenth of the work).
    pub fn quick() -> Self {
        Self {
            contacts_per_object: 40,
            baselines_per_contact: 2,
            refine_samples_per_object: 60,
            ..Self::default()
        }
    }
}

/// One labelled grasp configuration: a contact pair plus the collision flag of every approach.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GraspLabel {
    /// First contact `c` (workspace frame).
    pub contact: Point3<f32>,
    /// Unit baseline `b` from `c` to the second contact.
    pub baseline: Vector3<f32>,
    /// Outward unit surface normal at `c`.
    pub contact_normal: Vector3<f32>,
    /// Outward unit surface normal at the second contact.
    pub second_normal: Vector3<f32>,
    /// Distance between the contacts (m).
    pub width: f32,
    /// Antipodal quality `q`.
    pub quality: f32,
    /// `collision_free[i]`: the gripper at approach `a_i = approach_vectors(b)[i]` is free.
    pub collision_free: [bool; N_APPROACHES],
    /// Index of the grasped object in the scene.
    pub object: u32,
}

impl GraspLabel {
    /// Number of collision-free approaches (grasps) of this configuration.
    pub fn free_count(&self) -> usize {
        self.collision_free.iter().filter(|f| **f).count()
    }

    /// The second contact `c + w·b`.
    pub fn second_contact(&self) -> Point3<f32> {
        self.contact + self.baseline * self.width
    }

    /// The contact grasp at approach `i`.
    pub fn grasp(&self, i: usize) -> ContactGrasp {
        self.configuration().grasp(i)
    }

    /// As a [`GraspConfiguration`] with binary collision scores and `κ = 0`.
    pub fn configuration(&self) -> GraspConfiguration {
        GraspConfiguration {
            contact: self.contact,
            baseline: self.baseline,
            collision_scores: self.collision_free.map(|f| if f { 1.0 } else { 0.0 }),
            width: self.width,
            quality: self.quality,
            kappa: 0.0,
            kappa_floor: 0.0,
        }
    }

    /// The same pair seen from the second contact: (`c₂`, `−b`), flags reversed.
    pub fn mirrored(&self) -> GraspLabel {
        let mut flags = self.collision_free;
        flags.reverse();
        GraspLabel {
            contact: self.second_contact(),
            baseline: -self.baseline,
            contact_normal: self.second_normal,
            second_normal: self.contact_normal,
            width: self.width,
            quality: self.quality,
            collision_free: flags,
            object: self.object,
        }
    }
}

/// Counters of one labelling run.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct LabelStats {
    /// Objects that received contact samples (visible enough).
    pub visible_objects: usize,
    /// Objects with at least one stored grasp.
    pub graspable_objects: usize,
    /// Contact–baseline candidates sampled (exploration and refinement).
    pub candidates: usize,
    /// Candidates that passed the width and quality tests.
    pub antipodal_pairs: usize,
    /// Gripper poses tested for collision.
    pub poses_checked: usize,
    /// Gripper poses found collision-free.
    pub poses_free: usize,
    /// Gripper poses tested in the exploration pass alone (uniform contact sampling; the free
    /// share there is the unbiased rate of collision-free poses).
    pub exploration_poses_checked: usize,
    /// Collision-free poses found in the exploration pass.
    pub exploration_poses_free: usize,
    /// Poses rejected because the palm collides.
    pub palm_collisions: usize,
    /// Poses rejected because a finger collides.
    pub finger_collisions: usize,
    /// Poses rejected because something else sits between the fingers.
    pub closing_blocked: usize,
    /// Poses rejected because the hand's descent to them meets something
    /// ([`LabelConfig::approach_path`]; 0 when the test is off).
    #[serde(skip_serializing_if = "is_zero")]
    pub approach_path_blocked: usize,
    /// Grasp configurations stored (incl. mirrored ones).
    pub configurations: usize,
    /// Collision-free grasps stored (configurations × free approaches).
    pub grasps: usize,
    /// Stored grasps per object index.
    pub grasps_per_object: Vec<usize>,
    /// Physical grasps run through ACRONYM's physics check (a label and its mirror are one;
    /// [`crate::physics_check`]; 0 when the check is off).
    #[serde(skip_serializing_if = "is_zero")]
    pub physics_checked: usize,
    /// Of those, the ones that did not hold their object (their labels are dropped, or stored
    /// with quality 0: [`crate::FailedLabels`]).
    #[serde(skip_serializing_if = "is_zero")]
    pub physics_failed: usize,
}

/// `skip_serializing_if` for counters that only some datasets have.
pub(crate) fn is_zero(n: &usize) -> bool {
    *n == 0
}

impl LabelStats {
    /// Sets the counts of what is stored — configurations, collision-free grasps, grasps per
    /// object (its length, the scene's objects, is kept) and graspable objects — from `labels`.
    pub fn count_stored(&mut self, labels: &[GraspLabel]) {
        self.configurations = labels.len();
        self.grasps = labels.iter().map(GraspLabel::free_count).sum();
        self.grasps_per_object.iter_mut().for_each(|n| *n = 0);
        for label in labels {
            if let Some(n) = self.grasps_per_object.get_mut(label.object as usize) {
                *n += label.free_count();
            }
        }
        self.graspable_objects = self.grasps_per_object.iter().filter(|n| **n > 0).count();
    }

    /// Share of tested gripper poses that were collision-free.
    pub fn free_pose_share(&self) -> f64 {
        if self.poses_checked == 0 {
            0.0
        } else {
            self.poses_free as f64 / self.poses_checked as f64
        }
    }
}

/// The labels of one scene.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LabelSet {
    /// Stored configurations (each with at least one collision-free approach).
    pub labels: Vec<GraspLabel>,
    /// Counters.
    pub stats: LabelStats,
}

/// Why a single gripper pose is not collision-free.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PoseCheck {
    /// Free.
    Free,
    /// The palm intersects an object or the bin.
    PalmCollision,
    /// A finger intersects an object or the bin.
    FingerCollision,
    /// Another object or the bin intrudes the region between the fingers.
    ClosingRegionBlocked,
    /// The pose is free but the open hand's descent to it meets an object or the bin
    /// ([`LabelConfig::approach_path`]).
    ApproachPathBlocked,
}

/// Tests the gripper at `grasp` (opened `width + 2·clearance`) against the scene: at the
/// contacts' midpoint, then at each of `config.tcp_lifts_m`; free if any of them is, otherwise
/// what blocks the unlifted pose.
pub fn check_pose(
    scene: &Scene,
    gripper: &GripperModel,
    grasp: &ContactGrasp,
    object: usize,
    config: &LabelConfig,
) -> PoseCheck {
    let free = at_first_passing_lift(&config.tcp_lifts_m, |lift| {
        match check_pose_lifted(scene, gripper, grasp, object, config, lift) {
            PoseCheck::Free => Ok(()),
            blocked => Err(blocked),
        }
    });
    free.map_or_else(|blocked| blocked, |()| PoseCheck::Free)
}

/// [`check_pose`] at one lift of the tool centre point (m).
pub fn check_pose_lifted(
    scene: &Scene,
    gripper: &GripperModel,
    grasp: &ContactGrasp,
    object: usize,
    config: &LabelConfig,
    lift_m: f32,
) -> PoseCheck {
    let pose = grasp.workspace_from_gripper_lifted(lift_m);
    let opening = psgrasp_geometry::commanded_opening_m(
        grasp.width,
        2.0 * config.approach_clearance_m,
        gripper.max_opening_m,
    );
    for (k, b) in gripper.boxes(&pose, opening).iter().enumerate() {
        if scene.box_collides(b, None) {
            return if k == 0 {
                PoseCheck::PalmCollision
            } else {
                PoseCheck::FingerCollision
            };
        }
    }
    if config.check_closing_region {
        let region = gripper.closing_region(grasp.width).placed(&pose);
        if scene.box_collides(&region, Some(object)) {
            return PoseCheck::ClosingRegionBlocked;
        }
    }
    if let Some(path) = &config.approach_path {
        if path.blocked(scene, gripper, &pose, grasp.width) {
            return PoseCheck::ApproachPathBlocked;
        }
    }
    PoseCheck::Free
}

/// A unit vector drawn uniformly from the cone of half-angle `half_angle` around unit `axis`.
pub(crate) fn sample_cone(
    rng: &mut impl Rng,
    axis: &Vector3<f32>,
    half_angle: f32,
) -> Vector3<f32> {
    let cos_max = half_angle.cos();
    let cos_t: f32 = rng.random_range(cos_max..=1.0);
    let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
    let phi: f32 = rng.random_range(0.0..std::f32::consts::TAU);
    let helper = if axis.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let u = axis.cross(&helper).normalize();
    let v = axis.cross(&u);
    (axis * cos_t + u * (sin_t * phi.cos()) + v * (sin_t * phi.sin())).normalize()
}

/// A candidate pair before the collision tests.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Pair {
    pub(crate) contact: Point3<f32>,
    pub(crate) baseline: Vector3<f32>,
    pub(crate) n1: Vector3<f32>,
    pub(crate) n2: Vector3<f32>,
    pub(crate) width: f32,
    pub(crate) quality: f32,
}

impl Pair {
    /// The pair as a label of `object` with every approach still marked colliding.
    pub(crate) fn label(&self, object: usize) -> GraspLabel {
        GraspLabel {
            contact: self.contact,
            baseline: self.baseline,
            contact_normal: self.n1,
            second_normal: self.n2,
            width: self.width,
            quality: self.quality,
            collision_free: [false; N_APPROACHES],
            object: object as u32,
        }
    }
}

/// A point of `object`'s surface and its outward normal where a random line through its
/// bounding sphere (`centre`, `radius`) first meets it, cast against this object only; `None`
/// when the line misses. Reaches every face, the ones the camera barely sees included.
pub(crate) fn surface_point_on_random_line(
    scene: &Scene,
    object: usize,
    centre: &Vector3<f32>,
    radius: f32,
    rng: &mut impl Rng,
) -> Option<(Point3<f32>, Vector3<f32>)> {
    let d = sample_cone(rng, &Vector3::z(), std::f32::consts::PI);
    let helper = if d.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let e1 = d.cross(&helper).normalize();
    let e2 = d.cross(&e1);
    let r = radius * rng.random::<f32>().sqrt();
    let phi: f32 = rng.random_range(0.0..std::f32::consts::TAU);
    let origin = Point3::from(centre - d * (2.0 * radius) + (e1 * phi.cos() + e2 * phi.sin()) * r);
    match scene.cast_ray_object(object, &origin, &d, 4.0 * radius, true) {
        Some((toi, n)) if toi > 0.0 => Some((origin + d * toi, n)),
        _ => None,
    }
}

/// Finds the second contact for first contact `c` (outward normal `n1`) and baseline `b` on
/// `object`, or `None` if the pair is unusable.
pub(crate) fn antipodal_pair(
    scene: &Scene,
    object: usize,
    c: &Point3<f32>,
    n1: &Vector3<f32>,
    b: &Vector3<f32>,
    max_width: f32,
    config: &LabelConfig,
) -> Option<Pair> {
    // The far finger closes along −b from the maximum opening: the first surface it meets.
    let reach = max_width + 1e-3;
    let origin = c + b * reach;
    let (toi, n2) = scene.cast_ray_object(object, &origin, &-b, reach, true)?;
    if toi <= 1e-6 {
        return None; // the object extends beyond the maximum opening
    }
    let c2 = origin - b * toi;
    let width = (c2 - c).dot(b);
    if !(width >= config.min_width_m && width <= max_width) {
        return None;
    }
    // The near finger must reach c from outside: nothing of the object just behind c along −b.
    let eps = 2e-4;
    if scene
        .cast_ray_object(
            object,
            &(c - b * eps),
            &-b,
            config.approach_clearance_m,
            true,
        )
        .is_some_and(|(t, _)| t > 1e-6 || scene.object_contains_point(object, &(c - b * eps)))
    {
        return None;
    }
    let quality = antipodal_quality(b, n1, &n2);
    if quality <= config.min_quality {
        return None;
    }
    Some(Pair {
        contact: *c,
        baseline: *b,
        n1: *n1,
        n2,
        width,
        quality,
    })
}

/// Shared state of one labelling run.
struct Labeller<'a> {
    scene: &'a Scene,
    gripper: &'a GripperModel,
    config: &'a LabelConfig,
    max_width: f32,
}

impl Labeller<'_> {
    /// Tests one contact/baseline candidate: antipodal pair, then all approaches.
    fn evaluate(
        &self,
        object: usize,
        point: &Point3<f32>,
        normal: &Vector3<f32>,
        b: &Vector3<f32>,
        stats: &mut LabelStats,
    ) -> Option<GraspLabel> {
        stats.candidates += 1;
        let pair = antipodal_pair(
            self.scene,
            object,
            point,
            normal,
            b,
            self.max_width,
            self.config,
        )?;
        stats.antipodal_pairs += 1;
        let mut label = pair.label(object);
        for i in 0..N_APPROACHES {
            stats.poses_checked += 1;
            match check_pose(
                self.scene,
                self.gripper,
                &label.grasp(i),
                object,
                self.config,
            ) {
                PoseCheck::Free => {
                    label.collision_free[i] = true;
                    stats.poses_free += 1;
                }
                PoseCheck::PalmCollision => stats.palm_collisions += 1,
                PoseCheck::FingerCollision => stats.finger_collisions += 1,
                PoseCheck::ClosingRegionBlocked => stats.closing_blocked += 1,
                PoseCheck::ApproachPathBlocked => stats.approach_path_blocked += 1,
            }
        }
        (label.free_count() > 0).then_some(label)
    }

    /// Stores `label` (and its mirror), its quality first made robust when configured; the
    /// perturbations draw from `robust_rng`, a stream of their own, so that the labels sampled
    /// are the same with and without them.
    fn push(&self, labels: &mut Vec<GraspLabel>, mut label: GraspLabel, robust_rng: &mut impl Rng) {
        if let Some(robust) = &self.config.robust_quality {
            let min = self.config.min_quality;
            let share = robust.success_share(self.scene, self.gripper, &label, min, robust_rng);
            label.quality = robust.blend(label.quality, min, share);
        }
        labels.push(label);
        if self.config.store_symmetric {
            labels.push(label.mirrored());
        }
    }
}

/// Stream of the robust quality's perturbations ([`Labeller::push`]), apart from the sampling's.
const ROBUST_QUALITY_STREAM: u64 = 0x526f_6275_7374;

/// Generates the labels of `scene` as seen by `camera` (its `rendering` must come from
/// [`Scene::render`] with the same camera). Deterministic for `seed`.
pub fn generate_labels(
    scene: &Scene,
    camera: &psgrasp_geometry::CameraModel,
    rendering: &Rendering,
    gripper: &GripperModel,
    config: &LabelConfig,
    seed: u64,
) -> LabelSet {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut robust_rng = ChaCha8Rng::seed_from_u64(seed ^ ROBUST_QUALITY_STREAM);
    let n_obj = scene.object_count();
    let k = camera.intrinsics;
    let mut pixels: Vec<Vec<u32>> = vec![Vec::new(); n_obj];
    for (i, &s) in rendering.segmentation.iter().enumerate() {
        if s >= SEGMENT_OBJECT0 {
            let o = (s - SEGMENT_OBJECT0) as usize;
            if o < n_obj {
                pixels[o].push(i as u32);
            }
        }
    }
    let max_width = gripper.max_opening_m - config.width_margin_m;
    let half_angle = config
        .friction_cone_half_angle_deg
        .clamp(0.0, 89.0)
        .to_radians();
    let eye = camera.eye();
    let mut stats = LabelStats {
        grasps_per_object: vec![0; n_obj],
        ..Default::default()
    };
    let mut labels = Vec::new();
    let ctx = Labeller {
        scene,
        gripper,
        config,
        max_width,
    };
    for (object, pix) in pixels.iter().enumerate() {
        if pix.len() < config.min_visible_pixels.max(1) {
            continue;
        }
        stats.visible_objects += 1;
        let centre = scene.objects()[object]
            .workspace_from_object
            .translation
            .vector;
        let radius = scene.object_bounding_radius(object).unwrap_or(0.1);
        let n_visible = (config.visible_share.clamp(0.0, 1.0) * config.contacts_per_object as f32)
            .round() as usize;
        for sample in 0..config.contacts_per_object {
            let hit = if sample < n_visible {
                let p = pix[rng.random_range(0..pix.len())];
                let (u, v) = ((p % k.width) as f32, (p / k.width) as f32);
                let (u, v) = (
                    u + rng.random_range(-0.5f32..0.5),
                    v + rng.random_range(-0.5f32..0.5),
                );
                let dir = camera.workspace_from_camera.rotation * k.ray_direction(u, v);
                match scene.cast_ray(&eye, &dir, 20.0) {
                    Some(hit) if hit.target == HitTarget::Object(object) => (hit.point, hit.normal),
                    _ => continue,
                }
            } else {
                match surface_point_on_random_line(scene, object, &centre, radius, &mut rng) {
                    Some((point, n)) => {
                        if n.z.abs() > 0.9
                            && rng.random::<f32>() >= config.steep_normal_keep_probability
                        {
                            continue;
                        }
                        (point, n)
                    }
                    None => continue,
                }
            };
            let (point, normal) = hit;
            for _ in 0..config.baselines_per_contact {
                let b = sample_cone(&mut rng, &-normal, half_angle);
                if let Some(label) = ctx.evaluate(object, &point, &normal, &b, &mut stats) {
                    ctx.push(&mut labels, label, &mut robust_rng);
                }
            }
        }
    }

    // Refinement: more samples around the contacts that produced collision-free grasps (the
    // graspable regions), spread evenly over the graspable objects.
    let explored = labels.len();
    stats.exploration_poses_checked = stats.poses_checked;
    stats.exploration_poses_free = stats.poses_free;
    let mut seeds: Vec<Vec<(Point3<f32>, Vector3<f32>)>> = vec![Vec::new(); n_obj];
    for l in &labels[..explored] {
        seeds[l.object as usize].push((l.contact, l.contact_normal));
    }
    for (object, seeds) in seeds.iter().enumerate() {
        if seeds.is_empty() {
            continue;
        }
        for _ in 0..config.refine_samples_per_object {
            let (c, n) = seeds[rng.random_range(0..seeds.len())];
            let helper = if n.x.abs() < 0.9 {
                Vector3::x()
            } else {
                Vector3::y()
            };
            let t1 = n.cross(&helper).normalize();
            let t2 = n.cross(&t1);
            let sigma = config.refine_radius_m;
            let (du, dv): (f32, f32) = (rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0));
            let origin = c + n * 0.02 + (t1 * du + t2 * dv) * sigma;
            let Some((toi, normal)) =
                scene.cast_ray_object(object, &origin, &-n, 0.04 + sigma, true)
            else {
                continue;
            };
            if toi <= 0.0 {
                continue;
            }
            let point = origin - n * toi;
            let b = sample_cone(&mut rng, &-normal, half_angle);
            if let Some(label) = ctx.evaluate(object, &point, &normal, &b, &mut stats) {
                ctx.push(&mut labels, label, &mut robust_rng);
            }
        }
    }
    stats.count_stored(&labels);
    LabelSet { labels, stats }
}
