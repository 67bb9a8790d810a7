//! Shared helpers of the end-to-end tests: the `revisit` binary, the
//! project's Python environment and the shared data, as a user has them.
#![allow(dead_code, clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

pub use revisit_testkit::python;

/// `../shared/data/<rel>` beside the checkout.
pub fn shared_data(rel: &str) -> PathBuf {
    revisit_testkit::shared(&format!("data/{rel}"))
}

/// The shared model files (`../shared/models`), as a user points
/// `REVISIT_MODELS` at them.
pub fn models() -> PathBuf {
    revisit_testkit::shared("models")
}

/// The `revisit` binary with the project's Python and the shared models.
pub fn revisit() -> Command {
    let mut command = Command::new(env!("CARGO_BIN_EXE_revisit"));
    command.env("REVISIT_PYTHON", python()).env("REVISIT_MODELS", models());
    command.env("RUST_LOG", format!("warn,{}", revisit_node::QUIET_DDS));
    command
}

/// Runs `revisit` and returns its output, failing the test with stderr if it failed.
pub fn run_ok(args: &[&str]) -> Output {
    let output = revisit().args(args).output().expect("start revisit");
    assert!(output.status.success(), "revisit {args:?} failed:\n{}", String::from_utf8_lossy(&output.stderr));
    output
}

/// Runs `revisit`, expects it to fail, and returns its stderr.
pub fn run_err(args: &[&str]) -> String {
    let output = revisit().args(args).output().expect("start revisit");
    assert!(!output.status.success(), "revisit {args:?} should have failed");
    String::from_utf8_lossy(&output.stderr).into_owned()
}

pub fn read_json(path: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_str(&text).expect("valid JSON")
}

/// Copies the first `n` images (sorted) of a folder into a new folder.
pub fn copy_first(from: &Path, n: usize, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    let mut names: Vec<_> = std::fs::read_dir(from).unwrap().map(|e| e.unwrap().file_name()).collect();
    names.sort();
    for name in names.into_iter().take(n) {
        std::fs::copy(from.join(&name), to.join(&name)).unwrap();
    }
}

/// The survey's calibrated camera as `--camera` takes it (every session of
/// the synthetic reef has the same one).
pub fn camera(reef: &Path) -> String {
    let intrinsics = read_json(&reef.join("truth/intrinsics.json"));
    let first = &intrinsics[0];
    let params: Vec<String> = first["params"].as_array().unwrap().iter().map(|p| p.to_string()).collect();
    format!("{}:{}", first["model"].as_str().unwrap(), params.join(","))
}

/// `revisit reconstruct` over `sessions` of the reef into `work`, with the
/// calibrated camera and `extra` options.
pub fn reconstruct(reef: &Path, sessions: &[&str], work: &Path, extra: &[&str]) -> serde_json::Value {
    let camera = ["--camera".to_owned(), camera(reef)];
    let report =
        reconstruct_uncalibrated(reef, sessions, work, &[&camera.each_ref().map(String::as_str)[..], extra].concat());
    assert_calibration_held(work, &camera[1]);
    report
}

/// Every camera of `work`'s models has the calibration `camera` gave (`MODEL:p1,p2,...`):
/// mapping holds a calibrated camera fixed.
pub fn assert_calibration_held(work: &Path, camera: &str) {
    let params: Vec<f64> = camera.split_once(':').unwrap().1.split(',').map(|p| p.parse().unwrap()).collect();
    if !work.join("model").is_dir() {
        return;
    }
    for (path, model) in revisit_colmap::read_models(&work.join("model")).unwrap() {
        for camera in model.cameras.values() {
            assert_eq!(camera.params, params, "{}: camera {} was refined", path.display(), camera.camera_id);
        }
    }
}

/// `revisit reconstruct` over `sessions` of the reef into `work` with `extra` options only.
pub fn reconstruct_uncalibrated(reef: &Path, sessions: &[&str], work: &Path, extra: &[&str]) -> serde_json::Value {
    let mut args: Vec<String> = vec!["reconstruct".into(), "--out".into(), work.display().to_string()];
    for name in sessions {
        args.push("--session".into());
        args.push(format!("{name}={}", reef.join("sessions").join(name).display()));
    }
    args.extend(["--max-features", "1024"].map(String::from));
    args.extend(extra.iter().map(|s| s.to_string()));
    run_ok(&args.iter().map(String::as_str).collect::<Vec<_>>());
    read_json(&work.join("report.json"))
}

/// `--nav NAME=CSV` for each of `sessions`, from the navigation `revisit synth` wrote for the reef.
pub fn nav_args(reef: &Path, sessions: &[&str]) -> Vec<String> {
    sessions
        .iter()
        .flat_map(|s| ["--nav".into(), format!("{s}={}", reef.join(format!("nav/{s}.csv")).display())])
        .collect()
}

/// Median cross-session reprojection error (px) of `work`'s chosen model
/// over the truth's clicks between `sessions`, or None if nothing scored.
pub fn cross_error_px(reef: &Path, sessions: &[&str], work: &Path) -> Option<f64> {
    let report = read_json(&work.join("report.json"));
    let model = report["chosen_model"].as_str()?.to_owned();
    let mut args = vec!["eval".to_owned(), "--model".to_owned(), model, "--points".to_owned()];
    for (i, a) in sessions.iter().enumerate() {
        for b in &sessions[i + 1..] {
            args.push(reef.join("truth").join(format!("evaluation_points_{a}-{b}.csv")).display().to_string());
        }
    }
    let json = work.join("eval.json");
    args.extend(["--radius-px", "8", "--at-click-depth", "--json"].map(String::from));
    args.push(json.display().to_string());
    run_ok(&args.iter().map(String::as_str).collect::<Vec<_>>());
    let scores = read_json(&json);
    println!("{}: {} clicks scored, median {} px", work.display(), scores["scored"], scores["median_px"]);
    scores["median_px"].as_f64()
}

/// Sessions with every image registered in the chosen model.
pub fn fully_registered(report: &serde_json::Value) -> Vec<String> {
    let sessions = report["sessions"].as_object().unwrap();
    sessions.iter().filter(|(_, s)| s["registered"] == s["images"]).map(|(name, _)| name.clone()).collect()
}
