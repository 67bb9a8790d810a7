//! A synthetic multi-visit coral reef with exact ground truth.
//!
//! [`plan`] lays out a seabed with rocks, coral heads, coral tables, branching
//! corals and rubble, lets it change from visit to visit (graded by
//! [`ChangeGrade`]) and flies one lawnmower survey per visit over it, each with
//! its own altitude, heading, track offset and water. [`Survey::render`] draws
//! any image on the CPU (filtered albedo, Lambert light, caustics, water
//! attenuation and backscatter, blur, sensor noise) with its depth and object-id
//! buffers. The truth comes back as structs: the COLMAP model of the cameras
//! used to render ([`Survey::truth_model`]), cross-visit overlaps
//! ([`Survey::overlaps`]) and evaluation points in the published protocol's form
//! ([`Survey::evaluation_points`]).
//!
//! Invariants: no file I/O (the CLI writes files); deterministic for a seed:
//! the same options give byte-identical images on any machine and thread count.
//! World frame: x east, y north, z up, metres. Cameras follow COLMAP (x right,
//! y down, z forward; pixel centres at +0.5).

mod noise;
mod render;
mod scene;
mod survey;
mod truth;

use std::str::FromStr;

use serde::{Deserialize, Serialize};

pub use render::{sun_dir, Appearance, Rendered, NO_DEPTH, NO_OBJECT};
pub use scene::{ObjectKind, ObjectState, CELL_M, SEABED_ID, TEXEL_M};
pub use survey::{
    plan, ImageTruth, NavigationFix, NavigationSample, SessionIntrinsics, SessionPlan, Survey, NAV_DRIFT_PER_M,
    NAV_FIX_SIGMA_M,
};
pub use truth::{EvaluationOptions, EvaluationPair, Overlap};

/// Smallest image the renderer accepts (pixels).
pub const MIN_WIDTH: u32 = 64;
pub const MIN_HEIGHT: u32 = 48;
/// Largest image side the renderer accepts (pixels).
pub const MAX_SIDE: u32 = 8192;

/// How much the reef and the water change between visits.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ChangeGrade {
    /// Identical scene and light; only the trajectories differ.
    None,
    /// Water and light vary; a few corals grow, bleach, die or shift.
    #[default]
    Mild,
    /// Strong appearance change (light from any side, turbidity, colour,
    /// sediment moved so the sand looks new); many corals bleach, some die
    /// or move (none grow: see `scene::rates`).
    Strong,
    /// Turbid water; a storm has moved or removed 30-50% of the corals.
    Storm,
}

impl ChangeGrade {
    pub const ALL: [ChangeGrade; 4] = [Self::None, Self::Mild, Self::Strong, Self::Storm];

    pub fn name(self) -> &'static str {
        match self {
            Self::None => "none",
            Self::Mild => "mild",
            Self::Strong => "strong",
            Self::Storm => "storm",
        }
    }
}

impl std::fmt::Display for ChangeGrade {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for ChangeGrade {
    type Err = SynthError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|g| g.name() == s.to_ascii_lowercase())
            .ok_or_else(|| SynthError::UnknownChange(s.to_owned()))
    }
}

/// Options of a synthetic survey.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SynthOptions {
    /// Number of visits (sessions). Default 3; at least 1.
    pub sessions: usize,
    /// Images per session. Default 60; at least 2.
    pub images_per_session: usize,
    /// Seed of everything random. Default 0.
    pub seed: u64,
    /// Change between visits. Default mild.
    pub change: ChangeGrade,
    /// Image width in pixels. Default 640; at least 64.
    pub width: u32,
    /// Image height in pixels. Default 480; at least 48.
    pub height: u32,
    /// Frames per step between planned survey positions. Default 1; more makes a video-rate
    /// sequence, each step subdivided along the track, and a session holds
    /// `(images_per_session - 1) * frames_per_step + 1` frames.
    pub frames_per_step: usize,
}

impl Default for SynthOptions {
    fn default() -> Self {
        Self {
            sessions: 3,
            images_per_session: 60,
            seed: 0,
            change: ChangeGrade::Mild,
            width: 640,
            height: 480,
            frames_per_step: 1,
        }
    }
}

impl SynthOptions {
    /// Validates the options.
    pub fn check(&self) -> Result<(), SynthError> {
        if self.sessions == 0 {
            return Err(SynthError::NoSessions);
        }
        if self.sessions > 1000 {
            return Err(SynthError::TooManySessions(self.sessions));
        }
        if self.images_per_session < 2 {
            return Err(SynthError::TooFewImages(self.images_per_session));
        }
        if self.width < MIN_WIDTH || self.height < MIN_HEIGHT || self.width > MAX_SIDE || self.height > MAX_SIDE {
            return Err(SynthError::BadImageSize { width: self.width, height: self.height });
        }
        Ok(())
    }
}

#[derive(Debug, thiserror::Error)]
pub enum SynthError {
    #[error("the number of sessions must be at least 1")]
    NoSessions,
    #[error("the number of sessions must be at most 1000, got {0}")]
    TooManySessions(usize),
    #[error("images per session must be at least 2, got {0}")]
    TooFewImages(usize),
    #[error(
        "image size {width}x{height} is out of range: at least {MIN_WIDTH}x{MIN_HEIGHT}, at most {MAX_SIDE} per side"
    )]
    BadImageSize { width: u32, height: u32 },
    #[error("unknown change grade {0:?}: expected none, mild, strong or storm")]
    UnknownChange(String),
    #[error("image index {index} is out of range: the survey has {count} images")]
    NoSuchImage { index: usize, count: usize },
    #[error("session index {index} is out of range: the survey has {count} sessions")]
    NoSuchSession { index: usize, count: usize },
    #[error("the site holds {0} structures, more than 16-bit object ids allow")]
    TooManyObjects(usize),
    #[error("camera of session {session}: {source}")]
    Camera {
        session: String,
        #[source]
        source: revisit_core::CameraModelError,
    },
}
