//! Picks as JSON, the one shape every controller-facing output uses (`psgrasp next-pick`,
//! `psgrasp detect --json`, the HTTP endpoint): poses in the workspace frame and in the robot base
//! frame, each as position + quaternion and as a row-major 4×4 matrix.
use nalgebra::Point3;
use psgrasp_ipc::PickRecord;
use serde_json::{json, Value};

/// A pose as `{position_m, orientation_xyzw, matrix}`.
fn pose(position: [f32; 3], xyzw: [f32; 4]) -> Value {
    let p = psgrasp_geometry::pose_from_xyzw(position, xyzw).cast::<f64>();
    json!({
        "position_m": position,
        "orientation_xyzw": xyzw,
        "matrix": psgrasp_geometry::robot::matrix_rows(&p),
    })
}

/// The JSON of pick `p` of frame `frame_id`.
pub fn pick_json(frame_id: u64, p: &PickRecord) -> Value {
    let contact = Point3::from(p.contact);
    json!({
        "frame_id": frame_id,
        "rank": p.rank,
        "width_m": p.width,
        "quality": p.quality,
        "collision_score": p.collision_score,
        "configuration_index": p.configuration_index,
        "approach_index": p.approach_index,
        "fallback": p.fallback != 0,
        "pad_fill": p.pad_fill(),
        "workspace": {
            "tcp": pose(p.position, p.orientation_xyzw),
            "pregrasp_tcp": pose(p.pregrasp_position, p.orientation_xyzw),
            "contact_m": [contact.x, contact.y, contact.z],
        },
        "base": {
            "calibrated": p.base_calibrated != 0,
            "tcp": pose(p.base_position, p.base_orientation_xyzw),
            "pregrasp_tcp": pose(p.base_pregrasp_position, p.base_orientation_xyzw),
            "flange": pose(p.flange_position, p.flange_orientation_xyzw),
            "pregrasp_flange": pose(p.flange_pregrasp_position, p.flange_orientation_xyzw),
            "camera": pose(p.camera_position, p.camera_orientation_xyzw),
        },
    })
}

/// The JSON of a frame's picks.
pub fn picks_json(frame_id: u64, picks: &[PickRecord]) -> Value {
    json!({
        "frame_id": frame_id,
        "picks": picks.iter().map(|p| pick_json(frame_id, p)).collect::<Vec<_>>(),
    })
}

/// The pick back from its JSON (the fields a `PickRecord` holds); `None` if one is missing.
pub fn pick_from_json(v: &Value) -> Option<PickRecord> {
    let f = |v: &Value| v.as_f64().map(|x| x as f32);
    let arr = |v: &Value, n: usize| -> Option<Vec<f32>> {
        let a = v.as_array()?;
        (a.len() == n).then(|| a.iter().map(f).collect::<Option<Vec<f32>>>())?
    };
    let p3 = |v: &Value| arr(v, 3).map(|a| [a[0], a[1], a[2]]);
    let q4 = |v: &Value| arr(v, 4).map(|a| [a[0], a[1], a[2], a[3]]);
    let (w, b) = (&v["workspace"], &v["base"]);
    Some(
        PickRecord {
            position: p3(&w["tcp"]["position_m"])?,
            orientation_xyzw: q4(&w["tcp"]["orientation_xyzw"])?,
            pregrasp_position: p3(&w["pregrasp_tcp"]["position_m"])?,
            width: f(&v["width_m"])?,
            quality: f(&v["quality"])?,
            collision_score: f(&v["collision_score"])?,
            configuration_index: v["configuration_index"].as_u64()? as u32,
            approach_index: v["approach_index"].as_u64()? as u32,
            rank: v["rank"].as_u64()? as u32,
            // Absent in JSON written before the fallback tier existed: a primary pick.
            fallback: v["fallback"].as_bool().unwrap_or(false) as u32,
            contact: p3(&w["contact_m"])?,
            base_calibrated: b["calibrated"].as_bool()? as u32,
            base_position: p3(&b["tcp"]["position_m"])?,
            base_orientation_xyzw: q4(&b["tcp"]["orientation_xyzw"])?,
            base_pregrasp_position: p3(&b["pregrasp_tcp"]["position_m"])?,
            flange_position: p3(&b["flange"]["position_m"])?,
            flange_orientation_xyzw: q4(&b["flange"]["orientation_xyzw"])?,
            flange_pregrasp_position: p3(&b["pregrasp_flange"]["position_m"])?,
            camera_position: p3(&b["camera"]["position_m"])?,
            camera_orientation_xyzw: q4(&b["camera"]["orientation_xyzw"])?,
            pad_fill: 0.0,
            pad_fill_measured: 0,
        }
        // Absent (or null) in JSON written before the pad fill was sent: not measured.
        .with_pad_fill(f(&v["pad_fill"])),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Isometry3, Translation3, Vector3};
    use psgrasp_geometry::RobotConfig;

    #[test]
    fn a_pick_survives_its_json_bit_for_bit() {
        let pose = Isometry3::new(Vector3::new(0.1, 0.2, 0.3), Vector3::new(0.4, -0.2, 1.0));
        let pre = Isometry3::from_parts(Translation3::new(0.1, 0.2, 0.4), pose.rotation);
        let robot = RobotConfig {
            camera_in_base: Some(psgrasp_geometry::PoseSetting::from_parts(
                [0.5, -0.1, 1.2],
                [1.0, 0.0, 0.0, 0.0],
            )),
            ..Default::default()
        };
        let base = robot
            .resolve(0.0095)
            .unwrap()
            .base_frame(&Isometry3::translation(0.1, 0.2, 0.9));
        let p = PickRecord::new(
            &pose,
            &pre,
            &Point3::new(0.1, 0.2, 0.29),
            0.031,
            0.87,
            0.99,
            17,
            5,
            2,
            &base,
        );
        let text = serde_json::to_string(&pick_json(9, &p)).unwrap();
        let back = pick_from_json(&serde_json::from_str(&text).unwrap()).unwrap();
        assert_eq!(back, p);
        let v: Value = serde_json::from_str(&text).unwrap();
        assert_eq!(v["base"]["calibrated"], true);
        assert_eq!(v["fallback"], false);
        // A fallback-tier pick says so, and keeps saying so through its JSON.
        let weak = PickRecord { fallback: 1, ..p };
        let v = pick_json(9, &weak);
        assert_eq!(v["fallback"], true);
        assert_eq!(pick_from_json(&v).unwrap(), weak);
        // The pad fill: null when not measured, its value (bit for bit back) when it was.
        assert_eq!(v["pad_fill"], Value::Null);
        let edge = p.with_pad_fill(Some(0.43));
        let v = pick_json(9, &edge);
        assert!((v["pad_fill"].as_f64().unwrap() - 0.43).abs() < 1e-6);
        assert_eq!(pick_from_json(&v).unwrap(), edge);
        let m = &v["base"]["tcp"]["matrix"];
        assert_eq!(m[3], json!([0.0, 0.0, 0.0, 1.0]));
        assert!((m[0][3].as_f64().unwrap() - p.base_position[0] as f64).abs() < 1e-6);
    }
}
