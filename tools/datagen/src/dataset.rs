//! The on-disk dataset: one safetensors file per scene plus `manifest.json`.
//!
//! The exact layout is documented in `docs/dataset-format.md`. Files are written to a temporary
//! name in the same directory and renamed into place, so a reader never sees half a scene.
use crate::generate::Difficulty;
use crate::labels::{GraspLabel, LabelStats};
use crate::DatagenError;
use nalgebra::{Point3, Vector3};
use psgrasp_fusion::NormalGrid;
use psgrasp_geometry::{CameraModel, DepthImage, GripperModel, Workspace, N_APPROACHES};
use psgrasp_sim::{SceneDescription, SettleReport, Split};
use safetensors::tensor::{Dtype, TensorView};
use safetensors::SafeTensors;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::io::Write;
use std::path::{Path, PathBuf};

/// Version of the scene-file layout; bumped on any incompatible change.
pub const FORMAT_VERSION: u32 = 1;
/// Key of the JSON scene metadata in the safetensors header's `__metadata__` map.
pub const METADATA_KEY: &str = "psgrasp_scene";

/// JSON metadata stored in each scene file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SceneMeta {
    /// [`FORMAT_VERSION`] of the writer.
    pub format_version: u32,
    /// Name and version of the generator.
    pub generator: String,
    /// Index of the scene in its dataset.
    pub scene_index: u64,
    /// The scene seed (derived from the run seed and the index).
    pub seed: u64,
    /// Difficulty.
    pub difficulty: Difficulty,
    /// Object split used.
    pub split: Split,
    /// Object source (`procedural`, `ycb`, `random-urdf`, `mix`).
    pub object_source: String,
    /// True if `depth` carries dex noise (else it equals `depth_clean`).
    pub noise_applied: bool,
    /// Camera intrinsics and pose.
    pub camera: CameraModel,
    /// The voxel grid of `normals`, `tsdf` and `label_grid`.
    pub workspace: Workspace,
    /// The gripper the labels are for.
    pub gripper: GripperModel,
    /// Truncation distance of the TSDF (metres).
    pub truncation_m: f32,
    /// Bin and objects (exact geometry and poses).
    pub scene: SceneDescription,
    /// Physics summary.
    pub settle: SettleReport,
    /// Where the settled objects lie relative to the side walls.
    #[serde(default)]
    pub wall_zones: psgrasp_sim::WallZones,
    /// Label counters.
    pub label_stats: LabelStats,
}

/// Everything stored for one scene.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneRecord {
    /// Metadata.
    pub meta: SceneMeta,
    /// Clean rendered depth (metres, 0 = no hit).
    pub depth_clean: DepthImage,
    /// The depth the normal grid was fused from (noisy or clean, see `meta.noise_applied`).
    pub depth: DepthImage,
    /// Segmentation (0 nothing, 1 bin, 2 + i object i).
    pub segmentation: Vec<u16>,
    /// The normal grid (network input).
    pub grid: NormalGrid,
    /// The label grid (0 empty, 1 contact, 2 gripper space).
    pub label_grid: Vec<u8>,
    /// Grasp configurations.
    pub labels: Vec<GraspLabel>,
}

fn bytes_f32(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

fn bytes_u16(v: &[u16]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

fn bytes_u32(v: &[u32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

/// Encodes a record as safetensors bytes.
pub fn encode_scene(record: &SceneRecord) -> Result<Vec<u8>, DatagenError> {
    let (w, h) = (record.depth.width as usize, record.depth.height as usize);
    let [nx, ny, nz] = record.meta.workspace.dims.map(|d| d as usize);
    let g = record.labels.len();
    let mut contact = Vec::with_capacity(3 * g);
    let mut baseline = Vec::with_capacity(3 * g);
    let mut n1 = Vec::with_capacity(3 * g);
    let mut n2 = Vec::with_capacity(3 * g);
    let mut width = Vec::with_capacity(g);
    let mut quality = Vec::with_capacity(g);
    let mut free = Vec::with_capacity(N_APPROACHES * g);
    let mut object = Vec::with_capacity(g);
    for l in &record.labels {
        contact.extend_from_slice(l.contact.coords.as_slice());
        baseline.extend_from_slice(l.baseline.as_slice());
        n1.extend_from_slice(l.contact_normal.as_slice());
        n2.extend_from_slice(l.second_normal.as_slice());
        width.push(l.width);
        quality.push(l.quality);
        free.extend(l.collision_free.iter().map(|f| *f as u8));
        object.push(l.object);
    }
    let tensors: Vec<(&str, Dtype, Vec<usize>, Vec<u8>)> = vec![
        (
            "depth_clean",
            Dtype::F32,
            vec![h, w],
            bytes_f32(&record.depth_clean.data),
        ),
        (
            "depth",
            Dtype::F32,
            vec![h, w],
            bytes_f32(&record.depth.data),
        ),
        (
            "segmentation",
            Dtype::U16,
            vec![h, w],
            bytes_u16(&record.segmentation),
        ),
        (
            "normals",
            Dtype::F32,
            vec![3, nx, ny, nz],
            bytes_f32(&record.grid.normals),
        ),
        (
            "tsdf",
            Dtype::F32,
            vec![nx, ny, nz],
            bytes_f32(&record.grid.tsdf),
        ),
        (
            "label_grid",
            Dtype::U8,
            vec![nx, ny, nz],
            record.label_grid.clone(),
        ),
        ("grasp_contact", Dtype::F32, vec![g, 3], bytes_f32(&contact)),
        (
            "grasp_baseline",
            Dtype::F32,
            vec![g, 3],
            bytes_f32(&baseline),
        ),
        (
            "grasp_contact_normal",
            Dtype::F32,
            vec![g, 3],
            bytes_f32(&n1),
        ),
        (
            "grasp_second_normal",
            Dtype::F32,
            vec![g, 3],
            bytes_f32(&n2),
        ),
        ("grasp_width", Dtype::F32, vec![g], bytes_f32(&width)),
        ("grasp_quality", Dtype::F32, vec![g], bytes_f32(&quality)),
        (
            "grasp_collision_free",
            Dtype::U8,
            vec![g, N_APPROACHES],
            free,
        ),
        ("grasp_object", Dtype::U32, vec![g], bytes_u32(&object)),
    ];
    let mut views = Vec::with_capacity(tensors.len());
    for (name, dtype, shape, data) in &tensors {
        let view =
            TensorView::new(*dtype, shape.clone(), data).map_err(|e| DatagenError::Tensor {
                name: (*name).to_owned(),
                reason: e.to_string(),
            })?;
        views.push((*name, view));
    }
    let meta = serde_json::to_string(&record.meta)?;
    let info = HashMap::from([(METADATA_KEY.to_owned(), meta)]);
    safetensors::serialize(views, Some(info)).map_err(|e| DatagenError::Tensor {
        name: "*".into(),
        reason: e.to_string(),
    })
}

fn tensor<'a>(
    st: &'a SafeTensors<'a>,
    name: &str,
    dtype: Dtype,
    shape: &[usize],
) -> Result<&'a [u8], DatagenError> {
    let bad = |reason: String| DatagenError::Tensor {
        name: name.to_owned(),
        reason,
    };
    let t = st.tensor(name).map_err(|e| bad(e.to_string()))?;
    if t.dtype() != dtype || t.shape() != shape {
        return Err(bad(format!(
            "expected {dtype:?} {shape:?}, found {:?} {:?}",
            t.dtype(),
            t.shape()
        )));
    }
    // The borrow of `t` ends here; re-borrow the data with the file's lifetime.
    let data = t.data();
    Ok(data)
}

fn f32s(b: &[u8]) -> Vec<f32> {
    b.chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}

/// Decodes safetensors bytes written by [`encode_scene`], checking every shape and dtype.
pub fn decode_scene(bytes: &[u8]) -> Result<SceneRecord, DatagenError> {
    let st = SafeTensors::deserialize(bytes).map_err(|e| DatagenError::Tensor {
        name: "*".into(),
        reason: e.to_string(),
    })?;
    let (_, header) = SafeTensors::read_metadata(bytes).map_err(|e| DatagenError::Tensor {
        name: "*".into(),
        reason: e.to_string(),
    })?;
    let meta_json = header
        .metadata()
        .as_ref()
        .and_then(|m| m.get(METADATA_KEY))
        .ok_or(DatagenError::MissingMetadata)?;
    let meta: SceneMeta = serde_json::from_str(meta_json)?;
    if meta.format_version != FORMAT_VERSION {
        return Err(DatagenError::FormatVersion {
            found: meta.format_version,
            expected: FORMAT_VERSION,
        });
    }
    let k = meta.camera.intrinsics;
    let (w, h) = (k.width as usize, k.height as usize);
    let [nx, ny, nz] = meta.workspace.dims.map(|d| d as usize);
    let g = st
        .tensor("grasp_width")
        .map(|t| t.shape().first().copied().unwrap_or(0))
        .unwrap_or(0);
    let depth_clean = f32s(tensor(&st, "depth_clean", Dtype::F32, &[h, w])?);
    let depth = f32s(tensor(&st, "depth", Dtype::F32, &[h, w])?);
    let segmentation = tensor(&st, "segmentation", Dtype::U16, &[h, w])?
        .chunks_exact(2)
        .map(|c| u16::from_le_bytes([c[0], c[1]]))
        .collect();
    let normals = f32s(tensor(&st, "normals", Dtype::F32, &[3, nx, ny, nz])?);
    let tsdf = f32s(tensor(&st, "tsdf", Dtype::F32, &[nx, ny, nz])?);
    let label_grid = tensor(&st, "label_grid", Dtype::U8, &[nx, ny, nz])?.to_vec();
    let contact = f32s(tensor(&st, "grasp_contact", Dtype::F32, &[g, 3])?);
    let baseline = f32s(tensor(&st, "grasp_baseline", Dtype::F32, &[g, 3])?);
    let n1 = f32s(tensor(&st, "grasp_contact_normal", Dtype::F32, &[g, 3])?);
    let n2 = f32s(tensor(&st, "grasp_second_normal", Dtype::F32, &[g, 3])?);
    let width = f32s(tensor(&st, "grasp_width", Dtype::F32, &[g])?);
    let quality = f32s(tensor(&st, "grasp_quality", Dtype::F32, &[g])?);
    let free = tensor(&st, "grasp_collision_free", Dtype::U8, &[g, N_APPROACHES])?;
    let object: Vec<u32> = tensor(&st, "grasp_object", Dtype::U32, &[g])?
        .chunks_exact(4)
        .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    let v3 = |v: &[f32], i: usize| Vector3::new(v[3 * i], v[3 * i + 1], v[3 * i + 2]);
    let labels = (0..g)
        .map(|i| GraspLabel {
            contact: Point3::from(v3(&contact, i)),
            baseline: v3(&baseline, i),
            contact_normal: v3(&n1, i),
            second_normal: v3(&n2, i),
            width: width[i],
            quality: quality[i],
            collision_free: std::array::from_fn(|a| free[i * N_APPROACHES + a] != 0),
            object: object[i],
        })
        .collect();
    let grid = NormalGrid {
        workspace: meta.workspace,
        normals,
        tsdf,
        truncation_m: meta.truncation_m,
    };
    Ok(SceneRecord {
        depth_clean: DepthImage {
            width: k.width,
            height: k.height,
            data: depth_clean,
        },
        depth: DepthImage {
            width: k.width,
            height: k.height,
            data: depth,
        },
        segmentation,
        grid,
        label_grid,
        labels,
        meta,
    })
}

/// Writes `bytes` to `path` atomically: a temporary file in the same directory, fsync, rename.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), DatagenError> {
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tmp = dir.join(format!(".{name}.tmp-{}", std::process::id()));
    let io = |error: std::io::Error, p: &Path| DatagenError::Io {
        path: p.to_path_buf(),
        error,
    };
    {
        let mut f = std::fs::File::create(&tmp).map_err(|e| io(e, &tmp))?;
        f.write_all(bytes).map_err(|e| io(e, &tmp))?;
        f.sync_all().map_err(|e| io(e, &tmp))?;
    }
    std::fs::rename(&tmp, path).map_err(|e| io(e, path))
}

/// Writes a scene file atomically.
pub fn write_scene(path: &Path, record: &SceneRecord) -> Result<(), DatagenError> {
    write_atomic(path, &encode_scene(record)?)
}

/// Reads and validates a scene file.
pub fn read_scene(path: &Path) -> Result<SceneRecord, DatagenError> {
    let bytes = std::fs::read(path).map_err(|error| DatagenError::Io {
        path: path.to_path_buf(),
        error,
    })?;
    decode_scene(&bytes)
}

/// Reads only the metadata of a scene file (cheap validity check for resuming).
pub fn read_scene_meta(path: &Path) -> Result<SceneMeta, DatagenError> {
    let bytes = std::fs::read(path).map_err(|error| DatagenError::Io {
        path: path.to_path_buf(),
        error,
    })?;
    SafeTensors::deserialize(&bytes).map_err(|e| DatagenError::Tensor {
        name: "*".into(),
        reason: e.to_string(),
    })?;
    let (_, header) = SafeTensors::read_metadata(&bytes).map_err(|e| DatagenError::Tensor {
        name: "*".into(),
        reason: e.to_string(),
    })?;
    let json = header
        .metadata()
        .as_ref()
        .and_then(|m| m.get(METADATA_KEY))
        .ok_or(DatagenError::MissingMetadata)?;
    let meta: SceneMeta = serde_json::from_str(json)?;
    if meta.format_version != FORMAT_VERSION {
        return Err(DatagenError::FormatVersion {
            found: meta.format_version,
            expected: FORMAT_VERSION,
        });
    }
    Ok(meta)
}

/// File name of scene `index`.
pub fn scene_file_name(index: u64) -> String {
    format!("scene_{index:06}.safetensors")
}

/// One scene's entry in the manifest.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ManifestScene {
    /// Scene index.
    pub index: u64,
    /// File name relative to the dataset directory.
    pub file: String,
    /// Scene seed.
    pub seed: u64,
    /// Objects in the settled scene.
    pub objects: usize,
    /// Stored grasp configurations.
    pub configurations: usize,
    /// Stored collision-free grasps.
    pub grasps: usize,
    /// Objects with at least one grasp.
    pub graspable_objects: usize,
    /// Gripper poses tested.
    pub poses_checked: usize,
    /// Gripper poses found collision-free.
    pub poses_free: usize,
    /// Where the settled objects lie relative to the side walls.
    #[serde(default)]
    pub wall_zones: psgrasp_sim::WallZones,
    /// Physical grasps run through the labels' physics check (absent when it is off).
    #[serde(default, skip_serializing_if = "crate::labels::is_zero")]
    pub physics_checked: usize,
    /// Of those, the ones that did not hold their object.
    #[serde(default, skip_serializing_if = "crate::labels::is_zero")]
    pub physics_failed: usize,
}

/// The dataset manifest (`manifest.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    /// Always `"psgrasp-dataset"`.
    pub format: String,
    /// [`FORMAT_VERSION`].
    pub format_version: u32,
    /// Generator name and version.
    pub generator: String,
    /// The run seed; scene `i` uses `derive_seed(run_seed, i)`.
    pub run_seed: u64,
    /// Number of scenes requested.
    pub scenes_requested: u64,
    /// Difficulty.
    pub difficulty: Difficulty,
    /// Split of the objects used.
    pub split: Split,
    /// Object source.
    pub object_source: String,
    /// The full generation configuration.
    pub config: crate::generate::GenerationConfig,
    /// Names of the training objects of the library used.
    pub train_objects: Vec<String>,
    /// Names of the test objects of the library used.
    pub test_objects: Vec<String>,
    /// Finished scenes, by index.
    pub scenes: Vec<ManifestScene>,
}

impl Manifest {
    /// Path of the manifest in `dir`.
    pub fn path(dir: &Path) -> PathBuf {
        dir.join("manifest.json")
    }

    /// Reads a manifest.
    pub fn read(dir: &Path) -> Result<Manifest, DatagenError> {
        let path = Self::path(dir);
        let text =
            std::fs::read_to_string(&path).map_err(|error| DatagenError::Io { path, error })?;
        Ok(serde_json::from_str(&text)?)
    }

    /// Writes the manifest atomically.
    pub fn write(&self, dir: &Path) -> Result<(), DatagenError> {
        let text = serde_json::to_string_pretty(self)?;
        write_atomic(&Self::path(dir), text.as_bytes())
    }
}
