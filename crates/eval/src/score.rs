//! The published protocol: the 3D point seen at a clicked pixel of `img0` is
//! projected into `img1` with the estimated pose; the error is the pixel
//! distance to where the point truly is in `img1`.

use std::collections::{BTreeMap, BTreeSet};

use nalgebra::Point2;
use revisit_core::{Image, Reconstruction};
use serde::{Deserialize, Serialize};

use crate::{median_mean, session_of, ClickPair, EvalError};

/// Options of [`score`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ScoreOptions {
    /// A click takes the 3D point of the nearest triangulated keypoint of
    /// `img0` within this distance, in pixels. Default 3.0.
    pub radius_px: f64,
    /// Added to both coordinates of every clicked and ground-truth pixel to
    /// bring them to COLMAP's convention (centre of the top-left pixel at
    /// (0.5, 0.5)). Default 0.0: the files use COLMAP's convention.
    pub uv_offset_px: f64,
    /// Instead of the nearest keypoint's 3D point itself, take the point on
    /// the clicked pixel's ray at that point's depth in `img0`. This removes
    /// the keypoint-to-click offset from the error (useful with exact
    /// synthetic clicks and sparse keypoints). Default false: the published
    /// rule.
    pub at_click_depth: bool,
}

impl Default for ScoreOptions {
    fn default() -> Self {
        Self { radius_px: 3.0, uv_offset_px: 0.0, at_click_depth: false }
    }
}

impl ScoreOptions {
    pub fn check(&self) -> Result<(), EvalError> {
        if !(self.radius_px.is_finite() && self.radius_px > 0.0) {
            return Err(EvalError::BadOption { option: "radius_px", reason: format!("{} is not > 0", self.radius_px) });
        }
        if !self.uv_offset_px.is_finite() {
            return Err(EvalError::BadOption { option: "uv_offset_px", reason: "not finite".to_owned() });
        }
        Ok(())
    }
}

/// Why a click was not scored.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SkipReason {
    /// `img0` is in no model (or its name is ambiguous).
    Img0NotInModel,
    /// `img1` is in no model (or its name is ambiguous).
    Img1NotInModel,
    /// No triangulated keypoint of `img0` within `radius_px` of the click.
    NoPoint3dWithinRadius,
    /// The 3D point is behind `img1`'s camera, or its camera model cannot
    /// project.
    NotProjectable,
}

impl SkipReason {
    pub const ALL: [SkipReason; 4] =
        [Self::Img0NotInModel, Self::Img1NotInModel, Self::NoPoint3dWithinRadius, Self::NotProjectable];

    pub fn as_str(self) -> &'static str {
        match self {
            Self::Img0NotInModel => "img0_not_in_model",
            Self::Img1NotInModel => "img1_not_in_model",
            Self::NoPoint3dWithinRadius => "no_point3d_within_radius",
            Self::NotProjectable => "not_projectable",
        }
    }
}

/// Figures over a set of clicks.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Summary {
    pub scored: usize,
    /// Clicks not scored, all reasons together.
    pub skipped: usize,
    pub skipped_by_reason: BTreeMap<SkipReason, usize>,
    /// `None` (JSON `null`) when nothing was scored.
    pub median_px: Option<f64>,
    pub mean_px: Option<f64>,
    /// Every scored error, in input order (for histograms).
    pub errors_px: Vec<f64>,
}

impl Summary {
    fn add(&mut self, outcome: Result<f64, SkipReason>) {
        match outcome {
            Ok(error_px) => {
                self.scored += 1;
                self.errors_px.push(error_px);
            }
            Err(reason) => {
                self.skipped += 1;
                *self.skipped_by_reason.entry(reason).or_default() += 1;
            }
        }
    }

    fn finish(&mut self) {
        (self.median_px, self.mean_px) = median_mean(&self.errors_px);
    }
}

/// What happened to one click.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ClickResult {
    pub source: String,
    pub row: usize,
    pub img0: String,
    pub img1: String,
    /// Session pair key, see [`Scores::pairs`].
    pub pair: String,
    pub uv_clicked: [f64; 2],
    pub uv_groundtruth: [f64; 2],
    /// Where the model puts the clicked point in `img1` (file convention).
    pub uv_projected: Option<[f64; 2]>,
    pub error_px: Option<f64>,
    pub skipped: Option<SkipReason>,
}

/// The scores of a set of click pairs.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Scores {
    /// All clicks together.
    #[serde(flatten)]
    pub overall: Summary,
    pub radius_px: f64,
    /// True iff a single model holds images of every session in the pairs.
    pub one_model: bool,
    /// Number of models given to [`score`].
    pub models: usize,
    /// Rows of the click files that could not be read. [`score`] leaves it at
    /// 0: the caller that parsed the files fills it in.
    pub malformed_rows: usize,
    /// Per session pair, keyed `"A-B"` with the two session names in sorted
    /// order (the same key for both directions).
    pub pairs: BTreeMap<String, Summary>,
    pub clicks: Vec<ClickResult>,
}

/// Where an image lives: which model, and the image.
type Located<'a> = (usize, &'a Image);

/// Finds images by name across models: the exact name, else a unique image
/// whose name ends with `/name` (published files may omit the session).
struct ImageIndex<'a> {
    by_name: BTreeMap<&'a str, Vec<Located<'a>>>,
}

impl<'a> ImageIndex<'a> {
    fn new(models: &'a [Reconstruction]) -> Self {
        let mut by_name: BTreeMap<&str, Vec<Located>> = BTreeMap::new();
        for (m, model) in models.iter().enumerate() {
            for image in model.images.values() {
                by_name.entry(image.name.as_str()).or_default().push((m, image));
            }
        }
        Self { by_name }
    }

    /// All models holding the image of that name (first model first).
    fn find(&self, name: &str) -> Vec<Located<'a>> {
        if let Some(found) = self.by_name.get(name) {
            return found.clone();
        }
        let suffix = format!("/{name}");
        let matches: Vec<&str> = self.by_name.keys().copied().filter(|n| n.ends_with(&suffix)).collect();
        match matches.as_slice() {
            [only] => self.by_name.get(only).cloned().unwrap_or_default(),
            _ => Vec::new(),
        }
    }
}

/// Scores click pairs against one or more models. With several models
/// (separately built, aligned afterwards) `img0` and `img1` may lie in
/// different ones: the 3D point comes from the model holding `img0` and is
/// projected with the model holding `img1`; the models are assumed to share
/// one frame. When one model holds both images, that model is used.
pub fn score(models: &[Reconstruction], pairs: &[ClickPair], options: &ScoreOptions) -> Scores {
    let index = ImageIndex::new(models);
    let mut scores = Scores { radius_px: options.radius_px, models: models.len(), ..Scores::default() };
    let mut sessions_in_pairs = BTreeSet::new();
    for pair in pairs {
        let found0 = index.find(&pair.img0);
        let found1 = index.find(&pair.img1);
        // Prefer a model that holds both; else the first holding each.
        let both =
            found0.iter().find_map(|&(m0, i0)| found1.iter().find(|(m1, _)| *m1 == m0).map(|&l1| ((m0, i0), l1)));
        let (loc0, loc1) = match both {
            Some((l0, l1)) => (Some(l0), Some(l1)),
            None => (found0.first().copied(), found1.first().copied()),
        };
        let session0 = loc0.map_or_else(|| session_of(&pair.img0).to_owned(), |(_, i)| session_of(&i.name).to_owned());
        let session1 = loc1.map_or_else(|| session_of(&pair.img1).to_owned(), |(_, i)| session_of(&i.name).to_owned());
        let key =
            if session0 <= session1 { format!("{session0}-{session1}") } else { format!("{session1}-{session0}") };
        sessions_in_pairs.insert(session0);
        sessions_in_pairs.insert(session1);
        for (clicked, truth) in pair.uv_clicked.iter().zip(&pair.uv_groundtruth) {
            let offset = options.uv_offset_px;
            let clicked_px = Point2::new(clicked[0] + offset, clicked[1] + offset);
            let truth_px = Point2::new(truth[0] + offset, truth[1] + offset);
            let projected = match (loc0, loc1) {
                (None, _) => Err(SkipReason::Img0NotInModel),
                (_, None) => Err(SkipReason::Img1NotInModel),
                (Some(l0), Some(l1)) => score_click(models, l0, l1, &clicked_px, options),
            };
            let outcome = projected.map(|p| (p - truth_px).norm());
            scores.overall.add(outcome);
            scores.pairs.entry(key.clone()).or_default().add(outcome);
            scores.clicks.push(ClickResult {
                source: pair.source.clone(),
                row: pair.row,
                img0: pair.img0.clone(),
                img1: pair.img1.clone(),
                pair: key.clone(),
                uv_clicked: *clicked,
                uv_groundtruth: *truth,
                uv_projected: projected.ok().map(|p| [p.x - offset, p.y - offset]),
                error_px: outcome.ok(),
                skipped: outcome.err(),
            });
        }
    }
    scores.overall.finish();
    for summary in scores.pairs.values_mut() {
        summary.finish();
    }
    scores.one_model = models.iter().any(|model| {
        let held: BTreeSet<&str> = model.images.values().map(|i| session_of(&i.name)).collect();
        sessions_in_pairs.iter().all(|s| held.contains(s.as_str()))
    });
    scores
}

/// The clicked pixel's 3D point (nearest triangulated keypoint of `img0`
/// within `radius_px`, optionally moved along the click's ray) projected into `img1`.
fn score_click(
    models: &[Reconstruction],
    (m0, image0): Located<'_>,
    (m1, image1): Located<'_>,
    clicked_px: &Point2<f64>,
    options: &ScoreOptions,
) -> Result<Point2<f64>, SkipReason> {
    let radius_px = options.radius_px;
    let (Some(model0), Some(model1)) = (models.get(m0), models.get(m1)) else {
        return Err(SkipReason::Img0NotInModel);
    };
    let point_in_world = image0
        .points2d
        .iter()
        .filter_map(|o| {
            let point = model0.points3d.get(&o.point3d_id?)?;
            let distance_px = (o.xy - clicked_px).norm();
            (distance_px <= radius_px).then_some((distance_px, point.xyz))
        })
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .map(|(_, xyz)| xyz)
        .ok_or(SkipReason::NoPoint3dWithinRadius)?;
    let point_in_world = if options.at_click_depth {
        let camera0 = model0.cameras.get(&image0.camera_id).ok_or(SkipReason::NotProjectable)?;
        let depth = (image0.cam_from_world * point_in_world).z;
        let ray = camera0.cam_from_img(clicked_px).ok_or(SkipReason::NotProjectable)?;
        image0.cam_from_world.inverse() * nalgebra::Point3::from(ray * depth)
    } else {
        point_in_world
    };
    model1.project(image1, &point_in_world).ok_or(SkipReason::NotProjectable)
}
