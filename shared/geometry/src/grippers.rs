//! Grippers as data: the hand files of `config/grippers/` (built into the binaries) and the
//! `[gripper]` table that names one of them.
//!
//! Every part of psgrasp that needs the hand — label generation, grasp selection, the simulated
//! hand of the evaluation, the model card check — takes its [`GripperModel`] from here, so one
//! file defines it. A `[gripper]` table reads `model = "franka"` (the real Franka hand),
//! (the default: [`DEFAULT_GRIPPER`]), `model = "robotiq-2f85"` or `model = "franka-15mm"` (the
//! hand psgrasp modelled until 2026-12, which the models before then were trained with); any of
//! the four size keys
//! given beside it replaces that file's value (a custom hand is a table with all four).
use crate::GripperModel;
use serde::Deserialize;
use std::sync::OnceLock;

/// The built-in gripper files: name, TOML text.
pub const GRIPPER_FILES: [(&str, &str); 3] = [
    (
        "franka",
        include_str!("../../../config/grippers/franka.toml"),
    ),
    (
        "franka-15mm",
        include_str!("../../../config/grippers/franka-15mm.toml"),
    ),
    (
        "robotiq-2f85",
        include_str!("../../../config/grippers/robotiq-2f85.toml"),
    ),
];

/// The name of the default gripper file: the real Franka hand, which the shipped model
/// (`models/default`) was trained with.
pub const DEFAULT_GRIPPER: &str = "franka";

/// A `[gripper]` table: a built-in gripper file and keys that replace its values.
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GripperTable {
    /// Name of a built-in gripper file ([`GRIPPER_FILES`]); [`DEFAULT_GRIPPER`] when absent.
    pub model: Option<String>,
    /// Replaces the file's largest opening between the pads.
    pub max_opening_m: Option<f32>,
    /// Replaces the file's finger size (x thickness, y width, z length).
    pub finger_size_m: Option<[f32; 3]>,
    /// Replaces the file's palm size.
    pub palm_size_m: Option<[f32; 3]>,
    /// Replaces how far the file's fingertips reach beyond the TCP.
    pub tip_beyond_tcp_m: Option<f32>,
}

/// A gripper file: all four sizes, nothing else.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct GripperFile {
    max_opening_m: f32,
    finger_size_m: [f32; 3],
    palm_size_m: [f32; 3],
    tip_beyond_tcp_m: f32,
}

fn parse_file(name: &str, text: &str) -> Result<GripperModel, String> {
    let f: GripperFile =
        toml::from_str(text).map_err(|e| format!("gripper file {name}.toml: {e}"))?;
    let g = GripperModel {
        max_opening_m: f.max_opening_m,
        finger_size_m: f.finger_size_m,
        palm_size_m: f.palm_size_m,
        tip_beyond_tcp_m: f.tip_beyond_tcp_m,
    };
    g.validate()
        .map_err(|e| format!("gripper file {name}.toml: {e}"))?;
    Ok(g)
}

/// The built-in gripper file `name` (`config/grippers/<name>.toml`).
pub fn named(name: &str) -> Result<GripperModel, String> {
    let (_, text) = GRIPPER_FILES
        .iter()
        .find(|(n, _)| *n == name)
        .ok_or_else(|| {
            let known: Vec<&str> = GRIPPER_FILES.iter().map(|(n, _)| *n).collect();
            format!(
                "unknown gripper model {name:?}; known: {}",
                known.join(", ")
            )
        })?;
    parse_file(name, text)
}

/// The default hand ([`DEFAULT_GRIPPER`]), parsed once.
pub fn default_gripper() -> GripperModel {
    static DEFAULT: OnceLock<GripperModel> = OnceLock::new();
    *DEFAULT.get_or_init(|| {
        // The file is part of the binary and checked by a unit test, so this cannot fail.
        named(DEFAULT_GRIPPER).expect("the default gripper file is valid")
    })
}

impl TryFrom<GripperTable> for GripperModel {
    type Error = String;

    fn try_from(t: GripperTable) -> Result<Self, String> {
        let mut g = match &t.model {
            Some(name) => named(name)?,
            None => default_gripper(),
        };
        if let Some(v) = t.max_opening_m {
            g.max_opening_m = v;
        }
        if let Some(v) = t.finger_size_m {
            g.finger_size_m = v;
        }
        if let Some(v) = t.palm_size_m {
            g.palm_size_m = v;
        }
        if let Some(v) = t.tip_beyond_tcp_m {
            g.tip_beyond_tcp_m = v;
        }
        Ok(g)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_built_in_file_parses_and_is_valid() {
        for (name, _) in GRIPPER_FILES {
            let g = named(name).unwrap();
            assert!(g.validate().is_ok(), "{name}");
        }
        assert_eq!(named("franka").unwrap().tip_beyond_tcp_m, 0.0095);
        assert_eq!(named("robotiq-2f85").unwrap().max_opening_m, 0.085);
    }

    #[test]
    fn the_default_hand_is_the_default_file() {
        assert_eq!(GripperModel::default(), named(DEFAULT_GRIPPER).unwrap());
        // The real hand and the hand modelled until 2026-12 differ only in the fingertip depth.
        let (real, old) = (named("franka").unwrap(), named("franka-15mm").unwrap());
        assert_eq!(
            GripperModel {
                tip_beyond_tcp_m: 0.015,
                ..real
            },
            old
        );
    }

    #[test]
    fn a_table_names_a_file_and_overrides_its_keys() {
        let g: GripperModel = toml::from_str("model = \"robotiq-2f85\"\n").unwrap();
        assert_eq!(g, named("robotiq-2f85").unwrap());
        let g: GripperModel =
            toml::from_str("model = \"franka\"\ntip_beyond_tcp_m = 0.012\n").unwrap();
        assert_eq!(
            g,
            GripperModel {
                tip_beyond_tcp_m: 0.012,
                ..named("franka").unwrap()
            }
        );
        let g: GripperModel = toml::from_str("").unwrap();
        assert_eq!(g, default_gripper());
    }

    #[test]
    fn an_unknown_model_or_key_is_refused_by_name() {
        let e = toml::from_str::<GripperModel>("model = \"robotiq-3f\"\n").unwrap_err();
        assert!(e.to_string().contains("robotiq-3f"), "{e}");
        assert!(
            e.to_string().contains("franka, franka-15mm, robotiq-2f85"),
            "{e}"
        );
        let e = toml::from_str::<GripperModel>("tip_length_m = 0.01\n").unwrap_err();
        assert!(e.to_string().contains("tip_length_m"), "{e}");
    }

    #[test]
    fn a_serialized_model_reads_back_the_same() {
        let g = named("robotiq-2f85").unwrap();
        let text = toml::to_string(&g).unwrap();
        assert_eq!(toml::from_str::<GripperModel>(&text).unwrap(), g);
    }
}
