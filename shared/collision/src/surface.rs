//! Boxes against the frame's height map ([`psgrasp_fusion::HeightMapView`]): a cell's column —
//! everything at or below the highest surface point measured in it — is solid, as a top-down
//! camera cannot see under a surface. The test is at the map's cell centres, so with cells the
//! size of the camera's pixels it resolves what the 9 mm voxel grid cannot (a finger overlapping
//! an object's footprint by a few millimetres).
use crate::occupancy::GrownBox;
use psgrasp_fusion::{HeightMapView, NO_HEIGHT};
use psgrasp_geometry::OrientedBox;

/// How many cells of `map` have their column inside `b` grown by `margin` (negative: shrunk),
/// counting up to `stop_at`. An unusable box (non-finite, or shrunk below nothing) counts as
/// `stop_at` (fail safe, as for the voxel test).
pub fn cells_under_surface_in_box(
    map: &HeightMapView<'_>,
    b: &OrientedBox,
    margin: f32,
    stop_at: usize,
) -> usize {
    let Some(g) = GrownBox::new(b, margin) else {
        return stop_at;
    };
    let mut count = 0;
    for_each_column(map, &g, |height, (bottom, _)| {
        // Unmeasured cells (NO_HEIGHT) hold nothing.
        if height != NO_HEIGHT && bottom <= height {
            count += 1;
            return count < stop_at;
        }
        true
    });
    count
}

/// The share of `b`'s volume that lies under the measured surface of `map` (in a measured
/// cell's column), sampled at the map's cell centres: 1 for a box buried in an object, 0 for
/// one in free space above it. Cells without a measurement count as empty. `None` for an
/// unusable box or one whose footprint holds no cell centre of the map.
pub fn volume_share_under_surface(map: &HeightMapView<'_>, b: &OrientedBox) -> Option<f32> {
    let g = GrownBox::new(b, 0.0)?;
    let (mut inside, mut total) = (0.0f64, 0.0f64);
    for_each_column(map, &g, |height, (bottom, top)| {
        total += f64::from(top - bottom);
        if height.is_finite() {
            inside += f64::from((height.min(top) - bottom).max(0.0));
        }
        true
    });
    (total > 0.0).then(|| (inside / total) as f32)
}

/// Calls `f(height, z interval of the box)` for every cell of `map` whose centre's vertical
/// line meets `g`, until `f` returns `false` (`height` is [`NO_HEIGHT`] where nothing was
/// measured).
fn for_each_column(
    map: &HeightMapView<'_>,
    g: &GrownBox,
    mut f: impl FnMut(f32, (f32, f32)) -> bool,
) {
    let geometry = &map.geometry;
    let s = geometry.cell_m;
    // Cells whose centre may lie inside the box's floor-plan bounds.
    let range = |lo: f32, hi: f32, n: usize| {
        let first = ((lo / s - 0.5).ceil().max(0.0)) as usize;
        let last = (hi / s - 0.5).floor();
        (last >= 0.0).then(|| (first, (last as usize).min(n.saturating_sub(1))))
    };
    let (Some((i0, i1)), Some((j0, j1))) = (
        range(g.lo.x, g.hi.x, geometry.nx),
        range(g.lo.y, g.hi.y, geometry.ny),
    ) else {
        return;
    };
    for i in i0..=i1 {
        let x = (i as f32 + 0.5) * s;
        for j in j0..=j1 {
            let y = (j as f32 + 0.5) * s;
            if let Some(interval) = g.z_interval(x, y) {
                if !f(map.height(i, j), interval) {
                    return;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Isometry3, UnitQuaternion, Vector3};
    use psgrasp_fusion::HeightMapGeometry;
    use psgrasp_geometry::Workspace;

    /// A 2 mm map of the default workspace: floor at z = 0 everywhere, and a block 40 mm high
    /// over x, y ∈ [0.2, 0.26].
    fn block_map() -> (HeightMapGeometry, Vec<f32>) {
        let g = HeightMapGeometry::new(&Workspace::default(), 0.002).unwrap();
        let mut h = vec![0.0; g.len()];
        for i in 0..g.nx {
            for j in 0..g.ny {
                let (x, y) = ((i as f32 + 0.5) * 0.002, (j as f32 + 0.5) * 0.002);
                if (0.2..0.26).contains(&x) && (0.2..0.26).contains(&y) {
                    h[i * g.ny + j] = 0.04;
                }
            }
        }
        h[0] = NO_HEIGHT;
        (g, h)
    }

    fn finger_at(x: f32, y: f32, z: f32, tilt: f32) -> OrientedBox {
        OrientedBox {
            parent_from_box: Isometry3::from_parts(
                Vector3::new(x, y, z).into(),
                UnitQuaternion::from_axis_angle(&Vector3::y_axis(), tilt),
            ),
            half_extents: Vector3::new(0.0105, 0.013, 0.027),
        }
    }

    #[test]
    fn the_volume_share_under_the_surface_of_boxes_in_and_around_a_block() {
        let (geometry, heights) = block_map();
        let map = HeightMapView {
            geometry,
            heights: &heights,
        };
        let block = |x: f32, y: f32, z: f32, half: [f32; 3]| OrientedBox {
            parent_from_box: Isometry3::translation(x, y, z),
            half_extents: Vector3::from(half),
        };
        let share = |b: &OrientedBox| volume_share_under_surface(&map, b).unwrap();
        // Buried in the block (40 mm high over x, y ∈ [0.2, 0.26]): all of it.
        assert_eq!(share(&block(0.23, 0.23, 0.02, [0.01, 0.01, 0.01])), 1.0);
        // Above the block's top: none of it.
        assert_eq!(share(&block(0.23, 0.23, 0.06, [0.01, 0.01, 0.01])), 0.0);
        // Straddling the top (z ∈ [0.03, 0.05]): the lower half.
        assert!((share(&block(0.23, 0.23, 0.04, [0.01, 0.01, 0.01])) - 0.5).abs() < 0.02);
        // Straddling the block's −x side above the floor: the half over the block.
        assert!((share(&block(0.2, 0.23, 0.02, [0.01, 0.01, 0.01])) - 0.5).abs() < 0.11);
        // Tilted 45° about y, centred in the block's top face: the half below it.
        let tilted = OrientedBox {
            parent_from_box: Isometry3::from_parts(
                Vector3::new(0.23, 0.23, 0.04).into(),
                UnitQuaternion::from_axis_angle(&Vector3::y_axis(), 0.25 * std::f32::consts::PI),
            ),
            half_extents: Vector3::new(0.008, 0.008, 0.008),
        };
        assert!((share(&tilted) - 0.5).abs() < 0.05, "{}", share(&tilted));
        // Unmeasured cells count as empty: the map's cell (0, 0) has no height.
        assert_eq!(
            share(&block(0.001, 0.001, 0.0, [0.0005, 0.0005, 0.01])),
            0.0
        );
        // Outside the map or unusable: no share.
        assert!(volume_share_under_surface(&map, &block(-0.5, -0.5, 0.0, [0.01; 3])).is_none());
        assert!(volume_share_under_surface(&map, &block(f32::NAN, 0.0, 0.0, [0.01; 3])).is_none());
    }

    #[test]
    fn a_finger_beside_a_block_is_free_and_one_overlapping_it_by_millimetres_is_not() {
        let (geometry, heights) = block_map();
        let map = HeightMapView {
            geometry,
            heights: &heights,
        };
        let count =
            |b: &OrientedBox, margin: f32| cells_under_surface_in_box(&map, b, margin, 1000);
        // Finger 21 mm thick, its bottom 5 mm above the floor, its inner face 3 mm from the
        // block's −x side (x = 0.2): free; moved 3 mm into the block's footprint: hits it.
        let beside = finger_at(0.2 - 0.003 - 0.0105, 0.23, 0.032, 0.0);
        assert_eq!(count(&beside, 0.001), 0);
        let into = finger_at(0.2 + 0.003 - 0.0105, 0.23, 0.032, 0.0);
        assert!(count(&into, 0.001) > 10, "{}", count(&into, 0.001));
        // A 5 mm margin reaches the block from 3 mm away; a negative margin tolerates an overlap.
        assert!(count(&beside, 0.005) > 0);
        assert_eq!(
            count(&finger_at(0.2 + 0.001 - 0.0105, 0.23, 0.032, 0.0), -0.002),
            0
        );
        // Above the block: free until its bottom goes below the block's top.
        assert_eq!(count(&finger_at(0.23, 0.23, 0.04 + 0.028, 0.0), 0.0), 0);
        assert!(count(&finger_at(0.23, 0.23, 0.04 + 0.025, 0.0), 0.0) > 0);
        // Down to the floor: the floor's cells count too.
        assert!(count(&finger_at(0.1, 0.1, 0.025, 0.0), 0.001) > 0);
        // A tilted finger is tested by its true shape: leaning over the block's edge, its
        // bounding box reaches into the block's footprint but the finger passes above the edge;
        // tilted the other way its foot is in the block.
        let leaning = finger_at(0.2 - 0.016, 0.23, 0.045, 0.3);
        assert_eq!(count(&leaning, 0.001), 0);
        assert!(cells_under_surface_in_box(&map, &leaning, 0.001, 1) == 0);
        assert!(count(&finger_at(0.2 - 0.016, 0.23, 0.045, -0.3), 0.001) > 0);
        // Counting stops where asked; a finger outside the map meets nothing; a bad box is a hit.
        assert_eq!(cells_under_surface_in_box(&map, &into, 0.001, 3), 3);
        assert_eq!(count(&finger_at(-0.5, -0.5, 0.03, 0.0), 0.001), 0);
        assert_eq!(
            cells_under_surface_in_box(&map, &finger_at(f32::NAN, 0.0, 0.0, 0.0), 0.0, 7),
            7
        );
    }
}
