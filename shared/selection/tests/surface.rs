//! The fingers against the frame's height map (`[selection.surface_check]`): a finger that
//! overlaps a neighbour by a few millimetres passes the 9 mm voxel test and is refused by the map.
use nalgebra::{Point2, Point3, Vector3};
use psgrasp_fusion::{HeightMapGeometry, HeightMapView, NormalGrid};
use psgrasp_geometry::{BinModel, GraspConfiguration, GripperModel, Workspace, N_APPROACHES};
use psgrasp_selection::{
    select_filtered, select_observed, Selection, SelectionConfig, SelectionError, SurfaceCheck,
};
use psgrasp_test_support::synthetic::{Primitive, SyntheticScene};

fn floor_z() -> f32 {
    BinModel::default().floor_center.z
}

/// A box standing on the floor, axis-aligned: its footprint's x and y ranges and its height.
#[derive(Clone, Copy)]
struct Block {
    x: [f32; 2],
    y: [f32; 2],
    height: f32,
}

impl Block {
    fn primitive(&self) -> Primitive {
        Primitive::Box {
            center_xy: Point2::new(0.5 * (self.x[0] + self.x[1]), 0.5 * (self.y[0] + self.y[1])),
            size_m: Vector3::new(self.x[1] - self.x[0], self.y[1] - self.y[0], self.height),
            yaw_rad: 0.0,
        }
    }
}

/// The object grasped (40 mm along x) and a neighbour whose −x face lies at x = 0.338.
fn blocks() -> [Block; 2] {
    [
        Block {
            x: [0.268, 0.308],
            y: [0.26, 0.32],
            height: 0.05,
        },
        Block {
            x: [0.338, 0.368],
            y: [0.26, 0.32],
            height: 0.05,
        },
    ]
}

/// The voxel grid of the floor and `blocks`.
fn grid(blocks: &[Block]) -> NormalGrid {
    let mut s = SyntheticScene::floor(floor_z());
    s.objects.extend(blocks.iter().map(Block::primitive));
    s.normal_grid(Workspace::default(), 0.027)
}

/// The height map a top-down frame of the floor and `blocks` gives, cells of `cell_m`.
fn height_map(blocks: &[Block], cell_m: f32) -> (HeightMapGeometry, Vec<f32>) {
    let g = HeightMapGeometry::new(&Workspace::default(), cell_m).unwrap();
    let mut heights = vec![floor_z(); g.len()];
    for i in 0..g.nx {
        for j in 0..g.ny {
            let (x, y) = ((i as f32 + 0.5) * cell_m, (j as f32 + 0.5) * cell_m);
            for b in blocks {
                if (b.x[0]..=b.x[1]).contains(&x) && (b.y[0]..=b.y[1]).contains(&y) {
                    heights[i * g.ny + j] = floor_z() + b.height;
                }
            }
        }
    }
    (g, heights)
}

/// Across the object, 25 mm over the floor, straight down: with the default 20 mm opening
/// clearance the +x finger spans x ∈ [0.321, 0.342] — 4 mm into the neighbour, whose nearest
/// occupied voxel centre (x = 0.3465) lies just beyond the finger grown by the 4 mm margin.
fn grasp() -> GraspConfiguration {
    let mut collision_scores = [0.0; N_APPROACHES];
    collision_scores[8] = 1.0;
    collision_scores[9] = 1.0;
    GraspConfiguration {
        contact: Point3::new(0.271, 0.288, floor_z() + 0.025),
        baseline: Vector3::x(),
        collision_scores,
        width: 0.04,
        quality: 0.95,
        kappa: 0.0,
        kappa_floor: 0.0,
    }
}

fn with_check(check: SurfaceCheck) -> SelectionConfig {
    SelectionConfig {
        surface_check: check,
        ..SelectionConfig::default()
    }
}

fn enabled() -> SurfaceCheck {
    SurfaceCheck {
        enabled: true,
        ..SurfaceCheck::default()
    }
}

fn run(
    blocks: &[Block],
    map: Option<&(HeightMapGeometry, Vec<f32>)>,
    cfg: &SelectionConfig,
) -> Result<Selection, SelectionError> {
    let grid = grid(blocks);
    let map = map.map(|(geometry, heights)| HeightMapView {
        geometry: *geometry,
        heights,
    });
    select_observed(
        &[grasp()],
        &grid.view(),
        map,
        &BinModel::default(),
        &GripperModel::default(),
        cfg,
        |_| true,
    )
}

#[test]
fn a_finger_millimetres_into_a_neighbour_is_refused_by_the_height_map_only() {
    let blocks = blocks();
    let map = height_map(&blocks, 0.002);
    // The voxel test passes the grasp (without the check, and with the check disabled).
    let plain = run(&blocks, None, &SelectionConfig::default()).unwrap();
    assert_eq!(plain.picks.len(), 1, "{:?}", plain.rejected);
    assert_eq!(plain.rejected.surface_collision, 0);
    // The height map refuses both straight-down approaches.
    let checked = run(&blocks, Some(&map), &with_check(enabled())).unwrap();
    assert!(checked.picks.is_empty());
    assert_eq!(
        checked.rejected.surface_collision, 2,
        "{:?}",
        checked.rejected
    );
    // Without the neighbour the same grasp passes the map; so does it when the fingers are
    // shrunk past the overlap, or when more cells must meet them than the overlap holds.
    let alone = [blocks[0]];
    let alone_map = height_map(&alone, 0.002);
    assert_eq!(
        run(&alone, Some(&alone_map), &with_check(enabled()))
            .unwrap()
            .picks
            .len(),
        1
    );
    let shrunk = SurfaceCheck {
        margin_m: -0.005,
        ..enabled()
    };
    assert_eq!(
        run(&blocks, Some(&map), &with_check(shrunk))
            .unwrap()
            .picks
            .len(),
        1
    );
    let tolerant = SurfaceCheck {
        min_cells: 100_000,
        ..enabled()
    };
    assert_eq!(
        run(&blocks, Some(&map), &with_check(tolerant))
            .unwrap()
            .picks
            .len(),
        1
    );
}

#[test]
fn an_enabled_check_needs_a_map_of_its_cells_and_sane_settings() {
    let blocks = blocks();
    let grid = grid(&blocks);
    let (bin, gripper) = (BinModel::default(), GripperModel::default());
    // Enabled but no map: an error, never a silently skipped check.
    let err = select_filtered(
        &[grasp()],
        &grid.view(),
        &bin,
        &gripper,
        &with_check(enabled()),
        |_| true,
    )
    .unwrap_err();
    assert!(matches!(err, SelectionError::HeightMap(_)), "{err}");
    // A map of other cells than the setting says.
    let coarse = height_map(&blocks, 0.004);
    let err = run(&blocks, Some(&coarse), &with_check(enabled())).unwrap_err();
    assert!(matches!(err, SelectionError::HeightMap(_)), "{err}");
    // Settings out of range are refused by name.
    for (check, field) in [
        (
            SurfaceCheck {
                cell_m: 0.0,
                ..enabled()
            },
            "surface_check.cell_m",
        ),
        (
            SurfaceCheck {
                margin_m: 0.5,
                ..enabled()
            },
            "surface_check.margin_m",
        ),
        (
            SurfaceCheck {
                min_cells: 0,
                ..enabled()
            },
            "surface_check.min_cells",
        ),
        (
            SurfaceCheck {
                defer_pad_fill_below: 1.5,
                ..enabled()
            },
            "surface_check.defer_pad_fill_below",
        ),
        (
            SurfaceCheck {
                defer_pad_fill_below: f32::NAN,
                ..enabled()
            },
            "surface_check.defer_pad_fill_below",
        ),
    ] {
        match with_check(check).validate() {
            Err(SelectionError::InvalidConfig { field: f, .. }) => assert_eq!(f, field),
            other => panic!("{field}: {other:?}"),
        }
    }
    // The default is off and not written; an enabled check round-trips through TOML.
    let text = toml::to_string(&SelectionConfig::default()).unwrap();
    assert!(!text.contains("surface_check"), "{text}");
    let cfg = with_check(enabled());
    let back: SelectionConfig = toml::from_str(&toml::to_string(&cfg).unwrap()).unwrap();
    assert_eq!(back.surface_check, cfg.surface_check);
}

/// Picks whose pads would close over the block's top rather than on its sides go after those
/// that meet the sides over the pads' whole length, and are still handed out.
#[test]
fn picks_closing_on_little_surface_are_deferred_not_refused() {
    let block = [blocks()[0]];
    let map = height_map(&block, 0.002);
    let grid = grid(&block);
    let view = || HeightMapView {
        geometry: map.0,
        heights: &map.1,
    };
    // At the block's top edge (50 mm): half of the pads' length lies above it. Halfway up
    // (25 mm): all of it on the block. The top-edge grasp scores better.
    let at_top = GraspConfiguration {
        contact: Point3::new(0.268, 0.29, floor_z() + 0.05),
        quality: 0.95,
        ..grasp()
    };
    let halfway = GraspConfiguration {
        contact: Point3::new(0.268, 0.29, floor_z() + 0.025),
        quality: 0.9,
        ..grasp()
    };
    let select = |configs: &[GraspConfiguration], defer: f32| {
        let cfg = SelectionConfig {
            pick_spacing_m: 0.0,
            ..with_check(SurfaceCheck {
                defer_pad_fill_below: defer,
                ..enabled()
            })
        };
        select_observed(
            configs,
            &grid.view(),
            Some(view()),
            &BinModel::default(),
            &GripperModel::default(),
            &cfg,
            |_| true,
        )
        .unwrap()
    };
    let both = [at_top, halfway];
    let plain = select(&both, 0.0);
    assert_eq!(plain.picks.len(), 2, "{:?}", plain.rejected);
    let fill = |s: &Selection, i: usize| s.picks[i].pad_fill.unwrap();
    assert_eq!(plain.picks[0].configuration_index, 0);
    assert!((fill(&plain, 0) - 0.5).abs() < 0.1, "{}", fill(&plain, 0));
    assert!(fill(&plain, 1) > 0.95, "{}", fill(&plain, 1));
    assert_eq!(plain.rejected.deferred_pad_fill, 0);
    // Deferred below 0.7: the halfway grasp first, the top-edge one after it.
    let deferred = select(&both, 0.7);
    let order: Vec<usize> = deferred
        .picks
        .iter()
        .map(|p| p.configuration_index)
        .collect();
    assert_eq!(order, [1, 0]);
    assert_eq!(deferred.rejected.deferred_pad_fill, 1);
    // Alone, a deferred grasp is still the pick.
    let alone = select(&[at_top], 0.7);
    assert_eq!(alone.picks.len(), 1);
    assert_eq!(alone.rejected.deferred_pad_fill, 1);
    // No height map, no fill: the check is off and nothing is deferred.
    let off = select_observed(
        &both,
        &grid.view(),
        None,
        &BinModel::default(),
        &GripperModel::default(),
        &SelectionConfig {
            pick_spacing_m: 0.0,
            ..SelectionConfig::default()
        },
        |_| true,
    )
    .unwrap();
    assert!(off.picks.iter().all(|p| p.pad_fill.is_none()));
    assert_eq!(off.picks[0].configuration_index, 0);
}
