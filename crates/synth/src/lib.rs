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
pub use truth::{ChangeKind, EvaluationOptions, EvaluationPair, Overlap, StructureChange};

/// Smallest image the renderer accepts (pixels).
pub const MIN_WIDTH: u32 = 64;
pub const MIN_HEIGHT: u32 = 48;
/// Largest coral cover a survey may ask for (share of the plan area).
pub const MAX_COVER: f64 = 0.8;
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
    /// Growth of every living coral per visit; `None` keeps the change grade's own (see
    /// [`ChangeGrade`]). Draws of its own: the same seed with and without growth differs in
    /// growth only.
    pub growth: Option<Growth>,
    /// Share of the site's plan area inside coral outlines in the first visit, 0 to
    /// [`MAX_COVER`]; `None` keeps the reef's own (about 0.2). Corals are added in the
    /// reef's proportions of heads, tables and branching corals, or some left out whatever their kind.
    pub cover: Option<f64>,
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
            growth: None,
            cover: None,
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
        if let Some(cover) = self.cover {
            if !(0.0..=MAX_COVER).contains(&cover) {
                return Err(SynthError::BadCover(cover));
            }
        }
        if let Some(growth) = &self.growth {
            growth.check()?;
        }
        if self.width < MIN_WIDTH || self.height < MIN_HEIGHT || self.width > MAX_SIDE || self.height > MAX_SIDE {
            return Err(SynthError::BadImageSize { width: self.width, height: self.height });
        }
        Ok(())
    }
}

/// Radial growth of a living coral per visit, a fraction of the colony's size by coral type
/// (height grows by the same fraction); each colony grows by its type's fraction times a
/// factor drawn from 0.5-1.5.
///
/// [`Growth::YEARLY`] is a year of growth at typical Indo-Pacific rates for the colony sizes of
/// this reef (radius 0.14-0.64 m heads, 0.3-0.8 m tables, 0.12-0.45 m branching colonies):
/// massive *Porites* heads extend about 1 cm a year (Lough & Barnes 2000, J. Exp. Mar. Biol.
/// Ecol. 245), tabular and branching *Acropora* 5-10 cm (Pratchett et al. 2015, Oceanogr. Mar.
/// Biol. Annu. Rev. 53), which on these sizes is about 4%, 12% and 25% a year.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Growth {
    /// Massive coral heads.
    pub head: f64,
    /// Tabular corals.
    pub table: f64,
    /// Branching corals.
    pub branching: f64,
}

impl Growth {
    pub const NONE: Growth = Growth { head: 0.0, table: 0.0, branching: 0.0 };
    pub const YEARLY: Growth = Growth { head: 0.04, table: 0.12, branching: 0.25 };
    /// The largest fraction a visit may add.
    pub const MAX: f64 = 1.0;

    /// The fraction of a coral kind; 0 for rocks and pebbles.
    pub fn fraction(&self, kind: ObjectKind) -> f64 {
        match kind {
            ObjectKind::CoralHead => self.head,
            ObjectKind::CoralTable => self.table,
            ObjectKind::BranchingCoral => self.branching,
            ObjectKind::Rock | ObjectKind::Pebble => 0.0,
        }
    }

    fn check(&self) -> Result<(), SynthError> {
        for (name, value) in [("head", self.head), ("table", self.table), ("branching", self.branching)] {
            if !(0.0..=Self::MAX).contains(&value) {
                return Err(SynthError::BadGrowth(format!("{name}={value} is outside 0-{}", Self::MAX)));
            }
        }
        Ok(())
    }
}

impl FromStr for Growth {
    type Err = SynthError;

    /// `yearly`, `none`, one fraction for every coral type (`0.1`), or per type
    /// (`head=0.04,table=0.12,branching=0.25`, types left out keep the yearly rate).
    fn from_str(text: &str) -> Result<Self, Self::Err> {
        let bad = |why: &str| SynthError::BadGrowth(format!("{text:?}: {why}"));
        let number = |s: &str| s.trim().parse::<f64>().map_err(|_| bad(&format!("{s:?} is not a number")));
        let growth = match text.trim() {
            "yearly" => Self::YEARLY,
            "none" => Self::NONE,
            t if !t.contains('=') => {
                let f = number(t)?;
                Growth { head: f, table: f, branching: f }
            }
            t => {
                let mut growth = Self::YEARLY;
                for part in t.split(',') {
                    let (name, value) = part.split_once('=').ok_or_else(|| bad("expected TYPE=FRACTION"))?;
                    let slot = match name.trim() {
                        "head" => &mut growth.head,
                        "table" => &mut growth.table,
                        "branching" => &mut growth.branching,
                        other => return Err(bad(&format!("unknown coral type {other:?} (head, table, branching)"))),
                    };
                    *slot = number(value)?;
                }
                growth
            }
        };
        growth.check()?;
        Ok(growth)
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
    #[error("coral cover {0} is outside 0-{MAX_COVER}")]
    BadCover(f64),
    #[error("bad growth {0}; expected yearly, none, a fraction per visit, or head=F,table=F,branching=F")]
    BadGrowth(String),
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
