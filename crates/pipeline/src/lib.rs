//! Revisit's pipeline: the stages of a joint multi-visit reconstruction over a
//! work folder, its store, the image files and COLMAP, as one library that
//! every front end drives.
//!
//! [`Workspace`] is the reconstruction job: open a work folder with checked
//! [`ReconstructOptions`], add sessions, run. Each stage returns what it
//! produced (hloc's style) and [`Workspace::run`] reads as their sequence; it
//! returns the typed [`Report`] that `report.json` holds. `revisit
//! reconstruct`, the benchmarks and the ROS 2 nodes call the same functions;
//! a node that sees one image or one pair at a time uses the streaming entry
//! points ([`stages::sift_features`], `revisit_matching::match_learned_pair`,
//! the store's one-record writes) that the stage loops are built on.
//!
//! Work already in the store is never redone: each stage asks the store what
//! is finished first, and writes one image or pair per transaction. Every long
//! loop checks a [`Cancel`] token between items.
//!
//! Invariant: the stage libraries (`features`, `matching`, `places`) stay
//! pure; this crate is where they meet files, the store and COLMAP.

pub mod bags;
pub mod cache;
pub mod cross;
pub mod export;
pub mod images;
pub mod ingest;
pub mod keyframes;
pub mod learned;
pub mod locate;
pub mod mapping;
pub mod memory;
pub mod messages;
pub mod navigation;
pub mod odometry;
pub mod options;
pub mod report;
pub mod stages;
pub mod surfaces;
pub mod workers;
mod workspace;

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

pub use options::{CrossStrategy, ReconstructOptions};
pub use report::Report;
pub use stages::StageCounts;
pub use workspace::{Session, SessionImage, Workspace};

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
    #[error("{0}")]
    Name(String),
    /// A bag that cannot be read or written, or a topic that holds no images.
    #[error("{0}")]
    Bag(String),
    /// A navigation CSV that cannot be read: its file, row (1 = the header) and what is wrong.
    #[error("{file}: row {row}: {message}")]
    BadNavigation { file: String, row: usize, message: String },
    #[error("session {session}: none of the {rows} navigation rows names one of its images (the first names {first})")]
    NavigationUnmatched { session: String, rows: usize, first: String },
    #[error("{path}: unreadable image: {reason}")]
    BadImage { path: PathBuf, reason: String },
    #[error(
        "session {session}, camera {camera}: {path} is {}x{} but {first} is {}x{}; a camera has one image size",
        size.0, size.1, first_size.0, first_size.1
    )]
    MixedSizes {
        session: String,
        camera: String,
        path: PathBuf,
        size: (u32, u32),
        first: PathBuf,
        first_size: (u32, u32),
    },
    #[error("session {session}, camera {camera}: {reason}")]
    Camera { session: String, camera: String, reason: String },
    #[error("{path}: {reason}")]
    Features { path: PathBuf, reason: String },
    #[error("matching images {} and {}: {reason}", pair.0, pair.1)]
    Matching { pair: (revisit_core::ImageId, revisit_core::ImageId), reason: String },
    #[error(transparent)]
    Options(#[from] options::OptionsError),
    #[error(transparent)]
    Onnx(#[from] revisit_onnx::OnnxError),
    #[error("stopped on request; finished work is stored, and running again resumes")]
    Cancelled,
    #[error(transparent)]
    Store(#[from] revisit_store::StoreError),
    #[error(transparent)]
    Colmap(#[from] revisit_colmap::ColmapError),
    #[error(transparent)]
    Mapper(#[from] revisit_colmap::MapperError),
    #[error(transparent)]
    Dense(revisit_colmap::DenseError),
}

impl From<revisit_colmap::DenseError> for PipelineError {
    fn from(error: revisit_colmap::DenseError) -> Self {
        match error {
            revisit_colmap::DenseError::Cancelled => Self::Cancelled,
            other => Self::Dense(other),
        }
    }
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

/// A request to stop, shared between whoever asks (a signal handler, a
/// node's shutdown) and the stages, which check it between items: the item in
/// flight is finished and stored, nothing after it is started.
#[derive(Clone, Debug, Default)]
pub struct Cancel(Arc<AtomicBool>);

impl Cancel {
    pub fn new() -> Cancel {
        Cancel::default()
    }

    /// Asks every holder of this token to stop.
    pub fn cancel(&self) {
        self.0.store(true, Ordering::SeqCst);
    }

    pub fn is_cancelled(&self) -> bool {
        self.0.load(Ordering::SeqCst)
    }

    /// `Err(Cancelled)` once a stop was asked for.
    pub fn check(&self) -> Result<(), PipelineError> {
        if self.is_cancelled() {
            return Err(PipelineError::Cancelled);
        }
        Ok(())
    }

    /// The flag itself, for code below this crate (the mapper driver).
    pub fn flag(&self) -> &AtomicBool {
        &self.0
    }
}
