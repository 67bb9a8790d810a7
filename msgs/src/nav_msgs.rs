//! nav_msgs: trajectories and odometry.

use crate::{
    geometry_msgs::{PoseStamped, PoseWithCovariance, TwistWithCovariance},
    ros_message,
    std_msgs::Header,
};
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Path {
    pub header: Header,
    pub poses: Vec<PoseStamped>,
}

/// The pose of `child_frame_id` in `header.frame_id`, and its velocity in `child_frame_id`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Odometry {
    pub header: Header,
    pub child_frame_id: String,
    pub pose: PoseWithCovariance,
    pub twist: TwistWithCovariance,
}

ros_message!(Path, "nav_msgs", [Header, PoseStamped]);
ros_message!(Odometry, "nav_msgs", [Header, PoseWithCovariance, TwistWithCovariance]);
