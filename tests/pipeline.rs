//! Multi-process tests: the four real stage binaries over real iceoryx2 shared memory.
//! Each test uses its own pipeline name, so tests run in parallel without interfering.
mod common;

use common::{bin_dir, nodes_of, shipped_config, test_config};
use psgrasp::launcher::write_temp_config;
use psgrasp::launcher::Supervisor;
use psgrasp::monitor::PipelineMonitor;
use psgrasp::run::run_frames;
use psgrasp::sources::save_depth_npy;
use psgrasp_config::{PipelineConfig, PoseConfig, SourceKind};
use psgrasp_inference::BackendConfig;
use psgrasp_ipc::{DropPolicy, Stage, Stamp, StatusCode};
use psgrasp_selection::PickOrder;
use std::collections::BTreeMap;
use std::time::{Duration, Instant};

#[test]
fn four_processes_turn_every_frame_into_picks() {
    let mut cfg = test_config("e2e");
    cfg.camera.frames = 4;
    cfg.camera.synthetic.objects = 8;
    every_frame_becomes_picks(&cfg);
}

#[test]
fn shipped_model_runs_in_the_pipeline() {
    let mut cfg = shipped_config("model");
    assert_eq!(
        cfg.cell.inference.kind(),
        "learned",
        "config/default.toml ships the model"
    );
    cfg.camera.frames = 2;
    cfg.camera.synthetic.objects = 8;
    every_frame_becomes_picks(&cfg);
}

/// Runs `cfg.camera.frames` frames through the four processes without loss and checks every
/// outcome: OK, stage stamps in order, picks from above with the pre-grasp behind, ≥ 1 pick.
fn every_frame_becomes_picks(cfg: &PipelineConfig) {
    let mut cfg = cfg.clone();
    let frames = cfg.camera.frames;
    cfg.pipeline.channel.block_timeout_ms = 120_000;
    cfg.pipeline.loss_timeout_ms = 120_000;
    cfg.pipeline.channel.drop_policy = DropPolicy::Block;
    let (report, mut sup) = run_frames(&cfg, frames, Duration::from_secs(240), &bin_dir()).unwrap();
    sup.shutdown(Duration::from_secs(3));
    assert_eq!(
        report.outcomes.len() as u64,
        frames,
        "every frame must come back: {:?}",
        report.outcomes.keys()
    );
    for o in report.outcomes.values() {
        assert_eq!(
            o.status(),
            StatusCode::Ok,
            "frame {}: {}",
            o.frame_id(),
            o.header.error_text()
        );
        let h = &o.header;
        let order = [
            Stamp::IngestPublished,
            Stamp::FusionStart,
            Stamp::FusionEnd,
            Stamp::InferenceStart,
            Stamp::InferenceEnd,
            Stamp::SelectionStart,
            Stamp::SelectionEnd,
        ];
        for w in order.windows(2) {
            assert!(
                h.stamps_ns[w[0] as usize] <= h.stamps_ns[w[1] as usize],
                "stamps out of order: {:?}",
                h.stamps_ns
            );
        }
        for p in &o.picks {
            assert!(p.quality >= cfg.cell.selection.min_quality - 1e-6);
            // Picks approach from above and the pre-grasp lies behind the grasp along the approach.
            let a = p.approach();
            assert!(a.z < 0.0, "approach {a:?} points up");
            let back =
                nalgebra::Vector3::from(p.pregrasp_position) - nalgebra::Vector3::from(p.position);
            assert!(back.dot(&a) < 0.0);
        }
    }
    let picks: usize = report.outcomes.values().map(|o| o.picks.len()).sum();
    assert!(
        picks >= 1,
        "bins with {} objects must yield executable picks",
        cfg.camera.synthetic.objects
    );
    // Clean shutdown leaves no node (and so no shared memory) of this pipeline behind.
    assert_eq!(nodes_of(&cfg.pipeline.name), 0);
}

#[test]
fn killing_inference_restarts_it_and_reports_lost_frames() {
    let mut cfg = test_config("kill");
    cfg.camera.rate_hz = 20.0;
    cfg.camera.frames = 40;
    cfg.camera.synthetic.frames_per_scene = 1000;
    cfg.pipeline.loss_timeout_ms = 1500;
    let path = write_temp_config(&cfg, &cfg.pipeline.name).unwrap();
    let mut monitor = PipelineMonitor::of(&cfg).unwrap();
    let mut sup = Supervisor::start(&path, &bin_dir(), true).unwrap();
    let mut outcomes = BTreeMap::new();
    let start = Instant::now();
    let mut killed = false;
    while outcomes.len() < 40 && start.elapsed() < Duration::from_secs(240) {
        sup.poll().unwrap();
        if let Some(o) = monitor.next_outcome(Duration::from_millis(50)).unwrap() {
            outcomes.insert(o.frame_id(), o);
        }
        if !killed && outcomes.len() >= 3 {
            assert!(sup.kill(Stage::Inference, 0).unwrap().is_some());
            killed = true;
            // Stay down for a while so frames certainly go missing.
            std::thread::sleep(Duration::from_millis(400));
        }
    }
    let restarts = sup
        .processes
        .iter()
        .find(|p| p.stage == Stage::Inference)
        .unwrap()
        .restart_count;
    sup.shutdown(Duration::from_secs(3));
    drop(monitor);
    assert!(killed);
    assert_eq!(
        restarts, 1,
        "the supervisor must restart the killed stage once"
    );
    assert_eq!(
        outcomes.len(),
        40,
        "every frame ends as picks or an error record"
    );
    let lost = outcomes
        .values()
        .filter(|o| o.status() == StatusCode::Lost)
        .count();
    let ok_after: usize = outcomes
        .values()
        .skip_while(|o| o.status() != StatusCode::Lost)
        .filter(|o| o.status() == StatusCode::Ok)
        .count();
    assert!(
        lost >= 1,
        "frames in flight while inference was down must be reported lost"
    );
    assert!(
        ok_after >= 1,
        "the restarted stage must produce results again"
    );
    assert_eq!(nodes_of(&cfg.pipeline.name), 0, "no residue after shutdown");
}

/// Replays the depth files of `dir` (`frames` of them) from the camera pose the synthetic source
/// used, losslessly: back-pressure instead of dropping, however slow a loaded machine is.
fn lossless_replay(cfg: &mut PipelineConfig, dir: &std::path::Path, frames: u64) {
    let cam = cfg.camera_model();
    let q = cam.workspace_from_camera.rotation.coords;
    let t = cam.workspace_from_camera.translation.vector;
    cfg.camera.source = SourceKind::Replay;
    cfg.camera.replay.path = dir.to_path_buf();
    cfg.camera.pose = Some(PoseConfig {
        translation: [t.x, t.y, t.z],
        rotation_xyzw: [q[0], q[1], q[2], q[3]],
    });
    cfg.camera.frames = frames;
    cfg.pipeline.channel.drop_policy = DropPolicy::Block;
    cfg.pipeline.channel.block_timeout_ms = 120_000;
    cfg.pipeline.loss_timeout_ms = 120_000;
}

#[test]
fn bad_frames_end_as_error_records() {
    let mut cfg = test_config("bad");
    let dir = std::env::temp_dir().join(format!("psgrasp-bad-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    // One good frame rendered from the synthetic scene, then NaN-only, zero-only, wrong size, corrupt.
    let mut synth = psgrasp::sources::SyntheticSource::new(&cfg);
    let good = synth.render(0).unwrap();
    save_depth_npy(&dir.join("0-good.npy"), &good).unwrap();
    let w = good.width;
    let h = good.height;
    save_depth_npy(
        &dir.join("1-nan.npy"),
        &psgrasp_geometry::DepthImage::from_metres(w, h, vec![f32::NAN; (w * h) as usize]).unwrap(),
    )
    .unwrap();
    save_depth_npy(
        &dir.join("2-zero.npy"),
        &psgrasp_geometry::DepthImage::from_metres(w, h, vec![0.0; (w * h) as usize]).unwrap(),
    )
    .unwrap();
    save_depth_npy(
        &dir.join("3-small.npy"),
        &psgrasp_geometry::DepthImage::from_metres(10, 10, vec![0.5; 100]).unwrap(),
    )
    .unwrap();
    std::fs::write(dir.join("4-corrupt.npy"), b"\x93NUMPY garbage").unwrap();
    lossless_replay(&mut cfg, &dir, 5);
    let (report, mut sup) = run_frames(&cfg, 5, Duration::from_secs(120), &bin_dir()).unwrap();
    sup.shutdown(Duration::from_secs(3));
    std::fs::remove_dir_all(&dir).ok();
    let statuses: Vec<(StatusCode, Option<Stage>, String)> = report
        .outcomes
        .values()
        .map(|o| (o.status(), o.error_stage(), o.header.error_text()))
        .collect();
    assert_eq!(statuses.len(), 5, "{statuses:?}");
    assert_eq!(statuses[0].0, StatusCode::Ok, "{statuses:?}");
    for (status, stage, text) in &statuses[1..] {
        assert_eq!(*status, StatusCode::InvalidDepth, "{statuses:?}");
        assert_eq!(*stage, Some(Stage::CameraIngest));
        assert!(!text.is_empty());
    }
    assert!(
        statuses[1].2.contains("no valid pixel"),
        "{}",
        statuses[1].2
    );
    assert!(statuses[3].2.contains("10×10"), "{}", statuses[3].2);
    assert!(statuses[4].2.contains("npy"), "{}", statuses[4].2);
}

#[test]
fn malformed_config_is_refused_with_a_clear_message() {
    let dir = std::env::temp_dir().join(format!("psgrasp-cfg-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let bad = dir.join("bad.toml");
    std::fs::write(&bad, "[pipeline.workers]\ninference = 0\n").unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_psgrasp"))
        .arg("check-config")
        .arg(&bad)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("pipeline.workers.inference"), "{err}");
    // A stage binary given the same file exits with an error instead of running.
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_psgrasp-inference"))
        .arg("--config")
        .arg(&bad)
        .output()
        .unwrap();
    assert!(!out.status.success());
    std::fs::write(&bad, "this is not toml = = \n").unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_psgrasp"))
        .arg("check-config")
        .arg(&bad)
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("malformed config"));
    std::fs::remove_dir_all(&dir).ok();
}

/// `psgrasp eval` and `psgrasp detect` run the perception chain in one process
/// (`Perception::detect`); the pipeline runs the same steps one per process. One frame through
/// both must give the same picks, bit for bit: for the shipped model and the analytic backend
/// (whose contacts are kept inside the bin by the cell's `perception.contact_region_inset_m`).
#[test]
fn the_evaluation_runs_exactly_what_the_pipeline_runs() {
    // The third run also tests the fingers against the frame's height map, which travels after
    // the normal grid in the same shared-memory message.
    for kind in ["learned", "analytic", "learned-surface"] {
        let mut cfg = shipped_config(&format!("same-{kind}"));
        if kind == "analytic" {
            cfg.cell.inference = BackendConfig::Analytic(Default::default());
        }
        cfg.cell.selection.surface_check.enabled = kind.ends_with("surface");
        // Twelve objects: a frame whose picks differ between the quality order and the shipped
        // cell's confident-first order (with eight, the best picks all lie above the floor).
        cfg.camera.synthetic.objects = 12;
        cfg.pipeline.seed = 11;
        // A known hand-eye calibration: the camera 1.1 m above a base whose origin lies 0.4 m
        // to its side, looking down, turned 30° about the vertical.
        let base_from_camera = [
            [0.866_025_403_784_438_6, 0.5, 0.0, 0.4],
            [0.5, -0.866_025_403_784_438_6, 0.0, -0.1],
            [0.0, 0.0, -1.0, 1.1],
            [0.0, 0.0, 0.0, 1.0],
        ];
        cfg.cell.robot.camera_in_base = Some(psgrasp_geometry::PoseSetting {
            matrix: Some(base_from_camera),
            ..Default::default()
        });
        // The frame in one process first, with the camera as the frame header carries it.
        let header = psgrasp_ipc::FrameHeader::new(
            psgrasp_ipc::MessageKind::DepthFrame,
            1,
            0,
            &cfg.camera_model(),
            &cfg.cell.workspace,
            0,
        );
        let mut chain = psgrasp_perception::Perception::new(&cfg.cell).unwrap();
        // The learned runs' second chain, in the quality order (the analytic run needs none).
        let mut by_quality = kind.starts_with("learned").then(|| {
            let mut by_quality_cell = cfg.cell.clone();
            by_quality_cell.selection.pick_order = PickOrder::Quality;
            psgrasp_perception::Perception::new(&by_quality_cell).unwrap()
        });
        let order = |picks: &[psgrasp_selection::SelectedGrasp]| {
            picks
                .iter()
                .map(|p| (p.configuration_index, p.approach_index))
                .collect::<Vec<_>>()
        };
        // The learned runs need a frame whose picks differ between the quality order and the
        // shipped cell's confident-first order (below); which scene has one depends on the
        // model, so take the first of eight scenes that does.
        let mut source = psgrasp::sources::SyntheticSource::new(&cfg);
        let per_scene = cfg.camera.synthetic.frames_per_scene;
        let mut chosen = None;
        for scene in 0..8u64 {
            let depth = source.render(scene * per_scene).unwrap();
            let detection = chain
                .detect(&depth, &header.camera(), cfg.pipeline.seed)
                .unwrap();
            let tells_orders_apart = by_quality.as_mut().is_none_or(|by_quality| {
                let quality = by_quality
                    .detect(&depth, &header.camera(), cfg.pipeline.seed)
                    .unwrap();
                order(&quality.selection.picks) != order(&detection.selection.picks)
            });
            if tells_orders_apart {
                chosen = Some((depth, detection));
                break;
            }
        }
        let (depth, detection) = chosen
            .unwrap_or_else(|| panic!("{kind}: no scene of 8 tells the two pick orders apart"));

        let dir = std::env::temp_dir().join(format!("psgrasp-same-{kind}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        save_depth_npy(&dir.join("0.npy"), &depth).unwrap();
        lossless_replay(&mut cfg, &dir, 1);
        let (report, mut sup) = run_frames(&cfg, 1, Duration::from_secs(240), &bin_dir()).unwrap();
        sup.shutdown(Duration::from_secs(3));
        std::fs::remove_dir_all(&dir).ok();
        let outcome = report.outcomes.values().next().expect("one outcome");
        assert_eq!(
            outcome.status(),
            StatusCode::Ok,
            "{}",
            outcome.header.error_text()
        );
        let base = cfg
            .cell
            .robot_cell()
            .unwrap()
            .base_frame(&header.camera().workspace_from_camera);
        let in_process = psgrasp::grasp_selection::pick_records(
            &detection.selection,
            &detection.configurations,
            cfg.cell.selection.top_k,
            &base,
        );
        assert!(!in_process.is_empty(), "{kind}: the frame must have picks");
        if kind.starts_with("learned") {
            // The shipped cell takes the picks whose κ is above the model card's floor first,
            // and the floor travels with the grasp set: this frame has configurations on both
            // sides of it and its picks differ between the two orders (chosen above), so the
            // pipeline's picks below match only if the floor arrived.
            assert_eq!(cfg.cell.selection.pick_order, PickOrder::ConfidentFirst);
            let at_floor = detection
                .configurations
                .iter()
                .filter(|c| c.kappa <= c.kappa_floor)
                .count();
            assert!(
                detection.configurations.iter().all(|c| c.kappa_floor > 0.0)
                    && at_floor > 0
                    && at_floor < detection.configurations.len(),
                "{kind}: {at_floor} of {} configurations at the floor",
                detection.configurations.len()
            );
        }
        assert_eq!(
            detection.selection.rejected.surface_collision > 0,
            cfg.cell.selection.surface_check.enabled,
            "{kind}: the height map refuses some approaches exactly when enabled: {:?}",
            detection.selection.rejected
        );
        assert_eq!(
            outcome.picks, in_process,
            "{kind}: pipeline vs in-process chain"
        );
        // Every pick in the robot base frame is the calibration applied to its workspace pose:
        // base ← camera (configured) ← workspace (the frame's camera pose), as plain matrices.
        let calibration = nalgebra::Matrix4::from_fn(|i, j| base_from_camera[i][j]);
        let workspace_from_camera = header
            .camera()
            .workspace_from_camera
            .to_homogeneous()
            .cast::<f64>();
        let base_from_workspace = calibration * workspace_from_camera.try_inverse().unwrap();
        for p in &outcome.picks {
            assert_eq!(p.base_calibrated, 1);
            let expected = base_from_workspace * p.workspace_from_gripper().to_homogeneous().cast();
            let got = p.base_from_gripper().to_homogeneous().cast::<f64>();
            assert!(
                (expected - got).abs().max() < 1e-5,
                "{kind}: rank {} base pose\n{got}\nexpected\n{expected}",
                p.rank
            );
            let pre = nalgebra::Point3::from(p.pregrasp_position)
                .cast::<f64>()
                .to_homogeneous();
            let pre_base = base_from_workspace * pre;
            let got = nalgebra::Vector3::from(p.base_pregrasp_position).cast::<f64>();
            assert!((pre_base.xyz() - got).norm() < 1e-5, "{kind}: pre-grasp");
            let cam = p.base_from_camera().to_homogeneous().cast::<f64>();
            assert!(
                (cam - calibration).abs().max() < 1e-6,
                "{kind}: camera pose"
            );
        }
    }
}

/// A stage that cannot start (here: inference with a model directory that does not exist) is
/// restarted with backoff, then `psgrasp up` stops the pipeline and exits non-zero naming the
/// stage, instead of running on with a pipeline that answers nothing (issue 19, failure 5).
#[test]
fn up_fails_when_a_stage_cannot_stay_up() {
    let mut cfg = test_config("giveup");
    cfg.cell.inference =
        BackendConfig::for_model_dir(std::path::Path::new("/nonexistent/model"), 1);
    cfg.pipeline.max_restarts = 2;
    cfg.pipeline.restart_backoff_ms = 20;
    let path = write_temp_config(&cfg, "giveup").unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_psgrasp"))
        .arg("up")
        .arg("--config")
        .arg(&path)
        .output()
        .unwrap();
    std::fs::remove_file(&path).ok();
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(!out.status.success(), "{text}");
    assert!(
        text.contains("inference[0] gave up after 2 restarts"),
        "{text}"
    );
    assert!(
        text.contains("restarts in 20 ms") && text.contains("restarts in 40 ms"),
        "{text}"
    );
    assert_eq!(
        nodes_of(&cfg.pipeline.name),
        0,
        "no residue after the failed pipeline"
    );
}
