//! `revisit reconstruct`: sessions in, one joint COLMAP reconstruction out.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use revisit_colmap::{Engine, MapperOptions, PlyColors};
use revisit_core::{Camera, CameraModel};
use revisit_features::SiftOptions;
use revisit_matching::RollSearch;
use revisit_matching::{MatchOptions, PairOptions, VerifyOptions};
use revisit_pipeline::cross::{self, CrossOptions, LearnedPairs, PlaceSource};
use revisit_pipeline::export::{self, PairReport, SessionReport, REGISTERED_RULE};
use revisit_pipeline::ingest::{self, SessionImages, SessionSpec};
use revisit_pipeline::mapping::{self, MappingOutcome};
use revisit_pipeline::{CrossStrategy, StageCounts};
use revisit_places::CandidateOptions;
use revisit_store::Store;
use serde::Serialize;

use crate::commands::models::{LearnedArg, ModelArgs};
use crate::progress::Bars;

#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum CrossArg {
    /// Intra-session pairs only: visits are not linked.
    None,
    /// Every cross-session pair with SIFT: the classic joint baseline.
    Sift,
    /// The learned matcher on every pair, within and across sessions (slowest).
    LearnedAll,
    /// The learned matcher on every cross-session pair; SIFT within sessions.
    LearnedCross,
    /// The learned matcher on place-recognition candidates only; SIFT within sessions.
    Vpr,
}

impl CrossArg {
    /// The name on the command line.
    pub fn name(self) -> &'static str {
        match self {
            CrossArg::None => "none",
            CrossArg::Sift => "sift",
            CrossArg::LearnedAll => "learned-all",
            CrossArg::LearnedCross => "learned-cross",
            CrossArg::Vpr => "vpr",
        }
    }
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum RollSearchArg {
    /// Decide the roll on the 256 strongest keypoints per image, then match
    /// once in full (in full at every roll if no roll wins by --roll-margin).
    Probe,
    /// Match in full at every roll (4x the matching cost).
    Full,
    /// Roll 0 only: for visits flown at the same heading.
    Off,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum MapperArg {
    /// COLMAP's incremental SfM; extends the previous model when sessions are added.
    Incremental,
    /// GLOMAP's global SfM (rebuilds from scratch).
    Global,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum PlyColorsArg {
    /// The points' own colours.
    Rgb,
    /// One colour per session (the session of the first image seeing the point).
    Session,
}

/// A calibrated camera: MODEL:P1,P2,... in COLMAP's parameter order.
#[derive(Clone, Debug)]
struct CameraArg {
    model: CameraModel,
    params: Vec<f64>,
}

impl std::str::FromStr for CameraArg {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let (model, params) =
            s.split_once(':').ok_or_else(|| format!("{s:?} is not MODEL:P1,P2,... (e.g. PINHOLE:512,512,320,240)"))?;
        let model = CameraModel::from_name(model.trim()).map_err(|e| e.to_string())?;
        let params = params
            .split(',')
            .map(|p| p.trim().parse::<f64>().map_err(|_| format!("{p:?} in {s:?} is not a number")))
            .collect::<Result<Vec<_>, _>>()?;
        // Checks the parameter count for the model.
        Camera::new(0, model, 1, 1, params.clone()).map_err(|e| e.to_string())?;
        Ok(CameraArg { model, params })
    }
}

/// A rectangle in pixels: X,Y,W,H.
#[derive(Clone, Copy, Debug)]
struct Region([u32; 4]);

impl std::str::FromStr for Region {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let values: Vec<u32> = s
            .split(',')
            .map(|v| v.trim().parse::<u32>().map_err(|_| format!("{s:?} is not X,Y,W,H in whole pixels")))
            .collect::<Result<_, _>>()?;
        match values[..] {
            [x, y, w, h] if w > 0 && h > 0 => Ok(Region([x, y, w, h])),
            _ => Err(format!("{s:?} is not X,Y,W,H with a positive width and height")),
        }
    }
}

/// Reconstruct one or more sessions (visits of one site) jointly: SIFT features,
/// verified matching within and across sessions, and ONE COLMAP mapping run.
///
/// Outputs in WORK: database.db (the store, a COLMAP database), model/ (COLMAP
/// binary model; model/1, model/2, ... largest first if COLMAP made several),
/// points.ply, poses.csv (cam_from_world of the chosen model's images) and
/// report.json. Re-running the same command resumes: finished features, pairs
/// and an up-to-date model are reused, never recomputed.
#[derive(clap::Args)]
pub struct Args {
    /// A session (one visit) as NAME=DIR; DIR holds its images (.png, .jpg), whose
    /// sorted file names give the time order. Repeat for every visit.
    #[arg(long = "session", value_name = "NAME=DIR", required = true)]
    sessions: Vec<SessionSpec>,
    /// Work folder for the store and every output (created if missing).
    #[arg(long, value_name = "WORK")]
    out: PathBuf,
    /// How images of different sessions are paired and matched.
    #[arg(long, value_enum, default_value = "vpr")]
    cross: CrossArg,
    /// The learned matcher for cross-session pairs.
    #[arg(long, value_enum, default_value = "aliked-lightglue")]
    learned: LearnedArg,
    /// How the roll (0/90/180/270 degrees) of the second image of a
    /// cross-session pair is chosen.
    #[arg(long, value_enum, default_value = "probe")]
    roll_search: RollSearchArg,
    /// Place recognition: each image of a later session is paired with its N
    /// nearest images of earlier sessions.
    #[arg(long, default_value_t = 5, value_name = "N")]
    vpr_top_k: usize,
    /// Place recognition: only candidates closer than D (L2 distance between
    /// normalised global descriptors, 0..2).
    #[arg(long, value_name = "D")]
    vpr_max_distance: Option<f32>,
    /// Place recognition: a global-descriptor ONNX model (RGB image [1, 3, H, W]
    /// in 0..1 -> [1, D]), e.g. MegaLoc. Default: built-in VLAD over the
    /// learned features, with a vocabulary learned from the survey.
    #[arg(long, value_name = "ONNX")]
    vpr_model: Option<PathBuf>,
    /// A learned keypoint this close to a SIFT keypoint is matched as that
    /// SIFT keypoint, which links cross-session matches to each session's tracks.
    #[arg(long, default_value_t = 1.5, value_name = "PX")]
    anchor_radius: f32,
    /// Fewest verified inliers of a learned (cross-visit) pair.
    #[arg(long, default_value_t = cross::CROSS_MIN_INLIERS, value_name = "N")]
    cross_min_inliers: usize,
    /// Largest epipolar error of a learned (cross-visit) inlier, pixels.
    #[arg(long, default_value_t = 4.0, value_name = "PX")]
    cross_max_error: f64,
    /// A cross-visit pair is kept only if its roll's inliers are at least R
    /// times those of the runner-up roll (chance matches find about as many
    /// at every roll); a probe that no roll wins by R falls back to the full
    /// search. 1 turns the check off.
    #[arg(long, default_value_t = 1.5, value_name = "R")]
    roll_margin: f32,
    #[command(flatten)]
    models: ModelArgs,
    /// Largest number of SIFT features per image (the strongest are kept).
    #[arg(long, default_value_t = 4096, value_name = "N")]
    max_features: usize,
    /// Images whose larger side exceeds this are downscaled for extraction
    /// (keypoints are reported in full-resolution pixels).
    #[arg(long, default_value_t = 3200, value_name = "PX")]
    max_image_size: u32,
    /// A calibrated camera for every session, as MODEL:PARAMS in COLMAP's
    /// order (e.g. PINHOLE:fx,fy,cx,cy or OPENCV:fx,fy,cx,cy,k1,k2,p1,p2);
    /// its intrinsics are then held fixed. Default: estimated per session
    /// (self-calibration, weak for flat seabeds and few images).
    #[arg(long, value_name = "MODEL:PARAMS")]
    camera: Option<CameraArg>,
    /// Upright SIFT (no orientation): only for cameras that never roll.
    #[arg(long)]
    upright: bool,
    /// A region to ignore in every image, X,Y,W,H in pixels (e.g. a burned-in
    /// timestamp). Repeatable.
    #[arg(long = "ignore-region", value_name = "X,Y,W,H")]
    ignore_regions: Vec<Region>,
    /// Sessions of at most this many images are matched exhaustively; longer
    /// ones with a sequential window plus periodic loop candidates.
    #[arg(long, default_value_t = 100, value_name = "N")]
    exhaustive_max_images: usize,
    /// Long sessions: match each image with the next N.
    #[arg(long, default_value_t = 10, value_name = "N")]
    window: usize,
    /// Long sessions: every N-th image is also matched with every other N-th.
    #[arg(long, default_value_t = 5, value_name = "N")]
    loop_period: usize,
    /// The COLMAP mapper.
    #[arg(long, value_enum, default_value = "incremental")]
    mapper: MapperArg,
    /// Seed of every random choice (RANSAC, COLMAP).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Python with pycolmap (default: $REVISIT_PYTHON, else the checkout's .venv).
    #[arg(long, value_name = "PATH")]
    python: Option<PathBuf>,
    /// How points.ply is coloured.
    #[arg(long, value_enum, default_value = "rgb")]
    ply_colors: PlyColorsArg,
}

#[derive(Serialize)]
struct Report {
    sessions: BTreeMap<String, SessionReport>,
    models: usize,
    model_sizes: Vec<usize>,
    chosen_model: Option<PathBuf>,
    registered_rule: &'static str,
    pairs: BTreeMap<String, PairReport>,
    /// Sessions (of several) with fewer than half their images in the chosen
    /// model: they could not be linked to the others.
    unlinked_sessions: Vec<String>,
    /// Verified cross-session pairs by the roll of their second image (degrees).
    rolls: BTreeMap<u32, usize>,
    features: StageCounts,
    matching: StageCounts,
    cross: CrossReport,
    mapping: MappingReport,
    seconds: BTreeMap<&'static str, f64>,
}

#[derive(Default, Serialize)]
struct CrossReport {
    learned_features: StageCounts,
    places: Option<StageCounts>,
    learned_matching: StageCounts,
}

#[derive(Serialize)]
struct MappingReport {
    reused: bool,
    extended: bool,
    mean_reprojection_error_px: Option<f64>,
}

fn timed<T>(
    seconds: &mut BTreeMap<&'static str, f64>,
    stage: &'static str,
    f: impl FnOnce() -> Result<T>,
) -> Result<T> {
    let start = Instant::now();
    let out = f()?;
    seconds.insert(stage, start.elapsed().as_secs_f64());
    Ok(out)
}

/// `WORK/images/<session>` links to each session's folder, so that COLMAP
/// finds `session/file` under one root.
fn link_images(work: &Path, sessions: &[SessionImages]) -> Result<PathBuf> {
    let root = work.join("images");
    std::fs::create_dir_all(&root).with_context(|| format!("creating {}", root.display()))?;
    for session in sessions {
        let link = root.join(&session.name);
        if std::fs::read_link(&link).is_ok_and(|target| target == session.dir) {
            continue;
        }
        if link.symlink_metadata().is_ok() {
            std::fs::remove_file(&link).with_context(|| format!("replacing {}", link.display()))?;
        }
        std::os::unix::fs::symlink(&session.dir, &link).with_context(|| format!("linking {}", link.display()))?;
    }
    Ok(root)
}

pub fn run(args: Args) -> Result<()> {
    let mut seconds = BTreeMap::new();
    let sessions = timed(&mut seconds, "ingest", || {
        ingest::check_unique(&args.sessions).context("--session")?;
        args.sessions
            .iter()
            .map(|spec| ingest::scan_session(spec).with_context(|| format!("--session {}", spec.name)))
            .collect::<Result<Vec<_>>>()
    })?;
    let python = revisit_colmap::find_python(args.python.as_deref()).context("--python")?;
    let sift = SiftOptions {
        max_num_features: args.max_features,
        upright: args.upright,
        ignore_regions_px: args.ignore_regions.iter().map(|r| r.0).collect(),
        ..SiftOptions::default()
    };
    sift.check().context("--max-features")?;
    let pair_options = PairOptions {
        exhaustive_max_images: args.exhaustive_max_images,
        window: args.window,
        loop_period: args.loop_period,
    };
    pair_options.check().context("--window/--loop-period")?;
    let sift_cross = if args.cross == CrossArg::Sift { CrossStrategy::Sift } else { CrossStrategy::None };
    let learned_pairs = match args.cross {
        CrossArg::None | CrossArg::Sift => None,
        CrossArg::LearnedAll => Some(LearnedPairs::All),
        CrossArg::LearnedCross => Some(LearnedPairs::Cross),
        CrossArg::Vpr => Some(LearnedPairs::Places),
    }
    .filter(|_| sessions.len() >= 2);
    let verify_options = VerifyOptions { seed: args.seed, ..VerifyOptions::default() };
    let cross_options = CrossOptions {
        roll_search: match args.roll_search {
            RollSearchArg::Probe => RollSearch::Probe { budget: 256, margin: args.roll_margin },
            RollSearchArg::Full => RollSearch::Full,
            RollSearchArg::Off => RollSearch::Off,
        },
        places: match &args.vpr_model {
            Some(path) => PlaceSource::Onnx(path.clone()),
            None => PlaceSource::Vlad { clusters: 64 },
        },
        candidates: CandidateOptions { top_k: args.vpr_top_k, max_distance: args.vpr_max_distance },
        anchor_radius_px: args.anchor_radius,
        verify: VerifyOptions {
            min_inliers: args.cross_min_inliers,
            max_error_px: args.cross_max_error,
            ..verify_options.clone()
        },
        roll_margin: args.roll_margin,
    };
    cross_options.verify.check().context("--cross-min-inliers/--cross-max-error")?;
    if args.roll_margin.is_nan() || args.roll_margin < 1.0 {
        bail!("--roll-margin must be at least 1, not {}", args.roll_margin);
    }
    if args.vpr_top_k == 0 {
        bail!("--vpr-top-k must be at least 1");
    }
    // Open the learned models before any work, so a missing model fails fast.
    let mut learned = match learned_pairs {
        Some(_) => Some(args.models.open(args.learned.method())?),
        None => None,
    };
    let mapper_options = MapperOptions {
        engine: match args.mapper {
            MapperArg::Incremental => Engine::Incremental,
            MapperArg::Global => Engine::Global,
        },
        seed: args.seed,
        refine_intrinsics: args.camera.is_none(),
        ..MapperOptions::default()
    };

    let work = &args.out;
    std::fs::create_dir_all(work).with_context(|| format!("--out {}", work.display()))?;
    let database = work.join("database.db");
    let mut store = Store::open(&database)?;
    let feature_setting = serde_json::json!({ "sift": sift, "max_image_size_px": args.max_image_size }).to_string();
    store.pin_setting("features", &feature_setting).context("--max-features/--upright/--ignore-region")?;

    let mut image_ids = BTreeMap::new();
    let camera_setting = args.camera.as_ref().map_or("estimated".to_owned(), |c| format!("{:?}", c));
    store.pin_setting("camera", &camera_setting).context("--camera")?;
    for session in &sessions {
        let camera = match &args.camera {
            Some(c) => Camera::new(0, c.model, session.width, session.height, c.params.clone())
                .with_context(|| format!("--camera for session {}", session.name))?,
            None => Camera::default_for_size(0, session.width, session.height),
        };
        let source = session.dir.display().to_string();
        let record = store
            .ensure_session(&session.name, &source, &camera, args.camera.is_some())
            .with_context(|| format!("--session {}", session.name))?;
        let stored = store.camera(record.camera_id)?;
        if (stored.width, stored.height) != (session.width, session.height) {
            bail!(
                "--session {}: images are now {}x{} but the store has them as {}x{}",
                session.name,
                session.width,
                session.height,
                stored.width,
                stored.height
            );
        }
        image_ids.extend(store.ensure_images(&session.image_names(), record.camera_id)?);
    }
    image_ids.retain(|name, _| sessions.iter().any(|s| name.starts_with(&format!("{}/", s.name))));
    let image_root = link_images(work, &sessions)?;

    let bars = Bars::default();
    let features = timed(&mut seconds, "features", || {
        Ok(revisit_pipeline::extract_features(&mut store, &sessions, &image_ids, &sift, args.max_image_size, &bars)?)
    })?;
    // Learned features come before matching within visits: their keypoints
    // join the SIFT ones there, so cross-visit tracks continue inside visits.
    let mut cross_report = CrossReport::default();
    let visits = cross::visits(&sessions, &image_ids);
    let search = cross_options.roll_search;
    let learned_keypoints = match learned.as_mut().filter(|_| learned_pairs.is_some()) {
        Some((_, learned)) => Some(timed(&mut seconds, "learned_features", || {
            cross_report.learned_features = cross::extract_learned(&mut store, learned, &visits, search, &bars)?;
            Ok(cross::register_learned_keypoints(&mut store, learned.method.name(), &visits)?)
        })?),
        None => None,
    };
    let matching = timed(&mut seconds, "matching", || {
        let pairs = match learned_pairs {
            Some(LearnedPairs::All) => Vec::new(),
            _ => revisit_pipeline::plan_pairs(&sessions, &image_ids, sift_cross, &pair_options),
        };
        let loaded = revisit_pipeline::load_features(&store, image_ids.values().copied())?;
        Ok(revisit_pipeline::match_pairs(
            &mut store,
            &pairs,
            &loaded,
            learned_keypoints.as_ref(),
            &MatchOptions::default(),
            &verify_options,
            &bars,
        )?)
    })?;
    drop(learned_keypoints);
    if let (Some(which), Some((runtime, learned))) = (learned_pairs, learned.as_mut()) {
        let places = match which {
            LearnedPairs::Places => Some(timed(&mut seconds, "places", || {
                let method = learned.method.name();
                Ok(cross::describe_places(&mut store, method, &cross_options.places, runtime, &visits, search, &bars)?)
            })?),
            _ => None,
        };
        cross_report.places = places.as_ref().map(|p| p.counts);
        cross_report.learned_matching = timed(&mut seconds, "learned_matching", || {
            let pairs = cross::plan_learned_pairs(which, &visits, places.as_ref(), &cross_options.candidates);
            Ok(cross::match_learned_pairs(&mut store, learned, &pairs, &cross_options, &bars)?)
        })?;
    }
    let records = store.pair_records()?;
    let inputs = {
        let inliers: usize = records.iter().map(|r| r.num_inliers).sum();
        let names: Vec<&String> = image_ids.keys().collect();
        format!("{} images {:?}; {} pairs, {inliers} inliers; {mapper_options:?}", names.len(), names, records.len())
    };
    let outcome: MappingOutcome = timed(&mut seconds, "mapping", || {
        Ok(mapping::map(&python, &database, &image_root, work, &inputs, &mapper_options)?)
    })?;

    let chosen = export::chosen_model(&outcome.models, &sessions);
    let report_sessions = export::session_reports(&sessions, &outcome.models, chosen);
    timed(&mut seconds, "export", || {
        let Some(model) = chosen.and_then(|k| outcome.models.get(k)) else {
            tracing::warn!("COLMAP registered no model: no poses.csv or points.ply");
            return Ok(());
        };
        let reconstruction = revisit_colmap::read_model(&model.path)?;
        let poses = work.join("poses.csv");
        std::fs::write(&poses, export::poses_csv(&reconstruction)).with_context(|| poses.display().to_string())?;
        let colors = match args.ply_colors {
            PlyColorsArg::Rgb => PlyColors::Rgb,
            PlyColorsArg::Session => PlyColors::BySession,
        };
        revisit_colmap::write_ply(&reconstruction, &work.join("points.ply"), colors)?;
        Ok(())
    })?;

    let report = Report {
        unlinked_sessions: report_sessions_unlinked(&report_sessions),
        sessions: report_sessions,
        models: outcome.models.len(),
        model_sizes: outcome.models.iter().map(|m| m.registered_images.len()).collect(),
        chosen_model: chosen.and_then(|k| outcome.models.get(k)).map(|m| m.path.clone()),
        registered_rule: REGISTERED_RULE,
        rolls: export::roll_histogram(&records),
        pairs: export::pair_reports(&records),
        features,
        matching,
        cross: cross_report,
        mapping: MappingReport {
            reused: outcome.reused,
            extended: outcome.extended,
            mean_reprojection_error_px: chosen
                .and_then(|k| outcome.models.get(k))
                .map(|m| m.mean_reprojection_error_px),
        },
        seconds,
    };
    let report_path = work.join("report.json");
    std::fs::write(&report_path, serde_json::to_string_pretty(&report)?)
        .with_context(|| report_path.display().to_string())?;
    print_summary(&report, work);
    Ok(())
}

fn report_sessions_unlinked(sessions: &BTreeMap<String, SessionReport>) -> Vec<String> {
    if sessions.len() < 2 {
        return Vec::new();
    }
    sessions.iter().filter(|(_, s)| 2 * s.registered < s.images).map(|(name, _)| name.clone()).collect()
}

fn print_summary(report: &Report, work: &Path) {
    println!("{:<16} {:>8} {:>11}", "session", "images", "registered");
    for (name, s) in &report.sessions {
        println!("{name:<16} {:>8} {:>11}", s.images, s.registered);
    }
    for (kind, p) in &report.pairs {
        println!("{kind} pairs: {} tried, {} verified", p.tried, p.verified);
    }
    if !report.rolls.is_empty() {
        println!("cross pairs by roll: {:?}", report.rolls);
    }
    println!("models: {} (sizes {:?})", report.models, report.model_sizes);
    for name in &report.unlinked_sessions {
        println!(
            "warning: session {name} could not be linked to the others: fewer than half its images are in \
             the chosen model (the rest are kept as their own model if COLMAP made one)"
        );
    }
    if let Some(model) = &report.chosen_model {
        println!("model:  {}", model.display());
    }
    for file in ["database.db", "points.ply", "poses.csv", "report.json"] {
        let path = work.join(file);
        if path.exists() {
            println!("wrote:  {}", path.display());
        }
    }
}
