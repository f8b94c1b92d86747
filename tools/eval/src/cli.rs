//! The `psgrasp eval` command: argument struct and run function.
//!
//! ```text
//! psgrasp eval --detector analytic --level easy,medium,challenging --scenes 100 --seed 0 --out eval-out
//! ```
//!
//! Every (detector, level, seed, scene) is one job; jobs run in parallel on `--jobs` threads
//! (each with its own detector instances) in scene-major order, so an interrupted run has
//! comparable scene counts everywhere. Finished scenes are appended to `OUT/records.jsonl`; a
//! rerun with the same `--out` skips them. At the end `OUT/summary.md`, `OUT/summary.json` and
//! `OUT/summary.png` are written and the Markdown is printed.
use crate::detectors::{default_detectors, BuiltDetector, DetectorList, DetectorSpec};
use crate::protocol::{clear_scene, run_scene_with, scene_seed, ProtocolConfig};
use crate::testset::TestSet;
use psgrasp_datagen::cli::ObjectPool;

/// Where an evaluation's scenes come from.
enum SceneSource {
    /// Generated from the run seeds.
    Generated(ObjectPool),
    /// The fixed test set.
    Fixed(Box<TestSet>),
}
use crate::records::{write_atomic, RecordsFile, RunDescription, SceneKey};
use crate::report::summarize;
use crate::seed_copies::{self, SeedCopyPlan};
use crate::EvalError;
use anyhow::Context;
use psgrasp_datagen::cli::{build_library, default_mesh_dir};
use psgrasp_datagen::{Difficulty, ObjectSource};
use psgrasp_progress::{BatchProgress, ProgressOutput};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::mpsc;
use std::time::Instant;

/// Arguments of `psgrasp eval`.
#[derive(Debug, Clone, clap::Args)]
pub struct EvalArgs {
    /// Detectors to compare, by name, comma-separated (default: every detector in the list).
    #[arg(long = "detector", value_delimiter = ',')]
    pub detectors: Vec<String>,
    /// Detector list (TOML `[[detector]]` tables with `name`, `label`, `backend`). Default: the
    /// analytic baseline plus one learned or VGN detector per model directory under --models-dir.
    #[arg(long)]
    pub detectors_file: Option<PathBuf>,
    /// Where the default detector list looks for model directories (folders with `card.json`).
    #[arg(long, default_value = "models")]
    pub models_dir: PathBuf,
    /// Test levels, comma-separated.
    #[arg(long = "level", value_enum, value_delimiter = ',',
          default_values_t = [Difficulty::Easy, Difficulty::Medium, Difficulty::Challenging])]
    pub levels: Vec<Difficulty>,
    /// Scenes per level and seed (the paper: 100).
    #[arg(long, default_value_t = 100)]
    pub scenes: u64,
    /// Run seeds, comma-separated; scene i of seed S is the dataset's test scene of that level
    /// with seed `derive_seed(S, i)`. Several seeds give mean ± sd over seeds.
    #[arg(long = "seed", value_delimiter = ',', default_values_t = [0u64])]
    pub seeds: Vec<u64>,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub jobs: Option<usize>,
    /// Output directory (created; a run into an existing directory resumes it).
    #[arg(long, default_value = "eval-out")]
    pub out: PathBuf,
    /// TOML file with a `ProtocolConfig` (scene generation, selection, execution; any field may be
    /// left out).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// The fixed test set to run (`psgrasp testset` writes one; scene i of a level is its stored
    /// scene i, the seed seeds the depth noise and the detectors' sampling).
    #[arg(long, default_value = crate::testset::DEFAULT_TESTSET_DIR)]
    pub test_set: PathBuf,
    /// Generate the scenes from the seeds instead of taking the test set's (scene i of seed S
    /// is the dataset's test scene with seed `derive_seed(S, i)`), e.g. for tuning seeds.
    #[arg(long)]
    pub generate_scenes: bool,
    /// Object source of generated test scenes (--generate-scenes).
    #[arg(long, value_enum, default_value_t = ObjectSource::Meshes)]
    pub objects: ObjectSource,
    /// Directory of the fetched meshes (default `~/.cache/psgrasp/objects`).
    #[arg(long)]
    pub mesh_dir: Option<PathBuf>,
    /// Only rebuild the reports from the records already in --out.
    #[arg(long)]
    pub report_only: bool,
    /// No progress line.
    #[arg(long)]
    pub quiet: bool,
    /// Run every round, also those that play the same under every seed (a detector that samples
    /// nothing on the stored noise-free levels), instead of recording copies of them
    /// ([`crate::seed_copies`]).
    #[arg(long)]
    pub run_every_seed: bool,
}

/// Arguments of `psgrasp testset`.
#[derive(Debug, Clone, clap::Args)]
pub struct TestSetArgs {
    /// Output directory (the repository's test set is `data/testset`).
    #[arg(long)]
    pub out: PathBuf,
    /// Run seed of the scenes.
    #[arg(long, default_value_t = 2026)]
    pub seed: u64,
    /// Scenes per level (the paper: 100).
    #[arg(long, default_value_t = 100)]
    pub scenes: u64,
    /// TOML file with a `ProtocolConfig` whose `[scenes]` settings generate the scenes.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Object source.
    #[arg(long, value_enum, default_value_t = ObjectSource::Meshes)]
    pub objects: ObjectSource,
    /// Directory of the fetched meshes (default `~/.cache/psgrasp/objects`).
    #[arg(long)]
    pub mesh_dir: Option<PathBuf>,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub jobs: Option<usize>,
}

/// `psgrasp testset`: generates the fixed test scenes of every level and their manifest.
pub fn run_testset(args: &TestSetArgs) -> anyhow::Result<()> {
    anyhow::ensure!(args.scenes > 0, "--scenes must be at least 1");
    let protocol = load_protocol(args.config.as_deref())?;
    let mesh_dir = args.mesh_dir.clone().unwrap_or_else(default_mesh_dir);
    let pool = build_library(args.objects, &mesh_dir)?;
    let jobs = args.jobs.unwrap_or_else(|| {
        std::thread::available_parallelism()
            .map(|n| n.get())
            .unwrap_or(1)
    });
    let mut command = format!(
        "psgrasp testset --out {} --seed {} --scenes {} --objects {}",
        args.out.display(),
        args.seed,
        args.scenes,
        args.objects.name()
    );
    if let Some(c) = &args.config {
        command.push_str(&format!(" --config {}", c.display()));
    }
    let start = Instant::now();
    let manifest = crate::testset::write_test_set(&crate::testset::TestSetRequest {
        out: &args.out,
        run_seed: args.seed,
        scenes: args.scenes,
        pool: &pool,
        protocol: &protocol,
        jobs,
        command,
    })?;
    for (name, level) in &manifest.levels {
        let z = level.wall_zones;
        println!(
            "{name}: {} scenes, {} objects, {} within 20 mm of a side wall, {} in a corner",
            level.scenes, z.objects, z.near_wall, z.in_corner
        );
    }
    println!(
        "{}: {} meshes, objects {}, {:.0} s",
        args.out.display(),
        manifest.meshes.len(),
        manifest.object_source,
        start.elapsed().as_secs_f64()
    );
    Ok(())
}

fn load_protocol(path: Option<&Path>) -> anyhow::Result<ProtocolConfig> {
    let cfg = match path {
        Some(p) => {
            let text =
                std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
            toml::from_str(&text).with_context(|| format!("parsing {}", p.display()))?
        }
        None => ProtocolConfig::default(),
    };
    cfg.validate()?;
    Ok(cfg)
}

fn check_args(args: &EvalArgs) -> anyhow::Result<()> {
    anyhow::ensure!(args.scenes > 0, "--scenes must be at least 1");
    anyhow::ensure!(!args.seeds.is_empty(), "--seed needs at least one value");
    anyhow::ensure!(!args.levels.is_empty(), "--level needs at least one value");
    anyhow::ensure!(
        !args.levels.contains(&Difficulty::Train),
        "--level takes the test levels easy, medium and challenging"
    );
    anyhow::ensure!(args.jobs != Some(0), "--jobs must be at least 1");
    Ok(())
}

fn dedup<T: PartialEq + Clone>(v: &[T]) -> Vec<T> {
    let mut out: Vec<T> = Vec::new();
    for x in v {
        if !out.contains(x) {
            out.push(x.clone());
        }
    }
    out
}

/// The job's state behind the progress display: every round of the request, the ones this run
/// executes and their running rates.
struct Progress {
    display: BatchProgress,
    total: usize,
    done: usize,
    /// Rounds recorded as copies ([`crate::seed_copies`]).
    copied: usize,
    attempts: usize,
    successes: usize,
    objects: usize,
}

impl Progress {
    fn status(&self) -> String {
        let rate = |a: usize, b: usize| {
            if b > 0 {
                format!("{:.0}%", 100.0 * a as f64 / b as f64)
            } else {
                "-".into()
            }
        };
        format!(
            "{}/{} scenes ({} copied)  SR {} CR {}",
            self.done,
            self.total,
            self.copied,
            rate(self.successes, self.attempts),
            rate(self.successes, self.objects),
        )
    }
}

/// Runs `psgrasp eval` (see the module docs).
pub fn run_eval(args: &EvalArgs) -> anyhow::Result<()> {
    check_args(args)?;
    let protocol = load_protocol(args.config.as_deref())?;
    let list = match &args.detectors_file {
        Some(p) => DetectorList::read(p)?,
        None => default_detectors(&args.models_dir),
    };
    let detectors = list.pick(&dedup(&args.detectors))?;
    anyhow::ensure!(!detectors.is_empty(), "the detector list is empty");
    let levels = dedup(&args.levels);
    let seeds = dedup(&args.seeds);

    let scene_source = scene_source_name(args)?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let request = RunDescription::new(scene_source.clone(), &protocol, &detectors);
    let run = match RunDescription::read(&args.out)? {
        Some(mut stored) => {
            stored.merge(&request, &args.out)?;
            stored
        }
        None => request,
    };
    if !args.report_only {
        run.write(&args.out)?;
    }
    let mut records = RecordsFile::open(&args.out)?;
    if records.dropped() > 0 && !args.quiet {
        eprintln!(
            "resuming: dropped {} lines of unfinished scenes",
            records.dropped()
        );
    }

    if !args.report_only {
        run_jobs(args, &protocol, &detectors, &levels, &seeds, &mut records)?;
    }

    let names: Vec<(String, String)> = detectors
        .iter()
        .map(|d| (d.name.clone(), d.display_name().to_owned()))
        .collect();
    let summary = summarize(records.lines(), &names, &levels, &seeds, args.scenes);
    let mut md = format!(
        "# psgrasp eval: {} scenes per level and seed, seeds {:?}, scenes: {}\n\n",
        args.scenes, seeds, scene_source
    );
    md.push_str(&summary.markdown(&seeds));
    write_atomic(&args.out.join("summary.md"), md.as_bytes())?;
    let json = serde_json::to_vec_pretty(&summary).context("encoding the summary")?;
    write_atomic(&args.out.join("summary.json"), &json)?;
    summary
        .chart()
        .render()
        .write_png(&args.out.join("summary.png"))?;
    if let Some(chart) = crate::kappa::chart(&summary) {
        chart
            .render()
            .write_png(&args.out.join("summary-kappa.png"))?;
    }
    println!("{md}");
    if !args.quiet {
        eprintln!(
            "wrote {}/summary.md, summary.json, summary.png (and summary-kappa.png for detectors with κ)",
            args.out.display()
        );
    }
    Ok(())
}

/// What the scenes come from, as `run.json` records it: the test set and its manifest's sha256,
/// or the object source of generated scenes.
fn scene_source_name(args: &EvalArgs) -> anyhow::Result<String> {
    if args.generate_scenes {
        return Ok(format!("generated, objects {}", args.objects.name()));
    }
    let path = args.test_set.join("manifest.json");
    let bytes = std::fs::read(&path).with_context(|| {
        format!(
            "reading the test set's {} (make one with `psgrasp testset`, or run with --generate-scenes)",
            path.display()
        )
    })?;
    Ok(format!(
        "test set {} (manifest sha256 {})",
        args.test_set.display(),
        psgrasp_inference::learned::card::sha256_hex(&bytes)
    ))
}

fn run_jobs(
    args: &EvalArgs,
    protocol: &ProtocolConfig,
    detectors: &[DetectorSpec],
    levels: &[Difficulty],
    seeds: &[u64],
    records: &mut RecordsFile,
) -> anyhow::Result<()> {
    // Scene-major order: an interrupted run has about as many scenes in every cell.
    let mut todo = Vec::new();
    let mut total = 0;
    for scene in 0..args.scenes {
        for &seed in seeds {
            for &level in levels {
                for d in detectors {
                    let key = SceneKey {
                        detector: d.name.clone(),
                        level,
                        seed,
                        scene,
                    };
                    total += 1;
                    if !records.is_done(&key) {
                        todo.push(key);
                    }
                }
            }
        }
    }
    if todo.is_empty() {
        return Ok(());
    }
    // Fail fast on a detector that cannot be built (missing model, bad settings).
    let mut uses_seed = HashMap::new();
    for d in detectors {
        uses_seed.insert(d.name.clone(), d.build(protocol)?.uses_seed());
    }
    let stored_scenes = !args.generate_scenes;
    let plan = seed_copies::plan(todo, records, |key| {
        !args.run_every_seed
            && seed_copies::round_is_seed_independent(
                key.level,
                stored_scenes,
                uses_seed.get(&key.detector).copied().unwrap_or(true),
            )
    });
    for (source, copy) in &plan.copy_now {
        records.append_copy(source, copy)?;
    }
    // The copies just written count as done; the rounds to run and their copies do not.
    let left = plan.len() - plan.copy_now.len();
    let SeedCopyPlan {
        run: todo,
        copy_now,
        mut copy_after,
    } = plan;
    let mesh_dir = args.mesh_dir.clone().unwrap_or_else(default_mesh_dir);
    let source = if args.generate_scenes {
        SceneSource::Generated(build_library(args.objects, &mesh_dir)?)
    } else {
        let set = TestSet::open(&args.test_set, &mesh_dir)?;
        for &level in levels {
            anyhow::ensure!(
                set.scene_count(level) >= args.scenes,
                "the test set {} holds {} {level:?} scenes, fewer than --scenes {}",
                args.test_set.display(),
                set.scene_count(level),
                args.scenes
            );
        }
        SceneSource::Fixed(Box::new(set))
    };
    let jobs = args
        .jobs
        .unwrap_or_else(|| {
            std::thread::available_parallelism()
                .map(|n| n.get())
                .unwrap_or(1)
        })
        .min(todo.len())
        .max(1);

    let mut progress = Progress {
        display: BatchProgress::new(
            todo.len() as u64,
            "scene",
            ProgressOutput::for_stderr(args.quiet),
        ),
        total,
        done: total - left,
        copied: copy_now.len(),
        attempts: 0,
        successes: 0,
        objects: 0,
    };
    progress.display.start(&progress.status());
    let by_name: HashMap<&str, &DetectorSpec> =
        detectors.iter().map(|d| (d.name.as_str(), d)).collect();
    let next = AtomicUsize::new(0);
    let stop = AtomicBool::new(false);
    type Outcome = Result<(SceneKey, crate::protocol::SceneRun), (SceneKey, EvalError)>;
    let (tx, rx) = mpsc::channel::<Outcome>();
    let mut first_error: Option<anyhow::Error> = None;
    std::thread::scope(|s| {
        for _ in 0..jobs {
            let tx = tx.clone();
            let (todo, next, stop, by_name, source) = (&todo, &next, &stop, &by_name, &source);
            s.spawn(move || {
                // Each detector's backend and the protocol it runs under (its selection overrides).
                let mut backends: HashMap<String, (BuiltDetector, ProtocolConfig)> = HashMap::new();
                loop {
                    if stop.load(Ordering::Relaxed) {
                        break;
                    }
                    let k = next.fetch_add(1, Ordering::Relaxed);
                    let Some(key) = todo.get(k) else { break };
                    let result = (|| {
                        if !backends.contains_key(&key.detector) {
                            let spec = by_name.get(key.detector.as_str()).ok_or_else(|| {
                                EvalError::UnknownDetector {
                                    name: key.detector.clone(),
                                    known: by_name.keys().map(|k| k.to_string()).collect(),
                                }
                            })?;
                            backends.insert(
                                key.detector.clone(),
                                (spec.build(protocol)?, spec.protocol(protocol)),
                            );
                        }
                        let (backend, protocol) = backends
                            .get_mut(&key.detector)
                            .expect("inserted just above");
                        let protocol = &*protocol;
                        match source {
                            SceneSource::Generated(pool) => run_scene_with(
                                key.level,
                                key.seed,
                                key.scene,
                                &pool.library,
                                &pool.meshes,
                                backend.as_detector(),
                                protocol,
                            ),
                            SceneSource::Fixed(set) => {
                                let started = Instant::now();
                                clear_scene(
                                    key.level,
                                    scene_seed(key.seed, key.scene),
                                    set.scene(key.level, key.scene)?,
                                    &set.meshes,
                                    backend.as_detector(),
                                    protocol,
                                    started,
                                )
                            }
                        }
                    })();
                    let msg = result
                        .map(|r| (key.clone(), r))
                        .map_err(|e| (key.clone(), e));
                    if tx.send(msg).is_err() {
                        break;
                    }
                }
            });
        }
        drop(tx);
        for msg in rx {
            match msg {
                Ok((key, run)) => {
                    let copies = copy_after.remove(&key).unwrap_or_default();
                    let appended = records
                        .append_scene(&key, &run.attempts, &run.summary)
                        .and_then(|()| {
                            copies
                                .iter()
                                .try_for_each(|copy| records.append_copy(&key, copy))
                        });
                    if let Err(e) = appended {
                        stop.store(true, Ordering::Relaxed);
                        first_error.get_or_insert(e.into());
                        continue;
                    }
                    progress.done += 1 + copies.len();
                    progress.copied += copies.len();
                    progress.attempts += run.summary.attempts as usize;
                    progress.successes += run.summary.successes as usize;
                    progress.objects += run.summary.objects;
                    let status = progress.status();
                    progress.display.advance(1, &status);
                }
                Err((key, e)) => {
                    stop.store(true, Ordering::Relaxed);
                    first_error.get_or_insert(anyhow::Error::from(e).context(format!(
                        "detector {} level {:?} seed {} scene {}",
                        key.detector, key.level, key.seed, key.scene
                    )));
                }
            }
        }
    });
    progress.display.finish();
    match first_error {
        Some(e) => Err(e),
        None => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shipped_allow_contact_protocol_differs_from_the_default_only_in_execution() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../config/eval-protocol-allow-contact.toml");
        let cfg = load_protocol(Some(&path)).unwrap();
        assert!(cfg.execution.close_after_approach_contact);
        let mut back = cfg.clone();
        back.execution.close_after_approach_contact = false;
        assert_eq!(back, ProtocolConfig::default());
        assert!(load_protocol(Some(Path::new("/nonexistent/protocol.toml"))).is_err());
    }

    #[test]
    fn shipped_paper_protocol_adds_the_simulated_pregrasp_check_to_allow_contact() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config");
        let paper = load_protocol(Some(&dir.join("eval-protocol-paper.toml"))).unwrap();
        let allow_contact =
            load_protocol(Some(&dir.join("eval-protocol-allow-contact.toml"))).unwrap();
        assert!(paper.skip_colliding_pregrasps);
        assert!(!allow_contact.skip_colliding_pregrasps);
        let mut back = paper.clone();
        back.skip_colliding_pregrasps = false;
        assert_eq!(back, allow_contact);
        // The depth-scale variant adds the pipeline's correction in perception, nothing else.
        let corrected =
            load_protocol(Some(&dir.join("eval-protocol-paper-depth-scale.toml"))).unwrap();
        assert!(corrected.cell().depth_scale.enabled && !paper.cell().depth_scale.enabled);
        let mut back = corrected.clone();
        back.scenes.cell.depth_scale.enabled = false;
        assert_eq!(back, paper);
        // The wide-opening variant widens the commanded opening, nothing else.
        let wide = load_protocol(Some(&dir.join("eval-protocol-paper-wide-opening.toml"))).unwrap();
        assert_eq!(wide.cell().selection.clearance.opening_clearance_m, 0.04);
        assert!(
            corrected.cell().selection.clearance.opening_clearance_m
                < wide.cell().selection.clearance.opening_clearance_m
        );
        let mut back = wide.clone();
        back.scenes.cell.selection.clearance.opening_clearance_m =
            corrected.cell().selection.clearance.opening_clearance_m;
        assert_eq!(back, corrected);
        // The Franka-fingertip protocol (the new benchmark's) is the wide-opening one with the
        // oracle's labels physics-checked: both take the default hand, the real Franka hand. The
        // models trained for the 15 mm fingertip are refused under it (their card's approach
        // depth) and run under a protocol that names `franka-15mm`.
        let franka = load_protocol(Some(&dir.join("eval-protocol-franka-fingertip.toml"))).unwrap();
        assert_eq!(franka.cell().gripper.tip_beyond_tcp_m, 0.0095);
        assert_eq!(franka.oracle.physics_check_max_width_m, 0.2);
        assert_eq!(wide.oracle.physics_check_max_width_m, 0.0);
        let mut back = franka.clone();
        back.oracle = wide.oracle.clone();
        assert_eq!(back, wide);
        let shipped = crate::DetectorSpec::for_model_dir("default", dir.join("../models/default"));
        assert!(shipped.build(&franka).is_ok());
        let mut old_hand = franka.clone();
        old_hand.scenes.cell.gripper = psgrasp_geometry::grippers::named("franka-15mm").unwrap();
        assert!(shipped.build(&old_hand).is_err());
        // A model made for the 15 mm fingertip: the shipped graphs with a card recording that
        // hand's approach depth (the cards of the models trained before 2026-12-04).
        let old_dir = tempfile::tempdir().unwrap();
        for file in ["unet.onnx", "mlp.onnx"] {
            std::fs::copy(
                dir.join("../models/default").join(file),
                old_dir.path().join(file),
            )
            .unwrap();
        }
        let card = std::fs::read_to_string(dir.join("../models/default/card.json")).unwrap();
        let mut card: serde_json::Value = serde_json::from_str(&card).unwrap();
        card["gripper"]["approach_depth_m"] = old_hand.cell().gripper.tcp_to_palm_m().into();
        std::fs::write(old_dir.path().join("card.json"), card.to_string()).unwrap();
        let old = crate::DetectorSpec::for_model_dir("old", old_dir.path().to_path_buf());
        if let Err(error) = old.build(&old_hand) {
            panic!("a 15 mm model under franka-15mm: {error:#}");
        }
        let refused = old
            .build(&franka)
            .err()
            .expect("a 15 mm model under the 9.5 mm hand");
        assert!(
            format!("{refused:#}").contains("approach_depth"),
            "{refused:#}"
        );
    }
}
