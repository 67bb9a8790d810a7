//! LightGlue and LighterGlue on ONNX Runtime against the PyTorch references
//! in ../shared/models/reference, and roll search on a real pair.

#![allow(clippy::unwrap_used, clippy::expect_used)] // test helpers panic on broken fixtures

use ndarray::ArrayD;
use ndarray_npy::NpzReader;
use revisit_core::{LearnedFeatures, Roll};
use revisit_matching::lightglue::{mutual_matches, LearnedMatch, LIGHTGLUE_MATCH_THRESHOLD};
use revisit_matching::{CrossOptions, LightGlue, RollSearch, VerifyOptions};
use revisit_onnx::Runtime;
use revisit_testkit::shared;

fn runtime() -> Runtime {
    revisit_testkit::runtime(0)
}

struct Reference {
    a: LearnedFeatures,
    b: LearnedFeatures,
    scores: ArrayD<f32>,
}

/// Reads a reference whose keys are `names` = [kpts0, kpts1, desc0, desc1, size0, size1].
fn reference(file: &str, names: [&str; 6]) -> Reference {
    let mut npz = NpzReader::new(std::fs::File::open(shared("models/reference").join(file)).unwrap()).unwrap();
    let mut get = |key: &str| -> ArrayD<f32> { npz.by_name(key).unwrap() };
    let mut features = |kpts: &str, desc: &str, size: &str| {
        let kpts = get(kpts);
        let desc = get(desc);
        let size = get(size);
        LearnedFeatures {
            keypoints: kpts
                .iter()
                .copied()
                .collect::<Vec<_>>()
                .chunks_exact(2)
                .map(|p| [p[0] + 0.5, p[1] + 0.5])
                .collect(),
            descriptor_dim: desc.shape()[2],
            descriptors: desc.iter().copied().collect(),
            scores: vec![1.0; kpts.shape()[1]],
            width: size[[0, 0]] as u32,
            height: size[[0, 1]] as u32,
        }
    };
    let a = features(names[0], names[2], names[4]);
    let b = features(names[1], names[3], names[5]);
    Reference { a, b, scores: get("scores") }
}

/// Largest difference between finite scores; non-finite ones must agree in position.
fn score_difference(ours: &[f32], theirs: &ArrayD<f32>) -> f32 {
    assert_eq!(ours.len(), theirs.len());
    let mut worst = 0.0f32;
    for (a, b) in ours.iter().zip(theirs.iter()) {
        if a.is_finite() && b.is_finite() {
            worst = worst.max((a - b).abs() / b.abs().max(1.0));
        } else {
            assert!(!a.is_finite() || !b.is_finite() || a.is_finite() == b.is_finite(), "{a} vs {b}");
        }
    }
    worst
}

#[test]
fn lightglue_aliked_reproduces_the_reference_scores() {
    let r = reference("lightglue_aliked_ref.npz", ["kpts0", "kpts1", "desc0", "desc1", "size0", "size1"]);
    let mut matcher = LightGlue::open(&runtime(), &shared("models/lightglue_aliked.onnx"), 128).unwrap();
    let diff = score_difference(&matcher.scores(&r.a, &r.b).unwrap(), &r.scores);
    assert!(diff < 1e-3, "relative score difference {diff}");
}

#[test]
fn lighterglue_xfeat_reproduces_the_reference_scores() {
    let r = reference("lighterglue_ref.npz", ["k0", "k1", "d0", "d1", "s0", "s1"]);
    let mut matcher = LightGlue::open(&runtime(), &shared("models/lighterglue_xfeat.onnx"), 64).unwrap();
    let diff = score_difference(&matcher.scores(&r.a, &r.b).unwrap(), &r.scores);
    assert!(diff < 1e-3, "relative score difference {diff}");
}

#[test]
fn the_real_pair_gives_the_reference_matches() {
    let r = reference("lightglue_aliked_realpair_ref.npz", ["kpts0", "kpts1", "desc0", "desc1", "size0", "size1"]);
    let reference: Vec<f32> = r.scores.iter().copied().collect();
    let expected = mutual_matches(&reference, r.a.len(), r.b.len(), LIGHTGLUE_MATCH_THRESHOLD);
    assert_eq!(expected.len(), 263, "PROVENANCE.md's count");
    let mut matcher = LightGlue::open(&runtime(), &shared("models/lightglue_aliked.onnx"), 128).unwrap();
    let indices = |found: &[LearnedMatch]| found.iter().map(|m| m.indices).collect::<Vec<_>>();
    let found = matcher.match_features(&r.a, &r.b, LIGHTGLUE_MATCH_THRESHOLD).unwrap();
    assert_eq!(indices(&found), indices(&expected));
    for (got, want) in found.iter().zip(&expected) {
        assert!((got.probability - want.probability).abs() < 1e-3, "{got:?} against the reference's {want:?}");
    }
    // A higher least probability keeps the reference's more probable matches only.
    let probable = matcher.match_features(&r.a, &r.b, 0.5).unwrap();
    assert_eq!(indices(&probable), indices(&mutual_matches(&reference, r.a.len(), r.b.len(), 0.5)));
    assert!(!probable.is_empty() && probable.len() < expected.len(), "{} of {}", probable.len(), expected.len());
    assert!(probable.iter().all(|m| m.probability > 0.5 && m.probability <= 1.0));
}

#[test]
fn within_a_budget_the_real_pair_keeps_most_reference_matches_at_their_full_indices() {
    let r = reference("lightglue_aliked_realpair_ref.npz", ["kpts0", "kpts1", "desc0", "desc1", "size0", "size1"]);
    let reference: Vec<f32> = r.scores.iter().copied().collect();
    let expected: Vec<[u32; 2]> =
        mutual_matches(&reference, r.a.len(), r.b.len(), LIGHTGLUE_MATCH_THRESHOLD).iter().map(|m| m.indices).collect();
    let mut matcher = LightGlue::open(&runtime(), &shared("models/lightglue_aliked.onnx"), 128).unwrap();
    let found = matcher.match_within(&r.a, &r.b, LIGHTGLUE_MATCH_THRESHOLD, Some(384)).unwrap();
    let agreeing = found.iter().filter(|m| expected.contains(&m.indices)).count();
    // Most of the pair's matches have a near descriptor across: LightGlue, on three eighths of
    // the keypoints, finds most of them again, and at the indices of the full sets.
    assert!(agreeing * 10 >= found.len() * 9, "{agreeing} of {} budgeted matches are the reference's", found.len());
    assert!(agreeing * 10 >= expected.len() * 7, "{agreeing} of the reference's {}", expected.len());
    let everything = matcher.match_within(&r.a, &r.b, LIGHTGLUE_MATCH_THRESHOLD, Some(1024)).unwrap();
    assert_eq!(everything.iter().map(|m| m.indices).collect::<Vec<_>>(), expected, "a budget of all is no budget");
}

#[test]
fn a_matcher_for_other_descriptors_is_refused() {
    let Err(error) = LightGlue::open(&runtime(), &shared("models/lightglue_aliked.onnx"), 64) else {
        panic!("LightGlue for ALIKED accepted as a 64-float matcher")
    };
    assert!(error.to_string().contains("desc0"), "{error}");
}

#[test]
fn roll_search_finds_the_roll_of_a_rotated_real_pair() {
    let runtime = runtime();
    let mut aliked =
        revisit_features::learned::Aliked::open(&runtime, &shared("models/aliked_n16_600x800.onnx")).unwrap();
    let mut matcher = LightGlue::open(&runtime, &shared("models/lightglue_aliked.onnx"), 128).unwrap();
    let a_image = image::open(shared("data/xfeat_pair/ref.png")).unwrap().to_rgb8();
    // The second image as a camera at another heading would see it: turned 90 degrees counter-clockwise.
    let b_image = image::imageops::rotate270(&image::open(shared("data/xfeat_pair/tgt.png")).unwrap().to_rgb8());
    let a = aliked.extract(&a_image, Roll::R0).unwrap();
    let b_by_roll: Vec<(Roll, LearnedFeatures)> =
        Roll::ALL.iter().map(|&roll| (roll, aliked.extract(&b_image, roll).unwrap())).collect();
    let options = CrossOptions { verify: VerifyOptions::default(), ..CrossOptions::default() };
    let search = |matcher: &mut LightGlue, search: RollSearch, place_roll: Option<Roll>| {
        revisit_matching::match_with_rolls(matcher, &a, &b_by_roll, (search, place_roll), &options).unwrap()
    };
    let off = search(&mut matcher, RollSearch::Off, None);
    assert_eq!(matcher.runs(), 1, "one roll, one run");
    let full = search(&mut matcher, RollSearch::Full, None);
    assert_eq!(matcher.runs(), 1 + 4, "the full search runs once per roll");
    let probe = search(&mut matcher, RollSearch::PROBE, None);
    // Searched from place recognition's roll: stopped there when it is right, at the right roll
    // (the second tried) when place recognition's is wrong.
    for (place_roll, runs) in [(Roll::R90, 1), (Roll::R0, 2)] {
        let before = matcher.runs();
        let ranked = search(&mut matcher, RollSearch::Predict, Some(place_roll));
        assert_eq!((ranked.roll, matcher.runs() - before), (Roll::R90, runs), "{:?}", ranked.inliers_by_roll);
    }
    assert_eq!(full.roll, Roll::R90, "{:?}", full.inliers_by_roll);
    assert_eq!(probe.roll, Roll::R90, "{:?}", probe.inliers_by_roll);
    let inliers = full.geometry.inlier_matches.len();
    assert!(inliers >= 100, "{inliers} inliers at the right roll");
    assert!(off.geometry.inlier_matches.len() * 3 < inliers, "{:?} without the roll", off.inliers_by_roll);
}
