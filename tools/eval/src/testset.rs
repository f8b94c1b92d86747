//! The fixed test set: the test scenes of every level generated once, stored with a manifest of
//! hashes, so that every detector and every later model meets exactly the same scenes
//! (`psgrasp testset` writes one, `psgrasp eval --test-set DIR` runs on it; the repository's is
//! `data/testset`, `docs/evaluation.md`).
//!
//! A test set directory holds `manifest.json` and one JSON-lines file per level (`easy.jsonl`,
//! one [`StoredScene`] per line: the settled scene as plain data). The manifest records how the
//! scenes were made (command, run seed, object source, the generation settings) and the sha256
//! of every level file and of every mesh the scenes use (the prepared triangles, so a changed
//! mesh file or a changed mesh preparation is caught). Scene `i` of a level is the scene that
//! `psgrasp eval --generate-scenes --seed S` would generate for the manifest's run seed `S` on the
//! build that wrote it; stored, it no longer depends on the physics engine's build.
use crate::protocol::{scene_seed, ProtocolConfig};
use crate::EvalError;
use psgrasp_datagen::cli::{build_library, ObjectPool};
use psgrasp_datagen::{derive_seed, Difficulty, GenerationConfig, ObjectSource};
use psgrasp_inference::learned::card::sha256_hex;
use psgrasp_sim::{generate_scene, MeshLibrary, Scene, SceneDescription, WallZones};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// `format` of a test set manifest.
pub const TESTSET_FORMAT: &str = "psgrasp-testset";
/// Version of the test set layout.
pub const TESTSET_VERSION: u32 = 1;
/// The repository's fixed test set, relative to the repository root.
pub const DEFAULT_TESTSET_DIR: &str = "data/testset";
/// The test levels a test set holds, in order.
pub const TEST_LEVELS: [Difficulty; 3] = [
    Difficulty::Easy,
    Difficulty::Medium,
    Difficulty::Challenging,
];

/// One stored test scene.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StoredScene {
    /// Index within its level.
    pub index: u64,
    /// Its scene seed ([`scene_seed`] of the run seed and the index).
    pub seed: u64,
    /// Where its objects lie relative to the side walls.
    pub wall_zones: WallZones,
    /// The settled scene.
    pub scene: SceneDescription,
}

/// A level file of the manifest.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LevelFile {
    /// File name in the test set directory.
    pub file: String,
    /// Scenes it holds.
    pub scenes: u64,
    /// sha256 of the file.
    pub sha256: String,
    /// Objects over all its scenes, and how many lie at a wall or in a corner.
    pub wall_zones: WallZones,
}

/// A mesh the scenes use.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MeshEntry {
    /// Its file under the mesh directory.
    pub file: String,
    /// sha256 of the prepared mesh ([`mesh_digest`]).
    pub sha256: String,
}

/// `manifest.json` of a test set.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TestSetManifest {
    /// [`TESTSET_FORMAT`].
    pub format: String,
    /// [`TESTSET_VERSION`].
    pub format_version: u32,
    /// The program that wrote it.
    pub generator: String,
    /// The command that wrote it.
    pub command: String,
    /// The run seed of its scenes.
    pub run_seed: u64,
    /// What the objects came from (`meshes`, or a fallback named by `psgrasp datagen`).
    pub object_source: String,
    /// Scene generation settings (object counts come from the levels).
    pub generation: GenerationConfig,
    /// Level files by level name.
    pub levels: BTreeMap<String, LevelFile>,
    /// Meshes by key.
    pub meshes: BTreeMap<String, MeshEntry>,
}

/// A test set, checked against its manifest and ready to run.
pub struct TestSet {
    /// Its directory.
    pub dir: PathBuf,
    /// Its manifest.
    pub manifest: TestSetManifest,
    /// sha256 of `manifest.json` (recorded in an evaluation's `run.json`).
    pub manifest_sha256: String,
    scenes: BTreeMap<Difficulty, Vec<StoredScene>>,
    /// The meshes its scenes use.
    pub meshes: MeshLibrary,
}

fn err(dir: &Path, reason: impl Into<String>) -> EvalError {
    EvalError::TestSet {
        dir: dir.to_path_buf(),
        reason: reason.into(),
    }
}

/// sha256 of a prepared mesh: its vertices (f32, little endian) then its triangles (u32).
pub fn mesh_digest(mesh: &psgrasp_sim::mesh::MeshAsset) -> String {
    let mut bytes = Vec::with_capacity(mesh.vertices.len() * 12 + mesh.triangles.len() * 12);
    for v in &mesh.vertices {
        for x in v {
            bytes.extend_from_slice(&x.to_le_bytes());
        }
    }
    for t in &mesh.triangles {
        for i in t {
            bytes.extend_from_slice(&i.to_le_bytes());
        }
    }
    sha256_hex(&bytes)
}

/// The mesh keys a scene uses.
fn mesh_keys(scene: &SceneDescription) -> impl Iterator<Item = &str> {
    scene.objects.iter().flat_map(|o| {
        o.spec.parts.iter().filter_map(|p| match &p.primitive {
            psgrasp_sim::Primitive::Mesh { key, .. } => Some(key.as_str()),
            _ => None,
        })
    })
}

fn level_name(level: Difficulty) -> &'static str {
    match level {
        Difficulty::Train => "train",
        Difficulty::Easy => "easy",
        Difficulty::Medium => "medium",
        Difficulty::Challenging => "challenging",
    }
}

/// Generates scene `index` of `level` for `run_seed`: the scene `psgrasp eval --generate-scenes`
/// runs.
pub fn generate_test_scene(
    level: Difficulty,
    run_seed: u64,
    index: u64,
    pool: &ObjectPool,
    gen: &GenerationConfig,
) -> Result<StoredScene, EvalError> {
    let seed = scene_seed(run_seed, index);
    let objects = pool
        .library
        .select(Some(level.split()), level.simple_only());
    let (scene, _) = generate_scene(
        derive_seed(seed, 1),
        &objects,
        &gen.cell.bin,
        &pool.meshes,
        &gen.scene_recipe(level),
    )?;
    Ok(StoredScene {
        index,
        seed,
        wall_zones: scene.wall_zones(),
        scene: scene.description().clone(),
    })
}

/// What [`write_test_set`] makes.
pub struct TestSetRequest<'a> {
    /// Output directory (created).
    pub out: &'a Path,
    /// Run seed of the scenes.
    pub run_seed: u64,
    /// Scenes per level.
    pub scenes: u64,
    /// The objects.
    pub pool: &'a ObjectPool,
    /// Scene generation settings.
    pub protocol: &'a ProtocolConfig,
    /// Worker threads.
    pub jobs: usize,
    /// The command line, recorded in the manifest.
    pub command: String,
}

/// Generates and writes a test set; returns its manifest.
pub fn write_test_set(req: &TestSetRequest<'_>) -> Result<TestSetManifest, EvalError> {
    use std::sync::atomic::{AtomicUsize, Ordering};
    let io = |path: &Path, e: std::io::Error| EvalError::Io {
        path: path.to_path_buf(),
        error: e,
    };
    std::fs::create_dir_all(req.out).map_err(|e| io(req.out, e))?;
    let gen = &req.protocol.scenes;
    let work: Vec<(Difficulty, u64)> = TEST_LEVELS
        .iter()
        .flat_map(|&l| (0..req.scenes).map(move |i| (l, i)))
        .collect();
    let next = AtomicUsize::new(0);
    let results: Vec<Result<(Difficulty, StoredScene), EvalError>> = std::thread::scope(|s| {
        let handles: Vec<_> = (0..req.jobs.max(1))
            .map(|_| {
                s.spawn(|| {
                    let mut out = Vec::new();
                    loop {
                        let k = next.fetch_add(1, Ordering::Relaxed);
                        let Some(&(level, i)) = work.get(k) else {
                            break;
                        };
                        out.push(
                            generate_test_scene(level, req.run_seed, i, req.pool, gen)
                                .map(|s| (level, s)),
                        );
                    }
                    out
                })
            })
            .collect();
        handles
            .into_iter()
            .flat_map(|h| h.join().unwrap_or_default())
            .collect()
    });
    let mut by_level: BTreeMap<Difficulty, Vec<StoredScene>> = BTreeMap::new();
    for r in results {
        let (level, scene) = r?;
        by_level.entry(level).or_default().push(scene);
    }
    let mut levels = BTreeMap::new();
    let mut meshes = BTreeMap::new();
    for (level, mut scenes) in by_level {
        scenes.sort_by_key(|s| s.index);
        let mut text = String::new();
        let mut zones = WallZones::default();
        for s in &scenes {
            text.push_str(&serde_json::to_string(s).map_err(|e| err(req.out, e.to_string()))?);
            text.push('\n');
            zones += s.wall_zones;
            for key in mesh_keys(&s.scene) {
                if meshes.contains_key(key) {
                    continue;
                }
                let mesh = req
                    .pool
                    .meshes
                    .get(key)
                    .ok_or_else(|| err(req.out, format!("mesh {key} is not loaded")))?;
                meshes.insert(
                    key.to_string(),
                    MeshEntry {
                        file: mesh.source_file.clone(),
                        sha256: mesh_digest(mesh),
                    },
                );
            }
        }
        let file = format!("{}.jsonl", level_name(level));
        let path = req.out.join(&file);
        std::fs::write(&path, &text).map_err(|e| io(&path, e))?;
        levels.insert(
            level_name(level).to_string(),
            LevelFile {
                file,
                scenes: scenes.len() as u64,
                sha256: sha256_hex(text.as_bytes()),
                wall_zones: zones,
            },
        );
    }
    let manifest = TestSetManifest {
        format: TESTSET_FORMAT.into(),
        format_version: TESTSET_VERSION,
        generator: format!("psgrasp-eval {}", env!("CARGO_PKG_VERSION")),
        command: req.command.clone(),
        run_seed: req.run_seed,
        object_source: req.pool.source.clone(),
        generation: gen.clone(),
        levels,
        meshes,
    };
    let path = req.out.join("manifest.json");
    let mut json =
        serde_json::to_string_pretty(&manifest).map_err(|e| err(req.out, e.to_string()))?;
    json.push('\n');
    std::fs::write(&path, json).map_err(|e| io(&path, e))?;
    Ok(manifest)
}

impl TestSet {
    /// Reads the test set in `dir` and checks it: format, every level file's sha256, and every
    /// mesh its scenes use (loaded from `mesh_dir`) against the manifest.
    pub fn open(dir: &Path, mesh_dir: &Path) -> Result<TestSet, EvalError> {
        let manifest_path = dir.join("manifest.json");
        let bytes = std::fs::read(&manifest_path).map_err(|e| {
            err(
                dir,
                format!(
                    "cannot read manifest.json ({e}); make a test set with `psgrasp testset` or run with --generate-scenes"
                ),
            )
        })?;
        let manifest: TestSetManifest =
            serde_json::from_slice(&bytes).map_err(|e| err(dir, format!("manifest.json: {e}")))?;
        if manifest.format != TESTSET_FORMAT || manifest.format_version != TESTSET_VERSION {
            return Err(err(
                dir,
                format!(
                    "manifest.json is {} v{}, expected {TESTSET_FORMAT} v{TESTSET_VERSION}",
                    manifest.format, manifest.format_version
                ),
            ));
        }
        let mut scenes = BTreeMap::new();
        for level in TEST_LEVELS {
            let Some(entry) = manifest.levels.get(level_name(level)) else {
                continue;
            };
            let path = dir.join(&entry.file);
            let text = std::fs::read_to_string(&path)
                .map_err(|e| err(dir, format!("{}: {e}", entry.file)))?;
            let digest = sha256_hex(text.as_bytes());
            if digest != entry.sha256 {
                return Err(err(
                    dir,
                    format!(
                        "{} has sha256 {digest}, the manifest says {}: the test scenes were changed",
                        entry.file, entry.sha256
                    ),
                ));
            }
            let mut list = Vec::new();
            for (n, line) in text.lines().enumerate() {
                let s: StoredScene = serde_json::from_str(line)
                    .map_err(|e| err(dir, format!("{} line {}: {e}", entry.file, n + 1)))?;
                if s.index != list.len() as u64 {
                    return Err(err(
                        dir,
                        format!("{} line {}: scene index {}", entry.file, n + 1, s.index),
                    ));
                }
                list.push(s);
            }
            if list.len() as u64 != entry.scenes {
                return Err(err(
                    dir,
                    format!(
                        "{} holds {} scenes, the manifest says {}",
                        entry.file,
                        list.len(),
                        entry.scenes
                    ),
                ));
            }
            scenes.insert(level, list);
        }
        let meshes = if manifest.meshes.is_empty() {
            MeshLibrary::default()
        } else {
            let pool = build_library(ObjectSource::Meshes, mesh_dir)
                .map_err(|e| err(dir, e.to_string()))?;
            for (key, entry) in &manifest.meshes {
                let mesh = pool.meshes.get(key).ok_or_else(|| {
                    err(
                        dir,
                        format!(
                            "mesh {key} ({}) is not under {}; run scripts/fetch_objects.sh",
                            entry.file,
                            mesh_dir.display()
                        ),
                    )
                })?;
                let digest = mesh_digest(mesh);
                if digest != entry.sha256 {
                    return Err(err(
                        dir,
                        format!(
                            "mesh {key} ({}) differs from the one the test set was made with (sha256 {digest}, manifest {}): its file or the mesh preparation changed",
                            entry.file, entry.sha256
                        ),
                    ));
                }
            }
            pool.meshes
        };
        Ok(TestSet {
            dir: dir.to_path_buf(),
            manifest_sha256: sha256_hex(&bytes),
            manifest,
            scenes,
            meshes,
        })
    }

    /// Scenes stored for `level` (0 if the set has none).
    pub fn scene_count(&self, level: Difficulty) -> u64 {
        self.scenes.get(&level).map_or(0, |v| v.len() as u64)
    }

    /// Stored scene `index` of `level`, built for queries.
    pub fn scene(&self, level: Difficulty, index: u64) -> Result<Scene, EvalError> {
        let stored = self
            .scenes
            .get(&level)
            .and_then(|v| v.get(index as usize))
            .ok_or_else(|| {
                err(
                    &self.dir,
                    format!(
                        "no scene {index} of level {}: the set holds {}",
                        level_name(level),
                        self.scene_count(level)
                    ),
                )
            })?;
        Ok(Scene::with_meshes(stored.scene.clone(), &self.meshes)?)
    }
}
