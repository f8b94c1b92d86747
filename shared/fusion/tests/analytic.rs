//! Fusion of analytic scenes rendered by the ray caster in `common`: TSDF zero crossings,
//! nearest-surface normals, multi-view fusion and volume bookkeeping.
mod common;

use common::*;
use nalgebra::{Point3, Vector3};
use psgrasp_fusion::{fuse_into, fuse_normal_grid, FusionConfig, NormalGrid, TsdfVolume};
use psgrasp_geometry::CameraModel;

/// Ambiguity margin of the ground truth: 1.5 voxels.
const MARGIN: f32 = 1.5 * 0.009;

fn fuse(scene: &Scene, cameras: &[CameraModel]) -> NormalGrid {
    let mut vol = TsdfVolume::new(workspace(), &FusionConfig::default()).unwrap();
    for cam in cameras {
        vol.integrate(&scene.render(cam), cam).unwrap();
    }
    vol.normal_grid()
}

fn check_scene(name: &str, scene: &Scene, cameras: &[CameraModel]) -> (NormalGrid, NormalReport) {
    let grid = fuse(scene, cameras);
    let report = evaluate_normals(&grid, scene, cameras, MARGIN);
    let (cols, max_err, mean_err) = zero_crossing_errors(&grid, scene, cameras, MARGIN);
    println!(
        "{name}: band {} evaluated {} within5° {:.4} p50 {:.2}° p95 {:.2}° p99 {:.2}° zero-normals {} | zero crossing cols {cols} max {:.2} mm mean {:.2} mm",
        report.band,
        report.evaluated,
        report.fraction_within(),
        report.percentile(0.5),
        report.percentile(0.95),
        report.percentile(0.99),
        report.zero_normals,
        max_err * 1e3,
        mean_err * 1e3
    );
    assert!(cols > 1000, "{name}: only {cols} columns checked");
    assert!(max_err < 0.5 * 0.009, "{name}: zero crossing off by {:.2} mm", max_err * 1e3);
    assert!(report.evaluated as f32 >= 0.75 * report.band as f32, "{name}: too much excluded: {report:?}");
    assert!(report.fraction_within() >= 0.95, "{name}: only {:.3} within 5°", report.fraction_within());
    assert_eq!(report.zero_normals, 0, "{name}: band voxels without a normal");
    (grid, report)
}

#[test]
fn floor_seen_top_down() {
    let scene = Scene { shapes: vec![floor()] };
    let (grid, report) = check_scene("floor", &scene, &[top_camera()]);
    // A plane is represented exactly: every band voxel points straight up.
    assert!(report.percentile(1.0) < 0.5, "worst {:.3}°", report.percentile(1.0));
    // The band is 2 × 4 voxels thick around z = 0.1 m over the whole seen floor.
    let ws = grid.workspace;
    let floor_k = FLOOR_Z / ws.voxel_size_m;
    for idx in 0..ws.voxel_count() {
        let [_, _, k] = ws.unindex(idx);
        let dz = (k as f32 + 0.5 - floor_k).abs();
        if grid.tsdf[idx].abs() < 1.0 {
            assert!(dz < 4.0 + 1e-3, "band voxel {dz} voxels from the floor");
        }
    }
}

#[test]
fn tilted_plane() {
    let n = Vector3::new(0.3, -0.2, 1.0).normalize();
    let d = n.dot(&Vector3::new(0.288, 0.288, 0.2));
    let scene = Scene { shapes: vec![Shape::Plane { n, d }] };
    let (_, report) = check_scene("tilted plane", &scene, &[top_camera()]);
    assert!(report.percentile(0.99) < 2.0, "p99 {:.3}°", report.percentile(0.99));
}

#[test]
fn sphere_on_floor() {
    let scene = Scene { shapes: vec![floor(), sphere()] };
    check_scene("sphere", &scene, &[top_camera()]);
}

#[test]
fn box_on_floor() {
    let scene = Scene { shapes: vec![floor(), cuboid()] };
    check_scene("box", &scene, &[top_camera()]);
}

#[test]
fn two_views_fuse_at_least_as_accurately() {
    let scene = Scene { shapes: vec![floor(), sphere(), cuboid()] };
    let (_, single) = check_scene("clutter, 1 view", &scene, &[top_camera()]);
    let (_, both) = check_scene("clutter, 2 views", &scene, &[top_camera(), side_camera()]);
    assert!(both.fraction_within() >= single.fraction_within() - 0.005);
    assert!(both.percentile(0.5) <= single.percentile(0.5) + 0.1);
    // The second view sees more of the scene (e.g. a side of the box).
    assert!(both.band > single.band);
}
