//! Fusion of analytic scenes rendered by the ray caster in `psgrasp_test_support::analytic`: TSDF zero crossings,
//! nearest-surface normals, multi-view fusion and volume bookkeeping.
use nalgebra::Vector3;
use psgrasp_fusion::{FusionConfig, NormalGrid, TsdfVolume};
use psgrasp_geometry::CameraModel;
use psgrasp_test_support::analytic::*;

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
    let (cols, missing, max_err, mean_err) = zero_crossing_errors(&grid, scene, cameras, MARGIN);
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
    assert_eq!(missing, 0, "{name}: columns without a zero crossing");
    assert!(
        max_err < 0.5 * 0.009,
        "{name}: zero crossing off by {:.2} mm",
        max_err * 1e3
    );
    assert!(
        report.evaluated as f32 >= 0.75 * report.band as f32,
        "{name}: too much excluded: {report:?}"
    );
    assert!(
        report.fraction_within() >= 0.95,
        "{name}: only {:.3} within 5°",
        report.fraction_within()
    );
    assert_eq!(
        report.zero_normals, 0,
        "{name}: band voxels without a normal"
    );
    (grid, report)
}

#[test]
fn floor_seen_top_down() {
    let scene = Scene {
        shapes: vec![floor()],
    };
    let (grid, report) = check_scene("floor", &scene, &[top_camera()]);
    // A plane is represented exactly: every band voxel points straight up.
    assert!(
        report.percentile(1.0) < 0.5,
        "worst {:.3}°",
        report.percentile(1.0)
    );
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
    let scene = Scene {
        shapes: vec![Shape::Plane { n, d }],
    };
    let (_, report) = check_scene("tilted plane", &scene, &[top_camera()]);
    assert!(
        report.percentile(0.99) < 2.0,
        "p99 {:.3}°",
        report.percentile(0.99)
    );
}

#[test]
fn sphere_on_floor() {
    let scene = Scene {
        shapes: vec![floor(), sphere()],
    };
    check_scene("sphere", &scene, &[top_camera()]);
}

#[test]
fn box_on_floor() {
    let scene = Scene {
        shapes: vec![floor(), cuboid()],
    };
    check_scene("box", &scene, &[top_camera()]);
}

#[test]
fn two_views_fuse_at_least_as_accurately() {
    let scene = Scene {
        shapes: vec![floor(), sphere(), cuboid()],
    };
    let top = [top_camera()];
    let both = [top_camera(), side_camera()];
    let (g1, r1) = check_scene("clutter, 1 view", &scene, &top);
    let (g2, r2) = check_scene("clutter, 2 views", &scene, &both);
    // The second view sees more of the scene (e.g. the +x side of the box).
    assert!(r2.band > r1.band + 1000, "band {} vs {}", r2.band, r1.band);
    // On the voxels both grids describe (in both bands, truth known from the top view), the
    // fused normals are at least as accurate.
    let ws = g1.workspace;
    let (v1, v2) = (g1.view(), g2.view());
    let (mut n, mut ok1, mut ok2, mut sum1, mut sum2) = (0usize, 0usize, 0usize, 0.0f64, 0.0f64);
    for idx in 0..ws.voxel_count() {
        if g1.tsdf[idx].abs() >= 1.0 || g2.tsdf[idx].abs() >= 1.0 {
            continue;
        }
        let [i, j, k] = ws.unindex(idx);
        let Some(t) = scene.truth(&top, &ws.voxel_center(i, j, k), MARGIN) else {
            continue;
        };
        let e = |v: &psgrasp_fusion::NormalGridView<'_>| {
            let a = v.normal(idx);
            angle_deg(&Vector3::new(a[0], a[1], a[2]), &t.normal)
        };
        let (e1, e2) = (e(&v1), e(&v2));
        n += 1;
        ok1 += usize::from(e1 <= 5.0);
        ok2 += usize::from(e2 <= 5.0);
        sum1 += e1 as f64;
        sum2 += e2 as f64;
    }
    let (f1, f2) = (ok1 as f64 / n as f64, ok2 as f64 / n as f64);
    println!(
        "common voxels {n}: within 5° {f1:.4} → {f2:.4}, mean error {:.3}° → {:.3}°",
        sum1 / n as f64,
        sum2 / n as f64
    );
    assert!(n > 20_000);
    assert!(f2 >= f1 - 0.002, "fused {f2:.4} < single {f1:.4}");
    assert!(sum2 <= sum1 * 1.05, "mean error grew: {sum1} → {sum2}");
}
