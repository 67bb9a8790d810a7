//! Options shared by the commands that run learned models.

use std::path::PathBuf;

use anyhow::{Context, Result};
use revisit_pipeline::learned::{find_models, Learned, LearnedMethod};

/// A learned matcher by name.
#[derive(Clone, Copy, clap::ValueEnum)]
pub enum LearnedArg {
    /// ALIKED + LightGlue: the most robust across years (1024 keypoints).
    AlikedLightglue,
    /// XFeat + LighterGlue: faster features, up to 4096 keypoints.
    XfeatLighterglue,
}

impl LearnedArg {
    pub fn method(self) -> LearnedMethod {
        match self {
            LearnedArg::AlikedLightglue => LearnedMethod::AlikedLightglue,
            LearnedArg::XfeatLighterglue => LearnedMethod::XfeatLighterglue,
        }
    }
}

/// Where the learned models and ONNX Runtime are found (shared by commands).
#[derive(clap::Args, Clone)]
pub struct ModelArgs {
    /// Folder of the ONNX model files (default: $REVISIT_MODELS, else models/
    /// in the current folder or the checkout). scripts/get-models.sh makes them.
    #[arg(long, value_name = "DIR")]
    pub models: Option<PathBuf>,
    /// The ONNX Runtime library (default: $ORT_DYLIB_PATH, else the one in the
    /// checkout's .venv, installed by scripts/setup.sh).
    #[arg(long, value_name = "PATH")]
    pub onnxruntime: Option<PathBuf>,
}

impl ModelArgs {
    /// These options as command-line words, to hand to another command.
    pub fn to_words(&self) -> Vec<String> {
        let mut words = Vec::new();
        if let Some(dir) = &self.models {
            words.extend(["--models".to_owned(), dir.display().to_string()]);
        }
        if let Some(path) = &self.onnxruntime {
            words.extend(["--onnxruntime".to_owned(), path.display().to_string()]);
        }
        words
    }

    /// Loads ONNX Runtime.
    pub fn runtime(&self) -> Result<revisit_onnx::Runtime> {
        revisit_onnx::Runtime::load(self.onnxruntime.as_deref(), 0).context("--onnxruntime")
    }

    /// Loads ONNX Runtime and opens `method`'s models.
    pub fn open(&self, method: LearnedMethod) -> Result<(revisit_onnx::Runtime, Learned)> {
        let runtime = self.runtime()?;
        let models = find_models(self.models.as_deref());
        let learned = Learned::open(&runtime, &models, method).context("--models")?;
        Ok((runtime, learned))
    }
}
