use serde::{Deserialize, Serialize};

use crate::{check_range, OptionsError};

/// How the images of one session (ordered by time) are paired for matching.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PairOptions {
    /// Sessions of at most this many images are matched exhaustively.
    /// Default 100.
    pub exhaustive_max_images: usize,
    /// Longer sessions: each image is matched with the next `window` images.
    /// Default 10.
    pub window: usize,
    /// Longer sessions: every `loop_period`-th image is also matched with every
    /// other `loop_period`-th image, to close loops and link revisited ground.
    /// Default 5.
    pub loop_period: usize,
}

impl Default for PairOptions {
    fn default() -> Self {
        Self { exhaustive_max_images: 100, window: 10, loop_period: 5 }
    }
}

impl PairOptions {
    pub fn check(&self) -> Result<(), OptionsError> {
        check_range("window", self.window, 1, usize::MAX, "at least 1")?;
        check_range("loop_period", self.loop_period, 1, usize::MAX, "at least 1")
    }
}

/// Every unordered pair `(i, j)`, `i < j`, of `n` images, sorted.
pub fn exhaustive_pairs(n: usize) -> Vec<(usize, usize)> {
    (0..n).flat_map(|i| (i + 1..n).map(move |j| (i, j))).collect()
}

/// The pairs to match within one session of `n` time-ordered images:
/// exhaustive for short sessions, a sequential window plus periodic loop
/// candidates for long, video-derived ones. Sorted, without duplicates.
pub fn intra_session_pairs(n: usize, options: &PairOptions) -> Vec<(usize, usize)> {
    if n <= options.exhaustive_max_images {
        return exhaustive_pairs(n);
    }
    let window = options.window.max(1);
    let period = options.loop_period.max(1);
    let mut pairs: Vec<(usize, usize)> = (0..n)
        .flat_map(|i| (i + 1..(i + 1 + window).min(n)).map(move |j| (i, j)))
        .chain((0..n).step_by(period).flat_map(|i| (i + period..n).step_by(period).map(move |j| (i, j))))
        .collect();
    pairs.sort_unstable();
    pairs.dedup();
    pairs
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn short_sessions_are_exhaustive() {
        assert_eq!(intra_session_pairs(4, &PairOptions::default()), exhaustive_pairs(4));
        assert_eq!(exhaustive_pairs(4).len(), 6);
    }

    #[test]
    fn long_sessions_use_window_and_loops() {
        let options = PairOptions { exhaustive_max_images: 10, window: 2, loop_period: 5 };
        let pairs = intra_session_pairs(20, &options);
        assert!(pairs.contains(&(3, 5)) && !pairs.contains(&(3, 6)));
        assert!(pairs.contains(&(0, 15)) && pairs.contains(&(5, 15)));
        let mut sorted = pairs.clone();
        sorted.sort_unstable();
        sorted.dedup();
        assert_eq!(sorted, pairs);
    }
}
