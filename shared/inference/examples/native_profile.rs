//! Per-op profile of the native runtime's U-Net on the learned bench's scene (a procedural
//! 12-object bin rendered top-down and fused), and its MLP on random features.
//!
//! `cargo run --release -p psgrasp-inference --example native_profile -- [THREADS] [RUNS] [MODEL_DIR]`
use psgrasp_geometry::{BinModel, GripperModel};
use psgrasp_inference::learned::{load_model_dir, GraphRuntime, HeadOutputs, ModelCard};
use psgrasp_inference::native::NativeRuntime;
use std::path::PathBuf;
use std::time::Instant;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let threads: usize = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(2);
    let runs: usize = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(10);
    let dir = args
        .get(3)
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../models/default"));
    let card = ModelCard::read(&dir).expect("card");
    let workspace = card.workspace();
    let files = load_model_dir(&dir, &workspace, &GripperModel::default()).expect("model");
    let t = Instant::now();
    let mut rt = NativeRuntime::new(&files, threads).expect("native runtime");
    println!(
        "load + background: {:.0} ms ({})",
        t.elapsed().as_secs_f64() * 1e3,
        rt.simd_name()
    );
    let scene = psgrasp_sim::procedural_scene(3, 12, &BinModel::default()).expect("scene");
    let grid = psgrasp_test_support::scenes::fused_top_down(&scene, &workspace);
    let normals = &grid.normals[..3 * workspace.voxel_count()];
    for skip in [true, false] {
        rt.set_background_skip(skip);
        rt.run_unet(normals).expect("unet");
        let mut totals: Vec<f64> = Vec::new();
        let mut per_op: Vec<f64> = Vec::new();
        for _ in 0..runs {
            let t = Instant::now();
            rt.run_unet(normals).expect("unet");
            totals.push(t.elapsed().as_secs_f64() * 1e3);
            let s = rt.unet_stats();
            per_op.resize(s.len(), f64::INFINITY);
            for (p, o) in per_op.iter_mut().zip(s) {
                *p = p.min(o.time.as_secs_f64() * 1e3);
            }
        }
        let min = totals.iter().cloned().fold(f64::INFINITY, f64::min);
        let mean = totals.iter().sum::<f64>() / runs as f64;
        println!(
            "\nbackground skip {}: U-Net {mean:.1} ms mean, {min:.1} ms min ({threads} threads)",
            if skip { "on" } else { "off" }
        );
        println!("| op | changed | GMAC computed / dense | min ms | GFLOP/s computed |");
        println!("|---|---:|---:|---:|---:|");
        let (mut m, mut d, mut tt) = (0u64, 0u64, 0.0);
        for (o, ms) in rt.unet_stats().iter().zip(&per_op) {
            m += o.macs;
            d += o.dense_macs;
            tt += ms;
            println!(
                "| {} | {:.1} % | {:.3} / {:.3} | {ms:.2} | {:.1} |",
                o.nodes[0],
                o.changed_share * 100.0,
                o.macs as f64 * 1e-9,
                o.dense_macs as f64 * 1e-9,
                2.0 * o.macs as f64 / (ms * 1e-3) * 1e-9
            );
        }
        let (i, o) = rt.unet_io_times();
        println!(
            "| input / output conversion (last run) | | | {:.2} / {:.2} | |",
            i.as_secs_f64() * 1e3,
            o.as_secs_f64() * 1e3
        );
        println!(
            "| sum of ops | | {:.3} / {:.3} | {tt:.2} | {:.1} |",
            m as f64 * 1e-9,
            d as f64 * 1e-9,
            2.0 * m as f64 / (tt * 1e-3) * 1e-9
        );
    }
    let f = card.feature_dim();
    let n = 11_672;
    let features: Vec<f32> = (0..n * f)
        .map(|i| ((i * 7919) % 1000) as f32 * 1e-3)
        .collect();
    let mut out = HeadOutputs::default();
    rt.run_mlp(&features, n, &mut out).expect("mlp");
    let mut v = Vec::new();
    for _ in 0..runs {
        out.clear();
        let t = Instant::now();
        rt.run_mlp(&features, n, &mut out).expect("mlp");
        v.push(t.elapsed().as_secs_f64() * 1e3);
    }
    let min = v.iter().cloned().fold(f64::INFINITY, f64::min);
    let flop = 2.0 * (n * rt.mlp_macs_per_row()) as f64;
    println!(
        "\nMLP {n} rows: {:.1} ms mean, {min:.1} ms min, {:.1} GFLOP/s at the min",
        v.iter().sum::<f64>() / runs as f64,
        flop / (min * 1e-3) * 1e-9
    );
}
