//! One learned pair, start to finish: the learned matcher with roll search,
//! anchoring of learned keypoints to each image's own keypoints, and the rule
//! that accepts or rejects the pair. The pipeline's store loop, `revisit
//! match` and the ROS matcher node all call [`match_learned_pair`].
//!
//! The acceptance rule ([`accept`]) is pure and separate so that it can be
//! read and tested on its own: a pair is kept only if
//! 1. its winning roll stands out ([`CrossMatch::roll_is_clear`]: on a pair
//!    that shows no common place every roll finds a few chance inliers, about
//!    as many at each), and
//! 2. its matches, once each learned keypoint is anchored to the image's own
//!    keypoint at the same spot and every keypoint is used at most once per
//!    side, verify geometrically with at least `verify.min_inliers` inliers.
//!
//! A pair so accepted is *confident* when its more probable matches
//! (`confident_probability`) verify on their own; their inliers are kept
//! beside the pair's. The others are *weak*. Asked to (`confident_pairs`),
//! the consistency stage maps two visits that hold enough confident pairs on
//! those alone, each on its confident inliers, and sets the weak ones aside.

use std::collections::HashSet;

use revisit_core::{CrossKey, Keypoint, LearnedFeatures, PairKind, Roll, TwoViewGeometry};
use revisit_onnx::OnnxError;
use serde::{Deserialize, Serialize};

use crate::consistency::{
    DEFAULT_CONSISTENCY_TOLERANCE_DEG, DEFAULT_LOOP_TOLERANCE, DEFAULT_NAVIGATION_TOLERANCE_SIGMAS,
};
use crate::lightglue::LIGHTGLUE_MATCH_THRESHOLD;
use crate::roll::{
    match_at_prediction, match_with_rolls, unrolled_keypoints, CrossMatch, Prediction, RollSearch, DEFAULT_ROLL_MARGIN,
};
use crate::verify::{verify, VerifyOptions};
use crate::{anchor_keypoints, check_range, LightGlue, OptionsError};

/// Fewest verified inliers of a learned pair, by default: cross-visit pairs
/// are rarer and their chance inliers more plentiful than within a visit, so
/// twice COLMAP's 15.
pub const CROSS_MIN_INLIERS: usize = 30;

/// Least probability of a learned match, by default: LightGlue's own
/// ([`LIGHTGLUE_MATCH_THRESHOLD`]). Across visits, where sand was renewed and
/// corals bleached, LightGlue also pairs keypoints of surfaces that changed,
/// placed where the geometry of the structure that held would put them: a few
/// pixels off, yet within the 4 px band, and coherent enough to bend the
/// fundamental matrix. On `scripts/demo.sh`'s survey (issue 11's note) half the
/// verified cross-visit pairs (52 of 108) are wrong by the truth at 0.1 and the
/// model is 0.98 px off; at 0.5, 3 of 54 and 0.52 px, with as many right pairs.
/// It stays at 0.1 because 0.5 leaves too few right pairs elsewhere: on a storm
/// survey (3 x 12, seed 5) the three that remain wrong (a moved coral, matched
/// with confidence) merge a visit 119 px off, where 0.1 links it right, and
/// `tests/compare.rs`'s 2 x 10 reef keeps 7 pairs and leaves a visit out. The
/// confident pairs ([`CrossOptions::confident_probability`]) take the more
/// probable matches where there are enough of them.
pub const DEFAULT_MIN_MATCH_PROBABILITY: f32 = LIGHTGLUE_MATCH_THRESHOLD;

/// Least probability of a confident match, by default: see
/// [`CrossOptions::confident_probability`]. On `scripts/demo.sh`'s survey
/// (issue 11's note) verifying a pair on its matches above 0.5 leaves 3 wrong
/// pairs of 54 where all matches above 0.1 leave 52 of 108.
pub const DEFAULT_CONFIDENT_PROBABILITY: f32 = 0.5;

/// Anchoring radius, by default, pixels.
pub const DEFAULT_ANCHOR_RADIUS_PX: f32 = 1.5;

/// Keypoints of each image LightGlue sees, by default: see [`CrossOptions::keypoint_budget`].
/// All of them. A budget of 384 (of ALIKED's 1024, those with the nearest descriptors across)
/// keeps as many right cross-visit pairs on three synthetic 3-visit surveys (strong seeds 0 and
/// 1, storm seed 5: 58, 30, 29 against 56, 28, 24), far fewer wrong ones (32, 12, 18 against
/// 52, 37, 39) in a third of the time, but places two visits of a storm survey less exactly
/// (fewer matches to place them by) and the change map between them finds fewer corals (26 of
/// 33 on seven 2 x 16 storm surveys, 512: 27, all: 29; README).
pub const DEFAULT_KEYPOINT_BUDGET: Option<usize> = None;

/// Options of learned pair matching.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CrossOptions {
    /// How the roll of the second image of a cross-visit pair is chosen.
    /// Default: the prediction ([`RollSearch::DEFAULT`]). Pairs within a visit
    /// are matched at roll 0.
    pub roll_search: RollSearch,
    /// A learned match is kept when its probability (exp of LightGlue's
    /// score) is above this. Default [`DEFAULT_MIN_MATCH_PROBABILITY`].
    pub min_match_probability: f32,
    /// An accepted pair whose matches at least this probable verify on their
    /// own is confident (their inliers are kept too). Default
    /// [`DEFAULT_CONFIDENT_PROBABILITY`].
    pub confident_probability: f32,
    /// When given, two visits with at least this many confident pairs are
    /// mapped with those alone, each on its confident inliers, and their weak
    /// (verified, not confident) pairs are set aside before mapping: those
    /// hold the matches LightGlue was unsure of, on surfaces that changed, a
    /// few pixels off. Default `None` (every verified pair mapped whole): where
    /// corals grew or moved, LightGlue is sure of them, and the rule keeps
    /// just the wrong pairs (README).
    pub confident_pairs: Option<usize>,
    /// The winning roll's inliers must be at least this many times the
    /// runner-up's, or the pair is rejected (and a probe falls back to the
    /// full search). 1 turns the check off. Default [`DEFAULT_ROLL_MARGIN`].
    pub roll_margin: f32,
    /// A learned keypoint within this distance of an own (SIFT) keypoint is
    /// matched as that keypoint. Default [`DEFAULT_ANCHOR_RADIUS_PX`].
    pub anchor_radius_px: f32,
    /// Verification; default asks for [`CROSS_MIN_INLIERS`] inliers.
    pub verify: VerifyOptions,
    /// Verified cross-visit pairs are checked against their roll and against
    /// each other before mapping ([`crate::consistency`]): a pair whose heading
    /// offset between its visits is further than this from the other pairs'
    /// is inconsistent. Default [`DEFAULT_CONSISTENCY_TOLERANCE_DEG`].
    pub consistency_tolerance_deg: f64,
    /// Inconsistent pairs are set aside (not mapped) rather than only
    /// reported. Default false: COLMAP's own robust steps absorb most of them,
    /// and on some surveys one is the only thing that brings an image into
    /// the model (issue 11's note).
    pub set_aside_inconsistent: bool,
    /// A verified cross-visit pair whose matches put the other camera farther
    /// from its navigated position than this many standard deviations of the
    /// two positions is inconsistent ([`crate::consistency`], rule 3); 0 turns
    /// the check off. Default [`DEFAULT_NAVIGATION_TOLERANCE_SIGMAS`].
    pub navigation_tolerance_sigmas: f64,
    /// A verified cross-visit pair whose loops through the other cross-visit
    /// pairs miss by more than this share of the image diagonal is
    /// inconsistent ([`crate::consistency`], rule 4); 0 turns the check off.
    /// Default [`DEFAULT_LOOP_TOLERANCE`].
    pub loop_tolerance: f64,
    /// LightGlue sees at most this many keypoints of each image, those likeliest to have a
    /// counterpart in the other ([`crate::lightglue::likeliest_to_match`]); `None`: all.
    /// Default [`DEFAULT_KEYPOINT_BUDGET`].
    pub keypoint_budget: Option<usize>,
}

impl Default for CrossOptions {
    fn default() -> Self {
        CrossOptions {
            roll_search: RollSearch::DEFAULT,
            min_match_probability: DEFAULT_MIN_MATCH_PROBABILITY,
            confident_probability: DEFAULT_CONFIDENT_PROBABILITY,
            confident_pairs: None,
            roll_margin: DEFAULT_ROLL_MARGIN,
            anchor_radius_px: DEFAULT_ANCHOR_RADIUS_PX,
            verify: VerifyOptions { min_inliers: CROSS_MIN_INLIERS, ..VerifyOptions::default() },
            consistency_tolerance_deg: DEFAULT_CONSISTENCY_TOLERANCE_DEG,
            set_aside_inconsistent: false,
            navigation_tolerance_sigmas: DEFAULT_NAVIGATION_TOLERANCE_SIGMAS,
            loop_tolerance: DEFAULT_LOOP_TOLERANCE,
            keypoint_budget: DEFAULT_KEYPOINT_BUDGET,
        }
    }
}

impl CrossOptions {
    pub fn check(&self) -> Result<(), OptionsError> {
        self.roll_search.check()?;
        check_range("min_match_probability", self.min_match_probability, 0.0, 1.0, "in [0, 1]")?;
        check_range("confident_probability", self.confident_probability, 0.0, 1.0, "in [0, 1]")?;
        if let Some(pairs) = self.confident_pairs {
            check_range("confident_pairs", pairs, 1, usize::MAX, "at least 1")?;
        }
        check_range("roll_margin", self.roll_margin, 1.0, f32::MAX, "at least 1")?;
        check_range("anchor_radius_px", self.anchor_radius_px, 0.0, 100.0, "in [0, 100]")?;
        check_range("consistency_tolerance_deg", self.consistency_tolerance_deg, 1.0, 180.0, "in [1, 180]")?;
        check_range("navigation_tolerance_sigmas", self.navigation_tolerance_sigmas, 0.0, 1e6, "0 (off) or positive")?;
        check_range("loop_tolerance", self.loop_tolerance, 0.0, 1.0, "in [0, 1]; 0 is off")?;
        if let Some(budget) = self.keypoint_budget {
            check_range("keypoint_budget", budget, 32, usize::MAX, "at least 32")?;
        }
        self.verify.check()
    }
}

/// A learned pair, matched and judged.
#[derive(Clone, Debug)]
pub struct LearnedPairMatch {
    /// The roll of the second image that won.
    pub roll: Roll,
    /// Inliers found at each roll tried (probe counts for a conclusive probe).
    pub inliers_by_roll: Vec<(Roll, usize)>,
    /// Whether a probe was inconclusive and the full search ran.
    pub fell_back: bool,
    /// The roll predicted first, when the pair was matched at a prediction.
    pub predicted: Option<Roll>,
    /// Each side's learned keypoints in its own unrolled frame, by learned
    /// index (the second side's at the winning roll).
    pub positions: [Vec<[f32; 2]>; 2],
    /// Every match, anchored, at most one per keypoint on each side.
    pub matches: Vec<[CrossKey; 2]>,
    /// The matches kept: empty if the pair was rejected.
    pub inliers: Vec<[CrossKey; 2]>,
    /// The verified geometry between the unrolled images (degenerate if rejected).
    pub geometry: TwoViewGeometry,
    /// A confident pair's confident inliers and their geometry (see the
    /// module's documentation); `None` for a weak or rejected pair.
    pub confident: Option<(Vec<[CrossKey; 2]>, TwoViewGeometry)>,
}

impl LearnedPairMatch {
    pub fn accepted(&self) -> bool {
        !self.inliers.is_empty()
    }
}

/// Matches image `a` (learned features at roll 0, and every keypoint it
/// already holds) with image `b` (learned features at each roll the search
/// needs, and its keypoints): a cross-visit pair at the `predicted` roll
/// when there is one ([`match_at_prediction`]), else with
/// `options.roll_search` (from `place_roll`, place recognition's, when it
/// searches in order); a pair within a visit at roll 0 only. Then
/// [`accept`] judges the result.
pub fn match_learned_pair(
    matcher: &mut LightGlue,
    a: (&LearnedFeatures, &[Keypoint]),
    b: (&[(Roll, LearnedFeatures)], &[Keypoint]),
    kind: PairKind,
    (predicted, place_roll): (Option<&Prediction>, Option<Roll>),
    options: &CrossOptions,
) -> Result<LearnedPairMatch, OnnxError> {
    let search = |matcher: &mut LightGlue, search: RollSearch| {
        match_with_rolls(matcher, a.0, b.0, (search, place_roll), options)
    };
    let found = match (kind, predicted) {
        (PairKind::Cross, Some(prediction)) => match_at_prediction(matcher, a.0, b.0, prediction, options)?,
        (PairKind::Cross, None) => search(matcher, options.roll_search)?,
        (PairKind::Intra, _) => search(matcher, RollSearch::Off)?,
    };
    Ok(judge(&found, a, b, options))
}

/// [`accept`] on what the learned matcher found for a pair (matched here, or by a matcher node),
/// given the same features and keypoints as [`match_learned_pair`].
pub fn judge(
    found: &CrossMatch,
    a: (&LearnedFeatures, &[Keypoint]),
    b: (&[(Roll, LearnedFeatures)], &[Keypoint]),
    options: &CrossOptions,
) -> LearnedPairMatch {
    let (b_by_roll, own_b) = b;
    let positions_a = a.0.keypoints.clone();
    let positions_b: Vec<[f32; 2]> = b_by_roll
        .iter()
        .find(|(roll, _)| *roll == found.roll)
        .map(|(roll, features)| unrolled_keypoints(features, *roll).iter().map(|k| [k.x, k.y]).collect())
        .unwrap_or_default();
    accept(found, [positions_a, positions_b], [a.1, own_b], options)
}

/// The acceptance rule (see the module's documentation): anchors `found`'s
/// matches (learned indices into `positions`) to the images' `own`
/// keypoints, keeps one match per keypoint and side, and verifies them if
/// the roll is clear.
pub fn accept(
    found: &CrossMatch,
    positions: [Vec<[f32; 2]>; 2],
    own: [&[Keypoint]; 2],
    options: &CrossOptions,
) -> LearnedPairMatch {
    let anchors = [0, 1].map(|side| anchor_keypoints(own[side], &positions[side], options.anchor_radius_px));
    let key = |side: usize, learned: u32| match anchors[side].get(learned as usize) {
        Some(Some(own)) => CrossKey::Own(*own),
        _ => CrossKey::Learned(learned),
    };
    let (mut used_a, mut used_b) = (HashSet::new(), HashSet::new());
    let probability = |k: usize| found.probabilities.get(k).copied().unwrap_or(0.0);
    let (matches, probabilities): (Vec<[CrossKey; 2]>, Vec<f32>) = found
        .matches
        .iter()
        .enumerate()
        .filter(|(_, [i, j])| (*i as usize) < positions[0].len() && (*j as usize) < positions[1].len())
        .map(|(k, &[i, j])| ([key(0, i), key(1, j)], probability(k)))
        .filter(|([ka, kb], _)| used_a.insert(*ka) && used_b.insert(*kb))
        .unzip();
    let position = |side: usize, key: CrossKey| -> Keypoint {
        let at = |[x, y]: [f32; 2]| Keypoint { x, y, scale: 1.0, orientation: 0.0 };
        match key {
            CrossKey::Own(i) => own[side].get(i as usize).copied().unwrap_or_else(|| at([f32::NAN; 2])),
            CrossKey::Learned(l) => at(positions[side].get(l as usize).copied().unwrap_or([f32::NAN; 2])),
        }
    };
    let verified = |kept: &[usize]| {
        let points_a: Vec<Keypoint> = kept.iter().map(|&k| position(0, matches[k][0])).collect();
        let points_b: Vec<Keypoint> = kept.iter().map(|&k| position(1, matches[k][1])).collect();
        let identity: Vec<[u32; 2]> = (0..kept.len() as u32).map(|k| [k, k]).collect();
        let geometry = verify(&points_a, &points_b, &identity, &options.verify);
        let inliers: Vec<[CrossKey; 2]> =
            geometry.inlier_matches.iter().filter_map(|m| kept.get(m[0] as usize).map(|&k| matches[k])).collect();
        (inliers, geometry)
    };
    let (mut inliers, mut geometry, mut confident) = (Vec::new(), TwoViewGeometry::degenerate(), None);
    if found.roll_is_clear(options.roll_margin) {
        (inliers, geometry) = verified(&(0..matches.len()).collect::<Vec<_>>());
        let sure: Vec<usize> = (0..matches.len())
            .filter(|&k| probabilities.get(k).is_some_and(|p| *p >= options.confident_probability))
            .collect();
        if !inliers.is_empty() {
            confident = match sure.len() == matches.len() {
                true => Some((inliers.clone(), geometry.clone())),
                false => Some(verified(&sure)).filter(|(sure_inliers, _)| !sure_inliers.is_empty()),
            };
        }
    }
    LearnedPairMatch {
        roll: found.roll,
        inliers_by_roll: found.inliers_by_roll.clone(),
        fell_back: found.fell_back,
        predicted: found.predicted,
        positions,
        matches,
        inliers,
        geometry,
        confident,
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::{Point3, Rotation3, Vector3};

    use super::*;

    /// `n` points seen by two cameras 1 m apart (focal 500 px, 640x480),
    /// projected: pixel positions in each image.
    fn two_views(n: usize) -> (Vec<[f32; 2]>, Vec<[f32; 2]>) {
        let project = |p: Point3<f64>, r: &Rotation3<f64>, t: Vector3<f64>| {
            let c = r * p.coords + t;
            [(500.0 * c.x / c.z + 320.0) as f32, (500.0 * c.y / c.z + 240.0) as f32]
        };
        let r2 = Rotation3::from_euler_angles(0.02, -0.05, 0.1);
        let (mut a, mut b) = (Vec::new(), Vec::new());
        for k in 0..n {
            // A deterministic scatter over a bumpy surface 4-6 m away.
            let (u, v) = ((k * 37 % 101) as f64 / 101.0 - 0.5, (k * 61 % 97) as f64 / 97.0 - 0.5);
            let p = Point3::new(3.0 * u, 2.4 * v, 5.0 + (7.0 * u).sin() * (5.0 * v).cos());
            a.push(project(p, &Rotation3::identity(), Vector3::zeros()));
            b.push(project(p, &r2, Vector3::new(-1.0, 0.1, 0.05)));
        }
        (a, b)
    }

    fn found(n: usize, inliers_by_roll: Vec<(Roll, usize)>) -> CrossMatch {
        CrossMatch {
            roll: Roll::R0,
            matches: (0..n as u32).map(|k| [k, k]).collect(),
            probabilities: vec![0.9; n],
            geometry: TwoViewGeometry::degenerate(),
            inliers_by_roll,
            fell_back: false,
            predicted: None,
        }
    }

    fn keypoint([x, y]: [f32; 2]) -> Keypoint {
        Keypoint { x, y, scale: 1.0, orientation: 0.0 }
    }

    #[test]
    fn a_clear_roll_with_enough_inliers_is_accepted_and_anchored() {
        let (a, b) = two_views(80);
        // The first image already holds a keypoint 0.5 px from learned keypoint 3.
        let own_a = vec![keypoint([a[3][0] + 0.5, a[3][1]])];
        let pair = accept(&found(80, vec![(Roll::R0, 70), (Roll::R90, 9)]), [a, b], [&own_a, &[]], &Default::default());
        assert!(pair.accepted());
        assert!(pair.inliers.len() >= 70, "{} inliers", pair.inliers.len());
        assert!(pair.inliers.contains(&[CrossKey::Own(0), CrossKey::Learned(3)]));
        assert!(!pair.inliers.iter().any(|m| m[0] == CrossKey::Learned(3)));
    }

    #[test]
    fn a_pair_whose_probable_matches_verify_alone_is_confident() {
        let (a, mut b) = two_views(90);
        // The last 30 matches, of low probability, a few pixels off (as on a surface that changed).
        for point in &mut b[60..] {
            point[0] += 2.5;
        }
        let mut unsure = found(90, vec![(Roll::R0, 90)]);
        unsure.probabilities = (0..90).map(|k| if k < 60 { 0.9 } else { 0.2 }).collect();
        let pair = accept(&unsure, [a.clone(), b.clone()], [&[], &[]], &Default::default());
        let (sure, _) = pair.confident.as_ref().expect("confident");
        assert!(sure.len() >= 55, "{} confident inliers", sure.len());
        assert!(sure.iter().all(|m| matches!(m[0], CrossKey::Learned(k) if k < 60)));
        assert!(pair.inliers.len() > sure.len(), "the pair keeps all its inliers too");
        // Too few probable matches to verify alone: the pair is weak.
        unsure.probabilities = (0..90).map(|k| if k < 20 { 0.9 } else { 0.2 }).collect();
        let pair = accept(&unsure, [a, b], [&[], &[]], &Default::default());
        assert!(pair.accepted() && pair.confident.is_none());
    }

    #[test]
    fn a_roll_that_does_not_stand_out_is_rejected() {
        let (a, b) = two_views(80);
        let pair = accept(&found(80, vec![(Roll::R0, 40), (Roll::R180, 35)]), [a, b], [&[], &[]], &Default::default());
        assert!(!pair.accepted());
        assert_eq!(pair.matches.len(), 80);
        assert!(pair.geometry.inlier_matches.is_empty());
    }

    #[test]
    fn too_few_inliers_are_rejected() {
        let (a, b) = two_views(CROSS_MIN_INLIERS - 5);
        let pair = accept(&found(a.len(), vec![(Roll::R0, 25)]), [a, b], [&[], &[]], &Default::default());
        assert!(!pair.accepted());
    }

    #[test]
    fn two_learned_keypoints_on_one_own_keypoint_make_one_match() {
        let (mut a, b) = two_views(60);
        a[1] = [a[0][0] + 0.3, a[0][1]];
        let own_a = vec![keypoint(a[0])];
        let pair = accept(&found(60, vec![(Roll::R0, 50)]), [a, b], [&own_a, &[]], &Default::default());
        let uses_own_0 = pair.matches.iter().filter(|m| m[0] == CrossKey::Own(0)).count();
        assert_eq!(uses_own_0, 1);
        assert_eq!(pair.matches.len(), 59);
    }

    #[test]
    fn options_are_checked() {
        assert!(CrossOptions::default().check().is_ok());
        assert!(CrossOptions { roll_margin: 0.5, ..Default::default() }.check().is_err());
        assert!(CrossOptions { roll_search: RollSearch::Probe { budget: 4 }, ..Default::default() }.check().is_err());
        assert!(CrossOptions { roll_search: RollSearch::Predict, ..Default::default() }.check().is_ok());
        assert!(CrossOptions { confident_probability: 1.5, ..Default::default() }.check().is_err());
        assert!(CrossOptions { confident_pairs: Some(0), ..Default::default() }.check().is_err());
    }
}
