//! The shipped model's top-10 picks on the native runtime (the default) equal those of the ONNX
//! reference runtime on the same frames — within 1 mm and 1° — through the whole chain (fusion,
//! the learned backend, selection): synthetic bin frames as `psgrasp stress` sends them, and the
//! real RealSense frame. The reference is ONNX Runtime when built with `--features ort`, else
//! tract.
use psgrasp::sources::SyntheticSource;
use psgrasp_config::PipelineConfig;
use psgrasp_geometry::{CameraModel, DepthImage};
use psgrasp_inference::{BackendConfig, RuntimeKind};
use psgrasp_perception::Perception;
use psgrasp_selection::SelectedGrasp;
use std::path::PathBuf;

/// Picks compared per frame.
const TOP: usize = 10;
/// Largest position difference of a pick allowed between the runtimes.
const MAX_POSITION_MM: f32 = 1.0;
/// Largest orientation difference of a pick allowed between the runtimes.
const MAX_ANGLE_DEG: f32 = 1.0;

fn reference_runtime() -> RuntimeKind {
    if cfg!(feature = "ort") {
        RuntimeKind::Ort
    } else {
        RuntimeKind::Tract
    }
}

fn config(file: &str) -> PipelineConfig {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(file);
    PipelineConfig::load(&path).unwrap()
}

fn with_runtime(cfg: &PipelineConfig, runtime: RuntimeKind) -> PipelineConfig {
    let mut cfg = cfg.clone();
    let BackendConfig::Learned(learned) = &mut cfg.cell.inference else {
        panic!("the shipped configuration runs the learned backend");
    };
    learned.runtime = runtime;
    cfg
}

fn top_picks(
    cfg: &PipelineConfig,
    frames: &[(DepthImage, CameraModel)],
) -> Vec<Vec<SelectedGrasp>> {
    let mut chain = Perception::new(&cfg.cell).unwrap();
    frames
        .iter()
        .enumerate()
        .map(|(k, (depth, camera))| {
            let detection = chain.detect(depth, camera, k as u64).unwrap();
            detection.selection.picks.into_iter().take(TOP).collect()
        })
        .collect()
}

/// Compares the picks rank by rank; returns the largest differences (mm, degrees).
fn assert_same_picks(
    what: &str,
    native: &[SelectedGrasp],
    reference: &[SelectedGrasp],
) -> (f32, f32) {
    assert_eq!(
        native.len(),
        reference.len(),
        "{what}: {} native picks, {} reference picks",
        native.len(),
        reference.len()
    );
    let (mut worst_mm, mut worst_deg) = (0.0f32, 0.0f32);
    for (rank, (a, b)) in native.iter().zip(reference).enumerate() {
        let (pa, pb) = (a.workspace_from_gripper, b.workspace_from_gripper);
        let mm = (pa.translation.vector - pb.translation.vector).norm() * 1000.0;
        let deg = pa.rotation.angle_to(&pb.rotation).to_degrees();
        assert!(
            mm <= MAX_POSITION_MM && deg <= MAX_ANGLE_DEG,
            "{what}: pick {rank} differs by {mm:.3} mm and {deg:.3}° (native {pa:?}, reference {pb:?})"
        );
        worst_mm = worst_mm.max(mm);
        worst_deg = worst_deg.max(deg);
    }
    (worst_mm, worst_deg)
}

fn compare(what: &str, cfg: &PipelineConfig, frames: &[(DepthImage, CameraModel)]) {
    let native = top_picks(&with_runtime(cfg, RuntimeKind::Native), frames);
    let reference = top_picks(&with_runtime(cfg, reference_runtime()), frames);
    let mut compared = 0;
    for (k, (n, r)) in native.iter().zip(&reference).enumerate() {
        let (mm, deg) = assert_same_picks(&format!("{what} frame {k}"), n, r);
        compared += n.len();
        eprintln!(
            "{what} frame {k}: {} picks, worst {mm:.4} mm / {deg:.4}°",
            n.len()
        );
    }
    assert!(
        compared >= frames.len() * 3,
        "{what}: only {compared} picks over {} frames — too few to compare",
        frames.len()
    );
}

#[test]
fn native_runtime_picks_equal_the_reference_on_synthetic_bin_frames() {
    let cfg = config("config/default.toml");
    let BackendConfig::Learned(learned) = &cfg.cell.inference else {
        panic!("config/default.toml runs the learned backend");
    };
    assert_eq!(
        learned.runtime,
        RuntimeKind::Native,
        "native is the default runtime"
    );
    let mut source = SyntheticSource::new(&cfg);
    let camera = cfg.camera_model();
    let per_scene = cfg.camera.synthetic.frames_per_scene;
    // Four different bins, as the stress tool's synthetic source sends them.
    let frames: Vec<_> = (0..4)
        .map(|s| (source.render(s * per_scene).unwrap(), camera))
        .collect();
    compare("synthetic", &cfg, &frames);
}

#[test]
fn native_runtime_picks_equal_the_reference_on_the_real_frame() {
    let dir = PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../shared/real/graspnet-realsense-example"
    ));
    let input = psgrasp::detect::DetectInput {
        depth: dir.join("depth.png"),
        intrinsics: Some(dir.join("intrinsics.json")),
        pose: None,
        depth_unit_m: None,
    };
    let cfg = config("config/tabletop.toml");
    let native =
        psgrasp::detect::detect_file(&with_runtime(&cfg, RuntimeKind::Native), &input).unwrap();
    let reference =
        psgrasp::detect::detect_file(&with_runtime(&cfg, reference_runtime()), &input).unwrap();
    let n = &native.picks[..native.picks.len().min(TOP)];
    let r = &reference.picks[..reference.picks.len().min(TOP)];
    assert_eq!(n.len(), r.len(), "pick counts differ");
    assert!(n.len() >= 3, "only {} picks on the real frame", n.len());
    for (rank, (a, b)) in n.iter().zip(r).enumerate() {
        let pa = nalgebra::Vector3::from(a.position);
        let pb = nalgebra::Vector3::from(b.position);
        let mm = (pa - pb).norm() * 1000.0;
        let qa = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::from(
            nalgebra::Vector4::from(a.orientation_xyzw),
        ));
        let qb = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::from(
            nalgebra::Vector4::from(b.orientation_xyzw),
        ));
        let deg = qa.angle_to(&qb).to_degrees();
        assert!(
            mm <= MAX_POSITION_MM && deg <= MAX_ANGLE_DEG,
            "real frame: pick {rank} differs by {mm:.3} mm and {deg:.3}°"
        );
    }
}
