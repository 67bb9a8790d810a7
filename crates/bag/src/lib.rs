//! rosbag2 bags: read mcap and sqlite3 (`.db3`) storage, write rosbag2-compatible mcap.
//!
//! A bag is a folder with `metadata.yaml` and its storage files, or a single `.mcap` or `.db3`
//! file. [`Bag::messages`] streams raw CDR messages in storage order with their topic; typed
//! decoding is `revisit_msgs::decode`. Reading allocates at most what one record holds, and a length
//! field can never claim more than the file has. [`BagWriter`] writes what `ros2 bag`, Foxglove,
//! Python `mcap-ros2-support` and `rosbags` open: profile `ros2`, `ros2msg` schemas with their
//! dependencies, `cdr` messages, per-channel QoS metadata, statistics and a `metadata.yaml`.

mod metadata;
mod read;
mod write;

pub use metadata::{QosProfile, Storage};
pub use read::{Bag, BagInfo, Offered, RawMessage, Topic, TopicStats};
pub use write::{BagWriter, TopicHandle, WrittenBag};

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum BagError {
    #[error("{}: {source}", path.display())]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{}: not a bag: {why}", path.display())]
    NotABag { path: PathBuf, why: String },
    #[error("{}: {source}", path.display())]
    Metadata { path: PathBuf, source: serde_yaml_ng::Error },
    #[error("{}: corrupt mcap: {source}", path.display())]
    Mcap { path: PathBuf, source: mcap::McapError },
    #[error("{}: corrupt sqlite3 bag: {source}", path.display())]
    Sqlite { path: PathBuf, source: rusqlite::Error },
    /// One message cannot be read; the rest of the file can.
    #[error("{}: {why}", path.display())]
    BadMessage { path: PathBuf, why: String },
    #[error("{}: topic {topic}: {why}", path.display())]
    Topic { path: PathBuf, topic: String, why: String },
    #[error("{}: topic {topic}: {source}", path.display())]
    Encode { path: PathBuf, topic: String, source: revisit_msgs::CdrError },
}
