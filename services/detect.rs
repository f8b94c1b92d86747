//! `psgrasp detect`: the perception chain once on one depth file, in this process — the same
//! steps the pipeline runs one per process ([`psgrasp_perception::Perception`]) — with the picks
//! as JSON and a picture of them drawn on the depth image.
use crate::grasp_selection::pick_records;
use crate::sources::{DepthSource, ReplaySource};
use anyhow::{Context, Result};
use psgrasp_config::{PipelineConfig, PoseConfig, SourceKind};
use psgrasp_geometry::{CameraModel, DepthImage, GripperModel, Workspace};
use psgrasp_ipc::PickRecord;
use psgrasp_perception::{DetectionTimings, Perception};
use psgrasp_picture::{draw_box, draw_gripper, ramp, Projector, RgbImage};
use std::path::{Path, PathBuf};

/// One file to detect grasps on.
#[derive(Debug, Clone)]
pub struct DetectInput {
    /// 16-bit PNG or `.npy` depth file.
    pub depth: PathBuf,
    /// Intrinsics JSON/TOML (`None`: the configuration's `camera.intrinsics`).
    pub intrinsics: Option<PathBuf>,
    /// The camera's pose in the workspace frame (`None`: the configuration's `camera.pose`, or
    /// the workspace placed on the dominant plane of the image).
    pub pose: Option<PoseConfig>,
    /// Metres per count of a 16-bit file (`None`: the intrinsics file's, else 1 mm).
    pub depth_unit_m: Option<f32>,
}

/// What one detection gave.
#[derive(Debug, Clone)]
pub struct DetectOutput {
    /// The depth frame as read.
    pub depth: DepthImage,
    /// The camera it was seen with.
    pub camera: CameraModel,
    /// The picks, best first, as the pipeline publishes them.
    pub picks: Vec<PickRecord>,
    /// Grasp configurations the backend proposed.
    pub configurations: usize,
    /// Why selection passed over the other configurations and approaches.
    pub rejected: psgrasp_selection::RejectionCounts,
    /// Time per step.
    pub timings: DetectionTimings,
}

/// Reads the frame as the replay source would and runs the chain of `cfg` on it.
pub fn detect_file(cfg: &PipelineConfig, input: &DetectInput) -> Result<DetectOutput> {
    let mut replay_cfg = cfg.clone();
    replay_cfg.camera.source = SourceKind::Replay;
    replay_cfg.camera.replay.path = input.depth.clone();
    replay_cfg.camera.replay.looping = false;
    if let Some(file) = &input.intrinsics {
        replay_cfg.camera.replay.intrinsics_file = file.clone();
    }
    if input.depth_unit_m.is_some() {
        replay_cfg.camera.replay.depth_unit_m = input.depth_unit_m;
    }
    if input.pose.is_some() {
        replay_cfg.camera.pose = input.pose;
    }
    let mut source = ReplaySource::new(&replay_cfg)?;
    let frame = source
        .next_frame()?
        .with_context(|| format!("no frame in {}", input.depth.display()))?;
    let mut chain = Perception::new(&cfg.cell).context("building the perception chain")?;
    let detection = chain
        .detect(&frame.depth, &frame.camera, cfg.pipeline.seed)
        .with_context(|| format!("detecting grasps in {}", input.depth.display()))?;
    let base = cfg
        .cell
        .robot_cell()?
        .base_frame(&frame.camera.workspace_from_camera);
    let picks = pick_records(
        &detection.selection,
        &detection.configurations,
        cfg.cell.selection.top_k,
        &base,
    );
    Ok(DetectOutput {
        depth: frame.depth,
        camera: frame.camera,
        picks,
        configurations: detection.configurations.len(),
        rejected: detection.selection.rejected,
        timings: detection.timings,
    })
}

/// Colour of the workspace outline in pictures.
const WORKSPACE_COLOUR: [u8; 3] = [60, 140, 255];

/// The depth image in grey with the workspace grid outlined in blue and every pick's gripper
/// outlined at its width, coloured by quality (red 0 → yellow ½ → green 1) and numbered by rank
/// from 1, worst drawn first so the best is on top.
pub fn draw_picks(
    depth: &DepthImage,
    camera: &CameraModel,
    workspace: &Workspace,
    gripper: &GripperModel,
    picks: &[PickRecord],
) -> RgbImage {
    let mut img = RgbImage::from_depth(depth);
    let projector = Projector::new(camera);
    let extent = workspace.extent();
    draw_box(
        &mut img,
        &projector,
        nalgebra::Point3::origin(),
        nalgebra::Point3::from(extent),
        WORKSPACE_COLOUR,
    );
    let scale = (depth.width / 320).max(1);
    for p in picks.iter().rev() {
        let colour = ramp(p.quality);
        draw_gripper(
            &mut img,
            &projector,
            gripper,
            &p.workspace_from_gripper(),
            p.width,
            colour,
        );
        if let Some((x, y)) = projector.pixel(&nalgebra::Point3::from(p.position)) {
            img.number(p.rank + 1, (x + 4.0, y + 4.0), scale, colour);
        }
    }
    img
}

/// `path` for frame `k` of `frames`: `path` itself for a single frame, else `<stem>-<k>.png`.
pub fn numbered_path(path: &Path, k: usize, frames: usize) -> PathBuf {
    if frames <= 1 {
        return path.to_path_buf();
    }
    let stem = path.file_stem().and_then(|s| s.to_str()).unwrap_or("picks");
    path.with_file_name(format!("{stem}-{k}.png"))
}
