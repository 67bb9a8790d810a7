//! What Revisit's tests share: the checkout, the shared data and models
//! beside it (`../shared`), and the project's Python and ONNX Runtime (made
//! by `scripts/setup.sh`), as a user has them. A missing one fails the test
//! with a message saying what to do; tests never skip.
//!
//! Only ever a dev-dependency.

#![allow(clippy::expect_used)] // a missing fixture fails the test that needs it

use std::path::{Path, PathBuf};
use std::process::Command;

use revisit_onnx::Runtime;

/// The repository's root.
pub fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..").canonicalize().expect("the repository's root")
}

/// `../shared/<rel>` beside the checkout (`data/...`, `models/...`).
pub fn shared(rel: &str) -> PathBuf {
    let path = repo().join("../shared").join(rel);
    assert!(path.exists(), "{} is missing: the tests need ../shared beside the checkout", path.display());
    path
}

/// The project's Python (`.venv/bin/python`).
pub fn python() -> PathBuf {
    let python = repo().join(".venv/bin/python");
    assert!(python.is_file(), "{} is missing: run scripts/setup.sh", python.display());
    python
}

/// ONNX Runtime from the project's `.venv`, `threads` per model (0: all cores).
pub fn runtime(threads: usize) -> Runtime {
    let library = revisit_onnx::libraries_in_venv(&repo().join(".venv")).into_iter().next();
    let library = library.expect("ONNX Runtime in .venv: run scripts/setup.sh");
    Runtime::load(&library, threads).expect("ONNX Runtime loads")
}

/// Runs a model-generating `script` (Python, with `onnx`) with the project's
/// Python into a fresh folder, and returns the folder.
pub fn generated_models(script: &Path) -> tempfile::TempDir {
    let dir = tempfile::tempdir().expect("a temporary folder");
    let status = Command::new(python()).arg(script).arg(dir.path()).status().expect("start Python");
    assert!(status.success(), "{} failed", script.display());
    dir
}

/// Runs `crates/bag/tests/interop.py COMMAND PATH SPEC` (independent ROS 2 readers, writers and
/// a Cyclone DDS peer) to its end, failing the test with its output if it fails.
pub fn interop(command: &str, path: &Path, spec: &Path) {
    let output = interop_command(command, path, spec).output().expect("start Python");
    assert!(
        output.status.success(),
        "interop.py {command} failed:\n{}{}",
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    );
}

/// `interop.py COMMAND PATH SPEC` with the project's Python, not started.
pub fn interop_command(command: &str, path: &Path, spec: &Path) -> Command {
    let mut python = Command::new(python());
    python.arg(repo().join("crates/bag/tests/interop.py")).arg(command).arg(path).arg(spec);
    python
}
