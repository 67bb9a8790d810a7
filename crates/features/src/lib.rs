//! Local features: image in, features out (no files, no topics).
//!
//! [`extract_sift`] is Lowe's SIFT with COLMAP's conventions: keypoints in the
//! pixel-corner convention and 128-byte descriptors (RootSIFT by default).
//! [`learned`] holds ALIKED and XFeat on ONNX Runtime.

pub mod learned;
mod sift;

pub use sift::{extract_sift, Normalization, SiftOptions, MIN_IMAGE_SIZE_PX};

/// Why features could not be extracted.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum FeatureError {
    #[error("invalid feature option {option}: {reason}")]
    InvalidOption { option: &'static str, reason: String },
    #[error("image of {width}x{height} pixels is too small for feature extraction (at least {min}x{min})")]
    ImageTooSmall { width: u32, height: u32, min: u32 },
}
