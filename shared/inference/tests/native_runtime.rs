//! The native runtime against the ONNX graphs as tract runs them: every U-Net output (label
//! logits, every encoder level) and every MLP output within 1e-4, on the fixture model and on
//! the shipped model with real fused scenes, frame after frame (the background skip keeps state
//! between frames); the scalar kernels against the SIMD ones; graphs outside the supported
//! subset refused at load, naming the node.
use psgrasp_geometry::{BinModel, GripperModel};
use psgrasp_inference::learned::{
    load_model_dir, GraphRuntime, HeadOutputs, ModelCard, ModelError, ModelFiles, TractRuntime,
};
use psgrasp_inference::native::kernels::Simd;
use psgrasp_inference::native::NativeRuntime;
use std::path::{Path, PathBuf};

const TOLERANCE: f32 = 1e-4;

fn fixture_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/tiny-model")
}

fn shipped_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/default")
}

fn files(dir: &Path) -> ModelFiles {
    let card = ModelCard::read(dir).expect("card");
    load_model_dir(dir, &card.workspace(), &GripperModel::default()).expect("model dir")
}

/// Max abs difference, asserting it is within [`TOLERANCE`] (NaN fails).
fn assert_close(what: &str, ours: &[f32], reference: &[f32]) -> f32 {
    assert_eq!(ours.len(), reference.len(), "{what}: length");
    let mut worst = 0.0f32;
    for (i, (a, b)) in ours.iter().zip(reference).enumerate() {
        let d = (a - b).abs();
        assert!(d <= TOLERANCE, "{what}[{i}]: {a} vs {b} (difference {d})");
        worst = worst.max(d);
    }
    worst
}

/// Runs both runtimes on `grid` and compares every U-Net output.
fn compare_unet(what: &str, native: &mut dyn GraphRuntime, tract: &mut TractRuntime, grid: &[f32]) {
    let ours = native.run_unet(grid).expect("native unet");
    let theirs = tract.run_unet(grid).expect("tract unet");
    assert_eq!(ours.label_logits.shape(), theirs.label_logits.shape());
    let mut worst = assert_close(
        &format!("{what} label_logits"),
        ours.label_logits.data(),
        theirs.label_logits.data(),
    );
    assert_eq!(ours.features.len(), theirs.features.len());
    for (l, (a, b)) in ours.features.iter().zip(&theirs.features).enumerate() {
        assert_eq!(a.shape(), b.shape());
        worst = worst.max(assert_close(&format!("{what} enc{l}"), a.data(), b.data()));
    }
    eprintln!("{what}: U-Net max abs difference {worst:.2e}");
}

/// Runs both runtimes' MLP on `features` (`n` rows) and compares every output.
fn compare_mlp(
    what: &str,
    native: &mut dyn GraphRuntime,
    tract: &mut TractRuntime,
    features: &[f32],
    n: usize,
) {
    let (mut a, mut b) = (HeadOutputs::default(), HeadOutputs::default());
    native.run_mlp(features, n, &mut a).expect("native mlp");
    tract.run_mlp(features, n, &mut b).expect("tract mlp");
    let mut worst = 0.0f32;
    for (name, x, y) in [
        ("baseline", &a.baseline, &b.baseline),
        ("kappa", &a.kappa, &b.kappa),
        ("width", &a.width, &b.width),
        ("quality_prior", &a.quality_prior, &b.quality_prior),
        ("collision_prior", &a.collision_prior, &b.collision_prior),
    ] {
        worst = worst.max(assert_close(&format!("{what} {name}"), x, y));
    }
    eprintln!("{what}: MLP ({n} rows) max abs difference {worst:.2e}");
}

/// Deterministic pseudo-random values in [lo, hi).
fn noise(n: usize, seed: u64, lo: f32, hi: f32) -> Vec<f32> {
    let mut s = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    (0..n)
        .map(|_| {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            lo + (hi - lo) * ((s >> 40) as f32 / (1u64 << 24) as f32)
        })
        .collect()
}

/// A normal grid that is zero outside the box `lo..hi` (voxels) and noise inside.
fn boxed_grid(dims: [usize; 3], lo: [usize; 3], hi: [usize; 3], seed: u64) -> Vec<f32> {
    let n = dims.iter().product::<usize>();
    let values = noise(3 * n, seed, -1.0, 1.0);
    let mut g = vec![0.0; 3 * n];
    for c in 0..3 {
        for x in lo[0]..hi[0] {
            for y in lo[1]..hi[1] {
                for z in lo[2]..hi[2] {
                    let i = c * n + (x * dims[1] + y) * dims[2] + z;
                    g[i] = values[i];
                }
            }
        }
    }
    g
}

#[test]
fn fixture_model_equals_tract_frame_after_frame() {
    let files = files(&fixture_dir());
    let dims = files.card.dims();
    let mut tract = TractRuntime::new(&files, 1).unwrap();
    for (threads, simd) in [(1, Simd::detect()), (2, Simd::detect()), (1, Simd::Scalar)] {
        let mut native = NativeRuntime::with_simd(&files, threads, simd).unwrap();
        let tag = format!("fixture {threads} thread(s) {}", simd.name());
        // Frames whose non-zero regions grow, move, touch the faces and vanish: each frame's
        // outputs must not depend on the frames before.
        let frames = [
            boxed_grid(dims, [5, 6, 7], [8, 9, 10], 1),
            boxed_grid(dims, [0, 0, 0], [dims[0], dims[1], dims[2]], 2),
            boxed_grid(dims, [10, 2, 12], [16, 5, 16], 3),
            vec![0.0; 3 * dims.iter().product::<usize>()],
            boxed_grid(dims, [0, 9, 0], [3, 16, 2], 4),
            boxed_grid(dims, [5, 6, 7], [8, 9, 10], 1),
        ];
        for (i, g) in frames.iter().enumerate() {
            compare_unet(&format!("{tag} frame {i}"), &mut native, &mut tract, g);
        }
        // Outputs still held while the next frame runs stay those of their frame (the runtime
        // updates its shared output grids in place only when nobody else holds them).
        let held = native.run_unet(&frames[1]).unwrap();
        let logits = held.label_logits.data().to_vec();
        let enc0 = held.features[0].data().to_vec();
        compare_unet(
            &format!("{tag} while held"),
            &mut native,
            &mut tract,
            &frames[2],
        );
        assert_eq!(held.label_logits.data(), &logits[..]);
        assert_eq!(held.features[0].data(), &enc0[..]);
        drop(held);
        compare_unet(
            &format!("{tag} after held"),
            &mut native,
            &mut tract,
            &frames[1],
        );
        let f = files.card.feature_dim();
        for (n, seed) in [(1usize, 7u64), (95, 8), (96, 9), (250, 10)] {
            compare_mlp(
                &tag,
                &mut native,
                &mut tract,
                &noise(n * f, seed, -2.0, 3.0),
                n,
            );
        }
    }
}

/// All outputs of one U-Net run, concatenated.
fn unet_values(rt: &mut NativeRuntime, grid: &[f32]) -> Vec<f32> {
    let o = rt.run_unet(grid).expect("unet");
    let mut v = o.label_logits.data().to_vec();
    for f in &o.features {
        v.extend_from_slice(f.data());
    }
    v
}

#[test]
fn approximate_band_mode_is_exact_with_a_wide_band_and_forgets_earlier_frames() {
    let files = files(&fixture_dir());
    let dims = files.card.dims();
    let frames = [
        boxed_grid(dims, [5, 6, 7], [8, 9, 10], 1),
        boxed_grid(dims, [0, 0, 0], [4, 16, 3], 2),
        boxed_grid(dims, [10, 2, 12], [16, 5, 16], 3),
    ];
    let mut exact = NativeRuntime::new(&files, 1).unwrap();
    let mut wide = NativeRuntime::new(&files, 1).unwrap();
    wide.set_band(32);
    let mut narrow = NativeRuntime::new(&files, 1).unwrap();
    narrow.set_band(2);
    for (i, g) in frames.iter().chain(frames.iter().rev()).enumerate() {
        let e = unet_values(&mut exact, g);
        assert_close(
            &format!("wide band, frame {i}"),
            &unet_values(&mut wide, g),
            &e,
        );
        // The narrow band's outputs depend on this frame only: a fresh runtime agrees.
        let mut fresh = NativeRuntime::new(&files, 1).unwrap();
        fresh.set_band(2);
        let n = unet_values(&mut narrow, g);
        assert_eq!(n, unet_values(&mut fresh, g), "narrow band, frame {i}");
        let worst = n
            .iter()
            .zip(&e)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        eprintln!("narrow band (2 voxels), frame {i}: max abs difference to exact {worst:.2e}");
    }
}

#[test]
fn shipped_model_equals_tract_on_fused_scenes() {
    let files = files(&shipped_dir());
    let workspace = files.card.workspace();
    let bin = BinModel::default();
    let grids: Vec<Vec<f32>> = [3u64, 5]
        .iter()
        .map(|&seed| {
            let scene = psgrasp_sim::procedural_scene(seed, 12, &bin).expect("scene");
            let grid = psgrasp_test_support::scenes::fused_top_down(&scene, &workspace);
            grid.normals[..3 * workspace.voxel_count()].to_vec()
        })
        .collect();
    let mut tract = TractRuntime::new(&files, 2).unwrap();
    let mut native = NativeRuntime::new(&files, 2).unwrap();
    for (i, g) in [&grids[0], &grids[1], &grids[0]].into_iter().enumerate() {
        compare_unet(&format!("shipped frame {i}"), &mut native, &mut tract, g);
    }
    let stats = native.unet_stats();
    let computed: u64 = stats.iter().map(|s| s.macs).sum();
    let dense: u64 = stats.iter().map(|s| s.dense_macs).sum();
    eprintln!(
        "shipped: {:.2} of {:.2} GMAC computed ({:.0} %)",
        computed as f64 * 1e-9,
        dense as f64 * 1e-9,
        100.0 * computed as f64 / dense as f64
    );
    assert!(computed < dense, "the background skip computed everything");
    // Real features: the levels sampled at the contact points of the last frame.
    let f = files.card.feature_dim();
    let n = 1000;
    compare_mlp(
        "shipped",
        &mut native,
        &mut tract,
        &noise(n * f, 11, 0.0, 4.0),
        n,
    );
}

/// The fixture directory's files with `from` replaced by `to` (same length) in one graph.
fn patched(graph: &str, from: &[u8], to: &[u8]) -> ModelFiles {
    let mut files = files(&fixture_dir());
    let bytes = if graph == "unet" {
        &mut files.unet_onnx
    } else {
        &mut files.mlp_onnx
    };
    assert_eq!(from.len(), to.len());
    let mut hits = 0;
    for i in 0..bytes.len().saturating_sub(from.len()) {
        if &bytes[i..i + from.len()] == from {
            bytes[i..i + from.len()].copy_from_slice(to);
            hits += 1;
        }
    }
    assert!(hits > 0, "{} not found", String::from_utf8_lossy(from));
    files
}

#[test]
fn graphs_outside_the_subset_are_refused_naming_the_node() {
    // Every Relu of the U-Net becomes a Tanh (names too, so the graph stays valid for tract).
    let files = patched("unet", b"Relu", b"Tanh");
    TractRuntime::new(&files, 1).expect("tract runs the patched graph");
    let err = NativeRuntime::new(&files, 1).unwrap_err();
    let ModelError::Graph {
        graph,
        runtime,
        source,
    } = &err
    else {
        panic!("expected a graph error, got {err}");
    };
    assert_eq!((*graph, *runtime), ("unet", "native"));
    let msg = source.to_string();
    assert!(
        msg.contains("node `/unet/stem/stem.2/Tanh` (Tanh)"),
        "{msg}"
    );
    assert!(msg.contains("outside the native U-Net subset"), "{msg}");

    // The MLP's Softplus becomes a Softsign.
    let files = patched("mlp", b"Softplus", b"Softsign");
    let err = NativeRuntime::new(&files, 1).unwrap_err();
    let msg = std::error::Error::source(&err)
        .map(|s| s.to_string())
        .unwrap_or_default();
    assert!(
        msg.contains("(Softsign)") && msg.contains("native MLP subset"),
        "{msg}"
    );

    // Garbage is an error, not a panic.
    let mut files = files;
    files.unet_onnx.truncate(files.unet_onnx.len() / 3);
    assert!(NativeRuntime::new(&files, 1).is_err());
}
