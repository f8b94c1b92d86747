//! Boxes against the frame's height map ([`psgrasp_fusion::HeightMapView`]): a cell's column —
//! everything at or below the highest surface point measured in it — is solid, as a top-down
//! camera cannot see under a surface. The test is at the map's cell centres, so with cells the
//! size of the camera's pixels it resolves what the 9 mm voxel grid cannot (a finger overlapping
//! an object's footprint by a few millimetres).
use crate::occupancy::GrownBox;
use psgrasp_fusion::HeightMapView;
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
        return 0;
    };
    let mut count = 0;
    for i in i0..=i1 {
        let x = (i as f32 + 0.5) * s;
        for j in j0..=j1 {
            let height = map.height(i, j);
            if height == f32::NEG_INFINITY {
                continue;
            }
            let y = (j as f32 + 0.5) * s;
            if g.z_interval(x, y)
                .is_some_and(|(bottom, _)| bottom <= height)
            {
                count += 1;
                if count >= stop_at {
                    return count;
                }
            }
        }
    }
    count
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Isometry3, UnitQuaternion, Vector3};
    use psgrasp_fusion::{HeightMapGeometry, NO_HEIGHT};
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
