//! Grasp inference: normal grid → grasp configurations.
//!
//! Every backend implements [`InferenceBackend`]: it takes one [`NormalGridView`] (the output of
//! fusion) and returns dense [`GraspConfiguration`]s — a contact point, a baseline, 18 approach
//! vectors with collision scores, an opening width, an antipodal quality and a concentration `κ`.
//! Backends are built from a [`BackendConfig`] (TOML/JSON, tagged by `kind`) with
//! [`backend_from_config`] or [`backend_for_workspace`].
//!
//! Every backend first runs [`validate_grid`] (the grid's own [`NormalGridView::validate`] in
//! `psgrasp-fusion`) and checks its gripper with [`validate_gripper`]
//! ([`GripperModel::validate`] in `psgrasp-geometry`); their errors keep their own
//! [`InferenceError`] variants.
//!
//! The analytic backend ([`AnalyticBackend`]) is the GPD-style geometric baseline: antipodal contact
//! pairs found by casting rays through the TSDF, collision scores from the occupancy of the
//! observed scene ([`OccupancyGrid`] / [`SceneCollisionChecker`], re-exported from
//! `psgrasp-collision`, which grasp selection uses too).
//!
//! The learned backend ([`LearnedBackend`], `kind = "learned"`) runs the paper's two-stage network
//! exported to ONNX (a model directory with a checked model card) on tract or, with the cargo
//! feature `ort`, ONNX Runtime; see [`learned`].
//!
//! The VGN backend ([`VgnBackend`], `kind = "vgn"`) is the volumetric baseline of Breyer et al.
//! (per-voxel quality, orientation and width from a fully convolutional network, retrained on
//! psgrasp's data), run on the same runtimes with VGN's post-processing; see [`vgn`].
//!
//! Both model backends run their graphs on [`onnx`] (the runtimes: [`RuntimeKind`], the
//! single-input graph engine, tract's thread pool, ONNX Runtime's sessions) and report model
//! problems — card, files, graph interface, runtime — as a [`ModelError`].
//!
//! Modules: [`analytic`] (the backend and its settings), [`learned`] (model card, two-graph
//! runtimes, feature sampling, decoding), [`vgn`] (card, post-processing), [`onnx`] (the graph
//! runtimes both use).
#![warn(missing_docs)]

pub mod analytic;
mod backend_de;
pub mod learned;
mod model_error;
pub mod native;
pub mod onnx;
pub mod vgn;

pub use analytic::{AnalyticBackend, AnalyticConfig, AnalyticStats, ContactRegion};
pub use learned::{
    LearnedBackend, LearnedConfig, LearnedModel, ModelCard, ModelError, RuntimeKind, StageTimings,
};
pub use psgrasp_collision::{OccupancyConfig, OccupancyGrid, SceneCollisionChecker};
pub use psgrasp_fusion::TSDF_RANGE_TOLERANCE;
pub use vgn::{VgnBackend, VgnCard, VgnConfig, VgnTimings};

use psgrasp_collision::CollisionError;
use psgrasp_fusion::{GridError, NormalGridView};
use psgrasp_geometry::{BinModel, GeometryError, GraspConfiguration, GripperModel, Workspace};
use serde::Serialize;
use std::path::Path;

/// Errors raised by inference backends; the errors of the grid checks (`psgrasp-fusion`), the
/// gripper check (`psgrasp-geometry`) and the occupancy grid (`psgrasp-collision`) arrive as the
/// matching variants below.
#[derive(Debug, thiserror::Error)]
pub enum InferenceError {
    /// The grid's workspace description is unusable (zero dimension, bad voxel size); the
    /// message is the workspace check's own ("invalid workspace: ...").
    #[error(transparent)]
    Workspace(#[from] GeometryError),
    /// The normal grid is unusable (buffer lengths, non-finite values, TSDF range, truncation);
    /// the checks and messages are the grid's own (`NormalGridView::validate`).
    #[error(transparent)]
    Grid(#[from] GridError),
    /// The gripper model is unusable (non-positive or non-finite sizes).
    #[error("invalid gripper model: {0}")]
    InvalidGripper(&'static str),
    /// A configuration value is out of its valid range.
    #[error("invalid configuration field `{field}`: {reason}")]
    InvalidConfig {
        /// Name of the field.
        field: &'static str,
        /// What the valid range is.
        reason: &'static str,
    },
    /// A learned or VGN model could not be loaded or run (card mismatch, corrupt file, runtime
    /// error); message and cause are the [`ModelError`]'s own.
    #[error(transparent)]
    Model(#[from] ModelError),
    /// A backend failed for a reason of its own (model file, runtime, device ...).
    #[error("backend `{backend}` failed")]
    Backend {
        /// The backend's [`InferenceBackend::name`].
        backend: String,
        /// The underlying error.
        #[source]
        source: Box<dyn std::error::Error + Send + Sync + 'static>,
    },
}

impl From<psgrasp_geometry::OutOfRange> for InferenceError {
    fn from(e: psgrasp_geometry::OutOfRange) -> Self {
        Self::InvalidConfig {
            field: e.field,
            reason: e.reason,
        }
    }
}

/// A grasp inference backend: one normal grid in, grasp configurations out.
pub trait InferenceBackend: Send {
    /// Short name for logs and records, e.g. "analytic".
    fn name(&self) -> &str;
    /// Grasp configurations for one normal grid; `seed` makes any sampling deterministic per frame.
    fn infer(
        &mut self,
        grid: &NormalGridView<'_>,
        seed: u64,
    ) -> Result<Vec<GraspConfiguration>, InferenceError>;
    /// Whether [`InferenceBackend::infer`]'s output can depend on `seed` (true unless the backend
    /// samples nothing). A backend that returns false promises the same configurations for the
    /// same grid under every seed; the evaluation then plays its rounds on noise-free scenes once
    /// for all run seeds.
    fn uses_seed(&self) -> bool {
        true
    }
}

/// A borrowed backend is a backend (the evaluation lends its detectors to a perception chain).
impl<B: InferenceBackend + ?Sized> InferenceBackend for &mut B {
    fn name(&self) -> &str {
        (**self).name()
    }

    fn infer(
        &mut self,
        grid: &NormalGridView<'_>,
        seed: u64,
    ) -> Result<Vec<GraspConfiguration>, InferenceError> {
        (**self).infer(grid, seed)
    }

    fn uses_seed(&self) -> bool {
        (**self).uses_seed()
    }
}

/// Which backend to run and its settings; `kind` selects the variant (`kind = "analytic"`), the
/// other keys are that backend's fields. Every key is optional: without `kind` the table is the
/// default backend's ([`BackendConfig::default`], analytic), and its missing keys take their
/// defaults.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum BackendConfig {
    /// The geometric antipodal backend ([`AnalyticBackend`]).
    Analytic(AnalyticConfig),
    /// The learned ONNX backend ([`LearnedBackend`]).
    Learned(LearnedConfig),
    /// The VGN-style volumetric baseline ([`VgnBackend`]).
    Vgn(VgnConfig),
}

impl Default for BackendConfig {
    fn default() -> Self {
        Self::Analytic(AnalyticConfig::default())
    }
}

impl BackendConfig {
    /// Checks the backend's settings (ranges; the model files are checked when it is built).
    pub fn validate(&self) -> Result<(), InferenceError> {
        match self {
            Self::Analytic(c) => c.validate(),
            Self::Learned(c) => c.validate(),
            Self::Vgn(c) => c.validate(),
        }
    }

    /// The `kind` tag of this configuration.
    pub fn kind(&self) -> &'static str {
        match self {
            Self::Analytic(_) => "analytic",
            Self::Learned(_) => "learned",
            Self::Vgn(_) => "vgn",
        }
    }

    /// The configuration that runs the model directory `dir` with `threads` runtime threads:
    /// `kind = "vgn"` for a VGN card ([`vgn::is_vgn_model_dir`]), otherwise `kind = "learned"`
    /// (whose checks report what is wrong with any other card). Other settings are defaults.
    pub fn for_model_dir(dir: &Path, threads: usize) -> Self {
        if vgn::is_vgn_model_dir(dir) {
            Self::Vgn(VgnConfig {
                model_dir: dir.to_owned(),
                threads,
                ..Default::default()
            })
        } else {
            Self::Learned(LearnedConfig {
                model_dir: dir.to_owned(),
                threads,
                ..Default::default()
            })
        }
    }

    /// Joins a relative model directory and `ort_library` onto `base` (the directory of the
    /// file the configuration was read from); absolute paths and model-free kinds are unchanged.
    pub fn resolve_paths(&mut self, base: &Path) {
        let (model_dir, ort_library) = match self {
            Self::Analytic(_) => return,
            Self::Learned(l) => (&mut l.model_dir, &mut l.ort_library),
            Self::Vgn(v) => (&mut v.model_dir, &mut v.ort_library),
        };
        if model_dir.is_relative() {
            *model_dir = base.join(&*model_dir);
        }
        if let Some(lib) = ort_library {
            if lib.is_relative() {
                *lib = base.join(&*lib);
            }
        }
    }

    /// An analytic backend without its own `contact_region` gets the interior of `bin` (inset by
    /// `inset_m`): contacts on the thin bin walls are never pickable. Other kinds are unchanged.
    pub fn with_bin_interior_contacts(mut self, bin: &BinModel, inset_m: f32) -> Self {
        if let Self::Analytic(a) = &mut self {
            if a.contact_region.is_none() {
                a.contact_region = Some(ContactRegion::inside_bin(bin, inset_m));
            }
        }
        self
    }
}

/// Builds the backend described by `cfg` for `gripper`, validating both. A model's card (learned
/// or VGN) is checked against `gripper` here and against each grid's workspace per frame; prefer
/// [`backend_for_workspace`] where the workspace is known, so a mismatch fails at start-up.
pub fn backend_from_config(
    cfg: &BackendConfig,
    gripper: GripperModel,
) -> Result<Box<dyn InferenceBackend>, InferenceError> {
    match cfg {
        BackendConfig::Analytic(c) => Ok(Box::new(AnalyticBackend::new(c.clone(), gripper)?)),
        BackendConfig::Learned(c) => Ok(Box::new(LearnedBackend::for_card_workspace(
            c.clone(),
            gripper,
        )?)),
        BackendConfig::Vgn(c) => Ok(Box::new(VgnBackend::for_card_workspace(
            c.clone(),
            gripper,
        )?)),
    }
}

/// Builds the backend described by `cfg` for the pipeline's `workspace` and `gripper`; a model
/// (learned or VGN) whose card records another grid or gripper is refused here.
pub fn backend_for_workspace(
    cfg: &BackendConfig,
    workspace: &Workspace,
    gripper: GripperModel,
) -> Result<Box<dyn InferenceBackend>, InferenceError> {
    match cfg {
        BackendConfig::Analytic(c) => Ok(Box::new(AnalyticBackend::new(c.clone(), gripper)?)),
        BackendConfig::Learned(c) => Ok(Box::new(LearnedBackend::new(
            c.clone(),
            workspace,
            gripper,
        )?)),
        BackendConfig::Vgn(c) => Ok(Box::new(VgnBackend::new(c.clone(), workspace, gripper)?)),
    }
}

/// Checks a normal grid before inference: valid workspace, buffer lengths, finite values, TSDF in
/// [−1, 1] (up to [`TSDF_RANGE_TOLERANCE`]) and a positive truncation distance
/// ([`NormalGridView::validate`], its errors as the matching [`InferenceError`] variants).
pub fn validate_grid(grid: &NormalGridView<'_>) -> Result<(), InferenceError> {
    Ok(grid.validate()?)
}

/// Checks that a gripper model has positive finite sizes ([`GripperModel::validate`], reported as
/// [`InferenceError::InvalidGripper`]).
pub fn validate_gripper(gripper: &GripperModel) -> Result<(), InferenceError> {
    gripper.validate().map_err(gripper_error)
}

/// A gripper model's validation error as an [`InferenceError`].
fn gripper_error(e: GeometryError) -> InferenceError {
    match e {
        GeometryError::InvalidGripper(reason) => InferenceError::InvalidGripper(reason),
        other => InferenceError::Workspace(other),
    }
}

impl From<CollisionError> for InferenceError {
    /// Grid, occupancy-setting and gripper errors of the collision checker keep their variants.
    fn from(e: CollisionError) -> Self {
        match e {
            CollisionError::Grid(e) => e.into(),
            CollisionError::InvalidConfig { field, reason } => {
                Self::InvalidConfig { field, reason }
            }
            CollisionError::Gripper(e) => gripper_error(e),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use psgrasp_fusion::NormalGrid;
    use psgrasp_geometry::Workspace;

    #[test]
    fn bin_interior_applies_only_to_analytic_backends_without_a_region() {
        let bin = BinModel::default();
        let inside = ContactRegion::inside_bin(&bin, 0.005);
        let BackendConfig::Analytic(a) =
            BackendConfig::default().with_bin_interior_contacts(&bin, 0.005)
        else {
            panic!("analytic expected");
        };
        assert_eq!(a.contact_region, Some(inside));
        let own = ContactRegion {
            min_m: [0.1; 3],
            max_m: [0.2; 3],
        };
        let configured = BackendConfig::Analytic(AnalyticConfig {
            contact_region: Some(own),
            ..Default::default()
        });
        assert_eq!(
            configured.clone().with_bin_interior_contacts(&bin, 0.005),
            configured
        );
        let learned = BackendConfig::Learned(LearnedConfig::default());
        assert_eq!(
            learned.clone().with_bin_interior_contacts(&bin, 0.005),
            learned
        );
    }

    fn small_grid() -> NormalGrid {
        let workspace = Workspace {
            dims: [4, 5, 6],
            voxel_size_m: 0.01,
        };
        let n = workspace.voxel_count();
        NormalGrid {
            workspace,
            normals: vec![0.0; 3 * n],
            tsdf: vec![1.0; n],
            truncation_m: 0.03,
        }
    }

    #[test]
    fn valid_grid_passes() {
        assert!(validate_grid(&small_grid().view()).is_ok());
    }

    #[test]
    fn bad_grids_are_reported_precisely() {
        let mut g = small_grid();
        g.tsdf.pop();
        assert!(matches!(
            validate_grid(&g.view()),
            Err(InferenceError::Grid(GridError::GridSizeMismatch {
                channel: "tsdf",
                got: 119,
                expected: 120
            }))
        ));

        let mut g = small_grid();
        g.normals.push(0.0);
        assert!(matches!(
            validate_grid(&g.view()),
            Err(InferenceError::Grid(GridError::GridSizeMismatch {
                channel: "normals",
                ..
            }))
        ));

        let mut g = small_grid();
        g.tsdf[17] = f32::NAN;
        assert!(matches!(
            validate_grid(&g.view()),
            Err(InferenceError::Grid(GridError::NonFiniteInput {
                channel: "tsdf",
                index: 17
            }))
        ));

        let mut g = small_grid();
        g.normals[200] = f32::INFINITY;
        assert!(matches!(
            validate_grid(&g.view()),
            Err(InferenceError::Grid(GridError::NonFiniteInput {
                channel: "normals",
                index: 200
            }))
        ));

        let mut g = small_grid();
        g.tsdf[3] = -1.5;
        assert!(matches!(
            validate_grid(&g.view()),
            Err(InferenceError::Grid(GridError::TsdfOutOfRange {
                index: 3,
                ..
            }))
        ));

        let mut g = small_grid();
        g.truncation_m = 0.0;
        assert!(matches!(
            validate_grid(&g.view()),
            Err(InferenceError::Grid(GridError::InvalidTruncation(_)))
        ));

        let mut g = small_grid();
        g.workspace.dims = [0, 5, 6];
        assert!(matches!(
            validate_grid(&g.view()),
            Err(InferenceError::Grid(GridError::Workspace(_)))
        ));
    }

    #[test]
    fn backend_config_parses_from_toml_with_defaults() {
        let cfg: BackendConfig =
            toml::from_str("kind = \"analytic\"\nmin_quality = 0.7\n").unwrap();
        let BackendConfig::Analytic(a) = &cfg else {
            panic!("analytic expected")
        };
        assert_eq!(a.min_quality, 0.7);
        assert_eq!(
            a.max_configurations,
            AnalyticConfig::default().max_configurations
        );
        assert_eq!(cfg.kind(), "analytic");
        assert!(toml::from_str::<BackendConfig>("kind = \"onnx-nope\"\n").is_err());
        let with_region: BackendConfig = toml::from_str(
            "kind = \"analytic\"\n[contact_region]\nmin_m = [0.0, 0.1, 0.02]\nmax_m = [0.5, 0.4, 0.3]\n",
        )
        .unwrap();
        let BackendConfig::Analytic(a) = &with_region else {
            panic!("analytic expected")
        };
        assert_eq!(a.contact_region.unwrap().max_m, [0.5, 0.4, 0.3]);
        assert!(
            toml::from_str::<BackendConfig>("kind = \"analytic\"\nmin_qualty = 0.7\n").is_err(),
            "typos must not be ignored"
        );
        let backend = backend_from_config(&cfg, GripperModel::default()).unwrap();
        assert_eq!(backend.name(), "analytic");
    }

    #[test]
    fn backend_config_without_kind_is_the_default_backend() {
        let cfg: BackendConfig = toml::from_str("min_quality = 0.7\n").unwrap();
        assert_eq!(cfg.kind(), BackendConfig::default().kind());
        let BackendConfig::Analytic(a) = &cfg else {
            panic!("analytic expected")
        };
        assert_eq!(a.min_quality, 0.7);
        assert_eq!(
            toml::from_str::<BackendConfig>("").unwrap(),
            BackendConfig::default()
        );
        // The default backend's keys only: another backend's key is unknown to it.
        let err = toml::from_str::<BackendConfig>("model_dir = \"m\"\n")
            .unwrap_err()
            .to_string();
        assert!(err.contains("unknown field `model_dir`"), "{err}");
        // JSON with the nulls of unset options (run records) still round trips.
        for cfg in [
            BackendConfig::default(),
            BackendConfig::for_model_dir(Path::new("/nonexistent/m"), 2),
        ] {
            let json = serde_json::to_string(&cfg).unwrap();
            assert!(json.contains("null"), "{json}");
            assert_eq!(serde_json::from_str::<BackendConfig>(&json).unwrap(), cfg);
        }
    }

    #[test]
    fn invalid_backend_settings_are_rejected() {
        let cfg = BackendConfig::Analytic(AnalyticConfig {
            min_quality: 1.5,
            ..AnalyticConfig::default()
        });
        assert!(matches!(
            backend_from_config(&cfg, GripperModel::default()),
            Err(InferenceError::InvalidConfig {
                field: "min_quality",
                ..
            })
        ));
        let gripper = GripperModel {
            max_opening_m: -0.1,
            ..GripperModel::default()
        };
        assert!(matches!(
            backend_from_config(&BackendConfig::default(), gripper),
            Err(InferenceError::InvalidGripper(_))
        ));
    }
}
