//! Where Revisit finds what it runs on: the Python environment with pycolmap,
//! the ONNX Runtime library and the learned models. One search order for all
//! three, stated once:
//!
//! 1. the path given explicitly (`--python`, `--onnxruntime`, `--models`);
//! 2. the environment variable (`REVISIT_PYTHON`, `ORT_DYLIB_PATH`, `REVISIT_MODELS`);
//! 3. the project's own (`.venv/bin/python`, the onnxruntime wheel inside
//!    `.venv`, `models/`) in the current folder, then in each folder above the
//!    executable (so a checkout's `target/release/revisit` finds the checkout's).
//!
//! Finding is cheap and checks only that the file or folder exists;
//! [`Tools::python`] also checks that Python imports pycolmap.

use std::path::{Path, PathBuf};

/// The environment variable naming the Python interpreter.
pub const PYTHON_ENV: &str = revisit_colmap::PYTHON_ENV;
/// The environment variable naming the ONNX Runtime library.
pub const ONNXRUNTIME_ENV: &str = revisit_onnx::LIBRARY_ENV;
/// The environment variable naming the folder of model files.
pub const MODELS_ENV: &str = "REVISIT_MODELS";

/// What a user gave explicitly; `None` means "search".
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Tools {
    pub python: Option<PathBuf>,
    pub onnxruntime: Option<PathBuf>,
    pub models: Option<PathBuf>,
}

/// One thing searched for: where it was found, or every place looked at.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Found {
    At(PathBuf),
    Missing { looked: Vec<PathBuf> },
}

impl Found {
    pub fn path(&self) -> Option<&Path> {
        match self {
            Found::At(path) => Some(path),
            Found::Missing { .. } => None,
        }
    }

    /// The places looked at, for an error message.
    pub fn looked(&self) -> String {
        match self {
            Found::At(path) => path.display().to_string(),
            Found::Missing { looked } => looked.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", "),
        }
    }
}

/// The folders searched in step 3: the current folder, then every folder
/// above the executable.
fn roots() -> Vec<PathBuf> {
    let mut roots: Vec<PathBuf> = std::env::current_dir().into_iter().collect();
    if let Ok(exe) = std::env::current_exe() {
        roots.extend(exe.ancestors().skip(1).map(Path::to_path_buf));
    }
    roots
}

/// Steps 1-3 for one thing: `own` lists its candidates under a root.
fn search(
    explicit: Option<&Path>,
    env: &str,
    own: impl Fn(&Path) -> Vec<PathBuf>,
    exists: impl Fn(&Path) -> bool,
) -> Found {
    let candidates: Vec<PathBuf> = match (explicit, std::env::var_os(env)) {
        (Some(path), _) => vec![path.to_path_buf()],
        (None, Some(path)) => vec![PathBuf::from(path)],
        (None, None) => roots().iter().flat_map(|root| own(root)).collect(),
    };
    match candidates.iter().find(|p| exists(p)) {
        Some(path) => Found::At(path.clone()),
        None => Found::Missing { looked: candidates },
    }
}

impl Tools {
    /// The Python interpreter (not yet checked for pycolmap).
    pub fn find_python(&self) -> Found {
        search(self.python.as_deref(), PYTHON_ENV, |root| vec![root.join(".venv/bin/python")], Path::is_file)
    }

    /// The ONNX Runtime shared library.
    pub fn find_onnxruntime(&self) -> Found {
        search(
            self.onnxruntime.as_deref(),
            ONNXRUNTIME_ENV,
            |root| revisit_onnx::libraries_in_venv(&root.join(".venv")),
            Path::is_file,
        )
    }

    /// The folder of model files.
    pub fn find_models(&self) -> Found {
        search(self.models.as_deref(), MODELS_ENV, |root| vec![root.join("models")], Path::is_dir)
    }

    /// The Python interpreter, checked to import pycolmap.
    pub fn python(&self) -> Result<PathBuf, revisit_colmap::MapperError> {
        match self.find_python() {
            Found::At(path) => revisit_colmap::check_python(&path),
            missing => Err(revisit_colmap::MapperError::NoPython { looked: missing.looked() }),
        }
    }

    /// ONNX Runtime, loaded (once per process), with `threads` threads per model (0: all cores).
    pub fn onnxruntime(&self, threads: usize) -> Result<revisit_onnx::Runtime, revisit_onnx::OnnxError> {
        match self.find_onnxruntime() {
            Found::At(path) => revisit_onnx::Runtime::load(&path, threads),
            missing => Err(revisit_onnx::OnnxError::NoLibrary { looked: missing.looked() }),
        }
    }

    /// The models folder; when none is found, the first place looked at, so
    /// that a missing model is reported under the path a user expects.
    pub fn models(&self) -> PathBuf {
        match self.find_models() {
            Found::At(path) => path,
            Found::Missing { looked } => looked.into_iter().next().unwrap_or_else(|| PathBuf::from("models")),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_explicit_path_wins_and_a_missing_one_is_named() {
        let tools = Tools { python: Some("/nonexistent/python".into()), ..Tools::default() };
        assert_eq!(tools.find_python(), Found::Missing { looked: vec!["/nonexistent/python".into()] });
        let err = tools.python().unwrap_err().to_string();
        assert!(err.contains("/nonexistent/python"), "{err}");
        let dir = tempfile::tempdir().unwrap();
        let tools = Tools { models: Some(dir.path().into()), ..Tools::default() };
        assert_eq!(tools.find_models(), Found::At(dir.path().into()));
    }
}
