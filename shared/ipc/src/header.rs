//! The frame header carried by every pipeline message.
use iceoryx2::prelude::ZeroCopySend;
use psgrasp_geometry::{CameraIntrinsics, CameraModel, Workspace};

/// Version of the message layouts; bump on any layout change.
pub const PROTOCOL_VERSION: u32 = 2;

/// Length of the fixed, NUL-padded UTF-8 error message in the header.
pub const ERROR_MESSAGE_LEN: usize = 164;

/// What a message carries.
#[repr(u32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MessageKind {
    /// A depth frame (`f32` metres).
    DepthFrame = 1,
    /// A normal grid (`f32` normals + TSDF).
    NormalGrid = 2,
    /// Grasp configurations ([`crate::GraspRecord`]).
    GraspSet = 3,
    /// Ranked executable picks ([`crate::PickRecord`]).
    SelectedGrasps = 4,
    /// Reserved (frame announcements of protocol v1 before the frame ledger; never sent).
    Announce = 5,
}

/// Pipeline stages, used in error records and statistics.
#[repr(u32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Stage {
    /// Depth acquisition.
    CameraIngest = 1,
    /// TSDF / normal-grid fusion.
    GridFusion = 2,
    /// Grasp inference.
    Inference = 3,
    /// Grasp selection.
    GraspSelection = 4,
}

impl Stage {
    /// All stages in data-flow order.
    pub const ALL: [Stage; 4] = [
        Stage::CameraIngest,
        Stage::GridFusion,
        Stage::Inference,
        Stage::GraspSelection,
    ];

    /// Decodes a stored stage id.
    pub fn from_u32(v: u32) -> Option<Self> {
        Self::ALL.into_iter().find(|s| *s as u32 == v)
    }

    /// Kebab-case name, as used for binaries and config sections.
    pub fn name(self) -> &'static str {
        match self {
            Stage::CameraIngest => "camera-ingest",
            Stage::GridFusion => "grid-fusion",
            Stage::Inference => "inference",
            Stage::GraspSelection => "grasp-selection",
        }
    }
}

/// Outcome of a frame; anything but `Ok` makes the message an error record with an empty payload.
#[repr(u32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum StatusCode {
    /// Processed normally.
    Ok = 0,
    /// The depth frame was malformed (size, NaN/zero everywhere, bad unit).
    InvalidDepth = 1,
    /// Camera intrinsics or pose were invalid.
    InvalidCamera = 2,
    /// Fusion failed (e.g. nothing inside the workspace).
    FusionFailed = 3,
    /// The inference backend failed.
    InferenceFailed = 4,
    /// Selection failed.
    SelectionFailed = 5,
    /// The frame was lost: the stage holding it restarted, or no result arrived within the loss
    /// timeout (the message says which).
    Lost = 6,
    /// A message violated the protocol (wrong version, kind or size).
    ProtocolError = 7,
    /// The payload did not fit the shared-memory segment.
    PayloadTooLarge = 8,
    /// Refused at admission: the pipeline already held `pipeline.max_frames_in_flight` frames
    /// (a live camera faster than the pipeline).
    Overload = 9,
}

impl StatusCode {
    /// Decodes a stored status.
    pub fn from_u32(v: u32) -> Option<Self> {
        use StatusCode::*;
        [
            Ok,
            InvalidDepth,
            InvalidCamera,
            FusionFailed,
            InferenceFailed,
            SelectionFailed,
            Lost,
            ProtocolError,
            PayloadTooLarge,
            Overload,
        ]
        .into_iter()
        .find(|s| *s as u32 == v)
    }
}

/// Indices into [`FrameHeader::stamps_ns`].
#[repr(usize)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stamp {
    /// When the camera captured (or the source produced) the frame.
    Capture = 0,
    /// Depth frame published by camera-ingest.
    IngestPublished = 1,
    /// Fusion received the frame.
    FusionStart = 2,
    /// Fusion published the grid.
    FusionEnd = 3,
    /// Inference received the grid.
    InferenceStart = 4,
    /// Inference published the grasp set.
    InferenceEnd = 5,
    /// Selection received the grasp set.
    SelectionStart = 6,
    /// Selection published the picks.
    SelectionEnd = 7,
}

/// Header of every pipeline message (`#[repr(C)]`, 344 bytes, 8-byte aligned; layout in
/// `docs/architecture.md`). Timestamps are `CLOCK_REALTIME` nanoseconds, comparable across processes.
#[repr(C)]
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[type_name("psgrasp::FrameHeader/v1")]
pub struct FrameHeader {
    /// [`PROTOCOL_VERSION`].
    pub version: u32,
    /// [`MessageKind`] as `u32`.
    pub kind: u32,
    /// Monotonically increasing id assigned by camera-ingest.
    pub frame_id: u64,
    /// Camera / source id.
    pub source_id: u32,
    /// [`StatusCode`] as `u32`.
    pub status: u32,
    /// [`Stage`] that raised the error (0 if `status == Ok`).
    pub error_stage: u32,
    /// Number of payload elements (mirrors the slice length).
    pub element_count: u32,
    /// Per-stage timestamps, indexed by [`Stamp`].
    pub stamps_ns: [u64; 8],
    /// Image width, height in pixels.
    pub image_size: [u32; 2],
    /// fx, fy, cx, cy in pixels.
    pub intrinsics: [f32; 4],
    /// Camera pose in the workspace frame: translation xyz (m), then quaternion xyzw.
    pub workspace_from_camera: [f32; 7],
    /// Grid voxels along x, y, z.
    pub grid_dims: [u32; 3],
    /// Voxel edge length in metres.
    pub voxel_size_m: f32,
    /// TSDF truncation distance in metres (grid messages).
    pub truncation_m: f32,
    /// Worker index that handled the frame at fusion, inference and selection.
    pub workers: [u16; 4],
    /// Process id of the last stage that wrote the header.
    pub last_pid: u32,
    /// NUL-padded UTF-8 reason for an error record.
    pub error_message: [u8; ERROR_MESSAGE_LEN],
}

impl Default for FrameHeader {
    /// An all-zero header with the current protocol version.
    fn default() -> Self {
        Self {
            version: PROTOCOL_VERSION,
            kind: 0,
            frame_id: 0,
            source_id: 0,
            status: 0,
            error_stage: 0,
            element_count: 0,
            stamps_ns: [0; 8],
            image_size: [0; 2],
            intrinsics: [0.0; 4],
            workspace_from_camera: [0.0; 7],
            grid_dims: [0; 3],
            voxel_size_m: 0.0,
            truncation_m: 0.0,
            workers: [0; 4],
            last_pid: 0,
            error_message: [0; ERROR_MESSAGE_LEN],
        }
    }
}

/// Size of a [`FrameHeader`] in bytes (its `#[repr(C)]` layout has no padding).
pub const FRAME_HEADER_SIZE: usize = 344;

/// Reads little-endian fields off the front of a byte slice.
struct Fields<'a>(&'a [u8]);

impl Fields<'_> {
    fn take<const N: usize>(&mut self) -> [u8; N] {
        let (head, rest) = self.0.split_at(N);
        self.0 = rest;
        head.try_into().expect("N bytes")
    }

    fn u16(&mut self) -> u16 {
        u16::from_le_bytes(self.take())
    }

    fn u32(&mut self) -> u32 {
        u32::from_le_bytes(self.take())
    }

    fn u64(&mut self) -> u64 {
        u64::from_le_bytes(self.take())
    }

    fn f32(&mut self) -> f32 {
        f32::from_le_bytes(self.take())
    }
}

impl FrameHeader {
    /// The header whose little-endian `#[repr(C)]` bytes are `bytes` (layout in
    /// `docs/architecture.md`), as another process may have written it: every bit pattern is a
    /// header, and its checks and accessors cope with any of them (fuzz target `frame_header`).
    pub fn from_le_bytes(bytes: &[u8; FRAME_HEADER_SIZE]) -> Self {
        let mut f = Fields(bytes);
        Self {
            version: f.u32(),
            kind: f.u32(),
            frame_id: f.u64(),
            source_id: f.u32(),
            status: f.u32(),
            error_stage: f.u32(),
            element_count: f.u32(),
            stamps_ns: std::array::from_fn(|_| f.u64()),
            image_size: std::array::from_fn(|_| f.u32()),
            intrinsics: std::array::from_fn(|_| f.f32()),
            workspace_from_camera: std::array::from_fn(|_| f.f32()),
            grid_dims: std::array::from_fn(|_| f.u32()),
            voxel_size_m: f.f32(),
            truncation_m: f.f32(),
            workers: std::array::from_fn(|_| f.u16()),
            last_pid: f.u32(),
            error_message: f.take(),
        }
    }

    /// A fresh header for a frame captured at `capture_ns` by `camera`, over `workspace`.
    pub fn new(
        kind: MessageKind,
        frame_id: u64,
        source_id: u32,
        camera: &CameraModel,
        workspace: &Workspace,
        capture_ns: u64,
    ) -> Self {
        let t = camera.workspace_from_camera.translation.vector;
        let q = camera.workspace_from_camera.rotation.coords; // (i, j, k, w)
        let k = camera.intrinsics;
        let mut stamps_ns = [0u64; 8];
        stamps_ns[Stamp::Capture as usize] = capture_ns;
        Self {
            version: PROTOCOL_VERSION,
            kind: kind as u32,
            frame_id,
            source_id,
            status: StatusCode::Ok as u32,
            error_stage: 0,
            element_count: 0,
            stamps_ns,
            image_size: [k.width, k.height],
            intrinsics: [k.fx, k.fy, k.cx, k.cy],
            workspace_from_camera: [t.x, t.y, t.z, q[0], q[1], q[2], q[3]],
            grid_dims: workspace.dims,
            voxel_size_m: workspace.voxel_size_m,
            truncation_m: 0.0,
            workers: [0; 4],
            last_pid: std::process::id(),
            error_message: [0; ERROR_MESSAGE_LEN],
        }
    }

    /// The same frame re-labelled as another kind (for the next stage's output).
    pub fn forwarded(&self, kind: MessageKind) -> Self {
        Self {
            kind: kind as u32,
            last_pid: std::process::id(),
            element_count: 0,
            ..*self
        }
    }

    /// Turns the header into an error record raised at `stage`.
    pub fn into_error(mut self, status: StatusCode, stage: Stage, message: &str) -> Self {
        self.status = status as u32;
        self.error_stage = stage as u32;
        self.element_count = 0;
        self.error_message = [0; ERROR_MESSAGE_LEN];
        // Truncate on a char boundary so the stored bytes stay valid UTF-8.
        let mut end = message.len().min(ERROR_MESSAGE_LEN - 1);
        while !message.is_char_boundary(end) {
            end -= 1;
        }
        self.error_message[..end].copy_from_slice(&message.as_bytes()[..end]);
        self
    }

    /// Decoded status (`ProtocolError` for unknown values).
    pub fn status(&self) -> StatusCode {
        StatusCode::from_u32(self.status).unwrap_or(StatusCode::ProtocolError)
    }

    /// True for a normal (non-error) message.
    pub fn is_ok(&self) -> bool {
        self.status == StatusCode::Ok as u32
    }

    /// The error message as text.
    pub fn error_text(&self) -> String {
        let end = self
            .error_message
            .iter()
            .position(|&b| b == 0)
            .unwrap_or(ERROR_MESSAGE_LEN);
        String::from_utf8_lossy(&self.error_message[..end]).into_owned()
    }

    /// Records the current time at `stamp`.
    pub fn stamp(&mut self, stamp: Stamp) {
        self.stamps_ns[stamp as usize] = now_ns();
    }

    /// Checks version and kind.
    pub fn check(&self, expected: MessageKind) -> Result<(), String> {
        if self.version != PROTOCOL_VERSION {
            return Err(format!(
                "protocol version {} (expected {PROTOCOL_VERSION})",
                self.version
            ));
        }
        if self.kind != expected as u32 {
            return Err(format!(
                "message kind {} (expected {})",
                self.kind, expected as u32
            ));
        }
        Ok(())
    }

    /// Camera model stored in the header.
    pub fn camera(&self) -> CameraModel {
        let [fx, fy, cx, cy] = self.intrinsics;
        let p = self.workspace_from_camera;
        CameraModel {
            intrinsics: CameraIntrinsics {
                width: self.image_size[0],
                height: self.image_size[1],
                fx,
                fy,
                cx,
                cy,
            },
            workspace_from_camera: psgrasp_geometry::pose_from_xyzw(
                [p[0], p[1], p[2]],
                [p[3], p[4], p[5], p[6]],
            ),
        }
    }

    /// Workspace stored in the header.
    pub fn workspace(&self) -> Workspace {
        Workspace {
            dims: self.grid_dims,
            voxel_size_m: self.voxel_size_m,
        }
    }

    /// Milliseconds between two stamps (0 if either is unset).
    pub fn span_ms(&self, from: Stamp, to: Stamp) -> f64 {
        let (a, b) = (self.stamps_ns[from as usize], self.stamps_ns[to as usize]);
        if a == 0 || b == 0 || b < a {
            0.0
        } else {
            (b - a) as f64 * 1e-6
        }
    }
}

/// `CLOCK_REALTIME` in nanoseconds.
pub fn now_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;
    use std::mem::{align_of, offset_of, size_of};

    #[test]
    fn layout_is_stable() {
        assert_eq!(size_of::<FrameHeader>(), FRAME_HEADER_SIZE);
        assert_eq!(align_of::<FrameHeader>(), 8);
        assert_eq!(offset_of!(FrameHeader, frame_id), 8);
        assert_eq!(offset_of!(FrameHeader, stamps_ns), 32);
        assert_eq!(offset_of!(FrameHeader, image_size), 96);
        assert_eq!(offset_of!(FrameHeader, intrinsics), 104);
        assert_eq!(offset_of!(FrameHeader, workspace_from_camera), 120);
        assert_eq!(offset_of!(FrameHeader, grid_dims), 148);
        assert_eq!(offset_of!(FrameHeader, voxel_size_m), 160);
        assert_eq!(offset_of!(FrameHeader, truncation_m), 164);
        assert_eq!(offset_of!(FrameHeader, workers), 168);
        assert_eq!(offset_of!(FrameHeader, last_pid), 176);
        assert_eq!(offset_of!(FrameHeader, error_message), 180);
    }

    #[test]
    #[cfg(target_endian = "little")]
    fn from_le_bytes_reads_the_memory_layout() {
        let cam = CameraModel::top_down(
            CameraIntrinsics::default_640x480(),
            Point3::new(0.3, 0.2, 0.9),
        );
        let mut h = FrameHeader::new(
            MessageKind::NormalGrid,
            7,
            2,
            &cam,
            &Workspace::default(),
            9,
        )
        .into_error(StatusCode::FusionFailed, Stage::GridFusion, "no surface");
        h.workers = [1, 2, 3, 4];
        h.truncation_m = 0.036;
        // The header's own bytes (x86-64 and aarch64 are little-endian), read field by field.
        let mut bytes = [0u8; FRAME_HEADER_SIZE];
        // SAFETY: `FrameHeader` is `#[repr(C)]` of integers, floats and bytes without padding
        // (`layout_is_stable`); reading its bytes as `u8` is valid.
        let raw = unsafe {
            std::slice::from_raw_parts((&h as *const FrameHeader).cast::<u8>(), FRAME_HEADER_SIZE)
        };
        bytes.copy_from_slice(raw);
        let back = FrameHeader::from_le_bytes(&bytes);
        assert_eq!(back.frame_id, 7);
        assert_eq!(back.workers, [1, 2, 3, 4]);
        assert_eq!(back.truncation_m, 0.036);
        assert_eq!(back.camera().intrinsics, cam.intrinsics);
        assert_eq!(back.status(), StatusCode::FusionFailed);
        assert_eq!(back.error_text(), "no surface");
        assert_eq!(back.stamps_ns, h.stamps_ns);
        assert_eq!(back.last_pid, h.last_pid);
    }

    #[test]
    fn camera_and_workspace_round_trip() {
        let cam = CameraModel::top_down(
            CameraIntrinsics::default_640x480(),
            Point3::new(0.3, 0.2, 0.9),
        );
        let ws = Workspace::default();
        let h = FrameHeader::new(MessageKind::DepthFrame, 7, 2, &cam, &ws, 123);
        let back = h.camera();
        assert_eq!(back.intrinsics, cam.intrinsics);
        assert!(
            (back.workspace_from_camera.to_homogeneous()
                - cam.workspace_from_camera.to_homogeneous())
            .norm()
                < 1e-6
        );
        assert_eq!(h.workspace(), ws);
        assert!(h.check(MessageKind::DepthFrame).is_ok());
        assert!(h.check(MessageKind::NormalGrid).is_err());
    }

    #[test]
    fn error_records_carry_reason() {
        let cam = CameraModel::top_down(
            CameraIntrinsics::default_640x480(),
            Point3::new(0.3, 0.2, 0.9),
        );
        let h = FrameHeader::new(
            MessageKind::DepthFrame,
            1,
            0,
            &cam,
            &Workspace::default(),
            0,
        );
        let long = "é".repeat(200);
        let e = h.into_error(StatusCode::InvalidDepth, Stage::GridFusion, &long);
        assert_eq!(e.status(), StatusCode::InvalidDepth);
        assert!(!e.is_ok());
        let text = e.error_text();
        assert!(text.len() < ERROR_MESSAGE_LEN && text.chars().all(|c| c == 'é'));
        assert_eq!(Stage::from_u32(e.error_stage), Some(Stage::GridFusion));
    }
}
