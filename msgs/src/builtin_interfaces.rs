//! builtin_interfaces: time stamps.

use crate::ros_message;
use serde::{Deserialize, Serialize};

/// A point in time: seconds and nanoseconds since the clock's epoch.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
pub struct Time {
    pub sec: i32,
    pub nanosec: u32,
}

impl Time {
    /// From nanoseconds since the epoch (rosbag2's log times).
    pub fn from_nanos(nanos: i64) -> Self {
        Self { sec: nanos.div_euclid(1_000_000_000) as i32, nanosec: nanos.rem_euclid(1_000_000_000) as u32 }
    }

    pub fn as_nanos(&self) -> i64 {
        i64::from(self.sec) * 1_000_000_000 + i64::from(self.nanosec)
    }
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Duration {
    pub sec: i32,
    pub nanosec: u32,
}

ros_message!(Time, "builtin_interfaces", []);
ros_message!(Duration, "builtin_interfaces", []);
