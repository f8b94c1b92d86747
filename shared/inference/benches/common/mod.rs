//! Helpers shared by the model benches (`learned.rs`, `vgn.rs`).
use psgrasp_fusion::NormalGrid;
use psgrasp_geometry::{BinModel, GripperModel, Workspace};
use std::path::{Path, PathBuf};
use std::time::Duration;

/// The benches' input: a procedural 12-object bin scene rendered top-down and fused into `workspace`.
pub fn fused_grid(workspace: Workspace) -> NormalGrid {
    let bin = BinModel::default();
    let scene = psgrasp_sim::procedural_scene(3, 12, &bin).expect("procedural scene");
    psgrasp_test_support::scenes::fused_top_down(&scene, &workspace)
}

/// An unsigned integer from the environment, else `default`.
pub fn env_usize(name: &str, default: usize) -> usize {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// The thread counts of `PSGRASP_BENCH_THREADS` (comma-separated, default `1,2`).
pub fn bench_threads() -> Vec<usize> {
    std::env::var("PSGRASP_BENCH_THREADS")
        .unwrap_or_else(|_| "1,2".into())
        .split(',')
        .filter_map(|t| t.trim().parse().ok())
        .collect()
}

/// The hand the model is loaded for: `$PSGRASP_BENCH_GRIPPER` (a name of `config/grippers`, e.g.
/// `franka-15mm` for a model trained with it), else the default hand.
pub fn bench_gripper() -> GripperModel {
    match std::env::var("PSGRASP_BENCH_GRIPPER") {
        Ok(name) => psgrasp_geometry::grippers::named(&name)
            .unwrap_or_else(|e| panic!("PSGRASP_BENCH_GRIPPER: {e}")),
        Err(_) => GripperModel::default(),
    }
}

/// Milliseconds.
pub fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// The model directory: the first non-flag argument, else `$env_var`, else `models/<default>` in
/// the repository.
pub fn model_dir(env_var: &str, default: &str) -> PathBuf {
    let arg = std::env::args().skip(1).find(|a| !a.starts_with('-'));
    arg.map(PathBuf::from)
        .or_else(|| std::env::var_os(env_var).map(PathBuf::from))
        .unwrap_or_else(|| {
            Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("../../models")
                .join(default)
        })
}

/// `"mean (min)"` of millisecond values with `decimals` decimals.
pub fn mean_min(v: &[f64], decimals: usize) -> String {
    let mean = v.iter().sum::<f64>() / v.len() as f64;
    let min = v.iter().cloned().fold(f64::INFINITY, f64::min);
    format!("{mean:.decimals$} ({min:.decimals$})")
}
