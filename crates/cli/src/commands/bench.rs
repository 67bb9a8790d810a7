//! `revisit bench ...`: figures side by side with the reference implementations.

mod bag;
mod colmap;
mod compare;
mod live;
mod matching;
mod scaling;
mod sift;

#[derive(clap::Subcommand)]
pub enum Bench {
    /// Bag read throughput (MB/s, messages/s, images decoded/s) beside Python
    /// mcap + mcap-ros2-support on the same mcap file.
    Bag(bag::Args),
    /// Revisit's whole reconstruction beside pycolmap's own pipeline (SIFT,
    /// exhaustive or sequential matching, incremental mapping) on the same
    /// sessions: seconds per stage, images registered, peak memory, time ratio.
    Colmap(Box<colmap::Args>),
    /// Revisit's SIFT against OpenCV's on the same real images: time per image
    /// at equal feature count and verified inliers on overlapping pairs.
    Sift(sift::Args),
    /// The cross-visit strategies (sift, learned-all, learned-cross, vpr) on one
    /// synthetic dataset: matching time, pairs, inliers, sessions in one model,
    /// cross-visit error; place-recognition recall; roll-search agreement and
    /// cost; learned extraction speed. With --scale, the scaling study over
    /// survey sizes (JSON and a log-log plot).
    Matching(matching::Args),
    /// The published comparison on a synthetic dataset: Revisit's joint
    /// reconstruction, joint SIFT and two ablations against the post-hoc
    /// baselines (each visit alone, aligned by ICP, FPFH + RANSAC or
    /// navigation), scored by the same click protocol; writes compare.json and
    /// a self-contained index.html (table, histograms, 3D views).
    Compare(compare::Args),
    /// The node graph under a live camera (30 Hz 1280x720 by default, JPEG then raw): frames
    /// received, dropped and lost, keyframes kept, each node's sustained rate and peak memory,
    /// and the delay from a keyframe to its registered pose.
    Live(live::Args),
}

pub fn run(bench: Bench) -> anyhow::Result<()> {
    match bench {
        Bench::Bag(args) => bag::run(args),
        Bench::Colmap(args) => colmap::run(*args),
        Bench::Compare(args) => compare::run(args),
        Bench::Sift(args) => sift::run(args),
        Bench::Matching(args) => matching::run(args),
        Bench::Live(args) => live::run(args),
    }
}

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use anyhow::{ensure, Context, Result};
use revisit_core::Reconstruction;
use revisit_eval::{parse_points_csv, score, ClickPair, ScoreOptions, Summary};
use revisit_pipeline::options::CameraSpec;

/// Writes a bench's figures as JSON to `--json`'s file, if one was given.
fn write_json(path: Option<&std::path::Path>, figures: &impl serde::Serialize) -> anyhow::Result<()> {
    use anyhow::Context;
    if let Some(path) = path {
        std::fs::write(path, serde_json::to_string_pretty(figures)? + "\n")
            .with_context(|| format!("--json {}", path.display()))?;
        println!("wrote: {}", path.display());
    }
    Ok(())
}

/// The session folders of a synthetic dataset (`DATASET/sessions/NAME`), sorted; at least two.
fn session_names(dataset: &Path) -> Result<Vec<String>> {
    let sessions_dir = dataset.join("sessions");
    let mut names: Vec<String> = std::fs::read_dir(&sessions_dir)
        .with_context(|| format!("--dataset {}: no sessions/ folder", dataset.display()))?
        .filter_map(|e| e.ok())
        .filter(|e| e.path().is_dir())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    ensure!(names.len() >= 2, "--dataset {}: fewer than two sessions", dataset.display());
    Ok(names)
}

/// The truth's camera (intrinsics.json) when every session has the same one
/// (the synthetic surveys' is calibrated).
fn calibrated_camera(truth: &Path) -> Result<Option<CameraSpec>> {
    let intrinsics = read_json(&truth.join("intrinsics.json"))?;
    let cameras: BTreeSet<String> = intrinsics
        .as_array()
        .into_iter()
        .flatten()
        .filter_map(|c| {
            let params: Vec<String> = c["params"].as_array()?.iter().map(|p| p.to_string()).collect();
            Some(format!("{}:{}", c["model"].as_str()?, params.join(",")))
        })
        .collect();
    match cameras.into_iter().collect::<Vec<_>>()[..] {
        [ref one] => Ok(Some(one.parse().map_err(anyhow::Error::msg).context("truth/intrinsics.json")?)),
        _ => Ok(None),
    }
}

fn read_json(path: &Path) -> Result<serde_json::Value> {
    let text = std::fs::read_to_string(path).with_context(|| path.display().to_string())?;
    serde_json::from_str(&text).with_context(|| path.display().to_string())
}

/// Every click of the truth's click files (`evaluation_points_*.csv`).
fn truth_clicks(truth: &Path) -> Result<Vec<ClickPair>> {
    let mut pairs = Vec::new();
    let mut paths: Vec<PathBuf> = std::fs::read_dir(truth)
        .with_context(|| truth.display().to_string())?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.file_name().and_then(|n| n.to_str()).is_some_and(|n| n.starts_with("evaluation_points_")))
        .collect();
    paths.sort();
    for path in paths {
        let text = std::fs::read_to_string(&path).with_context(|| path.display().to_string())?;
        pairs.extend(parse_points_csv(&text, &path.display().to_string())?.pairs);
    }
    Ok(pairs)
}

/// The cross-visit click errors of one model, as the tests measure them (exact synthetic
/// clicks: scored at the click's own depth, nearest 3D point within 8 px).
fn score_clicks(model: &Reconstruction, clicks: &[ClickPair]) -> Summary {
    let options = ScoreOptions { radius_px: 8.0, at_click_depth: true, ..ScoreOptions::default() };
    score(std::slice::from_ref(model), clicks, &options).overall
}
