//! The model card (`card.json`) and loading a model directory.
//!
//! A model directory holds `card.json`, `unet.onnx` and `mlp.onnx` (the card names the files).
//! [`load_model_dir`] reads the card, checks it against the pipeline (workspace grid, gripper,
//! the 18 approaches) and itself, reads both ONNX files and checks their SHA-256 against the card.
//! Every mismatch is a [`ModelError`] naming the card field.
pub use crate::model_error::ModelError;
use psgrasp_geometry::{GripperModel, Workspace, N_APPROACHES};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use std::path::{Component, Path, PathBuf};

/// The `format` string of a psgrasp model card.
pub const CARD_FORMAT: &str = "psgrasp-model";
/// The card `format_version` this crate reads.
pub const CARD_FORMAT_VERSION: u32 = 1;
/// File name of the card inside a model directory.
pub const CARD_FILE: &str = "card.json";
/// Tolerance (metres) for the gripper sizes recorded in the card.
pub const GRIPPER_TOLERANCE_M: f32 = 1e-4;
/// Tolerance (radians) for the approach angle range recorded in the card.
pub const ANGLE_TOLERANCE_RAD: f32 = 1e-4;
/// Relative tolerance for the voxel size recorded in the card.
pub const VOXEL_SIZE_REL_TOLERANCE: f32 = 1e-5;
/// The class order of the label logits.
pub const CLASSES: [&str; 3] = ["empty", "contact", "gripper"];
/// Sub-voxel points per contact voxel (2 per axis).
pub const SUBVOXELS_PER_CONTACT: usize = 8;

/// The contents of `card.json` (network contract version 1).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelCard {
    /// Always [`CARD_FORMAT`].
    pub format: String,
    /// Always [`CARD_FORMAT_VERSION`] for cards this crate reads.
    pub format_version: u32,
    /// Model name, e.g. `psgrasp-8app-b8`.
    pub name: String,
    /// Training variant.
    pub variant: ModelVariant,
    /// What wrote the export (package and framework versions).
    #[serde(default)]
    pub generator: String,
    /// The two ONNX graphs.
    pub files: CardFiles,
    /// The input grid.
    pub grid: CardGrid,
    /// Class names of the label logits, in channel order.
    pub classes: Vec<String>,
    /// U-Net structure.
    pub unet: CardUnet,
    /// MLP head structure.
    pub mlp: CardMlp,
    /// Base concentration κ₀ of the baseline distribution.
    pub kappa0: f32,
    /// False for the "wo κ" ablation (the graph outputs the constant κ₀).
    pub kappa_learned: bool,
    /// The approach vectors the collision head was trained for.
    pub approaches: CardApproaches,
    /// The gripper the labels were made for.
    pub gripper: CardGripper,
    /// Suggested decision thresholds.
    pub thresholds: CardThresholds,
    /// Decoding settings.
    pub inference: CardInference,
    /// Provenance of the training run (free-form beyond the fields named here).
    #[serde(default)]
    pub training: serde_json::Value,
    /// Held-out validation figures (free-form beyond the fields named here).
    #[serde(default)]
    pub validation: serde_json::Value,
}

/// The training variant of a model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum ModelVariant {
    /// The full model: 18 approaches with collision scores.
    #[serde(rename = "8app")]
    EightApproach,
    /// Single approach, baseline with learned κ.
    #[serde(rename = "1app-kappa")]
    SingleApproachKappa,
    /// Single approach, cosine baseline loss (no κ).
    #[serde(rename = "1app-cosine")]
    SingleApproachCosine,
}

/// `files` of the card.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct CardFiles {
    /// The U-Net graph.
    pub unet: CardFile,
    /// The MLP graph.
    pub mlp: CardFile,
}

/// One file of the model directory.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct CardFile {
    /// Path relative to the model directory (no `..`, not absolute).
    pub path: String,
    /// Lower-case hex SHA-256 of the file.
    pub sha256: String,
}

/// `grid` of the card.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CardGrid {
    /// Voxels along x, y, z.
    pub dims: [u32; 3],
    /// Voxel edge in metres.
    pub voxel_size_m: f32,
    /// Input kind; only `"normals"` exists.
    pub input: String,
    /// Input channels; 3.
    pub input_channels: u32,
}

/// `unet` of the card.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct CardUnet {
    /// Encoder levels L.
    pub levels: u32,
    /// Channels C_l of each encoder level.
    pub channels: Vec<u32>,
    /// Output names of the encoder feature grids, `enc0..enc{L-1}`.
    pub feature_outputs: Vec<String>,
}

/// `mlp` of the card.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct CardMlp {
    /// Feature vector size F = Σ C_l.
    pub feature_dim: u32,
    /// Hidden layer widths (informational).
    #[serde(default)]
    pub hidden: Vec<u32>,
}

/// `approaches` of the card.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CardApproaches {
    /// Number of approach vectors; must be [`N_APPROACHES`].
    pub count: u32,
    /// First rotation angle γ₀ (π/2).
    pub gamma_min_rad: f32,
    /// Last rotation angle (3π/2).
    pub gamma_max_rad: f32,
}

/// `gripper` of the card.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CardGripper {
    /// Maximum opening; the width head is `max_opening_m · sigmoid(raw)`.
    pub max_opening_m: f32,
    /// TCP to palm distance d used for the approach points `t_i = tcp − a_i·d`.
    pub approach_depth_m: f32,
}

/// `thresholds` of the card.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CardThresholds {
    /// Contact voxels have `P_contact` at least this.
    pub contact_probability: f32,
    /// Suggested quality threshold for selection.
    pub quality: f32,
    /// Suggested collision-score threshold for selection.
    pub collision: f32,
}

/// `inference` of the card.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct CardInference {
    /// Points per contact voxel; must be [`SUBVOXELS_PER_CONTACT`].
    pub subvoxels_per_contact: u32,
    /// Keep only the best approach per configuration.
    pub single_approach: bool,
}

/// A model directory whose card was checked and whose ONNX files match their SHA-256.
#[derive(Debug, Clone)]
pub struct ModelFiles {
    /// The model directory.
    pub dir: PathBuf,
    /// The checked card.
    pub card: ModelCard,
    /// Bytes of `unet.onnx`.
    pub unet_onnx: Vec<u8>,
    /// Bytes of `mlp.onnx`.
    pub mlp_onnx: Vec<u8>,
}

fn mismatch(field: &'static str, card: impl ToString, expected: impl ToString) -> ModelError {
    ModelError::Mismatch {
        field,
        card: card.to_string(),
        expected: expected.to_string(),
    }
}

fn invalid(field: &'static str, reason: impl Into<String>) -> ModelError {
    ModelError::InvalidCard {
        field,
        reason: reason.into(),
    }
}

fn close(a: f32, b: f32, tol: f32) -> bool {
    a.is_finite() && b.is_finite() && (a - b).abs() <= tol
}

/// Parses a card of any format from JSON text; `path` is only used in the error.
pub(crate) fn card_from_json<T: serde::de::DeserializeOwned>(
    text: &str,
    path: &Path,
) -> Result<T, ModelError> {
    serde_json::from_str(text).map_err(|source| ModelError::CardJson {
        path: path.to_owned(),
        source,
    })
}

/// Reads and parses `dir/card.json` of any format (no checks beyond the JSON schema).
pub(crate) fn read_card<T: serde::de::DeserializeOwned>(dir: &Path) -> Result<T, ModelError> {
    let path = dir.join(CARD_FILE);
    let text = std::fs::read_to_string(&path).map_err(|source| ModelError::Io {
        path: path.clone(),
        source,
    })?;
    card_from_json(&text, &path)
}

impl CardFile {
    /// Checks the path (relative, inside the model directory) and the SHA-256 syntax; `field`
    /// names the card entry in errors.
    pub(crate) fn validate(&self, field: &'static str) -> Result<(), ModelError> {
        check_relative_path(field, &self.path)?;
        if self.sha256.len() != 64 || !self.sha256.bytes().all(|b| b.is_ascii_hexdigit()) {
            return Err(invalid(field, "sha256 must be 64 hex digits"));
        }
        Ok(())
    }

    /// Reads the file from `dir`, refusing it if its SHA-256 differs from the card.
    pub(crate) fn read_checked(&self, dir: &Path) -> Result<Vec<u8>, ModelError> {
        let path = dir.join(&self.path);
        let bytes = std::fs::read(&path).map_err(|source| ModelError::Io {
            path: path.clone(),
            source,
        })?;
        let actual = sha256_hex(&bytes);
        if !actual.eq_ignore_ascii_case(&self.sha256) {
            return Err(ModelError::Sha256Mismatch {
                path,
                expected: self.sha256.clone(),
                actual,
            });
        }
        Ok(bytes)
    }
}

impl CardGrid {
    /// The workspace the model was trained for.
    pub fn workspace(&self) -> Workspace {
        Workspace {
            dims: self.dims,
            voxel_size_m: self.voxel_size_m,
        }
    }

    /// Checks the input kind (`normals`, 3 channels) and that the grid is a valid workspace.
    pub fn validate(&self) -> Result<(), ModelError> {
        if self.input != "normals" {
            return Err(mismatch("grid.input", &self.input, "normals"));
        }
        if self.input_channels != 3 {
            return Err(mismatch("grid.input_channels", self.input_channels, 3));
        }
        self.workspace()
            .validate()
            .map_err(|e| invalid("grid", e.to_string()))
    }

    /// Checks the grid dims and voxel size (within [`VOXEL_SIZE_REL_TOLERANCE`]) against
    /// `workspace`.
    pub fn check_workspace(&self, workspace: &Workspace) -> Result<(), ModelError> {
        if self.dims != workspace.dims {
            return Err(mismatch(
                "grid.dims",
                format!("{:?}", self.dims),
                format!("{:?}", workspace.dims),
            ));
        }
        let s = workspace.voxel_size_m;
        if !close(self.voxel_size_m, s, VOXEL_SIZE_REL_TOLERANCE * s.abs()) {
            return Err(mismatch("grid.voxel_size_m", self.voxel_size_m, s));
        }
        Ok(())
    }
}

impl CardGripper {
    /// Checks that the maximum opening is positive and the approach depth non-negative.
    pub fn validate(&self) -> Result<(), ModelError> {
        if !(self.max_opening_m.is_finite() && self.max_opening_m > 0.0) {
            return Err(invalid(
                "gripper.max_opening_m",
                "must be positive and finite",
            ));
        }
        if !(self.approach_depth_m.is_finite() && self.approach_depth_m >= 0.0) {
            return Err(invalid(
                "gripper.approach_depth_m",
                "must be finite and >= 0",
            ));
        }
        Ok(())
    }

    /// Checks the maximum opening and the approach depth (finger length − `tip_beyond_tcp_m`)
    /// against `gripper`, within [`GRIPPER_TOLERANCE_M`].
    pub fn check(&self, gripper: &GripperModel) -> Result<(), ModelError> {
        if !close(
            self.max_opening_m,
            gripper.max_opening_m,
            GRIPPER_TOLERANCE_M,
        ) {
            return Err(mismatch(
                "gripper.max_opening_m",
                self.max_opening_m,
                gripper.max_opening_m,
            ));
        }
        let depth = gripper.tcp_to_palm_m();
        if !close(self.approach_depth_m, depth, GRIPPER_TOLERANCE_M) {
            return Err(mismatch(
                "gripper.approach_depth_m",
                self.approach_depth_m,
                depth,
            ));
        }
        Ok(())
    }
}

impl ModelCard {
    /// Parses a card from JSON text; `path` is only used in the error.
    pub fn from_json(text: &str, path: &Path) -> Result<Self, ModelError> {
        card_from_json(text, path)
    }

    /// Reads and parses `dir/card.json` (no checks beyond the JSON schema).
    pub fn read(dir: &Path) -> Result<Self, ModelError> {
        read_card(dir)
    }

    /// Level count L.
    pub fn levels(&self) -> usize {
        self.unet.levels as usize
    }

    /// Grid dims as `usize`.
    pub fn dims(&self) -> [usize; 3] {
        self.grid.dims.map(|d| d as usize)
    }

    /// Dims of encoder level `l`: `dims / 2^l`.
    pub fn level_dims(&self, l: usize) -> [usize; 3] {
        self.dims().map(|d| d >> l)
    }

    /// Feature size F = Σ C_l.
    pub fn feature_dim(&self) -> usize {
        self.mlp.feature_dim as usize
    }

    /// The workspace the model was trained for.
    pub fn workspace(&self) -> Workspace {
        self.grid.workspace()
    }

    /// Checks the card on its own: format, version, internal consistency and value ranges.
    pub fn validate(&self) -> Result<(), ModelError> {
        if self.format != CARD_FORMAT {
            return Err(ModelError::Format {
                found: self.format.clone(),
            });
        }
        if self.format_version != CARD_FORMAT_VERSION {
            return Err(ModelError::FormatVersion {
                found: self.format_version,
            });
        }
        self.files.unet.validate("files.unet")?;
        self.files.mlp.validate("files.mlp")?;
        self.grid.validate()?;
        if self.classes.iter().map(String::as_str).ne(CLASSES) {
            return Err(mismatch(
                "classes",
                format!("{:?}", self.classes),
                format!("{CLASSES:?}"),
            ));
        }
        let levels = self.levels();
        if !(1..=8).contains(&levels) {
            return Err(invalid("unet.levels", "must lie in 1..=8"));
        }
        if self.unet.channels.len() != levels || self.unet.channels.contains(&0) {
            return Err(invalid(
                "unet.channels",
                format!("needs {levels} positive channel counts"),
            ));
        }
        let expected_names: Vec<String> = (0..levels).map(|l| format!("enc{l}")).collect();
        if self.unet.feature_outputs != expected_names {
            return Err(invalid(
                "unet.feature_outputs",
                format!("must be {expected_names:?}"),
            ));
        }
        let div = 1u32 << (levels - 1);
        if self.grid.dims.iter().any(|d| d % div != 0) {
            return Err(invalid(
                "grid.dims",
                format!("must be divisible by 2^(levels-1) = {div}"),
            ));
        }
        // In u64: channel counts near u32::MAX must not wrap into a matching sum.
        let channel_sum: u64 = self.unet.channels.iter().map(|&c| u64::from(c)).sum();
        if u64::from(self.mlp.feature_dim) != channel_sum {
            return Err(invalid(
                "mlp.feature_dim",
                format!(
                    "is {}, Σ unet.channels = {channel_sum}",
                    self.mlp.feature_dim
                ),
            ));
        }
        if !(self.kappa0.is_finite() && self.kappa0 > 0.0) {
            return Err(invalid("kappa0", "must be positive and finite"));
        }
        for (field, v) in [
            (
                "thresholds.contact_probability",
                self.thresholds.contact_probability,
            ),
            ("thresholds.quality", self.thresholds.quality),
            ("thresholds.collision", self.thresholds.collision),
        ] {
            if !(0.0..=1.0).contains(&v) {
                return Err(invalid(field, "must lie in [0, 1]"));
            }
        }
        self.gripper.validate()
    }

    /// Checks the card against the pipeline: grid dims and voxel size, the approach count and
    /// angle range, the gripper's maximum opening and approach depth (within
    /// [`GRIPPER_TOLERANCE_M`]) and the sub-voxel count.
    pub fn check_pipeline(
        &self,
        workspace: &Workspace,
        gripper: &GripperModel,
    ) -> Result<(), ModelError> {
        self.check_workspace(workspace)?;
        self.check_gripper(gripper)
    }

    /// Checks the grid dims and voxel size against `workspace`.
    pub fn check_workspace(&self, workspace: &Workspace) -> Result<(), ModelError> {
        self.grid.check_workspace(workspace)
    }

    /// Checks the approach count and angle range, the gripper's maximum opening and approach
    /// depth (within [`GRIPPER_TOLERANCE_M`]) and the sub-voxel count.
    pub fn check_gripper(&self, gripper: &GripperModel) -> Result<(), ModelError> {
        if self.approaches.count as usize != N_APPROACHES {
            return Err(mismatch(
                "approaches.count",
                self.approaches.count,
                N_APPROACHES,
            ));
        }
        let (lo, hi) = (
            std::f32::consts::FRAC_PI_2,
            3.0 * std::f32::consts::FRAC_PI_2,
        );
        if !close(self.approaches.gamma_min_rad, lo, ANGLE_TOLERANCE_RAD) {
            return Err(mismatch(
                "approaches.gamma_min_rad",
                self.approaches.gamma_min_rad,
                lo,
            ));
        }
        if !close(self.approaches.gamma_max_rad, hi, ANGLE_TOLERANCE_RAD) {
            return Err(mismatch(
                "approaches.gamma_max_rad",
                self.approaches.gamma_max_rad,
                hi,
            ));
        }
        self.gripper.check(gripper)?;
        if self.inference.subvoxels_per_contact as usize != SUBVOXELS_PER_CONTACT {
            return Err(mismatch(
                "inference.subvoxels_per_contact",
                self.inference.subvoxels_per_contact,
                SUBVOXELS_PER_CONTACT,
            ));
        }
        Ok(())
    }
}

/// Refuses absolute paths and `..`: the card may only name files inside its directory.
fn check_relative_path(field: &'static str, path: &str) -> Result<(), ModelError> {
    let p = Path::new(path);
    let ok = !path.is_empty()
        && p.components()
            .all(|c| matches!(c, Component::Normal(_) | Component::CurDir));
    if ok {
        Ok(())
    } else {
        Err(invalid(
            field,
            format!("path {path:?} must be relative to the model directory without `..`"),
        ))
    }
}

/// Lower-case hex SHA-256 of `bytes`.
pub fn sha256_hex(bytes: &[u8]) -> String {
    let digest = Sha256::digest(bytes);
    let mut s = String::with_capacity(64);
    for b in digest.iter() {
        s.push_str(&format!("{b:02x}"));
    }
    s
}

/// Loads a model directory: reads `card.json`, validates it ([`ModelCard::validate`]), checks it
/// against `workspace` and `gripper` ([`ModelCard::check_pipeline`]) and reads both ONNX files,
/// refusing any whose SHA-256 differs from the card. The graphs are not parsed here.
pub fn load_model_dir(
    dir: &Path,
    workspace: &Workspace,
    gripper: &GripperModel,
) -> Result<ModelFiles, ModelError> {
    let card = ModelCard::read(dir)?;
    card.validate()?;
    card.check_pipeline(workspace, gripper)?;
    let unet_onnx = card.files.unet.read_checked(dir)?;
    let mlp_onnx = card.files.mlp.read_checked(dir)?;
    Ok(ModelFiles {
        dir: dir.to_owned(),
        card,
        unet_onnx,
        mlp_onnx,
    })
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A valid card for the default workspace and gripper (sha256 values are placeholders).
    pub(crate) fn example_card_json() -> String {
        r#"{
          "format": "psgrasp-model", "format_version": 1,
          "name": "psgrasp-8app-b8", "variant": "8app",
          "generator": "psgrasp_training 0.1.0 (torch 2.11.0)",
          "files": {"unet": {"path": "unet.onnx", "sha256": "00000000000000000000000000000000000000000000000000000000000000aa"},
                    "mlp": {"path": "mlp.onnx", "sha256": "00000000000000000000000000000000000000000000000000000000000000bb"}},
          "grid": {"dims": [64,64,64], "voxel_size_m": 0.009, "input": "normals", "input_channels": 3},
          "classes": ["empty", "contact", "gripper"],
          "unet": {"levels": 4, "channels": [8,16,32,64], "feature_outputs": ["enc0","enc1","enc2","enc3"]},
          "mlp": {"feature_dim": 120, "hidden": [256, 256, 128]},
          "kappa0": 25.0, "kappa_learned": true,
          "approaches": {"count": 18, "gamma_min_rad": 1.5707963, "gamma_max_rad": 4.712389},
          "gripper": {"max_opening_m": 0.08, "approach_depth_m": 0.0445},
          "thresholds": {"contact_probability": 0.5, "quality": 0.5, "collision": 0.5},
          "inference": {"subvoxels_per_contact": 8, "single_approach": false},
          "training": {"dataset_manifest_sha256": "abc", "scenes": 0, "iterations": 0, "seed": 0, "config": {}},
          "validation": {"scenes": 0, "iou": {"empty": 0, "contact": 0, "gripper": 0},
                         "baseline_angle_error_deg": 0, "width_error_mm": 0, "quality_mae": 0}
        }"#
        .to_string()
    }

    type CardEdit = Box<dyn Fn(&mut ModelCard)>;

    fn card() -> ModelCard {
        ModelCard::from_json(&example_card_json(), Path::new("card.json")).unwrap()
    }

    fn pipeline_check(c: &ModelCard) -> Result<(), ModelError> {
        c.validate()?;
        c.check_pipeline(&Workspace::default(), &GripperModel::default())
    }

    fn mismatch_field(r: Result<(), ModelError>) -> &'static str {
        match r {
            Err(ModelError::Mismatch { field, .. }) => field,
            other => panic!("expected a mismatch, got {other:?}"),
        }
    }

    fn invalid_field(r: Result<(), ModelError>) -> &'static str {
        match r {
            Err(ModelError::InvalidCard { field, .. }) => field,
            other => panic!("expected an invalid card, got {other:?}"),
        }
    }

    #[test]
    fn example_card_is_accepted() {
        let c = card();
        pipeline_check(&c).unwrap();
        assert_eq!(c.variant, ModelVariant::EightApproach);
        assert_eq!(c.level_dims(3), [8, 8, 8]);
        assert_eq!(c.feature_dim(), 120);
        // Round trip through JSON keeps every field.
        let back =
            ModelCard::from_json(&serde_json::to_string(&c).unwrap(), Path::new("x")).unwrap();
        assert_eq!(back, c);
    }

    #[test]
    fn every_pipeline_mismatch_is_refused_by_field() {
        let cases: Vec<(&str, CardEdit)> = vec![
            ("grid.dims", Box::new(|c| c.grid.dims = [32, 64, 64])),
            (
                "grid.voxel_size_m",
                Box::new(|c| c.grid.voxel_size_m = 0.01),
            ),
            ("grid.input", Box::new(|c| c.grid.input = "tsdf".into())),
            (
                "grid.input_channels",
                Box::new(|c| c.grid.input_channels = 4),
            ),
            ("classes", Box::new(|c| c.classes.swap(1, 2))),
            ("approaches.count", Box::new(|c| c.approaches.count = 8)),
            (
                "approaches.gamma_min_rad",
                Box::new(|c| c.approaches.gamma_min_rad = 0.0),
            ),
            (
                "approaches.gamma_max_rad",
                Box::new(|c| c.approaches.gamma_max_rad = 3.0),
            ),
            (
                "gripper.max_opening_m",
                Box::new(|c| c.gripper.max_opening_m = 0.1),
            ),
            (
                "gripper.approach_depth_m",
                Box::new(|c| c.gripper.approach_depth_m = 0.0448),
            ),
            (
                "inference.subvoxels_per_contact",
                Box::new(|c| c.inference.subvoxels_per_contact = 1),
            ),
        ];
        for (field, change) in cases {
            let mut c = card();
            change(&mut c);
            assert_eq!(mismatch_field(pipeline_check(&c)), field);
        }
        // Within tolerance is fine.
        let mut c = card();
        c.gripper.approach_depth_m = 0.04455;
        c.gripper.max_opening_m = 0.08009;
        pipeline_check(&c).unwrap();
    }

    #[test]
    fn a_card_made_for_another_gripper_file_is_refused_by_field() {
        // The card fixture records the shipped model's hand (franka: opening 80 mm, approach
        // depth 54 − 9.5 = 44.5 mm).
        let c = card();
        let file = |name: &str| psgrasp_geometry::grippers::named(name).unwrap();
        c.gripper.check(&file("franka")).unwrap();
        assert_eq!(
            mismatch_field(c.gripper.check(&file("franka-15mm"))),
            "gripper.approach_depth_m"
        );
        assert_eq!(
            mismatch_field(c.gripper.check(&file("robotiq-2f85"))),
            "gripper.max_opening_m"
        );
    }

    #[test]
    fn inconsistent_cards_are_refused_by_field() {
        let cases: Vec<(&str, CardEdit)> = vec![
            ("unet.levels", Box::new(|c| c.unet.levels = 0)),
            (
                "unet.channels",
                Box::new(|c| c.unet.channels.pop().map(drop).unwrap()),
            ),
            (
                "unet.feature_outputs",
                Box::new(|c| c.unet.feature_outputs[1] = "e1".into()),
            ),
            ("mlp.feature_dim", Box::new(|c| c.mlp.feature_dim = 64)),
            // Found by the model_card fuzz target: the sum overflowed (a panic in debug builds).
            (
                "mlp.feature_dim",
                Box::new(|c| c.unet.channels[1] = u32::MAX),
            ),
            // A sum that wraps to feature_dim in u32 does not match.
            (
                "mlp.feature_dim",
                Box::new(|c| {
                    c.unet.channels = vec![u32::MAX, 1, 1, c.mlp.feature_dim - 1];
                }),
            ),
            ("kappa0", Box::new(|c| c.kappa0 = -1.0)),
            (
                "thresholds.contact_probability",
                Box::new(|c| c.thresholds.contact_probability = 1.5),
            ),
            (
                "files.unet",
                Box::new(|c| c.files.unet.path = "../unet.onnx".into()),
            ),
            (
                "files.mlp",
                Box::new(|c| c.files.mlp.path = "/tmp/mlp.onnx".into()),
            ),
            ("files.mlp", Box::new(|c| c.files.mlp.sha256 = "xyz".into())),
            (
                "grid.dims",
                Box::new(|c| {
                    c.grid.dims = [60, 64, 64];
                }),
            ),
        ];
        for (field, change) in cases {
            let mut c = card();
            change(&mut c);
            assert_eq!(invalid_field(c.validate()), field);
        }
    }

    #[test]
    fn format_and_version_are_checked() {
        let mut c = card();
        c.format = "onnx".into();
        assert!(matches!(c.validate(), Err(ModelError::Format { .. })));
        let mut c = card();
        c.format_version = 2;
        assert!(matches!(
            c.validate(),
            Err(ModelError::FormatVersion { found: 2 })
        ));
        let text = example_card_json().replace("\"8app\"", "\"9app\"");
        assert!(matches!(
            ModelCard::from_json(&text, Path::new("card.json")),
            Err(ModelError::CardJson { .. })
        ));
        let text = example_card_json().replace("\"kappa0\": 25.0,", "");
        let err = ModelCard::from_json(&text, Path::new("card.json")).unwrap_err();
        assert!(format!("{:?}", err).contains("kappa0"), "{err:?}");
    }

    #[test]
    fn sha256_of_known_input() {
        assert_eq!(
            sha256_hex(b"abc"),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
    }
}
