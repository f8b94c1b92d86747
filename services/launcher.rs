//! Starts the stage processes of a pipeline and supervises them: a stage that dies is restarted
//! (its dead iceoryx2 node is cleaned up, the others keep running), and shutdown stops every
//! process and leaves no shared-memory residue.
use anyhow::{Context, Result};
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
}

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
        check_shm_space(&config)?;
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
                });
            }
        }
        let mut sup = Self {
            config_path: config_path.to_path_buf(),
            config,
            bin_dir: bin_dir.to_path_buf(),
            processes,
            quiet,
        };
        for i in 0..sup.processes.len() {
            sup.spawn(i)?;
        }
        Ok(sup)
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

    /// Checks every process; restarts the ones that died. Returns descriptions of what happened.
    pub fn poll(&mut self) -> Result<Vec<String>> {
        let mut events = Vec::new();
        for i in 0..self.processes.len() {
            let status = match self.processes[i].child.as_mut() {
                Some(c) => c.try_wait()?,
                None => continue,
            };
            let Some(status) = status else { continue };
            let p = &mut self.processes[i];
            p.child = None;
            let name = format!("{}[{}]", p.stage.name(), p.worker);
            if status.success() {
                p.finished = true;
                events.push(format!("{name} exited normally"));
                continue;
            }
            events.push(format!("{name} died ({status})"));
            tracing::warn!("{name} died ({status})");
            if !self.config.pipeline.restart_on_failure {
                continue;
            }
            let window = Duration::from_secs(self.config.pipeline.restart_window_s);
            p.restarts.retain(|t| t.elapsed() < window);
            if p.restarts.len() as u32 >= self.config.pipeline.max_restarts {
                events.push(format!(
                    "{name} gave up after {} restarts in {window:?}",
                    p.restarts.len()
                ));
                tracing::error!("{name}: too many restarts, not restarting");
                continue;
            }
            p.restarts.push(Instant::now());
            p.restart_count += 1;
            cleanup_dead_nodes();
            self.spawn(i)?;
            events.push(format!("{name} restarted"));
        }
        Ok(events)
    }

    /// True while any non-finished process runs.
    pub fn any_running(&self) -> bool {
        self.processes.iter().any(|p| p.child.is_some())
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

    /// Stops everything: SIGTERM (camera first), wait up to `grace`, then SIGKILL; then removes
    /// any shared-memory resources of dead nodes.
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
        cleanup_dead_nodes();
    }
}

impl Drop for Supervisor {
    fn drop(&mut self) {
        if self.any_running() {
            self.shutdown(Duration::from_secs(3));
        }
    }
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
