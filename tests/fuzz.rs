//! Fuzz targets of what the stages read from outside (docs/testing.md, "Fuzzing"):
//! camera-ingest's `.npy` depth frames and intrinsics files (JSON and TOML), and the inference
//! stage's view of a grid message. Arbitrary bytes give a frame within the size limit, valid
//! intrinsics, a checked grid or a clean error; never a panic, never an allocation beyond what
//! the size limit allows.
use psgrasp::sources::{decode_depth_npy, IntrinsicsFile, IntrinsicsFormat};
use psgrasp_fuzz_support::{bolero, largest_allocation, Dictionary, Mutated, Target};
use psgrasp_geometry::{FrameSize, MAX_DEPTH_PIXELS};
use psgrasp_ipc::{FrameHeader, FRAME_HEADER_SIZE};

#[global_allocator]
static ALLOC: psgrasp_fuzz_support::TrackingAllocator = psgrasp_fuzz_support::TrackingAllocator;

/// The frame as `f32` metres for the largest frame [`FrameSize::Bounded`] admits, plus slack.
const MAX_NPY_ALLOC: usize = 4 * MAX_DEPTH_PIXELS as usize + (1 << 20);

fn npy_target() -> Target {
    Target::new(env!("CARGO_MANIFEST_DIR"), "depth_npy").max_alloc(MAX_NPY_ALLOC)
}

fn decode_npy(bytes: &[u8]) {
    for size in [
        FrameSize::Bounded,
        FrameSize::Exactly {
            width: 8,
            height: 6,
        },
    ] {
        for unit in [0.001, 0.0, f32::NAN] {
            if let Ok(depth) = decode_depth_npy(bytes, unit, size) {
                let (w, h) = (depth.width as usize, depth.height as usize);
                assert_eq!(depth.data.len(), w * h);
                assert!(size.check(w as u64, h as u64).is_ok());
            }
        }
    }
}

#[test]
fn depth_npy() {
    let t = npy_target();
    bolero::check!(name = t.name).for_each(|bytes: &[u8]| t.run(bytes, decode_npy));
}

#[test]
fn depth_npy_mutated() {
    let t = npy_target();
    let seeds = t.seeds();
    let dict = Dictionary::text(&seeds);
    bolero::check!(name = "depth_npy_mutated")
        .with_type::<Mutated>()
        .for_each(|m: &Mutated| t.run(&m.apply(&seeds, &dict), decode_npy));
}

fn intrinsics_target() -> Target {
    Target::new(env!("CARGO_MANIFEST_DIR"), "intrinsics")
}

fn parse_intrinsics(bytes: &[u8]) {
    let Ok(text) = std::str::from_utf8(bytes) else {
        return;
    };
    for format in [IntrinsicsFormat::Json, IntrinsicsFormat::Toml] {
        if let Ok(file) = IntrinsicsFile::parse(text, format) {
            assert!(file.intrinsics().validate().is_ok());
            assert!(file.depth_unit_m.is_none_or(|u| u > 0.0 && u.is_finite()));
        }
    }
}

#[test]
fn intrinsics() {
    let t = intrinsics_target();
    bolero::check!(name = t.name).for_each(|bytes: &[u8]| t.run(bytes, parse_intrinsics));
}

#[test]
fn intrinsics_mutated() {
    let t = intrinsics_target();
    let seeds = t.seeds();
    let dict = Dictionary::text(&seeds);
    bolero::check!(name = "intrinsics_mutated")
        .with_type::<Mutated>()
        .for_each(|m: &Mutated| t.run(&m.apply(&seeds, &dict), parse_intrinsics));
}

fn grid_target() -> Target {
    Target::new(env!("CARGO_MANIFEST_DIR"), "grid_message")
}

/// A grid message: a header (the first [`FRAME_HEADER_SIZE`] bytes, zero-padded) and its `f32`
/// payload (the rest), as the inference stage receives them.
fn check_grid_message(bytes: &[u8]) {
    let n = bytes.len().min(FRAME_HEADER_SIZE);
    let mut raw = [0u8; FRAME_HEADER_SIZE];
    raw[..n].copy_from_slice(&bytes[..n]);
    let header = FrameHeader::from_le_bytes(&raw);
    let payload: Vec<f32> = bytes[n..]
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    // Without and with the frame's height map after the grid (`[selection.surface_check]`).
    let with_map = psgrasp_selection::SurfaceCheck {
        enabled: true,
        cell_m: 0.02,
        ..Default::default()
    };
    for check in [psgrasp_selection::SurfaceCheck::default(), with_map] {
        if let Ok((view, map)) = psgrasp::inference::grid_view(&header, &payload, &check) {
            let voxels = view.workspace.voxel_count();
            assert_eq!((view.normals.len(), view.tsdf.len()), (3 * voxels, voxels));
            assert_eq!(map.is_some(), check.enabled);
            if let Some(map) = map {
                assert_eq!(map.heights.len(), map.geometry.len());
            }
            let _ = psgrasp_inference::validate_grid(&view);
        }
    }
}

#[test]
fn grid_message() {
    let t = grid_target();
    bolero::check!(name = t.name).for_each(|bytes: &[u8]| t.run(bytes, check_grid_message));
}

#[test]
fn grid_message_mutated() {
    let t = grid_target();
    let seeds = t.seeds();
    let dict = Dictionary::binary(&[]);
    bolero::check!(name = "grid_message_mutated")
        .with_type::<Mutated>()
        .for_each(|m: &Mutated| t.run(&m.apply(&seeds, &dict), check_grid_message));
}

fn seed(name: &str) -> Vec<u8> {
    std::fs::read(npy_target().corpus.join(name)).unwrap()
}

/// Issue 19: a `.npy` shape whose pixel count wraps in 64 bits (here 2³² × (2³² + 1)) overflowed
/// the size arithmetic (a panic in debug builds, a wrong size in release ones).
#[test]
fn a_wrapping_npy_shape_is_a_clean_error() {
    let err = decode_depth_npy(&seed("f4-huge-shape.npy"), 0.001, FrameSize::Bounded).unwrap_err();
    assert!(err.to_string().contains("larger than 8192"), "{err:#}");
}

/// Issue 19: an 8192² `.npy` frame was converted in full before its size was checked; now its
/// header is checked first, against the camera's size where one is known.
#[test]
fn an_oversized_npy_is_refused_from_its_header() {
    let bytes = seed("f4-8192x8192.npy");
    let (result, largest) =
        largest_allocation(|| decode_depth_npy(&bytes, 0.001, FrameSize::Bounded));
    let err = result.unwrap_err();
    assert!(err.to_string().contains("8192×8192"), "{err:#}");
    assert!(largest < 1 << 16, "allocated {largest} bytes");
    let camera = FrameSize::Exactly {
        width: 8,
        height: 4,
    };
    let err = decode_depth_npy(&seed("f4-6x8.npy"), 0.001, camera).unwrap_err();
    assert_eq!(err.to_string(), "depth frame is 8×6 but the camera is 8×4");
    let depth = decode_depth_npy(&seed("u2-6x8.npy"), 0.001, FrameSize::Bounded).unwrap();
    assert_eq!((depth.width, depth.height), (8, 6));
    assert!((depth.at(1, 0) - 0.601).abs() < 1e-6);
}
