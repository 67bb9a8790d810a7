//! The report of a reconstruction: what was done, what was reused, what came
//! out. `report.json` is this type written out, and anyone (a benchmark, a
//! test, a node's status) reads it back as this type.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use revisit_colmap::{ChangeAware, NavigationOffset};
use revisit_core::{CameraId, PairKind};
use revisit_matching::consistency::Placement;
use serde::{Deserialize, Serialize};

use crate::cross::{ConsistencyCounts, LearnedMatchingCounts};
use crate::options::ReconstructOptions;
use crate::{PipelineError, StageCounts};

/// Everything `report.json` says.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Report {
    /// Per session: visit order, images, registered images, cameras.
    pub sessions: BTreeMap<String, SessionReport>,
    /// Models COLMAP made.
    pub models: usize,
    /// Registered images of each model, largest first.
    pub model_sizes: Vec<usize>,
    /// The model that counts (see `registered_rule`).
    pub chosen_model: Option<PathBuf>,
    pub registered_rule: String,
    /// Pairs tried and verified, within (`intra`) and across (`cross`) visits.
    pub pairs: BTreeMap<PairKind, PairReport>,
    /// Sessions (of several) with fewer than half their images in the
    /// chosen model: they could not be linked to the others.
    pub unlinked_sessions: Vec<String>,
    /// Verified cross-visit pairs by the roll of their second image, degrees.
    pub rolls: BTreeMap<u32, usize>,
    /// SIFT feature extraction.
    pub features: StageCounts,
    /// SIFT matching (within visits, and across for `--cross sift`).
    pub matching: StageCounts,
    pub cross: CrossReport,
    pub mapping: MappingReport,
    /// Seconds per stage.
    pub seconds: BTreeMap<String, f64>,
    /// Peak resident memory per stage, MiB: Revisit's process during the
    /// stage, and for mapping the larger of it and COLMAP's process.
    #[serde(default)]
    pub peak_rss_mib: BTreeMap<String, f64>,
    /// The options the reconstruction ran with.
    pub options: ReconstructOptions,
}

/// One session's line of the report.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SessionReport {
    /// Place in the order of visits (0 = the reference).
    pub visit: usize,
    pub images: usize,
    pub registered: usize,
    /// Images with a navigation prior (`reconstruct --nav`).
    #[serde(default)]
    pub navigation: usize,
    /// Cameras by name.
    pub cameras: BTreeMap<String, CameraReport>,
}

/// One camera of a session.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraReport {
    /// COLMAP's camera id (shared across sessions with `cameras.shared`).
    pub camera_id: CameraId,
    pub width: u32,
    pub height: u32,
    pub images: usize,
    /// Whether its intrinsics were given (and held fixed).
    pub calibrated: bool,
}

/// Pairs of one kind: tried and verified.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PairReport {
    pub tried: usize,
    pub verified: usize,
}

/// The cross-visit stages; `None` where a stage did not run.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CrossReport {
    pub learned_features: Option<StageCounts>,
    pub places: Option<StageCounts>,
    pub learned_matching: Option<LearnedMatchingCounts>,
    /// Verified cross-visit pairs checked against their rolls and each other before mapping.
    pub consistency: Option<ConsistencyCounts>,
}

/// The mapping stage.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MappingReport {
    /// The store had not changed since the last run: its models were kept.
    pub reused: bool,
    /// The previous model was extended rather than rebuilt.
    pub extended: bool,
    pub mean_reprojection_error_px: Option<f64>,
    /// The frame the model is in.
    #[serde(default)]
    pub frame: ModelFrame,
    /// RMS distance between the chosen model's cameras and their navigation, metres.
    #[serde(default)]
    pub navigation_rms_m: Option<f64>,
    /// Per visit of the chosen model: how far its navigation sat from where the images put it.
    #[serde(default)]
    pub navigation_offsets: BTreeMap<String, NavigationOffset>,
    /// Change-aware mapping (`--change-aware`): the visits it placed and, per visit pair, the
    /// cross-visit matches the joint model kept and dropped.
    #[serde(default)]
    pub change_aware: Option<ChangeAware>,
    /// Per pair of visits of the chosen model (`"s1-s2"`): how it holds the cross-visit pairs
    /// the loops confirmed before mapping (`reconstruct` warns of a suspect one).
    #[serde(default)]
    pub placement: BTreeMap<String, Placement>,
}

/// The frame of a model's coordinates.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ModelFrame {
    /// COLMAP's own: origin, orientation and scale arbitrary.
    #[default]
    Arbitrary,
    /// The navigation's (metres; ENU or NED as the navigation gives it): mapping used the
    /// navigation priors and placed the model on them.
    Navigation,
}

impl Report {
    /// Reads `report.json`.
    pub fn read(path: &Path) -> Result<Report, PipelineError> {
        let text =
            std::fs::read_to_string(path).map_err(|source| PipelineError::Io { path: path.to_path_buf(), source })?;
        serde_json::from_str(&text).map_err(|e| PipelineError::Io {
            path: path.to_path_buf(),
            source: std::io::Error::new(std::io::ErrorKind::InvalidData, e),
        })
    }

    /// Writes `report.json` (pretty-printed), replacing it whole.
    pub fn write(&self, path: &Path) -> Result<(), PipelineError> {
        let io = |source| PipelineError::Io { path: path.to_path_buf(), source };
        let json = serde_json::to_string_pretty(self).map_err(|e| io(std::io::Error::other(e)))?;
        let partial = path.with_extension("json.partial");
        std::fs::write(&partial, json).map_err(io)?;
        std::fs::rename(&partial, path).map_err(io)
    }

    /// Sessions with every image registered in the chosen model.
    pub fn fully_registered(&self) -> Vec<&str> {
        self.sessions.iter().filter(|(_, s)| s.registered == s.images).map(|(name, _)| name.as_str()).collect()
    }

    /// Tried and verified pairs of `kind` (zero if none).
    pub fn pairs_of(&self, kind: PairKind) -> PairReport {
        self.pairs.get(&kind).cloned().unwrap_or_default()
    }
}
