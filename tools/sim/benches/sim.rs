//! Scene simulation and rendering speed: `cargo bench -p psgrasp-sim`.
use psgrasp_geometry::{BinModel, CameraIntrinsics};
use psgrasp_sim::{add_dex_noise, default_camera, procedural_scene, NoiseConfig};
use std::time::Instant;

fn main() {
    let bin = BinModel::default();
    let camera = default_camera(&bin, CameraIntrinsics::default_640x480());
    let reps = 5u64;
    println!("| objects | settle (ms) | render 640×480 (ms) | dex noise (ms) | objects kept |");
    println!("|---:|---:|---:|---:|---:|");
    for n in [5usize, 10, 20, 35] {
        let (mut t_settle, mut t_render, mut t_noise, mut kept) = (0.0, 0.0, 0.0, 0);
        for seed in 0..reps {
            let t = Instant::now();
            let scene = procedural_scene(seed, n, &bin).expect("scene");
            t_settle += t.elapsed().as_secs_f64();
            let t = Instant::now();
            let depth = scene.render_depth(&camera);
            t_render += t.elapsed().as_secs_f64();
            let t = Instant::now();
            let noisy = add_dex_noise(
                &depth,
                seed,
                &NoiseConfig {
                    gp_rate: 1.0,
                    ..Default::default()
                },
            );
            t_noise += t.elapsed().as_secs_f64();
            std::hint::black_box(noisy);
            kept += scene.object_count();
        }
        let r = reps as f64;
        println!(
            "| {n} | {:.1} | {:.1} | {:.1} | {:.1} |",
            1e3 * t_settle / r,
            1e3 * t_render / r,
            1e3 * t_noise / r,
            kept as f64 / r
        );
    }
}
