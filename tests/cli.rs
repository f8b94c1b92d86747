//! The `psgrasp` command line as a user meets it: error messages.
use std::process::Command;

fn psgrasp() -> Command {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_psgrasp"));
    cmd.current_dir(env!("CARGO_MANIFEST_DIR"));
    cmd
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
