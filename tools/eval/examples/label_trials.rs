//! Executes an evenly spread sample of the labeler's collision-free grasps on test-set scenes and prints
//! the success rate by contact angle and width: which labels the simulated hand can hold.
//! `cargo run --release -p psgrasp-eval --example label_trials -- [LEVEL] [SCENES] [GRASPS_PER_SCENE]`
mod common;

use psgrasp_datagen::Difficulty;
use psgrasp_eval::{execute_grasp, GraspOutcome};

/// One trial: largest contact angle to the baseline (°), width (mm), random-URDF target, success,
/// distance of the object's origin from the grasp axis (mm), the nearest distance beyond the
/// contact planes from which the pads' closing paths are free of the target (mm, band class).
type Trial = (f32, f32, bool, bool, f32, usize);

/// Band edges (mm beyond the contact planes) tried by `pad_clear_class`.
const BAND_MM: [f32; 6] = [0.5, 1.0, 2.0, 3.0, 5.0, 8.0];

/// The index of the smallest `BAND_MM` from which the pads' paths up to 10 mm beyond the
/// contacts are free of the target object (`BAND_MM.len()`: none).
fn pad_clear_class(
    scene: &psgrasp_sim::Scene,
    gripper: &psgrasp_geometry::GripperModel,
    pose: &nalgebra::Isometry3<f32>,
    width: f32,
    object: usize,
) -> usize {
    BAND_MM
        .iter()
        .position(|near| {
            gripper
                .pad_sweep_regions(width, near * 1e-3, 0.010)
                .iter()
                .all(|b| !scene.box_hits_object(&b.placed(pose), object))
        })
        .unwrap_or(BAND_MM.len())
}

/// Angle between a contact normal and the baseline, folded to [0°, 90°].
fn contact_angle_deg(normal: &nalgebra::Vector3<f32>, baseline: &nalgebra::Vector3<f32>) -> f32 {
    baseline
        .dot(normal)
        .abs()
        .clamp(0.0, 1.0)
        .acos()
        .to_degrees()
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let level = common::level_arg(args.get(1), Difficulty::Medium);
    let scenes: u64 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(5);
    let per_scene: usize = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(40);
    let (cfg, set) = common::benchmark();
    let gripper = cfg.scenes.cell.gripper;
    let mut rows: Vec<Trial> = Vec::new();
    let mut outcomes = std::collections::BTreeMap::new();
    for i in 0..scenes {
        let (scene, labels) = common::labelled_scene(&cfg, &set, level, i);
        for (k, a) in common::spread_free_grasps(&labels, |_| true, per_scene) {
            let l = &labels[k];
            let g = l.grasp(a);
            let cmd = common::label_command(&cfg, l, a);
            let ex = execute_grasp(&scene, &set.meshes, &gripper, &cmd, &cfg.execution).unwrap();
            *outcomes
                .entry(format!("{:?}", ex.report.outcome))
                .or_insert(0usize) += 1;
            if ex.report.outcome == GraspOutcome::PregraspCollision {
                continue;
            }
            let theta = contact_angle_deg(&l.contact_normal, &l.baseline)
                .max(contact_angle_deg(&l.second_normal, &l.baseline));
            let mesh = scene.objects()[l.object as usize]
                .spec
                .name
                .starts_with("random");
            if std::env::var_os("TRIALS_VERBOSE").is_some() {
                println!(
                    "w {:5.1} mm θ {:4.1}° {:?} touch {:?} open {:.1} mm lifted {:?} obj {} z {:.3}",
                    l.width * 1e3,
                    theta,
                    ex.report.outcome,
                    ex.report.approach_touch.as_ref().map(|t| (format!("{:?}", t.part), (t.short_of_grasp_m * 1e3).round())),
                    ex.report.final_opening_m * 1e3,
                    ex.report.lifted_objects,
                    l.object,
                    g.center().z
                );
            }
            // The object's origin (its bounding-box centre) from the line through the contacts.
            let origin = scene.objects()[l.object as usize]
                .workspace_from_object
                .translation
                .vector;
            let d = origin - l.contact.coords;
            let off_axis = (d - l.baseline * d.dot(&l.baseline)).norm() * 1e3;
            let band = pad_clear_class(
                &scene,
                &gripper,
                &g.workspace_from_gripper(),
                l.width,
                l.object as usize,
            );
            rows.push((
                theta,
                l.width * 1e3,
                mesh,
                ex.report.outcome == GraspOutcome::Success,
                off_axis,
                band,
            ));
        }
        eprintln!(
            "scene {i}: {} labels, {} trials so far",
            labels.len(),
            rows.len()
        );
    }
    println!("outcomes {outcomes:?} (pre-grasp collisions are left out below)");
    let show = |name: &str, key: &dyn Fn(&Trial) -> usize, edges: &[&str]| {
        println!("{name}");
        for (b, e) in edges.iter().enumerate() {
            let sel: Vec<_> = rows.iter().filter(|r| key(r) == b).collect();
            let ok = sel.iter().filter(|r| r.3).count();
            if !sel.is_empty() {
                println!(
                    "  {e:>10}: {ok:4} / {:4} = {:5.1} %",
                    sel.len(),
                    100.0 * ok as f32 / sel.len() as f32
                );
            }
        }
    };
    show(
        "by largest contact angle to the baseline",
        &|r| ((r.0 / 10.0) as usize).min(5),
        &["0-10°", "10-20°", "20-30°", "30-40°", "40-50°", "50°+"],
    );
    show(
        "by width",
        &|r| ((r.1 / 10.0) as usize).min(7),
        &[
            "0-10mm", "10-20", "20-30", "30-40", "40-50", "50-60", "60-70", "70+",
        ],
    );
    show(
        "random URDF (1) vs other (0)",
        &|r| r.2 as usize,
        &["other", "random"],
    );
    show(
        "by distance of the object's centre from the grasp axis",
        &|r| ((r.4 / 10.0) as usize).min(5),
        &["0-10mm", "10-20", "20-30", "30-40", "40-50", "50+"],
    );
    show(
        "by the pads' paths: free of the target from this far beyond the contacts",
        &|r| r.5,
        &["0.5 mm", "1 mm", "2 mm", "3 mm", "5 mm", "8 mm", "never"],
    );
    show(
        "narrow (<20 mm): paths free from 2 mm (0) / not (1)",
        &|r| if r.1 < 20.0 { (r.5 > 2) as usize } else { 9 },
        &["free", "not free"],
    );
    show(
        "narrow (<20 mm) by angle <30° (0) / >=30° (1)",
        &|r| {
            if r.1 < 20.0 {
                (r.0 >= 30.0) as usize
            } else {
                9
            }
        },
        &["<30°", ">=30°"],
    );
}
