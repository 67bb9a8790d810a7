//! LightGlue-family matchers on ONNX Runtime (LightGlue for ALIKED,
//! LighterGlue for XFeat). The model returns a log-assignment matrix with a
//! dustbin row and column; a pair (i, j) matches when j is the best of row i,
//! i the best of column j (dustbins excluded) and exp(score), the match's
//! probability, exceeds the caller's minimum. Non-finite scores never match.

use std::path::Path;

use ndarray::{ArrayView, IxDyn};
use revisit_core::LearnedFeatures;
use revisit_onnx::{Contract, InputSpec, Model, OnnxError, OutputSpec, Runtime};

const LIGHTGLUE_ALIKED: Contract = contract(&[
    InputSpec { name: "kpts0", shape: &[Some(1), None, Some(2)] },
    InputSpec { name: "kpts1", shape: &[Some(1), None, Some(2)] },
    InputSpec { name: "desc0", shape: &[Some(1), None, Some(128)] },
    InputSpec { name: "desc1", shape: &[Some(1), None, Some(128)] },
    InputSpec { name: "size0", shape: &[Some(1), Some(2)] },
    InputSpec { name: "size1", shape: &[Some(1), Some(2)] },
]);

const LIGHTERGLUE_XFEAT: Contract = contract(&[
    InputSpec { name: "kpts0", shape: &[Some(1), None, Some(2)] },
    InputSpec { name: "kpts1", shape: &[Some(1), None, Some(2)] },
    InputSpec { name: "desc0", shape: &[Some(1), None, Some(64)] },
    InputSpec { name: "desc1", shape: &[Some(1), None, Some(64)] },
    InputSpec { name: "size0", shape: &[Some(1), Some(2)] },
    InputSpec { name: "size1", shape: &[Some(1), Some(2)] },
]);

const fn contract(inputs: &'static [InputSpec]) -> Contract {
    Contract { inputs, outputs: &[OutputSpec { name: "scores", shape: &[Some(1), None, None] }] }
}

/// LightGlue's own minimum match probability (its `filter_threshold`), as its
/// reference matches are counted; Revisit's learned pairs use
/// `CrossOptions::min_match_probability` (by default the same).
pub const LIGHTGLUE_MATCH_THRESHOLD: f32 = 0.1;

/// An opened LightGlue-family model for descriptors of `descriptor_dim`.
pub struct LightGlue {
    model: Model,
    descriptor_dim: usize,
    runs: usize,
}

impl LightGlue {
    /// Opens a matcher for descriptors of `descriptor_dim` floats (128 for
    /// ALIKED's LightGlue, 64 for XFeat's LighterGlue).
    pub fn open(runtime: &Runtime, path: &Path, descriptor_dim: usize) -> Result<LightGlue, OnnxError> {
        let contract = match descriptor_dim {
            64 => &LIGHTERGLUE_XFEAT,
            128 => &LIGHTGLUE_ALIKED,
            other => {
                return Err(OnnxError::BadModel {
                    path: path.to_path_buf(),
                    message: format!("no LightGlue contract for {other}-float descriptors"),
                })
            }
        };
        Ok(LightGlue { model: Model::open(runtime, path, contract)?, descriptor_dim, runs: 0 })
    }

    /// How many times the network has run since the matcher was opened (a pair matched at
    /// several rolls runs it once per roll): the unit of learned matching's cost.
    pub fn runs(&self) -> usize {
        self.runs
    }

    /// The raw log-assignment matrix, (len(a) + 1) x (len(b) + 1), row-major.
    pub fn scores(&mut self, a: &LearnedFeatures, b: &LearnedFeatures) -> Result<Vec<f32>, OnnxError> {
        let path = self.model.path().to_path_buf();
        let bad = |message: String| OnnxError::Run { path: path.clone(), message };
        for features in [a, b] {
            if features.descriptor_dim != self.descriptor_dim {
                return Err(bad(format!(
                    "descriptors of {} floats given to a matcher for {}",
                    features.descriptor_dim, self.descriptor_dim
                )));
            }
        }
        // The models take pixel positions with (0, 0) at the centre of the top-left pixel.
        let centred =
            |f: &LearnedFeatures| -> Vec<f32> { f.keypoints.iter().flat_map(|p| [p[0] - 0.5, p[1] - 0.5]).collect() };
        let (kpts0, kpts1) = (centred(a), centred(b));
        let size0 = [a.width as f32, a.height as f32];
        let size1 = [b.width as f32, b.height as f32];
        let dim = self.descriptor_dim;
        fn view<'d>(shape: &[usize], data: &'d [f32]) -> Result<ndarray::ArrayViewD<'d, f32>, ndarray::ShapeError> {
            ArrayView::from_shape(IxDyn(shape), data)
        }
        let inputs = [
            ("kpts0", view(&[1, a.len(), 2], &kpts0)),
            ("kpts1", view(&[1, b.len(), 2], &kpts1)),
            ("desc0", view(&[1, a.len(), dim], &a.descriptors)),
            ("desc1", view(&[1, b.len(), dim], &b.descriptors)),
            ("size0", view(&[1, 2], &size0)),
            ("size1", view(&[1, 2], &size1)),
        ];
        let mut checked = Vec::with_capacity(inputs.len());
        for (name, view) in inputs {
            checked.push((name, view.map_err(|e| bad(format!("input {name}: {e}")))?));
        }
        self.runs += 1;
        let scores = self.model.run(&checked, &["scores"])?.remove("scores").unwrap_or_default();
        self.model.check_output("scores", scores.shape(), &[Some(1), Some(a.len() + 1), Some(b.len() + 1)])?;
        Ok(scores.into_iter().collect())
    }

    /// Mutual best matches more probable than `min_probability`.
    pub fn match_features(
        &mut self,
        a: &LearnedFeatures,
        b: &LearnedFeatures,
        min_probability: f32,
    ) -> Result<Vec<LearnedMatch>, OnnxError> {
        if a.is_empty() || b.is_empty() {
            return Ok(Vec::new());
        }
        let scores = self.scores(a, b)?;
        Ok(mutual_matches(&scores, a.len(), b.len(), min_probability))
    }

    /// [`LightGlue::match_features`] on at most `budget` keypoints of each side, those
    /// [`likeliest_to_match`] the other side; the matches index the full sets. `None`: every
    /// keypoint.
    pub fn match_within(
        &mut self,
        a: &LearnedFeatures,
        b: &LearnedFeatures,
        min_probability: f32,
        budget: Option<usize>,
    ) -> Result<Vec<LearnedMatch>, OnnxError> {
        let Some(budget) = budget.filter(|&n| n < a.len().max(b.len())) else {
            return self.match_features(a, b, min_probability);
        };
        let [kept_a, kept_b] = likeliest_to_match(a, b, budget);
        let mut found = self.match_features(&a.subset(&kept_a), &b.subset(&kept_b), min_probability)?;
        for m in &mut found {
            m.indices = [kept_a[m.indices[0] as usize], kept_b[m.indices[1] as usize]];
        }
        Ok(found)
    }
}

/// Each side's `budget` keypoints (ascending indices) whose descriptors come nearest one of the
/// other side's: those with a counterpart to be found. LightGlue's cost grows with the square
/// of the keypoints; a keypoint of a part of the scene the other image does not show (in
/// pairs across visits, most of each image) has no near descriptor there and costs as much
/// as one that matches.
pub fn likeliest_to_match(a: &LearnedFeatures, b: &LearnedFeatures, budget: usize) -> [Vec<u32>; 2] {
    fn matrix(f: &LearnedFeatures) -> Result<ndarray::ArrayView2<'_, f32>, ndarray::ShapeError> {
        ndarray::ArrayView2::from_shape((f.len(), f.descriptor_dim), &f.descriptors)
    }
    let (Ok(da), Ok(db)) = (matrix(a), matrix(b)) else {
        return [a, b].map(|f| (0..f.len().min(budget) as u32).collect());
    };
    let similarity = da.dot(&db.t());
    let best = |values: ndarray::ArrayView1<f32>| values.fold(f32::NEG_INFINITY, |m, &v| m.max(v));
    let best_a: Vec<f32> = similarity.rows().into_iter().map(best).collect();
    let best_b: Vec<f32> = similarity.columns().into_iter().map(best).collect();
    [best_a, best_b].map(|best| {
        let mut order: Vec<u32> = (0..best.len() as u32).collect();
        order.sort_by(|&i, &j| best[j as usize].total_cmp(&best[i as usize]).then(i.cmp(&j)));
        order.truncate(budget);
        order.sort_unstable();
        order
    })
}

/// A learned match: `[index in a, index in b]`, and how probable the matcher
/// finds it (exp of its score).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LearnedMatch {
    pub indices: [u32; 2],
    pub probability: f32,
}

/// Mutual row/column maxima of the `rows` x `cols` block of a
/// (rows + 1) x (cols + 1) log-assignment matrix with exp(score) > `threshold`.
/// None if `scores` is not of that size.
pub fn mutual_matches(scores: &[f32], rows: usize, cols: usize, threshold: f32) -> Vec<LearnedMatch> {
    if scores.len() != (rows + 1) * (cols + 1) {
        return Vec::new();
    }
    let stride = cols + 1;
    let finite = |v: f32| if v.is_finite() { v } else { f32::NEG_INFINITY };
    let best_in_row: Vec<Option<usize>> = (0..rows)
        .map(|i| {
            let row = &scores[i * stride..i * stride + cols];
            argmax(row.iter().map(|&v| finite(v)))
        })
        .collect();
    let best_in_column: Vec<Option<usize>> =
        (0..cols).map(|j| argmax((0..rows).map(|i| finite(scores[i * stride + j])))).collect();
    let log_threshold = threshold.ln();
    best_in_row
        .iter()
        .enumerate()
        .filter_map(|(i, best)| {
            let j = (*best)?;
            let score = finite(scores[i * stride + j]);
            (best_in_column[j] == Some(i) && score > log_threshold)
                .then(|| LearnedMatch { indices: [i as u32, j as u32], probability: score.exp() })
        })
        .collect()
}

/// Index of the first largest finite value.
fn argmax(values: impl Iterator<Item = f32>) -> Option<usize> {
    let mut best: Option<(usize, f32)> = None;
    for (i, v) in values.enumerate() {
        if v.is_finite() && best.is_none_or(|(_, b)| v > b) {
            best = Some((i, v));
        }
    }
    best.map(|(i, _)| i)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mutual_matches_skip_dustbins_and_non_finite_scores() {
        // 2 x 2 block plus dustbins; row 1 is poisoned with -inf except one NaN.
        let ln = |p: f32| p.ln();
        let scores = vec![
            ln(0.9),
            ln(0.05),
            ln(0.99), //
            f32::NEG_INFINITY,
            f32::NAN,
            ln(0.5), //
            ln(0.1),
            ln(0.1),
            0.0,
        ];
        let found = mutual_matches(&scores, 2, 2, 0.1);
        assert_eq!(found.iter().map(|m| m.indices).collect::<Vec<_>>(), vec![[0, 0]]);
        assert!((found[0].probability - 0.9).abs() < 1e-6, "{found:?}");
        assert!(mutual_matches(&scores, 2, 2, 0.95).is_empty());
    }

    #[test]
    fn mutual_matches_of_a_matrix_of_the_wrong_size_are_none() {
        assert!(mutual_matches(&[0.0; 4], 2, 2, 0.1).is_empty());
    }

    #[test]
    fn the_keypoints_kept_are_those_with_a_counterpart() {
        // Unit descriptors along the axes of a 4-float space: a's keypoints 1 and 3 have a copy
        // in b (b's 0 and 2), the others point elsewhere.
        let axis = |k: usize| (0..4).map(|d| if d == k { 1.0 } else { 0.0 }).collect::<Vec<f32>>();
        let features = |axes: &[usize]| LearnedFeatures {
            keypoints: vec![[0.0, 0.0]; axes.len()],
            descriptors: axes.iter().flat_map(|&k| axis(k)).collect(),
            descriptor_dim: 4,
            scores: vec![1.0; axes.len()],
            width: 8,
            height: 8,
        };
        let (a, b) = (features(&[0, 1, 0, 2]), features(&[1, 3, 2, 3]));
        assert_eq!(likeliest_to_match(&a, &b, 2), [vec![1, 3], vec![0, 2]]);
        assert_eq!(likeliest_to_match(&a, &b, 9), [vec![0, 1, 2, 3], vec![0, 1, 2, 3]]);
    }
}
