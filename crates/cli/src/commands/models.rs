//! Options shared by the commands that run COLMAP or the learned models:
//! where the tools are, and the named methods as command-line values.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::builder::{PossibleValue, PossibleValuesParser, TypedValueParser};
use revisit_features::learned::LearnedInput;
use revisit_pipeline::learned::{Learned, LearnedMethod};
use revisit_pipeline::locate::Tools;
use revisit_pipeline::CrossStrategy;

/// `--cross`'s values, with their help, from the pipeline's one list.
pub fn cross_strategies() -> impl TypedValueParser<Value = CrossStrategy> {
    let values = CrossStrategy::ALL.map(|s| PossibleValue::new(s.name()).help(s.description()));
    PossibleValuesParser::new(values).map(|name| CrossStrategy::from_name(&name).unwrap_or_default())
}

/// `--learned`'s values, with their help, from the pipeline's one list.
pub fn learned_methods() -> impl TypedValueParser<Value = LearnedMethod> {
    let values = LearnedMethod::ALL.map(|m| PossibleValue::new(m.name()).help(m.description()));
    PossibleValuesParser::new(values).map(|name| LearnedMethod::from_name(&name).unwrap_or_default())
}

/// Where Python (pycolmap), ONNX Runtime and the learned models are found.
/// Each is searched in this order: the option, its environment variable,
/// then the project's own (`.venv`, `models/`) in the current folder and in
/// every folder above the executable. `revisit doctor` shows what is found.
#[derive(clap::Args, Clone, Debug, Default)]
pub struct ToolArgs {
    /// Folder of the ONNX model files (default: $REVISIT_MODELS, else models/).
    /// scripts/get-models.sh makes them.
    #[arg(long, value_name = "DIR")]
    pub models: Option<PathBuf>,
    /// The ONNX Runtime library (default: $ORT_DYLIB_PATH, else the one in
    /// .venv, installed by scripts/setup.sh).
    #[arg(long, value_name = "PATH")]
    pub onnxruntime: Option<PathBuf>,
    /// Python with pycolmap (default: $REVISIT_PYTHON, else .venv/bin/python).
    #[arg(long, value_name = "PATH")]
    pub python: Option<PathBuf>,
}

impl ToolArgs {
    pub fn tools(&self) -> Tools {
        Tools { python: self.python.clone(), onnxruntime: self.onnxruntime.clone(), models: self.models.clone() }
    }

    /// Loads ONNX Runtime and opens `method`'s models.
    pub fn open(&self, method: LearnedMethod) -> Result<(revisit_onnx::Runtime, Learned)> {
        let tools = self.tools();
        let runtime = tools.onnxruntime(0).context("--onnxruntime")?;
        let learned = Learned::open(&runtime, &tools.models(), method, LearnedInput::default()).context("--models")?;
        Ok((runtime, learned))
    }
}
