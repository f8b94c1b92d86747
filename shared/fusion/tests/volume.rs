//! Volume bookkeeping: layouts, invariants, reset, repeat integration, one-shot helpers.
use psgrasp_fusion::{fuse_into, fuse_normal_grid, FusionConfig, TsdfVolume};
use psgrasp_test_support::analytic::*;

#[test]
fn grid_invariants_and_one_shot_helpers_agree() {
    let scene = Scene {
        shapes: vec![floor(), sphere(), cuboid()],
    };
    let cam = top_camera();
    let depth = scene.render(&cam);
    let ws = workspace();
    let cfg = FusionConfig::default();
    let grid = fuse_normal_grid(&depth, &cam, &ws, &cfg).unwrap();
    let n = ws.voxel_count();
    assert_eq!(grid.normals.len(), 3 * n);
    assert_eq!(grid.tsdf.len(), n);
    assert!((grid.truncation_m - 4.0 * 0.009).abs() < 1e-7);
    let view = grid.view();
    for idx in 0..n {
        let t = grid.tsdf[idx];
        assert!((-1.0..=1.0).contains(&t));
        let [x, y, z] = view.normal(idx);
        let len = (x * x + y * y + z * z).sqrt();
        if t.abs() < 1.0 {
            assert!(
                (len - 1.0).abs() < 1e-4,
                "band voxel {idx} has normal length {len}"
            );
        } else {
            assert_eq!(len, 0.0, "voxel {idx} outside the band has a normal");
        }
    }
    // Deep below the floor is occluded (−1); high above the floor is free (+1).
    assert_eq!(grid.tsdf[ws.index(5, 5, 0)], -1.0);
    assert_eq!(grid.tsdf[ws.index(5, 5, 60)], 1.0);
    assert_eq!(
        view.band_voxel_count(),
        grid.tsdf.iter().filter(|t| t.abs() < 1.0).count()
    );

    let (mut normals, mut tsdf) = (vec![f32::NAN; 3 * n], vec![f32::NAN; n]);
    let stats = fuse_into(&depth, &cam, &ws, &cfg, &mut normals, &mut tsdf).unwrap();
    assert_eq!(stats.frames_integrated, 1);
    assert_eq!(normals, grid.normals);
    assert_eq!(tsdf, grid.tsdf);
}

#[test]
fn narrow_camera_leaves_unseen_voxels_unobserved() {
    let scene = Scene {
        shapes: vec![floor()],
    };
    let mut cam = top_camera();
    cam.intrinsics.fx = 3000.0;
    cam.intrinsics.fy = 3000.0;
    let mut vol = TsdfVolume::new(workspace(), &FusionConfig::default()).unwrap();
    vol.integrate(&scene.render(&cam), &cam).unwrap();
    let ws = workspace();
    // A corner column is outside the ~7 cm wide view: never observed, +1 at every height.
    for k in 0..64 {
        let idx = ws.index(0, 0, k);
        assert_eq!(vol.weights()[idx], 0.0);
        assert_eq!(vol.tsdf()[idx], 1.0);
    }
    // The centre column is observed.
    assert!(vol.weights()[ws.index(32, 32, 12)] > 0.0);
}

#[test]
fn repeat_integration_reset_and_write_are_consistent() {
    let scene = Scene {
        shapes: vec![floor(), sphere()],
    };
    let cam = top_camera();
    let depth = scene.render(&cam);
    let mut vol = TsdfVolume::new(workspace(), &FusionConfig::default()).unwrap();
    let s1 = vol.integrate(&depth, &cam).unwrap();
    let once = vol.normal_grid();
    let s2 = vol.integrate(&depth, &cam).unwrap();
    assert_eq!(s2.frames_integrated, 2);
    assert_eq!(s1.band_updates, s2.band_updates);
    let twice = vol.normal_grid();
    // The same frame twice: the running average does not change.
    for (a, b) in once.tsdf.iter().zip(&twice.tsdf) {
        assert!((a - b).abs() < 1e-5);
    }
    for (a, b) in once.normals.iter().zip(&twice.normals) {
        assert!((a - b).abs() < 1e-4);
    }
    // write_normal_grid fills every element of dirty buffers.
    let n = workspace().voxel_count();
    let (mut normals, mut tsdf) = (vec![7.0; 3 * n], vec![7.0; n]);
    vol.write_normal_grid(&mut normals, &mut tsdf).unwrap();
    assert_eq!(normals, twice.normals);
    assert_eq!(tsdf, twice.tsdf);
    let copy = vol.clone();
    assert_eq!(copy.normal_grid(), twice);
    vol.reset();
    assert_eq!(vol.frames_integrated(), 0);
    assert!(vol.tsdf().iter().all(|&t| t == 1.0) && vol.weights().iter().all(|&w| w == 0.0));
    assert_eq!(vol.normal_grid().view().band_voxel_count(), 0);
}
