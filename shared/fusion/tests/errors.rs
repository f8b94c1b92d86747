//! Bad inputs give clear errors, never panics, and leave the volume untouched.
use nalgebra::{Point3, Vector3};
use psgrasp_fusion::{fuse_into, fuse_normal_grid, FusionConfig, FusionError, TsdfVolume};
use psgrasp_geometry::{CameraIntrinsics, DepthError, DepthImage, GeometryError};
use psgrasp_test_support::analytic::*;

fn volume() -> TsdfVolume {
    TsdfVolume::new(workspace(), &FusionConfig::default()).unwrap()
}

fn frame(value: f32) -> DepthImage {
    DepthImage::from_metres(640, 480, vec![value; 640 * 480]).unwrap()
}

fn untouched(vol: &TsdfVolume) -> bool {
    vol.tsdf().iter().all(|&t| t == 1.0)
        && vol.weights().iter().all(|&w| w == 0.0)
        && vol.frames_integrated() == 0
}

#[test]
fn nan_or_zero_or_negative_everywhere_is_no_valid_pixels() {
    for v in [f32::NAN, 0.0, -1.0, f32::INFINITY] {
        let mut vol = volume();
        let err = vol.integrate(&frame(v), &top_camera()).unwrap_err();
        assert_eq!(
            err,
            FusionError::Depth(DepthError::NoValidPixels),
            "value {v}"
        );
        assert!(untouched(&vol));
    }
}

#[test]
fn wrong_frame_size() {
    let mut vol = volume();
    let depth = DepthImage::from_metres(320, 240, vec![0.8; 320 * 240]).unwrap();
    let err = vol.integrate(&depth, &top_camera()).unwrap_err();
    assert_eq!(
        err,
        FusionError::FrameSizeMismatch {
            got_w: 320,
            got_h: 240,
            want_w: 640,
            want_h: 480
        }
    );
    // A hand-built image whose buffer disagrees with its size.
    let broken = DepthImage {
        width: 640,
        height: 480,
        data: vec![0.8; 10],
    };
    assert!(matches!(
        vol.integrate(&broken, &top_camera()),
        Err(FusionError::Depth(DepthError::SizeMismatch { got: 10, .. }))
    ));
    assert!(untouched(&vol));
}

#[test]
fn bad_intrinsics_and_pose() {
    let mut vol = volume();
    let mut cam = top_camera();
    cam.intrinsics.fx = f32::NAN;
    assert!(matches!(
        vol.integrate(&frame(0.8), &cam),
        Err(FusionError::Geometry(GeometryError::InvalidIntrinsics(_)))
    ));
    let mut cam = top_camera();
    cam.intrinsics.fy = -5.0;
    assert!(matches!(
        vol.integrate(&frame(0.8), &cam),
        Err(FusionError::Geometry(_))
    ));
    let mut cam = top_camera();
    cam.workspace_from_camera.translation.vector.x = f32::NAN;
    assert!(matches!(
        vol.integrate(&frame(0.8), &cam),
        Err(FusionError::Geometry(GeometryError::InvalidPose(_)))
    ));
    assert!(untouched(&vol));
}

#[test]
fn nothing_inside_the_workspace_is_empty_view() {
    let mut vol = volume();
    // Looking up, away from the workspace.
    let up = look_at(
        CameraIntrinsics::default_640x480(),
        Point3::new(0.3, 0.3, 1.0),
        Point3::new(0.3, 0.3, 2.0),
        Vector3::y(),
    );
    assert_eq!(vol.integrate(&frame(0.8), &up), Err(FusionError::EmptyView));
    // Looking down, but every reading ends far above the box (0.1 m from a camera 2 m up).
    let high = top_camera();
    let mut cam = high;
    cam.workspace_from_camera.translation.vector.z = 2.0;
    assert_eq!(
        vol.integrate(&frame(0.2), &cam),
        Err(FusionError::EmptyView)
    );
    // All readings beyond the configured range.
    assert_eq!(
        vol.integrate(&frame(5.0), &top_camera()),
        Err(FusionError::EmptyView)
    );
    assert!(untouched(&vol));
}

#[test]
fn invalid_pixels_are_skipped_and_counted() {
    let scene = Scene {
        shapes: vec![floor()],
    };
    let cam = top_camera();
    let mut depth = scene.render(&cam);
    let (mut nan, mut invalid, mut far) = (0, 0, 0);
    for (i, d) in depth.data.iter_mut().enumerate() {
        if i % 7 == 0 {
            *d = f32::NAN;
            nan += 1;
        } else if i % 11 == 0 {
            *d = 0.0;
            invalid += 1;
        } else if i % 13 == 0 {
            *d = -0.3;
            invalid += 1;
        } else if i % 17 == 0 {
            *d = 7.0;
            far += 1;
        }
    }
    let mut vol = volume();
    let stats = vol.integrate(&depth, &cam).unwrap();
    assert_eq!(stats.pixels, 640 * 480);
    assert_eq!(stats.invalid_pixels, nan + invalid);
    assert_eq!(stats.out_of_range_pixels, far);
    assert_eq!(stats.valid_pixels, 640 * 480 - nan - invalid - far);
    assert!(stats.band_updates > 25_000, "{stats:?}");
    // Holes do not move the surface: the floor is still found everywhere.
    let grid = vol.normal_grid();
    // A voxel whose four pixels are all holes stays unobserved (+1), which can hide the
    // crossing of its column; everywhere else the surface is where it was.
    let (cols, missing, max_err, _) = zero_crossing_errors(&grid, &scene, &[cam], 0.0135);
    assert!(
        cols > 4000 && missing * 50 < cols,
        "{missing} of {cols} columns without a crossing"
    );
    assert!(max_err < 0.0045, "max error {max_err}");
}

#[test]
fn bad_buffers_and_config() {
    let vol = volume();
    let n = workspace().voxel_count();
    let (mut normals, mut tsdf) = (vec![0.0; 3 * n - 1], vec![0.0; n]);
    assert_eq!(
        vol.write_normal_grid(&mut normals, &mut tsdf),
        Err(FusionError::BufferSize {
            name: "normals",
            got: 3 * n - 1,
            expected: 3 * n
        })
    );
    let (mut normals, mut tsdf) = (vec![0.0; 3 * n], vec![0.0; n + 1]);
    assert!(matches!(
        vol.write_normal_grid(&mut normals, &mut tsdf),
        Err(FusionError::BufferSize { name: "tsdf", .. })
    ));
    let cfg = FusionConfig::default();
    assert!(matches!(
        fuse_into(
            &frame(0.8),
            &top_camera(),
            &workspace(),
            &cfg,
            &mut normals,
            &mut tsdf
        ),
        Err(FusionError::BufferSize { .. })
    ));
    for bad in [
        FusionConfig {
            truncation_voxels: 0.0,
            ..cfg
        },
        FusionConfig {
            truncation_voxels: f32::NAN,
            ..cfg
        },
        FusionConfig {
            min_depth_m: 2.0,
            max_depth_m: 1.0,
            ..cfg
        },
        FusionConfig {
            max_weight: 0.5,
            ..cfg
        },
        FusionConfig {
            free_space_weight: 0.0,
            ..cfg
        },
        FusionConfig {
            min_gradient: -1.0,
            ..cfg
        },
    ] {
        assert!(
            matches!(
                TsdfVolume::new(workspace(), &bad),
                Err(FusionError::InvalidConfig(_))
            ),
            "{bad:?}"
        );
    }
    let mut ws = workspace();
    ws.voxel_size_m = 0.0;
    assert!(matches!(
        TsdfVolume::new(ws, &cfg),
        Err(FusionError::Geometry(_))
    ));
    assert!(fuse_normal_grid(&frame(f32::NAN), &top_camera(), &workspace(), &cfg).is_err());
}

#[test]
fn config_reads_from_toml_with_defaults() {
    let cfg: FusionConfig = toml::from_str("truncation_voxels = 3.0\nmax_depth_m = 1.5").unwrap();
    assert_eq!(cfg.truncation_voxels, 3.0);
    assert_eq!(cfg.max_depth_m, 1.5);
    assert_eq!(cfg.min_depth_m, FusionConfig::default().min_depth_m);
    assert!(
        toml::from_str::<FusionConfig>("truncation = 3.0").is_err(),
        "unknown keys are rejected"
    );
}
