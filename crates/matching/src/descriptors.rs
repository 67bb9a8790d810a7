use ndarray::linalg::general_mat_mul;
use ndarray::{ArrayView2, ArrayViewMut2};
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

/// L2-normalised descriptors, row-major, `dim` values per row.
fn normalised(features: &Features) -> Vec<f32> {
    let dim = features.descriptor_dim.max(1);
    let mut out = Vec::with_capacity(features.descriptors.len());
    for row in features.descriptors.chunks_exact(dim) {
        let norm = row.iter().map(|&v| f32::from(v) * f32::from(v)).sum::<f32>().sqrt().max(1e-12);
        out.extend(row.iter().map(|&v| f32::from(v) / norm));
    }
    out
}

/// Best and second-best similarity, and the index of the best.
#[derive(Clone, Copy)]
struct BestTwo {
    best: f32,
    second: f32,
    index: usize,
}

impl BestTwo {
    const NONE: Self = Self { best: -1.0, second: -1.0, index: usize::MAX };

    fn push(&mut self, similarity: f32, index: usize) {
        if similarity > self.best {
            self.second = self.best;
            self.best = similarity;
            self.index = index;
        } else if similarity > self.second {
            self.second = similarity;
        }
    }
}

fn angle(similarity: f32) -> f32 {
    similarity.clamp(-1.0, 1.0).acos()
}

/// Rows of `a` per block of the similarity matrix (bounds memory at 8192 columns to 32 MiB).
const BLOCK_ROWS: usize = 1024;

/// Matches descriptors of two images: nearest neighbour by angle, ratio test,
/// distance cap, optional mutual check. Returns `[index in a, index in b]`
/// pairs sorted by index in `a`.
pub fn match_descriptors(a: &Features, b: &Features, options: &MatchOptions) -> Vec<[u32; 2]> {
    let dim = a.descriptor_dim;
    if a.is_empty() || b.is_empty() || dim == 0 || dim != b.descriptor_dim {
        return Vec::new();
    }
    match_normalised(&normalised(a), &normalised(b), dim, options)
}

/// [`match_descriptors`] for float descriptors that are L2-normalised
/// already (learned ones), `dim` values per row.
pub fn match_unit_descriptors(a: &[f32], b: &[f32], dim: usize, options: &MatchOptions) -> Vec<[u32; 2]> {
    if a.is_empty() || b.is_empty() || dim == 0 || !a.len().is_multiple_of(dim) || !b.len().is_multiple_of(dim) {
        return Vec::new();
    }
    match_normalised(a, b, dim, options)
}

fn match_normalised(da: &[f32], db: &[f32], dim: usize, options: &MatchOptions) -> Vec<[u32; 2]> {
    let (na, nb) = (da.len() / dim, db.len() / dim);
    let mut forward = vec![BestTwo::NONE; na];
    let mut backward = vec![BestTwo::NONE; nb];
    let mut similarity = vec![0.0f32; BLOCK_ROWS.min(na) * nb];
    for block_start in (0..na).step_by(BLOCK_ROWS) {
        let rows = BLOCK_ROWS.min(na - block_start);
        let block = &da[block_start * dim..(block_start + rows) * dim];
        // similarity (rows x nb, row-major) = block (rows x dim) * db^T (dim x nb).
        if similarities(block, db, &mut similarity[..rows * nb], dim).is_err() {
            // The slices were cut to rows x dim, nb x dim and rows x nb above.
            return Vec::new();
        }
        for (r, row) in similarity[..rows * nb].chunks_exact(nb).enumerate() {
            let i = block_start + r;
            let mut best = BestTwo::NONE;
            for (j, (&s, back)) in row.iter().zip(backward.iter_mut()).enumerate() {
                best.push(s, j);
                back.push(s, i);
            }
            if let Some(slot) = forward.get_mut(i) {
                *slot = best;
            }
        }
    }
    let mut matches = Vec::new();
    for (i, f) in forward.iter().enumerate() {
        let (best_angle, second_angle) = (angle(f.best), angle(f.second));
        if best_angle > options.max_distance || best_angle >= options.max_ratio * second_angle {
            continue;
        }
        if options.cross_check && backward.get(f.index).map(|b| b.index) != Some(i) {
            continue;
        }
        matches.push([i as u32, f.index as u32]);
    }
    matches
}

/// `similarity = a * b^T` for `a` (m x `dim`) and `b` (n x `dim`), giving
/// `similarity` (m x n), all row-major.
fn similarities(a: &[f32], b: &[f32], similarity: &mut [f32], dim: usize) -> Result<(), ndarray::ShapeError> {
    let a = ArrayView2::from_shape((a.len() / dim, dim), a)?;
    let b = ArrayView2::from_shape((b.len() / dim, dim), b)?;
    let mut similarity = ArrayViewMut2::from_shape((a.nrows(), b.nrows()), similarity)?;
    general_mat_mul(1.0, &a, &b.t(), 0.0, &mut similarity);
    Ok(())
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
    fn similarities_are_the_dot_products_of_rows() {
        let dim = 3;
        let a = [1.0, 2.0, 3.0, -1.0, 0.5, 0.0];
        let b = [0.0, 1.0, 0.0, 2.0, 0.0, 1.0, 1.0, 1.0, 1.0, -3.0, 0.0, 4.0];
        let mut similarity = vec![0.0; 2 * 4];
        similarities(&a, &b, &mut similarity, dim).unwrap();
        assert_eq!(similarity, vec![2.0, 5.0, 6.0, 9.0, 0.5, -2.0, -0.5, 3.0]);
    }

    #[test]
    fn twins_are_found_across_similarity_blocks() {
        // More rows than one block holds; b is a permuted copy of a.
        let n = BLOCK_ROWS + 300;
        let mut state = 7u64;
        let mut next = || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (state >> 56) as u8
        };
        let rows: Vec<[u8; 32]> = (0..n).map(|_| std::array::from_fn(|_| next())).collect();
        let twin_of = |i: usize| (i * 7 + 3) % n; // a permutation: gcd(7, n) = 1
        let mut permuted = vec![[0u8; 32]; n];
        for (i, row) in rows.iter().enumerate() {
            permuted[twin_of(i)] = *row;
        }
        let features = |rows: &[[u8; 32]]| Features {
            keypoints: vec![Keypoint { x: 0.0, y: 0.0, scale: 1.0, orientation: 0.0 }; rows.len()],
            descriptors: rows.iter().flatten().copied().collect(),
            descriptor_dim: 32,
        };
        let matches = match_descriptors(&features(&rows), &features(&permuted), &MatchOptions::default());
        let expected: Vec<[u32; 2]> = (0..n).map(|i| [i as u32, twin_of(i) as u32]).collect();
        assert_eq!(matches, expected);
    }

    #[test]
    fn cross_check_drops_one_sided_matches() {
        let a = features(&[[255, 0, 0, 0], [250, 40, 0, 0]]);
        let b = features(&[[252, 20, 0, 0], [0, 0, 0, 255]]);
        let options = MatchOptions { max_ratio: 1.0, ..MatchOptions::default() };
        assert_eq!(match_descriptors(&a, &b, &options).len(), 1);
    }
}
