//! revisit_msgs: the messages between Revisit's nodes. The `.msg` files in `revisit_msgs/msg/` are
//! the source; these types mirror them field by field (checked by `tests/python.rs`).

use crate::{
    geometry_msgs::PoseWithCovariance,
    message,
    sensor_msgs::{CameraInfo, CompressedImage},
    std_msgs::Header,
};
use serde::{Deserialize, Serialize};

/// Starts or ends a visit; see `SessionControl.msg`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct SessionControl {
    pub header: Header,
    pub command: u8,
    pub session: String,
    pub source: String,
    pub keyframes: u32,
}

impl SessionControl {
    pub const START: u8 = 0;
    pub const END: u8 = 1;
}

/// One image kept by keyframe selection; see `Keyframe.msg`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Keyframe {
    pub header: Header,
    pub session: String,
    pub camera: String,
    pub image_name: String,
    pub image: CompressedImage,
    pub camera_info: CameraInfo,
    pub has_prior: bool,
    pub prior: PoseWithCovariance,
}

/// Local features of one image; see `Features.msg`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Features {
    pub header: Header,
    pub session: String,
    pub image_name: String,
    pub method: String,
    pub roll_degrees: i32,
    pub count: u32,
    pub width: u32,
    pub height: u32,
    pub keypoints: Vec<f32>,
    pub scores: Vec<f32>,
    pub descriptor_size: u32,
    pub descriptor_type: u8,
    #[serde(with = "serde_bytes")]
    pub descriptors: Vec<u8>,
}

impl Features {
    pub const DESCRIPTOR_UINT8: u8 = 0;
    pub const DESCRIPTOR_FLOAT32: u8 = 1;
}

#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct PlaceCandidate {
    pub session: String,
    pub image_name: String,
    pub distance: f32,
    pub roll_degrees: i32,
}

/// The nearest images of earlier visits to one query image; see `PlaceCandidates.msg`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct PlaceCandidates {
    pub header: Header,
    pub session: String,
    pub image_name: String,
    pub candidates: Vec<PlaceCandidate>,
}

/// Verified matches between two images of different visits; see `CrossVisitMatches.msg`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct CrossVisitMatches {
    pub header: Header,
    pub session1: String,
    pub image_name1: String,
    pub session2: String,
    pub image_name2: String,
    pub method: String,
    pub roll_degrees: i32,
    pub matches: Vec<u32>,
    pub rolls_tried: Vec<i32>,
    pub inliers_by_roll: Vec<u32>,
    pub fell_back: bool,
    pub probabilities: Vec<f32>,
}

#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct SessionStatus {
    pub session: String,
    pub visit: u32,
    pub images: u32,
    pub registered: u32,
}

/// What the mapper is doing and what the map holds; see `MapStatus.msg`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct MapStatus {
    pub header: Header,
    pub state: u8,
    pub message: String,
    pub sessions: Vec<SessionStatus>,
    pub points: u32,
    pub mean_reprojection_error_px: f64,
}

impl MapStatus {
    pub const IDLE: u8 = 0;
    pub const COLLECTING: u8 = 1;
    pub const MAPPING: u8 = 2;
    pub const READY: u8 = 3;
    pub const FAILED: u8 = 4;
}

message!(SessionControl, "revisit_msgs", "revisit_msgs", [Header]);
message!(Keyframe, "revisit_msgs", "revisit_msgs", [Header, CompressedImage, CameraInfo, PoseWithCovariance]);
message!(Features, "revisit_msgs", "revisit_msgs", [Header]);
message!(PlaceCandidate, "revisit_msgs", "revisit_msgs", []);
message!(PlaceCandidates, "revisit_msgs", "revisit_msgs", [Header, PlaceCandidate]);
message!(CrossVisitMatches, "revisit_msgs", "revisit_msgs", [Header]);
message!(SessionStatus, "revisit_msgs", "revisit_msgs", []);
message!(MapStatus, "revisit_msgs", "revisit_msgs", [Header, SessionStatus]);
