//! revisit-eval: the published cross-visit evaluation protocol, pose errors
//! against ground truth, and histogram plots.
//!
//! - [`parse_points_csv`] reads the published click files
//!   (`img0,img1,uv_clicked,uv_groundtruth`); [`write_points_csv`] writes them.
//! - [`score`] takes the 3D point seen at each clicked pixel of `img0`,
//!   projects it into `img1` with the estimated pose and measures the distance
//!   to the true location: per session pair and overall.
//! - [`parse_truth_poses_csv`] and [`score_truth`] measure registration rates
//!   and camera errors after a similarity alignment ([`umeyama`], from `revisit-core`).
//! - [`median_epipolar_error_px`] tells a right pair from a wrong one by the
//!   true poses.
//! - [`histogram`] draws the error histogram of a session pair.
//!
//! Invariant: pure functions over models and texts; no file I/O (the CLI reads
//! models and writes reports and images).

mod clicks;
pub mod draw;
mod pairs;
mod plot;
mod score;
mod truth;

pub use clicks::{parse_points_csv, write_points_csv, ClickPair, MalformedRow, PointsCsv};
pub use pairs::{median_epipolar_error_px, MAX_RIGHT_PAIR_ERROR_PX};
pub use plot::{histogram, log_log, HistogramOptions, Series};
pub use revisit_core::{umeyama, AlignError, Similarity};
pub use score::{score, ClickResult, ScoreOptions, Scores, SkipReason, Summary};
pub use truth::{
    parse_truth_poses_csv, score_truth, Alignment, PoseErrors, SessionTruth, TruthOptions, TruthPose, TruthScores,
};

/// Errors of the evaluation inputs; each names the file (`source`) and, where
/// it applies, the row.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    #[error("{source_name}: {reason}")]
    BadFile { source_name: String, reason: String },
    #[error("{source_name}: row {row}: {reason}")]
    BadRow { source_name: String, row: usize, reason: String },
    #[error("invalid option {option}: {reason}")]
    BadOption { option: &'static str, reason: String },
}

pub use revisit_core::session_of;

/// Median and mean of a list (the median of an even count averages the two
/// middle values); `None` when empty.
pub(crate) fn median_mean(values: &[f64]) -> (Option<f64>, Option<f64>) {
    if values.is_empty() {
        return (None, None);
    }
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    let mid = sorted.len() / 2;
    let median = if sorted.len() % 2 == 1 {
        sorted.get(mid).copied()
    } else {
        match (sorted.get(mid - 1), sorted.get(mid)) {
            (Some(a), Some(b)) => Some(0.5 * (a + b)),
            _ => None,
        }
    };
    (median, Some(values.iter().sum::<f64>() / values.len() as f64))
}
