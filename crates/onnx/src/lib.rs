//! ONNX Runtime for Revisit's learned models.
//!
//! The runtime is a shared library loaded at run time (`ort`'s `load-dynamic`;
//! the project's `.venv` has it, from PyPI's `onnxruntime` wheel, and
//! `revisit_pipeline::locate` finds it). [`Runtime::load`] checks that it
//! exists before `ort` touches it, because `ort` panics on a missing library. [`Model::open`] opens a model and
//! checks its inputs and outputs against the [`Contract`] the caller expects,
//! so a wrong file is one clear error naming the file and the input or output
//! at fault rather than a shape error (or a panic) deep inside a run. Outputs
//! are checked again after every run, and [`Model::check_output`] checks the
//! sizes that follow the inputs.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use ndarray::{ArrayD, ArrayViewD};
use ort::session::Session;
use ort::value::TensorRef;

/// The environment variable naming the ONNX Runtime library, as `ort` reads it.
pub const LIBRARY_ENV: &str = "ORT_DYLIB_PATH";

#[derive(Debug, thiserror::Error)]
pub enum OnnxError {
    #[error(
        "ONNX Runtime library not found (looked for {looked}); run scripts/setup.sh, or pass --onnxruntime / set \
         {LIBRARY_ENV}"
    )]
    NoLibrary { looked: String },
    #[error("ONNX Runtime library {path}: {message}")]
    BadLibrary { path: PathBuf, message: String },
    #[error("model {path}: file not found (scripts/get-models.sh makes the model files)")]
    MissingModel { path: PathBuf },
    #[error("model {path}: {message}")]
    BadModel { path: PathBuf, message: String },
    #[error("model {path}: input `{input}` {message}")]
    Contract { path: PathBuf, input: String, message: String },
    /// An output missing, of the wrong type, or of the wrong shape: declared
    /// so when the model is opened, or found so after a run.
    #[error("model {path}: output `{output}` {message}")]
    Output { path: PathBuf, output: String, message: String },
    #[error("model {path}: run failed: {message}")]
    Run { path: PathBuf, message: String },
}

/// A loaded ONNX Runtime. Only one library can be loaded per process; the
/// first successful [`Runtime::load`] wins and later calls share it.
#[derive(Clone)]
pub struct Runtime {
    environment: ort::environment::Environment,
    threads: usize,
}

static RUNTIME: OnceLock<Result<(PathBuf, ort::environment::Environment), String>> = OnceLock::new();

impl Runtime {
    /// Loads the ONNX Runtime library at `path` (`revisit_pipeline::locate`
    /// finds it). `threads` is the number of threads each model runs on (0:
    /// all cores).
    pub fn load(path: &Path, threads: usize) -> Result<Runtime, OnnxError> {
        // `ort` panics on a missing library: check first.
        if !path.is_file() {
            return Err(OnnxError::NoLibrary { looked: path.display().to_string() });
        }
        let loaded = RUNTIME.get_or_init(|| {
            let environment = ort::init_from(path)
                .map_err(|e| e.to_string())?
                .with_name("revisit")
                .build()
                .map_err(|e| e.to_string())?;
            Ok((path.to_path_buf(), environment))
        });
        match loaded {
            Ok((_, environment)) => Ok(Runtime { environment: environment.clone(), threads }),
            Err(message) => Err(OnnxError::BadLibrary { path: path.to_path_buf(), message: message.clone() }),
        }
    }
}

/// The `libonnxruntime.so*` files of PyPI's onnxruntime wheel inside the
/// virtual environment `venv`, sorted.
pub fn libraries_in_venv(venv: &Path) -> Vec<PathBuf> {
    let mut found = Vec::new();
    let Ok(pythons) = std::fs::read_dir(venv.join("lib")) else { return found };
    let mut pythons: Vec<PathBuf> = pythons.flatten().map(|p| p.path()).collect();
    pythons.sort();
    for python in pythons {
        let capi = python.join("site-packages").join("onnxruntime").join("capi");
        let Ok(files) = std::fs::read_dir(&capi) else { continue };
        let mut libraries: Vec<PathBuf> = files
            .flatten()
            .map(|f| f.path())
            .filter(|p| p.file_name().and_then(|n| n.to_str()).is_some_and(|n| n.starts_with("libonnxruntime.so")))
            .collect();
        libraries.sort();
        found.extend(libraries);
    }
    found
}

/// One input a model must have: its name and shape, `None` for a dimension
/// the caller chooses (dynamic in the model, or read back with
/// [`Model::input_shape`]).
#[derive(Debug, Clone, Copy)]
pub struct InputSpec {
    pub name: &'static str,
    pub shape: &'static [Option<i64>],
}

/// One output a model must have: its name and shape, `None` for a dimension
/// that follows the inputs (the caller checks it after a run with
/// [`Model::check_output`]).
#[derive(Debug, Clone, Copy)]
pub struct OutputSpec {
    pub name: &'static str,
    pub shape: &'static [Option<i64>],
}

/// The inputs and outputs a caller relies on. Extra outputs are allowed.
#[derive(Debug, Clone, Copy)]
pub struct Contract {
    pub inputs: &'static [InputSpec],
    pub outputs: &'static [OutputSpec],
}

impl Contract {
    /// The names of the outputs, in the contract's order (for [`Model::run`]).
    pub fn output_names(&self) -> Vec<&'static str> {
        self.outputs.iter().map(|o| o.name).collect()
    }
}

fn output_error(path: &Path, output: &str, message: String) -> OnnxError {
    OnnxError::Output { path: path.to_path_buf(), output: output.to_owned(), message }
}

fn check_output_shape(path: &Path, name: &str, found: &[usize], expected: &[Option<usize>]) -> Result<(), OnnxError> {
    let fits = found.len() == expected.len() && found.iter().zip(expected).all(|(&f, e)| e.is_none_or(|e| f == e));
    if fits {
        return Ok(());
    }
    Err(output_error(path, name, format!("has shape {found:?}, expected {}", expected_shape(expected))))
}

/// `[1, 64, ?, ?]`: a shape as a contract gives it, `?` for any size.
fn expected_shape<T: std::fmt::Display>(shape: &[Option<T>]) -> String {
    let dims: Vec<String> = shape.iter().map(|d| d.as_ref().map_or_else(|| "?".to_owned(), T::to_string)).collect();
    format!("[{}]", dims.join(", "))
}

/// A model input or output as declared: name, whether it is a float tensor,
/// and its shape (-1 for a dynamic dimension).
#[derive(Clone, Debug, PartialEq)]
pub struct Outlet {
    pub name: String,
    pub is_float_tensor: bool,
    pub shape: Vec<i64>,
}

impl Outlet {
    fn of(outlet: &ort::value::Outlet) -> Outlet {
        Outlet {
            name: outlet.name().to_owned(),
            is_float_tensor: outlet.dtype().tensor_type() == Some(ort::value::TensorElementType::Float32),
            shape: outlet.dtype().tensor_shape().map(|s| s.to_vec()).unwrap_or_default(),
        }
    }
}

/// An opened model that satisfies its contract.
pub struct Model {
    path: PathBuf,
    session: Session,
    /// The contract's outputs, checked again after every run.
    outputs: &'static [OutputSpec],
}

impl Model {
    /// Opens `path` and checks it against `contract`: every input by name,
    /// rank, float type and fixed dimensions, every output by name.
    pub fn open(runtime: &Runtime, path: &Path, contract: &Contract) -> Result<Model, OnnxError> {
        let mut model = Model::open_unchecked(runtime, path)?;
        model.check(contract)?;
        model.outputs = contract.outputs;
        Ok(model)
    }

    /// Opens `path` without a contract: for models whose input and output
    /// names are the user's (the caller checks [`Model::inputs`]).
    pub fn open_unchecked(runtime: &Runtime, path: &Path) -> Result<Model, OnnxError> {
        if !path.is_file() {
            return Err(OnnxError::MissingModel { path: path.to_path_buf() });
        }
        let bad = |e: ort::Error| OnnxError::BadModel { path: path.to_path_buf(), message: e.to_string() };
        let mut builder = Session::builder(&runtime.environment).map_err(bad)?;
        if runtime.threads > 0 {
            builder = builder.with_intra_threads(runtime.threads).map_err(|e| bad(e.into()))?;
        }
        let session = builder.commit_from_file(path).map_err(bad)?;
        Ok(Model { path: path.to_path_buf(), session, outputs: &[] })
    }

    /// Every input: name, element type (None if not a tensor) and declared shape.
    pub fn inputs(&self) -> Vec<Outlet> {
        self.session.inputs().iter().map(Outlet::of).collect()
    }

    /// Every output, as [`Model::inputs`].
    pub fn outputs(&self) -> Vec<Outlet> {
        self.session.outputs().iter().map(Outlet::of).collect()
    }

    fn check(&self, contract: &Contract) -> Result<(), OnnxError> {
        let error = |input: &str, message: String| OnnxError::Contract {
            path: self.path.clone(),
            input: input.to_owned(),
            message,
        };
        for spec in contract.inputs {
            let Some(outlet) = self.session.inputs().iter().find(|o| o.name() == spec.name) else {
                let names: Vec<&str> = self.session.inputs().iter().map(|o| o.name()).collect();
                return Err(error(spec.name, format!("is missing (the model's inputs are {names:?})")));
            };
            if outlet.dtype().tensor_type() != Some(ort::value::TensorElementType::Float32) {
                return Err(error(spec.name, format!("must be a float32 tensor, not {}", outlet.dtype())));
            }
            let shape: &[i64] = outlet.dtype().tensor_shape().map(|s| &s[..]).unwrap_or(&[]);
            let expected: Vec<String> =
                spec.shape.iter().map(|d| d.map_or_else(|| "?".to_owned(), |d| d.to_string())).collect();
            let fits = shape.len() == spec.shape.len()
                && shape.iter().zip(spec.shape).all(|(&got, want)| want.is_none_or(|w| got == w || got < 0));
            if !fits {
                return Err(error(spec.name, format!("has shape {shape:?}, expected [{}]", expected.join(", "))));
            }
        }
        for spec in contract.outputs {
            let error = |message: String| self.output_error(spec.name, message);
            let Some(outlet) = self.session.outputs().iter().find(|o| o.name() == spec.name) else {
                let names: Vec<&str> = self.session.outputs().iter().map(|o| o.name()).collect();
                return Err(error(format!("is missing (the model's outputs are {names:?})")));
            };
            if outlet.dtype().tensor_type() != Some(ort::value::TensorElementType::Float32) {
                return Err(error(format!("must be a float32 tensor, not {}", outlet.dtype())));
            }
            // An output declared without a shape is checked after each run only.
            let shape: &[i64] = outlet.dtype().tensor_shape().map(|s| &s[..]).unwrap_or(&[]);
            let fits = shape.len() == spec.shape.len()
                && shape.iter().zip(spec.shape).all(|(&got, want)| want.is_none_or(|w| got == w || got < 0));
            if !shape.is_empty() && !fits {
                return Err(error(format!("has shape {shape:?}, expected {}", expected_shape(spec.shape))));
            }
        }
        Ok(())
    }

    fn output_error(&self, output: &str, message: String) -> OnnxError {
        output_error(&self.path, output, message)
    }

    /// Checks the shape `found` of output `name` after a run against the
    /// shape the caller expects (`None`: any size); a mismatch is an
    /// [`OnnxError::Output`] naming the model file and the output.
    pub fn check_output(&self, name: &str, found: &[usize], expected: &[Option<usize>]) -> Result<(), OnnxError> {
        check_output_shape(&self.path, name, found, expected)
    }

    /// The declared shape of input `name` (-1 for a dynamic dimension).
    pub fn input_shape(&self, name: &str) -> Option<Vec<i64>> {
        let outlet = self.session.inputs().iter().find(|o| o.name() == name)?;
        outlet.dtype().tensor_shape().map(|s| s.to_vec())
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Runs the model on named float inputs and returns the requested float outputs.
    pub fn run(
        &mut self,
        inputs: &[(&str, ArrayViewD<'_, f32>)],
        outputs: &[&str],
    ) -> Result<HashMap<String, ArrayD<f32>>, OnnxError> {
        let path = self.path.clone();
        let fail = |e: ort::Error| OnnxError::Run { path: path.clone(), message: e.to_string() };
        let mut values = Vec::with_capacity(inputs.len());
        for (name, array) in inputs {
            let tensor = TensorRef::from_array_view(array.view()).map_err(fail)?;
            values.push((std::borrow::Cow::Borrowed(*name), ort::session::SessionInputValue::from(tensor)));
        }
        let results = self.session.run(values).map_err(fail)?;
        let mut out = HashMap::new();
        for name in outputs {
            let value = results.get(*name).ok_or_else(|| output_error(&self.path, name, "is missing".to_owned()))?;
            let array = value.try_extract_array::<f32>().map_err(|e| output_error(&self.path, name, e.to_string()))?;
            if let Some(spec) = self.outputs.iter().find(|o| o.name == *name) {
                let expected: Vec<Option<usize>> =
                    spec.shape.iter().map(|d| d.and_then(|d| usize::try_from(d).ok())).collect();
                check_output_shape(&self.path, name, array.shape(), &expected)?;
            }
            out.insert((*name).to_owned(), array.as_standard_layout().into_owned());
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_missing_library_is_an_error_naming_the_path() {
        let Err(error) = Runtime::load(Path::new("/nonexistent/libonnxruntime.so"), 0) else {
            panic!("a missing library was accepted");
        };
        assert!(error.to_string().contains("/nonexistent/libonnxruntime.so"), "{error}");
    }
}
