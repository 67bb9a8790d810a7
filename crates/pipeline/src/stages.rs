//! The SIFT stages over the store: features per image, pairs within (and,
//! for `--cross sift`, across) visits, descriptor matching and verification.
//! [`sift_features`] is the one-image entry point they are built on.

use std::collections::HashMap;

use image::DynamicImage;
use revisit_core::{pair_id, Features, ImageId, Keypoint, LearnedFeatures, PairKind};
use revisit_matching::{
    intra_session_pairs, match_descriptors, match_unit_descriptors, verify, MatchOptions, PairOptions, VerifyOptions,
};
use revisit_store::{PairRecord, Store};
use serde::{Deserialize, Serialize};

use crate::options::FeatureOptions;
use crate::{workers, Cancel, PipelineError, Progress, Session};

/// What a stage did: new work, and finished work found in the store.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct StageCounts {
    pub done: usize,
    pub reused: usize,
}

/// Runs `work` over `items` on every core and hands each result to `write` on
/// the calling thread, in item order (so the store is written
/// deterministically): [`workers::in_order`] with workers that hold nothing.
fn parallel_in_order<T, R>(
    items: &[T],
    work: impl Fn(&T) -> Result<R, PipelineError> + Sync,
    mut write: impl FnMut(R) -> Result<(), PipelineError>,
    progress: &dyn Progress,
    cancel: &Cancel,
) -> Result<(), PipelineError>
where
    T: Sync,
    R: Send,
{
    let mut cores = vec![(); workers::cores()];
    let write = |(): &mut (), _, result| {
        write(result)?;
        progress.advance();
        Ok(())
    };
    workers::in_order(&mut (), &mut cores, items.len(), |(), _| Ok(()), |(), i, ()| work(&items[i]), write, cancel)
}

/// SIFT features of one decoded image, as every stage and node extracts them:
/// downscaled to `options.max_image_size_px`, keypoints in full-resolution pixels.
pub fn sift_features(options: &FeatureOptions, image: &DynamicImage) -> Result<Features, String> {
    let (grey, factor) = crate::images::grey_at_most(image, options.max_image_size_px);
    let mut features = revisit_features::extract_sift(&options.sift, &grey).map_err(|e| e.to_string())?;
    if factor != 1.0 {
        for kp in &mut features.keypoints {
            kp.x *= factor;
            kp.y *= factor;
            kp.scale *= factor;
        }
    }
    Ok(features)
}

/// SIFT features of every image of `sessions` whose features are not in the store yet.
pub fn extract_features(
    store: &mut Store,
    sessions: &[Session],
    options: &FeatureOptions,
    progress: &dyn Progress,
    cancel: &Cancel,
) -> Result<StageCounts, PipelineError> {
    let finished = store.images_with_features()?;
    let all: Vec<_> = sessions.iter().flat_map(|s| &s.images).collect();
    let todo: Vec<_> = all.iter().filter(|image| !finished.contains(&image.id)).collect();
    let counts = StageCounts { done: todo.len(), reused: all.len() - todo.len() };
    tracing::info!(new = counts.done, reused = counts.reused, "features");
    progress.start("features", todo.len() as u64);
    parallel_in_order(
        &todo,
        |image| {
            let decoded = crate::images::read(&image.path)?;
            let features = sift_features(options, &decoded)
                .map_err(|reason| PipelineError::Features { path: image.path.clone(), reason })?;
            Ok((image.id, features))
        },
        |(id, features)| store.write_features(id, &features).map_err(PipelineError::from),
        progress,
        cancel,
    )?;
    progress.finish();
    Ok(counts)
}

/// An image pair to match, and whether it crosses visits.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub struct PlannedPair {
    pub image_id1: ImageId,
    pub image_id2: ImageId,
    pub kind: PairKind,
}

/// Plans the SIFT pairs: pairs within each visit by `pair_options`, and
/// (`across`) every pair across visits. Sorted by (image 1, image 2).
pub fn plan_pairs(sessions: &[Session], across: bool, pair_options: &PairOptions) -> Vec<PlannedPair> {
    let ids: Vec<Vec<ImageId>> = sessions.iter().map(|s| s.images.iter().map(|i| i.id).collect()).collect();
    let mut pairs = Vec::new();
    for session in &ids {
        for (i, j) in intra_session_pairs(session.len(), pair_options) {
            if let (Some(&a), Some(&b)) = (session.get(i), session.get(j)) {
                pairs.push(PlannedPair { image_id1: a, image_id2: b, kind: PairKind::Intra });
            }
        }
    }
    if across {
        for (s, first) in ids.iter().enumerate() {
            for second in &ids[s + 1..] {
                for &a in first {
                    for &b in second {
                        pairs.push(PlannedPair { image_id1: a, image_id2: b, kind: PairKind::Cross });
                    }
                }
            }
        }
    }
    pairs.sort_unstable();
    pairs.dedup();
    pairs
}

/// Reads the features of `image_ids` from the store.
pub fn load_features(
    store: &Store,
    image_ids: impl IntoIterator<Item = ImageId>,
) -> Result<HashMap<ImageId, Features>, PipelineError> {
    image_ids.into_iter().map(|id| Ok((id, store.read_features(id)?))).collect()
}

/// Learned keypoints that images hold in their keypoint lists (after their
/// SIFT keypoints), matched within visits alongside SIFT so that the tracks
/// of cross-visit matches continue inside each visit.
#[derive(Clone, Debug, Default)]
pub struct LearnedKeypoints {
    /// The learned method's name.
    pub method: String,
    /// Per image: its learned features at roll 0 and the keypoint index of each.
    pub images: HashMap<ImageId, (LearnedFeatures, Vec<u32>)>,
}

impl LearnedKeypoints {
    /// SIFT keypoints then the learned ones, at their keypoint indices.
    fn all_keypoints(&self, image_id: ImageId, own: &[Keypoint]) -> Vec<Keypoint> {
        let mut all = own.to_vec();
        if let Some((features, indices)) = self.images.get(&image_id) {
            let len = indices.iter().map(|&i| i as usize + 1).max().unwrap_or(0).max(all.len());
            all.resize(len, Keypoint { x: 0.0, y: 0.0, scale: 1.0, orientation: 0.0 });
            for (&[x, y], &index) in features.keypoints.iter().zip(indices) {
                all[index as usize] = Keypoint { x, y, scale: 1.0, orientation: 0.0 };
            }
        }
        all
    }

    /// Nearest-neighbour matches of the learned descriptors of two images, by keypoint index.
    fn matches(&self, a: ImageId, b: ImageId, options: &MatchOptions) -> Vec<[u32; 2]> {
        let (Some((fa, ia)), Some((fb, ib))) = (self.images.get(&a), self.images.get(&b)) else {
            return Vec::new();
        };
        match_unit_descriptors(&fa.descriptors, &fb.descriptors, fa.descriptor_dim, options)
            .into_iter()
            .filter_map(|[i, j]| Some([*ia.get(i as usize)?, *ib.get(j as usize)?]))
            .collect()
    }
}

/// Matches and verifies every planned pair not yet in the store (with
/// `learned`, SIFT and learned matches together, verified as one set).
#[allow(clippy::too_many_arguments)] // the stage's inputs, each needed
pub fn match_pairs(
    store: &mut Store,
    pairs: &[PlannedPair],
    features: &HashMap<ImageId, Features>,
    learned: Option<&LearnedKeypoints>,
    match_options: &MatchOptions,
    verify_options: &VerifyOptions,
    progress: &dyn Progress,
    cancel: &Cancel,
) -> Result<StageCounts, PipelineError> {
    let method = match learned {
        Some(l) => format!("sift+{}", l.method),
        None => "sift".to_owned(),
    };
    let stored = store.pair_methods()?;
    let todo: Vec<PlannedPair> =
        pairs.iter().filter(|p| stored.get(&pair_id(p.image_id1, p.image_id2)) != Some(&method)).copied().collect();
    let counts = StageCounts { done: todo.len(), reused: pairs.len() - todo.len() };
    tracing::info!(new = counts.done, reused = counts.reused, "matching");
    progress.start("matching", todo.len() as u64);
    let empty = Features::default();
    parallel_in_order(
        &todo,
        |pair| {
            let a = features.get(&pair.image_id1).unwrap_or(&empty);
            let b = features.get(&pair.image_id2).unwrap_or(&empty);
            let mut matches = match_descriptors(a, b, match_options);
            let geometry = match learned {
                Some(learned) => {
                    matches.extend(learned.matches(pair.image_id1, pair.image_id2, match_options));
                    let all_a = learned.all_keypoints(pair.image_id1, &a.keypoints);
                    let all_b = learned.all_keypoints(pair.image_id2, &b.keypoints);
                    verify(&all_a, &all_b, &matches, verify_options)
                }
                None => verify(&a.keypoints, &b.keypoints, &matches, verify_options),
            };
            let record = PairRecord {
                image_id1: pair.image_id1,
                image_id2: pair.image_id2,
                kind: pair.kind,
                method: method.clone(),
                roll_deg: 0,
                predicted_roll_deg: None,
                num_matches: matches.len(),
                num_inliers: geometry.inlier_matches.len(),
            };
            Ok((record, matches, geometry))
        },
        |(record, matches, geometry)| store.write_pair(&record, &matches, &geometry).map_err(PipelineError::from),
        progress,
        cancel,
    )?;
    progress.finish();
    Ok(counts)
}
