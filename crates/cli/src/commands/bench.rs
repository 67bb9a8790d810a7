//! `revisit bench ...`: figures side by side with the reference implementations.

mod bag;
mod colmap;
mod live;
mod matching;
mod sift;

#[derive(clap::Subcommand)]
pub enum Bench {
    /// Bag read throughput (MB/s, messages/s, images decoded/s) beside Python
    /// mcap + mcap-ros2-support on the same mcap file.
    Bag(bag::Args),
    /// Revisit's whole reconstruction beside pycolmap's own pipeline (SIFT,
    /// exhaustive or sequential matching, incremental mapping) on the same
    /// sessions: seconds per stage, images registered, peak memory, time ratio.
    Colmap(colmap::Args),
    /// Revisit's SIFT against OpenCV's on the same real images: time per image
    /// at equal feature count and verified inliers on overlapping pairs.
    Sift(sift::Args),
    /// The cross-visit strategies (sift, learned-all, learned-cross, vpr) on one
    /// synthetic dataset: matching time, pairs, inliers, sessions in one model,
    /// cross-visit error; place-recognition recall; roll-search agreement and
    /// cost; learned extraction speed.
    Matching(matching::Args),
    /// The node graph under a live camera (30 Hz 1280x720 by default, JPEG then raw): frames
    /// received, dropped and lost, keyframes kept, each node's sustained rate and peak memory,
    /// and the delay from a keyframe to its registered pose.
    Live(live::Args),
}

pub fn run(bench: Bench) -> anyhow::Result<()> {
    match bench {
        Bench::Bag(args) => bag::run(args),
        Bench::Colmap(args) => colmap::run(args),
        Bench::Sift(args) => sift::run(args),
        Bench::Matching(args) => matching::run(args),
        Bench::Live(args) => live::run(args),
    }
}

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
