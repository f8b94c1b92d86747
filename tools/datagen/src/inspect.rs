//! `psgrasp inspect`: a PNG of a scene's depth image with its labelled grasps drawn on it.
use crate::dataset::SceneRecord;
use nalgebra::Point3;
use psgrasp_picture::{Projector, RgbImage};

/// Renders the depth image (near = bright) with up to `max_grasps` grasp configurations drawn:
/// the contact pair as a line coloured by quality (red at 0.5 → green at 1), the first contact as
/// a dot, and the most downward collision-free approach as a blue line from the grasp centre to
/// the approach point.
pub fn render_inspection(
    record: &SceneRecord,
    max_grasps: usize,
    use_input_depth: bool,
) -> RgbImage {
    let depth = if use_input_depth {
        &record.depth
    } else {
        &record.depth_clean
    };
    let mut img = RgbImage::from_depth(depth);
    let projector = Projector::new(&record.meta.camera);
    let project = |p: &Point3<f32>| projector.pixel(p);
    let n = record.labels.len();
    let take = max_grasps.min(n);
    let gripper = record.meta.gripper;
    for k in 0..take {
        let l = &record.labels[k * n / take.max(1)];
        let t = ((l.quality - 0.5) / 0.5).clamp(0.0, 1.0);
        let colour = [(255.0 * (1.0 - t)) as u8, (255.0 * t) as u8, 0];
        let (Some(a), Some(b)) = (project(&l.contact), project(&l.second_contact())) else {
            continue;
        };
        img.line(a, b, colour);
        // The collision-free approach closest to straight down (middle indices).
        let mid = (psgrasp_geometry::N_APPROACHES as f32 - 1.0) / 2.0;
        if let Some(i) = (0..psgrasp_geometry::N_APPROACHES)
            .filter(|&i| l.collision_free[i])
            .min_by(|&x, &y| (x as f32 - mid).abs().total_cmp(&(y as f32 - mid).abs()))
        {
            let g = l.grasp(i);
            if let (Some(c), Some(tp)) =
                (project(&g.center()), project(&g.approach_point(&gripper)))
            {
                img.line(c, tp, [40, 90, 255]);
            }
        }
        img.dot(a, colour);
    }
    img
}
