//! The VGN-style baseline backend (`kind = "vgn"`): a fully convolutional network that predicts
//! per voxel a grasp quality, a gripper orientation and an opening width (Breyer et al.,
//! "Volumetric Grasping Network"), retrained on psgrasp's data and exported to ONNX.
//!
//! A model directory holds `card.json` (format `psgrasp-vgn-model`, [`card`]), `vgn.onnx` and,
//! for the agreement tests, `reference.safetensors`. The graph has one input `normal_grid`
//! `[1, 3, X, Y, Z]` (the fused grid's normals buffer, as the learned U-Net's input) and four
//! outputs: `quality` `[1, 1, X, Y, Z]` in [0, 1], `baseline` and `approach` `[1, 3, X, Y, Z]`
//! (unit, orthogonal) and `width` `[1, 1, X, Y, Z]` in metres. The grasp of voxel `(i, j, k)` has
//! its tool centre point at the voxel centre and its contacts at `centre ∓ b·w/2`.
//!
//! Per frame: input checks ([`crate::validate_grid`], the grid's workspace against the card),
//! the network on tract or ONNX Runtime ([`crate::onnx`], the learned backend's runtimes), then VGN's
//! post-processing and decoding ([`decode`]: smoothing, width check, threshold, NMS, ranking,
//! approach snapping). The seed is unused (the network is deterministic). Stage times of the
//! last frame are in [`VgnBackend::last_timings`].
pub mod card;
pub mod decode;

pub use card::{is_vgn_model_dir, load_vgn_dir, VgnCard, VgnModelFiles};
pub use decode::{snap_approach, VgnDecodeSettings, VgnDecoder, VgnOutputs};

use crate::learned::check_model_source;
use crate::learned::runtime::UNET_INPUT;
use crate::model_error::ModelError;
use crate::onnx::{FixedGraph, GraphSpec, OutputTensor, RuntimeKind};
use crate::{validate_grid, validate_gripper, InferenceBackend, InferenceError};
use psgrasp_fusion::NormalGridView;
use psgrasp_geometry::{GraspConfiguration, GripperModel, Workspace};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Input name of `vgn.onnx` (the same as the learned U-Net's).
pub const VGN_INPUT: &str = UNET_INPUT;
/// Output names of `vgn.onnx`, in the order of [`VgnNetworkOutputs`].
pub const VGN_OUTPUTS: [&str; 4] = ["quality", "baseline", "approach", "width"];

/// Settings of the VGN backend (`kind = "vgn"`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VgnConfig {
    /// Model directory with `card.json` and `vgn.onnx` (default `models/vgn`; relative paths are
    /// relative to the working directory of the process, or to the pipeline config file).
    pub model_dir: PathBuf,
    /// Graph runtime (default tract).
    pub runtime: RuntimeKind,
    /// Worker threads of the runtime (tract matrix products, ONNX Runtime intra-op); 0 = all
    /// cores (default).
    pub threads: usize,
    /// `libonnxruntime.so` for `runtime = "ort"`; if unset, `$ORT_DYLIB_PATH`.
    pub ort_library: Option<PathBuf>,
    /// Smallest smoothed quality of a grasp (default 0.9, as VGN).
    pub quality_threshold: f32,
    /// Standard deviation of the Gaussian smoothing of the quality grid, in voxels (default 1.0,
    /// as VGN); 0 disables smoothing.
    pub smoothing_sigma_voxels: f32,
    /// Edge of the non-maximum-suppression window in voxels (default 4, as VGN's
    /// `maximum_filter(size=4)`); 1 disables suppression. Windows follow SciPy: size n covers
    /// offsets −⌊n/2⌋ … n−1−⌊n/2⌋, so an even size is not centred (2 = offsets −1 and 0).
    pub nms_window_voxels: usize,
    /// Narrowest accepted predicted width in metres (default 0); widths above the gripper's
    /// maximum opening are always rejected.
    pub min_width_m: f32,
    /// Most grasps per frame, the best first (default 256).
    pub max_grasps: usize,
}

impl Default for VgnConfig {
    fn default() -> Self {
        Self {
            model_dir: PathBuf::from("models/vgn"),
            runtime: RuntimeKind::Tract,
            threads: 0,
            ort_library: None,
            quality_threshold: 0.9,
            smoothing_sigma_voxels: 1.0,
            nms_window_voxels: 4,
            min_width_m: 0.0,
            max_grasps: 256,
        }
    }
}

impl VgnConfig {
    /// Checks every field's range.
    pub fn validate(&self) -> Result<(), InferenceError> {
        let bad = |field, reason| Err(InferenceError::InvalidConfig { field, reason });
        check_model_source(&self.model_dir, self.ort_library.as_deref(), self.threads)?;
        if self.runtime == RuntimeKind::Native {
            return bad(
                "runtime",
                "\"native\" runs the learned backend only; use \"tract\" or \"ort\"",
            );
        }
        if !(0.0..=1.0).contains(&self.quality_threshold) {
            return bad("quality_threshold", "must lie in [0, 1]");
        }
        if !(0.0..=8.0).contains(&self.smoothing_sigma_voxels) {
            return bad("smoothing_sigma_voxels", "must lie in [0, 8]");
        }
        if !(1..=16).contains(&self.nms_window_voxels) {
            return bad("nms_window_voxels", "must lie in 1..=16");
        }
        if !(self.min_width_m.is_finite() && self.min_width_m >= 0.0) {
            return bad("min_width_m", "must be finite and >= 0");
        }
        if !(1..=1 << 20).contains(&self.max_grasps) {
            return bad("max_grasps", "must lie in 1..=1048576");
        }
        Ok(())
    }
}

/// Wall time of each stage of the last frame and what it produced.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct VgnTimings {
    /// Network forward pass (input copy and output checks included).
    pub network: Duration,
    /// Post-processing and decoding.
    pub decoding: Duration,
    /// The whole `infer` call (input validation included).
    pub total: Duration,
    /// Voxels that passed threshold and NMS.
    pub candidates: usize,
    /// Grasps returned (at most `max_grasps`).
    pub grasps: usize,
}

impl std::fmt::Display for VgnTimings {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let ms = |d: Duration| d.as_secs_f64() * 1e3;
        write!(
            f,
            "network {:.1} ms, decoding {:.1} ms, total {:.1} ms ({} candidates, {} grasps)",
            ms(self.network),
            ms(self.decoding),
            ms(self.total),
            self.candidates,
            self.grasps
        )
    }
}

/// The four output tensors of `vgn.onnx` for one grid (shapes checked).
#[derive(Debug)]
pub struct VgnNetworkOutputs {
    /// `[1, 1, X, Y, Z]` quality.
    pub quality: OutputTensor,
    /// `[1, 3, X, Y, Z]` baselines.
    pub baseline: OutputTensor,
    /// `[1, 3, X, Y, Z]` approaches.
    pub approach: OutputTensor,
    /// `[1, 1, X, Y, Z]` widths.
    pub width: OutputTensor,
}

impl VgnNetworkOutputs {
    /// The values as decoder input.
    pub fn view(&self) -> VgnOutputs<'_> {
        VgnOutputs {
            quality: self.quality.data(),
            baseline: self.baseline.data(),
            approach: self.approach.data(),
            width: self.width.data(),
        }
    }
}

/// A loaded VGN model: its checked card and the graph on a runtime.
pub struct VgnModel {
    card: VgnCard,
    graph: FixedGraph,
}

impl std::fmt::Debug for VgnModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("VgnModel")
            .field("card", &self.card.name)
            .field("runtime", &self.graph.runtime_name())
            .finish()
    }
}

impl VgnModel {
    /// Builds the runtime `kind` for checked model files (`ort_library` and `threads` as in
    /// [`VgnConfig`]); the graph's input and output names are checked here.
    pub fn new(
        files: &VgnModelFiles,
        kind: RuntimeKind,
        ort_library: Option<&Path>,
        threads: usize,
    ) -> Result<Self, ModelError> {
        let d = files.card.dims();
        let spec = GraphSpec {
            graph: "vgn",
            input_name: VGN_INPUT,
            input_shape: vec![1, 3, d[0], d[1], d[2]],
            output_names: VGN_OUTPUTS.iter().map(|s| s.to_string()).collect(),
        };
        let graph = FixedGraph::load(kind, &files.onnx, spec, ort_library, threads)?;
        Ok(Self {
            card: files.card.clone(),
            graph,
        })
    }

    /// Loads `dir` ([`load_vgn_dir`]) and builds the runtime.
    pub fn load(
        dir: &Path,
        workspace: &Workspace,
        gripper: &GripperModel,
        kind: RuntimeKind,
        ort_library: Option<&Path>,
        threads: usize,
    ) -> Result<Self, ModelError> {
        Self::new(
            &load_vgn_dir(dir, workspace, gripper)?,
            kind,
            ort_library,
            threads,
        )
    }

    /// The model card.
    pub fn card(&self) -> &VgnCard {
        &self.card
    }

    /// The runtime's name (`"tract"` or `"ort"`).
    pub fn runtime_name(&self) -> &'static str {
        self.graph.runtime_name()
    }

    /// Runs the network on a normals buffer (`[3, X, Y, Z]`) and checks the output shapes.
    pub fn run(&mut self, normals: &[f32]) -> Result<VgnNetworkOutputs, ModelError> {
        let d = self.card.dims();
        let mut it = self.graph.run(normals)?.into_iter();
        let mut next = |name: &str, channels: usize| {
            let t = it.next().ok_or_else(|| ModelError::GraphInterface {
                graph: "vgn",
                reason: format!("output `{name}` missing"),
            })?;
            let expected = [1, channels, d[0], d[1], d[2]];
            if t.shape() != expected {
                return Err(ModelError::GraphInterface {
                    graph: "vgn",
                    reason: format!(
                        "output `{name}` has shape {:?}, expected {expected:?}",
                        t.shape()
                    ),
                });
            }
            Ok(t)
        };
        Ok(VgnNetworkOutputs {
            quality: next(VGN_OUTPUTS[0], 1)?,
            baseline: next(VGN_OUTPUTS[1], 3)?,
            approach: next(VGN_OUTPUTS[2], 3)?,
            width: next(VGN_OUTPUTS[3], 1)?,
        })
    }
}

/// The VGN backend (see the module docs).
pub struct VgnBackend {
    model: VgnModel,
    cfg: VgnConfig,
    decoder: VgnDecoder,
    timings: VgnTimings,
}

impl std::fmt::Debug for VgnBackend {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("VgnBackend")
            .field("model", &self.model)
            .field("cfg", &self.cfg)
            .finish_non_exhaustive()
    }
}

impl VgnBackend {
    /// Loads the model of `cfg` for `workspace` and `gripper`, refusing a card that does not
    /// match them.
    pub fn new(
        cfg: VgnConfig,
        workspace: &Workspace,
        gripper: GripperModel,
    ) -> Result<Self, InferenceError> {
        cfg.validate()?;
        validate_gripper(&gripper)?;
        workspace.validate()?;
        let files = load_vgn_dir(&cfg.model_dir, workspace, &gripper)?;
        Self::from_files(cfg, &files, gripper)
    }

    /// Like [`VgnBackend::new`] for the workspace the card records; grids of another workspace
    /// are refused frame by frame.
    pub fn for_card_workspace(
        cfg: VgnConfig,
        gripper: GripperModel,
    ) -> Result<Self, InferenceError> {
        cfg.validate()?;
        let card = VgnCard::read(&cfg.model_dir)?;
        card.validate()?;
        Self::new(cfg, &card.workspace(), gripper)
    }

    /// Builds the backend from already checked model files for `gripper`.
    pub fn from_files(
        cfg: VgnConfig,
        files: &VgnModelFiles,
        gripper: GripperModel,
    ) -> Result<Self, InferenceError> {
        cfg.validate()?;
        validate_gripper(&gripper)?;
        if cfg.min_width_m >= gripper.max_opening_m {
            return Err(InferenceError::InvalidConfig {
                field: "min_width_m",
                reason: "must be below the gripper's maximum opening",
            });
        }
        let model = VgnModel::new(files, cfg.runtime, cfg.ort_library.as_deref(), cfg.threads)?;
        Ok(Self {
            model,
            decoder: VgnDecoder::new(VgnDecodeSettings::new(&cfg, &gripper)),
            cfg,
            timings: VgnTimings::default(),
        })
    }

    /// The model card.
    pub fn card(&self) -> &VgnCard {
        self.model.card()
    }

    /// The loaded model (for stage-by-stage use).
    pub fn model_mut(&mut self) -> &mut VgnModel {
        &mut self.model
    }

    /// The decoder (its settings and the last frame's processed quality grid).
    pub fn decoder(&self) -> &VgnDecoder {
        &self.decoder
    }

    /// Stage timings of the last successful [`InferenceBackend::infer`].
    pub fn last_timings(&self) -> VgnTimings {
        self.timings
    }
}

impl InferenceBackend for VgnBackend {
    /// The network's forward pass and the decoding sample nothing: the seed is unused.
    fn uses_seed(&self) -> bool {
        false
    }

    fn name(&self) -> &str {
        "vgn"
    }

    fn infer(
        &mut self,
        grid: &NormalGridView<'_>,
        _seed: u64,
    ) -> Result<Vec<GraspConfiguration>, InferenceError> {
        let start = Instant::now();
        validate_grid(grid)?;
        self.model.card().check_workspace(&grid.workspace)?;
        let workspace = self.model.card().workspace();
        let mut t = VgnTimings::default();

        let t0 = Instant::now();
        let outputs = self.model.run(grid.normals)?;
        t.network = t0.elapsed();

        let t0 = Instant::now();
        let mut out = Vec::new();
        self.decoder.decode(&workspace, &outputs.view(), &mut out)?;
        drop(outputs);
        t.decoding = t0.elapsed();
        t.total = start.elapsed();
        t.candidates = self.decoder.candidate_count();
        t.grasps = out.len();
        self.timings = t;
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn config_defaults_and_ranges() {
        let c = VgnConfig::default();
        c.validate().unwrap();
        assert_eq!(c.model_dir, PathBuf::from("models/vgn"));
        assert_eq!(c.quality_threshold, 0.9);
        assert_eq!(c.nms_window_voxels, 4);
        let cases: Vec<(&str, VgnConfig)> = vec![
            (
                "model_dir",
                VgnConfig {
                    model_dir: PathBuf::new(),
                    ..c.clone()
                },
            ),
            (
                "threads",
                VgnConfig {
                    threads: 5000,
                    ..c.clone()
                },
            ),
            (
                "ort_library",
                VgnConfig {
                    ort_library: Some(PathBuf::new()),
                    ..c.clone()
                },
            ),
            (
                "quality_threshold",
                VgnConfig {
                    quality_threshold: f32::NAN,
                    ..c.clone()
                },
            ),
            (
                "smoothing_sigma_voxels",
                VgnConfig {
                    smoothing_sigma_voxels: -1.0,
                    ..c.clone()
                },
            ),
            (
                "nms_window_voxels",
                VgnConfig {
                    nms_window_voxels: 0,
                    ..c.clone()
                },
            ),
            (
                "min_width_m",
                VgnConfig {
                    min_width_m: f32::INFINITY,
                    ..c.clone()
                },
            ),
            (
                "max_grasps",
                VgnConfig {
                    max_grasps: 0,
                    ..c.clone()
                },
            ),
        ];
        for (field, cfg) in cases {
            match cfg.validate() {
                Err(InferenceError::InvalidConfig { field: f, .. }) => assert_eq!(f, field),
                other => panic!("{field}: {other:?}"),
            }
        }
    }
}
