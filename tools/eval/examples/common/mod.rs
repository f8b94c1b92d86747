//! What the label diagnostics (`label_trials`, `narrow_trace`) share: the new benchmark's
//! protocol and test set, the labeler's grasps on a test scene, and a grasp command per label.
use psgrasp_datagen::labels::{generate_labels, GraspLabel};
use psgrasp_datagen::Difficulty;
use psgrasp_eval::{GraspCommand, ProtocolConfig, TestSet};
use psgrasp_sim::Scene;

/// The protocol of the new benchmark and the committed test set (meshes from the set-up cache).
pub fn benchmark() -> (ProtocolConfig, TestSet) {
    let text = std::fs::read_to_string("config/eval-protocol-franka-fingertip.toml")
        .expect("run from the repository root");
    let cfg: ProtocolConfig = toml::from_str(&text).expect("the protocol file parses");
    let mesh_dir =
        std::path::PathBuf::from(std::env::var("HOME").unwrap()).join(".cache/psgrasp/objects");
    let set = TestSet::open(std::path::Path::new("data/testset"), &mesh_dir)
        .expect("data/testset and its meshes (scripts/fetch_objects.sh)");
    (cfg, set)
}

/// A level named on the command line (`easy`, `medium`, `challenging`), or `default`.
pub fn level_arg(arg: Option<&String>, default: Difficulty) -> Difficulty {
    match arg.map(String::as_str) {
        Some("easy") => Difficulty::Easy,
        Some("medium") => Difficulty::Medium,
        Some("challenging") => Difficulty::Challenging,
        _ => default,
    }
}

/// Test scene `index` of `level` and the labeler's grasps on it.
pub fn labelled_scene(
    cfg: &ProtocolConfig,
    set: &TestSet,
    level: Difficulty,
    index: u64,
) -> (Scene, Vec<GraspLabel>) {
    let scene = set.scene(level, index).unwrap();
    let camera = psgrasp_sim::default_camera(scene.bin(), cfg.scenes.intrinsics);
    let rendering = scene.render(&camera);
    let gripper = cfg.scenes.cell.gripper;
    let labels = generate_labels(
        &scene,
        &camera,
        &rendering,
        &gripper,
        &cfg.scenes.labels,
        index,
    )
    .labels;
    (scene, labels)
}

/// (label, approach) of every collision-free approach of the labels `keep` accepts, and at
/// most `count` of them spread evenly over the list (labels come object by object).
pub fn spread_free_grasps(
    labels: &[GraspLabel],
    keep: impl Fn(&GraspLabel) -> bool,
    count: usize,
) -> Vec<(usize, usize)> {
    let free: Vec<(usize, usize)> = free_grasps(labels)
        .filter(|&(k, _)| keep(&labels[k]))
        .collect();
    spread(&free, count)
}

/// (label, approach) of every collision-free approach of `labels`.
pub fn free_grasps(labels: &[GraspLabel]) -> impl Iterator<Item = (usize, usize)> + '_ {
    labels.iter().enumerate().flat_map(|(k, l)| {
        (0..l.collision_free.len())
            .filter(|&a| l.collision_free[a])
            .map(move |a| (k, a))
    })
}

/// At most `count` of `items`, spread evenly over the list.
pub fn spread<T: Copy>(items: &[T], count: usize) -> Vec<T> {
    let n = count.min(items.len());
    (0..n).map(|j| items[j * items.len() / n]).collect()
}

/// The command that executes approach `approach` of `label` with the hand fully open, from the
/// protocol's pre-grasp distance.
pub fn label_command(cfg: &ProtocolConfig, label: &GraspLabel, approach: usize) -> GraspCommand {
    GraspCommand {
        workspace_from_gripper: label.grasp(approach).workspace_from_gripper(),
        opening_m: cfg.scenes.cell.gripper.max_opening_m,
        pregrasp_distance_m: cfg.cell().selection.clearance.pregrasp_distance_m,
    }
}
