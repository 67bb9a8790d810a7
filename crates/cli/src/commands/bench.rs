//! `revisit bench ...`: figures side by side with the reference implementations.

mod matching;
mod sift;

#[derive(clap::Subcommand)]
pub enum Bench {
    /// Revisit's SIFT against OpenCV's on the same real images: time per image
    /// at equal feature count and verified inliers on overlapping pairs.
    Sift(sift::Args),
    /// The cross-visit strategies (sift, learned-all, learned-cross, vpr) on one
    /// synthetic dataset: matching time, pairs, inliers, sessions in one model,
    /// cross-visit error; place-recognition recall; roll-search agreement and
    /// cost; learned extraction speed.
    Matching(matching::Args),
}

pub fn run(bench: Bench) -> anyhow::Result<()> {
    match bench {
        Bench::Sift(args) => sift::run(args),
        Bench::Matching(args) => matching::run(args),
    }
}
