//! Roll search: the second image of a cross-visit pair is matched rolled by
//! 0, 90, 180 and 270 degrees, and the roll with the most geometrically
//! verified inliers wins. Matches come back against the unrolled images.
//!
//! [`RollSearch::Probe`] is the cheap way to the same answer: it matches only
//! the strongest keypoints of each image at every roll (LightGlue's cost grows
//! with the product of the two keypoint counts). If one roll wins the probe
//! clearly, the full sets are matched once, at that roll; if none does (a hard
//! pair, or one that shows no common place), it falls back to the full search.
//!
//! Cheapest of all, once other pairs of the same two visits are verified: the
//! turn they agree on predicts the pair's roll ([`Prediction`], from
//! [`crate::consistency::Predictor`]), and [`match_at_prediction`] matches
//! once at that roll (twice when the turn falls between two rolls). Until
//! then, [`RollSearch::Predict`] searches in full from the roll place
//! recognition ranks first, and stops at a roll that wins clearly.

use revisit_core::{Keypoint, LearnedFeatures, Roll, TwoViewGeometry};
use revisit_onnx::OnnxError;

use serde::{Deserialize, Serialize};

use crate::consistency::UNLINKED_MIN_INLIERS;
use crate::cross::CrossOptions;
use crate::lightglue::{LearnedMatch, LightGlue};
use crate::verify::{verify, VerifyOptions};
use crate::{check_range, OptionsError};

/// How to choose the roll of the second image.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum RollSearch {
    /// Match at roll 0 only.
    Off,
    /// Match the full keypoint sets at every roll (4 matches per pair).
    Full,
    /// Decide on the `budget` strongest keypoints of each image, then match
    /// once in full; if no roll wins the probe by the roll margin (see
    /// [`CrossMatch::roll_is_clear`]), search in full.
    Probe { budget: usize },
    /// Match at the roll the visits' other verified pairs predict
    /// ([`match_at_prediction`]); a pair without a prediction is searched in
    /// full from place recognition's roll, and the search stops at a roll
    /// that wins clearly ([`wins_clearly`]).
    Predict,
}

/// How much the winning roll's inliers must exceed the runner-up's, by default.
pub const DEFAULT_ROLL_MARGIN: f32 = 1.5;

/// Keypoints a side of the default probe.
pub const DEFAULT_PROBE_BUDGET: usize = 256;

impl Default for RollSearch {
    fn default() -> Self {
        RollSearch::DEFAULT
    }
}

impl RollSearch {
    /// The default: the prediction. About 3x faster than the probe and it
    /// keeps pairs at a roll other than their visits' out (most of them
    /// wrong); an image that only such a pair linked may stay out of the
    /// model (see the README).
    pub const DEFAULT: RollSearch = RollSearch::PREDICT;

    /// The probe with [`DEFAULT_PROBE_BUDGET`] keypoints a side.
    pub const PROBE: RollSearch = RollSearch::Probe { budget: DEFAULT_PROBE_BUDGET };

    /// Predicted; searched from place recognition's roll until there is a prediction.
    pub const PREDICT: RollSearch = RollSearch::Predict;

    /// Fewer than 8 probe keypoints cannot verify anything.
    pub fn check(self) -> Result<(), OptionsError> {
        match self {
            RollSearch::Probe { budget } => check_range("roll probe budget", budget, 8, usize::MAX, "at least 8"),
            RollSearch::Off | RollSearch::Full | RollSearch::Predict => Ok(()),
        }
    }

    /// The rolls of the second image that this search needs features for.
    pub fn rolls(self) -> &'static [Roll] {
        match self {
            RollSearch::Off => &[Roll::R0],
            RollSearch::Full | RollSearch::Probe { .. } | RollSearch::Predict => &Roll::ALL,
        }
    }
}

/// Beyond this many degrees from the roll that undoes it, a predicted turn is
/// also tried at the next roll (ALIKED and XFeat, not rotation-invariant,
/// still match well within about 20 degrees of upright).
pub const SECOND_ROLL_FROM_DEG: f64 = 20.0;

/// A pair's roll as the other pairs predict it: the turn its matches should
/// show ([`crate::consistency::turn`], from image 1 to image 2), and how far
/// the matches' turn may be from it for the pair to be accepted.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Prediction {
    pub turn_deg: f64,
    pub tolerance_deg: f64,
}

impl Prediction {
    /// The rolls to try, nearest first: the roll that undoes the turn (a pair
    /// matched at roll `r` turns by about `-r`), and the next nearest when the
    /// turn is more than [`SECOND_ROLL_FROM_DEG`] from it.
    pub fn rolls(&self) -> Vec<Roll> {
        let undo = (-self.turn_deg).rem_euclid(360.0);
        let roll_at = |quarter: f64| Roll::ALL[(quarter.rem_euclid(4.0)) as usize];
        let nearest = (undo / 90.0).round();
        let residual = undo - 90.0 * nearest; // in [-45, 45]
        let mut rolls = vec![roll_at(nearest)];
        if residual.abs() > SECOND_ROLL_FROM_DEG {
            rolls.push(roll_at(nearest + residual.signum()));
        }
        rolls
    }

    /// Whether matched points turn as predicted.
    fn agrees(&self, points1: &[[f64; 2]], points2: &[[f64; 2]]) -> bool {
        crate::consistency::turn(points1, points2)
            .is_some_and(|t| crate::consistency::angle_between(t.deg, self.turn_deg) <= self.tolerance_deg)
    }
}

/// The outcome of matching a pair across visits.
#[derive(Clone, Debug)]
pub struct CrossMatch {
    /// The roll of the second image that won.
    pub roll: Roll,
    /// Every mutual match at that roll, `[index in a, index in b at that roll]`.
    pub matches: Vec<[u32; 2]>,
    /// Each match's probability, side by side with `matches` (empty when not known).
    pub probabilities: Vec<f32>,
    /// Verified geometry between the unrolled images (same indices).
    pub geometry: TwoViewGeometry,
    /// Inliers found at each roll tried (probe counts for a conclusive probe).
    pub inliers_by_roll: Vec<(Roll, usize)>,
    /// Whether a probe was inconclusive and the full search ran.
    pub fell_back: bool,
    /// The roll predicted first, when the pair was matched at a prediction.
    pub predicted: Option<Roll>,
}

impl CrossMatch {
    /// Whether the winning roll stands out: its inliers are at least `margin`
    /// times those of the runner-up (always, when one roll was tried). On a
    /// pair that shows no common place every roll finds a few chance inliers,
    /// about as many at each; on a true pair one roll wins clearly.
    pub fn roll_is_clear(&self, margin: f32) -> bool {
        match best_and_runner_up(&self.inliers_by_roll) {
            Some((best, Some(runner_up))) => best as f32 >= margin * runner_up as f32 && best > 0,
            _ => true,
        }
    }
}

/// The most inliers of the rolls `tried`, and the runner-up's (`None` with one roll tried).
fn best_and_runner_up(tried: &[(Roll, usize)]) -> Option<(usize, Option<usize>)> {
    let mut counts: Vec<usize> = tried.iter().map(|(_, n)| *n).collect();
    counts.sort_unstable_by(|a, b| b.cmp(a));
    counts.first().map(|best| (*best, counts.get(1).copied()))
}

/// Whether the best of the rolls `tried` wins without trying the others: its
/// inliers are at least `margin` times the runner-up's and `margin` times
/// [`UNLINKED_MIN_INLIERS`], more than a wrong roll or a pair of two places was
/// seen to verify (30 to 44 on the surveys measured; right pairs hold 30 up,
/// most over 60). A weaker winner needs every roll tried.
pub fn wins_clearly(tried: &[(Roll, usize)], margin: f32) -> bool {
    best_and_runner_up(tried).is_some_and(|(best, runner_up)| {
        best as f32 >= margin * runner_up.unwrap_or(0).max(UNLINKED_MIN_INLIERS) as f32
    })
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
/// at each roll [`RollSearch::rolls`] asks for) and keeps the best roll. A
/// probe falls back to the full search when no roll wins it by `roll_margin`;
/// [`RollSearch::Predict`] (a pair without a prediction) searches from
/// `place_roll` (place recognition's: the query roll whose descriptor was
/// nearest), then the others, and stops at a roll that [`wins_clearly`]
/// (by `options.roll_margin`). Matches are `options`' most probable
/// ([`CrossOptions::min_match_probability`]) and verified by `options.verify`.
pub fn match_with_rolls(
    matcher: &mut LightGlue,
    a: &LearnedFeatures,
    b_by_roll: &[(Roll, LearnedFeatures)],
    (search, place_roll): (RollSearch, Option<Roll>),
    options: &CrossOptions,
) -> Result<CrossMatch, OnnxError> {
    let (roll_margin, verify_options) = (options.roll_margin, &options.verify);
    let a_keypoints = unrolled_keypoints(a, Roll::R0);
    let full = |matcher: &mut LightGlue, roll: Roll, b: &LearnedFeatures| -> Result<CrossMatch, OnnxError> {
        let (matches, probabilities) =
            split(matcher.match_within(a, b, options.min_match_probability, options.keypoint_budget)?);
        let geometry = verify(&a_keypoints, &unrolled_keypoints(b, roll), &matches, verify_options);
        let inliers = geometry.inlier_matches.len();
        Ok(CrossMatch {
            roll,
            matches,
            probabilities,
            geometry,
            inliers_by_roll: vec![(roll, inliers)],
            fell_back: false,
            predicted: None,
        })
    };
    let mut candidates: Vec<&(Roll, LearnedFeatures)> =
        b_by_roll.iter().filter(|(roll, _)| search.rolls().contains(roll)).collect();
    if search == RollSearch::Predict {
        // Place recognition's roll first (a stable sort keeps the others in order).
        candidates.sort_by_key(|(roll, _)| Some(*roll) != place_roll);
    }
    let Some(first) = candidates.first() else {
        let geometry = TwoViewGeometry::degenerate();
        return Ok(CrossMatch {
            roll: Roll::R0,
            matches: Vec::new(),
            probabilities: Vec::new(),
            geometry,
            inliers_by_roll: Vec::new(),
            fell_back: false,
            predicted: None,
        });
    };
    // Every roll in turn; `stop_when_clear`: until one wins clearly.
    let full_search = |matcher: &mut LightGlue, stop_when_clear: bool| -> Result<CrossMatch, OnnxError> {
        let mut best: Option<CrossMatch> = None;
        let mut tried = Vec::new();
        for (roll, b) in &candidates {
            let result = full(matcher, *roll, b)?;
            let inliers = result.geometry.inlier_matches.len();
            tried.push((*roll, inliers));
            if best.as_ref().is_none_or(|b| inliers > b.geometry.inlier_matches.len()) {
                best = Some(result);
            }
            if stop_when_clear && wins_clearly(&tried, roll_margin) {
                break;
            }
        }
        let mut best = best.unwrap_or_else(|| unreachable!("at least one roll was tried"));
        best.inliers_by_roll = tried;
        Ok(best)
    };
    match search {
        RollSearch::Off => full(matcher, first.0, &first.1),
        RollSearch::Full => full_search(matcher, false),
        RollSearch::Predict => full_search(matcher, true),
        RollSearch::Probe { budget } => {
            let a_probe = a.strongest(budget);
            let a_probe_keypoints = unrolled_keypoints(&a_probe, Roll::R0);
            // A probe has a fraction of the keypoints: count its inliers down
            // to the 8-point minimum, and let the margin decide.
            let probe_verify = VerifyOptions { min_inliers: 8, min_inlier_ratio: 0.0, ..verify_options.clone() };
            let mut probe = CrossMatch {
                roll: first.0,
                matches: Vec::new(),
                probabilities: Vec::new(),
                geometry: TwoViewGeometry::degenerate(),
                inliers_by_roll: Vec::new(),
                fell_back: false,
                predicted: None,
            };
            let mut best: Option<(usize, usize, &LearnedFeatures)> = None;
            for (roll, b) in &candidates {
                let b_probe = b.strongest(budget);
                let (matches, _) = split(matcher.match_features(&a_probe, &b_probe, options.min_match_probability)?);
                let geometry =
                    verify(&a_probe_keypoints, &unrolled_keypoints(&b_probe, *roll), &matches, &probe_verify);
                let inliers = geometry.inlier_matches.len();
                probe.inliers_by_roll.push((*roll, inliers));
                // Most verified inliers; among none, most raw matches.
                if best.is_none_or(|(i, m, _)| (inliers, matches.len()) > (i, m)) {
                    best = Some((inliers, matches.len(), b));
                    probe.roll = *roll;
                }
            }
            if !probe.roll_is_clear(roll_margin) {
                let mut result = full_search(matcher, false)?;
                result.fell_back = true;
                return Ok(result);
            }
            let (_, _, b) = best.unwrap_or_else(|| unreachable!("at least one roll was tried"));
            let mut result = full(matcher, probe.roll, b)?;
            result.inliers_by_roll = probe.inliers_by_roll;
            Ok(result)
        }
    }
}

/// Matches `a` against `b_by_roll` at the rolls `prediction` gives, nearest
/// first, and keeps the first roll whose matches verify and turn as
/// predicted. When none does, the result has no matches (the pair is
/// rejected): a pair of the two visits that does not turn as their other
/// pairs agree is not searched at other rolls.
pub fn match_at_prediction(
    matcher: &mut LightGlue,
    a: &LearnedFeatures,
    b_by_roll: &[(Roll, LearnedFeatures)],
    prediction: &Prediction,
    options: &CrossOptions,
) -> Result<CrossMatch, OnnxError> {
    let rolls = prediction.rolls();
    let a_keypoints = unrolled_keypoints(a, Roll::R0);
    let mut tried = Vec::new();
    for &roll in &rolls {
        let Some((_, b)) = b_by_roll.iter().find(|(r, _)| *r == roll) else { continue };
        let b_keypoints = unrolled_keypoints(b, roll);
        let (matches, probabilities) =
            split(matcher.match_within(a, b, options.min_match_probability, options.keypoint_budget)?);
        let geometry = verify(&a_keypoints, &b_keypoints, &matches, &options.verify);
        tried.push((roll, geometry.inlier_matches.len()));
        let at = |keypoints: &[Keypoint], side: usize| -> Vec<[f64; 2]> {
            let point = |k: &Keypoint| [f64::from(k.x), f64::from(k.y)];
            geometry.inlier_matches.iter().filter_map(|m| keypoints.get(m[side] as usize).map(point)).collect()
        };
        if !geometry.inlier_matches.is_empty() && prediction.agrees(&at(&a_keypoints, 0), &at(&b_keypoints, 1)) {
            return Ok(CrossMatch {
                roll,
                matches,
                probabilities,
                geometry,
                inliers_by_roll: tried,
                fell_back: false,
                predicted: Some(rolls[0]),
            });
        }
    }
    Ok(CrossMatch {
        roll: rolls[0],
        matches: Vec::new(),
        probabilities: Vec::new(),
        geometry: TwoViewGeometry::degenerate(),
        inliers_by_roll: tried,
        fell_back: false,
        predicted: Some(rolls[0]),
    })
}

/// Learned matches as verification takes them, and their probabilities, side by side.
fn split(found: Vec<LearnedMatch>) -> (Vec<[u32; 2]>, Vec<f32>) {
    found.into_iter().map(|m| (m.indices, m.probability)).unzip()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rolls(turn_deg: f64) -> Vec<u32> {
        Prediction { turn_deg, tolerance_deg: 30.0 }.rolls().iter().map(|r| r.degrees()).collect()
    }

    #[test]
    fn a_roll_wins_clearly_over_chance_inliers_and_the_runner_up() {
        let tried = |counts: &[usize]| counts.iter().map(|n| (Roll::R0, *n)).collect::<Vec<_>>();
        assert!(wins_clearly(&tried(&[68]), 1.5));
        assert!(!wins_clearly(&tried(&[60]), 1.5), "a wrong roll may verify 44");
        assert!(!wins_clearly(&tried(&[100, 70]), 1.5));
        assert!(wins_clearly(&tried(&[10, 120]), 1.5));
        assert!(!wins_clearly(&[], 1.5));
    }

    #[test]
    fn a_predicted_turn_is_undone_by_its_nearest_roll_then_the_next() {
        assert_eq!(rolls(0.0), [0]);
        assert_eq!(rolls(355.0), [0]);
        assert_eq!(rolls(-90.0), [90]);
        assert_eq!(rolls(88.0), [270]);
        assert_eq!(rolls(180.0), [180]);
        // Undoing a turn of 30 degrees takes 330: 30 from roll 0, 60 from roll 270.
        assert_eq!(rolls(30.0), [0, 270]);
        assert_eq!(rolls(-30.0), [0, 90]);
        assert_eq!(rolls(225.0 - 1.0), [180, 90]);
    }
}
