//! Independent re-checks of labels, by other means than the labeller uses: surface normals from
//! finite differences of the signed distance (instead of ray-cast normals) and gripper collision
//! from dense point samples on the gripper boxes tested for containment in every solid (instead
//! of box–shape intersection tests).
use crate::labels::GraspLabel;
use nalgebra::{Point3, Vector3};
use psgrasp_geometry::{antipodal_quality, GripperModel, OrientedBox};
use psgrasp_sim::Scene;

/// Outward normal of object `object` near surface point `p`, from central differences of the
/// signed distance with step `h`.
pub fn finite_difference_normal(
    scene: &Scene,
    object: usize,
    p: &Point3<f32>,
    h: f32,
) -> Option<Vector3<f32>> {
    let sd = |q: Point3<f32>| scene.object_signed_distance(object, &q);
    let mut g = Vector3::zeros();
    for a in 0..3 {
        let mut e = Vector3::zeros();
        e[a] = h;
        g[a] = (sd(p + e)? - sd(p - e)?) / (2.0 * h);
    }
    let n = g.norm();
    (n > 1e-6).then(|| g / n)
}

/// Antipodal quality recomputed with finite-difference normals at both contacts.
pub fn recompute_quality(scene: &Scene, label: &GraspLabel, h: f32) -> Option<f32> {
    let o = label.object as usize;
    let n1 = finite_difference_normal(scene, o, &label.contact, h)?;
    let n2 = finite_difference_normal(scene, o, &label.second_contact(), h)?;
    Some(antipodal_quality(&label.baseline, &n1, &n2))
}

/// Distance of both contacts from the object surface (should be ~0).
pub fn contact_surface_error(scene: &Scene, label: &GraspLabel) -> Option<f32> {
    let o = label.object as usize;
    let a = scene.object_signed_distance(o, &label.contact)?.abs();
    let b = scene
        .object_signed_distance(o, &label.second_contact())?
        .abs();
    Some(a.max(b))
}

/// Points on the surface of `b` with spacing at most `step` (faces, edges and corners).
pub fn box_surface_points(b: &OrientedBox, step: f32) -> Vec<Point3<f32>> {
    let h = b.half_extents;
    let n = |e: f32| ((2.0 * e / step).ceil() as usize).max(1);
    let (nx, ny, nz) = (n(h.x), n(h.y), n(h.z));
    let lerp = |e: f32, i: usize, m: usize| -e + 2.0 * e * i as f32 / m as f32;
    let mut out = Vec::new();
    for i in 0..=nx {
        for j in 0..=ny {
            for k in 0..=nz {
                let on_face = i == 0 || i == nx || j == 0 || j == ny || k == 0 || k == nz;
                if on_face {
                    let local = Point3::new(lerp(h.x, i, nx), lerp(h.y, j, ny), lerp(h.z, k, nz));
                    out.push(b.parent_from_box * local);
                }
            }
        }
    }
    out
}

/// True if a sample on the surface of any gripper box lies inside an object or a bin box, or an
/// object's origin lies inside a gripper box (an object swallowed whole). `opening` is the finger
/// opening used for the check.
pub fn gripper_hits_scene_sampled(
    scene: &Scene,
    gripper: &GripperModel,
    label: &GraspLabel,
    approach: usize,
    opening: f32,
    step: f32,
) -> bool {
    let pose = label.grasp(approach).workspace_from_gripper();
    let bin_boxes = scene.bin().boxes();
    for gb in gripper.boxes(&pose, opening) {
        let centre = Point3::from(gb.parent_from_box.translation.vector);
        let radius = gb.half_extents.norm();
        let near = scene.objects_near_point(&centre, radius);
        for p in box_surface_points(&gb, step) {
            if near.iter().any(|&o| scene.object_contains_point(o, &p)) {
                return true;
            }
            if bin_boxes.iter().any(|bb| bb.contains(&p, 0.0)) {
                return true;
            }
        }
        // An object swallowed whole: the centre of its first part lies inside the gripper box.
        let swallowed = scene.objects().iter().any(|o| {
            o.spec.parts.first().is_some_and(|part| {
                let inner = o.workspace_from_object
                    * Point3::from(part.object_from_part.translation.vector);
                gb.contains(&inner, 0.0)
            })
        });
        if swallowed {
            return true;
        }
    }
    false
}
