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
    command.env("REVISIT_PYTHON", python()).env("REVISIT_MODELS", models()).env("RUST_LOG", "warn");
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
