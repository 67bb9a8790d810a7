//! rosgraph_msgs: simulated time.

use crate::{builtin_interfaces::Time, ros_message};
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Clock {
    pub clock: Time,
}

ros_message!(Clock, "rosgraph_msgs", [Time]);
