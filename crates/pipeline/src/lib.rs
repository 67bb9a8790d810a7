//! Revisit's stages in sequence, over the store and the image files.
//!
//! Each stage takes its inputs and returns what it produced (hloc's style), so
//! `revisit reconstruct`, the ROS nodes and the benchmarks call the very same
//! functions. Work already in the store is never redone: each stage asks the
//! store what is finished first.
//!
//! Invariant: the stage libraries (`features`, `matching`) stay pure; this
//! crate is where they meet files, the store and COLMAP.

pub mod cross;
pub mod export;
pub mod ingest;
pub mod learned;
pub mod mapping;
mod stages;

use std::path::PathBuf;

pub use stages::{
    extract_features, load_features, match_pairs, plan_pairs, CrossStrategy, LearnedKeypoints, PlannedPair, StageCounts,
};

#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("session {session}: folder {dir} holds no images (.png, .jpg, .jpeg)")]
    NoImages { session: String, dir: PathBuf },
    #[error("session {session}: {dir} holds one image; a session needs at least two")]
    OneImage { session: String, dir: PathBuf },
    #[error("session {0} is given twice")]
    DuplicateSession(String),
    #[error("{path}: unreadable image: {reason}")]
    BadImage { path: PathBuf, reason: String },
    #[error(
        "session {session}: {path} is {}x{} but {first} is {}x{}; a session must have one camera and one image size",
        size.0, size.1, first_size.0, first_size.1
    )]
    MixedSizes { session: String, path: PathBuf, size: (u32, u32), first: PathBuf, first_size: (u32, u32) },
    #[error("{path}: {reason}")]
    Features { path: PathBuf, reason: String },
    #[error("matching images {} and {}: {reason}", pair.0, pair.1)]
    Matching { pair: (revisit_core::ImageId, revisit_core::ImageId), reason: String },
    #[error(transparent)]
    Store(#[from] revisit_store::StoreError),
    #[error(transparent)]
    Colmap(#[from] revisit_colmap::ColmapError),
    #[error(transparent)]
    Mapper(#[from] revisit_colmap::MapperError),
}

/// How a long stage reports progress: the CLI draws bars, a node logs.
pub trait Progress: Sync {
    fn start(&self, stage: &str, len: u64);
    fn advance(&self);
    fn finish(&self);
}

/// Progress that goes nowhere.
pub struct Silent;

impl Progress for Silent {
    fn start(&self, _stage: &str, _len: u64) {}
    fn advance(&self) {}
    fn finish(&self) {}
}
