//! Learned matching methods by name: which model files they need, where those
//! are found, and opening them on ONNX Runtime.

use std::path::Path;

use image::RgbImage;
use revisit_core::{LearnedFeatures, Roll};
use revisit_features::learned::{Aliked, LearnedExtractor, LearnedInput, XFeat, XFeatOptions};
use revisit_matching::{match_with_rolls, CrossMatch, CrossOptions, LightGlue, RollSearch};
use revisit_onnx::{OnnxError, Runtime};
use serde::{Deserialize, Serialize};

/// A learned detector + matcher pair.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum LearnedMethod {
    /// ALIKED (1024 keypoints) + LightGlue: the default, the most robust across years.
    #[default]
    AlikedLightglue,
    /// XFeat (up to 4096 keypoints) + LighterGlue: a faster detector.
    XfeatLighterglue,
}

impl LearnedMethod {
    pub const ALL: [LearnedMethod; 2] = [LearnedMethod::AlikedLightglue, LearnedMethod::XfeatLighterglue];

    /// The method named `name` (see [`LearnedMethod::name`]).
    pub fn from_name(name: &str) -> Option<LearnedMethod> {
        LearnedMethod::ALL.into_iter().find(|m| m.name() == name)
    }

    /// One line on the method, for `--help`.
    pub fn description(self) -> &'static str {
        match self {
            LearnedMethod::AlikedLightglue => "ALIKED (1024 keypoints) + LightGlue: the most robust across years",
            LearnedMethod::XfeatLighterglue => "XFeat (up to 4096 keypoints) + LighterGlue: faster features",
        }
    }

    /// The name used in options and in the store.
    pub fn name(self) -> &'static str {
        match self {
            LearnedMethod::AlikedLightglue => "aliked-lightglue",
            LearnedMethod::XfeatLighterglue => "xfeat-lighterglue",
        }
    }

    /// The model files, (extractor, matcher), inside the models folder.
    pub fn model_files(self) -> [&'static str; 2] {
        match self {
            LearnedMethod::AlikedLightglue => ["aliked_n16_480x640.onnx", "lightglue_aliked.onnx"],
            LearnedMethod::XfeatLighterglue => ["xfeat_backbone.onnx", "lighterglue_xfeat.onnx"],
        }
    }
}

/// The extractor of `method`, from the `models` folder, given `input` of each image.
pub fn open_extractor(
    runtime: &Runtime,
    models: &Path,
    method: LearnedMethod,
    input: LearnedInput,
) -> Result<LearnedExtractor, OnnxError> {
    let [extractor_file, _] = method.model_files();
    let path = models.join(extractor_file);
    Ok(match method {
        LearnedMethod::AlikedLightglue => LearnedExtractor::aliked(Aliked::open(runtime, &path)?, input),
        LearnedMethod::XfeatLighterglue => {
            LearnedExtractor::xfeat(XFeat::open(runtime, &path, XFeatOptions::default())?, input)
        }
    })
}

/// The matcher of `method` (for the extractor's `descriptor_dim`), from the `models` folder.
pub fn open_matcher(
    runtime: &Runtime,
    models: &Path,
    method: LearnedMethod,
    descriptor_dim: usize,
) -> Result<LightGlue, OnnxError> {
    let [_, matcher_file] = method.model_files();
    LightGlue::open(runtime, &models.join(matcher_file), descriptor_dim)
}

/// A learned method, opened: its extractor and its matcher.
pub struct Learned {
    pub method: LearnedMethod,
    pub extractor: LearnedExtractor,
    pub matcher: LightGlue,
}

impl Learned {
    /// `input`: what the extractor is given of each image (a store's features
    /// come from one kind: `FeatureOptions::learned_input`, pinned).
    pub fn open(
        runtime: &Runtime,
        models: &Path,
        method: LearnedMethod,
        input: LearnedInput,
    ) -> Result<Learned, OnnxError> {
        let extractor = open_extractor(runtime, models, method, input)?;
        let matcher = open_matcher(runtime, models, method, extractor.descriptor_dim())?;
        Ok(Learned { method, extractor, matcher })
    }

    /// Features of `image` rolled by `roll`.
    pub fn extract(&mut self, image: &RgbImage, roll: Roll) -> Result<LearnedFeatures, OnnxError> {
        self.extractor.extract(image, roll)
    }

    /// Matches `a` with the second image's features at the rolls `search`
    /// needs, from `place_roll` when it searches in order (roll search alone,
    /// without anchoring or acceptance), as `options` ask.
    pub fn match_rolls(
        &mut self,
        a: &LearnedFeatures,
        b_by_roll: &[(Roll, LearnedFeatures)],
        search: (RollSearch, Option<Roll>),
        options: &CrossOptions,
    ) -> Result<CrossMatch, OnnxError> {
        match_with_rolls(&mut self.matcher, a, b_by_roll, search, options)
    }
}
