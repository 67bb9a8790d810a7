use nalgebra::DMatrix;
use revisit_core::Features;
use serde::{Deserialize, Serialize};

use crate::{check_range, OptionsError};

/// Nearest-neighbour descriptor matching, as COLMAP's SIFT matcher does it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MatchOptions {
    /// Lowe's ratio test on angular distances: best / second best below this.
    /// Default 0.8 (COLMAP's `max_ratio`).
    pub max_ratio: f32,
    /// Largest angle between matched descriptors, radians. Default 0.7
    /// (COLMAP's `max_distance`).
    pub max_distance: f32,
    /// Keep only mutual nearest neighbours. Default true.
    pub cross_check: bool,
}

impl Default for MatchOptions {
    fn default() -> Self {
        Self { max_ratio: 0.8, max_distance: 0.7, cross_check: true }
    }
}

impl MatchOptions {
    pub fn check(&self) -> Result<(), OptionsError> {
        check_range("max_ratio", self.max_ratio, 0.0, 1.0, "in [0, 1]")?;
        check_range("max_distance", self.max_distance, 0.0, std::f32::consts::PI, "in [0, pi]")
    }
}

/// Rows of L2-normalised descriptors as an (n x dim) matrix.
fn normalised(features: &Features) -> DMatrix<f32> {
    let dim = features.descriptor_dim.max(1);
    let n = features.descriptors.len() / dim;
    let mut m = DMatrix::<f32>::zeros(n, dim);
    for (i, row) in features.descriptors.chunks_exact(dim).enumerate() {
        let norm = row.iter().map(|&v| f32::from(v) * f32::from(v)).sum::<f32>().sqrt().max(1e-12);
        for (j, &v) in row.iter().enumerate() {
            m[(i, j)] = f32::from(v) / norm;
        }
    }
    m
}

/// Best and second-best (similarity, index) per row of a similarity matrix.
fn best_two_per_row(similarity: &DMatrix<f32>) -> Vec<(f32, f32, usize)> {
    (0..similarity.nrows())
        .map(|i| {
            let (mut best, mut second, mut best_j) = (-1.0f32, -1.0f32, usize::MAX);
            for (j, &s) in similarity.row(i).iter().enumerate() {
                if s > best {
                    second = best;
                    best = s;
                    best_j = j;
                } else if s > second {
                    second = s;
                }
            }
            (best, second, best_j)
        })
        .collect()
}

fn angle(similarity: f32) -> f32 {
    similarity.clamp(-1.0, 1.0).acos()
}

/// Matches descriptors of two images: nearest neighbour by angle, ratio test,
/// distance cap, optional mutual check. Returns `[index in a, index in b]`
/// pairs sorted by index in `a`.
pub fn match_descriptors(a: &Features, b: &Features, options: &MatchOptions) -> Vec<[u32; 2]> {
    if a.is_empty() || b.is_empty() || a.descriptor_dim != b.descriptor_dim {
        return Vec::new();
    }
    let (da, db) = (normalised(a), normalised(b));
    let similarity = &da * db.transpose();
    let forward = best_two_per_row(&similarity);
    let backward = if options.cross_check {
        best_two_per_row(&similarity.transpose())
    } else {
        Vec::new()
    };
    let mut matches = Vec::new();
    for (i, &(best, second, j)) in forward.iter().enumerate() {
        let (best_angle, second_angle) = (angle(best), angle(second));
        if best_angle > options.max_distance || best_angle >= options.max_ratio * second_angle {
            continue;
        }
        if options.cross_check && backward.get(j).map(|&(_, _, back)| back) != Some(i) {
            continue;
        }
        matches.push([i as u32, j as u32]);
    }
    matches
}

#[cfg(test)]
mod tests {
    use revisit_core::Keypoint;

    use super::*;

    fn features(rows: &[[u8; 4]]) -> Features {
        Features {
            keypoints: vec![Keypoint { x: 0.0, y: 0.0, scale: 1.0, orientation: 0.0 }; rows.len()],
            descriptors: rows.iter().flatten().copied().collect(),
            descriptor_dim: 4,
        }
    }

    #[test]
    fn distinct_descriptors_match_their_twins() {
        let a = features(&[[255, 0, 0, 0], [0, 255, 0, 0], [0, 0, 255, 0]]);
        let b = features(&[[0, 0, 250, 10], [250, 5, 0, 0], [0, 255, 3, 0]]);
        assert_eq!(match_descriptors(&a, &b, &MatchOptions::default()), vec![[0, 1], [1, 2], [2, 0]]);
    }

    #[test]
    fn ambiguous_descriptors_fail_the_ratio_test() {
        let a = features(&[[255, 255, 0, 0]]);
        let b = features(&[[255, 250, 0, 0], [250, 255, 0, 0]]);
        assert!(match_descriptors(&a, &b, &MatchOptions::default()).is_empty());
    }

    #[test]
    fn cross_check_drops_one_sided_matches() {
        let a = features(&[[255, 0, 0, 0], [250, 40, 0, 0]]);
        let b = features(&[[252, 20, 0, 0], [0, 0, 0, 255]]);
        let options = MatchOptions { max_ratio: 1.0, ..MatchOptions::default() };
        assert_eq!(match_descriptors(&a, &b, &options).len(), 1);
    }
}
