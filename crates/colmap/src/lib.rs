//! revisit-colmap: COLMAP models on disk and the COLMAP mapping driver.
//!
//! [`model`] reads and writes sparse models (`cameras`, `images`, `points3D`)
//! in COLMAP's binary and text forms, byte for byte as COLMAP 3.8 and
//! pycolmap 4.2.1 do, plus a PLY export of the points. The decoders and
//! encoders work on byte slices and strings; thin wrappers do the file I/O.
//!
//! [`dense`] makes each visit's dense surface from its images at a model's poses
//! (OpenCV's semi-global matching).
//!
//! Invariant: this is the only crate that starts Python.

pub mod dense;
mod mapper;
pub mod model;

pub use dense::{run_dense, DenseError, DenseOptions, DenseRun, DenseVisit};
pub use mapper::{
    check_python, run_mapper, run_until_cancelled, ChangeAware, CrossMatchFate, Engine, Mapped, MapperError,
    MapperOptions, MapperRun, ModelSummary, NavigationOffset, MIN_POSE_PRIORS, PYTHON_ENV,
};

pub use model::{
    read_model, read_models, session_palette, write_binary, write_ply, write_text, ColmapError, ModelFormat, PlyColors,
};
