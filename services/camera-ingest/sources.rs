//! Depth sources for camera-ingest: the built-in synthetic bin, file replay, an Intel RealSense
//! camera ([`RealSenseSource`]), and the [`DepthSource`] trait a camera driver implements.
//!
//! # Adding a real camera
//! Implement [`DepthSource`] for your driver (return frames in metres with the intrinsics and
//! the calibrated camera pose in the workspace frame), then construct it in
//! [`source_from_config`] under a new `camera.source` kind. Everything downstream is unchanged.
use anyhow::{bail, Context, Result};
use psgrasp_config::{PipelineConfig, SourceKind};
use psgrasp_geometry::{CameraIntrinsics, CameraModel, DepthImage, FrameSize, MAX_DEPTH_PIXELS};
use psgrasp_ipc::now_ns;
use serde::Deserialize;
use std::path::{Path, PathBuf};

#[path = "realsense.rs"]
mod realsense;
pub use realsense::RealSenseSource;

/// One frame from a source.
#[derive(Debug, Clone)]
pub struct SourceFrame {
    /// Depth in metres (0/NaN = no measurement).
    pub depth: DepthImage,
    /// Camera intrinsics and pose in the workspace frame for this frame.
    pub camera: CameraModel,
    /// Capture time (`CLOCK_REALTIME` ns).
    pub capture_ns: u64,
}

/// A stream of depth frames.
pub trait DepthSource: Send {
    /// Short name for logs.
    fn name(&self) -> &str;
    /// The next frame; `Ok(None)` at the end of a finite stream. A frame that cannot be read
    /// is an `Err`: camera-ingest turns it into an error record and continues.
    fn next_frame(&mut self) -> Result<Option<SourceFrame>>;
}

/// Builds the configured source.
pub fn source_from_config(cfg: &PipelineConfig) -> Result<Box<dyn DepthSource>> {
    match cfg.camera.source {
        SourceKind::Synthetic => Ok(Box::new(SyntheticSource::new(cfg))),
        SourceKind::Replay => Ok(Box::new(ReplaySource::new(cfg)?)),
        SourceKind::Realsense => Ok(Box::new(RealSenseSource::new(cfg)?)),
    }
}

/// Procedural bin scenes rendered by ray casting (needs no files).
pub struct SyntheticSource {
    cfg: PipelineConfig,
    camera: CameraModel,
    frame: u64,
    scene: Option<(u64, psgrasp_sim::Scene)>,
    /// Clean render of the current scene (re-rendered only when the scene changes).
    clean: Option<DepthImage>,
}

impl SyntheticSource {
    /// A source following `camera.synthetic`.
    pub fn new(cfg: &PipelineConfig) -> Self {
        Self {
            cfg: cfg.clone(),
            camera: cfg.camera_model(),
            frame: 0,
            scene: None,
            clean: None,
        }
    }

    /// Renders frame `k` (deterministic for the configured seed).
    pub fn render(&mut self, k: u64) -> Result<DepthImage> {
        let s = &self.cfg.camera.synthetic;
        let scene_seed = s.seed.wrapping_add(k / s.frames_per_scene);
        if self.scene.as_ref().map(|(seed, _)| *seed) != Some(scene_seed) {
            let scene = psgrasp_sim::procedural_scene(scene_seed, s.objects, &self.cfg.cell.bin)
                .with_context(|| format!("generating synthetic scene {scene_seed}"))?;
            self.clean = Some(scene.render_depth(&self.camera));
            self.scene = Some((scene_seed, scene));
        }
        let clean = self.clean.as_ref().expect("rendered with the scene");
        Ok(if s.noise {
            psgrasp_sim::add_dex_noise(
                clean,
                scene_seed ^ k.rotate_left(17),
                &psgrasp_sim::NoiseConfig::default(),
            )
        } else {
            clean.clone()
        })
    }
}

impl DepthSource for SyntheticSource {
    fn name(&self) -> &str {
        "synthetic"
    }

    fn next_frame(&mut self) -> Result<Option<SourceFrame>> {
        let k = self.frame;
        self.frame += 1;
        let depth = self.render(k)?;
        Ok(Some(SourceFrame {
            depth,
            camera: self.camera,
            capture_ns: now_ns(),
        }))
    }
}

/// Intrinsics file (JSON or TOML): `width, height, fx, fy, cx, cy` and optionally `depth_unit_m`.
#[derive(Debug, Clone, Deserialize)]
pub struct IntrinsicsFile {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Focal length x.
    pub fx: f32,
    /// Focal length y.
    pub fy: f32,
    /// Principal point x.
    pub cx: f32,
    /// Principal point y.
    pub cy: f32,
    /// Metres per depth count.
    pub depth_unit_m: Option<f32>,
}

/// The syntax of an intrinsics file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum IntrinsicsFormat {
    /// JSON (any file not ending in `.toml`).
    Json,
    /// TOML (`.toml`).
    Toml,
}

impl IntrinsicsFile {
    /// Reads and validates an intrinsics file (TOML if it ends in `.toml`, else JSON).
    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("reading intrinsics {}", path.display()))?;
        let format = if path.extension().is_some_and(|e| e == "toml") {
            IntrinsicsFormat::Toml
        } else {
            IntrinsicsFormat::Json
        };
        Self::parse(&text, format).with_context(|| format!("intrinsics {}", path.display()))
    }

    /// Parses and validates the text of an intrinsics file.
    pub fn parse(text: &str, format: IntrinsicsFormat) -> Result<Self> {
        let file: Self = match format {
            IntrinsicsFormat::Toml => toml::from_str(text).context("parsing")?,
            IntrinsicsFormat::Json => serde_json::from_str(text).context("parsing")?,
        };
        file.intrinsics().validate()?;
        if let Some(u) = file.depth_unit_m {
            anyhow::ensure!(u.is_finite() && u > 0.0, "depth_unit_m {u} must be > 0");
        }
        Ok(file)
    }

    /// As camera intrinsics.
    pub fn intrinsics(&self) -> CameraIntrinsics {
        CameraIntrinsics {
            width: self.width,
            height: self.height,
            fx: self.fx,
            fy: self.fy,
            cx: self.cx,
            cy: self.cy,
        }
    }
}

/// Where the camera of a recorded or real source is: the configured `camera.pose`, or, without
/// one, the workspace put on the dominant plane of the first frame, then kept.
pub struct CameraPlacement {
    intrinsics: CameraIntrinsics,
    pose: Option<nalgebra::Isometry3<f32>>,
    cfg: PipelineConfig,
}

impl CameraPlacement {
    /// The placement of a camera with `intrinsics` under `cfg`.
    pub fn new(intrinsics: CameraIntrinsics, cfg: &PipelineConfig) -> Self {
        Self {
            intrinsics,
            pose: cfg.camera.pose.map(|p| p.isometry()),
            cfg: cfg.clone(),
        }
    }

    /// The camera's intrinsics.
    pub fn intrinsics(&self) -> CameraIntrinsics {
        self.intrinsics
    }

    /// The camera model of a frame: the known pose, or the plane fit of this first frame.
    pub fn camera_for(&mut self, depth: &DepthImage) -> Result<CameraModel> {
        if let Some(pose) = self.pose {
            return Ok(CameraModel {
                intrinsics: self.intrinsics,
                workspace_from_camera: pose,
            });
        }
        // No calibrated pose: put the workspace on the dominant plane once, then keep it.
        let camera = fit_workspace_to_plane(depth, &self.intrinsics, &self.cfg)?;
        self.pose = Some(camera.workspace_from_camera);
        Ok(camera)
    }
}

/// Replays 16-bit PNG or `.npy` depth files from a file or a folder.
pub struct ReplaySource {
    files: Vec<PathBuf>,
    next: usize,
    looping: bool,
    unit_m: f32,
    placement: CameraPlacement,
}

impl ReplaySource {
    /// A source following `camera.replay`.
    pub fn new(cfg: &PipelineConfig) -> Result<Self> {
        let r = &cfg.camera.replay;
        let files = list_depth_files(&r.path)?;
        let (intrinsics, file_unit) = if r.intrinsics_file.as_os_str().is_empty() {
            (cfg.camera.intrinsics, None)
        } else {
            let f = IntrinsicsFile::load(&r.intrinsics_file)?;
            (f.intrinsics(), f.depth_unit_m)
        };
        let unit_m = file_unit.or(r.depth_unit_m).unwrap_or(0.001);
        Ok(Self {
            files,
            next: 0,
            looping: r.looping,
            unit_m,
            placement: CameraPlacement::new(intrinsics, cfg),
        })
    }
}

/// Places the workspace on the dominant plane (table or bin floor) seen in `depth`.
pub fn fit_workspace_to_plane(
    depth: &DepthImage,
    intrinsics: &CameraIntrinsics,
    cfg: &PipelineConfig,
) -> Result<CameraModel> {
    let plane = psgrasp_fusion::fit_support_plane(
        depth,
        intrinsics,
        &psgrasp_fusion::PlaneFitConfig::default(),
        0,
    )
    .context("fitting the support plane to place the workspace")?;
    // The plane (bin floor or table) goes where the configured bin floor is.
    let placement = psgrasp_fusion::PlacementConfig {
        plane_height_m: cfg.cell.bin.floor_center.z,
    };
    Ok(psgrasp_fusion::workspace_camera_from_plane(
        &plane,
        intrinsics,
        &cfg.cell.workspace,
        &placement,
    )?)
}

impl DepthSource for ReplaySource {
    fn name(&self) -> &str {
        "replay"
    }

    fn next_frame(&mut self) -> Result<Option<SourceFrame>> {
        if self.next >= self.files.len() {
            if !self.looping {
                return Ok(None);
            }
            self.next = 0;
        }
        let path = self.files[self.next].clone();
        self.next += 1;
        // Held to the intrinsics' size from the file header, before the pixels are decoded.
        let size = FrameSize::of(&self.placement.intrinsics());
        let depth = load_depth_file_sized(&path, self.unit_m, size)?;
        let camera = self.placement.camera_for(&depth)?;
        Ok(Some(SourceFrame {
            depth,
            camera,
            capture_ns: now_ns(),
        }))
    }
}

/// Depth files under `path` (a file, or a folder's `.png`/`.npy` files sorted by name).
pub fn list_depth_files(path: &Path) -> Result<Vec<PathBuf>> {
    let meta =
        std::fs::metadata(path).with_context(|| format!("replay path {}", path.display()))?;
    let mut files = if meta.is_dir() {
        std::fs::read_dir(path)?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|e| e == "png" || e == "npy"))
            .collect::<Vec<_>>()
    } else {
        vec![path.to_path_buf()]
    };
    files.sort();
    anyhow::ensure!(
        !files.is_empty(),
        "no .png or .npy depth files in {}",
        path.display()
    );
    Ok(files)
}

/// Loads a 16-bit PNG (counts × `unit_m`) or a 2-D `.npy` (`<u2` counts × `unit_m`, or `<f4`/`<f8`
/// metres) of any size within [`FrameSize::Bounded`].
pub fn load_depth_file(path: &Path, unit_m: f32) -> Result<DepthImage> {
    load_depth_file_sized(path, unit_m, FrameSize::Bounded)
}

/// [`load_depth_file`] for frames of `size` (the replay source passes its camera's): the file
/// header's width and height are checked before the pixels are read or decoded.
pub fn load_depth_file_sized(path: &Path, unit_m: f32, size: FrameSize) -> Result<DepthImage> {
    match path.extension().and_then(|e| e.to_str()) {
        Some("png") => psgrasp_fusion::load_depth_png_sized(path, unit_m, size)
            .with_context(|| format!("reading {}", path.display())),
        Some("npy") => load_depth_npy_sized(path, unit_m, size),
        _ => bail!(
            "{}: unsupported depth file (expected .png or .npy)",
            path.display()
        ),
    }
}

/// Longest `.npy` header read, bytes (numpy's own reader stops at 10 000 by default).
pub const MAX_NPY_HEADER_BYTES: usize = 65_536;

/// Minimal `.npy` reader for 2-D little-endian `u2`, `f4` or `f8` arrays in C order, of any
/// size within [`FrameSize::Bounded`].
pub fn load_depth_npy(path: &Path, unit_m: f32) -> Result<DepthImage> {
    load_depth_npy_sized(path, unit_m, FrameSize::Bounded)
}

/// [`load_depth_npy`] for frames of `size`; a file longer than any frame of that size can be is
/// refused before it is read.
pub fn load_depth_npy_sized(path: &Path, unit_m: f32, size: FrameSize) -> Result<DepthImage> {
    let context = || format!("reading {}", path.display());
    let len = std::fs::metadata(path).with_context(context)?.len();
    let max_pixels = match size {
        FrameSize::Bounded => MAX_DEPTH_PIXELS,
        FrameSize::Exactly { width, height } => u64::from(width) * u64::from(height),
    };
    // The largest file a frame of `size` makes: the longest header and 8 bytes a pixel (`<f8`).
    let max_len = (12 + MAX_NPY_HEADER_BYTES as u64) + 8 * max_pixels;
    anyhow::ensure!(
        len <= max_len,
        "{}: {len} bytes, more than any accepted depth frame's .npy ({max_len} bytes)",
        path.display()
    );
    let bytes = std::fs::read(path).with_context(context)?;
    decode_depth_npy(&bytes, unit_m, size).with_context(context)
}

/// The `.npy` reader of [`load_depth_npy_sized`] for a file already in memory: the header is
/// parsed and its shape checked against `size` (with checked arithmetic) before any pixel is
/// converted.
pub fn decode_depth_npy(bytes: &[u8], unit_m: f32, size: FrameSize) -> Result<DepthImage> {
    anyhow::ensure!(
        bytes.len() >= 10 && bytes.starts_with(b"\x93NUMPY"),
        "not a .npy file"
    );
    let (header_len, start) = match bytes[6] {
        1 => (usize::from(u16::from_le_bytes([bytes[8], bytes[9]])), 10),
        2 | 3 if bytes.len() >= 12 => (
            u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
            12,
        ),
        2 | 3 => bail!("truncated header"),
        v => bail!("unsupported .npy version {v}"),
    };
    anyhow::ensure!(
        header_len <= MAX_NPY_HEADER_BYTES,
        "header of {header_len} bytes (at most {MAX_NPY_HEADER_BYTES})"
    );
    let header = bytes
        .get(start..start + header_len)
        .context("truncated header")?;
    let header = std::str::from_utf8(header).context("header is not UTF-8")?;
    let header = NpyHeader::parse(header)?;
    anyhow::ensure!(
        !header.fortran_order,
        "Fortran-order arrays are not supported"
    );
    let [h, w] = header.shape[..] else {
        bail!(
            "expected a 2-D array (height, width), got shape {:?}",
            header.shape
        );
    };
    size.check(w, h)?;
    let item = match header.descr {
        "<u2" | "|u2" => 2,
        "<f4" => 4,
        "<f8" => 8,
        other => bail!("unsupported dtype {other} (use <u2, <f4 or <f8)"),
    };
    if item == 2 {
        anyhow::ensure!(
            unit_m.is_finite() && unit_m > 0.0,
            "depth unit must be a positive finite number of metres, got {unit_m}"
        );
    }
    // Within the size limit, so neither product can overflow.
    let n = (w * h) as usize;
    let data = &bytes[start + header_len..];
    anyhow::ensure!(
        data.len() >= n * item,
        "file is shorter than its shape says ({} data bytes, {h}×{w} of {} needs {})",
        data.len(),
        header.descr,
        n * item
    );
    let data = &data[..n * item];
    let values: Vec<f32> = match item {
        2 => data
            .chunks_exact(2)
            .map(|c| f32::from(u16::from_le_bytes([c[0], c[1]])) * unit_m)
            .collect(),
        4 => data
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect(),
        _ => data
            .chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().expect("8 bytes")) as f32)
            .collect(),
    };
    Ok(DepthImage::from_metres(w as u32, h as u32, values)?)
}

/// The fields of a `.npy` header (a Python dict literal) the reader needs.
#[derive(Debug, PartialEq)]
struct NpyHeader<'a> {
    descr: &'a str,
    fortran_order: bool,
    shape: Vec<u64>,
}

impl<'a> NpyHeader<'a> {
    fn parse(text: &'a str) -> Result<Self> {
        // The text after `'key':` (or `"key":`), leading spaces dropped.
        let value = |key: &str| -> Option<&'a str> {
            ["'", "\""].iter().find_map(|q| {
                let at = text.find(&format!("{q}{key}{q}"))? + key.len() + 2;
                text[at..]
                    .trim_start()
                    .strip_prefix(':')
                    .map(str::trim_start)
            })
        };
        let descr = value("descr")
            .and_then(|v| {
                let q = v.chars().next().filter(|c| *c == '\'' || *c == '"')?;
                v[1..].split(q).next()
            })
            .context("no descr")?;
        let fortran_order = match value("fortran_order") {
            Some(v) if v.starts_with("True") => true,
            Some(v) if v.starts_with("False") => false,
            _ => bail!("no fortran_order"),
        };
        let shape_txt = value("shape")
            .and_then(|v| v.strip_prefix('('))
            .and_then(|v| v.split(')').next())
            .context("no shape")?;
        let shape = shape_txt
            .split(',')
            .map(str::trim)
            .filter(|s| !s.is_empty())
            .map(|s| s.parse::<u64>())
            .collect::<Result<Vec<_>, _>>()
            .map_err(|_| anyhow::anyhow!("bad shape ({shape_txt})"))?;
        Ok(Self {
            descr,
            fortran_order,
            shape,
        })
    }
}

/// Writes a 2-D `<f4` `.npy` file (metres), e.g. to record synthetic frames for replay.
pub fn save_depth_npy(path: &Path, depth: &DepthImage) -> Result<()> {
    let mut header = format!(
        "{{'descr': '<f4', 'fortran_order': False, 'shape': ({}, {}), }}",
        depth.height, depth.width
    );
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut out = Vec::with_capacity(10 + header.len() + depth.data.len() * 4);
    out.extend_from_slice(b"\x93NUMPY\x01\x00");
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    for v in &depth.data {
        out.extend_from_slice(&v.to_le_bytes());
    }
    std::fs::write(path, out).with_context(|| format!("writing {}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn npy_round_trip_and_bad_files() {
        let dir = std::env::temp_dir().join(format!("psgrasp-npy-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let img = DepthImage::from_metres(3, 2, vec![0.5, 0.6, 0.0, f32::NAN, 1.0, 2.5]).unwrap();
        let p = dir.join("a.npy");
        save_depth_npy(&p, &img).unwrap();
        let back = load_depth_npy(&p, 0.001).unwrap();
        assert_eq!((back.width, back.height), (3, 2));
        assert_eq!(back.data[4], 1.0);
        assert!(back.data[3].is_nan());
        std::fs::write(dir.join("bad.npy"), b"hello").unwrap();
        let err = load_depth_npy(&dir.join("bad.npy"), 0.001).unwrap_err();
        assert!(
            format!("{err:#}").contains("bad.npy: not a .npy"),
            "{err:#}"
        );
        let mut truncated = std::fs::read(&p).unwrap();
        truncated.truncate(truncated.len() - 4);
        std::fs::write(dir.join("short.npy"), truncated).unwrap();
        assert!(load_depth_npy(&dir.join("short.npy"), 0.001).is_err());
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn replay_holds_frames_to_the_intrinsics_size_from_the_header() {
        let dir = std::env::temp_dir().join(format!("psgrasp-replay-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("frame.npy");
        save_depth_npy(&p, &DepthImage::from_metres(3, 2, vec![0.7; 6]).unwrap()).unwrap();
        let mut cfg = PipelineConfig::default();
        cfg.camera.source = SourceKind::Replay;
        cfg.camera.replay.path = p.clone();
        cfg.camera.pose = Some(psgrasp_config::PoseConfig {
            translation: [0.3, 0.3, 0.9],
            rotation_xyzw: [1.0, 0.0, 0.0, 0.0],
        });
        let mut source = ReplaySource::new(&cfg).unwrap();
        let err = source.next_frame().unwrap_err();
        assert!(
            format!("{err:#}").ends_with("depth frame is 3×2 but the camera is 640×480"),
            "{err:#}"
        );
        cfg.camera.intrinsics.width = 3;
        cfg.camera.intrinsics.height = 2;
        cfg.camera.intrinsics.cx = 1.0;
        cfg.camera.intrinsics.cy = 0.5;
        let frame = ReplaySource::new(&cfg)
            .unwrap()
            .next_frame()
            .unwrap()
            .unwrap();
        assert_eq!((frame.depth.width, frame.depth.height), (3, 2));
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn intrinsics_files_parse_as_json_and_toml() {
        let json = r#"{"width": 8, "height": 6, "fx": 7.0, "fy": 7.0, "cx": 3.5, "cy": 2.5}"#;
        let f = IntrinsicsFile::parse(json, IntrinsicsFormat::Json).unwrap();
        assert_eq!((f.width, f.height, f.depth_unit_m), (8, 6, None));
        let toml = "width = 8\nheight = 6\nfx = 7.0\nfy = 7.0\ncx = 3.5\ncy = 2.5\ndepth_unit_m = 0.0001\n";
        let f = IntrinsicsFile::parse(toml, IntrinsicsFormat::Toml).unwrap();
        assert_eq!(f.depth_unit_m, Some(0.0001));
        let err = IntrinsicsFile::parse(&json.replace("7.0,", "-7.0,"), IntrinsicsFormat::Json)
            .unwrap_err();
        assert!(
            format!("{err:#}").contains("focal lengths must be > 0"),
            "{err:#}"
        );
        let err = IntrinsicsFile::parse(json, IntrinsicsFormat::Toml).unwrap_err();
        assert!(format!("{err:#}").starts_with("parsing: "), "{err:#}");
    }
}
