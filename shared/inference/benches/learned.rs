//! Learned backend speed per stage on a 64³ fused grid (a procedural bin scene rendered top-down
//! and fused), for tract and — with `--features ort` — ONNX Runtime.
//!
//! Run: `cargo bench -p psgrasp-inference --bench learned [-- MODEL_DIR]`
//! (`--features ort` with `ORT_DYLIB_PATH=/path/to/libonnxruntime.so` adds the ort rows).
//! The model directory is the argument, else `$PSGRASP_MODEL_DIR`, else `models/default` in the
//! repository. `PSGRASP_BENCH_ITERS` sets the timed runs per row (default 5), `PSGRASP_BENCH_THREADS`
//! a comma-separated list of thread counts (default `1,2`).
//!
//! Two contact settings per runtime: the card's threshold, and a forced 4096 contact voxels
//! (threshold 0, the cap decides), the worst case of the default config.
use nalgebra::Point3;
use psgrasp_fusion::{fuse_normal_grid, FusionConfig, NormalGrid};
use psgrasp_geometry::{BinModel, CameraIntrinsics, CameraModel, GripperModel, Workspace};
use psgrasp_inference::{
    InferenceBackend, LearnedBackend, LearnedConfig, ModelCard, RuntimeKind, StageTimings,
};
use std::path::{Path, PathBuf};
use std::time::Duration;

fn model_dir() -> PathBuf {
    let arg = std::env::args().skip(1).find(|a| !a.starts_with('-'));
    arg.map(PathBuf::from)
        .or_else(|| std::env::var_os("PSGRASP_MODEL_DIR").map(PathBuf::from))
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/default"))
}

fn fused_grid(workspace: Workspace) -> NormalGrid {
    let bin = BinModel::default();
    let scene = psgrasp_sim::procedural_scene(3, 12, &bin).expect("procedural scene");
    let camera = CameraModel::top_down(
        CameraIntrinsics::default_640x480(),
        Point3::new(0.288, 0.288, 0.018 + 0.28 + 0.6),
    );
    let depth = scene.render_depth(&camera);
    fuse_normal_grid(&depth, &camera, &workspace, &FusionConfig::default()).expect("fusion")
}

fn env_usize(name: &str, default: usize) -> usize {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// Mean and minimum of each stage over `iters` runs after one warm-up.
fn run_row(
    backend: &mut LearnedBackend,
    grid: &NormalGrid,
    iters: usize,
) -> (StageTimings, Vec<StageTimings>) {
    backend.infer(&grid.view(), 0).expect("inference");
    let runs: Vec<StageTimings> = (0..iters)
        .map(|_| {
            backend.infer(&grid.view(), 0).expect("inference");
            backend.last_timings()
        })
        .collect();
    (runs[0], runs)
}

fn main() {
    let dir = model_dir();
    let card = match ModelCard::read(&dir) {
        Ok(c) => c,
        Err(e) => {
            println!(
                "learned bench: no model at {} ({e}); pass MODEL_DIR or set PSGRASP_MODEL_DIR",
                dir.display()
            );
            return;
        }
    };
    let workspace = card.workspace();
    let iters = env_usize("PSGRASP_BENCH_ITERS", 5).max(1);
    let threads: Vec<usize> = std::env::var("PSGRASP_BENCH_THREADS")
        .unwrap_or_else(|_| "1,2".into())
        .split(',')
        .filter_map(|t| t.trim().parse().ok())
        .collect();
    let grid = fused_grid(workspace);
    println!(
        "learned backend: model {} ({}, U-Net channels {:?}, MLP hidden {:?}) at {}, grid {:?} × {} mm, \
         {} band voxels; {iters} runs per row after a warm-up; milliseconds, mean (min)\n",
        card.name,
        dir.display(),
        card.unet.channels,
        card.mlp.hidden,
        card.generator,
        workspace.dims,
        workspace.voxel_size_m * 1e3,
        grid.view().band_voxel_count(),
    );
    println!("| runtime | threads | contacts | contact voxels | points | U-Net | sampling | MLP | decoding | total |");
    println!("|---|---|---|---|---|---|---|---|---|---|");
    let mut runtimes = vec![RuntimeKind::Tract];
    if cfg!(feature = "ort") {
        runtimes.push(RuntimeKind::Ort);
    }
    for runtime in runtimes {
        for &t in &threads {
            for (label, threshold) in [("card threshold", None), ("forced 4096", Some(0.0))] {
                let cfg = LearnedConfig {
                    model_dir: dir.clone(),
                    runtime,
                    threads: t,
                    contact_probability: threshold,
                    ..LearnedConfig::default()
                };
                let mut backend =
                    match LearnedBackend::new(cfg, &workspace, GripperModel::default()) {
                        Ok(b) => b,
                        Err(e) => {
                            println!("| {} | {t} | {label} | error: {e} |", runtime.name());
                            let mut src = std::error::Error::source(&e);
                            while let Some(s) = src {
                                println!("  caused by: {s}");
                                src = s.source();
                            }
                            continue;
                        }
                    };
                let (first, runs) = run_row(&mut backend, &grid, iters);
                let stat = |f: fn(&StageTimings) -> Duration| {
                    let v: Vec<f64> = runs.iter().map(|r| ms(f(r))).collect();
                    let mean = v.iter().sum::<f64>() / v.len() as f64;
                    let min = v.iter().cloned().fold(f64::INFINITY, f64::min);
                    format!("{mean:.1} ({min:.1})")
                };
                println!(
                    "| {} | {t} | {label} | {} | {} | {} | {} | {} | {} | {} |",
                    runtime.name(),
                    first.contact_voxels,
                    first.points,
                    stat(|r| r.unet),
                    stat(|r| r.sampling),
                    stat(|r| r.mlp),
                    stat(|r| r.decoding),
                    stat(|r| r.total),
                );
            }
        }
    }
}
