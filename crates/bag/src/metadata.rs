//! rosbag2's `metadata.yaml` and QoS profiles.

use serde::{Deserialize, Serialize};

/// How a bag stores its messages.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Storage {
    Mcap,
    Sqlite3,
}

impl Storage {
    pub fn identifier(self) -> &'static str {
        match self {
            Storage::Mcap => "mcap",
            Storage::Sqlite3 => "sqlite3",
        }
    }

    /// From a storage file's extension.
    pub fn of_file(path: &std::path::Path) -> Option<Storage> {
        match path.extension()?.to_str()? {
            "mcap" => Some(Storage::Mcap),
            "db3" => Some(Storage::Sqlite3),
            _ => None,
        }
    }
}

#[derive(Debug, Serialize)]
pub(crate) struct MetadataFile {
    pub rosbag2_bagfile_information: Metadata,
}

/// What a reader needs of `metadata.yaml`, whatever its version: the storage files.
#[derive(Debug, Deserialize)]
pub(crate) struct ReadMetadataFile {
    pub rosbag2_bagfile_information: ReadMetadata,
}

#[derive(Debug, Default, Deserialize)]
#[serde(default)]
pub(crate) struct ReadMetadata {
    pub relative_file_paths: Vec<String>,
    pub compression_format: String,
    pub compression_mode: String,
}

/// rosbag2's metadata, version 9, as Revisit writes it.
#[derive(Debug, Default, Serialize)]
pub(crate) struct Metadata {
    pub version: u32,
    pub storage_identifier: String,
    pub duration: Nanoseconds,
    pub starting_time: NanosecondsSinceEpoch,
    pub message_count: u64,
    pub topics_with_message_count: Vec<TopicWithCount>,
    pub compression_format: String,
    pub compression_mode: String,
    pub relative_file_paths: Vec<String>,
    pub files: Vec<FileInfo>,
    pub custom_data: Option<std::collections::BTreeMap<String, String>>,
    pub ros_distro: String,
}

#[derive(Debug, Default, Serialize)]
pub(crate) struct Nanoseconds {
    pub nanoseconds: u64,
}

#[derive(Debug, Default, Serialize)]
pub(crate) struct NanosecondsSinceEpoch {
    pub nanoseconds_since_epoch: u64,
}

#[derive(Debug, Default, Serialize)]
pub(crate) struct TopicWithCount {
    pub topic_metadata: TopicMetadata,
    pub message_count: u64,
}

#[derive(Debug, Default, Serialize)]
pub(crate) struct TopicMetadata {
    pub name: String,
    #[serde(rename = "type")]
    pub type_name: String,
    pub serialization_format: String,
    pub offered_qos_profiles: Vec<QosProfile>,
    pub type_description_hash: String,
}

#[derive(Debug, Default, Serialize)]
pub(crate) struct FileInfo {
    pub path: String,
    pub starting_time: NanosecondsSinceEpoch,
    pub duration: Nanoseconds,
    pub message_count: u64,
}

/// A publisher's QoS as rosbag2 records it (rmw's numeric policies), so that `ros2 bag play`
/// offers the same.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct QosProfile {
    pub history: u32,
    pub depth: u32,
    pub reliability: u32,
    pub durability: u32,
    pub deadline: QosDuration,
    pub lifespan: QosDuration,
    pub liveliness: u32,
    pub liveliness_lease_duration: QosDuration,
    pub avoid_ros_namespace_conventions: bool,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct QosDuration {
    pub sec: u64,
    pub nsec: u64,
}

impl QosProfile {
    /// A reliable, volatile, keep-last-10 publisher: rclcpp's default.
    pub const RELIABLE: QosProfile = QosProfile::new(1, 2);
    /// A reliable publisher that keeps its last message for late subscribers (maps, status).
    pub const LATCHED: QosProfile = QosProfile::new(1, 1);
    /// Sensor data: best effort, volatile.
    pub const SENSOR_DATA: QosProfile = QosProfile::new(2, 2);

    const fn new(reliability: u32, durability: u32) -> Self {
        // rmw's "infinite" duration.
        const UNSET: QosDuration = QosDuration { sec: 9_223_372_036, nsec: 854_775_807 };
        QosProfile {
            history: 1,
            depth: 10,
            reliability,
            durability,
            deadline: UNSET,
            lifespan: UNSET,
            liveliness: 1,
            liveliness_lease_duration: UNSET,
            avoid_ros_namespace_conventions: false,
        }
    }
}
