//! `revisit bench compare`: the published comparison on one dataset with
//! exact truth. Joint reconstructions (Revisit's default, joint SIFT, and two
//! ablations) against the post-hoc baselines (each visit reconstructed alone,
//! then aligned by ICP, by FPFH global registration, or to navigation), all
//! scored by the same cross-visit click protocol (`revisit eval`'s), written
//! to `REPORT/compare.json` and a self-contained `REPORT/index.html`.
//!
//! The published reef figures beside them: median cross-visit error 165 px
//! after ICP, 77 px after BUFFER-X global registration, 3.65 px joint.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use revisit_core::{session_of, NavigationFix, Reconstruction};
use revisit_eval::{parse_truth_poses_csv, score_truth, ClickPair, TruthOptions};
use revisit_matching::RollSearch;
use revisit_pipeline::export::is_linked;
use revisit_pipeline::ingest::{scan_session, SessionSpec};
use revisit_pipeline::navigation::read_navigation_csv;
use revisit_pipeline::options::ReconstructOptions;
use revisit_pipeline::{CrossStrategy, Workspace};
use revisit_posthoc::{align_visits, AlignContext, Alignment, VisitAlignment};
use serde::Serialize;

use crate::commands::models::ToolArgs;
use crate::progress::Bars;

/// The page's script (plotly), embedded and written to the report's work folder.
const PAGE_SCRIPT: &str = include_str!("../../../python/revisit_compare_page.py");
/// Points of each model drawn in the page's 3D views (every n-th, in id order).
const CLOUD_POINTS: usize = 4000;
/// The published median cross-visit errors (reef, px).
const PUBLISHED: [(&str, f64); 3] = [("ICP", 165.0), ("BUFFER-X", 77.0), ("joint (the paper's method)", 3.65)];

/// One method of the comparison.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Method {
    /// A joint reconstruction with these options.
    Joint {
        name: &'static str,
        cross: CrossStrategy,
        roll_search: Option<RollSearch>,
        /// Each visit's navigation (`nav/NAME.csv`) as pose priors.
        navigation: bool,
        /// Change-aware mapping (`reconstruct --change-aware`).
        change_aware: bool,
        about: &'static str,
    },
    /// Each visit alone, aligned afterwards.
    Posthoc(Alignment),
}

/// The joint method whose matches `revisit-nav` and the change-aware methods reuse when it ran
/// first.
const REVISIT: &str = "revisit";

const METHODS: [Method; 10] = [
    Method::Joint {
        name: REVISIT,
        cross: CrossStrategy::Vpr,
        roll_search: None,
        navigation: false,
        change_aware: false,
        about: "joint: place recognition + learned matching with roll search (Revisit's default)",
    },
    Method::Joint {
        name: "revisit-nav",
        cross: CrossStrategy::Vpr,
        roll_search: None,
        navigation: true,
        change_aware: false,
        about: "joint, with each visit's navigation as pose priors (reconstruct --nav); the matches of \
                revisit when it ran first (only mapping is timed then)",
    },
    Method::Joint {
        name: "revisit-change-aware",
        cross: CrossStrategy::Vpr,
        roll_search: None,
        navigation: false,
        change_aware: true,
        about: "joint, change-aware mapping (reconstruct --change-aware): each visit mapped alone, placed by its \
                cross-visit matches' consensus, solved jointly on the matches that hold; the matches of revisit \
                when it ran first",
    },
    Method::Joint {
        name: "revisit-nav-change-aware",
        cross: CrossStrategy::Vpr,
        roll_search: None,
        navigation: true,
        change_aware: true,
        about: "joint, change-aware mapping with each visit's navigation (placements gated by it, model placed on \
                it); the matches of revisit when it ran first",
    },
    Method::Joint {
        name: "joint-sift",
        navigation: false,
        change_aware: false,
        cross: CrossStrategy::Sift,
        roll_search: None,
        about: "joint: SIFT on every cross-visit pair",
    },
    Method::Joint {
        name: "no-roll-search",
        navigation: false,
        change_aware: false,
        cross: CrossStrategy::Vpr,
        roll_search: Some(RollSearch::Off),
        about: "joint, ablation: Revisit's default matching at roll 0 only",
    },
    Method::Joint {
        name: "no-places",
        navigation: false,
        change_aware: false,
        cross: CrossStrategy::LearnedCross,
        roll_search: None,
        about: "joint, ablation: the learned matcher on every cross-visit pair, no place recognition",
    },
    Method::Posthoc(Alignment::Icp),
    Method::Posthoc(Alignment::Fpfh),
    Method::Posthoc(Alignment::Navigation),
];

impl Method {
    fn name(self) -> &'static str {
        match self {
            Method::Joint { name, .. } => name,
            Method::Posthoc(Alignment::Icp) => "posthoc-icp",
            Method::Posthoc(Alignment::Fpfh) => "posthoc-fpfh",
            Method::Posthoc(Alignment::Navigation) => "posthoc-nav",
        }
    }

    fn about(self) -> &'static str {
        match self {
            Method::Joint { about, .. } => about,
            Method::Posthoc(Alignment::Icp) => "post-hoc: each visit alone, ICP (with scale) from the centroids",
            Method::Posthoc(Alignment::Fpfh) => {
                "post-hoc: each visit alone, FPFH + RANSAC global registration, then ICP"
            }
            Method::Posthoc(Alignment::Navigation) => {
                "post-hoc: each visit alone, a similarity fitted to its navigation (INS + fix)"
            }
        }
    }
}

fn method_names() -> impl clap::builder::TypedValueParser<Value = String> {
    use clap::builder::{PossibleValue, PossibleValuesParser};
    PossibleValuesParser::new(METHODS.map(|m| PossibleValue::new(m.name()).help(m.about())))
}

#[derive(clap::Args)]
pub struct Args {
    /// A dataset made by `revisit synth`: sessions/NAME/*.png, truth/ (with the
    /// evaluation click files) and nav/NAME.csv (for posthoc-nav).
    #[arg(long, value_name = "DIR")]
    dataset: PathBuf,
    /// Report folder: compare.json, index.html, every scored model (models/METHOD,
    /// COLMAP binary; a post-hoc one holds the aligned visits) and the work
    /// folders (work/). Re-running reuses the finished work; a method's seconds
    /// are then those of what was left to do.
    #[arg(long, value_name = "REPORT")]
    out: PathBuf,
    /// The methods, in the order they run (default: all).
    #[arg(long, value_delimiter = ',', value_parser = method_names(), value_name = "LIST")]
    methods: Vec<String>,
    /// SIFT features per image (every method).
    #[arg(long, default_value_t = 1024, value_name = "N")]
    max_features: usize,
    /// The scaling benchmark's JSON (`bench matching --json`), drawn in the page when given.
    #[arg(long, value_name = "FILE")]
    scaling: Option<PathBuf>,
    #[command(flatten)]
    tools: ToolArgs,
}

/// A model's points for the page: a sample, each with the visit that saw it
/// (an index into `sessions`), or -1 when several visits saw it.
#[derive(Serialize)]
struct Cloud {
    sessions: Vec<String>,
    points: Vec<[f32; 3]>,
    visit: Vec<i32>,
}

#[derive(Serialize)]
struct MethodFigures {
    method: String,
    about: String,
    /// Why the method gave no scored model, if it did not.
    failure: Option<String>,
    /// Visits with at least half their images in the scored model (linked, as `reconstruct`
    /// reports it), of all visits.
    sessions_merged: usize,
    sessions: usize,
    median_px: Option<f64>,
    mean_px: Option<f64>,
    clicks_scored: usize,
    clicks: usize,
    seconds: f64,
    /// Against the truth's cameras: each visit's scale over the model's, minus 1.
    visit_scale_rel_error: BTreeMap<String, Option<f64>>,
    /// Each visit's median camera rotation error, degrees (the model aligned to the truth as a whole).
    visit_rotation_deg: BTreeMap<String, Option<f64>>,
    /// The scale that takes the model onto the truth (1 for a metric model).
    truth_from_model_scale: Option<f64>,
    /// The scored model (COLMAP binary).
    model: Option<PathBuf>,
    /// Post-hoc methods: where each visit went.
    visits: Vec<VisitAlignment>,
    /// Every scored click's error, px (for the histograms).
    errors_px: Vec<f64>,
    cloud: Option<Cloud>,
}

#[derive(Serialize)]
struct Comparison {
    dataset: PathBuf,
    sessions: Vec<String>,
    published_median_px: BTreeMap<&'static str, f64>,
    methods: Vec<MethodFigures>,
    /// The scaling benchmark's figures, as given by `--scaling`.
    scaling: Option<serde_json::Value>,
}

/// Each visit reconstructed alone, shared by every post-hoc method.
struct Alone {
    models: Vec<(String, Option<Reconstruction>)>,
    seconds: f64,
}

pub fn run(args: Args) -> Result<()> {
    let sessions_dir = args.dataset.join("sessions");
    let truth = args.dataset.join("truth");
    let sessions = super::session_names(&args.dataset)?;
    let clicks = super::truth_clicks(&truth)?;
    let session_images: Vec<usize> = sessions
        .iter()
        .map(|s| scan_session(&SessionSpec { name: s.clone(), dir: sessions_dir.join(s) }).map(|images| images.len()))
        .collect::<Result<_, _>>()?;
    let poses_path = truth.join("poses.csv");
    let poses = match poses_path.exists() {
        true => {
            let text = std::fs::read_to_string(&poses_path).with_context(|| poses_path.display().to_string())?;
            Some(parse_truth_poses_csv(&text, &poses_path.display().to_string())?)
        }
        false => None,
    };
    let camera = super::calibrated_camera(&truth)?;
    let scaling = match &args.scaling {
        Some(path) => Some(super::read_json(path).with_context(|| format!("--scaling {}", path.display()))?),
        None => None,
    };
    let methods: Vec<Method> = if args.methods.is_empty() {
        METHODS.to_vec()
    } else {
        args.methods.iter().filter_map(|name| METHODS.iter().find(|m| m.name() == name).copied()).collect()
    };
    let work = args.out.join("work");
    std::fs::create_dir_all(&work).with_context(|| format!("--out {}", args.out.display()))?;
    let cancel = crate::signals::cancel_on_signals()?;
    let options_for = |cross: CrossStrategy, roll_search: Option<RollSearch>| {
        let mut options = ReconstructOptions { cross, ..ReconstructOptions::default() };
        options.features.sift.max_num_features = args.max_features;
        if let Some(roll_search) = roll_search {
            options.learned_matching.roll_search = roll_search;
        }
        if let Some(camera) = &camera {
            options.cameras.calibrated.insert(String::new(), camera.clone());
        }
        options
    };
    let reconstruct = |dir: &Path,
                       options: ReconstructOptions,
                       visits: &[String],
                       navigation: Option<&[NavigationFix]>|
     -> Result<Option<Reconstruction>> {
        let mut workspace = Workspace::open(dir, options, args.tools.tools())?;
        for session in visits {
            workspace
                .add_session(scan_session(&SessionSpec { name: session.clone(), dir: sessions_dir.join(session) })?)?;
            if let Some(navigation) = navigation {
                workspace.add_navigation(session, navigation)?;
            }
        }
        let report = workspace.run(&Bars::default(), &cancel)?;
        match &report.chosen_model {
            Some(model) => Ok(Some(revisit_colmap::read_model(model).with_context(|| model.display().to_string())?)),
            None => Ok(None),
        }
    };

    let mut alone: Option<Alone> = None;
    let mut figures = Vec::new();
    for method in methods {
        println!("== {}", method.name());
        let (model, visits, mut failure, seconds) = match method {
            Method::Joint { name, cross, roll_search, navigation, change_aware, .. } => {
                let navigation = match navigation {
                    false => None,
                    true => match read_navigation(&args.dataset, &sessions)? {
                        Ok(navigation) => Some(navigation),
                        Err(missing) => {
                            let failure = format!("no navigation: {} does not exist", missing.display());
                            figures.push(failed_row(method, failure, &sessions, &clicks, 0.0));
                            continue;
                        }
                    },
                };
                let dir = work.join(name);
                if navigation.is_some() || change_aware {
                    start_from_store(&work.join(REVISIT), &dir)?;
                }
                let started = Instant::now();
                let mut options = options_for(cross, roll_search);
                options.mapper.change_aware = change_aware;
                let model = reconstruct(&dir, options, &sessions, navigation.as_deref())
                    .with_context(|| format!("method {name}"))?;
                let failure = model.is_none().then(|| "COLMAP made no model".to_owned());
                (model, Vec::new(), failure, started.elapsed().as_secs_f64())
            }
            Method::Posthoc(alignment) => {
                let alone = match &mut alone {
                    Some(alone) => &*alone,
                    empty @ None => {
                        let started = Instant::now();
                        let mut models = Vec::new();
                        for session in &sessions {
                            let dir = work.join("alone").join(session);
                            let options = options_for(CrossStrategy::None, None);
                            let model = reconstruct(&dir, options, std::slice::from_ref(session), None)
                                .with_context(|| format!("visit {session} alone"))?;
                            models.push((session.clone(), model));
                        }
                        &*empty.insert(Alone { models, seconds: started.elapsed().as_secs_f64() })
                    }
                };
                let navigation = match alignment {
                    Alignment::Navigation => match read_navigation(&args.dataset, &sessions)? {
                        Ok(navigation) => navigation,
                        Err(missing) => {
                            let failure = format!("no navigation: {} does not exist", missing.display());
                            figures.push(failed_row(method, failure, &sessions, &clicks, alone.seconds));
                            continue;
                        }
                    },
                    _ => Vec::new(),
                };
                let python = args.tools.tools().python().context("--python")?;
                let context =
                    AlignContext { python: &python, scratch: &work.join("register"), seed: 0, navigation: &navigation };
                let started = Instant::now();
                let aligned = align_visits(&alone.models, alignment, &context, cancel.flag())
                    .with_context(|| format!("method {}", method.name()))?;
                let seconds = alone.seconds + started.elapsed().as_secs_f64();
                let failure = failed_visits(&aligned.visits);
                let model = (!aligned.model.images.is_empty()).then_some(aligned.model);
                (model, aligned.visits, failure, seconds)
            }
        };
        let mut row = MethodFigures { visits, ..failed_row(method, String::new(), &sessions, &clicks, seconds) };
        if let Some(model) = model {
            let dir = args.out.join("models").join(method.name());
            std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
            revisit_colmap::write_binary(&model, &dir).with_context(|| format!("writing {}", dir.display()))?;
            let summary = super::score_clicks(&model, &clicks);
            row.sessions_merged = sessions
                .iter()
                .zip(&session_images)
                .filter(|&(s, &images)| {
                    let registered = model.images.values().filter(|i| session_of(&i.name) == s.as_str()).count();
                    is_linked(registered, images)
                })
                .count();
            if row.sessions_merged < sessions.len() && failure.is_none() {
                failure = Some(format!("{} of {} visits in one model", row.sessions_merged, sessions.len()));
            }
            row.median_px = summary.median_px;
            row.mean_px = summary.mean_px;
            row.clicks_scored = summary.scored;
            row.errors_px = summary.errors_px;
            if let Some(poses) = &poses {
                let t = score_truth(std::slice::from_ref(&model), poses, &TruthOptions::default());
                for (name, visit) in &t.sessions {
                    row.visit_scale_rel_error.insert(name.clone(), visit.scale_rel_error);
                    row.visit_rotation_deg.insert(name.clone(), visit.pose.rotation_median_deg);
                }
                row.truth_from_model_scale = t.similarities.first().copied().flatten().map(|s| s.scale);
            }
            row.cloud = Some(cloud(&model, &sessions));
            row.model = Some(dir);
        }
        row.failure = failure.or_else(|| row.model.is_none().then(|| "no model".to_owned()));
        figures.push(row);
    }
    let comparison = Comparison {
        dataset: args.dataset.clone(),
        sessions,
        published_median_px: PUBLISHED.into_iter().collect(),
        methods: figures,
        scaling,
    };
    print_table(&comparison);
    let json = args.out.join("compare.json");
    std::fs::write(&json, serde_json::to_string(&comparison)? + "\n").with_context(|| json.display().to_string())?;
    write_page(&args, &json)?;
    Ok(())
}

/// A method's row before scoring: no model, `failure` as given.
fn failed_row(
    method: Method,
    failure: String,
    sessions: &[String],
    clicks: &[ClickPair],
    seconds: f64,
) -> MethodFigures {
    MethodFigures {
        method: method.name().to_owned(),
        about: method.about().to_owned(),
        failure: Some(failure),
        sessions_merged: 0,
        sessions: sessions.len(),
        median_px: None,
        mean_px: None,
        clicks_scored: 0,
        clicks: clicks.iter().map(|p| p.uv_clicked.len()).sum(),
        seconds,
        visit_scale_rel_error: BTreeMap::new(),
        visit_rotation_deg: BTreeMap::new(),
        truth_from_model_scale: None,
        model: None,
        visits: Vec::new(),
        errors_px: Vec::new(),
        cloud: None,
    }
}

/// "s2: reason; s3: reason" for the visits that were not aligned.
fn failed_visits(visits: &[VisitAlignment]) -> Option<String> {
    let failed: Vec<String> =
        visits.iter().filter_map(|v| v.failure.as_ref().map(|reason| format!("{}: {reason}", v.session))).collect();
    (!failed.is_empty()).then(|| failed.join("; "))
}

/// A new work folder `to` starts with a copy of the store of `from` (a finished joint method
/// with the same options), so that it redoes no matching; nothing happens when `to` has a store
/// or `from` has none.
fn start_from_store(from: &Path, to: &Path) -> Result<()> {
    let (store, target) = (from.join("database.db"), to.join("database.db"));
    if target.exists() || !store.exists() {
        return Ok(());
    }
    std::fs::create_dir_all(to).with_context(|| format!("creating {}", to.display()))?;
    // Copied beside, then renamed: a killed copy leaves no half store.
    let partial = to.join("database.db.partial");
    if partial.exists() {
        std::fs::remove_file(&partial).with_context(|| format!("removing {}", partial.display()))?;
    }
    revisit_store::Store::open_read_only(&store)?.copy_to(&partial)?;
    std::fs::rename(&partial, &target).with_context(|| format!("writing {}", target.display()))?;
    Ok(())
}

/// Every visit's `DATASET/nav/NAME.csv`, or the first that does not exist.
fn read_navigation(dataset: &Path, sessions: &[String]) -> Result<Result<Vec<NavigationFix>, PathBuf>> {
    let mut fixes = Vec::new();
    for session in sessions {
        let path = dataset.join("nav").join(format!("{session}.csv"));
        if !path.exists() {
            return Ok(Err(path));
        }
        fixes.extend(read_navigation_csv(&path, session)?);
    }
    Ok(Ok(fixes))
}

/// About [`CLOUD_POINTS`] of `model`'s points, each with its visit.
fn cloud(model: &Reconstruction, sessions: &[String]) -> Cloud {
    let step = model.points3d.len().div_ceil(CLOUD_POINTS).max(1);
    let mut cloud = Cloud { sessions: sessions.to_vec(), points: Vec::new(), visit: Vec::new() };
    for point in model.points3d.values().step_by(step) {
        let mut visits = point.track.iter().filter_map(|t| {
            let image = model.images.get(&t.image_id)?;
            sessions.iter().position(|s| s == session_of(&image.name))
        });
        let first = visits.next().map_or(-1, |v| v as i32);
        let visit = if visits.all(|v| v as i32 == first) { first } else { -1 };
        cloud.points.push(point.xyz.coords.map(|c| c as f32).into());
        cloud.visit.push(visit);
    }
    cloud
}

fn print_table(c: &Comparison) {
    let width = c.methods.iter().map(|m| m.method.len()).max().unwrap_or(0).max("method".len());
    println!();
    println!(
        "{:<width$} {:>10} {:>10} {:>9} {:>8} {:>11} {:>9} {:>9}  failure",
        "method", "median px", "mean px", "clicks", "visits", "visit scale", "rot deg", "seconds"
    );
    let px = |v: Option<f64>| v.map_or("-".to_owned(), |v| format!("{v:.2}"));
    for m in &c.methods {
        let worst =
            |values: &BTreeMap<String, Option<f64>>| values.values().flatten().map(|v| v.abs()).max_by(f64::total_cmp);
        println!(
            "{:<width$} {:>10} {:>10} {:>9} {:>8} {:>11} {:>9} {:>9.1}  {}",
            m.method,
            px(m.median_px),
            px(m.mean_px),
            format!("{}/{}", m.clicks_scored, m.clicks),
            format!("{}/{}", m.sessions_merged, m.sessions),
            worst(&m.visit_scale_rel_error).map_or("-".to_owned(), |v| format!("{:.2}%", 100.0 * v)),
            px(worst(&m.visit_rotation_deg)),
            m.seconds,
            m.failure.as_deref().unwrap_or("")
        );
    }
    let published: Vec<String> = PUBLISHED.iter().map(|(name, px)| format!("{name} {px} px")).collect();
    println!("published (reef, median cross-visit error): {}", published.join(", "));
    println!(
        "visit scale: the worst visit's scale against its model's (by the truth's cameras); rot deg: the worst \
         visit's median camera rotation error"
    );
    let median = |name: &str| c.methods.iter().find(|m| m.method == name).and_then(|m| m.median_px);
    if let Some(revisit) = median("revisit") {
        for m in c.methods.iter().filter(|m| m.method.starts_with("posthoc")) {
            if let Some(baseline) = m.median_px {
                println!("{} / revisit median error: {:.1}x (goal >= 10x)", m.method, baseline / revisit.max(1e-9));
            }
        }
    }
}

/// `REPORT/index.html`, drawn by the embedded plotly script from compare.json.
fn write_page(args: &Args, json: &Path) -> Result<()> {
    let script = args.out.join("work").join("revisit_compare_page.py");
    std::fs::write(&script, PAGE_SCRIPT).with_context(|| script.display().to_string())?;
    let python = args.tools.tools().python().context("--python")?;
    let page = args.out.join("index.html");
    let output = Command::new(&python)
        .arg(&script)
        .arg(json)
        .arg(&page)
        .output()
        .with_context(|| format!("could not start {}", python.display()))?;
    if !output.status.success() {
        bail!("{} {} failed: {}", python.display(), script.display(), String::from_utf8_lossy(&output.stderr).trim());
    }
    println!("wrote: {} and {}", json.display(), page.display());
    Ok(())
}
