//! The learned backend: the two-stage network of the paper exported to ONNX.
//!
//! A model directory, written by `python -m psgrasp_training export`, holds `card.json` (the model
//! card, [`card`]), `unet.onnx` and `mlp.onnx` (network interface contract version 1; optionally
//! `reference.safetensors`, PyTorch's outputs on one scene, used by the agreement tests).
//! Per frame:
//!
//! 1. **U-Net** ([`GraphRuntime::run_unet`]): the fused grid's normals `[1, 3, X, Y, Z]` →
//!    label logits (empty / contact / gripper) and encoder feature grids `enc0..enc{L-1}`.
//! 2. **Sampling** ([`sampling`]): softmax class probabilities; contact voxels with
//!    `P_contact ≥ contact_probability` (at most `max_contact_voxels`, the most probable); 8
//!    sub-voxel points per contact voxel; trilinear features from every level, concatenated.
//! 3. **MLP** ([`GraphRuntime::run_mlp`], in batches of `mlp_batch` rows): baseline, κ, width,
//!    quality prior and 18 collision priors per point.
//! 4. **Decoding** ([`decode`]): `q = I(P_contact, c)·q′`, `σ_i = I(P_gripper, t_i)·σ′_i`.
//!
//! The output holds one [`GraspConfiguration`] per point, in contact-voxel index order then
//! sub-voxel order; the seed is unused (the network is deterministic). Per-stage wall times of the
//! last frame are in [`LearnedBackend::last_timings`].
//!
//! Runtimes: psgrasp's own kernels ([`crate::native`], `runtime = "native"`, the default and the
//! fastest on CPUs), tract (pure Rust, `runtime = "tract"`) and ONNX Runtime (`runtime = "ort"`,
//! cargo feature `ort`, library from `ort_library` or `ORT_DYLIB_PATH`); tract and ONNX Runtime
//! are the references the native runtime is tested against.
pub mod card;
pub mod decode;
pub mod runtime;
pub mod sampling;

pub use card::{load_model_dir, ModelCard, ModelError, ModelFiles, ModelVariant};
pub use decode::{DecodeSettings, Decoder, HeadOutputs};
#[cfg(feature = "ort")]
pub use runtime::OrtRuntime;
pub use runtime::{GraphRuntime, OutputTensor, RuntimeKind, TractRuntime, UnetOutputs};
pub use sampling::{ClassProbabilities, FeaturePyramid, GridLevel};

use crate::{validate_grid, validate_gripper, InferenceBackend, InferenceError};
use psgrasp_fusion::NormalGridView;
use psgrasp_geometry::{GraspConfiguration, GripperModel, Workspace};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Settings of the learned backend (`kind = "learned"`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LearnedConfig {
    /// Model directory with `card.json`, `unet.onnx`, `mlp.onnx` (relative paths are relative to
    /// the working directory of the process).
    pub model_dir: PathBuf,
    /// Graph runtime (default: native).
    pub runtime: RuntimeKind,
    /// `libonnxruntime.so` for `runtime = "ort"`; if unset, `$ORT_DYLIB_PATH`.
    pub ort_library: Option<PathBuf>,
    /// Worker threads of the runtime (tract matrix products, ONNX Runtime intra-op); 0 = all cores.
    pub threads: usize,
    /// Most contact voxels per frame (the most probable are kept); 8 points each.
    pub max_contact_voxels: usize,
    /// Overrides the card's `thresholds.contact_probability`.
    pub contact_probability: Option<f32>,
    /// Rows per MLP run.
    pub mlp_batch: usize,
    /// Overrides the card's `inference.single_approach`: `true` keeps only the best of the 18
    /// approaches per grasp (the paper's "w κ + 1app" ablation of a model trained as 8app).
    pub single_approach: Option<bool>,
    /// `runtime = "native"` only, approximate: computes the U-Net only within this many voxels
    /// of the observed surface (the grid's non-zero normals; halved per level) and takes every
    /// layer's background value farther away. 0 (default): exact. Effect on the outputs in
    /// docs/benchmarks.md.
    pub native_band_voxels: usize,
}

impl Default for LearnedConfig {
    fn default() -> Self {
        Self {
            model_dir: PathBuf::from("models/default"),
            runtime: RuntimeKind::Native,
            ort_library: None,
            threads: 0,
            max_contact_voxels: 4096,
            contact_probability: None,
            mlp_batch: 4096,
            single_approach: None,
            native_band_voxels: 0,
        }
    }
}

impl LearnedConfig {
    /// Checks every field's range.
    pub fn validate(&self) -> Result<(), InferenceError> {
        let bad = |field, reason| Err(InferenceError::InvalidConfig { field, reason });
        check_model_source(&self.model_dir, self.ort_library.as_deref(), self.threads)?;
        if !(1..=1 << 20).contains(&self.max_contact_voxels) {
            return bad("max_contact_voxels", "must lie in 1..=1048576");
        }
        if let Some(p) = self.contact_probability {
            if !(0.0..=1.0).contains(&p) {
                return bad("contact_probability", "must lie in [0, 1]");
            }
        }
        if !(1..=1 << 20).contains(&self.mlp_batch) {
            return bad("mlp_batch", "must lie in 1..=1048576");
        }
        if self.native_band_voxels > 64 {
            return bad("native_band_voxels", "must lie in 0..=64");
        }
        if self.native_band_voxels > 0 && self.runtime != RuntimeKind::Native {
            return bad("native_band_voxels", "needs runtime = \"native\"");
        }
        Ok(())
    }
}

/// Checks the settings every ONNX backend shares: a model directory, an `ort_library` that names
/// a file when set, and `threads` in 0..=1024.
pub(crate) fn check_model_source(
    model_dir: &Path,
    ort_library: Option<&Path>,
    threads: usize,
) -> Result<(), InferenceError> {
    let bad = |field, reason| Err(InferenceError::InvalidConfig { field, reason });
    if model_dir.as_os_str().is_empty() {
        return bad("model_dir", "must name a directory");
    }
    if threads > 1024 {
        return bad("threads", "must lie in 0..=1024");
    }
    if ort_library.is_some_and(|p| p.as_os_str().is_empty()) {
        return bad("ort_library", "must name a file when set");
    }
    Ok(())
}

/// Wall time of each stage of the last frame and what it processed.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct StageTimings {
    /// U-Net forward pass (input copy and output checks included).
    pub unet: Duration,
    /// Softmax, contact selection, points and feature sampling.
    pub sampling: Duration,
    /// MLP forward passes.
    pub mlp: Duration,
    /// Decoding into configurations.
    pub decoding: Duration,
    /// The whole `infer` call (input validation included).
    pub total: Duration,
    /// Contact voxels selected.
    pub contact_voxels: usize,
    /// Points decoded (8 per contact voxel).
    pub points: usize,
}

impl std::fmt::Display for StageTimings {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let ms = |d: Duration| d.as_secs_f64() * 1e3;
        write!(
            f,
            "unet {:.1} ms, sampling {:.1} ms, mlp {:.1} ms, decoding {:.1} ms, total {:.1} ms \
             ({} contact voxels, {} points)",
            ms(self.unet),
            ms(self.sampling),
            ms(self.mlp),
            ms(self.decoding),
            ms(self.total),
            self.contact_voxels,
            self.points
        )
    }
}

/// A loaded model: its checked card and a runtime holding both graphs.
pub struct LearnedModel {
    card: ModelCard,
    runtime: Box<dyn GraphRuntime>,
}

impl std::fmt::Debug for LearnedModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LearnedModel")
            .field("card", &self.card.name)
            .field("runtime", &self.runtime.name())
            .finish()
    }
}

impl LearnedModel {
    /// Builds the runtime `kind` for checked model files (`ort_library` and `threads` as in
    /// [`LearnedConfig`]).
    pub fn new(
        files: &ModelFiles,
        kind: RuntimeKind,
        ort_library: Option<&Path>,
        threads: usize,
    ) -> Result<Self, ModelError> {
        let runtime: Box<dyn GraphRuntime> = match kind {
            RuntimeKind::Tract => Box::new(TractRuntime::new(files, threads)?),
            #[cfg(feature = "ort")]
            RuntimeKind::Ort => Box::new(OrtRuntime::new(files, ort_library, threads)?),
            #[cfg(not(feature = "ort"))]
            RuntimeKind::Ort => {
                let _ = ort_library;
                return Err(crate::onnx::ort_not_built());
            }
            RuntimeKind::Native => Box::new(crate::native::NativeRuntime::new(files, threads)?),
        };
        Ok(Self {
            card: files.card.clone(),
            runtime,
        })
    }

    /// Loads `dir` ([`load_model_dir`]) and builds the runtime.
    pub fn load(
        dir: &Path,
        workspace: &Workspace,
        gripper: &GripperModel,
        kind: RuntimeKind,
        ort_library: Option<&Path>,
        threads: usize,
    ) -> Result<Self, ModelError> {
        let files = load_model_dir(dir, workspace, gripper)?;
        Self::new(&files, kind, ort_library, threads)
    }

    /// The model card.
    pub fn card(&self) -> &ModelCard {
        &self.card
    }

    /// The native runtime, when that is the runtime (its statistics and settings).
    pub fn native_mut(&mut self) -> Option<&mut crate::native::NativeRuntime> {
        self.runtime.as_native()
    }

    /// The runtime's name (`"tract"` or `"ort"`).
    pub fn runtime_name(&self) -> &'static str {
        self.runtime.name()
    }

    /// Runs the U-Net on a normals buffer (`[3, X, Y, Z]`).
    pub fn run_unet(&mut self, normals: &[f32]) -> Result<UnetOutputs, ModelError> {
        self.runtime.run_unet(normals)
    }

    /// The encoder levels of `outputs` as sampling grids (level `l` has voxel size `s·2^l`).
    pub fn levels<'a>(&self, outputs: &'a UnetOutputs) -> Result<Vec<GridLevel<'a>>, ModelError> {
        let s = self.card.grid.voxel_size_m;
        outputs
            .features
            .iter()
            .enumerate()
            .map(|(l, t)| {
                let c = self.card.unet.channels.get(l).copied().unwrap_or(0) as usize;
                GridLevel::new(t.data(), c, self.card.level_dims(l), s * (1u32 << l) as f32)
            })
            .collect()
    }

    /// Runs the MLP on `features` (`[n, F]`) in batches of `batch` rows; `out` is cleared first.
    pub fn run_mlp(
        &mut self,
        features: &[f32],
        batch: usize,
        out: &mut HeadOutputs,
    ) -> Result<(), ModelError> {
        out.clear();
        let f = self.card.feature_dim();
        if f == 0 || !features.len().is_multiple_of(f) {
            return Err(ModelError::GraphInterface {
                graph: "mlp",
                reason: format!("{} feature values are not rows of {f}", features.len()),
            });
        }
        for chunk in features.chunks(batch.max(1) * f) {
            self.runtime.run_mlp(chunk, chunk.len() / f, out)?;
        }
        Ok(())
    }

    /// Decoding settings from the card.
    pub fn decode_settings(&self) -> DecodeSettings {
        DecodeSettings {
            approach_depth_m: self.card.gripper.approach_depth_m,
            single_approach: self.card.inference.single_approach,
            kappa_floor: self.card.kappa0,
        }
    }
}

/// The learned grasp backend (see the module docs).
pub struct LearnedBackend {
    model: LearnedModel,
    cfg: LearnedConfig,
    name: String,
    contact_probability: f32,
    /// Runs sampling and decoding on `threads` threads (None: the calling thread only).
    pool: Option<std::sync::Arc<rayon::ThreadPool>>,
    probabilities: ClassProbabilities,
    voxels: Vec<u32>,
    points: Vec<[f32; 3]>,
    pyramid: FeaturePyramid,
    features: Vec<f32>,
    head: HeadOutputs,
    timings: StageTimings,
}

impl std::fmt::Debug for LearnedBackend {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LearnedBackend")
            .field("model", &self.model)
            .field("cfg", &self.cfg)
            .finish_non_exhaustive()
    }
}

impl LearnedBackend {
    /// Loads the model of `cfg` for `workspace` and `gripper`, refusing a card that does not
    /// match them.
    pub fn new(
        cfg: LearnedConfig,
        workspace: &Workspace,
        gripper: GripperModel,
    ) -> Result<Self, InferenceError> {
        cfg.validate()?;
        validate_gripper(&gripper)?;
        workspace.validate()?;
        let files = load_model_dir(&cfg.model_dir, workspace, &gripper)?;
        Self::from_files(cfg, &files)
    }

    /// Like [`LearnedBackend::new`] for the workspace the card records; grids of another
    /// workspace are refused frame by frame.
    pub fn for_card_workspace(
        cfg: LearnedConfig,
        gripper: GripperModel,
    ) -> Result<Self, InferenceError> {
        cfg.validate()?;
        let card = ModelCard::read(&cfg.model_dir)?;
        card.validate()?;
        Self::new(cfg, &card.workspace(), gripper)
    }

    /// Builds the backend from already checked model files.
    pub fn from_files(cfg: LearnedConfig, files: &ModelFiles) -> Result<Self, InferenceError> {
        cfg.validate()?;
        let mut model =
            LearnedModel::new(files, cfg.runtime, cfg.ort_library.as_deref(), cfg.threads)?;
        // The native runtime's pool also runs sampling and decoding: one set of worker threads
        // per backend, not two taking turns on the same cores.
        let mut native_pool = None;
        if let Some(native) = model.native_mut() {
            native.set_band(cfg.native_band_voxels);
            native_pool = native.thread_pool();
        }
        let contact_probability = cfg
            .contact_probability
            .unwrap_or(files.card.thresholds.contact_probability);
        let threads = runtime::resolve_threads(cfg.threads);
        let pool = if native_pool.is_some() {
            native_pool
        } else if threads > 1 {
            Some(std::sync::Arc::new(
                rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .thread_name(|i| format!("psgrasp-learned-{i}"))
                    .build()
                    .map_err(|e| ModelError::RuntimeUnavailable {
                        runtime: "rayon",
                        reason: format!("cannot start {threads} threads: {e}"),
                    })?,
            ))
        } else {
            None
        };
        Ok(Self {
            pool,
            name: format!("learned-{}", model.runtime_name()),
            model,
            cfg,
            contact_probability,
            probabilities: ClassProbabilities::default(),
            voxels: Vec::new(),
            points: Vec::new(),
            pyramid: FeaturePyramid::default(),
            features: Vec::new(),
            head: HeadOutputs::default(),
            timings: StageTimings::default(),
        })
    }

    /// The model card.
    pub fn card(&self) -> &ModelCard {
        self.model.card()
    }

    /// The loaded model (for stage-by-stage use).
    pub fn model_mut(&mut self) -> &mut LearnedModel {
        &mut self.model
    }

    /// The contact probability threshold in use (config override or card).
    pub fn contact_probability(&self) -> f32 {
        self.contact_probability
    }

    /// Stage timings of the last successful [`InferenceBackend::infer`].
    pub fn last_timings(&self) -> StageTimings {
        self.timings
    }

    /// Class probabilities of the last frame (level-0 grids).
    pub fn last_probabilities(&self) -> &ClassProbabilities {
        &self.probabilities
    }
}

impl InferenceBackend for LearnedBackend {
    /// The network's forward pass and the decoding sample nothing: the seed is unused.
    fn uses_seed(&self) -> bool {
        false
    }

    fn name(&self) -> &str {
        &self.name
    }

    fn infer(
        &mut self,
        grid: &NormalGridView<'_>,
        _seed: u64,
    ) -> Result<Vec<GraspConfiguration>, InferenceError> {
        let start = Instant::now();
        validate_grid(grid)?;
        let card = self.model.card();
        card.check_workspace(&grid.workspace)?;
        let workspace = card.workspace();
        let voxels = workspace.voxel_count();
        let mut t = StageTimings::default();

        let t0 = Instant::now();
        let unet = self.model.run_unet(grid.normals)?;
        t.unet = t0.elapsed();

        let t0 = Instant::now();
        self.probabilities
            .compute(unet.label_logits.data(), voxels)?;
        sampling::select_contact_voxels(
            &self.probabilities.contact,
            self.contact_probability,
            self.cfg.max_contact_voxels,
            &mut self.voxels,
        );
        sampling::contact_points(&workspace, &self.voxels, &mut self.points);
        let levels = self.model.levels(&unet)?;
        match &self.pool {
            Some(pool) => {
                self.pyramid.fill_in(&levels, pool);
                self.pyramid
                    .sample_in(&self.points, &mut self.features, pool);
            }
            None => {
                self.pyramid.fill(&levels);
                self.pyramid.sample(&self.points, &mut self.features);
            }
        }
        drop(levels);
        drop(unet);
        t.sampling = t0.elapsed();

        let t0 = Instant::now();
        self.model
            .run_mlp(&self.features, self.cfg.mlp_batch, &mut self.head)?;
        t.mlp = t0.elapsed();

        let t0 = Instant::now();
        let mut settings = self.model.decode_settings();
        if let Some(single) = self.cfg.single_approach {
            settings.single_approach = single;
        }
        let decoder = Decoder::new(
            &self.probabilities,
            &workspace,
            &self.points,
            &self.head,
            &settings,
        )?;
        let mut out = Vec::with_capacity(decoder.len());
        match &self.pool {
            Some(pool) => pool.install(|| {
                use rayon::prelude::*;
                out.par_extend(
                    (0..decoder.len())
                        .into_par_iter()
                        .map(|n| decoder.config(n)),
                )
            }),
            None => out.extend((0..decoder.len()).map(|n| decoder.config(n))),
        }
        t.decoding = t0.elapsed();
        t.total = start.elapsed();
        t.contact_voxels = self.voxels.len();
        t.points = self.points.len();
        self.timings = t;
        Ok(out)
    }
}
