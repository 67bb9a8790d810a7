//! `revisit bench matching`: the cross-visit strategies side by side on one
//! synthetic dataset with exact truth, each through the pipeline's
//! `Workspace` (what `revisit reconstruct` runs), plus place-recognition
//! recall, roll-search agreement and cost, and learned extraction speed.
//!
//! Every strategy gets its own work folder (nothing is shared between them,
//! so each pays its whole matching cost). The published figures beside them:
//! for 2.5k images, exhaustive learned matching took 57.1 h, cross-visit-only
//! 15.8 h and VPR-guided 2.5 h (4.4%), with 6.33 px against 3.65 px.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{ensure, Context, Result};
use revisit_core::{session_of, ImageId, PairKind, Roll};
use revisit_eval::{median_epipolar_error_px, MAX_RIGHT_PAIR_ERROR_PX};
use revisit_matching::roll::unrolled_keypoints;
use revisit_matching::{CrossOptions, RollSearch};
use revisit_pipeline::ingest::{scan_session, SessionSpec};
use revisit_pipeline::learned::LearnedMethod;
use revisit_pipeline::options::{PlaceSource, ReconstructOptions};
use revisit_pipeline::{CrossStrategy, Report, Workspace};
use revisit_places::{nearest, CandidateOptions};
use revisit_store::Store;
use serde::Serialize;

use crate::commands::models::{cross_strategies, ToolArgs};
use crate::progress::Bars;

/// Image pairs of different visits overlapping at least this much (truth's
/// `overlaps.csv`) count as places a query should find.
const MIN_PLACE_OVERLAP: f64 = 0.3;
/// The goal: `vpr` at most this share of `learned-all`'s matching time.
const MAX_VPR_TIME_SHARE: f64 = 0.10;
/// The goal: roll search at most this many times the cost of one match.
const MAX_ROLL_COST: f64 = 1.3;
/// The goal: the roll chosen is the full search's on this share of the pairs it verifies.
const MIN_ROLL_AGREEMENT: f64 = 0.95;
/// A mapped pair this far off its epipolar lines (median, pixels) shows another place.
const FAR_WRONG_PAIR_ERROR_PX: f64 = 20.0;

#[derive(clap::Args)]
pub struct Args {
    /// A dataset made by `revisit synth`: sessions/NAME/*.png and truth/.
    #[arg(long, value_name = "DIR", required_unless_present = "scale")]
    dataset: Option<PathBuf>,
    /// Work folder: one reconstruction per strategy in WORK/STRATEGY
    /// (default: DATASET/bench; with --scale, bench-scaling). Re-running
    /// reuses what is there.
    #[arg(long, value_name = "WORK")]
    pub(super) work: Option<PathBuf>,
    /// The scaling study instead of one dataset: a synthetic survey of 3
    /// visits x N images at strong change (seed 0) for each N, made in
    /// WORK/N/reef; each strategy run on it, or estimated from a random
    /// sample of its pairs when its learned matching would take longer than
    /// --budget-minutes. Writes WORK/scaling.json and WORK/scaling.png
    /// (matching time against images, log-log). Run again, it keeps the rows
    /// it measured; a strategy it did not finish is run again from the start.
    #[arg(long, value_delimiter = ',', value_name = "N,...", conflicts_with = "dataset")]
    pub(super) scale: Vec<usize>,
    /// The scaling study: a strategy whose learned matching would take longer
    /// than this is estimated, not run.
    #[arg(long, default_value_t = 60.0, value_name = "MINUTES")]
    pub(super) budget_minutes: f64,
    /// The scaling study: pairs timed for a strategy's estimate (and to
    /// decide whether it fits the budget).
    #[arg(long, default_value_t = 16, value_name = "N")]
    pub(super) sample_pairs: usize,
    /// The strategies, in the order they run.
    #[arg(long, value_delimiter = ',', default_value = "sift,learned-all,learned-cross,vpr", value_parser = cross_strategies())]
    pub(super) strategies: Vec<CrossStrategy>,
    /// SIFT features per image (all strategies).
    #[arg(long, default_value_t = 1024, value_name = "N")]
    pub(super) max_features: usize,
    /// Place-recognition candidates per query image (`vpr`).
    #[arg(long, default_value_t = 5, value_name = "N")]
    pub(super) vpr_top_k: usize,
    /// Images timed for learned extraction (ALIKED and XFeat).
    #[arg(long, default_value_t = 10, value_name = "N")]
    extraction_images: usize,
    /// Write every figure as JSON here too.
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
    #[command(flatten)]
    pub(super) tools: ToolArgs,
}

#[derive(Serialize)]
pub(super) struct StrategyFigures {
    pub(super) strategy: String,
    /// SIFT matching + place recognition + learned matching (learned
    /// extraction apart, in `learned_features_secs`).
    pub(super) matching_secs: f64,
    pub(super) learned_features_secs: f64,
    pub(super) pairs_matched: usize,
    cross_pairs_matched: usize,
    pub(super) cross_pairs_verified: usize,
    /// Verified cross-visit pairs set aside by the consistency check.
    cross_pairs_set_aside: usize,
    /// Verified cross-visit pairs COLMAP maps with, and how many of them are
    /// wrong by the truth (median epipolar error over 4 px; over 20 px).
    cross_pairs_mapped: usize,
    wrong_cross_pairs_mapped: usize,
    far_wrong_cross_pairs_mapped: usize,
    cross_inliers: usize,
    sessions: usize,
    pub(super) sessions_in_chosen_model: usize,
    models: usize,
    pub(super) median_cross_error_px: Option<f64>,
    clicks_scored: usize,
}

#[derive(Serialize)]
struct PlaceFigures {
    queries: usize,
    recall_at: BTreeMap<usize, f64>,
    /// Cross-visit pairs sent to the learned matcher, of all cross-visit pairs.
    cross_pairs_sent_share: f64,
}

#[derive(Serialize)]
struct RollFigures {
    pairs: usize,
    /// Pairs the full search verifies (a roll to agree on).
    verified_by_full: usize,
    /// Of those, the ones right by the truth (median epipolar error at most
    /// [`MAX_RIGHT_PAIR_ERROR_PX`]).
    right_verified_by_full: usize,
    /// The pairs the `vpr` run (the default roll choice: predicted from the
    /// visits' verified pairs) verified, right by the truth, predicted.
    verified_by_default: usize,
    right_verified_by_default: usize,
    predicted_by_default: usize,
    /// The default's roll is the full search's: share of the pairs the full
    /// search verifies, and of those both verify.
    default_same_roll_share_of_verified: f64,
    default_same_roll_share_of_both: f64,
    /// The `vpr` run's learned matching time per cross-visit pair (stored,
    /// verified and checked: the whole cost).
    default_secs: f64,
    /// The `vpr` run's learned matcher runs per cross-visit pair (1 = one match a pair).
    default_runs_per_pair: f64,
    same_roll_share_of_verified: f64,
    same_roll_share_of_all: f64,
    probe_fell_back: usize,
    /// The roll whose place descriptor is nearest (what place recognition
    /// predicts) is the full search's roll: share of the pairs it verifies.
    place_roll_share_of_verified: f64,
    /// The search of a pair without a prediction (from place recognition's
    /// roll, stopped at a clear winner): the full search's roll on this share
    /// of the pairs the full search verifies, and verified too; its matcher
    /// runs per pair.
    ranked_same_roll_share_of_verified: f64,
    ranked_verified_share_of_verified: f64,
    ranked_runs_per_pair: f64,
    one_match_secs: f64,
    full_search_secs: f64,
    probe_search_secs: f64,
    ranked_search_secs: f64,
}

#[derive(Serialize)]
struct ExtractionFigures {
    method: &'static str,
    images: usize,
    secs_per_image: f64,
    target_secs: f64,
}

#[derive(Serialize)]
struct Figures {
    dataset: PathBuf,
    strategies: Vec<StrategyFigures>,
    places: Option<PlaceFigures>,
    roll_search: Option<RollFigures>,
    extraction: Vec<ExtractionFigures>,
}

pub fn run(args: Args) -> Result<()> {
    let Some(dataset) = args.dataset.clone() else { return super::scaling::run(&args) };
    let sessions_dir = dataset.join("sessions");
    let truth_dir = dataset.join("truth");
    let work = args.work.clone().unwrap_or_else(|| dataset.join("bench"));

    let mut figures = Figures {
        dataset: dataset.clone(),
        strategies: Vec::new(),
        places: None,
        roll_search: None,
        extraction: Vec::new(),
    };
    let session_names = super::session_names(&dataset)?;
    let cancel = crate::signals::cancel_on_signals()?;
    for &strategy in &args.strategies {
        let name = strategy.name();
        let out = work.join(name);
        let (report, figures_of_run) = run_strategy(&args, strategy, &dataset, &out, &cancel)?;
        figures.strategies.push(figures_of_run);
        if strategy == CrossStrategy::Vpr {
            figures.places = Some(place_figures(&report, &out, &truth_dir)?);
            figures.roll_search = Some(roll_figures(&report, &out, &truth_dir, &args.tools)?);
        }
    }
    figures.extraction = extraction_figures(&sessions_dir, &session_names, args.extraction_images, &args.tools)?;

    print_figures(&figures);
    super::write_json(args.json.as_deref(), &figures)
}

/// One strategy's reconstruction of `dataset` in `out`, as `revisit
/// reconstruct` would run it with the bench's options, and its figures.
pub(super) fn run_strategy(
    args: &Args,
    strategy: CrossStrategy,
    dataset: &Path,
    out: &Path,
    cancel: &revisit_pipeline::Cancel,
) -> Result<(Report, StrategyFigures)> {
    let name = strategy.name();
    let truth_dir = dataset.join("truth");
    let mut options = ReconstructOptions { cross: strategy, ..ReconstructOptions::default() };
    options.features.sift.max_num_features = args.max_features;
    options.places.candidates.top_k = args.vpr_top_k;
    if let Some(camera) = super::calibrated_camera(&truth_dir)? {
        options.cameras.calibrated.insert(String::new(), camera);
    }
    println!("== {name}");
    let mut workspace = Workspace::open(out, options, args.tools.tools())?;
    for session in super::session_names(dataset)? {
        let spec = SessionSpec { dir: dataset.join("sessions").join(&session), name: session };
        workspace.add_session(scan_session(&spec)?)?;
    }
    let report = workspace.run(&Bars::default(), cancel).with_context(|| format!("strategy {name}"))?;
    let figures = strategy_figures(name, &report, out, &truth_dir)?;
    Ok((report, figures))
}

fn strategy_figures(name: &str, report: &Report, out: &Path, truth: &Path) -> Result<StrategyFigures> {
    let secs = |stage: &str| report.seconds.get(stage).copied().unwrap_or(0.0);
    let store = Store::open_read_only(&out.join("database.db"))?;
    let records = store.pair_records()?;
    let cross: Vec<_> = records.iter().filter(|r| r.kind == PairKind::Cross).collect();
    let (median, scored) = match &report.chosen_model {
        Some(model) => cross_error(model, truth)?,
        None => (None, 0),
    };
    let errors = mapped_pair_errors(&store, &TruthPairs::open(&store, truth)?)?;
    let wrong_over = |px: f64| errors.iter().filter(|e| **e > px).count();
    Ok(StrategyFigures {
        strategy: name.to_owned(),
        matching_secs: secs("matching") + secs("places") + secs("learned_matching"),
        learned_features_secs: secs("learned_features"),
        pairs_matched: records.len(),
        cross_pairs_matched: cross.len(),
        cross_pairs_verified: cross.iter().filter(|r| r.num_inliers > 0).count(),
        cross_pairs_set_aside: store.set_aside_pairs()?.len(),
        cross_pairs_mapped: errors.len(),
        wrong_cross_pairs_mapped: wrong_over(MAX_RIGHT_PAIR_ERROR_PX),
        far_wrong_cross_pairs_mapped: wrong_over(FAR_WRONG_PAIR_ERROR_PX),
        cross_inliers: cross.iter().map(|r| r.num_inliers).sum(),
        sessions: report.sessions.len(),
        // A visit reported unlinked is not in the model, whatever stray image of it is.
        sessions_in_chosen_model: report
            .sessions
            .iter()
            .filter(|(name, s)| s.registered > 0 && !report.unlinked_sessions.contains(*name))
            .count(),
        models: report.models,
        median_cross_error_px: median,
        clicks_scored: scored,
    })
}

/// The median epipolar error under the true poses (`truth/`, a COLMAP text
/// model) of the inliers of every cross-visit pair COLMAP maps with.
fn mapped_pair_errors(store: &Store, truth: &TruthPairs) -> Result<Vec<f64>> {
    let mut errors = Vec::new();
    for record in store.pair_records()?.iter().filter(|r| r.kind == PairKind::Cross && r.num_inliers > 0) {
        let (a, b) = (record.image_id1, record.image_id2);
        let Some((_, inliers)) = store.two_view_geometry(revisit_core::pair_id(a, b))? else { continue };
        let (keypoints1, keypoints2) = (store.read_keypoints(a)?, store.read_keypoints(b)?);
        let points: Vec<([f64; 2], [f64; 2])> = inliers
            .iter()
            .filter_map(|&[i, j]| Some((keypoints1.get(i as usize)?, keypoints2.get(j as usize)?)))
            .map(|(p, q)| ([f64::from(p.x), f64::from(p.y)], [f64::from(q.x), f64::from(q.y)]))
            .collect();
        if let Some(error) = truth.error_px(a, b, &points)? {
            errors.push(error);
        }
    }
    Ok(errors)
}

/// The truth's poses and cameras by the store's image ids: how far a pair's
/// matches lie from their true epipolar lines.
struct TruthPairs {
    model: revisit_core::Reconstruction,
    names: BTreeMap<ImageId, String>,
    dir: PathBuf,
}

impl TruthPairs {
    fn open(store: &Store, truth: &Path) -> Result<TruthPairs> {
        let model = revisit_colmap::read_model(truth)?;
        let names = store.image_ids()?.into_iter().map(|(name, id)| (id, name)).collect();
        Ok(TruthPairs { model, names, dir: truth.to_path_buf() })
    }

    /// The median epipolar error (pixels of image `b`) of `points` (pixels of `a`, of `b`).
    fn error_px(&self, a: ImageId, b: ImageId, points: &[([f64; 2], [f64; 2])]) -> Result<Option<f64>> {
        let image = |id: ImageId| {
            let name = self.names.get(&id).with_context(|| format!("image {id} has no name"))?;
            let image = self.model.image_by_name(name).with_context(|| format!("{}: no {name}", self.dir.display()))?;
            let camera = self.model.cameras.get(&image.camera_id).context("truth: an image without its camera")?;
            anyhow::Ok((image, camera))
        };
        let ((image1, camera1), (image2, camera2)) = (image(a)?, image(b)?);
        Ok(median_epipolar_error_px([camera1, camera2], &image1.cam_from_world, &image2.cam_from_world, points))
    }
}

/// Median cross-session reprojection error of `model` over every click file
/// of the truth, and the clicks scored.
fn cross_error(model: &Path, truth: &Path) -> Result<(Option<f64>, usize)> {
    let model = revisit_colmap::read_model(model)?;
    let summary = super::score_clicks(&model, &super::truth_clicks(truth)?);
    Ok((summary.median_px, summary.scored))
}

/// Truth overlaps between images of different sessions, by image name.
fn read_overlaps(truth: &Path) -> Result<Vec<(String, String, f64)>> {
    let path = truth.join("overlaps.csv");
    let mut reader = csv::Reader::from_path(&path).with_context(|| path.display().to_string())?;
    reader
        .deserialize::<(String, String, f64)>()
        .enumerate()
        .map(|(k, row)| row.with_context(|| format!("{}: row {}: expected img0,img1,overlap", path.display(), k + 2)))
        .collect()
}

/// The place descriptors the default options make (VLAD over the default
/// learned features) that the store of `out` holds, by (image, roll degrees).
fn default_place_descriptors(store: &Store, out: &Path) -> Result<BTreeMap<(ImageId, u32), Vec<f32>>> {
    let PlaceSource::Vlad { clusters } = PlaceSource::default() else { anyhow::bail!("the default places are VLAD") };
    let name = format!("vlad{clusters}-{}", LearnedMethod::default().name());
    let descriptors = store.global_descriptors(&name)?;
    ensure!(!descriptors.is_empty(), "{}: no {name} descriptors", out.display());
    Ok(descriptors)
}

/// Recall@k of the place candidates against the truth: a query (an image of
/// a later visit with at least one truly overlapping image in earlier
/// visits) is found at k if one of its k nearest is such an image.
fn place_figures(report: &Report, out: &Path, truth: &Path) -> Result<PlaceFigures> {
    let store = Store::open_read_only(&out.join("database.db"))?;
    let ids = store.image_ids()?;
    let names: BTreeMap<ImageId, &String> = ids.iter().map(|(n, id)| (*id, n)).collect();
    let sessions: Vec<String> = store.sessions()?.into_iter().map(|s| s.name).collect();
    let descriptors = default_place_descriptors(&store, out)?;
    let mut truly: BTreeSet<(String, String)> = BTreeSet::new();
    for (a, b, overlap) in read_overlaps(truth)? {
        if overlap >= MIN_PLACE_OVERLAP {
            truly.insert((a.clone(), b.clone()));
            truly.insert((b, a));
        }
    }
    let visit = |name: &str| sessions.iter().position(|s| s == session_of(name)).unwrap_or(usize::MAX);
    let ks = [1, 5, 10];
    let mut found = BTreeMap::<usize, usize>::new();
    let mut queries = 0;
    for (&query, query_name) in &names {
        let v = visit(query_name);
        if v == 0 || v == usize::MAX {
            continue;
        }
        let earlier: Vec<ImageId> = names.iter().filter(|(_, n)| visit(n) < v).map(|(id, _)| *id).collect();
        if !earlier.iter().any(|id| truly.contains(&((*query_name).clone(), names[id].clone()))) {
            continue;
        }
        queries += 1;
        let database: Vec<&[f32]> =
            earlier.iter().filter_map(|id| descriptors.get(&(*id, 0)).map(Vec::as_slice)).collect();
        let by_roll: Vec<(Roll, &[f32])> = Roll::ALL
            .iter()
            .filter_map(|r| descriptors.get(&(query, r.degrees())).map(|d| (*r, d.as_slice())))
            .collect();
        let ranked = nearest(&by_roll, &database, &CandidateOptions { top_k: 10, max_distance: None });
        for k in ks {
            let hit = ranked
                .iter()
                .take(k)
                .any(|c| truly.contains(&((*query_name).clone(), names[&earlier[c.index]].clone())));
            *found.entry(k).or_default() += usize::from(hit);
        }
    }
    let counts: Vec<usize> = sessions.iter().map(|s| report.sessions.get(s).map_or(0, |s| s.images)).collect();
    let all_cross: usize = (0..counts.len())
        .flat_map(|i| (i + 1..counts.len()).map(move |j| (i, j)))
        .map(|(i, j)| counts[i] * counts[j])
        .sum();
    let sent = report.pairs_of(PairKind::Cross).tried as f64;
    Ok(PlaceFigures {
        queries,
        recall_at: ks
            .iter()
            .map(|&k| (k, found.get(&k).copied().unwrap_or(0) as f64 / queries.max(1) as f64))
            .collect(),
        cross_pairs_sent_share: sent / all_cross.max(1) as f64,
    })
}

/// The `vpr` run's rolls (the default: predicted) and the probe against the
/// full roll search on its cross-visit pairs, with the features it stored;
/// which verified pairs are right, by the truth.
fn roll_figures(report: &Report, out: &Path, truth: &Path, tools: &ToolArgs) -> Result<RollFigures> {
    let method = LearnedMethod::default();
    let (_, mut learned) = tools.open(method)?;
    let store = Store::open_read_only(&out.join("database.db"))?;
    let truth = TruthPairs::open(&store, truth)?;
    let pairs: Vec<_> = store.pair_records()?.into_iter().filter(|r| r.kind == PairKind::Cross).collect();
    let options = CrossOptions::default();
    let margin = options.roll_margin;
    let default_errors = mapped_pair_errors(&store, &truth)?;
    let mut figures = RollFigures {
        pairs: pairs.len(),
        verified_by_full: 0,
        right_verified_by_full: 0,
        verified_by_default: pairs.iter().filter(|r| r.num_inliers > 0).count(),
        right_verified_by_default: default_errors.iter().filter(|e| **e <= MAX_RIGHT_PAIR_ERROR_PX).count(),
        predicted_by_default: pairs.iter().filter(|r| r.predicted_roll_deg.is_some()).count(),
        default_same_roll_share_of_verified: 0.0,
        default_same_roll_share_of_both: 0.0,
        default_secs: report.seconds.get("learned_matching").copied().unwrap_or(0.0) / pairs.len().max(1) as f64,
        default_runs_per_pair: report.cross.learned_matching.and_then(|m| m.runs_per_pair()).unwrap_or(0.0),
        same_roll_share_of_verified: 0.0,
        same_roll_share_of_all: 0.0,
        probe_fell_back: 0,
        place_roll_share_of_verified: 0.0,
        ranked_same_roll_share_of_verified: 0.0,
        ranked_verified_share_of_verified: 0.0,
        ranked_runs_per_pair: 0.0,
        one_match_secs: 0.0,
        full_search_secs: 0.0,
        probe_search_secs: 0.0,
        ranked_search_secs: 0.0,
    };
    let places = default_place_descriptors(&store, out)?;
    let place_roll = |a: ImageId, b: ImageId| -> Option<Roll> {
        let database = [places.get(&(a, 0))?.as_slice()];
        let query: Vec<(Roll, &[f32])> =
            Roll::ALL.iter().filter_map(|r| Some((*r, places.get(&(b, r.degrees()))?.as_slice()))).collect();
        nearest(&query, &database, &CandidateOptions { top_k: 1, max_distance: None }).first().map(|c| c.roll)
    };
    let (mut same_verified, mut same_all, mut place_same) = (0, 0, 0);
    let (mut ranked_same, mut ranked_verified, mut ranked_runs) = (0, 0, 0);
    let (mut default_same, mut both, mut default_same_both) = (0, 0, 0);
    let bar = crate::progress::bar(pairs.len() as u64, "roll search: default and probe vs full");
    for pair in &pairs {
        let a = store.read_learned_features(pair.image_id1, method.name(), 0)?;
        let b_by_roll = Roll::ALL
            .iter()
            .map(|r| Ok((*r, store.read_learned_features(pair.image_id2, method.name(), r.degrees())?)))
            .collect::<Result<Vec<_>>>()?;
        let start = Instant::now();
        let full = learned.match_rolls(&a, &b_by_roll, (RollSearch::Full, None), &options)?;
        figures.full_search_secs += start.elapsed().as_secs_f64();
        let start = Instant::now();
        let probe = learned.match_rolls(&a, &b_by_roll, (RollSearch::PROBE, None), &options)?;
        figures.probe_search_secs += start.elapsed().as_secs_f64();
        let (start, runs_before) = (Instant::now(), learned.matcher.runs());
        let place = place_roll(pair.image_id1, pair.image_id2);
        let ranked = learned.match_rolls(&a, &b_by_roll, (RollSearch::Predict, place), &options)?;
        figures.ranked_search_secs += start.elapsed().as_secs_f64();
        ranked_runs += learned.matcher.runs() - runs_before;
        let start = Instant::now();
        let chosen = b_by_roll.iter().find(|(r, _)| *r == full.roll).map_or(&b_by_roll[0], |x| x);
        learned.match_rolls(&a, std::slice::from_ref(chosen), (RollSearch::Off, None), &options)?;
        figures.one_match_secs += start.elapsed().as_secs_f64();
        figures.probe_fell_back += usize::from(probe.fell_back);
        let agree = probe.roll == full.roll;
        same_all += usize::from(agree);
        if !full.geometry.inlier_matches.is_empty() && full.roll_is_clear(margin) {
            figures.verified_by_full += 1;
            same_verified += usize::from(agree);
            place_same += usize::from(place == Some(full.roll));
            ranked_same += usize::from(ranked.roll == full.roll);
            let ranked_verifies = !ranked.geometry.inlier_matches.is_empty() && ranked.roll_is_clear(margin);
            ranked_verified += usize::from(ranked_verifies && ranked.roll == full.roll);
            let default_agrees = i64::from(pair.roll_deg) == i64::from(full.roll.degrees());
            default_same += usize::from(default_agrees);
            if pair.num_inliers > 0 {
                both += 1;
                default_same_both += usize::from(default_agrees);
            }
            let (keypoints1, keypoints2) = (unrolled_keypoints(&a, Roll::R0), unrolled_keypoints(&chosen.1, full.roll));
            let points: Vec<([f64; 2], [f64; 2])> = full
                .geometry
                .inlier_matches
                .iter()
                .filter_map(|&[i, j]| Some((keypoints1.get(i as usize)?, keypoints2.get(j as usize)?)))
                .map(|(p, q)| ([f64::from(p.x), f64::from(p.y)], [f64::from(q.x), f64::from(q.y)]))
                .collect();
            let error = truth.error_px(pair.image_id1, pair.image_id2, &points)?;
            figures.right_verified_by_full += usize::from(error.is_some_and(|e| e <= MAX_RIGHT_PAIR_ERROR_PX));
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    let n = pairs.len().max(1) as f64;
    figures.same_roll_share_of_verified = same_verified as f64 / figures.verified_by_full.max(1) as f64;
    figures.default_same_roll_share_of_verified = default_same as f64 / figures.verified_by_full.max(1) as f64;
    figures.default_same_roll_share_of_both = default_same_both as f64 / both.max(1) as f64;
    figures.same_roll_share_of_all = same_all as f64 / n;
    figures.place_roll_share_of_verified = place_same as f64 / figures.verified_by_full.max(1) as f64;
    figures.ranked_same_roll_share_of_verified = ranked_same as f64 / figures.verified_by_full.max(1) as f64;
    figures.ranked_verified_share_of_verified = ranked_verified as f64 / figures.verified_by_full.max(1) as f64;
    figures.ranked_runs_per_pair = ranked_runs as f64 / n;
    figures.one_match_secs /= n;
    figures.full_search_secs /= n;
    figures.probe_search_secs /= n;
    figures.ranked_search_secs /= n;
    Ok(figures)
}

fn extraction_figures(
    sessions_dir: &Path,
    sessions: &[String],
    count: usize,
    tools: &ToolArgs,
) -> Result<Vec<ExtractionFigures>> {
    let mut images = Vec::new();
    for session in sessions {
        images.extend(session_images(&sessions_dir.join(session))?);
    }
    images.truncate(count.max(1));
    let decoded = images
        .iter()
        .map(|p| Ok(image::open(p).with_context(|| p.display().to_string())?.to_rgb8()))
        .collect::<Result<Vec<_>>>()?;
    let mut out = Vec::new();
    for (method, target_secs) in [(LearnedMethod::XfeatLighterglue, 0.2), (LearnedMethod::AlikedLightglue, 1.0)] {
        let (_, mut learned) = tools.open(method)?;
        // One warm-up run: ONNX Runtime plans its kernels on the first call.
        if let Some(first) = decoded.first() {
            learned.extract(first, Roll::R0)?;
        }
        let start = Instant::now();
        for image in &decoded {
            learned.extract(image, Roll::R0)?;
        }
        let secs_per_image = start.elapsed().as_secs_f64() / decoded.len().max(1) as f64;
        out.push(ExtractionFigures { method: method.name(), images: decoded.len(), secs_per_image, target_secs });
    }
    Ok(out)
}

fn print_figures(f: &Figures) {
    println!();
    println!(
        "{:<14} {:>10} {:>9} {:>8} {:>10} {:>8} {:>18} {:>10} {:>12} {:>10}",
        "strategy",
        "match s",
        "pairs",
        "cross",
        "verified",
        "aside",
        "mapped (wrong/far)",
        "inliers",
        "one model",
        "median px"
    );
    for s in &f.strategies {
        println!(
            "{:<14} {:>10.1} {:>9} {:>8} {:>10} {:>8} {:>18} {:>10} {:>12} {:>10}",
            s.strategy,
            s.matching_secs,
            s.pairs_matched,
            s.cross_pairs_matched,
            s.cross_pairs_verified,
            s.cross_pairs_set_aside,
            format!("{} ({}/{})", s.cross_pairs_mapped, s.wrong_cross_pairs_mapped, s.far_wrong_cross_pairs_mapped),
            s.cross_inliers,
            format!("{}/{}", s.sessions_in_chosen_model, s.sessions),
            s.median_cross_error_px.map_or("-".to_owned(), |m| format!("{m:.2}")),
        );
    }
    println!(
        "aside: verified cross-visit pairs the consistency check set aside; mapped (wrong/far): those COLMAP maps \
         with, and of them wrong by the truth (median epipolar error over {MAX_RIGHT_PAIR_ERROR_PX} px / over \
         {FAR_WRONG_PAIR_ERROR_PX} px)"
    );
    let secs = |name: &str| f.strategies.iter().find(|s| s.strategy == name).map(|s| s.matching_secs);
    if let (Some(vpr), Some(all)) = (secs("vpr"), secs("learned-all")) {
        println!(
            "vpr / learned-all matching time: {:.1}% (goal <= {:.0}%; published 4.4% at 2.5k images)",
            100.0 * vpr / all.max(1e-9),
            100.0 * MAX_VPR_TIME_SHARE
        );
    }
    if let Some(p) = &f.places {
        let recall: Vec<String> = p.recall_at.iter().map(|(k, r)| format!("R@{k} {:.1}%", 100.0 * r)).collect();
        println!(
            "place recognition: {} queries, {}; {:.1}% of cross-visit pairs sent to the matcher",
            p.queries,
            recall.join(", "),
            100.0 * p.cross_pairs_sent_share
        );
    }
    if let Some(r) = &f.roll_search {
        println!(
            "default roll (predicted on {} of {} pairs): the full search's roll on {:.1}% of the {} pairs it \
             verifies, {:.1}% of those both verify (goal >= {:.0}%); verified: default {} ({} right), full search \
             {} ({} right; right = median epipolar error <= {MAX_RIGHT_PAIR_ERROR_PX} px by the truth)",
            r.predicted_by_default,
            r.pairs,
            100.0 * r.default_same_roll_share_of_verified,
            r.verified_by_full,
            100.0 * r.default_same_roll_share_of_both,
            100.0 * MIN_ROLL_AGREEMENT,
            r.verified_by_default,
            r.right_verified_by_default,
            r.verified_by_full,
            r.right_verified_by_full
        );
        println!(
            "roll search on {} pairs: probe picks the full search's roll on {:.1}% of the {} it verifies (goal >= {:.0}%), {:.1}% of all; fell back {} times",
            r.pairs,
            100.0 * r.same_roll_share_of_verified,
            r.verified_by_full,
            100.0 * MIN_ROLL_AGREEMENT,
            100.0 * r.same_roll_share_of_all,
            r.probe_fell_back
        );
        println!(
            "place recognition's roll (nearest descriptor) is the full search's on {:.1}% of the pairs it verifies",
            100.0 * r.place_roll_share_of_verified
        );
        println!(
            "search without a prediction (from place recognition's roll, stopped at a clear winner): the full \
             search's roll on {:.1}% of the pairs it verifies, verified there on {:.1}%; {:.2} matcher runs a pair \
             against 4, {:.2} s ({:.2}x one match)",
            100.0 * r.ranked_same_roll_share_of_verified,
            100.0 * r.ranked_verified_share_of_verified,
            r.ranked_runs_per_pair,
            r.ranked_search_secs,
            r.ranked_search_secs / r.one_match_secs.max(1e-9)
        );
        println!(
            "roll search cost per pair: one match {:.2} s, full search {:.2} s ({:.2}x), probe {:.2} s ({:.2}x), \
             default {:.2} s ({:.2}x, the vpr run's whole learned matching a pair, {:.2} matcher runs; goal <= \
             {MAX_ROLL_COST}x)",
            r.one_match_secs,
            r.full_search_secs,
            r.full_search_secs / r.one_match_secs.max(1e-9),
            r.probe_search_secs,
            r.probe_search_secs / r.one_match_secs.max(1e-9),
            r.default_secs,
            r.default_secs / r.one_match_secs.max(1e-9),
            r.default_runs_per_pair
        );
    }
    for e in &f.extraction {
        println!(
            "{} extraction at the dataset's size: {:.3} s per image over {} images (goal < {} s on 2 cores)",
            e.method, e.secs_per_image, e.images, e.target_secs
        );
    }
}

/// A synthetic session folder's images (PNG or JPEG), in name order.
pub(super) fn session_images(dir: &Path) -> Result<Vec<PathBuf>> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| dir.display().to_string())?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "png" || e == "jpg"))
        .collect();
    files.sort();
    Ok(files)
}
