//! `revisit bench colmap`: Revisit's whole reconstruction beside pycolmap's
//! own pipeline (SIFT extraction, exhaustive or sequential matching,
//! incremental mapping) on the same images, in the same run: seconds per
//! stage, images registered, peak memory, and the ratio of the totals.
//!
//! Revisit runs with `reconstruct`'s options (the same flags), from an empty
//! work folder so that nothing is reused; pycolmap runs
//! `python/colmap_pipeline.py` with one camera per session and every core.

use std::path::PathBuf;
use std::process::Command;

use anyhow::{bail, ensure, Context, Result};
use revisit_pipeline::ingest::{self, SessionSpec};
use revisit_pipeline::{Report, Workspace};
use serde::{Deserialize, Serialize};

use crate::commands::models::ToolArgs;
use crate::commands::options::OptionArgs;
use crate::progress::Bars;

/// The goal: Revisit's whole reconstruction at most this share of pycolmap's time.
const MAX_TIME_RATIO: f64 = 0.6;

#[derive(clap::Args)]
pub struct Args {
    /// A session (one visit) as NAME=DIR, as `reconstruct --session`; repeat for every visit.
    #[arg(long = "session", value_name = "NAME=DIR", required = true)]
    sessions: Vec<SessionSpec>,
    /// Work folder: WORK/revisit and WORK/colmap, emptied first.
    #[arg(long, value_name = "WORK")]
    work: PathBuf,
    /// pycolmap's pairs: every pair, or consecutive images (by name) plus its loop detection.
    #[arg(long, value_parser = ["exhaustive", "sequential"], default_value = "exhaustive")]
    colmap_matching: String,
    /// pycolmap's side.
    #[arg(long, default_value = "python/colmap_pipeline.py", value_name = "PY")]
    script: PathBuf,
    /// Write the figures as JSON here too.
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
    #[command(flatten)]
    options: OptionArgs,
    #[command(flatten)]
    tools: ToolArgs,
}

/// One side's figures.
#[derive(Debug, Serialize, Deserialize)]
struct Side {
    /// Seconds of feature extraction, matching (everything that pairs and
    /// verifies images) and mapping.
    seconds: Stages,
    images: usize,
    /// Images in the largest model (Revisit: its chosen model).
    registered: usize,
    models: usize,
    peak_rss_mib: Option<f64>,
}

#[derive(Debug, Default, Serialize, Deserialize)]
struct Stages {
    features: f64,
    matching: f64,
    mapping: f64,
}

impl Stages {
    fn total(&self) -> f64 {
        self.features + self.matching + self.mapping
    }
}

#[derive(Serialize)]
struct Figures {
    revisit: Side,
    colmap: Side,
    colmap_matching: String,
    time_ratio: f64,
}

pub fn run(args: Args) -> Result<()> {
    ingest::check_specs(&args.sessions).context("--session")?;
    let scanned = args
        .sessions
        .iter()
        .map(|spec| ingest::scan_session(spec).with_context(|| format!("--session {}", spec.name)))
        .collect::<Result<Vec<_>>>()?;
    ensure!(args.script.is_file(), "--script {}: no such file", args.script.display());
    for dir in ["revisit", "colmap"].map(|d| args.work.join(d)) {
        if dir.exists() {
            std::fs::remove_dir_all(&dir).with_context(|| format!("--work: cannot empty {}", dir.display()))?;
        }
    }

    println!("== revisit");
    let cancel = crate::signals::cancel_on_signals()?;
    let mut workspace = Workspace::open(&args.work.join("revisit"), args.options.options(), args.tools.tools())?;
    for session in scanned.iter().cloned() {
        let name = session.name.clone();
        workspace.add_session(session).with_context(|| format!("--session {name}"))?;
    }
    let report = workspace.run(&Bars::default(), &cancel)?;
    let revisit = revisit_side(&report);

    println!("== pycolmap ({} matching)", args.colmap_matching);
    let colmap = colmap_side(&args, &scanned)?;
    let figures = Figures {
        time_ratio: revisit.seconds.total() / colmap.seconds.total().max(1e-9),
        revisit,
        colmap,
        colmap_matching: args.colmap_matching.clone(),
    };
    print_figures(&figures);
    super::write_json(args.json.as_deref(), &figures)
}

/// Revisit's stages folded into the three of COLMAP's pipeline.
fn revisit_side(report: &Report) -> Side {
    let secs = |stages: &[&str]| stages.iter().filter_map(|s| report.seconds.get(*s)).sum::<f64>();
    Side {
        seconds: Stages {
            features: secs(&["features", "learned_features"]),
            matching: secs(&["matching", "places", "learned_matching", "consistency"]),
            mapping: secs(&["mapping", "export"]),
        },
        images: report.sessions.values().map(|s| s.images).sum(),
        registered: report.sessions.values().map(|s| s.registered).sum(),
        models: report.models,
        peak_rss_mib: report.peak_rss_mib.values().copied().reduce(f64::max),
    }
}

/// Links every session's folder under one root (COLMAP names images by their
/// path below it, one camera per folder) and runs the script there.
fn colmap_side(args: &Args, sessions: &[ingest::SessionImages]) -> Result<Side> {
    let root = args.work.join("colmap");
    let images = root.join("images");
    std::fs::create_dir_all(&images).with_context(|| images.display().to_string())?;
    let mut names = Vec::new();
    for session in sessions {
        let link = images.join(&session.name);
        std::os::unix::fs::symlink(&session.dir, &link).with_context(|| link.display().to_string())?;
        names.extend(session.images().into_iter().map(|(_, name)| name.to_string()));
    }
    let list = root.join("images.txt");
    std::fs::write(&list, names.join("\n")).with_context(|| list.display().to_string())?;
    let python = args.tools.tools().python().context("--python")?;
    let output = Command::new(&python)
        .arg(&args.script)
        .args(["--image-path".as_ref(), images.as_os_str(), "--image-list".as_ref(), list.as_os_str()])
        .args(["--work".as_ref(), root.join("run").as_os_str()])
        .args(["--matching", &args.colmap_matching])
        .stderr(std::process::Stdio::inherit())
        .output()
        .with_context(|| format!("could not start {}", python.display()))?;
    if !output.status.success() {
        bail!("{} {} failed ({})", python.display(), args.script.display(), output.status);
    }
    let stdout = String::from_utf8_lossy(&output.stdout);
    let line = stdout.lines().rev().find(|l| l.starts_with('{')).unwrap_or("");
    serde_json::from_str(line).with_context(|| format!("{}: no figures in its output", args.script.display()))
}

fn print_figures(f: &Figures) {
    println!();
    println!(
        "{:<22} {:>10} {:>10} {:>10} {:>10} {:>12} {:>8} {:>10}",
        "", "features s", "matching s", "mapping s", "total s", "registered", "models", "peak MiB"
    );
    for (name, side) in [("revisit", &f.revisit), (format!("pycolmap {}", f.colmap_matching).as_str(), &f.colmap)] {
        println!(
            "{:<22} {:>10.1} {:>10.1} {:>10.1} {:>10.1} {:>12} {:>8} {:>10}",
            name,
            side.seconds.features,
            side.seconds.matching,
            side.seconds.mapping,
            side.seconds.total(),
            format!("{}/{}", side.registered, side.images),
            side.models,
            side.peak_rss_mib.map_or("-".to_owned(), |m| format!("{m:.0}")),
        );
    }
    println!(
        "revisit / pycolmap time: {:.2}x (goal <= {MAX_TIME_RATIO}x with at least as many images registered)",
        f.time_ratio
    );
}
