//! The command line is a thin shell over the pipeline library: the same
//! survey reconstructed by `revisit reconstruct` and by `Workspace` through
//! the library API gives the same report and the same poses.

#![allow(clippy::unwrap_used)]

mod common;

use std::path::Path;

use common::{python, run_ok};
use revisit_pipeline::ingest::{scan_session, SessionSpec};
use revisit_pipeline::locate::Tools;
use revisit_pipeline::{Cancel, CrossStrategy, ReconstructOptions, Report, Silent, Workspace};

/// The report with what differs between two work folders taken out: timings
/// and the model's path (relative to its work folder instead).
fn comparable(mut report: Report, work: &Path) -> Report {
    // Time and memory are measured, not computed: they differ from run to run.
    report.seconds.clear();
    report.peak_rss_mib.clear();
    if let Some(change_aware) = &mut report.mapping.change_aware {
        change_aware.seconds = 0.0;
    }
    report.chosen_model = report.chosen_model.map(|m| m.strip_prefix(work).unwrap().to_path_buf());
    report
}

#[test]
fn the_binary_and_the_library_give_the_same_report_and_poses() {
    let dir = tempfile::tempdir().unwrap();
    let reef = dir.path().join("reef");
    let reef_arg = reef.to_str().unwrap();
    run_ok(&["synth", "--out", reef_arg, "--sessions", "2", "--images-per-session", "6", "--change", "none"]);
    let sessions = ["s1", "s2"].map(|s| (s, reef.join("sessions").join(s)));

    let by_binary = dir.path().join("binary");
    let mut args = vec!["reconstruct".to_owned(), "--out".into(), by_binary.display().to_string()];
    for (name, folder) in &sessions {
        args.extend(["--session".to_owned(), format!("{name}={}", folder.display())]);
    }
    args.extend(["--cross", "sift", "--max-features", "1024"].map(String::from));
    run_ok(&args.iter().map(String::as_str).collect::<Vec<_>>());

    let by_library = dir.path().join("library");
    let mut options = ReconstructOptions { cross: CrossStrategy::Sift, ..Default::default() };
    options.features.sift.max_num_features = 1024;
    let tools = Tools { python: Some(python()), models: Some(common::models()), onnxruntime: None };
    let mut workspace = Workspace::open(&by_library, options, tools).unwrap();
    for (name, folder) in &sessions {
        let spec = SessionSpec { name: (*name).to_owned(), dir: folder.clone() };
        workspace.add_session(scan_session(&spec).unwrap()).unwrap();
    }
    let library_report = workspace.run(&Silent, &Cancel::new()).unwrap();

    let binary_report = Report::read(&by_binary.join("report.json")).unwrap();
    assert_eq!(binary_report.models, 1, "{binary_report:#?}");
    assert_eq!(comparable(library_report, &by_library), comparable(binary_report, &by_binary));
    let poses = |work: &Path| std::fs::read_to_string(work.join("poses.csv")).unwrap();
    assert_eq!(poses(&by_library), poses(&by_binary));
}

#[test]
fn doctor_says_what_is_ready_and_what_is_not() {
    let output = run_ok(&["doctor"]);
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(stdout.contains("everything is ready"), "{stdout}");
    assert_eq!(stdout.lines().filter(|l| l.starts_with("ready")).count(), 8, "{stdout}");

    let empty = tempfile::tempdir().unwrap();
    let output = common::revisit().args(["doctor", "--models", empty.path().to_str().unwrap()]).output().unwrap();
    assert!(!output.status.success());
    let stdout = String::from_utf8_lossy(&output.stdout);
    let missing: Vec<&str> = stdout.lines().filter(|l| l.starts_with("MISSING")).collect();
    assert_eq!(missing.len(), 5, "{stdout}");
    assert!(missing.iter().all(|l| l.contains("scripts/get-models.sh")), "{stdout}");
}
