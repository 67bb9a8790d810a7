//! The mapper stage: one joint COLMAP run over a Revisit store, driven through
//! pycolmap from the project's virtual environment.
//!
//! This is the only place in Revisit that starts Python. The entry point is
//! embedded in the binary and written next to the output before each run, so
//! an installed `revisit` needs nothing but a Python with pycolmap.

use std::path::{Path, PathBuf};
use std::process::Command;

use serde::{Deserialize, Serialize};

const ENTRY_POINT: &str = include_str!("../python/revisit_mapper.py");

/// Environment variable naming the Python interpreter to use.
pub const PYTHON_ENV: &str = "REVISIT_PYTHON";

#[derive(Debug, thiserror::Error)]
pub enum MapperError {
    #[error(
        "no Python environment with pycolmap found (looked for {looked}); run scripts/setup.sh, \
         or pass --python / set {PYTHON_ENV}"
    )]
    NoPython { looked: String },
    #[error("Python {python} cannot import pycolmap: {stderr}")]
    NoPycolmap { python: PathBuf, stderr: String },
    #[error("could not start {python}: {source}")]
    Spawn { python: PathBuf, source: std::io::Error },
    #[error("writing {path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("COLMAP mapping failed (exit {code:?}): {stderr_tail}")]
    Failed { code: Option<i32>, stderr_tail: String },
    #[error("COLMAP mapping printed no summary: {0}")]
    BadSummary(String),
}

/// Which COLMAP mapper runs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Engine {
    /// Incremental SfM (COLMAP's default); can extend an existing model.
    #[default]
    Incremental,
    /// Global SfM (GLOMAP).
    Global,
}

/// Options of the mapper stage.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MapperOptions {
    /// Default incremental.
    pub engine: Engine,
    /// Seed of COLMAP's random choices. Default 0.
    pub seed: u64,
    /// Threads; -1 = all cores. Default -1.
    pub threads: i32,
    /// Smallest model COLMAP keeps, in images. Default 10 (COLMAP's).
    pub min_model_size: usize,
    /// Refine focal lengths and distortion in bundle adjustment. Default
    /// true; false for calibrated cameras, whose intrinsics are held fixed.
    pub refine_intrinsics: bool,
}

impl Default for MapperOptions {
    fn default() -> Self {
        Self { engine: Engine::Incremental, seed: 0, threads: -1, min_model_size: 10, refine_intrinsics: true }
    }
}

/// One model the mapper produced.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ModelSummary {
    /// Folder holding the binary model.
    pub path: PathBuf,
    /// Names (`session/file`) of the registered images, sorted.
    pub registered_images: Vec<String>,
    pub points: usize,
    pub mean_reprojection_error_px: f64,
}

#[derive(Debug, Deserialize)]
struct Summary {
    models: Vec<ModelSummary>,
}

/// Finds the Python interpreter: `explicit` if given, else `$REVISIT_PYTHON`,
/// else `.venv/bin/python` in the current folder or any parent of the
/// executable's folder (a checkout's `target/release/revisit` finds the
/// checkout's `.venv`). Checks that it imports pycolmap.
pub fn find_python(explicit: Option<&Path>) -> Result<PathBuf, MapperError> {
    let mut candidates: Vec<PathBuf> = Vec::new();
    if let Some(path) = explicit {
        candidates.push(path.to_path_buf());
    } else if let Some(env) = std::env::var_os(PYTHON_ENV) {
        candidates.push(PathBuf::from(env));
    } else {
        let venv = Path::new(".venv").join("bin").join("python");
        if let Ok(cwd) = std::env::current_dir() {
            candidates.push(cwd.join(&venv));
        }
        if let Ok(exe) = std::env::current_exe() {
            candidates.extend(exe.ancestors().skip(1).map(|dir| dir.join(&venv)));
        }
    }
    let Some(python) = candidates.iter().find(|p| p.is_file()).cloned() else {
        let looked = candidates.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", ");
        return Err(MapperError::NoPython { looked });
    };
    let output = Command::new(&python)
        .args(["-c", "import pycolmap"])
        .output()
        .map_err(|source| MapperError::Spawn { python: python.clone(), source })?;
    if !output.status.success() {
        let stderr = String::from_utf8_lossy(&output.stderr);
        let last = stderr.lines().last().unwrap_or("").to_owned();
        return Err(MapperError::NoPycolmap { python, stderr: last });
    }
    Ok(python)
}

/// Maps the store `database` (images under `image_root`) into `output/<k>`,
/// k = 0, 1, ... by decreasing size, and returns every model produced.
/// `extend` is an existing model to continue (incremental engine only).
pub fn run_mapper(
    python: &Path,
    database: &Path,
    image_root: &Path,
    output: &Path,
    extend: Option<&Path>,
    options: &MapperOptions,
) -> Result<Vec<ModelSummary>, MapperError> {
    let parent = output.parent().unwrap_or(Path::new("."));
    let script = parent.join("revisit_mapper.py");
    std::fs::write(&script, ENTRY_POINT).map_err(|source| MapperError::Io { path: script.clone(), source })?;
    let mut command = Command::new(python);
    command
        .arg(&script)
        .arg("--database")
        .arg(database)
        .arg("--image-path")
        .arg(image_root)
        .arg("--output")
        .arg(output)
        .arg("--engine")
        .arg(match options.engine {
            Engine::Incremental => "incremental",
            Engine::Global => "global",
        })
        .arg("--seed")
        .arg(options.seed.to_string())
        .arg("--threads")
        .arg(options.threads.to_string())
        .arg("--min-model-size")
        .arg(options.min_model_size.to_string());
    if !options.refine_intrinsics {
        command.arg("--fixed-intrinsics");
    }
    if let (Some(input), Engine::Incremental) = (extend, options.engine) {
        command.arg("--input-path").arg(input);
    }
    tracing::debug!(?command, "starting COLMAP");
    let result = command.output().map_err(|source| MapperError::Spawn { python: python.to_path_buf(), source })?;
    let stderr = String::from_utf8_lossy(&result.stderr);
    if !result.status.success() {
        let tail: Vec<&str> = stderr.lines().rev().take(3).collect();
        let stderr_tail = tail.into_iter().rev().collect::<Vec<_>>().join(" | ");
        return Err(MapperError::Failed { code: result.status.code(), stderr_tail });
    }
    let stdout = String::from_utf8_lossy(&result.stdout);
    let line = stdout.lines().rev().find(|l| l.starts_with('{')).unwrap_or("");
    let summary: Summary = serde_json::from_str(line).map_err(|e| MapperError::BadSummary(e.to_string()))?;
    Ok(summary.models)
}
