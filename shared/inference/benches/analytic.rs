//! Analytic backend speed on cluttered synthetic bins (64³ × 9 mm grid, exact normal grids).
//!
//! Run: `cargo bench -p psgrasp-inference --bench analytic`. Prints one table; single-threaded.
use nalgebra::{Isometry3, Point2, Translation3, UnitQuaternion, Vector3};
use psgrasp_geometry::{BinModel, GripperModel, Workspace};
use psgrasp_inference::{
    AnalyticBackend, AnalyticConfig, ContactRegion, InferenceBackend, OccupancyConfig,
    OccupancyGrid, SceneCollisionChecker,
};
use psgrasp_test_support::synthetic::{Primitive, SyntheticScene};
use std::hint::black_box;
use std::time::Instant;

const ITERATIONS: usize = 10;

/// A bin floor at 18 mm, the two long walls inside the grid and `objects` random primitives.
fn scene(objects: usize, seed: u64) -> SyntheticScene {
    let mut s = SyntheticScene::random_clutter(
        0.018,
        Point2::new(0.06, 0.12),
        Point2::new(0.52, 0.46),
        objects,
        seed,
    );
    for y in [0.083, 0.493] {
        s.objects.push(Primitive::Box {
            center_xy: Point2::new(0.288, y),
            size_m: Vector3::new(0.62, 0.01, 0.28),
            yaw_rad: 0.0,
        });
    }
    s
}

/// (mean, min) milliseconds of `f` over `ITERATIONS` runs after one warm-up.
fn time_ms(mut f: impl FnMut()) -> (f64, f64) {
    f();
    let mut times = Vec::with_capacity(ITERATIONS);
    for _ in 0..ITERATIONS {
        let t = Instant::now();
        f();
        times.push(t.elapsed().as_secs_f64() * 1e3);
    }
    (
        times.iter().sum::<f64>() / times.len() as f64,
        times.iter().cloned().fold(f64::INFINITY, f64::min),
    )
}

fn main() {
    let ws = Workspace::default();
    let gripper = GripperModel::default();
    println!(
        "analytic backend, {}³ grid of {} mm voxels, truncation 27 mm, {ITERATIONS} runs each\n",
        ws.dims[0],
        ws.voxel_size_m * 1e3
    );
    println!("| scene | surface voxels | sampled | candidates | configurations | infer mean ms | infer min ms |");
    println!("|---|---|---|---|---|---|---|");
    let region = ContactRegion::inside_bin(&BinModel::default(), 0.005);
    let rows = [
        (10, 4000, true),
        (25, 4000, true),
        (25, 1000, true),
        (40, 4000, true),
        (25, 4000, false),
    ];
    for (objects, samples, in_bin) in rows {
        let grid = scene(objects, 42).normal_grid(ws, 0.027);
        let cfg = AnalyticConfig {
            max_contact_samples: samples,
            contact_region: in_bin.then_some(region),
            ..AnalyticConfig::default()
        };
        let mut backend = AnalyticBackend::new(cfg, gripper).expect("valid config");
        let mut n = 0;
        let (mean, min) =
            time_ms(|| n = black_box(backend.infer(&grid.view(), 7).expect("valid grid")).len());
        let s = backend.last_stats();
        println!(
            "| {objects} objects, {samples} samples, {} | {} | {} | {} | {n} | {mean:.1} | {min:.1} |",
            if in_bin { "contacts in bin" } else { "whole grid (walls too)" },
            s.surface_voxels, s.sampled_contacts, s.candidates
        );
    }

    let grid = scene(25, 42).normal_grid(ws, 0.027);
    let (build_mean, build_min) = time_ms(|| {
        black_box(
            OccupancyGrid::from_normal_grid(&grid.view(), &OccupancyConfig::default())
                .expect("valid grid"),
        );
    });
    let checker =
        SceneCollisionChecker::from_normal_grid(&grid.view(), &OccupancyConfig::default(), gripper)
            .expect("valid grid");
    // 10 000 poses over the bin, tilted up to ~60° from straight down, at random-ish heights.
    let poses: Vec<Isometry3<f32>> = (0..10_000)
        .map(|i| {
            let f = i as f32;
            let down = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f32::consts::PI);
            let tilt = UnitQuaternion::from_scaled_axis(
                Vector3::new((f * 0.37).sin(), (f * 0.11).cos(), 0.0) * 1.0,
            );
            let t = Translation3::new(
                0.06 + (f * 0.013) % 0.46,
                0.12 + (f * 0.029) % 0.34,
                0.03 + (f * 0.007) % 0.15,
            );
            Isometry3::from_parts(t, tilt * down)
        })
        .collect();
    let mut free = 0;
    let (check_mean, _) = time_ms(|| {
        free = poses
            .iter()
            .filter(|p| !checker.gripper_collides(p, 0.06, 0.004))
            .count();
    });
    let (count_mean, _) = time_ms(|| {
        black_box(
            poses
                .iter()
                .map(|p| checker.gripper_collision_count(p, 0.06, 0.004))
                .sum::<usize>(),
        );
    });
    println!("\n| occupancy / collision (25 objects) | value |");
    println!("|---|---|");
    println!("| occupancy build, mean (min) ms | {build_mean:.2} ({build_min:.2}) |");
    println!(
        "| gripper_collides, µs per pose ({free} of {} free) | {:.2} |",
        poses.len(),
        check_mean * 1e3 / poses.len() as f64
    );
    println!(
        "| gripper_collision_count, µs per pose | {:.2} |",
        count_mean * 1e3 / poses.len() as f64
    );
}
