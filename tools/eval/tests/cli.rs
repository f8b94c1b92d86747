//! `psgrasp eval` end to end: a 2-scene run, resume, reports, and independence from --jobs.
use psgrasp_datagen::{Difficulty, ObjectSource};
use psgrasp_eval::records::{RecordLine, RecordsFile, RECORDS_FILE};
use psgrasp_eval::{run_eval, EvalArgs};
use std::path::Path;

mod common;

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
        run_every_seed: false,
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
    // The analytic detector has no baseline distribution: no κ chart.
    assert!(!out.join("summary-kappa.png").exists());
    let md = std::fs::read_to_string(out.join("summary.md")).unwrap();
    assert!(md.contains("| Analytic antipodal (GPD-style) |"), "{md}");
    assert!(md.contains("2 / 2"), "{md}");
    // Every object a round left carries why it has no grasp, and the report counts them.
    let left: Vec<_> = RecordsFile::open(&out)
        .unwrap()
        .lines()
        .iter()
        .filter_map(|l| match l {
            RecordLine::Scene { summary, .. } => Some(summary.remaining_objects.clone()),
            _ => None,
        })
        .flatten()
        .collect();
    assert!(
        !left.is_empty(),
        "the analytic detector leaves objects in medium"
    );
    assert!(left.iter().all(|o| o.graspability.is_some()));
    assert!(md.contains("## Why the objects left have no grasp"), "{md}");
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

#[test]
fn a_detector_can_carry_its_own_quality_threshold() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let list = dir.path().join("detectors.toml");
    std::fs::write(
        &list,
        "[[detector]]\nname = \"analytic\"\nbackend = { kind = \"analytic\" }\n\n\
         [[detector]]\nname = \"analytic-q999\"\nbackend = { kind = \"analytic\" }\nmin_quality = 0.999\n",
    )
    .unwrap();
    let mut a = args(&out, 2, 2);
    a.detectors = vec!["analytic".into(), "analytic-q999".into()];
    a.detectors_file = Some(list.clone());
    run_eval(&a).unwrap();
    let f = RecordsFile::open(&out).unwrap();
    let qualities = |name: &str| -> Vec<f32> {
        f.lines()
            .iter()
            .filter_map(|l| match l {
                RecordLine::Attempt { key, attempt } if key.detector == name => {
                    Some(attempt.quality)
                }
                _ => None,
            })
            .collect()
    };
    let (plain, strict) = (qualities("analytic"), qualities("analytic-q999"));
    // The protocol's 0.5 lets the plain detector execute grasps below 0.999 (it picks the best
    // first, so these are 0.96-0.99); the override executes none, on the same scenes.
    assert!(plain.iter().any(|q| *q < 0.999), "{plain:?}");
    assert!(
        strict.iter().all(|q| *q >= 0.999) && strict != plain,
        "{strict:?}"
    );
    // An override outside [0, 1] is refused, naming the detector.
    std::fs::write(
        &list,
        "[[detector]]\nname = \"bad\"\nbackend = { kind = \"analytic\" }\nmin_quality = 1.5\n",
    )
    .unwrap();
    let mut bad = args(&dir.path().join("bad"), 1, 1);
    bad.detectors = vec!["bad".into()];
    bad.detectors_file = Some(list);
    let err = format!("{:#}", run_eval(&bad).unwrap_err());
    assert!(err.contains("bad") && err.contains("min_quality"), "{err}");
}

#[test]
fn executed_grasps_carry_the_detectors_kappa_and_the_report_bins_it() {
    // The shipped model on four easy scenes: every attempt records the κ of the configuration it
    // executed (at or above the model's floor κ0 = 25, from its Power-Spherical head); the
    // analytic detector has no baseline distribution (κ = 0) and gets no κ row.
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let list = common::analytic_and_shipped_detectors(dir.path());
    let mut a = args(&out, 4, 2);
    a.detectors = vec!["analytic".into(), "learned".into()];
    a.detectors_file = Some(list);
    a.levels = vec![Difficulty::Easy];
    run_eval(&a).unwrap();
    let f = RecordsFile::open(&out).unwrap();
    let kappas = |name: &str| -> Vec<Option<f32>> {
        f.lines()
            .iter()
            .filter_map(|l| match l {
                RecordLine::Attempt { key, attempt } if key.detector == name => Some(attempt.kappa),
                _ => None,
            })
            .collect()
    };
    let (analytic, learned) = (kappas("analytic"), kappas("learned"));
    assert!(!learned.is_empty() && !analytic.is_empty());
    assert!(
        learned.iter().all(|k| k.is_some_and(|k| k >= 25.0)),
        "{learned:?}"
    );
    assert!(analytic.iter().all(|k| *k == Some(0.0)), "{analytic:?}");
    let md = std::fs::read_to_string(out.join("summary.md")).unwrap();
    let section = md
        .split("## Concentration κ of the executed grasps")
        .nth(1)
        .unwrap_or("");
    assert!(learned.len() >= 4, "{learned:?}");
    assert!(section.contains("| learned | Easy |"), "{md}");
    assert!(!section.contains("| analytic |"), "{md}");
    // κ against success as a chart: one panel (easy), one group (the learned detector), its four
    // κ quarters' success rates with binomial standard errors.
    let summary: psgrasp_eval::report::Summary =
        serde_json::from_slice(&std::fs::read(out.join("summary.json")).unwrap()).unwrap();
    let chart = psgrasp_eval::kappa::chart(&summary).expect("a detector with κ");
    assert_eq!(chart.series.len(), 4);
    assert_eq!(chart.panels.len(), 1);
    let groups = &chart.panels[0].groups;
    assert_eq!(groups.len(), 1, "{chart:?}");
    let (group, bars) = &groups[0];
    assert_eq!(group, "LEARNED");
    let bins = summary.cells.iter().find_map(|c| c.kappa.clone()).unwrap();
    for (q, bar) in bars.iter().enumerate() {
        let (rate, se) = bar.unwrap();
        let n = bins.attempts[q] as f64;
        let p = bins.successes[q] as f64 / n;
        assert!((rate - p).abs() < 1e-12 && (se - (p * (1.0 - p) / n).sqrt()).abs() < 1e-12);
    }
    let png = std::fs::File::open(out.join("summary-kappa.png")).unwrap();
    let info = png::Decoder::new(std::io::BufReader::new(png))
        .read_info()
        .unwrap();
    assert!(info.info().width > 100 && info.info().height > 100);
}
