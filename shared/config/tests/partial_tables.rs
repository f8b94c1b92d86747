//! Issue 19: every key of a pipeline configuration is optional (config/default.toml says so), also
//! inside a table: a partial `[workspace]`, `[bin]`, `[gripper]`, `[camera.intrinsics]` or
//! `[inference]` takes the defaults for its missing keys instead of failing with "missing field".
use psgrasp_config::{ConfigError, PipelineConfig};
use psgrasp_geometry::{BinModel, CameraIntrinsics, GripperModel, Workspace};
use psgrasp_inference::{AnalyticConfig, BackendConfig};
use std::path::Path;

fn parse(text: &str) -> Result<PipelineConfig, ConfigError> {
    PipelineConfig::parse(text, Path::new("<test>"))
}

#[test]
fn a_partial_workspace_table_takes_the_default_dims() {
    let cfg = parse("[workspace]\nvoxel_size_m = 0.008\n").unwrap();
    assert_eq!(
        cfg.cell.workspace,
        Workspace {
            voxel_size_m: 0.008,
            ..Workspace::default()
        }
    );
}

#[test]
fn a_partial_bin_table_takes_the_default_size_and_placement() {
    let cfg = parse("[bin]\nwall_thickness_m = 0.02\n").unwrap();
    assert_eq!(
        cfg.cell.bin,
        BinModel {
            wall_thickness_m: 0.02,
            ..BinModel::default()
        }
    );
}

#[test]
fn a_partial_gripper_table_takes_the_default_hand() {
    let cfg = parse("[gripper]\ntip_beyond_tcp_m = 0.0095\n").unwrap();
    assert_eq!(
        cfg.cell.gripper,
        GripperModel {
            tip_beyond_tcp_m: 0.0095,
            ..GripperModel::default()
        }
    );
}

#[test]
fn a_partial_intrinsics_table_takes_the_default_camera() {
    let cfg = parse("[camera.intrinsics]\nfx = 600.0\nfy = 600.0\n").unwrap();
    assert_eq!(
        cfg.camera.intrinsics,
        CameraIntrinsics {
            fx: 600.0,
            fy: 600.0,
            ..CameraIntrinsics::default_640x480()
        }
    );
}

#[test]
fn an_inference_table_without_kind_is_the_default_backend() {
    let cfg = parse("[inference]\nmin_quality = 0.7\n").unwrap();
    assert_eq!(
        cfg.cell.inference,
        BackendConfig::Analytic(AnalyticConfig {
            min_quality: 0.7,
            ..AnalyticConfig::default()
        })
    );
    assert_eq!(cfg.cell.inference.kind(), BackendConfig::default().kind());
    // A partial table of another kind takes that kind's defaults.
    let cfg = parse("[inference]\nkind = \"learned\"\nthreads = 2\n").unwrap();
    let BackendConfig::Learned(l) = &cfg.cell.inference else {
        panic!("learned expected: {:?}", cfg.cell.inference);
    };
    assert_eq!(l.threads, 2);
}

#[test]
fn partial_tables_still_refuse_unknown_keys() {
    for (text, key) in [
        ("[workspace]\ndimz = [32, 32, 32]\n", "dimz"),
        ("[bin]\nwall_thickness = 0.02\n", "wall_thickness"),
        ("[gripper]\nmax_opening = 0.1\n", "max_opening"),
        ("[camera.intrinsics]\nfocal = 600.0\n", "focal"),
        ("[inference]\nmin_qualty = 0.7\n", "min_qualty"),
        (
            "[inference]\nmodel_dir = \"../models/default\"\n",
            "model_dir",
        ),
    ] {
        let err = parse(text).unwrap_err();
        assert!(matches!(err, ConfigError::Parse { .. }), "{text}: {err}");
        assert!(err.to_string().contains(key), "{text}: {err}");
    }
}
