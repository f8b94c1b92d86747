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
use psgrasp_fusion::NormalGrid;
use psgrasp_geometry::{GripperModel, Workspace};
use psgrasp_inference::learned::{
    decode, load_model_dir, sampling, ClassProbabilities, Decoder, FeaturePyramid, HeadOutputs,
};
use psgrasp_inference::{
    InferenceBackend, LearnedBackend, LearnedConfig, LearnedModel, ModelCard, RuntimeKind,
    StageTimings,
};
use std::hint::black_box;
use std::path::Path;
use std::time::{Duration, Instant};

mod common;
use common::{bench_threads, env_usize, fused_grid, mean_min, model_dir, ms};

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
    let dir = model_dir("PSGRASP_MODEL_DIR", "default");
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
    let threads = bench_threads();
    let grid = fused_grid(workspace);
    if std::env::var_os("PSGRASP_BENCH_BREAKDOWN_ONLY").is_some() {
        breakdown(&dir, workspace, &grid, iters.max(10));
        return;
    }
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
                    mean_min(&v, 1)
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
    breakdown(&dir, workspace, &grid, iters.max(10));
}

/// Mean and min milliseconds of `f` over `iters` runs after one warm-up.
fn time_ms(iters: usize, mut f: impl FnMut()) -> String {
    f();
    let v: Vec<f64> = (0..iters)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    mean_min(&v, 2)
}

/// The sampling and decoding steps one by one (single thread), 4096 contact voxels.
fn breakdown(dir: &Path, workspace: Workspace, grid: &NormalGrid, iters: usize) {
    let files = load_model_dir(dir, &workspace, &GripperModel::default()).expect("model");
    let mut model = LearnedModel::new(&files, RuntimeKind::Tract, None, 1).expect("tract");
    let unet = model.run_unet(&grid.normals).expect("unet");
    let n = workspace.voxel_count();
    let mut probs = ClassProbabilities::default();
    let mut voxels = Vec::new();
    let mut points = Vec::new();
    let mut features = Vec::new();
    let mut head = HeadOutputs::default();
    let mut out = Vec::new();
    println!("\n| step (tract outputs, 4096 contact voxels, 32768 points) | ms mean (min) |");
    println!("|---|---|");
    let t = time_ms(iters, || {
        probs.compute(unet.label_logits.data(), n).expect("softmax")
    });
    println!("| softmax (P_contact, P_gripper of {n} voxels) | {t} |");
    let t = time_ms(iters, || {
        sampling::select_contact_voxels(&probs.contact, 0.0, 4096, &mut voxels);
        sampling::contact_points(&workspace, &voxels, &mut points);
    });
    println!("| contact selection + sub-voxel points | {t} |");
    let levels = model.levels(&unet).expect("levels");
    let t = time_ms(iters, || {
        sampling::sample_features(&levels, &points, &mut features)
    });
    println!(
        "| trilinear features, channel-major gathers (F = {}) | {t} |",
        features.len() / points.len().max(1)
    );
    let mut pyramid = FeaturePyramid::default();
    let t = time_ms(iters, || pyramid.fill(&levels));
    println!("| channel-last copy of the encoder levels | {t} |");
    let t = time_ms(iters, || pyramid.sample(&points, &mut features));
    println!("| trilinear features, channel-last rows | {t} |");
    let pool = rayon_pool(2);
    let t = time_ms(iters, || {
        pyramid.fill_in(&levels, &pool);
        pyramid.sample_in(&points, &mut features, &pool);
    });
    println!("| channel-last copy + features, 2 threads | {t} |");
    model.run_mlp(&features, 4096, &mut head).expect("mlp");
    let settings = model.decode_settings();
    let t = time_ms(iters, || {
        out.clear();
        decode::decode(&probs, &workspace, &points, &head, &settings, &mut out).expect("decode");
        black_box(&out);
    });
    println!("| decoding (19 probability samples per point) | {t} |");
    let t = time_ms(iters, || {
        let decoder = Decoder::new(&probs, &workspace, &points, &head, &settings).expect("decoder");
        out.clear();
        pool.install(|| {
            use rayon::prelude::*;
            out.par_extend(
                (0..decoder.len())
                    .into_par_iter()
                    .map(|i| decoder.config(i)),
            )
        });
        black_box(&out);
    });
    println!("| decoding, 2 threads | {t} |");
}

fn rayon_pool(threads: usize) -> rayon::ThreadPool {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("thread pool")
}
