//! `revisit bench ...`: figures side by side with the reference implementations.

mod sift;

#[derive(clap::Subcommand)]
pub enum Bench {
    /// Revisit's SIFT against OpenCV's on the same real images: time per image
    /// at equal feature count and verified inliers on overlapping pairs.
    Sift(sift::Args),
}

pub fn run(bench: Bench) -> anyhow::Result<()> {
    match bench {
        Bench::Sift(args) => sift::run(args),
    }
}
