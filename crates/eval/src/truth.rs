//! Registration and camera pose errors against ground-truth poses.

use std::collections::{BTreeMap, BTreeSet};

use nalgebra::Point3;
use revisit_core::{image_name, Reconstruction, Rigid3};
use serde::{Deserialize, Serialize};

use crate::{median_mean, umeyama, EvalError, Similarity};

/// A ground-truth camera pose.
#[derive(Clone, Debug, PartialEq)]
pub struct TruthPose {
    pub session: String,
    /// The image name in models: `session/image`.
    pub name: String,
    pub cam_from_world: Rigid3,
}

const TRUTH_COLUMNS: [&str; 9] = ["session", "image", "qw", "qx", "qy", "qz", "tx", "ty", "tz"];

/// Parses `poses.csv` (`session,image,qw,qx,qy,qz,tx,ty,tz`, `cam_from_world`).
/// The truth is generated, not clicked: any bad row is an error.
pub fn parse_truth_poses_csv(text: &str, source: &str) -> Result<Vec<TruthPose>, EvalError> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut reader = csv::ReaderBuilder::new().trim(csv::Trim::All).from_reader(text.as_bytes());
    let bad_file = |reason: String| EvalError::BadFile { source_name: source.to_owned(), reason };
    let headers = reader.headers().map_err(|e| bad_file(format!("header: {e}")))?.clone();
    let mut index = [0usize; 9];
    for (slot, column) in index.iter_mut().zip(TRUTH_COLUMNS) {
        *slot = headers
            .iter()
            .position(|h| h == column)
            .ok_or_else(|| bad_file(format!("no column {column:?} (expected {})", TRUTH_COLUMNS.join(","))))?;
    }
    let mut poses = Vec::new();
    for (i, record) in reader.records().enumerate() {
        let row = i + 1;
        let bad_row = |reason: String| EvalError::BadRow { source_name: source.to_owned(), row, reason };
        let record = record.map_err(|e| bad_row(e.to_string()))?;
        let cell = |k: usize| index.get(k).and_then(|&i| record.get(i)).unwrap_or_default();
        let mut numbers = [0.0f64; 7];
        for (k, value) in numbers.iter_mut().enumerate() {
            let text = cell(k + 2);
            *value = text.parse().map_err(|_| {
                bad_row(format!("{} {text:?} is not a number", TRUTH_COLUMNS.get(k + 2).unwrap_or(&"?")))
            })?;
        }
        let [qw, qx, qy, qz, tx, ty, tz] = numbers;
        let session = cell(0).to_owned();
        poses.push(TruthPose {
            name: image_name(&session, cell(1)),
            session,
            cam_from_world: Rigid3::from_wxyz([qw, qx, qy, qz], [tx, ty, tz]),
        });
    }
    Ok(poses)
}

/// How several models are aligned to the truth.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Alignment {
    /// One similarity for all models together: they are meant to share a
    /// frame (a joint model, or separately built models aligned afterwards),
    /// so a model in the wrong place shows as error. The default.
    #[default]
    Union,
    /// One similarity per model: each model's own accuracy, ignoring how the
    /// models sit relative to each other.
    EachModel,
}

/// Options of [`score_truth`].
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TruthOptions {
    /// Default [`Alignment::Union`].
    pub alignment: Alignment,
}

/// Camera errors after alignment over a set of images.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct PoseErrors {
    /// Images with both truth and an aligned estimate.
    pub images: usize,
    pub centre_median_m: Option<f64>,
    pub centre_mean_m: Option<f64>,
    /// The same as fractions of the scene size.
    pub centre_median_rel: Option<f64>,
    pub centre_mean_rel: Option<f64>,
    /// Angle of `R_truth * R_aligned^T`, degrees.
    pub rotation_median_deg: Option<f64>,
    pub rotation_mean_deg: Option<f64>,
}

impl PoseErrors {
    fn from_errors(centres_m: &[f64], rotations_deg: &[f64], scene_size_m: f64) -> Self {
        let (centre_median_m, centre_mean_m) = median_mean(centres_m);
        let (rotation_median_deg, rotation_mean_deg) = median_mean(rotations_deg);
        let rel = |v: Option<f64>| v.filter(|_| scene_size_m > 0.0).map(|v| v / scene_size_m);
        Self {
            images: centres_m.len(),
            centre_median_m,
            centre_mean_m,
            centre_median_rel: rel(centre_median_m),
            centre_mean_rel: rel(centre_mean_m),
            rotation_median_deg,
            rotation_mean_deg,
        }
    }
}

/// Truth figures of one session.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct SessionTruth {
    pub images_in_truth: usize,
    /// Images of this session registered in the largest model.
    pub registered_in_largest: usize,
    /// `registered_in_largest / images_in_truth`.
    pub registration_rate: f64,
    /// Images of this session registered in any model.
    pub registered_in_any: usize,
    pub pose: PoseErrors,
    /// The session's scale in its model against the model's: the similarity fitted to this
    /// session's cameras alone, its scale over that of the alignment used for the model, minus
    /// 1 (0.01 = this visit comes out 1% larger than the rest of the model). `None` with fewer
    /// than 3 registered images.
    pub scale_rel_error: Option<f64>,
}

/// Figures against ground-truth poses.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct TruthScores {
    pub alignment: Alignment,
    /// Diagonal of the bounding box of the truth camera centres, metres.
    pub scene_size_m: f64,
    pub images_in_truth: usize,
    /// Index of the model with the most truth images (first on ties).
    pub largest_model: Option<usize>,
    /// The similarity per model (truth from model); `None` where a model
    /// could not be aligned (fewer than 3 usable images, or degenerate).
    pub similarities: Vec<Option<Similarity>>,
    pub overall: PoseErrors,
    pub sessions: BTreeMap<String, SessionTruth>,
}

/// Registration rates and camera errors of `models` against `truth`.
pub fn score_truth(models: &[Reconstruction], truth: &[TruthPose], options: &TruthOptions) -> TruthScores {
    let truth_by_name: BTreeMap<&str, &TruthPose> = truth.iter().map(|t| (t.name.as_str(), t)).collect();
    let centres: Vec<Point3<f64>> = truth.iter().map(|t| t.cam_from_world.origin_of_target()).collect();
    let scene_size_m = bounding_box_diagonal(&centres);

    // Each image counted once, in its first model.
    let mut seen = BTreeSet::new();
    let mut per_model: Vec<Vec<(&TruthPose, Rigid3)>> = Vec::with_capacity(models.len());
    for model in models {
        let mut matched = Vec::new();
        for image in model.images.values() {
            if let Some(t) = truth_by_name.get(image.name.as_str()) {
                if seen.insert(image.name.as_str()) {
                    matched.push((*t, image.cam_from_world));
                }
            }
        }
        per_model.push(matched);
    }
    let largest_model = per_model
        .iter()
        .enumerate()
        .max_by(|(ia, a), (ib, b)| a.len().cmp(&b.len()).then(ib.cmp(ia)))
        .filter(|(_, m)| !m.is_empty())
        .map(|(i, _)| i);

    let fit = |pairs: &[&(&TruthPose, Rigid3)]| {
        let src: Vec<Point3<f64>> = pairs.iter().map(|(_, est)| est.origin_of_target()).collect();
        let dst: Vec<Point3<f64>> = pairs.iter().map(|(t, _)| t.cam_from_world.origin_of_target()).collect();
        umeyama(&src, &dst).ok()
    };
    let similarities: Vec<Option<Similarity>> = match options.alignment {
        Alignment::Union => {
            let all: Vec<&(&TruthPose, Rigid3)> = per_model.iter().flatten().collect();
            let union = fit(&all);
            per_model.iter().map(|_| union).collect()
        }
        Alignment::EachModel => per_model.iter().map(|m| fit(&m.iter().collect::<Vec<_>>())).collect(),
    };

    let mut centre_errors: BTreeMap<&str, Vec<f64>> = BTreeMap::new();
    let mut rotation_errors: BTreeMap<&str, Vec<f64>> = BTreeMap::new();
    for (matched, similarity) in per_model.iter().zip(&similarities) {
        let Some(similarity) = similarity else { continue };
        for (t, est) in matched {
            let centre = similarity.apply(&est.origin_of_target());
            let centre_error_m = (centre - t.cam_from_world.origin_of_target()).norm();
            // cam_from_truth = cam_from_est * est_from_truth
            let rotation_aligned = est.rotation * similarity.rotation.inverse();
            let rotation_error_deg = (t.cam_from_world.rotation * rotation_aligned.inverse()).angle().to_degrees();
            centre_errors.entry(t.session.as_str()).or_default().push(centre_error_m);
            rotation_errors.entry(t.session.as_str()).or_default().push(rotation_error_deg);
        }
    }

    let mut sessions: BTreeMap<String, SessionTruth> = BTreeMap::new();
    for t in truth {
        sessions.entry(t.session.clone()).or_default().images_in_truth += 1;
    }
    for (m, matched) in per_model.iter().enumerate() {
        for (t, _) in matched {
            if let Some(s) = sessions.get_mut(&t.session) {
                s.registered_in_any += 1;
                if Some(m) == largest_model {
                    s.registered_in_largest += 1;
                }
            }
        }
    }
    for (name, s) in sessions.iter_mut() {
        s.registration_rate = s.registered_in_largest as f64 / s.images_in_truth.max(1) as f64;
        let empty = Vec::new();
        s.pose = PoseErrors::from_errors(
            centre_errors.get(name.as_str()).unwrap_or(&empty),
            rotation_errors.get(name.as_str()).unwrap_or(&empty),
            scene_size_m,
        );
    }
    for (matched, similarity) in per_model.iter().zip(&similarities) {
        let Some(similarity) = similarity else { continue };
        for (name, s) in sessions.iter_mut() {
            let own: Vec<&(&TruthPose, Rigid3)> = matched.iter().filter(|(t, _)| t.session == *name).collect();
            if own.len() >= 3 {
                s.scale_rel_error = fit(&own).map(|alone| alone.scale / similarity.scale - 1.0);
            }
        }
    }
    let all_centres: Vec<f64> = centre_errors.values().flatten().copied().collect();
    let all_rotations: Vec<f64> = rotation_errors.values().flatten().copied().collect();
    TruthScores {
        alignment: options.alignment,
        scene_size_m,
        images_in_truth: truth.len(),
        largest_model,
        similarities,
        overall: PoseErrors::from_errors(&all_centres, &all_rotations, scene_size_m),
        sessions,
    }
}

fn bounding_box_diagonal(points: &[Point3<f64>]) -> f64 {
    let Some(first) = points.first() else { return 0.0 };
    let (mut lo, mut hi) = (first.coords, first.coords);
    for p in points {
        lo = lo.inf(&p.coords);
        hi = hi.sup(&p.coords);
    }
    (hi - lo).norm()
}
