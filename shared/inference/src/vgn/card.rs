//! The VGN model card (`card.json` of format `psgrasp-vgn-model`) and loading a VGN model
//! directory.
//!
//! The card shares its `files` entries, `grid` and `gripper` sections (and their checks) with
//! the learned backend's card ([`crate::learned::card`]); every mismatch is a [`ModelError`]
//! naming the card field.
use crate::learned::card::{read_card, CardFile, CardGrid, CardGripper, ModelError, CARD_FILE};
use psgrasp_geometry::{GripperModel, Workspace};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The `format` string of a VGN model card.
pub const VGN_CARD_FORMAT: &str = "psgrasp-vgn-model";
/// The VGN card `format_version` this crate reads.
pub const VGN_CARD_FORMAT_VERSION: u32 = 1;
/// The only `variant` of a VGN card.
pub const VGN_VARIANT: &str = "vgn";

/// The contents of a VGN `card.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct VgnCard {
    /// Always [`VGN_CARD_FORMAT`].
    pub format: String,
    /// Always [`VGN_CARD_FORMAT_VERSION`] for cards this crate reads.
    pub format_version: u32,
    /// Model name.
    pub name: String,
    /// Always [`VGN_VARIANT`].
    pub variant: String,
    /// What wrote the export (package and framework versions).
    #[serde(default)]
    pub generator: String,
    /// The ONNX graph.
    pub files: VgnCardFiles,
    /// The input grid.
    pub grid: CardGrid,
    /// The gripper the labels were made for (`approach_depth_m` = finger length −
    /// `tip_beyond_tcp_m`).
    pub gripper: CardGripper,
    /// Network structure (informational beyond the checks).
    pub network: VgnNetwork,
    /// Provenance of the training run (free-form).
    #[serde(default)]
    pub training: serde_json::Value,
    /// Held-out validation figures (free-form or null).
    #[serde(default)]
    pub validation: serde_json::Value,
}

/// `files` of a VGN card.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct VgnCardFiles {
    /// The network graph, `vgn.onnx`.
    pub vgn: CardFile,
}

/// `network` of a VGN card.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct VgnNetwork {
    /// Channels of the encoder levels.
    pub channels: Vec<u32>,
}

/// A VGN model directory whose card was checked and whose ONNX file matches its SHA-256.
#[derive(Debug, Clone)]
pub struct VgnModelFiles {
    /// The model directory.
    pub dir: PathBuf,
    /// The checked card.
    pub card: VgnCard,
    /// Bytes of `vgn.onnx`.
    pub onnx: Vec<u8>,
}

impl VgnCard {
    /// Parses a card from JSON text; `path` is only used in the error.
    pub fn from_json(text: &str, path: &Path) -> Result<Self, ModelError> {
        crate::learned::card::card_from_json(text, path)
    }

    /// Reads and parses `dir/card.json` (no checks beyond the JSON schema).
    pub fn read(dir: &Path) -> Result<Self, ModelError> {
        read_card(dir)
    }

    /// Grid dims as `usize`.
    pub fn dims(&self) -> [usize; 3] {
        self.grid.dims.map(|d| d as usize)
    }

    /// The workspace the model was trained for.
    pub fn workspace(&self) -> Workspace {
        self.grid.workspace()
    }

    /// Checks the card on its own: format, version, variant, file entry, grid, gripper sizes and
    /// network channels.
    pub fn validate(&self) -> Result<(), ModelError> {
        if self.format != VGN_CARD_FORMAT {
            return Err(ModelError::Format {
                found: self.format.clone(),
            });
        }
        if self.format_version != VGN_CARD_FORMAT_VERSION {
            return Err(ModelError::FormatVersion {
                found: self.format_version,
            });
        }
        if self.variant != VGN_VARIANT {
            return Err(ModelError::Mismatch {
                field: "variant",
                card: self.variant.clone(),
                expected: VGN_VARIANT.into(),
            });
        }
        self.files.vgn.validate("files.vgn")?;
        self.grid.validate()?;
        self.gripper.validate()?;
        if self.network.channels.is_empty() || self.network.channels.contains(&0) {
            return Err(ModelError::InvalidCard {
                field: "network.channels",
                reason: "needs at least one positive channel count".into(),
            });
        }
        Ok(())
    }

    /// Checks the grid dims and voxel size against `workspace`.
    pub fn check_workspace(&self, workspace: &Workspace) -> Result<(), ModelError> {
        self.grid.check_workspace(workspace)
    }

    /// Checks the gripper's maximum opening and approach depth against `gripper`.
    pub fn check_gripper(&self, gripper: &GripperModel) -> Result<(), ModelError> {
        self.gripper.check(gripper)
    }
}

/// Loads a VGN model directory: reads `card.json`, validates it ([`VgnCard::validate`]), checks
/// it against `workspace` and `gripper` and reads the ONNX file, refusing it if its SHA-256
/// differs from the card. The graph is not parsed here.
pub fn load_vgn_dir(
    dir: &Path,
    workspace: &Workspace,
    gripper: &GripperModel,
) -> Result<VgnModelFiles, ModelError> {
    let card = VgnCard::read(dir)?;
    card.validate()?;
    card.check_workspace(workspace)?;
    card.check_gripper(gripper)?;
    let onnx = card.files.vgn.read_checked(dir)?;
    Ok(VgnModelFiles {
        dir: dir.to_owned(),
        card,
        onnx,
    })
}

/// True if `dir/card.json` is JSON whose `format` is [`VGN_CARD_FORMAT`] (any other card, or
/// none, is not a VGN model directory).
pub fn is_vgn_model_dir(dir: &Path) -> bool {
    std::fs::read_to_string(dir.join(CARD_FILE))
        .ok()
        .and_then(|text| serde_json::from_str::<serde_json::Value>(&text).ok())
        .is_some_and(|v| v.get("format").and_then(|f| f.as_str()) == Some(VGN_CARD_FORMAT))
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A valid VGN card for the default workspace and gripper (the sha256 is a placeholder).
    pub(crate) fn example_vgn_card_json() -> String {
        r#"{
          "format": "psgrasp-vgn-model", "format_version": 1,
          "name": "vgn-baseline", "variant": "vgn",
          "generator": "psgrasp_training 0.1.0 (torch 2.11.0)",
          "files": {"vgn": {"path": "vgn.onnx", "sha256": "00000000000000000000000000000000000000000000000000000000000000aa"}},
          "grid": {"dims": [64,64,64], "voxel_size_m": 0.009, "input": "normals", "input_channels": 3},
          "gripper": {"max_opening_m": 0.08, "approach_depth_m": 0.0445},
          "network": {"channels": [16, 32, 64]},
          "training": {"iterations": 0},
          "validation": null
        }"#
        .to_string()
    }

    fn card() -> VgnCard {
        VgnCard::from_json(&example_vgn_card_json(), Path::new("card.json")).unwrap()
    }

    fn check(c: &VgnCard) -> Result<(), ModelError> {
        c.validate()?;
        c.check_workspace(&Workspace::default())?;
        c.check_gripper(&GripperModel::default())
    }

    type CardEdit = Box<dyn Fn(&mut VgnCard)>;

    #[test]
    fn example_card_is_accepted_and_round_trips() {
        let c = card();
        check(&c).unwrap();
        assert_eq!(c.dims(), [64, 64, 64]);
        assert_eq!(c.workspace(), Workspace::default());
        assert!(c.validation.is_null());
        let back = VgnCard::from_json(&serde_json::to_string(&c).unwrap(), Path::new("x")).unwrap();
        assert_eq!(back, c);
        // `training`, `validation` and `generator` may be left out.
        let mut v: serde_json::Value = serde_json::from_str(&example_vgn_card_json()).unwrap();
        for key in ["training", "validation", "generator"] {
            v.as_object_mut().unwrap().remove(key);
        }
        check(&VgnCard::from_json(&v.to_string(), Path::new("x")).unwrap()).unwrap();
    }

    #[test]
    fn mismatches_and_bad_fields_are_refused_by_field() {
        let mismatches: Vec<(&str, CardEdit)> = vec![
            ("grid.dims", Box::new(|c| c.grid.dims = [32, 64, 64])),
            (
                "grid.voxel_size_m",
                Box::new(|c| c.grid.voxel_size_m = 0.01),
            ),
            ("grid.input", Box::new(|c| c.grid.input = "tsdf".into())),
            (
                "grid.input_channels",
                Box::new(|c| c.grid.input_channels = 1),
            ),
            (
                "gripper.max_opening_m",
                Box::new(|c| c.gripper.max_opening_m = 0.1),
            ),
            (
                "gripper.approach_depth_m",
                Box::new(|c| c.gripper.approach_depth_m = 0.05),
            ),
            ("variant", Box::new(|c| c.variant = "8app".into())),
        ];
        for (field, edit) in mismatches {
            let mut c = card();
            edit(&mut c);
            match check(&c) {
                Err(ModelError::Mismatch { field: f, .. }) => assert_eq!(f, field),
                other => panic!("{field}: expected a mismatch, got {other:?}"),
            }
        }
        let invalid: Vec<(&str, CardEdit)> = vec![
            (
                "files.vgn",
                Box::new(|c| c.files.vgn.path = "../vgn.onnx".into()),
            ),
            ("files.vgn", Box::new(|c| c.files.vgn.sha256 = "12".into())),
            ("grid", Box::new(|c| c.grid.dims = [0, 64, 64])),
            (
                "gripper.max_opening_m",
                Box::new(|c| c.gripper.max_opening_m = -0.08),
            ),
            (
                "gripper.approach_depth_m",
                Box::new(|c| c.gripper.approach_depth_m = f32::NAN),
            ),
            ("network.channels", Box::new(|c| c.network.channels.clear())),
            (
                "network.channels",
                Box::new(|c| c.network.channels = vec![16, 0]),
            ),
        ];
        for (field, edit) in invalid {
            let mut c = card();
            edit(&mut c);
            match c.validate() {
                Err(ModelError::InvalidCard { field: f, .. }) => assert_eq!(f, field),
                other => panic!("{field}: expected an invalid card, got {other:?}"),
            }
        }
        // Within tolerance is fine.
        let mut c = card();
        c.gripper.approach_depth_m = 0.04455;
        check(&c).unwrap();
    }

    #[test]
    fn format_version_and_json_errors() {
        let mut c = card();
        c.format = "psgrasp-model".into();
        assert!(matches!(c.validate(), Err(ModelError::Format { .. })));
        let mut c = card();
        c.format_version = 2;
        assert!(matches!(
            c.validate(),
            Err(ModelError::FormatVersion { found: 2 })
        ));
        let text =
            example_vgn_card_json().replace("\"network\": {\"channels\": [16, 32, 64]},", "");
        let err = VgnCard::from_json(&text, Path::new("card.json")).unwrap_err();
        assert!(format!("{err:?}").contains("network"), "{err:?}");
        assert!(matches!(
            VgnCard::from_json("{ nope", Path::new("card.json")),
            Err(ModelError::CardJson { .. })
        ));
    }

    #[test]
    fn vgn_directories_are_recognised_by_their_card_format() {
        let dir = std::env::temp_dir().join(format!("psgrasp-vgn-card-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        assert!(!is_vgn_model_dir(&dir));
        std::fs::write(dir.join(CARD_FILE), example_vgn_card_json()).unwrap();
        assert!(is_vgn_model_dir(&dir));
        std::fs::write(
            dir.join(CARD_FILE),
            crate::learned::card::tests::example_card_json(),
        )
        .unwrap();
        assert!(!is_vgn_model_dir(&dir));
        std::fs::write(dir.join(CARD_FILE), "{}").unwrap();
        assert!(!is_vgn_model_dir(&dir));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
