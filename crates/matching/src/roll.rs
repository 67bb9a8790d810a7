//! Roll search: the second image of a cross-visit pair is matched rolled by
//! 0, 90, 180 and 270 degrees, and the roll with the most geometrically
//! verified inliers wins. Matches come back against the unrolled images.
//!
//! [`RollSearch::Probe`] is the cheap way to the same answer: it decides the
//! roll by matching only the strongest keypoints of each image at every roll
//! (LightGlue's cost grows with the product of the two keypoint counts), then
//! matches the full sets once, at the chosen roll.

use revisit_core::{Keypoint, LearnedFeatures, Roll, TwoViewConfig, TwoViewGeometry};
use revisit_onnx::OnnxError;

use crate::lightglue::LightGlue;
use crate::verify::{verify, VerifyOptions};

/// How to choose the roll of the second image.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RollSearch {
    /// Match at roll 0 only.
    Off,
    /// Match the full keypoint sets at every roll (4 matches per pair).
    Full,
    /// Decide on the `budget` strongest keypoints of each image, then match once in full.
    Probe { budget: usize },
}

impl RollSearch {
    /// The default probe: 256 keypoints a side.
    pub const DEFAULT: RollSearch = RollSearch::Probe { budget: 256 };

    /// The rolls of the second image that this search needs features for.
    pub fn rolls(self) -> &'static [Roll] {
        match self {
            RollSearch::Off => &[Roll::R0],
            RollSearch::Full | RollSearch::Probe { .. } => &Roll::ALL,
        }
    }
}

/// The outcome of matching a pair across visits.
#[derive(Clone, Debug)]
pub struct CrossMatch {
    /// The roll of the second image that won.
    pub roll: Roll,
    /// Every mutual match at that roll, `[index in a, index in b at that roll]`.
    pub matches: Vec<[u32; 2]>,
    /// Verified geometry between the unrolled images (same indices).
    pub geometry: TwoViewGeometry,
    /// Inliers found at each roll tried (probe counts for a probe), for reports.
    pub inliers_by_roll: Vec<(Roll, usize)>,
}

/// Keypoints of `features`, extracted at `roll`, mapped back to the unrolled image.
pub fn unrolled_keypoints(features: &LearnedFeatures, roll: Roll) -> Vec<Keypoint> {
    let (width, height) = roll.rolled_size(features.width, features.height);
    features
        .keypoints
        .iter()
        .map(|&p| {
            let [x, y] = roll.unroll_point(p, width, height);
            Keypoint { x, y, scale: 1.0, orientation: 0.0 }
        })
        .collect()
}

/// Matches `a` (unrolled) against `b_by_roll` (features of the second image
/// at each roll [`RollSearch::rolls`] asks for) and keeps the best roll.
pub fn match_with_rolls(
    matcher: &mut LightGlue,
    a: &LearnedFeatures,
    b_by_roll: &[(Roll, LearnedFeatures)],
    search: RollSearch,
    verify_options: &VerifyOptions,
) -> Result<CrossMatch, OnnxError> {
    let a_keypoints = unrolled_keypoints(a, Roll::R0);
    let full = |matcher: &mut LightGlue, roll: Roll, b: &LearnedFeatures| -> Result<CrossMatch, OnnxError> {
        let matches = matcher.match_features(a, b)?;
        let geometry = verify(&a_keypoints, &unrolled_keypoints(b, roll), &matches, verify_options);
        let inliers = geometry.inlier_matches.len();
        Ok(CrossMatch { roll, matches, geometry, inliers_by_roll: vec![(roll, inliers)] })
    };
    let candidates: Vec<&(Roll, LearnedFeatures)> =
        b_by_roll.iter().filter(|(roll, _)| search.rolls().contains(roll)).collect();
    let Some(first) = candidates.first() else {
        let geometry = TwoViewGeometry {
            config: TwoViewConfig::Degenerate,
            inlier_matches: Vec::new(),
            f: None,
            e: None,
            h: None,
            cam2_from_cam1: None,
        };
        return Ok(CrossMatch { roll: Roll::R0, matches: Vec::new(), geometry, inliers_by_roll: Vec::new() });
    };
    match search {
        RollSearch::Off => full(matcher, first.0, &first.1),
        RollSearch::Full => {
            let mut best: Option<CrossMatch> = None;
            let mut tried = Vec::new();
            for (roll, b) in candidates {
                let result = full(matcher, *roll, b)?;
                let inliers = result.geometry.inlier_matches.len();
                tried.push((*roll, inliers));
                if best.as_ref().is_none_or(|b| inliers > b.geometry.inlier_matches.len()) {
                    best = Some(result);
                }
            }
            let mut best = best.unwrap_or_else(|| unreachable!("at least one roll was tried"));
            best.inliers_by_roll = tried;
            Ok(best)
        }
        RollSearch::Probe { budget } => {
            let a_probe = a.strongest(budget);
            let a_probe_keypoints = unrolled_keypoints(&a_probe, Roll::R0);
            let mut tried = Vec::new();
            let mut best: Option<(Roll, usize, usize, &LearnedFeatures)> = None;
            for (roll, b) in candidates {
                let b_probe = b.strongest(budget);
                let matches = matcher.match_features(&a_probe, &b_probe)?;
                let geometry =
                    verify(&a_probe_keypoints, &unrolled_keypoints(&b_probe, *roll), &matches, verify_options);
                let inliers = geometry.inlier_matches.len();
                tried.push((*roll, inliers));
                // Most verified inliers; among none, most raw matches.
                if best.is_none_or(|(_, i, m, _)| (inliers, matches.len()) > (i, m)) {
                    best = Some((*roll, inliers, matches.len(), b));
                }
            }
            let (roll, _, _, b) = best.unwrap_or_else(|| unreachable!("at least one roll was tried"));
            let mut result = full(matcher, roll, b)?;
            result.inliers_by_roll = tried;
            Ok(result)
        }
    }
}
