//! Conversions between our nalgebra types and the glam types used by parry/rapier.
use nalgebra::{Isometry3, Point3, Quaternion, Translation3, UnitQuaternion, Vector3};
use parry3d::glamx::{Pose3, Quat, Vec3};

/// nalgebra vector → glam vector.
#[inline]
pub fn vec_to_glam(v: &Vector3<f32>) -> Vec3 {
    Vec3::new(v.x, v.y, v.z)
}

/// nalgebra point → glam vector.
#[inline]
pub fn point_to_glam(p: &Point3<f32>) -> Vec3 {
    Vec3::new(p.x, p.y, p.z)
}

/// glam vector → nalgebra vector.
#[inline]
pub fn vec_from_glam(v: Vec3) -> Vector3<f32> {
    Vector3::new(v.x, v.y, v.z)
}

/// glam vector → nalgebra point.
#[inline]
pub fn point_from_glam(v: Vec3) -> Point3<f32> {
    Point3::new(v.x, v.y, v.z)
}

/// nalgebra isometry → glam pose.
#[inline]
pub fn pose_to_glam(iso: &Isometry3<f32>) -> Pose3 {
    let q = iso.rotation.quaternion();
    Pose3::from_parts(
        vec_to_glam(&iso.translation.vector),
        Quat::from_xyzw(q.i, q.j, q.k, q.w).normalize(),
    )
}

/// glam pose → nalgebra isometry.
#[inline]
pub fn pose_from_glam(pose: &Pose3) -> Isometry3<f32> {
    let r = pose.rotation;
    Isometry3::from_parts(
        Translation3::from(vec_from_glam(pose.translation)),
        UnitQuaternion::from_quaternion(Quaternion::new(r.w, r.x, r.y, r.z)),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pose_round_trip_maps_points_identically() {
        let iso = Isometry3::new(Vector3::new(0.1, -0.2, 0.3), Vector3::new(0.4, -0.5, 0.9));
        let pose = pose_to_glam(&iso);
        let p = Point3::new(0.03, 0.07, -0.11);
        let a = iso * p;
        let b = point_from_glam(pose.transform_point(point_to_glam(&p)));
        assert!((a - b).norm() < 1e-6);
        let back = pose_from_glam(&pose);
        assert!((back * p - a).norm() < 1e-6);
    }
}
