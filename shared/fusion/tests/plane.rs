//! Support-plane fitting and workspace placement, on analytic frames and the real RealSense frame.
use nalgebra::{Point3, Vector3};
use psgrasp_fusion::{
    fit_support_plane, fuse_normal_grid, load_depth_png, workspace_camera_from_plane, FusionConfig,
    FusionError, NormalGrid, PlacementConfig, Plane, PlaneFitConfig,
};
use psgrasp_geometry::{CameraIntrinsics, CameraModel, DepthImage};
use psgrasp_test_support::analytic::*;

const REAL: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../../../shared/real/graspnet-realsense-example"
);

/// An oblique camera over a floor with a box on it.
fn oblique_scene() -> (Scene, CameraModel) {
    let scene = Scene {
        shapes: vec![floor(), cuboid()],
    };
    let cam = look_at(
        CameraIntrinsics::default_640x480(),
        Point3::new(0.6, -0.1, FLOOR_Z + 0.6),
        Point3::new(0.25, 0.3, FLOOR_Z),
        Vector3::new(0.0, 0.0, -1.0),
    );
    (scene, cam)
}

/// Share of floor band voxels (plane at workspace height `h`, columns whose top surface is the
/// plane) whose normal is within `deg` of +z, and how many there are.
fn floor_normal_share(grid: &NormalGrid, h: f32, deg: f32) -> (f32, usize) {
    let ws = grid.workspace;
    let s = ws.voxel_size_m;
    let [nx, ny, nz] = ws.dims.map(|d| d as usize);
    let kh = (h / s) as usize;
    let view = grid.view();
    let (mut total, mut good) = (0usize, 0usize);
    for i in 2..nx - 2 {
        for j in 2..ny - 2 {
            // The column and its neighbours must be plain table: a crossing within a voxel of
            // the plane and nothing in the band above it.
            let plain = |i: usize, j: usize| {
                (kh + 6..nz).all(|k| grid.tsdf[ws.index(i, j, k)] >= 1.0)
                    && (kh.saturating_sub(1)..=kh + 1)
                        .any(|k| grid.tsdf[ws.index(i, j, k)].abs() < 0.3)
            };
            if !(i - 2..=i + 2).all(|a| (j - 2..=j + 2).all(|b| plain(a, b))) {
                continue;
            }
            for k in kh.saturating_sub(2)..=kh + 2 {
                let idx = ws.index(i, j, k);
                if grid.tsdf[idx].abs() >= 1.0 {
                    continue;
                }
                let n = view.normal(idx);
                total += 1;
                if angle_deg(&Vector3::new(n[0], n[1], n[2]), &Vector3::z()) <= deg {
                    good += 1;
                }
            }
        }
    }
    (good as f32 / total.max(1) as f32, total)
}

#[test]
fn plane_fit_on_an_analytic_frame_is_exact_and_seeded() {
    let (scene, cam) = oblique_scene();
    let depth = scene.render(&cam);
    let cfg = PlaneFitConfig::default();
    let plane = fit_support_plane(&depth, &cam.intrinsics, &cfg, 7).unwrap();
    let camera_from_workspace = cam.workspace_from_camera.inverse();
    let true_normal = camera_from_workspace.rotation * Vector3::z();
    let true_offset =
        -true_normal.dot(&(camera_from_workspace * Point3::new(0.0, 0.0, FLOOR_Z)).coords);
    assert!(angle_deg(&plane.normal, &true_normal) < 0.2, "{plane:?}");
    assert!(
        (plane.offset_m - true_offset).abs() < 0.001,
        "{plane:?} vs {true_offset}"
    );
    assert!(
        plane.inlier_fraction() > 0.6 && plane.rms_m < 1e-3,
        "{plane:?}"
    );
    assert_eq!(
        plane,
        fit_support_plane(&depth, &cam.intrinsics, &cfg, 7).unwrap()
    );
    // Another seed finds the same plane.
    let other = fit_support_plane(&depth, &cam.intrinsics, &cfg, 8).unwrap();
    assert!(angle_deg(&other.normal, &plane.normal) < 0.05);
}

#[test]
fn workspace_placed_on_the_plane_sees_a_flat_floor() {
    let (scene, cam) = oblique_scene();
    let depth = scene.render(&cam);
    let plane = fit_support_plane(&depth, &cam.intrinsics, &PlaneFitConfig::default(), 1).unwrap();
    let placement = PlacementConfig::default();
    let ws = workspace();
    let placed = workspace_camera_from_plane(&plane, &cam.intrinsics, &ws, &placement).unwrap();
    // Points of the plane land at workspace height plane_height_m.
    let p_cam = cam.intrinsics.deproject(320.0, 400.0, depth.at(320, 400));
    let p_ws = placed.workspace_from_camera * p_cam;
    assert!((p_ws.z - placement.plane_height_m).abs() < 2e-3, "{p_ws}");
    // The optical axis meets the plane at the centre of the box footprint.
    let centre =
        placed.workspace_from_camera * Point3::new(0.0, 0.0, plane.offset_m / -plane.normal.z);
    let ext = ws.extent();
    assert!(
        (centre.x - ext.x / 2.0).abs() < 1e-3 && (centre.y - ext.y / 2.0).abs() < 1e-3,
        "{centre}"
    );
    // The camera is above the plane.
    assert!(placed.eye().z > 0.3);
    let grid = fuse_normal_grid(&depth, &placed, &ws, &FusionConfig::default()).unwrap();
    let (share, total) = floor_normal_share(&grid, placement.plane_height_m, 2.0);
    assert!(total > 5000 && share > 0.98, "{share} of {total}");
}

#[test]
fn plane_fit_errors() {
    let k = CameraIntrinsics::default_640x480();
    let cfg = PlaneFitConfig::default();
    // Almost no valid pixel.
    let mut data = vec![0.0; 640 * 480];
    data[1000] = 0.8;
    let sparse = DepthImage::from_metres(640, 480, data).unwrap();
    assert!(matches!(
        fit_support_plane(&sparse, &k, &cfg, 0),
        Err(FusionError::TooFewPoints { .. })
    ));
    // A ball fills the view: no plane carries 20% of the points.
    let ball = Scene {
        shapes: vec![Shape::Sphere {
            c: Point3::new(0.0, 0.0, 0.0),
            r: 0.6,
        }],
    };
    let inside = look_at(
        k,
        Point3::new(0.0, 0.0, 0.0),
        Point3::new(0.0, 0.0, -1.0),
        Vector3::y(),
    );
    assert!(matches!(
        fit_support_plane(&ball.render(&inside), &k, &cfg, 0),
        Err(FusionError::PlaneNotFound { .. })
    ));
    // Wrong size, no valid pixel, bad config.
    let small = DepthImage::from_metres(2, 2, vec![1.0; 4]).unwrap();
    assert!(matches!(
        fit_support_plane(&small, &k, &cfg, 0),
        Err(FusionError::FrameSizeMismatch { .. })
    ));
    let nan = DepthImage::from_metres(640, 480, vec![f32::NAN; 640 * 480]).unwrap();
    assert!(matches!(
        fit_support_plane(&nan, &k, &cfg, 0),
        Err(FusionError::Depth(_))
    ));
    let bad = PlaneFitConfig {
        inlier_threshold_m: 0.0,
        ..cfg
    };
    assert!(matches!(
        fit_support_plane(&nan, &k, &bad, 0),
        Err(FusionError::InvalidConfig(_))
    ));
    // A plane the optical axis never meets cannot carry the workspace.
    let wall = Plane {
        normal: Vector3::x(),
        offset_m: 0.5,
        inlier_count: 1,
        point_count: 1,
        rms_m: 0.0,
    };
    assert!(matches!(
        workspace_camera_from_plane(&wall, &k, &workspace(), &PlacementConfig::default()),
        Err(FusionError::BadPlane(_))
    ));
    let broken = Plane {
        normal: Vector3::new(f32::NAN, 0.0, -1.0),
        ..wall
    };
    assert!(matches!(
        workspace_camera_from_plane(&broken, &k, &workspace(), &PlacementConfig::default()),
        Err(FusionError::BadPlane(_))
    ));
}

#[test]
fn real_realsense_frame() {
    let json = std::fs::read_to_string(format!("{REAL}/intrinsics.json"))
        .expect("the real test frame lives in ../shared/real next to the repository");
    let k: CameraIntrinsics = serde_json::from_str(&json).unwrap();
    let depth = load_depth_png(format!("{REAL}/depth.png"), 0.001).unwrap();
    assert_eq!((depth.width, depth.height), (1280, 720));
    let plane = fit_support_plane(&depth, &k, &PlaneFitConfig::default(), 42).unwrap();
    println!(
        "plane n {:?} offset {:.3} m, inliers {}/{} ({:.2}), rms {:.2} mm",
        plane.normal,
        plane.offset_m,
        plane.inlier_count,
        plane.point_count,
        plane.inlier_fraction(),
        plane.rms_m * 1e3
    );
    assert!(plane.inlier_fraction() > 0.4, "{plane:?}");
    assert!(plane.rms_m < 0.004);
    // The camera looks down at an angle, 0.3–1 m above the table.
    assert!((0.3..1.0).contains(&plane.offset_m));
    assert!(angle_deg(&-plane.normal, &Vector3::z()) > 10.0);

    let ws = workspace();
    let placement = PlacementConfig::default();
    let cam = workspace_camera_from_plane(&plane, &k, &ws, &placement).unwrap();
    let mut vol = psgrasp_fusion::TsdfVolume::new(ws, &FusionConfig::default()).unwrap();
    let stats = vol.integrate(&depth, &cam).unwrap();
    println!("{stats:?}");
    assert!(stats.invalid_pixels > 0, "the real frame has holes");
    let grid = vol.normal_grid();
    let band = grid.view().band_voxel_count();
    let (share5, total) = floor_normal_share(&grid, placement.plane_height_m, 5.0);
    let (share10, _) = floor_normal_share(&grid, placement.plane_height_m, 10.0);
    println!("band voxels {band}, table voxels {total}, within 5°/10° of the plane normal {share5:.3}/{share10:.3}");
    assert!(band > 15_000, "only {band} band voxels");
    // Sensor noise (~2 mm rms on the table) and a slight bow of the real table against the
    // fitted plane (~3° mean tilt) leave a tail; most table voxels are within a few degrees.
    assert!(
        total > 2000 && share5 > 0.7 && share10 > 0.85,
        "{share5}/{share10} of {total}"
    );

    // The depth-scale correction on a real, calibrated frame: with the table as the floor of a
    // shallow bin where the placement put it, the scale found is 1 and the frame is left alone.
    let c = ws.extent() * 0.5;
    let bin = psgrasp_geometry::BinModel {
        inner_size_m: [0.5, 0.5, 0.05],
        wall_thickness_m: 0.01,
        floor_center: nalgebra::Point3::new(c.x, c.y, placement.plane_height_m),
    };
    let scale_cfg = psgrasp_fusion::DepthScaleConfig {
        enabled: true,
        ..Default::default()
    };
    let mut same = depth.clone();
    let (found, applied) =
        psgrasp_fusion::correct_depth_scale(&mut same, &cam, &bin, &scale_cfg).unwrap();
    println!("depth scale on the real frame: {found:?}");
    let found = found.expect("the table is in view");
    assert!((found.scale - 1.0).abs() < 0.002, "{found:?}");
    assert!(!applied);
    assert_eq!(same.data, depth.data);
}
