//! Zero-copy messages and iceoryx2 transport of the psgrasp pipeline.
//!
//! Wire format: every message is an iceoryx2 publish-subscribe sample with the `#[repr(C)]`
//! [`FrameHeader`] as user header and a slice payload of one element type per service:
//!
//! | service            | payload element            | producer          |
//! |--------------------|----------------------------|-------------------|
//! | `<pipeline>/depth`    | `f32` depth in metres, row-major | camera-ingest |
//! | `<pipeline>/grid`     | `f32`: 3·N normals (channel-major) then N normalised TSDF | grid-fusion |
//! | `<pipeline>/grasps`   | [`GraspRecord`]          | inference         |
//! | `<pipeline>/picks`    | [`PickRecord`]           | grasp-selection   |
//! | `<pipeline>/stats`    | [`StageStats`] (fixed size) | every stage    |
//! | `<pipeline>/progress` | [`ProgressEvent`] (one)  | every stage; read by camera-ingest's [`FrameLedger`] |
//! | `<pipeline>/next-pick`| request-response [`NextPickRequest`] → [`NextPickResponse`] | grasp-selection |
//!
//! Each publish-subscribe service is paired with an event service of the same name; publishers
//! notify after every send so subscribers sleep in a WaitSet instead of polling. The header's
//! `version` must equal [`PROTOCOL_VERSION`]; a receiver rejects anything else. The iceoryx2
//! type names carry the version too (`psgrasp::FrameHeader/v1`), so processes built from
//! different protocol versions cannot even connect.
#![warn(missing_docs)]

pub mod header;
pub mod ledger;
pub mod records;
pub mod transport;

pub use header::{
    now_ns, FrameHeader, MessageKind, Stage, Stamp, StatusCode, FRAME_HEADER_SIZE, PROTOCOL_VERSION,
};
pub use ledger::{is_stale, FrameLedger, ProgressEvent, ProgressKind, RecentIds, Verdict};
pub use records::{
    GraspRecord, NextPickMode, NextPickRequest, NextPickResponse, NextPickStatus, PickRecord,
    StageStats,
};
pub use transport::{
    cleanup_dead_nodes, install_termination_handlers, note_termination, termination_requested,
    ChannelConfig, DropPolicy, FramePublisher, FrameSubscriber, InputPort, IpcError, PipelineNode,
    ServiceNames, OUTCOME_BUFFER, PROGRESS_BUFFER,
};
