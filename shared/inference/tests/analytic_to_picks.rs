//! The analytic backend's configurations through selection, checked against the exact scene.
use nalgebra::{Point2, Point3, Vector3};
use psgrasp_geometry::{BinModel, GripperModel, Workspace};
use psgrasp_inference::{AnalyticBackend, AnalyticConfig, ContactRegion, InferenceBackend};
use psgrasp_selection::{select, SelectionConfig};
use psgrasp_test_support::synthetic::{Primitive, SyntheticScene};

#[test]
fn picks_from_the_analytic_backend_hold_an_object_and_clear_the_scene() {
    let bin = BinModel::default();
    let floor = bin.floor_center.z;
    let mut scene = SyntheticScene::floor(floor)
        .with(Primitive::Box {
            center_xy: Point2::new(0.2, 0.2),
            size_m: Vector3::new(0.045, 0.07, 0.06),
            yaw_rad: 0.4,
        })
        .with(Primitive::Box {
            center_xy: Point2::new(0.38, 0.3),
            size_m: Vector3::new(0.05, 0.05, 0.09),
            yaw_rad: 1.1,
        })
        .with(Primitive::Cylinder {
            center_xy: Point2::new(0.27, 0.36),
            radius_m: 0.025,
            height_m: 0.08,
        })
        .with(Primitive::Box {
            center_xy: Point2::new(0.3, 0.2),
            size_m: Vector3::new(0.035, 0.05, 0.04),
            yaw_rad: 0.0,
        });
    // The two long walls inside the grid.
    for y in [0.083, 0.493] {
        scene.objects.push(Primitive::Box {
            center_xy: Point2::new(0.288, y),
            size_m: Vector3::new(0.62, 0.01, 0.28),
            yaw_rad: 0.0,
        });
    }
    let grid = scene.normal_grid(Workspace::default(), 0.027);
    let gripper = GripperModel::default();
    let cfg = AnalyticConfig {
        contact_region: Some(ContactRegion::inside_bin(&bin, 0.005)),
        ..AnalyticConfig::default()
    };
    let mut backend = AnalyticBackend::new(cfg, gripper).unwrap();
    let configs = backend.infer(&grid.view(), 17).unwrap();
    assert!(!configs.is_empty());

    let sel = select(
        &configs,
        &grid.view(),
        &bin,
        &gripper,
        &SelectionConfig::default(),
    )
    .unwrap();
    // With the default pick spacing the picks spread over the objects (9-18 cm apart): every
    // object gets one, and no two picks lie closer than the spacing (the real hand's deeper
    // reach finds a second grasp 5 cm from the first on the 9 cm tall box).
    let spacing = SelectionConfig::default().pick_spacing_m;
    assert!((4..=6).contains(&sel.picks.len()), "{:?}", sel.rejected);
    for (i, a) in sel.picks.iter().enumerate() {
        for b in &sel.picks[i + 1..] {
            let d = (a.workspace_from_gripper.translation.vector
                - b.workspace_from_gripper.translation.vector)
                .norm();
            assert!(d >= spacing - 1e-4, "two picks {d} m apart");
        }
    }
    let centres: Vec<Point2<f32>> = [(0.2, 0.2), (0.38, 0.3), (0.27, 0.36), (0.3, 0.2)]
        .map(|(x, y)| Point2::new(x, y))
        .to_vec();
    let mut hit: Vec<usize> = sel
        .picks
        .iter()
        .map(|p| {
            let t = p.workspace_from_gripper.translation.vector;
            (0..4)
                .min_by(|&a, &b| {
                    let d = |i: usize| (centres[i] - Point2::new(t.x, t.y)).norm();
                    d(a).total_cmp(&d(b))
                })
                .unwrap()
        })
        .collect();
    hit.sort();
    hit.dedup();
    assert_eq!(hit, vec![0, 1, 2, 3], "a pick on each object");
    let sd = |p: &Point3<f32>| {
        scene.signed_distance(&Vector3::new(p.x as f64, p.y as f64, p.z as f64)) as f32
    };
    for pick in &sel.picks {
        // The TCP lies inside an object: the fingers close on something.
        let tcp = Point3::from(pick.workspace_from_gripper.translation.vector);
        assert!(sd(&tcp) < 0.0, "TCP {tcp:?} is not inside an object");
        // No point of the gripper (grasp and pre-grasp) is deeper than 2 mm inside the exact scene.
        for p in psgrasp_test_support::grasps::pick_gripper_points(&gripper, pick, 5) {
            assert!(
                sd(&p) > -0.002,
                "gripper point {p:?} is {} m inside the scene",
                -sd(&p)
            );
        }
        let down = -(pick.workspace_from_gripper.rotation * Vector3::z()).z;
        assert!(down >= 60f32.to_radians().cos() - 1e-5);
    }
}
