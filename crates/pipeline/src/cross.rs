//! Cross-visit stages: learned features, place recognition, pair selection
//! and learned matching with roll search, over the store.
//!
//! Visits are ordered (the first is the reference): an image of a later visit
//! is described at every roll the search needs and queries the images of all
//! earlier visits, which are described at roll 0 only. So a new visit queries
//! the previous ones without recomputing anything of theirs.

use std::collections::{BTreeMap, BTreeSet, HashSet};
use std::path::{Path, PathBuf};

use revisit_core::{pair_id, ImageId, LearnedFeatures, Roll, TwoViewGeometry};
use revisit_matching::roll::unrolled_keypoints;
use revisit_matching::{anchor_keypoints, verify, RollSearch, VerifyOptions};
use revisit_places::{nearest, CandidateOptions, GlobalDescriptor, OnnxPlaces, Vlad, Vocabulary};
use revisit_store::{CrossKey, CrossSide, PairRecord, Store};
use serde::Serialize;

use crate::learned::Learned;
use crate::{LearnedKeypoints, PipelineError, Progress, StageCounts};

/// One visit's images in time order, with their store ids and files.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Visit {
    pub name: String,
    pub images: Vec<(ImageId, PathBuf)>,
}

/// Builds the visits of `sessions` (in the given order) from the store's ids.
pub fn visits(sessions: &[crate::ingest::SessionImages], image_ids: &BTreeMap<String, ImageId>) -> Vec<Visit> {
    sessions
        .iter()
        .map(|s| Visit {
            name: s.name.clone(),
            images: s
                .files
                .iter()
                .filter_map(|f| image_ids.get(&revisit_core::image_name(&s.name, f)).map(|&id| (id, s.dir.join(f))))
                .collect(),
        })
        .collect()
}

/// Which pairs the learned matcher sees.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum LearnedPairs {
    /// Every pair of images, within and across visits.
    All,
    /// Every pair of images from different visits.
    Cross,
    /// The place-recognition candidates of each image of a later visit.
    Places,
}

/// Where global descriptors come from.
#[derive(Clone, Debug, PartialEq)]
pub enum PlaceSource {
    /// VLAD over the learned descriptors, with a vocabulary of `clusters`
    /// centres learned from the survey (stored; later visits reuse it).
    Vlad { clusters: usize },
    /// A user's ONNX model (image -> L2-normalised vector).
    Onnx(PathBuf),
}

/// Options of the cross-visit stages.
#[derive(Clone, Debug, PartialEq)]
pub struct CrossOptions {
    pub roll_search: RollSearch,
    pub places: PlaceSource,
    pub candidates: CandidateOptions,
    /// A learned keypoint within this distance of an own (SIFT) keypoint is
    /// matched as that keypoint (see `revisit_matching::anchor_keypoints`).
    pub anchor_radius_px: f32,
    /// Verification of learned pairs. Cross-visit pairs are rarer and their
    /// chance inliers more plentiful than within a visit: the default asks for
    /// 30 inliers, twice COLMAP's 15.
    pub verify: VerifyOptions,
    /// A cross-visit pair is kept only if its roll's inliers are at least this
    /// many times the runner-up roll's (see `CrossMatch::roll_is_clear`).
    pub roll_margin: f32,
}

impl Default for CrossOptions {
    fn default() -> Self {
        CrossOptions {
            roll_search: RollSearch::DEFAULT,
            places: PlaceSource::Vlad { clusters: 64 },
            candidates: CandidateOptions::default(),
            anchor_radius_px: 1.5,
            verify: VerifyOptions { min_inliers: CROSS_MIN_INLIERS, ..VerifyOptions::default() },
            roll_margin: 1.5,
        }
    }
}

/// Fewest verified inliers of a learned pair, by default.
pub const CROSS_MIN_INLIERS: usize = 30;

/// The rolls each image needs: roll 0 for the first visit, every roll the
/// search tries for later ones.
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
    visits: &[Visit],
    search: RollSearch,
    stored: impl Fn(ImageId, Roll) -> bool,
) -> (Vec<MissingRolls<'_>>, StageCounts) {
    let mut todo = Vec::new();
    let mut total = 0;
    for (v, visit) in visits.iter().enumerate() {
        for (id, path) in &visit.images {
            let rolls = rolls_of(v, search);
            total += rolls.len();
            let missing: Vec<Roll> = rolls.iter().copied().filter(|r| !stored(*id, *r)).collect();
            if !missing.is_empty() {
                todo.push((*id, path.as_path(), missing));
            }
        }
    }
    let done: usize = todo.iter().map(|t| t.2.len()).sum();
    (todo, StageCounts { done, reused: total - done })
}

fn load_rgb(path: &Path) -> Result<image::RgbImage, PipelineError> {
    Ok(image::open(path)
        .map_err(|e| PipelineError::BadImage { path: path.to_path_buf(), reason: e.to_string() })?
        .to_rgb8())
}

fn onnx_error(path: &Path, error: revisit_onnx::OnnxError) -> PipelineError {
    PipelineError::Features { path: path.to_path_buf(), reason: error.to_string() }
}

/// Learned features of every image at the rolls it needs that the store lacks.
pub fn extract_learned(
    store: &mut Store,
    learned: &mut Learned,
    visits: &[Visit],
    search: RollSearch,
    progress: &dyn Progress,
) -> Result<StageCounts, PipelineError> {
    let method = learned.method.name();
    let stored = store.learned_feature_keys(method)?;
    let (todo, counts) = missing_rolls(visits, search, |id, roll| stored.contains(&(id, roll.degrees())));
    tracing::info!(new = counts.done, reused = counts.reused, method, "learned features");
    progress.start("learned features", counts.done as u64);
    for (id, path, rolls) in todo {
        let image = load_rgb(path)?;
        for roll in rolls {
            let features = learned.extract(&image, roll).map_err(|e| onnx_error(path, e))?;
            store.write_learned_features(id, method, roll.degrees(), &features)?;
            progress.advance();
        }
    }
    progress.finish();
    Ok(counts)
}

/// Registers every image's roll-0 learned keypoints in its keypoint list
/// (where not done yet) and returns them, for matching within visits
/// alongside SIFT (see [`crate::match_pairs`]).
pub fn register_learned_keypoints(
    store: &mut Store,
    method: &str,
    visits: &[Visit],
) -> Result<LearnedKeypoints, PipelineError> {
    let mut out = LearnedKeypoints { method: method.to_owned(), images: Default::default() };
    for (id, _) in visits.iter().flat_map(|v| &v.images) {
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
pub fn describe_places(
    store: &mut Store,
    learned_method: &str,
    source: &PlaceSource,
    runtime: &revisit_onnx::Runtime,
    visits: &[Visit],
    search: RollSearch,
    progress: &dyn Progress,
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
                    let vocabulary = train_vocabulary(store, learned_method, visits, *clusters)?;
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
    let (todo, counts) = missing_rolls(visits, search, |id, roll| descriptors.contains_key(&(id, roll.degrees())));
    tracing::info!(new = counts.done, reused = counts.reused, name, "place descriptors");
    progress.start("place descriptors", counts.done as u64);
    for (id, path, rolls) in todo {
        let image = match describer {
            Describer::Onnx(_) => Some(load_rgb(path)?),
            Describer::Vlad(_) => None,
        };
        for roll in rolls {
            let descriptor = match (&mut describer, &image) {
                (Describer::Vlad(vlad), _) => {
                    vlad.describe(&store.read_learned_features(id, learned_method, roll.degrees())?.descriptors)
                }
                (Describer::Onnx(model), Some(image)) => {
                    model.describe(image, roll).map_err(|e| onnx_error(path, e))?
                }
                (Describer::Onnx(_), None) => unreachable!("images are loaded for ONNX descriptors"),
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
    visits: &[Visit],
    clusters: usize,
) -> Result<Vocabulary, PipelineError> {
    const PER_IMAGE: usize = 64;
    let mut samples = Vec::new();
    let mut dim = 0;
    for (id, _) in visits.iter().flat_map(|v| &v.images) {
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
    pub cross: bool,
}

/// The pairs the learned matcher sees. For [`LearnedPairs::Places`], `places`
/// must hold every image's descriptors.
pub fn plan_learned_pairs(
    which: LearnedPairs,
    visits: &[Visit],
    places: Option<&Places>,
    candidates: &CandidateOptions,
) -> Vec<LearnedPair> {
    let mut pairs = BTreeSet::new();
    let ids: Vec<Vec<ImageId>> = visits.iter().map(|v| v.images.iter().map(|i| i.0).collect()).collect();
    for (v, later) in ids.iter().enumerate() {
        let earlier: Vec<ImageId> = ids[..v].iter().flatten().copied().collect();
        match which {
            LearnedPairs::All | LearnedPairs::Cross => {
                for &b in later {
                    pairs.extend(earlier.iter().map(|&a| LearnedPair { image_id1: a, image_id2: b, cross: true }));
                }
                if which == LearnedPairs::All {
                    for (i, &a) in later.iter().enumerate() {
                        pairs.extend(later[i + 1..].iter().map(|&b| LearnedPair {
                            image_id1: a,
                            image_id2: b,
                            cross: false,
                        }));
                    }
                }
            }
            LearnedPairs::Places => {
                let Some(places) = places else { continue };
                let database: Vec<&[f32]> =
                    earlier.iter().filter_map(|a| places.descriptors.get(&(*a, 0)).map(Vec::as_slice)).collect();
                if database.len() != earlier.len() {
                    continue;
                }
                for &b in later {
                    let query: Vec<(Roll, &[f32])> = Roll::ALL
                        .iter()
                        .filter_map(|r| places.descriptors.get(&(b, r.degrees())).map(|d| (*r, d.as_slice())))
                        .collect();
                    for candidate in nearest(&query, &database, candidates) {
                        pairs.insert(LearnedPair { image_id1: earlier[candidate.index], image_id2: b, cross: true });
                    }
                }
            }
        }
    }
    pairs.into_iter().collect()
}

/// Matches every planned pair not yet in the store with the learned matcher
/// (roll search on cross-visit pairs), anchors, verifies and stores it.
pub fn match_learned_pairs(
    store: &mut Store,
    learned: &mut Learned,
    pairs: &[LearnedPair],
    options: &CrossOptions,
    progress: &dyn Progress,
) -> Result<StageCounts, PipelineError> {
    let finished = store.matched_pairs()?;
    let todo: Vec<&LearnedPair> =
        pairs.iter().filter(|p| !finished.contains(&pair_id(p.image_id1, p.image_id2))).collect();
    let counts = StageCounts { done: todo.len(), reused: pairs.len() - todo.len() };
    let method = learned.method.name();
    tracing::info!(new = counts.done, reused = counts.reused, method, "learned matching");
    progress.start("learned matching", todo.len() as u64);
    for pair in todo {
        let search = if pair.cross { options.roll_search } else { RollSearch::Off };
        let a = store.read_learned_features(pair.image_id1, method, 0)?;
        let b_by_roll: Vec<(Roll, LearnedFeatures)> = search
            .rolls()
            .iter()
            .map(|r| Ok((*r, store.read_learned_features(pair.image_id2, method, r.degrees())?)))
            .collect::<Result<_, PipelineError>>()?;
        let found = learned
            .match_pair(&a, &b_by_roll, search, &options.verify)
            .map_err(|e| PipelineError::Matching { pair: (pair.image_id1, pair.image_id2), reason: e.to_string() })?;
        let b = b_by_roll.iter().find(|(r, _)| *r == found.roll).map(|(_, f)| f).unwrap_or(&b_by_roll[0].1);
        let positions_a: Vec<[f32; 2]> = a.keypoints.clone();
        let positions_b: Vec<[f32; 2]> = unrolled_keypoints(b, found.roll).iter().map(|k| [k.x, k.y]).collect();
        // Every keypoint an image holds: SIFT and its registered learned ones.
        let own_a = store.read_keypoints(pair.image_id1)?;
        let own_b = store.read_keypoints(pair.image_id2)?;
        let anchors_a = anchor_keypoints(&own_a, &positions_a, options.anchor_radius_px);
        let anchors_b = anchor_keypoints(&own_b, &positions_b, options.anchor_radius_px);
        let key = |anchors: &[Option<u32>], l: u32| anchors[l as usize].map_or(CrossKey::Learned(l), CrossKey::Own);
        // One match per keypoint on each side, once anchored.
        let (mut used_a, mut used_b) = (HashSet::new(), HashSet::new());
        let matches: Vec<[CrossKey; 2]> = found
            .matches
            .iter()
            .map(|&[i, j]| [key(&anchors_a, i), key(&anchors_b, j)])
            .filter(|[ka, kb]| used_a.insert(*ka) && used_b.insert(*kb))
            .collect();
        let position = |key: CrossKey, own: &[revisit_core::Keypoint], learned: &[[f32; 2]]| match key {
            CrossKey::Own(i) => own[i as usize],
            CrossKey::Learned(l) => {
                let [x, y] = learned[l as usize];
                revisit_core::Keypoint { x, y, scale: 1.0, orientation: 0.0 }
            }
        };
        let points_a: Vec<_> = matches.iter().map(|m| position(m[0], &own_a, &positions_a)).collect();
        let points_b: Vec<_> = matches.iter().map(|m| position(m[1], &own_b, &positions_b)).collect();
        let identity: Vec<[u32; 2]> = (0..matches.len() as u32).map(|k| [k, k]).collect();
        let geometry = if found.roll_is_clear(options.roll_margin) {
            verify(&points_a, &points_b, &identity, &options.verify)
        } else {
            TwoViewGeometry::degenerate()
        };
        let inliers: Vec<[CrossKey; 2]> = geometry.inlier_matches.iter().map(|m| matches[m[0] as usize]).collect();
        let record = PairRecord {
            image_id1: pair.image_id1,
            image_id2: pair.image_id2,
            kind: if pair.cross { "cross" } else { "intra" }.to_owned(),
            method: method.to_owned(),
            roll_deg: found.roll.degrees() as i32,
            num_matches: matches.len(),
            num_inliers: inliers.len(),
        };
        let sides = [
            CrossSide { image_id: pair.image_id1, method, roll_deg: 0, positions: &positions_a },
            CrossSide { image_id: pair.image_id2, method, roll_deg: found.roll.degrees(), positions: &positions_b },
        ];
        store.write_cross_pair(&record, sides, &matches, &inliers, &geometry)?;
        progress.advance();
    }
    progress.finish();
    Ok(counts)
}
