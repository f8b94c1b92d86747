//! Fusion timings on one core: `cargo bench -p psgrasp-fusion`.
//!
//! Renders an analytic bin scene (floor, sphere, box) top-down with the test ray caster (`psgrasp_test_support::analytic`), then
//! times `TsdfVolume::integrate` (into a freshly reset volume), `write_normal_grid` (into
//! preallocated buffers), the whole frame (reset + integrate + extract) and the depth-scale
//! estimate against a bin whose floor is the scene's (frame scaled by 1.02), and the frame's 2 mm
//! height map (`[selection.surface_check]`). Prints a Markdown table.
use nalgebra::Point3;
use psgrasp_fusion::{
    estimate_depth_scale, write_height_map, DepthScaleConfig, FusionConfig, HeightMapGeometry,
    TsdfVolume,
};
use psgrasp_geometry::{BinModel, CameraIntrinsics, CameraModel};
use psgrasp_test_support::analytic::*;
use std::time::Instant;

fn stats(mut v: Vec<f64>) -> (f64, f64, f64, f64) {
    v.sort_by(|a, b| a.total_cmp(b));
    let mean = v.iter().sum::<f64>() / v.len() as f64;
    let at = |q: f64| v[((v.len() - 1) as f64 * q).round() as usize];
    (mean, at(0.5), at(0.99), v[0])
}

fn main() {
    let iterations: usize = std::env::var("FUSION_BENCH_ITERS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(200);
    let scene = Scene {
        shapes: vec![floor(), sphere(), cuboid()],
    };
    let ws = workspace();
    let c = ws.extent() * 0.5;
    let hd = CameraIntrinsics {
        width: 1280,
        height: 720,
        fx: 900.0,
        fy: 900.0,
        cx: 639.5,
        cy: 359.5,
    };
    let cameras = [
        ("640×480", top_camera()),
        (
            "1280×720",
            CameraModel::top_down(hd, Point3::new(c.x, c.y, FLOOR_Z + 0.8)),
        ),
    ];
    println!("| frame | grid | stage | mean ms | p50 ms | p99 ms | min ms |");
    println!("|---|---|---|---|---|---|---|");
    for (name, cam) in cameras {
        let depth = scene.render(&cam);
        let mut vol = TsdfVolume::new(ws, &FusionConfig::default()).unwrap();
        let n = ws.voxel_count();
        let (mut normals, mut tsdf) = (vec![0.0f32; 3 * n], vec![0.0f32; n]);
        // Warm-up (allocates the per-pixel scratch).
        vol.integrate(&depth, &cam).unwrap();
        let (mut t_int, mut t_ext, mut t_all) = (Vec::new(), Vec::new(), Vec::new());
        for _ in 0..iterations {
            vol.reset();
            let t0 = Instant::now();
            std::hint::black_box(vol.integrate(&depth, &cam).unwrap());
            t_int.push(t0.elapsed().as_secs_f64() * 1e3);
            let t0 = Instant::now();
            vol.write_normal_grid(&mut normals, &mut tsdf).unwrap();
            std::hint::black_box(&normals);
            t_ext.push(t0.elapsed().as_secs_f64() * 1e3);
            let t0 = Instant::now();
            vol.reset();
            vol.integrate(&depth, &cam).unwrap();
            vol.write_normal_grid(&mut normals, &mut tsdf).unwrap();
            std::hint::black_box(&normals);
            t_all.push(t0.elapsed().as_secs_f64() * 1e3);
        }
        // The depth-scale estimate on the frame with a 2 % range error, the floor as the bin's.
        let bin = BinModel {
            floor_center: Point3::new(c.x, c.y, FLOOR_Z),
            ..BinModel::default()
        };
        let mut scaled = depth.clone();
        scaled.data.iter_mut().for_each(|d| *d *= 1.02);
        let scale_cfg = DepthScaleConfig {
            enabled: true,
            ..DepthScaleConfig::default()
        };
        let mut t_scale = Vec::new();
        for _ in 0..iterations {
            let t0 = Instant::now();
            let e = estimate_depth_scale(&scaled, &cam, &bin, &scale_cfg).unwrap();
            t_scale.push(t0.elapsed().as_secs_f64() * 1e3);
            assert!(e.is_some_and(|e| (e.scale - 1.02).abs() < 1e-3), "{e:?}");
        }
        // The 2 mm height map of the same frame (selection's surface check).
        let geometry = HeightMapGeometry::new(&ws, 0.002).unwrap();
        let mut heights = vec![0.0f32; geometry.len()];
        let mut t_map = Vec::new();
        for _ in 0..iterations {
            let t0 = Instant::now();
            write_height_map(&depth, &cam, &geometry, &mut heights).unwrap();
            std::hint::black_box(&heights);
            t_map.push(t0.elapsed().as_secs_f64() * 1e3);
        }
        let dims = ws.dims;
        let grid = format!(
            "{}×{}×{} @ {} mm",
            dims[0],
            dims[1],
            dims[2],
            ws.voxel_size_m * 1e3
        );
        for (stage, v) in [
            ("integrate", t_int),
            ("normal extraction", t_ext),
            ("total (reset+integrate+extract)", t_all),
            ("depth-scale estimate", t_scale),
            ("height map (2 mm cells)", t_map),
        ] {
            let (mean, p50, p99, min) = stats(v);
            println!("| {name} | {grid} | {stage} | {mean:.3} | {p50:.3} | {p99:.3} | {min:.3} |");
        }
    }
    println!(
        "\n{iterations} iterations per row, one thread (no rayon); `min` is the best estimate on a \
         shared machine. Set FUSION_BENCH_ITERS to change the count."
    );
}
