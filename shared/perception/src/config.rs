//! The cell's configuration: what every perception step needs to know.
use psgrasp_fusion::{DepthScaleConfig, FusionConfig};
use psgrasp_geometry::{BinModel, GripperModel, RobotCell, RobotConfig, Workspace};
use psgrasp_inference::{BackendConfig, InferenceBackend, InferenceError};
use psgrasp_selection::SelectionConfig;
use serde::{Deserialize, Serialize};

/// The cell: workspace grid, bin, gripper and the settings of each perception step. Embedded
/// (flattened) by the pipeline configuration, the dataset configuration and the evaluation
/// protocol; every table is optional and takes its defaults.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(default, deny_unknown_fields)]
pub struct CellConfig {
    /// The voxel grid over the bin.
    pub workspace: Workspace,
    /// The bin.
    pub bin: BinModel,
    /// The gripper.
    pub gripper: GripperModel,
    /// TSDF / normal-grid fusion.
    pub fusion: FusionConfig,
    /// Per-frame depth-scale correction against the bin before fusion (off by default).
    pub depth_scale: DepthScaleConfig,
    /// Inference backend.
    pub inference: BackendConfig,
    /// Grasp selection.
    pub selection: SelectionConfig,
    /// How the steps are joined.
    pub perception: ChainConfig,
    /// The robot around the cell: hand-eye calibration and the gripper on the flange, for
    /// picks in the robot base frame.
    pub robot: RobotConfig,
}

/// Settings of the chain itself (between the steps).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ChainConfig {
    /// Contacts of an analytic backend without its own `contact_region` are kept this far inside
    /// the bin's inner volume, metres: contacts on the thin bin walls are never pickable.
    pub contact_region_inset_m: f32,
    /// Largest grasp set passed from inference to selection: configurations beyond it are cut,
    /// best antipodal quality first.
    pub max_grasps_per_frame: usize,
}

impl Default for ChainConfig {
    fn default() -> Self {
        Self {
            contact_region_inset_m: 0.005,
            max_grasps_per_frame: 16_384,
        }
    }
}

/// A setting of the cell that is out of range: the key and why.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{field}: {reason}")]
pub struct InvalidSetting {
    /// The offending key (`gripper`, `perception.max_grasps_per_frame`, ...).
    pub field: &'static str,
    /// What is wrong.
    pub reason: String,
}

fn invalid(field: &'static str, reason: impl ToString) -> InvalidSetting {
    InvalidSetting {
        field,
        reason: reason.to_string(),
    }
}

impl CellConfig {
    /// Checks ranges of every table, the inference backend's settings included (its model files
    /// are checked when it is built).
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        self.workspace
            .validate()
            .map_err(|e| invalid("workspace", e))?;
        self.inference
            .validate()
            .map_err(|e| invalid("inference", e))?;
        self.depth_scale
            .validate()
            .map_err(|e| invalid("depth_scale", e))?;
        self.fusion.validate().map_err(|e| invalid("fusion", e))?;
        self.selection
            .validate()
            .map_err(|e| invalid("selection", e))?;
        let g = &self.gripper;
        let extra = [g.max_opening_m, g.tip_beyond_tcp_m];
        let mut dims = g
            .finger_size_m
            .iter()
            .chain(g.palm_size_m.iter())
            .chain(extra.iter());
        if !dims.all(|v| v.is_finite() && *v >= 0.0) || g.max_opening_m <= 0.0 {
            return Err(invalid(
                "gripper",
                "sizes must be finite, non-negative, max_opening_m > 0",
            ));
        }
        let b = &self.bin;
        let sizes_ok = b.inner_size_m.iter().all(|v| v.is_finite() && *v > 0.0);
        let wall_ok = b.wall_thickness_m.is_finite() && b.wall_thickness_m >= 0.0;
        let centre_ok = b.floor_center.iter().all(|v| v.is_finite());
        if !(sizes_ok && wall_ok && centre_ok) {
            return Err(invalid(
                "bin",
                "inner_size_m must be > 0, wall_thickness_m ≥ 0 and floor_center finite",
            ));
        }
        let p = &self.perception;
        if !(p.contact_region_inset_m.is_finite() && p.contact_region_inset_m >= 0.0) {
            return Err(invalid(
                "perception.contact_region_inset_m",
                format!("{} must be ≥ 0", p.contact_region_inset_m),
            ));
        }
        if p.max_grasps_per_frame == 0 {
            return Err(invalid("perception.max_grasps_per_frame", "must be ≥ 1"));
        }
        self.robot_cell()?;
        Ok(())
    }

    /// The robot cell with this cell's gripper (its TCP in the flange frame).
    pub fn robot_cell(&self) -> Result<RobotCell, InvalidSetting> {
        self.robot
            .resolve(self.gripper.tip_beyond_tcp_m)
            .map_err(|e| match e {
                psgrasp_geometry::GeometryError::InvalidRobot(m) => invalid("robot", m),
                other => invalid("robot", other),
            })
    }

    /// `backend` as this cell runs it: an analytic backend without its own contact region gets
    /// the bin interior, inset by [`ChainConfig::contact_region_inset_m`], and scores collisions
    /// with the hand clearance selection uses (`[selection.clearance]`).
    pub fn effective_backend(&self, backend: &BackendConfig) -> BackendConfig {
        let mut backend = backend
            .clone()
            .with_bin_interior_contacts(&self.bin, self.perception.contact_region_inset_m);
        if let BackendConfig::Analytic(a) = &mut backend {
            a.clearance = self.selection.clearance;
        }
        backend
    }

    /// Builds `backend` (as [`CellConfig::effective_backend`]) for this cell's workspace and
    /// gripper; a model whose card records another grid or gripper is refused here.
    pub fn build_backend(
        &self,
        backend: &BackendConfig,
    ) -> Result<Box<dyn InferenceBackend>, InferenceError> {
        psgrasp_inference::backend_for_workspace(
            &self.effective_backend(backend),
            &self.workspace,
            self.gripper,
        )
    }
}

/// The last field of a configuration that flattens [`CellConfig`] into its top level: serde's
/// `deny_unknown_fields` does not work with flattening, so this field takes every key that no
/// other field took and refuses the first one (`unknown field `…``), as a misspelt table must
/// not be dropped silently. Never serialised.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
pub struct NoUnknownKeys;

impl<'de> Deserialize<'de> for NoUnknownKeys {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct Refuse;
        impl<'de> serde::de::Visitor<'de> for Refuse {
            type Value = NoUnknownKeys;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("no further keys")
            }
            fn visit_map<A: serde::de::MapAccess<'de>>(
                self,
                mut map: A,
            ) -> Result<Self::Value, A::Error> {
                match map.next_key::<String>()? {
                    Some(key) => Err(serde::de::Error::custom(format!("unknown field `{key}`"))),
                    None => Ok(NoUnknownKeys),
                }
            }
        }
        deserializer.deserialize_map(Refuse)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_table_is_optional_and_defaults_validate() {
        let cell: CellConfig = toml::from_str("").unwrap();
        assert_eq!(cell, CellConfig::default());
        cell.validate().unwrap();
        let cell: CellConfig = toml::from_str("[perception]\nmax_grasps_per_frame = 8\n").unwrap();
        assert_eq!(cell.perception.max_grasps_per_frame, 8);
        assert_eq!(cell.perception.contact_region_inset_m, 0.005);
    }

    #[test]
    fn out_of_range_settings_name_their_key() {
        let mut cell = CellConfig::default();
        cell.perception.max_grasps_per_frame = 0;
        assert_eq!(
            cell.validate().unwrap_err().field,
            "perception.max_grasps_per_frame"
        );
        let mut cell = CellConfig::default();
        cell.perception.contact_region_inset_m = -1.0;
        assert_eq!(
            cell.validate().unwrap_err().field,
            "perception.contact_region_inset_m"
        );
        let mut cell = CellConfig::default();
        cell.gripper.max_opening_m = 0.0;
        assert_eq!(cell.validate().unwrap_err().field, "gripper");
        let mut cell = CellConfig::default();
        cell.bin.inner_size_m[0] = f32::NAN;
        assert_eq!(cell.validate().unwrap_err().field, "bin");
        // Found by the pipeline_config fuzz target: a NaN floor centre placed the camera at NaN.
        let mut cell = CellConfig::default();
        cell.bin.floor_center.y = f32::NAN;
        assert_eq!(cell.validate().unwrap_err().field, "bin");
        // What a stage checks when it starts is checked with the configuration.
        let mut cell = CellConfig::default();
        cell.selection.top_k = 0;
        let e = cell.validate().unwrap_err();
        assert_eq!(e.field, "selection");
        assert!(e.reason.contains("top_k"), "{e}");
        let mut cell = CellConfig::default();
        cell.fusion.truncation_voxels = -4.0;
        assert_eq!(cell.validate().unwrap_err().field, "fusion");
        assert!(toml::from_str::<CellConfig>("[perception]\nbogus = 1\n").is_err());
        // The backend's settings too (found by the pipeline_config fuzz target: an infinite
        // contact region passed the configuration check and stopped the inference stage).
        let cell: CellConfig = toml::from_str(
            "[inference.contact_region]\nmin_m = [0.0, 1e39, 0.0]\nmax_m = [1.0, 1.0, 1.0]\n",
        )
        .unwrap();
        let e = cell.validate().unwrap_err();
        assert_eq!(e.field, "inference");
        assert!(e.reason.contains("contact_region"), "{e}");
        let cell: CellConfig =
            toml::from_str("[inference]\nkind = \"vgn\"\nmodel_dir = \"m\"\nmin_width_m = nan\n")
                .unwrap();
        assert!(cell.validate().unwrap_err().reason.contains("min_width_m"));
    }

    /// A configuration that embeds the cell as the pipeline, dataset and protocol configs do.
    #[derive(Debug, Default, Deserialize, Serialize)]
    #[serde(default)]
    struct Embedding {
        own: u32,
        #[serde(flatten)]
        cell: CellConfig,
        #[serde(flatten, skip_serializing)]
        _unknown_keys: NoUnknownKeys,
    }

    #[test]
    fn an_embedded_cell_refuses_unknown_tables_and_keeps_nested_checks() {
        let e: Embedding = toml::from_str("own = 2\n[selection]\ntop_k = 3\n").unwrap();
        assert_eq!((e.own, e.cell.selection.top_k), (2, 3));
        let err = toml::from_str::<Embedding>("[selectoin]\ntop_k = 3\n").unwrap_err();
        assert!(
            err.to_string().contains("unknown field `selectoin`"),
            "{err}"
        );
        let err = toml::from_str::<Embedding>("[selection]\ntop_kk = 3\n").unwrap_err();
        assert!(err.to_string().contains("top_kk"), "{err}");
        let written = toml::to_string(&e).unwrap();
        assert!(!written.contains("unknown"), "{written}");
        let back: Embedding = toml::from_str(&written).unwrap();
        assert_eq!(back.cell, e.cell);
    }

    #[test]
    fn analytic_contacts_are_kept_inside_the_bin_by_the_configured_inset() {
        let mut cell = CellConfig::default();
        cell.perception.contact_region_inset_m = 0.02;
        let BackendConfig::Analytic(a) = cell.effective_backend(&cell.inference) else {
            panic!("default backend is analytic");
        };
        let region = a.contact_region.expect("bin interior");
        let expected = psgrasp_inference::ContactRegion::inside_bin(&cell.bin, 0.02);
        assert_eq!(region, expected);
    }

    #[test]
    fn the_analytic_scores_use_the_clearance_selection_uses() {
        let mut cell: CellConfig =
            toml::from_str("[selection.clearance]\nopening_clearance_m = 0.04\n").unwrap();
        assert_eq!(cell.selection.clearance.opening_clearance_m, 0.04);
        cell.selection.clearance.collision_margin_m = 0.006;
        let BackendConfig::Analytic(a) = cell.effective_backend(&cell.inference) else {
            panic!("default backend is analytic");
        };
        assert_eq!(a.clearance, cell.selection.clearance);
        // Not a key of [inference]: the clearance is defined once.
        assert!(toml::from_str::<CellConfig>(
            "[inference]\nkind = \"analytic\"\nopening_clearance_m = 0.04\n"
        )
        .is_err());
    }
}
