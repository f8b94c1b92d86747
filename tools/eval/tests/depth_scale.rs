//! The depth-scale correction on rendered test scenes with the datasets' "dex" noise: the scale
//! it finds is the noise's own multiplicative factor.
use psgrasp_datagen::{derive_seed, Difficulty, GenerationConfig};
use psgrasp_fusion::{correct_depth_scale, estimate_depth_scale, DepthScaleConfig};
use psgrasp_sim::{add_dex_noise, default_camera, generate_scene, MeshLibrary, ObjectLibrary};

#[test]
fn the_scale_found_in_cluttered_noisy_frames_is_the_noise_factor() {
    let gen = GenerationConfig::default();
    let library = ObjectLibrary::procedural();
    let meshes = MeshLibrary::default();
    let cfg = DepthScaleConfig {
        enabled: true,
        ..DepthScaleConfig::default()
    };
    // The multiplicative factor alone: the same draw without the additive field.
    let factor_only = psgrasp_sim::NoiseConfig {
        gp_rate: 0.0,
        ..gen.noise
    };
    let mut worst = 0.0f32;
    for (level, index) in [
        (Difficulty::Challenging, 0u64),
        (Difficulty::Challenging, 1),
        (Difficulty::Challenging, 2),
        (Difficulty::Medium, 0),
    ] {
        let seed = derive_seed(7, index);
        let recipe = gen.scene_recipe(level);
        let pool = library.select(Some(level.split()), level.simple_only());
        let (scene, _) =
            generate_scene(derive_seed(seed, 1), &pool, &gen.cell.bin, &meshes, &recipe).unwrap();
        let camera = default_camera(scene.bin(), gen.intrinsics);
        let clean = scene.render(&camera).depth;
        // A calibrated frame: the scale is 1 and nothing is changed.
        let mut same = clean.clone();
        let (found, applied) = correct_depth_scale(&mut same, &camera, scene.bin(), &cfg).unwrap();
        assert!((found.unwrap().scale - 1.0).abs() < 1e-3, "{found:?}");
        assert!(!applied);
        assert_eq!(same.data, clean.data);
        for k in 0..4u64 {
            let noise_seed = derive_seed(seed, 10 + k);
            let noisy = add_dex_noise(&clean, noise_seed, &gen.noise);
            let scaled = add_dex_noise(&clean, noise_seed, &factor_only);
            let i = clean.data.iter().position(|&d| d > 0.0).unwrap();
            let truth = scaled.data[i] / clean.data[i];
            let est = estimate_depth_scale(&noisy, &camera, scene.bin(), &cfg)
                .unwrap()
                .unwrap();
            worst = worst.max((est.scale - truth).abs());
            // Corrected, a floor pixel is back at its true depth (up to the additive noise).
            let mut fixed = noisy.clone();
            let (_, applied) = correct_depth_scale(&mut fixed, &camera, scene.bin(), &cfg).unwrap();
            assert_eq!(applied, (est.scale - 1.0).abs() >= cfg.min_correction);
            if applied {
                let mean_ratio = |img: &psgrasp_geometry::DepthImage| {
                    let (mut sum, mut n) = (0.0f64, 0usize);
                    for (a, b) in img.data.iter().zip(&clean.data) {
                        if *a > 0.0 && *b > 0.0 {
                            sum += f64::from(a / b);
                            n += 1;
                        }
                    }
                    sum / n as f64
                };
                let before = (mean_ratio(&noisy) - 1.0).abs();
                let after = (mean_ratio(&fixed) - 1.0).abs();
                assert!(after < 0.002 && after < before, "{before} → {after}");
            }
        }
    }
    // Dex noise draws factors with σ ≈ 3 %; what is left after the correction is below 0.1 %.
    assert!(worst < 0.001, "worst scale error {worst}");

    // A scale error beyond the searched range, or a frame that sees nothing of the bin, gives no
    // estimate and the frame is left as it is.
    let scene = generate_scene(
        derive_seed(7, 0),
        &library.select(Some(Difficulty::Medium.split()), false),
        &gen.cell.bin,
        &meshes,
        &gen.scene_recipe(Difficulty::Medium),
    )
    .unwrap()
    .0;
    let camera = default_camera(scene.bin(), gen.intrinsics);
    let clean = scene.render(&camera).depth;
    let mut far = clean.clone();
    far.data.iter_mut().for_each(|d| *d *= 1.3);
    let kept = far.clone();
    assert_eq!(
        correct_depth_scale(&mut far, &camera, scene.bin(), &cfg).unwrap(),
        (None, false)
    );
    assert_eq!(far.data, kept.data);
    let mut blank = clean.clone();
    blank.data.iter_mut().for_each(|d| *d = 0.0);
    assert_eq!(
        estimate_depth_scale(&blank, &camera, scene.bin(), &cfg).unwrap(),
        None
    );
    // A frame of the wrong size is an error, not a guess.
    let mut small = clean.clone();
    small.width -= 1;
    assert!(estimate_depth_scale(&small, &camera, scene.bin(), &cfg).is_err());
    // Disabled, nothing is estimated.
    let mut same = clean.clone();
    assert_eq!(
        correct_depth_scale(
            &mut same,
            &camera,
            scene.bin(),
            &DepthScaleConfig::default()
        )
        .unwrap(),
        (None, false)
    );
}

#[test]
fn a_bad_depth_scale_setting_is_refused_by_the_protocol() {
    let mut proto = psgrasp_eval::ProtocolConfig::default();
    proto.scenes.cell.depth_scale.max_deviation = 0.9;
    let e = proto.validate().unwrap_err().to_string();
    assert!(e.contains("depth_scale.max_deviation"), "{e}");
}
