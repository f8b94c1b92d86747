//! `psgrasp eval` end to end: a 2-scene run, resume, reports, and independence from --jobs.
use psgrasp_datagen::{Difficulty, ObjectSource};
use psgrasp_eval::records::{RecordLine, RecordsFile, RECORDS_FILE};
use psgrasp_eval::{run_eval, EvalArgs};
use std::path::Path;

fn args(out: &Path, scenes: u64, jobs: usize) -> EvalArgs {
    EvalArgs {
        detectors: vec!["analytic".into()],
        detectors_file: None,
        models_dir: out.join("no-models"),
        levels: vec![Difficulty::Easy, Difficulty::Medium],
        scenes,
        seeds: vec![3],
        jobs: Some(jobs),
        out: out.to_owned(),
        config: None,
        test_set: out.join("no-test-set"),
        generate_scenes: true,
        objects: ObjectSource::Procedural,
        mesh_dir: None,
        report_only: false,
        quiet: true,
    }
}

/// The records without wall times, in a canonical order.
fn outcomes(dir: &Path) -> Vec<String> {
    let f = RecordsFile::open(dir).unwrap();
    let mut v: Vec<String> = f
        .lines()
        .iter()
        .map(|l| match l {
            RecordLine::Attempt { key, attempt } => {
                format!("{key:?} {} {:?}", attempt.attempt, attempt.outcome)
            }
            RecordLine::Scene { key, summary } => format!(
                "{key:?} {} {} {} {:?}",
                summary.objects, summary.attempts, summary.successes, summary.end
            ),
        })
        .collect();
    v.sort();
    v
}

#[test]
fn two_scene_eval_writes_reports_and_resumes() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    // First a 1-scene run (as if killed after scene 0), then the 2-scene run resumes it.
    run_eval(&args(&out, 1, 2)).unwrap();
    let after_one = outcomes(&out);
    run_eval(&args(&out, 2, 2)).unwrap();
    let after_two = outcomes(&out);
    assert!(after_one.iter().all(|l| after_two.contains(l)));
    let finished = RecordsFile::open(&out)
        .unwrap()
        .lines()
        .iter()
        .filter(|l| matches!(l, RecordLine::Scene { .. }))
        .count();
    assert_eq!(finished, 4, "2 levels x 2 scenes");
    for f in [
        "run.json",
        "summary.md",
        "summary.json",
        "summary.png",
        RECORDS_FILE,
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    let md = std::fs::read_to_string(out.join("summary.md")).unwrap();
    assert!(md.contains("| Analytic antipodal (GPD-style) |"), "{md}");
    assert!(md.contains("2 / 2"), "{md}");
    // A third run has nothing left to do and changes no record.
    let bytes = std::fs::read(out.join(RECORDS_FILE)).unwrap();
    run_eval(&args(&out, 2, 1)).unwrap();
    assert_eq!(std::fs::read(out.join(RECORDS_FILE)).unwrap(), bytes);

    // The same run with one worker from scratch gives the same outcomes.
    let single = dir.path().join("single");
    run_eval(&args(&single, 2, 1)).unwrap();
    assert_eq!(outcomes(&single), after_two);

    // Other protocol settings in the same directory are refused.
    let cfg = dir.path().join("proto.toml");
    std::fs::write(&cfg, "max_consecutive_failures = 5\n").unwrap();
    let mut changed = args(&out, 2, 1);
    changed.config = Some(cfg);
    let err = run_eval(&changed).unwrap_err().to_string();
    assert!(err.contains("different protocol settings"), "{err}");
    // Unknown detectors and the training level are refused.
    let mut unknown = args(&out, 2, 1);
    unknown.detectors = vec!["nope".into()];
    assert!(run_eval(&unknown)
        .unwrap_err()
        .to_string()
        .contains("unknown detector"));
    let mut train = args(&out, 2, 1);
    train.levels = vec![Difficulty::Train];
    assert!(run_eval(&train).is_err());
}
