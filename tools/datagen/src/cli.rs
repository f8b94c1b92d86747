//! The `psgrasp datagen` and `psgrasp inspect` commands (argument structs and run functions).
use crate::dataset::{
    read_scene, read_scene_meta, scene_file_name, write_scene, Manifest, ManifestScene,
    FORMAT_VERSION,
};
use crate::generate::{derive_seed, generate_record, Difficulty, GenerationConfig};
use crate::inspect::render_inspection;
use crate::labels::LabelConfig;
use crate::DatagenError;
use anyhow::Context;
use psgrasp_progress::{BatchProgress, ProgressOutput};
use psgrasp_sim::{MeshLibrary, ObjectLibrary, Split};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::mpsc;

/// Where the objects come from.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "kebab-case")]
pub enum ObjectSource {
    /// Procedural objects only (always available).
    Procedural,
    /// The 78 YCB meshes (needs `scripts/fetch_objects.sh`).
    Ycb,
    /// The 1000 pybullet random URDF meshes (needs `scripts/fetch_objects.sh`).
    RandomUrdf,
    /// Procedural objects plus every mesh set found.
    Mix,
    /// The scanned and generated meshes (YCB and random URDF; the default): a set that is
    /// missing is replaced by the procedural objects, with a warning, and the dataset records
    /// `meshes+procedural` or `procedural`.
    Meshes,
}

impl ObjectSource {
    /// The name used on the command line and in metadata.
    pub fn name(self) -> &'static str {
        match self {
            ObjectSource::Procedural => "procedural",
            ObjectSource::Ycb => "ycb",
            ObjectSource::RandomUrdf => "random-urdf",
            ObjectSource::Mix => "mix",
            ObjectSource::Meshes => "meshes",
        }
    }
}

/// Arguments of `psgrasp datagen`.
#[derive(Debug, Clone, clap::Args)]
pub struct DatagenArgs {
    /// Number of scenes in the dataset.
    #[arg(long, default_value_t = 100)]
    pub scenes: u64,
    /// Object source.
    #[arg(long, value_enum, default_value_t = ObjectSource::Meshes)]
    pub objects: ObjectSource,
    /// Scene difficulty (train uses training objects, the others test objects).
    #[arg(long, value_enum, default_value_t = Difficulty::Train)]
    pub difficulty: Difficulty,
    /// Output directory (created; a run into an existing directory resumes it).
    #[arg(long)]
    pub out: PathBuf,
    /// Run seed.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub jobs: Option<usize>,
    /// TOML file with a `GenerationConfig` (any field may be left out).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Reduced label sampling (about a tenth of the work) for previews and CI.
    #[arg(long)]
    pub quick: bool,
    /// Directory of the fetched meshes (default `~/.cache/psgrasp/objects`).
    #[arg(long)]
    pub mesh_dir: Option<PathBuf>,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
}

/// Arguments of `psgrasp inspect`.
#[derive(Debug, Clone, clap::Args)]
pub struct InspectArgs {
    /// A scene file written by `psgrasp datagen`.
    pub scene: PathBuf,
    /// Output PNG (default: the scene path with `.png`).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Most grasp configurations drawn.
    #[arg(long, default_value_t = 400)]
    pub max_grasps: usize,
    /// Draw on the clean depth instead of the network-input depth.
    #[arg(long)]
    pub clean: bool,
}

/// The default mesh directory (`$HOME/.cache/psgrasp/objects`).
pub fn default_mesh_dir() -> PathBuf {
    std::env::var_os("HOME")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("."))
        .join(".cache/psgrasp/objects")
}

/// The objects a run draws from.
pub struct ObjectPool {
    /// The objects with their split.
    pub library: ObjectLibrary,
    /// The meshes they reference.
    pub meshes: MeshLibrary,
    /// What was loaded: the source's name, or for [`ObjectSource::Meshes`] with a set missing
    /// `meshes+procedural` / `procedural`.
    pub source: String,
}

/// Builds the object library (and meshes) for a source.
pub fn build_library(source: ObjectSource, mesh_dir: &Path) -> Result<ObjectPool, DatagenError> {
    use psgrasp_sim::mesh::MeshSet;
    let mut library = ObjectLibrary::default();
    let mut meshes = MeshLibrary::default();
    if matches!(source, ObjectSource::Procedural | ObjectSource::Mix) {
        library.extend(ObjectLibrary::procedural());
    }
    let sets: &[MeshSet] = match source {
        ObjectSource::Procedural => &[],
        ObjectSource::Ycb => &[MeshSet::Ycb],
        ObjectSource::RandomUrdf => &[MeshSet::RandomUrdf],
        ObjectSource::Mix | ObjectSource::Meshes => &[MeshSet::Ycb, MeshSet::RandomUrdf],
    };
    let mut missing = 0;
    for set in sets {
        match psgrasp_sim::mesh::load_mesh_set(mesh_dir, *set, &mut meshes) {
            Ok(lib) => library.extend(lib),
            Err(e) if matches!(source, ObjectSource::Mix | ObjectSource::Meshes) => {
                eprintln!("warning: skipping {set:?} meshes: {e}");
                missing += 1;
            }
            Err(e) => return Err(e.into()),
        }
    }
    let mut name = source.name().to_string();
    if source == ObjectSource::Meshes && missing > 0 {
        library.extend(ObjectLibrary::procedural());
        name = if missing == sets.len() {
            "procedural".into()
        } else {
            "meshes+procedural".into()
        };
        eprintln!("warning: procedural objects stand in for the missing mesh set ({name}); run scripts/fetch_objects.sh");
    }
    Ok(ObjectPool {
        library,
        meshes,
        source: name,
    })
}

fn load_config(args: &DatagenArgs) -> anyhow::Result<GenerationConfig> {
    let mut config = match &args.config {
        Some(path) => {
            let text = std::fs::read_to_string(path)
                .with_context(|| format!("reading {}", path.display()))?;
            toml::from_str(&text).with_context(|| format!("parsing {}", path.display()))?
        }
        None => GenerationConfig::default(),
    };
    if args.quick {
        // Less sampling, the same poses: the lifts of the tool centre point stay.
        config.labels = LabelConfig {
            tcp_lifts_m: config.labels.tcp_lifts_m.clone(),
            ..LabelConfig::quick()
        };
    }
    config.labels.validate()?;
    Ok(config)
}

fn remove_stale_temp_files(dir: &Path) {
    if let Ok(entries) = std::fs::read_dir(dir) {
        for e in entries.flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            if name.starts_with('.') && name.contains(".tmp-") {
                let _ = std::fs::remove_file(e.path());
            }
        }
    }
}

fn manifest_entry(index: u64, meta: &crate::dataset::SceneMeta) -> ManifestScene {
    ManifestScene {
        index,
        file: scene_file_name(index),
        seed: meta.seed,
        objects: meta.scene.objects.len(),
        configurations: meta.label_stats.configurations,
        grasps: meta.label_stats.grasps,
        graspable_objects: meta.label_stats.graspable_objects,
        poses_checked: meta.label_stats.poses_checked,
        poses_free: meta.label_stats.poses_free,
        wall_zones: meta.wall_zones,
        physics_checked: meta.label_stats.physics_checked,
        physics_failed: meta.label_stats.physics_failed,
    }
}

/// "N objects, X (x %) within 20 mm of a side wall, Y (y %) in a corner".
pub fn describe_wall_zones(z: &psgrasp_sim::WallZones) -> String {
    let share = |n: usize| 100.0 * n as f64 / z.objects.max(1) as f64;
    format!(
        "{} objects, {} ({:.1} %) within {:.0} mm of a side wall, {} ({:.1} %) in a corner",
        z.objects,
        z.near_wall,
        share(z.near_wall),
        psgrasp_sim::NEAR_WALL_M * 1000.0,
        z.in_corner,
        share(z.in_corner)
    )
}

/// Runs `psgrasp datagen`: generates (or resumes) a dataset in `args.out`, scenes in parallel.
/// Scene `i` uses seed `derive_seed(seed, i)`, so the result does not depend on `--jobs`.
pub fn run_datagen(args: &DatagenArgs) -> anyhow::Result<()> {
    anyhow::ensure!(args.scenes > 0, "--scenes must be at least 1");
    let jobs = args.jobs.unwrap_or_else(|| {
        std::thread::available_parallelism()
            .map(|n| n.get())
            .unwrap_or(1)
    });
    anyhow::ensure!(jobs >= 1, "--jobs must be at least 1");
    let config = load_config(args)?;
    let mesh_dir = args.mesh_dir.clone().unwrap_or_else(default_mesh_dir);
    let pool = build_library(args.objects, &mesh_dir)?;
    let (library, meshes) = (&pool.library, &pool.meshes);
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    remove_stale_temp_files(&args.out);

    let names = |split: Split| -> Vec<String> {
        library
            .objects
            .iter()
            .filter(|o| o.split == split)
            .map(|o| o.spec.name.clone())
            .collect()
    };
    let mut manifest = Manifest {
        format: "psgrasp-dataset".into(),
        format_version: FORMAT_VERSION,
        generator: format!("psgrasp-datagen {}", env!("CARGO_PKG_VERSION")),
        run_seed: args.seed,
        scenes_requested: args.scenes,
        difficulty: args.difficulty,
        split: args.difficulty.split(),
        object_source: pool.source.clone(),
        config: config.clone(),
        train_objects: names(Split::Train),
        test_objects: names(Split::Test),
        scenes: Vec::new(),
    };
    if Manifest::path(&args.out).exists() {
        let old = Manifest::read(&args.out).context("reading the existing manifest")?;
        let same = old.run_seed == manifest.run_seed
            && old.difficulty == manifest.difficulty
            && old.object_source == manifest.object_source
            && old.config == manifest.config
            && old.format_version == manifest.format_version;
        if !same {
            return Err(DatagenError::ManifestMismatch {
                dir: args.out.clone(),
            }
            .into());
        }
        manifest.scenes_requested = manifest.scenes_requested.max(old.scenes_requested);
    }

    // Finished scenes are kept when their file parses and carries the expected seed.
    let mut todo = Vec::new();
    for i in 0..args.scenes {
        let path = args.out.join(scene_file_name(i));
        let seed = derive_seed(args.seed, i);
        match read_scene_meta(&path) {
            Ok(meta) if meta.seed == seed && meta.scene_index == i => {
                manifest.scenes.push(manifest_entry(i, &meta))
            }
            _ => todo.push(i),
        }
    }
    manifest.write(&args.out)?;

    let mut done = args.scenes - todo.len() as u64;
    let mut progress = BatchProgress::new(
        todo.len() as u64,
        "scene",
        ProgressOutput::for_stderr(args.quiet),
    );
    progress.start(&format!("{done}/{} scenes", args.scenes));
    let next = AtomicUsize::new(0);
    let stop = AtomicBool::new(false);
    let (tx, rx) = mpsc::channel::<Result<ManifestScene, (u64, DatagenError)>>();
    let source_name = pool.source.as_str();
    let mut first_error = None;
    std::thread::scope(|s| {
        for _ in 0..jobs.min(todo.len().max(1)) {
            let tx = tx.clone();
            let (todo, next, stop, config) = (&todo, &next, &stop, &config);
            let out = &args.out;
            let (run_seed, difficulty) = (args.seed, args.difficulty);
            s.spawn(move || loop {
                if stop.load(Ordering::Relaxed) {
                    break;
                }
                let k = next.fetch_add(1, Ordering::Relaxed);
                let Some(&i) = todo.get(k) else { break };
                let seed = derive_seed(run_seed, i);
                let result =
                    generate_record(i, seed, difficulty, source_name, library, meshes, config)
                        .and_then(|rec| {
                            write_scene(&out.join(scene_file_name(i)), &rec)
                                .map(|_| manifest_entry(i, &rec.meta))
                        })
                        .map_err(|e| (i, e));
                if tx.send(result).is_err() {
                    break;
                }
            });
        }
        drop(tx);
        for msg in rx {
            match msg {
                Ok(entry) => {
                    manifest.scenes.push(entry);
                    done += 1;
                    progress.advance(1, &format!("{done}/{} scenes", args.scenes));
                    if progress.ran().is_multiple_of(10) {
                        manifest.scenes.sort_by_key(|e| e.index);
                        if let Err(e) = manifest.write(&args.out) {
                            first_error.get_or_insert(anyhow::Error::from(e));
                            stop.store(true, Ordering::Relaxed);
                        }
                    }
                }
                Err((i, e)) => {
                    stop.store(true, Ordering::Relaxed);
                    first_error.get_or_insert(anyhow::Error::from(e).context(format!("scene {i}")));
                }
            }
        }
    });
    progress.finish();
    manifest.scenes.sort_by_key(|e| e.index);
    manifest.write(&args.out)?;
    let mut zones = psgrasp_sim::WallZones::default();
    for s in &manifest.scenes {
        zones += s.wall_zones;
    }
    println!(
        "{}: {} scenes; {}",
        args.out.display(),
        manifest.scenes.len(),
        describe_wall_zones(&zones)
    );
    let checked: usize = manifest.scenes.iter().map(|s| s.physics_checked).sum();
    if checked > 0 {
        let failed: usize = manifest.scenes.iter().map(|s| s.physics_failed).sum();
        let fate = match manifest.config.physics_check.failed_labels {
            crate::FailedLabels::Drop => "were dropped",
            crate::FailedLabels::ZeroQuality => "were kept with quality 0",
        };
        println!(
            "physics check of the labels: {failed} of {checked} grasps ({:.1} %) did not hold their object and {fate}",
            100.0 * failed as f64 / checked as f64
        );
    }
    if let Some(e) = first_error {
        return Err(e);
    }
    Ok(())
}

/// Runs `psgrasp inspect`: writes a PNG of the scene's depth image with its grasps drawn on it.
pub fn run_inspect(args: &InspectArgs) -> anyhow::Result<()> {
    let record =
        read_scene(&args.scene).with_context(|| format!("reading {}", args.scene.display()))?;
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| args.scene.with_extension("png"));
    let img = render_inspection(&record, args.max_grasps, !args.clean);
    img.write_png(&out)?;
    println!(
        "{}: {}; {} grasp configurations, {} collision-free grasps -> {}",
        args.scene.display(),
        describe_wall_zones(&record.meta.wall_zones),
        record.labels.len(),
        record.labels.iter().map(|l| l.free_count()).sum::<usize>(),
        out.display()
    );
    Ok(())
}
