//! Which image pairs to match, how to match their descriptors, and how to
//! verify the matches geometrically.
//!
//! Invariant: pure given features. No files, no store, no topics: callers hand
//! in features and get matches and two-view geometries back.

mod anchor;
pub mod consistency;
pub mod cross;
mod descriptors;
pub mod lightglue;
mod pairs;
pub mod roll;
mod verify;

pub use anchor::anchor_keypoints;
pub use consistency::{
    check_cross_pairs, similarity, turn, CheckedPair, Motion, Navigated, Navigation, Predictor, Similarity, Turn,
    Verdict, DEFAULT_CONSISTENCY_TOLERANCE_DEG, DEFAULT_LOOP_TOLERANCE, DEFAULT_NAVIGATION_TOLERANCE_SIGMAS,
};
pub use cross::{match_learned_pair, CrossOptions, LearnedPairMatch, CROSS_MIN_INLIERS};
pub use descriptors::{match_descriptors, match_unit_descriptors, MatchOptions};
pub use lightglue::LightGlue;
pub use pairs::{exhaustive_pairs, intra_session_pairs, PairOptions};
pub use roll::{match_at_prediction, match_with_rolls, CrossMatch, Prediction, RollSearch};
pub use verify::{verify, VerifyOptions};

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum OptionsError {
    #[error("option {name} = {value} is out of range: {expected}")]
    OutOfRange { name: &'static str, value: String, expected: &'static str },
}

fn check_range<T: PartialOrd + std::fmt::Display>(
    name: &'static str,
    value: T,
    low: T,
    high: T,
    expected: &'static str,
) -> Result<(), OptionsError> {
    // Written so that NaN is out of every range.
    if !(value >= low && value <= high) {
        return Err(OptionsError::OutOfRange { name, value: value.to_string(), expected });
    }
    Ok(())
}
