//! Starts the stage processes of a pipeline and supervises them: a stage that dies is restarted
//! (its dead iceoryx2 node is cleaned up, the others keep running), and shutdown stops every
//! process and leaves no shared-memory residue.
use anyhow::{Context, Result};
use iceoryx2::node::NodeView;
use iceoryx2::prelude::*;
use psgrasp_config::PipelineConfig;
use psgrasp_ipc::{cleanup_dead_nodes, Stage};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// One supervised process.
#[derive(Debug)]
pub struct StageProcess {
    /// Which stage.
    pub stage: Stage,
    /// Worker index.
    pub worker: u32,
    child: Option<Child>,
    /// Restart times within the window.
    restarts: Vec<Instant>,
    /// Total restarts.
    pub restart_count: u32,
    /// Exited normally (finite source) and must not be restarted.
    pub finished: bool,
    /// Died and waits for its restart (backoff) until this instant.
    restart_due: Option<Instant>,
    /// Died more than `max_restarts` times within the window: not restarted again. The reason.
    pub gave_up: Option<String>,
    /// Asked to stop ([`Supervisor::stop`]): not restarted whatever its exit.
    stopping: bool,
}

impl StageProcess {
    /// Process id, if running.
    pub fn pid(&self) -> Option<u32> {
        self.child.as_ref().map(|c| c.id())
    }
}

/// The set of stage processes of one pipeline.
pub struct Supervisor {
    config_path: PathBuf,
    config: PipelineConfig,
    bin_dir: PathBuf,
    /// The processes, consumers first.
    pub processes: Vec<StageProcess>,
    quiet: bool,
    /// A config file written for this run ([`Supervisor::launch`]), removed at shutdown.
    temp_config: Option<PathBuf>,
}

/// Environment variable through which a stage learns its launcher's pid (see
/// [`crate::stage::end_with_parent`]).
pub const PARENT_PID_ENV: &str = "PSGRASP_PARENT_PID";

/// Directory holding the stage binaries: next to the running executable (also for test binaries
/// under `target/*/deps`).
pub fn default_bin_dir() -> PathBuf {
    let exe = std::env::current_exe().unwrap_or_default();
    let dir = exe.parent().map(Path::to_path_buf).unwrap_or_default();
    if dir.ends_with("deps") {
        dir.parent().map(Path::to_path_buf).unwrap_or(dir)
    } else {
        dir
    }
}

impl Supervisor {
    /// Starts all stages of `config_path` (consumers first, the camera last).
    pub fn start(config_path: &Path, bin_dir: &Path, quiet: bool) -> Result<Self> {
        let config = PipelineConfig::load(config_path)?;
        cleanup_dead_nodes();
        refuse_running_pipeline(&config.pipeline.name)?;
        check_shm_space(&config)?;
        // A new pipeline hands out no picks of an earlier one.
        let _ = std::fs::remove_file(crate::next_pick::state_path(&config.pipeline.name));
        let w = config.pipeline.workers;
        let mut processes = Vec::new();
        for (stage, n) in [
            (Stage::GraspSelection, w.selection),
            (Stage::Inference, w.inference),
            (Stage::GridFusion, w.fusion),
            (Stage::CameraIngest, 1),
        ] {
            for worker in 0..n {
                processes.push(StageProcess {
                    stage,
                    worker,
                    child: None,
                    restarts: vec![],
                    restart_count: 0,
                    finished: false,
                    restart_due: None,
                    gave_up: None,
                    stopping: false,
                });
            }
        }
        let mut sup = Self {
            config_path: config_path.to_path_buf(),
            config,
            bin_dir: bin_dir.to_path_buf(),
            processes,
            quiet,
            temp_config: None,
        };
        for i in 0..sup.processes.len() {
            sup.spawn(i)?;
        }
        Ok(sup)
    }

    /// Starts the pipeline of `cfg` from a private temporary config file, which the supervisor
    /// removes at shutdown.
    pub fn launch(cfg: &PipelineConfig, bin_dir: &Path, quiet: bool) -> Result<Self> {
        let path = write_temp_config(cfg, &cfg.pipeline.name)?;
        match Self::start(&path, bin_dir, quiet) {
            Ok(mut sup) => {
                sup.temp_config = Some(path);
                Ok(sup)
            }
            Err(e) => {
                let _ = std::fs::remove_file(&path);
                Err(e)
            }
        }
    }

    /// The loaded configuration.
    pub fn config(&self) -> &PipelineConfig {
        &self.config
    }

    fn spawn(&mut self, i: usize) -> Result<()> {
        let p = &mut self.processes[i];
        let exe = self.bin_dir.join(format!("psgrasp-{}", p.stage.name()));
        let mut cmd = Command::new(&exe);
        cmd.arg("--config")
            .arg(&self.config_path)
            .arg("--worker")
            .arg(p.worker.to_string())
            .env(PARENT_PID_ENV, std::process::id().to_string())
            .stdin(Stdio::null());
        if self.quiet {
            cmd.env(
                "RUST_LOG",
                std::env::var("RUST_LOG").unwrap_or_else(|_| "warn".into()),
            );
        }
        let child = cmd
            .spawn()
            .with_context(|| format!("starting {}", exe.display()))?;
        tracing::info!(
            "started {}[{}] pid {}",
            p.stage.name(),
            p.worker,
            child.id()
        );
        p.child = Some(child);
        Ok(())
    }

    /// Checks every process; schedules a restart (with backoff) for the ones that died and
    /// starts the ones whose backoff has passed. Returns descriptions of what happened.
    pub fn poll(&mut self) -> Result<Vec<String>> {
        let mut events = Vec::new();
        let pipeline = self.config.pipeline.clone();
        let window = Duration::from_secs(pipeline.restart_window_s);
        for i in 0..self.processes.len() {
            let p = &mut self.processes[i];
            let name = format!("{}[{}]", p.stage.name(), p.worker);
            if let Some(due) = p.restart_due {
                if Instant::now() >= due {
                    p.restart_due = None;
                    p.restarts.push(Instant::now());
                    p.restart_count += 1;
                    cleanup_dead_nodes();
                    self.spawn(i)?;
                    events.push(format!("{name} restarted"));
                }
                continue;
            }
            let status = match p.child.as_mut() {
                Some(c) => c.try_wait()?,
                None => continue,
            };
            let Some(status) = status else { continue };
            p.child = None;
            if p.stopping {
                p.finished = true;
                events.push(format!("{name} stopped ({status})"));
                continue;
            }
            if status.success() {
                p.finished = true;
                events.push(format!("{name} exited normally"));
                continue;
            }
            events.push(format!("{name} died ({status})"));
            tracing::warn!("{name} died ({status})");
            if !pipeline.restart_on_failure {
                p.gave_up = Some(format!("{name} died ({status}); restart_on_failure is off"));
                continue;
            }
            p.restarts.retain(|t| t.elapsed() < window);
            if p.restarts.len() as u32 >= pipeline.max_restarts {
                let reason = format!(
                    "{name} gave up after {} restarts in {window:?} (last exit: {status})",
                    p.restarts.len()
                );
                tracing::error!("{reason}");
                events.push(reason.clone());
                p.gave_up = Some(reason);
                continue;
            }
            let backoff = restart_backoff(
                pipeline.restart_backoff_ms,
                pipeline.restart_backoff_max_ms,
                p.restarts.len() as u32,
            );
            p.restart_due = Some(Instant::now() + backoff);
            events.push(format!("{name} restarts in {} ms", backoff.as_millis()));
        }
        Ok(events)
    }

    /// Why the pipeline cannot run any more: the stages that gave up (empty while it can).
    pub fn failures(&self) -> Vec<String> {
        self.processes
            .iter()
            .filter_map(|p| p.gave_up.clone())
            .collect()
    }

    /// True while any non-finished process runs or waits for its restart.
    pub fn any_running(&self) -> bool {
        self.processes
            .iter()
            .any(|p| p.child.is_some() || p.restart_due.is_some())
    }

    /// Kills one stage process with SIGKILL (for failure tests and drills).
    pub fn kill(&mut self, stage: Stage, worker: u32) -> Result<Option<u32>> {
        for p in &mut self.processes {
            if p.stage == stage && p.worker == worker {
                if let Some(c) = p.child.as_mut() {
                    let pid = c.id();
                    c.kill()?;
                    return Ok(Some(pid));
                }
            }
        }
        Ok(None)
    }

    /// True while a stage waits for its restart.
    pub fn restart_pending(&self) -> bool {
        self.processes.iter().any(|p| p.restart_due.is_some())
    }

    /// Asks one stage process to stop (SIGTERM); it is not restarted.
    pub fn stop(&mut self, stage: Stage, worker: u32) {
        for p in &mut self.processes {
            if p.stage == stage && p.worker == worker {
                p.stopping = true;
                p.restart_due = None;
                if let Some(c) = &p.child {
                    // SAFETY: plain kill(2) on a child pid we own.
                    unsafe {
                        libc::kill(c.id() as i32, libc::SIGTERM);
                    }
                }
            }
        }
    }

    /// Stops everything: SIGTERM (camera first), wait up to `grace`, then SIGKILL; then removes
    /// any shared-memory resources of dead nodes and the temporary config file.
    pub fn shutdown(&mut self, grace: Duration) {
        for p in self.processes.iter().rev() {
            if let Some(c) = &p.child {
                // SAFETY: plain kill(2) on a child pid we own.
                unsafe {
                    libc::kill(c.id() as i32, libc::SIGTERM);
                }
            }
        }
        let deadline = Instant::now() + grace;
        for p in &mut self.processes {
            if let Some(mut c) = p.child.take() {
                loop {
                    match c.try_wait() {
                        Ok(Some(_)) => break,
                        Ok(None) if Instant::now() < deadline => {
                            std::thread::sleep(Duration::from_millis(10))
                        }
                        _ => {
                            let _ = c.kill();
                            let _ = c.wait();
                            break;
                        }
                    }
                }
            }
        }
        for p in &mut self.processes {
            p.restart_due = None;
        }
        cleanup_dead_nodes();
        let _ = std::fs::remove_file(crate::next_pick::state_path(&self.config.pipeline.name));
        if let Some(path) = self.temp_config.take() {
            let _ = std::fs::remove_file(path);
        }
    }
}

impl Drop for Supervisor {
    fn drop(&mut self) {
        if self.any_running() || self.temp_config.is_some() {
            self.shutdown(Duration::from_secs(3));
        }
    }
}

/// Writes `cfg` to a private temp file the stage processes can read.
pub fn write_temp_config(cfg: &PipelineConfig, tag: &str) -> Result<PathBuf> {
    let dir = std::env::temp_dir().join("psgrasp");
    std::fs::create_dir_all(&dir)?;
    let path = dir.join(format!("{tag}-{}.toml", std::process::id()));
    std::fs::write(&path, cfg.to_toml())?;
    Ok(path)
}

/// The live stage nodes of pipeline `name` (`<name>-<stage>-<worker>`).
pub fn running_stage_nodes(name: &str) -> Vec<String> {
    let mut found = Vec::new();
    let _ = Node::<ipc::Service>::list(Config::global_config(), |state| {
        if let NodeState::Alive(view) = &state {
            if let Some(d) = view.details() {
                let node = d.name().as_str();
                let is_stage = Stage::ALL.iter().any(|s| {
                    node.strip_prefix(&format!("{name}-{}-", s.name()))
                        .is_some_and(|w| !w.is_empty() && w.bytes().all(|b| b.is_ascii_digit()))
                });
                if is_stage {
                    found.push(node.to_string());
                }
            }
        }
        CallbackProgression::Continue
    });
    found.sort();
    found
}

/// Refuses to start pipeline `name` while stages of it are alive (an earlier launcher's, or
/// orphans of one that was killed): two pipelines on the same services would handle every frame
/// twice.
pub fn refuse_running_pipeline(name: &str) -> Result<()> {
    let nodes = running_stage_nodes(name);
    anyhow::ensure!(
        nodes.is_empty(),
        "pipeline '{name}' is already running (live stage nodes: {}); stop it first, or give this \
         one another pipeline.name",
        nodes.join(", ")
    );
    Ok(())
}

/// The wait before restart number `earlier + 1` within the window: `base_ms · 2^earlier`, at most
/// `max_ms`.
pub fn restart_backoff(base_ms: u64, max_ms: u64, earlier: u32) -> Duration {
    let factor = 1u64.checked_shl(earlier.min(32)).unwrap_or(u64::MAX);
    Duration::from_millis(base_ms.saturating_mul(factor).min(max_ms))
}

/// Builds everything the stages of `cfg` load at start-up, without starting them: the depth
/// source, the fusion step, the inference backend (model files included), the selection step,
/// and the `/dev/shm` check. What this accepts, every stage starts with (`psgrasp check-config`).
pub fn preflight(cfg: &PipelineConfig) -> Result<()> {
    // First: a workspace too large for /dev/shm would also take gigabytes to build here.
    check_shm_space(cfg)?;
    crate::sources::source_from_config(cfg).context("camera-ingest: depth source")?;
    psgrasp_perception::FusionStep::new(&cfg.cell).context("grid-fusion")?;
    psgrasp_perception::InferenceStep::new(&cfg.cell).context("inference")?;
    psgrasp_perception::SelectionStep::new(&cfg.cell).context("grasp-selection")?;
    Ok(())
}

/// Fails early when `/dev/shm` cannot hold the pipeline's buffers (a full tmpfs makes publishers
/// die with SIGBUS later).
pub fn check_shm_space(cfg: &PipelineConfig) -> Result<()> {
    let n = cfg.cell.workspace.voxel_count() * 16;
    let px = cfg.camera.intrinsics.pixel_count() * 4;
    let slots = cfg.pipeline.channel.subscriber_buffer * cfg.pipeline.channel.max_subscribers + 4;
    let need = (n + px) as u64 * slots as u64 * 2;
    // SAFETY: statvfs fills a plain C struct.
    let mut st: libc::statvfs = unsafe { std::mem::zeroed() };
    let path = c"/dev/shm";
    if unsafe { libc::statvfs(path.as_ptr(), &mut st) } == 0 {
        let free = st.f_bavail as u64 * st.f_frsize as u64;
        anyhow::ensure!(
            free >= need,
            "/dev/shm has {} MiB free but the pipeline may need {} MiB; enlarge it or lower pipeline.channel.subscriber_buffer",
            free >> 20,
            need >> 20
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn restarts_back_off_exponentially_up_to_the_cap() {
        let ms = |n| restart_backoff(100, 5_000, n).as_millis();
        assert_eq!(
            [ms(0), ms(1), ms(2), ms(5), ms(6)],
            [100, 200, 400, 3_200, 5_000]
        );
        assert_eq!(restart_backoff(100, 5_000, 1_000).as_millis(), 5_000);
        assert_eq!(restart_backoff(0, 5_000, 3).as_millis(), 0);
    }
}
