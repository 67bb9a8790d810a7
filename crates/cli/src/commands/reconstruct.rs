//! `revisit reconstruct`: sessions in, one joint COLMAP reconstruction out.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use revisit_colmap::{Engine, MapperOptions, PlyColors};
use revisit_core::Camera;
use revisit_features::SiftOptions;
use revisit_matching::{MatchOptions, PairOptions, VerifyOptions};
use revisit_pipeline::export::{self, PairReport, SessionReport, REGISTERED_RULE};
use revisit_pipeline::ingest::{self, SessionImages, SessionSpec};
use revisit_pipeline::mapping::{self, MappingOutcome};
use revisit_pipeline::{CrossStrategy, StageCounts};
use revisit_store::Store;
use serde::Serialize;

use crate::progress::Bars;

#[derive(Clone, Copy, clap::ValueEnum)]
enum CrossArg {
    /// Intra-session pairs only: visits are not linked.
    None,
    /// Every cross-session pair with SIFT: the classic joint baseline.
    Sift,
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
    /// How images of different sessions are paired for matching.
    #[arg(long, value_enum, default_value = "sift")]
    cross: CrossArg,
    /// Largest number of SIFT features per image (the strongest are kept).
    #[arg(long, default_value_t = 4096, value_name = "N")]
    max_features: usize,
    /// Images whose larger side exceeds this are downscaled for extraction
    /// (keypoints are reported in full-resolution pixels).
    #[arg(long, default_value_t = 3200, value_name = "PX")]
    max_image_size: u32,
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
    features: StageCounts,
    matching: StageCounts,
    mapping: MappingReport,
    seconds: BTreeMap<&'static str, f64>,
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
    let cross = match args.cross {
        CrossArg::None => CrossStrategy::None,
        CrossArg::Sift => CrossStrategy::Sift,
    };
    let verify_options = VerifyOptions { seed: args.seed, ..VerifyOptions::default() };
    let mapper_options = MapperOptions {
        engine: match args.mapper {
            MapperArg::Incremental => Engine::Incremental,
            MapperArg::Global => Engine::Global,
        },
        seed: args.seed,
        ..MapperOptions::default()
    };

    let work = &args.out;
    std::fs::create_dir_all(work).with_context(|| format!("--out {}", work.display()))?;
    let database = work.join("database.db");
    let mut store = Store::open(&database)?;
    let feature_setting = serde_json::json!({ "sift": sift, "max_image_size_px": args.max_image_size }).to_string();
    store.pin_setting("features", &feature_setting).context("--max-features/--upright/--ignore-region")?;

    let mut image_ids = BTreeMap::new();
    for session in &sessions {
        let camera = Camera::default_for_size(0, session.width, session.height);
        let source = session.dir.display().to_string();
        let record = store
            .ensure_session(&session.name, &source, &camera)
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
    let matching = timed(&mut seconds, "matching", || {
        let pairs = revisit_pipeline::plan_pairs(&sessions, &image_ids, cross, &pair_options);
        let loaded = revisit_pipeline::load_features(&store, image_ids.values().copied())?;
        Ok(revisit_pipeline::match_pairs(
            &mut store,
            &pairs,
            &loaded,
            &MatchOptions::default(),
            &verify_options,
            &bars,
        )?)
    })?;
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
        sessions: report_sessions,
        models: outcome.models.len(),
        model_sizes: outcome.models.iter().map(|m| m.registered_images.len()).collect(),
        chosen_model: chosen.and_then(|k| outcome.models.get(k)).map(|m| m.path.clone()),
        registered_rule: REGISTERED_RULE,
        pairs: export::pair_reports(&records),
        features,
        matching,
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

fn print_summary(report: &Report, work: &Path) {
    println!("{:<16} {:>8} {:>11}", "session", "images", "registered");
    for (name, s) in &report.sessions {
        println!("{name:<16} {:>8} {:>11}", s.images, s.registered);
    }
    for (kind, p) in &report.pairs {
        println!("{kind} pairs: {} tried, {} verified", p.tried, p.verified);
    }
    println!("models: {} (sizes {:?})", report.models, report.model_sizes);
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
