//! The `psgrasp` command line as a user meets it: output into a closed pipe, error messages.
use std::os::fd::{FromRawFd, OwnedFd};
use std::process::{Command, Stdio};

fn psgrasp() -> Command {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_psgrasp"));
    cmd.current_dir(env!("CARGO_MANIFEST_DIR"));
    cmd
}

/// A pipe whose read end is already closed: the first write into the returned end fails with
/// EPIPE, as when `head -2` has exited (no race with the reader).
fn pipe_without_reader() -> OwnedFd {
    let mut fds = [0; 2];
    // SAFETY: `fds` has room for the two descriptors `pipe` writes.
    assert_eq!(unsafe { libc::pipe(fds.as_mut_ptr()) }, 0);
    // SAFETY: both descriptors were just created and are owned here alone.
    let (read, write) = unsafe { (OwnedFd::from_raw_fd(fds[0]), OwnedFd::from_raw_fd(fds[1])) };
    drop(read);
    write
}

/// Issue 19: `psgrasp check-config config/default.toml | head -2` panicked on the broken pipe.
#[test]
fn output_into_a_closed_pipe_ends_quietly() {
    let out = psgrasp()
        .args(["check-config", "config/default.toml"])
        .stdout(Stdio::from(pipe_without_reader()))
        .stderr(Stdio::piped())
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert!(stderr.trim().is_empty(), "{stderr}");
    assert_eq!(out.status.code(), Some(128 + libc::SIGPIPE), "{stderr}");
    // With a reader, the same command prints the configuration and succeeds.
    let out = psgrasp()
        .args(["check-config", "config/default.toml"])
        .output()
        .unwrap();
    assert!(out.status.success());
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        stdout.starts_with("# config/default.toml is valid"),
        "{stdout}"
    );
}

/// Issue 19: error messages printed their cause twice ("X: X"): a cause both named in the
/// message and returned as its source, printed as a chain.
#[test]
fn a_bad_config_names_its_cause_once() {
    let dir = std::env::temp_dir().join(format!("psgrasp-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("bad.toml");
    std::fs::write(&file, "[pipeline]\nnmae = \"x\"\n").unwrap();
    let out = psgrasp().arg("check-config").arg(&file).output().unwrap();
    std::fs::remove_dir_all(&dir).ok();
    assert_eq!(out.status.code(), Some(1));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.starts_with("error: malformed config"), "{stderr}");
    assert_eq!(stderr.matches("TOML parse error").count(), 1, "{stderr}");
    assert_eq!(
        stderr.matches("unknown field `nmae`").count(),
        1,
        "{stderr}"
    );
    // The same for a file that cannot be read.
    let out = psgrasp()
        .args(["check-config", "/nonexistent/psgrasp.toml"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(
        stderr.matches("No such file or directory").count(),
        1,
        "{stderr}"
    );
}
