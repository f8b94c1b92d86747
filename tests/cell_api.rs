//! The controller interfaces against a live pipeline over real shared memory: `psgrasp
//! next-pick` (CLI), the C example and the C++ example (compiled here against
//! `libpsgrasp_c.so` and `bindings/c/include/psgrasp.h`), and the HTTP endpoint (a real HTTP
//! client). Each must hand out the same pick, in the robot base frame of a known calibration, and
//! they share one pick cursor: a failure reported through one moves all of them on.
mod common;

use common::{bin_dir, test_config};
use psgrasp::http::HttpEndpoint;
use psgrasp::launcher::{write_temp_config, Supervisor};
use psgrasp::monitor::PipelineMonitor;
use psgrasp::pick_json::pick_from_json;
use psgrasp_ipc::{PickRecord, StatusCode};
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

/// What a C/C++ example printed: frame, rank and the TCP in the base frame.
#[derive(Debug, PartialEq)]
struct PrintedPick {
    frame_id: u64,
    rank: u32,
    calibrated: u32,
    tcp: [f32; 7],
    flange: [f32; 7],
    /// `psgrasp_last_pick_details`: fallback flag and pad fill (`None`: unmeasured).
    fallback: u32,
    pad_fill: Option<f32>,
}

fn parse_printed(out: &str) -> Option<PrintedPick> {
    let mut frame_id = None;
    let mut rank = None;
    let mut calibrated = None;
    let mut tcp = None;
    let mut flange = None;
    let mut details = None;
    for line in out.lines() {
        let words: Vec<&str> = line.split_whitespace().collect();
        let pose = || -> Option<[f32; 7]> {
            let v: Vec<f32> = words[1..]
                .iter()
                .map(|w| w.parse::<f64>().ok().map(|x| x as f32))
                .collect::<Option<_>>()?;
            v.try_into().ok()
        };
        match words.first() {
            Some(&"frame_id") => {
                frame_id = words.get(1)?.parse().ok();
                rank = words.get(3)?.parse().ok();
                calibrated = words.get(5)?.parse().ok();
            }
            Some(&"tcp") => tcp = pose(),
            Some(&"flange") => flange = pose(),
            Some(&"details") => {
                let fallback: u32 = words.get(2)?.parse().ok()?;
                let measured: u32 = words.get(4)?.parse().ok()?;
                let fill: f64 = words.get(6)?.parse().ok()?;
                details = Some((fallback, (measured == 1).then_some(fill as f32)));
            }
            _ => {}
        }
    }
    Some(PrintedPick {
        frame_id: frame_id?,
        rank: rank?,
        calibrated: calibrated?,
        tcp: tcp?,
        flange: flange?,
        fallback: details?.0,
        pad_fill: details?.1,
    })
}

fn printed_of(frame_id: u64, p: &PickRecord) -> PrintedPick {
    let pose = |x: [f32; 3], q: [f32; 4]| [x[0], x[1], x[2], q[0], q[1], q[2], q[3]];
    PrintedPick {
        frame_id,
        rank: p.rank,
        calibrated: p.base_calibrated,
        tcp: pose(p.base_position, p.base_orientation_xyzw),
        flange: pose(p.flange_position, p.flange_orientation_xyzw),
        fallback: p.fallback,
        pad_fill: p.pad_fill(),
    }
}

/// Compiles `source` with `compiler` against the C API; the executable's path.
fn compile(compiler: &str, std: &str, source: &str, out_dir: &Path) -> PathBuf {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    // `cargo build -p psgrasp-c` puts it beside the binaries; `cargo test --workspace` builds it
    // as a dependency of the C crate's tests, in deps/.
    let lib_dir = [bin_dir(), bin_dir().join("deps")]
        .into_iter()
        .find(|d| d.join("libpsgrasp_c.so").exists())
        .unwrap_or_else(|| {
            panic!(
                "libpsgrasp_c.so is not in {} or its deps/: build it with `cargo build -p \
                 psgrasp-c` (`cargo test --workspace` does)",
                bin_dir().display()
            )
        });
    let exe = out_dir
        .join(Path::new(source).file_name().unwrap())
        .with_extension(compiler);
    let out = Command::new(compiler)
        .arg(format!("-std={std}"))
        .args(["-Wall", "-Wextra", "-Werror", "-O1", "-I"])
        .arg(root.join("bindings/c/include"))
        .arg(root.join(source))
        .arg("-L")
        .arg(&lib_dir)
        .arg("-lpsgrasp_c")
        .arg(format!("-Wl,-rpath,{}", lib_dir.display()))
        .arg("-o")
        .arg(&exe)
        .output()
        .unwrap_or_else(|e| panic!("running {compiler}: {e}"));
    assert!(
        out.status.success(),
        "{compiler} {source}:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    exe
}

fn run(exe: &Path, args: &[&str]) -> (i32, String) {
    let out = Command::new(exe).args(args).output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout).into_owned();
    (
        out.status.code().unwrap_or(-1),
        text + &String::from_utf8_lossy(&out.stderr),
    )
}

fn cli_next_pick(config: &Path, flag: Option<&str>) -> PickRecord {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_psgrasp"));
    cmd.arg("next-pick").arg("--config").arg(config);
    if let Some(f) = flag {
        cmd.arg(f);
    }
    let out = cmd.output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: Value = serde_json::from_slice(&out.stdout).unwrap();
    pick_from_json(&v).unwrap_or_else(|| panic!("a pick in {v}"))
}

/// An HTTP client that hands back error statuses as answers (the tests check them).
fn agent() -> ureq::Agent {
    ureq::Agent::config_builder()
        .http_status_as_error(false)
        .build()
        .into()
}

fn http_get(url: &str) -> (u16, String) {
    let mut r = agent().get(url).call().unwrap();
    (r.status().as_u16(), r.body_mut().read_to_string().unwrap())
}

fn http_post(url: &str, body: &str) -> (u16, String) {
    let mut r = agent()
        .post(url)
        .header("Content-Type", "application/json")
        .send(body)
        .unwrap();
    (r.status().as_u16(), r.body_mut().read_to_string().unwrap())
}

fn http_pick(status: u16, body: &str) -> (u64, PickRecord) {
    assert_eq!(status, 200, "{body}");
    let v: Value = serde_json::from_str(body).unwrap();
    assert_eq!(v["status"], "pick");
    let frame_id = v["pick"]["frame_id"].as_u64().unwrap();
    (frame_id, pick_from_json(&v["pick"]).unwrap())
}

#[test]
fn every_controller_interface_hands_out_the_same_pick() {
    let tmp = std::env::temp_dir().join(format!("psgrasp-cellapi-{}", std::process::id()));
    std::fs::create_dir_all(&tmp).unwrap();
    // Compile first: a compiler error should not leave a pipeline behind.
    let c_exe = compile("cc", "c11", "bindings/c/examples/next_pick.c", &tmp);
    let cpp_exe = compile("c++", "c++17", "bindings/c/examples/next_pick.cpp", &tmp);

    let mut cfg = test_config("cellapi");
    cfg.camera.frames = 3;
    cfg.camera.synthetic.objects = 6;
    cfg.pipeline.stats_interval_ms = 200;
    cfg.cell.robot.camera_in_base = Some(psgrasp_geometry::PoseSetting::from_parts(
        [0.55, -0.05, 1.25],
        [1.0, 0.0, 0.0, 0.0],
    ));
    cfg.http.port = 0;
    let config = write_temp_config(&cfg, &cfg.pipeline.name).unwrap();
    // The endpoint and the monitor attach before the first frame.
    let http = HttpEndpoint::start(&cfg).unwrap();
    let base = format!("http://{}", http.addr());
    let mut monitor = PipelineMonitor::of(&cfg).unwrap();
    let mut sup = Supervisor::start(&config, &bin_dir(), true).unwrap();
    let mut outcomes = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(120);
    while outcomes.len() < 3 && Instant::now() < deadline {
        if let Some(o) = monitor.next_outcome(Duration::from_millis(200)).unwrap() {
            outcomes.push(o);
        }
    }
    assert_eq!(outcomes.len(), 3, "three frames end");
    let last = outcomes.last().unwrap();
    assert_eq!(
        last.status(),
        StatusCode::Ok,
        "{}",
        last.header.error_text()
    );
    assert!(last.picks.len() >= 3, "the test needs three picks");
    // The shipped config's surface check measures every pick's pad fill, and it crosses the
    // shared memory with the pick (the interfaces below hand it on: HTTP = CLI = C = C++ = this
    // record).
    assert!(
        last.picks
            .iter()
            .all(|p| p.pad_fill().is_some_and(|f| (0.0..=1.0).contains(&f))),
        "every pick carries its measured pad fill"
    );

    // The same pick through every interface (none of them moves the cursor).
    let from_cli = cli_next_pick(&config, None);
    let (http_frame, from_http) = {
        let (s, b) = http_get(&format!("{base}/v1/pick?wait_ms=5000"));
        http_pick(s, &b)
    };
    let cfg_arg = config.to_str().unwrap();
    let (rc, c_out) = run(&c_exe, &[cfg_arg, "current", "5000"]);
    assert_eq!(rc, 0, "{c_out}");
    let (rc, cpp_out) = run(&cpp_exe, &[cfg_arg, "current", "5000"]);
    assert_eq!(rc, 0, "{cpp_out}");
    assert_eq!(http_frame, last.frame_id());
    assert_eq!(
        from_cli, last.picks[0],
        "CLI = the best pick of the latest frame"
    );
    assert_eq!(from_http, last.picks[0], "HTTP = CLI");
    let expected = printed_of(last.frame_id(), &last.picks[0]);
    assert_eq!(expected.calibrated, 1);
    assert_eq!(parse_printed(&c_out), Some(expected), "C = CLI:\n{c_out}");
    let expected = printed_of(last.frame_id(), &last.picks[0]);
    assert_eq!(
        parse_printed(&cpp_out),
        Some(expected),
        "C++ = CLI:\n{cpp_out}"
    );

    // One cursor: a failure reported over HTTP, then one from C; everyone sees rank 2.
    let (s, b) = http_post(
        &format!("{base}/v1/pick/result?wait_ms=5000"),
        r#"{"result": "failure"}"#,
    );
    assert_eq!(http_pick(s, &b).1, last.picks[1]);
    let (rc, c_out) = run(&c_exe, &[cfg_arg, "failed", "5000"]);
    assert_eq!(rc, 0, "{c_out}");
    assert_eq!(
        parse_printed(&c_out),
        Some(printed_of(last.frame_id(), &last.picks[2]))
    );
    assert_eq!(cli_next_pick(&config, None), last.picks[2]);
    let (rc, cpp_out) = run(&cpp_exe, &[cfg_arg, "current", "5000"]);
    assert_eq!(rc, 0);
    assert_eq!(
        parse_printed(&cpp_out),
        Some(printed_of(last.frame_id(), &last.picks[2]))
    );

    // The latest frame, by id and as "latest".
    let (s, b) = http_get(&format!("{base}/v1/frames/latest"));
    assert_eq!(s, 200, "{b}");
    let v: Value = serde_json::from_str(&b).unwrap();
    assert_eq!(v["frame_id"].as_u64(), Some(last.frame_id()));
    assert_eq!(v["status"], "Ok");
    let picks: Vec<PickRecord> = v["picks"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| pick_from_json(p).unwrap())
        .collect();
    assert_eq!(picks, last.picks);
    let (s, _) = http_get(&format!("{base}/v1/frames/{}", outcomes[0].frame_id()));
    assert_eq!(s, 200);
    assert_eq!(http_get(&format!("{base}/v1/frames/12345")).0, 404);

    // Health once every stage has reported statistics; metrics count the three frames.
    let deadline = Instant::now() + Duration::from_secs(10);
    let health = loop {
        let (s, b) = http_get(&format!("{base}/v1/health"));
        if s == 200 || Instant::now() > deadline {
            break (s, b);
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    assert_eq!(health.0, 200, "{}", health.1);
    let v: Value = serde_json::from_str(&health.1).unwrap();
    assert_eq!(v["healthy"], true);
    assert_eq!(v["outcomes"]["Ok"], 3);
    // Metrics: the stages' statistics arrive periodically, so wait for ones taken after the
    // third frame (at most 10 s).
    let expected = [
        "psgrasp_frames_total{status=\"Ok\"} 3",
        "psgrasp_latency_seconds_count{span=\"end_to_end\"} 3",
        "psgrasp_stage_up{stage=\"inference\",worker=\"0\"} 1",
        "psgrasp_stage_frames_out_total{stage=\"grasp-selection\",worker=\"0\"} 3",
    ];
    let deadline = Instant::now() + Duration::from_secs(10);
    let metrics = loop {
        let (s, text) = http_get(&format!("{base}/metrics"));
        assert_eq!(s, 200);
        if expected.iter().all(|e| text.contains(e)) || Instant::now() > deadline {
            break text;
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    for e in expected {
        assert!(metrics.contains(e), "{e} missing from\n{metrics}");
    }

    // A success: no pick of a frame taken before it, through HTTP and C alike.
    let (s, b) = http_post(
        &format!("{base}/v1/pick/result?wait_ms=1500"),
        r#"{"result": "success"}"#,
    );
    assert_eq!(s, 503, "{b}");
    assert!(b.contains("awaiting_new_frame"), "{b}");
    let (rc, c_out) = run(&c_exe, &[cfg_arg, "current", "2000"]);
    assert_eq!(rc, 3, "{c_out}");
    assert!(c_out.contains("no pick: result 3"), "{c_out}");

    // Bad requests get reasons.
    let (s, b) = http_post(&format!("{base}/v1/pick/result"), r#"{"result": "maybe"}"#);
    assert_eq!(s, 400);
    assert!(b.contains("success"), "{b}");
    assert_eq!(http_get(&format!("{base}/v1/pick?wait_ms=abc")).0, 400);
    assert_eq!(http_get(&format!("{base}/nothing")).0, 404);
    assert_eq!(http_post(&format!("{base}/metrics"), "").0, 405);

    drop(http);
    sup.shutdown(Duration::from_secs(3));
    std::fs::remove_file(&config).ok();
    std::fs::remove_dir_all(&tmp).ok();
}
