//! std_msgs: the header of stamped messages.

use crate::{builtin_interfaces::Time, ros_message};
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Header {
    pub stamp: Time,
    pub frame_id: String,
}

ros_message!(Header, "std_msgs", [Time]);
