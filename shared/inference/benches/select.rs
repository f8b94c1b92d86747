//! Selection speed on the analytic backend's output for cluttered synthetic bins (here, not in
//! `psgrasp-selection`, which does not depend on the backends).
//!
//! Run: `cargo bench -p psgrasp-inference --bench select`. Prints one table; single-threaded.
use nalgebra::{Point2, Vector3};
use psgrasp_geometry::{BinModel, GripperModel, Workspace};
use psgrasp_inference::{
    AnalyticBackend, AnalyticConfig, ContactRegion, InferenceBackend, OccupancyGrid,
};
use psgrasp_selection::{select, select_with_occupancy, SelectionConfig};
use psgrasp_test_support::synthetic::{Primitive, SyntheticScene};
use std::hint::black_box;
use std::time::Instant;

const ITERATIONS: usize = 20;

fn time_ms(mut f: impl FnMut()) -> f64 {
    f();
    let t = Instant::now();
    for _ in 0..ITERATIONS {
        f();
    }
    t.elapsed().as_secs_f64() * 1e3 / ITERATIONS as f64
}

fn main() {
    let ws = Workspace::default();
    let bin = BinModel::default();
    let gripper = GripperModel::default();
    println!("selection on analytic configurations, 64³ × 9 mm grid, {ITERATIONS} runs each\n");
    println!("| scene | configurations | picks | select ms (incl. occupancy) | select ms (prebuilt occupancy) |");
    println!("|---|---|---|---|---|");
    for objects in [10, 25, 40] {
        let mut scene = SyntheticScene::random_clutter(
            bin.floor_center.z,
            Point2::new(0.06, 0.12),
            Point2::new(0.52, 0.46),
            objects,
            42,
        );
        for y in [0.083, 0.493] {
            scene.objects.push(Primitive::Box {
                center_xy: Point2::new(0.288, y),
                size_m: Vector3::new(0.62, 0.01, 0.28),
                yaw_rad: 0.0,
            });
        }
        let grid = scene.normal_grid(ws, 0.027);
        let cfg = AnalyticConfig {
            contact_region: Some(ContactRegion::inside_bin(&bin, 0.005)),
            ..AnalyticConfig::default()
        };
        let configs = AnalyticBackend::new(cfg, gripper)
            .expect("valid config")
            .infer(&grid.view(), 7)
            .expect("valid grid");
        let sel_cfg = SelectionConfig::default();
        let mut picks = 0;
        let full = time_ms(|| {
            picks =
                black_box(select(&configs, &grid.view(), &bin, &gripper, &sel_cfg).expect("valid"))
                    .picks
                    .len();
        });
        let occupancy =
            OccupancyGrid::from_normal_grid(&grid.view(), &sel_cfg.occupancy).expect("valid grid");
        let reuse = time_ms(|| {
            black_box(
                select_with_occupancy(&configs, Some(&occupancy), &bin, &gripper, &sel_cfg)
                    .expect("valid"),
            );
        });
        println!(
            "| {objects} objects | {} | {picks} | {full:.2} | {reuse:.2} |",
            configs.len()
        );
    }
}
