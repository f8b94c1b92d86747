//! Oriented box–box overlap by the separating axis theorem.
use nalgebra::{Matrix3, Vector3};
use psgrasp_geometry::OrientedBox;

/// Added to the rotation terms so that near-parallel edges (cross products close to zero) do not
/// report a false separation through rounding.
const PARALLEL_EPS: f32 = 1e-6;

/// True if `a`, grown by `margin` on every side, and `b` overlap (touching counts as overlap).
/// Boxes with non-finite poses or sizes count as overlapping (fail safe).
///
/// Tests the 15 candidate separating axes of two boxes: the 3 face normals of each box and the
/// 9 cross products of their edge directions.
pub fn boxes_overlap(a: &OrientedBox, b: &OrientedBox, margin: f32) -> bool {
    let ra = a.half_extents.add_scalar(margin);
    let rb = b.half_extents;
    let ma = a.parent_from_box.rotation.to_rotation_matrix().into_inner();
    let mb = b.parent_from_box.rotation.to_rotation_matrix().into_inner();
    let t_world = b.parent_from_box.translation.vector - a.parent_from_box.translation.vector;
    let finite = ra
        .iter()
        .chain(rb.iter())
        .chain(ma.iter())
        .chain(mb.iter())
        .chain(t_world.iter())
        .all(|v| v.is_finite());
    if !finite || ra.iter().any(|&v| v < 0.0) || rb.iter().any(|&v| v < 0.0) {
        return true;
    }
    // Rotation of b in a's frame and the centre offset in a's frame.
    let r: Matrix3<f32> = ma.transpose() * mb;
    let abs_r = r.map(|v| v.abs() + PARALLEL_EPS);
    let t: Vector3<f32> = ma.transpose() * t_world;

    // a's face normals.
    for i in 0..3 {
        let rb_proj = rb[0] * abs_r[(i, 0)] + rb[1] * abs_r[(i, 1)] + rb[2] * abs_r[(i, 2)];
        if t[i].abs() > ra[i] + rb_proj {
            return false;
        }
    }
    // b's face normals.
    for j in 0..3 {
        let ra_proj = ra[0] * abs_r[(0, j)] + ra[1] * abs_r[(1, j)] + ra[2] * abs_r[(2, j)];
        let dist = t[0] * r[(0, j)] + t[1] * r[(1, j)] + t[2] * r[(2, j)];
        if dist.abs() > ra_proj + rb[j] {
            return false;
        }
    }
    // Edge–edge axes A_i × B_j.
    for i in 0..3 {
        let (i1, i2) = ((i + 1) % 3, (i + 2) % 3);
        for j in 0..3 {
            let (j1, j2) = ((j + 1) % 3, (j + 2) % 3);
            let ra_proj = ra[i1] * abs_r[(i2, j)] + ra[i2] * abs_r[(i1, j)];
            let rb_proj = rb[j1] * abs_r[(i, j2)] + rb[j2] * abs_r[(i, j1)];
            let dist = t[i2] * r[(i1, j)] - t[i1] * r[(i2, j)];
            if dist.abs() > ra_proj + rb_proj {
                return false;
            }
        }
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion};

    fn cube(center: [f32; 3], half: f32, rot: UnitQuaternion<f32>) -> OrientedBox {
        OrientedBox {
            parent_from_box: Isometry3::from_parts(
                Translation3::new(center[0], center[1], center[2]),
                rot,
            ),
            half_extents: Vector3::repeat(half),
        }
    }

    #[test]
    fn axis_aligned_cases() {
        let id = UnitQuaternion::identity();
        let a = cube([0.0, 0.0, 0.0], 1.0, id);
        assert!(boxes_overlap(&a, &cube([1.9, 0.0, 0.0], 1.0, id), 0.0));
        assert!(!boxes_overlap(&a, &cube([2.1, 0.0, 0.0], 1.0, id), 0.0));
        // The margin closes the 0.1 gap.
        assert!(boxes_overlap(&a, &cube([2.1, 0.0, 0.0], 1.0, id), 0.15));
        assert!(
            boxes_overlap(&a, &cube([0.0, 0.0, 0.0], 0.1, id), 0.0),
            "containment is overlap"
        );
    }

    #[test]
    fn rotated_cube_corner_reaches_further() {
        let id = UnitQuaternion::identity();
        let a = cube([0.0, 0.0, 0.0], 1.0, id);
        // Rotated 45° about z, the cube reaches √2 along x.
        let r = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), std::f32::consts::FRAC_PI_4);
        assert!(boxes_overlap(&a, &cube([2.3, 0.0, 0.0], 1.0, r), 0.0));
        assert!(!boxes_overlap(&a, &cube([2.5, 0.0, 0.0], 1.0, r), 0.0));
    }

    #[test]
    fn edge_edge_separation_is_found() {
        // Two long thin boxes crossing diagonally: only an edge–edge axis separates them.
        let rx = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), std::f32::consts::FRAC_PI_4);
        let ry = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f32::consts::FRAC_PI_4);
        let long = |c: [f32; 3], rot| OrientedBox {
            parent_from_box: Isometry3::from_parts(Translation3::new(c[0], c[1], c[2]), rot),
            half_extents: Vector3::new(2.0, 0.1, 0.1),
        };
        let a = long([0.0, 0.0, 0.0], rx);
        let b = long(
            [0.0, 0.0, 0.6],
            ry * UnitQuaternion::from_axis_angle(&Vector3::z_axis(), std::f32::consts::FRAC_PI_2),
        );
        let c = long(
            [0.0, 0.0, 0.1],
            ry * UnitQuaternion::from_axis_angle(&Vector3::z_axis(), std::f32::consts::FRAC_PI_2),
        );
        // Reference by dense point sampling of b against a.
        let sample_overlap = |a: &OrientedBox, b: &OrientedBox| {
            let n = 40;
            (0..n * n * n).any(|idx| {
                let f = |v: usize| v as f32 / (n - 1) as f32 * 2.0 - 1.0;
                let l = Point3::new(
                    f(idx % n) * b.half_extents.x,
                    f((idx / n) % n) * b.half_extents.y,
                    f(idx / (n * n)) * b.half_extents.z,
                );
                a.contains(&(b.parent_from_box * l), 0.0)
            })
        };
        assert_eq!(boxes_overlap(&a, &b, 0.0), sample_overlap(&a, &b));
        assert_eq!(boxes_overlap(&a, &c, 0.0), sample_overlap(&a, &c));
        assert!(!boxes_overlap(&a, &b, 0.0));
        assert!(boxes_overlap(&a, &c, 0.0));
    }

    #[test]
    fn non_finite_boxes_fail_safe() {
        let id = UnitQuaternion::identity();
        let a = cube([0.0, 0.0, 0.0], 1.0, id);
        assert!(boxes_overlap(
            &a,
            &cube([f32::NAN, 50.0, 0.0], 1.0, id),
            0.0
        ));
    }
}
