//! Learned backend speed per stage on a 64³ fused grid (a procedural bin scene rendered top-down
//! and fused), for tract, the native runtime and — with `--features ort` — ONNX Runtime, side by
//! side, with the U-Net's and the MLP's GFLOP/s against this machine's measured FMA peak; then
//! the native runtime's background skip (changed share, work, time with and without it) on the
//! bench scene, on a sequence of different scenes and on the real RealSense frame
//! (`../shared/real`, skipped when absent).
//!
//! Run: `cargo bench -p psgrasp-inference --bench learned [-- MODEL_DIR]`
//! (`--features ort` with `ORT_DYLIB_PATH=/path/to/libonnxruntime.so` adds the ort rows).
//! The model directory is the argument, else `$PSGRASP_MODEL_DIR`, else `models/default` in the
//! repository. `PSGRASP_BENCH_ITERS` sets the timed runs per row (default 5), `PSGRASP_BENCH_THREADS`
//! a comma-separated list of thread counts (default `1,2`), `PSGRASP_BENCH_GRIPPER` the hand the
//! model was trained for (default `franka`; `franka-15mm` for the models made before 2026-12-04).
//!
//! Two contact settings per runtime: the card's threshold, and a forced 4096 contact voxels
//! (threshold 0, the cap decides), the worst case of the default config.
use psgrasp_fusion::NormalGrid;
use psgrasp_geometry::Workspace;
use psgrasp_inference::learned::{
    decode, load_model_dir, sampling, ClassProbabilities, Decoder, FeaturePyramid, GraphRuntime,
    HeadOutputs,
};
use psgrasp_inference::native::NativeRuntime;
use psgrasp_inference::{
    InferenceBackend, LearnedBackend, LearnedConfig, LearnedModel, ModelCard, RuntimeKind,
    StageTimings,
};
use std::hint::black_box;
use std::path::Path;
use std::time::{Duration, Instant};

mod common;
use common::{bench_gripper, bench_threads, env_usize, fused_grid, mean_min, model_dir, ms};

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
    println!(
        "| runtime | threads | contacts | contact voxels | points | U-Net | sampling | MLP | decoding | total \
         | U-Net GFLOP/s dense-eq. (% of peak) | MLP GFLOP/s (% of peak) |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|");
    let files = load_model_dir(&dir, &workspace, &bench_gripper()).expect("model");
    let unet_gflop = 2e-9
        * psgrasp_inference::native::plan_unet(&files.unet_onnx, &card)
            .expect("plan")
            .dense_macs() as f64;
    let mlp_flop_per_point = 2.0
        * psgrasp_inference::native::plan_mlp(&files.mlp_onnx, &card)
            .expect("plan")
            .macs_per_row() as f64;
    let peaks: Vec<(usize, f64)> = threads.iter().map(|&t| (t, fma_peak_gflops(t))).collect();
    let peak = |t: usize| peaks.iter().find(|p| p.0 == t).map_or(f64::NAN, |p| p.1);
    let mut runtimes = vec![RuntimeKind::Tract];
    if cfg!(feature = "ort") {
        runtimes.push(RuntimeKind::Ort);
    }
    runtimes.push(RuntimeKind::Native);
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
                let mut backend = match LearnedBackend::new(cfg, &workspace, bench_gripper()) {
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
                let mean_ms = |f: fn(&StageTimings) -> Duration| {
                    runs.iter().map(|r| ms(f(r))).sum::<f64>() / runs.len() as f64
                };
                let rate = |gflop: f64, ms: f64| {
                    let r = gflop / (ms * 1e-3);
                    format!("{r:.0} ({:.0} %)", 100.0 * r / peak(t))
                };
                println!(
                    "| {} | {t} | {label} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
                    runtime.name(),
                    first.contact_voxels,
                    first.points,
                    stat(|r| r.unet),
                    stat(|r| r.sampling),
                    stat(|r| r.mlp),
                    stat(|r| r.decoding),
                    stat(|r| r.total),
                    rate(unet_gflop, mean_ms(|r| r.unet)),
                    rate(
                        first.points as f64 * mlp_flop_per_point * 1e-9,
                        mean_ms(|r| r.mlp)
                    ),
                );
            }
        }
    }
    for (t, p) in &peaks {
        println!(
            "\nFMA peak, {t} thread(s): {p:.0} GFLOP/s (measured: independent AVX2 FMA chains; \
             U-Net dense-equivalent {unet_gflop:.2} GFLOP, MLP {:.0} kFLOP per point)",
            mlp_flop_per_point * 1e-3
        );
    }
    background_skip(&files, &grid, iters, *threads.last().unwrap_or(&2));
    approximate_band(&dir, &grid, iters, *threads.last().unwrap_or(&2));
    breakdown(&dir, workspace, &grid, iters.max(10));
}

/// The native runtime's approximate mode (`native_band_voxels`, off by default): U-Net time
/// and how far the backend's outputs move from the exact ones, per band width.
fn approximate_band(dir: &Path, grid: &NormalGrid, iters: usize, threads: usize) {
    let card = ModelCard::read(dir).expect("card");
    let workspace = card.workspace();
    let mut inputs = vec![("bench scene", grid.clone())];
    if let Some(g) = real_grid(workspace) {
        inputs.push(("real frame", g));
    }
    println!(
        "\nNative approximate mode (`native_band_voxels`, off by default; {threads} threads): the \
         U-Net only within the band around the non-zero input, against the exact outputs \
         (card threshold). Contacts: voxels selected by both / only exact / only approximate; \
         the grasp differences are over the contacts both select\n"
    );
    println!("| input | band (voxels) | U-Net ms mean (min) | max abs Δ P_contact | max abs Δ P_gripper | contacts both / exact only / approx. only | max abs Δ quality | max abs Δ width (mm) | max Δ baseline (°) |");
    println!("|---|---|---|---|---|---|---|---|---|");
    for (label, g) in &inputs {
        let backend = |band: usize| {
            let cfg = LearnedConfig {
                model_dir: dir.to_path_buf(),
                runtime: RuntimeKind::Native,
                threads,
                native_band_voxels: band,
                ..LearnedConfig::default()
            };
            LearnedBackend::new(cfg, &workspace, bench_gripper()).expect("native backend")
        };
        let mut exact = backend(0);
        let reference = exact.infer(&g.view(), 0).expect("inference");
        let ref_probs = exact.last_probabilities().clone();
        for band in [0usize, 16, 12, 8, 6, 4] {
            let mut b = backend(band);
            b.infer(&g.view(), 0).expect("inference");
            let v: Vec<f64> = (0..iters)
                .map(|_| {
                    b.infer(&g.view(), 0).expect("inference");
                    ms(b.last_timings().unet)
                })
                .collect();
            let configs = b.infer(&g.view(), 0).expect("inference");
            let p = b.last_probabilities();
            let dmax = |a: &[f32], b: &[f32]| {
                a.iter()
                    .zip(b)
                    .map(|(x, y)| (x - y).abs())
                    .fold(0.0f32, f32::max)
            };
            let key = |c: &psgrasp_geometry::GraspConfiguration| {
                let q = |v: f32| (v * 1e5).round() as i64;
                [q(c.contact.x), q(c.contact.y), q(c.contact.z)]
            };
            let theirs: std::collections::HashMap<[i64; 3], &psgrasp_geometry::GraspConfiguration> =
                configs.iter().map(|c| (key(c), c)).collect();
            let (mut both, mut dq, mut dw, mut da) = (0usize, 0.0f32, 0.0f32, 0.0f32);
            for c in &reference {
                if let Some(o) = theirs.get(&key(c)) {
                    both += 1;
                    dq = dq.max((c.quality - o.quality).abs());
                    dw = dw.max((c.width - o.width).abs());
                    da = da.max(c.baseline.angle(&o.baseline).to_degrees());
                }
            }
            println!(
                "| {label} | {} | {} | {:.1e} | {:.1e} | {} / {} / {} | {dq:.1e} | {:.2} | {da:.2} |",
                if band == 0 { "exact".to_string() } else { band.to_string() },
                mean_min(&v, 1),
                dmax(&p.contact, &ref_probs.contact),
                dmax(&p.gripper, &ref_probs.gripper),
                both / 8,
                (reference.len() - both) / 8,
                (configs.len() - both) / 8,
                dw * 1e3,
            );
        }
    }
}

/// Measured peak of `threads` threads: 12 independent AVX2 FMA chains per thread, no memory.
#[cfg(not(target_arch = "x86_64"))]
fn fma_peak_gflops(_threads: usize) -> f64 {
    f64::NAN
}

/// Measured peak of `threads` threads: 12 independent AVX2 FMA chains per thread, no memory.
#[cfg(target_arch = "x86_64")]
fn fma_peak_gflops(threads: usize) -> f64 {
    let Some(v3) = pulp::x86::V3::try_new() else {
        return f64::NAN;
    };
    let iters = 50_000_000usize;
    let run = move || {
        v3.vectorize(
            #[inline(always)]
            || {
                let a = v3.avx._mm256_set1_ps(0.999);
                let b = v3.avx._mm256_set1_ps(0.001);
                let mut acc = [v3.avx._mm256_setzero_ps(); 12];
                for _ in 0..iters {
                    for x in acc.iter_mut() {
                        *x = v3.fma._mm256_fmadd_ps(*x, a, b);
                    }
                }
                black_box(acc);
            },
        )
    };
    let best = (0..3)
        .map(|_| {
            let t = Instant::now();
            std::thread::scope(|s| {
                for _ in 0..threads {
                    s.spawn(run);
                }
            });
            t.elapsed().as_secs_f64()
        })
        .fold(f64::INFINITY, f64::min);
    (threads * iters * 12 * 16) as f64 / best * 1e-9
}

/// Fused grid of the real RealSense frame in `../shared/real` (the workspace placed on the
/// table as `psgrasp detect` does), if the frame is there.
fn real_grid(workspace: Workspace) -> Option<NormalGrid> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/real/graspnet-realsense-example");
    let json = std::fs::read_to_string(dir.join("intrinsics.json")).ok()?;
    let k: psgrasp_geometry::CameraIntrinsics = serde_json::from_str(&json).ok()?;
    let depth = psgrasp_fusion::load_depth_png(dir.join("depth.png"), 0.001).ok()?;
    let plane = psgrasp_fusion::fit_support_plane(&depth, &k, &Default::default(), 42).ok()?;
    let cam =
        psgrasp_fusion::workspace_camera_from_plane(&plane, &k, &workspace, &Default::default())
            .ok()?;
    let mut vol = psgrasp_fusion::TsdfVolume::new(workspace, &Default::default()).ok()?;
    vol.integrate(&depth, &cam).ok()?;
    Some(vol.normal_grid())
}

/// The native runtime's background skip: share of each level that may differ from the
/// background, work and U-Net time with the skip on and off.
fn background_skip(
    files: &psgrasp_inference::learned::ModelFiles,
    grid: &NormalGrid,
    iters: usize,
    threads: usize,
) {
    let workspace = files.card.workspace();
    let n = 3 * workspace.voxel_count();
    let mut inputs: Vec<(String, Vec<Vec<f32>>)> = vec![(
        "bench scene (seed 3), repeated".into(),
        vec![grid.normals[..n].to_vec()],
    )];
    let bin = psgrasp_geometry::BinModel::default();
    let scenes: Vec<Vec<f32>> = (10..18)
        .map(|seed| {
            let scene = psgrasp_sim::procedural_scene(seed, 12, &bin).expect("scene");
            let g = psgrasp_test_support::scenes::fused_top_down(&scene, &workspace);
            g.normals[..n].to_vec()
        })
        .collect();
    inputs.push(("8 different scenes in turn (seeds 10–17)".into(), scenes));
    if let Some(g) = real_grid(workspace) {
        inputs.push((
            "real RealSense frame (../shared/real), repeated".into(),
            vec![g.normals[..n].to_vec()],
        ));
    }
    let mut rt = NativeRuntime::new(files, threads).expect("native runtime");
    println!(
        "\nNative U-Net, background skip ({threads} threads, {} kernels): share of each level that \
         may differ from the background (input / enc0 / enc1 / enc2 / dec0), work computed, U-Net \
         time mean (min) in ms\n",
        rt.simd_name()
    );
    println!("| input | changed share input / enc0 / enc1 / enc2 / dec0 | GMAC computed of dense | U-Net, skip on | U-Net, skip off | speed-up (mean) |");
    println!("|---|---|---|---|---|---|");
    for (label, frames) in &inputs {
        let mut times = [Vec::new(), Vec::new()];
        let mut shares = Vec::new();
        let mut computed = (0u64, 0u64);
        for (k, skip) in [true, false].into_iter().enumerate() {
            rt.set_background_skip(skip);
            rt.run_unet(&frames[frames.len() - 1]).expect("unet");
            for i in 0..iters.max(frames.len()) {
                let f = &frames[i % frames.len()];
                let t = Instant::now();
                black_box(rt.run_unet(f).expect("unet"));
                times[k].push(ms(t.elapsed()));
                if skip {
                    let s = rt.unet_stats();
                    computed.0 += s.iter().map(|o| o.macs).sum::<u64>();
                    computed.1 += s.iter().map(|o| o.dense_macs).sum::<u64>();
                    let at = |name: &str| {
                        s.iter()
                            .rev()
                            .find(|o| o.nodes.iter().any(|n| n.contains(name)))
                            .map_or(f64::NAN, |o| o.changed_share)
                    };
                    let input = f.chunks(workspace.voxel_count()).fold(
                        vec![false; workspace.voxel_count()],
                        |mut m, c| {
                            m.iter_mut().zip(c).for_each(|(m, &v)| *m |= v != 0.0);
                            m
                        },
                    );
                    let input = input.iter().filter(|&&b| b).count() as f64 / input.len() as f64;
                    shares.push([
                        input,
                        at("enc.0/"),
                        at("enc.1/"),
                        at("enc.2/"),
                        at("dec.0/"),
                    ]);
                }
            }
        }
        let avg = |i: usize| shares.iter().map(|s| s[i]).sum::<f64>() / shares.len() as f64;
        let mean = |v: &Vec<f64>| v.iter().sum::<f64>() / v.len() as f64;
        println!(
            "| {label} | {:.1} / {:.1} / {:.1} / {:.1} / {:.1} % | {:.2} of {:.2} ({:.0} %) | {} | {} | {:.2}× |",
            100.0 * avg(0),
            100.0 * avg(1),
            100.0 * avg(2),
            100.0 * avg(3),
            100.0 * avg(4),
            computed.0 as f64 * 1e-9 / shares.len() as f64,
            computed.1 as f64 * 1e-9 / shares.len() as f64,
            100.0 * computed.0 as f64 / computed.1 as f64,
            mean_min(&times[0], 1),
            mean_min(&times[1], 1),
            mean(&times[1]) / mean(&times[0]),
        );
    }
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
    let files = load_model_dir(dir, &workspace, &bench_gripper()).expect("model");
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
