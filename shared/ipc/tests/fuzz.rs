//! Fuzz target of the frame header (docs/testing.md, "Fuzzing"): a header made of arbitrary bytes,
//! as another process may have written it into shared memory, goes through every check and
//! accessor a stage uses on its input (protocol check, status, error text, camera, workspace,
//! stamps, forwarding, turning it into an error record) and the wire decoders of the records;
//! never a panic.
use psgrasp_fuzz_support::{bolero, Dictionary, Mutated, Target};
use psgrasp_ipc::header::ERROR_MESSAGE_LEN;
use psgrasp_ipc::{
    FrameHeader, MessageKind, NextPickMode, NextPickStatus, Stage, Stamp, StatusCode,
    FRAME_HEADER_SIZE,
};

#[global_allocator]
static ALLOC: psgrasp_fuzz_support::TrackingAllocator = psgrasp_fuzz_support::TrackingAllocator;

const KINDS: [MessageKind; 5] = [
    MessageKind::DepthFrame,
    MessageKind::NormalGrid,
    MessageKind::GraspSet,
    MessageKind::SelectedGrasps,
    MessageKind::Announce,
];

const STAMPS: [Stamp; 8] = [
    Stamp::Capture,
    Stamp::IngestPublished,
    Stamp::FusionStart,
    Stamp::FusionEnd,
    Stamp::InferenceStart,
    Stamp::InferenceEnd,
    Stamp::SelectionStart,
    Stamp::SelectionEnd,
];

fn target() -> Target {
    Target::new(env!("CARGO_MANIFEST_DIR"), "frame_header")
}

/// The first [`FRAME_HEADER_SIZE`] bytes (zero-padded) as a header; the rest as a message.
fn split(bytes: &[u8]) -> (FrameHeader, &[u8]) {
    let n = bytes.len().min(FRAME_HEADER_SIZE);
    let mut raw = [0u8; FRAME_HEADER_SIZE];
    raw[..n].copy_from_slice(&bytes[..n]);
    (FrameHeader::from_le_bytes(&raw), &bytes[n..])
}

fn check_header(bytes: &[u8]) {
    let (h, rest) = split(bytes);
    for kind in KINDS {
        let checked = h.check(kind);
        assert_eq!(
            checked.is_ok(),
            h.version == psgrasp_ipc::PROTOCOL_VERSION && h.kind == kind as u32
        );
        let fwd = h.forwarded(kind);
        assert_eq!((fwd.kind, fwd.element_count), (kind as u32, 0));
    }
    let status = h.status();
    assert_eq!(
        status,
        StatusCode::from_u32(h.status).unwrap_or(StatusCode::ProtocolError)
    );
    assert_eq!(h.is_ok(), h.status == StatusCode::Ok as u32);
    if let Some(stage) = Stage::from_u32(h.error_stage) {
        assert_eq!(stage as u32, h.error_stage);
        assert!(!stage.name().is_empty());
    }
    let text = h.error_text();
    assert!(text.chars().all(|c| c != '\0'));
    let camera = h.camera();
    let _ = camera.validate();
    let _ = camera.eye();
    let workspace = h.workspace();
    if workspace.validate().is_ok() {
        assert_eq!(
            workspace.voxel_count() as u64,
            workspace
                .dims
                .iter()
                .map(|&d| u64::from(d))
                .product::<u64>()
        );
    }
    for from in STAMPS {
        for to in STAMPS {
            let ms = h.span_ms(from, to);
            assert!(ms.is_finite() && ms >= 0.0, "{ms}");
        }
    }
    // An error record made from it keeps a prefix of the message, on a char boundary.
    let message = String::from_utf8_lossy(rest);
    let stage = Stage::from_u32(h.error_stage).unwrap_or(Stage::GridFusion);
    let e = h.into_error(StatusCode::ProtocolError, stage, &message);
    let kept = e.error_text();
    assert!(kept.len() < ERROR_MESSAGE_LEN);
    assert!(
        message.starts_with(kept.as_str()),
        "{kept:?} of {message:?}"
    );
    assert_eq!(
        (e.status(), e.element_count),
        (StatusCode::ProtocolError, 0)
    );
    // The records' wire values decode to a variant that encodes back to them, or to none.
    for v in [h.status, h.error_stage, h.kind, h.source_id] {
        if let Some(m) = NextPickMode::from_u32(v) {
            assert_eq!(m as u32, v);
        }
        if let Some(s) = NextPickStatus::from_u32(v) {
            assert_eq!(s as u32, v);
        }
        if let Some(s) = StatusCode::from_u32(v) {
            assert_eq!(s as u32, v);
        }
    }
}

#[test]
fn frame_header() {
    let t = target();
    bolero::check!(name = t.name).for_each(|bytes: &[u8]| t.run(bytes, check_header));
}

#[test]
fn frame_header_mutated() {
    let t = target();
    let seeds = t.seeds();
    let dict = Dictionary::binary(&[]);
    bolero::check!(name = "frame_header_mutated")
        .with_type::<Mutated>()
        .for_each(|m: &Mutated| t.run(&m.apply(&seeds, &dict), check_header));
}
