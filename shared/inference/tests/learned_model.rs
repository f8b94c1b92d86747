//! The learned backend against a real exported model directory and its PyTorch reference file.
//!
//! The model directory is `tests/fixtures/tiny-model` (an untrained tiny network on a 16³ grid,
//! exported by `psgrasp_training` with `reference.safetensors`; regenerate it with
//! `tests/fixtures/make_tiny_model.py`), or `$PSGRASP_TEST_MODEL_DIR` when set (any model
//! directory with a reference file, e.g. a 64³ export).
//!
//! With the cargo feature `ort`, the ONNX Runtime tests need `ORT_DYLIB_PATH` (the
//! `libonnxruntime.so` of the Python `onnxruntime` wheel).
use psgrasp_fusion::NormalGrid;
use psgrasp_geometry::{GripperModel, Workspace, N_APPROACHES};
use psgrasp_inference::learned::card::sha256_hex;
use psgrasp_inference::learned::{
    decode, load_model_dir, sampling, ClassProbabilities, HeadOutputs, LearnedModel, ModelCard,
    ModelError, RuntimeKind,
};
use psgrasp_inference::{
    backend_for_workspace, backend_from_config, BackendConfig, InferenceBackend, InferenceError,
    LearnedBackend, LearnedConfig,
};
use std::path::{Path, PathBuf};

mod common;
use common::{assert_card_mismatches_are_refused, assert_close, Reference};

fn model_dir() -> PathBuf {
    std::env::var_os("PSGRASP_TEST_MODEL_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/tiny-model"))
}

fn card() -> ModelCard {
    ModelCard::read(&model_dir()).expect("fixture card")
}

fn workspace() -> Workspace {
    card().workspace()
}

/// The gripper the fixture was exported for: the default Franka hand.
fn gripper() -> GripperModel {
    GripperModel::default()
}

/// Learned-model views of the reference tensors.
trait LearnedReference {
    fn points(&self) -> Vec<[f32; 3]>;
    fn head(&self) -> HeadOutputs;
}

impl LearnedReference for Reference {
    fn points(&self) -> Vec<[f32; 3]> {
        self.get("points")
            .chunks_exact(3)
            .map(|p| [p[0], p[1], p[2]])
            .collect()
    }

    fn head(&self) -> HeadOutputs {
        HeadOutputs {
            baseline: self.get("baseline").to_vec(),
            kappa: self.get("kappa").to_vec(),
            width: self.get("width").to_vec(),
            quality_prior: self.get("quality_prior").to_vec(),
            collision_prior: self.get("collision_prior").to_vec(),
        }
    }
}

/// Checks one runtime against every reference tensor.
fn agreement(kind: RuntimeKind, ort_library: Option<&Path>) {
    let reference = Reference::load(&model_dir());
    let files = load_model_dir(&model_dir(), &workspace(), &gripper()).expect("model dir");
    let mut model = LearnedModel::new(&files, kind, ort_library, 1).expect("runtime");
    let card = model.card().clone();

    // U-Net on the reference grid: logits and every encoder level.
    let unet = model.run_unet(reference.get("normal_grid")).expect("unet");
    assert_eq!(unet.label_logits.shape(), reference.shape("label_logits"));
    assert_close(
        "label_logits",
        unet.label_logits.data(),
        reference.get("label_logits"),
    );
    assert_eq!(unet.features.len(), card.levels());
    for (l, t) in unet.features.iter().enumerate() {
        let name = format!("enc{l}");
        assert_eq!(t.shape(), reference.shape(&name));
        assert_close(&name, t.data(), reference.get(&name));
    }

    // Contact sampling reproduces the reference points (the first ≤ 256 of the rule).
    let ws = card.workspace();
    let mut probs = ClassProbabilities::default();
    probs
        .compute(unet.label_logits.data(), ws.voxel_count())
        .unwrap();
    let mut voxels = Vec::new();
    sampling::select_contact_voxels(
        &probs.contact,
        card.thresholds.contact_probability,
        usize::MAX,
        &mut voxels,
    );
    let mut points = Vec::new();
    sampling::contact_points(&ws, &voxels, &mut points);
    let ref_points = reference.points();
    assert!(
        !ref_points.is_empty(),
        "the reference has no contact points: the agreement test would prove nothing"
    );
    points.truncate(ref_points.len());
    assert_close("points", points.as_flattened(), reference.get("points"));

    // Features at the points from our U-Net outputs.
    let levels = model.levels(&unet).unwrap();
    let mut features = Vec::new();
    sampling::sample_features(&levels, &ref_points, &mut features);
    assert_close("features", &features, reference.get("features"));

    // MLP on the reference features, in two batches to exercise the dynamic batch size.
    let mut head = HeadOutputs::default();
    let batch = ref_points.len().div_ceil(2).max(1);
    model
        .run_mlp(reference.get("features"), batch, &mut head)
        .unwrap();
    let r = reference.head();
    assert_close("baseline", &head.baseline, &r.baseline);
    assert_close("kappa", &head.kappa, &r.kappa);
    assert_close("width", &head.width, &r.width);
    assert_close("quality_prior", &head.quality_prior, &r.quality_prior);
    assert_close("collision_prior", &head.collision_prior, &r.collision_prior);

    // Decoding the reference MLP outputs at the reference points.
    let mut configs = Vec::new();
    decode::decode(
        &probs,
        &ws,
        &ref_points,
        &r,
        &model.decode_settings(),
        &mut configs,
    )
    .unwrap();
    let quality: Vec<f32> = configs.iter().map(|c| c.quality).collect();
    assert_close("quality", &quality, reference.get("quality"));
    let scores: Vec<f32> = configs.iter().flat_map(|c| c.collision_scores).collect();
    assert_close(
        "collision_scores",
        &scores,
        reference.get("collision_scores"),
    );
    if reference.has("approach_vectors") {
        let approaches: Vec<f32> = configs
            .iter()
            .flat_map(|c| c.approaches())
            .flat_map(|a| [a.x, a.y, a.z])
            .collect();
        assert_close(
            "approach_vectors",
            &approaches,
            reference.get("approach_vectors"),
        );
    }
}

#[test]
fn tract_agrees_with_the_pytorch_reference() {
    agreement(RuntimeKind::Tract, None);
}

#[test]
fn native_agrees_with_the_pytorch_reference() {
    agreement(RuntimeKind::Native, None);
}

#[cfg(feature = "ort")]
fn ort_library() -> PathBuf {
    std::env::var_os("ORT_DYLIB_PATH")
        .map(PathBuf::from)
        .expect("the `ort` feature tests need ORT_DYLIB_PATH = path of libonnxruntime.so")
}

#[cfg(feature = "ort")]
#[test]
fn ort_agrees_with_the_pytorch_reference() {
    agreement(RuntimeKind::Ort, Some(&ort_library()));
}

#[cfg(not(feature = "ort"))]
#[test]
fn ort_runtime_without_the_feature_is_a_clear_error() {
    let files = load_model_dir(&model_dir(), &workspace(), &gripper()).unwrap();
    let err = LearnedModel::new(&files, RuntimeKind::Ort, None, 1).unwrap_err();
    assert!(matches!(
        err,
        ModelError::RuntimeUnavailable { runtime: "ort", .. }
    ));
}

/// The reference grid as a fused grid (the TSDF does not enter the network: all +1).
fn reference_grid(reference: &Reference) -> NormalGrid {
    let workspace = workspace();
    NormalGrid {
        workspace,
        normals: reference.get("normal_grid").to_vec(),
        tsdf: vec![1.0; workspace.voxel_count()],
        truncation_m: 0.027,
    }
}

fn learned_config(kind: RuntimeKind) -> LearnedConfig {
    LearnedConfig {
        model_dir: model_dir(),
        runtime: kind,
        threads: 1,
        mlp_batch: 100,
        // No cap: the reference points are the first of *all* contact voxels.
        max_contact_voxels: 1 << 20,
        ..LearnedConfig::default()
    }
}

fn backend_end_to_end(kind: RuntimeKind, ort_library: Option<PathBuf>) {
    let reference = Reference::load(&model_dir());
    let grid = reference_grid(&reference);
    let cfg = LearnedConfig {
        ort_library,
        ..learned_config(kind)
    };
    let mut backend = LearnedBackend::new(cfg.clone(), &workspace(), gripper()).unwrap();
    assert_eq!(backend.name(), format!("learned-{}", kind.name()));
    let configs = backend.infer(&grid.view(), 0).unwrap();
    let t = backend.last_timings();
    assert_eq!(configs.len(), t.points);
    assert_eq!(t.points, 8 * t.contact_voxels);
    assert!(t.total >= t.unet + t.sampling + t.mlp + t.decoding);
    // The first configurations are the reference points, decoded by the whole pipeline.
    let m = reference.points().len();
    assert!(configs.len() >= m);
    let contacts: Vec<f32> = configs[..m]
        .iter()
        .flat_map(|c| [c.contact.x, c.contact.y, c.contact.z])
        .collect();
    assert_close("points", &contacts, reference.get("points"));
    let quality: Vec<f32> = configs[..m].iter().map(|c| c.quality).collect();
    assert_close("quality", &quality, reference.get("quality"));
    let scores: Vec<f32> = configs[..m]
        .iter()
        .flat_map(|c| c.collision_scores)
        .collect();
    assert_close(
        "collision_scores",
        &scores,
        reference.get("collision_scores"),
    );
    let widths: Vec<f32> = configs[..m].iter().map(|c| c.width).collect();
    assert_close("width", &widths, reference.get("width"));
    // Every configuration carries the card's κ0, the floor the graph clamps κ to, so that
    // selection in another process knows which κ are clamped.
    let kappa0 = backend.card().kappa0;
    for c in &configs {
        assert_eq!(c.kappa_floor, kappa0);
        assert!(
            c.kappa >= kappa0 && c.kappa <= 4.0 * kappa0,
            "κ {}",
            c.kappa
        );
        assert!((c.baseline.norm() - 1.0).abs() < 1e-4);
        assert!((0.0..=1.0).contains(&c.quality));
        assert!(c.collision_scores.iter().all(|s| (0.0..=1.0).contains(s)));
        assert_eq!(c.collision_scores.len(), N_APPROACHES);
    }
    // Same grid → same output, and the thread count changes nothing.
    assert_eq!(backend.infer(&grid.view(), 5).unwrap(), configs);
    let mut threaded = LearnedBackend::new(
        LearnedConfig {
            threads: 2,
            ..cfg.clone()
        },
        &workspace(),
        gripper(),
    )
    .unwrap();
    let threaded_configs = threaded.infer(&grid.view(), 0).unwrap();
    assert_eq!(threaded_configs.len(), configs.len());
    for (a, b) in threaded_configs.iter().zip(&configs) {
        assert_eq!(a.contact, b.contact);
        assert!((a.quality - b.quality).abs() <= 1e-6);
        for (x, y) in a.collision_scores.iter().zip(&b.collision_scores) {
            assert!((x - y).abs() <= 1e-6);
        }
    }

    // The "1app" override keeps, per grasp, only the best of the 8app scores.
    let mut single = LearnedBackend::new(
        LearnedConfig {
            single_approach: Some(true),
            ..cfg.clone()
        },
        &workspace(),
        gripper(),
    )
    .unwrap();
    let singles = single.infer(&grid.view(), 0).unwrap();
    assert_eq!(singles.len(), configs.len());
    let mut kept_some = false;
    for (one, all) in singles.iter().zip(&configs) {
        assert_eq!(one.contact, all.contact);
        let best = all.collision_scores.iter().cloned().fold(0.0f32, f32::max);
        let nonzero: Vec<f32> = one
            .collision_scores
            .iter()
            .cloned()
            .filter(|&s| s > 0.0)
            .collect();
        assert!(nonzero.len() <= 1);
        if let Some(&s) = nonzero.first() {
            assert!((s - best).abs() <= 1e-6);
            kept_some = true;
        }
    }
    assert!(kept_some);

    // A cap on contact voxels keeps the most probable ones.
    let capped_cfg = LearnedConfig {
        max_contact_voxels: 3,
        ..cfg.clone()
    };
    let mut capped = LearnedBackend::new(capped_cfg, &workspace(), gripper()).unwrap();
    let few = capped.infer(&grid.view(), 0).unwrap();
    assert_eq!(few.len(), 8 * 3.min(t.contact_voxels));
    // A threshold of 1 (override) leaves no contacts, which is not an error.
    let none_cfg = LearnedConfig {
        contact_probability: Some(1.0),
        ..cfg
    };
    let mut none = LearnedBackend::new(none_cfg, &workspace(), gripper()).unwrap();
    assert!(none.infer(&grid.view(), 0).unwrap().is_empty());

    // A grid of another workspace is refused, naming the field.
    let mut other = grid.clone();
    other.workspace.voxel_size_m *= 2.0;
    assert!(matches!(
        backend.infer(&other.view(), 0),
        Err(InferenceError::Model(ModelError::Mismatch {
            field: "grid.voxel_size_m",
            ..
        }))
    ));
}

#[test]
fn tract_backend_end_to_end() {
    backend_end_to_end(RuntimeKind::Tract, None);
}

#[test]
fn native_backend_end_to_end() {
    backend_end_to_end(RuntimeKind::Native, None);
}

#[cfg(feature = "ort")]
#[test]
fn ort_backend_end_to_end() {
    backend_end_to_end(RuntimeKind::Ort, Some(ort_library()));
}

#[test]
fn backend_builds_from_toml_config() {
    let text = format!(
        "kind = \"learned\"\nmodel_dir = {:?}\nthreads = 1\nmax_contact_voxels = 100\n",
        model_dir().display().to_string()
    );
    let cfg: BackendConfig = toml::from_str(&text).unwrap();
    assert_eq!(cfg.kind(), "learned");
    let backend = backend_from_config(&cfg, gripper()).unwrap();
    // A config that names no runtime runs the native one.
    assert_eq!(backend.name(), "learned-native");
    backend_for_workspace(&cfg, &workspace(), gripper()).unwrap();
    // The pipeline's workspace or gripper differs from the card: refused at start-up.
    assert_card_mismatches_are_refused(&cfg, workspace(), gripper());
    let missing: BackendConfig =
        toml::from_str("kind = \"learned\"\nmodel_dir = \"/nonexistent/psgrasp-model\"\n").unwrap();
    assert!(matches!(
        backend_from_config(&missing, gripper()),
        Err(InferenceError::Model(ModelError::Io { .. }))
    ));
    assert!(
        toml::from_str::<BackendConfig>("kind = \"learned\"\nmax_contact_voxel = 3\n").is_err(),
        "typos must not be ignored"
    );
    let bad: BackendConfig =
        toml::from_str("kind = \"learned\"\ncontact_probability = 1.5\n").unwrap();
    assert!(matches!(
        backend_from_config(&bad, gripper()),
        Err(InferenceError::InvalidConfig {
            field: "contact_probability",
            ..
        })
    ));
}

/// A copy of the fixture directory in a fresh temporary directory, removed on drop.
struct TempModel {
    dir: PathBuf,
}

impl TempModel {
    fn new(tag: &str) -> Self {
        let dir =
            std::env::temp_dir().join(format!("psgrasp-learned-{}-{tag}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        for f in ["card.json", "unet.onnx", "mlp.onnx"] {
            std::fs::copy(model_dir().join(f), dir.join(f)).unwrap();
        }
        Self { dir }
    }

    /// Replaces a file and records its new sha256 in the card (a consistent but broken model).
    fn replace_with_matching_card(&self, file: &str, bytes: &[u8]) {
        std::fs::write(self.dir.join(file), bytes).unwrap();
        let mut card: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(self.dir.join("card.json")).unwrap())
                .unwrap();
        let key = file.trim_end_matches(".onnx");
        card["files"][key]["sha256"] = serde_json::Value::String(sha256_hex(bytes));
        std::fs::write(self.dir.join("card.json"), card.to_string()).unwrap();
    }

    fn load(&self) -> Result<LearnedModel, ModelError> {
        self.load_with(RuntimeKind::Tract)
    }

    fn load_with(&self, kind: RuntimeKind) -> Result<LearnedModel, ModelError> {
        #[cfg(feature = "ort")]
        let library = (kind == RuntimeKind::Ort).then(ort_library);
        #[cfg(not(feature = "ort"))]
        let library: Option<PathBuf> = None;
        LearnedModel::load(
            &self.dir,
            &workspace(),
            &gripper(),
            kind,
            library.as_deref(),
            1,
        )
    }
}

impl Drop for TempModel {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

#[test]
fn changed_onnx_files_are_refused_by_sha256() {
    for file in ["unet.onnx", "mlp.onnx"] {
        let m = TempModel::new(&format!("sha-{file}"));
        let mut bytes = std::fs::read(m.dir.join(file)).unwrap();
        let mid = bytes.len() / 2;
        bytes[mid] ^= 0x01;
        std::fs::write(m.dir.join(file), &bytes).unwrap();
        match m.load() {
            Err(ModelError::Sha256Mismatch { path, .. }) => assert!(path.ends_with(file)),
            other => panic!("{file}: expected a sha256 mismatch, got {other:?}"),
        }
    }
    let m = TempModel::new("missing");
    std::fs::remove_file(m.dir.join("mlp.onnx")).unwrap();
    assert!(matches!(m.load(), Err(ModelError::Io { .. })));
}

#[test]
fn truncated_or_garbage_onnx_is_an_error_not_a_panic() {
    truncated_or_garbage(RuntimeKind::Tract);
}

#[test]
fn truncated_or_garbage_onnx_is_an_error_not_a_panic_with_native() {
    truncated_or_garbage(RuntimeKind::Native);
}

#[cfg(feature = "ort")]
#[test]
fn truncated_or_garbage_onnx_is_an_error_not_a_panic_with_ort() {
    truncated_or_garbage(RuntimeKind::Ort);
}

fn truncated_or_garbage(kind: RuntimeKind) {
    for file in ["unet.onnx", "mlp.onnx"] {
        let original = std::fs::read(model_dir().join(file)).unwrap();
        let cuts = [original.len() / 2, original.len() - 7, 100, 1];
        for cut in cuts {
            let m = TempModel::new(&format!("cut-{}-{file}-{cut}", kind.name()));
            m.replace_with_matching_card(file, &original[..cut]);
            assert!(
                matches!(
                    m.load_with(kind),
                    Err(ModelError::Graph { .. } | ModelError::GraphInterface { .. })
                ),
                "{file} cut at {cut}: {:?}",
                m.load_with(kind).map(|_| ())
            );
        }
        let m = TempModel::new(&format!("garbage-{}-{file}", kind.name()));
        m.replace_with_matching_card(file, b"this is not an onnx file at all");
        assert!(matches!(
            m.load_with(kind),
            Err(ModelError::Graph { .. } | ModelError::GraphInterface { .. })
        ));
    }
    // The graphs swapped: loads as ONNX but the interface is wrong.
    let m = TempModel::new(&format!("swapped-{}", kind.name()));
    let unet = std::fs::read(model_dir().join("unet.onnx")).unwrap();
    m.replace_with_matching_card("mlp.onnx", &unet);
    assert!(matches!(
        m.load_with(kind),
        Err(ModelError::GraphInterface { graph: "mlp", .. })
    ));
}

#[test]
fn card_mismatches_are_refused_when_loading() {
    let m = TempModel::new("card");
    let original = std::fs::read_to_string(m.dir.join("card.json")).unwrap();
    let edit = |f: &dyn Fn(&mut serde_json::Value)| {
        let mut v: serde_json::Value = serde_json::from_str(&original).unwrap();
        f(&mut v);
        std::fs::write(m.dir.join("card.json"), v.to_string()).unwrap();
        m.load().map(|_| ())
    };
    let r = edit(&|v| v["approaches"]["count"] = 8.into());
    assert!(
        matches!(
            r,
            Err(ModelError::Mismatch {
                field: "approaches.count",
                ..
            })
        ),
        "{r:?}"
    );
    let r = edit(&|v| v["format_version"] = 2.into());
    assert!(
        matches!(r, Err(ModelError::FormatVersion { found: 2 })),
        "{r:?}"
    );
    let r = edit(&|v| v["format"] = "other".into());
    assert!(matches!(r, Err(ModelError::Format { .. })), "{r:?}");
    let r = edit(&|v| v["grid"]["voxel_size_m"] = 0.01.into());
    assert!(
        matches!(
            r,
            Err(ModelError::Mismatch {
                field: "grid.voxel_size_m",
                ..
            })
        ),
        "{r:?}"
    );
    let r = edit(&|v| v["mlp"]["feature_dim"] = 7.into());
    assert!(
        matches!(
            r,
            Err(ModelError::InvalidCard {
                field: "mlp.feature_dim",
                ..
            })
        ),
        "{r:?}"
    );
    std::fs::write(m.dir.join("card.json"), "{ not json").unwrap();
    assert!(matches!(m.load(), Err(ModelError::CardJson { .. })));
    // Untouched card: loads.
    std::fs::write(m.dir.join("card.json"), &original).unwrap();
    m.load().unwrap();
}
