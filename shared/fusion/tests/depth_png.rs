//! 16-bit depth PNG round trips and format errors.
use psgrasp_fusion::{load_depth_png, save_depth_png, DepthPngError};
use psgrasp_geometry::{DepthError, DepthImage};

fn temp(name: &str) -> std::path::PathBuf {
    std::env::temp_dir().join(format!("psgrasp-fusion-{}-{name}", std::process::id()))
}

#[test]
fn round_trip_millimetres() {
    let data: Vec<f32> = (0..12 * 7).map(|i| 0.25 + i as f32 * 0.0137).collect();
    let mut img = DepthImage::from_metres(12, 7, data).unwrap();
    img.data[5] = f32::NAN;
    img.data[6] = -1.0;
    img.data[7] = 70.0; // saturates at 65.535 m
    let path = temp("rt.png");
    save_depth_png(&path, &img, 0.001).unwrap();
    let back = load_depth_png(&path, 0.001).unwrap();
    std::fs::remove_file(&path).ok();
    assert_eq!((back.width, back.height), (12, 7));
    for (i, (a, b)) in img.data.iter().zip(&back.data).enumerate() {
        match i {
            5 | 6 => assert_eq!(*b, 0.0),
            7 => assert!((b - 65.535).abs() < 1e-3),
            _ => assert!((a - b).abs() <= 0.0005 + 1e-6, "{i}: {a} vs {b}"),
        }
    }
}

#[test]
fn errors() {
    assert!(matches!(
        load_depth_png(temp("missing.png"), 0.001),
        Err(DepthPngError::Io { .. })
    ));
    assert!(matches!(
        load_depth_png(temp("missing.png"), 0.0),
        Err(DepthPngError::Depth(DepthError::BadUnit(_)))
    ));
    // An 8-bit PNG is not a depth frame.
    let path = temp("rgb8.png");
    {
        let file = std::fs::File::create(&path).unwrap();
        let mut enc = png::Encoder::new(std::io::BufWriter::new(file), 2, 2);
        enc.set_color(png::ColorType::Grayscale);
        enc.set_depth(png::BitDepth::Eight);
        enc.write_header()
            .unwrap()
            .write_image_data(&[1, 2, 3, 4])
            .unwrap();
    }
    let err = load_depth_png(&path, 0.001).unwrap_err();
    std::fs::remove_file(&path).ok();
    assert!(
        matches!(err, DepthPngError::UnsupportedFormat { .. }),
        "{err}"
    );
    // Garbage bytes.
    let path = temp("garbage.png");
    std::fs::write(&path, b"not a png").unwrap();
    assert!(matches!(
        load_depth_png(&path, 0.001),
        Err(DepthPngError::Decode(_))
    ));
    std::fs::remove_file(&path).ok();
    let broken = DepthImage {
        width: 3,
        height: 3,
        data: vec![1.0; 4],
    };
    assert!(matches!(
        save_depth_png(temp("x.png"), &broken, 0.001),
        Err(DepthPngError::Depth(_))
    ));
}
