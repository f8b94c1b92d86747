//! The VGN backend: decoding on hand-made output grids with known answers, and a real exported
//! model directory against its PyTorch reference file.
//!
//! The model directory is `tests/fixtures/vgn-tiny` (an untrained VGN-style network on a 16³ grid,
//! exported by `psgrasp_training` with `reference.safetensors`; regenerate it with
//! `tests/fixtures/make_tiny_vgn.py`), or `$PSGRASP_TEST_VGN_DIR` when set.
//!
//! With the cargo feature `ort`, the ONNX Runtime tests need `ORT_DYLIB_PATH` (the
//! `libonnxruntime.so` of the Python `onnxruntime` wheel); without it they are skipped with a
//! message.
use nalgebra::{Point2, Rotation3, Unit, Vector3};
use psgrasp_fusion::NormalGrid;
use psgrasp_geometry::{approach_vectors, GraspConfiguration, GripperModel, Workspace};
use psgrasp_inference::learned::card::sha256_hex;
use psgrasp_inference::learned::{ModelError, RuntimeKind};
use psgrasp_inference::vgn::{
    load_vgn_dir, VgnCard, VgnDecodeSettings, VgnDecoder, VgnModel, VgnOutputs,
};
use psgrasp_inference::{
    backend_for_workspace, backend_from_config, BackendConfig, InferenceBackend, InferenceError,
    VgnBackend, VgnConfig,
};
use psgrasp_test_support::synthetic::{Primitive, SyntheticScene};
use std::path::{Path, PathBuf};

mod common;
use common::{assert_card_mismatches_are_refused, assert_close, Reference};

// ---------------------------------------------------------------------------------------------
// Decoding on hand-made output grids
// ---------------------------------------------------------------------------------------------

/// Hand-made network outputs on a 12³ grid of 1 cm voxels: quality 0, baseline +x, approach −z,
/// width 4 cm everywhere unless set.
struct Grids {
    ws: Workspace,
    quality: Vec<f32>,
    baseline: Vec<f32>,
    approach: Vec<f32>,
    width: Vec<f32>,
}

impl Grids {
    fn new() -> Self {
        let ws = Workspace {
            dims: [12, 12, 12],
            voxel_size_m: 0.01,
        };
        let n = ws.voxel_count();
        let mut baseline = vec![0.0; 3 * n];
        baseline[..n].fill(1.0);
        let mut approach = vec![0.0; 3 * n];
        approach[2 * n..].fill(-1.0);
        Self {
            ws,
            quality: vec![0.0; n],
            baseline,
            approach,
            width: vec![0.04; n],
        }
    }

    fn n(&self) -> usize {
        self.ws.voxel_count()
    }

    fn index(&self, v: [usize; 3]) -> usize {
        self.ws.index(v[0], v[1], v[2])
    }

    fn set(&mut self, v: [usize; 3], q: f32, b: Vector3<f32>, a: Vector3<f32>, w: f32) {
        let (n, i) = (self.n(), self.index(v));
        self.quality[i] = q;
        for c in 0..3 {
            self.baseline[c * n + i] = b[c];
            self.approach[c * n + i] = a[c];
        }
        self.width[i] = w;
    }

    fn set_quality(&mut self, v: [usize; 3], q: f32) {
        let i = self.index(v);
        self.quality[i] = q;
    }

    fn outputs(&self) -> VgnOutputs<'_> {
        VgnOutputs {
            quality: &self.quality,
            baseline: &self.baseline,
            approach: &self.approach,
            width: &self.width,
        }
    }

    fn decode(&self, settings: VgnDecodeSettings) -> Vec<GraspConfiguration> {
        let mut decoder = VgnDecoder::new(settings);
        let mut out = vec![];
        decoder.decode(&self.ws, &self.outputs(), &mut out).unwrap();
        out
    }
}

/// No smoothing, threshold 0.9, NMS window 4, widths in [0, 8 cm], 256 grasps.
fn sharp() -> VgnDecodeSettings {
    VgnDecodeSettings {
        smoothing_sigma_voxels: 0.0,
        ..VgnDecodeSettings::new(&VgnConfig::default(), &GripperModel::default())
    }
}

/// The index of the one approach with score 1 (all others 0).
fn one_hot(c: &GraspConfiguration) -> usize {
    let ones: Vec<usize> = (0..c.collision_scores.len())
        .filter(|&i| c.collision_scores[i] == 1.0)
        .collect();
    assert_eq!(ones.len(), 1, "{:?}", c.collision_scores);
    assert!(c.collision_scores.iter().all(|&s| s == 0.0 || s == 1.0));
    ones[0]
}

#[test]
fn a_single_peak_decodes_to_its_known_grasp() {
    let b = Vector3::new(0.8, 0.6, 0.0);
    let av = approach_vectors(&b);
    let (v, w) = ([5, 6, 4], 0.05);
    let centre = Workspace {
        dims: [12, 12, 12],
        voxel_size_m: 0.01,
    }
    .voxel_center(5, 6, 4);
    for (i, flip) in [(5usize, 1.0f32), (11, 1.0), (0, -1.0), (17, -1.0)] {
        // The approach rotated 3° about the baseline (off the discrete set) and given a component
        // along b and a non-unit length: snapping must still find approach i.
        let a = Rotation3::from_axis_angle(&Unit::new_normalize(b), 3f32.to_radians()) * av[i];
        let mut g = Grids::new();
        g.set(v, 0.95, b * (2.0 * flip), (a + b * 0.2) * 1.5, w);
        let out = g.decode(sharp());
        assert_eq!(out.len(), 1);
        let c = &out[0];
        assert!((c.baseline.norm() - 1.0).abs() < 1e-6);
        assert!((c.baseline.dot(&b).abs() - 1.0).abs() < 1e-6);
        // Contacts at centre ∓ b·w/2: the first contact is centre − baseline·w/2 for the
        // baseline sign chosen.
        assert!((c.contact - (centre - c.baseline * (w / 2.0))).norm() < 1e-6);
        let expected_contact = [centre - b * (w / 2.0), centre + b * (w / 2.0)];
        assert!(expected_contact
            .iter()
            .any(|e| (c.contact - e).norm() < 1e-6));
        let k = one_hot(c);
        let snapped = approach_vectors(&c.baseline)[k];
        assert!(snapped.angle(&av[i]) < 1e-4, "flip {flip}, i {i} → {k}");
        assert_eq!(c.width, w);
        assert_eq!(c.quality, 0.95);
        assert_eq!(c.kappa, 0.0);
        let grasp = c.grasp(k);
        assert!(grasp.is_well_formed(1e-4));
        assert!((grasp.center() - centre).norm() < 1e-6);
        assert!(grasp.approach.angle(&av[i]) < 1e-4);
    }
}

#[test]
fn nms_keeps_one_of_two_neighbours_and_both_of_two_distant_peaks() {
    let (b, a) = (Vector3::x(), -Vector3::z());
    let mut g = Grids::new();
    g.set([5, 5, 5], 0.93, b, a, 0.04);
    g.set([5, 5, 6], 0.95, b, a, 0.04);
    let out = g.decode(sharp());
    assert_eq!(out.len(), 1);
    assert_eq!(out[0].quality, 0.95);
    let centre = g.ws.voxel_center(5, 5, 6);
    assert!((out[0].grasp(one_hot(&out[0])).center() - centre).norm() < 1e-6);

    // Six voxels apart: both survive, the better first.
    let mut g = Grids::new();
    g.set([2, 5, 5], 0.93, b, a, 0.04);
    g.set([8, 5, 5], 0.95, b, a, 0.04);
    let out = g.decode(sharp());
    assert_eq!(out.len(), 2);
    assert_eq!((out[0].quality, out[1].quality), (0.95, 0.93));
    // Window 1 = no suppression: the neighbours both survive.
    let mut g = Grids::new();
    g.set([5, 5, 5], 0.93, b, a, 0.04);
    g.set([5, 5, 6], 0.95, b, a, 0.04);
    let none = VgnDecodeSettings {
        nms_window_voxels: 1,
        ..sharp()
    };
    assert_eq!(g.decode(none).len(), 2);
    // Equal distant peaks are ordered by voxel index.
    let mut g = Grids::new();
    g.set([8, 5, 5], 0.95, b, Vector3::new(0.0, 0.6, -0.8), 0.04);
    g.set([2, 5, 5], 0.95, b, a, 0.04);
    let out = g.decode(sharp());
    assert_eq!(out.len(), 2);
    assert!(out[0].contact.x < out[1].contact.x);
}

#[test]
fn widths_out_of_range_and_low_quality_are_rejected() {
    let (b, a) = (Vector3::x(), -Vector3::z());
    let mut g = Grids::new();
    g.set([5, 5, 5], 0.95, b, a, 0.081);
    assert!(g.decode(sharp()).is_empty(), "wider than the gripper opens");
    g.set([5, 5, 5], 0.95, b, a, 0.08);
    assert_eq!(
        g.decode(sharp()).len(),
        1,
        "exactly the max opening is fine"
    );
    g.set([5, 5, 5], 0.95, b, a, -0.001);
    assert!(g.decode(sharp()).is_empty(), "negative width");
    g.set([5, 5, 5], 0.95, b, a, 0.01);
    let narrow = VgnDecodeSettings {
        min_width_m: 0.02,
        ..sharp()
    };
    assert!(g.decode(narrow).is_empty(), "below min_width_m");
    // A rejected voxel does not suppress its neighbour (VGN masks before NMS).
    let mut g = Grids::new();
    g.set([5, 5, 5], 0.99, b, a, 0.09);
    g.set([5, 5, 6], 0.95, b, a, 0.04);
    let out = g.decode(sharp());
    assert_eq!(out.len(), 1);
    assert_eq!(out[0].quality, 0.95);
    // The threshold.
    let mut g = Grids::new();
    g.set([5, 5, 5], 0.85, b, a, 0.04);
    assert!(g.decode(sharp()).is_empty());
    let low = VgnDecodeSettings {
        quality_threshold: 0.8,
        ..sharp()
    };
    assert_eq!(g.decode(low).len(), 1);
    // A threshold of 0 still needs a positive quality.
    let zero = VgnDecodeSettings {
        quality_threshold: 0.0,
        ..sharp()
    };
    assert_eq!(g.decode(zero).len(), 1);
}

#[test]
fn smoothing_removes_isolated_spikes_and_keeps_one_peak_of_a_blob() {
    // An isolated spike is smoothed far below the threshold.
    let mut g = Grids::new();
    g.set_quality([5, 5, 5], 0.95);
    let smooth = VgnDecodeSettings {
        smoothing_sigma_voxels: 1.0,
        ..sharp()
    };
    assert!(g.decode(smooth).is_empty());
    assert_eq!(g.decode(sharp()).len(), 1);

    // A flat 7³ blob of 0.97 around (5, 5, 5): without smoothing every voxel of the plateau is a
    // maximum of its window; smoothed, only the blob centre is, with quality < 0.97.
    let mut g = Grids::new();
    for i in 2..=8 {
        for j in 2..=8 {
            for k in 2..=8 {
                g.set_quality([i, j, k], 0.97);
            }
        }
    }
    let mut flat = VgnDecoder::new(sharp());
    let mut out = vec![];
    flat.decode(&g.ws, &g.outputs(), &mut out).unwrap();
    assert_eq!(flat.candidate_count(), 7 * 7 * 7);
    assert_eq!(out.len(), 256, "max_grasps");
    let mut decoder = VgnDecoder::new(smooth);
    decoder.decode(&g.ws, &g.outputs(), &mut out).unwrap();
    assert_eq!(out.len(), 1);
    assert_eq!(decoder.candidate_count(), 1);
    let centre = g.ws.voxel_center(5, 5, 5);
    assert!((out[0].grasp(one_hot(&out[0])).center() - centre).norm() < 1e-6);
    let q = decoder.processed_quality()[g.index([5, 5, 5])];
    assert_eq!(out[0].quality, q);
    assert!(q > 0.9 && q < 0.97, "{q}");
    // The decoder keeps working on the next frame (buffers reused).
    decoder.decode(&g.ws, &g.outputs(), &mut out).unwrap();
    assert_eq!(out.len(), 1);
}

#[test]
fn max_grasps_keeps_the_best() {
    let (b, a) = (Vector3::x(), -Vector3::z());
    let mut g = Grids::new();
    let peaks = [
        ([1, 1, 1], 0.91),
        ([6, 1, 1], 0.99),
        ([1, 6, 1], 0.95),
        ([6, 6, 6], 0.97),
    ];
    for (v, q) in peaks {
        g.set(v, q, b, a, 0.04);
    }
    let all = g.decode(sharp());
    let qs: Vec<f32> = all.iter().map(|c| c.quality).collect();
    assert_eq!(qs, [0.99, 0.97, 0.95, 0.91]);
    let two = VgnDecodeSettings {
        max_grasps: 2,
        ..sharp()
    };
    let qs: Vec<f32> = g.decode(two).iter().map(|c| c.quality).collect();
    assert_eq!(qs, [0.99, 0.97]);
}

#[test]
fn malformed_outputs_are_errors() {
    let g = Grids::new();
    let mut decoder = VgnDecoder::new(sharp());
    let mut out = vec![];
    let mut quality = g.quality.clone();
    quality[17] = f32::NAN;
    let bad = VgnOutputs {
        quality: &quality,
        ..g.outputs()
    };
    assert!(matches!(
        decoder.decode(&g.ws, &bad, &mut out),
        Err(ModelError::NonFiniteOutput {
            output: "quality",
            index: 17
        })
    ));
    let short = VgnOutputs {
        width: &g.width[1..],
        ..g.outputs()
    };
    assert!(matches!(
        decoder.decode(&g.ws, &short, &mut out),
        Err(ModelError::GraphInterface { graph: "vgn", .. })
    ));
    // A zero baseline at a peak is skipped, not a NaN grasp.
    let mut g = Grids::new();
    g.set([5, 5, 5], 0.95, Vector3::zeros(), -Vector3::z(), 0.04);
    assert!(g.decode(sharp()).is_empty());
}

// ---------------------------------------------------------------------------------------------
// The fixture model
// ---------------------------------------------------------------------------------------------

fn model_dir() -> PathBuf {
    std::env::var_os("PSGRASP_TEST_VGN_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/vgn-tiny"))
}

fn card() -> VgnCard {
    VgnCard::read(&model_dir()).expect("fixture card")
}

fn workspace() -> Workspace {
    card().workspace()
}

/// The gripper the fixture was exported for: the default Franka hand.
fn gripper() -> GripperModel {
    GripperModel::default()
}

fn agreement(kind: RuntimeKind, ort_library: Option<&Path>) {
    let reference = Reference::load(&model_dir());
    let files = load_vgn_dir(&model_dir(), &workspace(), &gripper()).expect("model dir");
    let mut model = VgnModel::new(&files, kind, ort_library, 1).expect("runtime");
    assert_eq!(model.runtime_name(), kind.name());
    let out = model.run(reference.get("normal_grid")).expect("run");
    for (name, t) in [
        ("quality", &out.quality),
        ("baseline", &out.baseline),
        ("approach", &out.approach),
        ("width", &out.width),
    ] {
        assert_eq!(t.shape(), reference.shape(name), "{name}");
        assert_close(name, t.data(), reference.get(name));
    }
}

#[test]
fn tract_agrees_with_the_pytorch_reference() {
    agreement(RuntimeKind::Tract, None);
}

/// `$ORT_DYLIB_PATH`, or None (with a message) to skip an ONNX Runtime test.
#[cfg(feature = "ort")]
fn ort_library() -> Option<PathBuf> {
    let lib = std::env::var_os("ORT_DYLIB_PATH").map(PathBuf::from);
    if lib.is_none() {
        eprintln!("skipped: the `ort` tests need ORT_DYLIB_PATH = path of libonnxruntime.so");
    }
    lib
}

#[cfg(feature = "ort")]
#[test]
fn ort_agrees_with_the_pytorch_reference() {
    if let Some(lib) = ort_library() {
        agreement(RuntimeKind::Ort, Some(&lib));
    }
}

#[cfg(not(feature = "ort"))]
#[test]
fn ort_runtime_without_the_feature_is_a_clear_error() {
    let files = load_vgn_dir(&model_dir(), &workspace(), &gripper()).unwrap();
    let err = VgnModel::new(&files, RuntimeKind::Ort, None, 1).unwrap_err();
    assert!(matches!(
        err,
        ModelError::RuntimeUnavailable { runtime: "ort", .. }
    ));
}

/// A synthetic scene on the fixture's workspace: a floor and two boxes.
fn synthetic_grid() -> NormalGrid {
    let ws = workspace();
    let e = ws.extent();
    SyntheticScene::floor(0.02)
        .with(Primitive::Box {
            center_xy: Point2::new(0.4 * e.x, 0.5 * e.y),
            size_m: Vector3::new(0.03, 0.05, 0.06),
            yaw_rad: 0.3,
        })
        .with(Primitive::Cylinder {
            center_xy: Point2::new(0.75 * e.x, 0.3 * e.y),
            radius_m: 0.015,
            height_m: 0.04,
        })
        .normal_grid(ws, 3.0 * ws.voxel_size_m)
}

fn vgn_config(kind: RuntimeKind, ort_library: Option<PathBuf>) -> VgnConfig {
    VgnConfig {
        model_dir: model_dir(),
        runtime: kind,
        ort_library,
        threads: 1,
        // The untrained fixture predicts quality ≈ 0.48 everywhere.
        quality_threshold: 0.3,
        max_grasps: 64,
        ..VgnConfig::default()
    }
}

fn backend_end_to_end(kind: RuntimeKind, ort_library: Option<PathBuf>) {
    let grid = synthetic_grid();
    let cfg = BackendConfig::Vgn(vgn_config(kind, ort_library.clone()));
    let mut backend = backend_for_workspace(&cfg, &workspace(), gripper()).unwrap();
    assert_eq!(backend.name(), "vgn");
    let configs = backend.infer(&grid.view(), 0).unwrap();
    assert!(!configs.is_empty(), "the threshold of 0.3 keeps NMS maxima");
    assert!(configs.len() <= 64);
    let ws = workspace();
    let g = gripper();
    for pair in configs.windows(2) {
        assert!(pair[0].quality >= pair[1].quality);
    }
    for c in &configs {
        let i = one_hot(c);
        let grasp = c.grasp(i);
        assert!(grasp.is_well_formed(1e-4), "{c:?}");
        assert!((0.3..=1.0).contains(&c.quality));
        assert!((0.0..=g.max_opening_m).contains(&c.width));
        assert_eq!(c.kappa, 0.0);
        // The centre is a voxel centre.
        let centre = grasp.center();
        let [vi, vj, vk] = ws.voxel_of(&centre).expect("centre inside the grid");
        assert!((ws.voxel_center(vi, vj, vk) - centre).norm() < 1e-5);
    }
    // Deterministic; the seed is unused.
    assert_eq!(backend.infer(&grid.view(), 7).unwrap(), configs);

    // Timings are recorded.
    let mut vgn = VgnBackend::new(vgn_config(kind, ort_library), &ws, gripper()).unwrap();
    assert_eq!(vgn.infer(&grid.view(), 0).unwrap(), configs);
    let t = vgn.last_timings();
    assert_eq!(t.grasps, configs.len());
    assert!(t.candidates >= t.grasps);
    assert!(t.total >= t.network + t.decoding);
    eprintln!("{t}");

    // The default threshold of 0.9 leaves no grasps for the untrained network: not an error.
    let strict = BackendConfig::Vgn(VgnConfig {
        quality_threshold: 0.9,
        ..vgn_config(kind, None)
    });
    if kind == RuntimeKind::Tract {
        let mut strict = backend_for_workspace(&strict, &ws, gripper()).unwrap();
        assert!(strict.infer(&grid.view(), 0).unwrap().is_empty());
    }

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
    // A malformed grid is refused before the network runs.
    let mut nan = grid.clone();
    nan.normals[5] = f32::NAN;
    assert!(matches!(
        backend.infer(&nan.view(), 0),
        Err(InferenceError::Grid(
            psgrasp_fusion::GridError::NonFiniteInput { .. }
        ))
    ));
}

#[test]
fn tract_backend_end_to_end() {
    backend_end_to_end(RuntimeKind::Tract, None);
}

#[cfg(feature = "ort")]
#[test]
fn ort_backend_end_to_end() {
    if let Some(lib) = ort_library() {
        backend_end_to_end(RuntimeKind::Ort, Some(lib));
    }
}

#[test]
fn the_backend_config_round_trips_through_toml() {
    let text = format!(
        "kind = \"vgn\"\nmodel_dir = {:?}\nthreads = 1\nquality_threshold = 0.5\n\
         smoothing_sigma_voxels = 0.0\nnms_window_voxels = 3\nmin_width_m = 0.01\nmax_grasps = 10\n",
        model_dir().display().to_string()
    );
    let cfg: BackendConfig = toml::from_str(&text).unwrap();
    assert_eq!(cfg.kind(), "vgn");
    let BackendConfig::Vgn(v) = &cfg else {
        panic!("vgn expected")
    };
    assert_eq!(v.quality_threshold, 0.5);
    assert_eq!(v.nms_window_voxels, 3);
    assert_eq!(v.min_width_m, 0.01);
    assert_eq!(v.max_grasps, 10);
    assert_eq!(v.runtime, RuntimeKind::Tract);
    assert_eq!(v.ort_library, None);
    let back: BackendConfig = toml::from_str(&toml::to_string(&cfg).unwrap()).unwrap();
    assert_eq!(back, cfg);
    // Defaults.
    let BackendConfig::Vgn(d) = toml::from_str::<BackendConfig>("kind = \"vgn\"\n").unwrap() else {
        panic!("vgn expected")
    };
    assert_eq!(d, VgnConfig::default());
    // Typos and keys of other kinds are not ignored.
    for bad in [
        "kind = \"vgn\"\nquality_treshold = 0.5\n",
        "kind = \"vgn\"\nmax_contact_voxels = 5\n",
    ] {
        assert!(toml::from_str::<BackendConfig>(bad).is_err(), "{bad}");
    }
    // Built from the config, with the card's workspace.
    let backend = backend_from_config(&cfg, gripper()).unwrap();
    assert_eq!(backend.name(), "vgn");
    // Out-of-range values are refused when building.
    let bad: BackendConfig = toml::from_str("kind = \"vgn\"\nquality_threshold = 1.5\n").unwrap();
    assert!(matches!(
        backend_from_config(&bad, gripper()),
        Err(InferenceError::InvalidConfig {
            field: "quality_threshold",
            ..
        })
    ));
    let wide = VgnConfig {
        min_width_m: 0.08,
        ..vgn_config(RuntimeKind::Tract, None)
    };
    assert!(matches!(
        VgnBackend::new(wide, &workspace(), gripper()),
        Err(InferenceError::InvalidConfig {
            field: "min_width_m",
            ..
        })
    ));
}

#[test]
fn pipeline_mismatches_are_refused_at_start_up() {
    let cfg = BackendConfig::Vgn(vgn_config(RuntimeKind::Tract, None));
    assert_card_mismatches_are_refused(&cfg, workspace(), gripper());
    let missing = BackendConfig::Vgn(VgnConfig {
        model_dir: "/nonexistent/psgrasp-vgn".into(),
        ..VgnConfig::default()
    });
    assert!(matches!(
        backend_from_config(&missing, gripper()),
        Err(InferenceError::Model(ModelError::Io { .. }))
    ));
    // A learned model directory is not a VGN one.
    let learned = BackendConfig::Vgn(VgnConfig {
        model_dir: Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/tiny-model"),
        ..VgnConfig::default()
    });
    assert!(matches!(
        backend_from_config(&learned, gripper()),
        Err(InferenceError::Model(ModelError::CardJson { .. }))
    ));
}

/// A copy of the fixture directory in a fresh temporary directory, removed on drop.
struct TempModel {
    dir: PathBuf,
}

impl TempModel {
    fn new(tag: &str) -> Self {
        let dir = std::env::temp_dir().join(format!("psgrasp-vgn-{}-{tag}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        for f in ["card.json", "vgn.onnx"] {
            std::fs::copy(model_dir().join(f), dir.join(f)).unwrap();
        }
        Self { dir }
    }

    /// Replaces `vgn.onnx` and records its new sha256 in the card (consistent but broken).
    fn replace_onnx_with_matching_card(&self, bytes: &[u8]) {
        std::fs::write(self.dir.join("vgn.onnx"), bytes).unwrap();
        let mut card: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(self.dir.join("card.json")).unwrap())
                .unwrap();
        card["files"]["vgn"]["sha256"] = serde_json::Value::String(sha256_hex(bytes));
        std::fs::write(self.dir.join("card.json"), card.to_string()).unwrap();
    }

    fn load(&self, kind: RuntimeKind) -> Result<VgnModel, ModelError> {
        #[cfg(feature = "ort")]
        let library = if kind == RuntimeKind::Ort {
            ort_library()
        } else {
            None
        };
        #[cfg(not(feature = "ort"))]
        let library: Option<PathBuf> = None;
        VgnModel::load(
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
fn broken_model_directories_are_errors_not_panics() {
    let kind = RuntimeKind::Tract;
    // A flipped byte: refused by its sha256.
    let m = TempModel::new("sha");
    let mut bytes = std::fs::read(m.dir.join("vgn.onnx")).unwrap();
    let mid = bytes.len() / 2;
    bytes[mid] ^= 0x01;
    std::fs::write(m.dir.join("vgn.onnx"), &bytes).unwrap();
    match m.load(kind) {
        Err(ModelError::Sha256Mismatch { path, .. }) => assert!(path.ends_with("vgn.onnx")),
        other => panic!("expected a sha256 mismatch, got {other:?}"),
    }
    // Missing graph, missing card, corrupt card.
    let m = TempModel::new("missing");
    std::fs::remove_file(m.dir.join("vgn.onnx")).unwrap();
    assert!(matches!(m.load(kind), Err(ModelError::Io { .. })));
    std::fs::write(m.dir.join("card.json"), "{ not json").unwrap();
    assert!(matches!(m.load(kind), Err(ModelError::CardJson { .. })));
    std::fs::remove_file(m.dir.join("card.json")).unwrap();
    assert!(matches!(m.load(kind), Err(ModelError::Io { .. })));

    // Card edits.
    let m = TempModel::new("card");
    let original = std::fs::read_to_string(m.dir.join("card.json")).unwrap();
    let edit = |f: &dyn Fn(&mut serde_json::Value)| {
        let mut v: serde_json::Value = serde_json::from_str(&original).unwrap();
        f(&mut v);
        std::fs::write(m.dir.join("card.json"), v.to_string()).unwrap();
        m.load(kind).map(|_| ())
    };
    let r = edit(&|v| v["format_version"] = 2.into());
    assert!(
        matches!(r, Err(ModelError::FormatVersion { found: 2 })),
        "{r:?}"
    );
    let r = edit(&|v| v["format"] = "psgrasp-model".into());
    assert!(matches!(r, Err(ModelError::Format { .. })), "{r:?}");
    let r = edit(&|v| v["grid"]["dims"] = serde_json::json!([16, 16, 32]));
    assert!(
        matches!(
            r,
            Err(ModelError::Mismatch {
                field: "grid.dims",
                ..
            })
        ),
        "{r:?}"
    );
    let r = edit(&|v| v["gripper"]["approach_depth_m"] = 0.05.into());
    assert!(
        matches!(
            r,
            Err(ModelError::Mismatch {
                field: "gripper.approach_depth_m",
                ..
            })
        ),
        "{r:?}"
    );
    let r = edit(&|v| v["files"]["vgn"]["path"] = "../vgn.onnx".into());
    assert!(
        matches!(
            r,
            Err(ModelError::InvalidCard {
                field: "files.vgn",
                ..
            })
        ),
        "{r:?}"
    );
    let r = edit(&|v| {
        v.as_object_mut().unwrap().remove("network");
    });
    assert!(matches!(r, Err(ModelError::CardJson { .. })), "{r:?}");
    std::fs::write(m.dir.join("card.json"), &original).unwrap();
    m.load(kind).unwrap();

    corrupt_graphs(kind);
}

#[cfg(feature = "ort")]
#[test]
fn corrupt_graphs_are_errors_not_panics_with_ort() {
    if ort_library().is_some() {
        corrupt_graphs(RuntimeKind::Ort);
    }
}

/// Truncated, garbage and wrong-interface graphs with a matching card.
fn corrupt_graphs(kind: RuntimeKind) {
    let original = std::fs::read(model_dir().join("vgn.onnx")).unwrap();
    for cut in [original.len() / 2, original.len() - 7, 100, 1] {
        let m = TempModel::new(&format!("cut-{}-{cut}", kind.name()));
        m.replace_onnx_with_matching_card(&original[..cut]);
        let r = m.load(kind).map(|_| ());
        assert!(
            matches!(
                r,
                Err(ModelError::Graph { .. } | ModelError::GraphInterface { .. })
            ),
            "cut at {cut}: {r:?}"
        );
    }
    let m = TempModel::new(&format!("garbage-{}", kind.name()));
    m.replace_onnx_with_matching_card(b"this is not an onnx file at all");
    assert!(matches!(
        m.load(kind),
        Err(ModelError::Graph { .. } | ModelError::GraphInterface { .. })
    ));
    // The learned U-Net (same input, other outputs) and MLP (other input) in place of vgn.onnx.
    let learned = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/tiny-model");
    for file in ["unet.onnx", "mlp.onnx"] {
        let m = TempModel::new(&format!("wrong-{}-{file}", kind.name()));
        m.replace_onnx_with_matching_card(&std::fs::read(learned.join(file)).unwrap());
        let r = m.load(kind).map(|_| ());
        assert!(
            matches!(r, Err(ModelError::GraphInterface { graph: "vgn", .. })),
            "{file}: {r:?}"
        );
    }
}
