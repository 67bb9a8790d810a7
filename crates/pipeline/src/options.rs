//! Every option of a reconstruction, with its default, in one place: the
//! command line, a node's parameters and a benchmark fill the same struct and
//! [`ReconstructOptions::check`] validates it once, before any work.

use std::collections::BTreeMap;
use std::path::PathBuf;

use revisit_colmap::{Engine, MapperOptions, PlyColors};
use revisit_core::{Camera, CameraModel};
use revisit_features::learned::LearnedInput;
use revisit_features::SiftOptions;
use revisit_matching::{CrossOptions, MatchOptions, PairOptions, VerifyOptions};
use revisit_places::CandidateOptions;
use serde::{Deserialize, Serialize};

use crate::learned::LearnedMethod;

/// How visits are linked: which pairs are matched, and by which matcher.
/// Within one visit SIFT is always used, except by `learned-all`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum CrossStrategy {
    /// Pairs within visits only: visits are not linked.
    None,
    /// Every cross-visit pair with SIFT: the classic joint baseline.
    Sift,
    /// The learned matcher on every pair, within and across visits (slowest).
    LearnedAll,
    /// The learned matcher on every cross-visit pair.
    LearnedCross,
    /// The learned matcher on place-recognition candidates only (the method).
    #[default]
    Vpr,
}

impl CrossStrategy {
    pub const ALL: [CrossStrategy; 5] = [
        CrossStrategy::None,
        CrossStrategy::Sift,
        CrossStrategy::LearnedAll,
        CrossStrategy::LearnedCross,
        CrossStrategy::Vpr,
    ];

    /// The name on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            CrossStrategy::None => "none",
            CrossStrategy::Sift => "sift",
            CrossStrategy::LearnedAll => "learned-all",
            CrossStrategy::LearnedCross => "learned-cross",
            CrossStrategy::Vpr => "vpr",
        }
    }

    /// The strategy named `name` (see [`CrossStrategy::name`]).
    pub fn from_name(name: &str) -> Option<CrossStrategy> {
        CrossStrategy::ALL.into_iter().find(|s| s.name() == name)
    }

    /// One line on what the strategy does, for `--help`.
    pub fn description(self) -> &'static str {
        match self {
            CrossStrategy::None => "pairs within visits only: visits are not linked",
            CrossStrategy::Sift => "SIFT on every cross-visit pair: the classic joint baseline",
            CrossStrategy::LearnedAll => "the learned matcher on every pair, within and across visits (slowest)",
            CrossStrategy::LearnedCross => "the learned matcher on every cross-visit pair; SIFT within visits",
            CrossStrategy::Vpr => {
                "the learned matcher on place-recognition candidates only; SIFT within visits (the method)"
            }
        }
    }

    /// Whether SIFT matches pairs within visits.
    pub fn sift_within(self) -> bool {
        self != CrossStrategy::LearnedAll
    }

    /// Whether SIFT matches pairs across visits.
    pub fn sift_across(self) -> bool {
        self == CrossStrategy::Sift
    }

    /// Whether the learned features and matcher are used at all.
    pub fn learned(self) -> bool {
        matches!(self, CrossStrategy::LearnedAll | CrossStrategy::LearnedCross | CrossStrategy::Vpr)
    }

    /// Whether place recognition picks the learned pairs.
    pub fn places(self) -> bool {
        self == CrossStrategy::Vpr
    }
}

/// Options of feature extraction (pinned in the store: a store holds
/// features made one way only).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FeatureOptions {
    /// SIFT; Revisit's default keeps 4096 features an image.
    pub sift: SiftOptions,
    /// Images whose larger side exceeds this are downscaled for SIFT
    /// (keypoints are reported in full-resolution pixels). Default 3200.
    pub max_image_size_px: u32,
    /// What the learned extractor is given of each image: by default the
    /// image as it is; or each channel stretched between its percentiles
    /// (`revisit_features::learned::stretch`), so that visits under other
    /// light, water and colour look alike.
    pub learned_input: LearnedInput,
}

impl Default for FeatureOptions {
    fn default() -> Self {
        FeatureOptions {
            sift: SiftOptions { max_num_features: 4096, ..SiftOptions::default() },
            max_image_size_px: 3200,
            learned_input: LearnedInput::default(),
        }
    }
}

/// The built-in VLAD vocabulary's size, by default.
pub const DEFAULT_VOCABULARY_SIZE: usize = 64;

/// Where global descriptors for place recognition come from.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum PlaceSource {
    /// VLAD over the learned descriptors, with a vocabulary of `clusters`
    /// centres learned from the survey (stored; later visits reuse it).
    Vlad { clusters: usize },
    /// A user's ONNX model (RGB image [1, 3, H, W] in 0..1 -> [1, D]).
    Onnx(PathBuf),
}

impl Default for PlaceSource {
    fn default() -> Self {
        PlaceSource::Vlad { clusters: DEFAULT_VOCABULARY_SIZE }
    }
}

/// Options of place recognition (strategy `vpr`).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PlaceOptions {
    pub source: PlaceSource,
    /// Each image of a later visit is paired with its `top_k` nearest images
    /// of earlier visits. Default 5.
    pub candidates: CandidateOptions,
    /// With navigation priors: images whose navigated camera centres lie farther apart than
    /// this (metres) are never a candidate pair, and each image of a later visit is also paired
    /// with its `top_k` nearest images of earlier visits within it. `None`: navigation picks
    /// no pairs.
    pub navigation_radius_m: Option<f64>,
}

/// A calibrated camera, `MODEL:P1,P2,...` in COLMAP's parameter order.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "String", into = "String")]
pub struct CameraSpec {
    pub model: CameraModel,
    pub params: Vec<f64>,
}

impl std::str::FromStr for CameraSpec {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let (model, params) =
            s.split_once(':').ok_or_else(|| format!("{s:?} is not MODEL:P1,P2,... (e.g. PINHOLE:512,512,320,240)"))?;
        let model = CameraModel::from_name(model.trim()).map_err(|e| e.to_string())?;
        let params = params
            .split(',')
            .map(|p| p.trim().parse::<f64>().ok().filter(|v| v.is_finite()))
            .collect::<Option<Vec<_>>>()
            .ok_or_else(|| format!("{s:?}: every parameter must be a finite number"))?;
        // Checks the parameter count for the model.
        Camera::new(0, model, 1, 1, params.clone()).map_err(|e| e.to_string())?;
        Ok(CameraSpec { model, params })
    }
}

impl TryFrom<String> for CameraSpec {
    type Error = String;
    fn try_from(s: String) -> Result<Self, String> {
        s.parse()
    }
}

impl From<CameraSpec> for String {
    fn from(spec: CameraSpec) -> String {
        let params: Vec<String> = spec.params.iter().map(f64::to_string).collect();
        format!("{}:{}", spec.model.name(), params.join(","))
    }
}

/// Cameras: which are calibrated, and whether visits share them.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CameraOptions {
    /// Calibrated cameras (intrinsics held fixed), by the cameras they apply
    /// to: `SESSION/CAMERA` (one camera), `SESSION` (every camera of a
    /// session) or `""` (every camera); the most specific key wins. Cameras
    /// without one are self-calibrated, starting from the EXIF focal length
    /// when the images carry one.
    pub calibrated: BTreeMap<String, CameraSpec>,
    /// Visits flown with the same camera share its intrinsics: a camera of
    /// one name and image size is one COLMAP camera across every visit,
    /// refined jointly from all their images. Default false (one camera per
    /// visit and camera name).
    pub shared: bool,
}

impl CameraOptions {
    /// The calibration for camera `camera` of `session`, if one is given.
    pub fn calibration(&self, session: &str, camera: &str) -> Option<&CameraSpec> {
        [format!("{session}/{camera}"), session.to_owned(), String::new()]
            .iter()
            .find_map(|key| self.calibrated.get(key))
    }
}

/// Every option of a reconstruction.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ReconstructOptions {
    /// How visits are linked. Default `vpr`.
    pub cross: CrossStrategy,
    /// The learned detector and matcher. Default ALIKED + LightGlue.
    pub learned: LearnedMethod,
    pub features: FeatureOptions,
    /// Which pairs within a visit are matched.
    pub pairs: PairOptions,
    /// SIFT descriptor matching.
    pub matching: MatchOptions,
    /// Verification of SIFT pairs (COLMAP's thresholds).
    pub verify: VerifyOptions,
    /// Learned pairs: roll search, anchoring, acceptance.
    pub learned_matching: CrossOptions,
    /// Images (learned features) and pairs (learned matching) worked on at once, each on one
    /// thread of ONNX Runtime (1: one at a time on every thread; 0, the default: one per core,
    /// as many as the available memory holds). The results do not depend on it.
    pub learned_workers: usize,
    pub places: PlaceOptions,
    pub cameras: CameraOptions,
    pub mapper: MapperOptions,
    /// How `points.ply` is coloured. Default by RGB.
    pub ply_colors: PlyColors,
}

/// An option out of range, named as in [`ReconstructOptions`].
#[derive(Debug, thiserror::Error)]
#[error("option {field}: {reason}")]
pub struct OptionsError {
    pub field: &'static str,
    pub reason: String,
}

impl ReconstructOptions {
    /// The options a node runs with, so that every node of a graph agrees with the others and
    /// with `reconstruct`: `file` (JSON, as `report.json`'s `options` shows them; default the
    /// defaults), then the strategy named `cross` if given. Checked; the error names the file.
    pub fn for_node(file: Option<&std::path::Path>, cross: Option<&str>) -> Result<ReconstructOptions, String> {
        let mut options = match file {
            Some(path) => {
                let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
                serde_json::from_str(&text).map_err(|e| format!("{}: {e}", path.display()))?
            }
            None => ReconstructOptions::default(),
        };
        if let Some(name) = cross {
            options.cross = CrossStrategy::from_name(name).ok_or_else(|| {
                let known: Vec<&str> = CrossStrategy::ALL.iter().map(|s| s.name()).collect();
                format!("cross {name:?} is not one of {known:?}")
            })?;
        }
        options.check().map_err(|e| e.to_string())?;
        Ok(options)
    }

    /// Every random choice (RANSAC within and across visits, COLMAP) from one seed.
    pub fn with_seed(mut self, seed: u64) -> Self {
        self.verify.seed = seed;
        self.learned_matching.verify.seed = seed;
        self.mapper.seed = seed;
        self
    }

    /// Checks every option; the stages can then trust them.
    pub fn check(&self) -> Result<(), OptionsError> {
        let fail = |field: &'static str| move |reason: String| OptionsError { field, reason };
        self.features.sift.check().map_err(|e| fail("features.sift")(e.to_string()))?;
        if self.features.max_image_size_px < 16 {
            return Err(fail("features.max_image_size_px")("must be at least 16".to_owned()));
        }
        self.pairs.check().map_err(|e| fail("pairs")(e.to_string()))?;
        self.matching.check().map_err(|e| fail("matching")(e.to_string()))?;
        self.verify.check().map_err(|e| fail("verify")(e.to_string()))?;
        self.learned_matching.check().map_err(|e| fail("learned_matching")(e.to_string()))?;
        self.places.candidates.check().map_err(fail("places.candidates"))?;
        if let Some(radius_m) = self.places.navigation_radius_m {
            if !(radius_m.is_finite() && radius_m > 0.0) {
                return Err(fail("places.navigation_radius_m")(format!(
                    "{radius_m} is not a positive number of metres"
                )));
            }
        }
        if let PlaceSource::Vlad { clusters } = self.places.source {
            if !(2..=4096).contains(&clusters) {
                return Err(fail("places.source")(format!(
                    "a VLAD vocabulary of {clusters} clusters is not in [2, 4096]"
                )));
            }
        }
        for key in self.cameras.calibrated.keys() {
            if key.chars().any(char::is_control) || key.split('/').count() > 2 {
                return Err(fail("cameras.calibrated")(format!("{key:?} is not SESSION[/CAMERA]")));
            }
        }
        if self.mapper.min_model_size < 2 {
            return Err(fail("mapper.min_model_size")("must be at least 2".to_owned()));
        }
        if self.mapper.min_pose_inliers < 4 {
            return Err(fail("mapper.min_pose_inliers")("must be at least 4".to_owned()));
        }
        if self.mapper.change_aware && self.mapper.engine != Engine::Incremental {
            return Err(fail("mapper.change_aware")("needs the incremental mapper".to_owned()));
        }
        if self.mapper.threads == 0 || self.mapper.threads < -1 {
            return Err(fail("mapper.threads")(format!(
                "{} is neither -1 (all cores) nor positive",
                self.mapper.threads
            )));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn options_read_from_json_refuse_unknown_fields_and_keep_defaults() {
        let options: ReconstructOptions =
            serde_json::from_str(r#"{"cross": "learned-cross", "cameras": {"shared": true}}"#).unwrap();
        assert_eq!(options.cross, CrossStrategy::LearnedCross);
        assert!(options.cameras.shared);
        assert_eq!(options.features, FeatureOptions::default());
        assert!(serde_json::from_str::<ReconstructOptions>(r#"{"crosss": "sift"}"#).is_err());
        let json = serde_json::to_string(&ReconstructOptions::default()).unwrap();
        assert_eq!(serde_json::from_str::<ReconstructOptions>(&json).unwrap(), ReconstructOptions::default());
    }

    #[test]
    fn options_are_checked_once_with_the_field_named() {
        assert!(ReconstructOptions::default().check().is_ok());
        let mut options = ReconstructOptions::default();
        options.places.candidates.top_k = 0;
        assert!(options.check().unwrap_err().to_string().contains("places.candidates"));
        let mut options = ReconstructOptions::default();
        options.places.navigation_radius_m = Some(-1.0);
        assert!(options.check().unwrap_err().to_string().contains("places.navigation_radius_m"));
        let mut options = ReconstructOptions::default();
        options.learned_matching.roll_margin = f32::NAN;
        assert!(options.check().unwrap_err().to_string().contains("learned_matching"));
    }

    #[test]
    fn the_most_specific_calibration_wins() {
        let spec = |f: f64| CameraSpec { model: CameraModel::Pinhole, params: vec![f, f, 320.0, 240.0] };
        let mut cameras = CameraOptions::default();
        cameras.calibrated.insert(String::new(), spec(1.0));
        cameras.calibrated.insert("s2".into(), spec(2.0));
        cameras.calibrated.insert("s2/left".into(), spec(3.0));
        assert_eq!(cameras.calibration("s1", "left"), Some(&spec(1.0)));
        assert_eq!(cameras.calibration("s2", "right"), Some(&spec(2.0)));
        assert_eq!(cameras.calibration("s2", "left"), Some(&spec(3.0)));
        let parsed: CameraSpec = "PINHOLE:3,3,320,240".parse().unwrap();
        assert_eq!(parsed, spec(3.0));
        assert_eq!(String::from(parsed), "PINHOLE:3,3,320,240");
        assert!("PINHOLE:1,2".parse::<CameraSpec>().is_err());
        assert!("PINHOLE:1,2,nan,4".parse::<CameraSpec>().is_err());
    }
}
