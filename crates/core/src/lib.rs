//! Revisit's vocabulary: sessions, images, cameras, poses, features, matches and
//! reconstructions. Every other crate speaks these types.
//!
//! Invariant: no I/O and no dependencies beyond math. Frames are named
//! `b_from_a` (`cam_from_world`); the camera frame is COLMAP's (x right, y down,
//! z forward); pixel (0, 0) is the *corner* of the top-left pixel, so the centre
//! of that pixel is (0.5, 0.5), as in COLMAP.

mod align;
mod camera;
mod features;
mod fingerprint;
mod name;
mod navigation;
mod pose;
mod reconstruction;

pub use align::{umeyama, AlignError, Similarity};
pub use camera::{Camera, CameraModel, CameraModelError};
pub use features::{
    pair_from_id, pair_id, CrossKey, Features, Keypoint, LearnedFeatures, Roll, TwoViewConfig, TwoViewGeometry,
};
pub use fingerprint::Fingerprint;
pub use name::{check_camera_name, check_session_name, session_of, ImageName, NameError, PairKind, SESSION_SEPARATOR};
pub use navigation::NavigationFix;
pub use pose::Rigid3;
pub use reconstruction::{Image, Observation, Point3D, Reconstruction, TrackElement};

/// COLMAP's identifier of a camera (one per session and image size in Revisit).
pub type CameraId = u32;
/// COLMAP's identifier of an image in a database or model.
pub type ImageId = u32;
/// COLMAP's identifier of a triangulated 3D point.
pub type Point3DId = u64;

/// Joins a session name and a file name into a COLMAP image name (unchecked:
/// [`ImageName::new`] checks both parts).
pub fn image_name(session: &str, file: &str) -> String {
    format!("{session}{SESSION_SEPARATOR}{file}")
}
