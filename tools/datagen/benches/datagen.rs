//! Seconds per generated scene by object count, on one core, with label statistics:
//! `cargo bench -p psgrasp-datagen`. Each row averages `REPS` scenes (train objects, default bin,
//! default label config), timing every stage of `generate_record`.
use psgrasp_datagen::dataset::encode_scene;
use psgrasp_datagen::{generate_record_with_recipe, Difficulty, GenerationConfig};
use psgrasp_sim::{MeshLibrary, ObjectLibrary, SceneRecipe};
use std::time::Instant;

const REPS: u64 = 4;

fn main() {
    let library = ObjectLibrary::procedural();
    let meshes = MeshLibrary::default();
    let config = GenerationConfig::default();
    println!("| objects | s/scene | encode (s) | objects kept | graspable | grasps/scene | grasps/graspable object | configurations/scene | free poses |");
    println!("|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for n in [5usize, 10, 20, 35] {
        let recipe = SceneRecipe {
            min_objects: n,
            max_objects: n,
            settle: config.settle.clone(),
            ..Default::default()
        };
        let (mut t_gen, mut t_enc) = (0.0, 0.0);
        let (mut kept, mut graspable, mut grasps, mut configs, mut checked, mut free) =
            (0, 0, 0, 0, 0, 0);
        for seed in 0..REPS {
            let t = Instant::now();
            let rec = generate_record_with_recipe(
                seed,
                1000 + seed,
                Difficulty::Train,
                &recipe,
                "procedural",
                &library,
                &meshes,
                &config,
            )
            .expect("scene");
            t_gen += t.elapsed().as_secs_f64();
            let t = Instant::now();
            std::hint::black_box(encode_scene(&rec).expect("encode"));
            t_enc += t.elapsed().as_secs_f64();
            let s = &rec.meta.label_stats;
            kept += rec.meta.scene.objects.len();
            graspable += s.graspable_objects;
            grasps += s.grasps;
            configs += s.configurations;
            checked += s.poses_checked;
            free += s.poses_free;
        }
        let r = REPS as f64;
        println!(
            "| {n} | {:.2} | {:.3} | {:.1} | {:.1} | {:.0} | {:.0} | {:.0} | {:.2} % |",
            t_gen / r,
            t_enc / r,
            kept as f64 / r,
            graspable as f64 / r,
            grasps as f64 / r,
            grasps as f64 / graspable.max(1) as f64,
            configs as f64 / r,
            100.0 * free as f64 / checked.max(1) as f64
        );
    }
}
