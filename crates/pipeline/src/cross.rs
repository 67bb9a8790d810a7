//! Cross-visit stages: learned features, place recognition, pair selection
//! and learned matching with roll search, over the store.
//!
//! Visits are ordered by the store (the first is the reference): an image of
//! a later visit is described at every roll the search needs and queries the
//! images of all earlier visits, which are described at roll 0 only. So a new
//! visit queries the previous ones without recomputing anything of theirs.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use nalgebra::Point3;

use revisit_core::{pair_id, ImageId, Keypoint, LearnedFeatures, PairKind, Reconstruction, Roll};
use revisit_features::learned::LearnedExtractor;
use revisit_matching::consistency::{self, CheckedPair, Motion, Navigated, Navigation, Placement, Predictor, Verdict};
use revisit_matching::{match_learned_pair, CrossOptions, LearnedPairMatch, LightGlue, Prediction, RollSearch};
use revisit_places::{nearest, Candidate, CandidateOptions, GlobalDescriptor, OnnxPlaces, Vlad, Vocabulary};
use revisit_store::{CrossSide, PairRecord, Store};
use serde::{Deserialize, Serialize};

use crate::learned::LearnedMethod;
use crate::options::{CrossStrategy, PlaceSource};
use crate::stages::LearnedKeypoints;
use crate::{workers, Cancel, PipelineError, Progress, Session, StageCounts};

/// The rolls each image needs: roll 0 for the first visit (the reference),
/// every roll the search tries for later ones.
fn rolls_of(visit_index: usize, search: RollSearch) -> &'static [Roll] {
    if visit_index == 0 {
        &[Roll::R0]
    } else {
        search.rolls()
    }
}

/// An image, its file, and the rolls it still needs.
type MissingRolls<'a> = (ImageId, &'a Path, Vec<Roll>);

/// Each image's rolls (by [`rolls_of`]) for which `stored` is false, with
/// the counts of what is to do and what is reused.
fn missing_rolls(
    sessions: &[Session],
    search: RollSearch,
    stored: impl Fn(ImageId, Roll) -> bool,
) -> (Vec<MissingRolls<'_>>, StageCounts) {
    let mut todo = Vec::new();
    let mut total = 0;
    for (v, session) in sessions.iter().enumerate() {
        for image in &session.images {
            let rolls = rolls_of(v, search);
            total += rolls.len();
            let missing: Vec<Roll> = rolls.iter().copied().filter(|r| !stored(image.id, *r)).collect();
            if !missing.is_empty() {
                todo.push((image.id, image.path.as_path(), missing));
            }
        }
    }
    let done: usize = todo.iter().map(|t| t.2.len()).sum();
    (todo, StageCounts { done, reused: total - done })
}

fn load_rgb(path: &Path) -> Result<image::RgbImage, PipelineError> {
    Ok(crate::images::read(path)?.to_rgb8())
}

fn onnx_error(path: &Path, error: revisit_onnx::OnnxError) -> PipelineError {
    PipelineError::Features { path: path.to_path_buf(), reason: error.to_string() }
}

/// Learned features of every image at the rolls it needs that the store
/// lacks: an image at a time on each of `extractors` (one worker thread each),
/// stored in image order.
pub fn extract_learned(
    store: &mut Store,
    method: LearnedMethod,
    extractors: &mut [LearnedExtractor],
    sessions: &[Session],
    search: RollSearch,
    progress: &dyn Progress,
    cancel: &Cancel,
) -> Result<StageCounts, PipelineError> {
    let method = method.name();
    let stored = store.learned_feature_keys(method)?;
    let (todo, counts) = missing_rolls(sessions, search, |id, roll| stored.contains(&(id, roll.degrees())));
    tracing::info!(new = counts.done, reused = counts.reused, method, workers = extractors.len(), "learned features");
    progress.start("learned features", counts.done as u64);
    workers::in_order(
        store,
        extractors,
        todo.len(),
        |_, _| Ok(()),
        |extractor, i, ()| {
            let (_, path, rolls) = &todo[i];
            let image = load_rgb(path)?;
            let extract = |roll: &Roll| Ok((*roll, extractor.extract(&image, *roll).map_err(|e| onnx_error(path, e))?));
            rolls.iter().map(extract).collect::<Result<Vec<_>, PipelineError>>()
        },
        |store, i, by_roll| {
            for (roll, features) in by_roll {
                store.write_learned_features(todo[i].0, method, roll.degrees(), &features)?;
                progress.advance();
            }
            Ok(())
        },
        cancel,
    )?;
    progress.finish();
    Ok(counts)
}

/// Registers every image's roll-0 learned keypoints in its keypoint list
/// (where not done yet) and returns them, for matching within visits
/// alongside SIFT (see [`crate::stages::match_pairs`]).
pub fn register_learned_keypoints(
    store: &mut Store,
    method: &str,
    sessions: &[Session],
) -> Result<LearnedKeypoints, PipelineError> {
    let mut out = LearnedKeypoints { method: method.to_owned(), images: Default::default() };
    for id in sessions.iter().flat_map(|s| &s.images).map(|image| &image.id) {
        let features = store.read_learned_features(*id, method, 0)?;
        let mut indices = store.learned_keypoint_indices(*id, method, 0)?;
        if indices.len() < features.len() {
            let side = CrossSide { image_id: *id, method, roll_deg: 0, positions: &features.keypoints };
            store.register_learned_keypoints(side)?;
            indices = store.learned_keypoint_indices(*id, method, 0)?;
        }
        let by_learned: Vec<u32> = (0..features.len() as u32).filter_map(|l| indices.get(&l).copied()).collect();
        if by_learned.len() != features.len() {
            return Err(PipelineError::Store(revisit_store::StoreError::Corrupt {
                path: store.path().to_path_buf(),
                what: format!("learned keypoints of image {id}"),
                reason: "not all registered".to_owned(),
            }));
        }
        out.images.insert(*id, (features, by_learned));
    }
    Ok(out)
}

/// The global descriptors of place recognition, computed where missing.
pub struct Places {
    /// The name descriptors are stored under.
    pub name: String,
    pub descriptors: BTreeMap<(ImageId, u32), Vec<f32>>,
    pub counts: StageCounts,
}

/// Describes every image at the rolls it needs with `source`, reusing what
/// the store holds (the VLAD vocabulary is learned once, on the visits
/// present the first time, and kept).
#[allow(clippy::too_many_arguments)] // the stage's inputs, each needed
pub fn describe_places(
    store: &mut Store,
    learned_method: &str,
    source: &PlaceSource,
    runtime: &revisit_onnx::Runtime,
    sessions: &[Session],
    search: RollSearch,
    progress: &dyn Progress,
    cancel: &Cancel,
) -> Result<Places, PipelineError> {
    enum Describer {
        Vlad(Vlad),
        Onnx(OnnxPlaces),
    }
    let mut describer = match source {
        PlaceSource::Vlad { clusters } => {
            let vocabulary_name = format!("vlad{clusters}-{learned_method}");
            let vocabulary = match store.vocabulary(&vocabulary_name)? {
                Some((dim, centres)) => Vocabulary { dim, centres },
                None => {
                    let vocabulary = train_vocabulary(store, learned_method, sessions, *clusters)?;
                    store.write_vocabulary(&vocabulary_name, vocabulary.dim, &vocabulary.centres)?;
                    vocabulary
                }
            };
            Describer::Vlad(Vlad { vocabulary, features: learned_method.to_owned() })
        }
        PlaceSource::Onnx(path) => Describer::Onnx(OnnxPlaces::open(runtime, path).map_err(|e| onnx_error(path, e))?),
    };
    let name = match &describer {
        Describer::Vlad(v) => v.name(),
        Describer::Onnx(o) => o.name(),
    };
    let mut descriptors = store.global_descriptors(&name)?;
    let (todo, counts) = missing_rolls(sessions, search, |id, roll| descriptors.contains_key(&(id, roll.degrees())));
    tracing::info!(new = counts.done, reused = counts.reused, name, "place descriptors");
    progress.start("place descriptors", counts.done as u64);
    for (id, path, rolls) in todo {
        cancel.check()?;
        let image = match describer {
            Describer::Onnx(_) => Some(load_rgb(path)?),
            Describer::Vlad(_) => None,
        };
        for roll in rolls {
            let descriptor = match (&mut describer, &image) {
                (Describer::Onnx(model), Some(image)) => {
                    model.describe(image, roll).map_err(|e| onnx_error(path, e))?
                }
                (Describer::Vlad(vlad), _) => {
                    vlad.describe(&store.read_learned_features(id, learned_method, roll.degrees())?.descriptors)
                }
                (Describer::Onnx(_), None) => continue, // images are loaded for ONNX descriptors
            };
            store.write_global_descriptor(id, &name, roll.degrees(), &descriptor)?;
            descriptors.insert((id, roll.degrees()), descriptor);
            progress.advance();
        }
    }
    progress.finish();
    Ok(Places { name, descriptors, counts })
}

/// k-means over up to 64 descriptors (the strongest) of every image at roll 0.
fn train_vocabulary(
    store: &Store,
    learned_method: &str,
    sessions: &[Session],
    clusters: usize,
) -> Result<Vocabulary, PipelineError> {
    const PER_IMAGE: usize = 64;
    let mut samples = Vec::new();
    let mut dim = 0;
    for id in sessions.iter().flat_map(|s| &s.images).map(|image| &image.id) {
        let features = store.read_learned_features(*id, learned_method, 0)?.strongest(PER_IMAGE);
        dim = features.descriptor_dim;
        samples.extend(features.descriptors);
    }
    tracing::info!(clusters, samples = samples.len() / dim.max(1), "training the VLAD vocabulary");
    Ok(Vocabulary::train(&samples, dim, clusters, 20, 0))
}

/// A pair for the learned matcher: `image_id2` is the one rolled.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub struct LearnedPair {
    pub image_id1: ImageId,
    pub image_id2: ImageId,
    pub kind: PairKind,
    /// Where image 1 stands among image 2's place-recognition candidates
    /// (0: the nearest); 0 for a pair not chosen by place recognition.
    pub rank: usize,
    /// Image 2's roll whose place descriptor was nearest image 1's, for a
    /// pair chosen by place recognition: where a roll search begins.
    pub place_roll: Option<Roll>,
}

/// Where the vehicle's navigation puts each image, and how near two images must be to show the
/// same place.
#[derive(Clone, Debug, Default)]
pub struct Nearby {
    /// Each image's camera centre in the navigation frame, metres (images without navigation
    /// are absent).
    pub positions_m: BTreeMap<ImageId, Point3<f64>>,
    pub radius_m: f64,
}

impl Nearby {
    /// Whether `a` and `b` may show the same place: within the radius, or not both navigated.
    fn allows(&self, a: ImageId, b: ImageId) -> bool {
        match (self.positions_m.get(&a), self.positions_m.get(&b)) {
            (Some(p), Some(q)) => (p - q).norm() <= self.radius_m,
            _ => true,
        }
    }

    /// The `k` images of `among` nearest to `image` within the radius, nearest first (ties by id).
    fn nearest(&self, image: ImageId, among: &[ImageId], k: usize) -> Vec<ImageId> {
        let Some(p) = self.positions_m.get(&image) else { return Vec::new() };
        let mut near: Vec<(f64, ImageId)> = among
            .iter()
            .filter_map(|a| Some(((self.positions_m.get(a)? - p).norm(), *a)))
            .filter(|(distance_m, _)| *distance_m <= self.radius_m)
            .collect();
        near.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)));
        near.into_iter().take(k).map(|(_, a)| a).collect()
    }
}

/// The pairs the learned matcher sees under `strategy`: every pair
/// (`learned-all`), every cross-visit pair (`learned-cross`), or each later
/// image's place-recognition candidates among earlier visits (`vpr`, for
/// which `places` must hold every image's descriptors). With navigation
/// (`nearby`), `vpr` drops the candidates farther than its radius and adds each
/// later image's `top_k` nearest earlier images within it.
pub fn plan_learned_pairs(
    strategy: CrossStrategy,
    sessions: &[Session],
    places: Option<&Places>,
    candidates: &CandidateOptions,
    nearby: Option<&Nearby>,
) -> Vec<LearnedPair> {
    let mut pairs = BTreeSet::new();
    let ids: Vec<Vec<ImageId>> = sessions.iter().map(|s| s.images.iter().map(|i| i.id).collect()).collect();
    let pair = |a, b, kind| LearnedPair { image_id1: a, image_id2: b, kind, rank: 0, place_roll: None };
    for (v, later) in ids.iter().enumerate() {
        let earlier: Vec<ImageId> = ids[..v].iter().flatten().copied().collect();
        match strategy {
            CrossStrategy::None | CrossStrategy::Sift => {}
            CrossStrategy::LearnedAll | CrossStrategy::LearnedCross => {
                for &b in later {
                    pairs.extend(earlier.iter().map(|&a| pair(a, b, PairKind::Cross)));
                }
                if strategy == CrossStrategy::LearnedAll {
                    for (i, &a) in later.iter().enumerate() {
                        pairs.extend(later[i + 1..].iter().map(|&b| pair(a, b, PairKind::Intra)));
                    }
                }
            }
            CrossStrategy::Vpr => {
                let Some(places) = places else { continue };
                let allows = |a, b| nearby.is_none_or(|nearby| nearby.allows(a, b));
                for (b, found) in place_candidates(sessions, places, candidates, v) {
                    let ranked = found.into_iter().enumerate().filter(|(_, (a, _))| allows(*a, b));
                    pairs.extend(ranked.map(|(rank, (a, candidate))| LearnedPair {
                        rank,
                        place_roll: Some(candidate.roll),
                        ..pair(a, b, PairKind::Cross)
                    }));
                }
                for (b, nearby) in later.iter().filter_map(|b| Some((*b, nearby?))) {
                    for a in nearby.nearest(b, &earlier, candidates.top_k) {
                        // The pair at any rank and place roll.
                        let (first, last) = (
                            pair(a, b, PairKind::Cross),
                            LearnedPair {
                                rank: usize::MAX,
                                place_roll: Some(Roll::R270),
                                ..pair(a, b, PairKind::Cross)
                            },
                        );
                        if pairs.range(first..=last).next().is_none() {
                            pairs.insert(first);
                        }
                    }
                }
            }
        }
    }
    pairs.into_iter().collect()
}

/// Place recognition's answer for each image of `sessions[visit]`: its nearest images among all
/// earlier visits' (at roll 0), each with its distance and the query's best roll. Empty if some
/// earlier image has no descriptor.
pub fn place_candidates(
    sessions: &[Session],
    places: &Places,
    options: &CandidateOptions,
    visit: usize,
) -> Vec<(ImageId, Vec<(ImageId, Candidate)>)> {
    let earlier: Vec<ImageId> =
        sessions[..visit.min(sessions.len())].iter().flat_map(|s| &s.images).map(|i| i.id).collect();
    let database: Vec<&[f32]> =
        earlier.iter().filter_map(|a| places.descriptors.get(&(*a, 0)).map(Vec::as_slice)).collect();
    if database.len() != earlier.len() {
        return Vec::new();
    }
    let Some(session) = sessions.get(visit) else { return Vec::new() };
    session
        .images
        .iter()
        .map(|image| {
            let query: Vec<(Roll, &[f32])> = Roll::ALL
                .iter()
                .filter_map(|r| places.descriptors.get(&(image.id, r.degrees())).map(|d| (*r, d.as_slice())))
                .collect();
            let found = nearest(&query, &database, options)
                .into_iter()
                .filter_map(|candidate| Some((*earlier.get(candidate.index)?, candidate)))
                .collect();
            (image.id, found)
        })
        .collect()
}

/// Stores one matched learned pair (its record, anchored matches and
/// accepted inliers) in one transaction: the one-pair entry point that the
/// matching loop and a matcher node share.
pub fn write_learned_pair(
    store: &mut Store,
    pair: &LearnedPair,
    method: &str,
    matched: &LearnedPairMatch,
) -> Result<(), PipelineError> {
    let record = PairRecord {
        image_id1: pair.image_id1,
        image_id2: pair.image_id2,
        kind: pair.kind,
        method: method.to_owned(),
        roll_deg: matched.roll.degrees() as i32,
        predicted_roll_deg: matched.predicted.map(|r| r.degrees() as i32),
        num_matches: matched.matches.len(),
        num_inliers: matched.inliers.len(),
    };
    let [positions_a, positions_b] = &matched.positions;
    let sides = [
        CrossSide { image_id: pair.image_id1, method, roll_deg: 0, positions: positions_a },
        CrossSide { image_id: pair.image_id2, method, roll_deg: matched.roll.degrees(), positions: positions_b },
    ];
    let confident = matched.confident.as_ref().filter(|_| pair.kind == PairKind::Cross);
    store.write_cross_pair(
        &record,
        sides,
        &matched.matches,
        (&matched.inliers, &matched.geometry),
        confident.map(|(inliers, geometry)| (inliers.as_slice(), geometry)),
    )?;
    Ok(())
}

/// What one learned pair needs from the store: both images' learned features (the second at
/// each roll the search tries) and every keypoint each image holds (SIFT and its registered
/// learned ones).
struct PairInputs {
    a: LearnedFeatures,
    b_by_roll: Vec<(Roll, LearnedFeatures)>,
    own_a: Vec<Keypoint>,
    own_b: Vec<Keypoint>,
}

fn read_pair_inputs(
    store: &Store,
    pair: &LearnedPair,
    predicted: Option<&Prediction>,
    method: &str,
    options: &CrossOptions,
) -> Result<PairInputs, PipelineError> {
    let rolls = match (pair.kind, predicted) {
        (PairKind::Cross, Some(prediction)) => prediction.rolls(),
        (PairKind::Cross, None) => options.roll_search.rolls().to_vec(),
        (PairKind::Intra, _) => RollSearch::Off.rolls().to_vec(),
    };
    Ok(PairInputs {
        a: store.read_learned_features(pair.image_id1, method, 0)?,
        b_by_roll: rolls
            .iter()
            .map(|r| Ok((*r, store.read_learned_features(pair.image_id2, method, r.degrees())?)))
            .collect::<Result<_, PipelineError>>()?,
        own_a: store.read_keypoints(pair.image_id1)?,
        own_b: store.read_keypoints(pair.image_id2)?,
    })
}

/// What [`match_learned_pairs`] did: pairs matched (`done`) and found stored (`reused`), and how
/// many times the learned matcher ran for them (a pair searched at several rolls runs it once per
/// roll tried, probes included), the cost of the roll search in matches.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LearnedMatchingCounts {
    pub done: usize,
    pub reused: usize,
    /// Searched pairs matched again at the roll their visits' offset settled on
    /// ([`Predictor::needs_settling`]); matched or reused, and counted there too.
    #[serde(default)]
    pub rematched: usize,
    #[serde(default)]
    pub matcher_runs: usize,
    /// Planned pairs left unmatched: their two visits' parts showed no clear offset within
    /// their search budget ([`search_budget`]), and none chained through other visits
    /// predicts them. Not in `done`.
    #[serde(default)]
    pub unlinked: usize,
}

impl LearnedMatchingCounts {
    /// The matcher's runs per pair matched (1: one match a pair); `None` when none was matched.
    pub fn runs_per_pair(&self) -> Option<f64> {
        (self.done > 0).then(|| self.matcher_runs as f64 / self.done as f64)
    }
}

/// Cross-visit pairs matched with the roll search (searched), per two parts of
/// two visits that have no consensus yet, before the next look for one: two
/// true pairs make a consensus even with a wrong one among them.
const BOOTSTRAP_PAIRS: usize = 3;

/// The most pairs searched between two parts of two visits while they show no clear offset:
/// a quarter of the pairs planned between them, and at least eight rounds of
/// `BOOTSTRAP_PAIRS`. Without a bound, visits that cannot be linked were searched to their
/// last pair (4 to 8 matcher runs each), every pair verified a likely wrong one (`--change
/// storm`, seed 5: 13 of 60 pairs, none right). Less is too little: the 3 x 64 survey's second
/// and third visits, linkable, had no offset after 35 of their 283 pairs, and `tests/compare.rs`'s
/// 2 x 10 reef finds its offset at the 17th of 50.
pub fn search_budget(planned: usize) -> usize {
    (planned / 4).max(8 * BOOTSTRAP_PAIRS)
}

/// Matches every planned pair not yet in the store with the learned matcher
/// ([`match_learned_pair`]: roll search on cross-visit pairs, anchoring,
/// acceptance) and stores it: one pair at a time on each of `matchers` (one
/// worker thread each), the store read and written on the calling thread, in
/// plan order. A pair's result does not depend on how many workers there are.
/// When cancelled or failing, the pairs already matched are stored.
///
/// With [`RollSearch::Predict`], pairs within visits come first; then, in
/// rounds, each cross-visit pair whose two visits' verified pairs agree on a
/// heading offset is matched at the roll that offset predicts, and
/// a few (`BOOTSTRAP_PAIRS`) more of each pair of visits (of connected parts) still
/// without one are searched, the nearest places first (by
/// [`LearnedPair::rank`]). Then the searched pairs whose matches turn
/// otherwise than their visits' settled offset are matched again at the
/// roll it predicts ([`Predictor::needs_settling`]). Two parts that show no
/// clear offset within their [`search_budget`] are searched no further: their
/// pairs wait for an offset chained through other visits, and are left
/// unmatched (`unlinked`) if none comes. The rounds depend only on what is
/// stored, so the result is the same on any number of workers, and a resumed
/// run searches no pair a finished one would not.
#[allow(clippy::too_many_arguments)] // the stage's inputs, each needed
pub fn match_learned_pairs(
    store: &mut Store,
    method: LearnedMethod,
    matchers: &mut [LightGlue],
    pairs: &[LearnedPair],
    sessions: &[Session],
    options: &CrossOptions,
    progress: &dyn Progress,
    cancel: &Cancel,
) -> Result<LearnedMatchingCounts, PipelineError> {
    let runs_before: usize = matchers.iter().map(LightGlue::runs).sum();
    let finished = store.matched_pairs()?;
    let todo: Vec<&LearnedPair> =
        pairs.iter().filter(|p| !finished.contains(&pair_id(p.image_id1, p.image_id2))).collect();
    let counts = StageCounts { done: todo.len(), reused: pairs.len() - todo.len() };
    let method = method.name();
    tracing::info!(new = counts.done, reused = counts.reused, method, workers = matchers.len(), "learned matching");
    progress.start("learned matching", todo.len() as u64);
    let mut run = |store: &mut Store, batch: &[(&LearnedPair, Option<Prediction>)]| {
        workers::in_order(
            store,
            matchers,
            batch.len(),
            |store, i| read_pair_inputs(store, batch[i].0, batch[i].1.as_ref(), method, options),
            |matcher, i, PairInputs { a, b_by_roll, own_a, own_b }| {
                let (pair, predicted) = &batch[i];
                let roll = (predicted.as_ref(), pair.place_roll);
                match_learned_pair(matcher, (&a, &own_a), (&b_by_roll, &own_b), pair.kind, roll, options).map_err(|e| {
                    PipelineError::Matching { pair: (pair.image_id1, pair.image_id2), reason: e.to_string() }
                })
            },
            |store, i, matched| {
                write_learned_pair(store, batch[i].0, method, &matched)?;
                progress.advance();
                Ok(())
            },
            cancel,
        )
    };
    let (mut rematched, mut unlinked) = (0, 0);
    if options.roll_search != RollSearch::Predict {
        let batch: Vec<_> = todo.into_iter().map(|p| (p, None)).collect();
        run(store, &batch)?;
        progress.finish();
    } else {
        let (intra, mut waiting): (Vec<&LearnedPair>, Vec<&LearnedPair>) =
            todo.into_iter().partition(|p| p.kind == PairKind::Intra);
        // Searched first: the nearest places (stable: in plan order within a rank).
        waiting.sort_by_key(|p| p.rank);
        run(store, &intra.into_iter().map(|p| (p, None)).collect::<Vec<_>>())?;
        let mut turns = PairTurns::new(sessions);
        let (mut predicted, mut searched) = (0, 0);
        while !waiting.is_empty() {
            turns.update(store)?;
            let predictor = Predictor::new(&turns.checked(), &turns.visit_of, options.consistency_tolerance_deg);
            let mut batch = Vec::new();
            let mut later = Vec::new();
            // Per two parts: the pairs planned, and those searched so far (by this run or one before).
            let mut by_parts: BTreeMap<Option<(ImageId, ImageId)>, (usize, usize)> = BTreeMap::new();
            for pair in pairs.iter().filter(|p| p.kind == PairKind::Cross) {
                let counts = by_parts.entry(predictor.parts(pair.image_id1, pair.image_id2)).or_default();
                counts.0 += 1;
                counts.1 += usize::from(turns.searched.contains(&pair_id(pair.image_id1, pair.image_id2)));
            }
            let mut bootstrapping: BTreeMap<Option<(ImageId, ImageId)>, usize> = BTreeMap::new();
            for pair in waiting {
                let (a, b) = (pair.image_id1, pair.image_id2);
                if let Some(turn_deg) = predictor.turn(a, b) {
                    let tolerance_deg = options.consistency_tolerance_deg;
                    batch.push((pair, Some(Prediction { turn_deg, tolerance_deg })));
                    predicted += 1;
                    continue;
                }
                let parts = predictor.parts(a, b);
                let (planned, searched_before) = by_parts.get(&parts).copied().unwrap_or_default();
                let started = bootstrapping.entry(parts).or_default();
                if *started < BOOTSTRAP_PAIRS && searched_before + *started < search_budget(planned) {
                    *started += 1;
                    batch.push((pair, None));
                    searched += 1;
                } else {
                    later.push(pair);
                }
            }
            tracing::debug!(pairs = batch.len(), waiting = later.len(), "cross-visit round");
            if batch.is_empty() {
                unlinked = later.len();
                break;
            }
            run(store, &batch)?;
            waiting = later;
        }
        tracing::info!(predicted, searched, unlinked, "cross-visit rolls");
        progress.finish();
        // Settled: a pair searched before its visits' offset was clear, whose matches turn
        // otherwise, is matched again at the settled roll (until none is left: a pair matched
        // at a prediction is never again, so a run resumed or extended settles the same pairs).
        let tolerance_deg = options.consistency_tolerance_deg;
        loop {
            turns.update(store)?;
            let predictor = Predictor::new(&turns.checked(), &turns.visit_of, tolerance_deg);
            let batch: Vec<_> = pairs
                .iter()
                .filter_map(|pair| {
                    let checked = turns.pairs.get(&pair_id(pair.image_id1, pair.image_id2))?.as_ref()?;
                    if !predictor.needs_settling(checked, tolerance_deg) {
                        return None;
                    }
                    // From the planned pair's first image (the store keeps a pair by its image ids).
                    let turn_deg = predictor.turn(pair.image_id1, pair.image_id2)?;
                    Some((pair, Some(Prediction { turn_deg, tolerance_deg })))
                })
                .collect();
            if batch.is_empty() {
                break;
            }
            tracing::info!(pairs = batch.len(), "cross-visit pairs matched again at their settled roll");
            progress.start("learned matching at settled rolls", batch.len() as u64);
            run(store, &batch)?;
            progress.finish();
            for (pair, _) in &batch {
                turns.pairs.remove(&pair_id(pair.image_id1, pair.image_id2));
            }
            rematched += batch.len();
        }
    }
    let matcher_runs = matchers.iter().map(LightGlue::runs).sum::<usize>() - runs_before;
    tracing::info!(pairs = counts.done - unlinked, rematched, unlinked, matcher_runs, "learned matching done");
    Ok(LearnedMatchingCounts { done: counts.done - unlinked, reused: counts.reused, rematched, matcher_runs, unlinked })
}

/// The store's verified pairs as the consistency check sees them (the turn
/// of their matches), each read once.
struct PairTurns {
    visit_of: BTreeMap<ImageId, usize>,
    /// Each image's centre, pixels.
    centres: BTreeMap<ImageId, [f64; 2]>,
    pairs: BTreeMap<u64, Option<CheckedPair>>,
    /// The cross-visit pairs stored without a prediction (searched), verified or not.
    searched: BTreeSet<u64>,
}

impl PairTurns {
    fn new(sessions: &[Session]) -> PairTurns {
        let visit_of = sessions.iter().enumerate().flat_map(|(v, s)| s.images.iter().map(move |i| (i.id, v))).collect();
        let centres = sessions
            .iter()
            .flat_map(|s| {
                s.images.iter().filter_map(|i| {
                    let camera = s.cameras.get(&i.camera)?;
                    Some((i.id, [f64::from(camera.width) / 2.0, f64::from(camera.height) / 2.0]))
                })
            })
            .collect();
        PairTurns { visit_of, centres, pairs: BTreeMap::new(), searched: BTreeSet::new() }
    }

    /// Reads the pairs stored since the last update.
    fn update(&mut self, store: &Store) -> Result<(), PipelineError> {
        // Read afresh each time: a learned pair stored since adds keypoints to its images.
        let mut keypoints: BTreeMap<ImageId, Vec<[f64; 2]>> = BTreeMap::new();
        for record in store.pair_records()? {
            let (a, b) = (record.image_id1, record.image_id2);
            let id = pair_id(a, b);
            match record.kind == PairKind::Cross && record.predicted_roll_deg.is_none() {
                true => self.searched.insert(id),
                false => self.searched.remove(&id),
            };
            if self.pairs.contains_key(&id) {
                continue;
            }
            if record.num_inliers == 0 || !self.visit_of.contains_key(&a) || !self.visit_of.contains_key(&b) {
                self.pairs.insert(id, None);
                continue;
            }
            for image in [a, b] {
                if let std::collections::btree_map::Entry::Vacant(entry) = keypoints.entry(image) {
                    let keypoints = store.read_keypoints(image)?;
                    entry.insert(keypoints.iter().map(|k| [f64::from(k.x), f64::from(k.y)]).collect());
                }
            }
            let matches = store.verified_matches(id)?;
            let at = |image: ImageId, side: usize| -> Vec<[f64; 2]> {
                matches.iter().filter_map(|m| keypoints[&image].get(m[side] as usize).copied()).collect()
            };
            let (points1, points2) = (at(a, 0), at(b, 1));
            let checked = consistency::turn(&points1, &points2).map(|turn| CheckedPair {
                image_id1: a,
                image_id2: b,
                kind: record.kind,
                turn,
                motion: match (self.centres.get(&a), self.centres.get(&b)) {
                    (Some(&centre1), Some(&centre2)) => consistency::similarity(&points1, &points2, turn.deg)
                        .map(|similarity| Motion { similarity, centre1, centre2 }),
                    _ => None,
                },
                inliers: record.num_inliers,
                // SIFT is matched at roll 0 whatever the turn: only a learned pair has a roll to agree with.
                roll: match record.kind == PairKind::Cross && record.method != "sift" {
                    true => u32::try_from(record.roll_deg).ok().and_then(Roll::from_degrees),
                    false => None,
                },
                predicted: record.predicted_roll_deg.is_some(),
            });
            self.pairs.insert(id, checked);
        }
        Ok(())
    }

    /// Every verified pair with a turn, by pair id.
    fn checked(&self) -> Vec<CheckedPair> {
        self.pairs.values().flatten().copied().collect()
    }
}

/// What [`check_consistency`] found among the verified cross-visit pairs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ConsistencyCounts {
    /// Verified cross-visit pairs checked.
    pub checked: usize,
    /// Inconsistent: matched at a roll their matches do not show.
    pub roll_disagrees: usize,
    /// Inconsistent: their visits' other pairs agree on another heading offset.
    pub off_consensus: usize,
    /// Inconsistent: their matches put the other camera where navigation does not.
    #[serde(default)]
    pub off_navigation: usize,
    /// Inconsistent: the loops they close with the other cross-visit pairs miss.
    #[serde(default)]
    pub off_loops: usize,
    /// Confirmed: consistent, and most of their loops close.
    #[serde(default)]
    pub confirmed: usize,
    /// Inconsistent: pairs of visits that show no clear heading offset, weak
    /// or at odds with another rule ([`Verdict::Unlinked`]).
    #[serde(default)]
    pub unlinked: usize,
    /// Inconsistent pairs set aside (not mapped): every one when asked for,
    /// those off the navigation when mapping change-aware, the unlinked ones always.
    pub set_aside: usize,
    /// Confident pairs mapped on their confident inliers: between two visits
    /// that hold enough of them (`CrossOptions::confident_pairs`, when given).
    #[serde(default)]
    pub confident: usize,
    /// Weak pairs set aside (not mapped): verified, not confident, between two
    /// visits that hold enough confident pairs (`CrossOptions::confident_pairs`).
    #[serde(default)]
    pub weak: usize,
}

impl ConsistencyCounts {
    /// The inconsistent pairs, whatever the rule.
    pub fn inconsistent(&self) -> usize {
        self.roll_disagrees + self.off_consensus + self.off_navigation + self.off_loops + self.unlinked
    }
}

/// Checks every verified cross-visit pair of `sessions` against its roll,
/// against the other pairs and against the navigation priors in the store
/// ([`revisit_matching::consistency`]) and logs each inconsistent one. With
/// `options.set_aside_inconsistent` every inconsistent pair is set aside
/// (COLMAP does not see it; the store keeps it), and the weak or inconsistent pairs
/// of visits that show no clear offset always are (they merged wrong places on every survey
/// measured, [`consistency::UNLINKED_MIN_INLIERS`]); every other pair set aside before is
/// put back (a visit added since can settle a consensus, and the options can
/// change). Deterministic: the same store gives the same verdicts.
///
/// Why pairs off the navigation are kept unless asked: nearly all are wrong by
/// the truth, but some hold a few of the right matches that link a visit whose
/// corals grew, and both mappers placed such visits worse without them
/// (README). Change-aware mapping judges every match against its visits'
/// placement; where few right matches link a visit it came out at 2.2-2.7 px
/// with them set aside against 1.2-1.4 px with them kept (within 0.3 px either
/// way elsewhere).
pub fn check_consistency(
    store: &mut Store,
    sessions: &[Session],
    options: &CrossOptions,
) -> Result<Consistency, PipelineError> {
    let names: BTreeMap<ImageId, String> =
        sessions.iter().flat_map(|s| &s.images).map(|i| (i.id, i.name.to_string())).collect();
    let mut turns = PairTurns::new(sessions);
    turns.update(store)?;
    let checked = turns.checked();
    let visit_of = &turns.visit_of;
    let navigation = Navigation { positions: navigated(store)?, tolerance_sigmas: options.navigation_tolerance_sigmas };
    let verdicts = consistency::check_cross_pairs(
        &checked,
        visit_of,
        options.consistency_tolerance_deg,
        &navigation,
        options.loop_tolerance,
    );
    let confidence =
        Confidence::of(&store.pair_records()?, &store.confident_pairs()?, visit_of, options.confident_pairs);
    let weak = &confidence.weak;
    let mut aside = store.set_aside_pairs()?;
    let mut counts = ConsistencyCounts {
        checked: verdicts.len(),
        confident: confidence.mapped.len(),
        weak: weak.len(),
        ..ConsistencyCounts::default()
    };
    let mut confirmed = Vec::new();
    let mut handled = BTreeSet::new();
    for (index, verdict) in verdicts {
        let pair = &checked[index];
        let id = pair_id(pair.image_id1, pair.image_id2);
        let unlinked = matches!(verdict, Verdict::Unlinked { .. });
        let reason = match verdict {
            Verdict::Consistent => continue,
            Verdict::Confirmed { .. } => {
                counts.confirmed += 1;
                // The model is checked against the pairs it was made from.
                if !weak.contains_key(&id) {
                    confirmed.push((pair.image_id1, pair.image_id2));
                }
                continue;
            }
            Verdict::OffNavigation { miss_m, tolerance_m } => {
                counts.off_navigation += 1;
                format!("its matches put the other camera {miss_m:.2} m from its navigated position ({tolerance_m:.2} m allowed)")
            }
            Verdict::RollDisagrees { turn_deg, roll } => {
                counts.roll_disagrees += 1;
                format!("matched at roll {}, but its matches turn the image by {turn_deg:.0} deg", roll.degrees())
            }
            Verdict::OffConsensus { offset_deg, consensus_deg } => {
                counts.off_consensus += 1;
                format!("heading offset {offset_deg:.0} deg between the visits; their other pairs agree on {consensus_deg:.0}")
            }
            Verdict::OffLoops { missed, closed } => {
                counts.off_loops += 1;
                format!("{missed} of the {} loops it makes with other cross-visit pairs miss", missed + closed)
            }
            Verdict::Unlinked { inliers, inconsistent } => {
                counts.unlinked += 1;
                let why = match inconsistent {
                    true => format!("it holds {inliers} inliers, but is at odds with its roll, its visits' other pairs, the navigation or its loops"),
                    false => format!("it holds {inliers} inliers (fewer than {})", consistency::UNLINKED_MIN_INLIERS),
                };
                format!("its visits' pairs agree on no heading offset, and {why}")
            }
        };
        let (a, b) = (&names[&pair.image_id1], &names[&pair.image_id2]);
        if options.set_aside_inconsistent || unlinked || weak.contains_key(&id) {
            tracing::warn!("cross-visit pair {a} - {b} set aside: {reason}");
            put_aside(store, &mut aside, id, &reason)?;
            handled.insert(id);
            counts.set_aside += 1;
        } else {
            tracing::warn!("cross-visit pair {a} - {b} is inconsistent (mapped all the same): {reason}");
        }
    }
    for (id, visits) in weak {
        if !handled.contains(id) {
            let reason = format!("weak: its visits hold {} confident pairs", confidence.per_visits[visits]);
            put_aside(store, &mut aside, *id, &reason)?;
        }
    }
    for ([v1, v2], confident) in &confidence.per_visits {
        let weak = weak.values().filter(|visits| *visits == &[*v1, *v2]).count();
        tracing::info!(
            "{} - {}: {confident} confident cross-visit pairs mapped on their confident inliers, {weak} weak ones set aside",
            sessions[*v1].name,
            sessions[*v2].name
        );
    }
    // What stays in `aside` is consistent now, or no longer to be set aside.
    for id in aside.into_keys() {
        store.restore_set_aside(id)?;
    }
    // Then every confident pair COLMAP sees is mapped on the inliers the rule gives it.
    for id in store.confident_pairs()? {
        store.use_confident(id, confidence.mapped.contains_key(&id))?;
    }
    Ok(Consistency { counts, confirmed })
}

/// Sets pair `id` aside for `reason` unless `aside` (the pairs set aside before) has it; takes it
/// out of `aside`.
fn put_aside(store: &mut Store, aside: &mut BTreeMap<u64, String>, id: u64, reason: &str) -> Result<(), PipelineError> {
    if aside.remove(&id).is_none() {
        store.set_aside(id, reason)?;
    }
    Ok(())
}

/// The confident-pairs rule ([`CrossOptions::confident_pairs`]) over the verified cross-visit
/// pairs: between two visits with enough confident pairs, those are mapped on their confident
/// inliers and the weak ones set aside.
struct Confidence {
    /// The confident pairs so mapped, by pair id, with their two visits (in visit order).
    mapped: BTreeMap<u64, [usize; 2]>,
    /// The weak pairs so set aside, likewise.
    weak: BTreeMap<u64, [usize; 2]>,
    /// How many confident pairs each such pair of visits holds.
    per_visits: BTreeMap<[usize; 2], usize>,
}

impl Confidence {
    /// The rule over `records`, of which `confident` (pair ids) hold a confident geometry; none
    /// without `min_confident`.
    fn of(
        records: &[PairRecord],
        confident: &BTreeSet<u64>,
        visit_of: &BTreeMap<ImageId, usize>,
        min_confident: Option<usize>,
    ) -> Confidence {
        let verified: Vec<(u64, [usize; 2])> = records
            .iter()
            .filter(|r| r.kind == PairKind::Cross && r.num_inliers > 0)
            .filter_map(|r| {
                let (v1, v2) = (*visit_of.get(&r.image_id1)?, *visit_of.get(&r.image_id2)?);
                Some((pair_id(r.image_id1, r.image_id2), [v1.min(v2), v1.max(v2)]))
            })
            .collect();
        let mut per_visits: BTreeMap<[usize; 2], usize> = BTreeMap::new();
        for (_, visits) in verified.iter().filter(|(id, _)| confident.contains(id)) {
            *per_visits.entry(*visits).or_default() += 1;
        }
        per_visits.retain(|_, count| min_confident.is_some_and(|least| *count >= least));
        let (mapped, weak) = verified
            .into_iter()
            .filter(|(_, visits)| per_visits.contains_key(visits))
            .partition(|(id, _)| confident.contains(id));
        Confidence { mapped, weak, per_visits }
    }
}

/// What [`check_consistency`] found: the counts, and the confirmed pairs.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Consistency {
    pub counts: ConsistencyCounts,
    /// The mapped cross-visit pairs the loops confirm, `(image 1, image 2)` as stored.
    pub confirmed: Vec<(ImageId, ImageId)>,
}

/// Per pair of visits that `model` joins (`"s1-s2"`, in visit order), how it
/// holds the `confirmed` cross-visit pairs between them
/// ([`consistency::placement_error_px`]), and how many mapped pairs of
/// `records` (the store's) join them.
/// The loops confirm a pair without the model, so a model whose placement of
/// two visits disagrees with most of them placed the visits wrong: a wrong
/// pair bent it, or it joined the visits where no pair says they meet. A join
/// without a confirmed pair is unchecked.
pub fn check_placement(
    store: &Store,
    sessions: &[Session],
    model: &Reconstruction,
    records: &[PairRecord],
    confirmed: &[(ImageId, ImageId)],
) -> Result<BTreeMap<String, Placement>, PipelineError> {
    let session_of: BTreeMap<ImageId, &Session> =
        sessions.iter().flat_map(|s| s.images.iter().map(move |i| (i.id, s))).collect();
    // The two visits of a cross-visit pair with both images in the model.
    let visits = |a: ImageId, b: ImageId| -> Option<String> {
        let (sa, sb) = (session_of.get(&a)?, session_of.get(&b)?);
        let (first, second) = if sa.visit <= sb.visit { (sa, sb) } else { (sb, sa) };
        (sa.visit != sb.visit && model.images.contains_key(&a) && model.images.contains_key(&b))
            .then(|| format!("{}-{}", first.name, second.name))
    };
    let aside = store.set_aside_pairs()?;
    let mut joining: BTreeMap<String, usize> = BTreeMap::new();
    for record in records {
        let (a, b) = (record.image_id1, record.image_id2);
        if record.kind == PairKind::Cross && record.num_inliers > 0 && !aside.contains_key(&pair_id(a, b)) {
            if let Some(visits) = visits(a, b) {
                *joining.entry(visits).or_default() += 1;
            }
        }
    }
    let mut errors: BTreeMap<String, Vec<(f64, f64)>> = joining.keys().map(|v| (v.clone(), Vec::new())).collect();
    for &(a, b) in confirmed {
        let (Some(visits), Some(image_b)) = (visits(a, b), model.images.get(&b)) else { continue };
        let matches = store.verified_matches(pair_id(a, b))?;
        let Some(error_px) = consistency::placement_error_px(model, a, b, &matches) else { continue };
        let Some(camera) = model.cameras.get(&image_b.camera_id) else { continue };
        let tolerance_px = consistency::PLACEMENT_TOLERANCE * f64::from(camera.width).hypot(f64::from(camera.height));
        errors.entry(visits).or_default().push((error_px, tolerance_px));
    }
    Ok(errors
        .into_iter()
        .map(|(visits, errors)| {
            let joining = joining.get(&visits).copied().unwrap_or_default();
            (visits, Placement { joining, ..Placement::of(&errors) })
        })
        .collect())
}

/// The images' navigated positions across the ground, from the store's pose
/// priors (a prior without a covariance counts as COLMAP takes it: 1 m per axis).
fn navigated(store: &Store) -> Result<BTreeMap<ImageId, Navigated>, PipelineError> {
    let navigated = |p: revisit_store::PosePrior| {
        let sigma_m = p.covariance_m2.map_or(2f64.sqrt(), |c| (c[(0, 0)] + c[(1, 1)]).max(0.0).sqrt());
        (p.image_id, Navigated { xy_m: [p.position_m.x, p.position_m.y], sigma_m })
    };
    Ok(store.pose_priors()?.into_iter().map(navigated).collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::workspace::SessionImage;

    fn session(name: &str, visit: usize, ids: &[ImageId]) -> Session {
        let image = |id: &ImageId| SessionImage {
            name: revisit_core::ImageName::new(name, &format!("{id}.png")).unwrap(),
            id: *id,
            camera: "cam".into(),
            path: format!("{id}.png").into(),
        };
        let images = ids.iter().map(image).collect();
        Session {
            name: name.into(),
            visit,
            dir: name.into(),
            images,
            cameras: BTreeMap::new(),
            calibrated: BTreeSet::new(),
        }
    }

    #[test]
    fn navigation_drops_far_candidates_and_adds_near_images() {
        let sessions = [session("s1", 0, &[1, 2, 3]), session("s2", 1, &[4, 5])];
        // Place recognition sends image 4 to 3 then 1, image 5 to 2 then 3.
        let mut descriptors = BTreeMap::new();
        for (id, d) in [(1, [1.0, 0.0]), (2, [0.0, 1.0]), (3, [0.8, 0.6])] {
            descriptors.insert((id, 0), d.to_vec());
        }
        for roll in Roll::ALL {
            descriptors.insert((4, roll.degrees()), vec![0.9, 0.436]);
            descriptors.insert((5, roll.degrees()), vec![0.0, 1.0]);
        }
        let places = Places { name: "test".into(), descriptors, counts: StageCounts::default() };
        let candidates = CandidateOptions { top_k: 2, max_distance: None };
        let plan = |nearby: Option<&Nearby>| -> Vec<(ImageId, ImageId, usize)> {
            let pairs = plan_learned_pairs(CrossStrategy::Vpr, &sessions, Some(&places), &candidates, nearby);
            pairs.into_iter().map(|p| (p.image_id1, p.image_id2, p.rank)).collect()
        };
        assert_eq!(plan(None), [(1, 4, 1), (2, 5, 0), (3, 4, 0), (3, 5, 1)]);
        // Along a line: image 4 near 1 and 2, image 5 far from every earlier image.
        let x = [(1, 0.0), (2, 0.9), (3, 1.9), (4, 0.1), (5, 5.0)];
        let positions_m = x.into_iter().map(|(id, x)| (id, Point3::new(x, 0.0, -10.0))).collect();
        let nearby = Nearby { positions_m, radius_m: 1.0 };
        assert_eq!(plan(Some(&nearby)), [(1, 4, 1), (2, 4, 0)]);
    }

    #[test]
    fn weak_pairs_go_only_between_visits_with_enough_confident_ones() {
        // Visits 0 (images 1-3), 1 (4-6) and 2 (7-9).
        let visit_of: BTreeMap<ImageId, usize> = (1..=9).map(|id| (id, (id as usize - 1) / 3)).collect();
        let record = |a: ImageId, b: ImageId, num_inliers: usize| PairRecord {
            image_id1: a,
            image_id2: b,
            kind: PairKind::Cross,
            method: "aliked-lightglue".into(),
            roll_deg: 0,
            predicted_roll_deg: None,
            num_matches: 100,
            num_inliers,
        };
        // Visits 0-1: two confident pairs, a weak one and one that did not verify; visits 0-2
        // and 1-2: one confident pair each, and a weak one.
        let records = [(1, 4, 60), (2, 5, 50), (3, 6, 40), (1, 6, 0), (1, 7, 60), (2, 8, 45), (4, 9, 60), (6, 9, 45)]
            .map(|(a, b, n)| record(a, b, n));
        let confident = BTreeSet::from([pair_id(1, 4), pair_id(2, 5), pair_id(1, 7), pair_id(4, 9)]);
        let rule = Confidence::of(&records, &confident, &visit_of, Some(2));
        assert_eq!(rule.weak, BTreeMap::from([(pair_id(3, 6), [0, 1])]));
        assert_eq!(rule.mapped, BTreeMap::from([(pair_id(1, 4), [0, 1]), (pair_id(2, 5), [0, 1])]));
        assert_eq!(rule.per_visits, BTreeMap::from([([0, 1], 2)]));
        let rule = Confidence::of(&records, &confident, &visit_of, Some(1));
        assert_eq!((rule.mapped.len(), rule.weak.len()), (4, 3));
        assert!(Confidence::of(&records, &confident, &visit_of, Some(3)).mapped.is_empty());
        assert!(Confidence::of(&records, &confident, &visit_of, None).weak.is_empty());
    }
}
