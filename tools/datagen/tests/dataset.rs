//! Dataset files, determinism, resuming and the inspect image.
use psgrasp_datagen::dataset::{decode_scene, encode_scene, scene_file_name};
use psgrasp_datagen::{
    derive_seed, generate_record, run_datagen, run_inspect, DatagenArgs, Difficulty,
    GenerationConfig, InspectArgs, LabelConfig, Manifest, ObjectSource,
};
use psgrasp_sim::{MeshLibrary, ObjectLibrary};

fn quick_config() -> GenerationConfig {
    GenerationConfig {
        labels: LabelConfig::quick(),
        ..Default::default()
    }
}

#[test]
fn same_seed_gives_a_byte_identical_scene_and_files_round_trip() {
    let lib = ObjectLibrary::procedural();
    let cfg = quick_config();
    let meshes = MeshLibrary::default();
    let a = generate_record(0, 77, Difficulty::Medium, "procedural", &lib, &meshes, &cfg).unwrap();
    let b = generate_record(0, 77, Difficulty::Medium, "procedural", &lib, &meshes, &cfg).unwrap();
    let bytes = encode_scene(&a).unwrap();
    assert_eq!(bytes, encode_scene(&b).unwrap());
    let back = decode_scene(&bytes).unwrap();
    assert_eq!(back, a);
    // Medium scenes use clean depth and test objects only.
    assert!(!a.meta.noise_applied);
    assert_eq!(a.depth, a.depth_clean);
    let test_names: Vec<&str> = lib
        .objects
        .iter()
        .filter(|o| o.split == psgrasp_sim::Split::Test)
        .map(|o| o.spec.name.as_str())
        .collect();
    assert!(a
        .meta
        .scene
        .objects
        .iter()
        .all(|o| test_names.contains(&o.spec.name.as_str())));
    // A corrupted file is an error, not a panic.
    assert!(decode_scene(&bytes[..bytes.len() / 2]).is_err());
    assert!(decode_scene(b"not a safetensors file").is_err());
}

#[test]
fn five_scene_dataset_resumes_and_inspects() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("ds");
    let args = DatagenArgs {
        scenes: 5,
        objects: ObjectSource::Procedural,
        difficulty: Difficulty::Train,
        out: out.clone(),
        seed: 11,
        jobs: Some(2),
        config: None,
        quick: true,
        mesh_dir: None,
        quiet: true,
    };
    run_datagen(&args).unwrap();
    let manifest = Manifest::read(&out).unwrap();
    assert_eq!(manifest.scenes.len(), 5);
    assert_eq!(manifest.train_objects.len(), 149);
    let files: Vec<Vec<u8>> = (0..5)
        .map(|i| std::fs::read(out.join(scene_file_name(i))).unwrap())
        .collect();
    // Every scene has objects and noisy input depth; the manifest matches the files.
    for (i, bytes) in files.iter().enumerate() {
        let rec = decode_scene(bytes).unwrap();
        assert_eq!(rec.meta.seed, derive_seed(11, i as u64));
        assert!(rec.meta.noise_applied);
        // Training scenes hold training objects only.
        assert!(rec
            .meta
            .scene
            .objects
            .iter()
            .all(|o| manifest.train_objects.contains(&o.spec.name)));
        assert_eq!(
            manifest.scenes[i].grasps,
            rec.labels.iter().map(|l| l.free_count()).sum::<usize>()
        );
    }

    // Simulate a killed run: one scene missing, one half-written, a stale temp file.
    std::fs::remove_file(out.join(scene_file_name(2))).unwrap();
    std::fs::write(out.join(scene_file_name(3)), &files[3][..1000]).unwrap();
    std::fs::write(out.join(".scene_000004.safetensors.tmp-1"), b"junk").unwrap();
    let before = std::fs::metadata(out.join(scene_file_name(0)))
        .unwrap()
        .modified()
        .unwrap();
    run_datagen(&args).unwrap();
    for (i, bytes) in files.iter().enumerate() {
        assert_eq!(
            &std::fs::read(out.join(scene_file_name(i as u64))).unwrap(),
            bytes,
            "scene {i}"
        );
    }
    assert_eq!(
        std::fs::metadata(out.join(scene_file_name(0)))
            .unwrap()
            .modified()
            .unwrap(),
        before
    );
    assert!(!out.join(".scene_000004.safetensors.tmp-1").exists());

    // The same directory with another seed is refused.
    let other = DatagenArgs {
        seed: 12,
        ..args.clone()
    };
    assert!(run_datagen(&other).is_err());

    let png_path = dir.path().join("s0.png");
    run_inspect(&InspectArgs {
        scene: out.join(scene_file_name(0)),
        out: Some(png_path.clone()),
        max_grasps: 100,
        clean: false,
    })
    .unwrap();
    let decoder = png::Decoder::new(std::io::BufReader::new(
        std::fs::File::open(&png_path).unwrap(),
    ));
    let reader = decoder.read_info().unwrap();
    assert_eq!((reader.info().width, reader.info().height), (640, 480));
}

#[test]
fn franka_fingertip_config_changes_the_tip_depth_only_and_typos_are_refused() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../config/datagen-franka-fingertip.toml");
    let franka: GenerationConfig = toml::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    assert_eq!(franka.cell.gripper.tip_beyond_tcp_m, 0.0095);
    let mut back = franka.clone();
    back.cell.gripper.tip_beyond_tcp_m = GenerationConfig::default().cell.gripper.tip_beyond_tcp_m;
    assert_eq!(back, GenerationConfig::default());
    // A misspelt table would otherwise be dropped silently and train on the default hand.
    let typo = "[griper]\ntip_beyond_tcp_m = 0.0095\n";
    let err = toml::from_str::<GenerationConfig>(typo).unwrap_err();
    assert!(err.to_string().contains("griper"), "{err}");
}

#[test]
fn every_shipped_datagen_config_loads_and_validates() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config");
    let mut loaded = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_name().unwrap().to_string_lossy().to_string();
        if !(name.starts_with("datagen-") && name.ends_with(".toml")) {
            continue;
        }
        let text = std::fs::read_to_string(&path).unwrap();
        let config: GenerationConfig =
            toml::from_str(&text).unwrap_or_else(|e| panic!("{name}: {e}"));
        config
            .labels
            .validate()
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        let robust = config.labels.robust_quality;
        assert_eq!(robust.is_some(), name.contains("robust"), "{name}");
        if name.ends_with("-robust-drop.toml") {
            assert_eq!(robust.unwrap().max_drop, Some(0.2));
        }
        loaded += 1;
    }
    assert!(loaded >= 8, "only {loaded} datagen configs");
}
