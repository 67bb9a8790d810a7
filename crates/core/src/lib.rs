//! Revisit's vocabulary: sessions, images, cameras, poses, features, matches and
//! reconstructions. Every other crate speaks these types.
//!
//! Invariant: no I/O and no dependencies beyond math. Frames are named
//! `b_from_a` (`cam_from_world`); the camera frame is COLMAP's (x right, y down,
//! z forward); pixel (0, 0) is the *corner* of the top-left pixel, so the centre
//! of that pixel is (0.5, 0.5), as in COLMAP.

mod camera;
mod features;
mod pose;
mod reconstruction;

pub use camera::{Camera, CameraModel, CameraModelError};
pub use features::{pair_from_id, pair_id, Features, Keypoint, LearnedFeatures, Roll, TwoViewConfig, TwoViewGeometry};
pub use pose::Rigid3;
pub use reconstruction::{Image, Observation, Point3D, Reconstruction, TrackElement};

/// COLMAP's identifier of a camera (one per session and image size in Revisit).
pub type CameraId = u32;
/// COLMAP's identifier of an image in a database or model.
pub type ImageId = u32;
/// COLMAP's identifier of a triangulated 3D point.
pub type Point3DId = u64;

/// Separator between a session name and a file name in COLMAP image names:
/// the image `frame_001.png` of session `2024` is named `2024/frame_001.png`.
pub const SESSION_SEPARATOR: char = '/';

/// Splits a COLMAP image name `session/file` into its session and file parts.
/// Returns `None` for a name with no session part.
pub fn split_image_name(name: &str) -> Option<(&str, &str)> {
    name.split_once(SESSION_SEPARATOR)
}

/// Joins a session name and a file name into a COLMAP image name.
pub fn image_name(session: &str, file: &str) -> String {
    format!("{session}{SESSION_SEPARATOR}{file}")
}
