//! VGN-style backend speed per stage on a 64³ fused grid (the procedural bin scene of the learned
//! bench), for tract and — with `--features ort` — ONNX Runtime.
//!
//! Run: `cargo bench --workspace --features ort --bench vgn [-- MODEL_DIR]` (the ort rows need
//! `ORT_DYLIB_PATH`). The model directory is the argument, else `$PSGRASP_VGN_MODEL_DIR`, else
//! `models/vgn`. `PSGRASP_BENCH_ITERS` sets the timed runs per row (default 5),
//! `PSGRASP_BENCH_THREADS` a comma-separated list of thread counts (default `1,2`),
//! `PSGRASP_BENCH_GRIPPER` the hand the model was trained for (default `franka`; `franka-15mm`
//! for `models/vgn` until it is retrained for the real hand).
use psgrasp_inference::vgn::{VgnBackend, VgnCard, VgnConfig, VgnTimings};
use psgrasp_inference::{InferenceBackend, RuntimeKind};
use std::time::Duration;

mod common;
use common::{bench_gripper, bench_threads, env_usize, fused_grid, mean_min, model_dir, ms};

fn main() {
    let dir = model_dir("PSGRASP_VGN_MODEL_DIR", "vgn");
    let card = match VgnCard::read(&dir) {
        Ok(c) => c,
        Err(e) => {
            println!(
                "vgn bench: no model at {} ({e}); pass MODEL_DIR or set PSGRASP_VGN_MODEL_DIR",
                dir.display()
            );
            return;
        }
    };
    let workspace = card.workspace();
    let iters = env_usize("PSGRASP_BENCH_ITERS", 5).max(1);
    let threads = bench_threads();
    let grid = fused_grid(workspace);
    println!(
        "VGN-style backend: model {} at {}, grid {:?} × {} mm; {iters} runs per row after a \
         warm-up; milliseconds, mean (min)\n",
        card.name,
        dir.display(),
        workspace.dims,
        workspace.voxel_size_m * 1e3,
    );
    println!("| runtime | threads | grasps | network | decoding | total |");
    println!("|---|---|---|---|---|---|");
    let mut runtimes = vec![RuntimeKind::Tract];
    if cfg!(feature = "ort") {
        runtimes.push(RuntimeKind::Ort);
    }
    for runtime in runtimes {
        for &t in &threads {
            let cfg = VgnConfig {
                model_dir: dir.clone(),
                runtime,
                threads: t,
                ..VgnConfig::default()
            };
            let mut backend = match VgnBackend::new(cfg, &workspace, bench_gripper()) {
                Ok(b) => b,
                Err(e) => {
                    println!("| {} | {t} | error: {e} |", runtime.name());
                    continue;
                }
            };
            backend.infer(&grid.view(), 0).expect("inference");
            let runs: Vec<VgnTimings> = (0..iters)
                .map(|_| {
                    backend.infer(&grid.view(), 0).expect("inference");
                    backend.last_timings()
                })
                .collect();
            let stat = |f: fn(&VgnTimings) -> Duration| {
                let v: Vec<f64> = runs.iter().map(|r| ms(f(r))).collect();
                mean_min(&v, 1)
            };
            println!(
                "| {} | {t} | {} | {} | {} | {} |",
                runtime.name(),
                runs[0].grasps,
                stat(|r| r.network),
                stat(|r| r.decoding),
                stat(|r| r.total),
            );
        }
    }
}
