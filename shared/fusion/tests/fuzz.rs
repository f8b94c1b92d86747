//! Fuzz target of the depth PNG loader (docs/testing.md, "Fuzzing"): arbitrary bytes decode to a
//! frame within the size limit or to a clean error, never a panic, and never allocate beyond
//! what the size limit allows.
use psgrasp_fusion::{decode_depth_png, DepthPngError};
use psgrasp_fuzz_support::{bolero, largest_allocation, Dictionary, Mutated, Target};
use psgrasp_geometry::{DepthError, FrameSize, MAX_DEPTH_PIXELS};

#[global_allocator]
static ALLOC: psgrasp_fuzz_support::TrackingAllocator = psgrasp_fuzz_support::TrackingAllocator;

/// The decoder's pixel buffer for the largest frame [`FrameSize::Bounded`] admits (2 bytes a
/// pixel), plus room for the PNG reader's own buffers.
const MAX_PNG_ALLOC: usize = 2 * MAX_DEPTH_PIXELS as usize + (1 << 20);

fn target() -> Target {
    Target::new(env!("CARGO_MANIFEST_DIR"), "depth_png").max_alloc(MAX_PNG_ALLOC)
}

fn decode(bytes: &[u8]) {
    for size in [
        FrameSize::Bounded,
        FrameSize::Exactly {
            width: 8,
            height: 6,
        },
    ] {
        if let Ok(depth) = decode_depth_png(bytes, 0.001, size) {
            let (w, h) = (depth.width as usize, depth.height as usize);
            assert_eq!(depth.data.len(), w * h);
            assert!(size.check(w as u64, h as u64).is_ok());
        }
    }
}

/// Recomputes every chunk's CRC, so that mutations reach the decoder's header and data checks
/// instead of all stopping at the first CRC mismatch.
fn fix_crcs(png: &mut [u8]) {
    let mut at = 8;
    while at + 12 <= png.len() {
        let len = u32::from_be_bytes(png[at..at + 4].try_into().unwrap()) as usize;
        let Some(end) = (at + 8).checked_add(len).filter(|e| e + 4 <= png.len()) else {
            return;
        };
        let crc = crc32(&png[at + 4..end]);
        png[end..end + 4].copy_from_slice(&crc.to_be_bytes());
        at = end + 4;
    }
}

/// CRC-32 (IEEE 802.3), as PNG chunks carry it.
fn crc32(bytes: &[u8]) -> u32 {
    !bytes.iter().fold(!0u32, |mut c, &b| {
        c ^= u32::from(b);
        for _ in 0..8 {
            c = if c & 1 != 0 {
                0xedb8_8320 ^ (c >> 1)
            } else {
                c >> 1
            };
        }
        c
    })
}

#[test]
fn depth_png() {
    let t = target();
    bolero::check!(name = t.name).for_each(|bytes: &[u8]| t.run(bytes, decode));
}

#[test]
fn depth_png_mutated() {
    let t = target();
    let seeds = t.seeds();
    let dict = Dictionary::binary(&[b"IHDR", b"IDAT", b"IEND", b"PLTE", b"tRNS", b"acTL"]);
    bolero::check!(name = "depth_png_mutated")
        .with_type::<Mutated>()
        .for_each(|m: &Mutated| {
            let mut bytes = m.apply(&seeds, &dict);
            fix_crcs(&mut bytes);
            t.run(&bytes, decode);
        });
}

#[test]
fn crc_fix_up_matches_the_png_crc() {
    let valid = std::fs::read(target().corpus.join("valid-8x6-mm.png")).unwrap();
    let mut broken = std::fs::read(target().corpus.join("bad-crc.png")).unwrap();
    assert_ne!(broken, valid);
    fix_crcs(&mut broken);
    assert_eq!(broken, valid);
}

/// Issue 19: the header of an 8192² frame was decoded in full (a 134 MB pixel buffer, then the
/// frame as f32) before its size was checked. Now the header alone refuses it.
#[test]
fn an_oversized_png_is_refused_from_its_header() {
    let bytes = std::fs::read(target().corpus.join("header-8192x8192.png")).unwrap();
    let (result, largest) =
        largest_allocation(|| decode_depth_png(&bytes, 0.001, FrameSize::Bounded));
    assert!(
        matches!(
            result,
            Err(DepthPngError::Depth(DepthError::TooLarge {
                width: 8192,
                height: 8192
            }))
        ),
        "{result:?}"
    );
    assert!(largest < 1 << 20, "allocated {largest} bytes");
    // Held to the camera's size, a frame of another size is refused the same way.
    let valid = std::fs::read(target().corpus.join("valid-8x6-mm.png")).unwrap();
    let camera = FrameSize::Exactly {
        width: 6,
        height: 8,
    };
    let err = decode_depth_png(&valid, 0.001, camera).unwrap_err();
    assert_eq!(err.to_string(), "depth frame is 8×6 but the camera is 6×8");
    let depth = decode_depth_png(&valid, 0.001, FrameSize::Bounded).unwrap();
    assert_eq!((depth.width, depth.height), (8, 6));
    assert!((depth.at(1, 0) - 0.61).abs() < 1e-6);
}
