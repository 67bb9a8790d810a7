//! The post-hoc baselines Revisit is measured against: each visit
//! reconstructed alone, then its model placed in a common frame afterwards,
//! by registering its point cloud onto the first visit's (ICP from the
//! centroids, or FPFH + RANSAC global registration then ICP, with Open3D) or
//! by fitting its cameras to the vehicle's navigation. The aligned visits are
//! merged into one model that `revisit eval` scores like a joint one.
//!
//! Separate reconstructions differ in scale, so every alignment is a
//! similarity. A visit that cannot be aligned is reported with the reason,
//! never dropped silently.

mod navigation;
mod register;

use std::path::Path;
use std::sync::atomic::AtomicBool;

use revisit_core::{NavigationFix, Reconstruction, Similarity};
use serde::Serialize;

pub use navigation::fit_to_navigation;
pub use register::{register, Registered, Registration};

#[derive(Debug, thiserror::Error)]
pub enum PosthocError {
    #[error("could not start {python}: {source}")]
    Spawn { python: std::path::PathBuf, source: std::io::Error },
    #[error("writing {path}: {source}")]
    Io { path: std::path::PathBuf, source: std::io::Error },
    #[error("registration (Open3D) failed ({status}): {stderr_tail}")]
    Failed { status: String, stderr_tail: String },
    #[error("registration printed no result: {0}")]
    BadResult(String),
    #[error("stopped on request")]
    Cancelled,
    #[error(transparent)]
    Colmap(#[from] revisit_colmap::ColmapError),
}

/// How each visit's model is placed in the common frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Alignment {
    /// Point-to-point ICP with scale, from the clouds' centroids and spreads.
    Icp,
    /// FPFH features + RANSAC global registration, refined by ICP.
    Fpfh,
    /// A similarity fitted from the visit's camera centres to its navigation.
    Navigation,
}

impl Alignment {
    pub fn name(self) -> &'static str {
        match self {
            Alignment::Icp => "icp",
            Alignment::Fpfh => "fpfh",
            Alignment::Navigation => "nav",
        }
    }
}

/// Where one visit's model went.
#[derive(Clone, Debug, Serialize)]
pub struct VisitAlignment {
    pub session: String,
    /// The similarity taking the visit's model into the common frame
    /// (`None` when it failed, see `failure`).
    pub common_from_visit: Option<Similarity>,
    /// Why the visit could not be aligned.
    pub failure: Option<String>,
    /// Registration's fitness (share of the visit's points with a
    /// counterpart), or for navigation the RMS distance of the camera centres
    /// from their navigation, metres.
    pub fitness: Option<f64>,
}

/// The visits' models in one frame.
#[derive(Clone, Debug)]
pub struct Aligned {
    /// The aligned visits merged (a failed visit is left out).
    pub model: Reconstruction,
    pub visits: Vec<VisitAlignment>,
}

/// What an alignment needs besides the models.
pub struct AlignContext<'a> {
    /// A Python with Open3D (registration only).
    pub python: &'a Path,
    /// A folder for the point clouds handed to Open3D.
    pub scratch: &'a Path,
    /// Seed of RANSAC's choices.
    pub seed: u64,
    /// Each image's navigation position, by `session/file` (navigation only).
    pub navigation: &'a [NavigationFix],
}

/// Places every visit's model (`None`: the visit's own reconstruction
/// failed) in one frame: the first visit's for registration, the
/// navigation's for [`Alignment::Navigation`].
pub fn align_visits(
    visits: &[(String, Option<Reconstruction>)],
    alignment: Alignment,
    context: &AlignContext<'_>,
    cancelled: &AtomicBool,
) -> Result<Aligned, PosthocError> {
    let mut results = Vec::new();
    let mut parts = Vec::new();
    let reference = visits.first().and_then(|(_, model)| model.as_ref());
    for (index, (session, model)) in visits.iter().enumerate() {
        let failed = |failure: String| VisitAlignment {
            session: session.clone(),
            common_from_visit: None,
            failure: Some(failure),
            fitness: None,
        };
        let Some(model) = model else {
            results.push(failed("the visit alone gave no model".to_owned()));
            continue;
        };
        let placed = match alignment {
            Alignment::Navigation => fit_to_navigation(model, context.navigation).map(|(s, rms)| (s, Some(rms))),
            _ if index == 0 => Ok((Similarity::identity(), None)),
            Alignment::Icp | Alignment::Fpfh => {
                let Some(reference) = reference else {
                    results.push(failed("the first visit, the reference, has no model".to_owned()));
                    continue;
                };
                let method = if alignment == Alignment::Icp { Registration::Icp } else { Registration::Fpfh };
                let scratch = context.scratch.join(format!("{}-{session}", alignment.name()));
                match register(context.python, &scratch, reference, model, method, context.seed, cancelled)? {
                    Registered::Aligned { fixed_from_moving, fitness } => Ok((fixed_from_moving, Some(fitness))),
                    Registered::Failed { reason } => Err(reason),
                }
            }
        };
        match placed {
            Ok((common_from_visit, fitness)) => {
                let mut part = model.clone();
                part.transform(common_from_visit.scale, &common_from_visit.rigid());
                parts.push(part);
                results.push(VisitAlignment {
                    session: session.clone(),
                    common_from_visit: Some(common_from_visit),
                    failure: None,
                    fitness,
                });
            }
            Err(reason) => results.push(failed(reason)),
        }
    }
    Ok(Aligned { model: Reconstruction::merge(&parts), visits: results })
}
