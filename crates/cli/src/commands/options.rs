//! The options of a reconstruction as command-line arguments: one flattened
//! group that `reconstruct` (and any command that runs a reconstruction)
//! turns into the pipeline's `ReconstructOptions`.

use std::path::PathBuf;

use revisit_colmap::{Engine, PlyColors};
use revisit_features::learned::LearnedInput;
use revisit_matching::RollSearch;
use revisit_pipeline::learned::LearnedMethod;
use revisit_pipeline::options::{CameraSpec, PlaceSource, ReconstructOptions};
use revisit_pipeline::CrossStrategy;

use crate::commands::models::{cross_strategies, learned_methods};

#[derive(Clone, Copy, clap::ValueEnum)]
enum LearnedInputArg {
    /// Each channel stretched linearly between its 1st and 99th percentiles:
    /// a visit's colour cast, haze and light level taken out (more right
    /// cross-visit matches; README).
    Stretched,
    /// Stretched, then CLAHE on the luminance (more matches, right and
    /// wrong; README).
    Equalized,
    /// The image as it is.
    Raw,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum RollSearchArg {
    /// Match at the roll that the two sessions' verified pairs agree on (their
    /// heading offset, chained through each session's own pairs): one match a
    /// pair, two when the predicted turn falls between two rolls; pairs before
    /// there is agreement are matched in full from the roll place recognition
    /// found nearest, until a roll wins clearly (--roll-margin times the
    /// runner-up and 45 inliers). About 3x faster than the probe and keeps
    /// pairs at a roll other than their visits' out (most of them wrong), so
    /// an image that only such a pair brought into the model may stay out.
    Predict,
    /// Decide the roll on the strongest keypoints of each image, then match
    /// once in full (in full at every roll if no roll wins by --roll-margin).
    Probe,
    /// Match in full at every roll (4x the matching cost).
    Full,
    /// Roll 0 only: for visits flown at the same heading.
    Off,
}

/// A calibrated camera for some cameras: `[SESSION[/CAMERA]=]MODEL:PARAMS`.
#[derive(Clone, Debug)]
struct CameraArg {
    key: String,
    spec: CameraSpec,
}

impl std::str::FromStr for CameraArg {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let (key, spec) = match s.split_once('=') {
            Some((key, spec)) => (key.to_owned(), spec),
            None => (String::new(), s),
        };
        Ok(CameraArg { key, spec: spec.parse()? })
    }
}

/// A rectangle in pixels: X,Y,W,H.
#[derive(Clone, Copy, Debug)]
struct Region([u32; 4]);

impl std::str::FromStr for Region {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let values: Vec<u32> = s
            .split(',')
            .map(|v| v.trim().parse::<u32>().map_err(|_| format!("{s:?} is not X,Y,W,H in whole pixels")))
            .collect::<Result<_, _>>()?;
        match values[..] {
            [x, y, w, h] if w > 0 && h > 0 => Ok(Region([x, y, w, h])),
            _ => Err(format!("{s:?} is not X,Y,W,H with a positive width and height")),
        }
    }
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum MapperArg {
    /// COLMAP's incremental SfM; extends the previous model when sessions are added.
    Incremental,
    /// GLOMAP's global SfM (rebuilds from scratch).
    Global,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum PlyColorsArg {
    /// The points' own colours.
    Rgb,
    /// One colour per session (the session of the first image seeing the point).
    Session,
}

/// Every option of a reconstruction (defaults: the pipeline's).
#[derive(clap::Args)]
pub struct OptionArgs {
    /// How images of different sessions are paired and matched.
    #[arg(long, default_value = "vpr", value_parser = cross_strategies())]
    pub cross: CrossStrategy,
    /// The learned matcher.
    #[arg(long, default_value = "aliked-lightglue", value_parser = learned_methods())]
    learned: LearnedMethod,
    /// How the roll (0/90/180/270 degrees) of the second image of a
    /// cross-session pair is chosen.
    #[arg(long, value_enum, default_value = "predict")]
    roll_search: RollSearchArg,
    /// Place recognition: each image of a later session is paired with its N
    /// nearest images of earlier sessions.
    #[arg(long, default_value_t = 5, value_name = "N")]
    vpr_top_k: usize,
    /// Place recognition: only candidates closer than D (L2 distance between
    /// normalised global descriptors, 0..2).
    #[arg(long, value_name = "D")]
    vpr_max_distance: Option<f32>,
    /// With navigation (--nav, --nav-topic): images whose navigated positions lie more than
    /// METRES apart are never a cross-visit pair (place recognition's candidates among them are
    /// dropped), and each image of a later visit is also paired with its --vpr-top-k nearest
    /// images of earlier visits within METRES. Set it to what the camera sees across plus the
    /// navigation's uncertainty (e.g. 2 x altitude x tan(half the field of view) + 3 sigma).
    /// Pairs the store already holds stay. Default: navigation picks no pairs.
    #[arg(long, value_name = "METRES")]
    nav_radius: Option<f64>,
    /// Place recognition: a global-descriptor ONNX model (RGB image [1, 3, H, W]
    /// in 0..1 -> [1, D]), e.g. MegaLoc. Default: built-in VLAD over the
    /// learned features, with a vocabulary learned from the survey.
    #[arg(long, value_name = "ONNX")]
    vpr_model: Option<PathBuf>,
    /// A learned keypoint this close to a SIFT keypoint is matched as that
    /// SIFT keypoint, which links cross-session matches to each session's tracks.
    #[arg(long, default_value_t = revisit_matching::cross::DEFAULT_ANCHOR_RADIUS_PX, value_name = "PX")]
    anchor_radius: f32,
    /// A learned match is kept only when LightGlue gives it more than this
    /// probability. At LightGlue's own 0.1 it also keeps matches it places on
    /// surfaces that changed between visits (renewed sand, bleached coral): a
    /// few pixels off, they verify and make about half the cross-visit pairs
    /// wrong at strong change. 0.5 keeps far fewer wrong pairs and places the
    /// visits better where change is in appearance, but can leave too few right
    /// pairs where corals moved (a storm): --confident-probability and
    /// --confident-pairs use the more probable matches where there are enough.
    #[arg(long, default_value_t = revisit_matching::cross::DEFAULT_MIN_MATCH_PROBABILITY, value_name = "P")]
    min_match_probability: f32,
    /// A verified cross-visit pair is confident when its matches more probable
    /// than P verify on their own (the store keeps their inliers beside the
    /// pair's); the others are weak. See --confident-pairs.
    #[arg(long, default_value_t = revisit_matching::cross::DEFAULT_CONFIDENT_PROBABILITY, value_name = "P")]
    confident_probability: f32,
    /// Map two visits with at least N confident cross-visit pairs on those
    /// alone, each on its confident inliers, and set their weak pairs aside
    /// (their inliers hold the matches LightGlue was unsure of: on changed
    /// surfaces, a few pixels off). Two visits with fewer keep every pair.
    /// For change in appearance (light, turbidity, bleaching, renewed sand):
    /// the demo survey goes from 0.98 to 0.52 px with N = 8. Not where corals
    /// grew or moved: LightGlue is sure of them, and the pairs kept are wrong.
    /// Decided afresh at every run (nothing is matched again). Default: off.
    #[arg(long, value_name = "N")]
    confident_pairs: Option<usize>,
    /// Fewest verified inliers of a learned (cross-visit) pair.
    #[arg(long, default_value_t = revisit_matching::CROSS_MIN_INLIERS, value_name = "N")]
    cross_min_inliers: usize,
    /// Largest epipolar error of a learned (cross-visit) inlier, pixels.
    #[arg(long, default_value_t = 4.0, value_name = "PX")]
    cross_max_error: f64,
    /// A cross-visit pair is kept only if its roll's inliers are at least R
    /// times those of the runner-up roll (chance matches find about as many
    /// at every roll); a probe that no roll wins by R falls back to the full
    /// search, and a search from place recognition's roll stops only at a roll
    /// with R times the runner-up's and R times 45 inliers. 1 turns the check off.
    #[arg(long, default_value_t = revisit_matching::roll::DEFAULT_ROLL_MARGIN, value_name = "R")]
    roll_margin: f32,
    /// Before mapping, a verified cross-visit pair is reported inconsistent when
    /// the heading offset between its two visits that its matches imply is
    /// more than DEG from the one the visits' other pairs agree on, or when its
    /// matches do not turn the image by the roll it was matched at.
    #[arg(long, default_value_t = revisit_matching::DEFAULT_CONSISTENCY_TOLERANCE_DEG, value_name = "DEG")]
    consistency_tolerance: f64,
    /// Set inconsistent cross-visit pairs aside (not mapped) instead of only
    /// reporting them.
    #[arg(long)]
    set_aside_inconsistent: bool,
    /// With navigation priors (--nav, --nav-topic), a verified cross-visit pair
    /// whose matches put the other camera farther from its navigated position
    /// than SIGMAS standard deviations of the two positions (at least 64
    /// pixels' worth) is inconsistent (reported; set aside with
    /// --set-aside-inconsistent): two images of different places can match
    /// coherently on a near-flat seabed, and navigation tells them apart. Such
    /// pairs still hold the few right matches a visit that changed much may
    /// have: --change-aware mapping judges their matches one by one, and
    /// placed such visits better with them. Each visit's own
    /// pairs calibrate how its navigation maps to its pixels (scale, headings,
    /// ENU or NED). When most pairs of two visits miss by about the same
    /// distance, the navigation is what is off (a visit's position fix): they
    /// are kept and the visit's offset is reported. 0 turns the check off.
    #[arg(long, default_value_t = revisit_matching::DEFAULT_NAVIGATION_TOLERANCE_SIGMAS, value_name = "SIGMAS")]
    nav_check: f64,
    /// A verified cross-visit pair whose loops with the other cross-visit
    /// pairs miss (image a to image b through another pair and the two
    /// visits' own pairs must land where the pair itself puts image a's centre,
    /// within SHARE of the image diagonal) is inconsistent when most of its
    /// loops through trusted pairs (pairs whose loops mostly close) miss.
    /// Needs no navigation: wrong pairs rarely agree with each other. The
    /// trusted pairs are confirmed, and after mapping the model is checked
    /// against them: two visits it placed at odds with most of their confirmed
    /// pairs are warned about. 0 turns both checks off.
    #[arg(long, default_value_t = revisit_matching::DEFAULT_LOOP_TOLERANCE, value_name = "SHARE")]
    loop_check: f64,
    /// LightGlue sees at most N keypoints of each image of a pair: those whose descriptors
    /// come nearest one of the other image's (a keypoint where the other image shows
    /// another part of the scene has none). Its cost grows with the square of N: 384 of
    /// ALIKED's 1024 match in a third of the time with far fewer wrong cross-visit pairs and
    /// as many right ones, but fewer matches to place the visits by, which the change map
    /// feels (README). 0: all.
    #[arg(long, default_value_t = revisit_matching::cross::DEFAULT_KEYPOINT_BUDGET.unwrap_or(0), value_name = "N")]
    cross_keypoints: usize,
    /// Images and pairs the learned models work on at once, each on one thread
    /// of ONNX Runtime; 1 = one at a time on every thread; 0 = one per core, as
    /// many as the available memory holds. The results do not depend on it.
    #[arg(long, default_value_t = 0, value_name = "N")]
    learned_workers: usize,
    /// Largest number of SIFT features per image (the strongest are kept).
    #[arg(long, default_value_t = 4096, value_name = "N")]
    max_features: usize,
    /// Images whose larger side exceeds this are downscaled for extraction
    /// (keypoints are reported in full-resolution pixels).
    #[arg(long, default_value_t = 3200, value_name = "PX")]
    max_image_size: u32,
    /// What the learned extractor sees of each image.
    #[arg(long, value_enum, default_value = "stretched")]
    learned_input: LearnedInputArg,
    /// A calibrated camera, [SESSION[/CAMERA]=]MODEL:PARAMS in COLMAP's
    /// parameter order (e.g. PINHOLE:fx,fy,cx,cy or
    /// OPENCV:fx,fy,cx,cy,k1,k2,p1,p2); its intrinsics are held fixed.
    /// Without SESSION it applies to every camera; the most specific wins.
    /// Repeatable. Cameras without one are self-calibrated, starting from
    /// the EXIF focal length when the images carry one.
    #[arg(long = "camera", value_name = "[SESSION[/CAMERA]=]MODEL:PARAMS")]
    cameras: Vec<CameraArg>,
    /// Visits flown with the same camera share its intrinsics: a camera of
    /// one name and size is one COLMAP camera across visits, refined jointly
    /// from all their images (stronger self-calibration than per visit).
    #[arg(long)]
    shared_camera: bool,
    /// Upright SIFT (no orientation): only for cameras that never roll.
    #[arg(long)]
    upright: bool,
    /// A region to ignore in every image, X,Y,W,H in pixels (e.g. a burned-in
    /// timestamp). Repeatable.
    #[arg(long = "ignore-region", value_name = "X,Y,W,H")]
    ignore_regions: Vec<Region>,
    /// Sessions of at most this many images are matched exhaustively; longer
    /// ones with a sequential window plus periodic loop candidates.
    #[arg(long, default_value_t = 100, value_name = "N")]
    exhaustive_max_images: usize,
    /// Long sessions: match each image with the next N.
    #[arg(long, default_value_t = 10, value_name = "N")]
    window: usize,
    /// Long sessions: every N-th image is also matched with every other N-th.
    #[arg(long, default_value_t = 5, value_name = "N")]
    loop_period: usize,
    /// The COLMAP mapper.
    #[arg(long, value_enum, default_value = "incremental")]
    mapper: MapperArg,
    /// Change-aware mapping: map each visit alone, place the visits by the
    /// similarity most of their cross-visit matches agree with (and by their
    /// navigation, with --nav), then triangulate every match at those
    /// placements and bundle-adjust them jointly, so that matches on
    /// structure that changed (a coral that grew) or wrong pairs do not bend
    /// whole visits. report.json says, per visit pair, how many cross-visit
    /// matches were kept and dropped. Incremental mapper only; maps afresh
    /// on every run.
    #[arg(long)]
    change_aware: bool,
    /// COLMAP's threads; -1 = all cores. More threads map faster, but the
    /// poses then differ in their last digits from run to run.
    #[arg(long, default_value_t = 1, value_name = "N", allow_negative_numbers = true)]
    mapper_threads: i32,
    /// Seed of every random choice (RANSAC, COLMAP).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// How points.ply is coloured.
    #[arg(long, value_enum, default_value = "rgb")]
    ply_colors: PlyColorsArg,
}

impl OptionArgs {
    /// The pipeline's options from the arguments (checked by the pipeline).
    pub fn options(&self) -> ReconstructOptions {
        let mut options = ReconstructOptions { cross: self.cross, learned: self.learned, ..Default::default() };
        let sift = &mut options.features.sift;
        sift.max_num_features = self.max_features;
        sift.upright = self.upright;
        sift.ignore_regions_px = self.ignore_regions.iter().map(|r| r.0).collect();
        options.features.max_image_size_px = self.max_image_size;
        options.features.learned_input = match self.learned_input {
            LearnedInputArg::Stretched => LearnedInput::Stretched,
            LearnedInputArg::Equalized => LearnedInput::Equalized,
            LearnedInputArg::Raw => LearnedInput::Raw,
        };
        options.pairs.exhaustive_max_images = self.exhaustive_max_images;
        options.pairs.window = self.window;
        options.pairs.loop_period = self.loop_period;
        let cross = &mut options.learned_matching;
        cross.roll_search = match self.roll_search {
            RollSearchArg::Predict => RollSearch::PREDICT,
            RollSearchArg::Probe => RollSearch::PROBE,
            RollSearchArg::Full => RollSearch::Full,
            RollSearchArg::Off => RollSearch::Off,
        };
        cross.roll_margin = self.roll_margin;
        cross.min_match_probability = self.min_match_probability;
        cross.confident_probability = self.confident_probability;
        cross.confident_pairs = self.confident_pairs;
        cross.anchor_radius_px = self.anchor_radius;
        cross.verify.min_inliers = self.cross_min_inliers;
        cross.verify.max_error_px = self.cross_max_error;
        cross.consistency_tolerance_deg = self.consistency_tolerance;
        cross.set_aside_inconsistent = self.set_aside_inconsistent;
        cross.navigation_tolerance_sigmas = self.nav_check;
        cross.loop_tolerance = self.loop_check;
        cross.keypoint_budget = (self.cross_keypoints > 0).then_some(self.cross_keypoints);
        options.learned_workers = self.learned_workers;
        options.places.candidates.top_k = self.vpr_top_k;
        options.places.candidates.max_distance = self.vpr_max_distance;
        options.places.navigation_radius_m = self.nav_radius;
        if let Some(model) = &self.vpr_model {
            options.places.source = PlaceSource::Onnx(model.clone());
        }
        options.cameras.calibrated = self.cameras.iter().map(|c| (c.key.clone(), c.spec.clone())).collect();
        options.cameras.shared = self.shared_camera;
        options.mapper.engine = match self.mapper {
            MapperArg::Incremental => Engine::Incremental,
            MapperArg::Global => Engine::Global,
        };
        options.mapper.threads = self.mapper_threads;
        options.mapper.change_aware = self.change_aware;
        options.ply_colors = match self.ply_colors {
            PlyColorsArg::Rgb => PlyColors::Rgb,
            PlyColorsArg::Session => PlyColors::BySession,
        };
        options.with_seed(self.seed)
    }
}
