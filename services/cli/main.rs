//! `psgrasp`: the one entry point for people — run the pipeline, the demo, the stress test.
use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use psgrasp::launcher::{default_bin_dir, Supervisor};
use psgrasp::{run, stress};
use psgrasp_config::PipelineConfig;
use psgrasp_ipc::{NextPickMode, NextPickStatus, PipelineNode, StatusCode};
use std::path::PathBuf;
use std::time::Duration;

#[derive(Parser)]
#[command(
    name = "psgrasp",
    version,
    about = "Dense 6-DoF grasp detection for bin picking"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Start all stages as separate processes and supervise them until Ctrl-C.
    Up {
        /// Pipeline configuration.
        #[arg(long, default_value = "config/default.toml")]
        config: PathBuf,
    },
    /// Run the built-in synthetic bin scene end to end and print the top grasps.
    Demo {
        /// Pipeline configuration (its camera section is replaced by the synthetic demo scene).
        #[arg(long, default_value = "config/default.toml")]
        config: PathBuf,
        /// Frames to run.
        #[arg(long, default_value_t = 2)]
        frames: u64,
        /// Scene seed.
        #[arg(long, default_value_t = 7)]
        seed: u64,
        /// Grasps to print per frame.
        #[arg(long, default_value_t = 5)]
        top: usize,
        /// Also write each frame's depth image with its picks drawn (one frame: this file; more:
        /// `<stem>-<k>.png`).
        #[arg(long, value_name = "PNG")]
        png: Option<PathBuf>,
    },
    /// Detect grasps on one depth file in this process (the pipeline's perception chain), print
    /// the picks, and write them as JSON and as a picture.
    Detect {
        /// 16-bit PNG (counts × depth unit) or `.npy` depth file.
        depth: PathBuf,
        /// Intrinsics JSON/TOML (`width, height, fx, fy, cx, cy[, depth_unit_m]`); default: the
        /// configuration's `camera.intrinsics`.
        #[arg(long)]
        intrinsics: Option<PathBuf>,
        /// The camera's pose in the workspace frame as `tx,ty,tz,qx,qy,qz,qw` (metres, unit
        /// quaternion); default: the configuration's `camera.pose`, else the workspace is put on
        /// the dominant plane of the image.
        #[arg(long, value_parser = parse_pose, allow_hyphen_values = true)]
        pose: Option<psgrasp_config::PoseConfig>,
        /// Metres per count of a 16-bit depth file (default: the intrinsics file's, else 0.001).
        #[arg(long)]
        depth_unit: Option<f32>,
        /// Pipeline configuration (the cell, backend, selection and `[robot]`).
        #[arg(long, default_value = "config/default.toml")]
        config: PathBuf,
        /// Write the picks as JSON here.
        #[arg(long, value_name = "FILE")]
        json: Option<PathBuf>,
        /// Write the depth image with the picks drawn here (PNG).
        #[arg(long, value_name = "FILE")]
        png: Option<PathBuf>,
    },
    /// Push frames through the live pipeline; print throughput, latency percentiles, drops and
    /// errors, and compare the shared-memory transport with a Unix socket.
    Stress {
        /// Pipeline configuration.
        #[arg(long, default_value = "config/default.toml")]
        config: PathBuf,
        /// Frames to push.
        #[arg(long, default_value_t = 50)]
        frames: u64,
        /// Camera rate in Hz (0 = as fast as possible).
        #[arg(long, default_value_t = 0.0)]
        rate: f64,
        /// Inference workers (overrides the config).
        #[arg(long)]
        inference_workers: Option<u32>,
        /// Messages per payload size in the transport comparison (0 = skip it).
        #[arg(long, default_value_t = 300)]
        transport_iterations: usize,
        /// Chaos drill: SIGKILL one stage every SECS seconds, rotating over the four stages,
        /// while the camera runs until `--frames` frames entered; reports outcomes by status,
        /// unaccounted frames, restarts and recovery times.
        #[arg(long, value_name = "SECS")]
        chaos: Option<f64>,
        /// Seed of the chaos drill's worker choice.
        #[arg(long, default_value_t = 0)]
        chaos_seed: u64,
        /// Longest run in seconds (a chaos drill then stops killing and winds down).
        #[arg(long, default_value_t = 600)]
        timeout: u64,
    },
    /// Validate a configuration file, load what every stage loads at start (depth source, model
    /// files, /dev/shm space), and print it with all defaults filled in.
    CheckConfig {
        /// Pipeline configuration.
        #[arg(default_value = "config/default.toml")]
        config: PathBuf,
    },
    /// Serve the HTTP/JSON endpoint (`[http]`, also when `enabled = false`) for a pipeline
    /// that runs already (`psgrasp up` serves it itself when `[http] enabled = true`).
    Http {
        /// Pipeline configuration (its name, channel settings and `[http]`).
        #[arg(long, default_value = "config/default.toml")]
        config: PathBuf,
        /// Port (overrides `[http] port`; 0: one the system picks).
        #[arg(long)]
        port: Option<u16>,
    },
    /// Ask a running pipeline for the next pick (as a cell controller would).
    NextPick {
        /// Pipeline configuration.
        #[arg(long, default_value = "config/default.toml")]
        config: PathBuf,
        /// The previous pick failed: hand out the next one.
        #[arg(long, conflicts_with = "picked")]
        failed: bool,
        /// The previous pick succeeded: the scene changed, so wait for a newer frame's best
        /// pick.
        #[arg(long)]
        picked: bool,
        /// How long to wait for an answer (also for a restarting grasp-selection), seconds.
        #[arg(long, default_value_t = 5.0)]
        wait: f64,
    },
    /// Generate synthetic bin scenes with dense grasp labels (a training or test dataset).
    Datagen(psgrasp_datagen::DatagenArgs),
    /// Draw a generated scene's labelled grasps on its depth image (PNG).
    Inspect(psgrasp_datagen::InspectArgs),
    /// Generate the fixed test scenes of every level once, with a manifest of hashes
    /// (`psgrasp eval --test-set DIR` runs on them; the repository's is data/testset).
    Testset(psgrasp_eval::cli::TestSetArgs),
    /// Simulated clutter clearing: run detectors on the test scenes, report SR/CR per level.
    Eval(psgrasp_eval::EvalArgs),
}

/// Exit status of a command whose stdout was closed under it (`psgrasp check-config | head`):
/// 128 + SIGPIPE, what the shell reports for a tool the signal ended.
const BROKEN_PIPE_EXIT: u8 = 128 + libc::SIGPIPE as u8;

/// True for the panic of `println!` on a closed stdout. (Rust ignores SIGPIPE, so the write fails
/// with EPIPE; restoring the signal instead would end `psgrasp up` without stopping its stages.)
fn is_broken_stdout(message: Option<&str>) -> bool {
    let broken = std::io::Error::from_raw_os_error(libc::EPIPE);
    message == Some(format!("failed printing to stdout: {broken}").as_str())
}

fn main() -> std::process::ExitCode {
    psgrasp::stage::init_logging();
    // A closed stdout ends the command quietly, after unwinding has run the destructors (a
    // supervisor stops its stages) — like any Unix tool, without a panic message.
    let report = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        if !is_broken_stdout(info.payload_as_str()) {
            report(info);
        }
    }));
    match std::panic::catch_unwind(|| run(Cli::parse())) {
        Ok(Ok(())) => std::process::ExitCode::SUCCESS,
        Ok(Err(e)) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
        Err(payload) => {
            let message = payload
                .downcast_ref::<String>()
                .map(String::as_str)
                .or_else(|| payload.downcast_ref::<&str>().copied());
            if is_broken_stdout(message) {
                std::process::ExitCode::from(BROKEN_PIPE_EXIT)
            } else {
                std::panic::resume_unwind(payload)
            }
        }
    }
}

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Up { config } => up(config),
        Command::Demo {
            config,
            frames,
            seed,
            top,
            png,
        } => demo(config, frames, seed, top, png),
        Command::Detect {
            depth,
            intrinsics,
            pose,
            depth_unit,
            config,
            json,
            png,
        } => {
            let input = psgrasp::detect::DetectInput {
                depth,
                intrinsics,
                pose,
                depth_unit_m: depth_unit,
            };
            detect(&config, &input, json, png)
        }
        Command::Stress {
            config,
            frames,
            rate,
            inference_workers,
            transport_iterations,
            chaos,
            chaos_seed,
            timeout,
        } => {
            let mut cfg = PipelineConfig::load(&config)?;
            cfg.pipeline.name = format!("stress-{}", std::process::id());
            // A drill's camera runs until stopped: a restarted camera-ingest would count anew.
            cfg.camera.frames = if chaos.is_some() { 0 } else { frames };
            cfg.camera.rate_hz = rate;
            cfg.camera.synthetic.frames_per_scene = frames.max(1);
            let chaos = match chaos {
                Some(secs) if !(secs.is_finite() && secs >= 0.5) => {
                    anyhow::bail!("--chaos {secs}: the time between kills must be at least 0.5 s")
                }
                Some(secs) => Some(run::ChaosPlan {
                    every: Duration::from_secs_f64(secs),
                    seed: chaos_seed,
                }),
                None => None,
            };
            if let Some(n) = inference_workers {
                cfg.pipeline.workers.inference = n;
            }
            cfg.validate(&config)?;
            println!(
                "Stress: {frames} frames at {} through {} fusion / {} inference / {} selection worker(s), drop policy {:?}",
                if rate > 0.0 { format!("{rate} Hz") } else { "max rate".into() },
                cfg.pipeline.workers.fusion,
                cfg.pipeline.workers.inference,
                cfg.pipeline.workers.selection,
                cfg.pipeline.channel.drop_policy
            );
            let opts = run::RunOptions {
                frames,
                timeout: Duration::from_secs(timeout),
                chaos,
            };
            let (report, mut sup) = run::run_pipeline(&cfg, opts, &default_bin_dir())?;
            sup.shutdown(Duration::from_secs(3));
            stress::print_report(&report);
            if report.interrupted {
                anyhow::bail!("interrupted");
            }
            if transport_iterations > 0 {
                let figures = stress::compare_transports(
                    &[1_228_800, 4 * 262_144 * 4],
                    transport_iterations,
                )?;
                stress::print_transport_table(&figures);
            }
            Ok(())
        }
        Command::Http { config, port } => {
            let mut cfg = PipelineConfig::load(&config)?;
            if let Some(port) = port {
                cfg.http.port = port;
            }
            let node = PipelineNode::new(
                &format!("{}-http-{}", cfg.pipeline.name, std::process::id()),
                &cfg.pipeline.name,
                cfg.pipeline.channel,
            )?;
            let endpoint = psgrasp::http::HttpEndpoint::start(&cfg)?;
            println!(
                "HTTP endpoint for pipeline '{}' on http://{}; Ctrl-C to stop",
                cfg.pipeline.name,
                endpoint.addr()
            );
            while node.sleep(Duration::from_millis(200)) {}
            Ok(())
        }
        Command::Datagen(args) => psgrasp_datagen::run_datagen(&args),
        Command::Inspect(args) => psgrasp_datagen::run_inspect(&args),
        Command::Eval(args) => psgrasp_eval::run_eval(&args),
        Command::Testset(args) => psgrasp_eval::cli::run_testset(&args),
        Command::CheckConfig { config } => {
            let cfg = PipelineConfig::load(&config)?;
            psgrasp::launcher::preflight(&cfg)?;
            println!(
                "# {} is valid; effective configuration:\n{}",
                config.display(),
                cfg.to_toml()
            );
            Ok(())
        }
        Command::NextPick {
            config,
            failed,
            picked,
            wait,
        } => {
            let mode = match (failed, picked) {
                (true, _) => NextPickMode::AfterFailure,
                (_, true) => NextPickMode::AfterSuccess,
                _ => NextPickMode::Current,
            };
            anyhow::ensure!(
                wait.is_finite() && (0.0..=3600.0).contains(&wait),
                "--wait {wait}: must be 0 to 3600 s"
            );
            let cfg = PipelineConfig::load(&config)?;
            let node = PipelineNode::new(
                &format!("{}-cli-{}", cfg.pipeline.name, std::process::id()),
                &cfg.pipeline.name,
                cfg.pipeline.channel,
            )?;
            let client = psgrasp::next_pick::PickClient::connect(&node)?;
            // The default is long enough to wait out a grasp-selection restart.
            match client.next_pick(mode, Duration::from_secs_f64(wait))? {
                None => anyhow::bail!(
                    "no answer from grasp-selection within {wait} s: is `psgrasp up` running?"
                ),
                Some(r) => match r.status() {
                    Some(NextPickStatus::Pick) => println!(
                        "{}",
                        serde_json::to_string_pretty(&psgrasp::pick_json::pick_json(r.frame_id, &r.pick))?
                    ),
                    Some(NextPickStatus::NoFrameYet) => println!("no frame processed yet"),
                    Some(NextPickStatus::Exhausted) => println!(
                        "all picks of frame {} used; wait for the next frame",
                        r.frame_id
                    ),
                    Some(NextPickStatus::AwaitingNewFrame) => println!(
                        "the last pick succeeded; no frame taken since has been processed yet (latest: {})",
                        r.frame_id
                    ),
                    Some(NextPickStatus::BadRequest) => {
                        anyhow::bail!("grasp-selection refused the request as malformed")
                    }
                    None => {
                        anyhow::bail!("unknown next-pick status {} from grasp-selection", r.status)
                    }
                },
            }
            Ok(())
        }
    }
}

fn up(config: PathBuf) -> Result<()> {
    let cfg = PipelineConfig::load(&config)?;
    let node = PipelineNode::new(
        &format!("{}-launcher", cfg.pipeline.name),
        &cfg.pipeline.name,
        cfg.pipeline.channel,
    )?;
    let mut sup = Supervisor::start(&config, &default_bin_dir(), false)?;
    println!(
        "psgrasp pipeline '{}' up ({} processes); Ctrl-C to stop",
        cfg.pipeline.name,
        sup.processes.len()
    );
    let http = if cfg.http.enabled {
        let endpoint = psgrasp::http::HttpEndpoint::start(&cfg)?;
        println!("HTTP endpoint on http://{}", endpoint.addr());
        Some(endpoint)
    } else {
        None
    };
    while node.sleep(Duration::from_millis(100)) {
        for e in sup.poll()? {
            println!("{e}");
        }
        if !sup.failures().is_empty() || !sup.any_running() {
            break;
        }
    }
    println!("stopping…");
    drop(http);
    sup.shutdown(Duration::from_secs(3));
    let failures = sup.failures();
    // A pipeline with a stage that cannot stay up answers nothing: say so and fail.
    anyhow::ensure!(
        failures.is_empty(),
        "pipeline '{}' failed: {}",
        cfg.pipeline.name,
        failures.join("; ")
    );
    Ok(())
}

/// Parses `tx,ty,tz,qx,qy,qz,qw`.
fn parse_pose(text: &str) -> Result<psgrasp_config::PoseConfig, String> {
    let v: Vec<f32> = text
        .split(',')
        .map(|x| x.trim().parse::<f32>().map_err(|e| format!("{x:?}: {e}")))
        .collect::<Result<_, _>>()?;
    if v.len() != 7 || v.iter().any(|x| !x.is_finite()) {
        return Err(format!(
            "expected 7 finite numbers tx,ty,tz,qx,qy,qz,qw, got {}",
            v.len()
        ));
    }
    let norm = v[3..].iter().map(|x| x * x).sum::<f32>().sqrt();
    if (norm - 1.0).abs() > 1e-3 {
        return Err(format!("the quaternion must have norm 1, not {norm}"));
    }
    Ok(psgrasp_config::PoseConfig {
        translation: [v[0], v[1], v[2]],
        rotation_xyzw: [v[3], v[4], v[5], v[6]],
    })
}

fn detect(
    config: &std::path::Path,
    input: &psgrasp::detect::DetectInput,
    json: Option<PathBuf>,
    png: Option<PathBuf>,
) -> Result<()> {
    let cfg = PipelineConfig::load(config)?;
    let out = psgrasp::detect::detect_file(&cfg, input)?;
    let t = &out.timings;
    println!(
        "{}: {} grasp configurations, {} picks; fusion {:.1} ms, inference {:.1} ms, selection {:.1} ms",
        input.depth.display(),
        out.configurations,
        out.picks.len(),
        t.fusion_ms,
        t.inference_ms,
        t.selection_ms
    );
    print_picks(&out.picks, out.picks.len());
    println!(
        "passed over: {}",
        serde_json::to_string(&out.rejected).unwrap_or_default()
    );
    if let Some(path) = json {
        let mut doc = psgrasp::pick_json::picks_json(0, &out.picks);
        doc["passed_over"] = serde_json::json!(out.rejected);
        doc["depth_file"] = serde_json::json!(input.depth);
        doc["camera"] = serde_json::json!({
            "intrinsics": out.camera.intrinsics,
            "workspace_from_camera": psgrasp_geometry::robot::matrix_rows(
                &out.camera.workspace_from_camera.cast::<f64>()
            ),
        });
        std::fs::write(&path, serde_json::to_string_pretty(&doc)? + "\n")
            .with_context(|| format!("writing {}", path.display()))?;
        println!("picks → {}", path.display());
    }
    if let Some(path) = png {
        psgrasp::detect::draw_picks(
            &out.depth,
            &out.camera,
            &cfg.cell.workspace,
            &cfg.cell.gripper,
            &out.picks,
        )
        .write_png(&path)?;
        println!("picture → {}", path.display());
    }
    Ok(())
}

/// The picks as a Markdown table (workspace and robot base frame).
fn print_picks(picks: &[psgrasp_ipc::PickRecord], top: usize) {
    println!("| rank | TCP (m, workspace) | TCP (m, robot base) | approach | width (mm) | quality | collision score | pad fill |");
    println!("|---|---|---|---|---|---|---|---|");
    for p in picks.iter().take(top) {
        let a = p.approach();
        println!(
            "| {} | ({:.3}, {:.3}, {:.3}) | ({:.3}, {:.3}, {:.3}) | ({:+.2}, {:+.2}, {:+.2}) | {:.1} | {:.2} | {:.2} | {} |",
            p.rank,
            p.position[0],
            p.position[1],
            p.position[2],
            p.base_position[0],
            p.base_position[1],
            p.base_position[2],
            a.x,
            a.y,
            a.z,
            p.width * 1000.0,
            p.quality,
            p.collision_score,
            p.pad_fill()
                .map_or_else(|| "–".to_string(), |f| format!("{f:.2}"))
        );
    }
}

fn demo(config: PathBuf, frames: u64, seed: u64, top: usize, png: Option<PathBuf>) -> Result<()> {
    // The error names the file already.
    let mut cfg = PipelineConfig::load(&config)?;
    cfg.pipeline.name = format!("demo-{}", std::process::id());
    cfg.camera.source = psgrasp_config::SourceKind::Synthetic;
    cfg.camera.frames = frames;
    cfg.camera.rate_hz = 0.0;
    cfg.camera.synthetic.seed = seed;
    println!(
        "psgrasp demo: {} synthetic bin scene(s) with {} objects, 4 processes over iceoryx2 shared memory…",
        frames, cfg.camera.synthetic.objects
    );
    let (report, mut sup) =
        run::run_frames(&cfg, frames, Duration::from_secs(300), &default_bin_dir())?;
    sup.shutdown(Duration::from_secs(3));
    anyhow::ensure!(
        report.outcomes.len() as u64 == frames,
        "only {} of {frames} frames came back",
        report.outcomes.len()
    );
    for o in report.outcomes.values() {
        let h = &o.header;
        if o.status() != StatusCode::Ok {
            println!(
                "\nframe {}: error record {:?} from {:?}: {}",
                o.frame_id(),
                o.status(),
                o.error_stage(),
                h.error_text()
            );
            continue;
        }
        println!(
            "\nframe {}: {} executable picks; fusion {:.1} ms, inference {:.1} ms, selection {:.1} ms, end-to-end {:.1} ms",
            o.frame_id(),
            o.picks.len(),
            h.span_ms(psgrasp_ipc::Stamp::FusionStart, psgrasp_ipc::Stamp::FusionEnd),
            h.span_ms(psgrasp_ipc::Stamp::InferenceStart, psgrasp_ipc::Stamp::InferenceEnd),
            h.span_ms(psgrasp_ipc::Stamp::SelectionStart, psgrasp_ipc::Stamp::SelectionEnd),
            h.span_ms(psgrasp_ipc::Stamp::IngestPublished, psgrasp_ipc::Stamp::SelectionEnd),
        );
        print_picks(&o.picks, top);
    }
    if let Some(path) = png {
        // The demo's frames are the synthetic source's frames 0, 1, … in order.
        let mut source = psgrasp::sources::SyntheticSource::new(&cfg);
        let camera = cfg.camera_model();
        for (k, o) in report.outcomes.values().enumerate() {
            let depth = source.render(k as u64)?;
            let file = psgrasp::detect::numbered_path(&path, k, report.outcomes.len());
            psgrasp::detect::draw_picks(
                &depth,
                &camera,
                &cfg.cell.workspace,
                &cfg.cell.gripper,
                &o.picks,
            )
            .write_png(&file)?;
            println!("frame {}: picture → {}", o.frame_id(), file.display());
        }
    }
    Ok(())
}
