//! tf2_msgs: the `/tf` and `/tf_static` topics.

use crate::{geometry_msgs::TransformStamped, ros_message};
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct TFMessage {
    pub transforms: Vec<TransformStamped>,
}

ros_message!(TFMessage, "tf2_msgs", [TransformStamped]);
