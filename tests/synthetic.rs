//! The synthetic reef end to end: render three visits with no change, reconstruct
//! them jointly, score the result against the exact truth; two of them again
//! with one shared, self-calibrated camera; a storm's change mapped between two visits; two
//! visits a year of coral growth apart mapped change-aware.

mod common;

use common::{read_json, run_err, run_ok};

#[test]
fn growing_corals_are_in_the_truth_of_changes() {
    let dir = tempfile::tempdir().unwrap();
    let reef = dir.path().join("reef");
    let reef_s = reef.to_str().unwrap();
    let synth = ["synth", "--out", reef_s, "--sessions", "2", "--images-per-session", "2", "--size", "64x48"];
    run_ok(&[&synth[..], &["--change", "strong", "--growth", "branching=0.3"]].concat());
    let mut table = csv::Reader::from_path(reef.join("truth/changes_s1-s2.csv")).unwrap();
    let header = table.headers().unwrap().clone();
    let column = |name: &str| header.iter().position(|h| h == name).unwrap();
    let (kind, change, growth) = (column("kind"), column("change"), column("growth"));
    let mut grown_branching = 0;
    for row in table.records().map(Result::unwrap) {
        let g: f64 = row[growth].parse().unwrap();
        if row[kind] == *"branching_coral" && row[change] == *"grown" {
            assert!((0.15..=0.45).contains(&g), "{row:?}");
            grown_branching += 1;
        }
        if row[kind] == *"rock" || row[kind] == *"pebble" {
            assert_eq!(g, 0.0, "{row:?}");
        }
    }
    assert!(grown_branching > 5, "{grown_branching} branching corals grew");

    let stderr = run_err(&[&synth[..], &["--growth", "branching=fast"]].concat());
    let first = stderr.lines().next().unwrap_or_default();
    assert!(first.contains("--growth") && first.contains("\"fast\" is not a number"), "{stderr}");
}

#[test]
fn unchanged_reef_reconstructs_to_subpixel_cross_visit_error() {
    let dir = tempfile::tempdir().unwrap();
    let reef = dir.path().join("reef");
    let work = dir.path().join("work");
    let reef_s = reef.to_str().unwrap();
    run_ok(&[
        "synth",
        "--out",
        reef_s,
        "--sessions",
        "3",
        "--images-per-session",
        "40",
        "--change",
        "none",
        "--seed",
        "0",
    ]);

    let mut args: Vec<String> = vec!["reconstruct".into(), "--out".into(), work.to_str().unwrap().into()];
    let mut names: Vec<String> = std::fs::read_dir(reef.join("sessions"))
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    names.sort();
    assert_eq!(names.len(), 3);
    for name in &names {
        args.push("--session".into());
        args.push(format!("{name}={}", reef.join("sessions").join(name).display()));
    }
    // An unchanged reef links with SIFT alone: this is the spine's test.
    args.extend(["--max-features", "1024", "--cross", "sift"].map(String::from));
    run_ok(&args.iter().map(String::as_str).collect::<Vec<_>>());
    let report = read_json(&work.join("report.json"));
    assert_eq!(report["models"], 1, "{report:#}");
    for name in &names {
        let session = &report["sessions"][name];
        assert_eq!(session["registered"], session["images"], "session {name}: {report:#}");
    }

    let mut points: Vec<String> = std::fs::read_dir(reef.join("truth"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.file_name().unwrap().to_str().unwrap().starts_with("evaluation_points_"))
        .map(|p| p.display().to_string())
        .collect();
    points.sort();
    assert_eq!(points.len(), 3, "one click file per session pair");
    let json = work.join("eval.json");
    let mut eval: Vec<String> = vec!["eval".into(), "--model".into(), work.join("model").display().to_string()];
    eval.push("--points".into());
    eval.extend(points);
    // Exact synthetic clicks and sparse keypoints: score the point at the
    // click's own pixel (see `revisit eval --help`).
    eval.extend(["--radius-px", "8", "--at-click-depth"].map(String::from));
    eval.extend([
        "--truth".into(),
        reef.join("truth").display().to_string(),
        "--json".into(),
        json.display().to_string(),
    ]);
    run_ok(&eval.iter().map(String::as_str).collect::<Vec<_>>());
    let scores = read_json(&json);
    println!("synthetic, change none: {scores:#}");
    assert_eq!(scores["one_model"], true);
    assert!(scores["scored"].as_u64().unwrap() >= 100, "too few clicks scored: {scores:#}");
    let median_px = scores["median_px"].as_f64().unwrap();
    assert!(median_px < 1.0, "median cross-session reprojection error {median_px} px");
    let centre_rel = scores["truth"]["overall"]["centre_median_rel"].as_f64().unwrap();
    assert!(centre_rel < 0.01, "camera-centre error {centre_rel} of the scene size");

    // The change map of a reef that did not change, from each visit's dense surface (the
    // default): measured over the visits' overlap, and no region beyond its level of detection.
    let change = dir.path().join("change");
    let (work_s, change_s) = (work.to_str().unwrap(), change.to_str().unwrap());
    let truth_s = reef.join("truth").display().to_string();
    let change_args = ["change", "--model", work_s, "--from", "s1", "--to", "s3", "--out", change_s];
    let out = run_ok(&[&change_args[..], &["--truth", &truth_s]].concat());
    println!("{}", String::from_utf8_lossy(&out.stdout));
    let summary = read_json(&change.join("change_s1-s3.json"));
    assert_eq!(summary["surface"], "dense");
    for (k, visit) in ["s1", "s3"].iter().enumerate() {
        let made = &summary["dense"][k];
        assert_eq!(made["visit"], *visit);
        assert_eq!(made["fused"], made["images"], "every image with at least two partners: {made:#}");
        let ply = std::fs::read(change.join("dense").join(format!("{visit}.ply"))).unwrap();
        let header = String::from_utf8_lossy(&ply[..300]).to_string();
        assert!(header.contains(&format!("element vertex {}\n", made["points"])), "{header}");
        assert!(made["points"].as_u64().unwrap() > 10_000, "{made:#}");
    }
    // Made once: a second map of the same model reads the surfaces back.
    let again = run_ok(&change_args);
    assert_eq!(String::from_utf8_lossy(&again.stdout).matches("(made before,").count(), 2);
    assert_eq!(read_json(&change.join("change_s1-s3.json"))["regions"], summary["regions"]);
    let measured = summary["cells_measured"].as_u64().unwrap();
    assert!(measured >= 300, "{summary:#}");
    assert_eq!(summary["regions"].as_array().unwrap().len(), 0, "{summary:#}");
    assert_eq!(summary["truth"]["regions"], 0);
    let ply = std::fs::read(change.join("change_s1-s3.ply")).unwrap();
    assert!(String::from_utf8_lossy(&ply[..400]).contains(&format!("element vertex {measured}\n")));
    let csv = std::fs::read_to_string(change.join("regions_s1-s3.csv")).unwrap();
    assert_eq!(csv.lines().count(), 1, "header only: {csv}");
    let png = image::open(change.join("change_s1-s3.png")).unwrap();
    assert!(png.width() >= 520);
    // From the model's sparse points: no region either.
    let sparse = dir.path().join("change-sparse");
    run_ok(&[
        "change",
        "--model",
        work_s,
        "--from",
        "s1",
        "--to",
        "s3",
        "--out",
        sparse.to_str().unwrap(),
        "--surface",
        "sparse",
    ]);
    let summary = read_json(&sparse.join("change_s1-s3.json"));
    assert!(summary["cells_measured"].as_u64().unwrap() >= 300, "{summary:#}");
    assert_eq!(summary["regions"].as_array().unwrap().len(), 0, "{summary:#}");
    let err = run_err(&["change", "--model", work_s, "--from", "s1", "--to", "s9", "--out", change_s]);
    assert!(err.contains("visit s9 has no image in the model (its visits: s1, s2, s3)"), "{err}");
    assert_eq!(err.lines().count(), 1, "{err}");
    let err = run_err(&[&change_args[..], &["--max-seen-through", "2"]].concat());
    assert!(err.contains("--max-seen-through: 2 is not a share from 0 to 1"), "{err}");
    assert_eq!(err.lines().count(), 1, "{err}");

    // Visits flown with one uncalibrated camera share it and refine it jointly: one camera for
    // both, and still sub-pixel across them.
    let two = ["s1", "s2"];
    let shared = dir.path().join("shared-camera");
    let report = common::reconstruct_uncalibrated(&reef, &two, &shared, &["--cross", "sift", "--shared-camera"]);
    assert_eq!(common::fully_registered(&report), two, "{report:#}");
    let camera_ids: Vec<&serde_json::Value> =
        two.iter().map(|s| &report["sessions"][s]["cameras"]["640x480"]["camera_id"]).collect();
    assert!(camera_ids.iter().all(|id| *id == camera_ids[0]), "{report:#}");
    let shared_px = common::cross_error_px(&reef, &two, &shared).expect("clicks scored");
    assert!(shared_px < 1.0, "shared camera: median cross-visit error {shared_px} px");
}

/// A storm moves and removes corals: two visits mapped jointly with their navigation, the
/// change map between them puts its regions on corals that changed and finds most of the moved
/// and removed ones it measured (small colonies included: 9 of 11 on this survey; 8 when every
/// region had to pass the test made for changes beside structures both visits saw, 4 with the
/// previous, coarser map).
#[test]
fn a_storm_change_map_finds_the_corals_it_moved_or_removed() {
    let dir = tempfile::tempdir().unwrap();
    let (reef, work, change) = (dir.path().join("reef"), dir.path().join("work"), dir.path().join("change"));
    let reef_s = reef.to_str().unwrap();
    let synth = ["synth", "--out", reef_s, "--sessions", "2", "--images-per-session", "16", "--change", "storm"];
    run_ok(&[&synth[..], &["--seed", "5"]].concat());
    let nav = common::nav_args(&reef, &["s1", "s2"]);
    let nav: Vec<&str> = nav.iter().map(String::as_str).collect();
    let report = common::reconstruct(&reef, &["s1", "s2"], &work, &[&["--change-aware"], &nav[..]].concat());
    assert_eq!(report["models"], 1, "{report:#}");

    let truth_s = reef.join("truth").display().to_string();
    let (work_s, change_s) = (work.to_str().unwrap(), change.to_str().unwrap());
    run_ok(&["change", "--model", work_s, "--from", "s1", "--to", "s2", "--out", change_s, "--truth", &truth_s]);
    let scores = &read_json(&change.join("change_s1-s2.json"))["truth"];
    println!("storm change map: {scores:#}");
    let count = |key: &str| scores[key].as_u64().unwrap();
    assert!(count("targets") >= 8, "{scores:#}");
    assert_eq!(count("true_regions"), count("regions"), "false regions: {scores:#}");
    assert!(4 * count("found") >= 3 * count("targets"), "{} of {} found: {scores:#}", count("found"), count("targets"));
}

/// A year of coral growth between two visits (strong change: the sand renewed, so most
/// cross-visit matches fall on corals that grew): the plain joint solve bends one visit onto the
/// grown corals, change-aware mapping with the visits' navigation places the second visit by the
/// structure that held and keeps both visits in one model, several times nearer the truth (3.9
/// px against 9.7 px; 15 px when a grown coral's many matches outvoted the rest).
#[test]
fn change_aware_mapping_holds_through_a_year_of_growth() {
    let dir = tempfile::tempdir().unwrap();
    let (reef, work) = (dir.path().join("reef"), dir.path().join("work"));
    let reef_s = reef.to_str().unwrap();
    let synth = ["synth", "--out", reef_s, "--sessions", "2", "--images-per-session", "10", "--change", "strong"];
    run_ok(&[&synth[..], &["--seed", "3", "--growth", "yearly"]].concat());
    let nav = common::nav_args(&reef, &["s1", "s2"]);
    let nav: Vec<&str> = nav.iter().map(String::as_str).collect();
    common::reconstruct(&reef, &["s1", "s2"], &work, &nav);
    let plain_px = common::cross_error_px(&reef, &["s1", "s2"], &work).expect("clicks scored");

    let report = common::reconstruct(&reef, &["s1", "s2"], &work, &[&["--change-aware"], &nav[..]].concat());
    assert_eq!(report["features"]["done"], 0, "only mapping runs again: {report:#}");
    assert_eq!(report["models"], 1, "{report:#}");
    assert_eq!(common::fully_registered(&report), ["s1", "s2"], "{report:#}");
    let change_aware_px = common::cross_error_px(&reef, &["s1", "s2"], &work).expect("clicks scored");
    println!("a year of growth: change-aware {change_aware_px:.2} px, plain {plain_px:.2} px");
    assert!(change_aware_px < 6.0, "change-aware: median cross-visit error {change_aware_px} px");
    assert!(2.0 * change_aware_px < plain_px, "change-aware {change_aware_px} px against plain {plain_px} px");
}
