use std::collections::{BTreeMap, HashMap};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;

use rayon::prelude::*;
use revisit_core::{pair_id, Features, ImageId, Keypoint, LearnedFeatures};
use revisit_features::SiftOptions;
use revisit_matching::{
    intra_session_pairs, match_descriptors, match_unit_descriptors, verify, MatchOptions, PairOptions, VerifyOptions,
};
use revisit_store::{PairRecord, Store};
use serde::Serialize;

use crate::ingest::SessionImages;
use crate::{PipelineError, Progress};

/// What a stage did: new work, and finished work found in the store.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct StageCounts {
    pub done: usize,
    pub reused: usize,
}

/// Runs `work` over `items` in parallel and hands each result to `write` on
/// the calling thread, in item order (so the store is written
/// deterministically). Stops at the first error; results already written stay.
fn parallel_in_order<T, R, E>(
    items: &[T],
    work: impl Fn(&T) -> Result<R, E> + Sync,
    mut write: impl FnMut(R) -> Result<(), E>,
    progress: &dyn Progress,
) -> Result<(), E>
where
    T: Sync,
    R: Send,
    E: Send,
{
    let failed = AtomicBool::new(false);
    let (sender, receiver) = mpsc::channel::<(usize, Result<R, E>)>();
    std::thread::scope(|scope| {
        let failed = &failed;
        let work = &work;
        scope.spawn(move || {
            items.par_iter().enumerate().for_each_with(sender, |sender, (index, item)| {
                if !failed.load(Ordering::Relaxed) {
                    // The receiver outlives the workers unless it stopped on an error.
                    let _ = sender.send((index, work(item)));
                }
            });
        });
        let mut pending = BTreeMap::new();
        let mut next = 0;
        for (index, result) in receiver {
            pending.insert(index, result);
            while let Some(result) = pending.remove(&next) {
                next += 1;
                if let Err(err) = result.and_then(&mut write) {
                    failed.store(true, Ordering::Relaxed);
                    return Err(err);
                }
                progress.advance();
            }
        }
        Ok(())
    })
}

/// Decodes an image to grey, downscaled so its larger side is at most
/// `max_image_size_px`; returns it with the factor back to full resolution.
fn load_grey(path: &std::path::Path, max_image_size_px: u32) -> Result<(image::GrayImage, f32), PipelineError> {
    let bad = |reason: String| PipelineError::BadImage { path: path.to_path_buf(), reason };
    let bytes = std::fs::read(path).map_err(|source| PipelineError::Io { path: path.to_path_buf(), source })?;
    let format = image::guess_format(&bytes).map_err(|e| bad(e.to_string()))?;
    // JPEG decoders fill a cut-off file with grey instead of failing: insist on
    // the end-of-image marker (trailing padding allowed).
    if format == image::ImageFormat::Jpeg {
        let end = bytes.iter().rposition(|&b| b != 0 && b != b'\n' && b != b'\r').unwrap_or(0);
        if end < 1 || bytes.get(end - 1..=end) != Some(&[0xFF, 0xD9][..]) {
            return Err(bad("truncated JPEG (no end-of-image marker)".to_owned()));
        }
    }
    let grey = image::load_from_memory_with_format(&bytes, format).map_err(|e| bad(e.to_string()))?.to_luma8();
    let longest = grey.width().max(grey.height());
    if longest <= max_image_size_px {
        return Ok((grey, 1.0));
    }
    let factor = longest as f32 / max_image_size_px as f32;
    let width = ((grey.width() as f32 / factor).round() as u32).max(1);
    let height = ((grey.height() as f32 / factor).round() as u32).max(1);
    let small = image::imageops::resize(&grey, width, height, image::imageops::FilterType::Triangle);
    Ok((small, grey.width() as f32 / width as f32))
}

/// Feature extraction for every image of `sessions` whose features are not in
/// the store yet. `image_ids` maps COLMAP names to store ids.
pub fn extract_features(
    store: &mut Store,
    sessions: &[SessionImages],
    image_ids: &BTreeMap<String, ImageId>,
    sift: &SiftOptions,
    max_image_size_px: u32,
    progress: &dyn Progress,
) -> Result<StageCounts, PipelineError> {
    let finished = store.images_with_features()?;
    let mut todo = Vec::new();
    let mut total = 0;
    for session in sessions {
        for file in &session.files {
            total += 1;
            let name = revisit_core::image_name(&session.name, file);
            if let Some(&id) = image_ids.get(&name) {
                if !finished.contains(&id) {
                    todo.push((id, session.dir.join(file)));
                }
            }
        }
    }
    let counts = StageCounts { done: todo.len(), reused: total - todo.len() };
    tracing::info!(new = counts.done, reused = counts.reused, "features");
    progress.start("features", todo.len() as u64);
    parallel_in_order(
        &todo,
        |(id, path)| {
            let (grey, factor) = load_grey(path, max_image_size_px)?;
            let mut features = revisit_features::extract_sift(sift, &grey)
                .map_err(|e| PipelineError::Features { path: path.clone(), reason: e.to_string() })?;
            if factor != 1.0 {
                for kp in &mut features.keypoints {
                    kp.x *= factor;
                    kp.y *= factor;
                    kp.scale *= factor;
                }
            }
            Ok((*id, features))
        },
        |(id, features)| store.write_features(id, &features).map_err(PipelineError::from),
        progress,
    )?;
    progress.finish();
    Ok(counts)
}

/// Which images of other sessions each image is matched with.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum CrossStrategy {
    /// Intra-session pairs only.
    None,
    /// Every cross-session pair, with SIFT: the classic joint baseline.
    #[default]
    Sift,
}

/// An image pair to match, and whether it crosses sessions.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub struct PlannedPair {
    pub image_id1: ImageId,
    pub image_id2: ImageId,
    pub cross: bool,
}

/// Plans the pairs to match: intra-session pairs by `pair_options`, cross-session
/// pairs by `cross`. Sorted by (image 1, image 2).
pub fn plan_pairs(
    sessions: &[SessionImages],
    image_ids: &BTreeMap<String, ImageId>,
    cross: CrossStrategy,
    pair_options: &PairOptions,
) -> Vec<PlannedPair> {
    let ids: Vec<Vec<ImageId>> =
        sessions.iter().map(|s| s.image_names().iter().filter_map(|n| image_ids.get(n).copied()).collect()).collect();
    let mut pairs = Vec::new();
    for session in &ids {
        for (i, j) in intra_session_pairs(session.len(), pair_options) {
            if let (Some(&a), Some(&b)) = (session.get(i), session.get(j)) {
                pairs.push(PlannedPair { image_id1: a, image_id2: b, cross: false });
            }
        }
    }
    if cross == CrossStrategy::Sift {
        for (s, first) in ids.iter().enumerate() {
            for second in &ids[s + 1..] {
                for &a in first {
                    for &b in second {
                        pairs.push(PlannedPair { image_id1: a, image_id2: b, cross: true });
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
pub fn match_pairs(
    store: &mut Store,
    pairs: &[PlannedPair],
    features: &HashMap<ImageId, Features>,
    learned: Option<&LearnedKeypoints>,
    match_options: &MatchOptions,
    verify_options: &VerifyOptions,
    progress: &dyn Progress,
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
        |pair| -> Result<_, PipelineError> {
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
                kind: if pair.cross { "cross" } else { "intra" }.to_owned(),
                method: method.clone(),
                roll_deg: 0,
                num_matches: matches.len(),
                num_inliers: geometry.inlier_matches.len(),
            };
            Ok((record, matches, geometry))
        },
        |(record, matches, geometry)| store.write_pair(&record, &matches, &geometry).map_err(PipelineError::from),
        progress,
    )?;
    progress.finish();
    Ok(counts)
}
